"""The generated CAN codec (cantools' shape): raw pack/unpack bit-exact with cantools, encode and
decode in the build's scalar type (the double build exact with cantools, the float build exact
with a float32 model of the same formula), size errors, is_in_range against the DBC, one struct
per layout, and a float image on the target without any double-precision routine."""

from __future__ import annotations

import math
import re
import shutil
import subprocess
import zlib
from pathlib import Path

import numpy as np
import pytest

from smartjoint.bench import firmware
from smartjoint.codegen import can_codec
from smartjoint.common import law_registry
from smartjoint.design.control import artifact

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "firmware" / "generated" / "controller.json"
KINDS = ("JOINT_A1", "TIP_SENSORS", "SETPOINTS_A1_A3", "AMP_STATUS_A1", "CONTROLLER_STATUS")
COUNT = 100_000
EINVAL = can_codec.EINVAL


@pytest.fixture(scope="module")
def reference():
    return artifact.load(REFERENCE)


@pytest.fixture(scope="module")
def images(reference):
    return {real: firmware.Firmware(reference, "siso", real) for real in ("float", "double")}


def _raw_range(signal):
    return can_codec.raw_range(signal.length, signal.is_signed)


def _values(signal, count, rng):
    """Random physical values: inside the range, on its edges, beyond it (clamped), NaN."""
    if signal.minimum is not None:
        low, high = float(signal.minimum), float(signal.maximum)
    else:
        raw_min, raw_max = _raw_range(signal)
        low, high = raw_min * signal.scale + signal.offset, raw_max * signal.scale + signal.offset
    values = rng.uniform(low, high, count)
    values[::97] = low
    values[1::97] = high
    span = high - low
    values[2::89] = rng.uniform(high, high + span, values[2::89].size)
    values[3::89] = rng.uniform(low - span, low, values[3::89].size)
    if signal.length > 1:
        values[4::1009] = np.nan
    return values


def _raws(signal, count, rng):
    """Random raw values over the whole field, its extremes included."""
    low, high = _raw_range(signal)
    raws = rng.integers(low, high, count, endpoint=True)
    raws[::101] = low
    raws[1::101] = high
    return raws


def _cantools_expected(signal, value):
    """The physical value cantools must encode to give the documented raw value."""
    if math.isnan(value):
        return signal.offset  # NaN encodes as raw 0
    if signal.minimum is not None:
        return min(max(value, signal.minimum), signal.maximum)
    raw_min, raw_max = _raw_range(signal)  # no range in the DBC: kept within the field
    return min(max(value, raw_min * signal.scale + signal.offset), raw_max * signal.scale + signal.offset)


def _float_encode(signal, values):
    """The float build's encode, in numpy float32: NaN → 0, clamp, (v − offset)/scale rounded half
    to even, kept within the field."""
    f32 = np.float32
    v = np.asarray(values, dtype=np.float64).astype(f32)
    if signal.minimum is not None:
        low, high = f32(signal.minimum), f32(signal.maximum)
        v = np.where(v < low, low, np.where(v > high, high, v))
    q = np.rint((v - f32(signal.offset)) / f32(signal.scale))
    q = np.where(np.isnan(q), f32(0.0), q)
    raw_min, raw_max = _raw_range(signal)
    out = np.empty(q.shape, dtype=np.int64)
    below, above = q < f32(raw_min), q >= f32(raw_max + 1)
    inside = ~(below | above)
    out[below], out[above] = raw_min, raw_max
    out[inside] = q[inside].astype(np.int64)
    return out


def _float_decode(signal, raws):
    value = np.asarray(raws, dtype=np.int64).astype(np.float32)
    if signal.scale != 1:
        value = value * np.float32(signal.scale)
    if signal.offset != 0:
        value = value + np.float32(signal.offset)
    return value


@pytest.mark.parametrize("kind", KINDS)
def test_raw_pack_and_unpack_are_bit_exact_with_cantools(images, kind):
    """10⁵ random raw values per signal over its whole field: pack gives cantools' encoding of
    the raw values; unpack of 10⁵ random payloads gives cantools' raw decoding (both builds
    share this code: it holds no scalar type)."""
    image = images["float"]
    m = image.db.get_message_by_name(kind)
    rng = np.random.default_rng(zlib.crc32(kind.encode()))
    columns = {s.name: _raws(s, COUNT, rng) for s in m.signals}
    for k in range(COUNT):
        raw = {name: int(column[k]) for name, column in columns.items()}
        assert image.pack_raw(kind, raw) == m.encode(raw, scaling=False, strict=False), (kind, raw)
    for payload in rng.integers(0, 256, (COUNT, m.length), dtype=np.uint8):
        data = payload.tobytes()
        assert image.unpack_raw(kind, data) == m.decode(data, decode_choices=False, scaling=False), kind


@pytest.mark.parametrize("kind", KINDS)
def test_double_build_encodes_and_decodes_as_cantools(images, kind):
    """10⁵ random physical values per signal (in range, on its edges, beyond it, NaN): the
    double build packs what cantools encodes after the documented clamping (NaN as raw 0,
    beyond the range its end, without a range the field's end), and unpacks random payloads
    exactly as cantools decodes them."""
    image = images["double"]
    m = image.db.get_message_by_name(kind)
    rng = np.random.default_rng(zlib.crc32(kind.encode()) + 1)
    columns = {s.name: _values(s, COUNT, rng) for s in m.signals}
    for k in range(COUNT):
        values = {name: float(column[k]) for name, column in columns.items()}
        expected = {s.name: _cantools_expected(s, values[s.name]) for s in m.signals}
        assert image.pack(kind, values) == m.encode(expected, strict=False), (kind, values)
    for payload in rng.integers(0, 256, (COUNT, m.length), dtype=np.uint8):
        data = payload.tobytes()
        theirs = m.decode(data, decode_choices=False)
        assert image.unpack(kind, data) == {name: float(value) for name, value in theirs.items()}, kind


@pytest.mark.parametrize("kind", KINDS)
def test_float_build_encodes_and_decodes_in_float(images, kind):
    """The float build computes encode and decode in float (no double routine on the target):
    10⁵ physical values per signal encode exactly as the float32 model of the same formula, and
    10⁵ raw values decode as it; the encoding stays within what float resolves of cantools'."""
    image = images["float"]
    m = image.db.get_message_by_name(kind)
    rng = np.random.default_rng(zlib.crc32(kind.encode()) + 2)
    for s in m.signals:
        layout = f"smartjoint_can_{can_codec.layout_name(m.name, list(image.artifact.joint_names))}"
        encode = getattr(image.lib, f"{layout}_{s.name}_encode")
        decode = getattr(image.lib, f"{layout}_{s.name}_decode")
        values = _values(s, COUNT, rng)
        ours = np.array([encode(float(v)) for v in values])
        np.testing.assert_array_equal(ours, _float_encode(s, values), err_msg=f"{kind}.{s.name}")
        exact = np.array([s.conversion.scaled_to_raw(_cantools_expected(s, float(v))) for v in values])
        resolution = np.fmax(np.abs(values.astype(np.float32)).astype(np.float64), 1.0) * 2.0**-22 / s.scale
        assert np.all(np.abs(ours - exact) <= resolution + 1), f"{kind}.{s.name}"
        raws = _raws(s, COUNT, rng)
        decoded = np.array([decode(int(r)) for r in raws], dtype=np.float32)
        np.testing.assert_array_equal(decoded, _float_decode(s, raws), err_msg=f"{kind}.{s.name}")


def test_pack_and_unpack_refuse_short_buffers_and_null(images):
    """A destination or source shorter than the frame (or NULL): -EINVAL and nothing written; a
    longer one: the frame's length, the bytes beyond it untouched."""
    image = images["float"]
    ffi, lib = image.ffi, image.lib
    joints = list(image.artifact.joint_names)
    for m in image.db.messages:
        layout = f"smartjoint_can_{can_codec.layout_name(m.name, joints)}"
        pack, unpack = getattr(lib, f"{layout}_pack"), getattr(lib, f"{layout}_unpack")
        raw = ffi.new(f"struct {layout}_t *")
        buffer = ffi.new("uint8_t[]", [0xA5] * (m.length + 4))
        for size in (0, 1, m.length - 1):
            assert pack(buffer, raw, size) == -EINVAL, (m.name, size)
            assert unpack(raw, buffer, size) == -EINVAL, (m.name, size)
        assert bytes(ffi.buffer(buffer)) == bytes([0xA5] * (m.length + 4))
        assert pack(ffi.NULL, raw, m.length) == -EINVAL and pack(buffer, ffi.NULL, m.length) == -EINVAL
        assert unpack(ffi.NULL, buffer, m.length) == -EINVAL and unpack(raw, ffi.NULL, m.length) == -EINVAL
        assert pack(buffer, raw, m.length + 4) == m.length
        assert bytes(ffi.buffer(buffer))[m.length :] == bytes([0xA5] * 4)
        assert unpack(raw, buffer, m.length + 4) == m.length


@pytest.mark.parametrize("kind", KINDS)
def test_is_in_range_follows_the_dbc(images, kind):
    """is_in_range(raw) is whether cantools decodes the raw value within the signal's DBC
    [minimum, maximum]; without a range, whether the field carries it: at the bounds and for
    random raw values over the whole C type."""
    image = images["float"]
    m = image.db.get_message_by_name(kind)
    rng = np.random.default_rng(zlib.crc32(kind.encode()) + 3)
    layout = f"smartjoint_can_{can_codec.layout_name(m.name, list(image.artifact.joint_names))}"
    for s in m.signals:
        in_range = getattr(image.lib, f"{layout}_{s.name}_is_in_range")
        width = int(re.search(r"\d+", can_codec.ctype(s.length, s.is_signed)).group())
        type_low, type_high = can_codec.raw_range(width, s.is_signed)
        field_low, field_high = _raw_range(s)
        raws = list(rng.integers(type_low, type_high, 2000, endpoint=True))
        if s.minimum is not None:
            low, high = can_codec.raw_bounds(s, s.minimum, s.maximum)
            raws += [low - 1, low, low + 1, high - 1, high, high + 1]
        raws += [field_low, field_high, type_low, type_high]
        for raw in (int(r) for r in raws if type_low <= r <= type_high):
            if s.minimum is None:
                expected = field_low <= raw <= field_high
            else:
                expected = s.minimum <= s.conversion.raw_to_scaled(raw, decode_choices=False) <= s.maximum
            assert bool(in_range(raw)) == expected, (kind, s.name, raw)


def test_one_struct_of_raw_fields_per_layout(images):
    """The header declares one struct per frame layout (the joints' frames share theirs), each
    field the raw integer type of its signal's length and sign, and no per-frame struct."""
    image = images["float"]
    header = image.files["smartjoint_can.h"]
    structs = dict(re.findall(r"struct smartjoint_can_(\w+)_t \{\n(.*?)\n\};", header, re.S))
    assert sorted(structs) == ["amp_status", "controller_status", "joint", "setpoints_a1_a3", "tip_sensors"]
    joints = list(image.artifact.joint_names)
    for m in image.db.messages:
        body = structs[can_codec.layout_name(m.name, joints)]
        fields = dict((name, c) for c, name in re.findall(r"^\s+(u?int\d+_t) (\w+);", body, re.M))
        assert fields == {s.name: can_codec.ctype(s.length, s.is_signed) for s in m.signals}, m.name
    assert "double" not in "".join(structs.values())
    assert len(re.findall(r"^int smartjoint_can_\w+_pack\(", header, re.M)) == len(structs)


TARGET = ["-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard"]


@pytest.mark.skipif(
    shutil.which("arm-none-eabi-gcc") is None, reason="arm-none-eabi-gcc (GNU Arm toolchain) not on PATH"
)
def test_float_image_links_no_double_routine(reference, tmp_path):
    """The float firmware (controllers + CAN layer + E2E) linked for the Cortex-M4F from the CAN
    entry points (-O2, --gc-sections) holds no double-precision routine of libgcc or libm."""
    files = firmware.sources(reference, "float")
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    sources = [f"{law.c_name('smartjoint')}.c" for law in law_registry.LAWS.values()] + ["smartjoint_can.c", "sj_e2e.c"]
    flags = ["-std=c99", "-O2", "-ffp-contract=off", "-ffunction-sections", "-fdata-sections", "-Wall", "-Werror"]
    entries = [f"smartjoint_can_{e}" for e in ("init", "rx", "step", "tx")]
    subprocess.run(
        ["arm-none-eabi-gcc", *TARGET, *flags, "--specs=nano.specs", "-nostartfiles", "-Wl,--gc-sections"]
        + [f"-Wl,--entry={entries[0]}"]
        + [f"-Wl,--undefined={e}" for e in entries[1:]]
        + sources
        + ["-lm", "-o", "image.elf"],
        cwd=tmp_path,
        check=True,
    )
    symbols = subprocess.run(
        ["arm-none-eabi-nm", "image.elf"], cwd=tmp_path, capture_output=True, text=True, check=True
    )
    names = [line.split()[-1] for line in symbols.stdout.splitlines()]
    assert all(e in names for e in entries)
    doubles = [
        n for n in names if n.startswith("__aeabi_d") or re.match(r"^__(add|sub|mul|div|extendsf|truncdf)\w*df", n)
    ]
    assert doubles == []
