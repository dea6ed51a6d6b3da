"""The preloaded SISO law on the 12-joint mast over the sweep's 100 plants (issue 33): which of the
cells that beat passive F_N^max on 8 of 8 plants in mast_siso_grid holds the paper's orderings,
and why "cLQG's RMS tip deflection below SISO's" cannot hold with a SISO law that beats the passive
settings there.

It runs the SISO law alone at each candidate (ε, F_N^min) on the plants of
``examples/mast_30bay_sweep.toml`` (same seed, same spread: the same 100 plants, checked input by
input) and pairs each plant with the other laws' rows of a full sweep of that file (``--reference``,
``smartjoint sweep examples/mast_30bay_sweep.toml -o FOLDER``). Per candidate: the probabilities of
the SISO law's orderings with their MC standard error; and for every law the median RMS tip
deflection, which orders the constant forces by stiffness. Written to
``benchmarks/mast_siso_tradeoff.json`` and ``benchmarks/mast_siso_tradeoff.png``.

    python benchmarks/mast_siso_tradeoff.py --reference sweep-mast [--workers 2]
"""

from __future__ import annotations

import argparse
import re
import tempfile
import time
from pathlib import Path

import numpy as np
from machine import python_machine, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.bench.sweep import read_results, run_sweep
from smartjoint.design.control.sweep_file import load_sweep

HERE = Path(__file__).resolve().parent
EXAMPLE = HERE.parent / "examples" / "mast_30bay_sweep.toml"
# (F_N^min [N], ε [m/s]): the cells of mast_siso_grid below passive F_N^max on 8 of 8 plants (the
# grid of their values has a fourth cell, 200 N with 1e-3 m/s, which is run and reported too)
CANDIDATES = ((200.0, 1e-2), (300.0, 1e-3), (300.0, 1e-2))
PLANT_INPUTS = ("pulse_amplitude", "amplifier_lag", "modal_frequency_scale")  # must match row by row
LAWS = ("passive F_min", "passive F_max", "cLQG", "best passive E", "slip ratio", "active LQG")


def _rows(columns: dict, law: str, where=None) -> dict:
    """One law's rows (of one grid point), in sample order, as arrays."""
    names, samples = np.asarray(columns["law"]), np.asarray(columns["sample"])
    mask = names == law if where is None else (names == law) & where
    order = np.argsort(samples[mask])
    return {key: np.asarray(values)[mask][order] for key, values in columns.items()}


def _probability(hits) -> dict:
    p, n = float(np.mean(hits)), len(hits)
    return {"probability": p, "standard_error": float(np.sqrt(p * (1.0 - p) / n)), "samples": n}


def _candidate(siso: dict, reference: dict) -> dict:
    """The SISO law's orderings at one candidate, against the reference laws on the same plants."""
    for key in ("sample", *PLANT_INPUTS):
        if not np.array_equal(siso[key], reference["cLQG"][key]):
            raise SystemExit(f"{key}: the reference sweep's plants are not the example's — re-run it")
    below_passive = (siso["energy_end"] < reference["passive F_min"]["energy_end"]) & (
        siso["energy_end"] < reference["passive F_max"]["energy_end"]
    )
    return {
        "normal_force_min": float(siso["siso_normal_force_min"][0]),
        "boundary_layer": float(siso["siso_boundary_layer"][0]),
        "median_energy_measure": float(np.median(siso["energy_measure"])),
        "energy_measure_95": float(np.quantile(siso["energy_measure"], 0.95)),
        "median_tip_rms": float(np.median(siso["tip_rms_total"])),
        "siso_below_both_passive": _probability(below_passive),
        "clqg_rms_below_siso": _probability(reference["cLQG"]["tip_rms_total"] < siso["tip_rms_total"]),
        "clqg_energy_below_siso": _probability(reference["cLQG"]["energy_measure"] < siso["energy_measure"]),
        "siso_below_best_constant": _probability(
            siso["energy_measure"] < reference["best passive E"]["energy_measure"]
        ),
    }


def _plot(candidates: list[dict], stiffness: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(10.0, 3.8))
    labels = [f"{c['normal_force_min']:.0f} N\nε {c['boundary_layer']:g}" for c in candidates]
    x = np.arange(len(candidates))
    for offset, key, text in (
        (-0.2, "siso_below_both_passive", "SISO below both passive (e)"),
        (0.0, "clqg_energy_below_siso", "cLQG's E below SISO's"),
        (0.2, "clqg_rms_below_siso", "cLQG's RMS below SISO's"),
    ):
        values = [c[key]["probability"] for c in candidates]
        errors = [c[key]["standard_error"] for c in candidates]
        left.bar(x + offset, values, 0.2, yerr=errors, label=text)
    left.set_xticks(x, labels, fontsize=8)
    left.set_ylim(0, 1.05)
    left.set_ylabel("probability over 100 plants")
    left.set_title("preloaded SISO law: the paper's orderings", fontsize=9)
    left.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=3)
    names = sorted(stiffness, key=lambda n: stiffness[n]["median_tip_rms"])
    right.barh(range(len(names)), [stiffness[n]["median_tip_rms"] for n in names], color="tab:gray")
    right.set_yticks(range(len(names)), names, fontsize=8)
    right.set_xlabel("median RMS tip deflection (tip_rms_total)")
    right.set_title("RMS tip deflection orders by stiffness: F_N^max lowest", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference", type=Path, required=True, help="a full sweep of the example's file")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    columns = read_results(args.reference).to_pydict()
    reference = {law: _rows(columns, law) for law in (*LAWS, "SISO")}
    text = EXAMPLE.read_text()
    text = re.sub(r'^design = ".*"$', f'design = "{load_sweep(EXAMPLE).design.resolve()}"', text, flags=re.M)
    text = re.sub(r"^laws = .*$", 'laws = ["SISO"]', text, flags=re.M)
    floors, epsilons = sorted({c[0] for c in CANDIDATES}), sorted({c[1] for c in CANDIDATES})
    text += f"\n[grid]\nsiso_normal_force_min = {floors}\nsiso_boundary_layer = {epsilons}\n"
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "tradeoff.toml"
        path.write_text(text)
        started = time.perf_counter()
        run_sweep(load_sweep(path), Path(tmp) / "out", workers=args.workers, progress=lambda line: None)
        seconds = time.perf_counter() - started
        grid = read_results(Path(tmp) / "out").to_pydict()
    candidates = []
    points = np.asarray(grid["point"])
    for point in sorted(set(points.tolist())):
        siso = _rows(grid, "SISO", points == point)
        cell = (float(siso["siso_normal_force_min"][0]), float(siso["siso_boundary_layer"][0]))
        candidates.append({**_candidate(siso, reference), "grid_candidate": cell in CANDIDATES})
    stiffness = {
        law: {"median_tip_rms": float(np.median(reference[law]["tip_rms_total"]))} for law in LAWS if law in reference
    }
    stiffness["passive F_max"]["clqg_rms_below"] = _probability(
        reference["cLQG"]["tip_rms_total"] < reference["passive F_max"]["tip_rms_total"]
    )
    stiffness["passive F_max"]["best_constant_rms_below"] = _probability(
        reference["best passive E"]["tip_rms_total"] < reference["passive F_max"]["tip_rms_total"]
    )
    for c in candidates:
        print(
            f"F_N^min {c['normal_force_min']:5.0f} N, ε {c['boundary_layer']:g} m/s: median E(t_e) "
            f"{c['median_energy_measure']:.4g} J·s; P(SISO below both passive) "
            f"{c['siso_below_both_passive']['probability']:.2f}; P(cLQG's E below) "
            f"{c['clqg_energy_below_siso']['probability']:.2f}; P(cLQG's RMS below) "
            f"{c['clqg_rms_below_siso']['probability']:.2f}"
        )
    for law, figures in sorted(stiffness.items(), key=lambda item: item[1]["median_tip_rms"]):
        print(f"  {law:15s} median RMS tip deflection {figures['median_tip_rms']:.4g}")
    _plot(candidates, stiffness, HERE / "mast_siso_tradeoff.png")
    write_json(
        HERE / "mast_siso_tradeoff.json",
        {
            "machine": python_machine(workers=args.workers),
            "command": "python benchmarks/mast_siso_tradeoff.py --reference FOLDER",
            "seconds": seconds,
            "candidates": candidates,
            "stiffness": stiffness,
        },
    )
    print(f"{len(candidates)} candidates × 100 plants in {seconds:.0f} s: benchmarks/mast_siso_tradeoff.json, .png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
