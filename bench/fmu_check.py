"""The FMUs of a design checked against the project's own simulation (``smartjoint run``'s FMU stage).

* :func:`replay`: a controller FMU driven through FMPy with exactly the measurements the Python
  reference controller saw in the study (``backtoback.Recorder``); its normal forces against the
  reference's, sample by sample (double build: bit for bit; float build: within the documented
  bound, 1e-3 of the normal-force span).
* :func:`constant_force_run`: the plant FMU alone under constant normal forces, against the
  project's plant simulation (``design.plant.loop.simulate``, same scheme and step).
* :func:`fmu_study`: all of it for one design — both laws' controller FMUs and the plant FMU,
  FMI 2 and 3, validated by ``fmpy.validation.validate_fmu``, co-simulated
  (``bench.cosimulation``) against the model-in-the-loop runs of the study, with the paper's
  orderings on the co-simulated runs.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from smartjoint.bench.cosimulation import STATUS, FmuInstance, cosimulate
from smartjoint.codegen import fmu
from smartjoint.common import law_registry
from smartjoint.design.control import runs as study_runs
from smartjoint.design.control import study as closed_loop
from smartjoint.design.plant.interface import ConstantNormalForce
from smartjoint.design.plant.loop import simulate

FLOAT_BOUND = 1e-3  # |ΔF_N| of the float build per sample, as a fraction of F^max − F^min (docs/codegen.md)
# The study's run name of every law of the registry → (its name, its Python reference).
LAWS = {law.display: (law.name, law.python_reference) for law in law_registry.LAWS.values()}


def recorded_inputs(setup, artifact, name: str) -> list:
    """(measurements, normal forces) of every sample the Python reference law of ``name`` took in
    the study (``backtoback.Recorder`` around it)."""
    from smartjoint.codegen.backtoback import Recorder

    recorder = Recorder(LAWS[name][1](artifact))
    closed_loop.run_semi_active(setup, name, recorder)
    return recorder.log


def replay(path, log: list) -> tuple[np.ndarray, list[int]]:
    """A controller FMU fed with recorded measurements, one communication step per sample.

    Parameters
    ----------
    path : path-like
        The controller FMU.
    log : list of (Measurements, ndarray)
        What :func:`recorded_inputs` gives.

    Returns
    -------
    tuple of (ndarray, list of int)
        The commanded normal forces (samples × joints) and the step status per sample.
    """
    with FmuInstance(path, "replay") as controller:
        outputs = [v for v in controller.description.modelVariables if v.name.endswith(".normal_force")]
        joints = [v.name.split(".")[0][len("SETPOINT_") :] for v in outputs if v.name.startswith("SETPOINT_")]
        inputs = [v.name for v in controller.description.modelVariables if v.causality == "input"]
        references = controller.references(inputs)
        commands = controller.references([f"SETPOINT_{j}.normal_force" for j in joints])
        status = controller.references([STATUS])
        controller.initialize()
        step = float(controller.description.defaultExperiment.stepSize)  # the sample time
        forces, statuses = [], []
        for k, (m, _) in enumerate(log):
            controller.set_real(references, input_values(inputs, joints, m))
            forces.append(controller.get_real(commands))
            statuses.append(controller.get_integer(status)[0])
            controller.step(k * step, step)
        return np.array(forces), statuses


def input_values(names: list[str], joints: list[str], m) -> list[float]:
    """A controller FMU's input values (its input ``names`` in order) from one sample's measurements
    ``m``; ``joints`` in the measurements' order."""
    index = {j: k for k, j in enumerate(joints)}
    sensors = [n for n in names if n.startswith("TIP_SENSORS.")]
    values = []
    for name in names:
        part, quantity = name.split(".", 1)
        if part == "TIP_SENSORS":
            values.append(float(m.sensors[sensors.index(name)]))
        else:
            values.append(float(getattr(m, quantity)[index[part[len("JOINT_") :]]]))
    return values


def constant_force_run(setup, plant_path, normal_forces) -> dict:
    """The plant FMU under constant normal forces from t = 0 (set once; the pulse as in the study),
    beside the project's plant simulation with the same forces.

    Parameters
    ----------
    setup : StudySetup
    plant_path : path-like
    normal_forces : array_like
        F_N per joint [N].

    Returns
    -------
    dict
        ``fmu`` and ``simulation``: energy and sensors at every sample; ``max_energy_difference``
        relative to the peak energy, ``identical`` (every number equal).
    """
    forces = np.asarray(normal_forces, dtype=float)
    reference = simulate(
        setup.plant, setup.laws, ConstantNormalForce(forces, setup.sample_time), setup.pulse(), setup.duration,
        setup.plant_step, record_every=study_runs.PLANT_STEPS_PER_SAMPLE, backend="c", energy_books=False,
    )  # fmt: skip
    joints = list(setup.plant.joint_names)
    with FmuInstance(plant_path, "plant") as plant:
        energy_ref = plant.references(["energy"])
        sensor_refs = plant.references([f"TIP_SENSORS.{n}" for n in setup.plant.sensor_names])
        commands = plant.references([f"SETPOINT_{j}.normal_force" for j in joints])
        plant.initialize()
        energy, sensors = [], []
        h, ratio, steps = setup.plant_step, study_runs.PLANT_STEPS_PER_SAMPLE, setup.plant_steps
        plant.set_real(commands, forces)  # once: the forces act from t = 0 on, as in the simulation
        for first in range(0, steps, ratio):
            energy.append(plant.get_real(energy_ref)[0])
            sensors.append(plant.get_real(sensor_refs))
            plant.step(first * h, (min(first + ratio, steps) - first) * h)
        if steps % ratio == 0:
            energy.append(plant.get_real(energy_ref)[0])
            sensors.append(plant.get_real(sensor_refs))
    got = {"energy": np.array(energy), "sensors": np.array(sensors)}
    want = {"energy": reference.energy, "sensors": reference.sensors}
    same_shape = all(got[k].shape == want[k].shape for k in got)
    return {
        "fmu": got,
        "simulation": want,
        "identical": same_shape and all(np.array_equal(got[k], want[k]) for k in got),
        "max_energy_difference": float(np.max(np.abs(got["energy"] - want["energy"])) / np.max(want["energy"]))
        if same_shape
        else float("inf"),
    }


def fmu_study(study, design, artifact, folder: Path, progress=print) -> dict:
    """Write the design's FMUs into ``folder`` and check them against the study.

    Parameters
    ----------
    study : Study
        The closed-loop study (its set-up and its model-in-the-loop runs).
    design : Design
        The design the study was made from.
    artifact : ControllerArtifact
        The controller artefact of the study.
    folder : Path
        Where ``fmi2/`` and ``fmi3/`` with ``truss.fmu``, ``siso.fmu``, ``clqg.fmu`` (double build)
        and ``siso_float.fmu``, ``clqg_float.fmu`` go.
    progress : callable

    Returns
    -------
    dict
        Per FMI version: the FMUs written with their validation problems; per law the replay
        (bit-identical samples, float deviation) and the co-simulation against MIL (identical,
        largest difference of e(t)); the paper's orderings on the co-simulated runs; ``runs``:
        per law the co-simulated and the MIL run (of the last FMI version).
    """
    from fmpy.validation import validate_fmu

    setup = study.setup
    logs = {name: recorded_inputs(setup, artifact, name) for name in LAWS}
    span = float(np.min(np.asarray(artifact.normal_force_max) - np.asarray(artifact.normal_force_min)))
    out: dict = {"versions": {}, "float_bound": FLOAT_BOUND * span, "runs": {}}
    for version in fmu.VERSIONS:
        place = folder / f"fmi{version}"
        written = {"truss": fmu.plant_fmu(setup, design, place / "truss.fmu", version)}
        for law, _ in LAWS.values():
            for real, name in (("double", law), ("float", f"{law}_float")):  # the default experiment: the study
                written[name] = fmu.controller_fmu(artifact, law, place / f"{name}.fmu", version, real,
                                                   stop_time=setup.duration)  # fmt: skip
        figures: dict = {
            "fmus": {key: {"path": f.path, "problems": validate_fmu(str(f.path))} for key, f in written.items()}
        }
        progress(f"      FMI {version}: {', '.join(f.path.name for f in written.values())} written and validated")
        runs = []
        for name, (law, _) in LAWS.items():
            expected = np.array([forces for _, forces in logs[name]])
            double, _ = replay(written[law].path, logs[name])
            single, _ = replay(written[f"{law}_float"].path, logs[name])
            run, safe = cosimulate(setup, written["truss"].path, written[law].path, name)
            mil = study.run(name)
            same = _identical(run, mil)
            run.metrics = closed_loop.metrics(run, study.run("passive F_max"), study.sensor_quantities)
            runs.append(run)
            out["runs"][name] = (run, mil)
            figures[name] = {
                "samples": len(logs[name]),
                "double_identical_samples": int(np.sum(np.all(double == expected, axis=1))),
                "float_max_deviation": float(np.max(np.abs(single - expected))),
                "cosimulation_identical": same,
                "cosimulation_energy_difference": float(np.max(np.abs(run.energy - mil.energy)) / np.max(mil.energy))
                if run.energy.shape == mil.energy.shape
                else float("inf"),
                "cosimulation_energy_measure": run.energy_measure(),
                "mil_energy_measure": mil.energy_measure(),
                "safe_state_samples": safe,
            }
            progress(
                f"      FMI {version} {name}: replay {figures[name]['double_identical_samples']}/{len(logs[name])} "
                f"bit-identical (double), float max |ΔF_N| {figures[name]['float_max_deviation']:.3g} N; "
                f"co-simulation {'identical to' if same else 'DIFFERS from'} MIL"
            )
        study_runs_all = [study.run("passive F_min"), study.run("passive F_max"), *runs, study.run("active LQG")]
        figures["orderings"] = dataclasses.replace(study, runs=study_runs_all).orderings()
        out["versions"][version] = figures
    return out


def _identical(run, mil) -> bool:
    """Every recorded number of the co-simulated run equals the MIL run's."""
    fields = ("time", "energy", "sensors", "normal_force", "joint_force", "sliding_velocity")
    return all(np.array_equal(getattr(run, f), getattr(mil, f)) for f in fields)


__all__ = ["FLOAT_BOUND", "LAWS", "constant_force_run", "fmu_study", "input_values", "recorded_inputs", "replay"]
