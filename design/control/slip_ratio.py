"""The slip-ratio law: a local law that holds each joint at the edge of sticking by steering how
much of the time it slips (issue 32: a local law designed on the physical spread).

A friction joint dissipates only while it slips (u_R·v), and dissipates most per cycle near the
normal force at which it just breaks loose: far above, it sticks and the truss rings as if
welded; far below, it slides at a friction force too small to take energy out. The paper's
SISO law (Eq. 30) switches F_N on the sign of the joint's power u_R·v; measured over the
physical spread it loses to a well-chosen constant preload (docs/control.md). This law instead
integrates the joint's slip: per joint j, at sample k, with v_k the measured sliding velocity::

    slipping_k = |v_k| > v*_j
    F_k = clip(F_k−1·(1 + Δt·r_rise),  F_N^min, F_N^max)      while slipping
    F_k = clip(F_k−1·(1 − Δt·r_decay), F_N^min, F_N^max)      while stuck
    F_0 = F_N^max                                            (reset: the joint locked)

F_N grows at the relative rate r_rise while the joint slips and relaxes at r_decay while it
sticks, so on average the joint slips the fraction r_decay/(r_rise + r_decay) of the time (to first
order in Δt·r),
whatever the level of force that takes: the law finds the break-away level of each joint on each
plant (of its LuGre parameters, its preload, the vibration's amplitude) and follows it as the
vibration decays. The change is relative (the explicit Euler step of dF/dt = ±r·F), so one rate
serves joints whose forces differ by decades; the product needs F_N^min > 0 (F = 0 would stay 0)
and Δt·r_decay < 1. The memory is the law's own last command, not the measured F_N (the
amplifier's lag and a held command during the excitation leave it unchanged).

It reads only its own joint's v (and the measured F_N, checked like every law's): a law for the
joint node (the paper's local concept, Section 5.1). An unusable input (NaN/±Inf, or outside its
plausible range) puts every joint at the safe normal force and holds the affected joint's memory;
the others go on integrating.

The slipratio entry of the law registry names this module: its Python reference
(:func:`slip_ratio_law`), the law the study runs (:func:`controller`), what its templates see
(:func:`context`) and the tuning of its settings on the nominal study (:func:`tuned`). Its
settings for the bundled designs were chosen on an ensemble of the physical spread
(``benchmarks/local_laws.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control.laws import (
    STATUS_OK,
    any_status,
    check_limits,
    input_status,
    magnitude_limit,
    measured_range,
    safe_force,
    safe_state_options,
)
from smartjoint.design.plant.interface import Measurements

LAW = law_registry.LAWS["slipratio"]


class SlipRatioLaw:
    """The slip-ratio law per joint (``reset()``, ``step(measurements) -> normal_forces``,
    ``sample_time``: ``interface.Controller``).

    Parameters
    ----------
    sample_time : float
        Δt [s].
    normal_force_min, normal_force_max : array_like
        F_N^min (> 0) and F_N^max per joint [N].
    velocity : float or array_like
        v*_j [m/s] (> 0): the sliding speed above which a joint counts as slipping.
    rise, decay : float
        r_rise and r_decay [1/s] (> 0; Δt·r_decay < 1): the relative rates of F_N while
        slipping and while stuck.

    Without the safety arguments: safe force F_N^max, no ranges beyond finiteness
    (:func:`slip_ratio_law` builds the law with the artefact's).
    """

    def __init__(
        self,
        sample_time: float,
        normal_force_min,
        normal_force_max,
        velocity,
        rise: float,
        decay: float,
        *,
        safe_normal_force=None,
        sliding_velocity_limit=None,
        friction_force_limit=None,
        measured_normal_force_min=None,
        measured_normal_force_max=None,
    ):
        del friction_force_limit  # the law reads no friction force
        self.sample_time = float(sample_time)
        self.normal_force_min = np.array(normal_force_min, dtype=float)
        self.normal_force_max = np.array(normal_force_max, dtype=float)
        check_limits(self.normal_force_min, self.normal_force_max)
        count = self.normal_force_min.size
        if np.any(self.normal_force_min <= 0):
            raise ModelError(
                f"normal_force_min: {self.normal_force_min.tolist()} — the slip-ratio law needs F_N^min > 0: "
                "its relative steps would hold F_N = 0 for ever"
            )
        self.velocity = np.array(np.broadcast_to(np.asarray(velocity, dtype=float), (count,)))
        if not np.all(np.isfinite(self.velocity)) or np.any(self.velocity <= 0):
            raise ModelError(f"slipratio_velocity: {self.velocity.tolist()} — v* must be finite and > 0 [m/s]")
        self.rise, self.decay = float(rise), float(decay)
        if not (math.isfinite(self.rise) and self.rise > 0):
            raise ModelError(f"slipratio_rise: {self.rise!r} — r_rise must be finite and > 0 [1/s]")
        if not (self.decay > 0 and self.sample_time * self.decay < 1):
            raise ModelError(
                f"slipratio_decay: {self.decay!r} — r_decay must be > 0 and below 1/Δt = "
                f"{1 / self.sample_time:.6g} 1/s (F_N would turn negative in one sample)"
            )
        # The C's arithmetic: the upper limit as F^min + (F^max − F^min), as its tables hold it.
        self.normal_force_high = self.normal_force_min + (self.normal_force_max - self.normal_force_min)
        self.safe_normal_force = safe_force(safe_normal_force, self.normal_force_min, self.normal_force_max)
        self.sliding_velocity_limit = magnitude_limit("sliding_velocity_limit", sliding_velocity_limit, count)
        self.measured_normal_force_min, self.measured_normal_force_max = measured_range(
            measured_normal_force_min, measured_normal_force_max, count
        )
        self.reset()

    def reset(self) -> None:
        self.command = self.normal_force_high.copy()  # F_0 = F_N^max: the joint locked
        self.status = STATUS_OK

    def step(self, measurements: Measurements) -> np.ndarray:
        velocity = np.asarray(measurements.sliding_velocity, dtype=float)
        applied = np.asarray(measurements.normal_force, dtype=float)
        joint_status = input_status(velocity, -self.sliding_velocity_limit, self.sliding_velocity_limit) | input_status(
            applied, self.measured_normal_force_min, self.measured_normal_force_max
        )
        usable = joint_status == STATUS_OK
        self.status = any_status(joint_status)
        # The same expressions, in the same order, as the C step (bit-identical in double).
        grow = 1.0 + self.sample_time * self.rise
        shrink = 1.0 - self.sample_time * self.decay
        with np.errstate(invalid="ignore"):
            slipping = np.abs(velocity) > self.velocity
        stepped = self.command * np.where(slipping, grow, shrink)
        clipped = np.where(
            stepped > self.normal_force_min,
            np.where(stepped < self.normal_force_high, stepped, self.normal_force_high),
            self.normal_force_min,
        )
        self.command = np.where(usable, clipped, self.command)  # an unusable input holds its joint's memory
        if self.status != STATUS_OK:
            return self.safe_normal_force.copy()
        return self.command.copy()


def slip_ratio_law(artifact) -> SlipRatioLaw:
    """The slip-ratio law's Python reference from a controller artefact alone, with its safe
    normal force and plausibility ranges (what the generated C checks).

    Parameters
    ----------
    artifact : ControllerArtifact

    Returns
    -------
    SlipRatioLaw
    """
    return SlipRatioLaw(
        artifact.sample_time,
        artifact.normal_force_min,
        artifact.normal_force_max,
        artifact.slipratio_velocity,
        artifact.slipratio_rise,
        artifact.slipratio_decay,
        sliding_velocity_limit=artifact.sliding_velocity_limit,
        **safe_state_options(artifact),
    )


def controller(setup, lqg, settings: dict) -> SlipRatioLaw:
    """The slip-ratio law the closed-loop study runs: its limits and the tuned settings."""
    del lqg
    return SlipRatioLaw(
        setup.sample_time,
        setup.normal_force_min,
        setup.normal_force_max,
        settings["velocity"],
        settings["rise"],
        settings["decay"],
    )


def context(artifact, lit, row) -> dict:
    """What the slip-ratio law's templates see beyond the common context."""
    return {
        "velocity": row(artifact.slipratio_velocity),
        "rise": lit(artifact.slipratio_rise),
        "decay": lit(artifact.slipratio_decay),
        "sliding_velocity_limit": row(artifact.sliding_velocity_limit),
    }


# The tuning on an ensemble of the design's physical spread (a design that gives no settings):
# a scan, then Nelder–Mead from its best point, of the mean E(t_e) over TUNING_PLANTS plants.
TUNING_PLANTS = 8
TUNING_SEED = 1  # the ensembles the law is judged on use other seeds (benchmarks/local_laws.py)
VELOCITY_FRACTIONS = (0.05, 0.15, 0.45)  # v* / the largest post-pulse |v| of the nominal plant at F_N^min
STEP_RATES = (0.03, 0.1)  # Δt·(r_rise + r_decay): the relative change of F_N per sample
SLIP_FRACTIONS = (0.15, 0.3)  # r_decay / (r_rise + r_decay): the mean fraction of time a joint slips
REFINEMENTS = 16  # Nelder–Mead evaluations after the scan


@dataclass
class SlipRatioTuning:
    """The slip-ratio settings chosen on an ensemble of the physical spread, and every evaluation."""

    velocity: float
    rise: float
    decay: float
    energy_measure: float  # the mean E(t_e) over the tuning plants
    plants: int
    seed: int
    evaluations: list[tuple[float, float, float, float]]  # (v*, r_rise, r_decay, mean E(t_e))

    setting = "velocity"  # the setting its value reports (``Law.settings``)

    @property
    def value(self) -> float:
        """v* [m/s]."""
        return self.velocity

    def figures(self) -> dict:
        """The chosen settings and their mean E(t_e), JSON-ready."""
        return {
            "velocity": self.velocity,
            "rise": self.rise,
            "decay": self.decay,
            "energy_measure_mean": self.energy_measure,
            "plants": self.plants,
            "seed": self.seed,
        }

    def summary(self) -> dict:
        """:meth:`figures` and every evaluation, JSON-ready."""
        return {**self.figures(), "evaluations": [list(e) for e in self.evaluations]}

    def describe(self) -> str:
        """One sentence of what the tuning found."""
        return (
            f"v* = {self.velocity:.3g} m/s, r_rise = {self.rise:.3g} 1/s, r_decay = {self.decay:.3g} 1/s minimise "
            f"the mean E(t_e) = {self.energy_measure:.4g} J·s over {self.plants} plants of the physical spread "
            f"(seed {self.seed}; {len(self.evaluations)} evaluations)"
        )


def settings_of(velocity: float, step_rate: float, slip: float, sample_time: float) -> tuple[float, float, float]:
    """(v*, r_rise, r_decay) from v*, Δt·(r_rise + r_decay) and the slip fraction."""
    rate = step_rate / sample_time
    return velocity, rate * (1.0 - slip), rate * slip


def optimise(design, setup, progress=print, plants: int = TUNING_PLANTS, seed: int = TUNING_SEED) -> SlipRatioTuning:
    """The slip-ratio settings minimising the mean E(t_e) of Eq. 32 over ``plants`` plants drawn
    from the design's physical spread: a scan of :data:`VELOCITY_FRACTIONS` × :data:`STEP_RATES` ×
    :data:`SLIP_FRACTIONS`, then Nelder–Mead (scipy) in log v*, log Δt·r and the logit of the slip
    fraction from the scan's best point. E is rough in the settings (stick/slip events move), so
    the mean over plants, not one trajectory, is minimised.

    Parameters
    ----------
    design : Design
        Its physical spread (``[uncertainty]``).
    setup : StudySetup
        The nominal study.
    progress : callable
        Receives one line per evaluation.
    plants, seed : int
        The tuning ensemble.

    Returns
    -------
    SlipRatioTuning
    """
    from scipy.optimize import minimize

    from smartjoint.design.control.ensemble import drawn_setups  # the study's loop and the spread
    from smartjoint.design.control.runs import run_passive, run_semi_active

    free = run_passive(setup, "passive F_min", setup.normal_force_min)
    after = free.time >= 0.2 * setup.duration  # past the pulse and its transient
    speed = float(np.max(np.abs(free.sliding_velocity[after]))) if np.any(after) else 0.0
    if not speed > 0:
        raise ModelError("slipratio_velocity: the joints never slide at F_N^min in the study — give it in [control]")
    ensemble = drawn_setups(design, setup, plants, seed)
    evaluations: list[tuple[float, float, float, float]] = []

    def mean_energy(velocity: float, step_rate: float, slip: float) -> float:
        chosen = settings_of(velocity, step_rate, slip, setup.sample_time)
        energies = [
            run_semi_active(
                s, LAW.display, SlipRatioLaw(s.sample_time, s.normal_force_min, s.normal_force_max, *chosen)
            ).energy_measure()
            for s in ensemble
        ]
        evaluations.append((*chosen, float(np.mean(energies))))
        progress(
            f"      v* = {chosen[0]:.3g} m/s, r_rise = {chosen[1]:.3g} 1/s, r_decay = {chosen[2]:.3g} 1/s: "
            f"mean E(t_e) = {evaluations[-1][3]:.5g} J·s over {plants} plants"
        )
        return evaluations[-1][3]

    scanned = [
        ((fraction * speed, rate, slip), mean_energy(fraction * speed, rate, slip))
        for fraction in VELOCITY_FRACTIONS
        for rate in STEP_RATES
        for slip in SLIP_FRACTIONS
    ]
    start = min(scanned, key=lambda point: point[1])[0]

    def objective(x: np.ndarray) -> float:
        step_rate = min(math.exp(x[1]), 0.5)  # Δt·r_decay < 1 with room
        return mean_energy(math.exp(x[0]), step_rate, 1.0 / (1.0 + math.exp(-x[2])))

    x0 = np.array([math.log(start[0]), math.log(start[1]), math.log(start[2] / (1.0 - start[2]))])
    minimize(objective, x0, method="Nelder-Mead", options={"maxfev": REFINEMENTS})
    best = min(evaluations, key=lambda e: e[3])
    return SlipRatioTuning(*best, plants, seed, evaluations)


def tuned(design, settings: dict, setup, progress) -> tuple[dict, SlipRatioTuning | None]:
    """The settings from the design file, else (with a study to run) those minimising the mean
    E(t_e) over an ensemble of the design's physical spread (:func:`optimise`).

    Parameters
    ----------
    design : Design
    settings : dict
        The law's settings from the design file and defaults (None: open).
    setup : StudySetup or None
        The nominal study; None leaves open settings open.
    progress : callable

    Returns
    -------
    dict, SlipRatioTuning or None
        The settings, and the tuning (None when the design file gave them all).
    """
    if all(value is not None for value in settings.values()) or setup is None:
        return settings, None
    progress(
        f"      {LAW.display} law: v*, r_rise, r_decay for the mean E(t_e) of Eq. 32 over {TUNING_PLANTS} plants "
        "of the physical spread …"
    )
    found = optimise(design, setup, progress)
    chosen = {"velocity": np.full(len(design.joints), found.velocity), "rise": found.rise, "decay": found.decay}
    return {key: chosen[key] if value is None else value for key, value in settings.items()}, found


__all__ = [
    "LAW",
    "SlipRatioLaw",
    "SlipRatioTuning",
    "context",
    "controller",
    "optimise",
    "settings_of",
    "slip_ratio_law",
    "tuned",
]
