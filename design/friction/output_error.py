"""The output-error step of the LuGre identification: all six parameters from the stick-slip
velocities by multiple shooting of the rig model m·v̇ = F_exc − r·F_N·μ(v, φ) (Eq. 1–2),
driven by the measured excitation force (``rig_kernel.c``, 8 implicit trapezoidal substeps per
sample), fitted segment by segment from one sliding-velocity peak to the next."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import scipy.optimize
from scipy.signal import find_peaks, savgol_filter

from smartjoint.common.errors import ModelError
from smartjoint.design.friction import lugre, rig_integration
from smartjoint.design.friction.fitting import (
    VELOCITY_CUTOFF,
    StepResult,
    excitation_drive,
    low_pass,
    nrmse,
    rms,
    step_result,
)
from smartjoint.design.friction.records import Record, RecordError

P3 = ("sigma0", "sigma1", "sigma2", "coulomb", "stribeck", "stribeck_velocity")  # output error: all six
START_FRACTIONS = (0.1, 0.3, 1.0)  # F_d / F_c of the screened starts
START_SPEEDS = (0.03, 0.1, 0.3)  # v_s / the median sliding speed at the segment starts
# The search box's lower ends [SI, per unit normal force]: a parameter that ends there is one the
# records do not see (its interval is unbounded); the upper ends are lugre.PLAUSIBLE's.
SEARCH_FLOOR = {
    "sigma0": 1.0,
    "sigma1": 1e-9,
    "sigma2": 1e-9,
    "coulomb": 1e-4,
    "stribeck": 1e-7,
    "stribeck_velocity": 1e-8,
}


@dataclass
class Shooting:
    """A stick-slip record prepared for the output-error step (multiple shooting)."""

    record: Record
    force: np.ndarray  # low-passed excitation at the integrator's substep nodes
    gain: np.ndarray  # r·F_N at the nodes
    starts: np.ndarray  # sample index of every segment start: the sliding-velocity peaks
    start_velocity: np.ndarray  # measured velocity there, from a local quadratic fit
    measured: np.ndarray  # measured velocity of the samples the segments predict
    scale: float  # RMS velocity · √samples: every record counts alike


def output_error_gap(record: Record) -> str | None:
    """Why ``record`` cannot enter the output-error step (None when it can).

    Parameters
    ----------
    record : Record
        A stick-slip record.

    Returns
    -------
    str or None
        The missing column or metadata, naming the record.
    """
    if record.excitation_force is None:
        return f"{record.name}: no column 'excitation_force'"
    if not record.inertia:
        return f"{record.name}: no '# inertia = …' metadata (or inertia 0)"
    return None


def prepare_shooting(record: Record, arm: float) -> Shooting:
    """Cut a stick-slip record into output-error segments from one sliding-velocity peak to the next.

    Parameters
    ----------
    record : Record
        A record with its excitation force and inertia (`output_error_gap` is None).
    arm : float
        The moment arm r (1 for type A).

    Returns
    -------
    Shooting
        The low-passed excitation and r·F_N at the substep nodes, the segment starts and
        their start velocities, the measured velocities to predict and the record's scale.

    Raises
    ------
    RecordError
        When the velocity has no sliding peak.
    """
    force, frequency = excitation_drive(record)
    period = 1.0 / frequency
    smoothed = low_pass(record.sliding_velocity, record.sample_time, VELOCITY_CUTOFF * frequency, period)
    half_period = 0.5 * period / record.sample_time
    peaks, _ = find_peaks(
        np.abs(smoothed), distance=max(int(0.6 * half_period), 1), height=0.5 * np.abs(smoothed).max()
    )
    peaks = peaks[peaks < record.time.size - 1]
    if peaks.size == 0:
        raise RecordError(
            f"{record.name}: column 'sliding_velocity' has no sliding peak to start the output-error segments from"
        )
    # The start values: a quadratic fit to the raw velocity over ±0.1 half period. Reading the
    # low-passed velocity at its own maxima would pick the noise's ups (type B: σ2 +15 %, not +10 %).
    half_window = min(max(int(0.1 * half_period), 2), (record.time.size - 1) // 2)
    start_velocity = savgol_filter(record.sliding_velocity, 2 * half_window + 1, 2)[peaks]
    # Linear interpolation between samples: the substep nodes of rig_integration.integrate.
    substep = np.diff(record.time)[:, None] / rig_integration.SUBSTEPS * np.arange(rig_integration.SUBSTEPS)[None, :]
    nodes = np.append((record.time[:-1, None] + substep).ravel(), record.time[-1])
    measured = record.sliding_velocity[peaks[0] + 1 :]
    return Shooting(
        record,
        np.interp(nodes, record.time, force),
        arm * np.interp(nodes, record.time, record.normal_force),
        peaks,
        start_velocity,
        measured,
        rms(record.sliding_velocity) * math.sqrt(measured.size),
    )


def shoot(p: lugre.LuGreParameters, shooting: Shooting) -> np.ndarray:
    """Simulated velocity of the rig model (Eq. 1–2) for ``shooting.measured``.

    Each segment runs from one sliding-velocity peak to the next, from the measured velocity
    (local quadratic fit) and the steady-state deflection φ_ss(v) of Eq. 1 (at a peak the element slides
    steadily, and φ relaxes within F_c/(σ0·|v|) ≈ 0.1 ms).

    Parameters
    ----------
    p : LuGreParameters
        The parameters tried.
    shooting : Shooting
        The prepared record (`prepare_shooting`).

    Returns
    -------
    ndarray
        The simulated velocity at the samples of ``shooting.measured``.
    """
    record, step = shooting.record, rig_integration.SUBSTEPS
    bounds = np.append(shooting.starts, record.time.size - 1)
    parts = []
    for start, end, velocity0 in zip(bounds[:-1], bounds[1:], shooting.start_velocity):
        nodes = slice(start * step, end * step + 1)
        velocity, _ = rig_integration.integrate(
            p,
            shooting.gain[nodes],
            record.inertia,
            shooting.force[nodes],
            record.time[start : end + 1],
            step,
            velocity0,
            float(lugre.steady_state_deflection(p, velocity0)),
            backend="c",
        )
        parts.append(velocity[1:])
    return np.concatenate(parts)


def refine(
    stick: list[Record],
    start: lugre.LuGreParameters,
    progress,
    previous: lugre.LuGreParameters | None = None,
    screen: bool = True,
) -> tuple[StepResult, lugre.LuGreParameters]:
    """Output-error step: all six parameters from the stick-slip velocities, started at ``start``.

    The rig model m·v̇ = F_exc − r·F_N·μ(v, φ) (Eq. 1–2) is driven by the measured excitation
    force, so velocity noise is output noise only, which least squares averages out, where in
    Eq. 3 it is input noise that biases F_d. Two details keep the force noise from biasing it
    instead: the force is low-passed at ``EXCITATION_CUTOFF``× its frequency (its noise near the
    lightly damped bristle resonance would shake the simulated bristles during sticking), and
    the records are cut into segments from one velocity peak to the next (a sliding element's
    velocity is neutrally stable, so integrated force noise drifts over a whole record).
    Micro-slip records stay out: their velocity is the bristle resonance's response, and the
    force noise alone drives that far above the signal (velocity NRMSE 2.5–7.6 at the truth).

    Parameters
    ----------
    stick : list of Record
        The stick-slip records (each with excitation force and inertia).
    start : LuGreParameters
        The result of the Eq. 3 steps.
    previous : LuGreParameters, optional
        An earlier estimate, screened with the other starts.
    progress : callable or None
        Receives one line when the step is done.
    screen : bool
        Screen the grid of starts (`_starts`); False polishes from ``start`` alone (the
        bootstrap's replicates, which start at the estimate they were simulated with).

    Returns
    -------
    tuple
        (StepResult with the velocity NRMSE per record, the refined LuGreParameters).
    """
    shootings = [prepare_shooting(r, start.moment_arm) for r in stick]

    def parameters(theta):
        return lugre.LuGreParameters(radius=start.radius, **{n: float(math.exp(t)) for n, t in zip(P3, theta)})

    def residual(theta):
        p = parameters(theta)
        parts = [(shoot(p, s) - s.measured) / s.scale for s in shootings]
        # A wild trial point can make the Newton solve diverge: a large finite residual
        # sends the optimiser back instead of stopping it.
        return np.nan_to_num(np.concatenate(parts), nan=1e3, posinf=1e3, neginf=-1e3)

    lower, upper = _search_box("A" if start.radius is None else "B")
    if screen:
        thetas = _starts(start, shootings, previous, lower, upper)
    else:
        thetas = [np.clip(np.log([getattr(start, n) for n in P3]), lower + 1e-9, upper - 1e-9)]
    costs = [float(np.sum(residual(theta) ** 2)) for theta in thetas]
    solution = scipy.optimize.least_squares(
        residual,
        thetas[int(np.argmin(costs))],
        bounds=(lower, upper),
        x_scale=1.0,
        diff_step=1e-6,
        # Log parameters to 1e-8 and the cost to 1e-9 relative: far below any interval (≥ 0.1 %),
        # and a third of the evaluations of 1e-10 / 1e-12, which mostly polished noise.
        xtol=1e-8,
        ftol=1e-9,
        max_nfev=100,
    )
    solution.nfev += len(thetas)
    p = parameters(solution.x)
    errors = {s.record.name: nrmse(s.measured, shoot(p, s)) for s in shootings}
    lengths = np.concatenate([np.diff(np.append(s.starts, s.record.time.size - 1)) for s in shootings])
    if progress:
        progress(
            f"step 3 (output error: σ0, σ1, σ2, F_c, F_d, v_s, {len(stick)} stick-slip records, "
            f"{sum(s.starts.size for s in shootings)} segments): cost {solution.cost:.4g}"
        )
    return step_result(P3, solution, errors, solution.nfev, np.repeat(np.arange(lengths.size), lengths)), p


def _starts(start, shootings, previous, lower, upper) -> list[np.ndarray]:
    """The output-error step's candidate starts (log parameters inside the search box)."""
    # The Eq. 3 result is a poor start when its records are heavy (m·a swamps the friction
    # column: F_d and v_s collapse to 0, and the velocities barely tell that valley from the
    # truth, cost +18 %): screen it with a grid over F_d and v_s scaled from the records'
    # sliding speed, and polish the cheapest within the plausible box, not around the start.
    # The Eq. 3 result can also collapse the other way (F_c → 0, F_d the whole sliding level,
    # v_s far beyond the records: no Stribeck drop, type A from a prior F_c ×2, v_s ×2 at 3 %
    # noise), so the grid is laid out from its sliding level F_c + F_d as well as from its F_c.
    speed = float(np.median(np.concatenate([np.abs(s.start_velocity) for s in shootings])))
    levels = dict.fromkeys((start.coulomb, start.coulomb + start.stribeck))
    candidates = [start] + [
        dataclasses.replace(
            start,
            coulomb=level,
            stribeck=fraction * level,
            stribeck_velocity=factor * speed,
            sigma1=max(start.sigma1, 1e-4 * math.sqrt(start.sigma0)),
            sigma2=max(start.sigma2, 1e-3 * level),
        )
        for level in levels
        for fraction in START_FRACTIONS
        for factor in START_SPEEDS
    ]
    if previous is not None:
        candidates.append(dataclasses.replace(previous, radius=start.radius))
    thetas = [np.clip(np.log([getattr(c, n) for n in P3]), lower + 1e-9, upper - 1e-9) for c in candidates]
    return thetas


def _search_box(joint_type: str) -> tuple[np.ndarray, np.ndarray]:
    """Log bounds of the output-error search: ``SEARCH_FLOOR`` … ``lugre.PLAUSIBLE``'s upper ends."""
    column = 0 if joint_type == "A" else 1
    lower = np.log([SEARCH_FLOOR[n] for n in P3])
    upper = np.log([lugre.PLAUSIBLE[n][column][1] for n in P3])
    return lower, upper


def output_error_blocker(stick: list[Record], enabled: bool) -> str | None:
    """Why the output-error step cannot run (None when it can).

    Parameters
    ----------
    stick : list of Record
        The stick-slip records.
    enabled : bool
        Whether the step was asked for.

    Returns
    -------
    str or None
        The first reason: switched off, a record's gap, or the rig kernel unavailable.
    """
    if not enabled:
        return "switched off"
    for record in stick:
        gap = output_error_gap(record)
        if gap:
            return gap
    try:
        rig_integration.kernel()
    except ModelError as error:  # the Python reference loop would take hours here
        return f"rig kernel unavailable ({error})"
    return None


__all__ = ["P3", "Shooting", "output_error_blocker", "output_error_gap", "prepare_shooting", "refine", "shoot"]
