"""The reduction study of paper Section 4.3 (Fig. 10): the full model against reduced models
with 0…K Krylov vectors under the tip pulse, by friction force and by the error metrics."""

from __future__ import annotations

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design import plant
from smartjoint.design.friction.model import joint_parameters
from smartjoint.design.reduction.krylov import correction_frequency, reduce
from smartjoint.design.reduction.metrics import band_norms, error_metrics
from smartjoint.design.structure import modal
from smartjoint.design.structure.fem import build_model
from smartjoint.design.structure.solved import SolvedModel

WINDOWS = (0.05, 0.1, 0.2, 0.5)  # s: RMS windows of the friction-moment comparison


def _full_model(design, considered: int, progress, released: SolvedModel | None):
    """The released truss (``released``'s FE model where given), its full modal model (all
    modes of Eq. 5) and its first ``considered`` modes, from that one full solution: the basis
    and the reference the errors are measured against come from the same eigen solution."""
    fe = released.fe if released is not None else build_model(design, joints="released")
    modal.check_dense_fits(
        fe.n_dof,
        "reduction study: its reference, the full model, is every mode of the released truss",
        "the study runs on smaller models (it has no sparse full-model reference yet)",
    )
    progress(f"      all {fe.n_dof} modes of the released truss (the full model) …")
    everything = modal.solve_modes(fe, fe.n_dof)
    full = modal.modal_model(fe, everything)
    first = modal.Modes(
        everything.omega[:considered], everything.shapes[:, :considered], everything.damping[:considered]
    )
    return fe, full, first


def _friction_rms_errors(reduced_u: np.ndarray, reference, active: int, duration: float) -> dict:
    """The relative RMS error of the active joint's friction force over each window of ``WINDOWS``."""
    ref_u = reference.friction_force[:, active]
    diff = reduced_u - ref_u
    return {
        f"{w:g}": float(
            np.sqrt(np.mean(diff[reference.time <= w] ** 2)) / np.sqrt(np.mean(ref_u[reference.time <= w] ** 2))
        )
        for w in WINDOWS
        if w <= duration
    }


def _compared_run(count: int, reduced, result, reference, errors: dict, metrics: dict) -> dict:
    """One entry of the study's ``runs``: a reduced model's run compared with the full model's."""
    return {
        "krylov_per_joint": count,
        "states": reduced.model.n_states,
        "result": result,
        "reduction": reduced,
        "friction_rms_error": errors,
        "metrics": metrics,
        "energy_measure_ratio": result.energy_measure() / reference.energy_measure(),
    }


def _pulse_simulation(design, normal_forces: np.ndarray, duration: float, step: float):
    """``plant.simulate`` of a model under the study's run: the design's joint laws, the normal
    forces held constant, the paper's tip pulse (200 N along every input), no energy books."""
    laws = joint_parameters(design)
    controller = plant.ConstantNormalForce(normal_forces, 1e-3)
    pulse = plant.triangular_pulse(directions=np.ones(len(design.disturbances)))  # 200 N along every input

    def simulate_model(model):
        return plant.simulate(model, laws, controller, pulse, duration, step, energy_books=False)

    return simulate_model


def _krylov_runs(
    fe, full, first, keep: int, krylov, krylov_joints, simulate_model, reference, active, duration, progress, nyquist
) -> list[dict]:
    """One reduced model per Krylov count (``keep`` modes of ``first`` plus the vectors, quasi-static
    above 4× the controller's Nyquist frequency ``nyquist``), each run and compared with the full
    model's ``reference`` run, in the considered band and across the band to ``nyquist``."""
    band = float(first.omega[-1])
    runs = []
    for count in krylov:
        quasi_static = correction_frequency(np.pi / nyquist)
        reduced = reduce(fe, first, keep, count, krylov_joints=krylov_joints, correction_frequency=quasi_static)
        result = simulate_model(reduced.model)
        errors = _friction_rms_errors(result.friction_force[:, active], reference, active, duration)
        metrics = error_metrics(fe, full, reduced.model, band)
        if full.joint_input.shape[1]:
            metrics["uv_nyquist"] = band_norms(full, reduced.model, nyquist, "uv")
        metrics["nyquist_hz"] = nyquist / (2.0 * np.pi)
        runs.append(_compared_run(count, reduced, result, reference, errors, metrics))
        progress(
            f"      {keep} modes + {count} Krylov vector(s): friction RMS error "
            + ", ".join(f"{100 * e:.1f} % (0–{w} s)" for w, e in errors.items())
        )
    return runs


def reduction_study(
    design,
    normal_forces: np.ndarray,
    considered: int = 100,
    keep: int = 60,
    krylov: tuple[int, ...] = (0, 2),
    krylov_joints: list[int] | None = None,
    duration: float = 0.5,
    step: float = 5e-5,
    progress=print,
    released: SolvedModel | None = None,
) -> dict:
    """Full model (all modes of Eq. 5) against reduced models with 0…K Krylov vectors under the
    paper's tip pulse: the friction forces of Fig. 10 and the error metrics of Section 4.

    Parameters
    ----------
    design : Design
        A design with at least one joint.
    normal_forces : ndarray
        F_N per joint [N], held constant; the largest one marks the active joint compared.
    considered : int
        The first modes the selection chooses from (capped at the DOFs).
    keep : int
        Modes kept by Hankel values (capped at ``considered``).
    krylov : tuple of int
        Krylov vectors per joint, one reduced model each.
    krylov_joints : list of int, optional
        The joints (0-based) that get vectors (default: all).
    duration, step : float
        Simulated time and plant step [s].
    progress : callable
        Receives one line per stage.
    released : SolvedModel, optional
        The design's released FE model, built by the structure stage. Its every mode is solved
        here (the full model's dense solution, of which the selection's first ``considered``
        modes are a part).

    Returns
    -------
    dict
        ``fe``, ``full``, ``first``, ``reference`` and one entry of ``runs`` per Krylov count
        (result, reduction, ``friction_rms_error`` per window of ``WINDOWS``, metrics, energy
        ratio), with the sizes and settings; `study_summary` is its JSON-able part.

    Raises
    ------
    ModelError
        For a design without joints.
    """
    if not design.joints:
        raise ModelError("design has no [[joints]]: the reduction study needs at least one friction joint")
    fe, full, first = _full_model(design, considered, progress, released)
    simulate_model = _pulse_simulation(design, normal_forces, duration, step)
    considered = min(considered, fe.n_dof)
    keep = min(keep, considered)
    progress(f"      full model: {full.n_states} states, {duration:g} s at {step:g} s")
    reference = simulate_model(full)
    active = int(np.argmax(normal_forces))
    nyquist = np.pi / design.control.sample_time
    runs = _krylov_runs(
        fe, full, first, keep, krylov, krylov_joints, simulate_model, reference, active, duration, progress, nyquist
    )
    return {
        "fe": fe,
        "full": full,
        "first": first,
        "reference": reference,
        "runs": runs,
        "active": active,
        "considered": considered,
        "keep": keep,
        "duration": duration,
        "step": step,
        "correction_frequency_hz": correction_frequency(design.control.sample_time) / (2.0 * np.pi),
        "joint_names": [j.name for j in design.joints],
        "normal_forces": normal_forces.tolist(),
    }


def study_summary(study: dict) -> dict:
    """The JSON-able part of a reduction study.

    Parameters
    ----------
    study : dict
        A result of `reduction_study`.

    Returns
    -------
    dict
        Joints, forces, sizes, the (scaled) Hankel values u_R → v with the reference of each
        channel (kind, name, value, unit, the mode it sits at) and per run the kept modes, the Krylov
        frequencies [Hz], the friction RMS errors, the energy ratio and the error metrics.
    """
    hankel = study["runs"][0]["reduction"].hankel
    return {
        "joints": study["joint_names"],
        "normal_forces": study["normal_forces"],
        "active_joint": study["joint_names"][study["active"]],
        "full_states": study["full"].n_states,
        "considered_modes": study["considered"],
        "kept_modes": study["keep"],
        "duration_s": study["duration"],
        "correction_frequency_hz": study["correction_frequency_hz"],
        "step_s": study["step"],
        "hankel_uv": hankel["uv"].tolist(),
        "hankel_references": [
            {"kind": c.kind, "name": c.name, "value": c.value, "unit": c.unit, "mode": c.mode}
            for c in study["runs"][0]["reduction"].references
        ],
        "runs": [
            {
                "krylov_per_joint": r["krylov_per_joint"],
                "states": r["states"],
                "kept_modes": (r["reduction"].kept_modes + 1).tolist(),
                "krylov_frequencies_hz": (r["reduction"].model.omega[study["keep"] :] / (2 * np.pi)).tolist(),
                "friction_rms_error": r["friction_rms_error"],
                "energy_measure_ratio": r["energy_measure_ratio"],
                "metrics": r["metrics"],
            }
            for r in study["runs"]
        ],
    }


__all__ = ["WINDOWS", "reduction_study", "study_summary"]
