"""The nonlinear closed-loop plant (paper Eq. 12) and its seam to the controllers.

Owns: the controller interface (``interface``: Measurements, Controller, ConstantNormalForce,
HoldDuringExcitation), the disturbances (``disturbance``), the single Van Loan discretisation
(``discretisation``), the joints' LuGre laws (``joints``), the kernel protocol and the native
plant kernel (``kernel``, ``plant_kernel.c/.h``), the schemes (``fixed_step``, ``stick_exact``,
``linear``) and their registry (``schemes``), the loop driver (``loop.simulate``) and the Radau
reference (``reference``). Imports only ``smartjoint.common``, ``design.structure`` and
``design.friction``; never the controllers.
"""

from smartjoint.design.plant.discretisation import discretise, first_order_hold, work_coefficients
from smartjoint.design.plant.disturbance import TriangularPulse, triangular_pulse
from smartjoint.design.plant.interface import ConstantNormalForce, Controller, HoldDuringExcitation, Measurements
from smartjoint.design.plant.kernel import Kernel, PlantRun, Scheme
from smartjoint.design.plant.loop import SimulationResult, simulate
from smartjoint.design.plant.reference import reference_simulation, reference_system
from smartjoint.design.plant.schemes import SCHEMES

__all__ = [
    "SCHEMES",
    "ConstantNormalForce",
    "Controller",
    "HoldDuringExcitation",
    "Kernel",
    "Measurements",
    "PlantRun",
    "Scheme",
    "SimulationResult",
    "TriangularPulse",
    "discretise",
    "first_order_hold",
    "reference_simulation",
    "reference_system",
    "simulate",
    "triangular_pulse",
    "work_coefficients",
]
