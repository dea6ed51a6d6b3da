"""The design tools, one subpackage per stage in pipeline order (paper Sections 2–5).

``structure`` (the design file, the truss FE model, its modes, model updating, placement,
export), ``friction`` (the LuGre law, the isolated-joint rig, friction records and the
identification), ``reduction`` (Hankel mode selection and Krylov vectors), ``plant`` (the
nonlinear closed loop and its simulation schemes), ``control`` (the laws, the LQG design, the
controller artefact, the closed-loop study) and ``network`` (the CAN protocol description).
Here: the names a first script needs, from the structure stage.
"""

from smartjoint.common.errors import DesignError, ModelError, SmartjointError
from smartjoint.design.structure.description import Design
from smartjoint.design.structure.fem import FEModel, build_model
from smartjoint.design.structure.modal import Modes, solve_modes
from smartjoint.design.structure.spec import REFERENCE_DESIGN, load_design, parse_design
from smartjoint.design.structure.updating import UpdatingResult, update_model, updated_design

__all__ = [
    "Design",
    "DesignError",
    "FEModel",
    "ModelError",
    "Modes",
    "REFERENCE_DESIGN",
    "SmartjointError",
    "UpdatingResult",
    "build_model",
    "updated_design",
    "load_design",
    "parse_design",
    "solve_modes",
    "update_model",
]
