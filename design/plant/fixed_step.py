"""The fixed-step scheme (``simulate(...)`` by default): the modal truss with LuGre joints at a
fixed step h, stiff bristles without tiny steps; ``plant_kernel.c`` and its numpy mirror.

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
  integrator with first-order hold on v (see ``joints.JointLaws.advance``). Where a falling Stribeck
  branch is steeper than the step's compliance allows, the solve has no unique root; that
  step is halved (recursively, at most 2⁸ pieces) — the stick-to-slip transitions are the
  only places that need it.
* Normal-force jumps at controller samples act at once: u_R at the step start is recomputed
  with the new F_N before the step (the piezo is taken as instantaneous here).

Global error O(h²) for smooth motion; a sliding reversal inside a step costs O(h²) locally (the
kink of |v| in Eq. 1). ``reference.reference_simulation`` integrates the same ODE with scipy's Radau
and an analytic Jacobian, tests/test_simulate.py compares both and measures the order.

The energy books (``energy_books=True``) integrate W_in, W_joints and W_damping exactly over every
step (``discretisation.work_coefficients``); see ``loop.py`` for the balance they check.
"""

from __future__ import annotations

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.friction.model import plant_laws
from smartjoint.design.plant.discretisation import discretise, step_works, work_coefficients
from smartjoint.design.plant.interface import Measurements
from smartjoint.design.plant.joints import JointLaws
from smartjoint.design.plant.kernel import LAW_FIELDS, NativeStructs, PlantRun, Recorder, State, choose_kernel
from smartjoint.design.structure.modal import ModalModel

MAX_HALVINGS = 8  # a plant step may split into up to 2^8 substeps where the joints demand it
TOLERANCE = 1e-12  # Newton: |residual| ≤ TOLERANCE·(max(|v_free|, v_s) + |v_k|)
ITERATIONS = 30
MAX_DISTURBANCES = 64  # the C kernel keeps the halving's midpoint disturbance on its stack


class _SolveFailed(Exception):
    def __init__(self, residual):
        self.residual = residual


def _solve_joints(law: JointLaws, G, v_free, v_start, phi, normal_force, h, u_start):
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


class PlantTables:
    """The fixed-step scheme's tables of a run: what ``plant_kernel.c``'s ``sj_plant`` points
    into and the plant FMU ships. Everything a run needs that does not change during it, laid
    out as structure of arrays (rows of length n) like ``plant_kernel.c``: discretisation at
    step/2^d for d = 0…MAX_HALVINGS, the transposed input matrices, the outputs and the joint
    laws."""

    def __init__(self, model: ModalModel, joints, step: float, books: bool = True):
        self.n, self.l = model.n_coordinates, model.joint_input.shape[1]
        self.m, self.ny = model.disturbance_input.shape[1], model.velocity_output.shape[0]
        self.step = step
        # (l, n), padded with zero rows to a multiple of 4: the C kernel takes four joints per pass
        self.ET_padded = np.zeros((-(-self.l // 4) * 4, self.n))
        self.ET_padded[: self.l] = model.joint_input.T
        self.ET = self.ET_padded[: self.l]
        self.HT = np.ascontiguousarray(model.disturbance_input.T, dtype=float)  # (m, n)
        self.Vy = np.ascontiguousarray(model.velocity_output, dtype=float)
        self.Dy = np.ascontiguousarray(model.displacement_output / model.omega, dtype=float)
        self.two_xi_w = 2.0 * model.damping * model.omega
        self.law = plant_laws(joints)
        levels = MAX_HALVINGS + 1
        self.phi, self.g0, self.g1 = (
            np.zeros((levels, 4, self.n)),
            np.zeros((levels, 2, self.n)),
            np.zeros((levels, 2, self.n)),
        )
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


class _Kernel:
    """What both fixed-step kernels share: the run's plant, state and recorder."""

    def __init__(self, plant: PlantTables, state: State, recorder: Recorder):
        self.p, self.s, self.r = plant, state, recorder

    @property
    def recorder(self) -> Recorder:
        return self.r

    def measure(self, time: float):
        return self.s.measure(time, self.p.Vy, self.p.Dy)


class _PythonKernel(_Kernel):
    """The fixed-step scheme in numpy: the readable mirror of ``plant_kernel.c``."""

    name = "python"

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
                m0, m1, damping = step_works(p.book[depth], x0, x1, f_a, f_b)
                s.works += (p_a @ m0 + (p_b - p_a) @ m1, 0.0, np.sum(damping))
            s.x[:] = free0, free1
            return
        try:
            v_free = p.ET @ free0
            v_new, phi_new, u_new = _solve_joints(p.law, G, v_free, s.v, s.phi, s.fn, h, s.u)
        except _SolveFailed as failure:
            if depth >= MAX_HALVINGS:
                raise ModelError(
                    f"joint solve did not converge at step {h:.3g} s (residual {failure.residual:.3g}); reduce the step"
                ) from None
            w_mid = 0.5 * (w_a + w_b)  # linear in the step, as the first-order hold assumes
            self._advance(w_a, w_mid, depth + 1)
            self._advance(w_mid, w_b, depth + 1)
            return
        s.phi[:], s.u[:] = phi_new, u_new
        q_new = p.ET.T @ u_new
        if p.books:
            m0, m1, damping = step_works(p.book[depth], x0, x1, f_a, p_b - q_new)
            s.works += (p_a @ m0 + (p_b - p_a) @ m1, s.q @ m0 + (q_new - s.q) @ m1, np.sum(damping))
        s.q[:] = q_new
        s.x[:] = free0 - b[0] * s.q, free1 - b[1] * s.q
        s.v[:] = v_free - G @ u_new  # = Eᵀx0 exactly; v_free is recomputed from x every step

    def run(self, w, steps, k0, record_every):
        for k in range(steps):
            if (k0 + k) % record_every == 0:
                self.record_row((k0 + k) // record_every)
            self._advance(w[k], w[k + 1], 0)


class _CKernel(_Kernel):
    """``plant_kernel.c`` through cffi; the state arrays are shared with numpy."""

    name = "c"

    def __init__(self, plant: PlantTables, state: State, recorder: Recorder):
        super().__init__(plant, state, recorder)
        native = self.native = NativeStructs()  # holds the arrays the C structs point into
        ffi = self.ffi = native.ffi
        self.lib = native.lib
        ptr = native.pointer
        self.work = np.zeros(5 * plant.n + 7 * plant.l + plant.l**2 + 1)
        self.cp = ffi.new(
            "sj_plant *",
            dict(
                levels=MAX_HALVINGS + 1,
                books=int(plant.books),
                ET=ptr(plant.ET_padded),
                work=ptr(self.work),
                **native.numbers(plant, ("n", "l", "m", "ny", "step")),
                **native.pointers(plant, ("phi", "g0", "g1", "G", "book", "HT", "Vy", "Dy", "two_xi_w")),
                **native.pointers(plant.law, (*LAW_FIELDS, "bound")),
            ),
        )
        self.cs = ffi.new("sj_state *", native.shared(state, ("x", "q", "v", "phi", "u", "fn")))
        self.cr = native.record(recorder)

    def structs(self) -> tuple:
        """The C structs of this kernel (``sj_plant *``, ``sj_state *``, ``sj_record *``) and
        their cffi module: what another compiled loop is handed to step this very plant."""
        return self.cp, self.cs, self.cr, self.ffi

    def failure(self) -> tuple[float, float]:
        """Where the last joint solve failed: (time [s], residual)."""
        return float(self.cs.failed_step), float(self.cs.failed_residual)

    def _pull(self):
        cs = self.cs
        self.s.works[:] = (cs.work_in, cs.work_joints, cs.work_damping)

    def measure(self, time: float):
        sensors = np.zeros(self.p.ny)
        self.lib.sj_measure(self.cp, self.cs, self.ffi.cast("double *", self.ffi.from_buffer(sensors)))
        s = self.s
        return Measurements(time, sensors, s.v.copy(), s.u.copy(), s.fn.copy())

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
        done = self.lib.sj_run(
            self.cp, self.cs, self.ffi.cast("double *", self.ffi.from_buffer(w)), steps, k0, record_every, self.cr
        )
        self._pull()
        if done < steps:
            raise ModelError(
                f"joint solve did not converge at step {self.cs.failed_step:.3g} s (residual "
                f"{self.cs.failed_residual:.3g}); reduce the step"
            )


_C_FAILURE: list[str] = []  # why the C kernel is unavailable on this machine (reported once)


def check(run: PlantRun) -> None:
    """``Scheme.check`` (``kernel.py``): the general conditions of ``loop.simulate`` suffice."""


def tables(run: PlantRun) -> PlantTables:
    """The scheme's tables of a run (discretisations, inputs, outputs, joint laws)."""
    return PlantTables(run.model, run.joints, run.step, run.energy_books)


def kernel(run: PlantRun):
    """``Scheme.kernel`` (``kernel.py``): ``plant_kernel.c`` (backend "c"), its numpy mirror
    ("python") or the C where it builds ("auto"), state and recorder shared with numpy."""
    return choose_kernel(run, "plant simulation", tables(run), _CKernel, _PythonKernel, _C_FAILURE)


FRICTION = True  # LuGre joints; the controller commands normal forces
COMPACT_DISTURBANCE = False

__all__ = [
    "ITERATIONS",
    "MAX_DISTURBANCES",
    "MAX_HALVINGS",
    "COMPACT_DISTURBANCE",
    "FRICTION",
    "TOLERANCE",
    "check",
    "kernel",
]
