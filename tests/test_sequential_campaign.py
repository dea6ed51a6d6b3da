"""The sequential rig campaign (issue 30): rounds designed from the estimate, honest verdicts on
what the records determine, the same loop over a folder a person fills, and the design's refusal
of parameters that were not identified."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import tomli_w
from conftest import cli_error, run_cli, small_truss

from smartjoint.common.errors import DesignError
from smartjoint.design.friction import lugre, rig, rig_campaign
from smartjoint.design.friction.identifiability import half_width
from smartjoint.design.friction.sequential_campaign import (
    MAX_RECORDS,
    MAX_ROUNDS,
    TARGET_HALF_WIDTH,
    TARGETED,
    plan_round,
    run_sequential,
)
from smartjoint.design.structure.spec import parse_design

# The issue's joint: type A, not Table 1's.
TRUTH_A = lugre.LuGreParameters(
    sigma0=3e5, sigma1=0.05, sigma2=0.02, coulomb=0.8, stribeck=0.3, stribeck_velocity=0.005
)
TRUTH_B = lugre.LuGreParameters(
    sigma0=9e4, sigma1=0.03, sigma2=0.02, coulomb=0.35, stribeck=0.12, stribeck_velocity=0.03, radius=0.015
)


def _toml(path, joint_type, p: lugre.LuGreParameters):
    values = {"joint_type": joint_type, **p.values()}
    if p.radius is not None:
        values["radius"] = p.radius
    path.write_text(tomli_w.dumps(values))
    return path


@pytest.mark.numerics
def test_the_issues_failing_case_identifies_from_a_mixed_wrong_prior():
    """Type A, prior F_c ×2 and v_s ×0.5, 3 % noise, seed 1 (the run that ended with exit 2 and
    σ0 −11 … −21 % outside its interval): the campaign redesigns its records from its estimates;
    every targeted parameter it reports lies within 3 % of the truth and inside its own 95 %
    interval, and one it does not is named not identified to ±3 % with its width and the reason —
    within the budget."""
    prior = dataclasses.replace(TRUTH_A, coulomb=2 * TRUTH_A.coulomb, stribeck_velocity=0.5 * TRUTH_A.stribeck_velocity)
    result = run_sequential("A", prior, lambda test, name: rig.simulate(test, TRUTH_A), noise=0.03, seed=1)
    assert 1 < len(result.rounds) <= MAX_ROUNDS and result.records <= MAX_RECORDS
    assert result.rounds[1].plan.basis.startswith("the estimate of round 1")  # redesigned, not the prior's ladder
    identification = result.identification
    assert identification is not None and identification.accuracy == dict.fromkeys(TARGETED, TARGET_HALF_WIDTH)
    missing = identification.not_identified
    entries = identification.parameter_entries()
    for name in TARGETED:
        value, (lower, upper) = entries[name]["value"], entries[name]["ci95"]
        true = getattr(TRUTH_A, name)
        assert lower <= true <= upper, (name, lower / true, upper / true)  # honest, reported or not
        if name in missing:
            assert "wider than the required ±3 %" in missing[name] and not result.converged, missing[name]
            assert half_width(value, lower, upper) > TARGET_HALF_WIDTH
            assert "not identified to ±3 %: " in result.stop
        else:
            assert abs(value / true - 1.0) < TARGET_HALF_WIDTH, (name, value / true - 1.0)
    assert {"sigma0", "coulomb"}.isdisjoint(missing)  # the micro-slip and sliding levels are pinned
    # The widths shrink as rounds add the records the estimate asked for.
    first, last = result.rounds[0].half_widths, result.rounds[-1].half_widths
    assert all(last[n] < first[n] for n in TARGETED)
    for name, reason in missing.items():
        assert reason.startswith({"sigma0": "σ0", "coulomb": "F_c", "stribeck": "F_d", "stribeck_velocity": "v_s",
                                  "sigma1": "σ1", "sigma2": "σ2"}[name]), reason  # fmt: skip


def test_a_prior_whose_break_away_is_far_too_low_moves_the_ladder_up():
    """No rung slid: the next round is the ladder again with F_c and F_d ×3 — never the same
    records twice, and a campaign that cannot slide within the shaker's limit stops with a reason."""
    prior = dataclasses.replace(TRUTH_B, coulomb=TRUTH_B.coulomb / 6, stribeck=TRUTH_B.stribeck / 6)
    result = run_sequential("B", prior, lambda test, name: rig.simulate(test, TRUTH_B), noise=0.01, max_rounds=2)
    first, second = result.rounds
    assert not first.stick and first.failure and "stick-slip" in first.failure
    assert second.plan.ladder and "×3" in second.plan.basis
    assert second.plan.designed_from.coulomb == pytest.approx(3 * prior.coulomb)
    assert second.stick  # the moved ladder slides


def test_the_first_round_is_the_prior_s_ladder_and_planning_is_deterministic():
    prior = dataclasses.replace(TRUTH_A, coulomb=1.6)
    one = plan_round("A", prior, [])
    two = plan_round("A", prior, [])
    assert one == two and one.number == 1 and one.ladder and one.basis == "the prior"
    assert len(one.tests) == 8


@pytest.mark.numerics
def test_a_person_and_the_simulated_rig_run_the_same_loop_over_a_folder(tmp_path):
    """Without records the command writes round 1's plan and waits; with --simulate it fills them in
    and finishes; run again on the same folder without --simulate it replays to the same result
    from the files alone; the result file lists what was not identified without a value."""
    truth = _toml(tmp_path / "truth.toml", "B", TRUTH_B)
    prior = _toml(tmp_path / "prior.toml", "B", TRUTH_B)  # a friendly prior keeps this test short
    folder = tmp_path / "campaign"
    waiting = run_cli("campaign", folder, "--prior", prior, "--json")
    assert waiting.returncode == 0, waiting.stderr
    state = json.loads(waiting.stdout)
    assert state["state"] == "waiting" and state["round"] == 1
    plan = (folder / "round1_plan.md").read_text()
    assert all(name in plan for name in state["missing"]) and "to measure" in plan
    done = run_cli("campaign", folder, "--prior", prior, "--simulate", truth, "--noise", "0.01", "-o",
                   tmp_path / "joint.toml", "--json")  # fmt: skip
    assert done.returncode == 0, done.stderr
    first = json.loads(done.stdout)
    assert first["state"] == "done" and first["simulated_records"]
    again = json.loads(run_cli("campaign", folder, "--prior", prior, "--json").stdout)
    assert again["state"] == "done" and not again["simulated_records"]
    assert again["identification"]["parameters"] == first["identification"]["parameters"]
    text = (tmp_path / "joint.toml").read_text()
    for name in first["identification"]["not_identified"]:
        assert f"\n{name} = " not in text.split("[identification]")[0]  # no value at the top level
        assert f'\n{name} = "' in text.split("[identification.not_identified]")[1]  # the reason instead


def test_a_design_refuses_a_parameter_that_was_not_identified_unless_it_states_it(tmp_path):
    """A result file without σ1 (not identified): the design names σ1, the reason and the fix in one
    line; a value beside file = … fills it in; a value for an identified parameter is refused."""
    values = {"joint_type": "A", **{k: v for k, v in TRUTH_A.values().items() if k != "sigma1"}}
    values["identification"] = {"not_identified": {"sigma1": "σ1 (micro-damping), 95 % interval unbounded"}}
    (tmp_path / "joint.toml").write_text(tomli_w.dumps(values))
    data = small_truss()
    data["friction"]["A"] = {"file": str(tmp_path / "joint.toml")}
    with pytest.raises(DesignError, match=r"sigma1 not identified by its records \(σ1 \(micro-damping\).*state sigma1"):
        parse_design(data)
    data["friction"]["A"] = {"file": str(tmp_path / "joint.toml"), "sigma1": 0.04}
    design = parse_design(data)
    assert dict(design.friction["A"].parameters)["sigma1"] == 0.04
    data["friction"]["A"] = {"file": str(tmp_path / "joint.toml"), "sigma1": 0.04, "sigma0": 1e5}
    with pytest.raises(DesignError, match="identified it"):
        parse_design(data)


def test_the_campaign_command_refuses_bad_input_in_one_line(tmp_path):
    prior = _toml(tmp_path / "prior.toml", "A", TRUTH_A)
    (tmp_path / "file").write_text("keep")
    assert "is a file — name a folder" in cli_error("campaign", tmp_path / "file", "--prior", prior)
    assert (tmp_path / "file").read_text() == "keep"
    assert "--noise" in cli_error("campaign", tmp_path / "c", "--prior", prior, "--noise", "2")
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "round1_plan.md").write_text("my notes")
    assert "not a plan this command wrote" in cli_error("campaign", tmp_path / "c", "--prior", prior)
    assert (tmp_path / "c" / "round1_plan.md").read_text() == "my notes"


def test_the_run_takes_a_not_identified_parameter_only_from_the_design(tmp_path):
    """Records that cannot determine σ1 and σ2 (a short ladder: no resolved bristle resonance, no
    fast sliding): the friction stage of ``run`` uses the design's own σ1, σ2 and says so in the
    source; a design that states no type A parameters is refused in one line naming σ1, why and
    the fix — the identification's point value is never used."""
    from conftest import TABLE_1_A

    from smartjoint.design.friction.records import write_record
    from smartjoint.design.friction.rig_campaign import campaign, run_campaign
    from smartjoint.design.friction.stage import friction_stage

    truth = lugre.LuGreParameters(**{**TABLE_1_A, "sigma1": 0.05})
    measured = run_campaign(campaign("A", truth, noise=0.01, cycles=8), truth, lambda test: rig.simulate(test, truth))
    paths = []
    for k, record in enumerate(measured.micro + measured.stick):
        paths.append(str(tmp_path / f"r{k}.csv"))
        write_record(record, paths[-1])
    data = small_truss()
    data["friction"]["records"] = paths
    design, results = friction_stage(parse_design(data), tmp_path, lambda line: None)
    (a,) = [r for r in results if r.joint_type == "A"]
    missing = a.identification.not_identified
    assert {"sigma1", "sigma2"} <= set(missing) and not set(missing) & set(TARGETED)
    used = a.used.values()
    for name in missing:
        assert used[name] == TABLE_1_A[name]  # the design's value, not the estimate
        assert name in a.used.source
    assert used["sigma0"] == a.identification.parameters.sigma0
    del data["friction"]["A"]
    with pytest.raises(DesignError, match=r"sigma1 not identified by the records \(σ1 .*state it in \[friction\.A\]"):
        friction_stage(parse_design(data), tmp_path, lambda line: None)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_heavy_record_sliding_slowly_is_read_as_stick_slip(seed):
    """At 300 kg and 3 % noise the friction column F_exc − m·a carries m·a noise up to μ ≈ 8 where
    μ ≤ 1.1: a record sliding at 4·v_s must still count as stick-slip (the records nearest the
    Stribeck drop are the heavy ones), and a presliding record at the lightest inertia as micro-slip."""
    from smartjoint.design.friction.record_screening import classify

    heavy = rig.RigTest("A", 400.0, 573.0, 10.0, 8.0, 300.0, 20_000.0, 0.03, seed)
    record = rig.simulate(heavy, TRUTH_A)
    assert classify(dataclasses.replace(record, metadata={})) == "stick-slip"
    assert float(np.max(np.abs(record.sliding_velocity))) < 8 * TRUTH_A.stribeck_velocity
    breakaway = 400.0 * (TRUTH_A.coulomb + TRUTH_A.stribeck)
    presliding = rig.RigTest("A", 400.0, 0.15 * breakaway, 10.0, 8.0, 1.0, 20_000.0, 0.03, seed)
    assert classify(dataclasses.replace(rig.simulate(presliding, TRUTH_A), metadata={})) == "micro-slip"


@pytest.mark.numerics
def test_the_next_round_s_inertias_correct_how_fast_the_records_slid():
    """Type B, a round designed from the prior F_c ×2, F_d ×0.5, v_s ×2 (as when the first estimate
    does not bound v_s): the prior misjudges how fast the ladder's records slide; scaled by the
    records' measured over predicted momentum, the stick-slip records slide within ×/÷ 2.5 of the
    speeds they were designed for, where uncorrected they slide more than twice too fast."""
    import re

    from smartjoint.design.friction.round_design import for_design, momentum_ratio, refinement_tests
    from smartjoint.design.friction.sequential_campaign import identify_round, run_round

    prior = dataclasses.replace(TRUTH_B, coulomb=2 * TRUTH_B.coulomb, stribeck=0.5 * TRUTH_B.stribeck,
                                stribeck_velocity=2 * TRUTH_B.stribeck_velocity)  # fmt: skip
    first = plan_round("B", prior, [], noise=0.03, seed=0)
    rounds = [identify_round(first, run_round(first, lambda test, name: rig.simulate(test, TRUTH_B)), [])]
    ratio = momentum_ratio(for_design(prior), rounds)
    assert ratio > 2.0
    limits = rig_campaign.DEFAULT_RIGS["B"].inertia

    def speeds(momentum: float) -> list[float]:
        wide = ["coulomb", "stribeck", "stribeck_velocity"]
        tests, purpose = refinement_tests("B", prior, wide, rig_campaign.DEFAULT_RIGS["B"], 0.03, 1, 8.0, momentum)
        out = []
        for test, why in zip(tests, purpose):
            if limits[0] < test.inertia < limits[1]:  # not clipped by the rig's range
                designed = float(re.search(r"sliding at about ([0-9.]+)·v_s", why).group(1)) * prior.stribeck_velocity
                out.append(float(np.max(np.abs(rig.simulate(test, TRUTH_B).sliding_velocity))) / designed)
        return out

    corrected = speeds(ratio)
    assert len(corrected) >= 2 and all(0.4 < s < 2.5 for s in corrected), corrected
    assert max(speeds(1.0)) > 2.0
