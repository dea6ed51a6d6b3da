"""The slip-ratio law (issue 32's local law): its Python reference against the closed form of its
integration, its safe state, the generated C (double bit for bit, float within the bound), the
study, SIL over CAN with its mode id, the controller FMU and PIL, each against the reference;
its tuning on an ensemble of the physical spread; the artefact's refusals."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import SLIP_RATIO_SETTINGS, plausible_measurements, small_truss

from smartjoint.bench import firmware, fmu_check
from smartjoint.bench.loop import SilLoop
from smartjoint.codegen import controllers, fmu
from smartjoint.common import law_registry
from smartjoint.common.errors import DesignError, ModelError
from smartjoint.design import plant
from smartjoint.design.control import artifact, ensemble, slip_ratio, study, tuning
from smartjoint.design.control.laws import STATUS_INPUT_IMPLAUSIBLE, STATUS_INPUT_INVALID, STATUS_OK
from smartjoint.design.control.runs import run_passive, run_semi_active, setup
from smartjoint.design.control.slip_ratio import SlipRatioLaw
from smartjoint.design.structure.spec import parse_design

LAW = law_registry.LAWS["slipratio"]
REFERENCE = Path(__file__).resolve().parents[1] / "firmware" / "generated" / "controller.json"
VELOCITY = 2e-4  # m/s: v* of the C tests, of the order of the measurements' slip (both branches run)


@pytest.fixture(scope="module")
def small():
    """The small truss over 0.2 s: its design, set-up and its artefact with v* = ``VELOCITY``."""
    d = small_truss()
    d["control"] = {"modes": 4, "considered_modes": 10, "study_duration": 0.2, "siso_boundary_layer": 3e-4,
                    **SLIP_RATIO_SETTINGS, "slipratio_velocity": VELOCITY}  # fmt: skip
    design = parse_design(d)
    model = study.design_model(design, lambda line: None)
    lqg = study.lqg_for(design, model)
    return design, setup(design, model), ensemble.point_artifact(design, model, lqg, {})


def measurement(velocity, forces=(100.0, 200.0)) -> plant.Measurements:
    return plant.Measurements(0.0, np.zeros(1), np.asarray(velocity, dtype=float), np.zeros(2), np.asarray(forces))


def test_the_entry_and_its_settings():
    assert LAW.mode not in (law.mode for law in law_registry.LAWS.values() if law is not LAW)
    assert law_registry.by_mode()[LAW.mode] == "SLIPRATIO"
    assert LAW.inputs == ("sliding_velocity", "normal_force") and not LAW.constant  # its own joint's only
    assert [s.design_key(LAW.name) for s in LAW.settings] == list(SLIP_RATIO_SETTINGS)
    assert [s.per_joint for s in LAW.settings] == [True, False, False]


def test_the_reference_integrates_the_slip_in_closed_form():
    """From F^max: sticking k samples gives F^max·(1 − Δt·r_d)^k until F^min holds it; slipping
    grows by (1 + Δt·r_r) per sample until F^max holds it; a joint that slips the fraction
    r_d/(r_r + r_d) of the samples keeps its force (to first order in Δt·r)."""
    dt, rise, decay = 1e-3, 80.0, 20.0
    law = SlipRatioLaw(dt, [10.0, 10.0], [400.0, 400.0], 1e-3, rise, decay)
    law.reset()
    stuck = [law.step(measurement([0.0, 5e-3]))[0] for _ in range(300)]
    expected = np.maximum(400.0 * (1 - dt * decay) ** np.arange(1, 301), 10.0)
    assert np.allclose(stuck, expected, rtol=1e-12, atol=0)
    assert stuck[-1] == 10.0 and law.command[1] == 400.0  # the slipping joint held at F^max
    grown = [law.step(measurement([-2e-3, 0.0]))[0] for _ in range(20)]
    assert np.allclose(grown, 10.0 * (1 + dt * rise) ** np.arange(1, 21), rtol=1e-12, atol=0)
    # slipping 1 sample in 5 = r_d/(r_r + r_d): F_N drifts by (1 + Δt·r_r)^200·(1 − Δt·r_d)^800, to
    # first order in Δt·r none — the fixed point the rates set (a second-order drift at Δt·r ~ 0.1)
    for dt, tolerance in ((1e-3, 0.6), (1e-5, 1e-4)):
        law = SlipRatioLaw(dt, [10.0, 10.0], [400.0, 400.0], 1e-3, rise, decay)
        law.command[:] = 100.0
        for slipping in [1.0, 0.0, 0.0, 0.0, 0.0] * 200:
            law.step(measurement([slipping * 5e-3, 0.0]))
        drift = (1 + dt * rise) ** 200 * (1 - dt * decay) ** 800
        assert law.command[0] == pytest.approx(100.0 * drift, rel=1e-12) and abs(drift - 1.0) < tolerance


def test_an_unusable_input_goes_safe_and_holds_only_its_joints_memory():
    law = SlipRatioLaw(1e-3, [10.0, 10.0], [400.0, 300.0], [1e-3, 1e-3], 80.0, 20.0,
                       safe_normal_force=[400.0, 300.0], sliding_velocity_limit=1.0,
                       measured_normal_force_min=[-40.0, -40.0], measured_normal_force_max=[440.0, 340.0])  # fmt: skip
    law.reset()
    first = law.step(measurement([0.0, 0.0]))
    assert law.status == STATUS_OK and first.tolist() == [400.0 * 0.98, 300.0 * 0.98]
    assert law.step(measurement([np.nan, 0.0])).tolist() == [400.0, 300.0] and law.status == STATUS_INPUT_INVALID
    assert law.command.tolist() == [400.0 * 0.98, 300.0 * 0.98 * 0.98]  # joint 0 held, joint 1 went on
    assert law.step(measurement([0.0, 0.0], (100.0, 341.0))).tolist() == [400.0, 300.0]
    assert law.status == STATUS_INPUT_IMPLAUSIBLE
    assert law.command.tolist() == [400.0 * 0.98 * 0.98, 300.0 * 0.98 * 0.98]  # now joint 1 held
    # at the plausible limits (|v| = 1 m/s, F_N at its range's ends): both slip, both clip at F^max
    assert law.step(measurement([1.0, -1.0], (440.0, -40.0))).tolist() == [400.0, 300.0]
    assert law.status == STATUS_OK


@pytest.mark.parametrize(
    "change, message",
    [
        ({"normal_force_min": [0.0, 10.0]}, r"normal_force_min: \[0.0, 10.0\] — the slip-ratio law needs F_N\^min > 0"),
        ({"velocity": -1.0}, r"slipratio_velocity: \[-1.0, -1.0\] — v\* must be finite and > 0"),
        ({"rise": float("inf")}, r"slipratio_rise: inf — r_rise must be finite and > 0"),
        ({"decay": 1000.0}, r"slipratio_decay: 1000.0 — r_decay must be > 0 and below 1/Δt = 1000 1/s"),
    ],
)
def test_settings_it_cannot_run_are_one_line(change, message):
    arguments = {"normal_force_min": [10.0, 10.0], "velocity": 1e-3, "rise": 80.0, "decay": 20.0, **change}
    with pytest.raises(ModelError, match=message):
        SlipRatioLaw(1e-3, arguments["normal_force_min"], [400.0, 400.0], arguments["velocity"],
                     arguments["rise"], arguments["decay"])  # fmt: skip


@pytest.mark.numerics
@pytest.mark.parametrize("real", ["double", "float"])
def test_the_generated_c_is_the_reference(small, real):
    """Plausible and unusable measurements alike: double bit for bit with the same status, float
    within its bound of the F_N span (slips around v*, so both branches and both clips run)."""
    _, _, a = small
    # sticking first (|v| mostly below v*: F_N falls to F^min), then slipping (it rises to F^max)
    samples = plausible_measurements(a, 300, 7, 1e-5, VELOCITY / 4, 10.0)
    samples += plausible_measurements(a, 300, 8, 1e-5, VELOCITY * 4, 10.0)
    for k in range(0, 600, 37):  # some unusable: NaN, beyond the plausible range
        bad = np.array(samples[k].normal_force, dtype=float)
        bad[k % 2] = np.nan if k % 3 else 1e5
        samples[k] = dataclasses.replace(samples[k], normal_force=bad)
    reference, compiled = LAW.python_reference(a), controllers.compile_controllers(a, real).law(LAW.name)
    reference.reset()
    compiled.reset()
    span = float(np.min(a.normal_force_max - a.normal_force_min))
    commands = []
    for m in samples:
        expected, got = reference.step(m), compiled.step(m)
        assert compiled.status == reference.status
        commands.append(expected)
        if real == "double":
            assert got.tobytes() == expected.tobytes()
        else:  # float's rounding compounds in the product: the bound relative to the force held
            assert np.max(np.abs(got - expected)) <= 10 * fmu_check.FLOAT_BOUND * span
    commands = np.array(commands)
    assert np.any(commands == a.normal_force_min) and np.any(commands == a.normal_force_max)


@pytest.mark.numerics
def test_the_study_runs_it_and_its_force_follows_the_joints_slip(small):
    """After the pulse the law never leaves [F^min, F^max]; where the joints slip its force rises,
    where they stick it falls — and its run differs from both passive settings."""
    design, s, a = small
    run = run_semi_active(s, LAW.display, LAW.python_reference(a))
    after = run.time > 0.04 + 1e-9
    force = run.normal_force[after]
    assert np.all(force >= s.normal_force_min - 1e-9) and np.all(force <= s.normal_force_max + 1e-9)
    change = np.diff(run.normal_force[after], axis=0)
    slipping = np.abs(run.sliding_velocity[after][1:]) > VELOCITY
    inside = (force[1:] > s.normal_force_min) & (force[1:] < s.normal_force_max)
    assert np.all(change[slipping & inside] >= 0) and np.all(change[~slipping & inside] <= 0)
    for passive in (s.normal_force_min, s.normal_force_max):
        assert run_passive(s, "passive", passive).energy.tobytes() != run.energy.tobytes()
    figures = study.summary(study.run_study(design, s.model, progress=lambda line: None))
    assert LAW.display in figures["runs"] and figures["slipratio_rise"] == SLIP_RATIO_SETTINGS["slipratio_rise"]


@pytest.mark.numerics
def test_over_can_the_firmware_runs_it_in_its_mode(small):
    """SIL: the host float build through the CAN loop runs the law, never enters the safe state,
    and its heartbeat names the law's mode to every amplifier."""
    _, s, a = small
    loop = SilLoop(firmware.Firmware(a, LAW.name, "float"), 0.0, channel="smartjoint-test-slipratio")
    try:
        run = run_semi_active(s, LAW.display, loop)
    finally:
        loop.close()
    assert all(amplifier.controller_mode == LAW.mode for amplifier in loop.amplifiers)
    assert not any(loop.record.safe)
    after = run.time > 0.04 + 1e-9
    assert len(np.unique(run.normal_force[after])) > 10  # a law that moves, not a held force


@pytest.mark.numerics
@pytest.mark.parametrize("version", fmu.VERSIONS)
def test_the_controller_fmu_answers_as_the_reference(small, tmp_path, version):
    _, s, a = small
    log = fmu_check.recorded_inputs(s, a, LAW.display)
    expected = np.array([forces for _, forces in log])
    written = fmu.controller_fmu(a, LAW.name, tmp_path / "slipratio.fmu", fmi=version, real="double")
    replayed, status = fmu_check.replay(written.path, log)
    assert replayed.tobytes() == expected.tobytes() and set(status) == {0}


@pytest.mark.skipif(shutil.which("qemu-system-arm") is None, reason="no qemu-system-arm")
def test_on_the_target_it_commands_what_the_host_commands(small):
    from smartjoint.bench import pil_study, target

    if target.missing_tools():
        pytest.skip(target.missing_tools())
    _, s, a = small
    figures = pil_study.law_on_target(s, a, LAW.name)
    assert pil_study.identical(figures["difference"]) and figures["difference"]["command_max_difference"] == 0.0


@pytest.mark.numerics
def test_the_tuning_minimises_the_mean_over_plants_of_the_spread(small):
    """The tuning draws its plants from the design's physical spread (distinct plants, the same for
    the same seed) and keeps the evaluation of least mean E(t_e); a design that gives the settings
    is not tuned."""
    design, s, _ = small
    one = ensemble.drawn_setups(design, s, 3, 5)
    again = ensemble.drawn_setups(design, s, 3, 5)
    assert [x.pulse_amplitude for x in one] == [x.pulse_amplitude for x in again]
    assert len({x.pulse_amplitude for x in one}) == 3
    short = dataclasses.replace(s, duration=0.1)
    found = slip_ratio.optimise(design, short, lambda line: None, plants=2, seed=5)
    assert found.energy_measure == min(e[3] for e in found.evaluations)
    assert len(found.evaluations) <= 12 + slip_ratio.REFINEMENTS + 2
    open_settings = {setting.key: None for setting in LAW.settings}
    given = {"velocity": np.full(2, 1e-3), "rise": 80.0, "decay": 20.0}
    assert slip_ratio.tuned(design, given, s, print) == (given, None)
    settings, record = slip_ratio.tuned(design, open_settings, short, lambda line: None)
    assert record is not None and settings["rise"] == record.rise and settings["velocity"].shape == (2,)


def test_an_artefact_without_its_section_is_refused():
    data = json.loads(REFERENCE.read_text())
    del data["laws"]["slipratio"]
    with pytest.raises(ModelError, match=r"laws\.slipratio"):
        artifact.loads(json.dumps(data))
    data = json.loads(REFERENCE.read_text())
    data["laws"]["slipratio"]["rise"] = -1.0
    with pytest.raises(ModelError, match=r"slipratio_rise: -1.0"):
        artifact.loads(json.dumps(data))


def test_the_design_file_gives_its_settings():
    d = small_truss()
    d["control"] = {"slipratio_rise": 0.0}
    with pytest.raises(DesignError, match=r"control\.slipratio_rise: 0\.0 — must be > 0"):
        parse_design(d)
    d["control"] = dict(SLIP_RATIO_SETTINGS)
    design = parse_design(d)
    settings = tuning.tuned(LAW, design).settings
    assert settings["velocity"].tolist() == [1e-3, 1e-3] and settings["decay"] == 15.0
