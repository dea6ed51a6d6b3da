"""The supervisor of local mode: the central controller's side of the joint nodes' bus. The
executable specification of the generated ``<prefix>_supervisor.c`` (``codegen.joint_nodes``).

Every ``supervision_cycles`` samples the supervisor sends the heartbeat ``CONTROLLER_STATUS``
with the mode the operator requested: the node law's mode runs the law on every node, SAFE holds
every joint at its safe normal force (``bench.joint_node`` is the node). It reads each node's
``NODE_STATUS_<j>`` (``design.network.joint_node``), checked end to end, and keeps per node the
last valid status, decoded, and a health word (``SUPERVISOR_HEALTH``, in bit order):

* ``silent``: no valid status for more than ``timeout_cycles`` supervision periods — the node or
  its bus is lost;
* ``alone``: the node reports ``heartbeat_lost``: it runs on by itself;
* ``safe``: it holds its safe force while the law is requested (a bad input, its recovery);
* ``stale``: its heartbeat echo is neither the last heartbeat's counter nor the one before: it
  acts on old supervision.

The supervisor counts its heartbeats modulo 4 096: a heartbeat carries bits 0–3 of its count as
its alive counter and bits 4–11 in the clear (``cycle_high``), its CRC covering them as the
freshness byte (``bench.e2e``). A status is taken to echo one of the last 16 heartbeats
(``e2e.echoed_cycle``) and its CRC checked with that heartbeat's freshness byte: a status replayed
16…4 095 heartbeats old fails, and so does the status of a node that has lost the heartbeat for 16
periods or more — it falls silent.

Policy (docs/safety.md, "Local mode"): the supervisor never changes the requested mode by
itself. A semi-active joint cannot destabilise the structure, and a node that runs alone does
the best it can; what a degraded node calls for (log it, tell the operator, request SAFE) is the
application's decision, made on these health words. Power-up requests SAFE.

Per sample: :meth:`Supervisor.step` first, then :meth:`Supervisor.transmit` (the heartbeat when one
is due) and :meth:`Supervisor.receive` for every frame. Integers only: the float and the double
build are the same program.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from smartjoint.bench import e2e
from smartjoint.common import law_registry
from smartjoint.design.network.joint_node import (
    HEARTBEAT_COUNTS,
    HEARTBEAT_CYCLE_BYTE,
    HEARTBEAT_ID,
    HEARTBEAT_LENGTH,
    NODE_FAULTS,
    NODE_LAW,
    NODE_STATUS_BASE,
    NODE_STATUS_LENGTH,
    SILENT_MAX,
    SUPERVISION_CYCLES,
    SUPERVISOR_HEALTH,
)

SILENT, ALONE, SAFE, STALE = (1 << SUPERVISOR_HEALTH.index(bit) for bit in ("silent", "alone", "safe", "stale"))
HEARTBEAT_LOST = 1 << NODE_FAULTS.index("heartbeat_lost")
MODES = (NODE_LAW.mode, law_registry.MODE_SAFE)  # what the operator may request


@dataclass
class NodeView:
    """What the supervisor knows of one node: its last valid status, decoded, and its health."""

    receiver: int | None = None  # its status frames' last accepted counter
    silent: int = SILENT_MAX  # samples since its last valid status (saturating)
    command: int = 0  # its commanded F_N, 0.02 N per bit
    applied: int = 0  # its measured F_N, 0.02 N per bit
    mode: int = 0  # the mode it applies
    faults: int = 0  # its NODE_STATUS fault bits
    law_status: int = 0  # its law's status bits
    echo: int = 0  # the heartbeat counter it echoes (bits 0–3 of the heartbeat's count)
    health: int = SILENT  # SILENT | ALONE | SAFE | STALE


@dataclass
class Supervisor:
    """The supervisor of ``joints`` nodes (module docstring).

    Parameters
    ----------
    joints : int
        The number of nodes, ``NODE_STATUS_<j>`` = 0x300 + j.
    timeout_samples : int
        Samples without a valid status until a node is silent (``timeout_cycles`` periods).
    supervision_cycles : int
        Samples per heartbeat.
    """

    joints: int
    timeout_samples: int
    supervision_cycles: int = SUPERVISION_CYCLES
    nodes: list[NodeView] = field(init=False)

    def __post_init__(self):
        self.reset()

    @classmethod
    def of(cls, configs) -> Supervisor:
        """The supervisor of the nodes ``configs`` (``joint_node.node_config`` of every joint)."""
        return cls(len(configs), max(c.timeout_samples for c in configs), configs[0].supervision_cycles)

    def reset(self) -> None:
        """Power-up: SAFE requested, every node silent."""
        self.nodes = [NodeView() for _ in range(self.joints)]
        self.phase = 0
        self.mode = law_registry.MODE_SAFE
        self.heartbeats = 0  # the last heartbeat's count, modulo HEARTBEAT_COUNTS (e2e.CYCLE_MODULO)
        self.sent = False
        self.pending = False

    @property
    def counter(self) -> int:
        """The last heartbeat's alive counter: bits 0–3 of its count."""
        return self.heartbeats % e2e.COUNTER_MODULO

    def request(self, mode: int) -> bool:
        """The operator's mode: the node law's or SAFE (True), anything else refused (False)."""
        if mode not in MODES:
            return False
        self.mode = mode
        return True

    def step(self) -> None:
        """One sample, before transmit and receive: every node's silence, a heartbeat due."""
        for node in self.nodes:
            node.silent = min(node.silent + 1, SILENT_MAX)
            if node.silent > self.timeout_samples:
                node.health |= SILENT
        self.pending = self.phase == 0
        self.phase = self.supervision_cycles - 1 if self.phase == 0 else self.phase - 1

    def transmit(self) -> tuple[int, bytes] | None:
        """The heartbeat when one is due, else None."""
        if not self.pending:
            return None
        self.pending = False
        self.heartbeats = (self.heartbeats + 1) % HEARTBEAT_COUNTS
        self.sent = True
        payload = bytearray(HEARTBEAT_LENGTH)
        payload[2] = self.mode
        payload[HEARTBEAT_CYCLE_BYTE] = fresh = e2e.freshness(self.heartbeats)  # cycle_high, in the clear
        return HEARTBEAT_ID, bytes(e2e.protect(HEARTBEAT_ID, payload, self.counter, fresh))

    def receive(self, frame_id: int, data: bytes) -> bool:
        """A frame from the bus: only a node status of the right length that passes its E2E check
        counts (``e2e.check`` with the freshness byte of the heartbeat it echoes, taken 0…15
        heartbeats old; the receiver follows it unless it repeats or is stale)."""
        if not NODE_STATUS_BASE <= frame_id < NODE_STATUS_BASE + self.joints or len(data) != NODE_STATUS_LENGTH:
            return False
        node = self.nodes[frame_id - NODE_STATUS_BASE]
        fresh = e2e.freshness(e2e.echoed_cycle(self.heartbeats, data[1] >> 4))
        result = e2e.check(frame_id, data, node.receiver, fresh)
        if result.resynchronises:
            node.receiver = result.counter
        if not result.ok:
            return False
        node.silent = 0
        node.echo, node.mode, node.faults, node.law_status = data[1] >> 4, data[2] & 0x0F, data[2] >> 4, data[3]
        node.command = int.from_bytes(data[4:6], "little")
        node.applied = int.from_bytes(data[6:8], "little")
        before = (self.counter - 1) % e2e.COUNTER_MODULO
        node.health = (
            (ALONE if node.faults & HEARTBEAT_LOST else 0)
            | (SAFE if self.mode == NODE_LAW.mode and node.mode != NODE_LAW.mode else 0)
            | (STALE if self.sent and node.echo not in (self.counter, before) else 0)
        )
        return True

    @property
    def health(self) -> list[int]:
        """Every node's health word, in joint order."""
        return [node.health for node in self.nodes]


def compiled_supervisor(artifact, prefix: str = "smartjoint", **options):
    """The generated supervisor (``codegen.joint_nodes``), compiled with the strict flags and
    loaded with cffi. ``options`` go to ``render_nodes``."""
    from smartjoint.codegen import build, joint_nodes

    name = f"{prefix}_supervisor"
    files = {k: v for k, v in joint_nodes.render_nodes(artifact, prefix, **options).items() if k.startswith(name)}
    for runtime in ("sj_e2e.c", "sj_e2e.h"):
        files[runtime] = (e2e.RUNTIME / runtime).read_text()
    return build.load("supervisor", files, f"{name}.h", [n for n in files if n.endswith(".c")])[1]


class CompiledSupervisor:
    """The generated supervisor (``compiled_supervisor``) behind :class:`Supervisor`'s interface."""

    def __init__(self, module, prefix: str = "smartjoint"):
        self.ffi, self.lib, self.name = module.ffi, module.lib, f"{prefix}_supervisor"
        self.state = self.ffi.new(f"{self.name}_state *")
        self._id = self.ffi.new("uint32_t *")
        self._data = self.ffi.new("uint8_t[64]")
        self._length = self.ffi.new("uint8_t *")
        self.reset()

    def _call(self, function: str, *arguments):
        return getattr(self.lib, f"{self.name}_{function}")(*arguments)

    def reset(self) -> None:
        self._call("init", self.state)

    @property
    def counter(self) -> int:
        """The last heartbeat's alive counter: bits 0–3 of its count."""
        return self.heartbeats % e2e.COUNTER_MODULO

    def request(self, mode: int) -> bool:
        return bool(self._call("request", self.state, mode))

    def step(self) -> None:
        self._call("step", self.state)

    def transmit(self) -> tuple[int, bytes] | None:
        if not self._call("tx", self.state, self._id, self._data, self._length):
            return None
        return int(self._id[0]), bytes(self.ffi.buffer(self._data, self._length[0]))

    def receive(self, frame_id: int, data: bytes) -> bool:
        buffer = self.ffi.new("uint8_t[]", bytes(data) or b"\0")
        return bool(self._call("rx", self.state, frame_id, buffer, len(data)))

    @property
    def health(self) -> list[int]:
        return [int(node.health) for node in self.state.nodes]

    @property
    def mode(self) -> int:
        return int(self.state.mode)

    @property
    def heartbeats(self) -> int:
        return int(self.state.heartbeats)


__all__ = ["ALONE", "SAFE", "SILENT", "STALE", "CompiledSupervisor", "NodeView", "Supervisor", "compiled_supervisor"]
