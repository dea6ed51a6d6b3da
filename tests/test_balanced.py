"""Balanced truncation, the baseline of the reduction (design/reduction/balanced.py), and the
quasi-static Krylov corrections measured against it (issue 31)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from smartjoint.common.errors import ModelError
from smartjoint.design import reduction
from smartjoint.design.control import lqg
from smartjoint.design.reduction import balanced
from smartjoint.design.structure import modal
from smartjoint.design.structure.fem import build_model
from smartjoint.design.structure.spec import parse_design

pytestmark = pytest.mark.numerics  # run again by the portability leg (.ci/portability)


@pytest.fixture(scope="module")
def small():
    from conftest import small_truss

    fe = build_model(parse_design(small_truss()), joints="released")
    return fe, modal.solve_modes(fe, fe.n_dof)


def _error(full, reduced_response, grid, path="uv") -> float:
    """H∞ of full − reduced on the grid: the largest singular value."""
    exact = reduction.frequency_response(full, grid, path)
    return float(np.linalg.svd(exact - reduced_response, compute_uv=False).max())


def test_the_closed_form_gramians_solve_the_lyapunov_equations(small):
    fe, modes = small
    few = modal.modal_model(fe, modes, np.arange(20))
    A, B, C = balanced.state_space(few)
    P, Q = balanced.modal_gramians_exact(few)
    assert np.abs(A @ P + P @ A.T + B @ B.T).max() < 1e-10 * np.abs(B @ B.T).max()
    assert np.abs(A.T @ Q + Q @ A + C.T @ C).max() < 1e-10 * np.abs(C.T @ C).max()
    assert np.allclose(P, P.T) and np.linalg.eigvalsh(P).min() > -1e-12 * np.abs(P).max()


def test_balanced_truncation_is_python_controls_balred(small):
    """Same Hankel values and the same reduced transfer functions as SLICOT's AB09AD through
    python-control, on a model small enough for its dense Lyapunov solver."""
    import control

    fe, modes = small
    few = modal.modal_model(fe, modes, np.arange(20))
    A, B, C = balanced.state_space(few)
    ours = balanced.balanced_truncation(few, 12)
    theirs = control.balred(control.ss(A, B, C, 0), 12, method="truncate")
    hankel = control.hsvd(control.ss(A, B, C, 0))
    assert np.allclose(ours.hankel[:14], hankel[:14], rtol=1e-8)
    grid = np.linspace(0.0, 1.5 * few.omega.max(), 300)
    l = few.joint_input.shape[1]
    response = np.stack([theirs.C @ np.linalg.solve(1j * w * np.eye(12) - theirs.A, theirs.B) for w in grid])
    tolerance = 1e-9 * np.abs(response).max()
    assert np.allclose(ours.frequency_response(grid, "uv"), -response[:, :l, :l], rtol=1e-7, atol=tolerance)
    assert np.allclose(ours.frequency_response(grid, "wy"), response[:, l:, l:], rtol=1e-7, atol=tolerance)
    # H∞ error bound of balanced truncation: σ_13 ≤ ‖G − G_r‖∞ ≤ 2 Σ_{k>12} σ_k.
    error = _error(few, ours.frequency_response(grid, "uv"), grid)
    assert error <= 2.0 * ours.hankel[12:].sum()
    with pytest.raises(ModelError, match="order: 40"):
        balanced.balanced_truncation(few, 40)


def test_quasi_static_corrections_keep_the_static_compliance_and_add_no_resonance(small):
    """Eq. 26's correction has a lightly damped pseudo-mode inside the band; made quasi-static it
    keeps EᵀK⁻¹E exact and the in-band accuracy, and across the band it is no worse than the
    modes alone (the pseudo-mode's peak gone), where Eq. 26's form is several times worse."""
    fe, modes = small
    full = modal.modal_model(fe, modes)
    first = modal.Modes(modes.omega[:20], modes.shapes[:, :20], modes.damping[:20])
    paper = reduction.reduce(fe, first, 6, 1).model
    nyquist = 1.5 * paper.omega[6:].max()  # a controller whose band holds every pseudo-mode
    quasi = reduction.reduce(fe, first, 6, 1, correction_frequency=4.0 * nyquist).model
    alone = reduction.reduce(fe, first, 6, 0).model
    exact = reduction.static_compliance(fe)
    assert np.allclose(reduction.modal_compliance(quasi), exact, rtol=1e-9, atol=1e-12 * np.abs(exact).max())
    assert np.allclose(quasi.omega[6:], 4.0 * nyquist) and np.all(quasi.damping[6:] == reduction.QUASI_STATIC_DAMPING)
    assert np.array_equal(quasi.omega[:6], paper.omega[:6])
    assert np.array_equal(quasi.joint_input[:6], paper.joint_input[:6])
    grid = reduction.frequency_grid([full, paper, quasi], nyquist)
    errors = {name: _error(full, reduction.frequency_response(m, grid, "uv"), grid) for name, m in
              (("paper", paper), ("quasi", quasi), ("alone", alone))}  # fmt: skip
    assert errors["quasi"] <= 1.01 * errors["alone"]
    assert errors["paper"] > 3.0 * errors["quasi"]
    band = grid[grid <= first.omega[-1]]
    in_band = {name: _error(full, reduction.frequency_response(m, band, "uv"), band) for name, m in
               (("paper", paper), ("quasi", quasi))}  # fmt: skip
    assert in_band["quasi"] <= 1.01 * in_band["paper"]


def test_the_nyquist_rule_exempts_critically_damped_corrections_only(small):
    fe, modes = small
    first = modal.Modes(modes.omega[:20], modes.shapes[:, :20], modes.damping[:20])
    kept = reduction.reduce(fe, first, 6, 0).model
    sample_time = 0.25 / float(kept.omega.max() / (2 * np.pi))  # the kept modes below Nyquist
    quasi = reduction.reduce(fe, first, 6, 1, correction_frequency=reduction.correction_frequency(sample_time)).model
    assert quasi.omega.max() > np.pi / sample_time
    lqg.check_sample_time(quasi, sample_time)  # corrections above Nyquist, ξ = 1: nothing aliases
    with pytest.raises(ModelError, match="too coarse"):
        lqg.check_sample_time(dataclasses.replace(quasi, damping=np.full_like(quasi.damping, 0.01)), sample_time)
