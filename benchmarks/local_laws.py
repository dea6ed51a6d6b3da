"""The local laws against the best constant normal force on the physical spread (issue 32).

Three sweeps of the bundled three type A study (``smartjoint sweep``: the compiled closed loop
on Dask), every plant drawn from the design's physical spread (``[uncertain] from = "design"``:
its ``[uncertainty]`` and the defaults of docs/design-file.md), Latin hypercube:

1. **SISO tuned on an ensemble** (seed ``--tuning-seed``, ``--tuning-samples`` plants): the
   paper's SISO law over a grid of its boundary layer ε × the preload F_N^min; the point of least
   mean E(t_e) is the ensemble-optimised ("preloaded") SISO.
2. **The judgement** (seed ``--seed``, ``--samples`` plants, a seed the laws were not tuned on):
   both passive settings, the best constant F_N per plant for E(t_e) and for e(t_e) (searched as
   ``best passive E``/``best passive e`` do), the paper's SISO at the study's ε, the slip-ratio
   law at the design file's settings (tuned by ``smartjoint design``'s ensemble tuning on seed 1,
   ``--tune`` re-runs it), and the cLQG.
3. **The preloaded SISO** on the judgement's plants (same seed and inputs: the same plants).

Per law: P(E(t_e) below the best constant F_N's), the median ratio to it, P(e(t_e) below both
passive settings'), P(e(t_e) below the best constant F_N's for e), each with its Monte Carlo
standard error √(p(1−p)/n). Written to ``benchmarks/local_laws.json``.

    python benchmarks/local_laws.py [--samples 400] [--seed 2] [--tuning-samples 16] [--workers 2] [--tune]
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np
from machine import python_machine, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.bench.sweep import read_results, run_sweep
from smartjoint.common import package_data
from smartjoint.design.control.sweep_file import load_sweep

DESIGN = package_data.path("smartjoint.design", "data/three_type_a.toml")
# m/s: the study's SISO ε as the committed firmware holds it (Eq. 32's search in `smartjoint design`)
PAPER_EPSILON = float(
    json.loads((Path(__file__).resolve().parents[1] / "firmware/generated/controller.json").read_text())["laws"][
        "siso"
    ]["boundary_layer"][0]
)
EPSILONS = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2)  # m/s: the preloaded SISO's grid
PRELOADS = (10.0, 50.0, 100.0, 200.0, 300.0)  # N: F_N^min of the preloaded SISO's grid

SWEEP = """\
schema = "smartjoint-sweep/1"
design = "{design}"
laws = {laws}
samples = {samples}
seed = {seed}
sampler = "latin-hypercube"
batch = {batch}

[uncertain]
from = "design"

[grid]
{grid}
"""


def _sweep(folder: Path, name: str, laws, samples: int, seed: int, grid: str, workers: int):
    path = folder / f"{name}.toml"
    laws_text = "[" + ", ".join(f'"{law}"' for law in laws) + "]"
    batch = max(1, min(8, samples // (4 * workers)))
    path.write_text(SWEEP.format(design=DESIGN, laws=laws_text, samples=samples, seed=seed, batch=batch, grid=grid))
    started = time.perf_counter()
    out = run_sweep(load_sweep(path), folder / name, workers=workers, progress=lambda line: None)
    columns = read_results(folder / name).to_pydict()
    print(f"  {name}: {samples} plants × {len(laws)} laws, {time.perf_counter() - started:.0f} s")
    return columns, out


def _by_law(columns: dict, point: int | None = None) -> dict[str, dict[str, np.ndarray]]:
    """Per law, E(t_e) and e(t_e) by sample (ordered by sample number)."""
    law, sample = np.asarray(columns["law"]), np.asarray(columns["sample"])
    where = np.ones(law.size, bool) if point is None else np.asarray(columns["point"]) == point
    out = {}
    for name in dict.fromkeys(law[where].tolist()):
        rows = where & (law == name)
        order = np.argsort(sample[rows])
        out[name] = {
            "sample": sample[rows][order],
            "E": np.asarray(columns["energy_measure"], float)[rows][order],
            "e": np.asarray(columns["energy_end"], float)[rows][order],
        }
    return out


def _probability(wins: np.ndarray) -> dict:
    n = int(wins.size)
    p = float(np.mean(wins)) if n else math.nan
    return {"p": p, "standard_error": math.sqrt(p * (1 - p) / n) if n else math.nan, "n": n}


def _table(runs: dict, laws) -> dict:
    """Each law against the passive references of the same plants."""
    best_E, best_e = runs["best passive E"]["E"], runs["best passive e"]["e"]
    both = np.minimum(runs["passive F_min"]["e"], runs["passive F_max"]["e"])
    table = {}
    for law in laws:
        E, e = runs[law]["E"], runs[law]["e"]
        assert np.array_equal(runs[law]["sample"], runs["best passive E"]["sample"])
        table[law] = {
            "E_below_best_constant": _probability(E < best_E),
            "E_ratio_to_best_constant_median": float(np.median(E / best_E)),
            "E_ratio_to_best_constant_quartiles": [float(q) for q in np.quantile(E / best_E, [0.25, 0.75])],
            "e_below_both_passive": _probability(e < both),
            "e_below_best_constant_for_e": _probability(e < best_e),
            "E_mean": float(np.mean(E)),
            "e_median": float(np.median(e)),
        }
    return table


def _print(table: dict) -> None:
    print(
        f"  {'law':<22} {'P(E < best const.)':>20} {'median E/E_best':>16} {'P(e < both passive)':>21} "
        f"{'P(e < best const. e)':>21}"
    )
    for law, row in table.items():
        a, b, c = row["E_below_best_constant"], row["e_below_both_passive"], row["e_below_best_constant_for_e"]
        print(
            f"  {law:<22} {a['p']:>12.3f} ± {a['standard_error']:.3f} {row['E_ratio_to_best_constant_median']:>16.3f} "
            f"{b['p']:>13.3f} ± {b['standard_error']:.3f} {c['p']:>13.3f} ± {c['standard_error']:.3f}"
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=400)
    parser.add_argument("--seed", type=int, default=2)
    parser.add_argument("--tuning-samples", type=int, default=16)
    parser.add_argument("--tuning-seed", type=int, default=1)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--tune", action="store_true", help="re-run the slip-ratio law's ensemble tuning first")
    parser.add_argument("--json", default=str(Path(__file__).with_name("local_laws.json")))
    args = parser.parse_args()
    if args.seed == args.tuning_seed:
        parser.error(f"--seed {args.seed}: must differ from the tuning seed {args.tuning_seed}")
    result: dict = {
        "benchmark": "local_laws",
        "machine": python_machine(),
        "command": "python benchmarks/local_laws.py",
    }
    if args.tune:
        from smartjoint.design import load_design, updated_design
        from smartjoint.design.control import runs, slip_ratio, study

        design, _ = updated_design(load_design(DESIGN))
        s = runs.setup(design, study.design_model(design, lambda line: None))
        found = slip_ratio.optimise(design, s, print, plants=16, seed=slip_ratio.TUNING_SEED)
        print(found.describe())
        result["slip_ratio_tuning"] = found.summary()
    with tempfile.TemporaryDirectory() as temporary:
        folder = Path(temporary)
        print(f"1. the preloaded SISO: ε × F_N^min on {args.tuning_samples} plants (seed {args.tuning_seed})")
        grid = f"siso_boundary_layer = {list(EPSILONS)}\nnormal_force_min = {list(PRELOADS)}"
        tuning, _ = _sweep(folder, "siso-tuning", ["SISO"], args.tuning_samples, args.tuning_seed, grid, args.workers)
        points = sorted(set(tuning["point"]))
        mean = {}
        for point in points:
            rows = np.asarray(tuning["point"]) == point
            key = (float(np.asarray(tuning["siso_boundary_layer"])[rows][0]),
                   float(np.asarray(tuning["normal_force_min"])[rows][0]))  # fmt: skip
            mean[key] = float(np.mean(np.asarray(tuning["energy_measure"], float)[rows]))
        epsilon, preload = min(mean, key=mean.__getitem__)
        print(f"  least mean E(t_e) {mean[(epsilon, preload)]:.4g} J·s at ε = {epsilon:g} m/s, F_N^min = {preload:g} N")
        print(f"2. the judgement: {args.samples} plants (seed {args.seed})")
        laws = ["passive F_min", "passive F_max", "best passive E", "best passive e", "SISO", "slip ratio", "cLQG"]
        judged, out = _sweep(
            folder, "judgement", laws, args.samples, args.seed, f"siso_boundary_layer = [{PAPER_EPSILON}]", args.workers
        )
        print(f"3. the preloaded SISO on the same {args.samples} plants")
        preloaded, _ = _sweep(
            folder, "preloaded", ["SISO"], args.samples, args.seed,
            f"siso_boundary_layer = [{epsilon}]\nnormal_force_min = [{preload}]", args.workers,
        )  # fmt: skip
    runs = _by_law(judged)
    runs["SISO, preloaded"] = _by_law(preloaded)["SISO"]
    shown = ["SISO", "SISO, preloaded", "slip ratio", "cLQG", "passive F_max", "best passive e"]
    table = _table(runs, shown)
    _print(table)
    result.update(
        {
            "design": "three_type_a.toml",
            "spread": 'the design\'s physical spread ([uncertain] from = "design")',
            "samples": args.samples,
            "seed": args.seed,
            "tuning": {
                "seed": args.tuning_seed,
                "samples": args.tuning_samples,
                "siso_grid_mean_energy": [[e, f, m] for (e, f), m in sorted(mean.items())],
                "siso_preloaded": {"boundary_layer": epsilon, "normal_force_min": preload},
            },
            "siso_paper_boundary_layer": PAPER_EPSILON,
            "judgement_seconds": out["seconds"],
            "table": table,
            "best_constant_force_E_median": float(
                np.median(
                    np.asarray(judged["passive_normal_force"], float)[np.asarray(judged["law"]) == "best passive E"]
                )
            ),  # fmt: skip
        }
    )
    write_json(args.json, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
