"""Stick-exact steps: the stuck joints inside the exactly discretised linear part.

``simulate(..., stick_step=H)`` runs this scheme instead of the fixed-step one. With Eq. 1
written as φ̇ = v − d, d = ρ(v)·φ, ρ = σ0|v|/g(v), the friction force of Eq. 2 is

    u_R = r·F_N·[σ0·φ + (σ1 + σ2)·v − σ1·d],

so z = [x; φ] obeys a *linear* system — the truss (Eq. 12) with a bristle spring r·F_N·σ0 and a
damper r·F_N·(σ1 + σ2) in every joint — driven by the slip terms d and the disturbances w:

    ż = M·z + N_d·d + N_w·w,   M = [[A − B·c·C_v, −B·k], [C_v, 0]].

M is discretised exactly (first-order hold in d and w, Van Loan) once per set of normal forces
and step length; a step then solves d⁺ = ρ(v⁺)·φ⁺ by Newton in the l slip terms, started from
the held d. While the joints stick (ρ·h ≪ 1) d is a small, smooth correction and the stuck-joint
modes — the bristle springs against the structure, 610–1149 Hz with ξ ≈ 1e-3 on the 24-state
model — are exact at any step. So each interval H is one long step where, at both of its ends,
every joint has ρ·H < ``KAPPA`` and |u_R| < ``BETA[0]``·r·F_N·(F_c + F_d) (the second bound keeps
a slip from hiding inside a long step); else medium steps H/4 (H/2) under the same test with
``BETA[1]``; else short steps ``step``, all of the same scheme. A longer step is only tried where
the disturbance is off, and a tried step that ends outside the test is taken back. The slip
term's first-order hold makes the scheme second order in the step (tests/test_stick_exact.py).

Cost and limits: the state is dense (2n + l), so this is for reduced models (at most
``MAX_STATES`` states); each new set of normal forces costs two matrix exponentials (cached,
so passive joints and bang-bang laws such as the clipped LQG pay once per combination, a
continuous law every sample); the energy books are not kept (NaN). Accuracy on the 24-state
model in benchmarks/plant_sim.py and docs/simulation.md.
"""

from __future__ import annotations

import math

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.friction.model import plant_laws
from smartjoint.design.plant.discretisation import first_order_hold
from smartjoint.design.plant.kernel import LAW_FIELDS, NativeStructs, PlantRun, Recorder, State, choose_kernel

KAPPA = 0.05  # ρ·h below which a joint counts as stuck for a step h
BETA = (0.3, 0.5)  # |u_R| / break-away force below which it does, for the long and the medium step
MAX_STATES = 400  # dense discretisation: reduced models only
TOLERANCE = 1e-12  # |d − ρφ| ≤ TOLERANCE·(max(|v_free|, v_s) + |v|) ends the slip-term solve,
CORRECTION = 1e-5  # and so does a Newton correction below CORRECTION·(the same scale)
ITERATIONS = 30


def _aligned(shape) -> np.ndarray:
    """Zeros on a 64-byte boundary: the kernel's vector loads then never split a cache line, and
    its speed does not depend on where the allocator happened to put the matrices."""
    count = int(np.prod(shape))
    raw = np.zeros(count + 8)
    offset = (-raw.ctypes.data % 64) // 8
    return raw[offset : offset + count].reshape(shape)


class StickPlant:
    """The run's constant data and the discretisations per set of normal forces."""

    def __init__(self, model, law, step: float, long_step: float):
        A, B, H, Cv, Cy = model.state_space()
        self.A, self.B, self.H = A, B, H
        self.Cv, self.Cy = np.ascontiguousarray(Cv), np.ascontiguousarray(Cy)
        # the loop's view of the state (x as [η̇; ωη] rows, as the fixed-step scheme keeps it)
        self.ET = np.ascontiguousarray(model.joint_input.T, dtype=float)
        self.Vy = np.ascontiguousarray(model.velocity_output, dtype=float)
        self.Dy = np.ascontiguousarray(model.displacement_output / model.omega, dtype=float)
        self.n2, self.l, self.m, self.ny = A.shape[0], B.shape[1], H.shape[1], Cy.shape[0]
        self.N = self.n2 + self.l
        self.padded = -(-self.N // 4) * 4
        self.law = law
        self.step, self.long_step = step, long_step
        self.sub = int(round(long_step / step))
        # the medium step: a quarter (else a half) of the long one where it is a whole number of short steps
        first = next((r for r in (4, 2) if self.sub % r == 0), 1)
        self.ratio = (first, self.sub // first)
        self.lengths = (long_step, long_step / first, step)
        self._cache: dict[tuple, tuple[dict, dict, dict]] = {}

    def discretisations(self, normal_force) -> tuple[dict, dict, dict]:
        """The long, medium and short discretisations for these normal forces (cached)."""
        key = tuple(float(f) for f in normal_force)
        if key not in self._cache:
            law, fn = self.law, np.asarray(normal_force, dtype=float)
            stiffness, damping = law.arm * fn * law.s0, law.arm * fn * (law.s1 + law.s2)
            slip = law.arm * fn * law.s1
            n2, l, m, N = self.n2, self.l, self.m, self.N
            M = np.zeros((N, N))
            M[:n2, :n2] = self.A - (self.B * damping[None, :]) @ self.Cv
            M[:n2, n2:] = -self.B * stiffness[None, :]
            M[n2:, :n2] = self.Cv
            inputs = np.zeros((N, l + m))
            inputs[:n2, :l] = self.B * slip[None, :]
            inputs[n2:, :l] = -np.eye(l)
            inputs[:n2, l:] = self.H
            long, medium, short = (self._discretise(M, inputs, h) for h in self.lengths)
            self._cache[key] = long, medium, short
        return self._cache[key]

    def _discretise(self, M, inputs, h) -> dict:
        N, l, n2 = self.N, self.l, self.n2
        phi, gamma0, gamma_b = first_order_hold(M, inputs, h)
        out = {"phi": phi, "g0": gamma0, "g1": gamma_b}
        out["Gv"] = self.Cv @ gamma_b[:n2, :l]
        out["Gp"] = gamma_b[n2:, :l]
        out = {k: np.ascontiguousarray(v) for k, v in out.items()}
        # the C kernel walks the matrices column by column: their transposes, rows padded to a
        # multiple of four (zeros) so that its loops vectorise without a remainder
        for name in ("phi", "g0", "g1"):
            padded = _aligned((out[name].shape[1], self.padded))
            padded[:, :N] = out[name].T
            out[f"{name}T"] = padded
        return out


class _SolveFailed(Exception):
    def __init__(self, residual):
        self.residual = residual


class _StickPython:
    """The scheme in numpy: the readable mirror of ``sj_stick_run`` in plant_kernel.c."""

    name = "python"

    def __init__(self, plant: StickPlant, state: State, recorder: Recorder):
        self.p, self.s, self.r = plant, state, recorder
        self.recorder = recorder
        self.z = np.zeros(plant.N)
        self.z[: plant.n2] = np.column_stack([state.x[0], state.x[1]]).reshape(-1)
        self.d = np.zeros(plant.l)
        self.levels = None
        self.counts = np.zeros(3, dtype=np.int64)  # steps taken: long, medium, short

    def _rate(self, v):
        law = self.p.law
        g = law.level(v)
        dg = -2.0 * v / law.vs**2 * (g - law.fc)
        return law.s0 * np.abs(v) / g, law.s0 * (np.sign(v) * g - np.abs(v) * dg) / (g * g)

    def _forces(self):
        law, s, n2 = self.p.law, self.s, self.p.n2
        s.u[:] = law.arm * s.fn * (law.s0 * self.z[n2:] + law.s1 * (s.v - self.d) + law.s2 * s.v)

    def _sync(self):
        n2 = self.p.n2
        self.s.x[0], self.s.x[1] = self.z[0:n2:2], self.z[1:n2:2]
        self.s.phi[:] = self.z[n2:]

    def measure(self, time: float):
        return self.s.measure(time, self.p.Vy, self.p.Dy)

    def set_normal_force(self, normal_force):
        self.s.fn[:] = normal_force
        self.levels = self.p.discretisations(normal_force)
        self._forces()

    def start(self, w0):
        self.s.works[:] = np.nan

    def record_row(self, row):
        p, s, r = self.p, self.s, self.r
        r.v[row], r.u[row], r.fn[row], r.phi[row] = s.v, s.u, s.fn, self.z[p.n2 :]
        r.sensors[row] = p.Cy @ self.z[: p.n2]
        r.energy[row] = 0.5 * float(self.z[: p.n2] @ self.z[: p.n2])
        r.works[row] = np.nan

    def _advance(self, k, w_a, w_b):
        p, l = self.p, self.p.l
        z_free = k["phi"] @ self.z + k["g0"][:, :l] @ self.d
        if np.any(w_a) or np.any(w_b):  # as the C kernel: the disturbance terms only while it acts
            z_free = z_free + k["g0"][:, l:] @ w_a + k["g1"][:, l:] @ w_b
        v_free, phi_free = p.Cv @ z_free[: p.n2], z_free[p.n2 :]
        scale = np.maximum(np.abs(v_free), p.law.vs) + np.abs(self.s.v)
        d = self.d.copy()
        residual = np.zeros(l)
        for _ in range(ITERATIONS):
            v, phi = v_free + k["Gv"] @ d, phi_free + k["Gp"] @ d
            rho, drho = self._rate(v)
            residual = d - rho * phi
            if np.all(np.abs(residual) <= TOLERANCE * scale):
                self.z[:] = z_free + k["g1"][:, :l] @ d
                self.d[:], self.s.v[:] = d, v
                return
            jacobian = np.eye(l) - (drho * phi)[:, None] * k["Gv"] - rho[:, None] * k["Gp"]
            try:
                correction = np.linalg.solve(jacobian, residual)
            except np.linalg.LinAlgError:
                break
            limit = np.max(np.abs(correction) / scale)
            d = d - (correction if limit <= 1.0 else correction / limit)
            if limit <= CORRECTION:  # quadratic convergence: the next correction would be below tolerance
                self.z[:] = z_free + k["g1"][:, :l] @ d
                self.d[:], self.s.v[:] = d, v_free + k["Gv"] @ d
                return
        raise _SolveFailed(float(np.max(np.abs(residual))))

    def _quiet(self, h, beta):
        law, s = self.p.law, self.s
        rho, _ = self._rate(s.v)
        return bool(np.all(rho * h < KAPPA) and np.all(np.abs(s.u) < beta * law.arm * s.fn * (law.fc + law.fd)))

    def _interval(self, level, w, h):
        """One step at ``level`` where the joints are quiet for it at both ends and the
        disturbance is off on ``w`` (its samples at the short-step ends), else the next level."""
        if level == 2:
            self._advance(self.levels[2], w[0], w[1])
            self._forces()
            self.counts[2] += 1
            return
        if not np.any(w) and self._quiet(h, BETA[level]):
            saved = self.z.copy(), self.d.copy(), self.s.v.copy(), self.s.u.copy()
            try:
                self._advance(self.levels[level], w[0], w[-1])
                self._forces()
                if self._quiet(h, BETA[level]):
                    self.counts[level] += 1
                    return
            except _SolveFailed:
                pass
            self.z[:], self.d[:], self.s.v[:], self.s.u[:] = saved  # a slip may hide inside
        parts = self.p.ratio[level]
        span = (w.shape[0] - 1) // parts
        for i in range(parts):
            self._interval(level + 1, w[i * span : (i + 1) * span + 1], h / parts)

    def run(self, w, steps, k0, record_every):
        p, sub = self.p, self.p.sub
        if w.shape[0] < steps + 1:  # the rows after the disturbance's end are zero
            w = np.concatenate([w, np.zeros((steps + 1 - w.shape[0], p.m))])
        for k in range(steps // sub):
            if (k0 // sub + k) % (record_every // sub) == 0:
                self.record_row((k0 // sub + k) // (record_every // sub))
            try:
                self._interval(0, w[k * sub : (k + 1) * sub + 1], p.long_step)
            except _SolveFailed as failure:
                self._sync()
                raise ModelError(
                    f"slip-term solve did not converge at step {p.step:.3g} s (residual "
                    f"{failure.residual:.3g}); reduce the step"
                ) from None
        self._sync()


class _StickC:
    """``sj_stick_run`` of plant_kernel.c through cffi; z, d and the joint arrays shared with numpy."""

    name = "c"

    def __init__(self, plant: StickPlant, state: State, recorder: Recorder):
        native = self.native = NativeStructs()  # holds the arrays the C structs point into
        ffi = self.ffi = native.ffi
        self.lib = native.lib
        self.mirror = _StickPython(plant, state, recorder)  # holds z, d and the discretisations
        self.p, self.s, self.r = plant, state, recorder
        self.recorder = recorder
        ptr = native.pointer
        shared = native.shared(state, ("v", "u", "fn"))
        self.work = _aligned((2 * plant.padded + 2 * plant.N + 14 * plant.l + plant.l**2 + 1,))
        self.cp = ffi.new(
            "sj_stick *",
            dict(
                Np=plant.padded,
                ratio=list(plant.ratio),
                kappa=KAPPA,
                beta=list(BETA),
                work=ptr(self.work),
                **native.numbers(plant, ("N", "n2", "l", "m", "ny")),
                **native.pointers(plant, ("Cv", "Cy")),
                **native.pointers(plant.law, LAW_FIELDS),
            ),
        )
        self.cs = ffi.new("sj_stick_state *", dict(**native.pointers(self.mirror, ("z", "d")), **shared))
        self.cr = native.record(recorder)

    @property
    def counts(self):
        return np.array(list(self.cs.steps))

    def _point(self, target, k):
        for name, key in (("phi", "phiT"), ("g0", "g0T"), ("g1", "g1T"), ("Gv", "Gv"), ("Gp", "Gp")):
            setattr(target, name, self.ffi.cast("double *", self.ffi.from_buffer(k[key])))

    def measure(self, time: float):
        return self.mirror.measure(time)

    def set_normal_force(self, normal_force):
        self.mirror.set_normal_force(normal_force)  # the discretisations (numpy, cached) and u_R
        for level, discretisation in enumerate(self.mirror.levels):
            self._point(self.cp.level[level], discretisation)

    def start(self, w0):
        self.s.works[:] = np.nan

    def record_row(self, row):
        self.lib.sj_stick_record_row(self.cp, self.cs, self.cr, row)

    def run(self, w, steps, k0, record_every):
        sub = self.p.sub
        rows = w.shape[0]  # the rows after the disturbance's end are left out: zero
        w = np.ascontiguousarray(w if rows else np.zeros((1, self.p.m)), dtype=float)
        longs = steps // sub
        done = self.lib.sj_stick_run(
            self.cp,
            self.cs,
            self.ffi.cast("double *", self.ffi.from_buffer(w)),
            rows,
            longs,
            k0 // sub,
            record_every // sub,
            self.cr,
            self.p.long_step,
        )
        self.mirror._sync()
        if done < longs:
            raise ModelError(
                f"slip-term solve did not converge at step {self.cs.failed_step:.3g} s (residual "
                f"{self.cs.failed_residual:.3g}); reduce the step"
            )


_C_FAILURE: list[str] = []


def check(run: PlantRun) -> None:
    """``Scheme.check`` (``kernel.py``): the stick-exact run's own conditions, each a named error."""
    model, step, stick_step, controller = run.model, run.step, run.stick_step, run.controller
    record_every, energy_books, duration = run.record_every, run.energy_books, run.duration
    if not (isinstance(stick_step, (int, float)) and math.isfinite(stick_step) and stick_step >= step):
        raise ModelError(f"stick_step: {stick_step!r} — must be a step length >= step ({step!r} s)")
    ratio = stick_step / step
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise ModelError(f"stick_step: {stick_step!r} s must be a whole multiple of step {step!r} s")
    sub = int(round(ratio))
    if not getattr(controller, "holds_constant", False):
        per_sample = controller.sample_time / stick_step
        if abs(per_sample - round(per_sample)) > 1e-9 * per_sample or round(per_sample) < 1:
            raise ModelError(
                f"controller sample time {controller.sample_time!r} s must be a whole multiple of "
                f"stick_step {stick_step!r} s"
            )
    if record_every % sub:
        raise ModelError(
            f"record_every: {record_every} steps of {step:g} s — with stick_step it must be a multiple "
            f"of {sub} (records fall on long-step boundaries)"
        )
    steps = duration / stick_step
    if abs(steps - round(steps)) > 1e-9 * steps:
        raise ModelError(f"duration: {duration!r} s must be a whole multiple of stick_step {stick_step!r} s")
    if energy_books:
        raise ModelError("energy_books: True — the stick-exact scheme keeps no energy books; pass energy_books=False")
    states = 2 * model.n_coordinates + model.joint_input.shape[1]
    if states > MAX_STATES:
        raise ModelError(
            f"stick_step: the model has {states} states — the stick-exact scheme is dense and takes at "
            f"most {MAX_STATES} (a reduced model); leave stick_step out for the full model"
        )


def kernel(run: PlantRun):
    """``Scheme.kernel`` (``kernel.py``): ``sj_stick_run`` of plant_kernel.c (backend "c"), its
    numpy mirror ("python") or the C where it builds ("auto"); ``counts`` the steps taken per length."""
    assert run.stick_step is not None  # the scheme runs only with a stick step (see check)
    plant = StickPlant(run.model, plant_laws(run.joints), run.step, float(run.stick_step))
    return choose_kernel(run, "stick-exact simulation", plant, _StickC, _StickPython, _C_FAILURE)


FRICTION = True  # LuGre joints; the controller commands normal forces
COMPACT_DISTURBANCE = True


__all__ = ["BETA", "KAPPA", "MAX_STATES", "COMPACT_DISTURBANCE", "FRICTION", "check", "kernel"]
