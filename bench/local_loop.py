"""Software-in-the-loop bench of local mode: one compiled joint node per joint, each driving its own
amplifier, supervised over a python-can bus (docs/safety.md, "Local mode"; issue 33).

Per sample t_k (the plant simulation calls ``LocalLoop.step`` as its controller):

1. the supervisor (the generated ``<prefix>_supervisor.c``, ``bench.supervisor``) steps and,
   every ``supervision_cycles`` samples, sends its heartbeat ``CONTROLLER_STATUS`` (mode: the node
   law's, or SAFE) — E2E-protected: bits 0–3 of its heartbeat count as the alive counter, bits
   4–11 in the clear (``cycle_high``) and as its CRC's freshness byte;
2. each node takes the frames waiting for it (``<prefix>_node_rx``), steps on its own joint's
   measurements (v, u_R, F_N as the plant reports them, unquantised: they do not cross the bus)
   and drives its amplifier over its local link (``AmplifierModel.drive``);
3. each node's status frame, when due, goes on the bus; the supervisor takes them and keeps each
   node's health (silent, alone, safe, stale: ``LocalRecord.health``);
4. the amplifiers' output over [t_k, t_k+1) sets the normal forces (F_N^max while the study's
   pulse acts, as in ``bench.loop``).

The nodes are the generated C (``bench.joint_node.compiled_nodes``, float build by default); the
nodes of ``target_joints`` run instead as node images on the emulated target
(``bench.node_target.TargetNode``, processor in the loop) beside the others. The supervisor
requests one mode for the run. ``heartbeat_until`` silences its transmitter from that time on
(the nodes' policy on a lost bus; the supervisor counts on, so from the 16th heartbeat after the
last one the nodes took their statuses echo it too old — a replay's bytes — and fail its CRC:
the nodes fall silent to it); ``silent_nodes`` silences those nodes' status frames (the
supervisor's view of a lost node).
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from smartjoint.bench.amplifier import AmplifierModel, amplifier_options
from smartjoint.bench.joint_node import CompiledNode, compiled_nodes
from smartjoint.bench.loop import open_bus
from smartjoint.bench.supervisor import CompiledSupervisor, compiled_supervisor
from smartjoint.common import law_registry
from smartjoint.design.network import busload, joint_node, protocol
from smartjoint.design.plant.interface import Measurements


@dataclass
class LocalRecord:
    """Per sample: each node's command and fault bits, the amplifiers' force, the plant's F_N, and
    the supervisor's health word of each node."""

    time: list = field(default_factory=list)
    command: list = field(default_factory=list)
    faults: list = field(default_factory=list)
    amplifier_force: list = field(default_factory=list)
    applied: list = field(default_factory=list)
    health: list = field(default_factory=list)  # the supervisor's health word of every node


class LocalLoop:
    """Local mode behind the simulation's controller interface (module docstring).

    Parameters
    ----------
    artifact : ControllerArtifact
        The design's controller artefact: its joints, SISO law, limits and timeouts.
    real : str
        The nodes' scalar type, ``"float"`` (as on the target) or ``"double"``.
    excitation_end : float
        End of the study's pulse [s]: until then the plant gets ``excitation_force``.
    excitation_force : array_like, optional
        F_N while the pulse acts [N]; default the artefact's F_N^max.
    mode : int, optional
        The mode the operator requests of the supervisor: the node law's (default) or SAFE.
    heartbeat_until : float, optional
        The supervisor falls silent from this time on [s]; default never.
    supervision_cycles : int
        Samples per heartbeat and per node status frame.
    interface, channel : str
        The python-can bus (default the in-process ``virtual`` one).
    amplifier : dict, optional
        Options of the amplifier models (``time_constant``, ``slew_rate``, ``temperature``,
        ``voltage_max``).
    target_joints : sequence of int
        Joints whose node runs as its image on the emulated target (float build only).
    silent_nodes : sequence of int
        Joints whose node's status frames never reach the bus.
    """

    def __init__(
        self,
        artifact,
        real: str = "float",
        excitation_end: float = 0.0,
        excitation_force=None,
        mode: int | None = None,
        heartbeat_until: float = np.inf,
        supervision_cycles: int = joint_node.SUPERVISION_CYCLES,
        interface: str = "virtual",
        channel: str = "smartjoint-local",
        amplifier: dict | None = None,
        target_joints=(),
        silent_nodes=(),
    ):
        from smartjoint.common.errors import ModelError

        a = self.artifact = artifact
        self.target_joints = tuple(sorted({int(j) for j in target_joints}))
        if self.target_joints and real != "float":
            raise ModelError(f"real: {real!r} — a node on the target runs the float build only")
        if any(not 0 <= j < len(a.joint_names) for j in self.target_joints):
            raise ModelError(f"target_joints: {list(target_joints)} — joint indices 0 … {len(a.joint_names) - 1}")
        self.targets: dict = {}  # joint → TargetNode while its emulation runs
        self.sample_time = float(a.sample_time)
        self.real = real
        self.excitation_end = float(excitation_end)
        self.excitation_force = np.asarray(a.normal_force_max if excitation_force is None else excitation_force, float)
        self.mode = joint_node.NODE_LAW.mode if mode is None else int(mode)
        self.silent_nodes = frozenset(int(j) for j in silent_nodes)
        self.heartbeat_until = float(heartbeat_until)
        self.supervision_cycles = int(supervision_cycles)
        self.db = joint_node.supervision_database(a, self.supervision_cycles)
        self.interface, self.channel = interface, channel
        self.amplifier_options = amplifier_options(a, amplifier, local=True)
        self.module = compiled_nodes(a, real)
        self.supervisor = CompiledSupervisor(compiled_supervisor(a, supervision_cycles=self.supervision_cycles))
        if not self.supervisor.request(self.mode):
            raise ModelError(
                f"mode: {self.mode} — the supervisor requests {joint_node.NODE_LAW.mode} "
                f"({joint_node.NODE_LAW.name}) or {law_registry.MODE_SAFE} (SAFE)"
            )
        self.buses: list = []

    def reset(self) -> None:
        """Open the buses, power the nodes and amplifiers up: a run starts."""
        self.close()
        try:
            for _ in range(2):
                self.buses.append(open_bus(self.interface, self.channel, preserve_timestamps=True))
        except BaseException:
            self.close()
            raise
        self.supervisor_bus, self.node_bus = self.buses
        a = self.artifact
        for j in self.target_joints:
            if j in self.targets:
                self.targets[j].reset()
            else:
                from smartjoint.bench.node_target import TargetNode

                self.targets[j] = TargetNode(a, j)
        self.nodes = [self.targets.get(j) or CompiledNode(self.module, a, j) for j in range(len(a.joint_names))]
        self.amplifiers = [AmplifierModel(**options) for options in self.amplifier_options]
        self.supervisor.reset()
        self.supervisor.request(self.mode)
        self.k = 0
        self.record = LocalRecord()
        self.frame_counts: defaultdict[str, int] = defaultdict(int)
        self.statuses: dict[int, dict] = {}  # the supervisor's last decoded status per node

    def close(self) -> None:
        """Shut the buses and end the emulations of the target nodes."""
        targets, self.targets = self.targets, {}
        for node in targets.values():
            node.close()
        buses, self.buses = self.buses, []
        for bus in buses:
            try:
                bus.shutdown()
            except Exception:  # keep closing the others
                pass

    def _send(self, bus, frame_id: int, data: bytes, t: float) -> None:
        import can

        bus.send(can.Message(arbitration_id=frame_id, data=data, is_fd=True, bitrate_switch=True, timestamp=t))
        self.frame_counts[self.db.get_message_by_frame_id(frame_id).name] += 1

    @staticmethod
    def _drain(bus) -> list:
        out = []
        while (message := bus.recv(timeout=0.0)) is not None:
            out.append(message)
        return out

    def step(self, measurements: Measurements) -> np.ndarray:
        """One sample through local mode (steps 1–4 of the module docstring)."""
        t = float(measurements.time)
        self.supervisor.step()
        heartbeat = self.supervisor.transmit()
        if heartbeat is not None and t < self.heartbeat_until - 1e-12:
            self._send(self.supervisor_bus, *heartbeat, t)
        frames = [(int(m.arbitration_id), bytes(m.data)) for m in self._drain(self.node_bus)]
        commands, forces = [], []
        for j, (node, amplifier) in enumerate(zip(self.nodes, self.amplifiers)):
            for frame in frames:
                node.receive(*frame)
            command = node.step(
                float(measurements.sliding_velocity[j]),
                float(measurements.friction_force[j]),
                float(measurements.normal_force[j]),
            )
            amplifier.drive(command)
            forces.append(amplifier.advance(self.sample_time))
            commands.append(command)
            status = node.transmit()
            if status is not None and j not in self.silent_nodes:
                frame_id, data = status
                self._send(self.node_bus, frame_id, data, t)
        for message in self._drain(self.supervisor_bus):
            definition = self.db.get_message_by_frame_id(message.arbitration_id)
            self.statuses[message.arbitration_id] = dict(definition.decode(bytes(message.data), decode_choices=False))
            self.supervisor.receive(int(message.arbitration_id), bytes(message.data))
        amplifier_force = np.array(forces)
        applied = self.excitation_force.copy() if t < self.excitation_end - 1e-12 else amplifier_force.copy()
        r = self.record
        r.time.append(t)
        r.command.append(commands)
        r.faults.append([node.faults for node in self.nodes])
        r.amplifier_force.append(amplifier_force)
        r.applied.append(applied)
        r.health.append(self.supervisor.health)
        self.k += 1
        return np.maximum(applied, 0.0)

    def statistics(self, duration: float, bitrate: int, data_bitrate: int | None) -> dict:
        """Frames per name and the measured bus load over the run."""
        busy = sum(
            count * busload.frame_time(self.db.get_message_by_name(name).length, True, bitrate, data_bitrate)
            for name, count in self.frame_counts.items()
        )
        return {
            "frames": dict(sorted(self.frame_counts.items())),
            "bus_load": busy / duration,
            "planned_bus_load": busload.bus_load(
                protocol.load_dbc(protocol.dbc_text(self.db)), bitrate, data_bitrate
            ).load,
        }


__all__ = ["LocalLoop", "LocalRecord"]
