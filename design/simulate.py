"""Closed-loop plant simulation: modal truss model (full or reduced) with LuGre joints.

The plant is Eq. 12 in modal coordinates (``modal.ModalModel``)::

    ẋ = A·x − B·u_R + H·w,   v = Bᵀx,   φ̇_j = f(v_j, φ_j)  (Eq. 1),   u_R,j = r_j·F_N,j·μ_j  (Eq. 2)

and a controller behind one interface, ``step(measurements) -> normal_forces``, called every
``controller.sample_time`` with the normal forces held in between (zero-order hold).

Integration scheme (fixed step h, stiff bristles without tiny steps):

* The linear modal part is discretised exactly per 2×2 mode block for inputs that vary
  linearly over the step (first-order hold): x⁺ = Φx + γ0·f + γ1·f⁺ with f = −e_iᵀu_R + h_iᵀw
  the modal force at both step ends. Any ω·h is exact, so the kHz connector modes of the full
  model cost nothing in accuracy or stability.
* The joints are solved implicitly: the end-of-step velocity satisfies
  v⁺ = v_free − G·u_R(v⁺) with G = Σ_i γ1,i e_i e_iᵀ (l×l), where u_R(v⁺) uses the bristle
  state φ⁺ of the exact-exponential step of ``lugre.py`` at the midpoint velocity. This is a
  Newton solve in the l joint velocities only (diagonal ∂u_R/∂v). The stiff bristle coupling
  (σ0·F_N·r² ≈ 10⁷ N/m) is thereby treated like the trapezoidal rule treats a stiff spring:
  A-stable, second order, no artificial damping. The bristle state itself uses an exponential
  integrator with first-order hold on v (see ``_Joints.advance``). Where a falling Stribeck
  branch is steeper than the step's compliance allows, the solve has no unique root; that
  step is halved (recursively, at most 2⁸ pieces) — the stick-to-slip transitions are the
  only places that need it.
* Normal-force jumps at controller samples act at once: u_R at the step start is recomputed
  with the new F_N before the step (the piezo is taken as instantaneous here).

Global error O(h²) for smooth motion; a sliding reversal inside a step costs O(h²) locally (the
kink of |v| in Eq. 1). ``reference_simulation`` integrates the same ODE with scipy's Radau
and an analytic Jacobian, tests/test_simulate.py compares both and measures the order.

Energy (Eq. 32): e(t) = ½xᵀx is the kinetic plus strain energy of the structure (the states
are [η̇_i, ω_iη_i] of mass-normalised coordinates); the paper's measure is E(t_e) = ∫₀^t_e xᵀx dt.
The run also books the energy balance e(t) − e(0) = W_in − W_joints − W_damping.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np
import scipy.linalg

from . import lugre
from .errors import ModelError
from .modal import ModalModel


@dataclass
class Measurements:
    """What a controller sees at a sample: time, sensors y, joint velocities v, friction u_R, F_N."""

    time: float
    sensors: np.ndarray
    sliding_velocity: np.ndarray
    friction_force: np.ndarray
    normal_force: np.ndarray


class Controller(Protocol):
    sample_time: float

    def reset(self) -> None: ...

    def step(self, measurements: Measurements) -> np.ndarray: ...


@dataclass
class ConstantNormalForce:
    """Passive joints: a constant normal force per joint."""

    normal_forces: np.ndarray
    sample_time: float = 1e-3

    def reset(self) -> None:
        pass

    def step(self, measurements: Measurements) -> np.ndarray:
        return np.asarray(self.normal_forces, dtype=float)


def triangular_pulse(amplitude: float = 200.0, duration: float = 0.04, directions=(1.0, 1.0)) -> Callable:
    """The paper's tip disturbance (Section 4.3): a triangular force pulse, peak ``amplitude``
    at duration/2, zero after ``duration``, applied along each disturbance input with the
    given factors (y and z: both 1)."""
    directions = np.asarray(directions, dtype=float)
    if not (amplitude >= 0 and duration > 0):
        raise ModelError(f"pulse: amplitude {amplitude!r} must be >= 0 and duration {duration!r} > 0")

    def w(t: float) -> np.ndarray:
        shape = max(0.0, 1.0 - abs(2.0 * t / duration - 1.0)) if 0.0 <= t <= duration else 0.0
        return amplitude * shape * directions

    w.breakpoints = (0.0, 0.5 * duration, duration)
    return w


@dataclass
class SimulationResult:
    time: np.ndarray
    sensors: np.ndarray  # (n_t, n_y)
    sliding_velocity: np.ndarray  # (n_t, l)
    friction_force: np.ndarray  # (n_t, l)
    normal_force: np.ndarray  # (n_t, l) held value on [t_k, t_k+1)
    deflection: np.ndarray  # φ (n_t, l)
    energy: np.ndarray  # ½xᵀx (n_t,)
    work_in: np.ndarray  # ∫ η̇ᵀh w dt
    work_joints: np.ndarray  # ∫ u_Rᵀv dt
    work_damping: np.ndarray  # ∫ Σ 2ξω η̇² dt
    joint_names: list[str] = field(default_factory=list)
    sensor_names: list[str] = field(default_factory=list)

    def energy_measure(self, t_end: float | None = None) -> float:
        """Eq. 32: E(t_e) = ∫₀^t_e xᵀx dt (= 2∫ e dt)."""
        mask = self.time <= (self.time[-1] if t_end is None else t_end) + 1e-12
        return float(np.trapezoid(2.0 * self.energy[mask], self.time[mask]))

    def balance_error(self) -> float:
        """Largest |e(t) − e(0) − (W_in − W_joints − W_damping)| relative to the peak energy."""
        residual = self.energy - self.energy[0] - (self.work_in - self.work_joints - self.work_damping)
        return float(np.max(np.abs(residual)) / max(np.max(self.energy), 1e-300))


def discretise(model: ModalModel, step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact first-order-hold discretisation of every mode block for a unit modal force.

    Returns Φ (n, 2, 2), γ0 (n, 2), γ1 (n, 2) with x⁺ = Φx + γ0·f_k + γ1·f_{k+1}.
    """
    n = model.n_coordinates
    aug = np.zeros((n, 4, 4))
    aug[:, 0, 0] = -2.0 * model.damping * model.omega * step
    aug[:, 0, 1] = -model.omega * step
    aug[:, 1, 0] = model.omega * step
    aug[:, 0, 2] = step  # input enters η̈
    aug[:, 2, 3] = 1.0
    ex = scipy.linalg.expm(aug)
    phi = ex[:, :2, :2]
    gamma_a = ex[:, :2, 2]  # ∫ e^{A(h−τ)} b dτ
    gamma_b = ex[:, :2, 3]  # (1/h) ∫ e^{A(h−τ)} b τ dτ
    return phi, gamma_a - gamma_b, gamma_b


class _Joints:
    """Vectorised LuGre laws of the l joints (per unit normal force, times r·F_N)."""

    def __init__(self, parameters: list[lugre.LuGreParameters]):
        self.s0 = np.array([p.sigma0 for p in parameters])
        self.s1 = np.array([p.sigma1 for p in parameters])
        self.s2 = np.array([p.sigma2 for p in parameters])
        self.fc = np.array([p.coulomb for p in parameters])
        self.fd = np.array([p.stribeck for p in parameters])
        self.vs = np.array([p.stribeck_velocity for p in parameters])
        self.arm = np.array([p.moment_arm for p in parameters])
        self.bound = np.array([p.max_deflection for p in parameters])

    def level(self, v):
        return self.fc + self.fd * np.exp(-(v / self.vs) ** 2)

    def advance(self, phi, v_start, v_end, h):
        """φ⁺ of Eq. 1, φ̇ = v − ρφ with ρ = σ0|v|/(F_c + F_d·e^{−(v/v_s)²}) frozen at the
        midpoint velocity and v linear over the step — solved exactly (exponential integrator
        with first-order hold):

            φ⁺ = e^{−ρh}φ + h·[(φ1(ρh) − φ2(ρh))·v_k + φ2(ρh)·v_{k+1}],
            φ1(x) = (1 − e^{−x})/x,  φ2(x) = (1 − φ1(x))/x.

        Unlike the midpoint-velocity step of ``lugre.step`` it keeps second order when ρh ≫ 1
        (fast sliding: φ follows φ_ss(v(t)), not φ_ss of the midpoint), and it is the
        trapezoidal rule for ρh → 0. |φ| is clipped to φ_max, the bound of the exact solution.
        """
        mid = 0.5 * (v_start + v_end)
        x = self.s0 * np.abs(mid) / self.level(mid) * h
        small = x < 1e-4
        xs = np.where(small, 1.0, x)
        phi1 = np.where(small, 1.0 - x / 2.0 + x * x / 6.0, -np.expm1(-xs) / xs)
        phi2 = np.where(small, 0.5 - x / 6.0 + x * x / 24.0, (1.0 - phi1) / xs)
        out = np.exp(-x) * phi + h * ((phi1 - phi2) * v_start + phi2 * v_end)
        return np.clip(out, -self.bound, self.bound)

    def mu(self, v, phi):
        phidot = v - self.s0 * np.abs(v) / self.level(v) * phi
        return self.s0 * phi + self.s1 * phidot + self.s2 * v

    def force(self, v, phi, normal_force):
        return self.arm * normal_force * self.mu(v, phi)


def _check(model: ModalModel, joints, duration, step, controller):
    l = model.joint_input.shape[1]
    if len(joints) != l:
        raise ModelError(f"joints: {len(joints)} LuGre parameter sets for {l} joints in the model")
    if not (math.isfinite(duration) and duration > 0):
        raise ModelError(f"duration: {duration!r} — must be a positive number of seconds")
    if not (math.isfinite(step) and 0 < step <= duration):
        raise ModelError(f"step: {step!r} — must be > 0 and <= the duration")
    ratio = controller.sample_time / step
    if not (ratio >= 1 and abs(ratio - round(ratio)) < 1e-9 * ratio):
        raise ModelError(f"controller sample time {controller.sample_time!r} s must be a whole multiple of the "
                         f"plant step {step!r} s")
    return l, int(round(ratio))


def simulate(model: ModalModel, joints: list[lugre.LuGreParameters], controller: Controller,
             disturbance: Callable[[float], np.ndarray] | None = None, duration: float = 1.0, step: float = 1e-4,
             initial_state: np.ndarray | None = None, progress: Callable[[str], None] | None = None,
             record_every: int = 1) -> SimulationResult:
    """Run the closed loop for ``duration`` seconds at plant step ``step`` (see module docstring)."""
    l, ratio = _check(model, joints, duration, step, controller)
    n = model.n_coordinates
    m = model.disturbance_input.shape[1]
    law = _Joints(joints) if l else None
    phi_d, g0, g1 = discretise(model, step)
    Em = model.joint_input  # (n, l)
    Hm = model.disturbance_input  # (n, m)
    two_xi_w = 2.0 * model.damping * model.omega
    G = (Em * g1[:, 0:1]).T @ Em  # (l, l): end-of-step velocity per end-of-step joint force
    A, B, H, Cv, Cy = model.state_space()
    Vy = model.velocity_output
    Dy = model.displacement_output / model.omega

    levels = {0: (phi_d, g0, g1, G)}

    def level(depth):
        """Discretisation at step/2^depth (computed when first needed)."""
        if depth not in levels:
            p, a, b = discretise(model, step / 2**depth)
            levels[depth] = (p, a, b, (Em * b[:, 0:1]).T @ Em)
        return levels[depth]

    def advance(X, v, phi, u, w_a, w_b, t, depth):
        """One step of length step/2^depth; halves itself where the joint solve has no unique
        root (a Stribeck slope steeper than the step's compliance allows) and recurses."""
        p, a, b, Gd = level(depth)
        h = step / 2**depth
        X_free = np.einsum("nij,nj->ni", p, X) + a * (Hm @ w_a - Em @ u)[:, None] + b * (Hm @ w_b)[:, None]
        if not l:
            return X_free, v, phi, u
        try:
            v_new, phi_new, u_new = _solve_joints(law, Gd, Em.T @ X_free[:, 0], v, phi, normal_force, h)
        except ModelError:
            if depth >= MAX_HALVINGS:
                raise
            w_mid = np.asarray(w_fun(t + 0.5 * h), dtype=float).reshape(m)
            X, v, phi, u = advance(X, v, phi, u, w_a, w_mid, t, depth + 1)
            return advance(X, v, phi, u, w_mid, w_b, t + 0.5 * h, depth + 1)
        X = X_free - b * (Em @ u_new)[:, None]
        return X, Em.T @ X[:, 0], phi_new, u_new

    steps = int(round(duration / step))
    X = np.zeros((n, 2)) if initial_state is None else np.asarray(initial_state, dtype=float).reshape(n, 2).copy()
    phi = np.zeros(l)
    w_fun = disturbance or (lambda t: np.zeros(m))
    w_now = np.asarray(w_fun(0.0), dtype=float).reshape(m)
    v = Em.T @ X[:, 0]
    controller.reset()
    normal_force = np.zeros(l)
    u = np.zeros(l)

    n_rec = steps // record_every + 1
    rec = {k: np.zeros((n_rec, l)) for k in ("v", "u", "fn", "phi")}
    sensors = np.zeros((n_rec, Vy.shape[0]))
    energy = np.zeros(n_rec)
    works = np.zeros((n_rec, 3))
    time = np.zeros(n_rec)
    w_in = w_joint = w_damp = 0.0
    power_in_prev = float(X[:, 0] @ (Hm @ w_now))
    power_joint_prev = 0.0
    power_damp_prev = float(np.sum(two_xi_w * X[:, 0] ** 2))

    def record(k, t):
        r = k // record_every
        time[r] = t
        rec["v"][r], rec["u"][r], rec["fn"][r], rec["phi"][r] = v, u, normal_force, phi
        sensors[r] = Vy @ X[:, 0] + Dy @ X[:, 1]
        energy[r] = 0.5 * float(np.sum(X * X))
        works[r] = (w_in, w_joint, w_damp)

    report_every = max(steps // 10, 1)
    for k in range(steps + 1):
        t = k * step
        if k % ratio == 0 and k < steps:
            measured = Measurements(t, Vy @ X[:, 0] + Dy @ X[:, 1], v.copy(), u.copy(), normal_force.copy())
            new = np.asarray(controller.step(measured), dtype=float).reshape(l) if l else np.zeros(0)
            if not np.all(np.isfinite(new)) or np.any(new < 0):
                raise ModelError(f"controller returned normal forces {new.tolist()} at t = {t:.6g} s — must be finite "
                                 "and >= 0")
            normal_force = new
            if l:
                u = law.force(v, phi, normal_force)  # F_N acts at once (piezo taken as instantaneous)
                power_joint_prev = float(u @ v)
        if k % record_every == 0:
            record(k, t)
        if k == steps:
            break
        w_next = np.asarray(w_fun(t + step), dtype=float).reshape(m)
        X, v, phi, u = advance(X, v, phi, u, w_now, w_next, t, 0)
        # Energy bookkeeping (trapezoidal in time: consistent to O(h²)).
        power_in = float(X[:, 0] @ (Hm @ w_next))
        power_joint = float(u @ v)
        power_damp = float(np.sum(two_xi_w * X[:, 0] ** 2))
        w_in += 0.5 * step * (power_in_prev + power_in)
        w_joint += 0.5 * step * (power_joint_prev + power_joint)
        w_damp += 0.5 * step * (power_damp_prev + power_damp)
        power_in_prev, power_joint_prev, power_damp_prev = power_in, power_joint, power_damp
        w_now = w_next
        if progress and (k + 1) % report_every == 0:
            progress(f"t = {t + step:.3f} s of {duration:g} s")

    return SimulationResult(time, sensors, rec["v"], rec["u"], rec["fn"], rec["phi"], energy, works[:, 0],
                            works[:, 1], works[:, 2], list(model.joint_names), list(model.sensor_names))


MAX_HALVINGS = 8  # a plant step may split into up to 2^8 substeps where the joints demand it


def _solve_joints(law: _Joints, G, v_free, v_start, phi, normal_force, h, tolerance=1e-12, iterations=30):
    """Newton on R(v) = v − v_free + G·u_R(v) with a diagonal ∂u_R/∂v (finite difference).

    R is monotone (a unique root) unless a falling Stribeck branch is steeper than the step's
    compliance G; then Newton fails, the caller halves the step.
    """
    v = v_free.copy()
    scale = np.maximum(np.abs(v_free), law.vs) + np.abs(v_start)
    for _ in range(iterations):
        phi_new = law.advance(phi, v_start, v, h)
        u = law.force(v, phi_new, normal_force)
        residual = v - v_free + G @ u
        if np.all(np.abs(residual) <= tolerance * scale):
            return v, phi_new, u
        delta = 1e-7 * np.maximum(np.abs(v), law.vs)
        u_d = law.force(v + delta, law.advance(phi, v_start, v + delta, h), normal_force)
        jacobian = np.eye(v.size) + G * ((u_d - u) / delta)[None, :]
        if np.linalg.det(jacobian) <= 0.0:
            break  # a falling branch: no unique root at this step size
        correction = np.linalg.solve(jacobian, residual)
        # Damped near the |v| kink: never move by more than the current scale in one go.
        limit = np.max(np.abs(correction) / scale)
        v = v - (correction if limit <= 1.0 else correction / limit)
    raise ModelError(f"joint solve did not converge at step {h:.3g} s (residual {np.max(np.abs(residual)):.3g}); "
                     "reduce the step")


def reference_simulation(model: ModalModel, joints: list[lugre.LuGreParameters], normal_forces,
                         disturbance: Callable[[float], np.ndarray] | None, duration: float, times: np.ndarray,
                         rtol: float = 1e-10, atol: float = 1e-13, method: str = "Radau"):
    """Eq. 12 for constant normal forces through scipy.integrate.solve_ivp with an analytic
    Jacobian: the accuracy reference for :func:`simulate`. Returns (v, u_R, ½xᵀx) at ``times``."""
    from scipy.integrate import solve_ivp

    l = model.joint_input.shape[1]
    law = _Joints(joints)
    fn = np.asarray(normal_forces, dtype=float)
    A, B, H, Cv, _ = model.state_space()
    ns = A.shape[0]
    m = H.shape[1]
    w_fun = disturbance or (lambda t: np.zeros(m))

    def parts(v, phi):
        level = law.level(v)
        phidot = v - law.s0 * np.abs(v) / level * phi
        u = law.arm * fn * (law.s0 * phi + law.s1 * phidot + law.s2 * v)
        # ∂φ̇/∂v, ∂φ̇/∂φ (one-sided at v = 0)
        d_level = -2.0 * v / law.vs**2 * (level - law.fc)
        dphidot_dv = 1.0 - law.s0 * phi * (np.sign(v) * level - np.abs(v) * d_level) / level**2
        dphidot_dphi = -law.s0 * np.abs(v) / level
        du_dv = law.arm * fn * (law.s1 * dphidot_dv + law.s2)
        du_dphi = law.arm * fn * (law.s0 + law.s1 * dphidot_dphi)
        return u, phidot, du_dv, du_dphi, dphidot_dv, dphidot_dphi

    def rhs(t, z):
        x, phi = z[:ns], z[ns:]
        v = Cv @ x
        u, phidot, *_ = parts(v, phi)
        return np.concatenate([A @ x - B @ u + H @ np.asarray(w_fun(t), dtype=float), phidot])

    def jac(t, z):
        x, phi = z[:ns], z[ns:]
        v = Cv @ x
        _, _, du_dv, du_dphi, dpd_v, dpd_phi = parts(v, phi)
        J = np.zeros((ns + l, ns + l))
        J[:ns, :ns] = A - (B * du_dv[None, :]) @ Cv
        J[:ns, ns:] = -B * du_dphi[None, :]
        J[ns:, :ns] = dpd_v[:, None] * Cv
        J[ns:, ns:] = np.diag(dpd_phi)
        return J

    breaks = sorted({0.0, duration, *[b for b in getattr(disturbance, "breakpoints", ()) if 0 < b < duration]})
    z = np.zeros(ns + l)
    out_z = []
    for a, b in zip(breaks[:-1], breaks[1:]):  # restart at the kinks of the pulse
        inside = times[(times >= a) & (times < b)] if b < duration else times[(times >= a) & (times <= b)]
        sol = solve_ivp(rhs, (a, b), z, method=method, jac=jac, rtol=rtol, atol=atol, dense_output=True)
        if not sol.success:
            raise ModelError(f"reference integration failed: {sol.message}")
        out_z.append(sol.sol(inside).T if inside.size else np.zeros((0, ns + l)))
        z = sol.y[:, -1]
    Z = np.concatenate(out_z)
    x, phi = Z[:, :ns], Z[:, ns:]
    v = x @ Cv.T
    u = law.arm * fn * law.mu(v, phi)
    return v, u, 0.5 * np.sum(x * x, axis=1)


__all__ = ["ConstantNormalForce", "Controller", "Measurements", "SimulationResult", "discretise",
           "reference_simulation", "simulate", "triangular_pulse"]
