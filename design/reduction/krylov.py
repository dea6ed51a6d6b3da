"""Model reduction of the linear subsystem (paper Section 4): balanced mode selection plus
Krylov correction vectors.

* Mode selection (Eq. 16–18): for lightly damped, well separated modes the gramians of the
  modal state space are diagonal with 2×2 blocks w_i·I, in closed form

      w^c_i = ‖e_i‖²/(4ξ_iω_i),   w^o_i = (ω_i²‖w_i‖² + ‖v_i‖²)/(4ξ_iω_i³)        (Eq. 17)

  and the Hankel singular value of the path u_R → v is γ_uv,i = ‖e_i‖²/(4ξ_iω_i) (Eq. 18).
  The paths w → y (tip force → tip deflection, γ_wy,i = √(w^c_w,i·w^o_y,i)) and u_R → y add
  the modes the sensors and the disturbance need. A mode's score is its largest Hankel
  singular value over the paths, each path normalised by its own largest value; the n_d
  best are kept.
* Krylov correction vectors (Eq. 24–26): for joint j the start vector is the static correction
  K⁻¹e_j (Eq. 24), the next ones K⁻¹M·ψ_{k−1} (Eq. 25); each is M-orthonormalised against the
  retained modes and all previous vectors (twice, for round-off), and the small eigenproblem
  ΨᵀKΨ = T·Ω̂·Tᵀ (Eq. 26) rotates them so that [Φ_d Ψ̂] is M-orthonormal and K-diagonal. The
  reduced model (Eq. 27–29) then has the same modal form, with ω̂_m and the modal damping.
  One correction vector per joint already makes the static joint compliance EᵀK⁻¹E exact.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from smartjoint.common.errors import ModelError
from smartjoint.design.structure.modal import ModalModel, Modes, modal_model

PATHS = ("uv", "wy", "uy", "wv")


def hankel_values(model: ModalModel) -> dict[str, np.ndarray]:
    """Closed-form Hankel singular values per mode and path (Eq. 17–18)."""
    w = model.omega
    xi = model.damping
    e2 = np.sum(model.joint_input**2, axis=1)
    h2 = np.sum(model.disturbance_input**2, axis=1)
    y2 = (w**2 * np.sum(model.velocity_output**2, axis=0) + np.sum(model.displacement_output**2, axis=0))
    control_u = e2 / (4.0 * xi * w)
    control_w = h2 / (4.0 * xi * w)
    observe_v = e2 / (4.0 * xi * w)  # v = Bᵀx: same vectors as the input
    observe_y = y2 / (4.0 * xi * w**3)
    return {"uv": np.sqrt(control_u * observe_v), "wy": np.sqrt(control_w * observe_y),
            "uy": np.sqrt(control_u * observe_y), "wv": np.sqrt(control_w * observe_v),
            "controllability_u": control_u}


def select_modes(model: ModalModel, n_keep: int, paths: tuple[str, ...] = PATHS) -> np.ndarray:
    """Indices (ascending) of the ``n_keep`` modes with the largest normalised Hankel values."""
    if not 1 <= n_keep <= model.n_coordinates:
        raise ModelError(f"modes: {n_keep} — must be between 1 and the {model.n_coordinates} modes considered")
    values = hankel_values(model)
    score = np.zeros(model.n_coordinates)
    for path in paths:
        if path not in PATHS:
            raise ModelError(f"paths: {path!r} — allowed: {', '.join(PATHS)}")
        top = values[path].max()
        if top > 0:
            score = np.maximum(score, values[path] / top)
    order = np.argsort(-score, kind="stable")[:n_keep]
    return np.sort(order)


def krylov_vectors(stiffness: sp.spmatrix, mass: sp.spmatrix, E: np.ndarray, retained: np.ndarray, per_joint: int,
                   joints: list[int] | None = None):
    """Krylov correction vectors Ψ̂ and their ω̂ (Eq. 24–26).

    ``retained`` are the kept mass-normalised modes Φ_d (N, n_d); ``joints`` the columns of E
    that get vectors (default: all). Returns (Ψ̂ (N, l·K), ω̂, labels) ordered by ω̂.
    """
    joints = list(range(E.shape[1])) if joints is None else list(joints)
    count = per_joint * len(joints)
    if count == 0:
        return np.zeros((E.shape[0], 0)), np.zeros(0), []
    if retained.shape[1] + count > E.shape[0]:
        raise ModelError(f"Krylov vectors: {per_joint} per joint × {len(joints)} joints + {retained.shape[1]} kept modes "
                         f"= {retained.shape[1] + count} > {E.shape[0]} DOFs — the space allows at most "
                         f"{(E.shape[0] - retained.shape[1]) // max(len(joints), 1)} per joint")
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
                raise ModelError(f"Krylov vector {k} of joint {j + 1} is already in the span of the kept modes and "
                                 "previous vectors; use fewer vectors")
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
    return Psi @ T, np.sqrt(values), labels


@dataclass
class Reduction:
    """A reduced model and how it was obtained."""

    model: ModalModel
    considered: int  # n: modes the selection chose from
    kept_modes: np.ndarray  # 0-based indices into the considered modes
    krylov_per_joint: int
    hankel: dict[str, np.ndarray] = field(default_factory=dict)  # per considered mode


def reduce(fe_model, modes: Modes, n_keep: int, krylov_per_joint: int = 0, paths: tuple[str, ...] = PATHS,
           krylov_joints: list[int] | None = None) -> Reduction:
    """Select ``n_keep`` of ``modes`` by Hankel values and add Krylov vectors per joint (Eq. 27–29)."""
    if krylov_per_joint < 0:
        raise ModelError(f"krylov_per_joint: {krylov_per_joint} — must be >= 0")
    considered = modal_model(fe_model, modes)
    kept = select_modes(considered, n_keep, paths)
    reduced = modal_model(fe_model, modes, kept)
    if krylov_per_joint and fe_model.E.shape[1]:
        stiffness = fe_model.stiffness
        psi, omega_hat, labels = krylov_vectors(stiffness, fe_model.mass, fe_model.E, reduced.basis, krylov_per_joint,
                                                krylov_joints)
        basis = np.column_stack([reduced.basis, psi])
        xi = np.concatenate([reduced.damping, np.full(omega_hat.size, fe_model.design.modal_damping)])
        omega = np.concatenate([reduced.omega, omega_hat])
        reduced = ModalModel(omega, xi, basis.T @ fe_model.E, basis.T @ fe_model.F, fe_model.V @ basis,
                             fe_model.W @ basis, reduced.labels + [f"krylov {m + 1}" for m in range(omega_hat.size)],
                             reduced.joint_names, reduced.sensor_names, reduced.disturbance_names, basis)
    return Reduction(reduced, len(modes), kept, krylov_per_joint, hankel_values(considered))


# --------------------------------------------------------------------------- error metrics
def frequency_response(model: ModalModel, omega: np.ndarray, path: str) -> np.ndarray:
    """G(jω) of a path, shape (n_freq, outputs, inputs): 'uv' (u_R → v) or 'wy' (w → y)."""
    s = 1j * np.asarray(omega, dtype=float)[:, None]
    w, xi = model.omega[None, :], model.damping[None, :]
    # η_i(s) = f_i/(s² + 2ξωs + ω²); velocity outputs take s·η, displacement outputs η.
    modal = 1.0 / (s**2 + 2.0 * xi * w * s + w**2)  # (n_freq, n)
    if path == "uv":
        left, right, parts = model.joint_input.T, model.joint_input, [(s * modal, None)]
    elif path == "wy":
        left, right = None, model.disturbance_input
        parts = [(s * modal, model.velocity_output), (modal, model.displacement_output)]
    else:
        raise ModelError(f"path: {path!r} — allowed: 'uv', 'wy'")
    out = None
    for response, outputs in parts:
        rows = left if outputs is None else outputs
        # G[f, a, b] = Σ_n response[f, n]·rows[a, n]·right[n, b]: one matrix product per output.
        term = np.stack([response @ (rows[a][:, None] * right) for a in range(rows.shape[0])], axis=1)
        out = term if out is None else out + term
    return out


def frequency_grid(models: list[ModalModel], band: float, points: int = 4000) -> np.ndarray:
    """A grid on [0, band] rad/s, log-spaced plus ±5 half-power bandwidths around every
    resonance in band, so that band-limited norms of lightly damped models converge."""
    grid = [np.linspace(0.0, band, points), np.geomspace(band * 1e-4, band, points)]
    for m in models:
        inside = m.omega < band
        for w, xi in zip(m.omega[inside], m.damping[inside]):
            grid.append(w * (1.0 + xi * np.linspace(-8.0, 8.0, 33)))
    grid = np.unique(np.concatenate(grid))
    return grid[(grid >= 0.0) & (grid <= band)]


def band_norms(full: ModalModel, reduced: ModalModel, band: float, path: str) -> dict[str, float]:
    """Band-limited H2 and H∞ norms of a path and of the error full − reduced on [0, band].

    H2 over the band: √((1/π)∫₀^band ‖G(jω)‖_F² dω) by the trapezoidal rule on the refined
    grid; H∞: the largest singular value on the grid.
    """
    grid = frequency_grid([full, reduced], band)
    G = frequency_response(full, grid, path)
    R = frequency_response(reduced, grid, path)

    def h2(X):
        return float(np.sqrt(np.trapezoid(np.sum(np.abs(X) ** 2, axis=(1, 2)), grid) / np.pi))

    def hinf(X):
        return float(np.max(np.linalg.svd(X, compute_uv=False)))

    return {"h2": h2(G), "h2_error": h2(G - R), "hinf": hinf(G), "hinf_error": hinf(G - R),
            "h2_relative": h2(G - R) / max(h2(G), 1e-300), "hinf_relative": hinf(G - R) / max(hinf(G), 1e-300)}


def static_compliance(fe_model) -> np.ndarray:
    """Exact static joint compliance EᵀK⁻¹E of the full FE model (Eq. 24, k = 0)."""
    factor = spla.splu(sp.csc_matrix(fe_model.stiffness))
    return fe_model.E.T @ factor.solve(np.asarray(fe_model.E))


def modal_compliance(model: ModalModel) -> np.ndarray:
    """Static joint compliance of a modal model: Σ e_i e_iᵀ/ω_i²."""
    return (model.joint_input / model.omega[:, None] ** 2).T @ model.joint_input


def error_metrics(fe_model, full: ModalModel, reduced: ModalModel, band: float) -> dict:
    """Static gain, band-limited H2/H∞ of u_R → v and w → y: reduced against full."""
    exact = static_compliance(fe_model)
    approx = modal_compliance(reduced)
    out = {"static_compliance": {"full": exact.tolist(), "reduced": approx.tolist(),
                                 "relative_error": float(np.linalg.norm(exact - approx) / np.linalg.norm(exact))}
           if exact.size else None, "band_hz": band / (2.0 * np.pi)}
    if full.joint_input.shape[1]:
        out["uv"] = band_norms(full, reduced, band, "uv")
    if full.disturbance_input.shape[1] and full.displacement_output.shape[0]:
        out["wy"] = band_norms(full, reduced, band, "wy")
    return out


__all__ = ["Reduction", "band_norms", "error_metrics", "frequency_response", "hankel_values", "krylov_vectors",
           "modal_compliance", "reduce", "select_modes", "static_compliance"]
