"""Identification off the friendly path: errors and 95 % interval coverage over priors, noise,
seeds and both joint types, with the sequential campaign (``design/friction/sequential_campaign``).

Truths that are not Table 1's (type A: σ0 3e5, σ1 0.05, σ2 0.02, F_c 0.8, F_d 0.3, v_s 0.005;
type B: σ0 9e4, σ1 0.03, σ2 0.02, F_c 0.35, F_d 0.12, v_s 0.03 rad/s, r 15 mm). Priors: the
truth with each of σ0, F_c, F_d, v_s scaled by ×2 or ×0.5 — all 16 combinations — plus the
truth itself. Per case the campaign runs from the prior on the simulated rig and identifies;
the table counts, per parameter, the runs that report it (interval within the campaign's ±3 %
target; the rest are reported not identified), their largest error, how often the 95 % interval
holds the truth among them, and ("all") among every run, reported or not.

    python benchmarks/identification_coverage.py [--types A B] [--noise 0.01 0.03] [--seeds 0 1 2 3]
        [--rounds 4] [--jobs 2] [--json benchmarks/identification_coverage.json]
    python benchmarks/identification_coverage.py --table benchmarks/identification_coverage.json

``--rounds 1`` runs the ladder alone (the campaign before issue 30).
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from machine import python_machine, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.design.friction import lugre, rig
from smartjoint.design.friction.identifiability import half_width, not_identified
from smartjoint.design.friction.sequential_campaign import MAX_RECORDS, MAX_ROUNDS, plan_round, run_sequential

TRUTHS = {
    "A": lugre.LuGreParameters(
        sigma0=3e5, sigma1=0.05, sigma2=0.02, coulomb=0.8, stribeck=0.3, stribeck_velocity=0.005
    ),
    "B": lugre.LuGreParameters(
        sigma0=9e4, sigma1=0.03, sigma2=0.02, coulomb=0.35, stribeck=0.12, stribeck_velocity=0.03, radius=0.015
    ),
}
SCALED = ("sigma0", "coulomb", "stribeck", "stribeck_velocity")
REPORTED = SCALED + ("sigma1", "sigma2")
SYMBOLS = {
    "sigma0": "σ0",
    "sigma1": "σ1",
    "sigma2": "σ2",
    "coulomb": "F_c",
    "stribeck": "F_d",
    "stribeck_velocity": "v_s",
}
PRIORS = [(1.0, 1.0, 1.0, 1.0)] + list(itertools.product((2.0, 0.5), repeat=4))


def run_case(joint_type: str, factors: tuple, noise: float, seed: int, rounds: int) -> dict:
    """One campaign from the prior ``truth × factors`` on the simulated rig, and its verdicts."""
    truth = TRUTHS[joint_type]
    prior = dataclasses.replace(truth, **{n: getattr(truth, n) * f for n, f in zip(SCALED, factors)})
    start = time.process_time()
    result = run_sequential(
        joint_type, prior, lambda test, name: rig.simulate(test, truth), noise=noise, seed=seed, max_rounds=rounds
    )
    case = {
        "type": joint_type,
        "prior": dict(zip(SCALED, factors)),
        "noise": noise,
        "seed": seed,
        "rounds": len(result.rounds),
        "records": result.records,
        "converged": result.converged,
        "stop": result.stop,
        "cpu_s": time.process_time() - start,
    }
    identification = result.identification
    if identification is None:
        return case | {"failed": result.stop}
    missing = not_identified(identification)
    entries = identification.as_dict()["parameters"]
    case["parameters"] = {}
    for name in REPORTED:
        true = getattr(truth, name)
        lower, upper = entries[name]["ci95"]
        case["parameters"][name] = {
            "reported": name not in missing,
            "reason": missing.get(name),
            "error": entries[name]["value"] / true - 1.0,
            "half_width": half_width(entries[name]["value"], lower, upper),
            "covered": bool(lower <= true <= upper),
        }
    return case


def summary(cases: list[dict]) -> list[str]:
    """The Markdown table: per type and noise, per parameter the reported runs, their worst error
    and the coverage of their intervals; records and rounds."""
    lines = [
        "| type | noise | runs | failed | "
        + " | ".join(SYMBOLS[n] for n in REPORTED)
        + " | records (max) | rounds (max) |",
        "|---|---:|---:|---:|" + "---|" * len(REPORTED) + "---:|---:|",
    ]
    groups = sorted({(c["type"], c["noise"]) for c in cases})
    for joint_type, noise in groups:
        group = [c for c in cases if (c["type"], c["noise"]) == (joint_type, noise)]
        done = [c for c in group if "parameters" in c]
        cells = []
        for name in REPORTED:
            reported = [c["parameters"][name] for c in done if c["parameters"][name]["reported"]]
            covered = sum(p["covered"] for p in reported)
            worst = max((abs(p["error"]) for p in reported), default=0.0)
            everywhere = sum(c["parameters"][name]["covered"] for c in done)
            share = f"{len(reported)} rep., {covered}/{len(reported)} cov., ≤{100 * worst:.1f} %"
            cells.append(f"{share} (all {everywhere}/{len(done)})")
        records = [c["records"] for c in group]
        rounds = [c["rounds"] for c in group]
        lines.append(
            f"| {joint_type} | {100 * noise:g} % | {len(group)} | {len(group) - len(done)} | "
            + " | ".join(cells)
            + f" | {sum(records) / len(records):.1f} ({max(records)})"
            + f" | {sum(rounds) / len(rounds):.1f} ({max(rounds)}) |"
        )
    return lines


def _key(case: dict) -> tuple:
    return (case["type"], tuple(case["prior"][n] for n in SCALED), case["noise"], case["seed"])


def _earlier(path: str) -> dict:
    """The distinct cases a stopped run wrote to ``path`` (``--resume``)."""
    import json

    if not Path(path).is_file():
        return {}
    return {_key(c): c for c in json.loads(Path(path).read_text())["cases"] if not c.get("copy_of_sigma0")}


def _expand(cases: list[dict], priors: list) -> list[dict]:
    """Every prior's case: one that differs from a run case only in σ0's factor is that case
    (``copy_of_sigma0``), as its records are the same."""
    run = {_key(c): c for c in cases if not c.get("copy_of_sigma0")}
    out = list(run.values())
    for t, f, n, s in sorted({(k[0], f, k[2], k[3]) for k in run for f in priors}):
        source = run.get((t, _canonical(f), n, s))
        if (t, f, n, s) not in run and source is not None:
            out.append(source | {"prior": dict(zip(SCALED, f)), "copy_of_sigma0": True})
    return out


def _canonical(factors: tuple) -> tuple:
    """The prior whose run stands for ``factors``: σ0 ×2 for both of σ0's factors."""
    return factors if factors == PRIORS[0] else (2.0,) + tuple(factors[1:])


def _check_sigma0_enters_no_plan(types) -> None:
    """The reason the σ0 pairs may share a run: round 1's plan is the same for σ0 ×2 and ×0.5."""
    for joint_type in types:
        truth = TRUTHS[joint_type]
        plans = [plan_round(joint_type, dataclasses.replace(truth, sigma0=f * truth.sigma0), []) for f in (2.0, 0.5)]
        assert plans[0].tests == plans[1].tests, "σ0's prior changes the plan: run every prior"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--types", nargs="+", default=["A", "B"], choices=["A", "B"])
    parser.add_argument("--noise", nargs="+", type=float, default=[0.01, 0.03])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3])
    parser.add_argument("--priors", type=int, default=len(PRIORS), help="the first N priors (1: the truth only)")
    parser.add_argument("--rounds", type=int, default=MAX_ROUNDS, help=f"at most {MAX_ROUNDS}; 1: the ladder alone")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--json", default=str(Path(__file__).with_name("identification_coverage.json")))
    parser.add_argument("--resume", action="store_true", help="keep the cases an earlier run left in --json")
    parser.add_argument("--table", metavar="JSON", help="print the table of a (partial) earlier run's JSON and stop")
    args = parser.parse_args()
    if args.table:
        import json

        print("\n".join(summary(_expand(json.loads(Path(args.table).read_text())["cases"], PRIORS))))
        return 0
    # Seeds outermost: a run stopped early has whole seeds done. σ0's prior enters neither the
    # plans (amplitudes from F_c + F_d, inertias from v_s) nor the fit (no prior in identify):
    # priors that differ only in σ0 give the same records and result — run once, counted for each.
    priors = PRIORS[: args.priors]
    _check_sigma0_enters_no_plan(args.types)
    distinct = list(dict.fromkeys(_canonical(f) for f in priors))
    grid = [(t, f, n, s) for s, t, f, n in itertools.product(args.seeds, args.types, distinct, args.noise)]
    done = _earlier(args.json) if args.resume else {}
    print(
        f"{len(grid)} distinct campaigns for {len(priors)} priors ({len(done)} done earlier; budget {MAX_ROUNDS} "
        f"rounds, {MAX_RECORDS} records) on {args.jobs} processes",
        flush=True,
    )
    cases = list(done.values())
    with ProcessPoolExecutor(args.jobs) as pool:
        todo = [key for key in grid if key not in done]
        futures = [pool.submit(run_case, t, f, n, s, args.rounds) for t, f, n, s in todo]
        for k, future in enumerate(futures):
            cases.append(future.result())
            c = cases[-1]
            verdict = c.get("failed") or ", ".join(
                f"{SYMBOLS[n]} {100 * p['error']:+.1f} %{'' if p['covered'] else ' ✗'}"
                for n, p in c["parameters"].items()
                if p["reported"]
            )
            print(f"[{k + 1}/{len(todo)}] {c['type']} {c['prior']} {100 * c['noise']:g} % seed {c['seed']}: "
                  f"{c['rounds']} rounds, {c['records']} records — {verdict}", flush=True)  # fmt: skip
            write_json(args.json, {"benchmark": "identification_coverage", "complete": False, "cases": cases})
    cases = _expand(cases, priors)
    lines = summary(cases)
    print("\n".join(lines))
    write_json(args.json, {"benchmark": "identification_coverage", "complete": True, "machine": python_machine(),
                           "table": lines, "cases": cases})  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
