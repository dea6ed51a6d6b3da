"""The closed-loop study of paper Section 6: passive joints, every law of the registry (the
paper's SISO law of Eq. 30–31 and clipped LQG of Eq. 33–34 among them, each with its settings
tuned by ``tuning``) and the active LQG after the tip pulse.

The design model is the design's reduced model (the paper's 24 states); each run, its protocol
and its power are in ``runs`` (re-exported here). Everything here is deterministic: the same
inputs give bit-identical results.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design import reduction
from smartjoint.design.control import orderings as paper_orderings
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
)
from smartjoint.design.control.tuning import Tuning, tuned_laws
from smartjoint.design.structure import modal
from smartjoint.design.structure.description import SENSOR_QUANTITIES
from smartjoint.design.structure.fem import build_model
from smartjoint.design.structure.modal import ModalModel
from smartjoint.design.structure.solved import SolvedModel


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
    vectors per joint (Eq. 27–29), made quasi-static above the controller's band
    (`reduction.quasi_static_corrections`), joints frictionless (Eq. 6).

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
    if released is None:
        progress(f"      the lowest {considered} modes of the released truss ({fe.n_dof} DOFs) …")
    first = released.first(considered) if released is not None else modal.solve_modes(fe, considered)
    # The corrections quasi-static above the band the controller samples (no pseudo-mode in it).
    quasi_static = reduction.correction_frequency(c.sample_time)
    return reduction.reduce(fe, first, min(c.modes, considered), c.krylov, correction_frequency=quasi_static).model


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
    tunings: dict[str, Tuning]  # each law's settings, by name, in registry order
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

    def settings(self) -> dict[str, dict]:
        """Each law's tuned settings (law → key → value): what ``artifact_building`` takes."""
        return {name: t.settings for name, t in self.tunings.items()}

    def orderings(self) -> dict:
        """The paper's claims (Section 6, ``orderings``) as booleans on this study; the RMS tip
        deflection claims are None when no sensor measures a displacement (nothing to compare)."""
        return paper_orderings.study_orderings({r.name: r.metrics for r in self.runs})


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
    model = model if model is not None else design_model(design, progress)
    s = setup(design, model)
    lqg = lqg_for(design, model)
    tunings = tuned_laws(design, s, progress)
    runs = []
    for name in ("passive F_min", "passive F_max"):
        progress(f"      {name}: {s.duration:g} s …")
        runs.append(run_passive(s, name, s.normal_force_min if name == "passive F_min" else s.normal_force_max))
    for law in law_registry.LAWS.values():
        progress(f"      {law.display}: {s.duration:g} s …")
        runs.append(run_semi_active(s, law.display, law.study_controller(s, lqg, tunings[law.name].settings)))
    progress(f"      active LQG: {s.duration:g} s …")
    runs.append(run_active(s, lqg))
    reference = runs[1]
    quantities = sensor_quantities(design, model)
    for r in runs:
        r.metrics = metrics(r, reference, quantities)
    return Study(
        s,
        lqg,
        tunings,
        runs,
        list(model.sensor_names),
        list(model.joint_names),
        quantities,
    )


def settings_figures(tunings: dict[str, Tuning]) -> dict:
    """Each law's settings by their ``[control]`` keys (``siso_boundary_layer``), JSON-ready."""
    out = {}
    for name, t in tunings.items():
        for setting in law_registry.LAWS[name].settings:
            value = t.settings[setting.key]
            out[setting.design_key(name)] = value.tolist() if isinstance(value, np.ndarray) else value
    return out


def blind_modes_hz(lqg: LqgDesign, model: ModalModel) -> dict[str, list[float]]:
    """The design model's coordinates no sensor sees / no joint moves, by frequency [Hz]."""
    return {kind: [float(model.omega[i] / (2 * np.pi)) for i in found] for kind, found in lqg.blind_modes().items()}


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
    return {
        "sample_time": s.sample_time,
        "plant_step": s.plant_step,
        "duration": s.duration,
        "pulse_amplitude": s.pulse_amplitude,
        "states": s.model.n_states,
        "normal_force_min": s.normal_force_min.tolist(),
        "normal_force_max": s.normal_force_max.tolist(),
        **settings_figures(study.tunings),
        "tuning": {name: None if t.record is None else t.record.summary() for name, t in study.tunings.items()},
        "lqg_max_pole_magnitude": 1.0 - study.stability_margin,
        "lqg_stability_margin": study.stability_margin,
        "lqg_blind_modes_hz": blind_modes_hz(study.lqg, s.model),
        "runs": {r.name: r.metrics for r in study.runs},
        "orderings": study.orderings(),
        "joints": study.joint_names,
        "sensors": study.sensor_names,
        "sensor_quantities": study.sensor_quantities,
    }


__all__ = [
    "PLANT_STEPS_PER_SAMPLE",
    "PULSE_AMPLITUDE",
    "PULSE_DURATION",
    "SETTLING_FRACTION",
    "Run",
    "Study",
    "StudySetup",
    "blind_modes_hz",
    "controlled_joints",
    "design_model",
    "lqg_for",
    "metrics",
    "piezo_power",
    "run_active",
    "run_passive",
    "run_semi_active",
    "run_study",
    "sensor_metrics",
    "sensor_quantities",
    "settings_figures",
    "setup",
    "summary",
]
