"""The clipped LQG in two phases (issue 19): the reference's split — the output phase from
r = (K − KM·C)·q and the small constant products, the innovation in the update phase — is the
textbook current-form Kalman filter; the float build (fused multiply-adds) splits into its phases
bit for bit, with a repeatable output phase; and the float build refuses precomputed products it
cannot hold (codegen/rendering.check_products_fit_float)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import plausible_measurements
from scipy.linalg import block_diag

from smartjoint import cli
from smartjoint.codegen import controllers, generate
from smartjoint.common.errors import ModelError
from smartjoint.design.control import artifact
from smartjoint.design.control.filter import clipped_lqg
from smartjoint.design.control.realisation import SYMMETRY_TOLERANCE

ROOT = Path(__file__).resolve().parents[1]
FLOAT_TRUE_MIN = float(np.finfo(np.float32).smallest_subnormal)


@pytest.fixture(scope="module")
def reference():
    return artifact.load(ROOT / "firmware" / "generated" / "controller.json")


def _sequence(a, count=400, seed=3):
    """Plausible measurements only (no fault), most commands between the force limits."""
    return plausible_measurements(a, count, seed, sensor=1e-4, slip=1e-3, friction=20)


def _textbook(law):
    """Φ, Γ0·E, Γ1·E, C, M, K of the realised filter (control.realisation: the design's up to
    its cancelled entries) in the design's channels and the realisation's coordinates and basis."""
    r = law.realisation
    e = r.joint_input @ r.joints.matrix()
    hold = [(np.asarray(g)[:, :, None] * e[:, None, :]).reshape(-1, e.shape[1]) for g in (r.gamma0, r.gamma1)]
    ts = r.sensors.matrix()
    output, estimator = np.linalg.solve(ts, r.output), r.estimator_gain @ ts
    feedback = r.joints.matrix().T @ r.feedback_gain
    return block_diag(*r.blocks), hold[0], hold[1], output, estimator, feedback


def _close(realised, designed, scale):
    return np.abs(realised - designed).max() <= 2 * SYMMETRY_TOLERANCE * scale


@pytest.mark.numerics
def test_the_two_phase_reference_is_the_textbook_kalman_filter(reference):
    """x̂⁻ = Φ·x̂ − Γ0·E·u⁺ − Γ1·E·u_k (0 at the first sample), x̂ = x̂⁻ + M·(y − C·x̂⁻),
    u_d = −K·x̂, computed densely with the realised matrices: the reference's estimate (mapped
    back to the design's basis) and desired forces agree to rounding; and the realised matrices,
    mapped back by the change of basis T, are the design's to the cancellation tolerance."""
    law = clipped_lqg(reference)
    phi, hold0, hold1, output, estimator, feedback = _textbook(law)
    d, r = law.design, law.realisation
    states, t = r.state_order(), r.transformation()
    inverse = np.linalg.inv(t)
    assert _close(output @ inverse, d.output[:, states], np.abs(d.output).max())
    assert _close(t @ estimator, d.estimator_gain[states], np.abs(d.estimator_gain).max())
    assert _close(feedback @ inverse, d.feedback_gain[:, states], np.abs(d.feedback_gain).max())
    assert _close(t @ phi @ inverse, d.state_matrix[np.ix_(states, states)], 1.0)
    designed_hold = d.input_matrices()[1][states]
    assert _close(t @ hold1, designed_hold, np.abs(designed_hold).max())
    estimate, previous, started = np.zeros(phi.shape[0]), np.zeros(hold0.shape[1]), False
    worst = 0.0
    for m in _sequence(reference):
        law.step(m)
        assert law.status == 0, m.time
        prior = phi @ estimate - hold0 @ previous - hold1 @ m.friction_force if started else np.zeros(phi.shape[0])
        estimate = prior + estimator @ (m.sensors - output @ prior)
        desired = -feedback @ estimate
        scale = np.abs(feedback) @ np.abs(estimate)
        worst = max(worst, float(np.max(np.abs(law.desired_force - desired) / scale)))
        designed = r.to_design(estimate)
        np.testing.assert_allclose(law.estimate, designed, rtol=1e-9, atol=1e-12 * np.abs(designed).max())
        previous, started = law.previous_force.copy(), True
    assert worst < 1e-10, worst


def _phases(compiled):
    """A compiled cLQG stepped as output phase, output phase again (when it succeeded), update phase."""
    lib, prefix = compiled.c.lib, compiled.c.prefix
    output_phase, update_phase = (
        getattr(lib, f"{prefix}_clqg_output_phase"),
        getattr(lib, f"{prefix}_clqg_update_phase"),
    )

    def step(state, inputs, outputs):
        first = output_phase(state, inputs, outputs)
        if first == 0:  # a fault restarts the filter: the call after it is another sample's
            again = output_phase(state, inputs, outputs)
            assert again == first
        update_phase(state, inputs, outputs)
        return first

    compiled._step = step
    return compiled


@pytest.mark.numerics
@pytest.mark.parametrize("real", ["float", "double"])
def test_the_phases_are_the_step_bit_for_bit_and_the_output_phase_repeats(reference, real):
    """Faults included (the sequence of test_codegen with NaN/±Inf and absurd values): the C
    stepped as output, output again (a successful one repeats exactly), update gives the
    commands, desired forces and status bits of its own step — in the float build with its fused
    multiply-adds too. The target's self-test times the output phase by that repetition."""
    from test_codegen import _sequence as faulty

    build = controllers.compile_controllers(reference, real)
    if real == "float":
        assert "fmaf(" in build.files["smartjoint_clqg.c"]
    else:
        assert "fma" not in build.files["smartjoint_clqg.c"].replace("MULTIPLY", "")
    stepped, split = build.law("clqg"), _phases(build.law("clqg"))
    for m in faulty(reference, count=1500):
        assert split.step(m).tobytes() == stepped.step(m).tobytes(), m.time
        assert split.status == stepped.status and split.desired_force.tobytes() == stepped.desired_force.tobytes()


def _scaled(reference, **factors):
    return dataclasses.replace(
        reference, **{field: (np.asarray(getattr(reference, field)) * f).tolist() for field, f in factors.items()}
    )


def _gamma1_at_the_float_floor(reference) -> dict:
    """Γ1 scaled so that its smallest entry is 2× the least float: every entry fits, and
    C·Γ1·E, whose smallest entry is a few % of Γ1's (C and E entries below 1), does not."""
    g = np.abs(np.asarray(reference.gamma1, dtype=float))
    return {"gamma1": 2 * FLOAT_TRUE_MIN / g[g > 0].min()}


@pytest.mark.parametrize(
    "factors, product, words",
    [
        (lambda _: {"feedback_gain": 1e25, "estimator_gain": 1e25}, "feedback_hold", "exceeds the float range"),
        (_gamma1_at_the_float_floor, "output_hold", "underflows to 0 in float"),
    ],
)
def test_the_float_build_refuses_products_it_cannot_hold(reference, tmp_path, capsys, factors, product, words):
    """Every field fits a float, a precomputed product does not: one line naming the product and
    entry, nothing written; the double build takes the same artefact."""
    changed = _scaled(reference, **factors(reference))
    with pytest.raises(ModelError) as refused:
        generate.render(changed, "float")
    message = str(refused.value)
    assert message.startswith(f"{product}[") and words in message and "--real double" in message
    assert "\n" not in message
    generate.render(changed, "double")
    source = tmp_path / "scaled.json"
    source.write_text(artifact.dumps(changed))
    assert cli.main(["codegen", str(source), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert product in err and err.count("\n") == 0 and not (tmp_path / "out").exists(), err
