"""The C codec of the CAN frames, in the shape of cantools' generated C (``templates/can.*.j2``).

Each frame *layout* (the frames of every joint share one: ``JOINT_<j>`` → ``joint``,
``SETPOINT_<j>`` → ``setpoint``, ``AMP_STATUS_<j>`` → ``amp_status``) becomes one struct of raw
integer fields as on the bus (``uint8_t``/``uint16_t``/``uint32_t`` or the signed types, by each
signal's length and sign), a ``pack``/``unpack`` pair with size checks, and per signal
``encode`` (physical → raw), ``decode`` (raw → physical) and ``is_in_range`` (raw) in the
controllers' scalar type. Here the template's rows are built: C types, the byte statements of
pack and unpack (DBC little-endian bit fields), literals, and raw bounds of physical ranges.
"""

from __future__ import annotations

import math
import re

from smartjoint.codegen import rendering
from smartjoint.common.errors import ModelError

EINVAL = 22  # the magnitude of pack/unpack's error, as errno's EINVAL (cantools returns -EINVAL)


def layout_name(message: str, joints: list[str]) -> str:
    """The layout a frame belongs to: its name less the joint tag of a per-joint frame, lower case.

    Examples
    --------
    >>> layout_name("AMP_STATUS_A2", ["A1", "A2"]), layout_name("TIP_SENSORS", ["A1"])
    ('amp_status', 'tip_sensors')

    A ``SETPOINTS_<J>`` frame (several joints' setpoints) is a layout of its own.
    """
    if message.startswith("SETPOINTS_"):
        return message.lower()
    for tag in joints:
        if message.endswith(f"_{tag.upper()}"):
            return message[: -len(tag) - 1].lower()
    return message.lower()


def raw_range(length: int, signed: bool) -> tuple[int, int]:
    """The raw values a field of ``length`` bits holds."""
    return (-(2 ** (length - 1)), 2 ** (length - 1) - 1) if signed else (0, 2**length - 1)


def ctype(length: int, signed: bool) -> str:
    """The C type of a raw field: the narrowest of 8, 16 or 32 bits."""
    width = next(w for w in (8, 16, 32) if length <= w)
    return f"{'int' if signed else 'uint'}{width}_t"


def _width(c: str) -> int:
    """The bits of a <stdint.h> type name."""
    return int("".join(ch for ch in c if ch.isdigit()))


def _type_range(c: str) -> tuple[int, int]:
    return raw_range(_width(c), not c.startswith("u"))


def c_int(value: int, c: str) -> str:
    """An integer constant of type ``c`` (the type's extremes by their <stdint.h> names)."""
    low, high = _type_range(c)
    width = str(_width(c))
    if value == high and width != "8":
        return f"{c[:-2].upper()}_MAX"
    if value == low and low < 0 and width != "8":
        return f"INT{width}_MIN"
    return f"{value}{'u' if c.startswith('u') else ''}"


def raw_bounds(signal, low: float, high: float) -> tuple[int, int]:
    """The raw values whose decoded value ``raw·scale + offset`` (double, as cantools and the
    fuzz reference decode) lies within [low, high]: (first, last), clipped to the field."""
    scale, offset = float(signal.conversion.scale), float(signal.conversion.offset)
    field_low, field_high = raw_range(signal.length, signal.is_signed)
    value = lambda raw: raw * scale + offset  # noqa: E731

    def first_at_least(bound: float) -> int:
        raw = max(field_low, min(field_high, math.ceil((bound - offset) / scale)))
        while raw > field_low and value(raw - 1) >= bound:
            raw -= 1
        while raw <= field_high and value(raw) < bound:
            raw += 1
        return raw

    def last_at_most(bound: float) -> int:
        raw = max(field_low, min(field_high, math.floor((bound - offset) / scale)))
        while raw < field_high and value(raw + 1) <= bound:
            raw += 1
        while raw >= field_low and value(raw) > bound:
            raw -= 1
        return raw

    if scale <= 0.0:
        raise ModelError(f"signal {signal.name}: scale {scale!r} — the generated codec needs a positive scale")
    return first_at_least(low), last_at_most(high)


def _whole(value: int, real: str) -> str:
    """An integer-valued literal of the scalar type, digit for digit (powers of two here: exact)."""
    return f"{value}.0{'f' if real == 'float' else ''}"


def _pack_lines(name: str, start: int, length: int, raw: str) -> list[str]:
    """``dst_p[k] |= …`` for every byte the field touches (DBC little-endian, ``@1``)."""
    lines = []
    for byte in range(start // 8, (start + length - 1) // 8 + 1):
        offset = start - 8 * byte
        if offset >= 0:  # the field begins in this byte
            mask = ((1 << min(length, 8 - offset)) - 1) << offset
            value = f"({raw} << {offset}u)" if offset else raw
        else:
            bits = min(8, length + offset)
            mask = (1 << bits) - 1
            value = f"({raw} >> {-offset}u)"
        lines.append(f"dst_p[{byte}] |= (uint8_t)({value} & 0x{mask:02x}u);")
    return lines


def _byte_loops(rows: list[dict]) -> list[dict]:
    """Fields of whole bytes on byte boundaries, two or more of one width (the voltages of a packed
    SETPOINTS frame, the tip sensors): packed in one loop over the byte index, least significant
    byte first, instead of a statement per byte (which compilers merge into word-wise shuffles
    several times the size). Their rows then pack nothing of their own."""
    widths: dict[int, list[dict]] = {}
    for row in rows:
        if row["start"] % 8 == 0 and row["length"] % 8 == 0 and row["length"] >= 16:
            widths.setdefault(row["length"], []).append(row)
    loops = []
    for width, fields in sorted(widths.items()):
        if len(fields) < 2:
            continue
        for row in fields:
            row["pack"] = []
        loops.append({"bytes": width // 8, "fields": [(row["start"] // 8, row["name"]) for row in fields]})
    return loops


def _unpack_lines(start: int, length: int, raw: str) -> list[str]:
    """The statements that gather a field's bits from ``src_p`` into the uint32_t ``raw``."""
    terms = []
    for byte in range(start // 8, (start + length - 1) // 8 + 1):
        offset = start - 8 * byte
        if offset >= 0:
            mask = ((1 << min(length, 8 - offset)) - 1) << offset
            term = f"(uint32_t)src_p[{byte}]" if mask == 0xFF else f"(uint32_t)(src_p[{byte}] & 0x{mask:02x}u)"
            terms.append(f"{term} >> {offset}u" if offset else term)
        else:
            mask = (1 << min(8, length + offset)) - 1
            term = f"(uint32_t)src_p[{byte}]" if mask == 0xFF else f"(uint32_t)(src_p[{byte}] & 0x{mask:02x}u)"
            terms.append(f"{term} << {-offset}u")
    return [f"{raw} = {terms[0]};"] + [f"{raw} |= {t};" for t in terms[1:]]


def signal_row(signal, real: str, tag: str | None = None) -> dict:
    """One signal of a layout as the templates use it; ``tag``: the joint of the frame it was
    read from, for a layout every joint's frames share (its comments then speak of no joint)."""
    length, signed = signal.length, signal.is_signed
    if length > 32:
        raise ModelError(f"signal {signal.name}: {length} bits — the generated codec handles up to 32")
    if signal.byte_order != "little_endian" or signal.is_float:
        raise ModelError(f"signal {signal.name}: the generated codec handles little-endian integer signals only")
    c = ctype(length, signed)
    field_low, field_high = raw_range(length, signed)
    type_low, type_high = _type_range(c)
    ranged = signal.minimum is not None and signal.maximum is not None
    low, high = raw_bounds(signal, signal.minimum, signal.maximum) if ranged else (field_low, field_high)
    lit = lambda value: rendering.literal(float(value), real)  # noqa: E731
    scale, offset = float(signal.conversion.scale), float(signal.conversion.offset)
    raw = f"{signal.name}_raw"
    sign_bit = (
        f"if (({raw} & 0x{1 << (length - 1):x}u) != 0u) {{ {raw} |= 0x{(0xFFFFFFFF << length) & 0xFFFFFFFF:x}u; }}"
    )
    return {
        "name": signal.name,
        "ctype": c,
        "start": signal.start,
        "length": length,
        "signed": signed,
        "unit": signal.unit or "",
        "comment": _shared_comment(signal.comment or signal.name, tag).replace("*/", "* /"),
        "scale": None if scale == 1.0 else lit(scale),
        "offset": None if offset == 0.0 else lit(offset),
        "scale_text": f"{scale:g}",
        "offset_text": f"{offset:g}",
        "divisor": lit(scale),
        "subtrahend": lit(offset),
        "minimum": lit(signal.minimum) if ranged else None,
        "maximum": lit(signal.maximum) if ranged else None,
        "range_text": f"[{signal.minimum:g}, {signal.maximum:g}]" if ranged else "none (the field's)",
        # encode: the rounded quotient below raw_below (a power of two, exact in float) is the
        # raw minimum, from raw_above on the raw maximum
        "raw_below": _whole(field_low, real),
        "raw_above": _whole(field_high + 1, real),
        "raw_min": c_int(field_low, c),
        "raw_max": c_int(field_high, c),
        # is_in_range: only the comparisons the C type does not make always true
        "in_range_min": c_int(low, c) if low > type_low else None,
        "in_range_max": c_int(high, c) if high < type_high else None,
        "pack": _pack_lines(signal.name, signal.start, length, raw),
        "unpack": _unpack_lines(signal.start, length, raw),
        "sign_extend": sign_bit if signed and length not in (8, 16, 32) else None,
    }


def _joint_tag(message: str, layout: str) -> str | None:
    """The joint tag a per-joint frame's name ends with (``None`` for a frame of its own)."""
    return message[len(layout) + 1 :] if message.lower() != layout else None


def _shared_comment(comment: str, tag: str | None) -> str:
    return comment if tag is None else re.sub(rf"\bjoint {re.escape(tag)}\b", "the joint", comment, flags=re.I)


def layouts(db, joints: list[str], real: str) -> tuple[list[dict], dict[str, str]]:
    """The frame layouts of the bus, in the order of their first frame (by identifier), and the
    layout of every frame; frames of one layout must have the same length and signals."""
    rows: dict[str, dict] = {}
    keys: dict[str, tuple] = {}
    of: dict[str, str] = {}
    for m in sorted(db.messages, key=lambda m: m.frame_id):
        name = layout_name(m.name, joints)
        signals = sorted(m.signals, key=lambda s: s.start)
        key = (m.length,) + tuple(
            (s.name, s.start, s.length, s.is_signed, s.conversion.scale, s.conversion.offset, s.minimum, s.maximum)
            for s in signals
        )
        if name in keys and keys[name] != key:
            raise ModelError(
                f"frame {m.name}: layout {name!r} differs from its other frames (design/network/protocol.py)"
            )
        if name not in rows:
            keys[name] = key
            rows[name] = {
                "name": name,
                "NAME": name.upper(),
                "length": m.length,
                "signals": [signal_row(s, real, _joint_tag(m.name, name)) for s in signals],
                "byte_loops": [],
                "frames": [],
                "sent": False,
                "received": False,
            }
        rows[name]["frames"].append(m.name)
        of[m.name] = name
    for row in rows.values():
        row["byte_loops"] = _byte_loops(row["signals"])
    return list(rows.values()), of
