"""The firmware's CAN message layer and the SIL bench (the codec: test_can_codec.py): E2E on
receive, timeouts and the safe state under every injected fault, logs and replay."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import cli_error, quiet_joint_frame, run, run_cli

from smartjoint.bench import bus_rounding, e2e, firmware, logs, rounding_spread, sil
from smartjoint.bench.amplifier import SILENT_FAULTS
from smartjoint.bench.faults import Fault, check_faults, parse_fault
from smartjoint.bench.loop import SilLoop, open_bus
from smartjoint.bench.replay import replay
from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control import artifact
from smartjoint.design.control import study as closed_loop
from smartjoint.design.network import plan, protocol

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "firmware" / "generated" / "controller.json"


@pytest.fixture(scope="module")
def reference():
    return artifact.load(REFERENCE)


def test_receive_checks_identifier_length_crc_and_counter(reference):
    fw = firmware.Firmware(reference, "siso", "float")
    m = fw.db.get_message_by_name("JOINT_A1")
    good = quiet_joint_frame(m, 0)
    assert fw.rx(m.frame_id, bytes(good), 0) == 0
    assert fw.rx(0x7FF, bytes(8), 0) == 16  # unknown identifier
    assert fw.rx(m.frame_id, bytes(good[:8]), 0) == 1  # wrong length
    bad = bytearray(good)
    bad[5] ^= 1
    assert fw.rx(m.frame_id, bytes(bad), 0) == 2  # CRC
    assert fw.rx(m.frame_id, bytes(good), 0) == 4  # the same counter again
    c = fw.counters
    assert (c["unknown_ids"], c["length_errors"], c["crc_errors"], c["counter_errors"], c["rx_frames"]) == (
        1,
        1,
        1,
        1,
        1,
    )


@pytest.fixture(scope="module")
def bench(three_type_a, reference):
    design, model = three_type_a
    setup = closed_loop.setup(design, model)
    return dataclasses.replace(setup, duration=0.6), reference


def _run(bench, law, faults=(), log_path=None):
    setup, reference = bench
    loop = SilLoop(
        firmware.Firmware(reference, law, "float"), closed_loop.PULSE_DURATION, faults=faults, log_path=log_path
    )
    return loop, sil.run_loop(setup, loop)


# One of each family with the plant in the loop (every kind on every frame runs without the
# plant in tests/test_safety.py): a lost input, a late one, a damaged one, the firmware's own
# setpoint and heartbeat, an implausible value, amplifier faults, the bus off.
FAULTS = [
    Fault("drop", 0.2, 0.3, "JOINT_A2"),
    Fault("delay", 0.2, 0.3, "JOINT_A1", delay=0.006),
    Fault("corrupt_crc", 0.2, 0.3, "TIP_SENSORS"),
    Fault("drop", 0.2, 0.3, "SETPOINTS_A1_A3"),
    Fault("corrupt_crc", 0.2, 0.3, "CONTROLLER_STATUS"),
    Fault("implausible", 0.2, 0.3, "JOINT_A1", signal="sliding_velocity", value=1.9),
    Fault("amplifier", 0.2, 0.3, "A1", amplifier_fault="over_temperature"),
    Fault("amplifier", 0.2, 0.3, "A3", amplifier_fault="stuck_output"),
    Fault("bus_off", 0.2, 0.3),
]


@pytest.mark.parametrize("fault", FAULTS, ids=lambda f: f.label())
def test_every_injected_fault_reaches_the_safe_state_within_three_cycles_and_recovers(bench, fault):
    """With the plant in the loop: the force each joint's amplifier applies reaches the safe
    force within 3 cycles and holds, the loop recovers after the fault, the energy stays bounded
    (the safe state is passive); the case matrix without the plant is tests/test_safety.py."""
    from smartjoint.bench import safety

    loop, result = _run(bench, "clqg", [fault])
    record = loop.record
    safe = np.array(record.safe)
    row = safety.measure(record, (fault,), bench[1])
    assert not safe[: row["start"]].any()  # nothing before the fault (power-up included)
    assert row["ok"] and row["joints"] <= 3 and row["firmware"] <= 3, row
    assert row["recovery"] <= bench[1].timeout_cycles + bench[1].recovery_cycles + 1, row
    commands = np.array(record.command)
    assert np.all(commands[safe] == bench[1].safe_normal_force)  # the one safe normal force
    k1 = row["end"]
    applied = np.array(record.amplifier_force)  # the amplifiers follow the setpoints again
    assert np.allclose(applied[k1 + 15 :], commands[k1 + 15 :], atol=1e-5)
    after = result.time > closed_loop.PULSE_DURATION
    assert result.energy[after].max() <= result.energy.max() and np.all(np.isfinite(result.energy))


@pytest.mark.parametrize("kind", SILENT_FAULTS)
def test_a_joint_that_gets_less_force_than_driven_is_named_and_the_others_keep_their_law(bench, kind):
    """Issue 37: the joint's amplifier reports healthy (status, monitor voltage as commanded) while
    the joint gets 0 N, half the force or a frozen one. With the plant in the loop under the SISO
    law, from 0.1 s on: the firmware's heartbeat names that joint within 3 cycles of two short
    samples in a row, never another; nothing goes safe, every amplifier keeps taking the law. A
    force frozen high is never short of a command (more force is not judged): it is frozen at a
    sample where the fault-free run commands F_N^min, so the law's next F_N^max shows it."""
    from smartjoint.bench import safety

    start = 0.1
    if kind == "stuck_force":
        free, _ = _run(bench, "siso")
        low = np.array(free.record.command)[:, 1] < 0.5 * (bench[1].normal_force_max[1] + bench[1].normal_force_min[1])
        start = free.record.time[int(np.flatnonzero(low[100:])[0]) + 101]  # the sample after one at F_N^min
    fault = Fault("amplifier", start, math.inf, "A2", amplifier_fault=kind)
    loop, result = _run(bench, "siso", [fault])
    row = safety.measure(loop.record, (fault,), bench[1])
    shown = row["actuation"]
    assert row["ok"] and row["safe_samples"] == 0, row
    assert shown["shows"] is not None and shown["actuation"] <= safety.DETECTION_LIMIT, row
    assert shown["named"] == ["A2"], row
    failed = np.array(loop.record.failed)
    assert failed[shown["shows"] + shown["actuation"] :, 1].mean() > 0.5  # it stays named while it shows
    first = int(round(start / bench[1].sample_time))
    assert not np.array(loop.record.amplifier_safe)[first:].any()  # every amplifier keeps taking the law
    assert np.all(np.isfinite(result.energy))


def test_a_lagging_amplifier_and_the_pulse_protocol_never_trip_the_actuation_check(bench):
    """No false alarm: amplifiers with a first-order lag of half a sample (the sweep's widest) and
    the study's F_N^max during the pulse, under every law, name no joint in the whole study."""
    setup, reference = bench
    for law in ("siso", "clqg"):
        loop = SilLoop(
            firmware.Firmware(reference, law, "float"),
            closed_loop.PULSE_DURATION,
            amplifier={"time_constant": 0.5 * reference.sample_time},
        )
        sil.run_loop(setup, loop)
        assert not np.array(loop.record.failed).any(), law
        assert not any(b & 1 << protocol.CONTROLLER_FAULTS.index("actuation") for b in loop.record.faults), law


@pytest.mark.numerics
def test_sil_matches_the_model_in_the_loop_study(bench, tmp_path):
    """Without faults: zero E2E errors and timeouts, the planned bus load, and E(t_e) of the SIL
    within the MIL's own spread under float-rounding perturbations of its commands, widened by
    that spread (the stick–slip loop is chaotic: docs/can.md)."""
    setup, reference = bench
    setup = dataclasses.replace(setup, duration=1.0)
    out = sil.sil_study(setup, reference, spread_runs=8, log_folder=tmp_path, progress=lambda m: None)
    assert out["planned_bus_load"] < 0.7
    for law, f in out["laws"].items():
        # The float firmware is one more draw of the distribution the perturbed MIL runs sample
        # (the unperturbed run included: here the perturbed ones end 1-3 % below it). A new draw
        # falls outside the range of n = 9 draws with probability 2/10, so the band is that range
        # widened by its own width on each side (≈ 4 standard deviations out for a normal spread),
        # at least 1 %: measured in this test, on this machine, never a fixed percentage
        # (the portability leg's 1e-12 input perturbations put the SIL at +4.4 % against a +3.2 %
        # range of four runs).
        # The rule is rounding_spread.chaos_band, the one the report's "within the band?" applies.
        difference = f["energy_measure_difference"]
        assert f["within_band"], (law, difference, f["mil_spread_under_float_rounding"])
        low, high = rounding_spread.chaos_band(f["mil_spread_under_float_rounding"])
        assert low <= difference <= high and high - low >= 0.02
        assert f["bus"]["e2e_errors"] == 0 and f["bus"]["firmware"]["timeouts"] == 0 and f["bus"]["safe_samples"] == 0
        assert f["bus"]["bus_load"] == pytest.approx(out["planned_bus_load"], rel=0.02)
    # The MIL it is compared with sees the inputs as the firmware does, rounded to the frames'
    # steps (bench/bus_rounding.py): the same run, number for number; the SISO law, which reads
    # the velocity in 1e-9 m/s steps, runs differently on the unrounded inputs.
    steps = bus_rounding.bus_steps([p.database for p in plan.plan(reference).buses], reference)
    python = {entry.name: entry.python_reference for entry in law_registry.LAWS.values()}
    for law in ("siso", "clqg"):
        rounded = closed_loop.run_semi_active(setup, law, bus_rounding.Rounded(python[law](reference), steps))
        assert np.array_equal(rounded.energy, out["mil_runs"][law].energy), law
    unrounded = closed_loop.run_semi_active(setup, "siso", python["siso"](reference))
    assert not np.array_equal(unrounded.energy, out["mil_runs"]["siso"].energy)
    # The log replays through the firmware bit-exactly.
    messages, problem = logs.read(tmp_path / "sil_siso.blf")
    assert problem is None
    replayed = replay(messages, firmware.Firmware(reference, "siso", "float"))
    assert replayed["setpoints_compared"] == 3 * 1000 and replayed["differing"] == 0
    jitter = np.random.default_rng(4).uniform(-2e-4, 2e-4, len(messages))  # a rig's time stamps
    for message, dt in zip(messages, jitter):
        message.timestamp = max(message.timestamp + dt, 0.0)
    assert replay(messages, firmware.Firmware(reference, "siso", "float"))["differing"] == 0


def test_blf_and_asc_of_one_run_decode_to_the_same_signals(bench, tmp_path):
    import can

    loop, _ = _run((dataclasses.replace(bench[0], duration=0.1), bench[1]), "siso", log_path=tmp_path / "run.blf")
    messages, _ = logs.read(tmp_path / "run.blf")
    with can.Logger(str(tmp_path / "direct.asc")) as writer:
        for message in messages:
            writer.on_message_received(message)
    done = run(sys.executable, "-m", "can.logconvert", tmp_path / "run.blf", tmp_path / "converted.asc")
    assert done.returncode == 0, done.stderr
    db = loop.db
    blf = logs.decode(messages, db)
    for name in ("direct.asc", "converted.asc"):
        asc = logs.decode(logs.read(tmp_path / name)[0], db)
        assert len(asc.rows) == len(blf.rows) > 0
        for a, b in zip(asc.rows, blf.rows):
            assert a[1:3] == b[1:3] and a[3] == b[3] and abs(a[0] - b[0]) < 1e-5


def test_damaged_logs_and_unknown_interfaces_get_clear_messages(bench, tmp_path):
    _run((dataclasses.replace(bench[0], duration=0.05), bench[1]), "siso", log_path=tmp_path / "run.blf")
    data = (tmp_path / "run.blf").read_bytes()
    (tmp_path / "cut.blf").write_bytes(data[: len(data) // 2])
    messages, problem = logs.read(tmp_path / "cut.blf")
    full, _ = logs.read(tmp_path / "run.blf")
    assert len(messages) < len(full) and problem.startswith("truncated")
    (tmp_path / "garbage.blf").write_bytes(data[:1000] + b"\0garbage" * 100 + data[2000:])
    assert logs.read(tmp_path / "garbage.blf")[1] is not None
    done = run_cli("bench", "decode", tmp_path / "cut.blf", "--artifact", REFERENCE, "--json")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["frames"] == len(messages) and "ends early" in done.stderr and out["log_problem"].startswith("truncated")
    assert "not found" in cli_error("bench", "decode", tmp_path / "missing.blf", "--artifact", REFERENCE)
    with pytest.raises(ModelError, match="bench interface 'nope'.*python-can knows"):
        open_bus("nope", "x")
    assert "python-can knows" in cli_error(
        "bench", "log", "--interface", "nope", "-o", tmp_path / "x.blf", "--duration", "0.1"
    )
    assert not (tmp_path / "x.blf").exists()


def test_decode_skips_and_counts_malformed_frames(reference):
    import can

    from smartjoint.design.network import protocol

    db = protocol.database(reference)
    m = db.get_message_by_name("SETPOINT_A1")
    good = e2e.protect(m.frame_id, bytearray(m.encode({"crc": 0, "counter": 0, "voltage": 12.5})), 0)
    bad = bytearray(good)
    bad[3] ^= 0xFF
    frames = [
        can.Message(arbitration_id=m.frame_id, data=bytes(good), timestamp=0.0),
        can.Message(arbitration_id=0x555, data=bytes(4), timestamp=0.0),
        can.Message(arbitration_id=m.frame_id, data=bytes(good[:3]), timestamp=0.0),
        can.Message(arbitration_id=m.frame_id, data=bytes(bad), timestamp=0.0),
    ]
    decoded = logs.decode(frames, db)
    assert decoded.frames == 4 and len(decoded.rows) == 3
    assert decoded.summary()["unknown_ids"] == {"0x555": 1}
    assert decoded.wrong_length == {"SETPOINT_A1": 1} and decoded.bad_e2e == {"SETPOINT_A1": 1}
    assert [r[3] for r in decoded.rows if r[2] == "voltage"] == [12.5]


def test_bad_fault_specifications_are_named():
    with pytest.raises(ModelError, match="kind:target:start:end"):
        parse_fault("drop:JOINT_A1")
    with pytest.raises(ModelError, match="target 'JOINT_Z'"):
        check_faults([Fault("drop", 0.1, 0.2, "JOINT_Z")], {"JOINT_A1"}, ["A1"])
    with pytest.raises(ModelError, match="fault kind 'melt'"):
        check_faults([Fault("melt", 0.1, 0.2)], set(), [])
    with pytest.raises(ModelError, match="window"):
        check_faults([Fault("bus_off", 0.3, 0.2)], set(), [])


def test_a_fault_the_run_cannot_inject_is_refused_not_dropped(reference):
    """fault_run checks every fault against the artefact's bus and the study window before the
    run: a frame of another design, or a fault starting at t_e, is an error naming it."""
    from types import SimpleNamespace

    study = SimpleNamespace(duration=1.0)
    with pytest.raises(ModelError, match="target 'JOINT_JA'"):
        sil.fault_run(study, reference, faults=[Fault("drop", 0.5, 0.6, "JOINT_JA")])
    with pytest.raises(ModelError, match=r"faults bus_off bus: start at or after the study's end t_e = 1 s"):
        sil.fault_run(study, reference, faults=[Fault("bus_off", 1.0, 1.1)])


@pytest.mark.parametrize("suffix", [".blf", ".asc"])
def test_bench_log_records_a_live_bus_that_reopens_and_converts(reference, tmp_path, suffix):
    """``bench log`` (logs.record) on a python-can bus while a node sends: the file reopens with
    python-can's reader, converts with can.logconvert, and a rotation limit splits it."""
    import threading

    import can

    from smartjoint.design.network import protocol

    db = protocol.database(reference)
    m = db.get_message_by_name("SETPOINT_A1")
    listener = can.Bus(interface="virtual", channel=f"log-test{suffix}")
    sender = can.Bus(interface="virtual", channel=f"log-test{suffix}")
    sent = []

    def send():
        for k in range(300):
            payload = bytearray(m.encode({"crc": 0, "counter": 0, "voltage": 0.1 * k}))
            data = e2e.protect(m.frame_id, payload, k, e2e.freshness(k))  # the controller's cycle k
            sender.send(can.Message(arbitration_id=m.frame_id, data=bytes(data), is_extended_id=False))
            sent.append(0.1 * k)

    thread = threading.Thread(target=send)
    thread.start()
    path = tmp_path / f"bench{suffix}"
    out = logs.record(listener, path, duration=1.0)
    thread.join()
    listener.shutdown()
    sender.shutdown()
    assert out["frames"] == 300
    messages, problem = logs.read(path)
    assert problem is None and len(messages) == 300
    decoded = logs.decode(messages, db)
    assert [round(r[3], 6) for r in decoded.rows if r[2] == "voltage"] == [round(v, 6) for v in sent]
    other = ".asc" if suffix == ".blf" else ".blf"
    converted = tmp_path / f"converted{other}"
    done = run(sys.executable, "-m", "can.logconvert", path, converted)
    assert done.returncode == 0, done.stderr
    assert [r[1:] for r in logs.decode(logs.read(converted)[0], db).rows] == [r[1:] for r in decoded.rows]


def test_bench_log_writes_mf4_that_reopens(reference, tmp_path):
    """asammdf is a dependency (the XCP DAQ writes MF4 with it): ``bench log`` to .mf4 reopens with
    python-can's reader and decodes every frame sent."""
    import threading

    import can

    from smartjoint.design.network import protocol

    db = protocol.database(reference)
    m = db.get_message_by_name("SETPOINT_A1")
    listener = can.Bus(interface="virtual", channel="mf4-test")
    sender = can.Bus(interface="virtual", channel="mf4-test")
    sent = [0.5 * k for k in range(50)]

    def send():
        for k, volts in enumerate(sent):
            payload = bytearray(m.encode({"crc": 0, "counter": 0, "voltage": volts}))
            data = e2e.protect(m.frame_id, payload, k, e2e.freshness(k))  # the controller's cycle k
            sender.send(can.Message(arbitration_id=m.frame_id, data=bytes(data), is_extended_id=False))

    thread = threading.Thread(target=send)
    thread.start()
    path = tmp_path / "bench.mf4"
    out = logs.record(listener, path, duration=0.5)
    thread.join()
    listener.shutdown()
    sender.shutdown()
    messages, problem = logs.read(path)
    assert out["frames"] == len(sent) and problem is None and len(messages) == len(sent)
    decoded = logs.decode(messages, db)
    assert [round(r[3], 6) for r in decoded.rows if r[2] == "voltage"] == [round(v, 6) for v in sent]


@pytest.mark.parametrize("real", ["float", "double"])
def test_a_build_without_a_law_leaves_it_out_and_refuses_it(tmp_path, real):
    """``-D<PREFIX>_CAN_WITHOUT_<LAW>``: the build compiles clean without that law's module, and
    init refuses the law left out (-1, the safe state for good) while it accepts the others."""
    from smartjoint.codegen import build, can_layer, generate, output
    from smartjoint.common import law_registry

    a = artifact.load(Path(__file__).resolve().parents[1] / "firmware" / "generated" / "controller.json")
    files = {**generate.render(a, real), **can_layer.render_can(a, real=real)}
    output.write({k: v for k, v in files.items() if k.endswith((".c", ".h"))}, tmp_path)
    left_out, kept = "slipratio", [law for law in law_registry.NAMES if law != "slipratio"]
    main = ["#include <stdio.h>", '#include "smartjoint_can.h"', "static smartjoint_can_state state;",
            "int main(void)", "{"]  # fmt: skip
    for law in (left_out, *kept):
        main.append(f'    printf("%d\\n", smartjoint_can_init(&state, SMARTJOINT_CAN_LAW_{law.upper()}));')
    (tmp_path / "without.c").write_text("\n".join([*main, "    return 0;", "}", ""]))
    sources = ["without.c", "smartjoint_can.c", "sj_e2e.c", *(f"smartjoint_{law}.c" for law in kept)]
    flags = ["-std=c99", *build.WARNINGS, f"-DSMARTJOINT_CAN_WITHOUT_{left_out.upper()}"]
    done = run("gcc", *flags, "-I.", *sources, "-lm", "-o", "without", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    answers = run(str(tmp_path / "without"), cwd=tmp_path).stdout.split()
    assert answers == ["-1"] + ["0"] * len(kept)
