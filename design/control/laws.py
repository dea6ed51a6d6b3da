"""The local semi-active law of paper Section 5.1 and what every controller step shares.

These Python classes are the executable specification of the firmware: the generated C must
match them sample by sample, so each keeps its state, update order and saturation explicit.
All sit behind ``design.plant.interface.Controller`` (``reset()``, ``step(measurements) ->
normal_forces``, ``sample_time``).

* The status bits of a controller step and the checks of its inputs against their plausible
  ranges (``input_status``), shared with the LQG controllers of ``filter.py``.
* ``boundary_layer`` — the smoothed Heaviside of Eq. 30 and Eq. 34.
* ``SisoLaw`` — the local Lyapunov law of Eq. 30 in every joint with μ_j of Eq. 31.
"""

from __future__ import annotations

import math

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.plant.interface import Measurements

# Status bits of a controller step (the generated C returns the same values; 4 is the C's
# NULL_POINTER, 0x10 the CAN layer's SAFE_STATE). Any of them puts EVERY joint at the safe
# normal force (the artefact's safe_normal_force, docs/safety.md).
STATUS_OK = 0
STATUS_INPUT_INVALID = 1  # a measurement was NaN or ±Inf
STATUS_ESTIMATE_RESET = 2  # the cLQG estimate or force left the finite numbers: filter restarted
STATUS_INPUT_IMPLAUSIBLE = 8  # a finite measurement outside its plausible range


def _vector(field: str, value, count: int, default: float) -> np.ndarray:
    """A per-channel float vector (a number is broadcast; None gives ``default``)."""
    array = np.array(default if value is None else value, dtype=float)
    if array.ndim == 0:
        array = np.full(count, float(array))
    if array.shape != (count,) or np.any(np.isnan(array)):
        raise ModelError(f"{field}: {array.tolist()} — expected a number or {count} numbers, none NaN")
    return array


def safe_force(value, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The safe normal force per joint, checked against [F_N^min, F_N^max].

    Parameters
    ----------
    value : float, array_like or None
        The safe normal force (a number for every joint); None: F_N^max (the design file's
        default, locked joints).
    low, high : numpy.ndarray
        F_N^min and F_N^max per joint.

    Returns
    -------
    numpy.ndarray
        The safe normal force per joint.
    """
    safe = _vector("safe_normal_force", high if value is None else value, low.size, 0.0)
    if not np.all(np.isfinite(safe)) or np.any(safe < low) or np.any(safe > high):
        raise ModelError(
            f"safe_normal_force: {safe.tolist()} — must lie within [normal_force_min, normal_force_max] "
            f"= [{low.tolist()}, {high.tolist()}] N per joint"
        )
    return safe


def magnitude_limit(field: str, value, count: int) -> np.ndarray:
    """The plausible magnitude of a measured value per channel: |x| <= limit is plausible.

    Parameters
    ----------
    field : str
        The argument's name, for the error.
    value : float, array_like or None
        The limit (> 0); None: no range beyond finiteness (+inf).
    count : int
        Number of channels.

    Returns
    -------
    numpy.ndarray
        The limit per channel.
    """
    limit = _vector(field, value, count, math.inf)
    if np.any(limit <= 0):
        raise ModelError(f"{field}: {limit.tolist()} — must be > 0")
    return limit


def input_status(value, low, high) -> np.ndarray:
    """Per measured value, its status bits against its plausible range [low, high]:
    ``STATUS_INPUT_INVALID`` for NaN/±Inf, ``STATUS_INPUT_IMPLAUSIBLE`` for a number outside (a
    value at a limit is within), else 0. The range test is written as "within", false for NaN,
    as in the C (``check_input``).

    Parameters
    ----------
    value : array_like
        The measured values.
    low, high : float or array_like
        The plausible range, limits included.

    Returns
    -------
    ndarray of int
        One status per value.

    Examples
    --------
    >>> input_status([0.5, 2.0, np.nan], -1.0, 1.0).tolist()
    [0, 8, 1]
    """
    value = np.asarray(value, dtype=float)
    with np.errstate(invalid="ignore"):
        inside = (value >= low) & (value <= high)
    return np.where(~np.isfinite(value), STATUS_INPUT_INVALID, np.where(inside, STATUS_OK, STATUS_INPUT_IMPLAUSIBLE))


def any_status(*statuses: np.ndarray) -> int:
    """The OR of every bit of the per-value statuses.

    Parameters
    ----------
    *statuses : numpy.ndarray
        Status bits per value (``input_status``).

    Returns
    -------
    int
        The controller step's status.

    Examples
    --------
    >>> any_status(np.array([0, 1]), np.array([8]))
    9
    """
    return int(np.bitwise_or.reduce(np.concatenate([np.ravel(s) for s in statuses]), initial=STATUS_OK))


def boundary_layer(value, width):
    """The smoothed Heaviside H_ε(s) = clip(s/ε, 0, 1) of Eq. 30 and Eq. 34, with NaN → 0
    (written as s > 0 ? min(s, 1) : 0 so that C and numpy agree on every input).

    Parameters
    ----------
    value : array_like
        s, the switching quantity.
    width : float or array_like
        ε, the boundary layer (same unit as ``value``).

    Returns
    -------
    ndarray
        H_ε(s) in [0, 1].

    Examples
    --------
    >>> boundary_layer([-1.0, 0.5, 3.0, np.nan], 1.0).tolist()
    [0.0, 0.5, 1.0, 0.0]
    """
    with np.errstate(all="ignore"):
        ratio = np.asarray(value, dtype=float) / width
    return np.where(ratio > 0.0, np.minimum(ratio, 1.0), 0.0)


class SisoLaw:
    """Local Lyapunov law of Eq. 30 in each joint, μ_j from the previous sample (Eq. 31).

    At sample k, per joint j, with v_k the measured sliding velocity::

        μ_k   = u_R,k−1 / F_N,k−1                               (Eq. 31; 0 at the first sample)
        F_N,k = F_N^min + (F_N^max − F_N^min)·clip(μ_k·v_k / ε, 0, 1)     (Eq. 30)

    Inputs the law cannot use: a v, u_R or F_N that is NaN or ±Inf (``STATUS_INPUT_INVALID``)
    or a number outside its plausible range (``STATUS_INPUT_IMPLAUSIBLE``; plausible are
    |v| <= sliding_velocity_limit, |u_R| <= friction_force_limit and measured_normal_force_min
    <= F_N <= measured_normal_force_max, limits included). Then EVERY joint is commanded
    ``safe_normal_force`` and the affected joints forget their memory (μ = 0 at their next
    sample); the others keep theirs, μ being a ratio of their own measurements. ``status``
    holds the bits.

    u_R,k−1 and F_N,k−1 are the friction force and the applied normal force *measured* at the
    previous sample, so μ is always a ratio of quantities of one instant. Reading of Eq. 30:
    the paper writes the boundary-layer branch as F^min + (F^max/ε)·μv, which jumps at μv = ε
    unless F^min = 0; the continuous interpolation between the two outer branches is used.
    State: the previous friction force and normal force per joint (zero after reset).

    Without the safety arguments: safe force F_N^max, no ranges beyond finiteness
    (:func:`siso_law` builds the law with the artefact's).
    """

    def __init__(
        self,
        sample_time: float,
        normal_force_min,
        normal_force_max,
        boundary_layer_width,
        *,
        safe_normal_force=None,
        sliding_velocity_limit=None,
        friction_force_limit=None,
        measured_normal_force_min=None,
        measured_normal_force_max=None,
    ):
        self.sample_time = float(sample_time)
        self.normal_force_min = np.array(normal_force_min, dtype=float)
        self.normal_force_max = np.array(normal_force_max, dtype=float)
        self.boundary_layer = np.array(boundary_layer_width, dtype=float)
        check_limits(self.normal_force_min, self.normal_force_max)
        self.normal_force_range = self.normal_force_max - self.normal_force_min
        if np.any(self.normal_force_min <= 0):
            raise ModelError(
                f"normal_force_min: {self.normal_force_min.tolist()} — the SISO law needs F_N^min > 0: "
                "μ = u_R/F_N (Eq. 31) is undefined at F_N = 0"
            )
        if not np.all(np.isfinite(self.boundary_layer)) or np.any(self.boundary_layer <= 0):
            raise ModelError(f"siso_boundary_layer: {self.boundary_layer.tolist()} — ε must be finite and > 0 [m/s]")
        count = self.normal_force_min.size
        self.safe_normal_force = safe_force(safe_normal_force, self.normal_force_min, self.normal_force_max)
        self.sliding_velocity_limit = magnitude_limit("sliding_velocity_limit", sliding_velocity_limit, count)
        self.friction_force_limit = magnitude_limit("friction_force_limit", friction_force_limit, count)
        self.measured_normal_force_min, self.measured_normal_force_max = measured_range(
            measured_normal_force_min, measured_normal_force_max, count
        )
        self.reset()

    def reset(self) -> None:
        count = self.normal_force_min.size
        self.previous_friction = np.zeros(count)
        self.previous_normal_force = np.zeros(count)
        self.status = STATUS_OK

    def step(self, measurements: Measurements) -> np.ndarray:
        velocity = np.asarray(measurements.sliding_velocity, dtype=float)
        friction = np.asarray(measurements.friction_force, dtype=float)
        applied = np.asarray(measurements.normal_force, dtype=float)
        joint_status = (
            input_status(velocity, -self.sliding_velocity_limit, self.sliding_velocity_limit)
            | input_status(friction, -self.friction_force_limit, self.friction_force_limit)
            | input_status(applied, self.measured_normal_force_min, self.measured_normal_force_max)
        )
        usable = joint_status == STATUS_OK
        self.status = any_status(joint_status)
        previous_force, previous_normal = self.previous_friction, self.previous_normal_force
        self.previous_friction = np.where(usable, friction, 0.0)
        self.previous_normal_force = np.where(usable, applied, 0.0)
        if self.status != STATUS_OK:
            return self.safe_normal_force.copy()
        with np.errstate(all="ignore"):
            known = previous_normal > 0.0
            mu = np.where(known, previous_force / np.where(known, previous_normal, 1.0), 0.0)  # Eq. 31
            power = mu * velocity
        return self.normal_force_min + self.normal_force_range * boundary_layer(power, self.boundary_layer)


def safe_state_options(artifact) -> dict:
    """What every law takes from a controller artefact for the safe state: the safe normal force
    and the plausibility ranges of the friction force and the measured normal force."""
    return {
        "safe_normal_force": artifact.safe_normal_force,
        "friction_force_limit": artifact.friction_force_limit,
        "measured_normal_force_min": artifact.measured_normal_force_min,
        "measured_normal_force_max": artifact.measured_normal_force_max,
    }


def siso_law(artifact) -> SisoLaw:
    """The SISO law's Python reference from a controller artefact alone: Eq. 30 with μ of
    Eq. 31, per joint, with the artefact's safe normal force and plausibility ranges (what the
    generated C checks).

    Parameters
    ----------
    artifact : ControllerArtifact
        Its limits, ε per joint, safe force and plausibility ranges.

    Returns
    -------
    SisoLaw
    """
    return SisoLaw(
        artifact.sample_time,
        artifact.siso_normal_force_min,  # the law's own F_N^min (a preload), the joints' by default
        artifact.normal_force_max,
        artifact.siso_boundary_layer,
        sliding_velocity_limit=artifact.sliding_velocity_limit,
        **safe_state_options(artifact),
    )


def measured_range(low, high, count: int) -> tuple[np.ndarray, np.ndarray]:
    """The plausible range of a measured normal force per joint.

    Parameters
    ----------
    low, high : float, array_like or None
        measured_normal_force_min / _max; None: unbounded on that side.
    count : int
        Number of joints.

    Returns
    -------
    tuple of numpy.ndarray
        (low, high) per joint, low <= high.
    """
    low = _vector("measured_normal_force_min", low, count, -math.inf)
    high = _vector("measured_normal_force_max", high, count, math.inf)
    if np.any(low > high):
        raise ModelError(
            f"measured_normal_force_min {low.tolist()} / measured_normal_force_max {high.tolist()}: "
            "need min <= max per joint"
        )
    return low, high


def check_limits(low: np.ndarray, high: np.ndarray) -> None:
    """Check the commanded normal-force range: finite, one per joint, 0 <= F_N^min <= F_N^max.

    Parameters
    ----------
    low, high : numpy.ndarray
        F_N^min and F_N^max per joint.
    """
    if low.shape != high.shape or not np.all(np.isfinite(low)) or not np.all(np.isfinite(high)):
        raise ModelError(
            f"normal_force_min {low.tolist()} / normal_force_max {high.tolist()}: need finite values, one per joint"
        )
    if np.any(low < 0) or np.any(low > high):
        raise ModelError(
            f"normal_force_min {low.tolist()} / normal_force_max {high.tolist()}: need "
            "0 <= F_N^min <= F_N^max per joint"
        )


__all__ = [
    "STATUS_ESTIMATE_RESET",
    "STATUS_INPUT_IMPLAUSIBLE",
    "STATUS_INPUT_INVALID",
    "STATUS_OK",
    "SisoLaw",
    "any_status",
    "boundary_layer",
    "check_limits",
    "input_status",
    "magnitude_limit",
    "measured_range",
    "safe_force",
    "safe_state_options",
    "siso_law",
]
