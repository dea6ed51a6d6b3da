"""Stage 10 of ``smartjoint run`` (smartjoint/pipeline_ensemble.py, issue 20): the friction's spread
comes from the identification's 95 % intervals, the widest over the joint types, and a parameter
without an interval keeps ±5 %."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from smartjoint.common import friction_registry
from smartjoint.design.control.friction_uncertainty import (
    MAX_LOG_SIGMA,
    Z95,
    friction_inputs,
    friction_spreads,
)


def _type(**intervals):
    parameters = {name: {"value": 1.0, "ci95": interval} for name, interval in intervals.items()}
    parameters["radius"] = {"value": 0.02, "ci95": None}
    fitted = SimpleNamespace(model=friction_registry.DEFAULT)
    return SimpleNamespace(
        identification=SimpleNamespace(as_dict=lambda: {"parameters": parameters}, parameters=fitted)
    )


def test_the_spread_is_the_log_sigma_of_the_widest_interval():
    a = _type(sigma0=[0.9, 1.1], coulomb=[0.98, 1.02], sigma1=[0.01, 100.0])
    b = _type(sigma0=[0.8, 1.25], coulomb=[1.0, math.inf], stribeck=[0.0, 2.0], sigma2=[1e-300, 1e300])
    spreads = friction_spreads([a, b])
    assert spreads["sigma0"] == pytest.approx(math.log(1.25 / 0.8) / (2 * Z95), rel=1e-15)
    assert spreads["coulomb"] == pytest.approx(math.log(1.02 / 0.98) / (2 * Z95), rel=1e-15)  # b's is unbounded
    assert spreads["sigma1"] == MAX_LOG_SIGMA  # weakly identifiable: within a factor 2 at 95 %
    assert spreads["sigma2"] == MAX_LOG_SIGMA  # an interval whose ratio overflows: still capped
    assert set(spreads) == {"sigma0", "coulomb", "sigma1", "sigma2"}  # no radius, no interval from 0


def test_each_factor_is_lognormal_within_its_interval_or_five_percent_uniform():
    inputs = {u.name: u.distribution for u in friction_inputs({"sigma0": 0.1})}
    assert list(inputs) == [f"friction.{p}" for p in friction_registry.LUGRE.keys]
    d = inputs["friction.sigma0"]
    assert (d.kind, d.median, d.sigma) == ("lognormal", 1.0, 0.1)
    assert d.low == pytest.approx(math.exp(-Z95 * 0.1)) and d.high == pytest.approx(math.exp(Z95 * 0.1))
    other = inputs["friction.coulomb"]
    assert (other.kind, other.low, other.high) == ("uniform", 0.95, 1.05)
