"""The paper's SISO law on the 12-joint mast over its boundary layer ε and its lowest force F_N^min
(issue 33): why it ends above the passive settings there, and what would make it pay.

One ``smartjoint sweep`` of the mast with twelve type A joints (design/data/mast_30bay_twelve_a.toml)
on plants of its physical spread (``[uncertain] from = "design"``, Latin hypercube), the SISO law
on a grid of ε × F_N^min (the grid variable ``normal_force_min`` is the lower limit of the SISO
law's command, Eq. 30) beside the passive F_N^max on the same plants. Per grid point: the mean
E(t_e) (Eq. 32) and on how many plants the SISO law ends below F_N^max's E(t_e). Written to
``benchmarks/mast_siso_grid.json`` and the map ``benchmarks/mast_siso_grid.png``.

    python benchmarks/mast_siso_grid.py [--samples 8] [--seed 1] [--workers 2]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from machine import python_machine, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.bench.sweep import read_results, run_sweep
from smartjoint.common import package_data
from smartjoint.design.control.sweep_file import load_sweep

HERE = Path(__file__).resolve().parent
DESIGN = package_data.path("smartjoint.design", "data/mast_30bay_twelve_a.toml")
EPSILONS = (1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2)  # m/s: ε of Eq. 30
FLOORS = (10.0, 100.0, 200.0, 300.0)  # N: F_N^min of Eq. 30 (the joints' own is 10 N)

SWEEP = """\
schema = "smartjoint-sweep/1"
design = "{design}"
update = false
laws = ["SISO", "passive F_max"]
samples = {samples}
seed = {seed}
sampler = "latin-hypercube"
batch = 4

[uncertain]
from = "design"

[grid]
siso_boundary_layer = {epsilons}
normal_force_min = {floors}
"""


def _table(columns: dict) -> list[dict]:
    """Per grid point: ε, F_N^min, mean E(t_e) of SISO and of passive F_N^max, SISO's wins."""
    point, law, sample = (np.asarray(columns[k]) for k in ("point", "law", "sample"))
    energy = np.asarray(columns["energy_measure"], dtype=float)
    rows = []
    for p in sorted(set(point.tolist())):
        siso, passive = (point == p) & (law == "SISO"), (point == p) & (law == "passive F_max")
        a, b = np.argsort(sample[siso]), np.argsort(sample[passive])
        ours, theirs = energy[siso][a], energy[passive][b]
        rows.append(
            {
                "boundary_layer": float(np.asarray(columns["siso_boundary_layer"])[siso][0]),
                "normal_force_min": float(np.asarray(columns["normal_force_min"])[siso][0]),
                "siso_mean_energy_measure": float(ours.mean()),
                "passive_max_mean_energy_measure": float(theirs.mean()),
                "siso_below_passive_max": int(np.sum(ours < theirs)),
                "plants": int(ours.size),
            }
        )
    return rows


def _plot(rows: list[dict], path: Path) -> None:
    """The map of mean E(t_e) of SISO over F_N^max's, wins written in each cell."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ratio = np.full((len(FLOORS), len(EPSILONS)), np.nan)
    wins = {}
    for r in rows:
        i, j = FLOORS.index(r["normal_force_min"]), EPSILONS.index(r["boundary_layer"])
        ratio[i, j] = r["siso_mean_energy_measure"] / r["passive_max_mean_energy_measure"]
        wins[i, j] = f"{r['siso_below_passive_max']}/{r['plants']}"
    fig, ax = plt.subplots(figsize=(7.0, 3.6))
    image = ax.imshow(np.log10(ratio), cmap="RdBu_r", vmin=-1.3, vmax=1.3, origin="lower", aspect="auto")
    for (i, j), text in wins.items():
        ax.text(j, i, f"{ratio[i, j]:.2f}\n{text}", ha="center", va="center", fontsize=8)
    ax.set_xticks(range(len(EPSILONS)), [f"{e:g}" for e in EPSILONS])
    ax.set_yticks(range(len(FLOORS)), [f"{f:g}" for f in FLOORS])
    ax.set_xlabel("boundary layer ε [m/s]")
    ax.set_ylabel("SISO F_N^min [N]")
    ax.set_title("12-joint mast: mean E(t_e) of SISO / passive F_N^max (plants where SISO is below)", fontsize=9)
    fig.colorbar(image, ax=ax, label="log10 ratio")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=8)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        path = folder / "grid.toml"
        path.write_text(
            SWEEP.format(
                design=DESIGN, samples=args.samples, seed=args.seed, epsilons=list(EPSILONS), floors=list(FLOORS)
            )
        )
        started = time.perf_counter()
        run_sweep(load_sweep(path), folder / "out", workers=args.workers, progress=lambda line: None)
        seconds = time.perf_counter() - started
        rows = _table(read_results(folder / "out").to_pydict())
    for r in rows:
        print(
            f"ε = {r['boundary_layer']:8.0e} m/s, F_N^min = {r['normal_force_min']:5.0f} N: mean E(t_e) SISO "
            f"{r['siso_mean_energy_measure']:7.3f} J·s, passive F_N^max {r['passive_max_mean_energy_measure']:.3f}; "
            f"SISO below on {r['siso_below_passive_max']}/{r['plants']} plants"
        )
    _plot(rows, HERE / "mast_siso_grid.png")
    write_json(
        HERE / "mast_siso_grid.json",
        {
            "machine": python_machine(workers=args.workers),
            "command": "python benchmarks/mast_siso_grid.py",
            "samples": args.samples,
            "seed": args.seed,
            "seconds": seconds,
            "points": rows,
        },
    )
    print(f"{len(rows)} grid points × {args.samples} plants in {seconds:.0f} s: benchmarks/mast_siso_grid.json, .png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
