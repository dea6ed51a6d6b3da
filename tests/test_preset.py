"""The preset normal force, the third law (issue 29's proof that a law is an entry): its Python
reference, the generated C (double bit for bit, float within the bound), the study and the sweep
(at F^max it is the passive F^max run, sample for sample), SIL over CAN with its mode id, the
controller FMU and PIL, each against the reference."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import plausible_measurements, small_truss

from smartjoint.bench import firmware, fmu_check
from smartjoint.bench.loop import SilLoop
from smartjoint.codegen import controllers, fmu
from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design import plant
from smartjoint.design.control import artifact, ensemble, study, tuning
from smartjoint.design.control.laws import STATUS_INPUT_IMPLAUSIBLE, STATUS_INPUT_INVALID, STATUS_OK
from smartjoint.design.control.preset import PresetLaw
from smartjoint.design.control.runs import run_passive, run_semi_active, setup
from smartjoint.design.structure.spec import parse_design

LAW = law_registry.LAWS["preset"]
PRESET = [150.0, 250.0]  # N, one per joint of the small truss
REFERENCE = Path(__file__).resolve().parents[1] / "firmware" / "generated" / "controller.json"


@pytest.fixture(scope="module")
def small():
    """The small truss over 0.2 s: its set-up, its artefact with the preset force at F^max (the
    default) and one with ``PRESET``."""
    d = small_truss()
    d["control"] = {"modes": 4, "considered_modes": 10, "study_duration": 0.2, "siso_boundary_layer": 3e-4}
    design = parse_design(d)
    model = study.design_model(design, lambda line: None)
    lqg = study.lqg_for(design, model)
    default = ensemble.point_artifact(design, model, lqg, {})
    preset = ensemble.point_artifact(tuning.with_settings(design, {"preset_force": PRESET}), model, lqg, {})
    return design, setup(design, model), default, preset


def test_the_entry_and_its_setting():
    assert LAW.mode not in (law.mode for law in law_registry.LAWS.values() if law is not LAW)
    assert law_registry.by_mode()[LAW.mode] == "PRESET" and LAW.inputs == ("normal_force",)
    (setting,) = LAW.settings
    assert setting.design_key(LAW.name) == "preset_force" and setting.default == "normal_force_max"


def test_the_reference_holds_its_force_and_goes_safe_on_an_unusable_measurement():
    law = PresetLaw(1e-3, [10.0, 10.0], [400.0, 300.0], [150.0, 500.0], safe_normal_force=[400.0, 300.0],
                    measured_normal_force_min=[-40.0, -40.0], measured_normal_force_max=[440.0, 340.0])  # fmt: skip

    def step(forces):
        return law.step(plant.Measurements(0.0, np.zeros(1), np.zeros(2), np.zeros(2), np.asarray(forces)))

    assert step([100.0, 200.0]).tolist() == [150.0, 300.0] and law.status == STATUS_OK  # 500 N clipped to F^max
    assert step([np.nan, 200.0]).tolist() == [400.0, 300.0] and law.status == STATUS_INPUT_INVALID
    assert step([100.0, 341.0]).tolist() == [400.0, 300.0] and law.status == STATUS_INPUT_IMPLAUSIBLE
    assert step([440.0, -40.0]).tolist() == [150.0, 300.0] and law.status == STATUS_OK  # at the limits: plausible


@pytest.mark.numerics
@pytest.mark.parametrize("real", ["double", "float"])
def test_the_generated_c_is_the_reference(small, real):
    """Plausible and unusable measurements alike: double bit for bit with the same status, float
    within its bound of the F_N span."""
    _, _, _, a = small
    samples = plausible_measurements(a, 400, 7, 1e-5, 1e-4, 10.0)
    for k in range(0, 400, 37):  # some unusable: NaN, beyond the plausible range
        bad = np.array(samples[k].normal_force, dtype=float)
        bad[k % 2] = np.nan if k % 3 else 1e5
        samples[k] = dataclasses.replace(samples[k], normal_force=bad)
    reference, compiled = LAW.python_reference(a), controllers.compile_controllers(a, real).law(LAW.name)
    reference.reset()
    compiled.reset()
    span = float(np.min(a.normal_force_max - a.normal_force_min))
    for m in samples:
        expected, got = reference.step(m), compiled.step(m)
        assert compiled.status == reference.status
        if real == "double":
            assert got.tobytes() == expected.tobytes()
        else:
            assert np.max(np.abs(got - expected)) <= fmu_check.FLOAT_BOUND * span


@pytest.mark.numerics
def test_at_the_maximum_force_it_is_the_passive_maximum_run_and_the_study_runs_it(small):
    design, s, default, a = small
    held = run_semi_active(s, LAW.display, LAW.python_reference(default))
    passive = run_passive(s, "passive F_max", s.normal_force_max)
    assert held.energy.tobytes() == passive.energy.tobytes()
    run = run_semi_active(s, LAW.display, LAW.python_reference(a))
    after = run.time > 0.04 + 1e-9  # after the pulse (F^max during it, as for every law)
    assert np.all(run.normal_force[after] == PRESET)
    figures = study.summary(study.run_study(tuning.with_settings(design, {"preset_force": PRESET}), s.model,
                                            progress=lambda line: None))  # fmt: skip
    assert figures["preset_force"] == PRESET and LAW.display in figures["runs"]
    # A constant force is judged beside the passive settings, not against them (Law.constant):
    # the paper's orderings of the other laws stay, and none is claimed for the preset.
    assert "siso_below_both_passive" in figures["orderings"]
    assert not [key for key in figures["orderings"] if key.startswith(f"{LAW.name}_")]


@pytest.mark.numerics
def test_over_can_the_firmware_runs_it_in_its_mode(small):
    """SIL: the host float build through the CAN loop commands the preset forces after the pulse,
    never enters the safe state, and its heartbeat names the preset mode to every amplifier."""
    _, s, _, a = small
    loop = SilLoop(firmware.Firmware(a, LAW.name, "float"), 0.0, channel="smartjoint-test-preset")
    try:
        run = run_semi_active(s, LAW.display, loop)
    finally:
        loop.close()
    after = run.time > 0.04 + 1e-9
    assert np.all(run.normal_force[after] == np.float32(PRESET))
    assert all(amplifier.controller_mode == LAW.mode for amplifier in loop.amplifiers)
    assert not any(loop.record.safe)


@pytest.mark.numerics
@pytest.mark.parametrize("version", fmu.VERSIONS)
def test_the_controller_fmu_answers_as_the_reference(small, tmp_path, version):
    _, s, _, a = small
    log = fmu_check.recorded_inputs(s, a, LAW.display)
    expected = np.array([forces for _, forces in log])
    written = fmu.controller_fmu(a, LAW.name, tmp_path / "preset.fmu", fmi=version, real="double")
    replayed, status = fmu_check.replay(written.path, log)
    assert replayed.tobytes() == expected.tobytes() and set(status) == {0}


@pytest.mark.skipif(shutil.which("qemu-system-arm") is None, reason="no qemu-system-arm")
def test_on_the_target_it_commands_what_the_host_commands(small):
    from smartjoint.bench import pil_study, target

    if target.missing_tools():
        pytest.skip(target.missing_tools())
    _, s, _, a = small
    figures = pil_study.law_on_target(s, a, LAW.name)
    assert pil_study.identical(figures["difference"]) and figures["difference"]["command_max_difference"] == 0.0
    command = np.array(figures["record"].command)
    assert np.all(command[len(command) // 2 :] == np.float32(PRESET))


def test_an_artefact_without_the_preset_section_or_with_a_force_out_of_range_is_refused():
    data = json.loads(REFERENCE.read_text())
    del data["laws"]["preset"]
    with pytest.raises(ModelError, match=r"laws\.preset"):
        artifact.loads(json.dumps(data))
    data = json.loads(REFERENCE.read_text())
    data["laws"]["preset"]["force"][0] = 401.0
    with pytest.raises(ModelError, match=r"preset_force: 401.0 N for joint .* within \[normal_force_min"):
        artifact.loads(json.dumps(data))
