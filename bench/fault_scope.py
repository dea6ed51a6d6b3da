"""Which joints a fault must make safe, and which must run on, on the buses of a network plan.

On one bus, or under a law that couples the joints (one that reads the tip sensors estimates the
whole truss from every joint), any fault stops every joint: the safe-state policy of
docs/safety.md. On several buses a law that reads each joint's own measurements is supervised
bus by bus (the CAN layer's ``supervise_buses``), so a fault must stop exactly the joints of the
buses it touches, and the joints of the other buses must run on — never a safe state there,
never an amplifier's own watchdog:

- ``bus_off`` stops the bus it names (every bus without a target);
- an amplifier fault stops its joint's bus, except one past the amplifier (``SILENT_FAULTS``: the
  joint gets less force than driven while the amplifier reports healthy), which stops nothing
  whatever the law: the actuation check names the joint and the law runs on;
- a frame fault stops the buses that carry the frame (the heartbeat is on every bus); on a frame
  the law does not read (the tip sensors under a per-joint law) timing and E2E faults stop
  nothing, while an implausible value is a broken node whichever law runs and stops its bus.

Whatever the law, a fault on a frame the controller's CAN layer does not read at all (a joint
node's status in local mode, for the supervisor) stops nothing: the firmware must not react.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smartjoint.bench.actuation import silent_fault
from smartjoint.common import law_registry

SENSOR_FRAME = "TIP_SENSORS"  # the frame only a law that reads the sensors needs


@dataclass(frozen=True)
class FaultScope:
    """The buses (indices of the plan) a fault stops, their joints, and the buses that run on."""

    buses: tuple[int, ...]
    joints: tuple[bool, ...]  # per joint of the artefact: on a stopped bus
    running: tuple[int, ...]  # the other buses: no safe state there, no amplifier's watchdog

    @property
    def tolerated(self) -> bool:
        """Nothing must stop: the fault touches only what the law does not read."""
        return not self.buses


def _stopped(fault, law, plan, joint_bus: dict, frame_buses: dict) -> set[int]:
    """The buses ``fault`` stops under a per-joint ``law`` on ``plan`` (module docstring)."""
    if fault.kind == "bus_off":
        names = [p.bus.name for p in plan.buses]
        return set(range(len(names))) if not fault.target else {names.index(fault.target)}
    if fault.kind == "amplifier":
        return {joint_bus[fault.target]}
    if fault.target == SENSOR_FRAME and "sensors" not in law.inputs and fault.kind != "implausible":
        return set()
    return set(frame_buses[fault.target])


def fault_scope(faults, law: str, plan, joint_names, unread=frozenset()) -> FaultScope | None:
    """What ``faults`` acting together must stop under ``law`` on the buses of ``plan``.

    Parameters
    ----------
    faults : tuple of Fault
        The faults of one case.
    law : str
        A law of the registry by name.
    plan : design.network.plan.NetworkPlan
        The buses, their joints and frames.
    joint_names : sequence of str
        The artefact's joints, in order.
    unread : set of str
        Frames other nodes send that the controller's CAN layer does not read
        (``codegen.can_layer.input_frames``): a fault on them alone stops nothing.

    Returns
    -------
    FaultScope or None
        None where every joint must stop (one bus, or a law that couples the joints).
    """
    entry = law_registry.law(law)
    silent = [f for f in faults if silent_fault(f)]
    faults = [f for f in faults if f.kind in ("bus_off", "amplifier") or f.target not in unread]
    faults = [f for f in faults if f not in silent]  # past the amplifier: the law runs on (actuation check)
    if silent and not faults:
        return FaultScope((), tuple(False for _ in joint_names), tuple(range(len(plan.buses))))
    if faults and (len(plan.buses) < 2 or "sensors" in entry.inputs):
        return None
    joint_bus = {j: b for b, p in enumerate(plan.buses) for j in p.joints}
    frame_buses: dict[str, list[int]] = {}
    for b, p in enumerate(plan.buses):
        for m in p.database.messages:
            frame_buses.setdefault(m.name, []).append(b)
    stopped = set().union(*(_stopped(f, entry, plan, joint_bus, frame_buses) for f in faults))
    return FaultScope(
        tuple(sorted(stopped)),
        tuple(joint_bus[j] in stopped for j in joint_names),
        tuple(b for b in range(len(plan.buses)) if b not in stopped),
    )


def _runs_on(flags) -> bool:
    """Each column of safe-state flags (cycles × buses or joints) clears after power-up and never
    rises again: what runs on through a fault elsewhere."""
    flags = np.asarray(flags, dtype=bool)
    cleared = ~flags
    return bool(all(c.any() and not flags[int(np.argmax(c)) :, k].any() for k, c in enumerate(cleared.T)))


def scoped_flags(r, scope, joints: int):
    """The flags of a SIL record ``r`` as a case judges them (``bench.safety.measure``): the
    firmware's safe state (the stopped buses' on several), the joints that must stop, every
    amplifier's own safe state, and whether what lies out of ``scope`` ran on (True without one)."""
    stopped = np.ones(joints, dtype=bool) if scope is None else np.array(scope.joints, dtype=bool)
    amplifier_safe = np.array(r.amplifier_safe, dtype=bool).reshape(len(r.safe), -1)
    bus_safe = np.array(r.bus_safe, dtype=bool).reshape(len(r.safe), -1)
    safe = np.array(r.safe, dtype=bool)
    if scope is not None and scope.buses:
        safe = np.asarray(bus_safe[:, list(scope.buses)].all(axis=1))
    others = list(() if scope is None else scope.running)
    return safe, stopped, amplifier_safe, _runs_on(bus_safe[:, others]) and _runs_on(amplifier_safe[:, ~stopped])
