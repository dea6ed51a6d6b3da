"""The network plan: a controller's frames assigned to the CAN FD buses of a design's
``[network]`` (``design.structure.description.Network``), each proven to
carry its worst-case load within its limit and its sample's frames within one sample (issue 33).

The controller sits on every bus; each joint's node and amplifier on one. A bus carries:

* the heartbeat ``CONTROLLER_STATUS`` (every bus: every node there watches it);
* per joint of the bus ``JOINT_<j>`` and ``AMP_STATUS_<j>`` (one sender each, so never packed);
* the setpoints of its joints: one ``SETPOINT_<j>`` each, or — where that lowers the load —
  ``SETPOINTS_<J>`` frames of up to 15 joints' voltages (the controller sends them all, so one
  64-byte frame can carry many; id 0x200 + its first joint's index, the signals ``voltage_<j>``
  as in ``SETPOINT_<j>``);
* ``TIP_SENSORS`` on the first bus;
* in local mode (``[network] siso = "local"``) also each joint's ``NODE_STATUS_<j>`` every
  ``supervision_cycles`` samples (``joint_node``): the frames of the central laws stay, since the
  cLQG still runs centrally.

Joints go to the buses in their order, each bus taking as many as keep its load within its limit
(worst-case bit stuffing, ``busload``) and within a common ceiling: the lowest ceiling under which
every joint is placed (bisection to 0.1 %), so the buses share the load instead of the first ones
filling to their limits and the last one idling. A plan that cannot place every joint is refused
with one line naming the bus and the load it would reach. Latency: every frame of the controller's sample
has that sample as its cycle, so the worst case for the last of them is the whole sample's
frames back to back, ``busy`` = Σ frame times; the plan states it and refuses a bus whose
``busy`` exceeds the sample (a load above 100 % of the sample's frames).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from cantools.database import can

from smartjoint.common.errors import ModelError
from smartjoint.design.network import busload, joint_node, protocol
from smartjoint.design.structure.description import Bus, Network

PACK_MAX = 15  # voltages of a SETPOINTS frame: 2 E2E bytes + 4·15 = 62 ≤ 64


@dataclass
class BusPlan:
    """One bus of a plan: its joints, its frames (a cantools database, one DBC), its load and the
    worst-case busy time of one sample's frames."""

    bus: Bus
    joints: list[str]
    database: can.Database
    load: busload.BusLoad
    busy: float  # [s]
    packed: bool  # setpoints in SETPOINTS frames

    @property
    def dbc(self) -> str:
        return protocol.dbc_text(self.database)


@dataclass
class NetworkPlan:
    """The buses of a plan (``plan``), in the order of the spec."""

    buses: list[BusPlan] = field(default_factory=list)
    sample_time: float = 0.0

    def table(self) -> str:
        """The plan as a Markdown table: bus, rates, joints, frames, load against limit, busy time."""
        lines = [
            "| bus | bit rates | joints | frames | setpoints | worst-case load (limit) | busy per sample |",
            "|---|---|---|---:|---|---:|---:|",
        ]
        for p in self.buses:
            rates = f"{p.bus.bitrate / 1e6:g}/{p.bus.data_bitrate / 1e6:g} Mbit/s"
            lines.append(
                f"| {p.bus.name} | {rates} | {', '.join(p.joints) or '—'} | {len(p.database.messages)} | "
                f"{'packed' if p.packed else 'one frame each'} | {p.load.load:.1%} ({p.bus.limit:.0%}) | "
                f"{p.busy * 1e6:.0f} µs of {self.sample_time * 1e6:.0f} |"
            )
        return "\n".join(lines)


def _setpoints_message(joints: Sequence[tuple[int, str]], template: can.Message, cycle: int) -> can.Message:
    """One SETPOINTS frame carrying the voltages of ``joints`` ((index, name) each), each signal
    scaled as the SETPOINT frame's ``voltage`` (``template``)."""
    first = joints[0][0]
    frame_id = protocol.SETPOINT_BASE + first
    voltage = template.get_signal_by_name("voltage")
    conversion = (voltage.comment or "").partition(": ")[2]  # "F_N = <force per volt>*V + <preload> N": every joint's
    comments = [f"piezo voltage setpoint of joint {name}: {conversion}" for _, name in joints]
    signals = protocol.e2e_signals(frame_id)
    for k, (_, name) in enumerate(joints):
        signals.append(
            protocol.scaled(
                f"voltage_{protocol.identifier(name, 'joint').lower()}",
                16 + 32 * k,
                32,
                voltage.scale,
                False,
                voltage.unit,
                voltage.minimum,
                voltage.maximum,
                comments[k],
            )
        )
    tags = [protocol.identifier(name, "joint") for _, name in joints]
    return can.Message(
        frame_id,
        f"SETPOINTS_{tags[0]}" + (f"_{tags[-1]}" if len(tags) > 1 else ""),
        protocol.fd_length(2 + 4 * len(joints)),
        signals,
        senders=[protocol.CONTROLLER],
        cycle_time=cycle,
        is_fd=True,
        comment="setpoints of amplifiers " + ", ".join(name for _, name in joints),
    )


def _bus_database(
    full: can.Database, artifact, joints: list[int], first: bool, packed: bool, spec: Network
) -> can.Database:
    """The frames of one bus (module docstring) as a database, with its nodes and receivers."""
    names = list(artifact.joint_names)
    tags = {j: protocol.identifier(names[j], "joint") for j in joints}
    by_name = {m.name: m for m in full.messages}
    messages = [by_name["CONTROLLER_STATUS"]] + ([by_name["TIP_SENSORS"]] if first else [])
    for j in joints:
        messages += [by_name[f"JOINT_{tags[j]}"], by_name[f"AMP_STATUS_{tags[j]}"]]
    if packed:
        cycle = protocol.cycle_ms(artifact.sample_time)
        template = by_name[f"SETPOINT_{tags[joints[0]]}"]
        for start in range(0, len(joints), PACK_MAX):
            chunk = [(j, names[j]) for j in joints[start : start + PACK_MAX]]
            message = _setpoints_message(chunk, template, cycle)
            for signal in message.signals:
                signal.receivers = [f"AMPLIFIER_{tags[j]}" for j, _ in chunk]
            messages.append(message)
    else:
        messages += [by_name[f"SETPOINT_{tags[j]}"] for j in joints]
    if spec.siso == "local":
        supervision = joint_node.supervision_database(artifact, spec.supervision_cycles)
        messages += [supervision.get_message_by_name(f"NODE_STATUS_{tags[j]}") for j in joints]
    used = {protocol.CONTROLLER, *(s for m in messages for s in m.senders)}
    used |= {r for m in messages for s in m.signals for r in s.receivers}
    nodes = [n for n in full.nodes if n.name in used]
    db = can.Database(
        sorted(messages, key=lambda m: m.frame_id),
        nodes,
        version=full.version,
        dbc_specifics=protocol.fd_specifics(),
    )
    db.refresh()
    return db


def _bus_plan(full, artifact, bus: Bus, joints: list[int], first: bool, spec) -> BusPlan:
    """The cheaper of one frame per setpoint and packed setpoints for these joints on this bus."""
    options = []
    for packed in (False, True) if len(joints) > 1 else (False,):
        db = _bus_database(full, artifact, joints, first, packed, spec)
        load = busload.bus_load(db, bus.bitrate, bus.data_bitrate)
        options.append((load.load, packed, db, load))
    _, packed, db, load = min(options, key=lambda option: option[0])
    per_sample = sum(f.frame_time for f in load.frames if abs(f.cycle_time - artifact.sample_time) < 1e-12) + sum(
        f.frame_time for f in load.frames if f.cycle_time > artifact.sample_time + 1e-12
    )
    names = list(artifact.joint_names)
    return BusPlan(bus, [names[j] for j in joints], db, load, per_sample, packed)


def at_rates(artifact, bitrate: int, data_bitrate: int | None) -> BusPlan:
    """The bus of the default plan (:func:`plan` without a ``[network]``) at these bit rates
    (``data_bitrate`` None: classical CAN), its setpoints packed where that lowers the load, with
    no limit of its own: the caller checks the load against its limit (``busload.check``)."""
    bus = Bus("can0", bitrate, data_bitrate, 1.0)  # type: ignore[arg-type]  # None: classical CAN
    return plan(artifact, Network((bus,))).buses[0]


def _packed(database: can.Database) -> bool:
    """Whether a database's setpoints travel in ``SETPOINTS_<J>`` frames."""
    return any(m.name.startswith("SETPOINTS_") for m in database.messages)


def one_bus(artifact, database: can.Database) -> NetworkPlan:
    """Every frame of ``database`` on one bus at CAN FD 1/5 Mbit/s, as it is (a DBC read back, for
    example): the plan of frames already laid out."""
    bus = Network().buses[0]
    load = busload.bus_load(database, bus.bitrate, bus.data_bitrate)
    busy = sum(f.frame_time for f in load.frames)
    return NetworkPlan(
        [BusPlan(bus, list(artifact.joint_names), database, load, busy, _packed(database))], float(artifact.sample_time)
    )


def plan(artifact, spec: Network | None = None, amplifier: protocol.Amplifier | None = None) -> NetworkPlan:
    """Assign an artefact's frames to the buses of ``spec`` (module docstring).

    Parameters
    ----------
    artifact : ControllerArtifact
        Its joints, sensors and sample time (the frames of ``protocol.database``).
    spec : Network, optional
        The buses (in order of filling), where the SISO law runs, the supervision period; default
        one bus at CAN FD 1/5 Mbit/s, limit 70 %, the SISO law central: the plan of a controller
        built without a ``[network]``, its setpoints packed where that lowers the load.
    amplifier : protocol.Amplifier, optional
        The amplifier the setpoints command; default the artefact's (``protocol.amplifier_of``).

    Returns
    -------
    NetworkPlan
        Per bus its joints, database, load and busy time.

    Raises
    ------
    ModelError
        One line: the bus that would exceed its limit (or the sample) and the load it would reach,
        when the joints do not fit the buses.
    """
    spec = Network() if spec is None else spec
    full = protocol.database(artifact, amplifier)
    memo: dict[tuple[int, int, int], BusPlan] = {}  # (bus, first joint, end) → its plan
    result = _fill(full, artifact, spec, 1.0, memo)
    if result is None:
        _fill(full, artifact, spec, 1.0, memo, refuse=True)  # raises the one-line refusal
        raise AssertionError("the refusing fill places every joint only when the fill did")
    # The lowest common ceiling that still places every joint: placing is monotone in it.
    low, high = 0.0, max(p.load.load for p in result.buses)
    while high - low > 1e-3:
        middle = 0.5 * (low + high)
        trial = _fill(full, artifact, spec, middle, memo)
        if trial is None:
            low = middle
        else:
            result, high = trial, middle
    return result


def _fill(full, artifact, spec: Network, ceiling: float, memo: dict, refuse: bool = False) -> NetworkPlan | None:
    """Joints to buses in order, each bus within min(its limit, ``ceiling``); None when some joint
    is left over (``refuse``: raise the one-line refusal instead)."""
    count = len(artifact.joint_names)
    result = NetworkPlan(sample_time=float(artifact.sample_time))

    def bus_plan(index: int, start: int, end: int) -> BusPlan:
        if (index, start, end) not in memo:
            bus = spec.buses[index]
            memo[index, start, end] = _bus_plan(full, artifact, bus, list(range(start, end)), index == 0, spec)
        return memo[index, start, end]

    start = 0
    for index, bus in enumerate(spec.buses):
        taken = bus_plan(index, start, start)
        if not _fits(taken, artifact):
            raise _refusal(bus, taken, "its heartbeat and tip frames alone", spec)
        stop = start
        while stop < count:
            trial = bus_plan(index, start, stop + 1)
            if not _fits(trial, artifact, ceiling):
                if refuse and stop == start and index == len(spec.buses) - 1:
                    raise _refusal(bus, trial, f"joint {artifact.joint_names[stop]}", spec)
                break
            taken, stop = trial, stop + 1
        result.buses.append(taken)
        start = stop
    if start < count:
        if not refuse:
            return None
        last = spec.buses[-1]
        trial = _bus_plan(full, artifact, last, [*range(_first_index(result, artifact), count)], False, spec)
        rest = list(artifact.joint_names[start:])
        what = f"joint {rest[0]}" if len(rest) == 1 else f"joints {rest[0]} … {rest[-1]}"
        raise _refusal(last, trial, f"{what} as well", spec)
    return result


def check_design(design) -> NetworkPlan | None:
    """The plan of a design before any work (``smartjoint run`` stage 1): its controlled joints
    (``[control] joints``, else every joint, else ``[placement] count`` placeholders), its sensors
    and sample time are all the frames need; None for a design with neither joints nor placement.

    Raises
    ------
    ModelError
        The one-line refusal of :func:`plan`.
    """
    from types import SimpleNamespace

    names = list(design.control.joints) if design.control.joints is not None else [j.name for j in design.joints]
    if not names and design.placement is not None:
        names = [f"P{k + 1}" for k in range(design.placement.count)]
    if not names or not design.sensors:
        return None
    frames = SimpleNamespace(
        joint_names=names,
        sensor_names=[s.name for s in design.sensors],
        sensor_quantities=[s.quantity for s in design.sensors],
        sample_time=design.control.sample_time,
        artifact_sha256="0" * 64,
        piezo_force_per_volt=design.control.piezo_force_per_volt,
        piezo_preload=design.control.piezo_preload,
    )
    return plan(frames, design.network)


def _fits(p: BusPlan, artifact, ceiling: float = 1.0) -> bool:
    return p.load.load <= min(p.bus.limit, ceiling) and p.busy <= artifact.sample_time


def _first_index(result: NetworkPlan, artifact) -> int:
    """The index of the first joint of the last bus of ``result``."""
    last = result.buses[-1]
    return list(artifact.joint_names).index(last.joints[0]) if last.joints else len(artifact.joint_names)


def _refusal(bus: Bus, trial: BusPlan, what: str, spec: Network) -> ModelError:
    local = f" or run the {joint_node.NODE_LAW.display} law locally" if spec.siso == "central" else ""
    remedy = "add a bus or raise its data bit rate" + local
    return ModelError(
        f"network: bus {bus.name} would carry {trial.load.load:.1%} with {what} (limit {bus.limit:.0%}, "
        f"{bus.bitrate / 1e6:g}/{bus.data_bitrate / 1e6:g} Mbit/s) — {remedy}"
    )


__all__ = ["BusPlan", "NetworkPlan", "PACK_MAX", "at_rates", "check_design", "one_bus", "plan"]
