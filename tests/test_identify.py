"""Identification model consistency (Eq. 3) and the rig/identify command line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import run_cli

from smartjoint.design.friction import lugre, rig, rig_integration
from smartjoint.design.friction.equation_error import model_friction, simulate_friction
from smartjoint.design.friction.fitting import nrmse
from smartjoint.design.friction.record_screening import classify
from smartjoint.design.friction.rig_campaign import standard_campaign


@pytest.mark.numerics
@pytest.mark.parametrize("joint_type, inertia", [("A", 1.0), ("B", 2e-3)])
def test_true_parameters_reproduce_noise_free_records(joint_type, inertia):
    p = lugre.TABLE_1[joint_type]
    level = rig.breakaway(p, 400.0)
    micro = rig.simulate(rig.RigTest(joint_type, 400.0, 0.5 * level, 10.0, cycles=1.0, inertia=inertia))
    stick = rig.simulate(rig.RigTest(joint_type, 400.0, 1.1 * level, 5.0, cycles=1.0, inertia=inertia))
    assert classify(micro) == "micro-slip" and classify(stick) == "stick-slip"
    # Eq. 3 with the measured velocity as input reproduces both regimes.
    assert nrmse(micro.friction_force, model_friction(p, micro, micro.sliding_velocity)) < 0.01
    assert nrmse(stick.friction_force, model_friction(p, stick, stick.sliding_velocity)) < 0.01
    # A wrong Coulomb level is visible in the error: the measure discriminates.
    wrong = lugre.LuGreParameters(
        p.sigma0, p.sigma1, p.sigma2, 1.1 * p.coulomb, p.stribeck, p.stribeck_velocity, p.radius
    )
    assert nrmse(stick.friction_force, model_friction(wrong, stick, stick.sliding_velocity)) > 0.03


@pytest.mark.numerics
@pytest.mark.parametrize("joint_type", ["A", "B"])
def test_rig_kernel_matches_the_python_reference(joint_type):
    """rig_kernel.c mirrors rig_integration._integrate_python: both regimes, a varying F_N, uneven samples."""
    p = lugre.TABLE_1[joint_type]
    time = np.cumsum(np.r_[0.0, np.full(1999, 5e-5) * (1.0 + 0.2 * np.sin(np.arange(1999)))])
    fine = np.interp(np.linspace(0.0, 1999.0, 1999 * rig_integration.SUBSTEPS + 1), np.arange(2000.0), time)
    for factor, inertia in ((0.5, 1.0 if joint_type == "A" else 2e-3), (1.3, 0.2 if joint_type == "A" else 5e-4)):
        gain = p.moment_arm * 400.0 * (1.0 + 0.1 * np.sin(2.0 * np.pi * 7.0 * fine))
        force = factor * rig.breakaway(p, 400.0) * np.sin(2.0 * np.pi * 10.0 * fine)
        python = rig_integration.integrate(
            p, gain, inertia, force, time, rig_integration.SUBSTEPS, 1e-4, 0.0, backend="python"
        )
        native = rig_integration.integrate(
            p, gain, inertia, force, time, rig_integration.SUBSTEPS, 1e-4, 0.0, backend="c"
        )
        for reference, value in zip(python, native):
            assert np.max(np.abs(value - reference)) <= 1e-12 * np.max(np.abs(reference))
    with pytest.raises(ValueError, match="force: .* need"):
        rig_integration.integrate(p, 400.0, 1.0, np.zeros(5), time, rig_integration.SUBSTEPS)
    with pytest.raises(ValueError, match="gain: .* one per substep node"):
        rig_integration.integrate(p, np.ones(5), 1.0, np.zeros(fine.size), time, rig_integration.SUBSTEPS)


@pytest.mark.numerics
@pytest.mark.parametrize("joint_type", ["A", "B"])
def test_equation_error_kernel_matches_the_python_reference(joint_type):
    """sj_equation_error_friction mirrors the Python loop of Eq. 3's model force: both regimes,
    a varying F_N, uneven samples, a velocity through zero."""
    p = lugre.TABLE_1[joint_type]
    for factor in (0.5, 1.3):
        record = rig.simulate(
            rig.RigTest(
                joint_type,
                400.0,
                factor * rig.breakaway(p, 400.0),
                10.0,
                2.0,
                1.0 if joint_type == "A" else 2e-3,
                noise=0.01,
                seed=3,
            )
        )
        time = record.time * (1.0 + 0.01 * np.sin(np.arange(record.time.size)))
        time = np.maximum.accumulate(time) + 1e-9 * np.arange(time.size)
        normal_force = record.normal_force * (1.0 + 0.1 * np.sin(40.0 * record.time))
        args = (p, time, record.sliding_velocity, normal_force, record.friction_force[0])
        python = simulate_friction(*args, backend="python")
        native = simulate_friction(*args, backend="c")
        assert np.max(np.abs(native - python)) <= 1e-12 * np.max(np.abs(python))
        assert np.ptp(python) > 0.5 * np.ptp(record.friction_force)  # a real force history, not zeros


# One micro-slip test of the rig: F_N = 400 N, a 150 N excitation at 10 Hz, one cycle.
MICRO_SLIP = ("--normal-force", "400", "--amplitude", "150", "--frequency", "10", "--cycles", "1")


def test_rig_command_writes_a_readable_record(tmp_path):
    target = tmp_path / "r.csv"
    done = run_cli("rig", "--type", "A", *MICRO_SLIP, "--noise", "0.01", "-o", str(target), "--json")
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["records"][0]["regime"] == "micro-slip"
    from smartjoint.design.friction.records import read_record

    record = read_record(target)
    assert record.inertia == 1.0 and np.all(record.normal_force == 400.0)


def test_identify_refuses_missing_regime(tmp_path):
    target = tmp_path / "micro.csv"
    run_cli("rig", *MICRO_SLIP, "-o", str(target), check=True)
    done = run_cli("identify", str(target))
    assert done.returncode == 2 and "no stick-slip records" in done.stderr


@pytest.mark.parametrize("joint_type", ["A", "B"])
def test_identification_recovers_table_1_from_noisy_rig_records(joint_type):
    """Table 1 parameters, 1 % noise: σ0, F_c, F_d and v_s within 5 %, σ1 weakly identifiable.

    The output-error step (rig model driven by the excitation force) removes the Eq. 3
    errors-in-variables bias of F_d (type A +5.6 % after the Eq. 3 steps). It also pins σ2
    down to about ±15–45 % (95 %): σ2 is weakly identifiable by Eq. 3 alone, and its
    output-error interval must hold the true value.
    """
    from smartjoint.design.friction.identify import identify

    p = lugre.TABLE_1[joint_type]
    # prior = the simulated parameters (Table 1): the campaign of earlier versions, exact records
    records = [rig.simulate(test) for test in standard_campaign(joint_type, p, noise=0.01, cycles=8)]
    micro = [r for r in records if classify(r) == "micro-slip"]
    stick = [r for r in records if classify(r) == "stick-slip"]
    assert len(micro) == 2 and len(stick) == 4
    result = identify(micro, stick)
    assert result.refined is not None and result.steps[-1].startswith("output error (")
    for name in ("sigma0", "coulomb", "stribeck", "stribeck_velocity"):
        assert abs(getattr(result.parameters, name) / getattr(p, name) - 1) < 0.05, name
    assert "sigma1" in result.weakly_identifiable
    assert {"sigma1", "sigma2"} <= set(result.micro.weak + result.stick.weak)  # Eq. 3 alone
    sigma2 = result.refined.names.index("sigma2")
    assert result.refined.lower[sigma2] <= p.sigma2 <= result.refined.upper[sigma2]
    # The fit explains every record nearly as well as the true parameters (the rest is noise:
    # F_exc − m·a with a differentiated from the noisy velocity).
    fitted = {**result.micro.nrmse, **result.stick.nrmse}
    for record in micro + stick:
        truth = nrmse(record.friction_force, model_friction(p, record, record.sliding_velocity))
        assert fitted[record.name] <= 1.15 * truth, record.name
    # …and the output-error velocities down to the 1 % measurement noise.
    assert max(result.refined.nrmse.values()) < 0.012


@pytest.mark.numerics
def test_campaign_from_a_prior_off_by_two_identifies_the_joint():
    """The experimenter believes F_c, F_d, σ0 and v_s all twice type B's true values (Table 1):
    the campaign designed from that prior (amplitude ladder run upwards, records sorted by the
    regime they show) still holds both regimes, and σ0, F_c, F_d, v_s come out within 5 % at 1 %
    noise. The standard set designed from the same prior has no micro-slip record: its lowest
    amplitude is the true break-away (benchmarks/campaign_prior.py, docs/identification.md)."""
    from smartjoint.design.friction.identify import identify
    from smartjoint.design.friction.rig_campaign import campaign, run_campaign

    truth = lugre.TYPE_B
    prior = lugre.LuGreParameters(
        sigma0=2.0 * truth.sigma0,
        sigma1=truth.sigma1,
        sigma2=truth.sigma2,
        coulomb=2.0 * truth.coulomb,
        stribeck=2.0 * truth.stribeck,
        stribeck_velocity=2.0 * truth.stribeck_velocity,
        radius=truth.radius,
    )
    old = [rig.simulate(test, truth) for test in standard_campaign("B", prior, cycles=1)]
    assert {classify(r) for r in old} == {"stick-slip"}
    tests = campaign("B", prior, noise=0.01, cycles=8)
    measured = run_campaign(tests, prior, lambda test: rig.simulate(test, truth))  # the truth enters here only
    assert measured.micro and measured.stick
    result = identify(measured.micro, measured.stick)
    for name in ("sigma0", "coulomb", "stribeck", "stribeck_velocity"):
        assert abs(getattr(result.parameters, name) / getattr(truth, name) - 1) < 0.05, name


@pytest.mark.numerics
@pytest.mark.parametrize("joint_type", ["A", "B"])
def test_output_error_model_reproduces_a_noise_free_stick_slip_record(joint_type):
    """shoot(): segments from the velocity peaks, low-passed force, same integrator as the rig."""
    from smartjoint.design.friction.output_error import prepare_shooting as _prepare_shooting
    from smartjoint.design.friction.output_error import shoot

    p = lugre.TABLE_1[joint_type]
    record = rig.simulate(standard_campaign(joint_type, p, cycles=2)[1])  # prior = truth; stick-slip, 1.1× break-away
    shooting = _prepare_shooting(record, p.moment_arm)
    assert shooting.starts.size == 4  # one velocity peak per half period
    assert nrmse(shooting.measured, shoot(p, shooting)) < 5e-4
    wrong = lugre.LuGreParameters(
        p.sigma0, p.sigma1, p.sigma2, p.coulomb, 1.05 * p.stribeck, p.stribeck_velocity, p.radius
    )
    assert nrmse(shooting.measured, shoot(wrong, shooting)) > 1e-2


def test_output_error_step_needs_excitation_force_and_inertia():
    from smartjoint.design.friction.output_error import output_error_blocker as _output_error_blocker
    from smartjoint.design.friction.output_error import output_error_gap

    record = rig.simulate(standard_campaign("A", lugre.TYPE_A, cycles=1)[2])  # prior = the simulated Table 1
    assert output_error_gap(record) is None and _output_error_blocker([record], True) is None
    assert _output_error_blocker([record], False) == "switched off"
    record.inertia = None
    assert _output_error_blocker([record], True) == f"{record.name}: no '# inertia = …' metadata (or inertia 0)"
    record.excitation_force = None
    assert output_error_gap(record) == f"{record.name}: no column 'excitation_force'"


def test_stick_slip_step_refuses_a_record_without_slip():
    from smartjoint.design.friction.identify import identify
    from smartjoint.design.friction.records import RecordError

    micro = rig.simulate(rig.RigTest("A", 400.0, 150.0, 10.0, cycles=1.0))
    still = rig.simulate(rig.RigTest("A", 400.0, 100.0, 8.0, cycles=1.0))
    with pytest.raises(RecordError, match="rig_A_FN400_A100_f8: column 'sliding_velocity' shows no gross slip"):
        identify([micro], [still])


def test_identify_refuses_a_record_whose_friction_coefficient_no_metal_contact_has():
    """A type B rig record with F_N in daN read as N (μ ×10): refused in one line naming the
    record, the peak of its friction column F_exc − m·a averaged over a quarter excitation period
    (its m·a noise is not friction), μ = u_R/(r·F_N) there and the bound — also with the radius
    given to identify instead of carried by the records."""
    import re

    from smartjoint.design.friction.identify import identify
    from smartjoint.design.friction.record_screening import MAX_FRICTION_COEFFICIENT, friction_coefficient_peak
    from smartjoint.design.friction.records import RecordError

    records = [rig.simulate(test) for test in standard_campaign("B", lugre.TYPE_B, noise=0.01, cycles=2)]
    micro = [r for r in records if classify(r) == "micro-slip"]
    stick = [r for r in records if classify(r) == "stick-slip"]
    assert max(friction_coefficient_peak(r)[0] for r in micro + stick) < 0.6  # Table 1: F_c + F_d = 0.57
    slipped = stick[0]
    slipped.normal_force = slipped.normal_force / 10.0
    mu, time, window = friction_coefficient_peak(slipped)
    assert window == 500 and 5.0 < mu < 6.0  # 10 Hz at 20 kHz: a quarter period is 0.025 s
    expected = (
        f"{slipped.name}: friction coefficient |u_R|/(r·F_N) = {mu:.4g} at t = {time:.6g} s (its peak, averaged "
        f"over 500 samples = 0.025 s) — allowed: <= {MAX_FRICTION_COEFFICIENT:g} (dry friction of metal contacts "
        "stays below about 1.5; check the units of the force columns and the inertia)"
    )
    with pytest.raises(RecordError, match=f"^{re.escape(expected)}$"):
        identify(micro, stick)
    for record in micro + stick:
        record.radius = None
    with pytest.raises(RecordError, match=f"^{re.escape(expected)}$"):
        identify(micro, stick, radius=lugre.TYPE_B.radius)
