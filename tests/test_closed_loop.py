"""The study's closed loop compiled (codegen.closed_loop, issue 20): the plant kernel stepped from
C with the generated laws (double build) gives the Python loop's trajectory bit for bit — with the
Python reference laws of the same artefact, the specification — on a perturbed plant, through
the pulse and through the safe state; and refuses what it cannot run in one line."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import small_truss

from smartjoint.codegen.closed_loop import CompiledLoop
from smartjoint.common.errors import ModelError
from smartjoint.design.control import ensemble
from smartjoint.design.control.filter import clipped_lqg
from smartjoint.design.control.laws import siso_law
from smartjoint.design.control.runs import run_passive, run_semi_active, setup
from smartjoint.design.control.study import design_model, lqg_for
from smartjoint.design.structure.spec import parse_design

FIELDS = ("time", "energy", "sensors", "normal_force", "joint_force", "sliding_velocity")


@pytest.fixture(scope="module")
def study():
    """The small truss's study over 0.4 s, its artefact (ε = 3e-4 m/s) and the compiled loop."""
    d = small_truss()
    d["disturbances"].append({"name": "fz", "node": "TIP", "direction": "uz"})  # a plane for the pulse's angle
    d["control"] = {"modes": 4, "considered_modes": 10, "study_duration": 0.4, "siso_boundary_layer": 3e-4}
    design = parse_design(d)
    model = design_model(design, lambda line: None)
    artifact = ensemble.point_artifact(design, model, lqg_for(design, model), {})
    return setup(design, model), artifact, CompiledLoop(artifact)


def _perturbed(s):
    """The plant 2 % stiffer with 0.3 % damping, the friction 5 % stronger, a 230 N pulse at 70°,
    white noise of 20 µm on the tip sensors, amplifiers lagging by 2 ms, each sample's instant
    jittered by up to ±9 plant steps (±0.45 ms)."""
    plant = dataclasses.replace(s.model, omega=s.model.omega * 1.02, damping=np.full_like(s.model.damping, 3e-3))
    laws = [dataclasses.replace(law, coulomb=law.coulomb * 1.05, sigma0=law.sigma0 * 0.95) for law in s.laws]
    rng = np.random.default_rng(5)
    noise = 2e-5 * rng.standard_normal((400, plant.velocity_output.shape[0]))
    schedule = np.arange(400) * 20 + np.concatenate([[0], rng.integers(-9, 10, 399)])
    return dataclasses.replace(
        s,
        plant=plant,
        laws=laws,
        pulse_amplitude=230.0,
        pulse_direction=70.0,
        sensor_noise=noise,
        amplifier_lag=2e-3,
        sample_steps=schedule,
    )


class _Counting:
    """The Python reference law, counting the samples it spends in the safe state."""

    def __init__(self, inner):
        self.inner, self.sample_time, self.count = inner, inner.sample_time, 0

    def reset(self):
        self.inner.reset()
        self.count = 0

    def step(self, measurements):
        out = self.inner.step(measurements)
        self.count += int(self.inner.status != 0)
        return out


def _both(s, artifact, compiled, law):
    reference = _Counting(siso_law(artifact) if law == "SISO" else clipped_lqg(artifact))
    python = run_semi_active(s, law, reference)
    c, safe = compiled.run(s, law)
    return python, reference.count, c, safe


@pytest.mark.parametrize("law", ["SISO", "cLQG"])
@pytest.mark.parametrize("perturbed", [False, True], ids=["nominal", "perturbed"])
def test_the_compiled_loop_is_the_python_loop_bit_for_bit(study, law, perturbed):
    s, artifact, compiled = study
    s = _perturbed(s) if perturbed else s
    python, python_safe, c, c_safe = _both(s, artifact, compiled, law)
    for field in FIELDS:
        np.testing.assert_array_equal(getattr(c, field), getattr(python, field), err_msg=field)
    assert c.control_power == python.control_power and c_safe == python_safe == 0
    assert np.all(np.isfinite(c.energy))
    # F_N^max while the pulse acts (40 ms), the law after it: the run must have used both.
    assert np.all(c.normal_force[:40] == s.normal_force_max) and np.any(c.normal_force[41:] < s.normal_force_max)
    if perturbed:  # the lag: after the pulse F_N leaves F^max by α of the step, not at once
        alpha = -np.expm1(-1e-3 / 2e-3)
        step = python.normal_force[40] - s.normal_force_max  # the first sample after the pulse
        assert np.all(np.abs(step) <= alpha * (s.normal_force_max - s.normal_force_min) * (1 + 1e-12))
    if perturbed and law == "cLQG":  # the noise and the pulse's angle changed what the law did
        nominal, _ = compiled.run(dataclasses.replace(s, sensor_noise=None), law)
        assert not np.array_equal(nominal.normal_force, c.normal_force)
        turned, _ = compiled.run(dataclasses.replace(s, pulse_direction=45.0, sensor_noise=None), law)
        assert not np.array_equal(nominal.sensors, turned.sensors)
        regular, _ = compiled.run(dataclasses.replace(s, sample_steps=None, sensor_noise=None), law)
        assert not np.array_equal(nominal.sensors, regular.sensors)


@pytest.mark.parametrize("force", [40.0, 400.0])
def test_a_passive_run_is_the_python_loops_bit_for_bit(study, force):
    s, _, compiled = study
    s = _perturbed(s)
    forces = np.full(2, force)
    python, c = run_passive(s, "passive", forces), compiled.run_passive(s, "passive", forces)
    for field in FIELDS:
        np.testing.assert_array_equal(getattr(c, field), getattr(python, field), err_msg=field)
    # The amplifiers lag (τ = 2 ms): the step from F^max to the passive force decays e-fold per 2 ms
    # (on the regular schedule, where the recorded rows are the samples).
    c = compiled.run_passive(dataclasses.replace(s, sample_steps=None), "passive", forces)
    gap = c.normal_force[40:] - force
    assert np.all(c.normal_force[:40] == s.normal_force_max)
    if force < s.normal_force_max[0]:
        expected = (s.normal_force_max - force) * np.exp(-np.arange(1, 21) * 0.5)[:, None]
        np.testing.assert_allclose(gap[:20], expected, rtol=1e-9)


def test_the_pulse_at_45_degrees_is_the_studys_and_one_input_has_no_angle(study):
    s, _, _ = study
    at = dataclasses.replace(s, pulse_direction=45.0).pulse()
    assert np.array_equal(at(0.01), s.pulse()(0.01)) and np.array_equal(at.directions, [1.0, 1.0])
    turned = dataclasses.replace(s, pulse_direction=-30.0).pulse()
    assert np.hypot(*turned.directions) == pytest.approx(np.sqrt(2.0), rel=1e-15)
    one = dataclasses.replace(s.plant, disturbance_input=s.plant.disturbance_input[:, :1])
    with pytest.raises(
        ModelError, match=r"^pulse_direction: 10.0 deg — needs two disturbance inputs, the design has 1$"
    ):
        dataclasses.replace(s, plant=one, pulse_direction=10.0).pulse()


def test_a_schedule_out_of_order_is_one_line(study):
    s, _, compiled = study
    backwards = np.arange(400) * 20
    backwards[5] = backwards[4] - 1
    with pytest.raises(ModelError, match=r"^sample_steps: 400 values — need whole plant steps from 0, strictly"):
        compiled.run(dataclasses.replace(s, sample_steps=backwards), "cLQG")


def test_the_safe_state_is_the_python_loops_too(study):
    """Plausibility limits the motion exceeds: both loops go to the safe state on the same samples."""
    s, artifact, _ = study
    tight = dataclasses.replace(artifact, sliding_velocity_limit=tuple(np.full(2, 2e-4)))
    python, python_safe, c, c_safe = _both(s, tight, CompiledLoop(tight), "SISO")
    np.testing.assert_array_equal(c.normal_force, python.normal_force)
    assert c_safe == python_safe and 0 < c_safe < len(c.time) - 1


def test_what_the_compiled_loop_cannot_run_is_one_line(study):
    s, artifact, compiled = study
    with pytest.raises(ModelError, match=r"^law: 'active LQG' — allowed: siso, clqg, preset, slipratio$"):
        compiled.run(s, "active LQG")
    other = dataclasses.replace(s, normal_force_max=s.normal_force_max + 1.0)
    with pytest.raises(ModelError, match=r"^normal_force_max: the study's \[401.0, 401.0\] are not the artefact's$"):
        compiled.run(other, "cLQG")
    with pytest.raises(ModelError, match=r"^sample_time: 0.002 s — the artefact's law runs at 0.001 s$"):
        compiled.run(dataclasses.replace(s, sample_time=0.002), "SISO")
