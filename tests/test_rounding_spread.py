"""The band a faithful re-implementation's E(t_e) lies in (bench.rounding_spread.chaos_band): its
arithmetic, and the false-alarm rates its docstring states, checked by drawing."""

from __future__ import annotations

import numpy as np
import pytest

from smartjoint.bench.rounding_spread import chaos_band, verdict_cell, within_band


def test_the_band_is_the_range_with_the_unperturbed_run_widened_by_its_width():
    assert chaos_band([-0.02, 0.01]) == pytest.approx((-0.05, 0.04))
    assert chaos_band([0.01, 0.03]) == pytest.approx((-0.03, 0.06))  # the unperturbed run (0) is a draw too
    assert chaos_band([1e-4, -1e-4]) == pytest.approx((-0.0101, 0.0101))  # at least 1 % either side
    assert chaos_band([]) is None and within_band(0.0, []) is None and within_band(None, [0.1]) is None
    assert within_band(0.04, [-0.02, 0.01]) and not within_band(0.041, [-0.02, 0.01])
    assert verdict_cell(False, [-0.02, 0.01]) == "**no** (-5.0 … +4.0 %)"


@pytest.mark.parametrize("runs, rate", [(4, 0.030), (8, 0.003)])
def test_a_new_draw_leaves_the_range_as_often_as_stated_and_the_band_rarely(runs, rate):
    """``runs`` perturbed runs and the unperturbed one are runs + 1 draws of a spread: one more
    falls outside their range with probability 2/(runs + 2), outside the widened band with the
    rate the docstring states (normal draws), so a faithful run is seldom called unfaithful."""
    rng = np.random.default_rng(33)
    draws = 0.05 * rng.standard_normal((40000, runs + 2))
    spread = draws[:, 1 : runs + 1] - draws[:, [0]]  # relative to the unperturbed run, as mil_runs gives them
    new = draws[:, runs + 1] - draws[:, 0]
    low, high = np.minimum(spread.min(axis=1), 0.0), np.maximum(spread.max(axis=1), 0.0)
    assert abs(np.mean((new < low) | (new > high)) - 2 / (runs + 2)) < 0.01
    outside = np.mean([not within_band(float(d), s) for d, s in zip(new[:20000], spread[:20000])])
    assert abs(outside - rate) < 0.4 * rate + 0.001
