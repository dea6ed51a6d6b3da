"""Frequency responses and error metrics of a reduced model against the full one (paper Section 4.3):
static joint compliance, band-limited H2 and H∞ norms of the paths u_R → v and w → y."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from smartjoint.common.errors import ModelError
from smartjoint.design.structure.modal import ModalModel


def frequency_response(model: ModalModel, omega: np.ndarray, path: str) -> np.ndarray:
    """Frequency response G(jω) of a path of a modal model.

    Parameters
    ----------
    model : ModalModel
        The modal model.
    omega : array_like
        Angular frequencies [rad/s].
    path : str
        'uv' (u_R → v) or 'wy' (w → y).

    Returns
    -------
    ndarray
        Complex, shape (n_freq, outputs, inputs).
    """
    s = 1j * np.asarray(omega, dtype=float)[:, None]
    w, xi = model.omega[None, :], model.damping[None, :]
    # η_i(s) = f_i/(s² + 2ξωs + ω²); velocity outputs take s·η, displacement outputs η.
    modal = 1.0 / (s**2 + 2.0 * xi * w * s + w**2)  # (n_freq, n)
    parts: list[tuple[np.ndarray, np.ndarray | None]]
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
        assert rows is not None  # 'uv' multiplies by left, 'wy' by its outputs
        # G[f, a, b] = Σ_n response[f, n]·rows[a, n]·right[n, b]: one matrix product per output.
        term = np.stack([response @ (rows[a][:, None] * right) for a in range(rows.shape[0])], axis=1)
        out = term if out is None else out + term
    assert out is not None  # parts is never empty
    return out


def frequency_grid(models: list[ModalModel], band: float, points: int = 4000) -> np.ndarray:
    """A frequency grid on [0, band] rad/s for band-limited norms.

    Log-spaced plus ±5 half-power bandwidths around every resonance in band, so that
    band-limited norms of lightly damped models converge.

    Parameters
    ----------
    models : list of ModalModel
        The models whose resonances refine the grid.
    band : float
        The upper end [rad/s].
    points : int
        Points of the linear and of the logarithmic part.

    Returns
    -------
    ndarray
        The sorted, unique grid [rad/s].
    """
    grid = [np.linspace(0.0, band, points), np.geomspace(band * 1e-4, band, points)]
    for m in models:
        inside = m.omega < band
        for w, xi in zip(m.omega[inside], m.damping[inside]):
            grid.append(w * (1.0 + xi * np.linspace(-8.0, 8.0, 33)))
    merged = np.unique(np.concatenate(grid))
    return merged[(merged >= 0.0) & (merged <= band)]


def band_norms(full: ModalModel, reduced: ModalModel, band: float, path: str) -> dict[str, float]:
    """Band-limited H2 and H∞ norms of a path and of the error full − reduced on [0, band].

    H2 over the band: √((1/π)∫₀^band ‖G(jω)‖_F² dω) by the trapezoidal rule on the refined
    grid; H∞: the largest singular value on the grid.

    Parameters
    ----------
    full, reduced : ModalModel
        The reference and the reduced model.
    band : float
        The upper end of the band [rad/s].
    path : str
        'uv' or 'wy' (see `frequency_response`).

    Returns
    -------
    dict of str to float
        ``h2``, ``h2_error``, ``hinf``, ``hinf_error``, ``h2_relative``, ``hinf_relative``.
    """
    grid = frequency_grid([full, reduced], band)
    G = frequency_response(full, grid, path)
    R = frequency_response(reduced, grid, path)

    def h2(X):
        return float(np.sqrt(np.trapezoid(np.sum(np.abs(X) ** 2, axis=(1, 2)), grid) / np.pi))

    def hinf(X):
        return float(np.max(np.linalg.svd(X, compute_uv=False)))

    return {
        "h2": h2(G),
        "h2_error": h2(G - R),
        "hinf": hinf(G),
        "hinf_error": hinf(G - R),
        "h2_relative": h2(G - R) / max(h2(G), 1e-300),
        "hinf_relative": hinf(G - R) / max(hinf(G), 1e-300),
    }


def static_compliance(fe_model) -> np.ndarray:
    """Exact static joint compliance EᵀK⁻¹E of the full FE model (Eq. 24, k = 0).

    Parameters
    ----------
    fe_model : FEModel
        The FE model.

    Returns
    -------
    ndarray
        (K, K), one row and column per joint.
    """
    factor = spla.splu(sp.csc_matrix(fe_model.stiffness))
    return fe_model.E.T @ factor.solve(np.asarray(fe_model.E))


def modal_compliance(model: ModalModel) -> np.ndarray:
    """Static joint compliance of a modal model: Σ e_i e_iᵀ/ω_i².

    Parameters
    ----------
    model : ModalModel
        The modal model.

    Returns
    -------
    ndarray
        (K, K), one row and column per joint.
    """
    return (model.joint_input / model.omega[:, None] ** 2).T @ model.joint_input


def error_metrics(fe_model, full: ModalModel, reduced: ModalModel, band: float) -> dict:
    """Static gain, band-limited H2/H∞ of u_R → v and w → y: reduced against full.

    Parameters
    ----------
    fe_model : FEModel
        The FE model (for the exact static compliance).
    full, reduced : ModalModel
        The reference and the reduced model.
    band : float
        The upper end of the band [rad/s].

    Returns
    -------
    dict
        ``static_compliance`` (full, reduced, relative_error; None without joints),
        ``band_hz``, and ``uv`` / ``wy`` as `band_norms` where the model has those paths.
    """
    exact = static_compliance(fe_model)
    approx = modal_compliance(reduced)
    out = {
        "static_compliance": {
            "full": exact.tolist(),
            "reduced": approx.tolist(),
            "relative_error": float(np.linalg.norm(exact - approx) / np.linalg.norm(exact)),
        }
        if exact.size
        else None,
        "band_hz": band / (2.0 * np.pi),
    }
    if full.joint_input.shape[1]:
        out["uv"] = band_norms(full, reduced, band, "uv")
    if full.disturbance_input.shape[1] and full.displacement_output.shape[0]:
        out["wy"] = band_norms(full, reduced, band, "wy")
    return out


__all__ = [
    "band_norms",
    "error_metrics",
    "frequency_grid",
    "frequency_response",
    "modal_compliance",
    "static_compliance",
]
