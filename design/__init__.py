"""Design tools: design file, truss FE model, modal model, model updating (paper Sections 2–3).

Kept apart as in pyMOR: ``spec`` (the design file), ``beam``/``fem`` (the model), ``modal``
(the eigen solution), ``updating`` (the algorithm that fits the model to measurements).
"""

from .errors import DesignError, ModelError, SmartjointError
from .fem import FEModel, build_model
from .modal import Modes, solve_modes
from .spec import REFERENCE_DESIGN, Design, load_design, parse_design
from .updating import UpdatingResult, update_model, updated_design

__all__ = [
    "Design", "DesignError", "FEModel", "ModelError", "Modes", "REFERENCE_DESIGN", "SmartjointError",
    "UpdatingResult", "build_model", "updated_design", "load_design", "parse_design", "solve_modes", "update_model",
]
