"""The safe-state policy verified on the SIL bench: every fault kind on every frame, from power-up,
mid-run, never ending and two at once, with the normal force each joint really gets.

Per case the bench (compiled firmware ↔ python-can bus ↔ amplifier nodes) runs a few dozen
controller cycles and reports, counted from the fault's start — or, for a delay, from its
detection bound (the latency of ``timeout_cycles − 1`` cycles a frame may have):

- ``firmware``: cycles until the firmware is in its safe state and stays there while the fault
  lasts;
- ``joints``: cycles until every joint's amplifier applies the safe normal force and keeps it
  while the fault lasts (a joint whose output stage itself failed — ``stuck_output``,
  ``gain_error`` — cannot, whatever it is told: it is listed, the others must be safe);
- ``holds``: the joints do settle at the safe force before the fault ends;
- ``recovery``: cycles after the fault's end (a delay's: after its last late frame arrived)
  until the firmware controls again and no amplifier holds its own safe state.

The plant is replaced by replayed signals (:func:`signals`: an oscillation of the design's
size, or a recorded run), except that each joint's measured F_N is what its amplifier applied
— the safety logic sees values of the design's ranges, and a case takes milliseconds
(tests/test_can_layer.py repeats representative faults with the plant in the loop). The matrix's
table, paragraph and figure for the report: ``safety_report``. Policy and figures: docs/safety.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from smartjoint.bench import firmware as firmware_module
from smartjoint.bench.actuation import actuation_figures, silent_fault
from smartjoint.bench.amplifier import FAULTS as AMPLIFIER_FAULTS
from smartjoint.bench.amplifier import OUTPUT_STAGE_FAULTS
from smartjoint.bench.fault_scope import fault_scope, scoped_flags
from smartjoint.bench.faults import FRAME_FAULTS, Fault
from smartjoint.bench.loop import SilLoop
from smartjoint.codegen import can_layer
from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.network import plan
from smartjoint.design.plant.interface import Measurements

DETECTION_LIMIT = 3  # cycles from a fault (or its detection bound) to the safe force at every joint
FORCE_TOLERANCE = 1e-6  # N: "at the safe force" (the setpoint quantum is 8e-7 N)
START, END, LENGTH = 20, 40, 70  # cycles: fault window and run length of a mid-run case
TIMINGS = ("mid-run", "from t = 0", "never ending")
REPLAY_AGES = range(1, 65)  # cycles: every frame replayed at each age (the 16·m the 4-bit counter misses among them)
REPLAY_WINDOW = (max(REPLAY_AGES) + 6, max(REPLAY_AGES) + 26, max(REPLAY_AGES) + 56)  # start, end, run length


@dataclass(frozen=True)
class Case:
    """One fault scenario: the faults (one, or two at once) and the run length in cycles."""

    name: str
    timing: str
    faults: tuple
    cycles: int
    tolerated: bool = False  # a delay within the latency bound: no safe state expected


def setpoint_signal(db, tag: str) -> tuple[str, str]:
    """The (frame, signal) carrying joint ``tag``'s setpoint: ``SETPOINT_<tag>.voltage``, or its
    ``voltage_<tag>`` in a ``SETPOINTS`` frame of several joints (design.network.plan)."""
    names = {m.name for m in db.messages}
    if f"SETPOINT_{tag}" in names:
        return f"SETPOINT_{tag}", "voltage"
    signal = f"voltage_{tag.lower()}"
    frame = next(m.name for m in db.messages if m.name.startswith("SETPOINTS_") and signal in m.signal_tree)
    return frame, signal


def implausible_values(artifact, db) -> dict:
    """Per (frame, signal): a value the sender could carry that lies beyond the design's range.

    Parameters
    ----------
    artifact : ControllerArtifact
        The controller design artefact (its plausibility ranges).
    db : cantools.database.can.Database
        The bus (each value is clamped to what its signal's raw field carries).

    Returns
    -------
    dict of (str, str) to float
        The implausible value per (frame, signal).
    """
    values = {}
    for j, joint in enumerate(artifact.joint_names):
        tag = joint.upper()
        values[(f"JOINT_{tag}", "sliding_velocity")] = 1.5 * float(artifact.sliding_velocity_limit[j])
        values[(f"JOINT_{tag}", "friction_force")] = -1.5 * float(artifact.friction_force_limit[j])
        values[(f"JOINT_{tag}", "normal_force")] = 1.2 * float(artifact.measured_normal_force_max[j])
        values[(f"AMP_STATUS_{tag}", "temperature")] = artifact.amplifier_temperature_limit + 20.0
        values[(f"AMP_STATUS_{tag}", "current")] = -1.1 * artifact.amplifier_current_limit
        safe_volts = (float(artifact.safe_normal_force[j]) - artifact.piezo_preload) / artifact.piezo_force_per_volt
        values[(f"AMP_STATUS_{tag}", "monitor_voltage")] = safe_volts + 10.0 * artifact.tracking_tolerance
        high_volts = (float(artifact.normal_force_max[j]) - artifact.piezo_preload) / artifact.piezo_force_per_volt
        values[setpoint_signal(db, tag)] = high_volts + 10.0
    for r, sensor in enumerate(artifact.sensor_names):
        values[("TIP_SENSORS", sensor.lower())] = -1.5 * float(artifact.sensor_limit[r])
    values[("CONTROLLER_STATUS", "mode")] = 9.0  # the amplifiers read it: only 1, 2 (the laws) and 3 (safe) exist
    for (frame, signal), value in values.items():  # within what the frame's raw field carries
        s = db.get_message_by_name(frame).get_signal_by_name(signal)
        low = -(2 ** (s.length - 1)) if s.is_signed else 0
        high = 2 ** (s.length - 1) - 1 if s.is_signed else 2**s.length - 1
        values[(frame, signal)] = min(max(value, low * s.scale + s.offset), high * s.scale + s.offset)
    return values


def _pairs(artifact, db, joints: list[str], dt: float, late: float) -> list[tuple[Fault, Fault]]:
    """Faults two at once: an input and an output frame, the bus with an amplifier, a late and an
    implausible input, an output stage with the heartbeat, and bus-off with a silent amplifier
    from power-up on."""
    tag, other = joints[0].upper(), joints[-1].upper()
    return [
        (
            Fault("drop", START * dt, END * dt, f"JOINT_{tag}"),
            Fault("corrupt_crc", START * dt, END * dt, setpoint_signal(db, other)[0]),
        ),
        (
            Fault("bus_off", START * dt, END * dt),
            Fault("amplifier", START * dt, END * dt, joints[0], amplifier_fault="over_temperature"),
        ),
        (
            Fault("delay", START * dt, END * dt, "TIP_SENSORS", delay=late),
            Fault(
                "implausible",
                START * dt,
                END * dt,
                f"AMP_STATUS_{other}",
                signal="temperature",
                value=artifact.amplifier_temperature_limit + 20.0,
            ),
        ),
        (
            Fault("amplifier", START * dt, END * dt, joints[0], amplifier_fault="stuck_output"),
            Fault("drop", START * dt, END * dt, "CONTROLLER_STATUS"),
        ),
        (Fault("bus_off", 0.0, math.inf), Fault("amplifier", 0.0, math.inf, joints[-1], amplifier_fault="no_response")),
    ]


def cases(artifact, db, timings=TIMINGS, buses=(), replay_ages=REPLAY_AGES) -> list[Case]:
    """Every fault kind on every frame, each signal, amplifier and the bus, in each timing.

    Also a delay within the latency bound on each frame (tolerated), each frame replayed seamlessly
    at every age of ``replay_ages`` (mid-run, once its sender has sent that many) and pairs of
    faults at once.

    Parameters
    ----------
    artifact : ControllerArtifact
        The controller design artefact.
    db : cantools.database.can.Database
        The bus (every frame of the plan once).
    timings : iterable of str
        Some of :data:`TIMINGS`.
    buses : sequence of str
        The plan's buses when there are several: each also goes off alone.
    replay_ages : iterable of int
        The ages [cycles] each frame is replayed at.

    Returns
    -------
    list of Case
        The cases, single faults first.
    """
    dt = float(artifact.sample_time)
    frames = [m.name for m in sorted(db.messages, key=lambda m: m.frame_id)]
    joints = list(artifact.joint_names)
    timeout_cycles = artifact.timeout_cycles
    late = timeout_cycles * dt  # one cycle beyond the latency bound
    single = []
    for frame in frames:
        for kind in FRAME_FAULTS:
            single.append((kind, dict(target=frame, delay=late if kind == "delay" else None)))
    for (frame, signal), value in implausible_values(artifact, db).items():
        single.append(("implausible", dict(target=frame, signal=signal, value=value)))
    for joint in joints:
        for amplifier_fault in AMPLIFIER_FAULTS:
            single.append(("amplifier", dict(target=joint, amplifier_fault=amplifier_fault)))
    single.append(("bus_off", {}))
    single += [("bus_off", dict(target=bus)) for bus in (buses if len(buses) > 1 else ())]
    windows = {
        "mid-run": (START, END, LENGTH),
        "from t = 0": (0, END - START, LENGTH - START),
        "never ending": (START, None, END + 10),
    }
    out = []
    for timing in timings:
        first, last, length = windows[timing]
        for kind, fields in single:
            fault = Fault(kind, first * dt, math.inf if last is None else last * dt, **fields)
            out.append(Case(fault.label(), timing, (fault,), length))
    bound = (timeout_cycles - 1) * dt
    for frame in frames:  # late, but within the bound: used, never a timeout
        fault = Fault("delay", START * dt, END * dt, frame, delay=bound)
        out.append(Case(fault.label(), "within the latency bound", (fault,), LENGTH, tolerated=True))
    first, last, length = REPLAY_WINDOW
    for frame in frames:
        for age in replay_ages:
            fault = Fault("replay", first * dt, last * dt, frame, age=age)
            out.append(Case(fault.label(), "replayed mid-run", (fault,), length))
    for pair in _pairs(artifact, db, joints, dt, late):
        length = LENGTH if math.isfinite(pair[0].end) else END + 10
        timing = "two at once" if math.isfinite(pair[0].end) else "two at once, from t = 0, never ending"
        out.append(Case(" + ".join(f.label() for f in pair), timing, pair, length))
    return out


SIGNAL_FRACTION = 0.3  # the replayed signals swing through 30 % of each plausibility range


def signals(recorded, artifact, cycles: int):
    """What the nodes measure at the first ``cycles`` samples.

    Parameters
    ----------
    recorded : iterable of Measurements or None
        Recorded measurements (e.g. of a model-in-the-loop run); when None, a decaying
        oscillation at the design's median retained modal frequency through
        :data:`SIGNAL_FRACTION` of each signal's plausible range (the artefact's), so the safety
        logic sees values of the design's size, never a fault.
    artifact : ControllerArtifact
        The controller design artefact.
    cycles : int
        Samples needed.

    Returns
    -------
    list of Measurements
        ``cycles`` samples.

    Raises
    ------
    ModelError
        The recorded run is shorter than ``cycles``.
    """
    dt = float(artifact.sample_time)
    if recorded is not None:
        seen = list(recorded)[:cycles]
        if len(seen) < cycles:
            raise ModelError(f"fault cases: the recorded run has {len(seen)} samples — {cycles} needed")
        return seen
    frequency = float(np.median(artifact.modal_frequencies))
    sensors = SIGNAL_FRACTION * np.asarray(artifact.sensor_limit, dtype=float)
    velocity = SIGNAL_FRACTION * np.asarray(artifact.sliding_velocity_limit, dtype=float)
    friction = SIGNAL_FRACTION * np.asarray(artifact.friction_force_limit, dtype=float)
    out = []
    for k in range(cycles):
        t = k * dt
        wave = math.exp(-t * frequency / 10.0) * math.sin(2 * math.pi * frequency * t)
        out.append(Measurements(t, sensors * wave, velocity * wave, friction * wave, np.zeros(len(velocity))))
    return out


def run_case_loop(firmware, case: Case, measurements) -> SilLoop:
    """One case through the CAN loop without the plant: its faults injected, each joint's measured
    F_N what its amplifier applied over the last sample; the buses closed whatever happens.

    Parameters
    ----------
    firmware : bench.firmware.Firmware
        The compiled firmware image.
    case : Case
        The fault scenario (its faults and cycles).
    measurements : list of Measurements
        What the nodes measure (:func:`signals`), at least ``case.cycles`` of them.

    Returns
    -------
    SilLoop
        The closed loop, with the run's record.
    """
    loop = SilLoop(firmware, 0.0, faults=case.faults)
    loop.reset()
    applied = np.zeros(len(firmware.artifact.joint_names))
    try:
        for m in measurements[: case.cycles]:
            applied = loop.step(Measurements(m.time, m.sensors, m.sliding_velocity, m.friction_force, applied))
    finally:
        loop.close()
    return loop


def run_case(firmware, case: Case, measurements, scope=None) -> dict:
    """One case on the bench (:func:`run_case_loop`) and its figures.

    Parameters
    ----------
    firmware : bench.firmware.Firmware
        The compiled firmware image.
    case : Case
        The fault scenario.
    measurements : list of Measurements
        What the nodes measure (:func:`signals`); each joint's F_N is what its amplifier applied.
    scope : bench.fault_scope.FaultScope, optional
        What the case must stop and what must run on (:func:`measure`); None: every joint.

    Returns
    -------
    dict
        The case's name and timing with the figures of the module docstring (:func:`measure`).
    """
    loop = run_case_loop(firmware, case, measurements)
    return {
        "case": case.name,
        "timing": case.timing,
        "scope": None if scope is None else [j for j, s in zip(firmware.artifact.joint_names, scope.joints) if s],
        **measure(loop.record, case.faults, firmware.artifact, case.tolerated, scope),
    }


def _gain_error_shows(record, artifact, force, start: int, stop: int) -> int:
    """The cycle a gain error shows: no bit tells, so once the output is off its setpoint by more
    than the tracking tolerance (a small command halved is within it, and harmless)."""

    def volts(value):
        return (value - artifact.piezo_preload) / artifact.piezo_force_per_volt

    off = np.any(np.abs(volts(force) - volts(np.array(record.command))) > artifact.tracking_tolerance, axis=1)
    seen = np.flatnonzero(off[start:stop])
    return start + int(seen[0]) if seen.size else stop


def _first(flags, start: int) -> int | None:
    """Cycles from ``start`` to the first raised flag (None: never)."""
    hits = np.flatnonzero(flags[start:])
    return int(hits[0]) if hits.size else None


def _settled(flags, reference: int, stop: int) -> int | None:
    """Cycles from the reference until the flag holds for the rest of the fault (None: never)."""
    off = np.flatnonzero(~flags[reference:stop])
    return 0 if not off.size else (int(off[-1]) + 1 if off[-1] + 1 < stop - reference else None)


def measure(record, faults, artifact, tolerated: bool = False, scope=None) -> dict:
    """The figures of the module docstring for faults acting together in a SIL record.

    Parameters
    ----------
    record : loop.SilRecord
        The run's record.
    faults : tuple of Fault
        The faults injected.
    artifact : ControllerArtifact
        The controller design artefact (safe force, tolerances).
    tolerated : bool
        A delay within the latency bound: no safe state is expected.
    scope : bench.fault_scope.FaultScope, optional
        What must stop and what must run on (``running``) on several buses; None: every joint.

    Returns
    -------
    dict
        ``firmware``, ``joints``, ``holds``, ``recovery`` (cycles or None), ``observable`` and
        ``ok`` (the joints at the safe force within :data:`DETECTION_LIMIT` cycles, safe at power
        up, recovered after the fault's end, and the buses out of scope running).
    """
    r = record
    dt = float(artifact.sample_time)
    tolerated = tolerated or (scope is not None and scope.tolerated) or all(silent_fault(f) for f in faults)
    safe, stopped, amplifier_safe, running = scoped_flags(r, scope, len(artifact.joint_names))
    force = np.array(r.amplifier_force)
    own_safe = np.asarray(amplifier_safe[:, stopped].any(axis=1))
    target = np.asarray(artifact.safe_normal_force, dtype=float)
    failed_stage = sorted(
        {f.target for f in faults if f.kind == "amplifier" and f.amplifier_fault in OUTPUT_STAGE_FAULTS}
    )
    free = np.array([j not in failed_stage for j in artifact.joint_names]) & stopped
    at_safe = np.all(np.abs(force - target)[:, free] <= FORCE_TOLERANCE, axis=1)
    start = min(int(round(f.start / dt)) for f in faults)
    ends = [f.end for f in faults]
    # An end beyond the run (inf, or 1e308 s) never ends within it.
    end = None if any(not e / dt < len(safe) for e in ends) else int(round(max(ends) / dt))
    bound = max((int(math.ceil(f.lateness / dt - 1e-9)) - 1 if f.kind == "delay" else 0) for f in faults)
    reference = start + max(bound, 0)
    stop = len(safe) if end is None else min(end, len(safe))
    if any(f.kind == "amplifier" and f.amplifier_fault == "gain_error" for f in faults):
        reference = _gain_error_shows(r, artifact, force, start, stop)
    row: dict[str, Any] = {"running": running, "start": start, "end": end, "tolerated": tolerated}
    row.update(failed_output_stage=failed_stage, safe_samples=int(safe.sum()), observable=True)
    if start >= len(safe):
        row.update(firmware=None, joints=None, holds=None, recovery=None, observable=False, ok=True)
        return row
    actuation = actuation_figures(r, faults, artifact, DETECTION_LIMIT)
    if actuation is not None:
        row["actuation"] = actuation
    if tolerated:
        quiet = not safe[start:].any() and not own_safe[start:].any()
        checked = actuation is None or actuation["ok"]
        row.update(firmware=None, joints=None, holds=None, recovery=None, ok=quiet and row["running"] and checked)
        return row
    if reference >= stop:  # a fault that never showed (a gain error on commands within the tolerance)
        row.update(firmware=None, joints=None, holds=None, recovery=None, observable=False, ok=True)
        return row
    # A replay younger than the latency bound is seen at its seam (a repeated counter); after it
    # the stream is what a sender one cycle late sends, and is used as such (docs/safety.md).
    if all(f.kind == "replay" and f.age < artifact.timeout_cycles for f in faults):
        row["firmware"], row["joints"] = _first(safe, reference), _first(at_safe, reference)
    else:
        row["firmware"], row["joints"] = _settled(safe, reference, stop), _settled(at_safe, reference, stop)
    row["holds"] = row["joints"] is not None
    # Recovery counts from the fault's end; for a delay, from its last late frame.
    over = None if end is None else end + max((int(math.ceil(f.lateness / dt - 1e-9)) for f in faults), default=0)
    row["recovery"] = _first(~safe & ~own_safe, over) if over is not None and over < len(safe) else None
    running = _first(~safe, 0)  # until the first valid command the joints hold the safe force
    row["power_up_safe"] = bool(np.all(at_safe[: len(safe) if running is None else running]))
    row["ok"] = bool(
        row["running"]
        and row["joints"] is not None
        and row["joints"] <= DETECTION_LIMIT
        and row["power_up_safe"]
        and (end is None or end >= len(safe) or row["recovery"] is not None)
    )
    return row


def fault_matrix(
    artifact,
    law: str | None = None,
    real: str = "float",
    measurements=None,
    timings=TIMINGS,
    progress=None,
    image=None,
    network=None,
) -> dict:
    """Every case of :func:`cases` on one compiled firmware: rows and the worst figures.

    Parameters
    ----------
    artifact : ControllerArtifact
        The controller design artefact.
    law : str, optional
        A law of the registry by name; default the fault-matrix law (``law_registry.fault_matrix_law``).
    real : str
        The firmware's scalar type.
    measurements : iterable of Measurements, optional
        Recorded measurements to replay (default :func:`signals`' oscillation).
    timings : iterable of str
        Some of :data:`TIMINGS`.
    progress : callable, optional
        ``progress(message)`` hears every 50 cases.
    image : firmware, optional
        The firmware to run the cases on (default: the host build of ``law`` and ``real``; the
        target's, ``bench.pil.TargetFirmware``, for processor in the loop).
    network : Network, optional
        The design's buses (``[network]``): the host build on their plan, each bus also off alone,
        and under a per-joint law each case judged bus by bus (``bench.fault_scope``). Default
        ``image``'s plan, or one bus.

    Returns
    -------
    dict
        The rows, the number of cases, the failing ones and the worst cycles to the safe state
        (firmware, joints) and to recovery.

    Examples
    --------
    >>> out = fault_matrix(artifact.load("firmware/generated/controller.json"))  # doctest: +SKIP
    >>> out["failed"]  # doctest: +SKIP
    []
    """
    law = law_registry.fault_matrix_law().name if law is None else law
    planned = None if network is None else plan.plan(artifact, network)
    image = firmware_module.Firmware(artifact, law, real, network=planned) if image is None else image
    buses = [p.bus.name for p in image.network.buses]
    todo = cases(artifact, image.db, timings=timings, buses=buses)
    seen = signals(measurements, artifact, max(c.cycles for c in todo))
    rows = []
    unread = {m.name for m in image.db.messages if m.senders != ["CONTROLLER"]} - can_layer.input_frames(artifact)
    for i, case in enumerate(todo):
        scope = fault_scope(case.faults, law, image.network, artifact.joint_names, unread)
        rows.append(run_case(image, case, seen, scope))
        if progress and (i + 1) % 50 == 0:
            progress(f"        {i + 1}/{len(todo)} fault cases")
    checked = [r for r in rows if not r["tolerated"]]
    return {
        "law": law,
        "real": real,
        "buses": buses,
        "unread": sorted(unread),
        "rows": rows,
        "cases": len(rows),
        "failed": [r["case"] + " (" + r["timing"] + ")" for r in rows if not r["ok"]],
        "worst_firmware": max((r["firmware"] for r in checked if r["firmware"] is not None), default=None),
        "worst_joints": max((r["joints"] for r in checked if r["joints"] is not None), default=None),
        "worst_recovery": max((r["recovery"] for r in checked if r["recovery"] is not None), default=None),
    }
