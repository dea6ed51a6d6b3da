"""Stick-exact steps (simulate(..., stick_step=H)): Radau reference, C against the numpy mirror, errors."""

from __future__ import annotations

import numpy as np
import pytest

from smartjoint.common.errors import ModelError
from smartjoint.design import plant
from smartjoint.design.friction import lugre
from smartjoint.design.plant import stick_exact
from smartjoint.design.structure import modal
from smartjoint.design.structure.fem import build_model
from smartjoint.design.structure.spec import parse_design

JOINTS = [lugre.TYPE_A, lugre.TYPE_B]


@pytest.fixture(scope="module")
def model():
    from conftest import small_truss

    fe = build_model(parse_design(small_truss()), joints="released")
    return modal.modal_model(fe, modal.solve_modes(fe, 12))


def _counted(monkeypatch):
    """Keep the kernel of the next stick-exact run, to read how many steps of each length it took."""
    seen = {}
    build = stick_exact.kernel

    def keep(*args, **kwargs):
        seen["kernel"] = build(*args, **kwargs)
        return seen["kernel"]

    monkeypatch.setattr(stick_exact, "kernel", keep)
    return seen


def test_agrees_with_radau_and_converges_in_the_long_step(model, monkeypatch):
    """0.3 s from the tip pulse: friction force and energy against solve_ivp(Radau). After the
    pulse every step is long (the joints of the small truss stick); the error is the slip term's
    first-order hold over the long step and falls at second order with it (measured, joint B:
    2.2 %, 0.57 %, 0.14 % at 1, 0.5, 0.25 ms)."""
    pulse = plant.triangular_pulse(200.0, 0.04, (1.0,))
    normal_force = np.array([300.0, 400.0])
    duration = 0.3
    times = np.arange(0.0, duration + 1e-12, 1e-3)
    _, u_ref, e_ref = plant.reference_simulation(model, JOINTS, normal_force, pulse, duration, times)
    seen = _counted(monkeypatch)
    errors = []
    for long_step in (1e-3, 5e-4, 2.5e-4):
        result = plant.simulate(
            model,
            JOINTS,
            plant.ConstantNormalForce(normal_force, 1e-3),
            pulse,
            duration,
            2.5e-5,
            record_every=40,
            energy_books=False,
            stick_step=long_step,
        )
        u = result.friction_force
        errors.append(float(np.max(np.sqrt(np.mean((u - u_ref) ** 2, axis=0)) / np.sqrt(np.mean(u_ref**2, axis=0)))))
        assert np.max(np.abs(result.energy - e_ref)) / e_ref.max() < 1e-2
        assert np.all(np.isnan(result.work_joints))  # no books in this scheme
        long_steps = seen["kernel"].counts[0]
        assert long_steps >= 0.9 * (duration - pulse.duration) / long_step, seen["kernel"].counts
    assert errors[0] > 3.0 * errors[1] > 9.0 * errors[2] and errors[2] < 0.005, errors


class _Switching:
    """Bang-bang normal forces (F_min or F_max per joint, pseudo-random each sample)."""

    def __init__(self, count, sample_time, seed=5):
        self.count, self.sample_time, self.seed = count, sample_time, seed

    def reset(self):
        self.rng = np.random.default_rng(self.seed)

    def step(self, measurements):
        return np.where(self.rng.random(self.count) < 0.5, 10.0, 400.0)


@pytest.mark.numerics
def test_c_kernel_matches_numpy_mirror(model, monkeypatch):
    """sj_stick_run and its numpy mirror take the same steps of each length and agree to round-off,
    with the pulse and with normal forces switching every sample (a discretisation per combination)."""
    pulse = plant.triangular_pulse(200.0, 0.04, (1.0,))
    seen = _counted(monkeypatch)
    for controller in (plant.ConstantNormalForce(np.array([300.0, 400.0]), 1e-3), _Switching(2, 1e-3)):
        runs, counts = [], []
        for backend in ("python", "c"):
            runs.append(
                plant.simulate(
                    model,
                    JOINTS,
                    controller,
                    pulse,
                    0.12,
                    5e-5,
                    record_every=20,
                    energy_books=False,
                    backend=backend,
                    stick_step=1e-3,
                )
            )
            counts.append(seen["kernel"].counts.tolist())
        assert counts[0] == counts[1], counts
        # the passive joints stick after the pulse (long steps); at F_min = 10 N they keep slipping
        assert (counts[0][0] > 0) == isinstance(controller, plant.ConstantNormalForce), counts
        for name in ("friction_force", "sliding_velocity", "deflection", "energy", "sensors"):
            a, b = getattr(runs[0], name), getattr(runs[1], name)
            assert np.max(np.abs(a - b)) <= 1e-9 * np.max(np.abs(a)), name


def test_bad_stick_exact_settings_are_named(model):
    forces = plant.ConstantNormalForce(np.array([300.0, 400.0]), 1e-3)
    with pytest.raises(ModelError, match="energy_books: True — the stick-exact scheme keeps no energy books"):
        plant.simulate(model, JOINTS, forces, None, 0.01, 5e-5, record_every=20, stick_step=1e-3)
    with pytest.raises(ModelError, match=r"stick_step: 0.00012 s must be a whole multiple of step 5e-05 s"):
        plant.simulate(model, JOINTS, forces, None, 0.012, 5e-5, record_every=20, energy_books=False, stick_step=1.2e-4)
    with pytest.raises(
        ModelError, match="record_every: 10 steps of 5e-05 s — with stick_step it must be a multiple of 20"
    ):
        plant.simulate(model, JOINTS, forces, None, 0.01, 5e-5, record_every=10, energy_books=False, stick_step=1e-3)
    switching = _Switching(2, 1e-3)
    with pytest.raises(ModelError, match="controller sample time 0.001 s must be a whole multiple of stick_step 0.002"):
        plant.simulate(model, JOINTS, switching, None, 0.01, 5e-5, record_every=40, energy_books=False, stick_step=2e-3)


def test_full_models_are_refused(model, monkeypatch):
    monkeypatch.setattr(stick_exact, "MAX_STATES", 10)
    with pytest.raises(
        ModelError, match="the model has 26 states — the stick-exact scheme is dense and takes at most 10"
    ):
        plant.simulate(
            model,
            JOINTS,
            plant.ConstantNormalForce(np.zeros(2), 1e-3),
            None,
            0.01,
            5e-5,
            record_every=20,
            energy_books=False,
            stick_step=1e-3,
        )
