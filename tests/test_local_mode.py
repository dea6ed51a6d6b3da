"""Local mode on the SIL bench (issue 33): one generated joint node per joint, each driving its
own amplifier model, a supervisor's heartbeat on a python-can bus (``bench.local_loop``). The
local run gives the model in the loop's SISO numbers within a band measured here, the central
SIL run's within both bands; with the heartbeat lost the nodes go on as before; with SAFE every
joint holds its safe force; only the node law closes the loop."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import small_study

from smartjoint.bench.interconnection import CanLoop, LocalNodesLoop
from smartjoint.bench.local_loop import LocalLoop
from smartjoint.bench.rounding_spread import perturbed
from smartjoint.bench.target import missing_tools as target_missing
from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control.interconnection import PythonLoop
from smartjoint.design.control.runs import run_passive, run_semi_active

LAW = law_registry.node_law()


@pytest.fixture(scope="module")
def study():
    """The small truss's study over 0.2 s and its artefact (ε = 3e-4 m/s)."""
    return small_study()


def _deviation(run, reference) -> float:
    return abs(run.energy_measure() / reference.energy_measure() - 1.0)


@pytest.mark.numerics
def test_the_local_run_is_the_siso_study_within_its_band_and_the_central_runs(study):
    """Band of a loop: twice its double build's deviation from MIL (the amplifier's force ↔
    voltage round trip; the frames' quantisation centrally) plus ten times MIL's spread under
    6e-8 perturbations of its commands (float rounding)."""
    s, artifact = study
    mil, _ = PythonLoop(artifact).run(s, LAW.name)
    spread = max(
        _deviation(run_semi_active(s, LAW.display, perturbed(LAW.python_reference(artifact), 6e-8, k)), mil)
        for k in range(3)
    )
    runs = {}
    for where, loop in (("local", LocalNodesLoop), ("central", CanLoop)):
        for real in ("float", "double"):
            run, safe = loop(artifact, real).run(s, LAW.name)
            assert safe == 0, (where, real)
            np.testing.assert_array_equal(run.time, mil.time)
            runs[where, real] = run
    bands = {w: 2.0 * _deviation(runs[w, "double"], mil) + 10.0 * spread for w in ("local", "central")}
    assert _deviation(runs["local", "float"], mil) <= bands["local"], bands
    assert _deviation(runs["local", "float"], runs["central", "float"]) <= bands["local"] + bands["central"], bands


def _local_run(s, artifact, **options):
    loop = LocalLoop(artifact, "double", channel=f"smartjoint-local-test-{len(options)}", **options)
    try:
        return run_semi_active(s, LAW.display, loop), loop
    finally:
        loop.close()


def test_a_lost_heartbeat_leaves_the_nodes_running_their_law(study):
    """The supervisor silent after 20 ms: every node flags heartbeat_lost and commands what it
    commanded with the heartbeat (the same run bit for bit)."""
    s, artifact = study
    normal, _ = _local_run(s, artifact)
    lost, loop = _local_run(s, artifact, heartbeat_until=0.02)
    assert lost.energy.tobytes() == normal.energy.tobytes()
    faults = np.array(loop.record.faults)
    assert np.all(faults[-10:] == 2) and not np.any(faults[:20] & 2)


def test_safe_from_the_supervisor_holds_every_joint_at_its_safe_force(study):
    """Heartbeat mode SAFE: the run of the passive safe force (the amplifier's round trip aside)."""
    s, artifact = study
    safe_run, loop = _local_run(s, artifact, mode=law_registry.MODE_SAFE)
    passive = run_passive(s, "safe", artifact.safe_normal_force)
    assert _deviation(safe_run, passive) < 1e-9
    assert np.all(np.array(loop.record.faults) & 8)


def test_only_the_node_law_closes_the_local_loop(study):
    s, artifact = study
    other = next(law for law in law_registry.LAWS.values() if law.name != LAW.name)
    with pytest.raises(ModelError, match=r"^law: .* — the joint nodes run"):
        LocalNodesLoop(artifact).run(s, other.name)


@pytest.mark.skipif(target_missing() is not None, reason="the ARM toolchain and QEMU are needed")
def test_a_node_image_on_the_emulated_target_beside_the_bench_is_the_host_node(study):
    """Processor in the loop for local mode: joint 0's node runs as its image on the emulated
    Cortex-M4F (bench.node_target.TargetNode), the others on the host; every command, fault and
    status frame is the all-host float run's bit for bit, and so is the energy."""
    s, artifact = study
    runs = {}
    for where, joints in (("host", ()), ("target", (0,))):
        loop = LocalLoop(artifact, "float", channel=f"smartjoint-local-pil-{where}", target_joints=joints)
        try:
            runs[where] = run_semi_active(s, LAW.display, loop), loop.record, dict(loop.frame_counts)
        finally:
            loop.close()
    (host, host_record, host_frames), (pil, pil_record, pil_frames) = runs["host"], runs["target"]
    assert np.array(pil_record.command, np.float64).tobytes() == np.array(host_record.command, np.float64).tobytes()
    assert pil_record.faults == host_record.faults and pil_frames == host_frames
    assert pil.energy.tobytes() == host.energy.tobytes()
    with pytest.raises(ModelError, match=r"^real: 'double' — a node on the target runs the float build only$"):
        LocalLoop(artifact, "double", target_joints=(0,))


def test_smartjoint_run_reports_local_mode_against_the_same_mil_run(study):
    """Stage 8 of `smartjoint run` for `[network] siso = "local"`: the local run's E(t_e) against
    the central SIL row's MIL figure, and the report's row carries both differences and the band."""
    from smartjoint.pipeline_local import local_mode_markdown, local_mode_run

    s, artifact = study
    mil, _ = PythonLoop(artifact).run(s, LAW.name)
    central = {"energy_measure_mil": mil.energy_measure(), "mil_spread_under_float_rounding": (-0.01, 0.02)}
    sil_check = {"laws": {LAW.name: central | {"energy_measure_difference": 0.005}}}
    local = local_mode_run(artifact, s, sil_check, lambda line: None)
    run, _ = LocalNodesLoop(artifact, "float").run(s, LAW.name)
    assert local["energy_measure_local"] == run.energy_measure()
    assert local["supervisor_health"] == dict.fromkeys(("silent", "alone", "safe", "stale"), 0)
    assert local["node_samples"] == (len(run.time) - 1) * len(artifact.joint_names)  # a step per sample interval
    assert local["difference"] == run.energy_measure() / mil.energy_measure() - 1.0
    row = local_mode_markdown(sil_check | {"local": local})
    assert f"| {LAW.name} (local) |" in row and "+0.50 %" in row and "-1.0 … +2.0 %" in row
    assert "saw every node healthy at every sample" in row
    assert local_mode_markdown(sil_check) == ""
