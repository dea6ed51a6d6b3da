"""Render the CAN message layer of the controller (``templates/can.*.j2``) from the artefact and
the DBC of ``bench/protocol.py``: pack/unpack of every frame (bit-exact with cantools),
E2E check and protection (``firmware/runtime/sj_e2e.c``, copied next to it), per-input
timeouts, the safe state with recovery, the controller step between receive and transmit."""

from __future__ import annotations

import numpy as np

from .. import package_data
from ..bench import protocol
from ..design.artifact import ControllerArtifact
from ..design.errors import ModelError
from . import generate, identifiers

RUNTIME = package_data.folder("smartjoint.firmware", "runtime")
TIMEOUT_CYCLES = 3
RECOVERY_FRAMES = 3
UINT32_MAX = 2 ** 32 - 1  # the layer's clock: microseconds in uint32_t, wrapping


def _signal(signal) -> dict:
    lit = lambda value: generate.literal(float(value), "double")  # noqa: E731
    length, signed = signal.length, signal.is_signed
    if length > 32:  # raw limits must stay exact doubles and the int64 cast defined
        raise ModelError(f"signal {signal.name}: {length} bits — the generated codec handles up to 32")
    raw_min = -(2 ** (length - 1)) if signed else 0
    raw_max = 2 ** (length - 1) - 1 if signed else 2 ** length - 1
    return {"name": signal.name, "start": signal.start, "length": length, "signed": signed,
            "scale": lit(signal.conversion.scale), "offset": lit(signal.conversion.offset),
            # A range clamps only when both ends are given; else only the raw field limits apply.
            "minimum": None if signal.minimum is None or signal.maximum is None else lit(signal.minimum),
            "maximum": None if signal.minimum is None or signal.maximum is None else lit(signal.maximum),
            "raw_min": lit(raw_min), "raw_max": lit(raw_max), "unit": signal.unit or "",
            "comment": (signal.comment or signal.name).replace("*/", "* /")}


def check_can(artifact: ControllerArtifact, amplifier: protocol.Amplifier, safe_normal_force=None,
              timeout_cycles: int = TIMEOUT_CYCLES, recovery_frames: int = RECOVERY_FRAMES) -> np.ndarray:
    """What the CAN layer's C types and frames must hold, before anything is rendered; returns
    the safe normal force per joint."""
    identifiers.check_names(artifact.joint_names, artifact.sensor_names, members=protocol.E2E_SIGNALS)
    for name, value in (("timeout_cycles", timeout_cycles), ("recovery_frames", recovery_frames)):
        if isinstance(value, bool) or not (isinstance(value, int) and 1 <= value <= 255):
            raise ModelError(f"{name}: {value!r} — a whole number between 1 and 255")
    db = protocol.database(artifact, amplifier)  # names, cycle times and signal ranges of the DBC
    # Timeouts compare wrapped uint32 differences: they hold for intervals below 2^32 µs.
    cycle_us = int(round(artifact.sample_time * 1e6))
    if timeout_cycles * cycle_us > UINT32_MAX:
        raise ModelError(f"sample_time: {artifact.sample_time!r} s — the CAN layer counts microseconds in uint32_t: "
                         f"timeout_cycles·Δt = {timeout_cycles}·{cycle_us} µs must stay within {UINT32_MAX} µs "
                         f"(Δt ≤ {UINT32_MAX // timeout_cycles // 1000} ms with {timeout_cycles} timeout cycles)")
    low, high = np.asarray(artifact.normal_force_min), np.asarray(artifact.normal_force_max)
    k, preload = amplifier.force_per_volt, amplifier.preload
    reach = k * amplifier.voltage_max + preload
    for j, joint in enumerate(artifact.joint_names):
        tag = joint.upper()
        if preload > low[j]:
            raise ModelError(f"piezo_preload: {preload!r} N — above normal_force_min[{j}] = {float(low[j])!r} N "
                             f"of joint {joint!r}: the setpoint voltage cannot go below 0 V, so F_N^min is out of reach")
        if high[j] > reach:
            raise ModelError(f"normal_force_max[{j}]: {float(high[j])!r} N for joint {joint!r} — the setpoint frame "
                             f"commands at most piezo_force_per_volt·voltage_max + piezo_preload = {k:g}·"
                             f"{amplifier.voltage_max:g} + {preload:g} = {reach:g} N")
        measured = db.get_message_by_name(f"JOINT_{tag}").get_signal_by_name("normal_force").maximum
        if high[j] > measured:
            raise ModelError(f"normal_force_max[{j}]: {float(high[j])!r} N for joint {joint!r} — the JOINT_{tag} "
                             f"frame carries the applied F_N up to {measured:g} N (bench/protocol.py)")
    if safe_normal_force is None:
        return high.astype(float)
    try:
        safe = np.broadcast_to(np.asarray(safe_normal_force, dtype=float), (len(artifact.joint_names),))
    except (TypeError, ValueError):
        raise ModelError(f"safe_normal_force: {safe_normal_force!r} — numbers [N], one or one per joint "
                         f"({len(artifact.joint_names)})") from None
    for j, joint in enumerate(artifact.joint_names):
        if not low[j] <= safe[j] <= high[j]:  # also refuses NaN
            raise ModelError(f"safe_normal_force[{j}]: {float(safe[j])!r} N for joint {joint!r} — must lie within "
                             f"[normal_force_min, normal_force_max] = [{float(low[j])!r}, {float(high[j])!r}] N")
    return np.array(safe, dtype=float)


def _same_bus(db, loaded) -> bool:
    """The DBC text read back by cantools describes the same frames and signals."""
    def frames(database):
        return [(m.name, m.frame_id, m.length, m.is_fd, m.cycle_time, tuple(m.senders or ()),
                 tuple((s.name, s.start, s.length, s.is_signed, s.conversion.scale, s.conversion.offset, s.minimum,
                        s.maximum) for s in sorted(m.signals, key=lambda s: s.start)))
                for m in sorted(database.messages, key=lambda m: m.frame_id)]
    return frames(db) == frames(loaded)


def render_can(artifact: ControllerArtifact, prefix: str = "smartjoint", amplifier: protocol.Amplifier | None = None,
               safe_normal_force=None, timeout_cycles: int = TIMEOUT_CYCLES,
               recovery_frames: int = RECOVERY_FRAMES, full_codec: bool = False, real: str = "float") -> dict[str, str]:
    """File name → text: ``<prefix>_can.h/.c``, the E2E runtime ``sj_e2e.h/.c``, ``bus.dbc`` and
    an example ``main.c`` with the CAN loop. The firmware packs what it sends and unpacks what it
    receives; ``full_codec`` adds the other direction (test benches)."""
    generate.check(artifact, real, prefix)
    amplifier = amplifier or protocol.Amplifier(force_per_volt=artifact.piezo_force_per_volt,
                                                preload=artifact.piezo_preload)
    safe = check_can(artifact, amplifier, safe_normal_force, timeout_cycles, recovery_frames)
    db = protocol.database(artifact, amplifier)
    messages = [{"name": m.name, "frame_id": m.frame_id, "length": m.length,
                 "received": protocol.CONTROLLER not in (m.senders or []),
                 "signals": [_signal(s) for s in sorted(m.signals, key=lambda s: s.start)]} for m in db.messages]
    # Frames with identical signal rows share one layout table in the C.
    layouts: list[dict] = []
    keys: list = []
    for m in messages:
        fields = ("start", "length", "signed", "scale", "offset", "minimum", "maximum", "raw_min", "raw_max")
        key = tuple(tuple(sig[f] for f in fields) for sig in m["signals"])
        if key not in keys:
            keys.append(key)
            layouts.append({"signals": m["signals"]})
        m["layout"] = keys.index(key)
    by_name = {m.name: m for m in db.messages}
    joints = [j.upper() for j in artifact.joint_names]
    cycle_us = int(round(artifact.sample_time * 1e6))
    inputs = [{"kind": "joint", "index": j, "message": f"JOINT_{tag}", "clqg_only": 0,
               "cycle_us": int(by_name[f"JOINT_{tag}"].cycle_time) * 1000} for j, tag in enumerate(joints)]
    inputs.append({"kind": "tip", "index": 0, "message": "TIP_SENSORS", "clqg_only": 1,
                   "cycle_us": int(by_name["TIP_SENSORS"].cycle_time) * 1000})
    inputs += [{"kind": "amp", "index": j, "message": f"AMP_STATUS_{tag}", "clqg_only": 0,
                "cycle_us": int(by_name[f"AMP_STATUS_{tag}"].cycle_time) * 1000} for j, tag in enumerate(joints)]
    digest = artifact.artifact_sha256
    banner = (f"/* Generated by smartjoint {generate._version()} (codegen, CAN layer) from controller artefact sha256 "
              f"{digest}.\n * Do not edit: regenerate with `smartjoint codegen`. */")
    context = {"prefix": prefix, "PREFIX": prefix.upper(), "name": f"{prefix}_can", "NAME": f"{prefix}_can".upper(),
               "banner": banner, "joints": joints, "sensors": [s.upper() for s in artifact.sensor_names],
               "messages": messages, "layouts": layouts, "inputs": inputs, "cycle_us": cycle_us, "timeout_cycles": timeout_cycles,
               "recovery_frames": recovery_frames, "slow_factor": protocol.SLOW_FACTOR, "full_codec": full_codec,
               "safe_normal_force": ", ".join(generate.literal(v, "double") for v in safe),
               "force_per_volt": generate.literal(amplifier.force_per_volt, "double"),
               "preload": generate.literal(amplifier.preload, "double")}
    env = generate._environment()
    files = {f"{prefix}_can.h": env.get_template("can.h.j2").render(context),
             f"{prefix}_can.c": env.get_template("can.c.j2").render(context)}
    for name in ("sj_e2e.h", "sj_e2e.c"):
        source = RUNTIME / name
        if not source.exists():
            raise ModelError(f"{source}: the firmware runtime is missing (it ships with the source tree)")
        files[name] = source.read_text()
    files["bus.dbc"] = protocol.dbc_text(db)
    if not _same_bus(db, protocol.load_dbc(files["bus.dbc"])):
        raise ModelError("bus.dbc: the DBC text does not read back as the protocol it was written from "
                         "(names or attributes the DBC format cannot carry)")
    lit = lambda value: generate.literal(value, real)  # noqa: E731
    example = {**context, "zero": lit(0.0), "amplitude": lit(1e-3), "decay": lit(0.995), "friction_scale": lit(1e4),
               "sensor_scale": lit(10.0),
               "banner": f"/* Generated by smartjoint {generate._version()} (codegen) from controller artefact sha256 "
                         f"{digest}.\n * Scalar type: {real}. Do not edit: regenerate with `smartjoint codegen`. */"}
    files["main.c"] = env.get_template("main_can.c.j2").render(example)
    return files
