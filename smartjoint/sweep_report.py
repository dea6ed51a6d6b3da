"""The report of a sweep (``docs/sweep.md``): the paper's orderings as probabilities over the
ensemble with their Monte Carlo standard error, each law's distribution of Eq. 32's E(t_e), and
the inputs that drive it (Spearman rank correlations), as Markdown and an ECDF plot.

Read from the results table alone (``bench.sweep.read_results``), so a finished or resumed
sweep reports the same; written atomically beside the results (``report.md``, ``ecdf.png``).
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from smartjoint.bench.sweep_landscape import LANDSCAPE, LANDSCAPE_PLOT
from smartjoint.common import figures, output_path
from smartjoint.design.control import orderings as paper_orderings
from smartjoint.design.control.ensemble import KEYS
from smartjoint.design.control.sweep_file import LAWS

# The paper's claims (Section 6) and more, from the law registry (``design.control.orderings``):
# the law's metric (smaller is better) below the smallest of the others'.
ORDERINGS = paper_orderings.orderings()


def _groups(columns: dict) -> dict:
    """(point, sample) → law → the row's metrics and inputs."""
    groups: dict = defaultdict(dict)
    names = list(columns)
    for i in range(len(columns["law"])):
        row = {name: columns[name][i] for name in names}
        groups[(row["point"], row["sample"])][row["law"]] = row
    return groups


def orderings(columns: dict) -> dict:
    """Each ordering's probability over the samples of each grid point, with its Monte Carlo
    standard error √(p(1 − p)/n) (the samples independent; for a Latin hypercube an upper bound).

    Parameters
    ----------
    columns : dict
        The results table as columns (``Table.to_pydict()``).

    Returns
    -------
    dict
        point → ordering name → ``{"probability", "standard_error", "samples"}``; orderings
        whose laws the sweep did not run, or whose metric is NaN, are left out.
    """
    counts: dict = defaultdict(lambda: defaultdict(list))
    for (point, _), laws in _groups(columns).items():
        for ordering in ORDERINGS:
            if all(run in laws for run in (ordering.run, *ordering.others)):
                holds = ordering.holds(laws)
                if holds is not None:
                    counts[point][ordering.key].append(holds)
    out: dict = {}
    for point, by_name in sorted(counts.items()):
        out[point] = {}
        for name, hits in by_name.items():
            n, p = len(hits), float(np.mean(hits))
            out[point][name] = {"probability": p, "standard_error": math.sqrt(p * (1.0 - p) / n), "samples": n}
    return out


def sensitivity(columns: dict, inputs: list[str], metric="energy_measure", top: int = 3) -> dict:
    """Spearman rank correlation of ``metric`` with every uncertain input, per law and grid point;
    the ``top`` inputs by magnitude.

    Parameters
    ----------
    columns : dict
        The results table as columns.
    inputs : list of str
        The uncertain inputs' columns.
    metric : str or array_like
        A metric column, or one value per row (:func:`advantage`'s ratio).
    top : int
        How many inputs to name.

    Returns
    -------
    dict
        (point, law) → list of (input, rho), largest |rho| first.
    """
    from scipy.stats import spearmanr

    law = np.asarray(columns["law"])
    point = np.asarray(columns["point"])
    value = np.asarray(columns[metric] if isinstance(metric, str) else metric, dtype=float)
    out = {}
    for key in sorted({(int(p), str(w)) for p, w in zip(point, law)}):
        chosen = (point == key[0]) & (law == key[1]) & np.isfinite(value)
        if chosen.sum() < 3:
            continue
        rhos = []
        for name in inputs:
            x = np.asarray(columns[name], dtype=float)[chosen]
            if np.ptp(x) > 0:
                rhos.append((name, float(spearmanr(x, value[chosen]).statistic)))
        out[key] = sorted(rhos, key=lambda item: -abs(item[1]))[:top]
    return out


def _laws(columns: dict) -> list[str]:
    """The laws of the table in the sweep's order (``sweep_file.LAWS``)."""
    present = set(columns["law"])
    return [law for law in LAWS if law in present]


def advantage(columns: dict) -> dict:
    """Each row's E(t_e) over the reference's in the same sample and grid point — the best
    passive setting for E(t_e) where the sweep ran it, else passive F^max: the figure whose
    spread says whether a law's advantage survives the uncertainty (the pulse's scale cancels).

    Parameters
    ----------
    columns : dict
        The results table as columns.

    Returns
    -------
    dict
        ``reference`` (the law, or None without one) and ``ratio``, one value per row (NaN for
        the reference's own rows and where it is missing).
    """
    laws = _laws(columns)
    reference = next((law for law in ("best passive E", "passive F_max") if law in laws), None)
    value = np.asarray(columns["energy_measure"], dtype=float)
    ratio = np.full(value.size, np.nan)
    if reference is not None:
        index = {
            (p, s): i
            for i, (p, s, w) in enumerate(zip(columns["point"], columns["sample"], columns["law"]))
            if w == reference
        }
        for i, (p, s, w) in enumerate(zip(columns["point"], columns["sample"], columns["law"])):
            j = index.get((p, s))
            if j is not None and w != reference:
                ratio[i] = value[i] / value[j]
    return {"reference": reference, "ratio": ratio}


def _distribution_rows(columns: dict) -> list[str]:
    law, point = np.asarray(columns["law"]), np.asarray(columns["point"])
    value = np.asarray(columns["energy_measure"], dtype=float)
    lines = ["| point | law | samples | median E(t_e) [J·s] | 5 % | 95 % |", "|---:|---|---:|---:|---:|---:|"]
    for p in sorted(set(point.tolist())):
        for w in _laws(columns):
            v = value[(point == p) & (law == w)]
            v = v[np.isfinite(v)]
            if v.size:
                q05, q50, q95 = np.quantile(v, [0.05, 0.5, 0.95])
                lines.append(f"| {p} | {w} | {v.size} | {q50:.4g} | {q05:.4g} | {q95:.4g} |")
    return lines


def markdown(columns: dict, inputs: list[str], source: str) -> str:
    """The report's Markdown: distributions, orderings with standard errors, sensitivities."""
    lines = [f"# Sweep report: {source}", "", "## E(t_e) (Eq. 32) per law", "", *_distribution_rows(columns)]
    lines += ["", "![ECDF of E(t_e) per law](ecdf.png)", "", "## The paper's orderings over the ensemble", ""]
    lines += ["| point | ordering | probability | MC standard error | samples |", "|---:|---|---:|---:|---:|"]
    sentences = {o.key: o.sentence for o in ORDERINGS}
    for point, by_name in orderings(columns).items():
        for name, f in by_name.items():
            lines.append(
                f"| {point} | {sentences[name]} | {f['probability']:.3f} | {f['standard_error']:.3f} | {f['samples']} |"
            )
    lines += ["", "## What drives E(t_e): Spearman rank correlation, the three largest", ""]
    lines += _sensitivity_rows(sensitivity(columns, inputs))
    ratio = advantage(columns)
    if ratio["reference"] is not None:
        lines += ["", f"## What drives the advantage: E(t_e) over {ratio['reference']}'s in the same sample", ""]
        lines += _ratio_rows(columns, ratio["ratio"])
        lines += ["", "Rank correlations of that ratio (the pulse's scale cancels in it):", ""]
        lines += _sensitivity_rows(sensitivity(columns, inputs, ratio["ratio"]))
    forces = np.asarray(columns.get("passive_normal_force", []), dtype=float)
    if np.any(np.isfinite(forces)):
        law = np.asarray(columns["law"])
        lines += [
            "",
            "## The best constant normal force",
            "",
            "| law | median F_N [N] | 5 % | 95 % |",
            "|---|---:|---:|---:|",
        ]
        for w in ("best passive E", "best passive e"):
            f = forces[(law == w) & np.isfinite(forces)]
            if f.size:
                q05, q50, q95 = np.quantile(f, [0.05, 0.5, 0.95])
                lines.append(f"| {w} | {q50:.1f} | {q05:.1f} | {q95:.1f} |")
    return "\n".join(lines) + "\n"


def _sensitivity_rows(ranked: dict) -> list[str]:
    lines = ["| point | law | inputs (ρ) |", "|---:|---|---|"]
    for (point, law), rhos in ranked.items():
        lines.append(f"| {point} | {law} | " + ", ".join(f"`{n}` ({r:+.2f})" for n, r in rhos) + " |")
    return lines


def _ratio_rows(columns: dict, ratio: np.ndarray) -> list[str]:
    law, point = np.asarray(columns["law"]), np.asarray(columns["point"])
    lines = ["| point | law | median ratio | 5 % | 95 % | P(ratio < 1) |", "|---:|---|---:|---:|---:|---:|"]
    for p in sorted(set(point.tolist())):
        for w in _laws(columns):
            r = ratio[(point == p) & (law == w) & np.isfinite(ratio)]
            if r.size:
                q05, q50, q95 = np.quantile(r, [0.05, 0.5, 0.95])
                lines.append(f"| {p} | {w} | {q50:.3f} | {q05:.3f} | {q95:.3f} | {np.mean(r < 1):.3f} |")
    return lines


def plot_ecdf(columns: dict, path: Path) -> None:
    """ECDF of E(t_e) per law (first grid point), log axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    law, point = np.asarray(columns["law"]), np.asarray(columns["point"])
    value = np.asarray(columns["energy_measure"], dtype=float)
    figure, axis = plt.subplots(figsize=(6.4, 4.0))
    for w in _laws(columns):
        v = np.sort(value[(law == w) & (point == 0) & np.isfinite(value)])
        if v.size:
            axis.step(v, np.arange(1, v.size + 1) / v.size, where="post", label=w)
    axis.set_xscale("log")
    axis.set_xlabel("E(t_e) = ∫ xᵀx dt [J·s] (Eq. 32)")
    axis.set_ylabel("fraction of samples")
    axis.legend()
    axis.grid(True, alpha=0.3)
    figures.save(figure, path, 120)


def plot_landscape(landscape: dict, path: Path) -> None:
    """E(t_e) and e(t_e) against the constant F_N on the nominal plant: every force the two
    searches ran (``bench.sweep_landscape``), the best of each marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    forces = np.asarray(landscape["forces"], dtype=float)
    figure, axes = plt.subplots(2, 1, figsize=(6.4, 5.6), sharex=True)
    for axis, metric, label in (
        (axes[0], "energy_measure", "E(t_e) [J·s] (Eq. 32)"),
        (axes[1], "energy_end", "e(t_e) [J]"),
    ):
        axis.semilogy(forces, landscape[metric], ".-", lw=0.8, ms=3)
        best = landscape["best"][metric]
        axis.semilogy([best["force"]], [best["value"]], "o", color="tab:red", label=f"best {best['force']:.1f} N")
        axis.set_ylabel(label)
        axis.grid(True, alpha=0.3)
        axis.legend()
    axes[1].set_xlabel("constant normal force F_N at every joint [N] (F^max during the pulse)")
    axes[0].set_title("constant F_N on the nominal plant: every force searched", fontsize=10)
    figures.save(figure, path, 120)


def landscape_lines(landscape: dict) -> list[str]:
    """The report's section on the nominal plant's landscape."""
    search, best = landscape["search"], landscape["best"]
    return [
        "",
        "## The best constant normal force on the nominal plant",
        "",
        f"{len(landscape['forces'])} constant-force runs: a grid of {search['grid_intervals']} intervals over "
        f"[F^min, F^max], then Brent to {search['tolerance']:g} N around its {search['refined']} best local minima "
        "(`design/control/best_passive.py`). "
        f"Best for E(t_e): {best['energy_measure']['force']:.1f} N ({best['energy_measure']['value']:.4g} J·s); "
        f"for e(t_e): {best['energy_end']['force']:.1f} N ({best['energy_end']['value']:.3g} J).",
        "",
        f"![E(t_e) and e(t_e) against the constant F_N]({LANDSCAPE_PLOT})",
    ]


def write(folder: str | Path, table, inputs: list[str], source: str) -> Path:
    """Write ``report.md`` and ``ecdf.png`` into the sweep's folder (each atomically), and the
    best passive landscape's plot where the sweep wrote one (``bench.sweep_landscape``).

    Parameters
    ----------
    folder : str or Path
        The sweep's output folder.
    table : pyarrow.Table
        Its results (``bench.sweep.read_results``).
    inputs : list of str
        The uncertain inputs' columns.
    source : str
        The sweep file's name, for the title.

    Returns
    -------
    Path
        The report.
    """
    folder = Path(folder)
    columns = table.to_pydict()
    assert set(KEYS) <= set(columns)
    plot_ecdf(columns, folder / "ecdf.png")
    text = markdown(columns, inputs, source)
    if (folder / LANDSCAPE).is_file():
        landscape = json.loads((folder / LANDSCAPE).read_text())
        plot_landscape(landscape, folder / LANDSCAPE_PLOT)
        text += "\n".join(landscape_lines(landscape)) + "\n"
    return output_path.write_file(folder / "report.md", text)


__all__ = ["ORDERINGS", "advantage", "landscape_lines", "markdown", "orderings", "plot_ecdf",
           "plot_landscape", "sensitivity", "write"]  # fmt: skip
