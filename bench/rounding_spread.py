"""How far a faithful re-implementation may land from the model in the loop: the MIL run's spread
under float-rounding-sized perturbations of its commands, and the band a SIL (or local-mode, or
target) run's E(t_e) must lie in. The stick–slip closed loop is chaotic, so a single trajectory's
figure moves by percent under 1e-8 perturbations: a comparison against MIL is against this band,
measured in the same run, never against a fixed tolerance.
"""

from __future__ import annotations

import numpy as np

from smartjoint.design.control import study as closed_loop

CONFIRMING_RUNS = 8  # perturbed runs before a run outside the band is called outside


def perturbed(controller, relative: float, seed: int):
    """A controller with its normal-force commands multiplied by 1 + relative·N(0, 1).

    The sensitivity reference of the SIL comparison (float rounding is ~6e-8 relative).

    Parameters
    ----------
    controller : controller
        Any controller of the plant interface.
    relative : float
        The relative standard deviation of the perturbation.
    seed : int
        The random seed (restarted by ``reset``).

    Returns
    -------
    controller
        The perturbed controller.
    """

    class Perturbed:
        sample_time = controller.sample_time

        def __init__(self):
            self.rng = np.random.default_rng(seed)

        def reset(self):
            controller.reset()
            self.rng = np.random.default_rng(seed)

        def step(self, measurements):
            out = np.asarray(controller.step(measurements), dtype=float)
            return out * (1.0 + relative * self.rng.standard_normal(out.size))

    return Perturbed()


def mil_runs(setup, law: str, controller, spread_runs: int) -> tuple:
    """The model-in-the-loop run of a new ``controller()`` and the relative E(t_e) differences of
    ``spread_runs`` runs with its commands perturbed at float-rounding size (6e-8)."""
    mil = closed_loop.run_semi_active(setup, law, controller())
    return mil, more_runs(setup, law, controller, mil, range(spread_runs))


def more_runs(setup, law: str, controller, mil, seeds) -> list[float]:
    """The relative E(t_e) differences from ``mil`` of perturbed runs of a new ``controller()``,
    one per seed of ``seeds`` (seed k is the k-th run of :func:`mil_runs`)."""
    spread = []
    for seed in seeds:
        run = closed_loop.run_semi_active(setup, law, perturbed(controller(), 6e-8, seed))
        spread.append(run.energy_measure() / mil.energy_measure() - 1.0)
    return spread


def confirmed(setup, law: str, controller, mil, spread: list[float], energy_measure: float, progress) -> list[float]:
    """``spread``, with perturbed runs added up to :data:`CONFIRMING_RUNS` when a run's
    ``energy_measure`` lies outside its :func:`chaos_band` (``progress`` hears that it does)."""
    difference = energy_measure / mil.energy_measure() - 1.0
    if not spread or within_band(difference, spread) or len(spread) >= CONFIRMING_RUNS:
        return spread
    progress(
        f"      {law}: {difference:+.2%} lies outside the band of {len(spread)} perturbed runs: "
        f"judged on {CONFIRMING_RUNS} …"
    )
    return spread + more_runs(setup, law, controller, mil, range(len(spread), CONFIRMING_RUNS))


def chaos_band(spread) -> tuple[float, float] | None:
    """The band of E(t_e) differences from MIL that a faithful re-implementation lies in.

    The stick–slip loop is chaotic, so the float firmware is one more draw of the distribution
    that the MIL runs under float-rounding perturbations sample (the unperturbed run, 0, among
    them). A new draw falls outside the range of n draws with probability 2/(n + 1), so the band
    is that range widened by its own width on each side (at least 1 %). For a normal spread a
    faithful run falls outside it with probability 3 % after 4 perturbed runs and 0.3 % after 8
    (``tests/test_rounding_spread.py`` draws it), so a run outside the band of 4 is judged again
    on 8 (:data:`CONFIRMING_RUNS`). Measured in the run, never a fixed percentage.

    Parameters
    ----------
    spread : sequence of float
        Relative E(t_e) differences of the perturbed MIL runs from the unperturbed one.

    Returns
    -------
    (float, float) or None
        The band's lower and upper relative difference; None without perturbed runs.
    """
    if not len(spread):
        return None
    low, high = min(min(spread), 0.0), max(max(spread), 0.0)
    margin = max(high - low, 0.01)
    return low - margin, high + margin


def within_band(difference: float | None, spread) -> bool | None:
    """Whether a relative E(t_e) difference from MIL lies in :func:`chaos_band` (None: no band)."""
    band = None if spread is None else chaos_band(spread)
    return None if band is None or difference is None else bool(band[0] <= difference <= band[1])


def band_cell(spread) -> str:
    """The MIL spread (its range) for a report's table."""
    return "—" if spread is None else f"{100 * spread[0]:+.1f} … {100 * spread[1]:+.1f} %"


def verdict_cell(within: bool | None, spread) -> str:
    """Whether the difference lies in :func:`chaos_band`, with the band, for a report's table."""
    band = None if spread is None else chaos_band(spread)
    if within is None or band is None:
        return "—"
    return f"{'yes' if within else '**no**'} ({100 * band[0]:+.1f} … {100 * band[1]:+.1f} %)"
