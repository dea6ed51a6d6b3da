"""The best passive setting: the constant normal force that minimises Eq. 32's E(t_e), or the
energy e(t_e) left at t_e, for one plant — the reference a semi-active law must beat to be worth
its electronics (issue 20: a well-chosen preload is the engineer's alternative).

The search: the study's protocol (F_N^max during the pulse, then one constant F_N at every joint),
``SEARCH_POINTS`` forces evenly over [max F_N^min, min F_N^max], then bounded Brent
(``scipy.optimize.minimize_scalar``) to ``TOLERANCE`` newtons between the best grid point's
neighbours. The figure of a stick-slip loop is not smooth in F_N, so this is the best found by a
stated search, not a certified global minimum; every force evaluated is kept, and the best of all
of them is returned.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.control.runs import Run, StudySetup

SEARCH_POINTS = 9  # forces of the first pass
TOLERANCE = 1.0  # N: Brent's absolute tolerance in F_N
METRICS = {"energy_measure": "E(t_e) of Eq. 32", "energy_end": "e(t_e)"}


def figure(run: Run, metric: str) -> float:
    """The run's E(t_e) (``"energy_measure"``) or e(t_e) (``"energy_end"``)."""
    return run.energy_measure() if metric == "energy_measure" else float(run.energy[-1])


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

    grid = np.linspace(low, high, SEARCH_POINTS)
    values = [value(force) for force in grid]
    i = int(np.argmin(values))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    if b - a > TOLERANCE:
        from scipy.optimize import minimize_scalar

        minimize_scalar(value, bounds=(a, b), method="bounded", options={"xatol": TOLERANCE})
    best = min(runs, key=lambda force: (figure(runs[force], metric), force))
    return dataclasses.replace(runs[best], name=name), best


__all__ = ["METRICS", "SEARCH_POINTS", "TOLERANCE", "best_passive", "figure"]
