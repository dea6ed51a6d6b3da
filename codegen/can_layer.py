"""Render the CAN message layer of the controller (``templates/can.*.j2``) from the artefact and
the DBC of ``design/network/protocol.py``: pack/unpack of every frame (bit-exact with cantools),
E2E check and protection (``firmware/runtime/sj_e2e.c``, copied next to it), per-input ageing
by the senders' counters, plausibility of every decoded signal, the safe state with recovery
(the artefact's safe normal force; docs/safety.md), the controller step between receive and
transmit, the heartbeat the amplifiers watch."""

from __future__ import annotations

import numpy as np

from smartjoint.codegen import identifiers, rendering
from smartjoint.common import package_data
from smartjoint.common.errors import ModelError
from smartjoint.design.control.artifact import ControllerArtifact
from smartjoint.design.network import protocol

RUNTIME = package_data.folder("smartjoint.firmware", "runtime")


def _signal(signal) -> dict:
    lit = lambda value: rendering.literal(float(value), "double")  # noqa: E731
    length, signed = signal.length, signal.is_signed
    if length > 32:  # raw limits must stay exact doubles and the int64 cast defined
        raise ModelError(f"signal {signal.name}: {length} bits — the generated codec handles up to 32")
    raw_min = -(2 ** (length - 1)) if signed else 0
    raw_max = 2 ** (length - 1) - 1 if signed else 2**length - 1
    return {
        "name": signal.name,
        "start": signal.start,
        "length": length,
        "signed": signed,
        "scale": lit(signal.conversion.scale),
        "offset": lit(signal.conversion.offset),
        # A range clamps only when both ends are given; else only the raw field limits apply.
        "minimum": None if signal.minimum is None or signal.maximum is None else lit(signal.minimum),
        "maximum": None if signal.minimum is None or signal.maximum is None else lit(signal.maximum),
        "raw_min": lit(raw_min),
        "raw_max": lit(raw_max),
        "unit": signal.unit or "",
        "comment": (signal.comment or signal.name).replace("*/", "* /"),
    }


def check_can(artifact: ControllerArtifact, amplifier: protocol.Amplifier) -> None:
    """Refuse what the CAN layer's C types and frames cannot hold, before anything is rendered.

    The timing and the safe state come validated with the artefact; this checks the names
    against the frames' generated members, the normal-force range against the amplifier's
    reach and every limit against what its frame carries.

    Parameters
    ----------
    artifact : ControllerArtifact
        The controller design artefact.
    amplifier : protocol.Amplifier
        The piezo amplifier the setpoint frames command.

    Raises
    ------
    ModelError
        The first field that does not fit, named as in the artefact.
    """
    identifiers.check_names(artifact.joint_names, artifact.sensor_names, members=protocol.E2E_SIGNALS)
    db = protocol.database(artifact, amplifier)  # names, cycle times and signal ranges of the DBC
    low, high = np.asarray(artifact.normal_force_min), np.asarray(artifact.normal_force_max)
    k, preload = amplifier.force_per_volt, amplifier.preload
    reach = k * amplifier.voltage_max + preload
    for j, joint in enumerate(artifact.joint_names):
        tag = joint.upper()
        if preload > low[j]:
            raise ModelError(
                f"piezo_preload: {preload!r} N — above normal_force_min[{j}] = {float(low[j])!r} N "
                f"of joint {joint!r}: the setpoint voltage cannot go below 0 V, so F_N^min is out of reach"
            )
        if high[j] > reach:
            raise ModelError(
                f"normal_force_max[{j}]: {float(high[j])!r} N for joint {joint!r} — the setpoint frame "
                f"commands at most piezo_force_per_volt·voltage_max + piezo_preload = {k:g}·"
                f"{amplifier.voltage_max:g} + {preload:g} = {reach:g} N"
            )
        frame = db.get_message_by_name(f"JOINT_{tag}")
        measured = frame.get_signal_by_name("normal_force").maximum
        if high[j] > measured:
            raise ModelError(
                f"normal_force_max[{j}]: {float(high[j])!r} N for joint {joint!r} — the JOINT_{tag} "
                f"frame carries the applied F_N up to {measured:g} N (design/network/protocol.py)"
            )
        for field, signal, limit in (
            ("measured_normal_force_max", "normal_force", artifact.measured_normal_force_max[j]),
            ("sliding_velocity_limit", "sliding_velocity", artifact.sliding_velocity_limit[j]),
            ("friction_force_limit", "friction_force", artifact.friction_force_limit[j]),
        ):
            carried = frame.get_signal_by_name(signal).maximum
            if limit > carried:
                raise ModelError(
                    f"{field}[{j}]: {float(limit)!r} for joint {joint!r} — the JOINT_{tag} frame carries "
                    f"{signal} up to {carried:g} (design/network/protocol.py): a limit beyond it never trips"
                )
    tip = db.get_message_by_name("TIP_SENSORS")
    for r, sensor in enumerate(artifact.sensor_names):
        carried = tip.get_signal_by_name(sensor.lower()).maximum
        if artifact.sensor_limit[r] > carried:
            raise ModelError(
                f"sensor_limit[{r}]: {float(artifact.sensor_limit[r])!r} for sensor {sensor!r} — the "
                f"TIP_SENSORS frame carries up to {carried:g}: a limit beyond it never trips"
            )
    status = db.get_message_by_name(f"AMP_STATUS_{artifact.joint_names[0].upper()}")
    for field, signal in (("amplifier_temperature_limit", "temperature"), ("amplifier_current_limit", "current")):
        carried = status.get_signal_by_name(signal).maximum
        if getattr(artifact, field) >= carried:
            raise ModelError(
                f"{field}: {getattr(artifact, field)!r} — the AMP_STATUS frames carry {signal} up to "
                f"{carried:g}: the limit must lie below"
            )


def _same_bus(db, loaded) -> bool:
    """The DBC text read back by cantools describes the same frames and signals."""

    def frames(database):
        return [
            (
                m.name,
                m.frame_id,
                m.length,
                m.is_fd,
                m.cycle_time,
                tuple(m.senders or ()),
                tuple(
                    (
                        s.name,
                        s.start,
                        s.length,
                        s.is_signed,
                        s.conversion.scale,
                        s.conversion.offset,
                        s.minimum,
                        s.maximum,
                    )
                    for s in sorted(m.signals, key=lambda s: s.start)
                ),
            )
            for m in sorted(database.messages, key=lambda m: m.frame_id)
        ]

    return frames(db) == frames(loaded)


def _messages(db) -> tuple[list[dict], list[dict]]:
    """The template's frames (signals in bit order) and their layout tables: frames with
    identical signal rows share one layout table in the C."""
    messages = [
        {
            "name": m.name,
            "frame_id": m.frame_id,
            "length": m.length,
            "received": protocol.CONTROLLER not in (m.senders or []),
            "signals": [_signal(s) for s in sorted(m.signals, key=lambda s: s.start)],
        }
        for m in db.messages
    ]
    layouts: list[dict] = []
    keys: list = []
    for m in messages:
        fields = ("start", "length", "signed", "scale", "offset", "minimum", "maximum", "raw_min", "raw_max")
        key = tuple(tuple(sig[f] for f in fields) for sig in m["signals"])
        if key not in keys:
            keys.append(key)
            layouts.append({"signals": m["signals"]})
        m["layout"] = keys.index(key)
    return messages, layouts


def _inputs(db, joints: list[str], cycle_us: int) -> list[dict]:
    """The frames the controller receives, in the order the C ages them; each must come once per
    controller cycle, since ages count steps (design/network/protocol.py)."""
    by_name = {m.name: m for m in db.messages}
    inputs = [{"kind": "joint", "index": j, "message": f"JOINT_{tag}", "clqg_only": 0} for j, tag in enumerate(joints)]
    inputs.append({"kind": "tip", "index": 0, "message": "TIP_SENSORS", "clqg_only": 1})
    inputs += [
        {"kind": "amp", "index": j, "message": f"AMP_STATUS_{tag}", "clqg_only": 0} for j, tag in enumerate(joints)
    ]
    for i in inputs:
        if int(by_name[i["message"]].cycle_time) * 1000 != cycle_us:
            raise ModelError(
                f"{i['message']}: cycle time {by_name[i['message']].cycle_time} ms — the CAN layer ages "
                f"inputs in controller cycles and needs every input at Δt = {cycle_us / 1000:g} ms"
            )
    return inputs


def _limit_literals(artifact: ControllerArtifact, amplifier: protocol.Amplifier) -> dict[str, str]:
    """The safe state's force, the plausibility limits and the amplifier's scaling as C literals."""
    doubles = lambda values: ", ".join(rendering.literal(float(v), "double") for v in values)  # noqa: E731
    return {
        "safe_normal_force": doubles(artifact.safe_normal_force),
        "sliding_velocity_limit": doubles(artifact.sliding_velocity_limit),
        "friction_force_limit": doubles(artifact.friction_force_limit),
        "normal_force_low": doubles(artifact.measured_normal_force_min),
        "normal_force_high": doubles(artifact.measured_normal_force_max),
        "sensor_limit": doubles(artifact.sensor_limit),
        "temperature_limit": rendering.literal(artifact.amplifier_temperature_limit, "double"),
        "current_limit": rendering.literal(artifact.amplifier_current_limit, "double"),
        "tracking_tolerance": rendering.literal(artifact.tracking_tolerance, "double"),
        "voltage_max": rendering.literal(amplifier.voltage_max, "double"),
        "force_per_volt": rendering.literal(amplifier.force_per_volt, "double"),
        "preload": rendering.literal(amplifier.preload, "double"),
    }


def _runtime_sources() -> dict[str, str]:
    """The E2E runtime the generated layer links against, copied from ``firmware/runtime``."""
    files = {}
    for name in ("sj_e2e.h", "sj_e2e.c"):
        source = RUNTIME / name
        if not source.exists():
            raise ModelError(f"{source}: the firmware runtime is missing (it ships with the source tree)")
        files[name] = source.read_text()
    return files


def _checked_dbc(db) -> str:
    """The DBC text of the bus, checked to read back as the protocol it was written from."""
    text = protocol.dbc_text(db)
    if not _same_bus(db, protocol.load_dbc(text)):
        raise ModelError(
            "bus.dbc: the DBC text does not read back as the protocol it was written from "
            "(names or attributes the DBC format cannot carry)"
        )
    return text


def _example_context(context: dict, real: str, digest: str) -> dict:
    """The example ``main.c``'s context: the layer's, with its stimulus in the controllers' scalar."""
    lit = lambda value: rendering.literal(value, real)  # noqa: E731
    return {
        **context,
        "zero": lit(0.0),
        "amplitude": lit(1e-3),
        "decay": lit(0.995),
        "friction_scale": lit(1e4),
        "sensor_scale": lit(10.0),
        "banner": rendering.banner(digest, real),
    }


def render_can(
    artifact: ControllerArtifact,
    prefix: str = "smartjoint",
    amplifier: protocol.Amplifier | None = None,
    full_codec: bool = False,
    real: str = "float",
) -> dict[str, str]:
    """Render the CAN message layer of the controller.

    Parameters
    ----------
    artifact : ControllerArtifact
        The controller design artefact.
    prefix : str
        The prefix of every C identifier and file name.
    amplifier : protocol.Amplifier, optional
        The piezo amplifier; default the artefact's force per volt and preload.
    full_codec : bool
        The firmware packs what it sends and unpacks what it receives; ``True`` adds the other
        direction (test benches).
    real : str
        The scalar type of the controllers the example ``main.c`` drives.

    Returns
    -------
    dict of str to str
        File name → text: ``<prefix>_can.h/.c``, the E2E runtime ``sj_e2e.h/.c``, ``bus.dbc``
        and an example ``main.c`` with the CAN loop.

    Examples
    --------
    >>> files = render_can(artifact, full_codec=True)  # doctest: +SKIP
    >>> protocol.load_dbc(files["bus.dbc"]).messages  # doctest: +SKIP
    """
    rendering.check(artifact, real, prefix)
    amplifier = amplifier or protocol.Amplifier(
        force_per_volt=artifact.piezo_force_per_volt, preload=artifact.piezo_preload
    )
    check_can(artifact, amplifier)
    db = protocol.database(artifact, amplifier)
    messages, layouts = _messages(db)
    joints = [j.upper() for j in artifact.joint_names]
    cycle_us = int(round(artifact.sample_time * 1e6))
    inputs = _inputs(db, joints, cycle_us)
    digest = artifact.artifact_sha256
    banner = rendering.banner(digest, part="codegen, CAN layer")
    context = {
        "prefix": prefix,
        "PREFIX": prefix.upper(),
        "name": f"{prefix}_can",
        "NAME": f"{prefix}_can".upper(),
        "banner": banner,
        "joints": joints,
        "sensors": [s.upper() for s in artifact.sensor_names],
        "messages": messages,
        "layouts": layouts,
        "inputs": inputs,
        "cycle_us": cycle_us,
        "timeout_cycles": artifact.timeout_cycles,
        "recovery_cycles": artifact.recovery_cycles,
        "full_codec": full_codec,
        "mode_safe": protocol.MODE_SAFE,
        **_limit_literals(artifact, amplifier),
    }
    env = rendering.environment()
    files = {
        f"{prefix}_can.h": env.get_template("can.h.j2").render(context),
        f"{prefix}_can.c": env.get_template("can.c.j2").render(context),
    }
    files.update(_runtime_sources())
    files["bus.dbc"] = _checked_dbc(db)
    example = _example_context(context, real, digest)
    files["main.c"] = env.get_template("main_can.c.j2").render(example)
    return files
