"""Balanced mode selection (paper Section 4.1, Eq. 16–18).

For lightly damped, well separated modes the gramians of the modal state space are diagonal
with 2×2 blocks w_i·I, in closed form

    w^c_i = ‖e_i‖²/(4ξ_iω_i),   w^o_i = (ω_i²‖w_i‖² + ‖v_i‖²)/(4ξ_iω_i³)        (Eq. 17)

and the Hankel singular value of the path u_R → v is γ_uv,i = ‖e_i‖²/(4ξ_iω_i) (Eq. 18).
The paths w → y (tip force → tip deflection, γ_wy,i = √(w^c_w,i·w^o_y,i)) and u_R → y add
the modes the sensors and the disturbance need. A mode's score is its largest Hankel
singular value over the paths, each path normalised by its own largest value; the n_d
best are kept.
"""

from __future__ import annotations

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.structure.modal import ModalModel

PATHS = ("uv", "wy", "uy", "wv")


def hankel_values(model: ModalModel) -> dict[str, np.ndarray]:
    """Closed-form Hankel singular values per mode and path (Eq. 17–18).

    Parameters
    ----------
    model : ModalModel
        The modal model whose modes are scored.

    Returns
    -------
    dict of str to ndarray
        One value per mode for each path of ``PATHS`` ('uv', 'wy', 'uy', 'wv'), and the
        controllability gramian of the joint inputs under ``"controllability_u"``.
    """
    w = model.omega
    xi = model.damping
    e2 = np.sum(model.joint_input**2, axis=1)
    h2 = np.sum(model.disturbance_input**2, axis=1)
    y2 = w**2 * np.sum(model.velocity_output**2, axis=0) + np.sum(model.displacement_output**2, axis=0)
    control_u = e2 / (4.0 * xi * w)
    control_w = h2 / (4.0 * xi * w)
    observe_v = e2 / (4.0 * xi * w)  # v = Bᵀx: same vectors as the input
    observe_y = y2 / (4.0 * xi * w**3)
    return {
        "uv": np.sqrt(control_u * observe_v),
        "wy": np.sqrt(control_w * observe_y),
        "uy": np.sqrt(control_u * observe_y),
        "wv": np.sqrt(control_w * observe_v),
        "controllability_u": control_u,
    }


def select_modes(model: ModalModel, n_keep: int, paths: tuple[str, ...] = PATHS) -> np.ndarray:
    """Indices of the ``n_keep`` modes with the largest normalised Hankel values (Eq. 18).

    Parameters
    ----------
    model : ModalModel
        The considered modes.
    n_keep : int
        How many modes to keep, 1 … ``model.n_coordinates``.
    paths : tuple of str
        The paths of ``PATHS`` whose Hankel values score a mode.

    Returns
    -------
    ndarray of int
        0-based indices into the considered modes, ascending.

    Raises
    ------
    ModelError
        For ``n_keep`` out of range or an unknown path.
    """
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


__all__ = ["PATHS", "hankel_values", "select_modes"]
