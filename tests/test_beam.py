"""Beam element against analytical Euler–Bernoulli, torsion and axial bar solutions."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import ALUMINIUM, TUBE, beam_design

from smartjoint.design import build_model, parse_design, solve_modes
from smartjoint.design.structure.modal import eigensolve

pytestmark = pytest.mark.numerics  # run again by the portability leg (.ci/portability)

BETA_L = np.array([1.875104, 4.694091, 7.854757])


def _section():
    outer = TUBE["outer_diameter"]
    inner = outer - 2 * TUBE["wall_thickness"]
    area = np.pi / 4 * (outer**2 - inner**2)
    second = np.pi / 64 * (outer**4 - inner**4)
    return area, second


def _family_frequencies(model, dof: str, count: int) -> np.ndarray:
    """Frequencies of the modes whose motion is dominated by one DOF type (e.g. 'rx')."""
    values, shapes = eigensolve(model.stiffness, model.mass, model.n_dof)
    labels = np.array([label[1] for label in model.dof_labels])
    share = np.array(
        [np.sum(shapes[labels == dof, k] ** 2) / np.sum(shapes[:, k] ** 2) for k in range(shapes.shape[1])]
    )
    picked = np.sqrt(values[share > 0.9]) / (2 * np.pi)
    return picked[:count]


def test_cantilever_bending_matches_euler_bernoulli():
    length = 2.0
    model = build_model(parse_design(beam_design(length, elements=10)))
    modes = solve_modes(model, 6)
    area, second = _section()
    exact = (
        BETA_L**2
        / (2 * np.pi * length**2)
        * np.sqrt(ALUMINIUM["youngs_modulus"] * second / (ALUMINIUM["density"] * area))
    )
    fem = modes.frequencies_hz[::2]  # y and z bending coincide for a tube: pairs
    np.testing.assert_allclose(modes.frequencies_hz[1::2], fem, rtol=1e-9)
    error = np.abs(fem - exact) / exact
    assert error[0] < 1e-4  # 0.01 %
    assert error[2] < 1e-3  # 0.1 %
    assert error[0] < error[1] < error[2]


def test_cantilever_bending_converges_at_fourth_order():
    errors = []
    area, second = _section()
    exact = (
        BETA_L[2] ** 2
        / (2 * np.pi * 4.0)
        * np.sqrt(ALUMINIUM["youngs_modulus"] * second / (ALUMINIUM["density"] * area))
    )
    for n in (4, 8, 16):
        model = build_model(parse_design(beam_design(2.0, elements=n)))
        errors.append(abs(solve_modes(model, 6).frequencies_hz[4] - exact) / exact)
    order = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(order > 3.5), order


@pytest.mark.parametrize("dof, modulus", [("rx", "shear_modulus"), ("ux", "youngs_modulus")])
def test_torsion_and_axial_bar_modes(dof, modulus):
    length = 2.0
    # Clamped-free bar: f_n = (2n − 1)/(4L)·sqrt(E/ρ) axially, sqrt(G/ρ) in torsion (GJ/ρI_p).
    exact = np.array([1, 3]) / (4 * length) * np.sqrt(ALUMINIUM[modulus] / ALUMINIUM["density"])
    errors = []
    for n in (10, 20, 40):
        model = build_model(parse_design(beam_design(length, elements=n)))
        fem = _family_frequencies(model, dof, 2)
        errors.append(np.abs(fem - exact) / exact)
    errors = np.array(errors)
    # Linear elements with consistent mass overestimate ω by (k·h)²/24 to leading order,
    # k = (2n − 1)π/(2L): 0.103 % for the first mode at 10 elements.
    for row, n in zip(errors, (10, 20, 40)):
        predicted = (np.array([1, 3]) * np.pi / (2 * length) * length / n) ** 2 / 24
        np.testing.assert_allclose(row, predicted, rtol=0.05)
    order = np.log2(errors[:-1, 0] / errors[1:, 0])
    np.testing.assert_allclose(order, 2.0, atol=0.1)  # second order, as linear elements must be
