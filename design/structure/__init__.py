"""The structure (paper Sections 2–3): the design file, the truss FE model, its modes, model
updating, joint placement and the neutral model export.

In pipeline order: ``spec`` reads a design file (through ``files`` and ``table``) into the
dataclasses of ``description`` (``control_section`` reads [control], ``sections`` [safety] and
[updating]); ``beam`` is the
12-DOF element, ``mesh`` discretises the members (Fig. 6) and ``fem`` assembles M, K, S, E, F, V,
W (Eq. 4–10); ``modal`` solves the modes and builds the modal model (Eq. 5, 11); ``updating``
fits the model to the measured frequencies, pairing the modes by MAC (``correlation``) where the
design carries EMA shapes; ``participation`` gives the effective modal masses; ``placement``
ranks the connectors for joints;
``export`` writes the model out.
"""

from smartjoint.design.structure.description import Design
from smartjoint.design.structure.export import export_model
from smartjoint.design.structure.fem import FEModel, build_model
from smartjoint.design.structure.modal import ModalModel, Modes, modal_model, solve_modes
from smartjoint.design.structure.spec import REFERENCE_DESIGN, load_design, parse_design
from smartjoint.design.structure.updating import UpdatingResult, update_model, updated_design

__all__ = [
    "Design",
    "FEModel",
    "ModalModel",
    "Modes",
    "REFERENCE_DESIGN",
    "UpdatingResult",
    "build_model",
    "export_model",
    "load_design",
    "modal_model",
    "parse_design",
    "solve_modes",
    "update_model",
    "updated_design",
]
