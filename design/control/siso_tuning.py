"""The SISO law's settings for a study (paper Section 5.1): its boundary layer ε of Eq. 30 from
the design file, or optimised for E(t_e) of Eq. 32 on the study; the law the study runs.

The SISO entry of the law registry names this module (``tune``, ``controller``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from smartjoint.common import law_registry
from smartjoint.design.control.laws import SisoLaw
from smartjoint.design.control.runs import StudySetup, run_semi_active

LAW = law_registry.LAWS["siso"]
EPSILON_GRID = tuple(10.0 ** np.arange(-8.0, -1.75, 0.5))  # m/s: the ε scan before refinement


@dataclass
class BoundaryLayerOptimum:
    """The SISO ε (common to all joints) that minimises Eq. 32, every evaluation, and the
    check of the acceptance: E at ε/10 and 10ε."""

    boundary_layer: float
    energy_measure: float
    evaluations: list[tuple[float, float]]  # (ε, E(t_e)) in evaluation order
    tenth: float  # E(t_e) at ε/10
    tenfold: float  # E(t_e) at 10ε

    def figures(self) -> dict:
        """The optimum, its E(t_e) and the acceptance check, JSON-ready (no evaluations)."""
        return {
            "optimum": self.boundary_layer,
            "energy_measure": self.energy_measure,
            "energy_measure_tenth": self.tenth,
            "energy_measure_tenfold": self.tenfold,
        }

    setting = "boundary_layer"  # the setting it tuned (``Law.settings``)

    @property
    def value(self) -> float:
        """The tuned setting's value, ε [m/s]."""
        return self.boundary_layer

    def summary(self) -> dict:
        """:meth:`figures` and every evaluation (ε, E(t_e)), JSON-ready."""
        return {**self.figures(), "evaluations": [[w, e] for w, e in self.evaluations]}

    def describe(self) -> str:
        """One sentence of what the optimisation found."""
        return (
            f"ε = {self.boundary_layer:.3g} m/s optimised for E(t_e), E = {self.energy_measure:.4g} J·s; at ε/10 "
            f"{self.tenth:.4g}, at 10ε {self.tenfold:.4g} ({len(self.evaluations)} simulations)"
        )


def optimise_boundary_layer(
    s: StudySetup, progress=print, grid=EPSILON_GRID, normal_force_min=None
) -> BoundaryLayerOptimum:
    """ε of Eq. 30 minimising E(t_e) of Eq. 32 (Section 5.1): a half-decade scan of log ε, then
    bounded Brent (scipy ``minimize_scalar``) within a half decade of the best grid point. E is a
    rough function of ε (stick/slip events shift with it), hence the scan before the local search.

    Parameters
    ----------
    s : StudySetup
        The study the SISO runs are made in.
    progress : callable
        Receives one line per evaluation.
    grid : sequence of float
        The ε [m/s] scanned before the local search.
    normal_force_min : float or array_like, optional
        The law's F_N^min [N] (a preload); None: the study's.

    Returns
    -------
    BoundaryLayerOptimum
    """
    cache: dict[float, float] = {}

    def measure(log_width: float) -> float:
        width = float(10.0**log_width)
        if width not in cache:
            cache[width] = run_semi_active(s, LAW.display, siso(s, width, normal_force_min)).energy_measure()
            progress(f"      ε = {width:.3g} m/s: E(t_e) = {cache[width]:.5g} J·s")
        return cache[width]

    logs = [math.log10(g) for g in grid]
    values = [measure(v) for v in logs]
    best = logs[int(np.argmin(values))]
    found = minimize_scalar(
        measure, bounds=(best - 0.5, best + 0.5), method="bounded", options={"xatol": 0.02, "maxiter": 12}
    )
    log_width = float(found.x) if found.fun < min(values) else best
    width = float(10.0**log_width)
    best_value, tenth, tenfold = measure(log_width), measure(log_width - 1.0), measure(log_width + 1.0)
    return BoundaryLayerOptimum(width, best_value, list(cache.items()), tenth, tenfold)


def siso(s: StudySetup, boundary_layer, normal_force_min=None) -> SisoLaw:
    """The SISO law of Eq. 30–31 on the study's limits and sample time.

    Parameters
    ----------
    s : StudySetup
    boundary_layer : float or array_like
        ε [m/s], one for all joints or one per joint.
    normal_force_min : float or array_like, optional
        The law's F_N^min [N], a preload within the joints' limits; None: the study's F_N^min.

    Returns
    -------
    SisoLaw
    """
    width = np.broadcast_to(np.asarray(boundary_layer, dtype=float), s.normal_force_min.shape)
    low = s.normal_force_min if normal_force_min is None else normal_force_min
    low = np.broadcast_to(np.asarray(low, dtype=float), s.normal_force_min.shape)
    return SisoLaw(s.sample_time, low, s.normal_force_max, width)


def controller(setup: StudySetup, lqg, settings: dict) -> SisoLaw:
    """The SISO law the study runs with the tuned ε and its F_N^min (``settings``)."""
    return siso(setup, settings["boundary_layer"], settings.get("normal_force_min"))


def tuned(design, settings: dict, setup: StudySetup | None, progress) -> tuple[dict, BoundaryLayerOptimum | None]:
    """ε from the design file, else (with a study to run) the common ε minimising Eq. 32.

    Parameters
    ----------
    design : Design
    settings : dict
        The law's settings from the design file and defaults (``boundary_layer`` None: open).
    setup : StudySetup or None
        The study to optimise ε on; None leaves an open ε open.
    progress : callable

    Returns
    -------
    dict, BoundaryLayerOptimum or None
        The settings with ε per joint, and the optimisation (None when ε was given).
    """
    if settings["boundary_layer"] is not None or setup is None:
        return settings, None
    progress(f"      {LAW.display} boundary layer ε: optimising E(t_e) of Eq. 32 …")
    optimum = optimise_boundary_layer(setup, progress, normal_force_min=settings.get("normal_force_min"))
    return {**settings, "boundary_layer": np.full(len(design.joints), optimum.boundary_layer)}, optimum


__all__ = ["EPSILON_GRID", "LAW", "BoundaryLayerOptimum", "controller", "optimise_boundary_layer", "siso", "tuned"]
