"""The physical spread of the structure (issue 32): the design file's ``[uncertainty]`` table and
its one-line errors, the defaults beneath it with their sources, a joint's own friction factor
replacing the common one, the identification's intervals multiplied on top, and a sweep that
draws it with ``[uncertain] from = "design"``."""

from __future__ import annotations

import numpy as np
import pytest
import tomli_w
from conftest import small_truss

from smartjoint.common.errors import DesignError, ModelError
from smartjoint.design.control import ensemble, sweep_sampling
from smartjoint.design.control.physical_spread import describe, physical_spread, with_identification
from smartjoint.design.control.sweep_file import load_sweep
from smartjoint.design.structure.spec import parse_design


def _design(uncertainty: dict | None = None):
    data = small_truss()
    data["control"] = {"modes": 4, "considered_modes": 10, "study_duration": 0.2}
    if uncertainty is not None:
        data["uncertainty"] = uncertainty
    return data


def _names(design) -> list[str]:
    return [joint.name for joint in design.joints]


def test_the_defaults_cover_every_input_with_a_source():
    design = parse_design(_design())
    entries = physical_spread(design, 200.0)
    names = [e.input.name for e in entries]
    for name in ("modal_frequency_scale", "modal_damping", "pulse_amplitude", "amplifier_lag"):
        assert name in names
    # one noise figure per sample for every tip sensor: only where they share a quantity (a unit)
    assert ("sensor_noise" in names) == (len({sensor.quantity for sensor in design.sensors}) == 1)
    assert {n for n in names if n.startswith("friction.")} == {
        f"friction.{p}" for p in ("sigma0", "sigma1", "sigma2", "coulomb", "stribeck", "stribeck_velocity")
    }
    assert all(e.source.startswith("default: ") for e in entries)
    damping = next(e.input.distribution for e in entries if e.input.name == "modal_damping")
    assert damping.median == design.modal_damping  # around the design's own ξ, not a fixed number
    pulse = next(e.input.distribution for e in entries if e.input.name == "pulse_amplitude")
    assert (pulse.low, pulse.high) == pytest.approx((180.0, 220.0))
    lag = next(e.input.distribution for e in entries if e.input.name == "amplifier_lag")
    assert lag.high == pytest.approx(0.5 * design.control.sample_time)
    assert len(describe(entries)) == len(entries)


def test_the_design_file_replaces_a_default_and_defaults_false_takes_none():
    given = {"modal_frequency_scale": {"distribution": "uniform", "low": 0.9, "high": 1.1}}
    design = parse_design(_design(given))
    entries = {e.input.name: e for e in physical_spread(design, 200.0)}
    assert entries["modal_frequency_scale"].source == "design file"
    assert entries["modal_frequency_scale"].input.distribution.low == 0.9
    assert entries["modal_damping"].source.startswith("default")
    design = parse_design(_design({**given, "defaults": False}))
    assert [e.input.name for e in physical_spread(design, 200.0)] == ["modal_frequency_scale"]


def test_a_joints_own_friction_factor_replaces_the_common_one_for_that_joint_only():
    design = parse_design(_design())
    first, second = _names(design)[:2]
    own = {"distribution": "uniform", "low": 0.5, "high": 0.6}
    design = parse_design(_design({"friction": {first: {"coulomb": own}}, "defaults": True}))
    inputs = [e.input for e in physical_spread(design, 200.0)]
    columns = dict(sweep_sampling.column_distributions(inputs, _names(design)))
    assert columns[f"friction.{first}.coulomb"].low == 0.5
    assert columns[f"friction.{second}.coulomb"].kind == "normal"
    assert sum(c.endswith(".coulomb") for c in columns) == len(_names(design))  # one column per joint


@pytest.mark.parametrize(
    ("uncertainty", "expected"),
    [
        ({"stiffness": {}}, "uncertainty.stiffness: {} — unknown input; allowed: defaults,"),
        ({"friction": {"sigma3": {}}}, "uncertainty.friction.sigma3: {} — a friction parameter (sigma0,"),
        (
            {"modal_damping": {"distribution": "uniform", "low": 0.1, "high": 1.5}},
            "uncertainty.modal_damping.high: 1.5 — outside the support (0, 0.99]",
        ),
        (
            {"friction": {"coulomb": {"distribution": "normal", "mean": 1.0, "std": 0.0, "low": 0.5, "high": 1.5}}},
            "uncertainty.friction.coulomb.std: 0.0 — must be > 0",
        ),
        ({"defaults": "yes"}, "uncertainty.defaults: 'yes'"),
    ],
)
def test_uncertainty_errors_name_key_value_and_what_is_allowed(uncertainty, expected):
    with pytest.raises(DesignError) as caught:
        parse_design(_design(uncertainty))
    message = str(caught.value)
    assert "\n" not in message and expected in message, message


def test_a_joint_the_design_does_not_have_is_one_line():
    with pytest.raises(DesignError, match=r"uncertainty\.friction\.Z9: .*a joint's name"):
        parse_design(_design({"friction": {"Z9": {"coulomb": {"distribution": "uniform", "low": 0.9, "high": 1}}}}))


def test_the_identification_multiplies_its_factor_into_the_physical_one():
    design = parse_design(_design())
    entries = with_identification(physical_spread(design, 200.0), {"sigma0": 0.01, "unknown": 0.5, "coulomb": 0.0})
    added = [e for e in entries if e.input.name.startswith("identification.")]
    assert [e.input.name for e in added] == ["identification.sigma0"]
    d = added[0].input.distribution
    assert d.kind == "lognormal" and d.sigma == 0.01 and d.low * d.high == pytest.approx(1.0)
    # sample_setup: σ0 of a joint is nominal × physical factor × identification factor
    from smartjoint.design.control import study as closed_loop

    model = closed_loop.design_model(design, lambda line: None)
    base_setup = closed_loop.setup(design, model)

    class Base:  # what sample_setup reads of an ensemble base
        setups = (base_setup,)
        joint_names = tuple(_names(design))
        seed = 1

    joint = _names(design)[0]
    inputs = {f"friction.{joint}.sigma0": 1.5, f"identification.{joint}.sigma0": 1.1}
    s = ensemble.sample_setup(Base, {}, inputs)  # type: ignore[arg-type]
    assert s.laws[0].sigma0 == base_setup.laws[0].sigma0 * 1.5 * 1.1
    assert s.laws[1].sigma0 == base_setup.laws[1].sigma0


def test_a_sweep_from_the_design_draws_its_spread_and_keeps_its_own_entries(tmp_path):
    (tmp_path / "small.toml").write_text(tomli_w.dumps(_design()))
    (tmp_path / "sweep.toml").write_text(
        'design = "small.toml"\nlaws = ["SISO"]\nsamples = 64\nseed = 3\n[grid]\nsiso_boundary_layer = [1e-4]\n'
        '[uncertain]\nfrom = "design"\npulse_amplitude = { distribution = "uniform", low = 10.0, high = 20.0 }\n'
    )
    sweep = load_sweep(tmp_path / "sweep.toml")
    assert sweep.spread_from_design
    from smartjoint.bench.sweep import _design_spread

    design = parse_design(_design())
    lines: list[str] = []
    resolved = _design_spread(sweep, design, lines.append)
    names = [u.name for u in resolved.inputs]
    assert names.count("pulse_amplitude") == 1 and "modal_damping" in names and "friction.coulomb" in names
    columns, values = sweep_sampling.sample_inputs(resolved, _names(design))
    pulse = values[:, columns.index("pulse_amplitude")]
    assert pulse.min() >= 10.0 and pulse.max() <= 20.0  # the file's own entry, not the default
    frequency = values[:, columns.index("modal_frequency_scale")]
    assert 0.97 <= frequency.min() and frequency.max() <= 1.03 and np.std(frequency) > 0.005
    assert any("modal_damping" in line for line in lines)


def test_a_sweep_from_anything_else_is_one_line(tmp_path):
    (tmp_path / "small.toml").write_text(tomli_w.dumps(_design()))
    (tmp_path / "sweep.toml").write_text(
        'design = "small.toml"\nlaws = ["passive F_max"]\nsamples = 4\nseed = 3\n[uncertain]\nfrom = "paper"\n'
    )
    with pytest.raises(DesignError, match=r"uncertain\.from: 'paper' — only 'design'"):
        load_sweep(tmp_path / "sweep.toml")


def test_a_per_joint_entry_naming_a_joint_placed_later_is_checked_when_drawn():
    import dataclasses

    from smartjoint.design.structure.uncertainty import Distribution, UncertainInput, Uncertainty

    design = parse_design(_design())
    wrong = UncertainInput("friction.Q7.coulomb", Distribution("uniform", 0.9, 1.1))
    design = dataclasses.replace(design, uncertainty=Uncertainty((wrong,)))
    with pytest.raises(ModelError, match=r"uncertainty\.friction\.Q7\.coulomb: no joint 'Q7'"):
        physical_spread(design, 200.0)
