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
starting points; the best polished fit wins. Above ``RITZ_SCREENING_DOFS`` the screening runs
on a Rayleigh–Ritz model (`RitzScreen`, exact in K's linearity in p), the polish on the full one.

Where the design carries EMA mode shapes (``updating.measured_dofs``, docs/design-file.md) the
FE mode of each measured mode is not its number but its pair by MAC
(`correlation.pair_modes`), found anew at every evaluation from the FE shapes at the measured
DOFs; a pairing that differs from the numbers, or that changes during the fit, is warned
(:class:`~smartjoint.design.structure.correlation.ModeSwapWarning`). ``mac_weight`` w_MAC > 0
adds the residuals √w_MAC·(1 − MAC_i) of the paired modes to the objective (their derivatives
by forward differences). Without shapes everything is as before, bit for bit.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import scipy.stats

from smartjoint.common.errors import ModelError
from smartjoint.design.structure.correlation import (
    ModeCorrelation,
    ModeSwapWarning,
    correlate,
    measurement_matrix,
    modal_assurance_criterion,
)
from smartjoint.design.structure.fem import FEModel
from smartjoint.design.structure.modal import eigensolve

SEED = 20021  # fixed: the same design always updates to the same parameters
SCREENING_SAMPLES = 64
POLISHED_STARTS = 2
PAIRING_MARGIN = 4  # FE modes solved beyond the highest measured number, for a pair by MAC to reach
MAC_STEP = 1e-6  # forward-difference step in θ = ln(p/p⁰) of the MAC residuals
# Above this many DOFs the screening runs on a Rayleigh–Ritz model (`RitzScreen`): 64 sparse
# eigen solutions of a 1000-bay mast (384 126 DOFs) took over 20 minutes; below, the full model
# screens as before (the bundled 10-bay truss updates bit for bit as it did).
RITZ_SCREENING_DOFS = 20_000
RITZ_EXTRA_MODES = 8  # nominal modes in the Ritz basis beyond those the fit solves


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
    correlation: ModeCorrelation | None = None  # with EMA shapes: MAC matrix and pairing, updated
    initial_correlation: ModeCorrelation | None = None  # the same at the nominal parameters
    pairing_changes: int = 0  # evaluations at which the MAC pairing differed from the one before

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
            **({} if self.correlation is None else {"correlation": self.correlation_dict()}),
        }

    def correlation_dict(self) -> dict:
        """The MAC pairing before and after updating (only with EMA shapes)."""
        assert self.correlation is not None and self.initial_correlation is not None
        return {
            "updated": self.correlation.as_dict(),
            "initial": self.initial_correlation.as_dict(),
            "pairing_changes": self.pairing_changes,
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


def _multistart_fit(
    residual, jacobian, weight: np.ndarray, bound: np.ndarray, n_parameters: int, progress, screen=None
):
    """The least-squares fit of the log-parameters θ within ±``bound`` from several starts,
    screened by ``screen`` (a residual of θ; default ``residual`` itself).

    Returns the best solution and how many starts were polished."""
    screen = residual if screen is None else screen
    # Paired by mode number the objective is only piecewise smooth (modes cross), so local
    # descent alone stalls: screen a scrambled Sobol sample of the log-parameter box, then
    # polish the nominal point and the best samples with least squares.
    sampler = scipy.stats.qmc.Sobol(n_parameters, scramble=True, seed=SEED)
    samples = (2.0 * sampler.random(SCREENING_SAMPLES) - 1.0) * bound
    # The worst relative frequency error (without the MAC residuals that follow with a mac_weight).
    scores = np.array([np.max(np.abs(screen(theta)[: weight.size] / weight)) for theta in samples])
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
            progress(k + 1, len(starts), float(np.max(np.abs(best.fun[: weight.size] / weight))) * 100.0)
        if (
            np.max(np.abs(best.fun[: weight.size] / weight)) < 0.002
        ):  # within 0.2 % on every mode: no further start helps
            break
    assert best is not None  # starts always holds the nominal point
    return best, k + 1


class FitEvaluations:
    """The eigen solutions of the fit, one θ = ln(p/p⁰) cached at a time, and with EMA shapes the
    MAC pairing at each (`correlation.correlate`); counts the solutions and the pairing changes.

    Parameters
    ----------
    model : FEModel
        The locked truss.
    names : list of str
        The fitted parameters.
    initial : ndarray
        Their nominal values p⁰.
    index : ndarray of int
        The measured modes' numbers − 1 (the pairing without shapes).
    n_modes : int
        The highest measured mode number.
    """

    def __init__(self, model: FEModel, names, initial: np.ndarray, index: np.ndarray, n_modes: int):
        spec = model.design.updating
        assert spec is not None  # update_model checked it
        self.model, self.spec, self.names, self.initial, self.index = model, spec, names, initial, index
        self.restrict = measurement_matrix(model, spec.measured_dofs) if spec.has_shapes else None
        self.n_solve = min(model.n_dof, n_modes + PAIRING_MARGIN) if spec.has_shapes else n_modes
        self.calls = 0
        self.pairing_changes = 0
        self.last_pairing: np.ndarray | None = None
        self.cache: dict[bytes, tuple] = {}

    def solve(self, theta) -> tuple[np.ndarray, np.ndarray, np.ndarray, ModeCorrelation | None]:
        """(FE frequencies, shapes, the FE mode of each measured mode (0-based), the correlation)."""
        frequencies, shapes = _frequencies(self.model, self.names, self.initial * np.exp(theta), self.n_solve)
        if self.restrict is None:
            return frequencies, shapes, self.index, None
        correlation = correlate(self.spec, self.restrict @ shapes, frequencies)
        return frequencies, shapes, correlation.fe_modes - 1, correlation

    def __call__(self, theta) -> tuple[np.ndarray, np.ndarray, np.ndarray, ModeCorrelation | None]:
        key = np.asarray(theta).tobytes()
        if key not in self.cache:
            self.calls += 1
            self.cache.clear()
            self.cache[key] = self.solve(theta)
            paired = self.cache[key][2]
            if self.last_pairing is not None and not np.array_equal(paired, self.last_pairing):
                self.pairing_changes += 1
            self.last_pairing = paired
        return self.cache[key]

    def mac_residual(self, theta) -> np.ndarray:
        """√w_MAC·(1 − MAC_i) of every measured mode with its pair."""
        correlation = self(theta)[3]
        assert correlation is not None  # a MAC term needs shapes (parse_updating)
        return np.sqrt(self.spec.mac_weight) * (1.0 - correlation.diagonal)

    def mac_jacobian(self, theta) -> np.ndarray:
        """∂/∂θ of `mac_residual` by forward differences, the pairing held at θ's."""
        assert self.restrict is not None
        base, paired = self.mac_residual(theta), self(theta)[2]
        measured = np.array([m.shape for m in self.spec.measured], dtype=float).T
        columns = []
        for k in range(len(self.names)):
            stepped = np.array(theta, dtype=float)
            stepped[k] += MAC_STEP
            self.calls += 1
            _, shapes = _frequencies(self.model, self.names, self.initial * np.exp(stepped), self.n_solve)
            mac = np.diag(modal_assurance_criterion(measured, self.restrict @ shapes[:, paired]))
            columns.append((np.sqrt(self.spec.mac_weight) * (1.0 - mac) - base) / MAC_STEP)
        return np.column_stack(columns)


class RitzScreen:
    """The fit's frequencies and pairing on a Rayleigh–Ritz model of the truss, for the screening.

    K = Σ p_k·K_k is linear in the parameters, so on a fixed basis V the projected stiffness
    VᵀK(p)V = VᵀK(p⁰)V + Σ (p_k − p_k⁰)·VᵀK_kV costs a small dense eigen solution per sample.
    V: the nominal modes (those the fit solves plus ``RITZ_EXTRA_MODES``), per parameter
    K⁻¹K_kΦ (the directions the modes move in as p_k changes) and the modes at both ends of its
    range (2 eigen solutions per parameter instead of one per sample), M-orthonormalised. Ritz
    frequencies bound the exact ones from above; the polish runs on the full model.

    Parameters
    ----------
    evaluate : FitEvaluations
        The fit's full-model evaluations (model, parameters, pairing).
    """

    def __init__(self, evaluate: FitEvaluations):
        model, names = evaluate.model, evaluate.names
        stiffness = model.stiffness_with(dict(zip(names, evaluate.initial)))
        count = min(model.n_dof - 2, evaluate.n_solve + RITZ_EXTRA_MODES)
        _, shapes = eigensolve(stiffness, model.mass, count)
        factor = spla.splu(sp.csc_matrix(stiffness))
        parts = [model.stiffness_parts[n] for n in names]
        # The modes at each end of each parameter's range: the box spans factors of up to 100,
        # where the first-order directions alone leave Ritz errors of tens of per cent.
        ends = []
        for k, bound in enumerate(np.log(np.array(evaluate.spec.max_factors))):
            for sign in (-1.0, 1.0):
                theta = np.zeros(len(names))
                theta[k] = sign * bound
                at_end = dict(zip(names, evaluate.initial * np.exp(theta)))
                ends.append(eigensolve(model.stiffness_with(at_end), model.mass, count)[1])
        directions = (factor.solve(np.asarray(part @ shapes)) for part in parts)
        basis = np.column_stack([shapes, *directions, *ends])
        gram = basis.T @ (model.mass @ basis)
        values, vectors = np.linalg.eigh(0.5 * (gram + gram.T))
        keep = values > 1e-12 * values.max()  # directions already in the span add nothing
        self.basis = basis @ (vectors[:, keep] / np.sqrt(values[keep]))  # VᵀMV = I
        self.nominal = self.basis.T @ (stiffness @ self.basis)
        self.parts = [self.basis.T @ (part @ self.basis) for part in parts]
        self.evaluate = evaluate
        self.restricted = None if evaluate.restrict is None else evaluate.restrict @ self.basis

    def __call__(self, theta) -> tuple[np.ndarray, np.ndarray]:
        """(Ritz frequencies [Hz] of the fit's modes, the FE mode of each measured mode, 0-based)."""
        e = self.evaluate
        change = e.initial * (np.exp(theta) - 1.0)
        projected = self.nominal + sum(c * part for c, part in zip(change, self.parts))
        values, vectors = np.linalg.eigh(0.5 * (projected + projected.T))
        n = e.n_solve
        frequencies = np.sqrt(np.maximum(values[:n], 0.0)) / (2.0 * np.pi)
        if self.restricted is None:
            return frequencies, e.index
        return frequencies, correlate(e.spec, self.restricted @ vectors[:, :n], frequencies).fe_modes - 1


def update_model(model: FEModel, progress=None, warn=None) -> UpdatingResult:
    """Fit the design's ``[updating]`` parameters to its measured frequencies.

    With EMA shapes the measured modes pair with FE modes by MAC at every evaluation, and
    ``mac_weight`` adds their (1 − MAC) to the objective (module docstring).

    Parameters
    ----------
    model : FEModel
        The locked truss of a design with ``[updating]``.
    progress : callable, optional
        ``progress(k, n, worst_error_pct)`` after each polished start.
    warn : callable, optional
        ``warn(message)`` for each swap instead of a ModeSwapWarning (the command line's lines).

    Returns
    -------
    UpdatingResult
        The fitted parameters, the frequencies before and after, the errors and sensitivities;
        with shapes the MAC matrix and pairing before and after.

    Warns
    -----
    ModeSwapWarning
        When the MAC pairing differs from the mode numbers, or changed during the fit.
    """
    spec, names, initial, modes, measured, n_modes = _updating_inputs(model)
    index = modes - 1
    # Trust in each measured mode: its MAC against the FE shape where the EMA gives one.
    weight = np.array([m.mac if m.mac is not None else 1.0 for m in spec.measured])
    bound = np.log(np.array(spec.max_factors))
    parts = [model.stiffness_parts[n] for n in names]
    evaluate = FitEvaluations(model, names, initial, index, n_modes)
    mac_term = spec.mac_weight > 0.0

    def residual(theta):
        frequencies, _, paired, _ = evaluate(theta)
        relative = weight * (frequencies[paired] - measured) / measured
        return np.concatenate([relative, evaluate.mac_residual(theta)]) if mac_term else relative

    def jacobian(theta):
        frequencies, shapes, paired, _ = evaluate(theta)
        values = initial * np.exp(theta)
        phi = shapes[:, paired]
        d_lambda = np.column_stack([np.einsum("ij,ij->j", phi, part @ phi) for part in parts])  # ∂ω²/∂p
        f = frequencies[paired]
        rows = weight[:, None] * d_lambda * values[None, :] / (8.0 * np.pi**2 * f[:, None] * measured[:, None])
        return np.vstack([rows, evaluate.mac_jacobian(theta)]) if mac_term else rows

    screen = None
    if model.n_dof > RITZ_SCREENING_DOFS:
        ritz = RitzScreen(evaluate)

        def screen(theta):
            frequencies, paired = ritz(theta)
            return weight * (frequencies[paired] - measured) / measured

    best, polished = _multistart_fit(residual, jacobian, weight, bound, len(names), progress, screen)
    initial_hz, _, initial_index, initial_correlation = evaluate.solve(np.zeros(len(names)))
    updated = initial * np.exp(best.x)
    updated_hz, _, updated_index, correlation = evaluate(best.x)
    sensitivity = jacobian(best.x)[: len(modes)] * (measured / updated_hz[updated_index] / weight)[:, None]
    _warn_swaps(initial_correlation, correlation, warn)
    return UpdatingResult(
        names,
        initial,
        updated,
        modes,
        measured,
        initial_hz[initial_index],
        updated_hz[updated_index],
        sensitivity,
        evaluate.calls,
        polished,
        np.array([m.mac if m.mac is not None else np.nan for m in spec.measured]),
        correlation,
        initial_correlation,
        evaluate.pairing_changes,
    )


def _warn_swaps(initial: ModeCorrelation | None, updated: ModeCorrelation | None, warn=None) -> None:
    """A ModeSwapWarning naming the modes whose MAC pair is not their number, or changed in the fit."""
    if initial is None or updated is None:
        return
    messages = [f"model updating: {swap}" for swap in updated.swaps]
    moved = np.flatnonzero(initial.fe_modes != updated.fe_modes)
    if moved.size:
        messages.append(
            "model updating: the MAC pairing changed during the fit: "
            + ", ".join(
                f"measured mode {initial.measured_modes[i]} from FE mode {initial.fe_modes[i]} to {updated.fe_modes[i]}"
                for i in moved
            )
        )
    for message in messages:
        if warn is not None:
            warn(message)
        else:
            warnings.warn(message, ModeSwapWarning, stacklevel=3)


def updated_design(design, progress=None, warn=None, model=None):
    """The design with its ``[updating]`` parameters fitted, and the result (None without one).

    Updating always runs on the conventional truss (joints locked): that is what the modal
    survey measured, whatever joint setting the caller then builds its model with.

    Parameters
    ----------
    design : Design
        The design.
    progress, warn : callable, optional
        As for `update_model`.
    model : FEModel, optional
        The design's FE model with its joints locked, where the caller has built it already.

    Returns
    -------
    tuple
        (Design with the fitted parameters, UpdatingResult or None).
    """
    from smartjoint.design.structure.fem import build_model

    if design.updating is None:
        return design, None
    locked = model if model is not None else build_model(design, joints="locked")
    result = update_model(locked, progress=progress, warn=warn)
    return design.with_parameters(result.parameters), result


__all__ = [
    "FitEvaluations",
    "MAC_STEP",
    "PAIRING_MARGIN",
    "POLISHED_STARTS",
    "SCREENING_SAMPLES",
    "SEED",
    "update_model",
    "updated_design",
    "UpdatingResult",
]
