"""Semi-active normal-force controllers of paper Section 5, as discrete-time reference algorithms.

These Python classes are the executable specification of the firmware: the generated C must
match them sample by sample, so each keeps its state, update order and saturation explicit.
All sit behind ``simulate.Controller`` (``reset()``, ``step(measurements) -> normal_forces``,
``sample_time``).

* ``SisoLaw`` — the local Lyapunov law of Eq. 30 in every joint with μ_j of Eq. 31.
* ``ClippedLqg`` — Eq. 33–34: a Kalman filter on the tip sensors with the measured friction
  forces as known input, the LQR forces u_d = −K·x̂ and the clipped normal-force law.
* ``ActiveLqg`` — the fully active reference: the same LQG, u_d applied directly as forces.

The gains come from ``design_lqg`` (python-control ``dlqr``/``dlqe`` on the reduced modal model
discretised exactly at the sample time, ``discretise``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import control as ct
import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.structure.modal import ModalModel
from smartjoint.design.plant.simulate import Measurements, discretise


# Status bits of a controller step (the generated C returns the same values; 4 is the C's
# NULL_POINTER, 0x10 the CAN layer's SAFE_STATE). Any of them puts EVERY joint at the safe
# normal force (the artefact's safe_normal_force, docs/safety.md).
STATUS_OK = 0
STATUS_INPUT_INVALID = 1  # a measurement was NaN or ±Inf
STATUS_ESTIMATE_RESET = 2  # the cLQG estimate or force left the finite numbers: filter restarted
STATUS_INPUT_IMPLAUSIBLE = 8  # a finite measurement outside its plausible range


def _vector(field: str, value, count: int, default: float) -> np.ndarray:
    """A per-channel float vector (a number is broadcast; None gives ``default``)."""
    array = np.array(default if value is None else value, dtype=float)
    if array.ndim == 0:
        array = np.full(count, float(array))
    if array.shape != (count,) or np.any(np.isnan(array)):
        raise ModelError(f"{field}: {array.tolist()} — expected a number or {count} numbers, none NaN")
    return array


def _safe_force(value, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The safe normal force per joint; default F_N^max (the design file's default, locked joints)."""
    safe = _vector("safe_normal_force", high if value is None else value, low.size, 0.0)
    if not np.all(np.isfinite(safe)) or np.any(safe < low) or np.any(safe > high):
        raise ModelError(f"safe_normal_force: {safe.tolist()} — must lie within [normal_force_min, normal_force_max] "
                         f"= [{low.tolist()}, {high.tolist()}] N per joint")
    return safe


def _magnitude_limit(field: str, value, count: int) -> np.ndarray:
    """|x| <= limit is plausible; None: no range beyond finiteness (+inf)."""
    limit = _vector(field, value, count, math.inf)
    if np.any(limit <= 0):
        raise ModelError(f"{field}: {limit.tolist()} — must be > 0")
    return limit


def input_status(value, low, high) -> np.ndarray:
    """Per measured value, its status bits against its plausible range [low, high]:
    ``STATUS_INPUT_INVALID`` for NaN/±Inf, ``STATUS_INPUT_IMPLAUSIBLE`` for a number outside (a
    value at a limit is within), else 0. The range test is written as "within", false for NaN,
    as in the C (``check_input``)."""
    value = np.asarray(value, dtype=float)
    with np.errstate(invalid="ignore"):
        inside = (value >= low) & (value <= high)
    return np.where(~np.isfinite(value), STATUS_INPUT_INVALID, np.where(inside, STATUS_OK, STATUS_INPUT_IMPLAUSIBLE))


def _any_status(*statuses: np.ndarray) -> int:
    """The OR of every bit of the per-value statuses."""
    return int(np.bitwise_or.reduce(np.concatenate([np.ravel(s) for s in statuses]), initial=STATUS_OK))


def boundary_layer(value, width):
    """The smoothed Heaviside H_ε(s) = clip(s/ε, 0, 1) of Eq. 30 and Eq. 34, with NaN → 0
    (written as s > 0 ? min(s, 1) : 0 so that C and numpy agree on every input)."""
    with np.errstate(all="ignore"):
        ratio = np.asarray(value, dtype=float) / width
    return np.where(ratio > 0.0, np.minimum(ratio, 1.0), 0.0)


class SisoLaw:
    """Local Lyapunov law of Eq. 30 in each joint, μ_j from the previous sample (Eq. 31).

    At sample k, per joint j, with v_k the measured sliding velocity::

        μ_k   = u_R,k−1 / F_N,k−1                               (Eq. 31; 0 at the first sample)
        F_N,k = F_N^min + (F_N^max − F_N^min)·clip(μ_k·v_k / ε, 0, 1)     (Eq. 30)

    Inputs the law cannot use: a v, u_R or F_N that is NaN or ±Inf (``STATUS_INPUT_INVALID``)
    or a number outside its plausible range (``STATUS_INPUT_IMPLAUSIBLE``; plausible are
    |v| <= sliding_velocity_limit, |u_R| <= friction_force_limit and measured_normal_force_min
    <= F_N <= measured_normal_force_max, limits included). Then EVERY joint is commanded
    ``safe_normal_force`` and the affected joints forget their memory (μ = 0 at their next
    sample); the others keep theirs, μ being a ratio of their own measurements. ``status``
    holds the bits.

    u_R,k−1 and F_N,k−1 are the friction force and the applied normal force *measured* at the
    previous sample, so μ is always a ratio of quantities of one instant. Reading of Eq. 30:
    the paper writes the boundary-layer branch as F^min + (F^max/ε)·μv, which jumps at μv = ε
    unless F^min = 0; the continuous interpolation between the two outer branches is used.
    State: the previous friction force and normal force per joint (zero after reset).

    Without the safety arguments: safe force F_N^max, no ranges beyond finiteness (``siso_law``
    of ``design/control/artifact.py`` builds the law with the artefact's).
    """

    def __init__(self, sample_time: float, normal_force_min, normal_force_max, boundary_layer_width, *,
                 safe_normal_force=None, sliding_velocity_limit=None, friction_force_limit=None,
                 measured_normal_force_min=None, measured_normal_force_max=None):
        self.sample_time = float(sample_time)
        self.normal_force_min = np.array(normal_force_min, dtype=float)
        self.normal_force_max = np.array(normal_force_max, dtype=float)
        self.boundary_layer = np.array(boundary_layer_width, dtype=float)
        _check_limits(self.normal_force_min, self.normal_force_max)
        self.normal_force_range = self.normal_force_max - self.normal_force_min
        if np.any(self.normal_force_min <= 0):
            raise ModelError(f"normal_force_min: {self.normal_force_min.tolist()} — the SISO law needs F_N^min > 0: "
                             "μ = u_R/F_N (Eq. 31) is undefined at F_N = 0")
        if not np.all(np.isfinite(self.boundary_layer)) or np.any(self.boundary_layer <= 0):
            raise ModelError(f"siso_boundary_layer: {self.boundary_layer.tolist()} — ε must be finite and > 0 [m/s]")
        count = self.normal_force_min.size
        self.safe_normal_force = _safe_force(safe_normal_force, self.normal_force_min, self.normal_force_max)
        self.sliding_velocity_limit = _magnitude_limit("sliding_velocity_limit", sliding_velocity_limit, count)
        self.friction_force_limit = _magnitude_limit("friction_force_limit", friction_force_limit, count)
        self.measured_normal_force_min, self.measured_normal_force_max = _measured_range(
            measured_normal_force_min, measured_normal_force_max, count)
        self.reset()

    def reset(self) -> None:
        count = self.normal_force_min.size
        self.previous_friction = np.zeros(count)
        self.previous_normal_force = np.zeros(count)
        self.status = STATUS_OK

    def step(self, measurements: Measurements) -> np.ndarray:
        velocity = np.asarray(measurements.sliding_velocity, dtype=float)
        friction = np.asarray(measurements.friction_force, dtype=float)
        applied = np.asarray(measurements.normal_force, dtype=float)
        joint_status = (input_status(velocity, -self.sliding_velocity_limit, self.sliding_velocity_limit)
                        | input_status(friction, -self.friction_force_limit, self.friction_force_limit)
                        | input_status(applied, self.measured_normal_force_min, self.measured_normal_force_max))
        usable = joint_status == STATUS_OK
        self.status = _any_status(joint_status)
        previous_force, previous_normal = self.previous_friction, self.previous_normal_force
        self.previous_friction = np.where(usable, friction, 0.0)
        self.previous_normal_force = np.where(usable, applied, 0.0)
        if self.status != STATUS_OK:
            return self.safe_normal_force.copy()
        with np.errstate(all="ignore"):
            known = previous_normal > 0.0
            mu = np.where(known, previous_force / np.where(known, previous_normal, 1.0), 0.0)  # Eq. 31
            power = mu * velocity
        return self.normal_force_min + self.normal_force_range * boundary_layer(power, self.boundary_layer)


def _measured_range(low, high, count: int) -> tuple[np.ndarray, np.ndarray]:
    """The plausible range of a measured normal force; None: unbounded on that side."""
    low = _vector("measured_normal_force_min", low, count, -math.inf)
    high = _vector("measured_normal_force_max", high, count, math.inf)
    if np.any(low > high):
        raise ModelError(f"measured_normal_force_min {low.tolist()} / measured_normal_force_max {high.tolist()}: "
                         "need min <= max per joint")
    return low, high


@dataclass(frozen=True)
class LqgDesign:
    """Discrete LQG on the reduced modal model, x = [η̇_1, ω_1η_1, …] (mode-interleaved, 2n).

    x⁺ = Φx + Γ0·(−E u_k) + Γ1·(−E u_k+1) + …, y = C x; per mode a 2×2 block of Φ (``blocks``)
    and 2-vectors γ0, γ1 (``gamma0``, ``gamma1``; the input matrices are γ⊗eᵢᵀ, never dense).
    K: LQR gain for the force held over a sample (ZOH: B = −(Γ0+Γ1)E), u_d = −K·x̂.
    M: Kalman gain of the *current* estimator x̂ = x̂⁻ + M(y − Cx̂⁻), from python-control's
    ``dlqe`` covariance P: M = P·Cᵀ(C·P·Cᵀ + R_v)⁻¹ (dlqe's predictor gain is Φ·M).
    """

    sample_time: float
    blocks: np.ndarray  # (n, 2, 2)
    gamma0: np.ndarray  # (n, 2)
    gamma1: np.ndarray  # (n, 2)
    joint_input: np.ndarray  # E (n, l)
    output: np.ndarray  # C (ny, 2n)
    feedback_gain: np.ndarray  # K (l, 2n)
    estimator_gain: np.ndarray  # M (2n, ny)
    riccati_control: np.ndarray  # S of the LQR
    riccati_estimator: np.ndarray  # P of the Kalman filter (a priori)

    @property
    def state_matrix(self) -> np.ndarray:
        n = self.blocks.shape[0]
        a = np.zeros((2 * n, 2 * n))
        for i in range(n):
            a[2 * i:2 * i + 2, 2 * i:2 * i + 2] = self.blocks[i]
        return a

    def input_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """Dense Γ0·E and Γ1·E (2n, l), for checks and python-control; the C never forms them."""
        n, e = self.blocks.shape[0], self.joint_input
        g0 = (self.gamma0[:, :, None] * e[:, None, :]).reshape(2 * n, -1)
        g1 = (self.gamma1[:, :, None] * e[:, None, :]).reshape(2 * n, -1)
        return g0, g1

    def closed_loop_poles(self) -> np.ndarray:
        """Eigenvalues of the linear LQG loop (plant + current estimator + u = −Kx̂, ZOH force)."""
        a = self.state_matrix
        g0, g1 = self.input_matrices()
        b = -(g0 + g1)
        c, k, m = self.output, self.feedback_gain, self.estimator_gain
        # Estimator error e = x − x̂⁻ evolves with (I − MC) inside: e⁺ = (A − A M C) e.
        top = np.hstack([a - b @ k, b @ k @ (np.eye(a.shape[0]) - m @ c)])
        bottom = np.hstack([np.zeros_like(a), a - a @ m @ c])
        return np.linalg.eigvals(np.vstack([top, bottom]))


def _check_limits(low: np.ndarray, high: np.ndarray) -> None:
    if low.shape != high.shape or not np.all(np.isfinite(low)) or not np.all(np.isfinite(high)):
        raise ModelError(f"normal_force_min {low.tolist()} / normal_force_max {high.tolist()}: need finite values, "
                         "one per joint")
    if np.any(low < 0) or np.any(low > high):
        raise ModelError(f"normal_force_min {low.tolist()} / normal_force_max {high.tolist()}: need "
                         "0 <= F_N^min <= F_N^max per joint")


def check_sample_time(model: ModalModel, sample_time: float) -> None:
    """Rule: every retained mode below the Nyquist frequency, f_max·Δt < 1/2 — above it the
    discrete model aliases the mode and the estimator cannot tell it from a slower one."""
    if not (math.isfinite(sample_time) and sample_time > 0):
        raise ModelError(f"sample_time: {sample_time!r} — must be a finite number > 0 [s]")
    highest = float(model.omega.max()) / (2 * math.pi)
    if highest * sample_time >= 0.5:
        raise ModelError(f"sample_time: {sample_time:g} s is too coarse for the highest retained mode "
                         f"({highest:.1f} Hz): rule f_max·Δt < 1/2 (Nyquist) — use Δt < {0.5 / highest:.3g} s "
                         "or retain fewer modes")


def design_lqg(model: ModalModel, sample_time: float, state_weight: float = 1.0, control_weight: float = 1e-6,
               process_noise: float = 1e4, measurement_noise: float = 1e-10) -> LqgDesign:
    """LQR + Kalman filter (Eq. 33) for the reduced model at the controller sample time.

    Model: exact discretisation (``simulate.discretise``) of each mode block; friction enters
    as −E·u_R, disturbances as H·w (process noise, intensity ``process_noise`` N² per input),
    sensors y = C·x with noise ``measurement_noise`` m². Gains from python-control
    (``dlqr``, ``dlqe``); stabilisability and detectability are checked first (PBH test on
    every mode block), and a Riccati failure is reported with the weights that caused it.
    """
    check_sample_time(model, sample_time)
    for name, value in (("state_weight", state_weight), ("control_weight", control_weight),
                        ("process_noise", process_noise), ("measurement_noise", measurement_noise)):
        if not (math.isfinite(value) and value > 0):
            raise ModelError(f"{name}: {value!r} — must be a finite number > 0")
    n, l = model.n_coordinates, model.joint_input.shape[1]
    ny = model.velocity_output.shape[0]
    if l == 0:
        raise ModelError("design has no joints: the LQG needs at least one friction joint as actuator")
    if ny == 0:
        raise ModelError("design has no [[sensors]]: the Kalman filter needs the measured tip deflections")
    phi, g0, g1 = discretise(model, sample_time)
    a = np.zeros((2 * n, 2 * n))
    for i in range(n):
        a[2 * i:2 * i + 2, 2 * i:2 * i + 2] = phi[i]
    e, h = model.joint_input, model.disturbance_input
    gz = g0 + g1  # ZOH: a force held over the sample
    b = -(gz[:, :, None] * e[:, None, :]).reshape(2 * n, l)
    g = (gz[:, :, None] * h[:, None, :]).reshape(2 * n, h.shape[1])
    c = np.zeros((ny, 2 * n))
    c[:, 0::2] = model.velocity_output
    c[:, 1::2] = model.displacement_output / model.omega
    _check_pbh(a, b, "stabilisable", "no friction joint moves mode", model)
    _check_pbh(a.T, c.T, "detectable", "no sensor sees mode", model)
    q, r = state_weight * np.eye(2 * n), control_weight * np.eye(l)
    try:
        k, s, _ = ct.dlqr(a, b, q, r)
        _, p, _ = ct.dlqe(a, g, c, process_noise * np.eye(g.shape[1]), measurement_noise * np.eye(ny))
    except Exception as failure:  # python-control / slycot raise several types
        raise ModelError(f"Riccati solver failed ({type(failure).__name__}: {failure}) for state_weight "
                         f"{state_weight:g}, control_weight {control_weight:g}, process_noise {process_noise:g}, "
                         f"measurement_noise {measurement_noise:g}") from None
    k, s, p = np.asarray(k), np.asarray(s), np.asarray(p)
    if not (np.all(np.isfinite(k)) and np.all(np.isfinite(p))):
        raise ModelError("Riccati solver returned non-finite gains; check the weights")
    m = p @ c.T @ np.linalg.inv(c @ p @ c.T + measurement_noise * np.eye(ny))
    return LqgDesign(sample_time, phi, g0, g1, np.array(e, dtype=float), c, k, m, s, p)


def _check_pbh(a, b, word, reason, model) -> None:
    """PBH rank test per 2×2 mode block (modes are decoupled): rank[A − λI, B] = 2 for each λ."""
    n = a.shape[0] // 2
    for i in range(n):
        block = a[2 * i:2 * i + 2, 2 * i:2 * i + 2]
        rows = b[2 * i:2 * i + 2]
        for lam in np.linalg.eigvals(block):
            if abs(lam) < 1.0 - 1e-12:
                continue  # stable modes need no control/observation
            test = np.hstack([block - lam * np.eye(2), rows])
            if np.linalg.matrix_rank(test, tol=1e-12 * max(1.0, np.abs(test).max())) < 2:
                raise ModelError(f"reduced model is not {word}: {reason} {i + 1} "
                                 f"({model.omega[i] / 2 / np.pi:.2f} Hz) with |λ| = {abs(lam):.6f}")
    # With structural damping every mode is strictly stable, so the loop above only catches
    # undamped modes; a mode that no joint moves / no sensor sees is still reported:
    norms = np.linalg.norm(b.reshape(n, 2, -1), axis=(1, 2))
    if np.any(norms <= 1e-14 * max(norms.max(), 1e-300)):
        i = int(np.argmin(norms))
        raise ModelError(f"reduced model is not {word} in practice: {reason} {i + 1} "
                         f"({model.omega[i] / 2 / np.pi:.2f} Hz) at all — drop it from the reduced model")


class _Lqg:
    """Shared Kalman filter of ``ClippedLqg`` and ``ActiveLqg``. At sample k::

        x̂⁻ = Φ·x̂_k−1 − Γ0·E·u_k−1 − Γ1·E·u_k    (time update, first-order hold on the
                                                 applied joint forces; skipped at k = 0: x̂⁻ = 0)
        x̂_k = x̂⁻ + M·(y_k − C·x̂⁻)               (measurement update)
        u_d = −K·x̂_k                             (Eq. 33)

    u is the joint force that acts on the structure: the measured friction force for the
    clipped controller, the previous command for the active one."""

    def __init__(self, design: LqgDesign):
        self.design = design
        self.sample_time = design.sample_time
        self.reset()

    def reset(self) -> None:
        n2 = self.design.output.shape[1]
        self.estimate = np.zeros(n2)
        self.previous_force = np.zeros(self.design.joint_input.shape[1])
        self.started = False

    def _time_update(self, force: np.ndarray) -> np.ndarray:
        d = self.design
        n = d.blocks.shape[0]
        x = self.estimate.reshape(n, 2)
        if not self.started:
            return np.zeros(2 * n)
        start, end = ordered_product(d.joint_input, self.previous_force), ordered_product(d.joint_input, force)
        b = d.blocks
        out = np.empty((n, 2))
        out[:, 0] = (b[:, 0, 0] * x[:, 0] + b[:, 0, 1] * x[:, 1]) - d.gamma0[:, 0] * start - d.gamma1[:, 0] * end
        out[:, 1] = (b[:, 1, 0] * x[:, 0] + b[:, 1, 1] * x[:, 1]) - d.gamma0[:, 1] * start - d.gamma1[:, 1] * end
        return out.reshape(2 * n)

    def _estimate(self, sensors: np.ndarray, force: np.ndarray) -> np.ndarray:
        d = self.design
        prior = self._time_update(force)
        # Before the first sample the prediction is 0 (not C·0, whose zeros may carry a sign).
        predicted = ordered_product(d.output, prior) if self.started else np.zeros(d.output.shape[0])
        innovation = np.asarray(sensors, dtype=float) - predicted
        self.estimate = prior + ordered_product(d.estimator_gain, innovation)
        self.started = True
        return -ordered_product(d.feedback_gain, self.estimate)


def ordered_product(matrix: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """matrix @ vector summed strictly left to right over the columns, starting with the first
    product — the order of the generated C, so the double build reproduces this reference bit
    for bit (BLAS sums in blocks and with FMA, which differs in the last bits)."""
    total = matrix[:, 0] * vector[0]
    for k in range(1, matrix.shape[1]):
        total = total + matrix[:, k] * vector[k]
    return total


class ClippedLqg(_Lqg):
    """Clipped-optimal LQG, Eq. 33–34. Reading of Eq. 34, with e_j = u_d,j − u_R,j::

        F_N,j = F_N^min + (F_N^max − F_N^min)·clip(e_j·sgn(u_R,j) / ε, 0, 1)

    The paper's F^min + F^max·H[e_j·u_R,j] would exceed the stated bound F^max; scaling by
    (F^max − F^min) keeps F^min ≤ F_N ≤ F^max. H[e·u_R] has the sign of e·sgn(u_R), so the
    boundary layer is laid over that quantity and ε is a force [N]: the normal force rises when
    the friction force is smaller than the desired force in the same direction and falls to
    F^min when it is larger or opposes it. u_R,j = 0 counts as sgn = 0 (F^min: nothing to steer).

    Faults (``status``): a measurement that is NaN/±Inf (``STATUS_INPUT_INVALID``) or a number
    outside its plausible range (``STATUS_INPUT_IMPLAUSIBLE``; plausible are |y_r| <=
    sensor_limit, |u_R,j| <= friction_force_limit and measured_normal_force_min <= F_N,j <=
    measured_normal_force_max, limits included) → every joint at ``safe_normal_force``, u_d = 0,
    and the filter restarts; an estimate or desired force that is no longer finite → the same with
    ``STATUS_ESTIMATE_RESET``. Without the safety arguments: safe force F_N^max, no ranges
    beyond finiteness (``clipped_lqg`` of ``design/control/artifact.py`` passes the artefact's).
    """

    def __init__(self, design: LqgDesign, normal_force_min, normal_force_max, boundary_layer_width: float, *,
                 safe_normal_force=None, sensor_limit=None, friction_force_limit=None,
                 measured_normal_force_min=None, measured_normal_force_max=None):
        super().__init__(design)
        self.normal_force_min = np.array(normal_force_min, dtype=float)
        self.normal_force_max = np.array(normal_force_max, dtype=float)
        _check_limits(self.normal_force_min, self.normal_force_max)
        count = design.joint_input.shape[1]
        if self.normal_force_min.size != count:
            raise ModelError(f"normal_force_min: {self.normal_force_min.size} values for {count} joints")
        if not (math.isfinite(boundary_layer_width) and boundary_layer_width > 0):
            raise ModelError(f"clqg_boundary_layer: {boundary_layer_width!r} — must be finite and > 0 [N]")
        self.boundary_layer = float(boundary_layer_width)
        self.normal_force_range = self.normal_force_max - self.normal_force_min
        self.desired_force = np.zeros(self.normal_force_min.size)
        self.safe_normal_force = _safe_force(safe_normal_force, self.normal_force_min, self.normal_force_max)
        self.sensor_limit = _magnitude_limit("sensor_limit", sensor_limit, design.output.shape[0])
        self.friction_force_limit = _magnitude_limit("friction_force_limit", friction_force_limit, count)
        self.measured_normal_force_min, self.measured_normal_force_max = _measured_range(
            measured_normal_force_min, measured_normal_force_max, count)

    def reset(self) -> None:
        super().reset()
        self.desired_force = np.zeros(self.design.joint_input.shape[1])
        self.status = STATUS_OK

    def _fault(self, status: int) -> np.ndarray:
        self.reset()
        self.status = status
        return self.safe_normal_force.copy()

    def step(self, measurements: Measurements) -> np.ndarray:
        sensors = np.asarray(measurements.sensors, dtype=float)
        friction = np.asarray(measurements.friction_force, dtype=float)
        applied = np.asarray(measurements.normal_force, dtype=float)
        status = _any_status(input_status(sensors, -self.sensor_limit, self.sensor_limit),
                             input_status(friction, -self.friction_force_limit, self.friction_force_limit),
                             input_status(applied, self.measured_normal_force_min, self.measured_normal_force_max))
        if status != STATUS_OK:
            return self._fault(status)
        with np.errstate(all="ignore"):
            self.desired_force = self._estimate(sensors, friction)
        if not (np.all(np.isfinite(self.estimate)) and np.all(np.isfinite(self.desired_force))):
            return self._fault(STATUS_ESTIMATE_RESET)
        self.status = STATUS_OK
        error = self.desired_force - friction
        normal_force = self.normal_force_min + self.normal_force_range * boundary_layer(
            error * np.sign(friction), self.boundary_layer)
        # The friction force just after this sample: u_R = F_N·μ with μ continuous, so it scales
        # with the new normal force — the start value of the next time update's first-order hold.
        self.previous_force = np.where(applied > 0.0, friction * normal_force / np.where(applied > 0.0, applied, 1.0),
                                       friction)
        return normal_force


class ActiveLqg(_Lqg):
    """The fully active reference: u_d = −K·x̂ applied directly as joint forces (zero-order hold).
    ``step`` returns the forces; run it with ``simulate_active``."""

    def step(self, measurements: Measurements) -> np.ndarray:
        command = self._estimate(measurements.sensors, self.previous_force)
        self.previous_force = command.copy()
        return command


class HoldDuringExcitation:
    """The study's protocol (Section 6): F_N = F_N^max while the disturbance acts (t < ``until``),
    then the wrapped controller. The wrapped controller runs from the first sample (its filter
    and memories see everything); only its output is overridden."""

    def __init__(self, inner, until: float, normal_forces):
        self.inner, self.until = inner, float(until)
        self.normal_forces = np.array(normal_forces, dtype=float)
        self.sample_time = inner.sample_time

    def reset(self) -> None:
        self.inner.reset()

    def step(self, measurements: Measurements) -> np.ndarray:
        out = self.inner.step(measurements)
        return self.normal_forces.copy() if measurements.time < self.until - 1e-12 else out


@dataclass
class ActiveResult:
    """``simulate_active`` output at the controller samples (fields as ``SimulationResult``)."""

    time: np.ndarray
    sensors: np.ndarray
    sliding_velocity: np.ndarray
    force: np.ndarray  # applied u_d (n_t, l), held on [t_k, t_k+1)
    energy: np.ndarray

    def energy_measure(self, t_end: float | None = None) -> float:
        mask = self.time <= (self.time[-1] if t_end is None else t_end) + 1e-12
        return float(np.trapezoid(2.0 * self.energy[mask], self.time[mask]))


def simulate_active(model: ModalModel, controller: ActiveLqg, disturbance, duration: float,
                    excitation_end: float = 0.0) -> ActiveResult:
    """The fully active reference: the linear modal model (joints frictionless) driven by the
    disturbance and the LQG forces u_d held over each sample, discretised exactly at the
    sample time (first-order hold on w: exact for the triangular pulse, whose corners lie on
    the sample grid). During the excitation (t < ``excitation_end``) the actuators hold zero
    force — the semi-active runs hold F_N^max then, which the active system has no analogue of."""
    h = controller.sample_time
    steps = int(round(duration / h))
    phi, g0, g1 = discretise(model, h)
    e, hw = model.joint_input, model.disturbance_input
    times = np.arange(steps + 1) * h
    w = np.zeros((steps + 1, hw.shape[1])) if disturbance is None else np.array([disturbance(t) for t in times])
    x = np.zeros((model.n_coordinates, 2))
    l, ny = e.shape[1], model.velocity_output.shape[0]
    sensors, velocity, force, energy = np.zeros((steps + 1, ny)), np.zeros((steps + 1, l)), np.zeros((steps + 1, l)), \
        np.zeros(steps + 1)
    controller.reset()
    for k in range(steps + 1):
        y = model.velocity_output @ x[:, 0] + (model.displacement_output / model.omega) @ x[:, 1]
        v = e.T @ x[:, 0]
        u = controller.step(Measurements(times[k], y, v, np.zeros(l), np.zeros(l)))
        if not np.all(np.isfinite(u)):
            raise ModelError(f"active LQG produced non-finite forces at t = {times[k]:.4g} s")
        if times[k] < excitation_end - 1e-12:
            u = np.zeros(l)
            controller.previous_force = u.copy()
        sensors[k], velocity[k], force[k], energy[k] = y, v, u, 0.5 * float(np.sum(x * x))
        if k == steps:
            break
        fa, fb = hw @ w[k] - e @ u, hw @ w[k + 1] - e @ u
        x = np.einsum("nij,nj->ni", phi, x) + g0 * fa[:, None] + g1 * fb[:, None]
    return ActiveResult(times, sensors, velocity, force, energy)
