"""The firmware's CAN layer and the SIL bench on the buses of a network plan (issue 33): packed
SETPOINTS frames packed in C bit for bit as cantools packs them, every frame on its bus, each bus
supervised on its own (bus-off on one bus makes only its joints safe under a per-joint law), and
the fault-free run on two buses bit for bit the one-bus run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import quiet_joint_frame, run_cli, small_study

from smartjoint.bench import e2e, firmware, logs, safety, sil
from smartjoint.bench.amplifier import SILENT_FAULTS
from smartjoint.bench.fault_scope import FaultScope
from smartjoint.bench.faults import Fault
from smartjoint.bench.loop import SilLoop
from smartjoint.bench.replay import replay
from smartjoint.common.errors import ModelError
from smartjoint.design.control import artifact
from smartjoint.design.control import study as closed_loop
from smartjoint.design.network.plan import plan
from smartjoint.design.plant.interface import Measurements
from smartjoint.design.structure.description import Bus, Network

ROOT = Path(__file__).resolve().parents[1]
TWO = Network((Bus("can0"), Bus("can1")))
LOCAL_TWO = Network((Bus("can0"), Bus("can1")), siso="local")  # NODE_STATUS_<j> frames on the buses too


@pytest.fixture(scope="module")
def reference():
    return artifact.load(ROOT / "firmware" / "generated" / "controller.json")


@pytest.fixture(scope="module")
def small():
    return small_study()


def test_the_packed_setpoints_frame_packs_and_unpacks_as_cantools_in_the_double_build(reference):
    """SETPOINTS_A1_A3 of the bundled one-bus plan: the generated codec against cantools on raw
    values, and the frame the layer sends decodes to the setpoints of its commands."""
    packed = plan(reference)
    fw = firmware.Firmware(reference, "siso", "double", network=packed)
    frame = fw.db.get_message_by_name("SETPOINTS_A1_A3")
    rng = np.random.default_rng(7)
    for _ in range(2000):
        raw = {s.name: int(rng.integers(0, 2**s.length)) for s in frame.signals}
        data = fw.pack_raw(frame.name, raw)
        assert data == bytes(frame.encode(raw, scaling=False, strict=False))
        assert fw.unpack_raw(frame.name, data) == raw
    fw.step(0)
    sent = fw.tx_bus()
    assert [(b, i) for b, i, _ in sent] == [(0, frame.frame_id), (0, 0x080)]
    data = sent[0][2]
    assert e2e.check(frame.frame_id, data, None).crc_ok
    volts = frame.decode(data, decode_choices=False)
    for j, tag in enumerate(("a1", "a2", "a3")):  # the safe force at power-up, over the gain
        expected = fw.unpack(frame.name, fw.pack(frame.name, {f"voltage_{tag}": fw.command[j] / 8.0}))
        assert volts[f"voltage_{tag}"] == expected[f"voltage_{tag}"]


def test_every_frame_goes_to_and_comes_from_its_bus(small):
    """Two buses: the setpoint and heartbeat of each bus on it; a joint's frame on the other bus is
    an unknown identifier; the caller's bus-off report is checked."""
    _, a = small
    two = plan(a, TWO)
    fw = firmware.Firmware(a, "siso", "double", network=two)
    fw.step(0)
    expected = []
    for b, p in enumerate(two.buses):
        ids = sorted(m.frame_id for m in p.database.messages if m.senders == ["CONTROLLER"] and m.frame_id != 0x080)
        expected += [(b, i) for i in ids] + [(b, 0x080)]
    assert [(b, i) for b, i, _ in fw.tx_bus()] == expected
    joint_b = fw.db.get_message_by_name(f"JOINT_{two.buses[1].joints[0].upper()}")
    assert fw.rx(joint_b.frame_id, bytes(quiet_joint_frame(joint_b, 1)), 0, bus=0) == 16  # unknown on bus 0
    assert fw.rx(joint_b.frame_id, bytes(quiet_joint_frame(joint_b, 1)), 0, bus=1) == 0
    with pytest.raises(ModelError, match="bus: 2"):
        fw.bus_off(2)


def _run(small, law, network, faults=(), channel="multi-bus"):
    setup, a = small
    fw = firmware.Firmware(a, law, "double", network=None if network is None else plan(a, network))
    loop = SilLoop(fw, closed_loop.PULSE_DURATION, faults=faults, channel=channel)
    return loop, sil.run_loop(setup, loop)


def test_two_buses_without_faults_run_bit_for_bit_as_one_bus(small):
    """Only the frames' assignment differs: the same law on the same numbers."""
    one, r1 = _run(small, "siso", None, channel="multi-one")
    two, r2 = _run(small, "siso", TWO, channel="multi-two")
    assert np.array_equal(np.array(one.record.command), np.array(two.record.command))
    assert np.array_equal(r1.energy, r2.energy) and not any(two.record.safe)
    s = two.statistics(0.2, 1_000_000, 5_000_000)
    assert [b["frames_total"] for b in s["buses"]] == [1000, 800] and s["e2e_errors"] == 0


@pytest.mark.parametrize("law", ["siso", "clqg"])
def test_bus_off_on_one_bus_makes_only_its_joints_safe_under_a_per_joint_law(small, law):
    """bus_off:can1 for 50 ms: its joint safe within 3 cycles at the firmware and its amplifier,
    recovered after; under the SISO law the joint on can0 runs on, under the cLQG (it estimates the
    whole truss from every joint) every joint holds the safe force."""
    _, a = small
    fault = Fault("bus_off", 0.1, 0.15, "can1")
    loop, result = _run(small, law, TWO, [fault], channel=f"multi-off-{law}")
    bus_safe, amp_safe = np.array(loop.record.bus_safe), np.array(loop.record.amplifier_safe)
    k0, k1 = 100, 150  # the fault's samples at Δt = 1 ms
    assert not bus_safe[:k0].any()
    assert bus_safe[k0 + 2 : k1, 1].all() and not bus_safe[k1 + 6 :, 1].any()
    assert amp_safe[k0 + 3 : k1, 1].all() and not amp_safe[:, 0].any()
    if law == "siso":
        assert not bus_safe[:, 0].any() and not any(loop.record.safe)
        commands = np.array(loop.record.command)
        assert np.all(commands[k0 + 2 : k1, 1] == a.safe_normal_force[1])
    else:
        assert bus_safe[k0 + 2 : k1, 0].all()
    assert np.all(np.isfinite(result.energy))


def test_a_bus_off_fault_names_a_bus_of_the_plan(small):
    _, a = small
    fw = firmware.Firmware(a, "siso", "double", network=plan(a, TWO))
    with pytest.raises(ModelError, match=r"target 'can7' — a bus of the plan \(can0, can1\)"):
        SilLoop(fw, 0.0, faults=[Fault("bus_off", 0.1, 0.2, "can7")])


@pytest.mark.parametrize("law", ["siso", "clqg"])
def test_the_fault_matrix_on_two_buses_stops_what_a_fault_touches_and_nothing_else(small, law):
    """Every case of the matrix on the plan's two buses, each bus also off alone: under the SISO law
    (each joint's own measurements) a fault stops the joints of the buses it touches and the other
    bus runs on; under the cLQG (every joint and the tip sensors) it stops every joint. A claim
    the firmware does not keep fails: can1 off said to stop JA and leave can1 running."""
    _, a = small
    out = safety.fault_matrix(a, law=law, timings=("mid-run",), network=LOCAL_TWO)
    rows = {r["case"]: r for r in out["rows"]}
    assert out["failed"] == [] and out["buses"] == ["can0", "can1"]
    # the joint nodes' status frames of local mode are a supervisor's: the controller must not react
    assert out["unread"] == ["NODE_STATUS_JA", "NODE_STATUS_JB"]
    for kind in ("drop", "corrupt_crc", "silent"):
        row = rows[f"{kind} NODE_STATUS_JB"]
        assert row["scope"] == [] and row["tolerated"] and row["ok"] and row["safe_samples"] == 0
    if law == "siso":
        assert rows["bus_off can1"]["scope"] == ["JB"] and rows["bus_off can0"]["scope"] == ["JA"]
        assert rows["bus_off bus"]["scope"] == ["JA", "JB"] and rows["drop JOINT_JB"]["scope"] == ["JB"]
        assert rows["drop TIP_SENSORS"]["scope"] == [] and rows["drop TIP_SENSORS"]["firmware"] is None
        assert rows["drop CONTROLLER_STATUS"]["scope"] == ["JA", "JB"]  # the heartbeat is on every bus
        assert rows["bus_off can1"]["running"] and rows["bus_off can1"]["joints"] <= safety.DETECTION_LIMIT
    else:
        # every joint stops, except past an amplifier (it reports healthy): named, nothing stops
        silent = [r for r in out["rows"] if r["case"].endswith(SILENT_FAULTS)]
        assert len(silent) == 3 * 2 and all(r["scope"] == [] and r["actuation"]["ok"] for r in silent)
        assert all(r["scope"] is None for r in out["rows"] if "NODE_STATUS" not in r["case"] and r not in silent)
        assert rows["bus_off can1"]["joints"] <= safety.DETECTION_LIMIT
    fw = firmware.Firmware(a, law, "float", network=plan(a, TWO))
    case = next(c for c in safety.cases(a, fw.db, ("mid-run",), ["can0", "can1"]) if c.name == "bus_off can1")
    seen = safety.signals(None, a, case.cycles)
    assert not safety.run_case(fw, case, seen, FaultScope((0,), (True, False), (1,)))["ok"]


def test_a_log_of_several_buses_decodes_and_replays_bit_for_bit(tmp_path, reference):
    """A bench log of the reference firmware on two buses (the log's channel is the plan's bus):
    `bench decode --network` decodes every frame, the heartbeat once per bus; `bench replay
    --network` replays every setpoint bit for bit; read as one bus, the packed setpoints are not
    that protocol's, and with the channels swapped the replay differs."""
    design = tmp_path / "two_buses.toml"
    design.write_text(
        f'base = "{(ROOT / "design" / "data" / "three_type_a.toml").as_posix()}"\n'
        '[[network.buses]]\nname = "can0"\n[[network.buses]]\nname = "can1"\n'
    )
    path = ROOT / "firmware" / "generated" / "controller.json"
    planned = plan(reference, TWO)
    log = tmp_path / "two.blf"
    loop = SilLoop(firmware.Firmware(reference, "clqg", "float", network=planned), 0.0, log_path=log, channel="two-log")
    loop.reset()
    applied = np.zeros(3)
    try:
        for m in safety.signals(None, reference, 120):
            applied = loop.step(Measurements(m.time, m.sensors, m.sliding_velocity, m.friction_force, applied))
    finally:
        loop.close()
    decoded = json.loads(run_cli("bench", "decode", log, "--artifact", path, "--network", design, "--json").stdout)
    frames = sum(len(p.database.messages) for p in planned.buses)
    assert decoded["frames"] == 120 * frames and decoded["frames_skipped"] == 0
    done = run_cli("bench", "decode", log, "--artifact", path, "--network", design, "-o", tmp_path / "s.csv")
    assert done.returncode == 0, done.stderr
    labels = {line.split(",")[1] for line in (tmp_path / "s.csv").read_text().splitlines()[1:]}
    assert {"CONTROLLER_STATUS@can0", "CONTROLLER_STATUS@can1"} <= labels and "CONTROLLER_STATUS" not in labels
    done = run_cli("bench", "replay", log, "--artifact", path, "--network", design, "--law", "clqg", "--json")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["setpoints_compared"] == 120 * 3 and out["differing"] == 0 and out["unknown_id_frames"] == 0
    alone = run_cli("bench", "replay", log, "--artifact", path, "--law", "clqg", "--json")
    # Read as the default plan's one bus (all three setpoints in SETPOINTS_A1_A3): not its protocol.
    assert alone.returncode == 2 and "no recorded setpoint frame" in alone.stderr, alone.stderr
    messages, _ = logs.read(log)
    for m in messages:
        m.channel = 1 - m.channel
    swapped = replay(messages, firmware.Firmware(reference, "clqg", "float", network=planned))
    assert not swapped["ok"]
