"""The reduction study of paper Section 4.3 (Fig. 10): the full model against reduced models
with 0…K Krylov vectors under the tip pulse, by friction force and by the error metrics."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design import plant
from smartjoint.design.friction.model import joint_parameters
from smartjoint.design.reduction.comparison import compare_with_balanced_truncation
from smartjoint.design.reduction.krylov import (
    correction_frequency,
    krylov_vectors,
    quasi_static_corrections,
    reduce,
    with_corrections,
)
from smartjoint.design.reduction.metrics import band_norms, error_metrics, static_compliance
from smartjoint.design.structure import modal
from smartjoint.design.structure.fem import FEModel, build_model
from smartjoint.design.structure.modal import ModalModel
from smartjoint.design.structure.solved import SolvedModel

WINDOWS = (0.05, 0.1, 0.2, 0.5)  # s: RMS windows of the friction-moment comparison


DENSE_REFERENCE_DOFS = 10_000  # above: the sparse reference (a dense eigh of 10 000 DOFs: 2.4 GB, ~1 min)
REFERENCE_MODES_PER_CONSIDERED = 2  # the sparse reference: this many × the considered modes
# A window's friction error is judged only where the sparse reference moves by less than this
# (relative RMS) when its modes are halved; above, the reference is not converged there.
REFERENCE_CONVERGED = 0.1


class FullModel(NamedTuple):
    """The reduction study's reference: the released truss ``fe``, its full model ``model``, its
    first ``considered`` modes ``first`` and the band [rad/s] the errors are measured in (inf for
    every mode); ``halved`` is the sparse reference rebuilt from half its modes (None when dense),
    whose distance from ``model`` says how far the reference itself is converged."""

    fe: FEModel
    model: ModalModel
    first: modal.Modes
    band: float
    halved: ModalModel | None


def _with_static_residual(fe, modes: modal.Modes, correction: float) -> ModalModel:
    """``modes`` plus the static residual of every joint and disturbance input, K⁻¹[E F]
    M-orthogonalised against them and quasi-static at ``correction`` [rad/s]: exact static compliance."""
    model = modal.modal_model(fe, modes)
    assert model.basis is not None  # modal_model keeps the shapes
    psi, omega_hat, _ = krylov_vectors(fe.stiffness, fe.mass, np.column_stack([fe.E, fe.F]), model.basis, 1)
    residual = with_corrections(fe, model, psi, omega_hat, "krylov residual")
    return quasi_static_corrections(residual, correction)


def _full_model(design, considered: int, progress, released: SolvedModel | None, correction: float) -> FullModel:
    """The released truss (``released``'s FE model where given), its full-model reference and
    its first ``considered`` modes, from one eigen solution: the basis and the reference the
    errors are measured against come from the same modes.

    Up to ``DENSE_REFERENCE_DOFS`` the reference is every mode of Eq. 5 (a dense solution).
    Above, it is the lowest ``REFERENCE_MODES_PER_CONSIDERED`` × ``considered`` modes (sparse
    shift-invert) plus the static residual of every joint and disturbance input
    (`_with_static_residual`): exact static compliance and the dynamics of every mode up to the
    highest one solved, which bounds the band the errors are measured in. The same with half the
    modes is returned too: a reference that moves when its modes are halved cannot judge a
    reduced model (a pulse that has not reached the joint yet on a long truss, for example).
    """
    fe = released.fe if released is not None else build_model(design, joints="released")
    if fe.n_dof <= DENSE_REFERENCE_DOFS:
        modal.check_dense_fits(
            fe.n_dof,
            "reduction study: its reference, the full model, is every mode of the released truss",
            f"models above {DENSE_REFERENCE_DOFS} DOFs get the sparse reference",
        )
        progress(f"      all {fe.n_dof} modes of the released truss (the full model) …")
        everything = modal.solve_modes(fe, fe.n_dof)
        full = modal.modal_model(fe, everything)
        first = modal.Modes(
            everything.omega[:considered], everything.shapes[:, :considered], everything.damping[:considered]
        )
        return FullModel(fe, full, first, np.inf, None)
    count = min(REFERENCE_MODES_PER_CONSIDERED * considered, fe.n_dof - fe.E.shape[1] - fe.F.shape[1])
    if released is not None and len(released.modes) >= count:
        modes = released.first(count)
    else:
        progress(f"      the lowest {count} modes of the released truss ({fe.n_dof} DOFs, sparse) …")
        modes = modal.solve_modes(fe, count)
    progress(
        f"      full-model reference: {count} modes (to {modes.omega[-1] / (2 * np.pi):.4g} Hz) + the static residual "
        f"of {fe.E.shape[1]} joint and {fe.F.shape[1]} disturbance inputs, quasi-static at "
        f"{correction / (2 * np.pi):.0f} Hz (above {DENSE_REFERENCE_DOFS} DOFs every mode is not solved)"
    )
    half = count // 2
    halved = modal.Modes(modes.omega[:half], modes.shapes[:, :half], modes.damping[:half])
    first = modal.Modes(modes.omega[:considered], modes.shapes[:, :considered], modes.damping[:considered])
    return FullModel(
        fe,
        _with_static_residual(fe, modes, correction),
        first,
        float(modes.omega[-1]),
        _with_static_residual(fe, halved, correction),
    )


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


def window_text(errors: dict, convergence: dict | None) -> str:
    """Friction RMS errors per window as text, "not measured" where the reference moves by more
    than ``REFERENCE_CONVERGED`` when its modes are halved (``convergence``, None: every mode)."""
    if convergence is not None and all(convergence[w] > REFERENCE_CONVERGED for w in errors):
        return "not measured (the reference is not converged in any window)"
    return ", ".join(
        f"{100 * e:.1f} % (0–{w} s)"
        if convergence is None or convergence[w] <= REFERENCE_CONVERGED
        else f"not measured (0–{w} s)"
        for w, e in errors.items()
    )


def _convergence(halved: ModalModel | None, simulate_model, reference, active: int, duration: float, progress):
    """How far the sparse reference's friction force at the active joint moves per window when
    it is rebuilt from half its modes (``halved``): the resolution of every error measured against
    it. None for the dense reference (``halved`` None), which is exact."""
    if halved is None:
        return None
    moved = simulate_model(halved)
    convergence = _friction_rms_errors(moved.friction_force[:, active], reference, active, duration)
    unresolved = [w for w, e in convergence.items() if e > REFERENCE_CONVERGED]
    progress(
        "      the reference with half its modes moves by "
        + ", ".join(f"{100 * e:.1f} % (0–{w} s)" for w, e in convergence.items())
        + (
            f": not converged in {', '.join(f'0–{w} s' for w in unresolved)} (above "
            f"{100 * REFERENCE_CONVERGED:.0f} %), the friction errors there are not measured"
            if unresolved
            else ""
        )
    )
    return convergence


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


def load_case(design) -> np.ndarray:
    """The reduction study's constant F_N per joint of ``design`` (Fig. 10's load case), from the
    design only: ``[control] reduction_normal_force`` where given, else the first controlled joint
    at its F_N^max (the joint compared, which gets the Krylov vectors) and every other joint at its
    F_N^min, 0 N for a joint no controller sets.

    Returns
    -------
    ndarray
        One F_N [N] per ``design.joints`` entry; empty for a design without joints.
    """
    names = [j.name for j in design.joints]
    c = design.control
    if not names:
        return np.zeros(0)
    if c.reduction_normal_force is not None:
        return np.array(np.broadcast_to(np.asarray(c.reduction_normal_force, dtype=float), (len(names),)))
    controlled = list(c.joints) if c.joints is not None else names
    low = np.broadcast_to(np.asarray(c.normal_force_min, dtype=float), (len(controlled),))
    high = np.broadcast_to(np.asarray(c.normal_force_max, dtype=float), (len(controlled),))
    forces = np.zeros(len(names))
    for k, name in enumerate(controlled):
        forces[names.index(name)] = high[k] if k == 0 else low[k]
    return forces


def _pulse_simulation(design, normal_forces: np.ndarray, duration: float, step: float):
    """``plant.simulate`` of a model under the study's run: the design's joint laws, the normal
    forces held constant, the study's tip pulse (``[control] pulse_amplitude`` along every input), no
    energy books."""
    laws = joint_parameters(design)
    controller = plant.ConstantNormalForce(normal_forces, design.control.sample_time)
    pulse = plant.triangular_pulse(design.control.pulse_amplitude, directions=np.ones(len(design.disturbances)))

    def simulate_model(model):
        return plant.simulate(model, laws, controller, pulse, duration, step, energy_books=False)

    return simulate_model


def _krylov_runs(
    fe,
    full,
    first,
    keep: int,
    krylov,
    krylov_joints,
    simulate_model,
    reference,
    active,
    duration,
    progress,
    bands,
    convergence,
) -> list[dict]:
    """One reduced model per Krylov count (``keep`` modes of ``first`` plus the vectors, quasi-static
    at ``bands[0]``, 4× the controller's Nyquist frequency), each run and compared with the full
    model's ``reference`` run, in the considered band and across the band to ``bands[1]`` (the
    Nyquist frequency, or the sparse reference's highest mode below it) [rad/s]; ``convergence``
    is the reference's own change per window when its modes are halved (None: every mode)."""
    band = float(first.omega[-1])
    runs = []
    for count in krylov:
        quasi_static, nyquist = bands
        reduced = reduce(fe, first, keep, count, krylov_joints=krylov_joints, correction_frequency=quasi_static)
        result = simulate_model(reduced.model)
        errors = _friction_rms_errors(result.friction_force[:, active], reference, active, duration)
        metrics = error_metrics(fe, full, reduced.model, band)
        if full.joint_input.shape[1]:
            metrics["uv_nyquist"] = band_norms(full, reduced.model, nyquist, "uv")
        metrics["nyquist_hz"] = nyquist / (2.0 * np.pi)
        runs.append(_compared_run(count, reduced, result, reference, errors, metrics))
        progress(
            f"      {keep} modes + {count} Krylov vector(s): friction RMS error " + window_text(errors, convergence)
        )
    return runs


def _design_model_comparison(design, fe, full, first, design_model, nyquist, progress):
    """The design model against balanced truncation of ``full`` at its order (BT given the modes
    below 4× Nyquist), in the band of the first ``control.considered_modes`` and to Nyquist; None
    without a design model."""
    if design_model is None:
        return None
    considered = min(design.control.considered_modes, first.omega.size)
    progress(f"      design model ({design_model.n_states} states) against balanced truncation of the full model …")
    compared = compare_with_balanced_truncation(
        full, {"design model": design_model}, static_compliance(fe), float(first.omega[considered - 1]), nyquist
    )
    if compared.skipped:
        progress(f"      {compared.skipped}")
    else:
        progress(
            f"      u_R → v H∞ error to {compared.nyquist_hz:.0f} Hz: "
            f"{compared.ratio('nyquist', 'uv', 'design model'):.2f}× balanced truncation's, in band "
            f"{compared.ratio('band', 'uv', 'design model'):.2f}× ({compared.seconds:.0f} s)"
        )
    return compared


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
    design_model: ModalModel | None = None,
) -> dict:
    """Full model (all modes of Eq. 5, or `_full_model`'s sparse reference) against reduced models
    with 0…K Krylov vectors under the paper's tip pulse: Fig. 10 and the metrics of Section 4.

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
    krylov, krylov_joints : tuple of int, list of int or None
        Krylov vectors per joint (one reduced model each) and the joints (0-based) that get them.
    duration, step : float
        Simulated time and plant step [s].
    progress : callable
        Receives one line per stage.
    released : SolvedModel, optional
        The design's released FE model and modes, from the structure stage.
    design_model : ModalModel, optional
        The controllers' design model, compared with balanced truncation (``comparison``).

    Returns
    -------
    dict
        ``fe``, ``full``, ``first``, ``reference`` and one entry of ``runs`` per Krylov count
        (result, reduction, ``friction_rms_error`` per window of ``WINDOWS``, metrics, energy
        ratio), with the sizes and settings; `study_summary` is its JSON-able part.

    Raises ModelError for a design without joints.
    """
    if not design.joints:
        raise ModelError("design has no [[joints]]: the reduction study needs at least one friction joint")
    correction = correction_frequency(design.control.sample_time)
    fe, full, first, reference_band, halved = _full_model(design, considered, progress, released, correction)
    simulate_model = _pulse_simulation(design, normal_forces, duration, step)
    considered, keep = min(considered, fe.n_dof), min(keep, considered, fe.n_dof)
    progress(f"      full model: {full.n_states} states, {duration:g} s at {step:g} s")
    reference, active = simulate_model(full), int(np.argmax(normal_forces))
    convergence = _convergence(halved, simulate_model, reference, active, duration, progress)
    # Errors across the band to the Nyquist frequency, or to the reference's highest mode below it.
    upper = min(np.pi / design.control.sample_time, reference_band)
    runs = _krylov_runs(
        fe, full, first, keep, krylov, krylov_joints, simulate_model, reference, active, duration, progress,
        (correction, upper), convergence,
    )  # fmt: skip
    return {
        "comparison": _design_model_comparison(design, fe, full, first, design_model, upper, progress),
        "reference_band_hz": reference_band / (2.0 * np.pi),
        "reference_convergence": convergence,
        "fe": fe,
        "full": full,
        "first": first,
        **{"reference": reference, "runs": runs, "active": active, "considered": considered, "keep": keep},
        **{"duration": duration, "step": step},
        "correction_frequency_hz": correction / (2.0 * np.pi),
        "joint_names": [j.name for j in design.joints],
        "normal_forces": normal_forces.tolist(),
        "pulse_amplitude": design.control.pulse_amplitude,
        "disturbances": [d.name for d in design.disturbances],
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
        "pulse_amplitude": study["pulse_amplitude"],
        "disturbances": study["disturbances"],
        "active_joint": study["joint_names"][study["active"]],
        "full_states": study["full"].n_states,
        # None: every mode (dense); else the sparse reference's highest mode [Hz], its band's end
        "reference_band_hz": None if not np.isfinite(study["reference_band_hz"]) else study["reference_band_hz"],
        # None when dense; else the reference's own change when its modes are halved, per window
        "reference_convergence": study.get("reference_convergence"),
        "reference_converged_below": REFERENCE_CONVERGED,
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
        "design_model_comparison": None if study.get("comparison") is None else study["comparison"].summary(),
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


__all__ = ["WINDOWS", "load_case", "reduction_study", "study_summary", "window_text"]
