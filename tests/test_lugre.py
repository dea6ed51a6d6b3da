"""LuGre law (Eq. 1–2) and its exact-exponential step, against canonical cases and Radau."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from smartjoint.design.friction import lugre
from smartjoint.design.friction.lugre import CANUDAS_1995 as P


def test_steady_state_friction_is_the_stribeck_curve():
    v = np.concatenate([-np.logspace(-6, 1, 50), np.logspace(-6, 1, 50)])
    expected = np.sign(v) * (1.0 + 0.5 * np.exp(-((v / 1e-3) ** 2))) + 0.4 * v
    mu = lugre.friction_coefficient(P, v, lugre.steady_state_deflection(P, v))
    np.testing.assert_allclose(mu, expected, rtol=1e-9)
    # The discrete step reaches it from rest in one long step (exact solution).
    phi = lugre.step(P, np.zeros_like(v), v, dt=1e4)
    np.testing.assert_allclose(lugre.friction_coefficient(P, v, phi), expected, rtol=1e-9)


def test_step_is_bounded_for_any_step_and_stiffness():
    rng = np.random.default_rng(1)
    for sigma0 in (1e2, 1e5, 1e9, 1e13):
        p = lugre.LuGreParameters(sigma0, 1.0, 0.1, 0.61, 0.14, 0.01)
        phi = rng.uniform(-1, 1, 4000) * p.max_deflection
        for dt in (1e-9, 1e-5, 1e-3, 1.0, 1e3):
            v = rng.standard_normal(4000) * 10.0 ** rng.uniform(-8, 2, 4000)
            phi = lugre.step(p, phi, v, dt)
            assert np.all(np.isfinite(phi))
            assert np.max(np.abs(phi)) <= p.max_deflection * (1 + 1e-12)


def test_analytic_jacobian_matches_finite_differences():
    v = np.array([-0.3, -2e-3, -1e-4, 5e-4, 1e-3, 0.2])
    phi = 0.3 * lugre.steady_state_deflection(P, v) + 2e-6
    d_phi, d_v = lugre.rhs_jacobian(P, v, phi)
    h_phi, h_v = 1e-12, 1e-9
    np.testing.assert_allclose(
        d_phi, (lugre.rhs(P, v, phi + h_phi) - lugre.rhs(P, v, phi - h_phi)) / (2 * h_phi), rtol=1e-5
    )
    np.testing.assert_allclose(d_v, (lugre.rhs(P, v + h_v, phi) - lugre.rhs(P, v - h_v, phi)) / (2 * h_v), rtol=1e-5)


def _mass_with_friction(force, t_end, *, mass=1.0, spring=0.0, rtol, atol, max_step):
    """A mass with LuGre friction, states x, v, φ from rest, under the external force F(t, x);
    ``spring`` is −∂F/∂x, for the analytic Jacobian. Radau with dense output."""

    def f(t, s):
        x, v, phi = s
        friction = lugre.friction_coefficient(P, v, phi)
        return [v, (force(t, x) - friction) / mass, lugre.rhs(P, v, phi)]

    return solve_ivp(
        f,
        (0, t_end),
        [0.0, 0.0, 0.0],
        method="Radau",
        rtol=rtol,
        atol=atol,
        max_step=max_step,
        dense_output=True,
        jac=lambda t, s: _jacobian(s, mass, spring),
    )


def _jacobian(state, mass, spring=0.0):
    """Analytic Jacobian of the mass–friction system (x, v, φ)."""
    _, v, phi = state
    f_phi, f_v = lugre.rhs_jacobian(P, v, phi)
    mu_v = P.sigma1 * f_v + P.sigma2
    mu_phi = P.sigma0 + P.sigma1 * f_phi
    return np.array([[0.0, 1.0, 0.0], [-spring / mass, -mu_v / mass, -mu_phi / mass], [0.0, f_v, f_phi]])


def test_presliding_under_force_below_breakaway_is_bounded_and_returns():
    # Force cycles 0 → 0.9 F_s → 0 → −0.9 F_s → 0, slowly: presliding only, no gross sliding.
    period = 2.0
    amplitude = 0.9 * 1.5
    solution = _mass_with_friction(
        lambda t, x: amplitude * np.sin(2 * np.pi * t / period), 4 * period, rtol=1e-10, atol=1e-13, max_step=1e-2
    )
    t = np.linspace(0, 4 * period, 4001)
    x = solution.sol(t)[0]
    assert np.max(np.abs(x)) < 3 * P.max_deflection  # tens of micrometres: bristles, not sliding
    # No drift: the displacement at the same phase of consecutive cycles repeats.
    at_cycle_ends = solution.sol(np.arange(1, 5) * period)[0]
    assert np.ptp(at_cycle_ends[1:]) < 1e-3 * np.ptp(x)
    # Hysteresis: the force–displacement loop encloses a positive area (energy dissipated).
    last = t >= 3 * period
    force = amplitude * np.sin(2 * np.pi * t[last] / period)
    area = np.trapezoid(force, x[last])
    assert area > 1e-3 * amplitude * np.ptp(x)


def test_stick_slip_of_a_mass_pulled_through_a_spring_is_periodic():
    # Canudas de Wit et al. (1995): m = 1 kg, k = 2 N/m, pulled at 0.1 m/s.
    k, pull = 2.0, 0.1

    t_end = 40.0
    solution = _mass_with_friction(
        lambda t, x: k * (pull * t - x), t_end, spring=k, rtol=1e-9, atol=1e-12, max_step=5e-3
    )
    t = np.linspace(10.0, t_end, 60001)
    v = solution.sol(t)[1]
    sticking = np.abs(v) < 1e-3 * pull
    assert 0.1 < sticking.mean() < 0.9  # both phases present
    starts = t[1:][np.diff(sticking.astype(int)) == -1]  # slip onsets
    periods = np.diff(starts)
    assert len(periods) >= 4
    # The intervals between slip onsets repeat (a cycle may hold more than one stick phase).
    np.testing.assert_allclose(periods[2:], periods[:-2], rtol=1e-2)
    assert v.max() > 1.5 * pull  # slip overshoots the pulling speed


def _prescribed(t):
    # Two-tone sliding velocity whose reversals (every 0.1 s) fall on every grid tested: the
    # documented order holds between reversals; a reversal inside a step costs O(h²) locally.
    return 5e-3 * np.sin(2 * np.pi * 5.0 * t) * (1.0 + 0.5 * np.cos(2 * np.pi * 13.0 * t))


def _reference(t_end):
    jac = lambda t, phi: np.atleast_2d(lugre.rhs_jacobian(P, _prescribed(t), phi[0])[0])  # noqa: E731
    return solve_ivp(
        lambda t, phi: lugre.rhs(P, _prescribed(t), phi),
        (0, t_end),
        [0.0],
        method="Radau",
        jac=jac,
        rtol=1e-12,
        atol=1e-16,
        dense_output=True,
    )


@pytest.mark.parametrize("where, order", [("midpoint", 2.0), ("start", 1.0)])
def test_step_agrees_with_radau_at_its_documented_order(where, order):
    t_end = 0.2
    reference = _reference(t_end)
    errors = []
    steps = (2e-4, 1e-4, 5e-5, 2.5e-5)
    for dt in steps:
        n = round(t_end / dt)
        phi = 0.0
        history = np.empty(n)
        for i in range(n):
            t = i * dt + (0.5 * dt if where == "midpoint" else 0.0)
            phi = lugre.step(P, phi, _prescribed(t), dt)
            history[i] = phi
        exact = reference.sol(np.arange(1, n + 1) * dt)[0]
        mu_error = P.sigma0 * np.abs(history - exact)
        errors.append(mu_error.max())
    observed = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert errors[-1] < (2e-3 if where == "start" else 1e-6)  # friction coefficient error
    np.testing.assert_allclose(observed, order, atol=0.25)
