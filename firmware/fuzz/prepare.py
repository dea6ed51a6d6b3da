"""Prepare the sources the fuzz harnesses are built from (run by ``.ci/fuzz``).

Writes into FOLDER:

- ``double/``: the double build of the controllers of ``firmware/generated/controller.json``;
- ``codec/``: the CAN layer of the same artefact in the double build with both directions of
  every frame (``full_codec``, as the SIL bench compiles it), so pack and unpack can be fuzzed as
  a pair and encode/decode checked bit for bit against the double reference (the raw
  pack/unpack code is the same text in the float build), with the double controllers' headers;
- ``fuzz_codec.h/.c``: the binding of the codec under test, one ``fuzz_codec`` per frame:
  adaptors from the generated layout struct and per-signal functions (named by the documented
  rule ``<prefix>_can_<layout>_<signal>_<encode|decode|is_in_range>``) to arrays in start-bit
  order;
- ``fuzz_reference.h/.c``: what the harnesses check against, taken from the protocol and the
  artefact rather than from the generated C: the signal layout of ``bus.dbc``, F^min and F^max,
  the safe normal force, the amplifier gain and the plausible ranges of the controller inputs;
- ``fuzz_xcp_reference.h``: the XCP slave's calibration page as the A2L states it
  (``codegen.xcp_slave.calibration_values``): each value's limits, and per law and joint where
  F_N^min and its range lie and the largest sum the joint allows.

Before writing anything it renders the float firmware again and requires it to equal
``firmware/generated`` byte for byte, so the extra builds come from the generator that wrote
the reference firmware (the codec functions of ``codec/`` are those of the reference).

Usage: ``python firmware/fuzz/prepare.py FOLDER``.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "firmware" / "generated"
PREFIX = "smartjoint"


def _number(value: float) -> str:
    """A C double literal of a finite value that parses back to the same double."""
    if not math.isfinite(value):
        raise SystemExit(f"prepare.py: {value!r} — the bus table and the limits hold finite numbers only")
    text = repr(float(value))
    return text if any(c in text for c in ".e") else text + ".0"


def _reference_sources(artifact, can_layer, generate) -> dict[str, str]:
    files = {**generate.render(artifact, "float", PREFIX), **can_layer.render_can(artifact, PREFIX, nodes=True)}
    return {name: text for name, text in files.items() if name.endswith((".c", ".h"))}


def _layout(db, artifact) -> tuple[str, str]:
    """fuzz_reference.h and fuzz_reference.c: the bus table and the limits of the artefact."""
    messages = sorted(db.messages, key=lambda m: m.frame_id)
    return "\n".join(_header_lines(messages, artifact)), "\n".join(_source_lines(messages, artifact)) + "\n"


def _setpoint_frames(messages) -> list:
    """The setpoint frames (``SETPOINT_<j>``, ``SETPOINTS_<J>``) by identifier: the order the layer sends them."""
    return [m for m in messages if m.name.startswith(("SETPOINT_", "SETPOINTS_"))]


def _header_lines(messages, artifact) -> list[str]:
    """fuzz_reference.h: the sizes of the bus and the artefact, and the tables' declarations."""
    header = [
        "/* Written by firmware/fuzz/prepare.py from bus.dbc and controller.json of firmware/generated. */",
        "#ifndef FUZZ_REFERENCE_H",
        "#define FUZZ_REFERENCE_H",
        "",
        '#include "fuzz_support.h"',
        "",
    ]
    most = max(len(m.signals) for m in messages)
    longest = max(m.length for m in messages)
    header.append(f"#define FUZZ_MAX_SIGNALS {most}u")
    header.append(f"#define FUZZ_MAX_LENGTH {longest}u")
    header.append(f"#define FUZZ_MESSAGE_COUNT {len(messages)}u")
    header.append(f"#define FUZZ_JOINTS {len(artifact.joint_names)}u")
    header.append(f"#define FUZZ_SENSORS {len(artifact.sensor_names)}u")
    header.append("/* X(lower-case message name) for every frame of the bus */")
    header.append("#define FUZZ_MESSAGES(X) " + " ".join(f"X({m.name.lower()})" for m in messages))
    header.append("")
    for m in messages:
        header.append(f"extern const fuzz_message fuzz_message_{m.name.lower()};")
    header += [
        "extern const fuzz_message *const fuzz_bus[FUZZ_MESSAGE_COUNT];",
        "/* Per joint the frame (SETPOINT_<j> or SETPOINTS_<J>) and signal of its setpoint; the setpoint",
        " * frames in the order the layer sends them (then the heartbeat) */",
        "extern const uint32_t fuzz_setpoint_ids[FUZZ_JOINTS];",
        "extern const char *const fuzz_setpoint_signals[FUZZ_JOINTS];",
        f"#define FUZZ_SETPOINT_FRAMES {len(_setpoint_frames(messages))}u",
        f"#define FUZZ_FIRST_SETPOINT_ID 0x{_setpoint_frames(messages)[0].frame_id:03X}u",
        "extern const uint32_t fuzz_setpoint_frames[FUZZ_SETPOINT_FRAMES];",
        "extern const double fuzz_normal_force_min[FUZZ_JOINTS];",
        "extern const double fuzz_normal_force_max[FUZZ_JOINTS];",
        "/* The one safe force of the policy (artefact; docs/safety.md) */",
        "extern const double fuzz_safe_normal_force[FUZZ_JOINTS];",
        "extern const double fuzz_force_per_volt;",
        "extern const double fuzz_preload;",
        "/* The plausible ranges of the measured signals (artefact) */",
        "extern const double fuzz_sliding_velocity_limit[FUZZ_JOINTS];",
        "extern const double fuzz_friction_force_limit[FUZZ_JOINTS];",
        "extern const double fuzz_measured_normal_force_min[FUZZ_JOINTS];",
        "extern const double fuzz_measured_normal_force_max[FUZZ_JOINTS];",
        "extern const double fuzz_sensor_limit[FUZZ_SENSORS];",
        "extern const double fuzz_amplifier_temperature_limit;",
        "extern const double fuzz_amplifier_current_limit;",
        "extern const double fuzz_tracking_tolerance;",
        "",
        "#endif /* FUZZ_REFERENCE_H */",
        "",
    ]
    return header


def _message_table(m) -> list[str]:
    """One frame's signal rows and its fuzz_message in fuzz_reference.c."""
    rows = []
    lines: list[str] = []
    for s in sorted(m.signals, key=lambda s: s.start):
        if s.byte_order != "little_endian" or s.is_float:
            raise SystemExit(f"prepare.py: signal {m.name}.{s.name}: only little-endian integer signals are modelled")
        ranged = s.minimum is not None and s.maximum is not None
        rows.append(
            f'    {{"{s.name}", {s.start}u, {s.length}u, {int(s.is_signed)}, {int(ranged)}, '
            f"{_number(s.conversion.scale)}, {_number(s.conversion.offset)}, "
            f"{_number(s.minimum if ranged else 0.0)}, {_number(s.maximum if ranged else 0.0)}}},"
        )
    lower = m.name.lower()
    lines.append(f"static const fuzz_signal signals_{lower}[{len(rows)}] = {{")
    lines += rows
    lines.append("};")
    lines.append(
        f'const fuzz_message fuzz_message_{lower} = {{"{m.name}", 0x{m.frame_id:03X}u, {m.length}u, '
        f"{len(rows)}u, signals_{lower}}};"
    )
    lines.append("")
    return lines


def _source_lines(messages, artifact) -> list[str]:
    """fuzz_reference.c: every frame's table, the setpoint ids and the artefact's limits."""
    source = [
        "/* Written by firmware/fuzz/prepare.py from bus.dbc and controller.json of firmware/generated. */",
        '#include "fuzz_reference.h"',
        "",
    ]
    for m in messages:
        source += _message_table(m)
    source.append(
        "const fuzz_message *const fuzz_bus[FUZZ_MESSAGE_COUNT] = {"
        + ", ".join(f"&fuzz_message_{m.name.lower()}" for m in messages)
        + "};"
    )
    carriers = {}  # joint → (frame, signal) of its setpoint
    for m in _setpoint_frames(messages):
        for signal in m.signals:
            if m.name.startswith("SETPOINT_") and signal.name == "voltage":
                carriers[m.name[len("SETPOINT_") :]] = (m, signal.name)
            elif signal.name.startswith("voltage_"):
                carriers[signal.name[len("voltage_") :].upper()] = (m, signal.name)
    setpoints = [carriers[j.upper()] for j in artifact.joint_names]
    source.append(
        "const uint32_t fuzz_setpoint_ids[FUZZ_JOINTS] = {"
        + ", ".join(f"0x{m.frame_id:03X}u" for m, _ in setpoints)
        + "};"
    )
    source.append(
        "const char *const fuzz_setpoint_signals[FUZZ_JOINTS] = {" + ", ".join(f'"{s}"' for _, s in setpoints) + "};"
    )
    source.append(
        "const uint32_t fuzz_setpoint_frames[FUZZ_SETPOINT_FRAMES] = {"
        + ", ".join(f"0x{m.frame_id:03X}u" for m in _setpoint_frames(messages))
        + "};"
    )
    for name, values in (
        ("normal_force_min", artifact.normal_force_min),
        ("normal_force_max", artifact.normal_force_max),
        ("safe_normal_force", artifact.safe_normal_force),
    ):
        source.append(f"const double fuzz_{name}[FUZZ_JOINTS] = {{" + ", ".join(_number(v) for v in values) + "};")
    source.append(f"const double fuzz_force_per_volt = {_number(artifact.piezo_force_per_volt)};")
    source.append(f"const double fuzz_preload = {_number(artifact.piezo_preload)};")
    for name, values, size in (
        ("sliding_velocity_limit", artifact.sliding_velocity_limit, "FUZZ_JOINTS"),
        ("friction_force_limit", artifact.friction_force_limit, "FUZZ_JOINTS"),
        ("measured_normal_force_min", artifact.measured_normal_force_min, "FUZZ_JOINTS"),
        ("measured_normal_force_max", artifact.measured_normal_force_max, "FUZZ_JOINTS"),
        ("sensor_limit", artifact.sensor_limit, "FUZZ_SENSORS"),
    ):
        source.append(f"const double fuzz_{name}[{size}] = {{" + ", ".join(_number(v) for v in values) + "};")
    for name in ("amplifier_temperature_limit", "amplifier_current_limit", "tracking_tolerance"):
        source.append(f"const double fuzz_{name} = {_number(getattr(artifact, name))};")
    return source


def _codec_binding(messages, layout_of) -> tuple[str, str]:
    """fuzz_codec.h and fuzz_codec.c: per frame, adaptors of its layout's generated codec."""
    header = [
        "/* Written by firmware/fuzz/prepare.py: the generated codec of every frame behind arrays. */",
        "#ifndef FUZZ_CODEC_H",
        "#define FUZZ_CODEC_H",
        "",
        "#include <stddef.h>",
        "#include <stdint.h>",
        "",
        "/* Raw values as int64_t (signed fields sign-extended), physical values as double. */",
        "typedef struct {",
        "    int (*pack)(const int64_t *raw, uint8_t *dst, size_t size);",
        "    int (*unpack)(const uint8_t *src, size_t size, int64_t *raw);",
        "    void (*encode)(const double *values, int64_t *raw);",
        "    void (*decode)(const int64_t *raw, double *values);",
        "    void (*is_in_range)(const int64_t *raw, int *in_range);",
        "} fuzz_codec;",
        "",
    ]
    source = ["/* Written by firmware/fuzz/prepare.py. */", '#include "fuzz_codec.h"', f'#include "{PREFIX}_can.h"', ""]
    for m in messages:
        lower, layout = m.name.lower(), f"{PREFIX}_can_{layout_of(m.name)}"
        signals = sorted(m.signals, key=lambda s: s.start)
        header.append(f"extern const fuzz_codec fuzz_codec_{lower};")
        body = {
            "pack": [f"    struct {layout}_t s;"]
            + [f"    s.{sig.name} = ({_ctype(sig)})raw[{k}];" for k, sig in enumerate(signals)]
            + [f"    return {layout}_pack(dst, &s, size);"],
            "unpack": [f"    struct {layout}_t s;", f"    const int result = {layout}_unpack(&s, src, size);"]
            + [f"    raw[{k}] = (int64_t)s.{sig.name};" for k, sig in enumerate(signals)]
            + ["    return result;"],
            "encode": [
                f"    raw[{k}] = (int64_t){layout}_{sig.name}_encode(values[{k}]);" for k, sig in enumerate(signals)
            ],
            "decode": [
                f"    values[{k}] = {layout}_{sig.name}_decode(({_ctype(sig)})raw[{k}]);"
                for k, sig in enumerate(signals)
            ],
            "is_in_range": [
                f"    in_range[{k}] = {layout}_{sig.name}_is_in_range(({_ctype(sig)})raw[{k}]);"
                for k, sig in enumerate(signals)
            ],
        }
        heads = {
            "pack": "int {}(const int64_t *raw, uint8_t *dst, size_t size)",
            "unpack": "int {}(const uint8_t *src, size_t size, int64_t *raw)",
            "encode": "void {}(const double *values, int64_t *raw)",
            "decode": "void {}(const int64_t *raw, double *values)",
            "is_in_range": "void {}(const int64_t *raw, int *in_range)",
        }
        for what, lines in body.items():
            if what == "unpack":  # struct fields set before read: no uninitialised copy on failure
                lines.insert(1, "    memset(&s, 0, sizeof s);")
            source += [f"static {heads[what].format(f'{what}_{lower}')}", "{", *lines, "}", ""]
        source.append(
            f"const fuzz_codec fuzz_codec_{lower} = "
            f"{{pack_{lower}, unpack_{lower}, encode_{lower}, decode_{lower}, is_in_range_{lower}}};"
        )
        source.append("")
    header += ["", "#endif /* FUZZ_CODEC_H */", ""]
    source.insert(1, "#include <string.h>")
    return "\n".join(header), "\n".join(source)


def _ctype(signal) -> str:
    width = next(w for w in (8, 16, 32) if signal.length <= w)
    return f"{'int' if signal.is_signed else 'uint'}{width}_t"


def _xcp_reference(artifact) -> str:
    """fuzz_xcp_reference.h: the calibration page's limits in the float build (what the A2L says)."""
    import numpy as np

    from smartjoint.codegen import xcp_slave
    from smartjoint.design.structure.description import Xcp

    values = xcp_slave.calibration_values(artifact, "float", Xcp())
    index = {(v.law, v.field, v.joint): k for k, v in enumerate(values)}
    laws = list(dict.fromkeys(v.law for v in values))
    joints = list(artifact.joint_names)
    pairs, sums = [], []
    for law in laws:
        for j, joint in enumerate(joints):
            m, r = index[(law, "normal_force_min", joint)], index[(law, "normal_force_range", joint)]
            pairs.append(f"{{{m}u, {r}u}}")
            design = float(np.float32(values[m].value) + np.float32(values[r].value))
            sums.append(_number(max(float(np.float32(artifact.normal_force_max[j])), design)))
    return "\n".join([
        "/* The XCP slave's calibration page as the A2L states it (prepare.py): not the slave's tables. */",
        f"#define XCP_VALUES {len(values)}u",
        f"#define XCP_PAIRS {len(pairs)}u",
        f"static const double xcp_lower[XCP_VALUES] = {{{', '.join(_number(v.lower) for v in values)}}};",
        f"static const double xcp_upper[XCP_VALUES] = {{{', '.join(_number(v.upper) for v in values)}}};",
        "/* per law and joint: the value indices of F_N^min and of its range, and the largest sum */",
        f"static const unsigned int xcp_pairs[XCP_PAIRS][2] = {{{', '.join(pairs)}}};",
        f"static const double xcp_sum_limit[XCP_PAIRS] = {{{', '.join(sums)}}};",
        "",
    ])  # fmt: skip


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: prepare.py FOLDER", file=sys.stderr)
        return 2
    from smartjoint.codegen import can_codec, can_layer, generate
    from smartjoint.design.control import artifact as artifacts
    from smartjoint.design.network import protocol

    artifact = artifacts.load(REFERENCE / "controller.json")
    for name, text in _reference_sources(artifact, can_layer, generate).items():
        if not (REFERENCE / name).exists() or (REFERENCE / name).read_text() != text:
            print(
                f"prepare.py: firmware/generated/{name} is not what the generator writes: regenerate it "
                "(firmware/README.md)",
                file=sys.stderr,
            )
            return 2
    folder = Path(argv[0])
    files = {
        f"double/{name}": text
        for name, text in generate.render(artifact, "double", PREFIX).items()
        if name.endswith((".c", ".h")) and name != "main.c"
    }
    codec = can_layer.render_can(artifact, PREFIX, full_codec=True, real="double")
    files.update({f"codec/{name}": codec[name] for name in (f"{PREFIX}_can.h", f"{PREFIX}_can.c")})
    headers = {name: text for name, text in files.items() if name.startswith("double/") and name.endswith(".h")}
    files.update({f"codec/{name[len('double/') :]}": text for name, text in headers.items()})
    db = protocol.load_dbc((REFERENCE / "bus.dbc").read_text())
    files["fuzz_reference.h"], files["fuzz_reference.c"] = _layout(db, artifact)
    joints = [j.upper() for j in artifact.joint_names]
    messages = sorted(db.messages, key=lambda m: m.frame_id)
    layout_of = lambda name: can_codec.layout_name(name, joints)  # noqa: E731
    files["fuzz_codec.h"], files["fuzz_codec.c"] = _codec_binding(messages, layout_of)
    files["fuzz_xcp_reference.h"] = _xcp_reference(artifact)
    for name, text in files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
