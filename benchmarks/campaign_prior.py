"""Rig campaign from a wrong prior: identification errors, old (standard) campaign vs new (ladder).

The experimenter designs the campaign from a prior (what they believe); the rig simulates the
truth (paper Table 1, type A and B) with 1 % noise, 8 cycles a record; ``identify`` runs on the
records sorted by the regime they show. Priors: the truth itself (×1), and the truth with F_c,
F_d, σ0 and v_s all scaled together by ×0.5 and ×2 (``--scaled all``; or one of them alone,
``--scaled stribeck_velocity``; σ1, σ2 and r as the truth). Per case: the
errors of σ0, F_c, F_d, v_s, whether each final 95 % interval holds the true value, the record
count (micro/stick) and the CPU seconds of the identification.

    python benchmarks/campaign_prior.py [--types A B] [--factors 1 0.5 2] [--scaled all] [--seed 0]
                                        [--json benchmarks/campaign_prior.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from machine import python_machine, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.design.friction import lugre, rig
from smartjoint.design.friction.identify import identify
from smartjoint.design.friction.record_screening import classify
from smartjoint.design.friction.records import RecordError
from smartjoint.design.friction.rig_campaign import campaign, run_campaign, standard_campaign

NAMES = ("sigma0", "coulomb", "stribeck", "stribeck_velocity")
SYMBOLS = {"sigma0": "σ0", "coulomb": "F_c", "stribeck": "F_d", "stribeck_velocity": "v_s"}
CAMPAIGNS = {"old": standard_campaign, "new": campaign}


def prior_from(truth: lugre.LuGreParameters, factor: float, scaled: str) -> lugre.LuGreParameters:
    """The truth with F_c, F_d, σ0 and v_s (``scaled`` = 'all') or one of them scaled by ``factor``."""
    names = NAMES if scaled == "all" else (scaled,)
    return dataclasses.replace(truth, **{n: getattr(truth, n) * factor for n in names})


def run_case(joint_type: str, factor: float, scaled: str, name: str, seed: int) -> dict:
    """Design ``name``'s campaign from the prior, simulate the truth, identify, compare."""
    truth = lugre.TABLE_1[joint_type]
    prior = prior_from(truth, factor, scaled)
    tests = CAMPAIGNS[name](joint_type, prior, noise=0.01, seed=seed, cycles=8)
    if name == "new":  # rung by rung upwards, stopping 1.5× above the lowest that slid
        measured = run_campaign(tests, prior, lambda test: rig.simulate(test, truth))
        micro, stick = measured.micro, measured.stick
    else:
        records = [rig.simulate(test, truth) for test in tests]  # the only place the truth enters
        micro = [r for r in records if classify(r) == "micro-slip"]
        stick = [r for r in records if classify(r) == "stick-slip"]
    case = {"type": joint_type, "prior": factor, "scaled": scaled, "campaign": name}
    case.update({"micro": len(micro), "stick": len(stick)})
    start = time.process_time()
    try:
        result = identify(micro, stick).as_dict()
    except RecordError as error:
        return {**case, "failed": str(error), "cpu_s": time.process_time() - start}
    case["cpu_s"] = time.process_time() - start
    case["samples"] = sum(r.time.size for r in micro + stick)
    for parameter in NAMES:
        value = result["parameters"][parameter]["value"]
        lower, upper = result["parameters"][parameter]["ci95"]
        true = getattr(truth, parameter)
        case[parameter] = {"error": value / true - 1.0, "in_ci95": bool(lower <= true <= upper)}
    return case


def row(case: dict) -> str:
    """One table row: errors in %, ✗ where the 95 % interval misses the truth."""
    scaled = "" if case["prior"] == 1 or case["scaled"] == "all" else f" ({SYMBOLS[case['scaled']]} only)"
    head = f"| {case['type']} | ×{case['prior']:g}{scaled} | {case['campaign']} | {case['micro']}/{case['stick']} |"
    if "failed" in case:
        return f"{head} {case['failed'][:90]} |||| {case['cpu_s']:.0f} |"
    cells = [
        f"{100 * case[n]['error']:+.1f} %{'' if case[n]['in_ci95'] else ' ✗'}"  # ✗: interval misses
        for n in NAMES
    ]
    return f"{head} {' | '.join(cells)} | {case['cpu_s']:.0f} |"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--types", nargs="+", default=["A", "B"], choices=["A", "B"])
    parser.add_argument("--factors", nargs="+", type=float, default=[1.0, 0.5, 2.0])
    parser.add_argument("--scaled", default="all", choices=["all", *NAMES], help="which prior values the factors scale")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", default=str(Path(__file__).with_name("campaign_prior.json")))
    args = parser.parse_args()
    print("| type | prior | campaign | records micro/stick | σ0 | F_c | F_d | v_s | CPU [s] |")
    print("|---|---|---|---|---:|---:|---:|---:|---:|")
    cases = []
    for joint_type in args.types:
        for factor in args.factors:
            for name in CAMPAIGNS:
                cases.append(run_case(joint_type, factor, args.scaled, name, args.seed))
                print(row(cases[-1]), flush=True)
    machine = python_machine()
    write_json(args.json, {"benchmark": "campaign_prior", "seed": args.seed, "machine": machine, "cases": cases})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
