"""Eigen solution of the undamped truss (paper Eq. 7) with modal damping (Eq. 8).

K φ_i = ω_i² M φ_i, modes mass-normalised (φ_iᵀ M φ_j = δ_ij), ascending. Small models use a
dense symmetric solver (LAPACK, only the requested subset); large ones sparse shift-invert
Lanczos (ARPACK) around a slightly negative shift, which also works for nearly singular K.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .errors import ModelError

DENSE_LIMIT = 2500  # DOFs up to which the dense solver is faster than shift-invert Lanczos
SHIFT = -1.0  # (rad/s)²: below every elastic mode, keeps K − σM regular
# A zero-energy motion computed through shift-invert lands at |ω²| of round-off size;
# elastic modes of any plausible truss lie many decades above this.
ZERO_ENERGY = 1e-4  # (rad/s)²  (f < 1.6 mHz)


@dataclass
class Modes:
    """Mass-normalised real modes of Eq. 7 and the modal damping of Eq. 8."""

    omega: np.ndarray  # ω_i [rad/s], ascending
    shapes: np.ndarray  # Φ (N, n), Φᵀ M Φ = I
    damping: np.ndarray  # ξ_i

    @property
    def frequencies_hz(self) -> np.ndarray:
        return self.omega / (2.0 * np.pi)

    def __len__(self) -> int:
        return self.omega.size


def eigensolve(stiffness: sp.spmatrix, mass: sp.spmatrix, n_modes: int) -> tuple[np.ndarray, np.ndarray]:
    """Lowest ``n_modes`` eigenpairs (ω², Φ) of K φ = ω² M φ, Φ mass-normalised."""
    n_dof = stiffness.shape[0]
    if not 1 <= n_modes <= n_dof:
        raise ModelError(f"n_modes: {n_modes} — must be between 1 and the number of DOFs ({n_dof})")
    try:
        if n_dof <= DENSE_LIMIT or n_modes >= n_dof - 1:
            values, vectors = scipy.linalg.eigh(stiffness.toarray(), mass.toarray(), subset_by_index=[0, n_modes - 1])
        else:
            values, vectors = spla.eigsh(sp.csc_matrix(stiffness), k=n_modes, M=sp.csc_matrix(mass),
                                         sigma=SHIFT, which="LM", mode="normal")
    except (np.linalg.LinAlgError, RuntimeError) as error:
        raise ModelError(f"eigen solution failed ({error}); a DOF without mass (a massless node with a "
                         "released joint?) or a singular stiffness matrix") from None
    order = np.argsort(values)
    values, vectors = values[order], vectors[:, order]
    # Explicit mass normalisation: ARPACK's vectors are M-orthogonal but scaled loosely.
    scale = np.sqrt(np.einsum("ij,ij->j", vectors, mass @ vectors))
    vectors = vectors / scale
    # Deterministic sign: largest-magnitude entry positive (reports and files stay stable).
    peak = np.argmax(np.abs(vectors), axis=0)
    vectors = vectors * np.sign(vectors[peak, np.arange(vectors.shape[1])])
    return values, vectors


def solve_modes(model, n_modes: int, parameters: dict[str, float] | None = None) -> Modes:
    """The ``n_modes`` lowest modes of an :class:`~smartjoint.design.fem.FEModel`."""
    stiffness = model.stiffness_with(parameters or {})
    values, vectors = eigensolve(stiffness, model.mass, n_modes)
    if values[0] < ZERO_ENERGY:
        raise ModelError(f"lowest eigenvalue ω² = {values[0]:.3g} (rad/s)²: the structure is not fully supported")
    return Modes(np.sqrt(values), vectors, np.full(n_modes, model.design.modal_damping))


def count_zero_energy_modes(model, probe: int = 8) -> tuple[int, str]:
    """Number of zero-energy motions among the lowest ``probe`` modes and where the first sits."""
    n = min(probe, model.n_dof)
    values, vectors = eigensolve(model.stiffness, model.mass, n)
    zero = np.flatnonzero(values < ZERO_ENERGY)
    if zero.size == n and n < model.n_dof:
        values, vectors = eigensolve(model.stiffness, model.mass, model.n_dof if model.n_dof <= DENSE_LIMIT else min(model.n_dof - 1, 64))
        zero = np.flatnonzero(values < ZERO_ENERGY)
    if zero.size == 0:
        return 0, ""
    shape = vectors[:, zero[0]]
    top = np.argsort(-np.abs(shape))[:1]
    where = ", ".join(f"{model.dof_labels[i][0]}.{model.dof_labels[i][1]}" for i in top)
    return int(zero.size), where
