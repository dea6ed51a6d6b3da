"""Reduced models side by side with balanced truncation of the same full model (issue 31).

The baseline a control engineer would reach for is balanced truncation (BT) at the same order:
it keeps what the inputs [u_R, w] excite and the outputs [v, y] see, whatever the frequency.
Here it is given the modes of the full model below ``cut`` × the controller's Nyquist frequency
(the square-root method costs O(n³) in their count); what that cut alone loses is reported beside
it (``cut_alone``), so the baseline's own error is not mistaken for the cut's. Norms are taken in
the considered band and across the band to the Nyquist frequency, where a sampled controller
and its Kalman filter still see the structure.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from smartjoint.design.reduction import balanced, metrics
from smartjoint.design.structure.modal import ModalModel

PATHS = ("uv", "wy")
OVERDAMPED_STANDIN = 0.99  # ξ BT is given for a critically damped (quasi-static) coordinate
MAX_BALANCED_MODES = 2000  # modes given to BT at most: its SVD of 2n×2n gramian factors, ~1 min at 2000


@dataclass
class Comparison:
    """The norms of a comparison and what its Bode plot needs.

    ``norms[band][path][model]`` is a dict ``hinf``, ``h2``, ``hinf_relative`` of full − model,
    ``band`` ∈ {'band', 'nyquist'}, ``path`` ∈ `PATHS`, ``model`` the given names plus 'bt' and
    'cut_alone' (absent where BT was skipped, with ``skipped`` saying why).
    """

    order: int
    cut: float
    band_hz: float
    nyquist_hz: float
    balanced_modes: int
    static_compliance_error: dict[str, float]
    norms: dict[str, dict[str, dict[str, dict[str, float]]]]
    seconds: float
    skipped: str = ""
    grid: np.ndarray = field(default_factory=lambda: np.zeros(0))  # rad/s, to Nyquist
    gains: dict[str, np.ndarray] = field(default_factory=dict)  # σ_max of u_R → v on ``grid``

    def summary(self) -> dict:
        """The JSON-able part (no responses)."""
        return {
            "order": self.order,
            "cut": self.cut,
            "band_hz": self.band_hz,
            "nyquist_hz": self.nyquist_hz,
            "balanced_modes": self.balanced_modes,
            "static_compliance_error": self.static_compliance_error,
            "norms": self.norms,
            "seconds": self.seconds,
            "skipped": self.skipped,
        }

    def ratio(self, band: str, path: str, model: str, norm: str = "hinf") -> float:
        """``model``'s error over balanced truncation's (nan where BT was skipped)."""
        entry = self.norms[band][path]
        return entry[model][norm] / entry["bt"][norm] if "bt" in entry else float("nan")


def _error_norms(exact: np.ndarray, response: np.ndarray, grid: np.ndarray) -> dict[str, float]:
    """H∞ and H2 of exact − response on ``grid`` (trapezoidal H2, as `metrics.band_norms`)."""
    error = exact - response
    hinf = float(np.linalg.svd(error, compute_uv=False).max())
    h2 = float(np.sqrt(np.trapezoid(np.sum(np.abs(error) ** 2, axis=(1, 2)), grid) / np.pi))
    return {"hinf": hinf, "h2": h2, "hinf_relative": hinf / float(np.linalg.svd(exact, compute_uv=False).max())}


def _modes(model: ModalModel, indices: np.ndarray) -> ModalModel:
    """The coordinates ``indices`` of a modal model."""
    return ModalModel(
        model.omega[indices], model.damping[indices], model.joint_input[indices], model.disturbance_input[indices],
        model.displacement_output[:, indices], model.velocity_output[:, indices],
        [model.labels[i] for i in indices], model.joint_names, model.sensor_names, model.disturbance_names,
    )  # fmt: skip


def _balanced_baseline(full: ModalModel, order: int, upper: float, cut: float, max_modes: int):
    """BT of the coordinates of ``full`` below ``upper`` [rad/s] (and a sparse reference's static
    residual): (model or None, the coordinates given, why it was skipped)."""
    # A sparse reference's static residual (quasi-static, above the cut) is part of the full model.
    residual = np.array([label.startswith("krylov residual") for label in full.labels], dtype=bool)
    given = np.flatnonzero((full.omega < upper) | residual)
    if given.size > max_modes:
        return (
            None,
            given,
            (
                f"balanced truncation skipped: {given.size} modes below {cut:g}× Nyquist "
                f"({upper / (2 * np.pi):.0f} Hz), more than {max_modes}"
            ),
        )
    if 2 * given.size <= order:
        return (
            None,
            given,
            f"balanced truncation skipped: only {given.size} modes below {cut:g}× Nyquist for order {order}",
        )
    below = _modes(full, given)
    # The closed-form gramians need 0 < ξ < 1: a quasi-static residual (ξ = 1, a defective 2×2
    # block) is given at ξ = 0.99, which moves its response below ω_q/4 by less than 0.5 %.
    below = replace(below, damping=np.minimum(below.damping, OVERDAMPED_STANDIN))
    return balanced.balanced_truncation(below, order), given, ""


def _static_errors(models: dict[str, ModalModel], bt, exact_compliance: np.ndarray) -> dict[str, float]:
    """Relative static joint compliance error of each model and of BT (where given)."""
    norm = float(np.linalg.norm(exact_compliance))
    static = {
        name: float(np.linalg.norm(metrics.modal_compliance(model) - exact_compliance) / norm)
        for name, model in models.items()
    }
    if bt is not None:
        # BT's u_R → v is −C_v(sI − A)⁻¹B_u (its input is −u_R): the compliance, d/ds at 0, is C_v A⁻²B_u.
        joints = exact_compliance.shape[0]
        bt_static = bt.C[:joints] @ np.linalg.solve(bt.A, np.linalg.solve(bt.A, bt.B[:, :joints]))
        static["bt"] = float(np.linalg.norm(bt_static - exact_compliance) / norm)
    return static


def compare_with_balanced_truncation(
    full: ModalModel,
    models: dict[str, ModalModel],
    exact_compliance: np.ndarray,
    band: float,
    nyquist: float,
    cut: float = 4.0,
    points: int = 3000,
    max_modes: int = MAX_BALANCED_MODES,
) -> Comparison:
    """Reduced models and BT of ``full`` at their order, in the band and to Nyquist.

    Parameters
    ----------
    full : ModalModel
        The reference.
    models : dict of str to ModalModel
        Reduced models of one order (the first model's order is BT's).
    exact_compliance : ndarray
        The static joint compliance EᵀK⁻¹E of the FE model (`metrics.static_compliance`).
    band, nyquist : float
        The considered band's upper end and the controller's Nyquist frequency [rad/s].
    cut : float
        BT is given the modes of ``full`` below ``cut`` × ``nyquist``.
    points : int
        Base points of each frequency grid (refined at every resonance).
    max_modes : int
        Above this many modes below the cut, BT is skipped (``skipped`` says so).

    Returns
    -------
    Comparison
    """
    start = time.perf_counter()
    order = next(iter(models.values())).n_states
    bt, given, skipped = _balanced_baseline(full, order, cut * nyquist, cut, max_modes)
    static = _static_errors(models, bt, exact_compliance)
    norms: dict[str, dict[str, dict[str, dict[str, float]]]] = {}
    grid_nyquist = np.zeros(0)
    gains: dict[str, np.ndarray] = {}
    for label, upper in (("band", band), ("nyquist", nyquist)):
        grid = metrics.frequency_grid([full, *models.values()], upper, points)
        norms[label] = {}
        for path in PATHS:
            exact = metrics.frequency_response(full, grid, path)
            responses = {name: metrics.frequency_response(model, grid, path) for name, model in models.items()}
            if bt is not None:
                responses["bt"] = bt.frequency_response(grid, path)
                responses["cut_alone"] = metrics.frequency_response(_modes(full, given), grid, path)
            norms[label][path] = {name: _error_norms(exact, r, grid) for name, r in responses.items()}
            if label == "nyquist" and path == "uv":
                grid_nyquist = grid
                gains = {
                    name: np.linalg.svd(r, compute_uv=False)[:, 0]
                    for name, r in {"full": exact, **responses}.items()
                    if name != "cut_alone"
                }
    return Comparison(
        order=order,
        cut=cut,
        band_hz=band / (2 * np.pi),
        nyquist_hz=nyquist / (2 * np.pi),
        balanced_modes=int(given.size) if bt is not None else 0,
        static_compliance_error=static,
        norms=norms,
        seconds=time.perf_counter() - start,
        skipped=skipped,
        grid=grid_nyquist,
        gains=gains,
    )


__all__ = ["Comparison", "MAX_BALANCED_MODES", "compare_with_balanced_truncation"]
