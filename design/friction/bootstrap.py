"""Parametric bootstrap of the output-error step: intervals that hold the bias of the estimate.

The output-error step's curvature (sandwich) interval measures the scatter of the estimate
around its mean. Off the friendly path the mean is not the truth: the measured excitation force
drives the rig model, so its noise is input noise, and sticking and breaking away are
nonlinear in it; the estimate's bias (type B, 1 % noise: F_d −1.4 %) then exceeds its
curvature interval (±0.3 %). A parametric bootstrap measures both: each stick-slip record is
simulated again with the estimate θ̂ under its own excitation and normal force (low-passed as in
the output-error step, so harmonics and a drifting F_N are kept), the noise measured on the
record is added, and the output-error step is repeated from θ̂ on the replicate. The
replicates' mean minus θ̂ is the bias b at θ̂, their spread s the scatter; the interval is

    log θ̂ ± (|b| + t₀.₉₇₅(B − 1) · s · √(1 + 1/B))               (B replicates)

and the reported interval is its union with the curvature interval, so the curvature interval
stands only where it is the wider (docs/identification.md: coverage measured by
``benchmarks/identification_coverage.py``).

Noise: the white-noise level of each measured signal from its second differences (median
absolute deviation / √6 · 1.4826): at the rig's sampling rate the signals are smooth over three
samples except at the stick–slip transitions, which the median ignores.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import scipy.stats

from smartjoint.design.friction import lugre, rig_integration
from smartjoint.design.friction.fitting import excitation_drive, rms
from smartjoint.design.friction.output_error import P3, refine
from smartjoint.design.friction.records import Record, friction_from_excitation

REPLICATES = 12  # s from 12 replicates is within ±25 % (95 %); t(11) = 2.20 widens for that


@dataclass(frozen=True)
class Bootstrap:
    """The parametric bootstrap of one identification's output-error step.

    ``estimates`` holds the replicates' parameters (one row per replicate, columns ``names``);
    ``lower``/``upper`` the bias-widened 95 % interval per name; ``noise`` the relative noise
    levels (velocity, force) measured per record and added to its replicates.
    """

    names: tuple[str, ...]
    estimates: np.ndarray
    lower: dict[str, float]
    upper: dict[str, float]
    bias: dict[str, float]  # relative: mean replicate / θ̂ − 1 (geometric)
    noise: dict[str, tuple[float, float]]
    seed: int

    def as_dict(self) -> dict:
        return {
            "replicates": int(self.estimates.shape[0]),
            "seed": self.seed,
            "ci95": {n: [self.lower[n], self.upper[n]] for n in self.names},
            "bias": dict(self.bias),
            "noise": {name: {"velocity": v, "force": f} for name, (v, f) in self.noise.items()},
        }


def white_noise_level(signal: np.ndarray) -> float:
    """The standard deviation of a signal's white noise, from its second differences (robust)."""
    second = np.diff(np.asarray(signal, dtype=float), 2)
    return float(1.4826 * np.median(np.abs(second - np.median(second))) / math.sqrt(6.0))


def replicate(
    record: Record, parameters: lugre.LuGreParameters, rng: np.random.Generator, drive: np.ndarray | None = None
) -> Record:
    """``record`` simulated again with ``parameters``: the same excitation (``drive``, the
    record's `excitation_drive` when None) and normal force, the record's own start velocity,
    and its measured noise levels added."""
    time, step, excitation = record.time, rig_integration.SUBSTEPS, record.excitation_force
    assert excitation is not None and record.inertia  # a stick-slip record of the output-error step
    if drive is None:
        drive, _ = excitation_drive(record)
    substep = np.diff(time)[:, None] / step * np.arange(step)[None, :]
    nodes = np.append((time[:-1, None] + substep).ravel(), time[-1])
    gain = parameters.moment_arm * np.interp(nodes, time, record.normal_force)
    velocity0 = float(np.median(record.sliding_velocity[:5]))
    velocity, _ = rig_integration.integrate(
        parameters,
        gain,
        record.inertia,
        np.interp(nodes, time, drive),
        time,
        step,
        velocity0,
        float(lugre.steady_state_deflection(parameters, velocity0)),
        backend="c",
    )
    velocity = velocity + white_noise_level(record.sliding_velocity) * rng.standard_normal(time.size)
    force = drive + white_noise_level(excitation) * rng.standard_normal(time.size)
    friction = friction_from_excitation(time, velocity, force, record.inertia)
    return dataclasses.replace(record, sliding_velocity=velocity, friction_force=friction, excitation_force=force)


def bootstrap(identification, replicates: int = REPLICATES, seed: int = 0, progress=None) -> Bootstrap:
    """The parametric bootstrap of ``identification``'s output-error step.

    Parameters
    ----------
    identification : Identification
        With its output-error step (``refined`` not None).
    replicates : int
        B, at least 2.
    seed : int
        Seed of the replicates' noise.
    progress : callable, optional
        Receives one line when done.

    Returns
    -------
    Bootstrap
    """
    estimate = identification.parameters
    stick = [identification.records[name] for name in identification.refined.nrmse]
    rng = np.random.default_rng(seed)
    drives = [excitation_drive(record)[0] for record in stick]  # the same applied force in every replicate
    rows = []
    for _ in range(replicates):
        copies = [replicate(record, estimate, rng, drive) for record, drive in zip(stick, drives)]
        _, refined = refine(copies, estimate, None, screen=False)
        rows.append([math.log(getattr(refined, n)) for n in P3])
    logs = np.array(rows)
    centre = np.log([getattr(estimate, n) for n in P3])
    bias = logs.mean(axis=0) - centre
    half = scipy.stats.t.ppf(0.975, replicates - 1) * logs.std(axis=0, ddof=1) * math.sqrt(1.0 + 1.0 / replicates)
    # Widened by the bias, not shifted by it: B replicates leave the bias itself uncertain, and
    # shifting moved the interval off the truth where the estimate's own error had the other sign.
    lower = np.exp(centre - np.abs(bias) - half)
    upper = np.exp(centre + np.abs(bias) + half)
    noise = {
        r.name: (
            white_noise_level(r.sliding_velocity) / max(rms(r.sliding_velocity), 1e-300),
            white_noise_level(r.excitation_force) / max(rms(r.excitation_force), 1e-300),
        )
        for r in stick
    }
    if progress:
        progress(f"parametric bootstrap of the output-error step: {replicates} replicates of {len(stick)} records")
    return Bootstrap(
        P3,
        np.exp(logs),
        {n: float(v) for n, v in zip(P3, lower)},
        {n: float(v) for n, v in zip(P3, upper)},
        {n: float(math.expm1(b)) for n, b in zip(P3, bias)},
        noise,
        seed,
    )


def with_bootstrap(identification, replicates: int = REPLICATES, seed: int = 0, progress=None):
    """``identification`` with its bootstrap attached: its intervals become curvature ∪ bootstrap
    (``Identification.parameter_entries``); unchanged without an output-error step."""
    if identification.refined is None or replicates < 1:
        return identification
    return dataclasses.replace(identification, bootstrap=bootstrap(identification, replicates, seed, progress))


__all__ = ["REPLICATES", "Bootstrap", "bootstrap", "replicate", "white_noise_level", "with_bootstrap"]
