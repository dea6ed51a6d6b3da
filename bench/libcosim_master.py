"""The study co-simulated in libcosim (Open Simulation Platform, through libcosimpy): a master
that steps every FMU and then passes outputs on, unlike FMPy's loop (``bench.cosimulation``),
which sets the controller's inputs before it reads its outputs (docs/fmu.md).

libcosim's fixed-step algorithm steps all FMUs of a communication step in parallel, then copies
each output it cached after the step into the connected inputs. A command therefore reaches the
plant one step after the measurements it answers: no FMU can close a loop without delay there.
The controller FMU's ``held`` variant (``codegen.fmu``, ``exchange="held"``) makes that timing
exact and its own: its outputs are the law's step from the inputs of its last step, held until the
next, so the command of the measurements at t_k acts on [t_k+1, t_k+2]. The model-in-the-loop
study with ``runs.DelayedCommand`` around the law is the same loop, number for number.

The study's protocol (F_N^max while the pulse acts) is an override manipulator on the plant's
normal-force inputs, lifted at the first sample after the pulse.
"""

from __future__ import annotations

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.control import runs
from smartjoint.design.plant.loop import SimulationResult


def _references(execution, index: int) -> dict[str, tuple[int, int]]:
    """A slave's variables: name → (value reference, causality as libcosim numbers it)."""
    return {v.name.decode(): (v.reference, v.causality) for v in execution.slave_variables(index)}


def cosimulate(s: runs.StudySetup, plant_path, controller_path, name: str) -> runs.Run:
    """One semi-active run of the study in libcosim: the plant FMU and a controller FMU (FMI 2).

    Parameters
    ----------
    s : StudySetup
        The study the FMUs were written for (duration, sample time, pulse hold); no sensor noise
        or amplifier lag (libcosim would need them as FMUs of their own).
    plant_path, controller_path : path-like
        The FMUs; the controller best in its ``held`` variant (module text).
    name : str
        The run's name ("SISO", "cLQG").

    Returns
    -------
    Run
        The run at the controller samples, as ``runs.semi_active_run`` makes it.
    """
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    if s.sensor_noise is not None or s.amplifier_lag is not None or s.sample_steps is not None:
        raise ModelError("libcosim: the study's sensor noise, amplifier lag and jitter are FMPy's loop only")
    log_output_level(CosimLogLevel.ERROR)  # FMI Library's start-value complaint on `time` is its own bug
    execution = CosimExecution.from_step_size(int(round(s.sample_time * 1e9)))  # nanoseconds
    plant = execution.add_local_slave(CosimLocalSlave(fmu_path=str(plant_path), instance_name="plant"))
    controller = execution.add_local_slave(CosimLocalSlave(fmu_path=str(controller_path), instance_name="controller"))
    pv, cv = _references(execution, plant), _references(execution, controller)
    for variable, (reference, causality) in cv.items():
        if causality == 0:  # an input of the controller: the plant's output of that name
            if variable not in pv:
                raise ModelError(f"{variable}: the controller reads it, the plant FMU has no such output")
            execution.connect_real_variables(plant, pv[variable][0], controller, reference)
    joints = list(s.plant.joint_names)
    commands = [f"SETPOINT_{j}.normal_force" for j in joints]
    for command in commands:
        execution.connect_real_variables(controller, cv[command][0], plant, pv[command][0])
    hold = CosimManipulator.create_override()
    execution.add_manipulator(hold)
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    applied = [pv[c][0] for c in commands]
    hold.slave_real_values(plant, applied, [float(f) for f in s.normal_force_max])
    return _run(s, execution, observer, hold, plant, pv, applied, name)


def _run(s, execution, observer, hold, plant, pv, applied, name) -> runs.Run:
    from libcosimpy.CosimEnums import CosimVariableType

    joints = list(s.plant.joint_names)
    sensors = [n for n in pv if n.startswith("TIP_SENSORS.")]
    row = {
        "sensors": [pv[n][0] for n in sensors],
        "sliding_velocity": [pv[f"JOINT_{j}.sliding_velocity"][0] for j in joints],
        "friction_force": [pv[f"JOINT_{j}.friction_force"][0] for j in joints],
        "normal_force": [pv[f"JOINT_{j}.normal_force"][0] for j in joints],
        "energy": [pv["energy"][0]],
    }
    # After libcosim's step k the observer sees the plant at t_k+1, with the normal force it applied
    # over [t_k, t_k+1]: the row of sample k+1, but the normal force of sample k (the study records
    # the force applied from each sample on, and at t_e the last one again). At t = 0 the plant's
    # initial outputs: it starts at rest (zero), which libcosim's observer cannot show before a step.
    rows: dict[str, list] = {key: [[0.0] * len(references)] for key, references in row.items() if key != "normal_force"}
    rows["normal_force"] = []
    samples = int(round(s.duration / s.sample_time))
    held = True
    for k in range(samples):
        if held and k * s.sample_time >= runs.PULSE_DURATION - 1e-12:
            hold.reset_variables(plant, CosimVariableType.REAL, applied)  # the controller's command from here
            held = False
        if not execution.step():
            raise ModelError(f"libcosim: step {k} (t = {k * s.sample_time:.6g} s) failed")
        rows["normal_force"].append(observer.last_real_values(plant, row["normal_force"]))
        for key, references in row.items():
            if key != "normal_force":
                rows[key].append(observer.last_real_values(plant, references))
    rows["normal_force"].append(rows["normal_force"][-1])
    array = {key: np.array(values, dtype=float) for key, values in rows.items()}
    time = np.arange(samples + 1) * s.plant_step * runs.PLANT_STEPS_PER_SAMPLE  # as the study records it
    unknown = np.full(samples + 1, np.nan)
    result = SimulationResult(time, array["sensors"], array["sliding_velocity"], array["friction_force"],
                              array["normal_force"], np.full_like(array["normal_force"], np.nan), array["energy"][:, 0],
                              unknown, unknown, unknown, joints, list(s.plant.sensor_names))  # fmt: skip
    return runs.semi_active_run(s, name, result)


__all__ = ["cosimulate"]
