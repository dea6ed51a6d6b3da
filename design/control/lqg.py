"""The discrete LQG design of paper Eq. 33 on the reduced modal model.

``design_lqg``: python-control ``dlqr``/``dlqe`` on the reduced modal model discretised exactly
at the sample time (``design.plant.discretisation.discretise``, the plant's own first-order hold),
after the Nyquist rule (``check_sample_time``) and a PBH test per mode block. The controllers that
run the design are in ``filter.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import control as ct
import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.plant.discretisation import discretise
from smartjoint.design.structure.modal import ModalModel


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
            a[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = self.blocks[i]
        return a

    def input_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """Dense Γ0·E and Γ1·E (2n, l), for checks and python-control; the C never forms them."""
        n, e = self.blocks.shape[0], self.joint_input
        g0 = (self.gamma0[:, :, None] * e[:, None, :]).reshape(2 * n, -1)
        g1 = (self.gamma1[:, :, None] * e[:, None, :]).reshape(2 * n, -1)
        return g0, g1

    def blind_modes(self) -> dict[str, tuple[int, ...]]:
        """Coordinates (0-based) that no sensor sees and that no joint moves (`blind_coordinates`)."""
        g0, g1 = self.input_matrices()
        return {"unseen": blind_coordinates(self.output.T), "unmoved": blind_coordinates(g0 + g1)}

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


def check_sample_time(model: ModalModel, sample_time: float) -> None:
    """Rule: every retained oscillating mode below the Nyquist frequency, f_max·Δt < 1/2 — above
    it the discrete model aliases the mode and the estimator cannot tell it from a slower one.
    Coordinates damped at or above critical (ξ ≥ 1: the quasi-static Krylov corrections) have
    real poles, nothing that oscillates or aliases, and are exempt.

    Parameters
    ----------
    model : ModalModel
        The retained modes.
    sample_time : float
        Δt [s].

    Raises
    ------
    ModelError
        For a Δt that is not a finite positive number or too coarse for the highest mode.
    """
    if not (math.isfinite(sample_time) and sample_time > 0):
        raise ModelError(f"sample_time: {sample_time!r} — must be a finite number > 0 [s]")
    oscillating = model.omega[model.damping < 1.0]
    if oscillating.size == 0:
        return
    highest = float(oscillating.max()) / (2 * math.pi)
    if highest * sample_time >= 0.5:
        raise ModelError(
            f"sample_time: {sample_time:g} s is too coarse for the highest retained mode "
            f"({highest:.1f} Hz): rule f_max·Δt < 1/2 (Nyquist) — use Δt < {0.5 / highest:.3g} s "
            "or retain fewer modes"
        )


def design_lqg(
    model: ModalModel,
    sample_time: float,
    state_weight: float = 1.0,
    control_weight: float = 1e-6,
    process_noise: float = 1e4,
    measurement_noise: float = 1e-10,
) -> LqgDesign:
    """LQR + Kalman filter (Eq. 33) for the reduced model at the controller sample time.

    Model: exact discretisation (``discretisation.discretise``) of each mode block; friction enters
    as −E·u_R, disturbances as H·w (process noise, intensity ``process_noise`` N² per input),
    sensors y = C·x with noise ``measurement_noise`` m². Gains from python-control
    (``dlqr``, ``dlqe``); stabilisability and detectability are checked first (PBH test on
    every mode block), and a Riccati failure is reported with the weights that caused it.

    Parameters
    ----------
    model : ModalModel
        The reduced model (joints frictionless).
    sample_time : float
        Δt [s], below the Nyquist rule of :func:`check_sample_time`.
    state_weight, control_weight : float
        Q = q·I on the modal state, R = r·I on the joint forces.
    process_noise : float
        Intensity of the disturbance inputs [N²].
    measurement_noise : float
        Sensor noise intensity [m²].

    Returns
    -------
    LqgDesign
        The discrete model, the LQR gain K and the Kalman gain M.

    Raises
    ------
    ModelError
        For a non-positive weight, an unstabilisable or undetectable mode, or a Riccati failure.
    """
    check_sample_time(model, sample_time)
    _check_weights(
        state_weight=state_weight,
        control_weight=control_weight,
        process_noise=process_noise,
        measurement_noise=measurement_noise,
    )
    n, l = model.n_coordinates, model.joint_input.shape[1]
    ny = model.velocity_output.shape[0]
    if l == 0:
        raise ModelError("design has no joints: the LQG needs at least one friction joint as actuator")
    if ny == 0:
        raise ModelError("design has no [[sensors]]: the Kalman filter needs the measured tip deflections")
    phi, g0, g1 = discretise(model, sample_time)
    a = np.zeros((2 * n, 2 * n))
    for i in range(n):
        a[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = phi[i]
    e, h = model.joint_input, model.disturbance_input
    gz = g0 + g1  # ZOH: a force held over the sample
    b = -(gz[:, :, None] * e[:, None, :]).reshape(2 * n, l)
    g = (gz[:, :, None] * h[:, None, :]).reshape(2 * n, h.shape[1])
    c = np.zeros((ny, 2 * n))
    c[:, 0::2] = model.velocity_output
    c[:, 1::2] = model.displacement_output / model.omega
    _check_pbh(a, b, "stabilisable", "no friction joint moves mode", model)
    _check_pbh(a.T, c.T, "detectable", "no sensor sees mode", model)
    weights = (state_weight, control_weight, process_noise, measurement_noise)
    k, s, p = _riccati(a, b, c, g, weights)
    m = p @ c.T @ np.linalg.inv(c @ p @ c.T + measurement_noise * np.eye(ny))
    return LqgDesign(sample_time, phi, g0, g1, np.array(e, dtype=float), c, k, m, s, p)


def _riccati(a, b, c, g, weights: tuple[float, float, float, float]):
    """The LQR gain K, its Riccati solution S and the filter's P (python-control ``dlqr``,
    ``dlqe``) for ``weights`` = (q, r, process noise, measurement noise); a failure in one line."""
    state_weight, control_weight, process_noise, measurement_noise = weights
    try:
        k, s, _ = ct.dlqr(a, b, state_weight * np.eye(a.shape[0]), control_weight * np.eye(b.shape[1]))
        # G·Q_N·Gᵀ formed and symmetrised here: python-control checks symmetry to an absolute eps,
        # which the rounding of a large product (a long, soft truss) exceeds.
        noise = process_noise * (g @ g.T)
        _, p, _ = ct.dlqe(a, np.eye(a.shape[0]), c, 0.5 * (noise + noise.T), measurement_noise * np.eye(c.shape[0]))
    except Exception as failure:  # python-control / slycot raise several types
        raise ModelError(
            f"Riccati solver failed ({type(failure).__name__}: {failure}) for state_weight "
            f"{state_weight:g}, control_weight {control_weight:g}, process_noise {process_noise:g}, "
            f"measurement_noise {measurement_noise:g}"
        ) from None
    k, s, p = np.asarray(k), np.asarray(s), np.asarray(p)
    if not (np.all(np.isfinite(k)) and np.all(np.isfinite(p))):
        raise ModelError("Riccati solver returned non-finite gains; check the weights")
    return k, s, p


def _check_weights(**weights: float) -> None:
    """Each weight and noise intensity a finite number > 0 (Riccati needs Q, R > 0)."""
    for name, value in weights.items():
        if not (math.isfinite(value) and value > 0):
            raise ModelError(f"{name}: {value!r} — must be a finite number > 0")


def _check_pbh(a, b, word, reason, model) -> None:
    """PBH rank test per 2×2 mode block (modes are decoupled): rank[A − λI, B] = 2 for each λ
    on or outside the unit circle; and at least one mode that ``b`` reaches at all."""
    n = a.shape[0] // 2
    for i in range(n):
        block = a[2 * i : 2 * i + 2, 2 * i : 2 * i + 2]
        rows = b[2 * i : 2 * i + 2]
        for lam in np.linalg.eigvals(block):
            if abs(lam) < 1.0 - 1e-12:
                continue  # stable modes need no control/observation
            test = np.hstack([block - lam * np.eye(2), rows])
            if np.linalg.matrix_rank(test, tol=1e-12 * max(1.0, np.abs(test).max())) < 2:
                raise ModelError(
                    f"reduced model is not {word}: {reason} {i + 1} "
                    f"({model.omega[i] / 2 / np.pi:.2f} Hz) with |λ| = {abs(lam):.6f}"
                )
    if len(blind_coordinates(b)) == n:
        raise ModelError(f"reduced model is not {word} in practice: {reason.removesuffix(' mode')} any mode")


def blind_coordinates(b: np.ndarray) -> tuple[int, ...]:
    """The coordinates whose 2-row block of ``b`` (an input matrix, or Cᵀ) is zero to round-off.

    With structural damping every mode is strictly stable, so such a coordinate leaves the design
    detectable and stabilisable: no joint moves it (the LQR leaves it alone), or no sensor sees it
    (the filter predicts it from the measured friction forces alone, Eq. 33). A symmetric truss
    has such modes (a triangular mast's axial modes under tip sensors).

    Parameters
    ----------
    b : ndarray (2n, k)

    Returns
    -------
    tuple of int
        0-based coordinates whose rows are at most 1e-14 of the largest block's norm.
    """
    norms = np.linalg.norm(b.reshape(b.shape[0] // 2, 2, -1), axis=(1, 2))
    top = norms.max() if norms.size else 0.0
    return tuple(int(i) for i in np.flatnonzero(norms <= 1e-14 * max(top, 1e-300)))


__all__ = ["LqgDesign", "blind_coordinates", "check_sample_time", "design_lqg"]
