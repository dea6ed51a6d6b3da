"""One closed-loop run of the study (paper Section 6): what every run shares (``StudySetup``,
from the design's ``[control]`` table), the triangular tip pulse, the semi-active, passive and
active runs on the plant loop, and the mean control power each needs.

Protocol: the triangular tip pulse (200 N over 40 ms along every disturbance input), every joint
at F_N^max while it acts, then the controller until t_e; the plant simulated at a plant step that
divides the controller sample time (``design.plant.loop.simulate``); the active LQG on the
frictionless ``linear`` scheme of the same loop. Deterministic: the same inputs give
bit-identical results.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.control.filter import ActiveLqg
from smartjoint.design.control.lqg import LqgDesign, check_sample_time
from smartjoint.design.friction.model import joint_parameters
from smartjoint.design.plant.disturbance import TriangularPulse, triangular_pulse
from smartjoint.design.plant.interface import ConstantNormalForce, Controller, HoldDuringExcitation
from smartjoint.design.plant.loop import SimulationResult, simulate
from smartjoint.design.structure.modal import ModalModel

PULSE_DURATION = 0.04  # s (Section 4.3)
PULSE_AMPLITUDE = 200.0  # N
PLANT_STEPS_PER_SAMPLE = 20  # plant step = Δt/20 (50 µs at 1 ms): within the scheme's accuracy study
SETTLING_FRACTION = 0.1  # settling time: e(t) stays below 10 % of the energy at the end of the pulse


@dataclass(frozen=True)
class StudySetup:
    """What every run of the study shares. ``model``: the reduced design model the controllers
    are designed on; ``plant``: the model simulated (the same reduced model by default)."""

    model: ModalModel
    plant: ModalModel
    laws: list
    sample_time: float
    normal_force_min: np.ndarray
    normal_force_max: np.ndarray
    duration: float  # t_e of Eq. 32
    piezo_capacitance: float
    piezo_force_per_volt: float
    piezo_preload: float
    pulse_amplitude: float = PULSE_AMPLITUDE  # N: the tip pulse's peak (a sweep's uncertain input)
    pulse_direction: float | None = None  # deg in the plane of the first two disturbance inputs; None: all 1
    sensor_noise: np.ndarray | None = None  # added to the tip sensors, one row per controller sample; None: none
    amplifier_lag: float | None = None  # s: the time constant of the piezo amplifiers' first-order lag; None: none
    sample_steps: np.ndarray | None = None  # the plant step of each controller sample (jitter); None: regular

    @property
    def plant_step(self) -> float:
        return self.sample_time / PLANT_STEPS_PER_SAMPLE

    @property
    def plant_steps(self) -> int:
        """The plant steps of a run (``PlantRun.steps``)."""
        return int(round(self.duration / self.plant_step))

    @property
    def samples(self) -> int:
        """The controller samples of a run: the loop's calls, one every ``PLANT_STEPS_PER_SAMPLE``."""
        return -(-self.plant_steps // PLANT_STEPS_PER_SAMPLE)

    def pulse(self) -> TriangularPulse:
        directions = np.ones(self.plant.disturbance_input.shape[1])
        if self.pulse_direction is not None:
            if directions.size < 2:
                raise ModelError(
                    f"pulse_direction: {self.pulse_direction!r} deg — needs two disturbance inputs, the design has "
                    f"{directions.size}"
                )
            # (cos θ / cos 45°, sin θ / sin 45°): the study's (1, 1) exactly at 45°, and the magnitude
            # √2 at every angle (to rounding: cos 45° and sin 45° differ in their last bit).
            angle, diagonal = math.radians(self.pulse_direction), math.radians(45.0)
            directions[:2] = math.cos(angle) / math.cos(diagonal), math.sin(angle) / math.sin(diagonal)
        return triangular_pulse(self.pulse_amplitude, PULSE_DURATION, directions)


@dataclass
class Run:
    """One closed-loop run at the controller samples: e(t) = ½xᵀx, tip sensors, joint forces."""

    name: str
    time: np.ndarray
    energy: np.ndarray
    sensors: np.ndarray
    normal_force: np.ndarray  # semi-active: applied F_N; active: NaN
    joint_force: np.ndarray  # friction u_R (semi-active) or actuator force u_d (active)
    sliding_velocity: np.ndarray
    control_power: float  # mean over [0, t_e] [W]
    power_kind: str  # "piezo charging" or "actuator mechanical"
    metrics: dict = field(default_factory=dict)

    def energy_measure(self) -> float:
        """Eq. 32: E(t_e) = ∫₀^t_e xᵀx dt (trapezoid on the sample grid)."""
        return float(np.trapezoid(2.0 * self.energy, self.time))


def setup(design, model: ModalModel, plant: ModalModel | None = None) -> StudySetup:
    """What every run of the study shares, from the design's ``[control]`` table.

    Parameters
    ----------
    design : Design
        The design; its joints' friction laws and normal-force limits.
    model : ModalModel
        The reduced model the controllers are designed on.
    plant : ModalModel, optional
        The model simulated; ``model`` when not given.

    Returns
    -------
    StudySetup
    """
    c = design.control
    count = len(design.joints)
    low = np.array(np.broadcast_to(np.asarray(c.normal_force_min, dtype=float), (count,)))
    high = np.array(np.broadcast_to(np.asarray(c.normal_force_max, dtype=float), (count,)))
    if not (c.study_duration > PULSE_DURATION):
        raise ModelError(f"control.study_duration: {c.study_duration!r} s — must exceed the pulse ({PULSE_DURATION} s)")
    check_sample_time(model, c.sample_time)
    return StudySetup(
        model,
        plant if plant is not None else model,
        joint_parameters(design),
        float(c.sample_time),
        low,
        high,
        float(c.study_duration),
        float(c.piezo_capacitance),
        float(c.piezo_force_per_volt),
        float(c.piezo_preload),
        pulse_amplitude=float(c.pulse_amplitude),
    )


# ---------------------------------------------------------------------------------------- runs
def piezo_power(s: StudySetup, normal_force: np.ndarray) -> float:
    """Mean electrical power to charge the stacks, V = (F_N − preload)/k per joint, starting
    from 0 V before t = 0: ½C·max(0, V_k² − V_k−1²) per sample (no charge recovered).

    Parameters
    ----------
    s : StudySetup
        The piezo capacitance, force per volt, preload and the study's duration t_e.
    normal_force : ndarray
        F_N [N] at the controller samples, one column per joint.

    Returns
    -------
    float
        The mean power over [0, t_e] [W].
    """
    volts = np.maximum(normal_force - s.piezo_preload, 0.0) / s.piezo_force_per_volt
    squared = np.vstack([np.zeros((1, volts.shape[1])), volts]) ** 2
    charge = 0.5 * s.piezo_capacitance * np.maximum(np.diff(squared, axis=0), 0.0)
    return float(charge.sum() / s.duration)


def run_semi_active(s: StudySetup, name: str, controller) -> Run:
    """Any normal-force controller, F_N^max during the pulse (Section 6).

    Parameters
    ----------
    s : StudySetup
        The study's plant, laws, limits and timing.
    name : str
        The run's name in the tables.
    controller : Controller
        The normal-force law after the pulse (``design.plant.interface.Controller``).

    Returns
    -------
    Run
        The run at the controller samples with its mean piezo charging power.
    """
    return semi_active_run(s, name, simulate_semi_active(s, controller))


def simulate_semi_active(s: StudySetup, controller, energy_books: bool = False):
    """The plant under any normal-force controller as :func:`run_semi_active` runs it: F_N^max
    during the pulse, the study's sensor noise and amplifier lag where it has them.

    Parameters
    ----------
    s : StudySetup
        The study's plant, laws, limits and timing.
    controller : Controller
        The normal-force law after the pulse (``design.plant.interface.Controller``).
    energy_books : bool
        Keep the plant's energy books (W_in, W_joints, W_damping; ``design.plant.loop``).

    Returns
    -------
    SimulationResult
        What ``plant.simulate`` returned, at the controller samples.
    """
    if s.sensor_noise is not None:
        controller = NoisySensors(controller, s.sensor_noise)
    held: Controller = HoldDuringExcitation(controller, PULSE_DURATION, s.normal_force_max)
    if s.amplifier_lag is not None:
        held = LaggingAmplifiers(held, s.amplifier_lag)
    return simulate(
        s.plant,
        s.laws,
        held,
        s.pulse(),
        s.duration,
        s.plant_step,
        record_every=PLANT_STEPS_PER_SAMPLE,
        energy_books=energy_books,
        sample_steps=s.sample_steps,
    )


class NoisySensors:
    """A controller that reads the tip sensors with ``noise[k]`` added at its k-th sample (the
    same additions the compiled loop makes, so both see the same numbers)."""

    def __init__(self, inner, noise: np.ndarray):
        self.inner, self.noise, self.sample_time, self.sample = (
            inner,
            np.asarray(noise, dtype=float),
            inner.sample_time,
            0,
        )

    @property
    def status(self):
        return getattr(self.inner, "status", 0)

    def reset(self) -> None:
        self.inner.reset()
        self.sample = 0

    def step(self, measurements):
        noisy = dataclasses.replace(measurements, sensors=measurements.sensors + self.noise[self.sample])
        self.sample += 1
        return self.inner.step(noisy)


class LaggingAmplifiers:
    """The piezo amplifiers as a first-order lag of time constant τ on the commanded normal force,
    held over each sample: F_k = F_k−1 + α·(F_cmd,k − F_k−1), α = 1 − e^(−Δt/τ) (the step response
    of the lag sampled at the controller's rate), starting at the first command. The law reads
    the applied (lagging) force, as it would from the amplifier. The compiled loop computes the
    same numbers in the same order."""

    def __init__(self, inner, time_constant: float):
        if not (math.isfinite(time_constant) and time_constant > 0):
            raise ModelError(f"amplifier_lag: {time_constant!r} s — must be a positive number of seconds")
        self.inner, self.sample_time = inner, inner.sample_time
        self.gain = self.gain_of(self.sample_time, time_constant)
        self.applied: np.ndarray | None = None

    @staticmethod
    def gain_of(sample_time: float, time_constant: float) -> float:
        """α = 1 − e^(−Δt/τ), accurate for τ ≫ Δt too (the compiled loop takes the same number)."""
        return -math.expm1(-sample_time / time_constant)

    def reset(self) -> None:
        self.inner.reset()
        self.applied = None

    def step(self, measurements) -> np.ndarray:
        command = np.asarray(self.inner.step(measurements), dtype=float)
        if self.applied is None:
            self.applied = command.copy()
        else:
            self.applied = self.applied + self.gain * (command - self.applied)
        return self.applied.copy()


class DelayedCommand:
    """A normal-force law whose command acts one sample late: at sample k it returns the command
    of sample k − 1 (``first`` at sample 0), the law itself stepping on every sample's measurements.
    The loop a master that steps every FMU before it passes outputs on runs (libcosim,
    ``bench.libcosim_master``); the Python loop only, the compiled one has no delay.

    Parameters
    ----------
    inner : Controller
        The law (``design.plant.interface.Controller``).
    first : array_like
        The command before the law's first (F_N^max: the study holds it during the pulse anyway).
    """

    def __init__(self, inner, first):
        self.inner, self.first, self.sample_time = inner, np.asarray(first, dtype=float), inner.sample_time
        self.previous: np.ndarray | None = None

    @property
    def status(self):
        return getattr(self.inner, "status", 0)

    def reset(self) -> None:
        self.inner.reset()
        self.previous = None

    def step(self, measurements) -> np.ndarray:
        now = np.asarray(self.inner.step(measurements), dtype=float)
        out = self.first.copy() if self.previous is None else self.previous
        self.previous = now.copy()
        return out


def semi_active_run(s: StudySetup, name: str, r: SimulationResult) -> Run:
    """The :class:`Run` of a normal-force law from its simulation (recorded every sample), with
    its mean piezo charging power.

    Parameters
    ----------
    s : StudySetup
    name : str
    r : SimulationResult

    Returns
    -------
    Run
    """
    return Run(
        name,
        r.time,
        r.energy,
        r.sensors,
        r.normal_force,
        r.friction_force,
        r.sliding_velocity,
        piezo_power(s, r.normal_force),
        "piezo charging",
    )


def run_passive(s: StudySetup, name: str, normal_forces) -> Run:
    """:func:`run_semi_active` with constant normal forces.

    Parameters
    ----------
    s : StudySetup
    name : str
    normal_forces : array_like
        F_N [N], one per joint (or one for all).

    Returns
    -------
    Run
    """
    return run_semi_active(s, name, ConstantNormalForce(np.asarray(normal_forces, dtype=float), s.sample_time))


def run_active(s: StudySetup, design: LqgDesign) -> Run:
    """The fully active reference: u_d = −K·x̂ as forces on the linear model (the plant's
    frictionless ``linear`` scheme at the sample time, zero force during the pulse); mean
    mechanical actuator power Σ|u_d·v| on the sample grid.

    Parameters
    ----------
    s : StudySetup
        The study; its plant must be its design model.
    design : LqgDesign
        The LQR and Kalman gains.

    Returns
    -------
    Run
        Named "active LQG"; its normal force is NaN, its joint force the actuators' u_d.
    """
    if s.plant is not s.model:
        raise ModelError("the active LQG reference runs on the design model only")
    controller = ActiveLqg(design, hold_until=PULSE_DURATION)
    r = simulate(s.model, [], controller, s.pulse(), s.duration, s.sample_time, energy_books=False, scheme="linear")
    force = r.friction_force  # the linear scheme records the joint forces acting: the actuators'
    power = float(np.sum(np.abs(force * r.sliding_velocity)[:-1]) * s.sample_time / s.duration)
    return Run(
        "active LQG",
        r.time,
        r.energy,
        r.sensors,
        np.full_like(force, np.nan),
        force,
        r.sliding_velocity,
        power,
        "actuator mechanical",
    )


__all__ = [
    "PLANT_STEPS_PER_SAMPLE",
    "DelayedCommand",
    "LaggingAmplifiers",
    "NoisySensors",
    "PULSE_AMPLITUDE",
    "PULSE_DURATION",
    "SETTLING_FRACTION",
    "Run",
    "StudySetup",
    "piezo_power",
    "run_active",
    "run_passive",
    "run_semi_active",
    "simulate_semi_active",
    "semi_active_run",
    "setup",
]
