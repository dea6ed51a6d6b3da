"""Control design (paper Section 5): the SISO law (``laws``), the LQG design (``lqg``), the
controllers that run it (``filter``: clipped-optimal and fully active LQG), the controller
artefact (``artifact``, built from a design by ``artifact_building``) and the closed-loop study
of Section 6 (``study``, each of its runs in ``runs``).

The controllers implement ``design.plant.interface.Controller``; they depend on the plant's
interface and discretisation only, never on the simulator. The names below are the
controllers and their design; ``artifact``, ``artifact_building``, ``runs`` and ``study`` are
imported as modules (they import these, so this package does not import them).
"""

from smartjoint.design.control.filter import ActiveLqg, ClippedLqg
from smartjoint.design.control.laws import (
    STATUS_ESTIMATE_RESET,
    STATUS_INPUT_IMPLAUSIBLE,
    STATUS_INPUT_INVALID,
    STATUS_OK,
    SisoLaw,
    boundary_layer,
    input_status,
)
from smartjoint.design.control.lqg import LqgDesign, check_sample_time, design_lqg
from smartjoint.design.control.ordered_sums import ordered_product

__all__ = [
    "STATUS_ESTIMATE_RESET",
    "STATUS_INPUT_IMPLAUSIBLE",
    "STATUS_INPUT_INVALID",
    "STATUS_OK",
    "ActiveLqg",
    "ClippedLqg",
    "LqgDesign",
    "SisoLaw",
    "boundary_layer",
    "check_sample_time",
    "design_lqg",
    "input_status",
    "ordered_product",
]
