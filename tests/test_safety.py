"""The safe-state policy (docs/safety.md): one safe force from controller to amplifier, inputs
aged by the heartbeat their senders echo, plausibility of every decoded signal, and every fault
kind on every frame on the SIL bench — a test per case."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from smartjoint.bench import e2e, firmware, safety
from smartjoint.bench.amplifier import AmplifierModel
from smartjoint.bench.faults import FRAME_FAULTS, Fault, check_faults, parse_fault
from smartjoint.common.errors import ModelError
from smartjoint.design.control import artifact
from smartjoint.design.network import plan, protocol

REFERENCE = Path(__file__).resolve().parents[1] / "firmware" / "generated" / "controller.json"
LOADED = artifact.load(REFERENCE)
DATABASE = plan.plan(LOADED).buses[0].database  # the default plan: its setpoints in one SETPOINTS frame
SETPOINT_FRAMES = sorted(m.name for m in DATABASE.messages if m.name.startswith("SETPOINT"))
CASES = safety.cases(LOADED, DATABASE)
RECOVERY_LIMIT = LOADED.timeout_cycles + LOADED.recovery_cycles + 1  # stated in docs/safety.md
EXPECTED_BIT = {
    "sliding_velocity": "velocity",
    "friction_force": "friction",
    "normal_force": "normal_force",
    "temperature": "temperature",
    "current": "current",
    "monitor_voltage": "tracking",
    "voltage": "amplifier_safe",
    "mode": "amplifier_safe",
}  # the amplifier's own watchdog trips


@pytest.fixture(scope="module")
def image():
    return firmware.Firmware(LOADED, "clqg", "float")


@pytest.fixture(scope="module")
def signals():
    return safety.signals(None, LOADED, max(c.cycles for c in CASES))


@pytest.mark.parametrize("case", CASES, ids=[f"{c.name} ({c.timing})" for c in CASES])
def test_every_fault_reaches_the_safe_force_at_every_joint_within_three_cycles(image, signals, case):
    """The force the amplifiers really apply reaches the artefact's safe force within 3 cycles
    of the fault (of its detection bound for delays) and keeps it while the fault lasts; the
    loop recovers within the stated cycles after it ends; a delay within the latency bound is
    used, never a timeout; power-up holds the safe force until the first valid command."""
    loop = safety.run_case_loop(image, case, signals)
    row = safety.measure(loop.record, case.faults, LOADED, case.tolerated)
    if case.tolerated:
        assert row["safe_samples"] == 0 and row["ok"], row
        return
    if "actuation" in row and len(case.faults) == 1:  # past the amplifier: named, and the law runs on
        assert row["ok"] and row["safe_samples"] == 0, row
        shown = row["actuation"]
        assert shown["shows"] is None or shown["actuation"] <= safety.DETECTION_LIMIT, row
        assert set(shown["named"]) <= {case.faults[0].target}, row
        return
    assert row["ok"], row
    assert row["joints"] <= safety.DETECTION_LIMIT and row["firmware"] <= safety.DETECTION_LIMIT, row
    if row["end"] is not None:
        assert row["recovery"] <= RECOVERY_LIMIT, row
    commands = np.array(loop.record.command)[np.array(loop.record.safe)]
    assert np.all(commands == LOADED.safe_normal_force)  # one safe force: firmware and amplifiers
    for f in case.faults:  # an implausible value raises its own status bit
        signal = "voltage" if f.signal and f.signal.startswith("voltage_") else f.signal  # SETPOINTS_<J>.voltage_<j>
        if f.kind == "implausible" and signal in EXPECTED_BIT:
            bit = 1 << protocol.CONTROLLER_FAULTS.index(EXPECTED_BIT[signal])
            assert any(b & bit for b in loop.record.faults), (f.label(), EXPECTED_BIT[signal])
        elif f.kind == "implausible":  # a tip sensor
            assert any(b & 1 << protocol.CONTROLLER_FAULTS.index("sensor") for b in loop.record.faults)


def test_the_matrix_covers_every_frame_kind_signal_amplifier_fault_and_timing():
    frames = {m.name for m in DATABASE.messages}
    single = [c for c in CASES if len(c.faults) == 1]
    for kind in FRAME_FAULTS:
        for timing in safety.TIMINGS:
            assert {c.faults[0].target for c in single if c.faults[0].kind == kind and c.timing == timing} == frames
    decoded = {
        (m.name, s.name)
        for m in DATABASE.messages
        for s in m.signals
        if s.name not in ("crc", "counter", "sync", "cycle_high", "step_status", "missing_inputs", "faults")
        and s.length > 1
    }
    assert decoded == {(c.faults[0].target, c.faults[0].signal) for c in single if c.faults[0].kind == "implausible"}
    assert any(len(c.faults) == 2 and c.timing.startswith("two at once, from t = 0") for c in CASES)


class Nodes:
    """Healthy sensor nodes and amplifiers around the firmware: every input frame each cycle,
    the next alive counter, the heartbeat echo."""

    def __init__(self, fw, values=None):
        self.fw, self.counter, self.echo, self.fresh = fw, {}, 0, 0
        self.inputs = [
            m
            for m in sorted(fw.db.messages, key=lambda m: m.frame_id)
            if m.name.startswith(("JOINT_", "TIP_", "AMP_STATUS_"))
        ]
        self.values = values or {}

    def frames(self):
        out = []
        for m in self.inputs:
            counter = self.counter.get(m.name, 0)
            self.counter[m.name] = (counter + 1) % 16
            values = {s.name: 0.0 for s in m.signals}
            if m.name.startswith("AMP_STATUS_"):
                j = LOADED.joint_names.index(m.name[len("AMP_STATUS_") :])
                values["monitor_voltage"] = self.sent[j] if hasattr(self, "sent") else 50.0
                values["temperature"] = 35.0
            values.update(self.values.get(m.name, {}))
            values["sync"] = self.echo
            data = e2e.protect(m.frame_id, bytearray(m.encode(values, strict=False)), counter, self.fresh)
            out.append((m.frame_id, bytes(data)))
        return out

    def hear(self, sent):
        self.sent = []
        for frame_id, data in sent:
            name = self.fw.db.get_message_by_frame_id(frame_id).name
            if name == "CONTROLLER_STATUS":
                self.echo, self.fresh = data[1] & 0x0F, data[e2e.HEARTBEAT_CYCLE_BYTE]
            elif name.startswith("SETPOINT"):
                decoded = self.fw.db.get_message_by_frame_id(frame_id).decode(data)
                self.sent += [decoded[safety.setpoint_signal(self.fw.db, j.upper())[1]] for j in self.joints(name)]

    def joints(self, frame):
        """The joints whose setpoints ``frame`` carries."""
        return [j for j in LOADED.joint_names if safety.setpoint_signal(self.fw.db, j.upper())[0] == frame]


def _cycle(fw, nodes, k, late=(), stamp_offset=0):
    """One controller cycle: frames in (those of ``late`` inputs after the step), step, frames out."""
    now = (k * int(LOADED.sample_time * 1e6) + stamp_offset) & 0xFFFFFFFF
    held = []
    for frame_id, data in nodes.frames():
        if fw.db.get_message_by_frame_id(frame_id).name in late:
            held.append((frame_id, data))
        else:
            fw.rx(frame_id, data, now)
    fw.step(now)
    nodes.hear(fw.tx())
    return held


def test_jitter_within_the_cycle_never_trips_a_timeout(reference_firmware):
    """Frames stamped after the step time (an interrupt between reading the clock and stepping),
    and frames half a cycle late (they arrive after their step, before the next)."""
    fw = reference_firmware
    fw.reset()
    nodes = Nodes(fw)
    held = []
    for k in range(400):
        for frame_id, data in held:
            fw.rx(frame_id, data, k * 1000 - 500)
        held = _cycle(fw, nodes, k, late=("JOINT_A2", "TIP_SENSORS") if k % 3 else (), stamp_offset=5)
        assert not fw.safe, (k, fw.fault_names())
    assert fw.counters["timeouts"] == 0


def test_a_frame_later_than_the_bound_is_detected(reference_firmware):
    """A frame one cycle late is used (the bound); two cycles late trips the timeout at once,
    and it stays detected while the stream stays late."""
    fw = reference_firmware
    for lateness, detected in ((1, False), (2, True), (5, True)):
        fw.reset()
        nodes = Nodes(fw)
        queue = []
        safe = []
        for k in range(60):
            arriving = [(due, f) for due, f in queue if due <= k]
            queue = [(due, f) for due, f in queue if due > k]
            for _, (frame_id, data) in arriving:
                fw.rx(frame_id, data, k * 1000)
            held = _cycle(fw, nodes, k, late=("JOINT_A1",) if k >= 20 else ())
            queue += [(k + lateness, f) for f in held]
            safe.append(fw.safe)
        assert any(safe[20:]) == detected, lateness
        if detected:
            assert all(safe[20 + lateness :]), lateness  # no recovery while it stays late
            assert "timeout" in fw.fault_names()


def test_the_step_counter_wraps_without_a_hiccup(reference_firmware):
    fw = reference_firmware
    fw.reset()
    nodes = Nodes(fw)
    for k in range(5):
        _cycle(fw, nodes, k)
    fw.lib.smartjoint_can_set_steps(fw._state, 2**32 - 20)
    # The frames of the cycle after the jump echo a heartbeat of the old count: to the layer they
    # are ~2^32 cycles old, and their freshness byte fails; once the nodes hear the new count the
    # loop recovers, well before the count wraps at 2^32.
    settled = 5 + LOADED.timeout_cycles + LOADED.recovery_cycles + 1
    counters = []
    for k in range(5, 45):
        _cycle(fw, nodes, k)
        counters.append(nodes.echo)
        assert not fw.safe or k < settled, k
    assert all((b - a) % 16 == 1 for a, b in zip(counters, counters[1:]))  # one more per step, across the wrap


def test_an_unknown_law_is_refused_and_holds_the_safe_state(reference_firmware):
    fw = reference_firmware
    assert fw._call("init_opaque", fw._state, 7) == -1
    nodes = Nodes(fw)
    for k in range(10):
        _cycle(fw, nodes, k)
        assert fw.safe and "law" in fw.fault_names()
    with pytest.raises(ModelError, match="law: 'lqr'"):
        firmware.Firmware(LOADED, "lqr", "float")
    fw.reset()


def test_packing_does_not_depend_on_the_fpu_rounding_mode(reference_firmware):
    """rint rounds by the current mode (under FE_DOWNWARD 2.7 becomes 2: a whole step off); the
    layer rounds half to even itself. Under FE_DOWNWARD / FE_UPWARD / FE_TOWARDZERO every
    setpoint of the double build still packs as cantools encodes it — values whose quotient
    lies a fraction away from a half step; an exact tie may go either way, as the division
    (value − offset)/scale itself rounds by the mode by one ulp (docs/safety.md). The float
    build's quotient of a 32-bit field is already an integer (its ulp is 8 raw steps at 10⁸):
    there the mode moves the raw value by the two roundings before the rounding step (the
    value's conversion to float and the division), at most two ulps of the quotient."""
    import cffi

    ffi = cffi.FFI()
    ffi.cdef("int fesetround(int mode); int fegetround(void);")
    libm = ffi.dlopen(None)
    double_build = firmware.Firmware(LOADED, "clqg", "double")
    frame, signal = safety.setpoint_signal(reference_firmware.db, "A1")
    m = reference_firmware.db.get_message_by_name(frame)
    values = [12.34567898, 0.00000017, 49.99999987, 44.55078122, 1.00000003, 0.00000013]
    for v in values:  # each fraction is clearly off a half step, and rounding by the mode would move 3 of them
        fraction = v / 1e-7 - math.floor(v / 1e-7)
        assert 0.1 < abs(fraction - 0.5) < 0.4
    others = {s.name: 0 for s in m.signals}
    expected = [m.encode(others | {signal: v}) for v in values]
    encode = getattr(reference_firmware.lib, f"smartjoint_can_{frame.lower()}_{signal}_encode")
    quotients = [np.float32(v) / np.float32(1e-7) for v in values]
    nearest = [int(np.rint(q)) for q in quotients]
    default = libm.fegetround()
    for mode in (0x400, 0x800, 0xC00):  # x86-64 glibc: downward, upward, toward zero
        try:
            assert libm.fesetround(mode) == 0
            packed = [double_build.pack(frame, {signal: v}) for v in values]
            raw = [encode(v) for v in values]
        finally:
            libm.fesetround(default)
        assert packed == expected, hex(mode)
        for r, n, q in zip(raw, nearest, quotients):
            assert abs(r - n) <= 2.0 * float(np.spacing(q)), hex(mode)


def test_implausible_controller_inputs_reach_the_safe_state_and_name_their_bit(reference_firmware):
    """A value beyond its range in a frame with a valid E2E is a broken node: the safe force,
    with the check's own status bit."""
    fw = reference_firmware
    cases = {
        ("JOINT_A2", "sliding_velocity", 1.5): "velocity",
        ("JOINT_A1", "friction_force", -700.0): "friction",
        ("JOINT_A3", "normal_force", 500.0): "normal_force",
        ("TIP_SENSORS", "tip_z", 0.6): "sensor",
        ("AMP_STATUS_A2", "temperature", 120.0): "temperature",
        ("AMP_STATUS_A1", "current", 2.8): "current",
    }
    for (frame, signal, value), bit in cases.items():
        fw.reset()
        nodes = Nodes(fw)
        for k in range(10):
            _cycle(fw, nodes, k)
        assert not fw.safe
        nodes.values = {frame: {signal: value}}
        _cycle(fw, nodes, 10)
        assert fw.safe and bit in fw.fault_names(), (frame, signal, fw.fault_names())
        assert np.all(fw.command == LOADED.safe_normal_force)
        nodes.values = {}
        for k in range(11, 11 + LOADED.recovery_cycles + 1):
            _cycle(fw, nodes, k)
        assert not fw.safe, (frame, signal)


def test_the_amplifier_makes_its_joint_safe_on_its_own():
    """Power-up, a silent controller, a setpoint outside the design's range, a setpoint kept
    back behind its heartbeat: the safe voltage, from the amplifier alone."""
    j = 0
    amp = AmplifierModel(
        force_per_volt=LOADED.piezo_force_per_volt,
        safe_normal_force=float(LOADED.safe_normal_force[j]),
        normal_force_min=float(LOADED.normal_force_min[j]),
        normal_force_max=float(LOADED.normal_force_max[j]),
        timeout_cycles=LOADED.timeout_cycles,
    )
    dt = LOADED.sample_time
    assert amp.advance(dt) == pytest.approx(LOADED.safe_normal_force[j])  # power-up, nothing received
    one_each = protocol.database(LOADED)  # one SETPOINT frame per joint (a plan that does not pack)
    setpoint, heartbeat = one_each.get_message_by_name("SETPOINT_A1"), DATABASE.get_message_by_name("CONTROLLER_STATUS")

    def send(k, volts, heartbeat_counter=None):
        data = e2e.protect(
            setpoint.frame_id,
            bytearray(setpoint.encode({"crc": 0, "counter": 0, "voltage": volts})),
            k % 16,
            e2e.freshness(k),
        )
        amp.receive_setpoint(setpoint.frame_id, bytes(data), setpoint.length, lambda d: setpoint.decode(d)["voltage"])
        beat = e2e.protect(
            heartbeat.frame_id,
            bytearray(
                heartbeat.encode(
                    {"crc": 0, "counter": 0, "mode": 2, "missing_inputs": 0, "step_status": 0, "faults": 0}
                    | {"cycle_high": e2e.freshness(k if heartbeat_counter is None else heartbeat_counter)}
                    | {s.name: 0 for s in heartbeat.signals if s.name.startswith("failed_")}
                )
            ),
            (k if heartbeat_counter is None else heartbeat_counter) % 16,
            e2e.freshness(k if heartbeat_counter is None else heartbeat_counter),
        )
        amp.receive_heartbeat(
            heartbeat.frame_id,
            bytes(beat),
            heartbeat.length,
            lambda d: heartbeat.decode(d, decode_choices=False)["mode"],
        )
        return amp.advance(dt)

    assert send(1, 10.0) == pytest.approx(80.0)  # the first valid command ends the power-up hold
    assert send(2, 20.0) == pytest.approx(160.0)
    assert amp.advance(dt) == pytest.approx(160.0)  # one cycle without frames: within the bound
    assert amp.advance(dt) == pytest.approx(LOADED.safe_normal_force[j])  # silent: the safe force
    assert amp.status()["safe_state"] == 1
    k = 5  # the controller's cycles run on while the amplifier hears nothing
    for k in range(5, 5 + LOADED.recovery_cycles):
        send(k, 20.0)
    assert send(k + 1, 20.0) == pytest.approx(160.0) and amp.status()["safe_state"] == 0
    assert send(k + 2, 149.0) == pytest.approx(LOADED.safe_normal_force[j])  # beyond F^max: implausible
    first = k + 3
    for k in range(first, first + 1 + LOADED.recovery_cycles):
        send(k, 20.0)
    assert send(k + 1, 20.0) == pytest.approx(160.0)
    late = send(k + 2, 20.0, heartbeat_counter=k + 4)  # the setpoint 2 cycles behind its heartbeat
    assert late == pytest.approx(LOADED.safe_normal_force[j])


@pytest.fixture(scope="module")
def reference_firmware():
    return firmware.Firmware(LOADED, "clqg", "float")


def test_fault_fields_that_mean_nothing_are_refused():
    names, joints = {m.name for m in DATABASE.messages}, list(LOADED.joint_names)
    signals = {m.name: [s.name for s in m.signals] for m in DATABASE.messages}
    for fault, message in (
        (Fault("bus_off", 0.1, 0.2, "JOINT_A1"), "give no target"),
        (Fault("drop", 0.1, 0.2, "JOINT_A1", delay=0.01), "delay 0.01 — only for kind delay"),
        (Fault("drop", 0.1, 0.2, "JOINT_A1", amplifier_fault="stuck_output"), "only for kind"),
        (Fault("implausible", 0.1, 0.2, "JOINT_A1", signal="speed", value=1.0), "signal 'speed'"),
        (Fault("implausible", 0.1, 0.2, "JOINT_A1", signal="sliding_velocity"), "value None"),
        (Fault("amplifier", 0.1, 0.2, "A9", amplifier_fault="stuck_output"), "target 'A9'"),
        (Fault("drop", 0.2, 0.1, SETPOINT_FRAMES[0]), "window"),
        (Fault("drop", 0.1, math.nan, SETPOINT_FRAMES[0]), "window"),
        (Fault("replay", 0.1, 0.2, "JOINT_A1"), "age 0 — replay only, a whole number of cycles 1 … 4095"),
        (Fault("drop", 0.1, 0.2, "JOINT_A1", age=3), "age 3 — replay only"),
        (Fault("replay", 0.1, 0.2, "JOINT_A9", age=3), "target 'JOINT_A9'"),
    ):
        with pytest.raises(ModelError, match=message):
            check_faults([fault], names, joints, signals)
    for text, message in (
        ("drop:SETPOINT_A1:0.1:0.2:3", "takes no detail"),
        ("bus_off:X:1:2", None),
        ("melt:X:1:2", "kind 'melt'"),
        ("delay:JOINT_A1:1:2:soon", "the delay 'soon'"),
        ("replay:JOINT_A1:1:2", "the age None — a whole number of cycles 1 … 4095"),
        ("replay:JOINT_A1:1:2:4096", "the age '4096'"),
        ("replay:JOINT_A1:1:2:1.5", "the age '1.5'"),
    ):
        if message is None:
            with pytest.raises(ModelError, match="give no target"):
                check_faults([parse_fault(text)], names, joints, signals)
        else:
            with pytest.raises(ModelError, match=message):
                parse_fault(text)
    assert parse_fault("silent:CONTROLLER_STATUS:0:inf").end == math.inf
    assert parse_fault("replay:TIP_SENSORS:1:2:64") == Fault("replay", 1.0, 2.0, "TIP_SENSORS", age=64)


@pytest.mark.parametrize("age", [16, 50, 2000])
def test_a_replay_of_the_controllers_whole_stream_holds_every_joint_safe(reference_firmware, age, monkeypatch):
    """Heartbeat and setpoints replayed together ``age`` cycles old (a gateway replaying all it
    buffered): their CRCs hold and the 4-bit counters run on, so an amplifier that followed any
    heartbeat after a loss would drive the old setpoints. The heartbeat's 12-bit cycle keeps its
    order through the loss: every joint reaches the safe force within 3 cycles and holds it while
    the replay lasts; after it the jump back costs one cycle more than a single fault's recovery.
    With the receiver that followed whatever came after a loss, the same case fails."""
    dt = LOADED.sample_time
    start = age + 6
    frames = ["CONTROLLER_STATUS", *SETPOINT_FRAMES]
    faults = tuple(Fault("replay", start * dt, (start + 40) * dt, f, age=age) for f in frames)
    case = safety.Case(f"whole stream {age} cycles old", "replayed mid-run", faults, start + 80)
    measured = safety.signals(None, LOADED, case.cycles)
    row = safety.measure(safety.run_case_loop(reference_firmware, case, measured).record, faults, LOADED)
    assert row["ok"] and row["joints"] <= safety.DETECTION_LIMIT and row["recovery"] <= RECOVERY_LIMIT + 1, row
    post_init = AmplifierModel.__post_init__

    def forgetful(amplifier):  # the receiver before: after a loss, whatever heartbeat comes next
        post_init(amplifier)
        amplifier.heartbeat_watch.keeps_order = False

    monkeypatch.setattr(AmplifierModel, "__post_init__", forgetful)
    before = safety.measure(safety.run_case_loop(reference_firmware, case, measured).record, faults, LOADED)
    assert not before["ok"], before
