"""Software-in-the-loop bench: the compiled firmware on a python-can bus with the plant,
sensor nodes and amplifier models around it.

Owns the E2E protection and its C twin loaded (``e2e``), the
amplifier nodes (``amplifier``), the compiled firmware image (``firmware``), the faults the bench
injects (``faults``), the per-sample CAN loop behind the controller interface (``loop``), the
safe-state fault matrix (``safety``) and its table and figure (``safety_report``), the paper's
study through the loop (``sil``), CAN logs (``logs``) and their replay through the firmware
(``replay``), and the sweep engine (``sweep``: Dask workers running the compiled closed loop,
Parquet results).

May import ``smartjoint.common``, ``smartjoint.design`` and ``smartjoint.codegen`` (it compiles
and runs the generated C); only the command line builds on it.
"""

from smartjoint.bench.amplifier import AmplifierModel
from smartjoint.bench.faults import Fault, check_faults, parse_fault
from smartjoint.bench.firmware import Firmware
from smartjoint.bench.logs import LogContent
from smartjoint.bench.loop import SilLoop, SilRecord, open_bus
from smartjoint.bench.safety import fault_matrix
from smartjoint.bench.sil import fault_run, sil_study

__all__ = [
    "AmplifierModel",
    "Fault",
    "Firmware",
    "LogContent",
    "SilLoop",
    "SilRecord",
    "check_faults",
    "fault_matrix",
    "fault_run",
    "open_bus",
    "parse_fault",
    "sil_study",
]
