"""The sweep report (smartjoint/sweep_report.py, issue 20): the orderings' probabilities with
their Monte Carlo standard error, and the rank correlations that name the driving inputs, on a
table whose answers are known."""

from __future__ import annotations

import math

import numpy as np
import pyarrow as pa

from smartjoint.design.control.ensemble import METRICS
from smartjoint.sweep_report import markdown, orderings, sensitivity, write


def _table(samples: int = 40) -> dict:
    """SISO and cLQG rows; cLQG's E(t_e) below SISO's in the samples whose ``a`` exceeds 0.75,
    E(t_e) rising with ``a`` for both laws and not depending on ``b``."""
    rng = np.random.default_rng(3)
    a, b = rng.uniform(0.0, 1.0, samples), rng.uniform(0.0, 1.0, samples)
    columns: dict = {name: [] for name in ("sample", "point", "law", "a", "b", *METRICS)}
    for i in range(samples):
        for law, energy in (("SISO", 1.0 + a[i]), ("cLQG", 1.0 + a[i] + (-0.5 if a[i] > 0.75 else 0.5))):
            row = {"sample": i, "point": 0, "law": law, "a": a[i], "b": b[i], "energy_measure": energy}
            row.update({m: 0.0 for m in METRICS if m not in row})
            row["tip_rms_total"] = 1.0 if law == "SISO" else 2.0
            row["energy_end_relative"] = row["settling_time"] = math.nan  # no passive run, not settled
            for name in columns:
                columns[name].append(row[name])
    return columns


def test_an_ordering_is_its_frequency_with_the_binomial_standard_error():
    columns = _table()
    a = np.asarray(columns["a"][::2])
    got = orderings(columns)[0]
    p = float(np.mean(a > 0.75))
    assert got["clqg_energy_measure_below_siso"] == {
        "probability": p,
        "standard_error": math.sqrt(p * (1 - p) / 40),
        "samples": 40,
    }
    assert got["clqg_tip_rms_below_siso"]["probability"] == 0.0  # cLQG's RMS is always the larger
    assert "siso_below_both_passive" not in got  # the passive laws were not run


def test_the_driving_input_comes_first_with_its_rank_correlation():
    ranked = sensitivity(_table(), ["a", "b"])
    assert ranked[(0, "SISO")][0] == ("a", 1.0)  # E(t_e) = 1 + a: monotone, ρ = 1 exactly
    assert abs(ranked[(0, "SISO")][1][1]) < 0.5 and ranked[(0, "SISO")][1][0] == "b"


def test_the_report_is_written_whole(tmp_path):
    columns = _table()
    text = markdown(columns, ["a", "b"], "sweep.toml")
    assert "| 0 | cLQG's E(t_e) (Eq. 32) below SISO's |" in text and "`a` (+1.00)" in text
    report = write(tmp_path, pa.table(columns), ["a", "b"], "sweep.toml")
    assert report.read_text() == text and (tmp_path / "ecdf.png").stat().st_size > 1000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ecdf.png", "report.md"]


def test_the_nominal_landscape_joins_the_report_where_the_sweep_wrote_one(tmp_path):
    """best_passive_landscape.json (bench.sweep_landscape) → its plot and a section naming both
    best forces; the rest of the report unchanged."""
    import json

    from smartjoint.bench.sweep_landscape import LANDSCAPE

    forces = np.linspace(10.0, 400.0, 41)
    landscape = {
        "forces": forces.tolist(),
        "energy_measure": (1.0 / forces).tolist(),
        "energy_end": (1e-3 + (forces - 40.0) ** 2 * 1e-6).tolist(),
        "best": {"energy_measure": {"force": 400.0, "value": 0.0025}, "energy_end": {"force": 40.0, "value": 1e-3}},
        "search": {"grid_intervals": 40, "refined": 3, "tolerance": 0.1},
    }
    (tmp_path / LANDSCAPE).write_text(json.dumps(landscape))
    columns = _table()
    report = write(tmp_path, pa.table(columns), ["a", "b"], "sweep.toml").read_text()
    assert report.startswith(markdown(columns, ["a", "b"], "sweep.toml"))
    assert "41 constant-force runs" in report and "for E(t_e): 400.0 N" in report and "for e(t_e): 40.0 N" in report
    assert (tmp_path / "best_passive_landscape.png").stat().st_size > 1000


def test_energies_at_the_floor_tie_and_the_tie_holds_in_every_section():
    """e(t_e) of the active LQG 2.01e-7 J against the cLQG's 1.99e-7 J, passive F^max 1e-2 J: a
    difference of 2e-7 of passive F^max's, below ENERGY_TIE, is a tie and the ordering holds; a
    difference above it (1e-6 J, 1e-4 of it) does not; without a passive reference nothing ties."""
    from smartjoint.design.control.orderings import ACTIVE, ENERGY_TIE, orderings

    ordering = next(o for o in orderings() if o.key == "active_energy_below_clqg")
    reference = 1e-2

    def figures(active: float, clqg: float, with_reference: bool = True) -> dict:
        relative = (lambda e: e / reference) if with_reference else (lambda e: math.nan)
        return {
            ACTIVE: {"energy_end": active, "energy_end_relative": relative(active)},
            "cLQG": {"energy_end": clqg, "energy_end_relative": relative(clqg)},
        }

    assert 2.01e-7 - 1.99e-7 < ENERGY_TIE * reference < 1e-6
    assert ordering.holds(figures(2.01e-7, 1.99e-7)) is True
    assert ordering.holds(figures(1.2e-6, 2e-7)) is False
    assert ordering.holds(figures(2.01e-7, 1.99e-7, with_reference=False)) is False
    assert ordering.holds(figures(1.99e-7, 2.01e-7, with_reference=False)) is True
