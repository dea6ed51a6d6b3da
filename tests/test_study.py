"""The closed-loop study of paper Section 6 (design/control/study.py) and the design/study commands."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from conftest import cli_error, run_cli, small_control_truss, small_truss

from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design import parse_design
from smartjoint.design.control import artifact, siso_tuning, study, tuning


def _small(duration=0.3, **control):
    return parse_design(small_control_truss(duration, **{"krylov": 1, **control}))


@pytest.fixture(scope="module")
def small_study():
    design = _small(siso_boundary_layer=1e-4)
    return design, study.run_study(design, progress=lambda message: None)


@pytest.mark.numerics
def test_the_study_is_bit_identical_when_repeated(small_study):
    design, first = small_study
    again = study.run_study(design, progress=lambda message: None)
    for a, b in zip(first.runs, again.runs):
        for name in ("time", "energy", "sensors", "normal_force", "joint_force", "sliding_velocity"):
            assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), (a.name, name)
    assert json.dumps(study.summary(first)) == json.dumps(study.summary(again))


@pytest.mark.numerics
def test_metrics_follow_their_definitions(small_study):
    design, result = small_study
    s = result.setup
    passive = result.run("passive F_max")
    # Passive: the stacks are charged once, from 0 V to V_max, and held.
    volts = (s.normal_force_max - s.piezo_preload) / s.piezo_force_per_volt
    assert passive.control_power == pytest.approx(np.sum(0.5 * s.piezo_capacitance * volts**2) / s.duration, rel=1e-12)
    for r in result.runs:
        m = r.metrics
        after = r.time > study.PULSE_DURATION
        deflection = r.sensors[after][:, [q == "displacement" for q in result.sensor_quantities]]
        assert m["tip_peak"] == pytest.approx(np.max(np.abs(deflection), axis=0).tolist())
        assert m["energy_measure"] == pytest.approx(np.trapezoid(2 * r.energy, r.time))
        if m["settling_time"] is not None:
            later = r.time >= m["settling_time"]
            start = np.searchsorted(r.time, study.PULSE_DURATION - 1e-12)
            assert np.all(r.energy[later] <= 0.1 * r.energy[start])
            assert r.energy[np.flatnonzero(later)[0] - 1] > 0.1 * r.energy[start]
    assert result.run("passive F_max").metrics["energy_end_relative"] == 1.0
    # Semi-active normal forces stay in [F^min, F^max]; during the pulse they are F^max.
    for name in ("SISO", "cLQG"):
        force = result.run(name).normal_force
        assert np.all(force >= s.normal_force_min - 1e-12) and np.all(force <= s.normal_force_max + 1e-12)
        assert np.all(force[result.run(name).time < study.PULSE_DURATION - 1e-12] == s.normal_force_max)


@pytest.mark.numerics
def test_piezo_power_counts_charging_only():
    s = dataclasses.replace(
        study.setup(
            _small(siso_boundary_layer=1e-4), study.design_model(_small(siso_boundary_layer=1e-4), lambda m: None)
        ),
        duration=1.0,
    )
    low, high = 10.0, 90.0
    forces = np.tile([[high], [low]], (50, 1))  # 50 charges to 90 N, discharges are free
    expected = (
        50 * 0.5 * s.piezo_capacitance * ((high / s.piezo_force_per_volt) ** 2 - (low / s.piezo_force_per_volt) ** 2)
        + 0.5 * s.piezo_capacitance * (low / s.piezo_force_per_volt) ** 2
    )  # the very first charge from 0 V
    assert study.piezo_power(s, forces) == pytest.approx(expected, rel=1e-12)


@pytest.mark.numerics
def test_boundary_layer_optimum_beats_its_neighbours():
    design = _small(duration=0.3)
    model = study.design_model(design, lambda m: None)
    s = study.setup(design, model)
    messages = []
    grid = (1e-5, 1e-4, 1e-3, 1e-2)
    found = siso_tuning.optimise_boundary_layer(s, messages.append, grid=grid)
    values = dict(found.evaluations)
    assert len(messages) == len(values)
    # The optimum is exactly the best point of the search (grid and bounded Brent); the checks at
    # ε/10 and 10ε come after it unless they are grid points.
    checks = [found.boundary_layer / 10.0, found.boundary_layer * 10.0]

    def near(width, others):
        return any(abs(width / other - 1.0) < 1e-9 for other in others)

    searched = {width: value for width, value in values.items() if not near(width, checks) or near(width, grid)}
    assert found.energy_measure == min(searched.values())
    # A decade either side is not better beyond the roughness of E(ε). E is a rough function of ε
    # (stick–slip events shift with it; the loop is chaotic: 6e-8 perturbations of the commands
    # move E(t_e) by up to ~1e-3 here), and on this small truss ε/10 or 10ε come within 1e-3 of
    # the optimum, so which one wins bit for bit depends on the machine (10ε wins by 5e-4 with
    # OpenBLAS's Sandybridge kernels). The band is measured in this run: the spread of E over the
    # searched points within half a decade of the optimum (Brent always samples that bracket).
    local = [value for width, value in searched.items() if abs(math.log10(width / found.boundary_layer)) <= 0.5]
    band = max(local) / found.energy_measure - 1.0
    assert len(local) >= 4 and 0.0 < band < 0.02, local
    assert found.energy_measure <= min(found.tenth, found.tenfold) * (1.0 + band), (found, band)
    assert max(values.values()) > found.energy_measure * (1.0 + 3.0 * band)  # ε matters beyond the band


def test_the_controllers_need_every_joint_in_design_order():
    data = small_truss()
    data["control"] = {"joints": ["JA"]}
    with pytest.raises(ModelError, match="control.joints.*every friction joint"):
        study.design_model(parse_design(data), lambda m: None)
    data["control"] = {"joints": ["JB", "JA"]}
    with pytest.raises(ModelError, match="control.joints.*design order"):
        study.design_model(parse_design(data), lambda m: None)
    bad = _small(duration=0.01)
    with pytest.raises(ModelError, match="study_duration"):
        study.setup(bad, study.design_model(bad, lambda m: None))


@pytest.fixture(scope="module")
def bundled(three_type_a):
    """The paper's configuration: the reference truss with three type A joints (Fig. 11)."""
    design, model = three_type_a
    return study.run_study(design, model, progress=lambda message: None)


@pytest.mark.numerics
def test_the_active_reference_needs_more_power_and_the_lqg_loop_is_stable(bundled):
    """What does not hang on one chaotic trajectory (the energy and deflection orderings are
    asserted over an ensemble below): the power ranking, and the linear loop's poles."""
    m = {r.name: r.metrics for r in bundled.runs}
    assert m["active LQG"]["control_power"] > m["cLQG"]["control_power"]
    assert bundled.stability_margin > 0


def _stage_rows(design, bundled, spread=None, samples=16):
    """The rows of ``samples`` plants drawn as stage 10 of ``smartjoint run`` draws them (the
    physical spread, or ``spread`` replacing its entries of the same name; the compiled loop)."""
    from smartjoint.bench.sweep import prepare
    from smartjoint.design.control import ensemble
    from smartjoint.pipeline_ensemble import stage_sweep

    laws = ("passive F_min", "passive F_max", "SISO", "cLQG", "slip ratio", "active LQG")
    sweep = dataclasses.replace(stage_sweep(design, bundled), laws=laws)
    if spread:
        inputs = tuple(u for u in sweep.inputs if u.name not in {s.name for s in spread}) + tuple(spread)
        sweep = dataclasses.replace(sweep, inputs=inputs)
    prepared = prepare(sweep, progress=lambda line: None, design=design)
    assert prepared.compiled is not None
    rows = ensemble.run_batch(prepared.base, prepared.points, list(range(samples)), prepared.values, prepared.compiled)
    return {key: [row[key] for row in rows] for key in rows[0]}


@pytest.mark.numerics
def test_the_papers_orderings_hold_over_plants_drawn_around_the_bundled_truss(bundled, three_type_a):
    """The loop with stick-slip is chaotic: whether one trajectory's ordering holds can flip with
    the last bits of another machine's kernels. So the claims are asserted over 16 plants drawn as
    stage 10 of ``smartjoint run`` draws them, from the physical spread (docs/design-file.md,
    ``[uncertainty]``: friction ±10 % and ×/÷2, modal frequencies 1 %, damping ×/÷4, amplifier lag,
    sensor noise, the pulse ±10 %): each semi-active claim holds on at least 14 of them (all 16 on
    this machine). The active LQG is not robust to that spread: designed on the nominal model, it
    ends above the cLQG on 3 of the 16 plants here, one of them unstable at −2.4 % frequency
    (e(t_e) 4.7 J), while no semi-active run can gain energy. Its claims are the paper's on a
    matched model, so they are asserted with the modal frequencies within ±0.2 %."""
    from smartjoint import sweep_report
    from smartjoint.design.structure.uncertainty import Distribution, UncertainInput

    design, _ = three_type_a
    design = tuning.with_settings(design, study.settings_figures(bundled.tunings))
    columns = _stage_rows(design, bundled)
    held = sweep_report.orderings(columns)[0]
    claims = ["siso_below_both_passive", "clqg_below_both_passive", "clqg_tip_rms_below_siso"]
    claims += ["slipratio_below_both_passive"]  # the local law of issue 32 (benchmarks/local_laws.py)
    assert {name: held[name]["samples"] for name in claims} == dict.fromkeys(claims, 16)
    assert all(held[name]["probability"] >= 14 / 16 for name in claims), held
    law, end = np.asarray(columns["law"]), np.asarray(columns["energy_end"], dtype=float)
    semi_active = np.isin(law, ["SISO", "cLQG", "slip ratio", "passive F_min", "passive F_max"])
    assert np.all(end[semi_active] < 1.0), end[semi_active].max()  # about 0.6 J at the pulse's end: never gained

    matched = UncertainInput("modal_frequency_scale", Distribution("uniform", 0.998, 1.002))
    held = sweep_report.orderings(_stage_rows(design, bundled, [matched]))[0]
    claims = ["active_energy_below_clqg", "active_tip_rms_below_clqg"]
    assert all(held[name]["probability"] >= 14 / 16 for name in claims), held


@pytest.mark.numerics
def test_the_optimised_boundary_layer_beats_a_decade_either_side(bundled):
    o = bundled.tunings["siso"].record
    assert o is not None
    assert o.energy_measure < o.tenth and o.energy_measure < o.tenfold


def test_design_and_study_commands(tmp_path):
    import tomli_w

    data = small_control_truss(0.2, siso_boundary_layer=1e-4)
    path = tmp_path / "small.toml"
    path.write_text(tomli_w.dumps(data))
    out = tmp_path / "controller.json"
    done = run_cli("design", path, "-o", out, "--json")
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    loaded = artifact.load(out)
    assert loaded.artifact_sha256 == summary["artifact_sha256"] and loaded.joint_names == ("JA", "JB")
    assert summary["lqg_stability_margin"] > 0
    done = run_cli("study", path, "--json", "--plots", tmp_path / "plots")
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert set(result["runs"]) == {"passive F_min", "passive F_max", *law_registry.DISPLAY, "active LQG"}
    assert (tmp_path / "plots" / "control_energy.png").stat().st_size > 0
    refused = tmp_path / "refused.json"
    done = run_cli("design", path, "-o", refused, "--max-load", "0.1")  # refused after the model reduction
    assert done.returncode == 2 and "exceeds the limit 10 %" in done.stderr and not refused.exists()
    assert summary["bus_load"] < 0.7 and list(summary["bus_loads"]) == ["can0"]  # the [network] plan: one bus
    data["control"]["normal_force_min"] = 500.0
    path.write_text(tomli_w.dumps(data))
    assert "normal_force_min" in cli_error("design", path, "-o", tmp_path / "x.json")
    assert not (tmp_path / "x.json").exists()


@pytest.mark.numerics
def test_deflection_figures_come_from_the_displacement_sensors_alone(small_study):
    design, result = small_study
    assert result.sensor_names == ["tip_y", "tip_vz"]
    assert result.sensor_quantities == ["displacement", "velocity"]
    assert study.summary(result)["sensor_quantities"] == ["displacement", "velocity"]
    for r in result.runs:
        m = r.metrics
        after = r.sensors[r.time > study.PULSE_DURATION + 1e-12]
        # The same figures as from a study with tip_y as its only sensor, bit for bit.
        alone = study.sensor_metrics(after[:, [0]], ["displacement"])
        assert m["tip_rms"] == alone["tip_rms"] and m["tip_peak"] == alone["tip_peak"]
        assert m["tip_rms_total"] == alone["tip_rms_total"] == float(np.sqrt(np.mean(after[:, 0] ** 2)))
        assert alone["velocity_rms"] is None and alone["velocity_peak"] is None
        # tip_vz in m/s under its own keys
        assert m["velocity_rms"] == pytest.approx([np.sqrt(np.mean(after[:, 1] ** 2))], rel=1e-12)
        assert m["velocity_peak"] == pytest.approx([np.max(np.abs(after[:, 1]))], rel=1e-12)
    orderings = result.orderings()
    m = {r.name: r.metrics for r in result.runs}
    assert orderings["clqg_tip_rms_below_siso"] == (m["cLQG"]["tip_rms_total"] < m["SISO"]["tip_rms_total"])


def test_displacement_sensors_alone_keep_the_figures_bit_for_bit():
    y = np.random.default_rng(18).normal(scale=1e-3, size=(500, 3))
    figures = study.sensor_metrics(y, ["displacement"] * 3)
    assert figures["tip_rms"] == [float(v) for v in np.sqrt(np.mean(y**2, axis=0))]
    assert figures["tip_rms_total"] == float(np.sqrt(np.mean(np.sum(y**2, axis=1))))
    assert figures["tip_peak"] == [float(v) for v in np.max(np.abs(y), axis=0)]
    assert figures["velocity_rms"] is None and figures["velocity_peak"] is None
    with pytest.raises(ModelError, match="sensor quantities"):
        study.sensor_metrics(y, ["displacement", "acceleration", "velocity"])
    with pytest.raises(ModelError, match="sensor quantities"):
        study.sensor_metrics(y, ["displacement"])


def _velocity_only(result):
    """The small study with every sensor read as a velocity: no deflection to compare."""
    kinds = ["velocity"] * len(result.sensor_names)
    reference = result.run("passive F_max")
    runs = [dataclasses.replace(r, metrics=study.metrics(r, reference, kinds)) for r in result.runs]
    return dataclasses.replace(result, runs=runs, sensor_quantities=kinds)


def test_without_a_displacement_sensor_the_deflection_orderings_say_so(small_study):
    from smartjoint.codegen import backtoback
    from smartjoint.report_control import control_markdown

    moved = _velocity_only(small_study[1])
    for r in moved.runs:
        assert r.metrics["tip_rms"] is r.metrics["tip_rms_total"] is r.metrics["tip_peak"] is None
        assert len(r.metrics["velocity_rms"]) == 2
    orderings = moved.orderings()
    assert orderings["clqg_tip_rms_below_siso"] is None and orderings["active_tip_rms_below_clqg"] is None
    assert isinstance(orderings["siso_below_both_passive"], bool)
    text = control_markdown(moved)
    assert "cLQG's RMS tip deflection below SISO's: — (no displacement sensor)" in text
    assert "active LQG's RMS tip deflection below cLQG's: — (no displacement sensor)" in text
    assert "RMS tip_y [mm/s]" in text and "RMS tip_vz [mm/s]" in text
    row = next(line for line in text.splitlines() if line.startswith("| SISO |"))
    assert row.split(" | ")[6] == "—"  # peak tip [mm]: no deflection measured
    section = backtoback.markdown({"float_orderings": orderings}, _artifact_stub())
    assert "not judged without a displacement sensor: clqg_tip_rms_below_siso, active_tip_rms_below_clqg" in section


def test_the_float_orderings_line_names_what_fails():
    """The back-to-back section says which orderings hold and which fail, not only that some do."""
    from smartjoint.codegen import backtoback

    orderings = {"siso_below_both_passive": False, "clqg_below_both_passive": True, "clqg_tip_rms_below_siso": None}
    section = backtoback.markdown({"float_orderings": orderings}, _artifact_stub())
    assert "**not all hold** (hold: clqg_below_both_passive; fail: siso_below_both_passive)" in section


def _artifact_stub():
    """What backtoback.markdown reads of an artefact: the normal-force span."""
    return type("Stub", (), {"normal_force_max": np.array([100.0]), "normal_force_min": np.array([5.0])})()


@pytest.mark.numerics
def test_the_report_gives_each_sensor_its_unit(small_study, monkeypatch, tmp_path):
    from smartjoint import report_control
    from smartjoint.common import figures

    _, result = small_study
    text = report_control.control_markdown(result)
    assert "RMS tip_y [mm]" in text and "RMS tip_vz [mm/s]" in text and "tip_vz [mm]" not in text
    header = next(line for line in text.splitlines() if line.startswith("| run |"))
    columns = [cell.strip() for cell in header.strip("|").split("|")]
    for r in result.runs:
        row = next(line for line in text.splitlines() if line.startswith(f"| {r.name} |"))
        cells = dict(zip(columns, (cell.strip() for cell in row.strip("|").split("|"))))
        assert cells["RMS tip_y [mm]"] == f"{1e3 * r.metrics['tip_rms'][0]:.2f}"
        assert cells["RMS tip_vz [mm/s]"] == f"{1e3 * r.metrics['velocity_rms'][0]:.2f}"
        assert cells["peak tip [mm]"] == f"{1e3 * max(r.metrics['tip_peak']):.1f}"
        assert cells["peak tip velocity [mm/s]"] == f"{1e3 * max(r.metrics['velocity_peak']):.1f}"
    measures = [r.energy_measure() for r in result.runs]  # the span of E(t_e) over the runs
    assert f"E(t_e) spans {100 * (max(measures) / min(measures) - 1):.3g} % between the runs" in text
    labels = {}

    def keep_labels(fig, path, dpi):
        labels[path.name] = [axes.get_ylabel() for axes in fig.axes]
        figures.pyplot().close(fig)

    monkeypatch.setattr(figures, "save", keep_labels)
    report_control.plot_control_study(result, tmp_path)
    assert labels["control_tip.png"] == ["tip_y [mm]", "tip_vz [mm/s]"]


def test_the_pulse_and_the_limits_are_the_designs_and_the_papers_defaults_are_named():
    """`[control] pulse_amplitude` is the study's tip pulse (the reduction study's too); a design that
    leaves out the settings whose defaults are the paper's demonstrator's is told which, by name."""
    from smartjoint.design.control.runs import PULSE_DURATION
    from smartjoint.design.structure.control_section import paper_values_note

    data = small_control_truss(0.2, pulse_amplitude=50.0, sample_time=2e-3)
    design = parse_design(data)
    setup = study.setup(design, study.design_model(design, lambda line: None))
    pulse = setup.pulse()
    assert setup.pulse_amplitude == 50.0 and float(np.max(pulse(PULSE_DURATION / 2))) == pytest.approx(50.0)
    assert paper_values_note(design.control) is None  # 5 … 100 N, 2 ms, 0.2 s, 50 N: all the user's
    note = paper_values_note(parse_design(small_truss()).control)
    for shown in ("sample_time = 0.001 s", "normal_force_max = 400.0 N", "pulse_amplitude = 200 N", "not your joints'"):
        assert shown in note, note
