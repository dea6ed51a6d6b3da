"""The CAN message layer of a controller as data: frames, signals, scalings, ranges, senders and
cycle times, generated from the controller artefact as a cantools database (``protocol``); the
worst-case load of a bus (``busload``), the supervision bus of local mode (``joint_node``) and
the plan of frames over several buses (``plan``).

The one description of the bus that the C generator (``smartjoint.codegen.can_layer``) and the
bench (``smartjoint.bench``) both read, so neither imports the other for it. May import
``smartjoint.common`` and the controller artefact (``design/control``).
"""

from smartjoint.design.network.protocol import (
    AMPLIFIER_FAULTS,
    CONTROLLER,
    CONTROLLER_FAULTS,
    E2E_SIGNALS,
    MODE_SAFE,
    MODES,
    Amplifier,
    database,
    dbc_text,
    load_dbc,
)

__all__ = [
    "AMPLIFIER_FAULTS",
    "CONTROLLER",
    "CONTROLLER_FAULTS",
    "E2E_SIGNALS",
    "MODES",
    "MODE_SAFE",
    "Amplifier",
    "database",
    "dbc_text",
    "load_dbc",
]
