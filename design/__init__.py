"""Design tools: design file, truss FE model, modal model, model updating (paper Sections 2–3).

Kept apart as in pyMOR: ``spec`` (the design file), ``beam``/``fem`` (the model), ``modal``
(the eigen solution), ``updating`` (the algorithm that fits the model to measurements).
"""

from smartjoint.common.errors import DesignError, ModelError, SmartjointError
from smartjoint.design.structure.fem import FEModel, build_model
from smartjoint.design.structure.modal import Modes, solve_modes
from smartjoint.design.structure.description import Design
from smartjoint.design.structure.spec import REFERENCE_DESIGN, load_design, parse_design
from smartjoint.design.structure.updating import UpdatingResult, update_model, updated_design

__all__ = [
    "Design", "DesignError", "FEModel", "ModelError", "Modes", "REFERENCE_DESIGN", "SmartjointError",
    "UpdatingResult", "build_model", "updated_design", "load_design", "parse_design", "solve_modes", "update_model",
]
