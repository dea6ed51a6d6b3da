"""The friction joints (paper Section 3.2): the LuGre law (Eq. 1–3), the isolated-joint rig, its
records and the identification of the LuGre parameters.

``model`` is the seam to the friction model (the registry's entry, ``common/friction_registry.py``):
the parameter sets of a design's joints and the plant's joint laws, whatever the model;

``lugre`` is the law and its exact-exponential step, ``rig`` the simulated test rig and
``rig_integration`` its integrator (C kernel ``rig_kernel.c``), ``records`` the friction records
it writes and identification reads, ``record_quantities`` their units and plausible bounds,
``record_screening`` the checks and the regime of records before a fit, ``identify`` the two
Eq. 3 steps, ``output_error`` the output-error step on the rig model, and ``fitting`` what both
share (signal filters, NRMSE, the statistics of a step). The function
``identify`` is imported from its module (``from smartjoint.design.friction.identify import
identify``): exported here it would hide the module of the same name.
"""

from smartjoint.design.friction.equation_error import model_friction, simulate_friction
from smartjoint.design.friction.fitting import StepResult, nrmse
from smartjoint.design.friction.identify import Identification
from smartjoint.design.friction.lugre import TABLE_1, LuGreParameters
from smartjoint.design.friction.model import FrictionLaw, joint_parameters, plant_laws
from smartjoint.design.friction.record_screening import classify
from smartjoint.design.friction.records import Record, RecordError, read_record, write_record

__all__ = [
    "FrictionLaw",
    "Identification",
    "LuGreParameters",
    "Record",
    "RecordError",
    "StepResult",
    "TABLE_1",
    "classify",
    "joint_parameters",
    "model_friction",
    "nrmse",
    "plant_laws",
    "read_record",
    "simulate_friction",
    "write_record",
]
