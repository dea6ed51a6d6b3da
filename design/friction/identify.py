"""LuGre identification from friction records: paper Eq. 3 (Section 3.2), then output error.

The model force û_R(t_k) is simulated from the measured sliding velocity and normal force
(Eq. 2 with Eq. 1 integrated by the exact-exponential step of ``lugre.py`` at the midpoint
velocity) and compared with the measured friction force::

    min_p  J(p) = ½ Σ_records Σ_k [(u_R(t_k) − û_R(v(t_k), F_N, p)) / (rms_r·√N_r)]²     (Eq. 3)

Each record is normalised by its RMS force and length so that every record counts alike. The records
are screened first (``record_screening``: usable samples, one joint's radius, a friction
coefficient μ ≤ 2, the regime); a record that fails is refused in one line, never dropped.
As in the paper the problem is split in two:

1. p1 = [σ0, σ1] from micro-slip records (p2 held fixed),
2. p2 = [F_c, F_d, v_s, σ2] from stick-slip records (p1 held fixed),

and — because step 1 depends on the rough start of p2 — both steps run a second round from
the first round's results. Each fit is in log parameters with bounds
(``scipy.optimize.least_squares``); the starts are a small grid screened by cost, the best
few polished.

Eq. 3 takes the measured velocity as the model's input, so velocity noise is input noise: it
relaxes the simulated bristles during sticking and biases F_d (errors-in-variables; type A
+5.6 % at 1 % noise). When the stick-slip records carry the excitation force and the inertia
(rig records do), a third step refines all six parameters by output error: the rig model
m·v̇ = F_exc − r·F_N·μ(v, φ) with Eq. 1, driven by the measured excitation force
(``rig_kernel.c``, 8 implicit trapezoidal substeps per sample), fitted to the measured
velocity segment by segment (``output_error``).

Uncertainty: for the Eq. 3 steps the covariance s²·(JᵀJ)⁻¹ at the optimum with the residual
variance s² inflated by (1 + ρ)/(1 − ρ), ρ the lag-1 autocorrelation of the residuals
(effective instead of nominal sample count); for the output-error step the cluster-robust
(sandwich) covariance with one cluster per segment. 95 % intervals exp(θ ± 1.96σ_θ) and the
correlation matrix. A parameter whose interval is wider than ±50 % of its value is reported
weakly identifiable.

Experiment design matters more than the solver. LuGre's g(v) treats any |v| as sliding, so
the Stribeck parameters are only seen in samples that slide at velocities of a few v_s, and
velocity noise comparable to v_s hides them. ``rig`` campaigns therefore choose the moving
inertia so that stick-slip records slide at about 5·v_s (docs/identification.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.optimize

from smartjoint.common.errors import SmartjointError
from smartjoint.design.friction import lugre
from smartjoint.design.friction.equation_error import model_friction
from smartjoint.design.friction.fitting import (
    StepResult,
    filtered_velocity,
    nrmse,
    rms,
    smoothed_friction,
    step_result,
)
from smartjoint.design.friction.identifiability import not_identified
from smartjoint.design.friction.output_error import P3, output_error_blocker, refine
from smartjoint.design.friction.record_screening import check_records, joint_radius, slides
from smartjoint.design.friction.records import Record, RecordError

P1 = ("sigma0", "sigma1")
P2 = ("coulomb", "stribeck", "stribeck_velocity", "sigma2")
ROUNDS = 2


@dataclass
class Identification:
    """The identified parameters and every step's result.

    ``micro.nrmse`` and ``stick.nrmse`` are the Eq. 3 friction NRMSE of the final parameters;
    ``refined`` is the output-error step (None when it did not run: ``steps`` says why).
    """

    parameters: lugre.LuGreParameters
    joint_type: str
    micro: StepResult
    stick: StepResult
    records: dict[str, Record] = field(default_factory=dict)
    filtered: dict[str, np.ndarray] = field(default_factory=dict)
    refined: StepResult | None = None
    steps: list[str] = field(default_factory=list)
    bootstrap: Any = None  # bootstrap.Bootstrap of the output-error step (bootstrap imports this module's callers)
    # The relative 95 % half width a parameter must reach to be reported (a campaign's target,
    # ``sequential_campaign``); the rest is held to ``fitting.WEAK_RELATIVE_WIDTH`` alone.
    accuracy: dict[str, float] = field(default_factory=dict)

    @property
    def weakly_identifiable(self) -> list[str]:
        if self.refined is not None:
            return self.refined.weak
        return self.weak_by_equation_error

    @property
    def weak_by_equation_error(self) -> list[str]:
        """Weakly identifiable by the two Eq. 3 steps alone (the paper's method)."""
        return list(dict.fromkeys(self.micro.weak + self.stick.weak))

    @property
    def not_identified(self) -> dict[str, str]:
        """The parameters the records do not determine, each with why (``identifiability``)."""
        return not_identified(self)

    def parameter_entries(self) -> dict[str, dict]:
        """Per parameter its value, 95 % interval and the step that set it (the last one wins)."""
        results = [("p1", self.micro), ("p2", self.stick)]
        if self.refined is not None:
            results.append(("output error", self.refined))
        out: dict[str, dict] = {}
        for step, result in results:
            for k, name in enumerate(result.names):
                out[name] = {
                    "value": float(result.values[k]),
                    "ci95": [float(result.lower[k]), float(result.upper[k])],
                    "step": step,
                }
        if self.bootstrap is not None:  # the reported interval: curvature ∪ bootstrap
            for name in self.bootstrap.names:
                lower, upper = out[name]["ci95"]
                out[name]["ci95_curvature"] = [lower, upper]
                out[name]["ci95"] = [min(lower, self.bootstrap.lower[name]), max(upper, self.bootstrap.upper[name])]
        if self.parameters.radius is not None:
            out["radius"] = {"value": self.parameters.radius, "ci95": None, "step": "given"}
        return out

    def as_dict(self) -> dict:
        missing = self.not_identified
        out: dict = {
            "joint_type": self.joint_type,
            "parameters": {
                name: entry | {"identified": name not in missing} for name, entry in self.parameter_entries().items()
            },
            "not_identified": missing,
            "nrmse": {**self.micro.nrmse, **self.stick.nrmse},
            "weakly_identifiable": self.weakly_identifiable,
            "correlation": {},
            "steps": list(self.steps),
            "bootstrap": None if self.bootstrap is None else self.bootstrap.as_dict(),
            "accuracy": dict(self.accuracy),
        }
        results = [("p1", self.micro), ("p2", self.stick)]
        if self.refined is not None:
            results.append(("output error", self.refined))
            out["velocity_nrmse"] = dict(self.refined.nrmse)
        for step, result in results:
            out["correlation"][step] = {"names": list(result.names), "matrix": result.correlation.tolist()}
        return out


def _initial_guess(
    micro: list[Record], stick: list[Record], radius: float | None, velocities, joint_type: str
) -> dict[str, float]:
    arm = radius if radius is not None else 1.0
    mu = np.concatenate([smoothed_friction(r) / (arm * r.normal_force) for r in stick])
    v = np.concatenate([velocities[r.name] for r in stick])
    sliding = np.abs(v) > 0.3 * np.abs(v).max()
    coulomb = float(np.median(np.abs(mu[sliding])))
    if not coulomb > 0.0:
        raise RecordError(
            f"identify: stick-slip records {', '.join(r.name for r in stick)}: column 'friction_force' "
            "is zero while sliding — step 2 needs a Coulomb level F_c > 0"
        )
    peak = float(np.percentile(np.abs(mu), 99.5))
    # Only a start: kept within F_s ≤ 4·F_c, far beyond any contact's Stribeck peak.
    stribeck = min(max(peak - coulomb, 0.05 * coulomb), 3.0 * coulomb)
    # Presliding: μ grows like σ0·x with x = ∫v dt; the slope of μ over x gives σ0.
    slopes = []
    for r in micro:
        x = np.concatenate(
            [[0.0], np.cumsum(0.5 * (velocities[r.name][1:] + velocities[r.name][:-1]) * np.diff(r.time))]
        )
        m = r.friction_force / (arm * r.normal_force)
        small = np.abs(m) < 0.5 * np.abs(m).max()
        span = float(np.ptp(x[small])) if np.count_nonzero(small) >= 3 else 0.0
        if span > 0.0 and np.all(np.isfinite(m[small])):
            # x scaled to [−½, ½]: well conditioned whatever the displacement's magnitude
            with np.errstate(all="ignore"):
                slope = np.polyfit((x[small] - x[small].mean()) / span, m[small], 1)[0] / span
            if math.isfinite(slope) and slope > 0.0:
                slopes.append(slope)
    if not slopes:
        raise RecordError(
            f"identify: micro-slip records {', '.join(r.name for r in micro)}: the friction does not "
            "grow with the displacement (no presliding) — step 1 needs records whose friction force "
            "follows the displacement below break-away"
        )
    sigma0 = float(np.median(slopes))
    guess = {
        "sigma0": max(sigma0, 1.0),
        "sigma1": 1e-4 * math.sqrt(max(sigma0, 1.0)),
        "sigma2": 1e-3 * coulomb,
        "coulomb": coulomb,
        "stribeck": stribeck,
        "stribeck_velocity": float(0.05 * np.median(np.abs(v[sliding]))),
    }
    _check_plausible(guess, joint_type, "start")
    return guess


def _check_plausible(values: dict[str, float], joint_type: str, stage: str) -> None:
    """``RecordError`` when a start or result leaves the plausible range (``lugre.PLAUSIBLE``):
    the records then do not determine the parameters (e.g. a velocity of 1e-300 m/s)."""
    for name, value in values.items():
        lower, upper, _ = lugre.PLAUSIBLE[name][0 if joint_type == "A" else 1]
        if not (math.isfinite(value) and lower < value <= upper):
            raise RecordError(
                f"identify: the records give {name} = {value:.6g} as {stage} — plausible: > {lower:g} "
                f"and <= {upper:g}; the records do not determine the LuGre parameters"
            )


def _fit(
    records,
    names,
    fixed: dict[str, float],
    starts: list[dict[str, float]],
    radius,
    velocities,
    progress,
    label,
    polish: int = 2,
):
    count = [np.sqrt(r.time.size) for r in records]

    def parameters(theta):
        values = dict(fixed)
        values.update({n: float(math.exp(t)) for n, t in zip(names, theta)})
        return lugre.LuGreParameters(radius=radius, **values)

    def residual(theta):
        p = parameters(theta)
        parts = []
        for r, n in zip(records, count):
            friction = model_friction(p, r, velocities[r.name])
            parts.append((friction - r.friction_force) / (rms(r.friction_force) * n))
        return np.concatenate(parts)

    evaluations = 0
    if len(starts) > polish:
        # The objective has local minima (mostly in v_s): screen all candidate starts by their
        # cost and polish only the best few.
        costs = []
        for start in starts:
            costs.append(float(np.sum(residual(np.log([start[n] for n in names])) ** 2)))
            evaluations += 1
        starts = [starts[i] for i in np.argsort(costs)[:polish]]
    best = None
    for k, start in enumerate(starts):
        theta0 = np.log([start[n] for n in names])
        bounds = (theta0 - math.log(1e3), theta0 + math.log(1e3))
        solution = scipy.optimize.least_squares(
            residual, theta0, bounds=bounds, x_scale=1.0, diff_step=1e-6, xtol=1e-10, ftol=1e-12, max_nfev=200
        )
        evaluations += solution.nfev
        if best is None or solution.cost < best.cost:
            best = solution
        if progress:
            progress(f"{label}: start {k + 1}/{len(starts)}, cost {best.cost:.4g}")
    assert best is not None  # every caller passes at least one start
    p = parameters(best.x)
    errors = {r.name: nrmse(r.friction_force, model_friction(p, r, velocities[r.name])) for r in records}
    return step_result(names, best, errors, evaluations), p


def identify(
    micro: list[Record],
    stick: list[Record],
    radius: float | None = None,
    progress=None,
    cutoff_hz: float | None = None,
    output_error: bool = True,
    previous: lugre.LuGreParameters | None = None,
) -> Identification:
    """Two-step identification of Eq. 3 from micro-slip and stick-slip records, then the
    output-error step (`output_error.refine`) when every stick-slip record has its excitation force and
    inertia and ``output_error`` is on; ``Identification.steps`` lists what ran.

    Type B records need their radius (``radius``, or ``Record.radius`` of every record).
    Records the fit cannot use raise ``RecordError``; so does a numerical failure inside the fit
    (degenerate data that passed the checks), as one line instead of a traceback.

    Parameters
    ----------
    micro, stick : list of Record
        Micro-slip records (step 1: σ0, σ1) and stick-slip records (step 2: F_c, F_d, v_s, σ2).
    radius : float, optional
        [m] of type B records that do not carry one.
    progress : callable, optional
        Receives one line per start and step.
    cutoff_hz : float, optional
        Low-pass the measured velocity at this cutoff before Eq. 3 (default: the raw velocity).
    output_error : bool
        Run the output-error step where the records allow it.
    previous : LuGreParameters, optional
        An earlier estimate of the same joint (the round before, in a sequential campaign): one
        more start of the output-error step, which then converges in a few iterations.

    Returns
    -------
    Identification
        The parameters and every step's result.

    Raises
    ------
    RecordError
        For records the fit cannot use, or a fit that fails numerically.
    """
    if not micro:
        raise RecordError("identify: no micro-slip records (step 1 needs at least one)")
    if not stick:
        raise RecordError("identify: no stick-slip records (step 2 needs at least one)")
    types = {r.joint_type for r in micro + stick}
    if len(types) != 1:
        raise RecordError(f"identify: records mix joint types {sorted(types)}")
    joint_type = types.pop()
    radius = joint_radius(micro + stick, joint_type, radius)
    names = [r.name for r in micro + stick]
    if len(set(names)) != len(names):
        raise RecordError("identify: two records share a name; rename the files")
    check_records(micro + stick, radius)
    try:
        with np.errstate(all="ignore"):
            return _identify(micro, stick, joint_type, radius, progress, cutoff_hz, output_error, previous)
    except SmartjointError:
        raise
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as error:
        detail = " ".join(str(error).split())[:160]
        raise RecordError(
            f"identify: the fit failed on records {', '.join(names)} ({type(error).__name__}: {detail}) "
            "— they do not determine the LuGre parameters (micro-slip records must show presliding, "
            "stick-slip records must slide)"
        ) from None


def _identify(micro, stick, joint_type, radius, progress, cutoff_hz, output_error, previous) -> Identification:
    # The raw velocity unless a cutoff is given: a low-pass also cuts the bristle resonance
    # that the measured force contains, which biases the fit more than the noise does.
    velocities = {r.name: (filtered_velocity(r, cutoff_hz) if cutoff_hz else r.sliding_velocity) for r in micro + stick}
    for r in stick:
        if not slides(r, radius):
            raise RecordError(
                f"{r.name}: column 'sliding_velocity' shows no gross slip — a stick-slip record must "
                "slide (step 2 identifies F_c, F_d, v_s, σ2 from sliding)"
            )
    guess = _initial_guess(micro, stick, radius, velocities, joint_type)
    velocity_scale = max(float(np.abs(r.sliding_velocity).max()) for r in stick)
    p2 = {n: guess[n] for n in P2}
    p1_starts = [
        {**guess, "sigma0": guess["sigma0"] * a, "sigma1": guess["sigma1"] * b}
        for a in (0.5, 1.0, 2.0)
        for b in (1e-2, 1.0, 1e2)
    ]
    p2_starts = [
        {**p2, "stribeck": fraction * p2["coulomb"], "stribeck_velocity": factor * velocity_scale}
        for fraction in (0.1, 0.25, 0.5)
        for factor in (1e-2, 3e-2, 0.1, 0.3)
    ]
    for round_number in range(1, ROUNDS + 1):
        micro_result, _ = _fit(
            micro, P1, p2, p1_starts, radius, velocities, progress, f"round {round_number}, step 1 (σ0, σ1, micro-slip)"
        )
        p1 = dict(zip(P1, micro_result.values.tolist()))
        # The last round lets σ1 float in step 2 too: stick-slip onsets (large φ̇) constrain it
        # better than presliding does, and a σ1 left wrong by step 1 biases v_s.
        names = P2 + ("sigma1",) if round_number == ROUNDS else P2
        fixed = {n: v for n, v in p1.items() if n not in names}
        starts = [{**start, "sigma1": p1["sigma1"]} for start in p2_starts]
        stick_result, parameters = _fit(
            stick,
            names,
            fixed,
            starts,
            radius,
            velocities,
            progress,
            f"round {round_number}, step 2 ({', '.join(names)}, stick-slip)",
        )
        p2 = {n: v for n, v in zip(names, stick_result.values.tolist()) if n in P2}
        p1_starts = [p1] + [{**p1, "sigma1": p1["sigma1"] * b} for b in (1e-3, 1e-1, 10.0)]
        p2_starts = [p2]
    steps = [
        f"equation error (Eq. 3), {ROUNDS} rounds: step 1 σ0, σ1 on {len(micro)} micro-slip records, step 2 "
        f"F_c, F_d, v_s, σ2, σ1 on {len(stick)} stick-slip records"
    ]
    refined = None
    blocker = output_error_blocker(stick, output_error)
    if blocker is None:
        refined, parameters = refine(stick, parameters, progress, previous)
        steps.append(
            f"output error (rig model driven by the excitation force): σ0, σ1, σ2, F_c, F_d, v_s on "
            f"{len(stick)} stick-slip records"
        )
    else:
        steps.append(f"output error: skipped — {blocker}")
        if progress:
            progress(steps[-1])
    _check_plausible({n: getattr(parameters, n) for n in P3}, joint_type, "result")
    for result, records in ((micro_result, micro), (stick_result, stick)):
        result.nrmse = {
            r.name: nrmse(r.friction_force, model_friction(parameters, r, velocities[r.name])) for r in records
        }
    return Identification(
        parameters,
        joint_type,
        micro_result,
        stick_result,
        {r.name: r for r in micro + stick},
        velocities,
        refined,
        steps,
    )


__all__ = ["Identification", "identify"]
