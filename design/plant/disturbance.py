"""Disturbances w(t) of the plant (Eq. 12: the input H·w) and their sampling on the step grid.

A disturbance is any callable ``w(t) -> (m,)``; one that also offers ``sample(times) -> (n_t, m)``
is sampled in one vectorised call, and one with a ``support_end`` (w = 0 after it) is sampled
only up to there, so a long run never builds its full time axis.
"""

from __future__ import annotations

import math

import numpy as np

from smartjoint.common.errors import ModelError


class TriangularPulse:
    """The paper's tip disturbance (Section 4.3): a triangular force pulse, peak ``amplitude``
    at duration/2, zero after ``duration``, applied along each disturbance input with the
    given factors (y and z: both 1). ``w(t)`` for one time, ``sample(times)`` for many."""

    def __init__(self, amplitude: float = 200.0, duration: float = 0.04, directions=(1.0, 1.0)):
        if not (math.isfinite(amplitude) and amplitude >= 0 and math.isfinite(duration) and duration > 0):
            raise ModelError(f"pulse: amplitude {amplitude!r} must be >= 0 and duration {duration!r} > 0")
        self.amplitude, self.duration = float(amplitude), float(duration)
        self.directions = np.asarray(directions, dtype=float).reshape(-1)
        self.breakpoints = (0.0, 0.5 * duration, duration)
        self.support_end = self.duration  # w(t) = 0 after this time: a long run samples only the pulse

    def sample(self, times) -> np.ndarray:
        t = np.asarray(times, dtype=float).reshape(-1)
        out = np.zeros((t.size, self.directions.size))
        inside = np.flatnonzero((t >= 0) & (t <= self.duration))  # a long run is mostly after the pulse
        shape = np.maximum(0.0, 1.0 - np.abs(2.0 * t[inside] / self.duration - 1.0))
        out[inside] = self.amplitude * shape[:, None] * self.directions[None, :]
        return out

    def __call__(self, t: float) -> np.ndarray:
        return self.sample([t])[0]


def triangular_pulse(amplitude: float = 200.0, duration: float = 0.04, directions=(1.0, 1.0)) -> TriangularPulse:
    """The tip pulse of Section 4.3 (see :class:`TriangularPulse`).

    Parameters
    ----------
    amplitude : float
        Peak force [N], reached at ``duration / 2``.
    duration : float
        Length of the pulse [s]; w = 0 after it.
    directions : sequence of float
        Factor per disturbance input (one per column of H).

    Returns
    -------
    TriangularPulse
        The disturbance, callable as ``w(t)``.

    Examples
    --------
    >>> triangular_pulse(200.0, 0.04, (1.0,))(0.02).tolist()
    [200.0]
    """
    return TriangularPulse(amplitude, duration, directions)


def at_steps(disturbance, steps: int, step: float, m: int, compact: bool = False) -> np.ndarray:
    """w at the ends of ``steps`` steps of length ``step``.

    Parameters
    ----------
    disturbance : callable or None
        ``w(t)``; None: no disturbance.
    steps, step : int, float
        The step grid, times ``k·step`` for k = 0 … steps.
    m : int
        Number of disturbance inputs.
    compact : bool
        Leave the zero rows after the disturbance's ``support_end`` out (for a kernel that takes
        missing rows as zero).

    Returns
    -------
    numpy.ndarray
        (steps + 1, m), or fewer rows with ``compact``; sampled only up to the ``support_end``
        where the disturbance has one (zero after).
    """
    if disturbance is None:
        return np.zeros((0 if compact else steps + 1, m))
    end = getattr(disturbance, "support_end", None)
    inside = steps + 1
    if isinstance(end, (int, float)) and math.isfinite(end) and end >= 0:
        inside = min(steps + 1, int(math.floor(end / step)) + 2)  # one sample past the end, to be sure
    values = _samples(_Unbounded(disturbance), np.arange(inside) * step, m)
    if compact or inside == steps + 1:
        return values
    return np.concatenate([values, np.zeros((steps + 1 - inside, m))])


def _samples(disturbance, times: np.ndarray, m: int) -> np.ndarray:
    """w at the given times, (n_t, m): one vectorised call where the function offers it."""
    sample = getattr(disturbance, "sample", None)
    values = sample(times) if sample else np.array([np.asarray(disturbance(t), dtype=float).reshape(-1) for t in times])
    values = np.asarray(values, dtype=float)
    if values.shape != (times.size, m):
        raise ModelError(
            f"disturbance: returned {values.shape[1:] if values.ndim == 2 else values.shape} values per "
            f"time — need {m} (one per disturbance input)"
        )
    if not np.all(np.isfinite(values)):
        bad = np.flatnonzero(~np.all(np.isfinite(values), axis=1))[0]
        raise ModelError(f"disturbance: non-finite value {values[bad].tolist()} at t = {times[bad]:.6g} s")
    return values


class _Unbounded:
    """The same disturbance without its ``support_end`` (for sampling inside the support)."""

    def __init__(self, disturbance):
        self.disturbance = disturbance
        self.sample = getattr(disturbance, "sample", None)

    def __call__(self, t):
        return self.disturbance(t)


__all__ = ["TriangularPulse", "at_steps", "triangular_pulse"]
