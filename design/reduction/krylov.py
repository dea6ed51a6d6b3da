"""Krylov correction vectors and the reduced model (paper Section 4.2, Eq. 24–29).

For joint j the start vector is the static correction K⁻¹e_j (Eq. 24), the next ones
K⁻¹M·ψ_{k−1} (Eq. 25); each is M-orthonormalised against the retained modes and all previous
vectors (twice, for round-off), and the small eigenproblem ΨᵀKΨ = T·Ω̂·Tᵀ (Eq. 26) rotates them
so that [Φ_d Ψ̂] is M-orthonormal and K-diagonal. The reduced model (Eq. 27–29) then has the
same modal form, with ω̂_m and the modal damping. One correction vector per joint already makes
the static joint compliance EᵀK⁻¹E exact.

The Rayleigh frequency ω̂ of a correction vector is a mass-weighted mean of the modes it stands
for, which on a truss lies among the hundreds of dropped modes inside a controller's band (the
placed reference design: 138, 143 and 265 Hz, below the 500 Hz Nyquist frequency), where it adds
a lightly damped resonance that the full model does not have. ``quasi_static_corrections`` keeps
each correction's stiffness (so the static compliance stays exact) and gives it the mass of a
critically damped coordinate at a frequency well above the band: no resonance, nothing that
aliases in a sampled model, the quasi-static residual flexibility that the vector stands for.
docs/simulation.md says why this choice (measured against damping the pseudo-mode and against
balanced truncation).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from smartjoint.common.canonical import canonical_signs
from smartjoint.common.errors import ModelError
from smartjoint.design.reduction.selection import (
    PATHS,
    ChannelReference,
    channel_references,
    hankel_values,
    select_modes,
)
from smartjoint.design.structure.modal import ModalModel, Modes, modal_model


def krylov_vectors(
    stiffness: sp.spmatrix,
    mass: sp.spmatrix,
    E: np.ndarray,
    retained: np.ndarray,
    per_joint: int,
    joints: list[int] | None = None,
):
    """Krylov correction vectors Ψ̂ and their ω̂ (Eq. 24–26).

    Parameters
    ----------
    stiffness, mass : sparse matrix
        K and M of the FE model (N × N).
    E : ndarray
        The joint input vectors (N, K), one column per joint.
    retained : ndarray
        The kept mass-normalised modes Φ_d (N, n_d).
    per_joint : int
        Vectors l per joint.
    joints : list of int, optional
        The columns of E that get vectors (default: all).

    Returns
    -------
    tuple
        (Ψ̂ (N, l·K), ω̂ (l·K,), labels): the vectors ordered by ω̂ and the (joint, k) each
        started from.

    Raises
    ------
    ModelError
        When the vectors do not fit in the space, fall into the span of the kept modes, or span
        a zero-energy motion.
    """
    joints = list(range(E.shape[1])) if joints is None else list(joints)
    count = per_joint * len(joints)
    if count == 0:
        return np.zeros((E.shape[0], 0)), np.zeros(0), []
    if retained.shape[1] + count > E.shape[0]:
        raise ModelError(
            f"Krylov vectors: {per_joint} per joint × {len(joints)} joints + {retained.shape[1]} kept modes "
            f"= {retained.shape[1] + count} > {E.shape[0]} DOFs — the space allows at most "
            f"{(E.shape[0] - retained.shape[1]) // max(len(joints), 1)} per joint"
        )
    factor = spla.splu(sp.csc_matrix(stiffness))
    basis = [retained]
    vectors, labels = [], []
    for j in joints:
        previous = None
        for k in range(1, per_joint + 1):
            psi = factor.solve(E[:, j]) if k == 1 else factor.solve(mass @ previous)  # Eq. 24 / Eq. 25
            for _ in range(2):  # M-orthonormalisation against Σ_{k−1}, twice for round-off
                for block in basis:
                    psi = psi - block @ (block.T @ (mass @ psi))
            norm = float(np.sqrt(psi @ (mass @ psi)))
            scale = float(np.sqrt(E[:, j] @ factor.solve(E[:, j])))
            if not norm > 1e-10 * max(scale, 1e-300):
                raise ModelError(
                    f"Krylov vector {k} of joint {j + 1} is already in the span of the kept modes and "
                    "previous vectors; use fewer vectors"
                )
            psi = psi / norm
            basis.append(psi[:, None])
            vectors.append(psi)
            labels.append((j, k))
            previous = psi
    Psi = np.column_stack(vectors)
    small = Psi.T @ (stiffness @ Psi)
    values, T = np.linalg.eigh(0.5 * (small + small.T))  # Eq. 26
    if values.min() <= 0:
        raise ModelError("Krylov vectors span a zero-energy motion: the structure is not fully supported")
    return canonical_signs(Psi @ T), np.sqrt(values), labels  # eigh's signs are the machine's


QUASI_STATIC_DAMPING = 1.0  # ξ of a quasi-static correction: critical, real poles, no resonance
# ω_q = 4 × the Nyquist frequency π/Δt, measured (docs/simulation.md): Fig. 10's 0–50 ms friction
# error on fig10_three_joints is 5.98 %, 2.96 %, 2.03 %, 2.00 %, 2.11 % at 1×, 2×, 4×, 8×, 16×
# (placed reference design: 2.27 % at 4×, 2.36 % at 8×), the band norms do not change; 4× keeps
# the coordinate's time constant 1/ω_q at Δt/(4π), well inside one sample, and ω_q·h ≈ 0.6 at
# the plant step h = Δt/20.
NYQUIST_MULTIPLE = 4.0


def correction_frequency(sample_time: float) -> float:
    """ω_q [rad/s] of the quasi-static corrections for a controller sampled at Δt = ``sample_time``:
    ``NYQUIST_MULTIPLE`` × π/Δt."""
    if not (np.isfinite(sample_time) and sample_time > 0):
        raise ModelError(f"sample_time: {sample_time!r} — must be a finite number > 0 [s]")
    return NYQUIST_MULTIPLE * np.pi / sample_time


def quasi_static_corrections(model: ModalModel, frequency: float, damping: float = QUASI_STATIC_DAMPING) -> ModalModel:
    """The Krylov corrections of a reduced model made quasi-static above ``frequency``.

    Each correction coordinate m with ω̂_m < ``frequency`` keeps its stiffness and gets the mass
    (ω̂_m/ω_q)², ω_q = ``frequency``, and critical damping: in mass-normalised form its input and
    output rows scale by α = ω_q/ω̂_m, so its static contribution e_m e_mᵀ/ω̂_m² = (αe_m)(αe_m)ᵀ/ω_q²
    and the static compliance EᵀK⁻¹E of Eq. 24 are unchanged, u_R → v stays collocated (the
    same α on E and Eᵀ), and below ω_q the coordinate follows its load quasi-statically. Modes
    and corrections already above ω_q are kept as they are.

    Parameters
    ----------
    model : ModalModel
        A reduced model whose correction coordinates are labelled ``krylov …``.
    frequency : float
        ω_q [rad/s], e.g. a few times the controller's Nyquist frequency.
    damping : float
        ξ of the moved coordinates (default critical: real poles, nothing rings above Nyquist).

    Returns
    -------
    ModalModel
        The same model with the corrections below ω_q moved to ω_q, ξ = 1.
    """
    if not (np.isfinite(frequency) and frequency > 0):
        raise ModelError(f"correction frequency: {frequency!r} — must be a finite number > 0 [rad/s]")
    correction = np.array([label.startswith("krylov") for label in model.labels]) & (model.omega < frequency)
    scale = np.where(correction, frequency / model.omega, 1.0)
    return replace(
        model,
        omega=np.where(correction, frequency, model.omega),
        damping=np.where(correction, damping, model.damping),
        joint_input=model.joint_input * scale[:, None],
        disturbance_input=model.disturbance_input * scale[:, None],
        displacement_output=model.displacement_output * scale,
        velocity_output=model.velocity_output * scale,
        basis=None if model.basis is None else model.basis * scale,
    )


def with_corrections(fe_model, model: ModalModel, psi: np.ndarray, omega_hat: np.ndarray, label: str) -> ModalModel:
    """``model`` (with its shapes) and the correction vectors ``psi`` at ω̂ = ``omega_hat`` as further
    coordinates with the modal damping (Eq. 27–29), labelled ``label 1`` … on the FE model's E, F, V, W."""
    assert model.basis is not None  # modal_model always keeps the shapes
    basis = np.column_stack([model.basis, psi])
    return ModalModel(
        np.concatenate([model.omega, omega_hat]),
        np.concatenate([model.damping, np.full(omega_hat.size, fe_model.design.modal_damping)]),
        basis.T @ fe_model.E,
        basis.T @ fe_model.F,
        fe_model.V @ basis,
        fe_model.W @ basis,
        model.labels + [f"{label} {m + 1}" for m in range(omega_hat.size)],
        model.joint_names,
        model.sensor_names,
        model.disturbance_names,
        basis,
        model.joint_units,
        model.sensor_units,
        model.disturbance_units,
    )


@dataclass
class Reduction:
    """A reduced model and how it was obtained."""

    model: ModalModel
    considered: int  # n: modes the selection chose from
    kept_modes: np.ndarray  # 0-based indices into the considered modes
    krylov_per_joint: int
    hankel: dict[str, np.ndarray] = field(default_factory=dict)  # per considered mode
    references: list[ChannelReference] = field(default_factory=list)  # the channels' scales of `hankel`


def reduce(
    fe_model,
    modes: Modes,
    n_keep: int,
    krylov_per_joint: int = 0,
    paths: tuple[str, ...] = PATHS,
    krylov_joints: list[int] | None = None,
    correction_frequency: float | None = None,
) -> Reduction:
    """Select ``n_keep`` of ``modes`` by Hankel values and add Krylov vectors per joint (Eq. 27–29).

    Parameters
    ----------
    fe_model : FEModel
        The FE model the modes belong to.
    modes : Modes
        The considered modes (Eq. 5).
    n_keep : int
        Modes kept by the selection of Eq. 18.
    krylov_per_joint : int
        Krylov correction vectors per joint (Eq. 24–26), ≥ 0.
    paths : tuple of str
        The Hankel paths that score a mode (see `select_modes`).
    krylov_joints : list of int, optional
        The joints (0-based) that get vectors (default: all).
    correction_frequency : float, optional
        ω_q [rad/s]: the vectors made quasi-static above it (`quasi_static_corrections`); None
        keeps Eq. 26's ω̂ and the modal damping, as in the paper.

    Returns
    -------
    Reduction
        The reduced modal model, the kept modes, the Hankel values of the considered modes and
        the reference that scales each input and output channel in them.

    Examples
    --------
    >>> reduced = reduce(fe, solve_modes(fe, 100), 9, 1).model  # doctest: +SKIP
    """
    if krylov_per_joint < 0:
        raise ModelError(f"krylov_per_joint: {krylov_per_joint} — must be >= 0")
    considered = modal_model(fe_model, modes)
    kept = select_modes(considered, n_keep, paths)
    reduced = modal_model(fe_model, modes, kept)
    if krylov_per_joint and fe_model.E.shape[1]:
        assert reduced.basis is not None  # modal_model always keeps the shapes
        stiffness = fe_model.stiffness
        psi, omega_hat, labels = krylov_vectors(
            stiffness, fe_model.mass, fe_model.E, reduced.basis, krylov_per_joint, krylov_joints
        )
        reduced = with_corrections(fe_model, reduced, psi, omega_hat, "krylov")
        if correction_frequency is not None:
            reduced = quasi_static_corrections(reduced, correction_frequency)
    return Reduction(
        reduced, len(modes), kept, krylov_per_joint, hankel_values(considered), channel_references(considered)
    )


__all__ = [
    "NYQUIST_MULTIPLE",
    "QUASI_STATIC_DAMPING",
    "correction_frequency",
    "Reduction",
    "krylov_vectors",
    "quasi_static_corrections",
    "reduce",
    "with_corrections",
]
