"""The loop driver: the closed loop of a plant scheme and a controller (paper Eq. 12).

The plant is Eq. 12 in modal coordinates (``modal.ModalModel``)::

    ẋ = A·x − B·u_R + H·w,   v = Bᵀx,   φ̇_j = f(v_j, φ_j)  (Eq. 1),   u_R,j = r_j·F_N,j·μ_j  (Eq. 2)

and a controller behind one interface (``interface.Controller``: ``step(measurements) ->
normal_forces``), called every ``controller.sample_time`` with the normal forces held in between
(zero-order hold). :func:`simulate` drives any scheme of the registry (``schemes.py``): the
fixed-step scheme (``fixed_step.py``), the stick-exact one (``stick_exact.py``) or the
frictionless ``linear`` one (``linear.py``, where the controller commands the joint forces).

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
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.friction.model import FrictionParameters
from smartjoint.design.plant import disturbance as disturbances
from smartjoint.design.plant import schemes
from smartjoint.design.plant.fixed_step import MAX_DISTURBANCES
from smartjoint.design.plant.interface import Controller
from smartjoint.design.plant.kernel import Kernel, PlantRun
from smartjoint.design.structure.modal import ModalModel


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


def _check(model: ModalModel, joints, duration, step, controller, initial_state, friction: bool = True):
    """The conditions every scheme shares, each a named error; returns (l, samples per step)."""
    l = model.joint_input.shape[1]
    if friction and len(joints) != l:
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
        raise ModelError(
            f"controller sample time {sample_time!r} s must be a whole multiple of the plant step {step!r} s"
        )
    unstable = np.flatnonzero(
        ~(np.isfinite(model.damping) & (model.damping >= 0) & np.isfinite(model.omega) & (model.omega > 0))
    )
    if unstable.size:
        i = unstable[0]
        raise ModelError(
            f"modal model: coordinate {model.labels[i]!r} has ω = {float(model.omega[i])!r} rad/s, "
            f"ξ = {float(model.damping[i])!r} — need ω > 0 and ξ >= 0 (a stable structure)"
        )
    still: np.ndarray | list[int] = np.flatnonzero(~np.any(model.joint_input != 0.0, axis=0)) if l and friction else []
    if len(still):
        raise ModelError(
            f"joint {model.joint_names[still[0]]!r}: no coordinate of the model moves it (its column of "
            "E is zero) — a joint on a rigid DOF cannot slide; move it or add its Krylov vector"
        )
    if model.disturbance_input.shape[1] > MAX_DISTURBANCES:
        raise ModelError(f"disturbances: {model.disturbance_input.shape[1]} inputs — at most {MAX_DISTURBANCES}")
    if initial_state is not None:
        x0 = np.asarray(initial_state, dtype=float)
        if x0.size != 2 * model.n_coordinates or not np.all(np.isfinite(x0)):
            raise ModelError(
                f"initial_state: {x0.size} values — need {2 * model.n_coordinates} finite values "
                "([η̇_i, ω_iη_i] per coordinate)"
            )
    return l, int(round(ratio))


def _commands(raw, l: int, t: float, model: ModalModel, friction: bool) -> np.ndarray:
    """The controller's output as l finite values (>= 0 where they are normal forces)."""
    try:
        new = np.asarray(raw, dtype=float)
    except (TypeError, ValueError):
        new = np.array([np.nan])
    if new.shape not in ((l,), (1, l), (l, 1)) or not np.all(np.isfinite(new)) or (friction and np.any(new < 0)):
        shown = raw.tolist() if isinstance(raw, np.ndarray) else raw
        what, bound = ("normal forces", " >= 0") if friction else ("joint forces", "")
        raise ModelError(
            f"controller returned {what} {shown!r} at t = {t:.6g} s — need {l} finite values"
            f"{bound} (joints {', '.join(model.joint_names)})"
        )
    return new.reshape(l)


def _check_schedule(sample_steps, steps: int) -> None:
    """A sample schedule: whole plant steps from 0, strictly increasing, within the run."""
    if sample_steps is None:
        return
    k = np.asarray(sample_steps)
    if not (
        k.ndim == 1
        and k.size
        and np.issubdtype(k.dtype, np.integer)
        and k[0] == 0
        and np.all(np.diff(k) > 0)
        and k[-1] < steps
    ):
        raise ModelError(
            f"sample_steps: {k.size} values — need whole plant steps from 0, strictly increasing, below {steps}"
        )


def _check_options(record_every, energy_books) -> None:
    """The recording options: a whole ``record_every`` >= 1 and a boolean ``energy_books``."""
    if not (isinstance(record_every, int) and record_every >= 1):
        raise ModelError(f"record_every: {record_every!r} — must be a whole number >= 1")
    if not isinstance(energy_books, bool):
        raise ModelError(f"energy_books: {energy_books!r} — must be True or False")


def _run_loop(run: PlantRun, kernel, w: np.ndarray, l: int, friction: bool, ratio: int, progress) -> None:
    """Step the kernel through the run: a controller call every ``ratio`` plant steps (once
    for a controller that holds constant), a progress line about every tenth of the run."""
    model, controller, steps, step = run.model, run.controller, run.steps, run.step
    duration, record_every = run.duration, run.record_every
    controller.reset()
    kernel.start(w[0] if w.shape[0] else np.zeros(model.disturbance_input.shape[1]))
    if run.sample_steps is not None:  # a jittered schedule: each sample at its own plant step
        starts = [int(k) for k in run.sample_steps]
    else:
        starts = list(range(0, steps, steps if getattr(controller, "holds_constant", False) else ratio))
    report_every = max(steps // 10, 1)
    next_report = report_every
    for k0, end in zip(starts, [*starts[1:], steps]):
        t = k0 * step
        kernel.set_normal_force(_commands(controller.step(kernel.measure(t)), l, t, model, friction))
        n = end - k0
        kernel.run(w[k0 : k0 + n + 1], n, k0, record_every)
        if progress and k0 + n >= next_report:
            progress(f"t = {(k0 + n) * step:.3f} s of {duration:g} s")
            next_report = (k0 + n) // report_every * report_every + report_every
    if steps % record_every == 0:
        kernel.record_row(steps // record_every)


def result(r, model: ModalModel, step: float, record_every: int) -> SimulationResult:
    """The kernel's recorded rows as a :class:`SimulationResult` on the time grid ``step·record_every``."""
    time = np.arange(r.energy.size) * step * record_every
    return SimulationResult(
        time,
        r.sensors,
        r.v,
        r.u,
        r.fn,
        r.phi,
        r.energy,
        r.works[:, 0],
        r.works[:, 1],
        r.works[:, 2],
        list(model.joint_names),
        list(model.sensor_names),
    )


def simulate(
    model: ModalModel,
    joints: list[FrictionParameters],
    controller: Controller,
    disturbance: Callable[[float], np.ndarray] | None = None,
    duration: float = 1.0,
    step: float = 1e-4,
    initial_state: np.ndarray | None = None,
    progress: Callable[[str], None] | None = None,
    record_every: int = 1,
    backend: str = "auto",
    energy_books: bool = True,
    stick_step: float | None = None,
    scheme: str | None = None,
    sample_steps: np.ndarray | None = None,
) -> SimulationResult:
    """Run the closed loop for ``duration`` seconds at plant step ``step`` (see module docstring).

    Parameters
    ----------
    model : ModalModel
        The modal model of Eq. 12 (full or reduced).
    joints : list of FrictionParameters
        One parameter set per joint (LuGre: Eq. 1–2); empty for the frictionless ``linear`` scheme.
    controller : Controller
        Called every ``controller.sample_time`` (a whole multiple of ``step``); one with
        ``holds_constant = True`` is asked once, and the whole run is one kernel call.
    disturbance : callable or None
        ``w(t)`` along the disturbance inputs (``disturbance.triangular_pulse``).
    duration, step : float
        Length of the run and plant step [s].
    initial_state : array_like or None
        [η̇_i, ω_iη_i] per coordinate; None: at rest.
    progress : callable or None
        Called with a line about every tenth of the run.
    record_every : int
        Record every this many plant steps.
    backend : str
        "c" (``plant_kernel.c``, compiled on first use), "python" (its numpy mirror) or "auto"
        (C where a compiler is available).
    energy_books : bool
        Book W_in, W_joints and W_damping exactly every step (18 coefficients per mode; about
        doubles the step cost of a large model); False leaves them NaN — the state, e(t) and
        Eq. 32 are unaffected.
    stick_step : float or None
        Run the stick-exact scheme of ``stick_exact.py`` instead — long steps of this length
        while every joint sticks, ``step`` elsewhere (reduced models, energy_books=False).
    scheme : str or None
        A scheme of ``schemes.SCHEMES`` by name; None: "stick_exact" with ``stick_step``, else
        "fixed".
    sample_steps : array of int, optional
        The plant step of each controller sample (from 0, strictly increasing): a jittered
        schedule; None: every ``sample_time``.

    Returns
    -------
    SimulationResult
        The recorded rows at ``step·record_every`` (docs/simulation.md has an example).
    """
    chosen = schemes.scheme(scheme if scheme is not None else "fixed" if stick_step is None else "stick_exact")
    prepared = prepare(
        chosen,
        PlantRun(
            model,
            joints,
            controller,
            duration,
            step,
            initial_state,
            record_every,
            backend,
            energy_books,
            stick_step,
            sample_steps,
        ),
        disturbance,
    )
    _run_loop(prepared.run, prepared.kernel, prepared.w, prepared.joints, chosen.FRICTION, prepared.ratio, progress)
    return result(prepared.kernel.recorder, model, step, record_every)


@dataclass(frozen=True)
class PreparedRun:
    """A checked run with its kernel at the initial state: the disturbance rows ``w`` at the plant
    steps, the number of joints and the plant steps per controller sample (``ratio``)."""

    run: PlantRun
    kernel: Kernel
    w: np.ndarray
    joints: int
    ratio: int


def prepare(chosen, run: PlantRun, disturbance: Callable[[float], np.ndarray] | None) -> PreparedRun:
    """Check a run for the scheme ``chosen`` (a module of ``schemes.SCHEMES``) and build its kernel
    and disturbance rows: what :func:`simulate` steps, and what a compiled closed loop (which
    steps the kernel from C, ``codegen.closed_loop``) starts from.

    Parameters
    ----------
    chosen : Scheme
        The scheme (``schemes.scheme(name)``).
    run : PlantRun
        The run; its controller need only carry ``sample_time``.
    disturbance : callable or None
        ``w(t)`` along the disturbance inputs.

    Returns
    -------
    PreparedRun

    Raises
    ------
    ModelError
        For anything :func:`simulate` refuses, one line naming the field.
    """
    l, ratio = _check(run.model, run.joints, run.duration, run.step, run.controller, run.initial_state, chosen.FRICTION)
    _check_options(run.record_every, run.energy_books)
    _check_schedule(run.sample_steps, run.steps)
    chosen.check(run)
    kernel = chosen.kernel(run)
    w = disturbances.at_steps(
        disturbance, run.steps, run.step, run.model.disturbance_input.shape[1], compact=chosen.COMPACT_DISTURBANCE
    )
    return PreparedRun(run, kernel, w, l, ratio)


__all__ = ["PreparedRun", "SimulationResult", "prepare", "result", "simulate"]
