"""The closed-loop study of paper Section 6: passive, SISO (Eq. 30–31), cLQG (Eq. 33–34) and
active LQG joints after the tip pulse, and the ε optimisation of the SISO law for Eq. 32.

Protocol (Section 6): the triangular tip pulse (200 N over 40 ms along every disturbance input),
every joint at F_N^max while it acts, then the controller until t_e. The plant is the design's
reduced model (the paper's 24 states) with the LuGre joints of Table 1, simulated at a plant step
that divides the controller sample time (``design.plant.loop.simulate``); the active LQG on
the frictionless ``linear`` scheme of the same loop. Everything here is
deterministic: the same inputs give bit-identical results.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize_scalar

from smartjoint.common.errors import ModelError
from smartjoint.design import reduction
from smartjoint.design.control.filter import ActiveLqg, ClippedLqg
from smartjoint.design.control.laws import SisoLaw
from smartjoint.design.control.lqg import LqgDesign, check_sample_time, design_lqg
from smartjoint.design.friction import lugre
from smartjoint.design.plant.disturbance import TriangularPulse, triangular_pulse
from smartjoint.design.plant.interface import ConstantNormalForce, HoldDuringExcitation
from smartjoint.design.plant.loop import simulate
from smartjoint.design.structure import modal
from smartjoint.design.structure.fem import build_model
from smartjoint.design.structure.modal import ModalModel

PULSE_DURATION = 0.04  # s (Section 4.3)
PULSE_AMPLITUDE = 200.0  # N
PLANT_STEPS_PER_SAMPLE = 20  # plant step = Δt/20 (50 µs at 1 ms): within the scheme's accuracy study
SETTLING_FRACTION = 0.1  # settling time: e(t) stays below 10 % of the energy at the end of the pulse
EPSILON_GRID = tuple(10.0 ** np.arange(-8.0, -1.75, 0.5))  # m/s: the SISO ε scan before refinement


@dataclass(frozen=True)
class StudySetup:
    """What every run of the study shares. ``model``: the reduced design model the controllers
    are designed on; ``plant``: the model simulated (the same reduced model by default)."""

    model: ModalModel
    plant: ModalModel
    laws: list
    sample_time: float
    normal_force_min: np.ndarray
    normal_force_max: np.ndarray
    duration: float  # t_e of Eq. 32
    piezo_capacitance: float
    piezo_force_per_volt: float
    piezo_preload: float

    @property
    def plant_step(self) -> float:
        return self.sample_time / PLANT_STEPS_PER_SAMPLE

    def pulse(self) -> TriangularPulse:
        return triangular_pulse(PULSE_AMPLITUDE, PULSE_DURATION, np.ones(self.plant.disturbance_input.shape[1]))


@dataclass
class Run:
    """One closed-loop run at the controller samples: e(t) = ½xᵀx, tip sensors, joint forces."""

    name: str
    time: np.ndarray
    energy: np.ndarray
    sensors: np.ndarray
    normal_force: np.ndarray  # semi-active: applied F_N; active: NaN
    joint_force: np.ndarray  # friction u_R (semi-active) or actuator force u_d (active)
    sliding_velocity: np.ndarray
    control_power: float  # mean over [0, t_e] [W]
    power_kind: str  # "piezo charging" or "actuator mechanical"
    metrics: dict = field(default_factory=dict)

    def energy_measure(self) -> float:
        """Eq. 32: E(t_e) = ∫₀^t_e xᵀx dt (trapezoid on the sample grid)."""
        return float(np.trapezoid(2.0 * self.energy, self.time))


def controlled_joints(design) -> list[str]:
    """The joints the controllers act on: every joint of the design, in ``control.joints`` order
    where given. A strict subset would leave friction joints without a normal force law."""
    names = [j.name for j in design.joints]
    chosen = design.control.joints
    if chosen is not None and sorted(chosen) != sorted(names):
        raise ModelError(
            f"control.joints: {list(chosen)} — the controllers act on every friction joint of the "
            f"design ({', '.join(names)}); a joint outside control.joints would have no normal force"
        )
    if chosen is not None and list(chosen) != names:
        raise ModelError(f"control.joints: {list(chosen)} — list the joints in design order ({', '.join(names)})")
    return names


def design_model(design, progress=print) -> ModalModel:
    """The reduced model of Section 4 the controllers are designed on: ``control.modes`` of the
    first ``control.considered_modes`` modes by Hankel values plus ``control.krylov`` correction
    vectors per joint (Eq. 27–29), joints frictionless (Eq. 6)."""
    c = design.control
    if not design.joints:
        raise ModelError("design has no [[joints]]: the controllers need at least one friction joint")
    if not design.sensors:
        raise ModelError("design has no [[sensors]]: the Kalman filter needs the measured tip deflections")
    if not design.disturbances:
        raise ModelError("design has no [[disturbances]]: the study applies the tip pulse along them")
    controlled_joints(design)
    fe = build_model(design, joints="released")
    considered = min(c.considered_modes, fe.n_dof)
    progress(f"      reduced model: {c.modes} of the first {considered} modes + {c.krylov} Krylov vector(s) per joint")
    first = modal.solve_modes(fe, considered)
    return reduction.reduce(fe, first, min(c.modes, considered), c.krylov).model


def setup(design, model: ModalModel, plant: ModalModel | None = None) -> StudySetup:
    c = design.control
    count = len(design.joints)
    low = np.array(np.broadcast_to(np.asarray(c.normal_force_min, dtype=float), (count,)))
    high = np.array(np.broadcast_to(np.asarray(c.normal_force_max, dtype=float), (count,)))
    if not (c.study_duration > PULSE_DURATION):
        raise ModelError(f"control.study_duration: {c.study_duration!r} s — must exceed the pulse ({PULSE_DURATION} s)")
    check_sample_time(model, c.sample_time)
    return StudySetup(
        model,
        plant if plant is not None else model,
        [lugre.TABLE_1[j.type] for j in design.joints],
        float(c.sample_time),
        low,
        high,
        float(c.study_duration),
        float(c.piezo_capacitance),
        float(c.piezo_force_per_volt),
        float(c.piezo_preload),
    )


# ---------------------------------------------------------------------------------------- runs
def _piezo_power(s: StudySetup, normal_force: np.ndarray) -> float:
    """Mean electrical power to charge the stacks, V = (F_N − preload)/k per joint, starting
    from 0 V before t = 0: ½C·max(0, V_k² − V_k−1²) per sample (no charge recovered)."""
    volts = np.maximum(normal_force - s.piezo_preload, 0.0) / s.piezo_force_per_volt
    squared = np.vstack([np.zeros((1, volts.shape[1])), volts]) ** 2
    charge = 0.5 * s.piezo_capacitance * np.maximum(np.diff(squared, axis=0), 0.0)
    return float(charge.sum() / s.duration)


def run_semi_active(s: StudySetup, name: str, controller) -> Run:
    """Any normal-force controller, F_N^max during the pulse (Section 6)."""
    held = HoldDuringExcitation(controller, PULSE_DURATION, s.normal_force_max)
    r = simulate(
        s.plant,
        s.laws,
        held,
        s.pulse(),
        s.duration,
        s.plant_step,
        record_every=PLANT_STEPS_PER_SAMPLE,
        energy_books=False,
    )
    return Run(
        name,
        r.time,
        r.energy,
        r.sensors,
        r.normal_force,
        r.friction_force,
        r.sliding_velocity,
        _piezo_power(s, r.normal_force),
        "piezo charging",
    )


def run_passive(s: StudySetup, name: str, normal_forces) -> Run:
    return run_semi_active(s, name, ConstantNormalForce(np.asarray(normal_forces, dtype=float), s.sample_time))


def run_active(s: StudySetup, design: LqgDesign) -> Run:
    """The fully active reference: u_d = −K·x̂ as forces on the linear model (the plant's
    frictionless ``linear`` scheme at the sample time, zero force during the pulse); mean
    mechanical actuator power Σ|u_d·v| on the sample grid."""
    if s.plant is not s.model:
        raise ModelError("the active LQG reference runs on the design model only")
    controller = ActiveLqg(design, hold_until=PULSE_DURATION)
    r = simulate(s.model, [], controller, s.pulse(), s.duration, s.sample_time, energy_books=False, scheme="linear")
    force = r.friction_force  # the linear scheme records the joint forces acting: the actuators'
    power = float(np.sum(np.abs(force * r.sliding_velocity)[:-1]) * s.sample_time / s.duration)
    return Run(
        "active LQG",
        r.time,
        r.energy,
        r.sensors,
        np.full_like(force, np.nan),
        force,
        r.sliding_velocity,
        power,
        "actuator mechanical",
    )


def siso(s: StudySetup, boundary_layer) -> SisoLaw:
    width = np.broadcast_to(np.asarray(boundary_layer, dtype=float), s.normal_force_min.shape)
    return SisoLaw(s.sample_time, s.normal_force_min, s.normal_force_max, width)


# ------------------------------------------------------------------------------- ε optimisation
@dataclass
class BoundaryLayerOptimum:
    """The SISO ε (common to all joints) that minimises Eq. 32, every evaluation, and the
    check of the acceptance: E at ε/10 and 10ε."""

    boundary_layer: float
    energy_measure: float
    evaluations: list[tuple[float, float]]  # (ε, E(t_e)) in evaluation order
    tenth: float  # E(t_e) at ε/10
    tenfold: float  # E(t_e) at 10ε

    def figures(self) -> dict:
        """The optimum, its E(t_e) and the acceptance check, JSON-ready (no evaluations)."""
        return {
            "optimum": self.boundary_layer,
            "energy_measure": self.energy_measure,
            "energy_measure_tenth": self.tenth,
            "energy_measure_tenfold": self.tenfold,
        }


def optimise_boundary_layer(s: StudySetup, progress=print, grid=EPSILON_GRID) -> BoundaryLayerOptimum:
    """ε of Eq. 30 minimising E(t_e) of Eq. 32 (Section 5.1): a half-decade scan of log ε, then
    bounded Brent (scipy ``minimize_scalar``) within a half decade of the best grid point. E is a
    rough function of ε (stick/slip events shift with it), hence the scan before the local search."""
    cache: dict[float, float] = {}

    def measure(log_width: float) -> float:
        width = float(10.0**log_width)
        if width not in cache:
            cache[width] = run_semi_active(s, "SISO", siso(s, width)).energy_measure()
            progress(f"      ε = {width:.3g} m/s: E(t_e) = {cache[width]:.5g} J·s")
        return cache[width]

    logs = [math.log10(g) for g in grid]
    values = [measure(v) for v in logs]
    best = logs[int(np.argmin(values))]
    found = minimize_scalar(
        measure, bounds=(best - 0.5, best + 0.5), method="bounded", options={"xatol": 0.02, "maxiter": 12}
    )
    log_width = float(found.x) if found.fun < min(values) else best
    width = float(10.0**log_width)
    best_value, tenth, tenfold = measure(log_width), measure(log_width - 1.0), measure(log_width + 1.0)
    return BoundaryLayerOptimum(width, best_value, list(cache.items()), tenth, tenfold)


# ------------------------------------------------------------------------------------ metrics
def metrics(run: Run, reference: Run) -> dict:
    """Table of Section 6: energy at t_e (absolute and relative to the reference, passive F^max),
    E(t_e) of Eq. 32, RMS and peak tip deflection after the pulse, settling time to 10 % of the
    energy at the end of the pulse, mean control power."""
    after = run.time > PULSE_DURATION + 1e-12
    tip = run.sensors[after]
    start = int(np.searchsorted(run.time, PULSE_DURATION - 1e-12))
    threshold = SETTLING_FRACTION * run.energy[start]
    above = np.flatnonzero(run.energy > threshold)
    settled = (
        None
        if above.size and above[-1] == run.energy.size - 1
        else float(run.time[above[-1] + 1] if above.size else run.time[0])
    )
    return {
        "energy_end": float(run.energy[-1]),
        "energy_end_relative": float(run.energy[-1] / reference.energy[-1]),
        "energy_measure": run.energy_measure(),
        "tip_rms": [float(v) for v in np.sqrt(np.mean(tip**2, axis=0))],
        "tip_rms_total": float(np.sqrt(np.mean(np.sum(tip**2, axis=1)))),
        "tip_peak": [float(v) for v in np.max(np.abs(tip), axis=0)],
        "settling_time": settled,
        "control_power": run.control_power,
        "power_kind": run.power_kind,
    }


# -------------------------------------------------------------------------------- the study
@dataclass
class Study:
    setup: StudySetup
    lqg: LqgDesign
    boundary_layer: np.ndarray  # SISO ε per joint [m/s]
    optimum: BoundaryLayerOptimum | None  # None when ε came from the design file
    clqg_boundary_layer: float
    runs: list[Run]
    sensor_names: list[str]
    joint_names: list[str]

    def run(self, name: str) -> Run:
        return next(r for r in self.runs if r.name == name)

    @property
    def stability_margin(self) -> float:
        """1 − max|λ| of the linear LQG loop on the design model (> 0: stable)."""
        return float(1.0 - np.max(np.abs(self.lqg.closed_loop_poles())))

    def orderings(self) -> dict:
        """The paper's claims (Section 6) as booleans on this study."""
        m = {r.name: r.metrics for r in self.runs}
        passive = min(m["passive F_min"]["energy_end"], m["passive F_max"]["energy_end"])
        return {
            "siso_below_both_passive": m["SISO"]["energy_end"] < passive,
            "clqg_below_both_passive": m["cLQG"]["energy_end"] < passive,
            "clqg_tip_rms_below_siso": m["cLQG"]["tip_rms_total"] < m["SISO"]["tip_rms_total"],
            "active_tip_rms_below_clqg": m["active LQG"]["tip_rms_total"] < m["cLQG"]["tip_rms_total"],
            "active_energy_below_clqg": m["active LQG"]["energy_end"] < m["cLQG"]["energy_end"],
            "power_ratio_active_to_clqg": m["active LQG"]["control_power"] / m["cLQG"]["control_power"],
        }


def lqg_for(design, model: ModalModel) -> LqgDesign:
    c = design.control
    return design_lqg(model, c.sample_time, c.state_weight, c.control_weight, c.process_noise, c.measurement_noise)


def run_study(design, model: ModalModel | None = None, progress=print) -> Study:
    """Section 6 on ``design`` (already updated): design model, LQG, ε (from the design file or
    optimised), then the five runs and their metrics."""
    c = design.control
    model = model if model is not None else design_model(design, progress)
    s = setup(design, model)
    lqg = lqg_for(design, model)
    optimum = None
    if c.siso_boundary_layer is None:
        progress("      SISO boundary layer ε: optimising E(t_e) of Eq. 32 …")
        optimum = optimise_boundary_layer(s, progress)
        width = np.full(len(design.joints), optimum.boundary_layer)
    else:
        width = np.array(np.broadcast_to(np.asarray(c.siso_boundary_layer, dtype=float), (len(design.joints),)))
    runs = []
    for name, make in (
        ("passive F_min", lambda: run_passive(s, "passive F_min", s.normal_force_min)),
        ("passive F_max", lambda: run_passive(s, "passive F_max", s.normal_force_max)),
        ("SISO", lambda: run_semi_active(s, "SISO", siso(s, width))),
        (
            "cLQG",
            lambda: run_semi_active(
                s, "cLQG", ClippedLqg(lqg, s.normal_force_min, s.normal_force_max, c.clqg_boundary_layer)
            ),
        ),
        ("active LQG", lambda: run_active(s, lqg)),
    ):
        progress(f"      {name}: {s.duration:g} s …")
        runs.append(make())
    reference = runs[1]
    for r in runs:
        r.metrics = metrics(r, reference)
    return Study(
        s, lqg, width, optimum, float(c.clqg_boundary_layer), runs, list(model.sensor_names), list(model.joint_names)
    )


def summary(study: Study) -> dict:
    """JSON-ready figures of the study (no time series)."""
    s = study.setup
    optimum = study.optimum
    return {
        "sample_time": s.sample_time,
        "plant_step": s.plant_step,
        "duration": s.duration,
        "states": s.model.n_states,
        "normal_force_min": s.normal_force_min.tolist(),
        "normal_force_max": s.normal_force_max.tolist(),
        "siso_boundary_layer": study.boundary_layer.tolist(),
        "clqg_boundary_layer": study.clqg_boundary_layer,
        "boundary_layer_optimisation": None
        if optimum is None
        else {
            **optimum.figures(),
            "evaluations": [[w, e] for w, e in optimum.evaluations],
        },
        "lqg_max_pole_magnitude": 1.0 - study.stability_margin,
        "lqg_stability_margin": study.stability_margin,
        "runs": {r.name: r.metrics for r in study.runs},
        "orderings": study.orderings(),
        "joints": study.joint_names,
        "sensors": study.sensor_names,
    }
