"""The joint node's side of the bus and its constants (``bench.joint_node`` is its executable
specification, ``codegen.joint_nodes`` its firmware): the paper's first control concept
(Section 5.1), a feedback controller in each semi-active joint, supervised over CAN.

Every ``supervision_cycles`` samples the supervisor sends its heartbeat ``CONTROLLER_STATUS``
(mode: the node law's mode runs the law, any other the safe normal force) and each node its
``NODE_STATUS_<j>`` (0x300 + j, 8 bytes): byte 0 CRC-8, byte 1 the alive counter (bits 0–3) and
the heartbeat echo (bits 4–7), byte 2 the mode the node applies (bits 0–3) and its fault bits
(bits 4–7, ``NODE_FAULTS``), byte 3 the law's status bits, bytes 4–5 and 6–7 the commanded and the
measured F_N (uint16, 0.02 N, little-endian).

Freshness (``bench.e2e``): the supervisor counts its heartbeats modulo ``HEARTBEAT_COUNTS``; a
heartbeat carries bits 0–3 of its count as its alive counter and bits 4–11 in the clear
(``cycle_high``, byte ``HEARTBEAT_CYCLE_BYTE``), and its CRC covers them as its freshness byte. A
node judges the whole 12-bit count (a heartbeat behind the last one is ignored: a replay 16·m
heartbeats old, whose 4-bit counter looks fresh, cannot feed it) and protects its status with the
freshness byte of the heartbeat it echoes, so a status replayed 16…4 095 heartbeats old fails the
supervisor's CRC.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from cantools.database import can

from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.network import protocol

NODE_STATUS_BASE = 0x300
NODE_STATUS_LENGTH = 8
HEARTBEAT_ID = 0x080  # CONTROLLER_STATUS (design.network.protocol)
HEARTBEAT_LENGTH = 8  # CONTROLLER_STATUS without failed_<joint> bits (protocol.controller_status_message)
HEARTBEAT_CYCLE_BYTE = 6  # CONTROLLER_STATUS.cycle_high: bits 4–11 of the heartbeat count
HEARTBEAT_COUNTS = 4096  # the heartbeat count wraps here: counter (bits 0–3) and cycle_high (4–11)
SUPERVISION_CYCLES = 10  # heartbeat and node status every 10 samples: 100 Hz at 1 kHz
FORCE_SCALE = 0.02  # N per bit of the F_N fields (uint16: 0 … 1310.7 N)
FORCE_CODES = 0xFFFF
SILENT_MAX = 0xFFFF  # the silence counter saturates
# NODE_STATUS_<j>.faults (4 bits at bit 20), in bit order.
NODE_FAULTS = ("input", "heartbeat_lost", "recovering", "safe_commanded")
# The supervisor's health word of a node (``bench.supervisor``), in bit order: no valid status
# for timeout_cycles periods; the node lost the heartbeat; it holds its safe force while the law
# is requested; its heartbeat echo is older than the heartbeat before the last.
SUPERVISOR_HEALTH = ("silent", "alone", "safe", "stale")
NODE_LAW = law_registry.node_law()  # the law a node runs on its own joint


@dataclass(frozen=True)
class NodeConfig:
    """One joint node's constants, taken from the controller artefact (``node_config``)."""

    index: int
    name: str
    normal_force_min: float
    normal_force_max: float
    boundary_layer: float  # ε [m/s] (Eq. 30)
    safe_normal_force: float
    sliding_velocity_limit: float
    friction_force_limit: float
    measured_normal_force_min: float
    measured_normal_force_max: float
    timeout_cycles: int  # supervision periods without a valid heartbeat until it is lost
    recovery_cycles: int  # samples of usable inputs before the law commands again
    supervision_cycles: int  # samples per heartbeat and per status frame
    sample_time: float

    @property
    def status_id(self) -> int:
        return NODE_STATUS_BASE + self.index

    @property
    def timeout_samples(self) -> int:
        return self.timeout_cycles * self.supervision_cycles


def node_config(artifact, joint: int, supervision_cycles: int = SUPERVISION_CYCLES) -> NodeConfig:
    """The node of joint ``joint`` (index into the artefact's joints) with the artefact's law and limits."""
    pick = lambda field: float(np.asarray(getattr(artifact, field), dtype=float).reshape(-1)[joint])  # noqa: E731
    return NodeConfig(
        index=joint,
        name=artifact.joint_names[joint],
        normal_force_min=pick(NODE_LAW.lower_force_field()),  # the law's F_N^min (a preload)
        normal_force_max=pick("normal_force_max"),
        boundary_layer=pick(dict(NODE_LAW.artifact)["boundary_layer"]),
        safe_normal_force=pick("safe_normal_force"),
        sliding_velocity_limit=pick("sliding_velocity_limit"),
        friction_force_limit=pick("friction_force_limit"),
        measured_normal_force_min=pick("measured_normal_force_min"),
        measured_normal_force_max=pick("measured_normal_force_max"),
        timeout_cycles=int(artifact.timeout_cycles),
        recovery_cycles=int(artifact.recovery_cycles),
        supervision_cycles=int(supervision_cycles),
        sample_time=float(artifact.sample_time),
    )


def force_code(value: float) -> int:
    """An F_N field: value / 0.02 N rounded half up, 0 below (NaN too), saturated at 0xFFFF —
    the C's ``force_code``, in double."""
    scaled = value * (1.0 / FORCE_SCALE)  # the C multiplies by this literal too
    if not scaled > 0.0:
        return 0
    if scaled >= FORCE_CODES:
        return FORCE_CODES
    return int(scaled + 0.5)


def supervision_database(artifact, supervision_cycles: int = SUPERVISION_CYCLES) -> can.Database:
    """The bus of local mode: the supervisor's heartbeat and one ``NODE_STATUS_<j>`` per joint,
    each every ``supervision_cycles`` samples (module docstring); cantools database for the DBC
    and the bus load (``design.network.busload``).

    Raises
    ------
    ModelError
        A period that is no whole number of milliseconds or beyond the DBC's cycle-time range.
    """
    if not (isinstance(supervision_cycles, int) and supervision_cycles >= 1):
        raise ModelError(f"supervision_cycles: {supervision_cycles!r} — a whole number of samples >= 1")
    cycle = protocol.cycle_ms(artifact.sample_time * supervision_cycles)
    heartbeat = protocol.controller_status_message(cycle)
    nodes = [can.Node(protocol.CONTROLLER, comment="supervisor: heartbeat and mode")]
    messages = [heartbeat]
    for j, name in enumerate(artifact.joint_names):
        tag = protocol.identifier(name, "joint")
        node = f"JOINT_NODE_{tag}"
        nodes.append(can.Node(node, comment=f"joint {name}: its own sensors, {NODE_LAW.display} law and amplifier"))
        force = dict(scale=FORCE_SCALE, signed=False, unit="N", minimum=0.0, maximum=FORCE_SCALE * FORCE_CODES)
        signals = protocol.e2e_signals(NODE_STATUS_BASE + j, sync=12) + [
            can.Signal("mode", 16, 4, minimum=0, maximum=15, comment="the mode the node applies"),
            can.Signal("faults", 20, 4, comment="bits " + ", ".join(f"{k} {f}" for k, f in enumerate(NODE_FAULTS))),
            can.Signal("law_status", 24, 8, comment="status bits of the node's law"),
            protocol.scaled("command", 32, 16, comment="commanded F_N", **force),
            protocol.scaled("applied", 48, 16, comment="measured F_N", **force),
        ]
        for signal in signals:
            signal.receivers = [protocol.CONTROLLER]
        messages.append(
            can.Message(
                NODE_STATUS_BASE + j,
                f"NODE_STATUS_{tag}",
                NODE_STATUS_LENGTH,
                signals,
                senders=[node],
                cycle_time=cycle,
                is_fd=True,
                comment=f"joint node {name}: mode, faults and forces",
            )
        )
    for signal in heartbeat.signals:
        signal.receivers = [n.name for n in nodes[1:]]
    db = can.Database(
        messages,
        nodes,
        version=f"smartjoint local mode, artefact {artifact.artifact_sha256[:16]}",
        dbc_specifics=protocol.fd_specifics(),
    )
    db.refresh()
    return db


__all__ = [
    "HEARTBEAT_COUNTS",
    "HEARTBEAT_CYCLE_BYTE",
    "HEARTBEAT_ID",
    "NODE_FAULTS",
    "NODE_LAW",
    "NODE_STATUS_BASE",
    "SUPERVISION_CYCLES",
    "NodeConfig",
    "force_code",
    "node_config",
    "supervision_database",
]
