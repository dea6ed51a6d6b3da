"""Logs and replay: every controller sample of a log is stepped (also those without frames, so
the firmware's timeouts replay), ``bench replay`` fails on differing setpoints, and damaged
ASC/BLF/CSV logs report what was skipped, counted by kind."""

from __future__ import annotations

import math
from pathlib import Path

import can
import numpy as np
import pytest
from conftest import quiet_joint_frame

from smartjoint import cli
from smartjoint.bench import e2e, firmware, logs
from smartjoint.bench.faults import Fault
from smartjoint.bench.loop import SilLoop
from smartjoint.bench.replay import replay
from smartjoint.common.errors import ModelError
from smartjoint.design.control import artifact
from smartjoint.design.network import plan, protocol
from smartjoint.design.plant.interface import Measurements

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "firmware" / "generated" / "controller.json"
SAMPLES = 400  # 0.4 s at 1 ms
BUS_OFF = (0.1, 0.2)  # s


@pytest.fixture(scope="module")
def reference():
    return artifact.load(REFERENCE)


def _measurements(k: int, sample_time: float, joints: int, sensors: int) -> Measurements:
    """Synthetic sensor values that keep the cLQG's output moving (its state matters)."""
    t = k * sample_time
    phase = 2 * np.pi * 7 * t
    return Measurements(
        time=t,
        sensors=1e-4 * np.sin(phase + np.arange(sensors)),
        sliding_velocity=2e-3 * np.sin(phase + np.arange(joints)),
        friction_force=100 * np.cos(phase + np.arange(joints)),
        normal_force=np.full(joints, 200.0),
    )


def _sil_log(reference, path, law="clqg", faults=(), samples=SAMPLES):
    """Run the SIL loop directly on synthetic measurements, logging every frame to ``path``."""
    loop = SilLoop(firmware.Firmware(reference, law, "float"), faults=faults, log_path=path)
    loop.reset()
    try:
        for k in range(samples):
            loop.step(_measurements(k, reference.sample_time, len(reference.joint_names), len(reference.sensor_names)))
    finally:
        loop.close()
    return loop.record


@pytest.fixture(scope="module")
def bus_off_log(reference, tmp_path_factory):
    """A SIL log (cLQG, float firmware) of 0.4 s with the bus off on [0.1, 0.2) s."""
    path = tmp_path_factory.mktemp("replay") / "bus_off.blf"
    return path, _sil_log(reference, path, faults=[Fault("bus_off", *BUS_OFF)])


def _replay(reference, messages, **options):
    return replay(messages, firmware.Firmware(reference, "clqg", "float"), **options)


def test_a_bus_off_log_replays_every_setpoint(reference, bus_off_log):
    """The bus-off leaves 100 samples without any frame; stepping them makes the firmware time
    out and recover exactly as it did in the SIL, so all 3 × 300 recorded setpoints match (a
    replay that skipped them differed in 61 of 900). The firmware's setpoints during the bus-off
    never reached the log: counted, not compared."""
    path, record = bus_off_log
    content = logs.load(path)
    assert content.problem() is None
    safe = np.array(record.safe)
    k_end = int(round(BUS_OFF[1] / reference.sample_time))
    assert safe[k_end] and not safe[: int(round(BUS_OFF[0] / reference.sample_time))].any()  # a timeout to replay
    out = _replay(reference, content)
    joints = len(reference.joint_names)
    assert out["samples"] == SAMPLES and out["silent_samples"] == 100
    assert out["setpoints_compared"] == joints * (SAMPLES - 100) and out["differing"] == 0
    assert out["recorded_not_replayed"] == 0 and out["replayed_not_recorded"] == 0
    assert out["replayed_not_recorded_in_silent_samples"] == joints * 100
    assert out["ok"] and out["max_difference_V"] == 0.0
    # A rig's time stamps: absolute (since 1970), off the µs grid and jittering by up to 0.45 Δt —
    # every frame still goes to its sample.
    jitter = np.random.default_rng(16).uniform(-0.45, 0.45, len(content.messages)) * reference.sample_time
    for message, dt in zip(content.messages, jitter):
        message.timestamp += 1.7e9 + 321.5e-6 + dt
    jittered = _replay(reference, content)
    assert jittered["differing"] == 0 and jittered["setpoints_compared"] == out["setpoints_compared"]


def _setpoint(m, voltages: dict, counter: int, t: float, fresh: int = 0) -> can.Message:
    payload = bytearray(m.encode({"crc": 0, "counter": 0} | voltages))
    data = e2e.protect(m.frame_id, payload, counter, fresh)
    return can.Message(
        arbitration_id=m.frame_id,
        data=bytes(data),
        is_extended_id=False,
        is_fd=m.is_fd,
        bitrate_switch=m.is_fd,
        timestamp=t,
    )


def _write(messages, path):
    with can.Logger(str(path)) as writer:
        for message in messages:
            writer.on_message_received(message)
    return path


def _bench(capsys, command, log, *options):
    """Exit code and captured output of ``smartjoint bench COMMAND LOG --artifact <reference> OPTIONS``
    in this process (main returns, or raises SystemExit for exit 1)."""
    try:
        code = cli.main(["bench", command, str(log), "--artifact", str(REFERENCE), *options])
    except SystemExit as stop:
        code = stop.code
    return code, capsys.readouterr()


def test_bench_replay_exits_non_zero_when_a_setpoint_differs_or_was_not_replayed(
    reference, bus_off_log, tmp_path, capsys
):
    path, _ = bus_off_log
    messages = logs.load(path).messages
    code, captured = _bench(capsys, "replay", path, "--law", "clqg")
    assert code == 0 and "900 setpoints compared, 0 differ" in captured.out, captured

    a1 = next(k for k, m in enumerate(messages) if m.arbitration_id == 0x200 and m.timestamp > 0.3)
    original = messages[a1]
    counter = original.data[1] & 0x0F
    db = plan.plan(reference).buses[0].database  # the firmware's: the setpoints in one frame
    m = db.get_message_by_frame_id(0x200)
    assert m.name == "SETPOINTS_A1_A3"
    voltages = {k: v for k, v in m.decode(original.data).items() if k.startswith("voltage_")}
    voltage = voltages["voltage_a1"]
    fresh = e2e.freshness_of(original.arbitration_id, original.data)
    changed = list(messages)  # the recorded setpoint of A1 moved by 1 mV, CRC and counter kept valid
    moved = voltages | {"voltage_a1": voltage + (1e-3 if voltage < 25 else -1e-3)}
    changed[a1] = _setpoint(m, moved, counter, original.timestamp, fresh)
    code, captured = _bench(capsys, "replay", _write(changed, tmp_path / "changed.blf"), "--law", "clqg")
    assert code == 1
    first = captured.err.splitlines()[0]
    assert first.startswith("smartjoint bench replay: FAILED") and "900 setpoints compared, 1 differ" in first
    assert f"t = {original.timestamp:.6f} s SETPOINTS_A1_A3.voltage_a1 differs" in captured.err
    # Within a tolerance of 2 mV it passes.
    code, _ = _bench(capsys, "replay", tmp_path / "changed.blf", "--law", "clqg", "--tolerance", "2e-3")
    assert code == 0

    extra = list(messages)  # a second recorded SETPOINTS frame in one sample: the firmware sent one
    cycle = (fresh << 4 | counter) + 1  # the next cycle's setpoint, in the same sample
    extra.insert(a1 + 1, _setpoint(m, voltages, cycle % 16, original.timestamp, e2e.freshness(cycle)))
    code, captured = _bench(capsys, "replay", _write(extra, tmp_path / "extra.blf"), "--law", "clqg", "--json")
    assert code == 1 and "3 recorded but not replayed" in captured.err.splitlines()[0]
    assert '"recorded_not_replayed": 3' in captured.out and '"differing": 0' in captured.out

    # Issue 37: a log with every frame of one kind the firmware sends cut out is not the bus's log.
    # The heartbeat cut out fails the replay; the one setpoint frame cut out leaves nothing to compare.
    for name, status, words in (
        ("CONTROLLER_STATUS", 1, "sent by the firmware but never in the log: CONTROLLER_STATUS"),
        ("SETPOINTS_A1_A3", 2, "no recorded setpoint frame"),
    ):
        frame_id = db.get_message_by_name(name).frame_id
        cut = _write([k for k in messages if k.arbitration_id != frame_id], tmp_path / f"without_{name}.blf")
        code, captured = _bench(capsys, "replay", cut, "--law", "clqg")
        assert code == status and words in captured.err.splitlines()[0], (name, captured)


def test_empty_and_foreign_logs_are_errors_not_zero_comparisons(reference, tmp_path, capsys):
    (tmp_path / "empty.asc").write_text("")
    for command in ("replay", "decode"):
        code, captured = _bench(capsys, command, tmp_path / "empty.asc")
        assert code == 2 and "no frames" in captured.err and len(captured.err.strip().splitlines()) == 1
    foreign = _write(
        [can.Message(arbitration_id=0x555, data=bytes(8), timestamp=0.001 * k) for k in range(5)],
        tmp_path / "foreign.asc",
    )
    code, captured = _bench(capsys, "replay", foreign)
    assert code == 2 and "none with an identifier of the artefact's protocol" in captured.err
    _sil_log(reference, tmp_path / "short.blf", "siso", samples=20)
    sensors_only = _write(
        [m for m in logs.load(tmp_path / "short.blf").messages if m.arbitration_id < 0x200], tmp_path / "sensors.blf"
    )
    code, captured = _bench(capsys, "replay", sensors_only)
    assert code == 2 and "no recorded setpoint frame (SETPOINT_*, SETPOINTS_*)" in captured.err


def test_a_truncated_blf_says_after_how_many_frames_it_stops(bus_off_log, tmp_path):
    path, _ = bus_off_log
    data = path.read_bytes()
    full = logs.load(path)
    counts = []
    for cut in (200, 1000, len(data) // 3, len(data) // 2, len(data) - 10, len(data) - 1):
        (tmp_path / "cut.blf").write_bytes(data[:cut])
        content = logs.load(tmp_path / "cut.blf")
        assert content.truncated is not None, cut
        assert f"stopped after {len(content.messages)} of {len(full.messages)} frames" in content.truncated
        assert content.problem().startswith("truncated")
        # What was read is the file's beginning, frame by frame.
        read = len(content.messages)
        assert [bytes(m.data) for m in content.messages] == [bytes(m.data) for m in full.messages[:read]]
        counts.append(len(content.messages))
    assert counts == sorted(counts) and counts[0] < counts[-1]
    (tmp_path / "header.blf").write_bytes(data[:40])  # not even the file header
    with pytest.raises(ModelError, match="cannot open"):
        logs.load(tmp_path / "header.blf")
    (tmp_path / "garbage.blf").write_bytes(data[:1000] + b"\0garbage" * 100 + data[2000:])
    damaged = logs.load(tmp_path / "garbage.blf")
    assert damaged.truncated and len(damaged.messages) < len(full.messages)


def test_damaged_asc_reports_every_skipped_line_and_keeps_reading(bus_off_log, tmp_path, capsys):
    """python-can's ASCReader passes over lines it cannot match (a NaN or negative time stamp,
    text) without a word and stops for good at a frame line it cannot parse: each is counted
    here and the reading goes on after it."""
    path, _ = bus_off_log
    full = logs.load(path).messages
    asc = _write(full, tmp_path / "run.asc")
    assert logs.load(asc).problem() is None and len(logs.load(asc).messages) == len(full)
    lines = asc.read_text().splitlines(keepends=True)
    frame_line = next(k for k, line in enumerate(lines) if "CANFD" in line) + 50
    garbage = [
        "some text a tool wrote\n",
        " 0.050000 CANFD   1 Rx        1zz  1 0 c 12 00\n",  # the reader would stop here
        "nan CANFD   1 Rx        100  1 0 c 12 " + "00 " * 12 + "\n",
        "-0.001000 CANFD   1 Rx        100  1 0 c 12 " + "00 " * 12 + "\n",
    ]
    (tmp_path / "garbage.asc").write_text("".join(lines[:frame_line] + garbage + lines[frame_line:]))
    content = logs.load(tmp_path / "garbage.asc")
    assert len(content.messages) == len(full) and content.unparseable_lines == 4 and content.truncated is None
    assert f"line {frame_line + 1}: 'some text a tool wrote'" in content.first_unparseable
    code, captured = _bench(capsys, "decode", tmp_path / "garbage.asc")
    assert code == 0 and "4 unparseable line(s) skipped" in captured.err
    assert "unparseable_lines': 4" in captured.out

    text = asc.read_text()
    middle = lines[len(lines) // 2]
    cut_at = text.index(middle) + middle.index(" 1 0 ") + 14  # inside the data bytes of a frame
    (tmp_path / "cut.asc").write_text(text[:cut_at])
    cut = logs.load(tmp_path / "cut.asc")
    assert cut.truncated and f"stops after {len(cut.messages)} frames" in cut.truncated
    assert cut.cut_frames == 1 and 0 < len(cut.messages) < len(full)
    code, captured = _bench(capsys, "decode", tmp_path / "cut.asc", "--json")
    assert code == 0 and "ends early" in captured.err and "1 frame(s) cut short" in captured.err
    assert "frames not decoded: unknown ids 0, wrong length 1" in captured.err  # the cut frame, counted


def test_time_stamps_that_are_not_finite_are_refused_and_odd_ones_counted(reference, tmp_path, capsys):
    _sil_log(reference, tmp_path / "short.blf", "siso", samples=20)
    frames = logs.load(tmp_path / "short.blf").messages
    frames[7].timestamp = math.nan
    frames[30].timestamp = -0.5
    csv = _write(frames, tmp_path / "odd.csv")  # CSV carries NaN and negative time stamps
    content = logs.load(csv)
    assert (content.non_finite_times, content.negative_times, content.backwards_times) == (1, 1, 1)
    problem = content.problem()
    assert "1 non-finite" in problem and "1 negative" in problem and "1 time stamp(s) earlier" in problem
    with pytest.raises(ModelError, match="1 frame.* not finite"):
        _replay(reference, content)
    code, captured = _bench(capsys, "replay", csv)
    assert code == 2 and "not finite" in captured.err.splitlines()[-1]
    decoded = logs.decode(content, firmware.Firmware(reference, "siso", "float").db)
    assert decoded.non_finite_times == 1 and decoded.summary()["log"]["negative_times"] == 1


class StepAgeingFirmware:
    """A stand-in with the Firmware API whose setpoint depends on how many times ``step`` ran —
    the contract of a CAN layer that ages its inputs by controller steps: SETPOINT_A1 carries
    the steps since reset, plus 10 V while JOINT_A1 is more than 3 steps old and for the 3 steps
    after it came back (a recovery). Only a replay that steps every
    sample of the log, silent ones included, can reproduce it."""

    def __init__(self, reference):
        self.db = protocol.database(reference)
        self.artifact = reference
        self.frame = self.db.get_message_by_name("SETPOINT_A1")
        self.joint = self.db.get_message_by_name("JOINT_A1").frame_id
        self.reset()

    def reset(self):
        self.steps, self.since_input, self.recovery, self.counter, self.out = 0, 0, 0, 0, []

    def rx(self, frame_id, data, time_us):
        if frame_id == self.joint:
            self.since_input = 0
        return 0

    def step(self, time_us):
        self.steps += 1
        self.since_input += 1
        if self.since_input > 3:
            self.recovery = 3
        timed_out = self.recovery > 0
        if self.since_input <= 3 and self.recovery:
            self.recovery -= 1
        voltage = 0.01 * (self.steps % 1000) + (10.0 if timed_out else 0.0)
        data = e2e.protect(
            self.frame.frame_id,
            bytearray(self.frame.encode({"crc": 0, "counter": 0, "voltage": voltage})),
            self.counter,
            e2e.freshness(self.steps - 1),  # the cycle its counter counts
        )
        self.counter = (self.counter + 1) % e2e.COUNTER_MODULO
        self.out = [(self.frame.frame_id, bytes(data))]
        return 0

    def tx(self):
        out, self.out = self.out, []
        return out


def test_replay_reproduces_a_layer_that_ages_its_inputs_by_steps(reference):
    """A log with a silent bus on samples 50–79 and the controller alone off the bus on 120–129
    (sensor frames recorded, no setpoints): every recorded setpoint replays, including the
    recovery after the silent bus; the controller-alone gap counts as replayed, not recorded."""
    node = StepAgeingFirmware(reference)
    joint = node.db.get_message_by_name("JOINT_A1")
    frames = []
    for k in range(200):
        t = 0.25 + k * reference.sample_time  # a log that does not start at 0
        if 50 <= k < 80:
            node.step(0)
            node.tx()
            continue
        data = quiet_joint_frame(joint, k % e2e.COUNTER_MODULO)
        frames.append(can.Message(arbitration_id=joint.frame_id, data=bytes(data), is_fd=True, timestamp=t))
        node.rx(joint.frame_id, bytes(data), 0)
        node.step(0)
        for frame_id, payload in node.tx():
            if not 120 <= k < 130:
                frames.append(can.Message(arbitration_id=frame_id, data=payload, is_fd=False, timestamp=t))
    recorded = [r[3] for r in logs.decode(frames, node.db).rows if r[2] == "voltage"]
    assert sum(v >= 10 for v in recorded) == 3  # the recovery after the silent bus is in the log
    out = replay(frames, StepAgeingFirmware(reference))
    assert out["samples"] == 200 and out["silent_samples"] == 30
    assert out["setpoints_compared"] == 160 and out["differing"] == 0 and out["ok"]
    assert out["replayed_not_recorded_in_silent_samples"] == 30 and out["replayed_not_recorded"] == 10
    # The same log with the silent samples squeezed out (what a replay that skips them sees): the
    # setpoints after the gap are 30 cycles from where their time stamps put them, so their
    # freshness byte fails there, and the replay fails.
    squeezed = [
        can.Message(
            arbitration_id=m.arbitration_id,
            data=m.data,
            is_fd=m.is_fd,
            timestamp=m.timestamp - (30 * reference.sample_time if m.timestamp > 0.25 + 0.05 else 0),
        )
        for m in frames
    ]
    diverged = replay(squeezed, StepAgeingFirmware(reference))
    assert diverged["setpoints_compared"] == 50 and diverged["recorded_setpoints_bad_crc"] == 110
    assert not diverged["ok"]
