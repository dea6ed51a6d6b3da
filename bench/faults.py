"""Faults the SIL bench injects: what a fault is (:class:`Fault`), the kinds, their checks and
the command-line spelling (``kind:target:start:end[:detail]``, :func:`parse_fault`).

Frame faults act on one frame name on its way over the bus (the firmware's own frames included),
``implausible`` puts a value beyond the design's range into a signal with a valid E2E
protection, ``replay`` sends instead of each frame the one its sender sent ``age`` cycles
before, exactly as it was (a gateway that buffers, a babbling node, a replay), ``amplifier``
makes one joint's amplifier report (or suffer) a fault, ``bus_off`` takes a bus off: the one its
target names (``bus_off:can1:…``, a bus of the network plan), or every bus without a target. The
injector is ``bench/fault_injection.py``, the loop ``bench/loop.py``; the report's demonstration
sequence, built from the design's own frames and joints, is :func:`demo_faults`."""

from __future__ import annotations

import math
from dataclasses import dataclass

from smartjoint.bench.amplifier import FAULTS as AMPLIFIER_FAULTS
from smartjoint.common.errors import ModelError

FRAME_FAULTS = ("drop", "delay", "duplicate", "corrupt_crc", "corrupt_counter", "wrong_dlc", "silent")
BUS_FAULTS = ("bus_off",)
KINDS = FRAME_FAULTS + ("replay", "implausible", "amplifier") + BUS_FAULTS
MAX_REPLAY_AGE = 4095  # cycles: the freshness byte makes every age from 16 on fail the CRC (docs/can.md)
NEVER = math.inf  # the end of a fault that never ends
DEFAULT_DELAY = 0.005  # s


@dataclass(frozen=True)
class Fault:
    """One injected fault on [start, end) s (``end`` = inf: it never ends).

    ``target``: a frame name for frame faults and ``implausible`` (any frame the bus carries,
    the firmware's own ``SETPOINT_<j>`` and ``CONTROLLER_STATUS`` included — those are faulted on
    their way to the amplifiers), a joint name for ``amplifier`` (with ``amplifier_fault``), a
    bus name or nothing (every bus) for ``bus_off``. ``delay`` [s] only for ``delay``; ``signal`` and ``value`` only for
    ``implausible`` (the sender puts that value into the signal, with a valid E2E protection);
    ``age`` [cycles] only for ``replay``."""

    kind: str
    start: float
    end: float = NEVER
    target: str = ""
    amplifier_fault: str = ""
    delay: float | None = None
    signal: str = ""
    value: float | None = None
    age: int = 0  # replay: how many cycles old the replayed frames are

    def active(self, t: float) -> bool:
        """Whether the fault acts at time ``t`` [s]."""
        return self.start - 1e-12 <= t < self.end - 1e-12

    @property
    def lateness(self) -> float:
        """How late a ``delay`` fault makes its frames [s] (0 for every other kind)."""
        return (DEFAULT_DELAY if self.delay is None else self.delay) if self.kind == "delay" else 0.0

    def label(self) -> str:
        """A short human-readable name, e.g. ``drop JOINT_A1`` or ``delay JOINT_A1 5 ms``."""
        detail = {
            "delay": f" {1e3 * self.lateness:g} ms",
            "amplifier": f" {self.amplifier_fault}",
            "implausible": f".{self.signal} = {self.value:g}" if self.value is not None else "",
            "replay": f" {self.age} cycles old",
        }.get(self.kind, "")
        return f"{self.kind} {self.target or 'bus'}{detail}"


def check_faults(faults, frame_names, joint_names, signals=None, bus_names=None) -> None:
    """Refuse a fault that does not mean something on this bus.

    Every field of every fault must mean something: a known kind, an existing target, a detail
    only where the kind has one, a window 0 <= start < end (end may be inf).

    Parameters
    ----------
    faults : iterable of Fault
        The faults.
    frame_names : set of str
        The frames on the bus.
    joint_names : list of str
        The artefact's joints (targets of ``amplifier`` faults).
    signals : dict of str to list of str, optional
        Per frame its signals an ``implausible`` fault may set.
    bus_names : list of str, optional
        The buses of the network plan (targets of ``bus_off``); None: one bus, no target.

    Raises
    ------
    ModelError
        The first fault field that does not fit, with what would.
    """
    signals = signals or {}
    for f in faults:
        what = f"fault {f.kind}"
        if f.kind not in KINDS:
            raise ModelError(f"fault kind {f.kind!r} — allowed: {', '.join(KINDS)}")
        if f.kind in FRAME_FAULTS + ("replay", "implausible"):
            if f.target not in frame_names:
                raise ModelError(f"{what}: target {f.target!r} — a frame on the bus: {', '.join(sorted(frame_names))}")
        elif f.kind == "amplifier":
            if f.target not in joint_names or f.amplifier_fault not in AMPLIFIER_FAULTS:
                raise ModelError(
                    f"{what}: target {f.target!r} / {f.amplifier_fault!r} — a joint "
                    f"({', '.join(joint_names)}) and one of {', '.join(AMPLIFIER_FAULTS)}"
                )
        elif f.target and f.target not in (bus_names or ()):
            allowed = f"a bus of the plan ({', '.join(bus_names)}), or give no target: every bus" if bus_names else ""
            raise ModelError(
                f"{what}: target {f.target!r} — {allowed or 'bus_off takes the whole bus off: give no target'}"
            )
        if f.amplifier_fault and f.kind != "amplifier":
            raise ModelError(f"{what}: amplifier_fault {f.amplifier_fault!r} — only for kind amplifier")
        if f.delay is not None and f.kind != "delay":
            raise ModelError(f"{what}: delay {f.delay!r} — only for kind delay")
        if f.kind == "delay" and not (f.delay is None or (math.isfinite(f.delay) and f.delay > 0)):
            raise ModelError(f"{what}: delay {f.delay!r} — a time > 0 s")
        if (f.kind == "replay") != (f.age != 0) or not (isinstance(f.age, int) and 0 <= f.age <= MAX_REPLAY_AGE):
            raise ModelError(f"{what}: age {f.age!r} — replay only, a whole number of cycles 1 … {MAX_REPLAY_AGE}")
        if f.kind == "implausible":
            names = signals.get(f.target)
            if names is not None and f.signal not in names:
                raise ModelError(f"{what}: signal {f.signal!r} of {f.target} — one of {', '.join(names)}")
            if f.value is None or not math.isfinite(f.value):
                raise ModelError(f"{what}: value {f.value!r} — the finite value the sender puts into {f.signal}")
        elif f.signal or f.value is not None:
            raise ModelError(f"{what}: signal/value {f.signal!r}/{f.value!r} — only for kind implausible")
        if not (math.isfinite(f.start) and 0 <= f.start < f.end and not math.isnan(f.end)):
            raise ModelError(f"{what}: window [{f.start!r}, {f.end!r}) — need 0 <= start < end (end may be inf)")


def parse_fault(text: str) -> Fault:
    """Read the command-line spelling of a fault.

    Parameters
    ----------
    text : str
        ``kind:target:start:end[:detail]``; ``end``: seconds or ``inf`` (never ends); detail: the
        delay [s] (``delay``, default 5 ms), the age in cycles (``replay``, 1 … 4095), the
        amplifier fault (``amplifier``), the value (``implausible``, target ``FRAME.signal``);
        ``bus_off`` has no detail, and as target a bus of the network plan or none (every bus).

    Returns
    -------
    Fault
        The fault (checked against a bus by :func:`check_faults`).

    Raises
    ------
    ModelError
        Not of that form, with examples.

    Examples
    --------
    >>> parse_fault("drop:JOINT_A1:1.0:1.2").label()
    'drop JOINT_A1'
    """
    parts = text.split(":")
    example = (
        "e.g. drop:JOINT_A1:1.0:1.2, delay:JOINT_A1:1.0:1.2:0.002, replay:JOINT_A1:1.0:1.2:16, "
        "amplifier:A1:1.0:inf:over_temperature, "
        "implausible:JOINT_A1.sliding_velocity:1.0:1.2:2.1, bus_off::1.0:1.05, bus_off:can1:1.0:1.05"
    )
    if len(parts) not in (4, 5):
        raise ModelError(f"--fault {text!r}: expected kind:target:start:end[:detail], {example}")
    kind, target, detail = parts[0], parts[1], parts[4] if len(parts) == 5 else None
    try:
        start, end = float(parts[2]), float(parts[3])
    except ValueError:
        raise ModelError(f"--fault {text!r}: start and end must be numbers [s] (end may be inf)") from None
    if kind not in KINDS:
        raise ModelError(f"--fault {text!r}: kind {kind!r} — allowed: {', '.join(KINDS)}")
    fields: dict = {}
    if kind == "delay" and detail is not None:
        try:
            fields["delay"] = float(detail)
        except ValueError:
            raise ModelError(f"--fault {text!r}: the delay {detail!r} must be a number [s]") from None
    elif kind == "replay":
        if detail is None or not detail.isdigit() or not 1 <= int(detail) <= MAX_REPLAY_AGE:
            raise ModelError(
                f"--fault {text!r}: the age {detail!r} — a whole number of cycles 1 … {MAX_REPLAY_AGE}, "
                "e.g. replay:JOINT_A1:1.0:1.2:16"
            )
        fields["age"] = int(detail)
    elif kind == "amplifier":
        fields["amplifier_fault"] = detail or ""
    elif kind == "implausible":
        target, _, fields["signal"] = target.partition(".")
        try:
            fields["value"] = float(detail) if detail is not None else None
        except ValueError:
            raise ModelError(f"--fault {text!r}: the value {detail!r} must be a number") from None
    elif detail is not None:
        raise ModelError(f"--fault {text!r}: kind {kind} takes no detail (got {detail!r})")
    return Fault(kind, start, end, target, **fields)


def demo_faults(artifact, duration: float) -> tuple:
    """Four faults in sequence for the report, on the design's own frames and joints.

    A dropped joint frame, a damaged sensor frame, an over-heated amplifier, the bus off — at
    1/8, 1/4, 3/8 and 1/2 of the study.

    Parameters
    ----------
    artifact : ControllerArtifact
        The artefact (its joint names).
    duration : float
        The study's length [s].

    Returns
    -------
    tuple of Fault
        The four faults.
    """
    joints = list(artifact.joint_names)
    at = lambda fraction, length: (fraction * duration, fraction * duration + length)  # noqa: E731
    return (
        Fault("drop", *at(0.125, 0.1), f"JOINT_{joints[0].upper()}"),
        Fault("corrupt_crc", *at(0.25, 0.05), "TIP_SENSORS"),
        Fault("amplifier", *at(0.375, 0.1), joints[len(joints) // 2], amplifier_fault="over_temperature"),
        Fault("bus_off", *at(0.5, 0.05)),
    )
