"""Model updating to measured eigenfrequencies (paper Section 3.3; Friswell & Mottershead).

Sensitivity-based least squares: the uncertain stiffness parameters p_k (end connector EA, EI,
GJ; E and G of the tube material) enter K linearly, K = Σ_k p_k·K_k (see ``fem.py``), so the
eigenvalue sensitivities are exact and cheap (Fox & Kapoor, mass-normalised φ_i):

    ∂(ω_i²)/∂p_k = φ_iᵀ K_k φ_i        (M does not depend on p)

The residual of mode i is the relative frequency error r_i = w_i·(f_i − f̂_i)/f̂_i with the FE
mode paired to the EMA mode by its number (as in the paper's Fig. 7); the weight w_i is the
mode's MAC from the EMA where given (a clearly identified mode counts more), else 1. Parameters are solved
for in log scale, θ_k = ln(p_k/p_k⁰), bounded to [1/max_factor, max_factor]·p_k⁰, with
scipy.optimize.least_squares (trust-region reflective). Paired by number, the objective is
only piecewise smooth (modes cross), so a Sobol screening of the parameter box picks the
starting points; the best polished fit wins.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.stats

from smartjoint.common.errors import ModelError
from smartjoint.design.structure.fem import FEModel
from smartjoint.design.structure.modal import eigensolve

SEED = 20021  # fixed: the same design always updates to the same parameters
SCREENING_SAMPLES = 64
POLISHED_STARTS = 2


@dataclass
class UpdatingResult:
    parameter_names: list[str]
    initial: np.ndarray  # p⁰
    updated: np.ndarray  # p
    modes: np.ndarray  # measured mode numbers (1-based)
    measured_hz: np.ndarray
    initial_hz: np.ndarray
    updated_hz: np.ndarray
    sensitivity: np.ndarray  # (n_modes, n_params) ∂ln f_i / ∂ln p_k at the updated point
    evaluations: int
    starts: int
    mac: np.ndarray | None  # the EMA MAC values given in the design (for the report)

    @property
    def initial_error_pct(self) -> np.ndarray:
        return 100.0 * (self.initial_hz - self.measured_hz) / self.measured_hz

    @property
    def error_pct(self) -> np.ndarray:
        return 100.0 * (self.updated_hz - self.measured_hz) / self.measured_hz

    @property
    def parameters(self) -> dict[str, float]:
        return dict(zip(self.parameter_names, self.updated.tolist()))

    def as_dict(self) -> dict:
        return {
            "parameters": [
                {
                    "name": n,
                    "initial": float(p0),
                    "updated": float(p),
                    "ratio": float(p / p0),
                    "sensitivity": float(np.linalg.norm(self.sensitivity[:, k])),
                }
                for k, (n, p0, p) in enumerate(zip(self.parameter_names, self.initial, self.updated))
            ],
            "modes": [
                {
                    "index": int(i),
                    "ema_hz": float(m),
                    "fem_initial_hz": float(f0),
                    "fem_hz": float(f),
                    "error_pct": float(e),
                }
                for i, m, f0, f, e in zip(
                    self.modes, self.measured_hz, self.initial_hz, self.updated_hz, self.error_pct
                )
            ],
            "max_abs_error_pct": float(np.max(np.abs(self.error_pct))),
            "evaluations": self.evaluations,
            "starts": self.starts,
        }


def _frequencies(model: FEModel, names, values, n_modes):
    stiffness = model.stiffness_with(dict(zip(names, values)))
    eigenvalues, shapes = eigensolve(stiffness, model.mass, n_modes)
    if eigenvalues[0] <= 0.0:
        raise ModelError("model updating reached a parameter set with a singular stiffness matrix")
    return np.sqrt(eigenvalues) / (2.0 * np.pi), shapes


def _updating_inputs(model: FEModel):
    """The [updating] section, its parameters with their values in the model, the measured
    mode numbers and frequencies, and how many modes to solve — each checked against the model."""
    spec = model.design.updating
    if spec is None:
        raise ModelError(f"{model.design.source}: the design has no [updating] section")
    names = list(spec.parameters)
    initial = np.array([model.parameters[n] for n in names if n in model.parameters])
    missing = [n for n in names if n not in model.parameters]
    if missing:
        raise ModelError(f"updating.parameters: {missing[0]!r} is used by no element of the model")
    modes = np.array([m.mode for m in spec.measured])
    measured = np.array([m.frequency_hz for m in spec.measured])
    n_modes = int(modes.max())
    if n_modes > model.n_dof:
        raise ModelError(f"updating.measured: mode {n_modes} exceeds the model's {model.n_dof} DOFs")
    return spec, names, initial, modes, measured, n_modes


def _multistart_fit(residual, jacobian, weight: np.ndarray, bound: np.ndarray, n_parameters: int, progress):
    """The least-squares fit of the log-parameters θ within ±``bound`` from several starts.

    Returns the best solution and how many starts were polished."""
    # Paired by mode number the objective is only piecewise smooth (modes cross), so local
    # descent alone stalls: screen a scrambled Sobol sample of the log-parameter box, then
    # polish the nominal point and the best samples with least squares.
    sampler = scipy.stats.qmc.Sobol(n_parameters, scramble=True, seed=SEED)
    samples = (2.0 * sampler.random(SCREENING_SAMPLES) - 1.0) * bound
    scores = np.array([np.max(np.abs(residual(theta) / weight)) for theta in samples])
    if progress:
        progress(0, POLISHED_STARTS + 1, float(scores.min()) * 100.0)
    starts = [np.zeros(n_parameters)] + [samples[i] for i in np.argsort(scores)[:POLISHED_STARTS]]
    best = None
    for k, start in enumerate(starts):
        solution = scipy.optimize.least_squares(
            residual,
            start,
            jac=jacobian,
            bounds=(-bound, bound),
            method="trf",
            x_scale=1.0,
            xtol=1e-10,
            ftol=1e-12,
            max_nfev=60,
        )
        if best is None or solution.cost < best.cost:
            best = solution
        if progress:
            progress(k + 1, len(starts), float(np.max(np.abs(best.fun / weight))) * 100.0)
        if np.max(np.abs(best.fun / weight)) < 0.002:  # within 0.2 % on every mode: no further start helps
            break
    assert best is not None  # starts always holds the nominal point
    return best, k + 1


def update_model(model: FEModel, progress=None) -> UpdatingResult:
    """Fit the design's ``[updating]`` parameters to its measured frequencies.

    Parameters
    ----------
    model : FEModel
        The locked truss of a design with ``[updating]``.
    progress : callable, optional
        ``progress(k, n, worst_error_pct)`` after each polished start.

    Returns
    -------
    UpdatingResult
        The fitted parameters, the frequencies before and after, the errors and sensitivities.
    """
    spec, names, initial, modes, measured, n_modes = _updating_inputs(model)
    index = modes - 1
    # Trust in each measured mode: its MAC against the FE shape where the EMA gives one.
    weight = np.array([m.mac if m.mac is not None else 1.0 for m in spec.measured])
    bound = np.log(np.array(spec.max_factors))
    parts = [model.stiffness_parts[n] for n in names]
    calls = {"n": 0}
    cache: dict[bytes, tuple] = {}

    def evaluate(theta):
        key = np.asarray(theta).tobytes()
        if key not in cache:
            calls["n"] += 1
            cache.clear()
            cache[key] = _frequencies(model, names, initial * np.exp(theta), n_modes)
        return cache[key]

    def residual(theta):
        frequencies, _ = evaluate(theta)
        return weight * (frequencies[index] - measured) / measured

    def jacobian(theta):
        frequencies, shapes = evaluate(theta)
        values = initial * np.exp(theta)
        phi = shapes[:, index]
        d_lambda = np.column_stack([np.einsum("ij,ij->j", phi, part @ phi) for part in parts])  # ∂ω²/∂p
        f = frequencies[index]
        return weight[:, None] * d_lambda * values[None, :] / (8.0 * np.pi**2 * f[:, None] * measured[:, None])

    best, polished = _multistart_fit(residual, jacobian, weight, bound, len(names), progress)
    initial_hz, _ = _frequencies(model, names, initial, n_modes)
    updated = initial * np.exp(best.x)
    updated_hz, _ = evaluate(best.x)
    sensitivity = jacobian(best.x) * (measured / updated_hz[index] / weight)[:, None]
    return UpdatingResult(
        names,
        initial,
        updated,
        modes,
        measured,
        initial_hz[index],
        updated_hz[index],
        sensitivity,
        calls["n"],
        polished,
        np.array([m.mac if m.mac is not None else np.nan for m in spec.measured]),
    )


def updated_design(design, progress=None):
    """The design with its ``[updating]`` parameters fitted, and the result (None without one).

    Updating always runs on the conventional truss (joints locked): that is what the modal
    survey measured, whatever joint setting the caller then builds its model with.

    Parameters
    ----------
    design : Design
        The design.
    progress : callable, optional
        As for `update_model`.

    Returns
    -------
    tuple
        (Design with the fitted parameters, UpdatingResult or None).
    """
    from smartjoint.design.structure.fem import build_model

    if design.updating is None:
        return design, None
    result = update_model(build_model(design, joints="locked"), progress=progress)
    return design.with_parameters(result.parameters), result


__all__ = ["POLISHED_STARTS", "SCREENING_SAMPLES", "SEED", "update_model", "updated_design", "UpdatingResult"]
