"""The joint node of local mode (issue 33): the generated node firmware is its Python reference
bit for bit (double build: commands, fault bits, status frames), runs the central SISO law's
numbers for its joint, follows the policy of docs/safety.md on heartbeat loss, SAFE and bad
inputs, and the supervision bus of 12 joints stays within 15 % of CAN FD 1/5 Mbit/s."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from smartjoint.bench import e2e, node_target, target
from smartjoint.bench.joint_node import CompiledNode, JointNode, compiled_nodes
from smartjoint.common import law_registry
from smartjoint.design.control import artifact
from smartjoint.design.control.laws import siso_law
from smartjoint.design.network import busload, joint_node, protocol
from smartjoint.design.plant import Measurements

ROOT = Path(__file__).resolve().parents[1]
LAW = joint_node.NODE_LAW.mode
SAFE = law_registry.MODE_SAFE


@pytest.fixture(scope="module")
def reference():
    return artifact.load(ROOT / "firmware" / "generated" / "controller.json")


@pytest.fixture(scope="module")
def module(reference):
    return compiled_nodes(reference, "double")


def _heartbeat(mode: int, count: int) -> bytes:
    """The supervisor's heartbeat number ``count`` (mod 4096): counter bits 0–3, cycle_high 4–11."""
    payload = bytearray(joint_node.HEARTBEAT_LENGTH)
    payload[2] = mode
    payload[joint_node.HEARTBEAT_CYCLE_BYTE] = fresh = e2e.freshness(count)
    return bytes(e2e.protect(joint_node.HEARTBEAT_ID, payload, count, fresh))


def _script(count: int, seed: int, faults: bool):
    """(frames, measurement) per sample: a heartbeat every 10 samples (law mode, a few SAFE, a
    silence, a bad CRC, a repeat, replays 16 and 32 heartbeats old, the count's wrap at 4096),
    joint measurements around the boundary layer, with NaN and out-of-range inputs when ``faults``."""
    rng = np.random.default_rng(seed)
    heartbeats, sent, script = 4000, {}, []
    for k in range(count):
        frames = []
        if k % 10 == 0:
            # The supervisor's whole count, running on through the silence: since the 12-bit
            # count is judged, a bare 4-bit counter wrapping to 0 under cycle_high 0 would be stale.
            heartbeats = (heartbeats + 1) % 4096
        if k % 10 == 0 and not 400 <= k < 700:  # 300 samples of silence: the heartbeat is lost
            mode = SAFE if 1000 <= k < 1100 else LAW
            frame = bytearray(_heartbeat(mode, heartbeats))
            if faults and k in (1500, 1510):
                frame[3] ^= 0x40  # a corrupted heartbeat
            frames.append((joint_node.HEARTBEAT_ID, bytes(frame)))
            sent[heartbeats] = bytes(frame)
            if k == 1600:
                frames.append((joint_node.HEARTBEAT_ID, bytes(frame)))  # a repeat
            if k in (1800, 1900):  # the heartbeat 16 or 32 old after it: its 4-bit counter 1 ahead
                frames.append((joint_node.HEARTBEAT_ID, sent[(heartbeats + 1 - (k - 1700) // 100 * 16) % 4096]))
        velocity, friction, applied = rng.normal(0, 1e-5), rng.normal(0, 20), rng.uniform(10, 400)
        if faults and rng.random() < 0.01:
            velocity = float(rng.choice([np.nan, np.inf, 5.0]))
        if faults and rng.random() < 0.01:
            applied = float(rng.choice([np.nan, -100.0, 1e4]))
        script.append((frames, (velocity, friction, applied)))
    return script


def _run(node, script):
    """Per sample: the command, fault and status bytes, the status frame and whether each frame was taken."""
    out = []
    for frames, measured in script:
        taken = tuple(node.receive(*frame) for frame in frames)
        command = node.step(*measured)
        out.append((command, node.faults, node.status, node.transmit(), taken))
    return out


@pytest.mark.numerics
@pytest.mark.parametrize("joint", [0, 2])
def test_the_node_firmware_is_its_reference_bit_for_bit(reference, module, joint):
    """Double build against bench.joint_node over 2 000 samples with heartbeat loss, SAFE, bad
    heartbeats and bad inputs: every command, fault byte, status byte and frame equal."""
    script = _script(2000, seed=joint + 5, faults=True)
    python = _run(JointNode(joint_node.node_config(reference, joint)), script)
    compiled = _run(CompiledNode(module, reference, joint), script)
    for k, (p, c) in enumerate(zip(python, compiled)):
        assert np.float64(p[0]).tobytes() == np.float64(c[0]).tobytes(), (k, p, c)
        assert p[1:] == c[1:], (k, p, c)
    faults = {p[1] for p in python}
    assert {1, 2, 4, 8} <= {bit for f in faults for bit in (1, 2, 4, 8) if f & bit}, faults


@pytest.mark.numerics
def test_local_nodes_run_the_central_siso_law_numbers(reference, module):
    """Fault-free, every node in the law's mode: each joint's command is the central SISO law's
    for that joint, bit for bit (MIL: the same law, the same numbers)."""
    central = siso_law(reference)
    nodes = [CompiledNode(module, reference, j) for j in range(len(reference.joint_names))]
    for node in nodes:
        node.receive(joint_node.HEARTBEAT_ID, _heartbeat(LAW, 1))
    rng = np.random.default_rng(11)
    l = len(nodes)
    for k in range(3000):
        m = Measurements(k * 1e-3, np.zeros(2), rng.normal(0, 1e-5, l), rng.normal(0, 20, l), rng.uniform(10, 400, l))
        expected = central.step(m)
        if k % 10 == 0:
            for node in nodes:
                node.receive(joint_node.HEARTBEAT_ID, _heartbeat(LAW, k // 10 + 2))  # the count, not mod 16
        local = [n.step(m.sliding_velocity[j], m.friction_force[j], m.normal_force[j]) for j, n in enumerate(nodes)]
        assert np.asarray(local).tobytes() == np.asarray(expected).tobytes(), k
    assert central.status == 0


def test_the_policy_on_heartbeat_loss_safe_and_bad_inputs(reference, module):
    """Before a heartbeat: safe. With the law's mode: the law. Heartbeat lost: the law goes on,
    with the heartbeat_lost bit. SAFE: the safe force. A bad input: safe at once and for
    recovery_cycles usable samples after it."""
    config = joint_node.node_config(reference, 1)
    node = CompiledNode(module, reference, 1)
    safe = config.safe_normal_force
    fast = 50.0 * float(config.boundary_layer)  # μ·v/ε = 0.15 · 50 = 7.5: F^max whatever the artefact's ε
    assert node.step(fast, 30.0, 200.0) == safe and node.faults & 8  # no heartbeat yet
    node.receive(joint_node.HEARTBEAT_ID, _heartbeat(LAW, 1))
    node.step(fast, 30.0, 200.0)
    assert node.step(fast, 30.0, 200.0) == config.normal_force_max
    for _ in range(config.timeout_samples + 5):
        command = node.step(fast, 30.0, 200.0)
    assert command == config.normal_force_max and node.faults == 2  # lost, and the law runs on
    assert node.receive(joint_node.HEARTBEAT_ID, _heartbeat(SAFE, 2))
    assert node.step(fast, 30.0, 200.0) == safe and node.faults == 8
    node.receive(joint_node.HEARTBEAT_ID, _heartbeat(LAW, 3))
    assert node.step(np.nan, 30.0, 200.0) == safe and node.faults & 1
    held = [node.step(fast, 30.0, 200.0) for _ in range(config.recovery_cycles + 1)]
    assert held[:-1] == [safe] * config.recovery_cycles and held[-1] == config.normal_force_max
    assert not node.receive(joint_node.HEARTBEAT_ID, _heartbeat(SAFE, 3))  # a repeated counter


REPLAY = (60, 140, 150)  # heartbeat periods: genuine until 60, replayed until 140, genuine again
START = 4050  # the first heartbeat's count: the genuine stream crosses the wrap at 4096


def _replay_script(age: int | None, seed: int = 9):
    """A heartbeat (the law's mode) every 10 samples, counts START, START + 1, …; from period
    REPLAY[0] to REPLAY[1], when ``age`` is given, the last ``age`` heartbeats the node took
    replayed in a loop instead — seamless: the 4-bit counter steps by 1 throughout, across the
    loop's seam too, as the genuine stream's would. Measurements as in ``_script``, fault-free."""
    rng = np.random.default_rng(seed)
    script = []
    for k in range(REPLAY[2] * 10):
        period, frames = k // 10, []
        if k % 10 == 0:
            count = START + period
            if age is not None and REPLAY[0] <= period < REPLAY[1]:
                count = START + REPLAY[0] - age + (period - REPLAY[0]) % age
            frames.append((joint_node.HEARTBEAT_ID, _heartbeat(LAW, count % 4096)))
        script.append((frames, (rng.normal(0, 1e-5), rng.normal(0, 20), rng.uniform(10, 400))))
    return script


@pytest.mark.parametrize("age", [16, 32, 48, 64])
def test_a_heartbeat_stream_replayed_16_m_heartbeats_old_does_not_feed_the_node(reference, module, age):
    """A seamless replay of the heartbeats 16·m old (m = 1 … 4), whose 4-bit counter alone would
    pass every frame: neither twin takes one (their whole 12-bit count is behind), both report
    heartbeat_lost one timeout after the last genuine heartbeat and keep its mode (the law runs on,
    its commands those of the genuine run bit for bit), and both are fed again by the genuine
    stream's second heartbeat (the first is a jump). A genuine stream keeps them fed throughout."""
    config = joint_node.node_config(reference, 0)
    replayed, genuine = _replay_script(age), _replay_script(None)
    # the 4-bit rule alone (CRC with the byte carried, counter steps 1 … 3) passes the replay
    last = None
    for frames, _ in replayed:
        for frame_id, data in frames:
            checked = e2e.check(frame_id, data, last, data[joint_node.HEARTBEAT_CYCLE_BYTE])
            assert checked.ok
            last = checked.counter
    runs = {}
    for name, script in (("replayed", replayed), ("genuine", genuine)):
        python = _run(JointNode(config), script)
        compiled = _run(CompiledNode(module, reference, 0), script)
        assert [np.float64(p[0]).tobytes() for p in python] == [np.float64(c[0]).tobytes() for c in compiled]
        assert [p[1:] for p in python] == [c[1:] for c in compiled], name
        runs[name] = python
    taken = [p[4][0] for p in runs["replayed"][::10]]
    assert taken == [True] * REPLAY[0] + [False] * (REPLAY[1] - REPLAY[0] + 1) + [True] * (REPLAY[2] - REPLAY[1] - 1)
    lost = [k for k, p in enumerate(runs["replayed"]) if p[1] & 2]
    last_genuine = (REPLAY[0] - 1) * 10
    assert lost == list(range(last_genuine + config.timeout_samples, (REPLAY[1] + 1) * 10))
    assert all(p[1] == 2 for p in runs["replayed"][lost[0] : lost[-1] + 1])  # the law runs on: no safe_commanded
    assert [p[0] for p in runs["replayed"]] == [p[0] for p in runs["genuine"]]
    assert all(p[4] == (True,) for p in runs["genuine"][::10]) and not any(p[1] & 2 for p in runs["genuine"])


@pytest.mark.parametrize("silence", [0, 1000])
def test_a_node_that_lost_the_heartbeat_follows_a_restarted_supervisor(reference, module, silence):
    """The supervisor stops at count 1 999 and, after a silence, starts again from 1, now asking
    for SAFE: a count its node reads as 1 902 behind. A node that has lost the heartbeat takes the
    new supervisor's first heartbeat (a count of 0 … 3 is a start) and holds the safe force from
    there, C and Python alike; without the loss (the new count right after the old) it is not
    taken, as a replay of a start would not be."""
    config = joint_node.node_config(reference, 0)
    restart = 1000 + silence
    script = []
    for k in range(restart + 200):
        frames = []
        if k < 1000 and k % 10 == 0:
            frames.append((joint_node.HEARTBEAT_ID, _heartbeat(LAW, 1900 + k // 10)))
        if k >= restart and k % 10 == 0:
            frames.append((joint_node.HEARTBEAT_ID, _heartbeat(SAFE, 1 + (k - restart) // 10)))
        script.append((frames, (0.0, 0.0, 100.0)))
    python = _run(JointNode(config), script)
    compiled = _run(CompiledNode(module, reference, 0), script)
    assert [p[1:] for p in python] == [c[1:] for c in compiled]
    assert [np.float64(p[0]).tobytes() for p in python] == [np.float64(c[0]).tobytes() for c in compiled]
    taken = python[restart][4]
    if silence:
        assert taken == (True,) and python[restart][0] == config.safe_normal_force
        assert all(p[4] == (True,) for p in python[restart::10]) and not python[-1][1] & 2
    else:
        assert taken == (False,) and python[restart][0] != config.safe_normal_force


def test_the_status_frame_decodes_with_the_supervision_dbc(reference, module):
    """The node's NODE_STATUS frame is what the local mode's DBC says (cantools decodes it)."""
    db = protocol.load_dbc(protocol.dbc_text(joint_node.supervision_database(reference)))
    node = CompiledNode(module, reference, 2)
    node.receive(joint_node.HEARTBEAT_ID, _heartbeat(LAW, 0x127))
    node.step(0.0, 10.0, 123.44)
    frame_id, data = node.transmit()
    decoded = db.decode_message(frame_id, data)
    assert db.get_message_by_frame_id(frame_id).name == "NODE_STATUS_A3"
    assert decoded["sync"] == 7 and decoded["applied"] == pytest.approx(123.44, abs=0.01)
    assert decoded["command"] == pytest.approx(joint_node.node_config(reference, 2).normal_force_min, abs=0.01)
    # its CRC covers the echoed heartbeat's bits 4-11 (0x12), not sent: another byte fails
    assert e2e.check(frame_id, data, None, 0x12).ok and e2e.freshness_of(frame_id, data) == 0x12


@pytest.mark.parametrize("joints, limit", [(3, 0.03), (12, 0.15)])
def test_local_mode_loads_the_bus_lightly(joints, limit):
    """Supervision every 10 samples at 1 kHz on CAN FD 1/5 Mbit/s: 12 joints within 15 %."""
    design = SimpleNamespace(joint_names=[f"J{k}" for k in range(joints)], sample_time=1e-3, artifact_sha256="0" * 64)
    db = protocol.load_dbc(protocol.dbc_text(joint_node.supervision_database(design)))
    assert len(db.messages) == joints + 1
    assert busload.bus_load(db, 1_000_000, 5_000_000).load <= limit


@pytest.mark.skipif(target.missing_tools() is not None, reason=f"{target.missing_tools()} (CI installs them)")
def test_a_node_image_fits_its_target_and_computes_what_the_host_computes(reference):
    """Joint A1's node image on QEMU mps2-an386: ≤ 4 KiB flash, ≤ 256 B RAM, ≤ 200 instructions
    a step (issue 33), and its commands equal the host float build's bit for bit."""
    measured = node_target.measure(reference, 0, steps=300)
    limits = node_target.LIMITS
    assert measured["flash"] <= limits["flash"] and measured["ram"] <= limits["ram"], measured
    assert measured["instructions_per_step"] <= limits["instructions"], measured["instructions_per_step"]
    host = CompiledNode(compiled_nodes(reference, "float"), reference, 0)
    host.receive(joint_node.HEARTBEAT_ID, node_target.heartbeat())
    commands = np.array([host.step(*map(float, row)) for row in measured["inputs"]], dtype=np.float32)
    assert commands.tobytes() == measured["commands"].tobytes()
    assert len(set(commands.tolist())) > 100  # commands between the limits, not only the clip's ends
