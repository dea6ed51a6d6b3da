"""Balanced mode selection (paper Section 4.1, Eq. 16–18), independent of the channels' units.

For lightly damped, well separated modes the gramians of the modal state space are diagonal
with 2×2 blocks w_i·I, in closed form per input column e_ij of u_R (and h_ij of w) and per
output row of y

    w^c_ij = e_ij²/(4ξ_iω_i),   w^o_ik = (ω_i²W_ki² + V_ki²)/(4ξ_iω_i³)        (Eq. 17)

and the Hankel singular value of the path u_R → v is γ_uv,i = Σ_j w^c_ij (Eq. 18, v = Bᵀx).

The channels carry different units: a type A joint's u_R is a force [N] on a slip in metres, a
type B joint's a torque [N·m] on a rotation in radians; sensors measure displacements [m] or
velocities [m/s]; disturbances may be forces or moments. Summed as they are, a joint measured
in mrad instead of rad would weigh 10⁶ times more and could change the chosen modes. So every
channel is scaled by its own reference before the sum, the way each path below is normalised
by its own largest value: the reference r_j of an input is its largest modal controllability
gramian max_i w^c_ij over the considered modes [J/(s·N²) or J/(s·(N·m)²)], that of a sensor
its largest observability gramian max_i w^o_ik [m²·s/J, (m/s)²·s/J, …]. This is the scaling
u_j = √r_j·ũ_j, y_k = √r_k·ỹ_k of the state space, so the values stay Hankel singular values
(of the scaled system, tested against the Lyapunov gramians), and they no longer change when a
channel's unit does. The static joint compliance (the DC gain) would be the other natural
reference for the joints, but a velocity sensor has none; the largest modal value serves every
channel alike. Scaled per channel, not per physical kind, so that a joint that couples weakly
to every mode still has its modes kept: each joint's friction needs its own dominant modes.

A mode's score is its largest scaled Hankel value over the paths u_R → v, w → y
(γ_wy,i = √(w^c_w,i·w^o_y,i)), u_R → y and w → v, each path normalised by its own largest
value; the n_d best are kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.structure.modal import ModalModel

PATHS = ("uv", "wy", "uy", "wv")


@dataclass(frozen=True)
class ChannelReference:
    """The reference r that scales one input or output channel of the ranking (Eq. 17)."""

    kind: str  # "joint" (u_R), "disturbance" (w) or "sensor" (y)
    name: str
    value: float  # the channel's largest modal gramian over the considered modes
    unit: str  # of value; "" when the model does not know the channel's unit
    mode: int  # 1-based considered mode where the largest gramian sits


def modal_gramians(model: ModalModel) -> dict[str, np.ndarray]:
    """Closed-form gramians per mode and channel, in the channels' own units (Eq. 17).

    Parameters
    ----------
    model : ModalModel
        The modal model whose modes are scored.

    Returns
    -------
    dict of str to ndarray
        ``"joint"`` (n, l) w^c of each joint input, ``"disturbance"`` (n, m) w^c of each
        disturbance, ``"sensor"`` (n, n_y) w^o of each sensor output.
    """
    w = model.omega[:, None]
    xi = model.damping[:, None]
    return {
        "joint": model.joint_input**2 / (4.0 * xi * w),
        "disturbance": model.disturbance_input**2 / (4.0 * xi * w),
        "sensor": (w**2 * model.velocity_output.T**2 + model.displacement_output.T**2) / (4.0 * xi * w**3),
    }


def _gramian_unit(kind: str, unit: str) -> str:
    """The unit of a gramian: J/(s·U²) for an input of unit U, Y²·s/J for an output of unit Y."""
    if not unit:
        return ""
    squared = f"({unit})²" if ("/" in unit or "·" in unit) else f"{unit}²"
    return f"{squared}·s/J" if kind == "sensor" else f"J/(s·{squared})"


def channel_references(model: ModalModel) -> list[ChannelReference]:
    """The reference of every channel: its largest modal gramian over the modes of ``model``.

    Parameters
    ----------
    model : ModalModel
        The considered modes.

    Returns
    -------
    list of ChannelReference
        Joints, then disturbances, then sensors, each in the model's order. A channel that no
        mode reaches (all gramians zero) gets the reference 1: it adds nothing either way.
    """
    gramians = modal_gramians(model)
    channels = {
        "joint": (model.joint_names, model.joint_units),
        "disturbance": (model.disturbance_names, model.disturbance_units),
        "sensor": (model.sensor_names, model.sensor_units),
    }
    references = []
    for kind, (names, units) in channels.items():
        values = gramians[kind]
        for k, name in enumerate(names):
            top = int(np.argmax(values[:, k])) if values.shape[0] else 0
            value = float(values[top, k]) if values.shape[0] else 0.0
            unit = _gramian_unit(kind, units[k]) if k < len(units) else ""
            references.append(ChannelReference(kind, name, value if value > 0 else 1.0, unit, top + 1))
    return references


def hankel_values(model: ModalModel) -> dict[str, np.ndarray]:
    """Closed-form Hankel singular values per mode and path, channels scaled (Eq. 17–18).

    Parameters
    ----------
    model : ModalModel
        The considered modes, with the channels' units where known.

    Returns
    -------
    dict of str to ndarray
        One dimensionless value per mode for each path of ``PATHS`` ('uv', 'wy', 'uy', 'wv')
        and the scaled controllability of the joint inputs, Σ_j w^c_ij/r_j, under
        ``"controllability_u"``; the references r are those of `channel_references`.
    """
    gramians = modal_gramians(model)
    by_kind: dict[str, list[float]] = {"joint": [], "disturbance": [], "sensor": []}
    for reference in channel_references(model):
        by_kind[reference.kind].append(reference.value)
    scaled = {
        kind: (gramians[kind] / np.asarray(values)).sum(axis=1) if values else np.zeros(model.n_coordinates)
        for kind, values in by_kind.items()
    }
    control_u = scaled["joint"]
    control_w = scaled["disturbance"]
    observe_v = control_u  # v = Bᵀx: the same vectors and references as the input
    observe_y = scaled["sensor"]
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


__all__ = ["ChannelReference", "PATHS", "channel_references", "hankel_values", "modal_gramians", "select_modes"]
