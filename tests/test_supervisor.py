"""The supervisor of local mode (issue 33): the generated ``<prefix>_supervisor.c`` is its Python
reference bit for bit (heartbeats, decoded statuses, health words) over a script with lost nodes,
a lost heartbeat, bad inputs, stale echoes, corrupted and foreign frames and mode requests; each
health bit rises exactly where its fault is and nowhere else; on the SIL bench it sees a silent
node and nodes that run alone, and a healthy run leaves every word 0."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import small_study

from smartjoint.bench import e2e
from smartjoint.bench.joint_node import JointNode
from smartjoint.bench.local_loop import LocalLoop
from smartjoint.bench.supervisor import ALONE, SAFE, SILENT, STALE, CompiledSupervisor, Supervisor, compiled_supervisor
from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control import artifact
from smartjoint.design.control.runs import run_semi_active
from smartjoint.design.network import joint_node, protocol

ROOT = Path(__file__).resolve().parents[1]
LAW = joint_node.NODE_LAW
SILENT_NODE = (500, 900)  # node 1's status frames lost
NO_HEARTBEAT = (1200, 1600)  # the heartbeat lost on the way to the nodes
BAD_INPUT = (1800, 1805)  # node 2's velocity NaN
SAFE_REQUESTED = (2000, 2300)


@pytest.fixture(scope="module")
def reference():
    return artifact.load(ROOT / "firmware" / "generated" / "controller.json")


def _script(a, count: int = 2600):
    """Per sample: the frames the supervisors receive, and the mode requested before the step.
    Three reference nodes answer the heartbeat the Python supervisor sends; the script loses,
    corrupts, forges and replays frames on the way."""
    configs = [joint_node.node_config(a, j) for j in range(len(a.joint_names))]
    nodes = [JointNode(c) for c in configs]
    driver = Supervisor.of(configs)
    rng = np.random.default_rng(3)
    script = []
    for k in range(count):
        request = law_registry.MODE_SAFE if SAFE_REQUESTED[0] <= k < SAFE_REQUESTED[1] else LAW.mode
        if k in (100, 2400):
            request = 2  # another law: refused, the mode stays
        driver.request(request)
        driver.step()
        heartbeat = driver.transmit()
        if heartbeat is not None and not NO_HEARTBEAT[0] <= k < NO_HEARTBEAT[1]:
            for node in nodes:
                node.receive(*heartbeat)
        frames = []
        for j, node in enumerate(nodes):
            velocity = np.nan if j == 2 and BAD_INPUT[0] <= k < BAD_INPUT[1] else rng.normal(0, 1e-5)
            node.step(velocity, rng.normal(0, 20), rng.uniform(10, 400))
            status = node.transmit()
            if status is not None and not (j == 1 and SILENT_NODE[0] <= k < SILENT_NODE[1]):
                frames.append(status)
        if k == 2100:  # a status with a good CRC and counter but an echo three heartbeats old
            frame_id, data = frames[0]
            payload = bytearray(data)
            echoed = (driver.heartbeats - 3) % e2e.CYCLE_MODULO
            payload[1] = (payload[1] & 0x0F) | ((echoed % 16) << 4)
            fresh = e2e.freshness(echoed)  # as its node would protect it: the echoed heartbeat's
            frames[0] = (frame_id, bytes(e2e.protect(frame_id, payload, payload[1] & 0x0F, fresh)))
        if k == 2200:
            frames.append(frames[0])  # a repeat: refused
            frames.append((frames[1][0], frames[1][1][:1] + bytes([frames[1][1][1] ^ 0x01]) + frames[1][1][2:]))
            frames.append((0x123, bytes(8)))  # a frame of nobody's
            frames.append((joint_node.NODE_STATUS_BASE, bytes(7)))  # wrong length
        for frame in frames:
            driver.receive(*frame)
        script.append((request, frames))
    return script


def _view(supervisor) -> list:
    if isinstance(supervisor, CompiledSupervisor):
        nodes = supervisor.state.nodes
        return [(n.silent, n.command, n.applied, n.mode, n.faults, n.law_status, n.echo, n.health) for n in nodes]
    return [
        (n.silent, n.command, n.applied, n.mode, n.faults, n.law_status, n.echo, n.health) for n in supervisor.nodes
    ]


@pytest.mark.numerics
def test_the_generated_supervisor_is_its_reference_bit_for_bit(reference):
    configs = [joint_node.node_config(reference, j) for j in range(3)]
    python, compiled = Supervisor.of(configs), CompiledSupervisor(compiled_supervisor(reference))
    health = []
    for k, (request, frames) in enumerate(_script(reference)):
        assert python.request(request) == compiled.request(request) == (request != 2), k
        python.step()
        compiled.step()
        assert python.transmit() == compiled.transmit(), k
        for frame in frames:
            assert python.receive(*frame) == compiled.receive(*frame), (k, frame)
        assert _view(python) == _view(compiled), k
        assert python.mode == compiled.mode
        health.append(python.health)
    health = np.array(health)
    timeout = configs[0].timeout_samples
    # silent: node 1 while its statuses are lost, from the timeout after its last one until its
    # first one again
    silent = np.argwhere(health & SILENT)
    lost = silent[silent[:, 0] < NO_HEARTBEAT[0]]
    assert set(lost[:, 1]) == {1}
    first, last = lost[:, 0].min(), lost[:, 0].max()
    assert SILENT_NODE[0] + timeout - 10 <= first <= SILENT_NODE[0] + timeout
    # its frames are taken again once its 4-bit counter is within a step of 1 … 3 of the last
    # accepted one (docs/can.md): within 16 periods of its return
    assert SILENT_NODE[1] - 1 <= last < SILENT_NODE[1] + 16 * 10
    # and every node while the heartbeat is lost, as the freshness byte requires: from the 16th
    # heartbeat after the last one the nodes took (k = 1190) their statuses echo it 16 heartbeats
    # old — a replay's bytes — and fail the CRC; silent one timeout after the last one taken
    unheard = silent[silent[:, 0] >= NO_HEARTBEAT[0]]
    first_refused = NO_HEARTBEAT[0] - 10 + 16 * 10
    assert set(unheard[:, 1]) == {0, 1, 2} and unheard[:, 0].min() == first_refused - 10 + timeout + 1
    assert unheard[:, 0].max() < NO_HEARTBEAT[1] + 16 * 10
    # alone: every node, while the heartbeat is lost (after the nodes' own timeout), only then
    alone = np.argwhere(health & ALONE)
    assert set(alone[:, 1]) == {0, 1, 2} and NO_HEARTBEAT[0] < alone[:, 0].min() <= NO_HEARTBEAT[0] + timeout
    assert NO_HEARTBEAT[1] - 1 <= alone[:, 0].max() < NO_HEARTBEAT[1] + 16 * 10  # as for the silent node
    # safe: node 2 around its bad input (and its recovery), never while SAFE is requested
    safe = np.argwhere(health & SAFE)
    assert set(safe[:, 1]) == {2} and BAD_INPUT[0] <= safe[:, 0].min() and safe[:, 0].max() < SAFE_REQUESTED[0]
    # stale: every node while the heartbeat is lost (they echo the last one they took), and
    # node 0 from the forged status to its next one
    stale = np.argwhere(health & STALE)
    lost = stale[stale[:, 0] < SAFE_REQUESTED[0]]
    assert set(lost[:, 1]) == {0, 1, 2} and NO_HEARTBEAT[0] < lost[:, 0].min() <= NO_HEARTBEAT[0] + 10
    forged = stale[stale[:, 0] >= SAFE_REQUESTED[0]]
    assert set(forged[:, 1]) == {0} and forged[:, 0].min() == 2100 and forged[:, 0].max() < 2110
    # healthy elsewhere: the first sample's status already clears the power-up's silence
    assert not np.any(health[: SILENT_NODE[0]]) and not np.any(health[2300:])


def test_the_heartbeat_carries_its_whole_count_as_the_supervision_dbc_says(reference):
    """Both twins' heartbeats, across the count's wrap at 4096: the DBC decodes heartbeat n's
    counter as n mod 16 and its cycle_high as bits 4–11 of n, its CRC holds with that byte as the
    freshness byte, and the node's 12-bit rule (``e2e.check_heartbeat``) takes each with a step of 1."""
    assert joint_node.HEARTBEAT_COUNTS == e2e.CYCLE_MODULO
    db = protocol.load_dbc(protocol.dbc_text(joint_node.supervision_database(reference)))
    configs = [joint_node.node_config(reference, j) for j in range(3)]
    python, compiled = Supervisor.of(configs), CompiledSupervisor(compiled_supervisor(reference))
    python.heartbeats = compiled.state.heartbeats = 4090
    counts, last = [], None
    for _ in range(120):
        python.step()
        compiled.step()
        heartbeat = python.transmit()
        assert heartbeat == compiled.transmit()
        if heartbeat is not None:
            decoded = db.decode_message(*heartbeat, decode_choices=False)
            checked = e2e.check_heartbeat(*heartbeat, last)
            assert checked.ok and checked.counter == decoded["cycle_high"] * 16 + decoded["counter"]
            counts.append(last := checked.counter)
    assert counts == [n % 4096 for n in range(4091, 4103)] and python.heartbeats == compiled.heartbeats == 6


STATUS_REPLAY = (80, 100)  # heartbeat periods: genuine statuses until 80, replayed ones after
FIRST_COUNT = 4060  # the supervisors' count before the run: it wraps at 4096 in period 35


def _status_replay(supervisor, a, age: int):
    """Supervisor and node 0 (``JointNode``) in the loop, the supervisor's count started at
    FIRST_COUNT: the node's genuine statuses until period STATUS_REPLAY[0]; there the status sent
    ``age`` periods before, then the genuine one; after it only the statuses ``age`` periods old
    (seamless: the node sends one a period, so their 4-bit counter and echo are the genuine
    ones'). Per sample: the frames delivered with whether each was taken, and node 0's health;
    and the node's genuine statuses."""
    node, sent, out = JointNode(joint_node.node_config(a, 0)), [], []
    if isinstance(supervisor, CompiledSupervisor):
        supervisor.state.heartbeats = FIRST_COUNT
    else:
        supervisor.heartbeats = FIRST_COUNT
    replay_at = STATUS_REPLAY[0] * 10
    for k in range(STATUS_REPLAY[1] * 10):
        supervisor.step()
        heartbeat = supervisor.transmit()
        if heartbeat is not None:
            assert node.receive(*heartbeat)
        node.step(0.0, 10.0, 200.0)
        status, frames = node.transmit(), []
        if status is not None:
            sent.append(status)
            frames = ([sent[-1 - age]] if k >= replay_at else []) + ([status] if k <= replay_at else [])
        out.append(([(frame, supervisor.receive(*frame)) for frame in frames], supervisor.health[0]))
    return out, sent


@pytest.mark.parametrize("age", [16, 32, 48, 64])
def test_a_node_status_replayed_16_m_heartbeats_old_fails_the_supervisors_e2e(reference, age):
    """A NODE_STATUS replayed 16, 32, 48 or 64 heartbeats old — its CRC valid as sent, its 4-bit
    counter and echo those of the genuine status it replaces — is refused by both twins (its
    freshness byte is the echoed heartbeat's, 1 … 4 off the one the supervisor reconstructs),
    while the genuine status passes; with only replays on the bus node 0 falls silent one
    timeout after its last genuine status. Across the count's wrap at 4096 too."""
    configs = [joint_node.node_config(reference, j) for j in range(3)]
    python, sent = _status_replay(Supervisor.of(configs), reference, age)
    compiled, _ = _status_replay(CompiledSupervisor(compiled_supervisor(reference)), reference, age)
    assert python == compiled
    first = STATUS_REPLAY[0]
    for n, genuine in enumerate(sent[first:], first):
        replay, echoed = sent[n - age], FIRST_COUNT + n - age + 1  # the heartbeat its node echoed
        assert replay[1][1] == genuine[1][1]  # counter and echo: the 4-bit scheme cannot tell them apart
        assert e2e.check(*replay, None, e2e.freshness(echoed)).crc_ok  # valid as originally sent
        assert e2e.freshness(echoed) != e2e.freshness(echoed + age)
    taken = [t for frames, _ in python for t in frames]
    assert len(taken) == len(sent) + 1 and all(ok for _, ok in taken[:first])
    assert taken[first : first + 2] == [(sent[first - age], False), (sent[first], True)]
    assert not any(ok for _, ok in taken[first + 2 :])
    health = [h for _, h in python]
    silent = first * 10 + configs[0].timeout_samples + 1  # the last status taken at sample first * 10
    assert not any(health[:silent]) and set(health[silent:]) == {SILENT}


@pytest.fixture(scope="module")
def study():
    return small_study()


def _local(s, a, **options):
    loop = LocalLoop(a, "double", channel=f"smartjoint-supervisor-{sorted(options)}", **options)
    try:
        run_semi_active(s, LAW.display, loop)
        return np.array(loop.record.health)
    finally:
        loop.close()


@pytest.mark.numerics
def test_on_the_bench_it_sees_a_silent_node_and_nodes_alone(study):
    """SIL with the generated nodes and supervisor: a healthy run keeps every word 0; node 1's
    status frames lost from the start make it silent (never heard) and nothing else; the heartbeat
    lost after 20 ms makes every node report that it runs alone, on a stale echo, until its
    statuses echo a heartbeat 16 old and fail their CRC (silent); SAFE requested raises nothing."""
    s, a = study
    assert not np.any(_local(s, a))
    health = _local(s, a, silent_nodes=(1,))
    assert not np.any(health[:, 0]) and np.all(health[:, 1] == SILENT)  # never heard
    health = _local(s, a, heartbeat_until=0.02)
    timeout = a.timeout_cycles * 10
    # the last heartbeat went out at sample 10; the nodes' statuses echo it 16 heartbeats old from
    # sample 170 on, as a replay would, and fail their CRC (the freshness byte requires it): silent
    # one timeout after the last one taken (160)
    silent = 160 + timeout + 1
    assert not np.any(health[: 10 + timeout]) and np.all(health[10 + timeout : silent] == ALONE | STALE)
    assert np.all(health[silent:] == SILENT | ALONE | STALE) and len(health) > silent
    assert not np.any(_local(s, a, mode=law_registry.MODE_SAFE))
    with pytest.raises(ModelError, match=r"^mode: 2 — the supervisor requests"):
        LocalLoop(a, "double", mode=2)
