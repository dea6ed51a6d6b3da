"""The measurements as the bus carries them: each input of a law rounded to its signal's step and
held within its signal's range, as the firmware decodes it (``JOINT_<j>`` and ``TIP_SENSORS`` of
the plan's databases, ``design.network.protocol``).

The SIL study compares the firmware with the model in the loop. The firmware never sees a
measurement finer than its frame's step (the sliding velocity in 1e-9 m/s on the reference); a
noise-free MIL run that does is another trajectory of a chaotic loop, so the comparison's MIL and
its band see the inputs rounded alike (docs/can.md, the SIL results; benchmarks/velocity_resolution.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smartjoint.design.plant.interface import Measurements


@dataclass(frozen=True)
class InputSteps:
    """Per input of the controller interface: the step [unit] and the range each value is held in,
    one entry per joint or sensor (step 0: as measured)."""

    sliding_velocity: tuple[tuple[float, float, float], ...]
    friction_force: tuple[tuple[float, float, float], ...]
    normal_force: tuple[tuple[float, float, float], ...]
    sensors: tuple[tuple[float, float, float], ...]


def bus_steps(databases, artifact) -> InputSteps:
    """The steps and ranges of an artefact's inputs in the frames of ``databases`` (one per bus).

    Parameters
    ----------
    databases : iterable of cantools.database.can.Database
        The buses' frames (a plan's ``BusPlan.database`` each).
    artifact : ControllerArtifact
        Its joint and sensor names.

    Returns
    -------
    InputSteps
        (step, minimum, maximum) per joint for v, u_R, F_N and per sensor for y.
    """
    messages = {m.name: m for db in databases for m in db.messages}

    def row(frame: str, signal: str) -> tuple[float, float, float]:
        s = messages[frame].get_signal_by_name(signal)
        low = -np.inf if s.minimum is None else float(s.minimum)
        return float(s.scale), low, np.inf if s.maximum is None else float(s.maximum)

    joints = [f"JOINT_{name.upper()}" for name in artifact.joint_names]
    return InputSteps(
        tuple(row(frame, "sliding_velocity") for frame in joints),
        tuple(row(frame, "friction_force") for frame in joints),
        tuple(row(frame, "normal_force") for frame in joints),
        tuple(row("TIP_SENSORS", name.lower()) for name in artifact.sensor_names),
    )


def _rounded(values, rows) -> np.ndarray:
    """Each value held within its range, then rounded half to even to its step (0: kept)."""
    out = np.array(values, dtype=float)
    for k, (step, low, high) in enumerate(rows):
        if step:
            out[k] = np.round(min(max(out[k], low), high) / step) * step
    return out


class Rounded:
    """``controller`` (any of the plant interface) seeing its measurements as the bus carries them:
    ``steps`` (:func:`bus_steps`) give each input's step and range."""

    def __init__(self, controller, steps: InputSteps):
        self.controller, self.steps = controller, steps
        self.sample_time = controller.sample_time

    def reset(self) -> None:
        self.controller.reset()

    def step(self, measurements: Measurements):
        s = self.steps
        return self.controller.step(
            Measurements(
                measurements.time,
                _rounded(measurements.sensors, s.sensors),
                _rounded(measurements.sliding_velocity, s.sliding_velocity),
                _rounded(measurements.friction_force, s.friction_force),
                _rounded(measurements.normal_force, s.normal_force),
            )
        )


__all__ = ["InputSteps", "Rounded", "bus_steps"]
