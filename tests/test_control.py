"""Semi-active controllers (paper Section 5): Eq. 30–31 and Eq. 33–34 reference laws, LQG design."""

from __future__ import annotations

import dataclasses

import control as ct
import numpy as np
import pytest
import scipy.linalg

from smartjoint.common.errors import DesignError, ModelError
from smartjoint.design import control, plant
from smartjoint.design.friction import lugre
from smartjoint.design.structure import modal
from smartjoint.design.structure.fem import build_model
from smartjoint.design.structure.spec import parse_design

pytestmark = pytest.mark.numerics  # run again by the portability leg (.ci/portability)


@pytest.fixture(scope="module")
def model():
    from conftest import small_truss

    fe = build_model(parse_design(small_truss()), joints="released")
    return modal.modal_model(fe, modal.solve_modes(fe, 8))


def _measure(t, v, u, fn, y=(0.0,)):
    return plant.Measurements(t, np.array(y, float), np.array(v, float), np.array(u, float), np.array(fn, float))


def test_siso_law_follows_eq_30_with_mu_of_the_previous_sample():
    law = control.SisoLaw(1e-3, [10.0, 10.0], [110.0, 110.0], [1e-3, 1e-3])
    law.reset()
    # First sample: no previous μ → F_N^min.
    assert np.allclose(law.step(_measure(0.0, [0.1, 0.1], [30.0, -30.0], [100.0, 100.0])), [10.0, 10.0])
    # μ = u_R/F_N of the previous sample = ±0.3; μ·v = 0.3·0.1 ≥ ε → F^max; −0.3·0.1 ≤ 0 → F^min.
    out = law.step(_measure(1e-3, [0.1, 0.1], [5.0, 5.0], [50.0, 50.0]))
    assert np.allclose(out, [110.0, 10.0])
    # Now μ = 5/50 = 0.1; v = 5e-3 → μv = 5e-4 = ε/2: half way (continuous boundary layer).
    out = law.step(_measure(2e-3, [5e-3, -5e-3], [0.0, 0.0], [1.0, 1.0]))
    assert np.allclose(out, [60.0, 10.0])
    law.reset()
    assert np.allclose(law.step(_measure(0.0, [1.0, 1.0], [30.0, 30.0], [100.0, 100.0])), [10.0, 10.0])


def test_clipped_law_reads_eq_34_with_a_force_boundary_layer(model):
    design = control.design_lqg(model, 1e-3)
    law = control.ClippedLqg(design, np.full(2, 20.0), np.full(2, 220.0), 10.0)
    law.reset()
    m = _measure(0.0, [0.0, 0.0], [50.0, -50.0], [100.0, 100.0], y=np.zeros(model.velocity_output.shape[0]))
    out = law.step(m)
    e = law.desired_force - np.array([50.0, -50.0])
    expected = 20.0 + 200.0 * np.clip(e * np.sign([50.0, -50.0]) / 10.0, 0, 1)
    assert np.allclose(out, expected)
    assert np.all((out >= 20.0) & (out <= 220.0))


def test_lqg_gains_equal_python_control_and_the_loop_is_stable(model):
    """K from dlqr on the exactly discretised model; the current-form Kalman gain M is consistent
    with dlqe's predictor gain (L = Φ·M) and P solves the filter Riccati equation."""
    d = control.design_lqg(model, 1e-3, 1.0, 1e-6, 1e4, 1e-10)
    a = d.state_matrix
    g0, g1 = d.input_matrices()
    b = -(g0 + g1)
    k, _, _ = ct.dlqr(a, b, np.eye(a.shape[0]), 1e-6 * np.eye(b.shape[1]))
    assert np.max(np.abs(d.feedback_gain - k)) < 1e-9 * np.abs(k).max()  # measured 4e-11
    h = model.disturbance_input
    gz = d.gamma0 + d.gamma1
    g = (gz[:, :, None] * h[:, None, :]).reshape(a.shape[0], -1)
    c = d.output
    qn, rn = 1e4 * np.eye(g.shape[1]), 1e-10 * np.eye(c.shape[0])
    l_pred, p, _ = ct.dlqe(a, g, c, qn, rn)
    assert np.allclose(a @ d.estimator_gain, l_pred, rtol=1e-7, atol=1e-9 * np.abs(l_pred).max())
    p_ref = scipy.linalg.solve_discrete_are(a.T, c.T, g @ qn @ g.T, rn)
    assert np.allclose(d.riccati_estimator, p_ref, rtol=1e-6, atol=1e-9 * np.abs(p_ref).max())
    poles = d.closed_loop_poles()
    assert np.max(np.abs(poles)) < 1.0
    # The sensors see the tip; the state estimate converges on the linear model without noise.
    assert np.max(np.abs(np.linalg.eigvals(a - a @ d.estimator_gain @ c))) < 1.0


def test_active_lqg_damps_the_linear_model_far_more_than_structural_damping(model):
    d = control.design_lqg(model, 1e-3)
    pulse = plant.triangular_pulse(200.0, 0.04, (1.0,))
    active = plant.simulate(
        model, [], control.ActiveLqg(d, hold_until=0.04), pulse, 0.5, 1e-3, energy_books=False, scheme="linear"
    )
    free = plant.simulate(
        model, [], control.ActiveLqg(d, hold_until=10.0), pulse, 0.5, 1e-3, energy_books=False, scheme="linear"
    )  # never acts
    assert np.allclose(free.friction_force, 0.0)
    assert active.energy[-1] < 1e-2 * free.energy[-1]  # measured 1.9e-3


def test_study_runs_are_deterministic(model):
    d = control.design_lqg(model, 1e-3)
    laws = [lugre.TYPE_A, lugre.TYPE_B]
    pulse = plant.triangular_pulse(200.0, 0.04, (1.0,))
    runs = [
        plant.simulate(
            model,
            laws,
            plant.HoldDuringExcitation(
                control.ClippedLqg(d, np.full(2, 20.0), np.full(2, 300.0), 5.0), 0.04, np.full(2, 300.0)
            ),
            pulse,
            0.1,
            1e-4,
        )
        for _ in range(2)
    ]
    assert np.array_equal(runs[0].friction_force, runs[1].friction_force)
    assert np.array_equal(runs[0].normal_force, runs[1].normal_force)
    assert np.all(runs[0].normal_force[runs[0].time < 0.04 - 1e-9] == 300.0)


def test_bad_controller_inputs_are_named(model):
    with pytest.raises(ModelError, match="F_N\\^min > 0"):
        control.SisoLaw(1e-3, [0.0, 0.0], [100.0, 100.0], [1e-3, 1e-3])
    with pytest.raises(ModelError, match="F_N\\^min <= F_N\\^max"):
        control.SisoLaw(1e-3, [200.0, 10.0], [100.0, 100.0], [1e-3, 1e-3])
    with pytest.raises(ModelError, match="too coarse.*Nyquist"):
        control.design_lqg(model, 1.0 / model.omega.max() * 2 * np.pi)
    with pytest.raises(ModelError, match="control_weight"):
        control.design_lqg(model, 1e-3, control_weight=-1.0)
    blind = dataclasses.replace(
        model,
        displacement_output=np.zeros_like(model.displacement_output),
        velocity_output=np.zeros_like(model.velocity_output),
    )
    with pytest.raises(ModelError, match="not detectable in practice: no sensor sees any mode"):
        control.design_lqg(blind, 1e-3)


def test_a_mode_no_sensor_sees_or_no_joint_moves_is_designed_for_and_named(model):
    """A symmetric truss has such modes (a triangular mast's axial modes under tip sensors): they
    are stable, so the LQG exists; the design names them, the LQR leaves the unmoved one alone and
    the loop stays stable."""
    unseen, unmoved = 1, 2
    outputs = {name: getattr(model, name).copy() for name in ("displacement_output", "velocity_output")}
    for matrix in outputs.values():
        matrix[:, unseen] = 0.0
    joint_input = model.joint_input.copy()
    joint_input[unmoved] = 0.0
    symmetric = dataclasses.replace(model, joint_input=joint_input, **outputs)
    design = control.design_lqg(symmetric, 1e-3)
    assert design.blind_modes() == {"unseen": (unseen,), "unmoved": (unmoved,)}
    gain = np.abs(design.feedback_gain)
    assert gain[:, 2 * unmoved : 2 * unmoved + 2].max() <= 1e-9 * gain.max()
    assert np.abs(design.closed_loop_poles()).max() < 1.0
    assert control.design_lqg(model, 1e-3).blind_modes() == {"unseen": (), "unmoved": ()}


def test_design_file_control_table_errors_name_the_key():
    from conftest import small_truss

    data = small_truss()
    data["control"] = {"normal_force_min": 500.0, "normal_force_max": 400.0}
    with pytest.raises(DesignError, match="control.normal_force_min"):
        parse_design(data)
    data["control"] = {"joints": ["NOPE"]}
    with pytest.raises(DesignError, match="control.joints"):
        parse_design(data)
    data["control"] = {"sample_time": -1.0}
    with pytest.raises(DesignError, match="control.sample_time"):
        parse_design(data)
    data["control"] = {"normal_force_max": [100.0]}
    with pytest.raises(DesignError, match="control.normal_force_max"):
        parse_design(data)


SAFETY = dict(
    safe_normal_force=[60.0, 80.0],
    friction_force_limit=[100.0, 100.0],
    measured_normal_force_min=[-5.0, -5.0],
    measured_normal_force_max=[120.0, 120.0],
)


def test_siso_law_puts_every_joint_at_the_safe_force_on_an_unusable_input():
    law = control.SisoLaw(1e-3, [10.0, 10.0], [110.0, 110.0], [1e-3, 1e-3], sliding_velocity_limit=[1.0, 1.0], **SAFETY)
    law.step(_measure(0.0, [0.1, 0.1], [30.0, 30.0], [100.0, 100.0]))
    assert np.array_equal(law.step(_measure(1e-3, [0.1, 0.1], [30.0, 30.0], [100.0, 100.0])), [110.0, 110.0])
    # At the limits is plausible: the law acts (μ = 0.3, v = 1 → F^max).
    assert np.array_equal(law.step(_measure(2e-3, [1.0, -1.0], [100.0, -100.0], [120.0, -5.0])), [110.0, 10.0])
    assert law.status == control.STATUS_OK
    # One value just beyond its range in joint 0: both joints at their safe force, only joint 0 forgets μ.
    beyond = float(np.nextafter(100.0, np.inf))
    assert np.array_equal(law.step(_measure(3e-3, [0.1, -0.1], [beyond, -30.0], [100.0, 100.0])), [60.0, 80.0])
    assert law.status == control.STATUS_INPUT_IMPLAUSIBLE
    out = law.step(_measure(4e-3, [0.1, 0.1], [30.0, 30.0], [100.0, 100.0]))
    assert out[0] == 10.0 and out[1] == 10.0  # joint 0: μ = 0; joint 1: μ = −30/100 < 0 with v > 0
    # NaN is INPUT_INVALID only, Inf too; a finite absurd value is INPUT_IMPLAUSIBLE; both at once: both bits.
    for bad, status in (
        (np.nan, control.STATUS_INPUT_INVALID),
        (np.inf, control.STATUS_INPUT_INVALID),
        (1e38, control.STATUS_INPUT_IMPLAUSIBLE),
        (-200.0, control.STATUS_INPUT_IMPLAUSIBLE),
    ):
        assert np.array_equal(law.step(_measure(5e-3, [0.1, 0.1], [30.0, 30.0], [bad, 100.0])), [60.0, 80.0])
        assert law.status == status, bad
    law.step(_measure(6e-3, [np.nan, 2.0], [30.0, 30.0], [100.0, 100.0]))
    assert law.status == control.STATUS_INPUT_INVALID | control.STATUS_INPUT_IMPLAUSIBLE


def test_clipped_lqg_restarts_at_the_safe_force_on_an_unusable_input(model):
    design = control.design_lqg(model, 1e-3)
    ny = model.velocity_output.shape[0]
    law = control.ClippedLqg(
        design,
        np.full(2, 20.0),
        np.full(2, 220.0),
        10.0,
        sensor_limit=np.full(ny, 0.01),
        **{**SAFETY, "safe_normal_force": [220.0, 20.0]},
    )
    good = _measure(0.0, [0.0, 0.0], [50.0, -50.0], [100.0, 100.0], y=np.full(ny, 0.01))  # sensors at the limit
    fresh = law.step(good)
    assert law.status == control.STATUS_OK and law.started
    # A measured F_N is checked where it is used, by the update phase: its sample's command stands
    # (it uses only the sensors and friction forces), the filter restarts, the next sample is safe.
    for field, bad, status, later in (
        ("sensors", -0.0101, control.STATUS_INPUT_IMPLAUSIBLE, False),
        ("friction_force", -101.0, control.STATUS_INPUT_IMPLAUSIBLE, False),
        ("normal_force", 121.0, control.STATUS_INPUT_IMPLAUSIBLE, True),
        ("normal_force", np.nan, control.STATUS_INPUT_INVALID, True),
    ):
        law.step(good)
        faulty = _measure(0.0, [0.0, 0.0], [50.0, -50.0], [100.0, 100.0], y=np.full(ny, 0.01))
        getattr(faulty, field)[-1] = bad
        out = law.step(faulty)
        if later:
            assert law.status == control.STATUS_OK and not law.started and np.all(law.estimate == 0.0), field
            assert not np.array_equal(out, [220.0, 20.0])
            out = law.step(good)
        assert np.array_equal(out, [220.0, 20.0]) and law.status == status, field
        assert not law.started and np.all(law.desired_force == 0.0) and np.all(law.estimate == 0.0)
        assert np.array_equal(law.step(good), fresh)  # the filter restarted: as at its first sample


def test_defaults_without_safety_data_only_refuse_non_finite_inputs():
    law = control.SisoLaw(1e-3, [10.0, 10.0], [110.0, 110.0], [1e-3, 1e-3])
    assert np.array_equal(law.safe_normal_force, [110.0, 110.0])  # the design file's default: F^max
    law.step(_measure(0.0, [1e6, -1e6], [1e9, 1e9], [-1e9, 1e9]))
    assert law.status == control.STATUS_OK
    assert np.array_equal(law.step(_measure(0.0, [np.inf, 0.0], [0.0, 0.0], [1.0, 1.0])), [110.0, 110.0])
    assert law.status == control.STATUS_INPUT_INVALID


def test_bad_safety_arguments_are_named():
    args = (1e-3, [10.0, 10.0], [110.0, 110.0], [1e-3, 1e-3])
    with pytest.raises(ModelError, match="safe_normal_force: \\[5.0, 50.0\\] — must lie within"):
        control.SisoLaw(*args, safe_normal_force=[5.0, 50.0])
    with pytest.raises(ModelError, match="sliding_velocity_limit: \\[0.0, 1.0\\] — must be > 0"):
        control.SisoLaw(*args, sliding_velocity_limit=[0.0, 1.0])
    with pytest.raises(ModelError, match="friction_force_limit: .*expected a number or 2 numbers"):
        control.SisoLaw(*args, friction_force_limit=[1.0, 2.0, 3.0])
    with pytest.raises(ModelError, match="measured_normal_force_min .* need min <= max"):
        control.SisoLaw(*args, measured_normal_force_min=[0.0, 0.0], measured_normal_force_max=[-1.0, 100.0])
