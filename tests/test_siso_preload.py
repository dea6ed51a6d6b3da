"""The SISO law's own F_N^min, a preload (issue 33, benchmarks/mast_siso_grid.py): a setting of
the law's registry entry (``[control] siso_normal_force_min``, ``laws.siso.normal_force_min``),
by default the joints' F_N^min (the paper's law, so a version-5 artefact reads with the same
numbers); the Python reference, the generated C (double bit for bit), the joint nodes, the
controller FMU and the study all command it at rest; a preload outside the joint's limits is
refused in one line."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import plausible_measurements, small_truss

from smartjoint.bench import e2e, fmu_check
from smartjoint.bench.joint_node import CompiledNode, compiled_nodes
from smartjoint.codegen import controllers, fmu, fmu_variables, generate
from smartjoint.common import law_registry
from smartjoint.common.errors import DesignError, ModelError
from smartjoint.design.control import artifact, ensemble, study, tuning
from smartjoint.design.control.laws import siso_law
from smartjoint.design.control.runs import run_semi_active, setup
from smartjoint.design.network import joint_node
from smartjoint.design.plant import Measurements
from smartjoint.design.structure.spec import parse_design

LAW = law_registry.LAWS["siso"]
REFERENCE = Path(__file__).resolve().parents[1] / "firmware" / "generated" / "controller.json"
PRELOAD = [150.0, 200.0, 250.0]  # N, one per joint of the reference artefact


@pytest.fixture(scope="module")
def artefacts():
    """The reference artefact (the paper's law: preload = F_N^min) and the same with ``PRELOAD``."""
    reference = artifact.load(REFERENCE)
    return reference, dataclasses.replace(reference, siso_normal_force_min=np.array(PRELOAD))


def _at_rest(a) -> Measurements:
    l = len(a.joint_names)
    return Measurements(0.0, np.zeros(len(a.sensor_names)), np.zeros(l), np.zeros(l), np.full(l, 100.0))


def test_the_setting_is_the_laws_lower_force_and_defaults_to_the_joints(artefacts):
    reference, _ = artefacts
    (setting,) = [s for s in LAW.settings if s.lower_force]
    assert setting.design_key(LAW.name) == "siso_normal_force_min" and setting.default == "normal_force_min"
    assert setting.normal_force and setting.per_joint
    assert LAW.lower_force_field() == "siso_normal_force_min"
    others = [law for law in law_registry.LAWS.values() if law is not LAW]
    assert {law.lower_force_field() for law in others} == {"normal_force_min"}
    assert np.array_equal(reference.siso_normal_force_min, reference.normal_force_min)


def test_version_5_and_6_artefacts_read_as_7_with_the_same_numbers():
    """Version 5 had no preload, version 6 no actuation tolerance: each reads with what it implied
    (the joints' F_N^min; 0.1 × F_N^max, the design default), which is the committed version-7
    artefact byte for byte once written again."""
    data = json.loads(REFERENCE.read_text())
    assert data["schema_version"] == 7
    del data["safety"]["actuation_tolerance"]
    data["schema_version"] = 6
    assert artifact.dumps(artifact.loads(json.dumps(data))) == REFERENCE.read_text()
    del data["laws"]["siso"]["normal_force_min"]
    data["schema_version"] = 5
    migrated = artifact.loads(json.dumps(data))
    assert artifact.dumps(migrated) == REFERENCE.read_text()
    data["laws"]["siso"]["normal_force_min"] = [1.0, 1.0, 1.0]  # a version-5 file with a key it never had
    with pytest.raises(ModelError, match=r"schema_version: 5 — unknown"):
        artifact.loads(json.dumps(data))
    data = json.loads(REFERENCE.read_text())
    data["schema_version"] = 6  # a version-6 file with the key version 7 added: refused as version 6
    with pytest.raises(ModelError, match=r"schema_version: 6 — unknown"):
        artifact.loads(json.dumps(data))


@pytest.mark.parametrize(
    "value, message",
    [
        (401.0, r"siso_normal_force_min: 401.0 N for joint 'A1' — .* within \[normal_force_min, normal_force_max\]"),
        (5.0, r"siso_normal_force_min: 5.0 N for joint 'A1' — .* within \[normal_force_min, normal_force_max\]"),
    ],
)
def test_a_preload_outside_the_joints_limits_is_refused(value, message):
    data = json.loads(REFERENCE.read_text())
    data["laws"]["siso"]["normal_force_min"][0] = value
    with pytest.raises(ModelError, match=message):
        artifact.loads(json.dumps(data))


@pytest.mark.numerics
@pytest.mark.parametrize("real", ["double", "float"])
def test_the_generated_c_is_the_reference_with_a_preload(artefacts, real):
    """At rest the law commands the preload; over plausible measurements never less; the double
    build bit for bit with the reference, the float within its bound of the span."""
    _, a = artefacts
    reference, compiled = LAW.python_reference(a), controllers.compile_controllers(a, real).law(LAW.name)
    assert reference.step(_at_rest(a)).tolist() == PRELOAD
    reference.reset()
    span = float(np.min(a.normal_force_max - a.siso_normal_force_min))
    commands = []
    for m in plausible_measurements(a, 2000, 3, 1e-5, 1e-4, 20.0):
        expected, got = reference.step(m), compiled.step(m)
        assert compiled.status == reference.status == 0
        if real == "double":
            assert got.tobytes() == expected.tobytes()
        else:
            assert np.max(np.abs(got - expected)) <= fmu_check.FLOAT_BOUND * span
        commands.append(expected)
    commands = np.array(commands)
    assert np.all(commands >= PRELOAD) and np.all(commands <= a.normal_force_max)
    assert np.any(commands == PRELOAD) and np.any(commands > np.array(PRELOAD) + 1.0)  # both regimes ran
    text = generate.render(a, "double")[f"{LAW.c_name('smartjoint')}.c"]
    assert "150.0, 200.0, 250.0" in text  # the preload is the law's F^min in its parameters


@pytest.mark.numerics
def test_the_joint_nodes_run_the_preloaded_central_law(artefacts):
    """Each node's config carries its joint's preload, and the compiled nodes command the central
    preloaded SISO law's numbers bit for bit."""
    _, a = artefacts
    assert [joint_node.node_config(a, j).normal_force_min for j in range(3)] == PRELOAD
    module = compiled_nodes(a, "double")
    nodes = [CompiledNode(module, a, j) for j in range(3)]
    central = siso_law(a)
    rng = np.random.default_rng(5)
    for k in range(1500):
        if k % 10 == 0:
            count = k // 10 + 1  # the supervisor's heartbeat count: bits 0-3 the counter, 4-11 cycle_high
            heartbeat = bytearray(joint_node.HEARTBEAT_LENGTH)
            heartbeat[2] = joint_node.NODE_LAW.mode
            heartbeat[joint_node.HEARTBEAT_CYCLE_BYTE] = e2e.freshness(count)
            frame = bytes(e2e.protect(joint_node.HEARTBEAT_ID, heartbeat, count, e2e.freshness(count)))
            for node in nodes:
                assert node.receive(joint_node.HEARTBEAT_ID, frame), k  # every heartbeat taken
        m = Measurements(k * 1e-3, np.zeros(2), rng.normal(0, 1e-5, 3), rng.normal(0, 20, 3), rng.uniform(10, 400, 3))
        expected = central.step(m)
        local = [n.step(m.sliding_velocity[j], m.friction_force[j], m.normal_force[j]) for j, n in enumerate(nodes)]
        assert np.asarray(local).tobytes() == np.asarray(expected).tobytes(), k


def test_the_fmu_tunes_the_preload_as_the_laws_lower_force(artefacts):
    """The SISO FMU's JOINT_<j>.normal_force_min starts at the preload (no second variable)."""
    _, a = artefacts
    rows = {v.name: v for v in fmu_variables.controller_variables(a, LAW.name, "double")}
    assert [float(rows[f"JOINT_{name}.normal_force_min"].start) for name in a.joint_names] == PRELOAD
    assert not [name for name in rows if name.endswith(".normal_force_min") and not name.startswith("JOINT_")]


@pytest.mark.numerics
def test_the_fmu_and_the_study_command_the_preload(artefacts, tmp_path):
    """The design file's ``siso_normal_force_min`` reaches the study's law and the artefact;
    the controller FMU of that artefact replays the study's commands bit for bit."""
    d = small_truss()
    d["control"] = {"modes": 4, "considered_modes": 10, "study_duration": 0.2, "siso_boundary_layer": 3e-4,
                    "siso_normal_force_min": [120.0, 180.0]}  # fmt: skip
    design = parse_design(d)
    model = study.design_model(design, lambda line: None)
    a = ensemble.point_artifact(design, model, study.lqg_for(design, model), {})
    assert a.siso_normal_force_min.tolist() == [120.0, 180.0]
    assert tuning.tuned(LAW, design).settings["normal_force_min"].tolist() == [120.0, 180.0]
    s = setup(design, model)
    settings = tuning.tuned(LAW, design).settings
    run = run_semi_active(s, LAW.display, LAW.study_controller(s, None, settings))
    assert run.normal_force.tobytes() == run_semi_active(s, LAW.display, siso_law(a)).normal_force.tobytes()
    after = run.time > 0.04 + 1e-9  # after the pulse (F^max during it, as for every law)
    assert np.all(run.normal_force[after] >= [120.0, 180.0]) and np.any(run.normal_force[after] == [120.0, 180.0])
    log = fmu_check.recorded_inputs(s, a, LAW.display)
    expected = np.array([forces for _, forces in log])
    assert np.all(expected >= [120.0, 180.0])
    written = fmu.controller_fmu(a, LAW.name, tmp_path / "siso.fmu", fmi=2, real="double")
    replayed, status = fmu_check.replay(written.path, log)
    assert replayed.tobytes() == expected.tobytes() and set(status) == {0}


@pytest.mark.parametrize("value", [500.0, [100.0, 5.0]])
def test_the_design_file_refuses_a_preload_outside_the_limits_before_any_work(value):
    d = small_truss()
    d["control"] = {"siso_normal_force_min": value}
    with pytest.raises(DesignError, match=r"siso_normal_force_min.*must lie within \[F_N\^min, F_N\^max\]") as caught:
        parse_design(d)
    assert "\n" not in str(caught.value)
