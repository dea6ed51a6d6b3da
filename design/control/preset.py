"""The preset normal force: a fixed F_N per joint that the operator sets, the fall-back a bench
selects when a feedback law is not wanted (the passive joints of paper Section 6, as a law of the
firmware: its mode, its CAN frames, its safe state).

    F_N,k = clip(F_N^preset, F_N^min, F_N^max)           per joint, every sample

Its one setting, ``preset_force`` in ``[control]`` (default F_N^max: locked joints, the
stiffest truss), is the artefact's ``laws.preset.force`` and the FMU's tunable. The step
reads the measured normal force only to check it: an unusable one (NaN/±Inf, or outside
[measured_normal_force_min, measured_normal_force_max]) puts every joint at the safe normal force,
as every law does (docs/safety.md).

The preset entry of the law registry names this module: its Python reference (:func:`preset_law`),
the law the study runs (:func:`controller`) and what its templates see (:func:`context`).
"""

from __future__ import annotations

import numpy as np

from smartjoint.design.control.laws import (
    STATUS_OK,
    any_status,
    check_limits,
    input_status,
    measured_range,
    safe_force,
    safe_state_options,
)
from smartjoint.design.plant.interface import Measurements


class PresetLaw:
    """The preset normal force per joint, clipped to [F_N^min, F_N^max] (``reset()``,
    ``step(measurements) -> normal_forces``, ``sample_time``: ``interface.Controller``).

    Without the safety arguments: safe force F_N^max, a measured F_N plausible when finite.
    """

    def __init__(
        self,
        sample_time: float,
        normal_force_min,
        normal_force_max,
        normal_force,
        *,
        safe_normal_force=None,
        friction_force_limit=None,
        measured_normal_force_min=None,
        measured_normal_force_max=None,
    ):
        del friction_force_limit  # the law reads no friction force
        self.sample_time = float(sample_time)
        self.normal_force_min = np.array(normal_force_min, dtype=float)
        self.normal_force_max = np.array(normal_force_max, dtype=float)
        check_limits(self.normal_force_min, self.normal_force_max)
        count = self.normal_force_min.size
        preset = np.array(np.broadcast_to(np.asarray(normal_force, dtype=float), (count,)))
        # The C's arithmetic: the upper limit as F^min + (F^max − F^min), as its tables hold it.
        high = self.normal_force_min + (self.normal_force_max - self.normal_force_min)
        self.command = np.minimum(np.maximum(preset, self.normal_force_min), high)
        self.safe_normal_force = safe_force(safe_normal_force, self.normal_force_min, self.normal_force_max)
        self.measured_normal_force_min, self.measured_normal_force_max = measured_range(
            measured_normal_force_min, measured_normal_force_max, count
        )
        self.reset()

    def reset(self) -> None:
        self.status = STATUS_OK

    def step(self, measurements: Measurements) -> np.ndarray:
        applied = np.asarray(measurements.normal_force, dtype=float)
        self.status = any_status(input_status(applied, self.measured_normal_force_min, self.measured_normal_force_max))
        return (self.safe_normal_force if self.status != STATUS_OK else self.command).copy()


def preset_law(artifact) -> PresetLaw:
    """The preset law's Python reference from a controller artefact alone, with its safe normal
    force and plausibility ranges (what the generated C checks).

    Parameters
    ----------
    artifact : ControllerArtifact

    Returns
    -------
    PresetLaw
    """
    return PresetLaw(
        artifact.sample_time,
        artifact.normal_force_min,
        artifact.normal_force_max,
        artifact.preset_force,
        **safe_state_options(artifact),
    )


def controller(setup, lqg, settings: dict) -> PresetLaw:
    """The preset law the closed-loop study runs: its limits and the tuned preset force."""
    del lqg
    return PresetLaw(setup.sample_time, setup.normal_force_min, setup.normal_force_max, settings["force"])


def context(artifact, lit, row) -> dict:
    """What the preset law's templates see beyond the common context: the preset force per joint."""
    del lit
    return {"preset_force": row(artifact.preset_force)}


__all__ = ["PresetLaw", "context", "controller", "preset_law"]
