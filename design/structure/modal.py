"""Eigen solution of the undamped truss (paper Eq. 7) with modal damping (Eq. 8).

K φ_i = ω_i² M φ_i, modes mass-normalised (φ_iᵀ M φ_j = δ_ij), ascending. Small models use a
dense symmetric solver (LAPACK, only the requested subset); large ones sparse shift-invert
Lanczos (ARPACK) around a slightly negative shift, which also works for nearly singular K.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from smartjoint.common.canonical import canonical_signs
from smartjoint.common.errors import ModelError

DENSE_LIMIT = 2500  # DOFs up to which the dense solver is faster than shift-invert Lanczos
SHIFT = -1.0  # (rad/s)²: below every elastic mode, keeps K − σM regular
# A zero-energy motion is told from a soft elastic mode relative to its own energy scale, not
# by an absolute ω² (a 1000-bay mast's first mode is 0.6 mHz, ω² = 1.5e-5, below the former
# cut-off 1e-4). The eigenvalue the solver returns carries the error of the shift-invert
# solves (up to 4e-6 for a free 2-bay truss), but the energy φᵀKφ of the computed vector is
# quadratic in the vector's error and so is only limited by the cancellation in Kφ: a fraction
# of eps times the gross energy |φ|ᵀ|K||φ|, the energy φ would have if no term cancelled.
# Measured ratios φᵀKφ / |φ|ᵀ|K||φ|: mechanisms (free and pinned trusses, free masts of 10 and
# 300 bays, a hinged chain) ≤ 0.1 eps; the first mode of a clamped 1000-bay mast 11 eps,
# 300 bays 1300 eps, 10 bays 7e8 eps. The cut-off, eps, sits in the decade between.
ZERO_ENERGY_RELATIVE = float(np.finfo(float).eps)
# Dense N × N arrays of a dense solution: K, M, Φ and LAPACK's divide-and-conquer workspace
# (about 2N² for dsygvd) — 8 bytes each.
DENSE_ARRAYS = 5


def available_memory() -> int | None:
    """Bytes this process may still allocate: MemAvailable of /proc/meminfo (Linux), else the
    physical memory; None where neither is known."""
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):
        return None


def dense_memory(n_dof: int) -> int:
    """Bytes of a dense eigen solution of an N-DOF model (``DENSE_ARRAYS`` N × N doubles)."""
    return DENSE_ARRAYS * 8 * n_dof**2


def check_dense_fits(n_dof: int, what: str, instead: str) -> None:
    """One line before a dense solution that cannot fit (a 1000-bay mast's every mode: 384 129
    DOFs, 5.9 TB), never numpy's ArrayMemoryError from inside LAPACK's wrapper.

    Parameters
    ----------
    n_dof : int
        N.
    what : str
        What asks for it, leading the message.
    instead : str
        What to do instead, ending it.
    """
    needed, free = dense_memory(n_dof), available_memory()
    if free is not None and needed > free:
        raise ModelError(
            f"{what}: a dense eigen solution of {n_dof} DOFs needs about {needed / 1e9:.3g} GB, more than the "
            f"{free / 1e9:.3g} GB available — {instead}"
        )


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
    """Lowest ``n_modes`` eigenpairs (ω², Φ) of K φ = ω² M φ, Φ mass-normalised (Eq. 5).

    Parameters
    ----------
    stiffness, mass : sparse matrix
        K and M (N × N).
    n_modes : int
        How many pairs, from the lowest.

    Returns
    -------
    tuple of ndarray
        (ω² (n_modes,), Φ (N, n_modes)).
    """
    n_dof = stiffness.shape[0]
    if not 1 <= n_modes <= n_dof:
        raise ModelError(f"n_modes: {n_modes} — must be between 1 and the number of DOFs ({n_dof})")
    try:
        if n_dof <= DENSE_LIMIT or n_modes >= n_dof - 1:
            check_dense_fits(n_dof, f"n_modes: {n_modes}", f"ask for at most {n_dof - 2} modes (solved sparse)")
            if n_modes == n_dof:  # the whole spectrum: divide and conquer is several times faster
                values, vectors = scipy.linalg.eigh(stiffness.toarray(), mass.toarray(), driver="gvd")
            else:
                values, vectors = scipy.linalg.eigh(
                    stiffness.toarray(), mass.toarray(), subset_by_index=[0, n_modes - 1]
                )
        else:
            # A fixed start vector: ARPACK's default is random, which changes the last bits of
            # every result from run to run (artefacts and firmware must be byte-identical).
            start = np.random.default_rng(0).standard_normal(n_dof)
            values, vectors = spla.eigsh(
                sp.csc_matrix(stiffness),
                k=n_modes,
                M=sp.csc_matrix(mass),
                sigma=SHIFT,
                which="LM",
                mode="normal",
                v0=start,
            )
    except (np.linalg.LinAlgError, RuntimeError) as error:
        raise ModelError(
            f"eigen solution failed ({error}); a DOF without mass (a massless node with a "
            "released joint?) or a singular stiffness matrix"
        ) from None
    order = np.argsort(values)
    values, vectors = values[order], vectors[:, order]
    # Explicit mass normalisation: ARPACK's vectors are M-orthogonal but scaled loosely.
    scale = np.sqrt(np.einsum("ij,ij->j", vectors, mass @ vectors))
    vectors = vectors / scale
    # The same sign on every machine (common.canonical): the largest entry of a mirror-symmetric
    # structure's antisymmetric mode has an equal and opposite twin, and its last bits decided.
    return values, canonical_signs(vectors)


def gross_energy(stiffness: sp.spmatrix, vectors: np.ndarray) -> np.ndarray:
    """|φ|ᵀ|K||φ| per column: the energy scale against which round-off in φᵀKφ is measured.

    Parameters
    ----------
    stiffness : sparse matrix
        K, taken entry by entry in magnitude.
    vectors : ndarray
        Mode shapes φ, one per column, in any scaling.

    Returns
    -------
    ndarray
        One value per column.
    """
    magnitude = np.abs(vectors)
    return np.einsum("ij,ij->j", magnitude, abs(stiffness) @ magnitude)


def zero_energy(stiffness: sp.spmatrix, vectors: np.ndarray) -> np.ndarray:
    """Which computed modes are zero-energy motions: |φᵀKφ| ≤ eps·|φ|ᵀ|K||φ| (see
    :data:`ZERO_ENERGY_RELATIVE`), independent of units, size and the modes' scaling.

    Parameters
    ----------
    stiffness : sparse matrix
        K of the model the modes were solved for.
    vectors : ndarray
        The computed modes, one per column.

    Returns
    -------
    ndarray of bool
        One flag per column.
    """
    energy = np.einsum("ij,ij->j", vectors, stiffness @ vectors)
    return np.abs(energy) <= ZERO_ENERGY_RELATIVE * gross_energy(stiffness, vectors)


def solve_modes(model, n_modes: int, parameters: dict[str, float] | None = None) -> Modes:
    """The ``n_modes`` lowest modes of an :class:`~smartjoint.design.structure.fem.FEModel` (Eq. 5).

    Parameters
    ----------
    model : FEModel
        The FE model.
    n_modes : int
        How many modes.
    parameters : dict of str to float, optional
        Stiffness parameters that replace the model's own (model updating).

    Returns
    -------
    Modes
        ω, mass-normalised shapes and the design's modal damping.

    Examples
    --------
    >>> modes = solve_modes(build_model(load_design(), joints="locked"), 6)  # doctest: +SKIP
    >>> modes.frequencies_hz  # doctest: +SKIP
    """
    stiffness = model.stiffness_with(parameters or {})
    values, vectors = eigensolve(stiffness, model.mass, n_modes)
    if zero_energy(stiffness, vectors[:, :1])[0]:
        raise ModelError(
            f"lowest eigenvalue ω² = {values[0]:.3g} (rad/s)² is round-off of a zero-energy motion: "
            "the structure is not fully supported"
        )
    return Modes(np.sqrt(values), vectors, np.full(n_modes, model.design.modal_damping))


def probe_zero_energy(model, probe: int = 8) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The lowest ``probe`` modes (ω², Φ) and which of them are zero-energy motions; more modes
    when all of those are (a structure with more than ``probe`` of them).

    Parameters
    ----------
    model : FEModel
        The FE model; when all ``probe`` are zero-energy: every mode (up to DENSE_LIMIT DOFs), else 64.
    probe : int
        Modes solved at first.

    Returns
    -------
    tuple of ndarray
        (ω², Φ, zero-energy flags).
    """
    n = min(probe, model.n_dof)
    stiffness = model.stiffness
    values, vectors = eigensolve(stiffness, model.mass, n)
    zero = zero_energy(stiffness, vectors)
    if zero.all() and n < model.n_dof:
        more = model.n_dof if model.n_dof <= DENSE_LIMIT else min(model.n_dof - 1, 64)
        values, vectors = eigensolve(stiffness, model.mass, more)
        zero = zero_energy(stiffness, vectors)
    return values, vectors, zero


def count_zero_energy_modes(model, probe: int = 8) -> tuple[int, str]:
    """Number of zero-energy motions among the lowest ``probe`` modes and where the first sits.

    Parameters
    ----------
    model : FEModel
        The FE model whose support is checked.
    probe : int
        Modes solved at first (`probe_zero_energy`).

    Returns
    -------
    tuple
        (count, the label of the first motion's largest DOF, "" when none).
    """
    _, vectors, zero_mask = probe_zero_energy(model, probe)
    zero = np.flatnonzero(zero_mask)
    if zero.size == 0:
        return 0, ""
    shape = vectors[:, zero[0]]
    top = np.argsort(-np.abs(shape))[:1]
    where = ", ".join(f"{model.dof_labels[i][0]}.{model.dof_labels[i][1]}" for i in top)
    return int(zero.size), where


@dataclass
class ModalModel:
    """The linear subsystem of Eq. 8–12 in (generalised) modal coordinates.

    Each coordinate i obeys η̈_i + 2ξ_iω_i η̇_i + ω_i² η_i = e_iᵀ(−u_R) + h_iᵀ w with the state
    x_i = [η̇_i, ω_i·η_i] (Eq. 11). The coordinates are the eigenmodes of the frictionless
    truss (F_N = 0, Eq. 6–7), possibly followed by Krylov correction vectors (Eq. 27–28),
    which are M-orthonormal and K-diagonal too, so the same form holds for the reduced model.
    Sign: the joints act on the structure with −E·u_R (friction opposes sliding), so
    v = Eᵀż = Bᵀx and the energy ½xᵀx can only fall through u_Rᵀv ≥ 0.
    """

    omega: np.ndarray  # ω_i [rad/s]
    damping: np.ndarray  # ξ_i
    joint_input: np.ndarray  # (n, l): rows e_i of basisᵀ E (Eq. 9, 18)
    disturbance_input: np.ndarray  # (n, m): rows h_i of basisᵀ F
    displacement_output: np.ndarray  # (n_y, n): V·basis (Eq. 10)
    velocity_output: np.ndarray  # (n_y, n): W·basis
    labels: list[str]  # "mode 12" or "krylov B1.1" per coordinate
    joint_names: list[str]
    sensor_names: list[str]
    disturbance_names: list[str]
    basis: np.ndarray | None = None  # (N, n) shapes in z, kept for the reduction and plots
    # Units of u_R, y and w per channel ("N", "N·m"; "m", "m/s", "rad", "rad/s"), for the
    # references of the mode selection; empty when the model was built without a design.
    joint_units: list[str] = field(default_factory=list)
    sensor_units: list[str] = field(default_factory=list)
    disturbance_units: list[str] = field(default_factory=list)

    @property
    def n_coordinates(self) -> int:
        return self.omega.size

    @property
    def n_states(self) -> int:
        return 2 * self.omega.size

    def state_space(self):
        """A, B, H, C_v, C_y of Eq. 12 with v = Bᵀx (Eq. 9) and y = C_y x (Eq. 10).

        States ordered [η̇_1, ω_1η_1, η̇_2, …]; the friction enters as ẋ = Ax − B·u_R + H·w.
        """
        n = self.n_coordinates
        A = np.zeros((2 * n, 2 * n))
        idx = 2 * np.arange(n)
        A[idx, idx] = -2.0 * self.damping * self.omega
        A[idx, idx + 1] = -self.omega
        A[idx + 1, idx] = self.omega
        B = np.zeros((2 * n, self.joint_input.shape[1]))
        B[idx] = self.joint_input
        H = np.zeros((2 * n, self.disturbance_input.shape[1]))
        H[idx] = self.disturbance_input
        Cy = np.zeros((self.displacement_output.shape[0], 2 * n))
        Cy[:, idx] = self.velocity_output
        Cy[:, idx + 1] = self.displacement_output / self.omega
        return A, B, H, B.T.copy(), Cy


def channel_units(model) -> tuple[list[str], list[str], list[str]]:
    """The units of the joint inputs u_R, the sensor outputs y and the disturbances w of an FE model.

    Parameters
    ----------
    model : FEModel
        The FE model; its design gives the joint types, sensor quantities and directions.

    Returns
    -------
    tuple of list of str
        Per joint "N" (type A: force along the member, slip in m) or "N·m" (type B: torque,
        rotation in rad); per sensor "m", "m/s", "rad" or "rad/s"; per disturbance "N" or "N·m".
    """
    design = model.design
    types = {joint.name: joint.type for joint in design.joints}
    joints = ["N" if types[name] == "A" else "N·m" for name in model.joint_names]
    sensors = [
        ("rad" if any(sensor.direction[3:]) else "m") + ("/s" if sensor.quantity == "velocity" else "")
        for sensor in design.sensors
    ]
    disturbances = ["N·m" if any(d.direction[3:]) else "N" for d in design.disturbances]
    return joints, sensors, disturbances


def modal_model(model, modes: Modes, indices=None) -> ModalModel:
    """The modal model of an FE model's (released-joint) modes, optionally a subset ``indices``.

    Parameters
    ----------
    model : FEModel
        The FE model the modes belong to.
    modes : Modes
        Its modes (Eq. 5).
    indices : array_like of int, optional
        The modes kept (0-based, default: all).

    Returns
    -------
    ModalModel
        ω, damping, the modal joint and disturbance inputs and the sensor outputs (Eq. 11).
    """
    indices = np.arange(len(modes)) if indices is None else np.asarray(indices, dtype=int)
    shapes = modes.shapes[:, indices]
    joint_units, sensor_units, disturbance_units = channel_units(model)
    return ModalModel(
        omega=modes.omega[indices].copy(),
        damping=modes.damping[indices].copy(),
        joint_input=shapes.T @ model.E,
        disturbance_input=shapes.T @ model.F,
        displacement_output=model.V @ shapes,
        velocity_output=model.W @ shapes,
        labels=[f"mode {i + 1}" for i in indices],
        joint_names=list(model.joint_names),
        sensor_names=list(model.sensor_names),
        disturbance_names=list(model.disturbance_names),
        basis=shapes,
        joint_units=joint_units,
        sensor_units=sensor_units,
        disturbance_units=disturbance_units,
    )


__all__ = [
    "channel_units",
    "count_zero_energy_modes",
    "DENSE_LIMIT",
    "available_memory",
    "check_dense_fits",
    "dense_memory",
    "eigensolve",
    "gross_energy",
    "modal_model",
    "ModalModel",
    "Modes",
    "probe_zero_energy",
    "SHIFT",
    "solve_modes",
    "zero_energy",
    "ZERO_ENERGY_RELATIVE",
]
