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
The run also books the energy balance e(t) − e(0) = W_in − W_joints − W_damping, each work
integrated *exactly* over every step for the forces the step applies (disturbance and friction
linear over the step, the modal motion the exact solution under them; ``work_coefficients``):
W_in = ∫ wᵀHᵀη̇ dt, W_joints = ∫ u_Rᵀv dt, W_damping = ∫ Σ 2ξω η̇² dt. The three are computed
independently of e(t), so the balance closing to round-off checks the discretisation, the
books and the bookkeeping of F_N jumps together; how close the discrete trajectory is to the
continuous one is measured against Radau instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np
import scipy.linalg

from smartjoint.design.friction import lugre
from smartjoint.common.errors import ModelError
from smartjoint.design.structure.modal import ModalModel


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
    holds_constant = True  # simulate() asks once and runs the whole span in one kernel call

    def reset(self) -> None:
        pass

    def step(self, measurements: Measurements) -> np.ndarray:
        return np.asarray(self.normal_forces, dtype=float)


class TriangularPulse:
    """The paper's tip disturbance (Section 4.3): a triangular force pulse, peak ``amplitude``
    at duration/2, zero after ``duration``, applied along each disturbance input with the
    given factors (y and z: both 1). ``w(t)`` for one time, ``sample(times)`` for many."""

    def __init__(self, amplitude: float = 200.0, duration: float = 0.04, directions=(1.0, 1.0)):
        if not (math.isfinite(amplitude) and amplitude >= 0 and math.isfinite(duration) and duration > 0):
            raise ModelError(f"pulse: amplitude {amplitude!r} must be >= 0 and duration {duration!r} > 0")
        self.amplitude, self.duration = float(amplitude), float(duration)
        self.directions = np.asarray(directions, dtype=float).reshape(-1)
        self.breakpoints = (0.0, 0.5 * duration, duration)
        self.support_end = self.duration  # w(t) = 0 after this time: a long run samples only the pulse

    def sample(self, times) -> np.ndarray:
        t = np.asarray(times, dtype=float).reshape(-1)
        out = np.zeros((t.size, self.directions.size))
        inside = np.flatnonzero((t >= 0) & (t <= self.duration))  # a long run is mostly after the pulse
        shape = np.maximum(0.0, 1.0 - np.abs(2.0 * t[inside] / self.duration - 1.0))
        out[inside] = self.amplitude * shape[:, None] * self.directions[None, :]
        return out

    def __call__(self, t: float) -> np.ndarray:
        return self.sample([t])[0]


def triangular_pulse(amplitude: float = 200.0, duration: float = 0.04, directions=(1.0, 1.0)) -> TriangularPulse:
    return TriangularPulse(amplitude, duration, directions)


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


def work_coefficients(model: ModalModel, step: float) -> np.ndarray:
    """Exact work integrals of one step per mode, for the energy books.

    With y = [η̇, ωη, f_a, f_b] (state at the step start, modal force at both ends, linear in
    between) the exact modal motion gives η̇(t) = r(t)ᵀy, so over the step

        m0 = ∫ η̇ dt = c0ᵀy,   m1 = ∫ (t/h)·η̇ dt = c1ᵀy,   ∫ 2ξω η̇² dt = yᵀDy,

    and the work of any force p linear over the step is p_a·m0 + (p_b − p_a)·m1. Computed in
    normalised time τ = t/h by augmented matrix exponentials (Van Loan 1978): Γ1 = ∫₀¹e^{Ãτ}dτ,
    Γ2 = ∫₀¹(1−τ)e^{Ãτ}dτ and the Gram integral ∫₀¹e^{Ãᵀτ}e1e1ᵀe^{Ãτ}dτ, with Ã the mode block
    driven by f and its increment Δ = f_b − f_a as states. Returns (18, n): rows c0 (4), c1 (4),
    then D00, D11, D22, D33, 2D01, 2D02, 2D03, 2D12, 2D13, 2D23.
    """
    n = model.n_coordinates
    w, zeta = model.omega * step, 2.0 * model.damping * model.omega
    a = np.zeros((n, 4, 4))  # d/dτ [η̇, ωη, f, Δ]
    a[:, 0, 0], a[:, 0, 1], a[:, 1, 0], a[:, 0, 2], a[:, 2, 3] = -zeta * step, -w, w, step, 1.0
    eye = np.broadcast_to(np.eye(4), (n, 4, 4))
    linear = np.zeros((n, 12, 12))
    linear[:, :4, :4], linear[:, :4, 4:8], linear[:, 4:8, 8:] = a, eye, eye
    ex = scipy.linalg.expm(linear)
    gamma1, gamma2 = ex[:, :4, 4:8], ex[:, :4, 8:]
    to_ends = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, -1.0, 1.0]])  # y → [x, f_a, Δ]
    c0 = step * gamma1[:, 0, :] @ to_ends
    c1 = step * (gamma1[:, 0, :] - gamma2[:, 0, :]) @ to_ends
    gram_block = np.zeros((n, 8, 8))
    gram_block[:, :4, :4], gram_block[:, 4:, 4:] = -np.transpose(a, (0, 2, 1)), a
    gram_block[:, 0, 4] = 1.0
    ex = scipy.linalg.expm(gram_block)
    gram = np.transpose(ex[:, 4:, 4:], (0, 2, 1)) @ ex[:, :4, 4:]
    D = (zeta * step)[:, None, None] * (to_ends.T @ gram @ to_ends)
    D = 0.5 * (D + np.transpose(D, (0, 2, 1)))
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    rows = [c0.T, c1.T, np.stack([D[:, k, k] for k in range(4)]), np.stack([2.0 * D[:, i, j] for i, j in pairs])]
    return np.ascontiguousarray(np.concatenate(rows))


def _book(c, y0, y1, f_a, f_b):
    """m0, m1 and the damping work per mode for the rows of ``work_coefficients``."""
    m0 = c[0] * y0 + c[1] * y1 + c[2] * f_a + c[3] * f_b
    m1 = c[4] * y0 + c[5] * y1 + c[6] * f_a + c[7] * f_b
    damping = (y0 * (c[8] * y0 + c[12] * y1 + c[13] * f_a + c[14] * f_b) + y1 * (c[9] * y1 + c[15] * f_a + c[16] * f_b)
               + f_a * (c[10] * f_a + c[17] * f_b) + c[11] * f_b * f_b)
    return m0, m1, damping


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
        return self.fc + self.fd * np.exp(-(v / self.vs) * (v / self.vs))

    def advance(self, phi, v_start, v_end, h, derivative=False):
        """φ⁺ of Eq. 1, φ̇ = v − ρφ with ρ = σ0|v|/(F_c + F_d·e^{−(v/v_s)²}) frozen at the
        midpoint velocity and v linear over the step — solved exactly (exponential integrator
        with first-order hold):

            φ⁺ = e^{−ρh}φ + h·[(φ1(ρh) − φ2(ρh))·v_k + φ2(ρh)·v_{k+1}],
            φ1(x) = (1 − e^{−x})/x,  φ2(x) = (1 − φ1(x))/x.

        Unlike the midpoint-velocity step of ``lugre.step`` it keeps second order when ρh ≫ 1
        (fast sliding: φ follows φ_ss(v(t)), not φ_ss of the midpoint), and it is the
        trapezoidal rule for ρh → 0. |φ| is clipped to φ_max, the bound of the exact solution.
        With ``derivative`` also returns ∂φ⁺/∂v_{k+1} (for the Newton solve).
        """
        mid = 0.5 * (v_start + v_end)
        g = self.level(mid)
        x = self.s0 * np.abs(mid) / g * h
        small = x < SERIES
        xs = np.where(small, 1.0, x)
        decay_minus_one = np.expm1(-x)  # one call serves both e^{−x} and φ1 (as the C kernel)
        decay = 1.0 + decay_minus_one
        phi1 = np.where(small, 1.0 - x / 2.0 + x * x / 6.0, -decay_minus_one / xs)
        phi2 = np.where(small, 0.5 - x / 6.0 + x * x / 24.0, (1.0 - phi1) / xs)
        raw = decay * phi + h * ((phi1 - phi2) * v_start + phi2 * v_end)
        out = np.clip(raw, -self.bound, self.bound)
        if not derivative:
            return out
        dg = -2.0 * mid / self.vs**2 * (g - self.fc)
        dx = 0.5 * self.s0 * h * (np.sign(mid) * g - np.abs(mid) * dg) / (g * g)
        dphi1 = np.where(small, -0.5 + x / 3.0, (decay - phi1) / xs)
        dphi2 = np.where(small, -1.0 / 6.0 + x / 12.0, (-dphi1 - phi2) / xs)
        d_out = (-decay * phi + h * ((dphi1 - dphi2) * v_start + dphi2 * v_end)) * dx + h * phi2
        return out, np.where(np.abs(raw) > self.bound, 0.0, d_out)

    def mu(self, v, phi):
        phidot = v - self.s0 * np.abs(v) / self.level(v) * phi
        return self.s0 * phi + self.s1 * phidot + self.s2 * v

    def force(self, v, phi, normal_force):
        return self.arm * normal_force * self.mu(v, phi)

    def force_derivatives(self, v, phi, normal_force):
        """u_R of Eq. 2 with ∂u_R/∂v and ∂u_R/∂φ."""
        g = self.level(v)
        dg = -2.0 * v / self.vs**2 * (g - self.fc)
        scale = self.arm * normal_force
        dphidot_dv = 1.0 - self.s0 * phi * (np.sign(v) * g - np.abs(v) * dg) / (g * g)
        d_v = scale * (self.s1 * dphidot_dv + self.s2)
        d_phi = scale * (self.s0 - self.s1 * self.s0 * np.abs(v) / g)
        return self.force(v, phi, normal_force), d_v, d_phi


SERIES = 1e-4  # ρh below which φ1, φ2 use their Taylor series
MAX_HALVINGS = 8  # a plant step may split into up to 2^8 substeps where the joints demand it
TOLERANCE = 1e-12  # Newton: |residual| ≤ TOLERANCE·(max(|v_free|, v_s) + |v_k|)
ITERATIONS = 30
MAX_DISTURBANCES = 64  # the C kernel keeps the halving's midpoint disturbance on its stack


class _SolveFailed(Exception):
    def __init__(self, residual):
        self.residual = residual


def _solve_joints(law: _Joints, G, v_free, v_start, phi, normal_force, h, u_start):
    """Newton on R(v) = v − v_free + G·u_R(v) with the analytic Jacobian I + G·diag(du_R/dv).

    R is monotone (a unique root) unless a falling Stribeck branch is steeper than the step's
    compliance G; then det J ≤ 0 or Newton stalls, and the caller halves the step. The start
    holds the friction force at its step-start value u_start: in stick the root is close to it.
    """
    v = v_free - G @ u_start
    scale = np.maximum(np.abs(v_free), law.vs) + np.abs(v_start)
    residual = np.zeros_like(v)
    for _ in range(ITERATIONS):
        phi_new, dphi = law.advance(phi, v_start, v, h, derivative=True)
        u, du_dv, du_dphi = law.force_derivatives(v, phi_new, normal_force)
        residual = v - v_free + G @ u
        if np.all(np.abs(residual) <= TOLERANCE * scale):
            return v, phi_new, u
        jacobian = np.eye(v.size) + G * (du_dv + du_dphi * dphi)[None, :]
        if not np.linalg.det(jacobian) > 0.0:
            break  # a falling branch: no unique root at this step size
        correction = np.linalg.solve(jacobian, residual)
        # Damped near the |v| kink: never move by more than the current scale in one go.
        limit = np.max(np.abs(correction) / scale)
        v = v - (correction if limit <= 1.0 else correction / limit)
    raise _SolveFailed(float(np.max(np.abs(residual))))


class _Plant:
    """Everything a run needs that does not change during it, laid out as structure of arrays
    (rows of length n) like ``plant_kernel.c``: discretisation at step/2^d for
    d = 0…MAX_HALVINGS, the transposed input matrices, the outputs and the joint laws."""

    def __init__(self, model: ModalModel, joints, step: float, books: bool = True, discretised: bool = True):
        self.n, self.l = model.n_coordinates, model.joint_input.shape[1]
        self.m, self.ny = model.disturbance_input.shape[1], model.velocity_output.shape[0]
        self.step = step
        # (l, n), padded with zero rows to a multiple of 4: the C kernel takes four joints per pass
        self.ET_padded = np.zeros((-(-self.l // 4) * 4, self.n))
        self.ET_padded[:self.l] = model.joint_input.T
        self.ET = self.ET_padded[:self.l]
        self.HT = np.ascontiguousarray(model.disturbance_input.T, dtype=float)  # (m, n)
        self.Vy = np.ascontiguousarray(model.velocity_output, dtype=float)
        self.Dy = np.ascontiguousarray(model.displacement_output / model.omega, dtype=float)
        self.two_xi_w = 2.0 * model.damping * model.omega
        self.law = _Joints(joints)
        levels = MAX_HALVINGS + 1 if discretised else 0  # the stick-exact scheme brings its own
        self.phi, self.g0, self.g1 = np.zeros((levels, 4, self.n)), np.zeros((levels, 2, self.n)), np.zeros((levels, 2, self.n))
        self.G = np.zeros((levels, self.l, self.l))
        self.books = books
        self.book = np.zeros((levels, 18, self.n if books else 0))
        for d in range(levels):
            if books:
                self.book[d] = work_coefficients(model, step / 2**d)
            phi, g0, g1 = discretise(model, step / 2**d)
            self.phi[d] = phi.reshape(self.n, 4).T
            self.g0[d], self.g1[d] = g0.T, g1.T
            self.G[d] = (self.ET * g1[:, 0]) @ self.ET.T


class _State:
    """The plant state a kernel advances in place: x (2, n) = [η̇; ωη], q = E·u_R (n), and per joint
    v, φ, u_R, F_N."""

    def __init__(self, plant: _Plant, initial_state):
        n, l = plant.n, plant.l
        self.x = np.zeros((2, n)) if initial_state is None else \
            np.ascontiguousarray(np.array(initial_state, dtype=float).reshape(n, 2).T)
        self.q = np.zeros(n)
        self.v = plant.ET @ self.x[0]
        self.phi, self.u, self.fn = np.zeros(l), np.zeros(l), np.zeros(l)
        self.works = np.zeros(3)  # W_in, W_joints, W_damping


class _Recorder:
    def __init__(self, plant: _Plant, rows: int):
        l = plant.l
        self.v, self.u, self.fn, self.phi = (np.zeros((rows, l)) for _ in range(4))
        self.sensors = np.zeros((rows, plant.ny))
        self.energy = np.zeros(rows)
        self.works = np.zeros((rows, 3))


class _PythonKernel:
    """The fixed-step scheme in numpy: the readable mirror of ``plant_kernel.c``."""

    name = "python"

    def __init__(self, plant: _Plant, state: _State, recorder: _Recorder):
        self.p, self.s, self.r = plant, state, recorder

    def set_normal_force(self, normal_force):
        s = self.s
        s.fn[:] = normal_force
        s.u[:] = self.p.law.force(s.v, s.phi, s.fn)  # F_N acts at once (piezo taken as instantaneous)
        s.q[:] = self.p.ET.T @ s.u

    def start(self, w0):
        self.s.works[:] = 0.0 if self.p.books else np.nan

    def record_row(self, row):
        s, r, p = self.s, self.r, self.p
        r.v[row], r.u[row], r.fn[row], r.phi[row] = s.v, s.u, s.fn, s.phi
        r.sensors[row] = p.Vy @ s.x[0] + p.Dy @ s.x[1]
        r.energy[row] = 0.5 * float(np.sum(s.x * s.x))
        r.works[row] = s.works

    def _advance(self, w_a, w_b, depth):
        p, s = self.p, self.s
        Phi, a, b, G = p.phi[depth], p.g0[depth], p.g1[depth], p.G[depth]
        h = p.step / 2**depth
        x0, x1 = s.x
        p_a, p_b = p.HT.T @ w_a, p.HT.T @ w_b
        f_a = p_a - s.q
        f_b = p_b
        free0 = Phi[0] * x0 + Phi[1] * x1 + a[0] * f_a + b[0] * f_b
        free1 = Phi[2] * x0 + Phi[3] * x1 + a[1] * f_a + b[1] * f_b
        if not p.l:
            if p.books:
                m0, m1, damping = _book(p.book[depth], x0, x1, f_a, f_b)
                s.works += (p_a @ m0 + (p_b - p_a) @ m1, 0.0, np.sum(damping))
            s.x[:] = free0, free1
            return
        try:
            v_free = p.ET @ free0
            v_new, phi_new, u_new = _solve_joints(p.law, G, v_free, s.v, s.phi, s.fn, h, s.u)
        except _SolveFailed as failure:
            if depth >= MAX_HALVINGS:
                raise ModelError(f"joint solve did not converge at step {h:.3g} s (residual {failure.residual:.3g}); "
                                 "reduce the step") from None
            w_mid = 0.5 * (w_a + w_b)  # linear in the step, as the first-order hold assumes
            self._advance(w_a, w_mid, depth + 1)
            self._advance(w_mid, w_b, depth + 1)
            return
        s.phi[:], s.u[:] = phi_new, u_new
        q_new = p.ET.T @ u_new
        if p.books:
            m0, m1, damping = _book(p.book[depth], x0, x1, f_a, p_b - q_new)
            s.works += (p_a @ m0 + (p_b - p_a) @ m1, s.q @ m0 + (q_new - s.q) @ m1, np.sum(damping))
        s.q[:] = q_new
        s.x[:] = free0 - b[0] * s.q, free1 - b[1] * s.q
        s.v[:] = v_free - G @ u_new  # = Eᵀx0 exactly; v_free is recomputed from x every step

    def run(self, w, steps, k0, record_every):
        for k in range(steps):
            if (k0 + k) % record_every == 0:
                self.record_row((k0 + k) // record_every)
            self._advance(w[k], w[k + 1], 0)


class _CKernel:
    """``plant_kernel.c`` through cffi; the state arrays are shared with numpy."""

    name = "c"
    DECLARATIONS = """
    typedef struct {
        int n, l, m, ny, levels, books;
        double step;
        const double *phi, *g0, *g1, *G, *book;
        const double *ET, *HT, *Vy, *Dy, *two_xi_w;
        const double *s0, *s1, *s2, *fc, *fd, *vs, *arm, *bound;
        double *work;
    } sj_plant;
    typedef struct {
        double *x, *q, *v, *phi, *u, *fn;
        double work_in, work_joints, work_damping;
        double failed_step, failed_residual;
    } sj_state;
    typedef struct { double *v, *u, *fn, *phi, *sensors, *energy, *works; } sj_record;
    void sj_set_normal_force(const sj_plant *p, sj_state *s, const double *normal_force);
    void sj_start(const sj_plant *p, sj_state *s, const double *w0);
    void sj_record_row(const sj_plant *p, const sj_state *s, const sj_record *r, long row);
    long sj_run(const sj_plant *p, sj_state *s, const double *w, long steps, long k0, long record_every,
                const sj_record *r);
    typedef struct { const double *phi, *g0, *g1, *Gv, *Gp; } sj_stick_step;
    typedef struct {
        int N, Np, n2, l, m, ny;
        int ratio[2];
        double kappa, beta[2];
        sj_stick_step level[3];
        const double *Cv, *Cy;
        const double *s0, *s1, *s2, *fc, *fd, *vs, *arm;
        double *work;
    } sj_stick;
    typedef struct {
        double *z, *d, *v, *u, *fn;
        long steps[3];
        double failed_step, failed_residual;
    } sj_stick_state;
    void sj_stick_set_normal_force(const sj_stick *p, sj_stick_state *s, const double *normal_force);
    void sj_stick_record_row(const sj_stick *p, const sj_stick_state *s, const sj_record *r, long row);
    long sj_stick_run(const sj_stick *p, sj_stick_state *s, const double *w, long w_rows, long longs, long k0,
                      long record_every, const sj_record *r, double H);
    """

    def __init__(self, plant: _Plant, state: _State, recorder: _Recorder):
        from smartjoint.common import package_data
        from smartjoint.common import native

        module = native.load("plant", self.DECLARATIONS, package_data.path("smartjoint.design.plant", "plant_kernel.c"))
        self.ffi, self.lib = ffi, lib = module.ffi, module.lib
        self.p, self.s, self.r = plant, state, recorder
        self._keep = []  # arrays whose memory the C structs point into

        def ptr(array):
            array = np.ascontiguousarray(array, dtype=float)
            self._keep.append(array)
            return ffi.cast("double *", ffi.from_buffer(array))

        law = plant.law
        self.work = np.zeros(5 * plant.n + 7 * plant.l + plant.l**2 + 1)
        self.cp = ffi.new("sj_plant *", dict(
            n=plant.n, l=plant.l, m=plant.m, ny=plant.ny, levels=MAX_HALVINGS + 1, books=int(plant.books), step=plant.step,
            phi=ptr(plant.phi), g0=ptr(plant.g0), g1=ptr(plant.g1), G=ptr(plant.G), book=ptr(plant.book), ET=ptr(plant.ET_padded), HT=ptr(plant.HT),
            Vy=ptr(plant.Vy), Dy=ptr(plant.Dy), two_xi_w=ptr(plant.two_xi_w), s0=ptr(law.s0), s1=ptr(law.s1),
            s2=ptr(law.s2), fc=ptr(law.fc), fd=ptr(law.fd), vs=ptr(law.vs), arm=ptr(law.arm), bound=ptr(law.bound),
            work=ptr(self.work)))
        for name in ("x", "q", "v", "phi", "u", "fn"):  # shared memory: C writes, numpy reads
            setattr(state, name, np.ascontiguousarray(getattr(state, name), dtype=float))
        self.cs = ffi.new("sj_state *", {name: ptr(getattr(state, name)) for name in ("x", "q", "v", "phi", "u", "fn")})
        self.cr = ffi.new("sj_record *", dict(v=ptr(recorder.v), u=ptr(recorder.u), fn=ptr(recorder.fn),
                                              phi=ptr(recorder.phi), sensors=ptr(recorder.sensors),
                                              energy=ptr(recorder.energy), works=ptr(recorder.works)))

    def _pull(self):
        cs = self.cs
        self.s.works[:] = (cs.work_in, cs.work_joints, cs.work_damping)

    def set_normal_force(self, normal_force):
        fn = np.ascontiguousarray(normal_force, dtype=float)
        self.lib.sj_set_normal_force(self.cp, self.cs, self.ffi.cast("double *", self.ffi.from_buffer(fn)))
        self._pull()

    def start(self, w0):
        w0 = np.ascontiguousarray(w0, dtype=float)
        self.lib.sj_start(self.cp, self.cs, self.ffi.cast("double *", self.ffi.from_buffer(w0)))
        self._pull()

    def record_row(self, row):
        self.lib.sj_record_row(self.cp, self.cs, self.cr, row)

    def run(self, w, steps, k0, record_every):
        w = np.ascontiguousarray(w, dtype=float)
        done = self.lib.sj_run(self.cp, self.cs, self.ffi.cast("double *", self.ffi.from_buffer(w)), steps, k0,
                               record_every, self.cr)
        self._pull()
        if done < steps:
            raise ModelError(f"joint solve did not converge at step {self.cs.failed_step:.3g} s (residual "
                             f"{self.cs.failed_residual:.3g}); reduce the step")


_C_FAILURE: list[str] = []  # why the C kernel is unavailable on this machine (reported once)


def _kernel(backend: str, plant: _Plant, state: _State, recorder: _Recorder):
    from smartjoint.common import native

    return native.choose(backend, "plant simulation", lambda: _CKernel(plant, state, recorder),
                         lambda: _PythonKernel(plant, state, recorder), _C_FAILURE)


def _check(model: ModalModel, joints, duration, step, controller, initial_state):
    l = model.joint_input.shape[1]
    if len(joints) != l:
        raise ModelError(f"joints: {len(joints)} LuGre parameter sets for {l} joints in the model")
    if not (math.isfinite(duration) and duration > 0):
        raise ModelError(f"duration: {duration!r} — must be a positive number of seconds")
    if not (math.isfinite(step) and 0 < step <= duration):
        raise ModelError(f"step: {step!r} — must be > 0 and <= the duration")
    sample_time = getattr(controller, "sample_time", None)
    if not (isinstance(sample_time, (int, float)) and math.isfinite(sample_time) and sample_time > 0):
        raise ModelError(f"controller sample_time: {sample_time!r} — must be a positive number of seconds")
    ratio = sample_time / step
    if not (ratio >= 1 and abs(ratio - round(ratio)) < 1e-9 * ratio):
        raise ModelError(f"controller sample time {sample_time!r} s must be a whole multiple of the "
                         f"plant step {step!r} s")
    unstable = np.flatnonzero(~(np.isfinite(model.damping) & (model.damping >= 0) & np.isfinite(model.omega)
                                & (model.omega > 0)))
    if unstable.size:
        i = unstable[0]
        raise ModelError(f"modal model: coordinate {model.labels[i]!r} has ω = {float(model.omega[i])!r} rad/s, "
                         f"ξ = {float(model.damping[i])!r} — need ω > 0 and ξ >= 0 (a stable structure)")
    still = np.flatnonzero(~np.any(model.joint_input != 0.0, axis=0)) if l else []
    if len(still):
        raise ModelError(f"joint {model.joint_names[still[0]]!r}: no coordinate of the model moves it (its column of "
                         "E is zero) — a joint on a rigid DOF cannot slide; move it or add its Krylov vector")
    if model.disturbance_input.shape[1] > MAX_DISTURBANCES:
        raise ModelError(f"disturbances: {model.disturbance_input.shape[1]} inputs — at most {MAX_DISTURBANCES}")
    if initial_state is not None:
        x0 = np.asarray(initial_state, dtype=float)
        if x0.size != 2 * model.n_coordinates or not np.all(np.isfinite(x0)):
            raise ModelError(f"initial_state: {x0.size} values — need {2 * model.n_coordinates} finite values "
                             "([η̇_i, ω_iη_i] per coordinate)")
    return l, int(round(ratio))


def _disturbance_at_steps(disturbance, steps: int, step: float, m: int, compact: bool = False) -> np.ndarray:
    """w at the ends of ``steps`` steps, (steps + 1, m), sampled only up to the disturbance's
    ``support_end`` where it has one (zero after). ``compact``: leave those zero rows out (for a
    kernel that takes missing rows as zero) — a long run then never builds its full time axis."""
    if disturbance is None:
        return np.zeros((0 if compact else steps + 1, m))
    end = getattr(disturbance, "support_end", None)
    inside = steps + 1
    if isinstance(end, (int, float)) and math.isfinite(end) and end >= 0:
        inside = min(steps + 1, int(math.floor(end / step)) + 2)  # one sample past the end, to be sure
    values = _disturbance_samples(_Unbounded(disturbance), np.arange(inside) * step, m)
    if compact or inside == steps + 1:
        return values
    return np.concatenate([values, np.zeros((steps + 1 - inside, m))])


def _disturbance_samples(disturbance, times: np.ndarray, m: int) -> np.ndarray:
    """w at the given times, (n_t, m): one vectorised call where the function offers it."""
    if disturbance is None:
        return np.zeros((times.size, m))
    sample = getattr(disturbance, "sample", None)
    values = sample(times) if sample else np.array([np.asarray(disturbance(t), dtype=float).reshape(-1)
                                                     for t in times])
    values = np.asarray(values, dtype=float)
    if values.shape != (times.size, m):
        raise ModelError(f"disturbance: returned {values.shape[1:] if values.ndim == 2 else values.shape} values per "
                         f"time — need {m} (one per disturbance input)")
    if not np.all(np.isfinite(values)):
        bad = np.flatnonzero(~np.all(np.isfinite(values), axis=1))[0]
        raise ModelError(f"disturbance: non-finite value {values[bad].tolist()} at t = {times[bad]:.6g} s")
    return values


class _Unbounded:
    """The same disturbance without its ``support_end`` (for sampling inside the support)."""

    def __init__(self, disturbance):
        self.disturbance = disturbance
        self.sample = getattr(disturbance, "sample", None)

    def __call__(self, t):
        return self.disturbance(t)


def simulate(model: ModalModel, joints: list[lugre.LuGreParameters], controller: Controller,
             disturbance: Callable[[float], np.ndarray] | None = None, duration: float = 1.0, step: float = 1e-4,
             initial_state: np.ndarray | None = None, progress: Callable[[str], None] | None = None,
             record_every: int = 1, backend: str = "auto", energy_books: bool = True,
             stick_step: float | None = None) -> SimulationResult:
    """Run the closed loop for ``duration`` seconds at plant step ``step`` (see module docstring).

    The controller is called every ``controller.sample_time`` (a whole multiple of ``step``); a
    controller with ``holds_constant = True`` is asked once, and the whole run is one kernel
    call. ``backend``: "c" (``plant_kernel.c``, compiled on first use), "python" (its numpy
    mirror) or "auto" (C where a compiler is available). ``energy_books``: book W_in, W_joints
    and W_damping exactly every step (18 coefficients per mode; about doubles the step cost of
    a large model); False leaves them NaN — the state, e(t) and Eq. 32 are unaffected.
    ``stick_step``: run the stick-exact scheme of ``stick_exact.py`` instead — long steps of this
    length while every joint sticks, ``step`` elsewhere (reduced models, energy_books=False).
    """
    l, ratio = _check(model, joints, duration, step, controller, initial_state)
    if not (isinstance(record_every, int) and record_every >= 1):
        raise ModelError(f"record_every: {record_every!r} — must be a whole number >= 1")
    if not isinstance(energy_books, bool):
        raise ModelError(f"energy_books: {energy_books!r} — must be True or False")
    if stick_step is not None:
        from smartjoint.design.plant import stick_exact

        stick_exact.check(model, step, stick_step, controller, record_every, energy_books, duration)
    plant = _Plant(model, joints, step, energy_books, discretised=stick_step is None)
    steps = int(round(duration / step))
    state = _State(plant, initial_state)
    recorder = _Recorder(plant, steps // record_every + 1)
    if stick_step is None:
        kernel = _kernel(backend, plant, state, recorder)
    else:
        kernel = stick_exact.kernel(backend, model, plant.law, step, float(stick_step), state, recorder)
    w = _disturbance_at_steps(disturbance, steps, step, plant.m, compact=stick_step is not None)
    controller.reset()
    kernel.start(w[0])
    chunk = steps if getattr(controller, "holds_constant", False) else ratio
    report_every = max(steps // 10, 1)
    next_report = report_every
    for k0 in range(0, steps, chunk):
        t = k0 * step
        sensors = plant.Vy @ state.x[0] + plant.Dy @ state.x[1]
        measured = Measurements(t, sensors, state.v.copy(), state.u.copy(), state.fn.copy())
        raw = controller.step(measured)
        try:
            new = np.asarray(raw, dtype=float)
        except (TypeError, ValueError):
            new = np.array([np.nan])
        if new.shape not in ((l,), (1, l), (l, 1)) or not np.all(np.isfinite(new)) or np.any(new < 0):
            shown = raw.tolist() if isinstance(raw, np.ndarray) else raw
            raise ModelError(f"controller returned normal forces {shown!r} at t = {t:.6g} s — need {l} finite values "
                             f">= 0 (joints {', '.join(model.joint_names)})")
        kernel.set_normal_force(new.reshape(l))
        n = min(chunk, steps - k0)
        kernel.run(w[k0:k0 + n + 1], n, k0, record_every)
        if progress and k0 + n >= next_report:
            progress(f"t = {(k0 + n) * step:.3f} s of {duration:g} s")
            next_report = (k0 + n) // report_every * report_every + report_every
    if steps % record_every == 0:
        kernel.record_row(steps // record_every)
    r = recorder
    time = np.arange(r.energy.size) * step * record_every
    return SimulationResult(time, r.sensors, r.v, r.u, r.fn, r.phi, r.energy, r.works[:, 0], r.works[:, 1],
                            r.works[:, 2], list(model.joint_names), list(model.sensor_names))


def reference_system(model: ModalModel, joints: list[lugre.LuGreParameters], normal_forces,
                     disturbance: Callable[[float], np.ndarray] | None):
    """Eq. 12 with constant normal forces as an ODE z' = f(t, z), z = [x; φ], with its analytic
    Jacobian, for scipy.integrate.solve_ivp. Returns (rhs, jac, n_states, friction(z) -> u_R)."""
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

    def friction(Z):
        Z = np.atleast_2d(Z)
        x, phi = Z[:, :ns], Z[:, ns:]
        return law.arm * fn * law.mu(x @ Cv.T, phi)

    return rhs, jac, ns, friction


def reference_simulation(model: ModalModel, joints: list[lugre.LuGreParameters], normal_forces,
                         disturbance: Callable[[float], np.ndarray] | None, duration: float, times: np.ndarray,
                         rtol: float = 1e-10, atol: float = 1e-13, method: str = "Radau"):
    """Eq. 12 for constant normal forces through scipy.integrate.solve_ivp with an analytic
    Jacobian: the accuracy reference for :func:`simulate`. Returns (v, u_R, ½xᵀx) at ``times``."""
    from scipy.integrate import solve_ivp

    rhs, jac, ns, friction = reference_system(model, joints, normal_forces, disturbance)
    l = model.joint_input.shape[1]
    _, _, _, Cv, _ = model.state_space()
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
    x = Z[:, :ns]
    return x @ Cv.T, friction(Z), 0.5 * np.sum(x * x, axis=1)


__all__ = ["ConstantNormalForce", "Controller", "Measurements", "SimulationResult", "TriangularPulse", "discretise",
           "reference_simulation", "reference_system", "simulate", "triangular_pulse"]
