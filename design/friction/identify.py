"""LuGre identification from friction records: paper Eq. 3 (Section 3.2), then output error.

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

Eq. 3 takes the measured velocity as the model's input, so velocity noise is input noise: it
relaxes the simulated bristles during sticking and biases F_d (errors-in-variables; type A
+5.6 % at 1 % noise). When the stick-slip records carry the excitation force and the inertia
(rig records do), a third step refines all six parameters by output error: the rig model
m·v̇ = F_exc − r·F_N·μ(v, φ) with Eq. 1, driven by the measured excitation force
(``rig_kernel.c``, 8 implicit trapezoidal substeps per sample), fitted to the measured
velocity segment by segment (``_refine``, ``shoot``).

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

import numpy as np
import scipy.optimize
from scipy.signal import butter, find_peaks, savgol_filter, sosfiltfilt

from smartjoint.design.friction import lugre, rig
from smartjoint.common.errors import ModelError, SmartjointError
from smartjoint.design.friction.records import MIN_RADIUS, Record, RecordError, bound

P1 = ("sigma0", "sigma1")
P2 = ("coulomb", "stribeck", "stribeck_velocity", "sigma2")
P3 = ("sigma0", "sigma1", "sigma2", "coulomb", "stribeck", "stribeck_velocity")  # output error: all six
ROUNDS = 2
WEAK_RELATIVE_WIDTH = 0.5  # 95 % interval wider than ±50 % of the value: weakly identifiable
# Low-pass of the measured excitation force that drives the output-error model, in multiples
# of the excitation frequency: keeps the 4th harmonic, removes the sensor noise at the bristle
# resonance (20–40× the excitation frequency on the rig).
EXCITATION_CUTOFF = 5.0
VELOCITY_CUTOFF = 25.0  # default of filtered_velocity, which also gives the output-error segment starts
# Fewest samples per record: the 11-point Savitzky–Golay window of the friction column and the
# spectrum that finds the excitation frequency need a few times that.
MIN_SAMPLES = 50


def dominant_frequency(signal, sample_time: float) -> float:
    """The strongest non-zero frequency of a signal [Hz]: the excitation frequency of a rig record."""
    spectrum = np.abs(np.fft.rfft(signal - np.mean(signal)))
    frequencies = np.fft.rfftfreq(len(signal), sample_time)
    return float(frequencies[1:][np.argmax(spectrum[1:])])


def low_pass(signal, sample_time: float, cutoff_hz: float, period: float) -> np.ndarray:
    """Zero-phase 4th-order Butterworth low-pass, padded by one ``period`` [s] at both ends.

    scipy's default padding (a few samples) leaves end transients of the filter's own time
    constant: 150 N on a 330 N sine at 5× its frequency, against 0.01 N with one period.
    """
    fs = 1.0 / sample_time
    if cutoff_hz >= 0.45 * fs:
        return np.asarray(signal, dtype=float)
    sos = butter(4, cutoff_hz, fs=fs, output="sos")
    return sosfiltfilt(sos, signal, padlen=min(int(round(period * fs)), len(signal) - 1))


def filtered_velocity(record: Record, cutoff_hz: float | None = None) -> np.ndarray:
    """Zero-phase low-pass of the measured velocity (default cutoff: 25× the dominant frequency)."""
    dominant = dominant_frequency(record.sliding_velocity, record.sample_time)
    if cutoff_hz is None:
        cutoff_hz = VELOCITY_CUTOFF * dominant
    return low_pass(record.sliding_velocity, record.sample_time, cutoff_hz, 1.0 / dominant)


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
    nrmse: dict[str, float]  # per record: friction force (Eq. 3 steps), sliding velocity (output error)
    cost: float
    evaluations: int

    @property
    def weak(self) -> list[str]:
        with np.errstate(over="ignore"):  # an unbounded interval is simply weak
            width = (self.upper - self.lower) / (2.0 * self.values)
        return [n for n, w in zip(self.names, width) if not w <= WEAK_RELATIVE_WIDTH]


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

    @property
    def weakly_identifiable(self) -> list[str]:
        if self.refined is not None:
            return self.refined.weak
        return self.weak_by_equation_error

    @property
    def weak_by_equation_error(self) -> list[str]:
        """Weakly identifiable by the two Eq. 3 steps alone (the paper's method)."""
        return list(dict.fromkeys(self.micro.weak + self.stick.weak))

    def as_dict(self) -> dict:
        out = {"joint_type": self.joint_type, "parameters": {}, "nrmse": {**self.micro.nrmse, **self.stick.nrmse},
               "weakly_identifiable": self.weakly_identifiable, "correlation": {}, "steps": list(self.steps)}
        results = [("p1", self.micro), ("p2", self.stick)]
        if self.refined is not None:
            results.append(("output error", self.refined))
            out["velocity_nrmse"] = dict(self.refined.nrmse)
        for step, result in results:
            for k, name in enumerate(result.names):
                out["parameters"][name] = {"value": float(result.values[k]), "ci95": [float(result.lower[k]),
                                                                                       float(result.upper[k])],
                                           "step": step}
            out["correlation"][step] = {"names": list(result.names), "matrix": result.correlation.tolist()}
        if self.parameters.radius is not None:
            out["parameters"]["radius"] = {"value": self.parameters.radius, "ci95": None, "step": "given"}
        return out


def _initial_guess(micro: list[Record], stick: list[Record], radius: float | None, velocities,
                   joint_type: str) -> dict[str, float]:
    arm = radius if radius is not None else 1.0
    mu = np.concatenate([r.friction_force / (arm * r.normal_force) for r in stick])
    v = np.concatenate([velocities[r.name] for r in stick])
    sliding = np.abs(v) > 0.3 * np.abs(v).max()
    coulomb = float(np.median(np.abs(mu[sliding])))
    if not coulomb > 0.0:
        raise RecordError(f"identify: stick-slip records {', '.join(r.name for r in stick)}: column 'friction_force' "
                          "is zero while sliding — step 2 needs a Coulomb level F_c > 0")
    peak = float(np.percentile(np.abs(mu), 99.5))
    stribeck = max(peak - coulomb, 0.05 * coulomb)
    # Presliding: μ grows like σ0·x with x = ∫v dt; the slope of μ over x gives σ0.
    slopes = []
    for r in micro:
        x = np.concatenate([[0.0], np.cumsum(0.5 * (velocities[r.name][1:] + velocities[r.name][:-1]) * np.diff(r.time))])
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
        raise RecordError(f"identify: micro-slip records {', '.join(r.name for r in micro)}: the friction does not "
                          "grow with the displacement (no presliding) — step 1 needs records whose friction force "
                          "follows the displacement below break-away")
    sigma0 = float(np.median(slopes))
    guess = {"sigma0": max(sigma0, 1.0), "sigma1": 1e-4 * math.sqrt(max(sigma0, 1.0)), "sigma2": 1e-3 * coulomb,
             "coulomb": coulomb, "stribeck": stribeck,
             "stribeck_velocity": float(0.05 * np.median(np.abs(v[sliding])))}
    _check_plausible(guess, joint_type, "start")
    return guess


def _check_plausible(values: dict[str, float], joint_type: str, stage: str) -> None:
    """``RecordError`` when a start or result leaves the plausible range (``rig.PARAMETER_BOUNDS``):
    the records then do not determine the parameters (e.g. a velocity of 1e-300 m/s)."""
    for name, value in values.items():
        lower, upper, _ = rig.PARAMETER_BOUNDS[name][0 if joint_type == "A" else 1]
        if not (math.isfinite(value) and lower < value <= upper):
            raise RecordError(f"identify: the records give {name} = {value:.6g} as {stage} — plausible: > {lower:g} "
                              f"and <= {upper:g}; the records do not determine the LuGre parameters")


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
    p = parameters(best.x)
    errors = {r.name: nrmse(r.friction_force, model_friction(p, r, velocities[r.name])) for r in records}
    return _step_result(names, best, errors, evaluations), p


def _step_result(names, solution, errors: dict[str, float], evaluations: int, clusters=None) -> StepResult:
    """Values, 95 % intervals and correlation of a log-parameter least-squares ``solution``.

    ``clusters``: a group label per residual (output-error segments) for the cluster-robust
    (sandwich) covariance; without it s²·(JᵀJ)⁻¹ with s² inflated for autocorrelation.
    A parameter the residuals do not see (a null direction of J) or held at a bound gets an
    unbounded interval rather than the zero width a pseudo-inverse would give it.
    """
    J, r = solution.jac, solution.fun
    _, singular, vt = np.linalg.svd(J, full_matrices=False)
    seen = singular > singular[0] * 1e-8
    inverse = (vt[seen].T / singular[seen] ** 2) @ vt[seen]  # (JᵀJ)⁻¹ on the directions J sees
    if clusters is None:
        dof = max(r.size - len(names), 1)
        # Residuals of neighbouring samples are correlated (smooth signals, filtered inputs):
        # inflate the variance by (1 + ρ)/(1 − ρ), ρ the lag-1 autocorrelation, i.e. count
        # effective rather than nominal samples.
        e = r - r.mean()
        rho = float(np.clip(np.dot(e[1:], e[:-1]) / max(np.dot(e, e), 1e-300), 0.0, 0.999))
        covariance = 2.0 * solution.cost / dof * (1.0 + rho) / (1.0 - rho) * inverse
    else:
        # Errors within a segment share its start value and integrated force noise: each
        # segment is one independent observation of the gradient.
        count = int(clusters.max()) + 1
        gradients = np.zeros((count, len(names)))
        np.add.at(gradients, clusters, J * r[:, None])
        covariance = inverse @ (gradients.T @ gradients) @ inverse * count / max(count - len(names), 1)
    sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    sigma[np.any(np.abs(vt[~seen]) > 1e-6, axis=0) | (solution.active_mask != 0)] = np.inf
    with np.errstate(invalid="ignore"):
        correlation = np.nan_to_num(covariance / np.outer(np.maximum(sigma, 1e-300), np.maximum(sigma, 1e-300)))
    np.fill_diagonal(correlation, 1.0)
    return StepResult(tuple(names), np.exp(solution.x), np.exp(np.clip(solution.x - 1.96 * sigma, -700, 700)),
                      np.exp(np.clip(solution.x + 1.96 * sigma, -700, 700)), correlation, errors,
                      float(solution.cost), evaluations)


@dataclass
class _Shooting:
    """A stick-slip record prepared for the output-error step (multiple shooting)."""

    record: Record
    force: np.ndarray  # low-passed excitation at the integrator's substep nodes
    gain: np.ndarray  # r·F_N at the nodes
    starts: np.ndarray  # sample index of every segment start: the sliding-velocity peaks
    start_velocity: np.ndarray  # measured velocity there, from a local quadratic fit
    measured: np.ndarray  # measured velocity of the samples the segments predict
    scale: float  # RMS velocity · √samples: every record counts alike


def output_error_gap(record: Record) -> str | None:
    """Why ``record`` cannot enter the output-error step (None when it can)."""
    if record.excitation_force is None:
        return f"{record.name}: no column 'excitation_force'"
    if not record.inertia:
        return f"{record.name}: no '# inertia = …' metadata (or inertia 0)"
    return None


def _prepare_shooting(record: Record, arm: float) -> _Shooting:
    frequency = dominant_frequency(record.excitation_force, record.sample_time)
    period = 1.0 / frequency
    force = low_pass(record.excitation_force, record.sample_time, EXCITATION_CUTOFF * frequency, period)
    smoothed = low_pass(record.sliding_velocity, record.sample_time, VELOCITY_CUTOFF * frequency, period)
    half_period = 0.5 * period / record.sample_time
    peaks, _ = find_peaks(np.abs(smoothed), distance=max(int(0.6 * half_period), 1),
                          height=0.5 * np.abs(smoothed).max())
    peaks = peaks[peaks < record.time.size - 1]
    if peaks.size == 0:
        raise RecordError(f"{record.name}: column 'sliding_velocity' has no sliding peak to start the output-error "
                          "segments from")
    # The start values: a quadratic fit to the raw velocity over ±0.1 half period. Reading the
    # low-passed velocity at its own maxima would pick the noise's ups (type B: σ2 +15 %, not +10 %).
    half_window = min(max(int(0.1 * half_period), 2), (record.time.size - 1) // 2)
    start_velocity = savgol_filter(record.sliding_velocity, 2 * half_window + 1, 2)[peaks]
    # Linear interpolation between samples: the substep nodes of rig.integrate.
    substep = np.diff(record.time)[:, None] / rig.SUBSTEPS * np.arange(rig.SUBSTEPS)[None, :]
    nodes = np.append((record.time[:-1, None] + substep).ravel(), record.time[-1])
    measured = record.sliding_velocity[peaks[0] + 1:]
    return _Shooting(record, np.interp(nodes, record.time, force),
                     arm * np.interp(nodes, record.time, record.normal_force), peaks, start_velocity, measured,
                     _rms(record.sliding_velocity) * math.sqrt(measured.size))


def shoot(p: lugre.LuGreParameters, shooting: _Shooting) -> np.ndarray:
    """Simulated velocity of the rig model (Eq. 1–2) for ``shooting.measured``.

    Each segment runs from one sliding-velocity peak to the next, from the measured velocity
    (local quadratic fit) and the steady-state deflection φ_ss(v) of Eq. 1 (at a peak the element slides
    steadily, and φ relaxes within F_c/(σ0·|v|) ≈ 0.1 ms).
    """
    record, step = shooting.record, rig.SUBSTEPS
    bounds = np.append(shooting.starts, record.time.size - 1)
    parts = []
    for start, end, velocity0 in zip(bounds[:-1], bounds[1:], shooting.start_velocity):
        nodes = slice(start * step, end * step + 1)
        velocity, _ = rig.integrate(p, shooting.gain[nodes], record.inertia, shooting.force[nodes],
                                    record.time[start:end + 1], step, velocity0,
                                    float(lugre.steady_state_deflection(p, velocity0)), backend="c")
        parts.append(velocity[1:])
    return np.concatenate(parts)


def _refine(stick: list[Record], start: lugre.LuGreParameters, progress) -> tuple[StepResult, lugre.LuGreParameters]:
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
    """
    shootings = [_prepare_shooting(r, start.moment_arm) for r in stick]

    def parameters(theta):
        return lugre.LuGreParameters(radius=start.radius, **{n: float(math.exp(t)) for n, t in zip(P3, theta)})

    def residual(theta):
        p = parameters(theta)
        parts = [(shoot(p, s) - s.measured) / s.scale for s in shootings]
        # A wild trial point can make the Newton solve diverge: a large finite residual
        # sends the optimiser back instead of stopping it.
        return np.nan_to_num(np.concatenate(parts), nan=1e3, posinf=1e3, neginf=-1e3)

    theta0 = np.log([getattr(start, n) for n in P3])
    solution = scipy.optimize.least_squares(residual, theta0, bounds=(theta0 - math.log(1e3), theta0 + math.log(1e3)),
                                            x_scale=1.0, diff_step=1e-6, xtol=1e-10, ftol=1e-12, max_nfev=100)
    p = parameters(solution.x)
    errors = {s.record.name: nrmse(s.measured, shoot(p, s)) for s in shootings}
    lengths = np.concatenate([np.diff(np.append(s.starts, s.record.time.size - 1)) for s in shootings])
    if progress:
        progress(f"step 3 (output error: σ0, σ1, σ2, F_c, F_d, v_s, {len(stick)} stick-slip records, "
                 f"{sum(s.starts.size for s in shootings)} segments): cost {solution.cost:.4g}")
    return _step_result(P3, solution, errors, solution.nfev, np.repeat(np.arange(lengths.size), lengths)), p


def _output_error_blocker(stick: list[Record], enabled: bool) -> str | None:
    """Why the output-error step cannot run (None when it can)."""
    if not enabled:
        return "switched off"
    for record in stick:
        gap = output_error_gap(record)
        if gap:
            return gap
    try:
        rig.kernel()
    except ModelError as error:  # the Python reference loop would take hours here
        return f"rig kernel unavailable ({error})"
    return None


def _joint_radius(records: list[Record], joint_type: str, radius: float | None) -> float | None:
    """The radius of type B records: ``radius`` if given, else the one every record carries.

    Never a default: a type B record without a radius is refused (Table 1's 11 mm would put
    σ0, F_c and σ2 off by the ratio of the radii).
    """
    if joint_type == "A":
        if radius is not None:
            raise RecordError(f"identify: radius {radius!r} m given, but the records are type A — a type A joint has "
                              "no radius")
        return None
    if radius is not None:
        if not (isinstance(radius, (int, float)) and math.isfinite(radius)
                and MIN_RADIUS <= radius <= bound("radius", "B")):
            raise RecordError(f"identify: radius {radius!r} m — allowed: {MIN_RADIUS:g} … {bound('radius', 'B'):g} m")
        for record in records:
            if record.radius is not None and record.radius != radius:
                raise RecordError(f"identify: radius {radius!r} m given, but record {record.name} carries "
                                  f"radius = {record.radius!r} m — give one radius")
        return float(radius)
    carried = {}
    for record in records:
        if record.radius is None:
            raise RecordError(f"{record.name}: type B record without a radius — add '# radius = <r> m' to the record "
                              "(or pass the radius to identify / --radius); no default is assumed")
        carried.setdefault(record.radius, record.name)
    if len(carried) > 1:
        (first, one), (second, other) = list(carried.items())[:2]
        raise RecordError(f"identify: records {one} (radius {first!r} m) and {other} (radius {second!r} m) are not "
                          "of one joint — identify one joint's records at a time")
    return next(iter(carried))


def _check_records(records: list[Record]) -> None:
    """One-line errors for records the fit cannot use (too short, nothing measured)."""
    for record in records:
        if record.time.size < MIN_SAMPLES:
            raise RecordError(f"{record.name}: {record.time.size} samples — identify needs at least {MIN_SAMPLES} "
                              "per record")
        for column in ("sliding_velocity", "friction_force"):
            values = getattr(record, column)
            if not np.all(np.isfinite(values)):
                raise RecordError(f"{record.name}: column {column!r}: not finite — allowed: finite numbers")
            if not np.any(values != 0.0):
                raise RecordError(f"{record.name}: column {column!r} is zero throughout — nothing to identify from")
        if not (np.all(np.isfinite(record.time)) and np.all(np.diff(record.time) > 0.0)):
            raise RecordError(f"{record.name}: column 'time' must be finite and increase")
        if not np.all(np.isfinite(record.normal_force) & (record.normal_force > 0.0)):
            raise RecordError(f"{record.name}: column 'normal_force': F_N must be > 0 and finite")


def identify(micro: list[Record], stick: list[Record], radius: float | None = None, progress=None,
             cutoff_hz: float | None = None, output_error: bool = True) -> Identification:
    """Two-step identification of Eq. 3 from micro-slip and stick-slip records, then the
    output-error step (``_refine``) when every stick-slip record has its excitation force and
    inertia and ``output_error`` is on; ``Identification.steps`` lists what ran.

    Type B records need their radius (``radius``, or ``Record.radius`` of every record).
    Records the fit cannot use raise ``RecordError``; so does a numerical failure inside the fit
    (degenerate data that passed the checks), as one line instead of a traceback.
    """
    if not micro:
        raise RecordError("identify: no micro-slip records (step 1 needs at least one)")
    if not stick:
        raise RecordError("identify: no stick-slip records (step 2 needs at least one)")
    types = {r.joint_type for r in micro + stick}
    if len(types) != 1:
        raise RecordError(f"identify: records mix joint types {sorted(types)}")
    joint_type = types.pop()
    radius = _joint_radius(micro + stick, joint_type, radius)
    names = [r.name for r in micro + stick]
    if len(set(names)) != len(names):
        raise RecordError("identify: two records share a name; rename the files")
    _check_records(micro + stick)
    try:
        with np.errstate(all="ignore"):
            return _identify(micro, stick, joint_type, radius, progress, cutoff_hz, output_error)
    except SmartjointError:
        raise
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as error:
        detail = " ".join(str(error).split())[:160]
        raise RecordError(f"identify: the fit failed on records {', '.join(names)} ({type(error).__name__}: {detail}) "
                          "— they do not determine the LuGre parameters (micro-slip records must show presliding, "
                          "stick-slip records must slide)") from None


def _identify(micro, stick, joint_type, radius, progress, cutoff_hz, output_error) -> Identification:
    # The raw velocity unless a cutoff is given: a low-pass also cuts the bristle resonance
    # that the measured force contains, which biases the fit more than the noise does.
    velocities = {r.name: (filtered_velocity(r, cutoff_hz) if cutoff_hz else r.sliding_velocity) for r in micro + stick}
    for r in stick:
        if not slides(r, radius):
            raise RecordError(f"{r.name}: column 'sliding_velocity' shows no gross slip — a stick-slip record must "
                              "slide (step 2 identifies F_c, F_d, v_s, σ2 from sliding)")
    guess = _initial_guess(micro, stick, radius, velocities, joint_type)
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
    steps = [f"equation error (Eq. 3), {ROUNDS} rounds: step 1 σ0, σ1 on {len(micro)} micro-slip records, step 2 "
             f"F_c, F_d, v_s, σ2, σ1 on {len(stick)} stick-slip records"]
    refined = None
    blocker = _output_error_blocker(stick, output_error)
    if blocker is None:
        refined, parameters = _refine(stick, parameters, progress)
        steps.append(f"output error (rig model driven by the excitation force): σ0, σ1, σ2, F_c, F_d, v_s on "
                     f"{len(stick)} stick-slip records")
    else:
        steps.append(f"output error: skipped — {blocker}")
        if progress:
            progress(steps[-1])
    _check_plausible({n: getattr(parameters, n) for n in P3}, joint_type, "result")
    for result, records in ((micro_result, micro), (stick_result, stick)):
        result.nrmse = {r.name: nrmse(r.friction_force, model_friction(parameters, r, velocities[r.name]))
                        for r in records}
    return Identification(parameters, joint_type, micro_result, stick_result,
                          {r.name: r for r in micro + stick}, velocities, refined, steps)


def slides(record: Record, radius: float | None = None) -> bool:
    """Gross sliding: the element moves by far more than any bristle deflection μ/σ0 could."""
    arm = 1.0 if record.joint_type == "A" else (radius if radius is not None else record.moment_arm)
    mu = np.abs(record.friction_force / (arm * record.normal_force))
    displacement = np.ptp(np.cumsum(record.sliding_velocity) * record.sample_time)
    return bool(displacement * 1e4 > mu.max() and displacement > 1e-4)


def classify(record: Record, radius: float | None = None) -> str:
    """'stick-slip' or 'micro-slip': the record's ``regime`` metadata, else whether it slides."""
    if "regime" in record.metadata:
        return record.metadata["regime"]
    return "stick-slip" if slides(record, radius) else "micro-slip"


__all__ = ["Identification", "classify", "slides", "identify", "model_friction", "nrmse", "output_error_gap", "shoot",
           "simulate_friction"]
