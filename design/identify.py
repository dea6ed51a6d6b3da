"""Two-step LuGre identification from friction records (paper Eq. 3, Section 3.2).

The model force û_R(t_k) is simulated from the measured sliding velocity and normal force
(Eq. 2 with Eq. 1 integrated by the exact-exponential step of ``lugre.py`` at the midpoint
velocity) and compared with the measured friction force::

    min_p  J(p) = ½ Σ_records Σ_k [(u_R(t_k) − û_R(v(t_k), F_N, p)) / (rms_r·√N_r)]²     (Eq. 3)

Each record is normalised by its RMS force and length so that every record counts alike.
As in the paper the problem is split in two:

1. p1 = [σ0, σ1] from micro-slip records (p2 held fixed),
2. p2 = [F_c, F_d, v_s, σ2] from stick-slip records (p1 held fixed),

and — because step 1 depends on the rough start of p2 — both steps run a second round from
the first round's results. Each fit is in log parameters with bounds
(``scipy.optimize.least_squares``); the starts are a small grid screened by cost, the best
few polished.

Uncertainty: the covariance s²·(JᵀJ)⁻¹ at the optimum with the residual variance s² inflated
by (1 + ρ)/(1 − ρ), ρ the lag-1 autocorrelation of the residuals (effective instead of nominal
sample count); 95 % intervals exp(θ ± 1.96σ_θ) and the correlation matrix. A parameter whose
interval is wider than ±50 % of its value is reported weakly identifiable.

Experiment design matters more than the solver. LuGre's g(v) treats any |v| as sliding, so
the Stribeck parameters are only seen in samples that slide at velocities of a few v_s, and
velocity noise comparable to v_s hides them. ``rig`` campaigns therefore choose the moving
inertia so that stick-slip records slide at about 5·v_s (docs/identification.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.optimize
from scipy.signal import butter, sosfiltfilt

from . import lugre
from .records import Record, RecordError

P1 = ("sigma0", "sigma1")
P2 = ("coulomb", "stribeck", "stribeck_velocity", "sigma2")
ROUNDS = 2
WEAK_RELATIVE_WIDTH = 0.5  # 95 % interval wider than ±50 % of the value: weakly identifiable


def filtered_velocity(record: Record, cutoff_hz: float | None = None) -> np.ndarray:
    """Zero-phase low-pass of the measured velocity (default cutoff: 25× the dominant frequency)."""
    v = record.sliding_velocity
    fs = 1.0 / record.sample_time
    if cutoff_hz is None:
        spectrum = np.abs(np.fft.rfft(v - v.mean()))
        frequencies = np.fft.rfftfreq(v.size, 1.0 / fs)
        dominant = frequencies[1:][np.argmax(spectrum[1:])]
        cutoff_hz = 25.0 * dominant
    if cutoff_hz >= 0.45 * fs:
        return v
    sos = butter(4, cutoff_hz, fs=fs, output="sos")
    return sosfiltfilt(sos, v)


def simulate_friction(p: lugre.LuGreParameters, time, velocity, normal_force, initial_force: float = 0.0):
    """û_R at the sample times for a measured velocity (midpoint exact-exponential step).

    The same step as ``lugre.step`` and ``lugre.friction_coefficient``, written out on Python
    floats: the fit calls this for every sample thousands of times, and numpy's per-call
    overhead on scalars would cost about 10×.
    """
    s0, s1, s2 = p.sigma0, p.sigma1, p.sigma2
    fc, fd, vs = p.coulomb, p.stribeck, p.stribeck_velocity
    arm = p.moment_arm
    out = np.empty(len(time))
    bound = p.max_deflection
    phi = min(max(initial_force / (arm * normal_force[0] * s0), -bound), bound)  # consistent start
    previous_v = float(velocity[0])
    for k in range(len(time)):
        v = float(velocity[k])
        if k:
            dt = float(time[k] - time[k - 1])
            mid = 0.5 * (v + previous_v)
            level = fc + fd * math.exp(-(mid / vs) ** 2)
            rate = s0 * abs(mid) / level
            if rate > 0.0:
                target = math.copysign(level / s0, mid)
                phi = phi + (target - phi) * -math.expm1(-rate * dt)
        level = fc + fd * math.exp(-(v / vs) ** 2)
        phidot = v - s0 * abs(v) / level * phi
        out[k] = arm * float(normal_force[k]) * (s0 * phi + s1 * phidot + s2 * v)
        previous_v = v
    return out


def nrmse(measured, model) -> float:
    """‖u − û‖_rms / ‖u‖_rms."""
    return float(np.sqrt(np.mean((measured - model) ** 2)) / np.sqrt(np.mean(measured**2)))


@dataclass
class StepResult:
    names: tuple[str, ...]
    values: np.ndarray
    lower: np.ndarray  # 95 % interval
    upper: np.ndarray
    correlation: np.ndarray
    nrmse: dict[str, float]
    cost: float
    evaluations: int

    @property
    def weak(self) -> list[str]:
        width = (self.upper - self.lower) / (2.0 * self.values)
        return [n for n, w in zip(self.names, width) if not w <= WEAK_RELATIVE_WIDTH]


@dataclass
class Identification:
    parameters: lugre.LuGreParameters
    joint_type: str
    micro: StepResult
    stick: StepResult
    records: dict[str, Record] = field(default_factory=dict)
    filtered: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def weakly_identifiable(self) -> list[str]:
        return self.micro.weak + self.stick.weak

    def as_dict(self) -> dict:
        out = {"joint_type": self.joint_type, "parameters": {}, "nrmse": {**self.micro.nrmse, **self.stick.nrmse},
               "weakly_identifiable": self.weakly_identifiable, "correlation": {}}
        for step, result in (("p1", self.micro), ("p2", self.stick)):
            for k, name in enumerate(result.names):
                out["parameters"][name] = {"value": float(result.values[k]), "ci95": [float(result.lower[k]),
                                                                                       float(result.upper[k])],
                                           "step": step}
            out["correlation"][step] = {"names": list(result.names), "matrix": result.correlation.tolist()}
        if self.parameters.radius is not None:
            out["parameters"]["radius"] = {"value": self.parameters.radius, "ci95": None, "step": "given"}
        return out


def _initial_guess(micro: list[Record], stick: list[Record], radius: float | None, velocities) -> dict[str, float]:
    arm = radius if radius is not None else 1.0
    mu = np.concatenate([r.friction_force / (arm * r.normal_force) for r in stick])
    v = np.concatenate([velocities[r.name] for r in stick])
    sliding = np.abs(v) > 0.3 * np.abs(v).max()
    coulomb = float(np.median(np.abs(mu[sliding])))
    peak = float(np.percentile(np.abs(mu), 99.5))
    stribeck = max(peak - coulomb, 0.05 * coulomb)
    # Presliding: μ grows like σ0·x with x = ∫v dt; the slope of μ over x gives σ0.
    slopes = []
    for r in micro:
        x = np.concatenate([[0.0], np.cumsum(0.5 * (velocities[r.name][1:] + velocities[r.name][:-1]) * np.diff(r.time))])
        m = r.friction_force / (arm * r.normal_force)
        small = np.abs(m) < 0.5 * np.abs(m).max()
        slopes.append(np.polyfit(x[small] - x[small].mean(), m[small], 1)[0])
    sigma0 = float(np.median(slopes)) if slopes else 1e5
    return {"sigma0": max(sigma0, 1.0), "sigma1": 1e-4 * math.sqrt(max(sigma0, 1.0)), "sigma2": 1e-3 * coulomb,
            "coulomb": coulomb, "stribeck": stribeck,
            "stribeck_velocity": float(0.05 * np.median(np.abs(v[sliding])))}


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.asarray(x) ** 2)))


def model_friction(p: lugre.LuGreParameters, record: Record, velocity) -> np.ndarray:
    """û_R of Eq. 3 for a record, from the (possibly filtered) measured ``velocity``."""
    return simulate_friction(p, record.time, velocity, record.normal_force, record.friction_force[0])


def _fit(records, names, fixed: dict[str, float], starts: list[dict[str, float]], radius, velocities, progress, label,
         polish: int = 2):
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
            parts.append((friction - r.friction_force) / (_rms(r.friction_force) * n))
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
        solution = scipy.optimize.least_squares(residual, theta0, bounds=bounds, x_scale=1.0, diff_step=1e-6,
                                                xtol=1e-10, ftol=1e-12, max_nfev=200)
        evaluations += solution.nfev
        if best is None or solution.cost < best.cost:
            best = solution
        if progress:
            progress(f"{label}: start {k + 1}/{len(starts)}, cost {best.cost:.4g}")
    J = best.jac
    dof = max(best.fun.size - len(names), 1)
    # Residuals of neighbouring samples are correlated (smooth signals, filtered inputs):
    # inflate the variance by (1 + ρ)/(1 − ρ), ρ the lag-1 autocorrelation, i.e. count
    # effective rather than nominal samples.
    e = best.fun - best.fun.mean()
    rho = float(np.clip(np.dot(e[1:], e[:-1]) / max(np.dot(e, e), 1e-300), 0.0, 0.999))
    variance = 2.0 * best.cost / dof * (1.0 + rho) / (1.0 - rho)
    covariance = variance * np.linalg.pinv(J.T @ J)
    sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    correlation = covariance / np.outer(np.maximum(sigma, 1e-300), np.maximum(sigma, 1e-300))
    p = parameters(best.x)
    values = np.exp(best.x)
    errors = {r.name: nrmse(r.friction_force, model_friction(p, r, velocities[r.name])) for r in records}
    result = StepResult(tuple(names), values, np.exp(np.clip(best.x - 1.96 * sigma, -700, 700)),
                        np.exp(np.clip(best.x + 1.96 * sigma, -700, 700)),
                        correlation, errors, float(best.cost), evaluations)
    return result, p


def identify(micro: list[Record], stick: list[Record], radius: float | None = None, progress=None,
             cutoff_hz: float | None = None) -> Identification:
    """Two-step identification of Eq. 3 from micro-slip and stick-slip records."""
    if not micro:
        raise RecordError("identify: no micro-slip records (step 1 needs at least one)")
    if not stick:
        raise RecordError("identify: no stick-slip records (step 2 needs at least one)")
    types = {r.joint_type for r in micro + stick}
    if len(types) != 1:
        raise RecordError(f"identify: records mix joint types {sorted(types)}")
    joint_type = types.pop()
    if joint_type == "B" and radius is None:
        radius = lugre.TYPE_B.radius
    names = [r.name for r in micro + stick]
    if len(set(names)) != len(names):
        raise RecordError("identify: two records share a name; rename the files")
    # The raw velocity unless a cutoff is given: a low-pass also cuts the bristle resonance
    # that the measured force contains, which biases the fit more than the noise does.
    velocities = {r.name: (filtered_velocity(r, cutoff_hz) if cutoff_hz else r.sliding_velocity) for r in micro + stick}
    for r in stick:
        if not slides(r, radius):
            raise RecordError(f"{r.name}: column 'sliding_velocity' shows no gross slip — a stick-slip record must "
                              "slide (step 2 identifies F_c, F_d, v_s, σ2 from sliding)")
    guess = _initial_guess(micro, stick, radius, velocities)
    velocity_scale = max(float(np.abs(r.sliding_velocity).max()) for r in stick)
    p2 = {n: guess[n] for n in P2}
    p1_starts = [{**guess, "sigma0": guess["sigma0"] * a, "sigma1": guess["sigma1"] * b}
                 for a in (0.5, 1.0, 2.0) for b in (1e-2, 1.0, 1e2)]
    p2_starts = [{**p2, "stribeck": fraction * p2["coulomb"], "stribeck_velocity": factor * velocity_scale}
                 for fraction in (0.1, 0.25, 0.5) for factor in (1e-2, 3e-2, 0.1, 0.3)]
    for round_number in range(1, ROUNDS + 1):
        micro_result, _ = _fit(micro, P1, p2, p1_starts, radius, velocities, progress,
                               f"round {round_number}, step 1 (σ0, σ1, micro-slip)")
        p1 = dict(zip(P1, micro_result.values.tolist()))
        # The last round lets σ1 float in step 2 too: stick-slip onsets (large φ̇) constrain it
        # better than presliding does, and a σ1 left wrong by step 1 biases v_s.
        names = P2 + ("sigma1",) if round_number == ROUNDS else P2
        fixed = {n: v for n, v in p1.items() if n not in names}
        starts = [{**start, "sigma1": p1["sigma1"]} for start in p2_starts]
        stick_result, parameters = _fit(stick, names, fixed, starts, radius, velocities, progress,
                                        f"round {round_number}, step 2 ({', '.join(names)}, stick-slip)")
        p2 = {n: v for n, v in zip(names, stick_result.values.tolist()) if n in P2}
        p1_starts = [p1] + [{**p1, "sigma1": p1["sigma1"] * b} for b in (1e-3, 1e-1, 10.0)]
        p2_starts = [p2]
    micro_result.nrmse = {r.name: nrmse(r.friction_force, model_friction(parameters, r, velocities[r.name]))
                          for r in micro}
    return Identification(parameters, joint_type, micro_result, stick_result,
                          {r.name: r for r in micro + stick}, velocities)


def slides(record: Record, radius: float | None = None) -> bool:
    """Gross sliding: the element moves by far more than any bristle deflection μ/σ0 could."""
    arm = radius if radius is not None else (lugre.TYPE_B.radius if record.joint_type == "B" else 1.0)
    mu = np.abs(record.friction_force / (arm * record.normal_force))
    displacement = np.ptp(np.cumsum(record.sliding_velocity) * record.sample_time)
    return bool(displacement * 1e4 > mu.max() and displacement > 1e-4)


def classify(record: Record, radius: float | None = None) -> str:
    """'stick-slip' or 'micro-slip': the record's ``regime`` metadata, else whether it slides."""
    if "regime" in record.metadata:
        return record.metadata["regime"]
    return "stick-slip" if slides(record, radius) else "micro-slip"


__all__ = ["Identification", "classify", "slides", "identify", "model_friction", "nrmse", "simulate_friction"]
