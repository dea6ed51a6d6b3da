"""CAN protocol pieces: E2E protection (CRC-8 SAE J1850, alive counter) in Python and C, the DBC
generated from the controller artefact, and the worst-case bus load."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import SLIP_RATIO_LAW

from smartjoint.bench import e2e
from smartjoint.common.errors import ModelError
from smartjoint.design.control import artifact
from smartjoint.design.network import busload, protocol

REFERENCE = Path(__file__).resolve().parents[1] / "firmware" / "generated" / "controller.json"
# AUTOSAR "Specification of CRC Routines", CRC8 SAE J1850 check table.
VECTORS = [
    (b"\x00\x00\x00\x00", 0x59),
    (b"\xf2\x01\x83", 0x37),
    (b"\x0f\xaa\x00\x55", 0x79),
    (b"\x00\xff\x55\x11", 0xB8),
    (b"\x33\x22\x55\xaa\xbb\xcc\xdd\xee\xff", 0xCB),
    (b"\x92\x6b\x55", 0x8C),
    (b"\xff\xff\xff\xff", 0x74),
    (b"123456789", 0x4B),
]


@pytest.fixture(scope="module")
def runtime():
    return e2e.compiled()


@pytest.mark.parametrize("data, crc", VECTORS)
def test_crc8_j1850_vectors_in_python_and_c(runtime, data, crc):
    assert e2e.crc8(data) == crc
    assert runtime.lib.sj_crc8_j1850(data, len(data), 0xFF) ^ 0xFF == crc


def test_frame_crc_and_protection_agree_between_c_and_python(runtime):
    ffi, lib = runtime.ffi, runtime.lib
    rng = np.random.default_rng(5)
    for _ in range(20000):
        length = int(rng.integers(2, 65))
        frame_id = int(rng.integers(0, 0x800))
        payload = bytearray(rng.integers(0, 256, length, dtype=np.uint8).tobytes())
        counter = int(rng.integers(0, 16))
        fresh = int(rng.integers(0, 256))
        expected = e2e.protect(frame_id, bytearray(payload), counter, fresh)
        buffer = ffi.new("uint8_t[]", bytes(payload))
        lib.sj_e2e_protect(frame_id, buffer, length, counter, fresh)
        assert bytes(ffi.buffer(buffer, length)) == bytes(expected)
        assert lib.sj_e2e_frame_crc(frame_id, bytes(expected), length, fresh) == expected[0]
        assert e2e.freshness_of(frame_id, expected) == fresh


def test_a_frame_of_another_cycle_16_to_4095_cycles_away_fails_its_crc(runtime):
    """The freshness byte (bits 4-11 of the frame's cycle) is in the CRC but not on the wire: every
    one of its 255 wrong values changes the CRC (a difference within 8 adjacent bits, which a
    CRC-8 with x^0 always detects), so a frame read as 0..15 cycles old that is really 16..4095
    older fails, whatever its payload. Exhaustive over the wrong bytes, for random payloads."""
    rng = np.random.default_rng(11)
    for _ in range(50):
        payload = e2e.protect(0x101, bytearray(rng.integers(0, 256, 12, dtype=np.uint8).tobytes()), 3, 0x5A)
        assert e2e.check(0x101, payload, None, 0x5A).crc_ok
        assert sum(e2e.check(0x101, payload, None, f).crc_ok for f in range(256)) == 1
        assert runtime.lib.sj_e2e_check(runtime.ffi.new("sj_e2e_receiver *"), 0x101, bytes(payload), 12, 12, 0x5B) == 2
    heartbeat = 0x7A3  # the newest cycle the receiver knows
    for age in range(4096):  # a node frame echoing heartbeat - age, read back by its 4-bit echo
        sent = (heartbeat - age) % e2e.CYCLE_MODULO
        read = e2e.echoed_cycle(heartbeat, sent % 16)
        assert (e2e.freshness(read) == e2e.freshness(sent)) == (age < 16), age


def test_every_single_bit_error_and_a_wrong_identifier_are_detected(runtime):
    payload = e2e.protect(0x101, bytearray(range(12)), 5)
    for bit in range(8 * len(payload)):
        flipped = bytearray(payload)
        flipped[bit // 8] ^= 1 << (bit % 8)
        assert not e2e.check(0x101, flipped, None).crc_ok
    assert not e2e.check(0x102, payload, None).crc_ok  # same bytes under another identifier


def test_alive_counter_policy_is_the_same_in_c_and_python(runtime):
    """Steps 1…3 pass; a repeat and a stale frame (8…15 ahead, i.e. behind) are rejected and not
    followed; a jump of 4…7 is rejected and the sequence restarts there."""
    ffi, lib = runtime.ffi, runtime.lib
    receiver = ffi.new("sj_e2e_receiver *")
    last = None
    rng = np.random.default_rng(2)
    counter = 0
    seen = set()
    for k in range(4000):
        counter = (counter + int(rng.choice([0, 1, 1, 1, 2, 3, 4, 6, 9, 13]))) % 16
        payload = e2e.protect(0x180, bytearray(12), counter)
        if k % 97 == 0:
            payload[5] ^= 0x10  # corrupted on the wire
        python = e2e.check(0x180, payload, last)
        status = lib.sj_e2e_check(receiver, 0x180, bytes(payload), len(payload), 12, 0)
        expected = {"ok": 0, "crc": 2, "counter repeated": 4, "counter jump": 8, "counter stale": 32}[python.reason]
        assert status == expected, (k, status, python)
        assert (status == 0) == python.ok
        seen.add(python.reason)
        if python.resynchronises:
            last = python.counter
    assert seen == {"ok", "crc", "counter repeated", "counter jump", "counter stale"}
    assert lib.sj_e2e_check(receiver, 0x180, bytes(12), 8, 12, 0) == 1  # wrong length


@pytest.fixture(scope="module")
def reference():
    return artifact.load(REFERENCE)


def test_dbc_is_generated_from_the_artefact_and_round_trips(reference):
    db = protocol.database(reference)
    text = protocol.dbc_text(db)
    again = protocol.load_dbc(text)
    assert protocol.dbc_text(again) == text
    names = {m.name: m for m in again.messages}
    for j, joint in enumerate(reference.joint_names):
        joint_frame = names[f"JOINT_{joint.upper()}"]
        assert joint_frame.frame_id == 0x100 + j and joint_frame.is_fd and joint_frame.cycle_time == 1
        assert (
            names[f"SETPOINT_{joint.upper()}"].cycle_time == 1 and names[f"AMP_STATUS_{joint.upper()}"].cycle_time == 1
        )
        # the frames the controller reads echo its heartbeat: it ages them by that (docs/safety.md)
        assert joint_frame.get_signal_by_name("sync").length == 4
        assert names[f"AMP_STATUS_{joint.upper()}"].get_signal_by_name("sync").length == 4
    assert names["CONTROLLER_STATUS"].cycle_time == 1  # the heartbeat, every cycle
    tip = names["TIP_SENSORS"]
    assert [s.name for s in tip.signals][3:] == [s.lower() for s in reference.sensor_names]
    assert tip.get_signal_by_name("sync").start == 12
    for message in again.messages:  # every frame starts with the E2E bytes
        assert message.get_signal_by_name("crc").start == 0 and message.get_signal_by_name("counter").start == 8
    frame = names["JOINT_A1"]
    decoded = frame.decode(
        frame.encode(
            {
                "crc": 0,
                "counter": 3,
                "sync": 5,
                "sliding_velocity": 1.234567891e-3,
                "friction_force": -123.45678,
                "normal_force": 399.98,
            }
        )
    )
    assert decoded["sliding_velocity"] == pytest.approx(1.234567891e-3, abs=1e-9)
    assert decoded["friction_force"] == pytest.approx(-123.45678, abs=1e-5)


def test_protocol_refuses_what_it_cannot_carry(reference):
    import dataclasses

    with pytest.raises(ModelError, match="joint_names.*not a valid"):
        protocol.database(dataclasses.replace(reference, joint_names=("A 1", "A2", "A3")))
    with pytest.raises(ModelError, match="sample_time.*whole milliseconds"):
        protocol.database(dataclasses.replace(reference, sample_time=2.5e-4))


def test_bus_load_worst_case_frames_and_the_limit(reference):
    assert busload.classical_bits(8) == 135 and busload.classical_bits(0) == 55  # Davis et al. 2007
    assert busload.fd_bits(12) == (34, 5 + 96 + 25 + 4 + 17 + 6)
    db = protocol.database(reference)
    fast = busload.bus_load(db, 1_000_000, 5_000_000)
    slow = busload.bus_load(db, 1_000_000, 2_000_000)
    assert 0 < fast.load < slow.load
    by_hand = sum(
        (34 / 1e6 + busload.fd_bits(m.length)[1] / 5e6 if m.is_fd else 34 / 1e6 + busload.fd_bits(m.length)[1] / 5e6)
        / (m.cycle_time / 1e3)
        for m in db.messages
    )
    assert fast.load == pytest.approx(by_hand, rel=1e-12)
    assert busload.check(db, 1_000_000, 5_000_000).load == fast.load
    assert fast.load == pytest.approx(0.6426, abs=5e-4)  # docs/can.md: 64.3 % with the heartbeat every cycle
    with pytest.raises(ModelError, match=r"exceeds the limit 70 %; it fits at CAN FD 1/5 Mbit/s, CAN FD 1/8 Mbit/s"):
        busload.check(db, 1_000_000, 2_000_000)
    with pytest.raises(ModelError, match=r"no standard bitrate carries it — lengthen the sample time"):
        busload.check(db, 500_000, 2_000_000)
    with pytest.raises(ModelError, match="classical CAN"):
        busload.check(db, 1_000_000)
    with pytest.raises(ModelError, match="bitrate"):
        busload.bus_load(db, 12)


def _small_artifact(velocity_limit=None):
    """The artefact of the small truss: tip_y a displacement, tip_vz a velocity."""
    from conftest import small_truss

    from smartjoint.design import control, parse_design
    from smartjoint.design.control import artifact_building
    from smartjoint.design.structure import modal
    from smartjoint.design.structure.fem import build_model

    data = small_truss()
    if velocity_limit is not None:
        data["safety"] = {"velocity_limit": velocity_limit}
    design = parse_design(data)
    fe = build_model(design, joints="released")
    model = modal.modal_model(fe, modal.solve_modes(fe, 8))
    lqg = control.design_lqg(model, design.control.sample_time)
    return artifact_building.from_design(
        design, model, lqg, {"siso": {"boundary_layer": 1e-3}, "slipratio": SLIP_RATIO_LAW}
    )


def test_tip_sensor_signals_carry_the_unit_and_range_of_their_quantity():
    import can

    from smartjoint.bench import logs
    from smartjoint.codegen import can_layer

    built = _small_artifact()
    assert built.sensor_quantities == ("displacement", "velocity")
    tip = protocol.load_dbc(protocol.dbc_text(protocol.database(built))).get_message_by_name("TIP_SENSORS")
    shown = {s.name: (s.unit, s.minimum, s.maximum) for s in tip.signals[3:]}
    assert shown == {"tip_y": ("m", -20.0, 20.0), "tip_vz": ("m/s", -10.0, 10.0)}
    header = can_layer.render_can(built)["smartjoint_can.h"]
    assert "sensor tip_y [m];" in header and "sensor tip_vz [m/s];" in header
    values = {"crc": 0, "counter": 1, "sync": 0, "tip_y": 1e-3, "tip_vz": -0.25}
    payload = e2e.protect(tip.frame_id, bytearray(tip.encode(values)), 1)
    decoded = logs.decode(
        [can.Message(arbitration_id=tip.frame_id, data=payload, is_fd=True)], protocol.database(built)
    )
    assert {row[2]: row[3] for row in decoded.rows[3:]} == pytest.approx({"tip_y": 1e-3, "tip_vz": -0.25}, abs=1e-8)
    assert decoded.units[("TIP_SENSORS", "tip_y")] == "m" and decoded.units[("TIP_SENSORS", "tip_vz")] == "m/s"
    # A velocity limit beyond what the frame carries would never trip: refused before rendering.
    with pytest.raises(ModelError, match=r"sensor_limit\[1\]: 15.0 for sensor 'tip_vz'.*up to 10"):
        can_layer.check_can(_small_artifact(velocity_limit=15.0), protocol.Amplifier())


def test_a_logs_freshness_follows_its_heartbeats_and_refuses_a_replayed_one():
    """``e2e.LogFreshness`` reads every frame of a log at its cycle: node frames by the heartbeat
    they echo, the controller's by their counter, the cycle running on with the time stamps; a
    heartbeat replayed 20 cycles old fails and does not move the cycle, so the genuine frames
    around it still pass."""
    fresh = e2e.LogFreshness(echoes={0x101}, sample_time=1e-3)

    def heartbeat(cycle):
        payload = bytearray(8)
        payload[e2e.HEARTBEAT_CYCLE_BYTE] = e2e.freshness(cycle)
        return e2e.protect(e2e.HEARTBEAT_ID, payload, cycle, e2e.freshness(cycle))

    def joint(echoed):
        payload = bytearray(12)
        payload[1] = (echoed & 0x0F) << 4
        return e2e.protect(0x101, payload, echoed, e2e.freshness(echoed))

    passed = []
    for cycle in range(1, 120):
        t = cycle * 1e-3
        passed.append(fresh.crc_ok(0x101, joint(cycle - 1), t))  # sampled after the last heartbeat
        passed.append(fresh.crc_ok(0x200, e2e.protect(0x200, bytearray(6), cycle, e2e.freshness(cycle)), t))
        sent = cycle - 20 if 50 <= cycle < 60 else cycle
        assert fresh.crc_ok(e2e.HEARTBEAT_ID, heartbeat(sent), t) == (sent == cycle), cycle
    assert all(passed) and len(passed) == 238
    # …and a node frame that echoes a heartbeat 16 or more cycles back does not.
    assert not fresh.crc_ok(0x101, joint(100), 0.120)
