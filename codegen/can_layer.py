"""Render the CAN message layer of the controller (``templates/can.*.j2``) from the artefact and
the DBC of ``design/network/protocol.py``: pack/unpack of every frame (bit-exact with cantools),
E2E check and protection (``firmware/runtime/sj_e2e.c``, copied next to it), per-input ageing
by the senders' counters, plausibility of every decoded signal, the safe state with recovery
(the artefact's safe normal force; docs/safety.md), the controller step between receive and
transmit, the heartbeat the amplifiers watch."""

from __future__ import annotations

import re

import numpy as np

from smartjoint.codegen import can_codec, identifiers, rendering
from smartjoint.common import law_registry, package_data
from smartjoint.common.errors import ModelError
from smartjoint.design.control.artifact import ControllerArtifact
from smartjoint.design.network import plan, protocol

RUNTIME = package_data.folder("smartjoint.firmware", "runtime")


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
                tuple(sorted(m.receivers)),
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


def _messages(db, joints: list[str], real: str, full_codec: bool) -> tuple[list[dict], list[dict]]:
    """The template's frames (by identifier) and layouts (``can_codec.layouts``); a layout is
    packed when the controller sends one of its frames, unpacked when it receives one (both with
    ``full_codec``)."""
    layouts, of = can_codec.layouts(db, joints, real)
    by_name = {layout["name"]: layout for layout in layouts}
    messages = []
    for m in sorted(db.messages, key=lambda m: m.frame_id):
        sent = protocol.CONTROLLER in (m.senders or [])
        messages.append({"name": m.name, "frame_id": m.frame_id, "length": m.length, "layout": of[m.name]})
        layout = by_name[of[m.name]]
        layout["packed"] = layout.get("packed", False) or sent or full_codec
        layout["unpacked"] = layout.get("unpacked", False) or not sent or full_codec
    return messages, layouts


def input_frames(artifact: ControllerArtifact) -> frozenset[str]:
    """The frames the CAN layer receives and ages (the input table of ``render_can``): each joint's
    ``JOINT_<j>`` and ``AMP_STATUS_<j>`` and ``TIP_SENSORS``. Any other frame a node sends (a joint
    node's ``NODE_STATUS_<j>`` in local mode, which a supervisor reads) is an unknown identifier to it."""
    joints = [j.upper() for j in artifact.joint_names]
    return frozenset([*(f"JOINT_{t}" for t in joints), "TIP_SENSORS", *(f"AMP_STATUS_{t}" for t in joints)])


def _inputs(db, joints: list[str], cycle_us: int, joint_bus: list[int]) -> list[dict]:
    """The frames the controller receives, in the order the C ages them, each with its bus
    (``joint_bus``: each joint's; the tip sensors on the first); each must come once per
    controller cycle, since ages count steps (design/network/protocol.py)."""
    by_name = {m.name: m for m in db.messages}
    inputs = [
        {"kind_c": "INPUT_JOINT", "index": j, "message": f"JOINT_{tag}", "sensors_only": 0, "bus": joint_bus[j]}
        for j, tag in enumerate(joints)
    ]
    inputs.append({"kind_c": "INPUT_TIP", "index": 0, "message": "TIP_SENSORS", "sensors_only": 1, "bus": 0})
    inputs += [
        {
            "kind_c": "INPUT_AMPLIFIER",
            "index": j,
            "message": f"AMP_STATUS_{tag}",
            "sensors_only": 0,
            "bus": joint_bus[j],
        }
        for j, tag in enumerate(joints)
    ]
    for i in inputs:
        if int(by_name[i["message"]].cycle_time) * 1000 != cycle_us:
            raise ModelError(
                f"{i['message']}: cycle time {by_name[i['message']].cycle_time} ms — the CAN layer ages "
                f"inputs in controller cycles and needs every input at Δt = {cycle_us / 1000:g} ms"
            )
    # ascending identifiers: the order rx searches and the order of the per-input arrays
    return sorted(inputs, key=lambda i: by_name[i["message"]].frame_id)


def _raw_limits(db, artifact: ControllerArtifact) -> dict[str, str]:
    """The plausibility limits of the artefact as raw bounds of the signals they apply to: the
    raw values whose decoded value (double, as the layer decoded before) lies within."""
    joint = db.get_message_by_name(f"JOINT_{artifact.joint_names[0].upper()}")
    tip = db.get_message_by_name("TIP_SENSORS")
    status = db.get_message_by_name(f"AMP_STATUS_{artifact.joint_names[0].upper()}")
    out: dict[str, str] = {}

    def bounds(key, signal, lows, highs, text):
        pairs = [can_codec.raw_bounds(signal, float(lo), float(hi)) for lo, hi in zip(lows, highs)]
        c = can_codec.ctype(signal.length, signal.is_signed)
        out[f"{key}_low"] = ", ".join(can_codec.c_int(p[0], c) for p in pairs)
        out[f"{key}_high"] = ", ".join(can_codec.c_int(p[1], c) for p in pairs)
        out[f"{key}_text"] = text

    v, u = np.asarray(artifact.sliding_velocity_limit), np.asarray(artifact.friction_force_limit)
    bounds("sliding_velocity", joint.get_signal_by_name("sliding_velocity"), -v, v, "|v| <= sliding_velocity_limit")
    bounds("friction_force", joint.get_signal_by_name("friction_force"), -u, u, "|u_R| <= friction_force_limit")
    bounds(
        "normal_force",
        joint.get_signal_by_name("normal_force"),
        artifact.measured_normal_force_min,
        artifact.measured_normal_force_max,
        "measured F_N within [measured_normal_force_min, measured_normal_force_max]",
    )
    y = np.asarray(artifact.sensor_limit)
    for r, sensor in enumerate(artifact.sensor_names):
        bounds(f"sensor{r}", tip.get_signal_by_name(sensor.lower()), [-y[r]], [y[r]], "")
    out["sensor_low"] = ", ".join(out.pop(f"sensor{r}_low") for r in range(len(y)))
    out["sensor_high"] = ", ".join(out.pop(f"sensor{r}_high") for r in range(len(y)))
    out["sensor_text"] = "|y| <= sensor_limit"
    for r in range(len(y)):
        out.pop(f"sensor{r}_text")
    bounds(
        "temperature",
        status.get_signal_by_name("temperature"),
        [-1000.0],
        [artifact.amplifier_temperature_limit],
        f"amplifier_temperature_limit = {artifact.amplifier_temperature_limit:g} degC",
    )
    current = artifact.amplifier_current_limit
    bounds("current", status.get_signal_by_name("current"), [-current], [current], f"|I| <= {current:g} A")
    return out


def _limit_literals(artifact: ControllerArtifact, amplifier: protocol.Amplifier, real: str) -> dict[str, str]:
    """The safe state's force, the tracking and actuation tolerances and the amplifier's scaling as
    C literals."""
    lit = lambda value: rendering.literal(float(value), real)  # noqa: E731
    return {
        "safe_normal_force": ", ".join(lit(v) for v in artifact.safe_normal_force),
        "tracking_tolerance": lit(artifact.tracking_tolerance),
        "actuation_tolerance": ", ".join(lit(v) for v in artifact.actuation_tolerance),
        "force_per_volt": lit(amplifier.force_per_volt),
        "preload": lit(amplifier.preload),
        "amplifier_text": f"F_N = {amplifier.force_per_volt:g} N/V * V + {amplifier.preload:g} N, "
        f"V within [0, {amplifier.voltage_max:g}] V",
    }


def _raw_types(artifact: ControllerArtifact, layouts: list[dict], setpoint: tuple[str, str]) -> dict:
    """The raw C types the layer's state and limits take from the frames it reads and sends;
    ``setpoint`` the (layout, signal) of the first setpoint voltage, whose codec the layer's
    setpoints go through (every setpoint signal has the SETPOINT frame's scaling)."""
    kinds = {layout["name"]: {s["name"]: s["ctype"] for s in layout["signals"]} for layout in layouts}
    sensor_ctypes = {kinds["tip_sensors"][s.lower()] for s in artifact.sensor_names}
    if len(sensor_ctypes) != 1:
        raise ModelError("TIP_SENSORS: the sensors' signals need one raw type (design/network/protocol.py)")
    return {
        "joint_ctypes": kinds["joint"],
        "amp_ctypes": kinds["amp_status"],
        "sensor_ctype": sensor_ctypes.pop(),
        "setpoint_ctype": kinds[setpoint[0]][setpoint[1]],
    }


def _outputs(network: plan.NetworkPlan, joints: list[str], prefix: str) -> dict:
    """What the layer sends each sample, per bus in the plan's order: its setpoint frames (one
    ``SETPOINT_<j>`` each, or ``SETPOINTS_<J>`` with several voltages), then its heartbeat; the
    bus of every joint; the codec functions' stem of the first setpoint signal."""
    outputs: list[dict] = []
    joint_bus = [0] * len(joints)
    for b, bus in enumerate(network.buses):
        for tag in bus.joints:
            joint_bus[joints.index(tag.upper())] = b
        for m in sorted(bus.database.messages, key=lambda m: m.frame_id):
            if m.name.startswith("SETPOINTS_"):
                voltages = [
                    {"signal": s.name, "joint": joints.index(s.name[len("voltage_") :].upper())}
                    for s in sorted(m.signals, key=lambda s: s.start)
                    if s.name.startswith("voltage_")
                ]
                outputs.append(
                    {
                        "message": m.name,
                        "bus": b,
                        "kind_c": f"OUTPUT_{m.name}",
                        "joint": voltages[0]["joint"],
                        "packed": True,
                        "layout": can_codec.layout_name(m.name, joints),
                        "voltages": voltages,
                    }
                )
            elif m.name.startswith("SETPOINT_"):
                joint = joints.index(m.name[len("SETPOINT_") :])
                outputs.append(
                    {"message": m.name, "bus": b, "kind_c": "OUTPUT_SETPOINT", "joint": joint, "packed": False}
                )
        outputs.append(
            {"message": "CONTROLLER_STATUS", "bus": b, "kind_c": "OUTPUT_HEARTBEAT", "joint": 0, "packed": False}
        )
    first = outputs[0]
    setpoint = (first["layout"], first["voltages"][0]["signal"]) if first["packed"] else ("setpoint", "voltage")
    single = any(o["kind_c"] == "OUTPUT_SETPOINT" for o in outputs)
    kinds = [o["kind_c"] for o in outputs if o["packed"]] + ["OUTPUT_SETPOINT"] * single + ["OUTPUT_HEARTBEAT"]
    return {
        "outputs": outputs,
        "output_kinds": kinds,
        "single_setpoints": single,
        "joint_bus": joint_bus,
        "setpoint": setpoint,
        "setpoint_codec": f"{prefix}_can_{setpoint[0]}_{setpoint[1]}",
        "buses": [
            {"index": b, "name": p.bus.name, "joints_text": ", ".join(p.joints) or "no joint"}
            for b, p in enumerate(network.buses)
        ],
    }


def network_database(network: plan.NetworkPlan):
    """Every frame of a plan in one cantools database (the heartbeat, on every bus, once): the
    frames the layer's codec and dispatch are generated from."""
    from cantools.database import can

    seen: dict[str, can.Message] = {}
    nodes: dict[str, can.Node] = {}
    for p in network.buses:
        for m in p.database.messages:
            seen.setdefault(m.name, m)
        for n in p.database.nodes:
            nodes.setdefault(n.name, n)
    db = can.Database(
        sorted(seen.values(), key=lambda m: m.frame_id),
        list(nodes.values()),
        version=network.buses[0].database.version,
        dbc_specifics=protocol.fd_specifics(),
    )
    db.refresh()
    return db


def dbc_files(network: plan.NetworkPlan) -> dict[str, str]:
    """The DBC of every bus of a plan, checked to read back: ``bus.dbc`` for one bus, else
    ``bus_<name>.dbc`` per bus (characters other than letters, digits, ``_``, ``-`` and ``.`` of
    the bus's name as ``_``)."""
    if len(network.buses) == 1:
        return {"bus.dbc": _checked_dbc(network.buses[0].database)}
    return {f"bus_{re.sub(r'[^A-Za-z0-9_.-]', '_', p.bus.name)}.dbc": _checked_dbc(p.database) for p in network.buses}


def _arithmetic(real: str) -> dict[str, str]:
    """The constants of the codec's rounding in the scalar type: from ``exact_integers`` on every
    value is an integer, below it ``truncation`` holds the integer part exactly."""
    lit = lambda value: rendering.literal(float(value), real)  # noqa: E731
    return {
        "exact_integers": "8388608.0f" if real == "float" else "4503599627370496.0",
        "truncation": "int32_t" if real == "float" else "int64_t",
        "zero": lit(0.0),
        "half": lit(0.5),
        "one": lit(1.0),
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


def _example_context(context: dict, real: str, digest: str, nodes: bool) -> dict:
    """The example ``main.c``'s context: the layer's, with its stimulus in the controllers' scalar;
    with ``nodes`` (the joint nodes and their supervisor beside it) it runs local mode too."""
    lit = lambda value: rendering.literal(value, real)  # noqa: E731
    prefix = context["prefix"]
    return {
        **context,
        "node_configs": [f"{prefix}_node_{j.lower()}_config" for j in context["joints"]] if nodes else [],
        "zero": lit(0.0),
        "amplitude": lit(1e-3),
        "decay": lit(0.995),
        "friction_scale": lit(1e4),
        "sensor_scale": lit(10.0),
        "banner": rendering.banner(digest, real),
    }


def _laws_context() -> dict:
    """Every law of the registry (the layer runs the one its RESET / init names) and the law the
    example runs (the fault-matrix law: it reads every frame)."""
    return {
        "laws": [
            {"name": law.name, "display": law.display, "mode": law.mode, "inputs": law.inputs}
            for law in law_registry.LAWS.values()
        ],
        "example_law": law_registry.fault_matrix_law().name,
    }


def render_can(
    artifact: ControllerArtifact,
    prefix: str = "smartjoint",
    amplifier: protocol.Amplifier | None = None,
    full_codec: bool = False,
    real: str = "float",
    network: plan.NetworkPlan | None = None,
    nodes: bool = False,
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
        The scalar type of the controllers the layer drives (``<prefix>_real``): the codec's
        encode/decode compute in it, so the float build uses no double arithmetic.
    network : NetworkPlan, optional
        The buses and their frames (``design.network.plan.plan``: its setpoints packed into
        ``SETPOINTS_<J>`` frames where that lowers the load); default the plan of one bus at
        CAN FD 1/5 Mbit/s (``plan.plan`` without a ``[network]``).
    nodes : bool
        The joint nodes and their supervisor are beside it: ``main.c`` runs local mode too.

    Returns
    -------
    dict of str to str
        File name → text: ``<prefix>_can.h/.c``, the E2E runtime ``sj_e2e.h/.c``, the DBC of
        every bus (``dbc_files``) and an example ``main.c`` with the CAN loop.
    """
    rendering.check(artifact, real, prefix)
    amplifier = amplifier or protocol.amplifier_of(artifact)
    check_can(artifact, amplifier)
    network = network or plan.plan(artifact, amplifier=amplifier)
    db = network_database(network)
    joints = [j.upper() for j in artifact.joint_names]
    messages, layouts = _messages(db, joints, real, full_codec)
    sending = _outputs(network, joints, prefix)
    cycle_us = int(round(artifact.sample_time * 1e6))
    digest = artifact.artifact_sha256
    context = {
        "prefix": prefix,
        "PREFIX": prefix.upper(),
        "name": f"{prefix}_can",
        "NAME": f"{prefix}_can".upper(),
        "banner": rendering.banner(digest, part="codegen, CAN layer"),
        "joints": joints,
        "sensors": [s.upper() for s in artifact.sensor_names],
        "messages": messages,
        "layouts": layouts,
        "inputs": _inputs(db, joints, cycle_us, sending["joint_bus"]),
        **sending,
        "cycle_us": cycle_us,
        "timeout_cycles": artifact.timeout_cycles,
        "recovery_cycles": artifact.recovery_cycles,
        "full_codec": full_codec,
        "mode_safe": protocol.MODE_SAFE,
        **_laws_context(),
        "einval": can_codec.EINVAL,
        "limits": _raw_limits(db, artifact),
        **_raw_types(artifact, layouts, sending["setpoint"]),
        **_limit_literals(artifact, amplifier, real),
        **_arithmetic(real),
    }
    env = rendering.environment()
    files = {f"{prefix}_can.{kind}": env.get_template(f"can.{kind}.j2").render(context) for kind in "hc"}
    files.update({**_runtime_sources(), **dbc_files(network)})
    example = _example_context(context, real, digest, nodes)
    files["main.c"] = env.get_template("main_can.c.j2").render(example)
    return files
