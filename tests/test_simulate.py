"""Closed-loop plant simulation: exact linear part, energy balance, Radau reference."""

from __future__ import annotations

import numpy as np
import pytest

from smartjoint.design import lugre, modal, simulate
from smartjoint.design.fem import build_model
from smartjoint.design.spec import parse_design


@pytest.fixture(scope="module")
def model():
    from conftest import small_truss

    fe = build_model(parse_design(small_truss()), joints="released")
    return modal.modal_model(fe, modal.solve_modes(fe, 12))


JOINTS = [lugre.TYPE_A, lugre.TYPE_B]


def test_free_decay_is_exact_for_any_step(model):
    """F_N = 0: each mode decays as the analytic damped oscillator, whatever the step."""
    x0 = np.zeros((model.n_coordinates, 2))
    x0[0, 1] = 1.0  # ω_1·η_1 = 1, at rest
    w, xi = model.omega[0], model.damping[0]
    wd = w * np.sqrt(1 - xi**2)
    for step in (1e-3, 5e-3):
        result = simulate.simulate(model, JOINTS, simulate.ConstantNormalForce(np.zeros(2), step), None, 0.5, step,
                                   initial_state=x0)
        t = result.time
        eta = (1 / w) * np.exp(-xi * w * t) * (np.cos(wd * t) + xi * w / wd * np.sin(wd * t))
        energy = 0.5 * ((w * eta) ** 2 + np.gradient(eta, t) ** 2)
        assert np.allclose(result.energy[::10], 0.5 * (w * eta[::10]) ** 2 + 0.5 * _velocity(w, xi, t[::10]) ** 2,
                           rtol=1e-9, atol=1e-12)
        assert energy.size == t.size


def _velocity(w, xi, t):
    wd = w * np.sqrt(1 - xi**2)
    return -(w / wd) * np.exp(-xi * w * t) * np.sin(wd * t)


def test_energy_balance_and_dissipation(model):
    """e(t) − e(0) = W_in − W_joints − W_damping to O(h²); the joints dissipate net."""
    pulse = simulate.triangular_pulse(200.0, 0.04, (1.0,))
    errors = []
    for step in (2e-4, 1e-4):
        result = simulate.simulate(model, JOINTS, simulate.ConstantNormalForce(np.array([20.0, 20.0]), 1e-3), pulse,
                                   0.2, step)
        errors.append(result.balance_error())
        # Net dissipation in the joints (u_R·v itself may dip below zero while the bristles unload).
        assert result.work_joints[-1] > 0.05 * result.work_in[-1]
        assert result.energy[-1] < result.work_in[-1] - result.work_joints[-1]
    assert errors[1] < 1e-3 and errors[1] < 0.35 * errors[0]  # second order


def test_agrees_with_radau_reference(model):
    """Friction force and energy against solve_ivp(Radau, analytic Jacobian), 60 ms after the pulse starts."""
    pulse = simulate.triangular_pulse(200.0, 0.04, (1.0,))
    normal_force = np.array([300.0, 400.0])
    times = np.arange(0.0, 0.06 + 1e-12, 1e-3)
    v_ref, u_ref, e_ref = simulate.reference_simulation(model, JOINTS, normal_force, pulse, 0.06, times)
    errors, energy_errors = [], []
    for step in (5e-5, 2.5e-5):
        result = simulate.simulate(model, JOINTS, simulate.ConstantNormalForce(normal_force, 1e-3), pulse, 0.06, step)
        index = np.round(times / step).astype(int)
        u = result.friction_force[index]
        errors.append(np.sqrt(np.mean((u - u_ref) ** 2, axis=0)) / np.sqrt(np.mean(u_ref**2, axis=0)))
        energy_errors.append(np.max(np.abs(result.energy[index] - e_ref)) / e_ref.max())
    # Energy: second order (measured 4.6e-7 → 1.2e-7); friction force of both joints below 1 %
    # at 25 µs and falling (docs/simulation.md has the whole convergence table).
    assert energy_errors[1] < 1e-6 and energy_errors[1] < 0.35 * energy_errors[0]
    assert np.all(errors[1] < 0.01) and np.all(errors[1] < errors[0])


def test_bad_inputs_are_named(model):
    with pytest.raises(Exception, match="whole multiple"):
        simulate.simulate(model, JOINTS, simulate.ConstantNormalForce(np.zeros(2), 1.5e-4), None, 0.1, 1e-4)
    with pytest.raises(Exception, match="joints: 1 LuGre"):
        simulate.simulate(model, JOINTS[:1], simulate.ConstantNormalForce(np.zeros(1), 1e-3), None, 0.1, 1e-4)
    with pytest.raises(Exception, match="normal forces"):
        simulate.simulate(model, JOINTS, simulate.ConstantNormalForce(np.array([-1.0, 0.0]), 1e-3), None, 0.1, 1e-4)


def test_simulate_command_names_a_wrong_normal_force_list():
    import subprocess
    import sys

    from smartjoint.pipeline import FIG10_DESIGN

    done = subprocess.run([sys.executable, "-m", "smartjoint.cli", "simulate", str(FIG10_DESIGN), "--no-update",
                           "--normal-force", "400,0"], capture_output=True, text=True)
    assert done.returncode == 2
    assert "--normal-force: '400,0' — need 3 finite values >= 0 (joints B1, A2, A3)" in done.stderr
