"""The local joint node: the paper's first control concept (Section 5.1), a feedback controller in
each semi-active joint. The executable specification of the generated ``<prefix>_node.c``.

A node reads its own joint's sensors (sliding velocity v, friction force u_R and the applied
normal force F_N, at the joint, not over CAN), runs the SISO law of Eq. 30–31 on them and commands
its own amplifier. The bus carries only supervision, every ``supervision_cycles`` samples:

* the supervisor's heartbeat ``CONTROLLER_STATUS`` (its mode: ``siso`` runs the local law, every
  other mode puts the joint at its safe normal force), which the node checks end to end: its CRC
  with the freshness byte it carries in the clear (``cycle_high``), its 4-bit alive counter
  (``e2e.check``) and its whole 12-bit count (``e2e.check_heartbeat``), so that a heartbeat stream
  replayed 16·m heartbeats old, whose 4-bit counter runs on as if fresh, feeds no node;
* the node's ``NODE_STATUS_<j>`` (0x300 + j, 8 bytes): E2E bytes with the heartbeat echo, the mode
  the node applies, its fault bits, the law's status bits, the commanded and the measured F_N; its
  CRC covers the freshness byte of the heartbeat it echoes (0 before any).

Policy (docs/safety.md): a node follows the last valid heartbeat's mode. A node that loses the
heartbeat (``timeout_cycles`` supervision periods without a valid one) **keeps that mode** and
says so (``heartbeat_lost``): the SISO law needs only the joint's own sensors, and it can only
dissipate energy (the semi-active joint cannot destabilise the structure), so it is the best a
node can do alone; a joint at a constant force dissipates less. A node that never saw a heartbeat
holds the safe force (mode INIT). An input its law cannot use puts the joint at the safe force at
once (the law clears its memory, ``SisoLaw``) and holds it for ``recovery_cycles`` samples of
usable inputs after the last bad one. Faults of one node never move another joint: in the central
SISO law one bad input makes every joint safe, locally only its own.
"""

from __future__ import annotations

import numpy as np

from smartjoint.bench import e2e
from smartjoint.common import law_registry
from smartjoint.design.control.laws import SisoLaw
from smartjoint.design.network.joint_node import (
    HEARTBEAT_CYCLE_BYTE,
    HEARTBEAT_ID,
    HEARTBEAT_LENGTH,
    NODE_LAW,
    NODE_STATUS_LENGTH,
    SILENT_MAX,
    NodeConfig,
    force_code,
)
from smartjoint.design.plant.interface import Measurements

MODE_NODE_LAW = NODE_LAW.mode


class JointNode:
    """One joint node (module docstring): ``receive`` a frame, ``step`` once a sample with the
    joint's own measurements, ``transmit`` the status frame when one is due."""

    def __init__(self, config: NodeConfig):
        self.config = c = config
        self.law = SisoLaw(
            c.sample_time,
            [c.normal_force_min],
            [c.normal_force_max],
            [c.boundary_layer],
            safe_normal_force=[c.safe_normal_force],
            sliding_velocity_limit=[c.sliding_velocity_limit],
            friction_force_limit=[c.friction_force_limit],
            measured_normal_force_min=[c.measured_normal_force_min],
            measured_normal_force_max=[c.measured_normal_force_max],
        )
        self.reset()

    def reset(self) -> None:
        self.law.reset()
        self.mode = law_registry.MODE_INIT  # the last valid heartbeat's
        self.silent = SILENT_MAX  # samples since the last valid heartbeat: none yet
        self.echoed = 0  # the last valid heartbeat's count: its bits 0–3 echoed, 4–11 the status's freshness
        self.receiver: int | None = None  # the heartbeat's last followed alive counter
        self.heartbeat_count: int | None = None  # its last followed 12-bit count
        self.hold = 0  # samples the safe force still holds after a bad input
        self.sample = 0
        self.counter = 0  # the status frame's alive counter
        self.faults = 0
        self.status = 0
        self.command = self.config.safe_normal_force
        self.applied = 0.0
        self.pending = False

    def receive(self, frame_id: int, data: bytes) -> bool:
        """A frame from the bus: only a heartbeat of the right length whose CRC holds and whose
        12-bit count (``e2e.check_heartbeat``) and 4-bit counter (``e2e.check``) both step 1…3
        counts. A count repeated or behind the last one — a replay 16·m heartbeats old, whose
        4-bit counter looks fresh — is ignored before the counter moves (else the next genuine
        heartbeat would be its repeat); otherwise each follows the frame unless it repeats or is
        stale (``e2e.Check.resynchronises``). A node that has lost the heartbeat takes a SAFE
        heartbeat with a count of 0 … 3 as a supervisor's (re)start and follows it afresh."""
        if frame_id != HEARTBEAT_ID or len(data) != HEARTBEAT_LENGTH:
            return False
        count = data[HEARTBEAT_CYCLE_BYTE] << 4 | data[1] & 0x0F
        start = count <= e2e.MAX_COUNTER_STEP and data[2] & 0x0F == law_registry.MODE_SAFE
        start = start and data[0] == e2e.frame_crc(frame_id, data, data[HEARTBEAT_CYCLE_BYTE])
        if self.heartbeat_lost and start:  # a supervisor that has (re)started, SAFE at power-up: a new count
            self.heartbeat_count = self.receiver = None
        checked = e2e.check_heartbeat(frame_id, data, self.heartbeat_count)
        if not checked.resynchronises:
            return False
        counter = e2e.check(frame_id, data, self.receiver, data[HEARTBEAT_CYCLE_BYTE])
        if counter.resynchronises:
            self.receiver = counter.counter
        self.heartbeat_count = checked.counter
        if not (counter.ok and checked.ok):
            return False
        self.mode = data[2] & 0x0F
        self.echoed = checked.counter
        self.silent = 0
        return True

    @property
    def heartbeat_lost(self) -> bool:
        return self.silent > self.config.timeout_samples

    def step(self, velocity: float, friction: float, applied: float) -> float:
        """One sample: the command F_N for the joint's amplifier from its own measurements."""
        c = self.config
        self.silent = min(self.silent + 1, SILENT_MAX)
        faults = 0
        if self.mode == MODE_NODE_LAW:
            measured = Measurements(0.0, np.zeros(0), np.array([velocity]), np.array([friction]), np.array([applied]))
            command = float(self.law.step(measured)[0])
            self.status = self.law.status
            if self.status:
                faults |= 1
                self.hold = c.recovery_cycles
            elif self.hold > 0:
                self.hold -= 1
                faults |= 4
                command = c.safe_normal_force
        else:
            self.law.reset()
            self.status, self.hold = 0, 0
            faults |= 8
            command = c.safe_normal_force
        if self.heartbeat_lost:
            faults |= 2
        self.faults, self.command, self.applied = faults, command, float(applied)
        self.pending = self.sample % c.supervision_cycles == 0
        self.sample += 1
        return command

    def applied_mode(self) -> int:
        return MODE_NODE_LAW if self.mode == MODE_NODE_LAW and not (self.faults & 5) else law_registry.MODE_SAFE

    def transmit(self) -> tuple[int, bytes] | None:
        """The NODE_STATUS frame when one is due after a step, else None."""
        if not self.pending:
            return None
        self.pending = False
        payload = bytearray(NODE_STATUS_LENGTH)
        payload[1] = (self.echoed & 0x0F) << 4
        payload[2] = self.applied_mode() | (self.faults << 4)
        payload[3] = self.status & 0xFF
        payload[4:6] = force_code(self.command).to_bytes(2, "little")
        payload[6:8] = force_code(self.applied).to_bytes(2, "little")
        e2e.protect(self.config.status_id, payload, self.counter, e2e.freshness(self.echoed))
        self.counter = (self.counter + 1) % e2e.COUNTER_MODULO
        return self.config.status_id, bytes(payload)


def compiled_nodes(artifact, real: str = "double", prefix: str = "smartjoint", **options):
    """The generated node firmware (``codegen.joint_nodes``) of every joint, compiled with the
    strict flags and loaded with cffi: (lib, ffi, names). ``options`` go to ``render_nodes``."""
    from smartjoint.bench.e2e import RUNTIME
    from smartjoint.codegen import build, generate, joint_nodes

    files = joint_nodes.render_nodes(artifact, prefix, real, **options)
    types = f"{prefix}_types.h"
    files[types] = generate.render(artifact, real, prefix)[types]
    for runtime in ("sj_e2e.c", "sj_e2e.h"):
        files[runtime] = (RUNTIME / runtime).read_text()
    sources = [n for n in files if n.endswith(".c")]
    module = build.load(f"node_{real}", files, f"{prefix}_node.h", sources)[1]
    return module


class CompiledNode:
    """One joint's generated node (``compiled_nodes``) behind ``JointNode``'s interface."""

    def __init__(self, module, artifact, joint: int, prefix: str = "smartjoint"):
        self.ffi, self.lib, self.prefix = module.ffi, module.lib, prefix
        name = artifact.joint_names[joint].lower()
        # cffi reads an extern const struct as a value: the node points at a copy it keeps.
        self.config = self.ffi.new(f"{prefix}_node_config *", getattr(self.lib, f"{prefix}_node_{name}_config"))
        self.state = self.ffi.new(f"{prefix}_node_state *")
        self.input = self.ffi.new(f"{prefix}_node_input *")
        self._id = self.ffi.new("uint32_t *")
        self._data = self.ffi.new("uint8_t[64]")
        self._length = self.ffi.new("uint8_t *")
        self.reset()

    def reset(self) -> None:
        getattr(self.lib, f"{self.prefix}_node_init")(self.state, self.config)

    def receive(self, frame_id: int, data: bytes) -> bool:
        buffer = self.ffi.new("uint8_t[]", bytes(data) or b"\0")
        return bool(getattr(self.lib, f"{self.prefix}_node_rx")(self.state, frame_id, buffer, len(data)))

    def step(self, velocity: float, friction: float, applied: float) -> float:
        self.input.sliding_velocity, self.input.friction_force, self.input.normal_force = velocity, friction, applied
        return float(getattr(self.lib, f"{self.prefix}_node_step")(self.state, self.input))

    def transmit(self) -> tuple[int, bytes] | None:
        if not getattr(self.lib, f"{self.prefix}_node_tx")(self.state, self._id, self._data, self._length):
            return None
        return int(self._id[0]), bytes(self.ffi.buffer(self._data, self._length[0]))

    @property
    def faults(self) -> int:
        return int(self.state.faults)

    @property
    def status(self) -> int:
        return int(self.state.status)


__all__ = ["CompiledNode", "JointNode", "compiled_nodes"]
