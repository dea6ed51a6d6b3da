"""What a real rig adds to the ideal test of ``rig``: a shaker whose force has harmonics, a
preload that drifts during the record, and sensors with a resolution and a noise floor.

The ideal rig drives the element with A·sin(ωt) at a constant normal force and records the
nominal F_N. A real one (paper Section 3.2: shaker, piezo or bolt preload, load cells) does
not: the shaker's force is distorted by the friction load it drives (harmonics), the preload
relaxes or creeps (a drift of a few per cent over a record), and every channel is sampled by an
ADC (its least significant bit) above a noise floor that does not scale with the signal. The
record's ``normal_force`` column is then the *measured* F_N(t), not the nominal one, and the
identification uses it sample by sample (Eq. 3's model force, the output-error step's r·F_N(t),
the bootstrap's replicates).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from smartjoint.common.errors import SmartjointError

MAX_HARMONICS = 5
MAX_ORDER = 10
CHANNELS = ("velocity", "excitation force", "normal force")


@dataclass(frozen=True)
class RigImperfections:
    """A real rig's departures from the ideal test (all zero: the ideal rig).

    ``normal_force_drift``: the relative change of F_N from the record's start to its end (a
    linear drift; −0.03 is a preload relaxing by 3 %). ``harmonics``: the shaker force's
    harmonics as (order, amplitude relative to the fundamental). ``resolution`` and
    ``noise_floor``: per channel (velocity [m/s or rad/s], excitation force [N or N·m], normal
    force [N]) the ADC's least significant bit and an absolute Gaussian noise σ, added to the
    test's relative noise.
    """

    normal_force_drift: float = 0.0
    harmonics: tuple[tuple[int, float], ...] = ()
    resolution: tuple[float, float, float] = (0.0, 0.0, 0.0)
    noise_floor: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def ideal(self) -> bool:
        return self == IDEAL

    def check(self) -> None:
        """``SmartjointError`` in one line naming the field, the value and what is allowed."""
        drift = self.normal_force_drift
        if not (math.isfinite(drift) and abs(drift) <= 0.5):
            raise SmartjointError(f"normal_force_drift: {drift!r} — allowed: −0.5 … 0.5 (relative over a record)")
        if len(self.harmonics) > MAX_HARMONICS:
            raise SmartjointError(f"harmonics: {len(self.harmonics)} given — allowed: at most {MAX_HARMONICS}")
        for order, amplitude in self.harmonics:
            if not (isinstance(order, int) and 2 <= order <= MAX_ORDER):
                raise SmartjointError(f"harmonics: order {order!r} — allowed: an integer 2 … {MAX_ORDER}")
            if not (math.isfinite(amplitude) and abs(amplitude) <= 0.5):
                raise SmartjointError(f"harmonics: amplitude {amplitude!r} — allowed: −0.5 … 0.5 of the fundamental")
        for field, values in (("resolution", self.resolution), ("noise_floor", self.noise_floor)):
            if len(values) != len(CHANNELS):
                raise SmartjointError(f"{field}: {values!r} — allowed: one value per channel ({', '.join(CHANNELS)})")
            for channel, value in zip(CHANNELS, values):
                if not (math.isfinite(value) and value >= 0.0):
                    raise SmartjointError(f"{field} of the {channel}: {value!r} — allowed: a finite number >= 0")


IDEAL = RigImperfections()


def excitation(imperfections: RigImperfections, amplitude: float, omega: float, time: np.ndarray) -> np.ndarray:
    """The shaker force A·(sin ωt + Σ a_k·sin kωt) at ``time``."""
    force = np.sin(omega * time)
    for order, relative in imperfections.harmonics:
        force = force + relative * np.sin(order * omega * time)
    return amplitude * force


def normal_force(imperfections: RigImperfections, nominal: float, time: np.ndarray, duration: float) -> np.ndarray:
    """F_N(t): the nominal preload drifting linearly by ``normal_force_drift`` over ``duration``."""
    return nominal * (1.0 + imperfections.normal_force_drift * time / duration)


def measured(signal: np.ndarray, channel: int, imperfections: RigImperfections, rng: np.random.Generator) -> np.ndarray:
    """``signal`` as the channel's sensor records it: its noise floor added, then quantised."""
    out = signal
    floor = imperfections.noise_floor[channel]
    if floor > 0.0:
        out = out + floor * rng.standard_normal(signal.size)
    step = imperfections.resolution[channel]
    if step > 0.0:
        out = step * np.round(out / step)
    return out


__all__ = ["IDEAL", "RigImperfections", "excitation", "measured", "normal_force"]
