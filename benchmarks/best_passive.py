"""The best constant normal force: the search of ``design/control/best_passive.py`` against the
1-N grid over [F^min, F^max], on the bundled study and on plants of its physical spread (issue 36).

For the nominal study of the bundled three type A design and ``--plants`` plants drawn from the
design's physical spread (``ensemble.drawn_setups``, seed ``--seed``: what a sweep with
``[uncertain] from = "design"`` draws), every integer force of the common range is run once (the
compiled closed loop, the study's protocol): the baseline, the best a 1-N grid can say. Then the
search of each ``--intervals`` (grid intervals of its first pass; the module's ``GRID_INTERVALS``
is one of them) runs on every plant, and per plant and metric (E(t_e), e(t_e)) the benchmark
reports the search's force and figure against the 1-N grid's best: the force gap, the figure's
ratio, and the runs the search took. The landscape's structure is reported too: the local minima
of each 1-N landscape and the width of each basin (between the neighbouring local maxima), the
figure that sets the first pass's spacing.

Writes ``benchmarks/best_passive.json``, ``benchmarks/best_passive_landscape.png`` (the nominal
landscape and the plants'), and with ``--store`` the nominal 1-N landscape as the test data of
``tests/test_best_passive.py`` (``tests/data/best_passive_grid.json``).

    python benchmarks/best_passive.py [--plants 20] [--seed 36] [--intervals 10,20,40,80] [--workers 2] [--store]
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from machine import python_machine, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.common import package_data

HERE = Path(__file__).resolve().parent
DESIGN = package_data.path("smartjoint.design", "data/three_type_a.toml")
GRID_DATA = HERE.parent / "tests" / "data" / "best_passive_grid.json"
METRICS = ("energy_end", "energy_measure")

_state: dict = {}


def _setups(plants: int, seed: int):
    """The design (updated), its compiled loop and the nominal study followed by the plants."""
    from smartjoint.codegen.closed_loop import CompiledLoop
    from smartjoint.design import load_design, updated_design
    from smartjoint.design.control import ensemble
    from smartjoint.design.control.runs import setup
    from smartjoint.design.control.study import design_model, lqg_for

    design, _ = updated_design(load_design(DESIGN))
    model = design_model(design, lambda line: None)
    loop = CompiledLoop(ensemble.point_artifact(design, model, lqg_for(design, model), {}))
    s = setup(design, model)
    return design, loop, [s, *ensemble.drawn_setups(design, s, plants, seed)]


def _start(plants: int, seed: int) -> None:
    _state["design"], _state["loop"], _state["setups"] = _setups(plants, seed)


def _grid(index: int) -> tuple[int, list, float]:
    """The 1-N landscape of plant ``index``: (force, e(t_e), E(t_e)) per integer force."""
    from smartjoint.design.control.best_passive import figure

    s, loop = _state["setups"][index], _state["loop"]
    low, high = float(np.max(s.normal_force_min)), float(np.min(s.normal_force_max))
    start = time.perf_counter()
    rows = []
    for force in np.arange(np.ceil(low), high + 1e-9, 1.0):
        run = loop.run_passive(s, "grid", np.full(s.normal_force_min.shape, force))
        rows.append((float(force), figure(run, "energy_end"), figure(run, "energy_measure")))
    return index, rows, time.perf_counter() - start


def _search(job: tuple[int, int]) -> tuple[int, int, dict]:
    """The search with ``intervals`` first-pass intervals on plant ``index``, both metrics sharing runs."""
    from smartjoint.design.control import best_passive as search

    index, intervals = job
    s, loop = _state["setups"][index], _state["loop"]
    search.GRID_INTERVALS = intervals  # this worker's process only
    cache: dict = {}
    out = {}
    for metric in METRICS:
        run, force = search.best_passive(s, "best", metric, loop.run_passive, cache)
        out[metric] = {"force": force, "figure": search.figure(run, metric)}
    out["runs"] = len(cache)
    return index, intervals, out


def basins(forces: np.ndarray, values: np.ndarray) -> list[dict]:
    """Each local minimum of a landscape with the width of its basin (between the local maxima,
    or the range's ends, on either side)."""
    v = np.asarray(values)
    inner = np.arange(1, v.size - 1)
    maxima = [0, *inner[(v[inner] >= v[inner - 1]) & (v[inner] >= v[inner + 1])].tolist(), v.size - 1]
    left, right = np.concatenate([[np.inf], v[:-1]]), np.concatenate([v[1:], [np.inf]])
    out = []
    for i in np.flatnonzero((v < left) & (v <= right)):
        below = max(m for m in maxima if m <= i)
        above = min(m for m in maxima if m >= i)
        out.append({"force": float(forces[i]), "value": float(v[i]), "width": float(forces[above] - forces[below])})
    return sorted(out, key=lambda b: b["value"])


def _plot(grids: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    for index, rows in sorted(grids.items()):
        a = np.asarray(rows)
        style = (
            {"color": "k", "lw": 1.6, "label": "nominal"}
            if index == 0
            else {"color": "tab:blue", "lw": 0.5, "alpha": 0.5}
        )
        axes[0].semilogy(a[:, 0], a[:, 1], **style)
        axes[1].plot(a[:, 0], a[:, 2], **style)
    axes[0].set_ylabel("e(t_e) [J]")
    axes[1].set_ylabel("E(t_e) [J·s]")
    axes[1].set_xlabel("constant normal force F_N [N] (1-N grid)")
    axes[0].set_title("passive runs at constant F_N: the nominal study and the plants of its spread")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _compare(grids: dict, searched: dict, intervals: list[int]) -> dict:
    """Per first-pass interval count: every plant's search against its 1-N grid, and the summary."""
    per_intervals = {}
    for n in intervals:
        rows = []
        for index, grid in sorted(grids.items()):
            a = np.asarray(grid)
            row = {"plant": index, "runs": searched[(index, n)]["runs"]}
            for column, metric in ((1, "energy_end"), (2, "energy_measure")):
                best = int(np.argmin(a[:, column]))
                found = searched[(index, n)][metric]
                row[metric] = {
                    "grid_force": float(a[best, 0]),
                    "grid_figure": float(a[best, column]),
                    "force": found["force"],
                    "figure": found["figure"],
                    "ratio": found["figure"] / float(a[best, column]),
                }
            rows.append(row)
        summary = {"runs_mean": float(np.mean([r["runs"] for r in rows]))}
        for metric in METRICS:
            ratios = np.array([r[metric]["ratio"] for r in rows])
            gaps = np.array([abs(r[metric]["force"] - r[metric]["grid_force"]) for r in rows])
            summary[metric] = {
                "worst_ratio": float(ratios.max()),
                "plants_over_1_percent": int(np.sum(ratios > 1.01)),
                "nominal_force_gap": float(gaps[0]),
                "largest_force_gap": float(gaps.max()),
            }
        per_intervals[str(n)] = {"summary": summary, "plants": rows}
        e, big_e = summary["energy_end"], summary["energy_measure"]
        print(
            f"intervals {n:3d}: {summary['runs_mean']:.0f} runs a plant; e(t_e) worst {e['worst_ratio']:.4f}× "
            f"the 1-N grid's best ({e['plants_over_1_percent']} plants > 1 %), E(t_e) worst "
            f"{big_e['worst_ratio']:.4f}× ({big_e['plants_over_1_percent']} > 1 %); nominal force gap "
            f"{e['nominal_force_gap']:.2f} / {big_e['nominal_force_gap']:.2f} N",
            flush=True,
        )
    return per_intervals


def _structure(grids: dict) -> dict:
    """The landscapes' local minima and basins, per metric."""
    structure = {}
    for column, metric in ((1, "energy_end"), (2, "energy_measure")):
        found = [basins(np.asarray(g)[:, 0], np.asarray(g)[:, column]) for _, g in sorted(grids.items())]
        structure[metric] = {
            "nominal_basins": found[0],
            # the basin that holds each plant's best force: the first pass needs a point in it
            "narrowest_best_basin": min(b[0]["width"] for b in found),
            "local_minima_per_plant": [len(b) for b in found],
        }
        print(
            f"{metric}: nominal minima {[(b['force'], round(b['value'], 6), b['width']) for b in found[0]]}; "
            f"narrowest basin holding a plant's best: {structure[metric]['narrowest_best_basin']:.0f} N",
            flush=True,
        )
    return structure


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", type=int, default=20)
    parser.add_argument("--seed", type=int, default=36)
    parser.add_argument("--intervals", default="10,20,40,80")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--store", action="store_true", help="write the nominal 1-N landscape as test data")
    parser.add_argument("--json", default=str(HERE / "best_passive.json"))
    args = parser.parse_args(argv)
    intervals = [int(v) for v in args.intervals.split(",")]
    from smartjoint.design.control.best_passive import GRID_INTERVALS, REFINED, TOLERANCE

    started = time.perf_counter()
    with ProcessPoolExecutor(args.workers, initializer=_start, initargs=(args.plants, args.seed)) as pool:
        grids, grid_seconds = {}, 0.0
        for index, rows, seconds in pool.map(_grid, range(args.plants + 1)):
            grids[index], grid_seconds = rows, grid_seconds + seconds
            print(f"1-N grid of plant {index}: {len(rows)} runs, {seconds:.1f} s", flush=True)
        jobs = [(index, n) for n in intervals for index in grids]
        searched = {(index, n): out for index, n, out in pool.map(_search, jobs)}
    per_intervals = _compare(grids, searched, intervals)
    structure = _structure(grids)
    _plot(grids, HERE / "best_passive_landscape.png")
    write_json(
        args.json,
        {
            "command": "python benchmarks/best_passive.py " + " ".join(argv or []),
            "machine": python_machine(workers=args.workers),
            "plants": args.plants,
            "seed": args.seed,
            "search": {"grid_intervals": GRID_INTERVALS, "refined": REFINED, "tolerance": TOLERANCE},
            "grid_runs": sum(len(g) for g in grids.values()),
            "grid_seconds": grid_seconds,
            "seconds": time.perf_counter() - started,
            "structure": structure,
            "intervals": per_intervals,
            "grids": {str(k): g for k, g in sorted(grids.items())},  # (F_N, e(t_e), E(t_e)) per plant, 0 nominal
        },
    )
    if args.store:
        from smartjoint.design import load_design

        GRID_DATA.parent.mkdir(parents=True, exist_ok=True)
        data = {
            "what": "1-N landscape of the bundled three type A study: (F_N [N], e(t_e) [J], E(t_e) [J·s])",
            "command": "python benchmarks/best_passive.py --store",
            "design_sha256": load_design(DESIGN).sha256,
            "rows": grids[0],
        }
        GRID_DATA.write_text(json.dumps(data, indent=0) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
