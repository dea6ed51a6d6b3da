"""The best passive setting: the constant normal force that minimises Eq. 32's E(t_e), or the
energy e(t_e) left at t_e, for one plant — the reference a semi-active law must beat to be worth
its electronics (issue 20: a well-chosen preload is the engineer's alternative).

The search, on the study's protocol (F_N^max during the pulse, then one constant F_N at every
joint): ``GRID_INTERVALS`` + 1 forces evenly over [max F_N^min, min F_N^max], then bounded Brent
(``scipy.optimize.minimize_scalar``) to ``TOLERANCE`` newtons between the neighbours of each of the
``REFINED`` best local minima of that grid. A figure of a stick-slip loop has several basins in
F_N (on the bundled study e(t_e) has minima at 23 N and 40 N, the one at 40 N a notch 400× below
its surroundings within ±5 N, and E(t_e) one at 45 N and the global one at F^max): a coarse grid
followed by one Brent from its best point (issue 36) refined the wrong basin. The grid's spacing
is set from measured landscapes (``benchmarks/best_passive.py``); the search stays the best of a
stated search, not a certified global minimum. Every force evaluated is kept (``cache``, the
landscape), and the best of all of them is returned.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.control.runs import Run, StudySetup

GRID_INTERVALS = 80  # the first pass: intervals of the grid over the common force range (benchmarks/best_passive.py)
REFINED = 3  # local minima of the grid refined by Brent, best first
TOLERANCE = 0.1  # N: Brent's absolute tolerance in F_N
METRICS = {"energy_measure": "E(t_e) of Eq. 32", "energy_end": "e(t_e)"}


def figure(run: Run, metric: str) -> float:
    """The run's E(t_e) (``"energy_measure"``) or e(t_e) (``"energy_end"``)."""
    return run.energy_measure() if metric == "energy_measure" else float(run.energy[-1])


def local_minima(values: np.ndarray) -> list[int]:
    """Indices of the grid's local minima (a point no larger than its neighbours; an end counts
    against its one neighbour), best first; a plateau gives its first point."""
    v = np.asarray(values, dtype=float)
    left = np.concatenate([[np.inf], v[:-1]])
    right = np.concatenate([v[1:], [np.inf]])
    found = np.flatnonzero((v < left) & (v <= right))
    return sorted(found.tolist(), key=lambda i: (v[i], i))


def landscape(cache: dict, metric: str) -> tuple[np.ndarray, np.ndarray]:
    """The forces a search evaluated (``cache``: force → run), sorted, and their ``metric``."""
    forces = np.array(sorted(cache), dtype=float)
    return forces, np.array([figure(cache[f], metric) for f in forces])


def best_passive(
    s: StudySetup,
    name: str,
    metric: str,
    passive: Callable[[StudySetup, str, np.ndarray], Run],
    cache: dict[float, Run] | None = None,
) -> tuple[Run, float]:
    """The passive run of the constant F_N that minimises ``metric``, and that force.

    Parameters
    ----------
    s : StudySetup
        The sample's study (its plant, friction, pulse and limits).
    name : str
        The returned run's name.
    metric : str
        ``"energy_measure"`` (E(t_e), Eq. 32) or ``"energy_end"`` (e(t_e)).
    passive : callable
        ``passive(s, name, forces)`` runs the study at constant forces, one per joint
        (``runs.run_passive`` or the compiled loop's ``run_passive``; both give the same run).
    cache : dict, optional
        Force → run, shared between the searches of one sample (both metrics reuse each run).

    Returns
    -------
    tuple of (Run, float)

    Raises
    ------
    ModelError
        An unknown metric, or joints whose limits share no force.
    """
    if metric not in METRICS:
        raise ModelError(f"metric: {metric!r} — must be one of {', '.join(METRICS)}")
    low, high = float(np.max(s.normal_force_min)), float(np.min(s.normal_force_max))
    if not low <= high:
        raise ModelError(f"normal-force limits: no constant F_N lies in every joint's [F^min, F^max] ({low} > {high})")
    runs = {} if cache is None else cache

    def value(force: float) -> float:
        force = float(force)
        if force not in runs:
            runs[force] = passive(s, name, np.full(s.normal_force_min.shape, force))
        return figure(runs[force], metric)

    grid = np.linspace(low, high, GRID_INTERVALS + 1) if high > low else np.array([low])
    values = np.array([value(force) for force in grid])
    for i in local_minima(values)[:REFINED]:
        a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
        if b - a > TOLERANCE:
            from scipy.optimize import minimize_scalar

            minimize_scalar(value, bounds=(a, b), method="bounded", options={"xatol": TOLERANCE})
    best = min(runs, key=lambda force: (figure(runs[force], metric), force))
    return dataclasses.replace(runs[best], name=name), best


def search_landscape(s: StudySetup, passive: Callable[[StudySetup, str, np.ndarray], Run]) -> dict:
    """Both searches on one plant sharing their runs, and the landscape they saw: JSON-ready.

    Returns
    -------
    dict
        ``forces`` (every force run, sorted), per metric its value at each force and the best
        force and value (``best``), and the search's settings.
    """
    cache: dict[float, Run] = {}
    best = {}
    for metric in METRICS:
        run, force = best_passive(s, "best", metric, passive, cache)
        best[metric] = {"force": force, "value": figure(run, metric)}
    forces = sorted(cache)
    return {
        "forces": forces,
        **{metric: [figure(cache[f], metric) for f in forces] for metric in METRICS},
        "best": best,
        "search": {"grid_intervals": GRID_INTERVALS, "refined": REFINED, "tolerance": TOLERANCE},
    }


__all__ = [
    "GRID_INTERVALS",
    "METRICS",
    "REFINED",
    "TOLERANCE",
    "best_passive",
    "figure",
    "landscape",
    "local_minima",
    "search_landscape",
]
