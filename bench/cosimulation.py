"""Co-simulation of the plant FMU and a controller FMU in FMPy: the study, FMU to FMU.

A small fixed-step master (:func:`cosimulate`) runs the study of ``design.control.runs`` with the
two FMUs ``smartjoint fmu`` writes, in the order the model-in-the-loop study takes its steps, so
that the result is that study's trajectory number for number:

at every controller sample t_k (the communication points, one sample time apart)
  1. the plant's outputs at t_k are the controller's inputs (connected by name:
     ``TIP_SENSORS.*``, ``JOINT_*.friction_force``, ``.normal_force``, ``.sliding_velocity``);
  2. the controller's outputs at t_k are its law's step from them (direct feedthrough, as the
     firmware answers the sample's measurements); ``SETPOINT_*.normal_force`` holds F_N^max while
     the pulse acts (the study's protocol, ``HoldDuringExcitation``), then the command;
  3. the plant takes the normal forces (they act at once), and its outputs are the row the
     study records at t_k; both FMUs step to t_k+1.

A set-up's sensor noise and amplifier lag (the ensembles' uncertain inputs) are the master's:
added to the sensors the controller reads, applied to the commands, as the study's loop does.

:class:`FmuInstance` is the FMPy side of one FMU, FMI 2 and FMI 3 alike, with its log messages
kept (``messages``) for the reports and tests.
"""

from __future__ import annotations

import shutil
import tempfile
from ctypes import byref

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.control import runs
from smartjoint.design.control.runs import Run, StudySetup
from smartjoint.design.plant.loop import SimulationResult

STATUS = "CONTROLLER_STATUS.step_status"


class FmuInstance:
    """One co-simulation FMU loaded and instantiated in FMPy (FMI 2 or 3).

    Parameters
    ----------
    path : path-like
        The ``.fmu``.
    name : str
        The instance's name.
    logging : bool
        Debug logging on (errors and warnings are logged either way).
    """

    def __init__(self, path, name: str = "instance", logging: bool = False):
        import fmpy

        self.description = fmpy.read_model_description(str(path))
        self.version = int(self.description.fmiVersion[0])
        self.variables = {v.name: v for v in self.description.modelVariables}
        self.messages: list[tuple[int, str]] = []
        self.folder = tempfile.mkdtemp(prefix="smartjoint-fmu-")
        try:
            self._load(str(path), name, logging)
        except BaseException:
            shutil.rmtree(self.folder, ignore_errors=True)
            raise

    def _load(self, path: str, name: str, logging: bool) -> None:
        import fmpy

        fmpy.extract(path, unzipdir=self.folder)
        arguments = dict(
            guid=self.description.guid,
            unzipDirectory=self.folder,
            modelIdentifier=self.description.coSimulation.modelIdentifier,
            instanceName=name,
        )
        if self.version == 2:
            from fmpy import calloc, free
            from fmpy.fmi2 import (
                FMU2Slave,
                fmi2CallbackAllocateMemoryTYPE,
                fmi2CallbackFreeMemoryTYPE,
                fmi2CallbackFunctions,
                fmi2CallbackLoggerTYPE,
            )
            from fmpy.logging import addLoggerProxy

            self.fmu = FMU2Slave(**arguments)
            callbacks = self._callbacks = fmi2CallbackFunctions()
            callbacks.logger = fmi2CallbackLoggerTYPE(lambda env, who, status, category, text: self._log(status, text))
            callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
            callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
            addLoggerProxy(byref(callbacks))  # formats the printf-style message in C
            self.fmu.instantiate(callbacks=callbacks, loggingOn=logging)
        else:
            from fmpy.fmi3 import FMU3Slave

            self.fmu = FMU3Slave(**arguments)
            self.fmu.instantiate(
                loggingOn=logging, logMessage=lambda env, status, category, text: self._log(status, text)
            )

    def _log(self, status: int, text: bytes) -> None:
        self.messages.append((int(status), text.decode("utf-8", "replace") if isinstance(text, bytes) else str(text)))

    def references(self, names) -> list[int]:
        """The value references of ``names``; a name the FMU does not have is refused in one line."""
        missing = [n for n in names if n not in self.variables]
        if missing:
            raise ModelError(f"{missing[0]}: not a variable of {self.description.modelName}")
        return [self.variables[n].valueReference for n in names]

    def initialize(self, start_time: float = 0.0, parameters: dict | None = None) -> None:
        """Enter and leave initialization mode, setting ``parameters`` (name → value) in it."""
        if self.version == 2:
            self.fmu.setupExperiment(startTime=start_time)
            self.fmu.enterInitializationMode()
        else:
            self.fmu.enterInitializationMode(startTime=start_time)
        if parameters:
            self.set_real(self.references(list(parameters)), list(parameters.values()))
        self.fmu.exitInitializationMode()

    def get_real(self, references) -> np.ndarray:
        values = self.fmu.getReal(references) if self.version == 2 else self.fmu.getFloat64(references)
        return np.asarray(values, dtype=float)

    def set_real(self, references, values) -> None:
        values = [float(v) for v in values]
        if self.version == 2:
            self.fmu.setReal(references, values)
        else:
            self.fmu.setFloat64(references, values)

    def get_integer(self, references) -> list[int]:
        return list(self.fmu.getInteger(references) if self.version == 2 else self.fmu.getInt32(references))

    def step(self, time: float, step: float) -> None:
        self.fmu.doStep(time, step)

    def close(self) -> None:
        """Terminate (where allowed), free the instance and remove the unpacked FMU."""
        try:
            self.fmu.terminate()
        except Exception:  # noqa: BLE001 - an instance in the error state cannot terminate; free it anyway
            pass
        try:
            self.fmu.freeInstance()
        finally:
            shutil.rmtree(self.folder, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def cosimulate(s: StudySetup, plant_path, controller_path, name: str) -> tuple[Run, int]:
    """One semi-active run of the study, co-simulated: the plant FMU and a controller FMU.

    Parameters
    ----------
    s : StudySetup
        The study the FMUs were written for (its duration, sample time, pulse hold).
    plant_path, controller_path : path-like
        The FMUs (``smartjoint fmu``), FMI 2 or 3 each.
    name : str
        The run's name ("SISO", "cLQG").

    Returns
    -------
    tuple of (Run, int)
        The run at the controller samples, as ``runs.run_semi_active`` gives it, and the number of
        samples whose step status was not 0.

    Raises
    ------
    ModelError
        A jittered schedule (the controller FMU's step is its sample time), FMUs that do not
        connect, or a command the plant cannot take, in one line.

    Notes
    -----
    The set-up's sensor noise is added to the tip sensors the controller reads, and its amplifier
    lag applied to the commands (``runs.NoisySensors``, ``runs.LaggingAmplifiers``), in the
    master, as the study's loop does.
    """
    if s.sample_steps is not None:
        raise ModelError("sample_steps: the controller FMU steps at its sample time only (no jitter)")
    with FmuInstance(plant_path, "plant") as plant, FmuInstance(controller_path, "controller") as controller:
        return _run(s, plant, controller, name)


def _connections(plant: FmuInstance, controller: FmuInstance, joints: list[str]):
    """Value references: the controller's inputs from the plant's outputs of the same names, the
    commands into the plant, and the plant's row (sensors, v, u_R, F_N, e)."""
    inputs = [v.name for v in controller.description.modelVariables if v.causality == "input"]
    unknown = [n for n in inputs if n not in plant.variables or plant.variables[n].causality != "output"]
    if unknown:
        raise ModelError(f"{unknown[0]}: the controller reads it, the plant FMU has no such output")
    commands = [f"SETPOINT_{j}.normal_force" for j in joints]
    sensors = [v.name for v in plant.description.modelVariables if v.name.startswith("TIP_SENSORS.")]
    row = {
        "sensors": plant.references(sensors),
        "sliding_velocity": plant.references([f"JOINT_{j}.sliding_velocity" for j in joints]),
        "friction_force": plant.references([f"JOINT_{j}.friction_force" for j in joints]),
        "normal_force": plant.references([f"JOINT_{j}.normal_force" for j in joints]),
        "energy": plant.references(["energy"]),
    }
    return (
        plant.references(inputs),
        controller.references(inputs),
        controller.references(commands),
        plant.references(commands),
        row,
    )


def _noise_columns(s: StudySetup, controller: FmuInstance):
    """Where the set-up's sensor noise goes: the positions of the tip sensors among the
    controller's inputs, their columns of ``sensor_noise`` and the noise (None without noise)."""
    if s.sensor_noise is None:
        return None
    inputs = [v.name for v in controller.description.modelVariables if v.causality == "input"]
    sensors = list(s.plant.sensor_names)
    slots = [k for k, n in enumerate(inputs) if n.startswith("TIP_SENSORS.")]
    rows = np.asarray(s.sensor_noise).shape[0]
    if rows < s.samples:
        raise ModelError(f"sensor_noise: {rows} rows — need {s.samples} (one per controller sample)")
    columns = np.array([sensors.index(inputs[k].split(".", 1)[1]) for k in slots], dtype=int)
    return np.array(slots, dtype=int), columns, np.asarray(s.sensor_noise, dtype=float)


def _run(s: StudySetup, plant: FmuInstance, controller: FmuInstance, name: str) -> tuple[Run, int]:
    joints = list(s.plant.joint_names)
    measured, fed, commanded, applied, row_references = _connections(plant, controller, joints)
    status = controller.references([STATUS])
    plant.initialize()
    controller.initialize()
    steps, ratio, h = s.plant_steps, runs.PLANT_STEPS_PER_SAMPLE, s.plant_step
    rows: dict[str, list] = {key: [] for key in row_references}
    hold = np.asarray(s.normal_force_max, dtype=float)
    noise = _noise_columns(s, controller)
    gain = None if s.amplifier_lag is None else runs.LaggingAmplifiers.gain_of(s.sample_time, s.amplifier_lag)
    lagged = None  # the amplifiers' output (with a lag)
    safe = 0

    def record() -> None:
        for key, references in row_references.items():
            rows[key].append(plant.get_real(references))

    for sample, first in enumerate(range(0, steps, ratio)):
        time = first * h
        values = plant.get_real(measured)
        if noise is not None:
            slots, columns, table = noise
            values[slots] = values[slots] + table[sample, columns]
        controller.set_real(fed, values)
        command = controller.get_real(commanded)
        safe += int(controller.get_integer(status)[0] != 0)
        command = hold if time < runs.PULSE_DURATION - 1e-12 else command
        if gain is not None:
            lagged = command.copy() if lagged is None else lagged + gain * (command - lagged)
            command = lagged.copy()
        if not np.all(np.isfinite(command) & (command >= 0.0)):
            raise ModelError(f"controller returned normal forces that are not all finite and >= 0 at t = {time:.6g} s")
        plant.set_real(applied, command)
        record()
        controller.step(time, s.sample_time)
        plant.step(time, (min(first + ratio, steps) - first) * h)
    if steps % ratio == 0:
        record()
    array = {key: np.array(values) for key, values in rows.items()}
    unknown = np.full(array["energy"].shape[0], np.nan)  # the works are not outputs of the plant FMU
    result = SimulationResult(
        np.arange(array["energy"].shape[0]) * h * ratio,
        array["sensors"],
        array["sliding_velocity"],
        array["friction_force"],
        array["normal_force"],
        np.full_like(array["normal_force"], np.nan),  # nor the bristle deflection
        array["energy"][:, 0],
        unknown,
        unknown,
        unknown,
        joints,
        list(s.plant.sensor_names),
    )
    return runs.semi_active_run(s, name, result), safe


__all__ = ["STATUS", "FmuInstance", "cosimulate"]
