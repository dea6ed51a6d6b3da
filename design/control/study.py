"""The closed-loop study of paper Section 6: passive, SISO (Eq. 30–31), cLQG (Eq. 33–34) and
active LQG joints after the tip pulse, and the ε optimisation of the SISO law for Eq. 32.

The design model is the design's reduced model (the paper's 24 states); each run, its protocol
and its power are in ``runs`` (re-exported here). Everything here is deterministic: the same
inputs give bit-identical results.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from smartjoint.common.errors import ModelError
from smartjoint.design import reduction
from smartjoint.design.control.filter import ClippedLqg
from smartjoint.design.control.lqg import LqgDesign, design_lqg
from smartjoint.design.control.runs import (
    PLANT_STEPS_PER_SAMPLE,
    PULSE_AMPLITUDE,
    PULSE_DURATION,
    SETTLING_FRACTION,
    Run,
    StudySetup,
    piezo_power,
    run_active,
    run_passive,
    run_semi_active,
    setup,
    siso,
)
from smartjoint.design.structure import modal
from smartjoint.design.structure.description import SENSOR_QUANTITIES
from smartjoint.design.structure.fem import build_model
from smartjoint.design.structure.modal import ModalModel
from smartjoint.design.structure.solved import SolvedModel

EPSILON_GRID = tuple(10.0 ** np.arange(-8.0, -1.75, 0.5))  # m/s: the SISO ε scan before refinement


def controlled_joints(design) -> list[str]:
    """The joints the controllers act on: every joint of the design, in ``control.joints`` order
    where given. A strict subset would leave friction joints without a normal force law.

    Parameters
    ----------
    design : Design
        The design read from its file (``design.structure.spec``).

    Returns
    -------
    list of str
        The joint names in design order.

    Raises
    ------
    ModelError
        When ``control.joints`` names other joints or another order.
    """
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


def design_model(design, progress=print, released: SolvedModel | None = None) -> ModalModel:
    """The reduced model of Section 4 the controllers are designed on: ``control.modes`` of the
    first ``control.considered_modes`` modes by Hankel values plus ``control.krylov`` correction
    vectors per joint (Eq. 27–29), joints frictionless (Eq. 6).

    Parameters
    ----------
    design : Design
        The (updated) design with joints, sensors and disturbances.
    progress : callable
        Receives one progress line.
    released : SolvedModel, optional
        The design's released FE model and modes, solved by the structure stage (at least
        ``control.considered_modes`` of them); built and solved here when None.

    Returns
    -------
    ModalModel
        The reduced model (the paper's 24 states for ``three_type_a.toml``).
    """
    c = design.control
    if not design.joints:
        raise ModelError("design has no [[joints]]: the controllers need at least one friction joint")
    if not design.sensors:
        raise ModelError("design has no [[sensors]]: the Kalman filter needs the measured tip deflections")
    if not design.disturbances:
        raise ModelError("design has no [[disturbances]]: the study applies the tip pulse along them")
    controlled_joints(design)
    fe = released.fe if released is not None else build_model(design, joints="released")
    considered = min(c.considered_modes, fe.n_dof)
    progress(f"      reduced model: {c.modes} of the first {considered} modes + {c.krylov} Krylov vector(s) per joint")
    first = released.first(considered) if released is not None else modal.solve_modes(fe, considered)
    return reduction.reduce(fe, first, min(c.modes, considered), c.krylov).model


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
    rough function of ε (stick/slip events shift with it), hence the scan before the local search.

    Parameters
    ----------
    s : StudySetup
        The study the SISO runs are made in.
    progress : callable
        Receives one line per evaluation.
    grid : sequence of float
        The ε [m/s] scanned before the local search.

    Returns
    -------
    BoundaryLayerOptimum
    """
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
def _root_mean_square(values: np.ndarray) -> list[float]:
    """RMS of each column."""
    return [float(v) for v in np.sqrt(np.mean(values**2, axis=0))]


def _peak(values: np.ndarray) -> list[float]:
    """max |·| of each column."""
    return [float(v) for v in np.max(np.abs(values), axis=0)]


def sensor_metrics(sensors: np.ndarray, quantities) -> dict:
    """RMS and peak of the measured outputs y (Eq. 10) after the pulse, by the sensors' quantity.

    Tip deflection figures come from the displacement sensors only (m); velocity sensors get
    their own figures (m/s), so a velocity never enters a deflection.

    Parameters
    ----------
    sensors : ndarray
        y after the pulse, one column per sensor.
    quantities : sequence of str
        Each column's quantity, ``"displacement"`` or ``"velocity"`` (``SENSOR_QUANTITIES``).

    Returns
    -------
    dict
        ``tip_rms`` and ``tip_peak`` per displacement sensor [m] and ``tip_rms_total``, the RMS
        of the norm of the displacement sensors' y [m], all None without a displacement sensor;
        ``velocity_rms`` and ``velocity_peak`` per velocity sensor [m/s], None without one.
    """
    kinds = list(quantities)
    if len(kinds) != sensors.shape[1] or not set(kinds) <= set(SENSOR_QUANTITIES):
        raise ModelError(f"sensor quantities: {kinds} — one of {', '.join(SENSOR_QUANTITIES)} per sensor")
    # All displacement (the paper's sensors): y as it is, so the figures stay bit for bit the same.
    displacement = sensors if "velocity" not in kinds else sensors[:, [q == "displacement" for q in kinds]]
    velocity = sensors[:, [q == "velocity" for q in kinds]]
    deflection = displacement.shape[1] > 0
    return {
        "tip_rms": _root_mean_square(displacement) if deflection else None,
        "tip_rms_total": float(np.sqrt(np.mean(np.sum(displacement**2, axis=1)))) if deflection else None,
        "tip_peak": _peak(displacement) if deflection else None,
        "velocity_rms": _root_mean_square(velocity) if velocity.shape[1] else None,
        "velocity_peak": _peak(velocity) if velocity.shape[1] else None,
    }


def metrics(run: Run, reference: Run, quantities) -> dict:
    """Table of Section 6: energy at t_e (absolute and relative to the reference, passive F^max),
    E(t_e) of Eq. 32, RMS and peak tip deflection after the pulse (displacement sensors; the
    velocity sensors' own RMS and peak beside), settling time to 10 % of the energy at the end
    of the pulse, mean control power.

    Parameters
    ----------
    run : Run
        The run measured.
    reference : Run
        The run the final energy is related to (passive F^max in the study).
    quantities : sequence of str
        Each sensor's quantity in the run's sensor order (``Study.sensor_quantities``).

    Returns
    -------
    dict
        JSON-ready figures (:func:`sensor_metrics` for the sensors); ``settling_time`` is None
        when the run has not settled by t_e.
    """
    after = run.time > PULSE_DURATION + 1e-12
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
        **sensor_metrics(run.sensors[after], quantities),
        "settling_time": settled,
        "control_power": run.control_power,
        "power_kind": run.power_kind,
    }


# -------------------------------------------------------------------------------- the study
@dataclass
class Study:
    """The study's runs and what they were made with; ``sensor_quantities`` gives each sensor's
    quantity (``"displacement"`` in m or ``"velocity"`` in m/s) in ``sensor_names`` order."""

    setup: StudySetup
    lqg: LqgDesign
    boundary_layer: np.ndarray  # SISO ε per joint [m/s]
    optimum: BoundaryLayerOptimum | None  # None when ε came from the design file
    clqg_boundary_layer: float
    runs: list[Run]
    sensor_names: list[str]
    joint_names: list[str]
    sensor_quantities: list[str]

    def run(self, name: str) -> Run:
        return next(r for r in self.runs if r.name == name)

    @property
    def stability_margin(self) -> float:
        """1 − max|λ| of the linear LQG loop on the design model (> 0: stable)."""
        return float(1.0 - np.max(np.abs(self.lqg.closed_loop_poles())))

    def orderings(self) -> dict:
        """The paper's claims (Section 6) as booleans on this study; the RMS tip deflection
        claims are None when no sensor measures a displacement (nothing to compare)."""
        m = {r.name: r.metrics for r in self.runs}
        passive = min(m["passive F_min"]["energy_end"], m["passive F_max"]["energy_end"])

        def below(run: str, other: str) -> bool | None:
            low, high = m[run]["tip_rms_total"], m[other]["tip_rms_total"]
            return None if low is None or high is None else low < high

        return {
            "siso_below_both_passive": m["SISO"]["energy_end"] < passive,
            "clqg_below_both_passive": m["cLQG"]["energy_end"] < passive,
            "clqg_tip_rms_below_siso": below("cLQG", "SISO"),
            "active_tip_rms_below_clqg": below("active LQG", "cLQG"),
            "active_energy_below_clqg": m["active LQG"]["energy_end"] < m["cLQG"]["energy_end"],
            "power_ratio_active_to_clqg": m["active LQG"]["control_power"] / m["cLQG"]["control_power"],
        }


def lqg_for(design, model: ModalModel) -> LqgDesign:
    """The LQG of the design's ``[control]`` weights and noises (:func:`design_lqg`).

    Parameters
    ----------
    design : Design
    model : ModalModel
        The design model.

    Returns
    -------
    LqgDesign
    """
    c = design.control
    return design_lqg(model, c.sample_time, c.state_weight, c.control_weight, c.process_noise, c.measurement_noise)


def sensor_quantities(design, model: ModalModel) -> list[str]:
    """Each measured output's quantity, from the design's sensors in the model's order.

    Parameters
    ----------
    design : Design
        The design whose ``[[sensors]]`` say what each one measures.
    model : ModalModel
        The design model; its ``sensor_names`` give the order of y (Eq. 10).

    Returns
    -------
    list of str
        ``"displacement"`` or ``"velocity"`` per sensor of ``model.sensor_names``.

    Raises
    ------
    ModelError
        When the model measures a sensor the design does not have.
    """
    by_name = {sensor.name: sensor.quantity for sensor in design.sensors}
    missing = [name for name in model.sensor_names if name not in by_name]
    if missing:
        raise ModelError(f"sensors {missing} of the design model are not among the design's [[sensors]]")
    return [by_name[name] for name in model.sensor_names]


def run_study(design, model: ModalModel | None = None, progress=print) -> Study:
    """Section 6 on ``design`` (already updated): design model, LQG, ε (from the design file or
    optimised), then the five runs and their metrics.

    Parameters
    ----------
    design : Design
        The updated design.
    model : ModalModel, optional
        The design model; built by :func:`design_model` when not given.
    progress : callable
        Receives the progress lines.

    Returns
    -------
    Study

    Examples
    --------
    >>> from smartjoint.design.structure.spec import load_design
    >>> study = run_study(load_design("design/data/three_type_a.toml"), progress=lambda line: None)  # doctest: +SKIP
    >>> study.orderings()["clqg_below_both_passive"]  # doctest: +SKIP
    True
    """
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
    quantities = sensor_quantities(design, model)
    for r in runs:
        r.metrics = metrics(r, reference, quantities)
    return Study(
        s,
        lqg,
        width,
        optimum,
        float(c.clqg_boundary_layer),
        runs,
        list(model.sensor_names),
        list(model.joint_names),
        quantities,
    )


def summary(study: Study) -> dict:
    """JSON-ready figures of the study (no time series).

    Parameters
    ----------
    study : Study

    Returns
    -------
    dict
        Timing, limits, ε, the LQG's stability margin, each run's metrics and the orderings, the
        joints, the sensors and each sensor's quantity.
    """
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
        "sensor_quantities": study.sensor_quantities,
    }


__all__ = [
    "EPSILON_GRID",
    "PLANT_STEPS_PER_SAMPLE",
    "PULSE_AMPLITUDE",
    "PULSE_DURATION",
    "SETTLING_FRACTION",
    "BoundaryLayerOptimum",
    "Run",
    "Study",
    "StudySetup",
    "controlled_joints",
    "design_model",
    "lqg_for",
    "metrics",
    "optimise_boundary_layer",
    "piezo_power",
    "run_active",
    "run_passive",
    "run_semi_active",
    "run_study",
    "sensor_metrics",
    "sensor_quantities",
    "setup",
    "siso",
    "summary",
]
