"""The CAN protocol of a controller, generated from its design artefact as a cantools database.

The DBC is the one source of truth of the bus: every frame, signal, scaling, range, sender and
cycle time. Frames (11-bit identifiers, all CAN FD with bit-rate switch — at 1 ms a classical
bus cannot carry them: 8-byte classical frames take 135 µs each; every frame
starts with the E2E bytes of ``bench/e2e.py``: byte 0 CRC-8 J1850 (also over an implicit
freshness byte), bits 8–11 alive counter, bits 12–15 the heartbeat echo of the frames the
controller reads):

Frames: ``JOINT_<j>`` (0x100 + j, the joint's v, u_R, F_N), ``TIP_SENSORS`` (0x180, the design's
sensors y), ``SETPOINT_<j>`` (0x200 + j, the piezo voltage), ``AMP_STATUS_<j>`` (0x280 + j) and
the heartbeat ``CONTROLLER_STATUS`` (0x080), all every Δt; the table is in docs/can.md.

The heartbeat goes every cycle: the amplifiers watch it (and their setpoints) and go to the
safe normal force on their own when either stops, fails its E2E check or says "safe"
(docs/safety.md).

Scalings are chosen so that quantisation stays far below what the controllers resolve (the
SISO boundary layer ε ~ 1e-6 m/s: velocity step 1e-9 m/s; the voltage setpoint steps by 1e-7 V, 1e-6 N:
the clipped-LQG study is chaotic enough that a 1e-3 N command quantisation moves E(t_e) by ~2 %).
"""

from __future__ import annotations

import re
from collections import OrderedDict
from dataclasses import dataclass

import cantools
from cantools.database import can, conversion
from cantools.database.can.formats.dbc.dbc_attribute import DbcAttribute
from cantools.database.can.formats.dbc.dbc_attribute_definition import DbcAttributeDefinition
from cantools.database.can.formats.dbc.dbc_specifics import DbcSpecifics
from cantools.database.can.formats.dbc.dbc_writer import ATTRIBUTE_DEFINITION_GENMSGCYCLETIME

from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control.artifact import ControllerArtifact
from smartjoint.design.structure.sections import MAX_DISPLACEMENT

JOINT_BASE, TIP_ID, SETPOINT_BASE, STATUS_BASE, CONTROLLER_ID = 0x100, 0x180, 0x200, 0x280, 0x080
MAX_JOINTS = 0x80  # identifier blocks of 128
MAX_SENSORS = 15  # 2 + 4·15 = 62 bytes ≤ 64 (CAN FD)
FD_LENGTHS = (8, 12, 16, 20, 24, 32, 48, 64)
# A TIP_SENSORS signal's unit and the |y| it carries, by the sensor's quantity; both int32·1e-8
# (±21.47). A displacement up to MAX_DISPLACEMENT, the bound of [safety] displacement_limit; a
# tip velocity ω·amplitude stays below 10 m/s (centimetres at some ten hertz), five times the
# default velocity_limit, so a limit beyond what the frame carries is refused at codegen.
TIP_SIGNALS = {"displacement": ("m", MAX_DISPLACEMENT), "velocity": ("m/s", 10.0)}

CONTROLLER = "CONTROLLER"
MODES = law_registry.by_mode()  # CONTROLLER_STATUS.mode: INIT, each law of the registry, SAFE
AMPLIFIER_FAULTS = ("over_temperature", "no_response", "stuck_output", "over_current")
MODE_SAFE = law_registry.MODE_SAFE
_MODE_TEXT = {law_registry.MODE_INIT: "init", MODE_SAFE: "safe state"}  # the modes that are no law
# Fault bits of CONTROLLER_STATUS.faults, in bit order (the C layer's <PREFIX>_CAN_FAULT_*).
CONTROLLER_FAULTS = (
    "velocity", "friction", "normal_force", "sensor", "temperature", "current", "tracking", "amplifier",
    "amplifier_safe", "timeout", "e2e", "controller", "law", "bus_off", "actuation",
)  # fmt: skip
E2E_SIGNALS = ("crc", "counter", "sync")  # E2E bytes and the heartbeat echo; no sensor signal may take these names
CRC_COMMENT = (
    "CRC-8 SAE J1850 over id (2 bytes, low first), the freshness byte (bits 4-11 of the frame's "
    "controller cycle, not sent) and bytes 1..n-1"
)
SYNC_COMMENT = (
    "the alive counter of the last controller heartbeat this node saw: the controller tells from it "
    "how many of its cycles the frame is old (docs/safety.md)"
)
_CYCLE_TIME_MAX = ATTRIBUTE_DEFINITION_GENMSGCYCLETIME.maximum
assert isinstance(_CYCLE_TIME_MAX, int)  # cantools gives GenMsgCycleTime its range
CYCLE_TIME_MAX_MS: int = _CYCLE_TIME_MAX  # the DBC attribute is an INT of this range


@dataclass(frozen=True)
class Amplifier:
    """Piezo amplifier range and calibration of the stacks: F_N = force_per_volt·V + preload."""

    voltage_max: float = 150.0  # V
    force_per_volt: float = 8.0  # N/V
    preload: float = 0.0  # N


def _e2e(frame_id: int, sync: int | None = None) -> list[can.Signal]:
    """The E2E signals of a frame, and for the frames the controller reads the heartbeat echo
    (4 bits at ``sync``)."""
    crc, counter, echo = E2E_SIGNALS
    signals = [
        can.Signal(crc, 0, 8, comment=CRC_COMMENT),
        can.Signal(counter, 8, 4, minimum=0, maximum=15, comment="alive counter, +1 per frame, mod 16"),
    ]
    if sync is not None:
        signals.append(can.Signal(echo, sync, 4, minimum=0, maximum=15, comment=SYNC_COMMENT))
    return signals


def _scaled(name, start, length, scale, signed, unit, minimum, maximum, comment) -> can.Signal:
    return can.Signal(
        name,
        start,
        length,
        is_signed=signed,
        conversion=conversion.BaseConversion.factory(scale, 0.0),
        minimum=minimum,
        maximum=maximum,
        unit=unit,
        comment=comment,
    )


def _fd_length(payload_bytes: int) -> int:
    return next(n for n in FD_LENGTHS if n >= payload_bytes) if payload_bytes > 8 else 8


def _identifier(name: str, kind: str) -> str:
    if not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", name):
        raise ModelError(
            f"{kind}_names: {name!r} is not a valid DBC/C identifier ([A-Za-z_][A-Za-z0-9_]*) — it names "
            f"a frame of the CAN protocol; rename the {kind} in the design file"
        )
    return name.upper()


def _check_names(joints: list[str], sensors: list[str]) -> None:
    """Frame names upper-case the joint names, signal names lower-case the sensor names: both
    must stay distinct, and no sensor signal may repeat the E2E signals of its frame."""
    for field, names, spell, what in (
        ("joint_names", joints, str.upper, "frame JOINT_"),
        ("sensor_names", sensors, str.lower, "TIP_SENSORS signal "),
    ):
        taken = {spell(n): f"the E2E signal {n!r}" for n in E2E_SIGNALS} if field == "sensor_names" else {}
        for i, name in enumerate(names):
            _identifier(name, field[:-6])
            key = spell(name)
            if key in taken:
                raise ModelError(
                    f"{field}[{i}]: {name!r} — the {what}{key} would repeat {taken[key]}; "
                    f"rename the {field[:-6]} in the design file"
                )
            taken[key] = f"{field}[{i}] {name!r}"


def _check_ranges(db: can.Database) -> None:
    """Every signal's [minimum, maximum] lies within what its raw field can carry."""
    for message in db.messages:
        for signal in message.signals:
            if signal.minimum is None or signal.maximum is None:
                continue
            raw_min = -(2 ** (signal.length - 1)) if signal.is_signed else 0
            raw_max = 2 ** (signal.length - 1) - 1 if signal.is_signed else 2**signal.length - 1
            low, high = sorted((_physical(signal, raw_min), _physical(signal, raw_max)))
            if signal.minimum < low or signal.maximum > high:
                unit = f" {signal.unit}" if signal.unit else ""
                raise ModelError(
                    f"{message.name}.{signal.name}: range [{signal.minimum:g}, {signal.maximum:g}]{unit} "
                    f"— its {signal.length}-bit field carries [{float(low):g}, {float(high):g}]"
                )


def _physical(signal: can.Signal, raw: int) -> float:
    """A raw value in the signal's physical units: a number, as choices are not decoded."""
    value = signal.conversion.raw_to_scaled(raw, decode_choices=False)
    assert isinstance(value, (int, float))
    return value


def _cycle_ms(sample_time: float) -> int:
    """The frames' cycle time: the sample time in whole milliseconds, as DBC carries it."""
    cycle = sample_time * 1000.0
    if abs(cycle - round(cycle)) > 1e-9 or round(cycle) < 1:
        raise ModelError(
            f"sample_time: {sample_time!r} s — DBC cycle times are whole milliseconds; use a "
            "sample time of 1 ms, 2 ms, …"
        )
    cycle = int(round(cycle))
    if cycle > CYCLE_TIME_MAX_MS:
        raise ModelError(
            f"sample_time: {sample_time!r} s — DBC cycle times (GenMsgCycleTime) are at most {CYCLE_TIME_MAX_MS} ms"
        )
    return cycle


def _joint_message(j: int, name: str, tag: str, cycle: int) -> can.Message:
    """The JOINT frame of joint ``j``: sliding velocity, friction and applied normal force."""
    frame_id = JOINT_BASE + j
    signals = _e2e(frame_id, sync=12) + [
        _scaled("sliding_velocity", 16, 32, 1e-9, True, "m/s", -2.0, 2.0, f"v of joint {name}"),
        _scaled("friction_force", 48, 32, 1e-5, True, "N", -20000.0, 20000.0, f"u_R of joint {name}"),
        _scaled("normal_force", 80, 16, 0.02, False, "N", 0.0, 1310.0, f"applied F_N of joint {name}"),
    ]
    return can.Message(
        frame_id,
        f"JOINT_{tag}",
        12,
        signals,
        senders=[f"JOINT_NODE_{tag}"],
        cycle_time=cycle,
        is_fd=True,
        comment=f"joint {name}: v, u_R, F_N",
    )


def _setpoint_message(j: int, name: str, tag: str, amplifier: Amplifier, cycle: int) -> can.Message:
    """The SETPOINT frame the controller sends amplifier ``j``: the piezo voltage."""
    volts = _scaled(
        "voltage",
        16,
        32,
        1e-7,
        False,
        "V",
        0.0,
        amplifier.voltage_max,
        f"piezo voltage setpoint of joint {name}: F_N = {amplifier.force_per_volt:g}*V + {amplifier.preload:g} N",
    )
    return can.Message(
        SETPOINT_BASE + j,
        f"SETPOINT_{tag}",
        6,
        _e2e(SETPOINT_BASE + j) + [volts],
        senders=[CONTROLLER],
        cycle_time=cycle,
        is_fd=True,
        comment=f"setpoint of amplifier {name}",
    )


def _amplifier_status_message(j: int, name: str, tag: str, amplifier: Amplifier, cycle: int) -> can.Message:
    """The AMP_STATUS frame amplifier ``j`` sends: monitor voltage, current, temperature, faults."""
    status = (
        _e2e(STATUS_BASE + j, sync=12)
        + [
            _scaled("monitor_voltage", 16, 16, 0.005, False, "V", 0.0, amplifier.voltage_max, "measured output"),
            _scaled("current", 32, 16, 1e-4, True, "A", -3.0, 3.0, "output current"),
            can.Signal(
                "temperature",
                48,
                8,
                conversion=conversion.BaseConversion.factory(1.0, -40.0),
                minimum=-40.0,
                maximum=215.0,
                unit="degC",
                comment="amplifier temperature",
            ),
        ]
        + [
            can.Signal(fault, 57 + k, 1, comment=f"fault bit: {fault.replace('_', ' ')}")
            for k, fault in enumerate(AMPLIFIER_FAULTS)
        ]
        + [
            can.Signal(
                "safe_state",
                56,
                1,
                comment="the amplifier's watchdog tripped and holds the safe force "
                "(no fresh valid setpoint or heartbeat, or an implausible setpoint; not the power-up hold "
                "before the first command, nor following the heartbeat's mode)",
            )
        ]
    )
    return can.Message(
        STATUS_BASE + j,
        f"AMP_STATUS_{tag}",
        8,
        status,
        senders=[f"AMPLIFIER_{tag}"],
        cycle_time=cycle,
        is_fd=True,
        comment=f"amplifier {name} status",
    )


def _joint_frames(j: int, name: str, amplifier: Amplifier, cycle: int) -> tuple[list, list]:
    """The nodes (sensor node, amplifier) and frames (JOINT, SETPOINT, AMP_STATUS) of joint ``j``."""
    tag = _identifier(name, "joint")
    nodes = [
        can.Node(f"JOINT_NODE_{tag}", comment=f"sensors of joint {name}"),
        can.Node(f"AMPLIFIER_{tag}", comment=f"piezo amplifier of joint {name}"),
    ]
    messages = [
        _joint_message(j, name, tag, cycle),
        _setpoint_message(j, name, tag, amplifier, cycle),
        _amplifier_status_message(j, name, tag, amplifier, cycle),
    ]
    return nodes, messages


def _tip_message(sensors: list[str], quantities: list[str], cycle: int) -> can.Message:
    """The TIP_SENSORS frame: one signal per sensor of the design's y, in its quantity's unit
    and range (``TIP_SIGNALS``)."""
    tip = _e2e(TIP_ID, sync=12)
    for k, (s, quantity) in enumerate(zip(sensors, quantities)):
        unit, carried = TIP_SIGNALS[quantity]
        name = _identifier(s, "sensor").lower()
        tip.append(_scaled(name, 16 + 32 * k, 32, 1e-8, True, unit, -carried, carried, f"sensor {s}"))
    return can.Message(
        TIP_ID,
        "TIP_SENSORS",
        _fd_length(2 + 4 * len(sensors)),
        tip,
        senders=["TIP_NODE"],
        cycle_time=cycle,
        is_fd=True,
        comment="tip sensors y",
    )


def _controller_status_message(cycle: int, joints: tuple[str, ...] = ()) -> can.Message:
    """The CONTROLLER_STATUS heartbeat: mode, step status, missing inputs and fault bits, and per
    joint of ``joints`` whether it does not follow its commands (``failed_<joint>``, from bit 56:
    the actuation check, docs/safety.md; the local mode's supervisor sends none)."""
    mode = can.Signal(
        "mode",
        16,
        4,
        minimum=0,
        maximum=max(MODES),
        comment=", ".join(
            f"{mode} {_MODE_TEXT.get(mode) or law_registry.law(name.lower()).display}" for mode, name in MODES.items()
        ),
        conversion=conversion.BaseConversion.factory(1, 0, OrderedDict(MODES)),
    )
    controller = _e2e(CONTROLLER_ID) + [
        mode,
        can.Signal("step_status", 24, 8, comment="status bits of the last step"),
        can.Signal("missing_inputs", 20, 4, comment="inputs in timeout or invalid"),
        can.Signal(
            "cycle_high",
            48,
            8,
            minimum=0,
            maximum=255,
            comment="bits 4-11 of the controller's cycle count (the alive counter carries bits 0-3): a node "
            "learns from it the freshness byte its frames' CRC covers (docs/can.md, E2E)",
        ),
        can.Signal(
            "faults",
            32,
            16,
            comment="why the safe state holds, and actuation (a joint does not follow; the law runs on): bits "
            + ", ".join(f"{k} {name}" for k, name in enumerate(CONTROLLER_FAULTS)),
        ),
    ]
    controller += [
        can.Signal(
            f"failed_{_identifier(name, 'joint').lower()}",
            56 + j,
            1,
            comment=f"joint {name}: its measured F_N falls short of its commands (actuation check); 1 while it does",
        )
        for j, name in enumerate(joints)
    ]
    return can.Message(
        CONTROLLER_ID,
        "CONTROLLER_STATUS",
        _fd_length(7 + -(-len(joints) // 8)),
        controller,
        senders=[CONTROLLER],
        cycle_time=cycle,
        is_fd=True,
        comment="controller heartbeat: the amplifiers go to the safe force without it",
    )


def _set_receivers(messages: list[can.Message], tags: list[str]) -> None:
    """Every signal's receivers, so the DBC names who reads each frame: the controller reads the
    sensor and amplifier frames, amplifier j its setpoint, and every other node the heartbeat
    (the amplifiers watch it, the sensor nodes echo its counter)."""
    amplifiers = [f"AMPLIFIER_{tag}" for tag in tags]
    sensor_nodes = [f"JOINT_NODE_{tag}" for tag in tags] + ["TIP_NODE"]
    for m in messages:
        if m.name == "CONTROLLER_STATUS":
            readers = amplifiers + sensor_nodes
        elif m.name.startswith("SETPOINT_"):
            readers = [f"AMPLIFIER_{m.name[len('SETPOINT_') :]}"]
        else:
            readers = [CONTROLLER]
        for signal in m.signals:
            signal.receivers = list(readers)


def _fd_specifics() -> DbcSpecifics:
    """The DBC specifics that mark the bus as CAN FD."""
    # BusType "CAN FD" makes cantools write VFrameFormat per frame, so is_fd survives the DBC.
    bus_type = DbcAttributeDefinition("BusType", default_value="CAN", kind=None, type_name="STRING")
    return DbcSpecifics(
        attributes=OrderedDict(BusType=DbcAttribute("CAN FD", bus_type)),
        attribute_definitions=OrderedDict(BusType=bus_type),
    )


def amplifier_of(artifact: ControllerArtifact) -> Amplifier:
    """The piezo amplifier of an artefact: its ``piezo_force_per_volt`` and ``piezo_preload``."""
    return Amplifier(force_per_volt=float(artifact.piezo_force_per_volt), preload=float(artifact.piezo_preload))


def database(artifact: ControllerArtifact, amplifier: Amplifier | None = None) -> can.Database:
    """The cantools database of an artefact's controller bus (frames of the module docstring).

    Parameters
    ----------
    artifact : ControllerArtifact
        The controller design artefact: joints, sensors, sample time (the cycle time of every
        frame) and the ranges the signals carry.
    amplifier : Amplifier, optional
        The piezo amplifier the setpoint frames command (force per volt, preload, voltage range);
        default the artefact's own (:func:`amplifier_of`).

    Returns
    -------
    cantools.database.can.Database
        Every frame with its identifier, length, sender, cycle time and signals.

    Raises
    ------
    ModelError
        Too many joints or sensors for the identifier blocks or a CAN FD frame, names the DBC
        cannot carry, or a range beyond what a signal's field holds.
    """
    joints, sensors = list(artifact.joint_names), list(artifact.sensor_names)
    amplifier = amplifier_of(artifact) if amplifier is None else amplifier
    if not 1 <= len(joints) <= MAX_JOINTS:
        raise ModelError(f"joint_names: {len(joints)} joints — the protocol carries 1…{MAX_JOINTS}")
    if not 1 <= len(sensors) <= MAX_SENSORS:
        raise ModelError(f"sensor_names: {len(sensors)} sensors — one TIP_SENSORS frame carries 1…{MAX_SENSORS}")
    _check_names(joints, sensors)
    cycle = _cycle_ms(artifact.sample_time)
    nodes = [
        can.Node(CONTROLLER, comment="semi-active controller (generated firmware)"),
        can.Node("TIP_NODE", comment="tip deflection sensors"),
    ]
    messages = []
    for j, name in enumerate(joints):
        joint_nodes, joint_messages = _joint_frames(j, name, amplifier, cycle)
        nodes += joint_nodes
        messages += joint_messages
    messages.append(_tip_message(sensors, list(artifact.sensor_quantities), cycle))
    messages.append(_controller_status_message(cycle, tuple(joints)))
    messages.sort(key=lambda m: m.frame_id)
    _set_receivers(messages, [name.upper() for name in joints])
    db = can.Database(
        messages, nodes, version=f"smartjoint artefact {artifact.artifact_sha256[:16]}", dbc_specifics=_fd_specifics()
    )
    db.refresh()
    _check_ranges(db)
    return db


# The builders the local mode's supervision bus shares (design.network.joint_node).
cycle_ms = _cycle_ms
controller_status_message = _controller_status_message
e2e_signals = _e2e
scaled = _scaled
identifier = _identifier
fd_specifics = _fd_specifics
fd_length = _fd_length


def dbc_text(db: can.Database) -> str:
    """The DBC text of a database (what ``smartjoint codegen`` writes as ``bus.dbc``).

    Parameters
    ----------
    db : cantools.database.can.Database
        The database (:func:`database`).

    Returns
    -------
    str
        The DBC file's text.
    """
    return db.as_dbc_string()


def load_dbc(text: str) -> can.Database:
    """Read DBC text back into a cantools database.

    Parameters
    ----------
    text : str
        The DBC file's text.

    Returns
    -------
    cantools.database.can.Database
        The frames and signals it describes.

    Raises
    ------
    ModelError
        The text does not parse as DBC (one line, with cantools' reason).
    """
    try:
        db = cantools.database.load_string(text, database_format="dbc")
    except Exception as error:  # cantools raises several parser errors
        raise ModelError(f"DBC: cannot parse ({type(error).__name__}: {error})") from None
    assert isinstance(db, can.Database)  # the DBC format always loads a CAN database
    return db
