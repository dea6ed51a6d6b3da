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
from smartjoint.design.network import joint_node

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
            payload[1] = (payload[1] & 0x0F) | (((driver.counter - 3) % 16) << 4)
            frames[0] = (frame_id, bytes(e2e.protect(frame_id, payload, payload[1] & 0x0F)))
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
    # silent: node 1 only, from the timeout after its last status until its first one again
    silent = np.argwhere(health & SILENT)
    assert set(silent[:, 1]) == {1}
    first, last = silent[:, 0].min(), silent[:, 0].max()
    assert SILENT_NODE[0] + timeout - 10 <= first <= SILENT_NODE[0] + timeout
    # its frames are taken again once its 4-bit counter is within a step of 1 … 3 of the last
    # accepted one (docs/can.md): within 16 periods of its return
    assert SILENT_NODE[1] - 1 <= last < SILENT_NODE[1] + 16 * 10
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
    lost after 20 ms makes every node report that it runs alone, on a stale echo; SAFE requested
    raises nothing."""
    s, a = study
    assert not np.any(_local(s, a))
    health = _local(s, a, silent_nodes=(1,))
    assert not np.any(health[:, 0]) and np.all(health[:, 1] == SILENT)  # never heard
    health = _local(s, a, heartbeat_until=0.02)
    assert np.all(health[-10:] == ALONE | STALE) and not np.any(health[:20])
    assert not np.any(_local(s, a, mode=law_registry.MODE_SAFE))
    with pytest.raises(ModelError, match=r"^mode: 2 — the supervisor requests"):
        LocalLoop(a, "double", mode=2)
