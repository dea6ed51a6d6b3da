"""The plant/controller seam: what a controller sees, what it must offer, and two wrappers.

Every controller (``design/control``), the plant schemes (``design/plant``) and the SIL bench
import the interface from here, never from the simulator. A controller is any object with a
``sample_time`` [s], ``reset()`` and ``step(measurements) -> commands``; the loop driver
(``loop.simulate``) calls ``step`` every ``sample_time`` and holds the commands in between
(zero-order hold). For the friction schemes the commands are the joints' normal forces F_N
(Eq. 2); for the frictionless ``linear`` scheme they are the joint forces themselves.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass
class Measurements:
    """What a controller sees at a sample: time, sensors y, joint velocities v, friction u_R, F_N."""

    time: float
    sensors: np.ndarray
    sliding_velocity: np.ndarray
    friction_force: np.ndarray
    normal_force: np.ndarray


class Controller(Protocol):
    """A discrete-time controller: ``step`` every ``sample_time`` seconds, ``reset`` before a run."""

    sample_time: float

    def reset(self) -> None: ...

    def step(self, measurements: Measurements) -> np.ndarray: ...


@dataclass
class ConstantNormalForce:
    """Passive joints: a constant normal force per joint."""

    normal_forces: np.ndarray
    sample_time: float = 1e-3
    holds_constant = True  # simulate() asks once and runs the whole span in one kernel call

    def reset(self) -> None:
        pass

    def step(self, measurements: Measurements) -> np.ndarray:
        return np.asarray(self.normal_forces, dtype=float)


class HoldDuringExcitation:
    """The study's protocol (Section 6): F_N = F_N^max while the disturbance acts (t < ``until``),
    then the wrapped controller. The wrapped controller runs from the first sample (its filter
    and memories see everything); only its output is overridden."""

    def __init__(self, inner, until: float, normal_forces):
        self.inner, self.until = inner, float(until)
        self.normal_forces = np.array(normal_forces, dtype=float)
        self.sample_time = inner.sample_time

    def reset(self) -> None:
        self.inner.reset()

    def step(self, measurements: Measurements) -> np.ndarray:
        out = self.inner.step(measurements)
        return self.normal_forces.copy() if measurements.time < self.until - 1e-12 else out


__all__ = ["ConstantNormalForce", "Controller", "HoldDuringExcitation", "Measurements"]
