"""FMU export (codegen/fmu.py, bench/cosimulation.py, bench/fmu_check.py, smartjoint fmu): the
controllers and the plant as FMI 2 and 3 co-simulation units, against the project's own numbers."""

from __future__ import annotations

import dataclasses
import math
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import cli_error, run, run_cli, small_control_truss
from fmpy import read_model_description
from fmpy.build import build_platform_binary
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu

from smartjoint.bench import fmu_check
from smartjoint.bench.cosimulation import FmuInstance, cosimulate
from smartjoint.codegen import build, fmu
from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design import parse_design
from smartjoint.design.control import artifact_building
from smartjoint.design.control import study as closed_loop

VERSIONS = (2, 3)


def _study(design, duration: float):
    design = dataclasses.replace(design, control=dataclasses.replace(design.control, study_duration=duration))
    s = closed_loop.run_study(design, progress=lambda message: None)
    return design, s, artifact_building.from_design(design, s.setup.model, s.lqg, s.settings())


@pytest.fixture(scope="module")
def paper(three_type_a):
    """The paper's three type A joints (Fig. 11), a 1-s study."""
    return _study(three_type_a[0], 1.0)


@pytest.fixture(scope="module")
def small():
    """Not the paper's truss: the small truss with two joints of its own, other names and limits."""
    data = small_control_truss(0.3, krylov=1, siso_boundary_layer=1e-4)
    return _study(parse_design(data), 0.3)


@pytest.fixture(scope="module")
def written(paper, tmp_path_factory):
    """Every FMU of the paper's study, FMI 2 and 3: plant, both laws, double and float."""
    design, s, a = paper
    folder = tmp_path_factory.mktemp("fmus")
    out = {}
    for version in VERSIONS:
        out[version, "truss"] = fmu.plant_fmu(s.setup, design, folder / f"truss{version}.fmu", version)
        for law in law_registry.NAMES:
            for real in ("double", "float"):
                out[version, law, real] = fmu.controller_fmu(
                    a, law, folder / f"{law}{version}{real}.fmu", version, real
                )
    return out


def test_every_fmu_passes_fmpys_validation_and_is_the_same_bytes_when_written_again(written, paper, tmp_path):
    for key, f in written.items():
        assert validate_fmu(str(f.path)) == [], key
        with zipfile.ZipFile(f.path) as archive:
            names = set(archive.namelist())
        page = "documentation/_main.html" if f.fmi == 2 else "documentation/index.html"
        assert {"modelDescription.xml", f.binary, "sources/fmu_model.c", page} <= names, key
        assert any(n.endswith("Functions.h") for n in names), key  # the FMI headers, from FMPy
    root = Path(__file__).parents[1]
    assert not [p for p in root.rglob("fmi*Function*.h") if ".git" not in p.parts]  # never in the repository
    design, s, a = paper
    again = fmu.controller_fmu(a, "clqg", tmp_path / "clqg2double.fmu", 2, "double")
    assert again.path.read_bytes() == written[2, "clqg", "double"].path.read_bytes()
    plant = fmu.plant_fmu(s.setup, design, tmp_path / "truss3.fmu", 3)
    assert plant.path.read_bytes() == written[3, "truss"].path.read_bytes()


def test_fmus_are_readable_by_others_and_the_default_experiment_is_the_study(small, tmp_path):
    """An FMU gets an ordinary file's mode (0666 less the umask, not mkstemp's 0600); a controller
    FMU's default experiment is the study it is given; its time variable has no start value, as
    FMI 2.0 (2.2.7) and 3.0 demand of the independent variable (docs/fmu.md: FMI Library's error)."""
    import os

    design, s, a = small
    mask = os.umask(0o022)
    os.umask(mask)
    written = fmu.controller_fmu(a, "siso", tmp_path / "siso.fmu", 2, "double", stop_time=s.setup.duration)
    assert written.path.stat().st_mode & 0o777 == 0o666 & ~mask
    description = read_model_description(str(written.path))
    assert float(description.defaultExperiment.stopTime) == s.setup.duration == 0.3
    independent = [v for v in description.modelVariables if v.causality == "independent"]
    assert [v.name for v in independent] == ["time"] and independent[0].start is None
    from test_can_layer import REFERENCE

    done = run_cli("fmu", REFERENCE, "--law", "siso", "-o", tmp_path / "cli.fmu", "--json")
    assert done.returncode == 0, done.stderr
    assert float(read_model_description(str(tmp_path / "cli.fmu")).defaultExperiment.stopTime) == 4.0  # the default t_e
    line = cli_error("fmu", str(REFERENCE), "--law", "siso", "-o", str(tmp_path / "x.fmu"), "--stop-time", "-1")
    assert "--stop-time: -1.0 s — must be a finite number > 0" in line and not (tmp_path / "x.fmu").exists()


@pytest.mark.numerics
@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize("name", ["SISO", "cLQG"])
def test_a_controller_fmu_answers_the_studys_measurements_as_the_python_reference(written, paper, version, name):
    """Double build: every sample bit for bit; float build: within 1e-3 of the F_N span."""
    design, s, a = paper
    log = fmu_check.recorded_inputs(s.setup, a, name)
    expected = np.array([forces for _, forces in log])
    law = fmu_check.LAWS[name][0]
    double, status = fmu_check.replay(written[version, law, "double"].path, log)
    assert double.tobytes() == expected.tobytes() and set(status) == {0}
    single, _ = fmu_check.replay(written[version, law, "float"].path, log)
    span = float(np.min(np.asarray(a.normal_force_max) - np.asarray(a.normal_force_min)))
    deviation = np.max(np.abs(single - expected))
    assert 0.0 < deviation <= fmu_check.FLOAT_BOUND * span  # rounded to float, and within the bound


@pytest.mark.numerics
@pytest.mark.parametrize("version", VERSIONS)
def test_the_plant_fmu_under_constant_normal_forces_is_the_projects_plant_simulation(written, paper, version):
    design, s, _ = paper
    for forces in ([400.0, 400.0, 400.0], [10.0, 150.0, 333.0]):
        check = fmu_check.constant_force_run(s.setup, written[version, "truss"].path, forces)
        assert check["identical"], check["max_energy_difference"]
    # The same numbers whatever the communication step: one plant step at a time, or 5 ms at once.
    fine = _energies(written[version, "truss"].path, s.setup, s.setup.plant_step, 100)
    coarse = _energies(written[version, "truss"].path, s.setup, 100 * s.setup.plant_step, 1)
    assert fine[::100].tobytes() == coarse.tobytes()


def _energies(path, setup, step: float, every: int) -> np.ndarray:
    with FmuInstance(path) as plant:
        plant.initialize()
        plant.set_real(plant.references([f"SETPOINT_{j}.normal_force" for j in setup.plant.joint_names]), [50.0] * 3)
        energy = plant.references(["energy"])
        out = []
        for k in range(round(0.02 / step)):
            out.append(plant.get_real(energy)[0])
            plant.step(k * step, step)
        return np.array(out)


@pytest.mark.numerics
@pytest.mark.parametrize("version", VERSIONS)
def test_plant_and_controller_fmus_co_simulated_are_the_mil_study_and_the_orderings_hold(written, paper, version):
    design, s, a = paper
    runs = []
    for name, law in ((entry.display, entry.name) for entry in law_registry.LAWS.values()):
        run, safe = cosimulate(s.setup, written[version, "truss"].path, written[version, law, "double"].path, name)
        mil = s.run(name)
        for field in ("time", "energy", "sensors", "normal_force", "joint_force", "sliding_velocity"):
            assert getattr(run, field).tobytes() == getattr(mil, field).tobytes(), (name, field)
        assert safe == 0
        run.metrics = closed_loop.metrics(run, s.run("passive F_max"), s.sensor_quantities)
        runs.append(run)
    both = dataclasses.replace(s, runs=[s.run("passive F_min"), s.run("passive F_max"), *runs, s.run("active LQG")])
    # The same numbers give the same verdicts; whether the orderings hold over plants is the
    # ensemble's test (test_study.py), not one chaotic trajectory's.
    assert both.orderings() == s.orderings()


def test_the_co_simulation_master_adds_sensor_noise_and_amplifier_lag_as_the_studys_loop(written, paper):
    """The ensembles' perturbations on the FMUs: the compiled closed loop's numbers (which are the
    Python loop's, tests/test_closed_loop.py) with noise on the tip sensors and lagging amplifiers."""
    from smartjoint.codegen.closed_loop import CompiledLoop

    design, s, a = paper
    noise = np.random.default_rng(21).normal(0.0, 2e-5, (s.setup.samples, len(s.setup.plant.sensor_names)))
    perturbed = dataclasses.replace(s.setup, sensor_noise=noise, amplifier_lag=3e-3)
    loop = CompiledLoop(a)
    for name, law in (("SISO", "siso"), ("cLQG", "clqg")):
        run, safe = cosimulate(perturbed, written[2, "truss"].path, written[2, law, "double"].path, name)
        expected, expected_safe = loop.run(perturbed, name)
        assert run.energy.tobytes() == expected.energy.tobytes() and safe == expected_safe, name
        assert run.normal_force.tobytes() == expected.normal_force.tobytes(), name
        assert run.energy.tobytes() != s.run(name).energy.tobytes()  # the perturbations act
    jittered = dataclasses.replace(s.setup, sample_steps=np.arange(s.setup.samples) * 20)
    with pytest.raises(ModelError, match="sample_steps"):
        cosimulate(jittered, written[2, "truss"].path, written[2, "clqg", "double"].path, "cLQG")


def test_a_design_other_than_the_papers_gets_its_own_fmus_and_numbers(small, tmp_path):
    """Two joints with their own names, limits and friction: nothing of the paper's truss leaks in."""
    design, s, a = small
    plant = fmu.plant_fmu(s.setup, design, tmp_path / "small.fmu", 3)
    names = {v.name for v in plant.variables}
    joints = [j.name for j in design.joints]
    assert {f"SETPOINT_{j}.normal_force" for j in joints} <= names and not any("A1" in n for n in names)
    controller = fmu.controller_fmu(a, "clqg", tmp_path / "small_clqg.fmu", 3)
    starts = {v.name: v.start for v in controller.variables}
    assert starts[f"JOINT_{joints[0]}.normal_force_max"] == 100.0
    assert validate_fmu(str(plant.path)) == [] and validate_fmu(str(controller.path)) == []
    run, _ = cosimulate(s.setup, plant.path, controller.path, "cLQG")
    assert run.energy.tobytes() == s.run("cLQG").energy.tobytes()


def _listed_sources(folder: Path) -> list[Path]:
    """The translation units an unpacked FMU names (<SourceFiles> in FMI 2, buildDescription.xml in
    FMI 3), as FMPy reads them."""
    (configuration,) = read_model_description(str(folder)).buildConfigurations
    return [folder / "sources" / name for files in configuration.sourceFileSets for name in files.sourceFiles]


def _unpacked(f, folder: Path) -> Path:
    with zipfile.ZipFile(f.path) as archive:
        archive.extractall(folder)
    (folder / f.binary).unlink()
    return folder


def _packed(folder: Path, path: Path) -> Path:
    with zipfile.ZipFile(path, "w") as archive:
        for member in sorted(folder.rglob("*")):
            archive.write(member, member.relative_to(folder).as_posix())
    return path


def _same_numbers(key, rebuilt: Path, shipped: Path, s, a) -> bool:
    if key[1] == "truss":
        return fmu_check.constant_force_run(s.setup, rebuilt, [200.0, 150.0, 100.0])["identical"]
    log = fmu_check.recorded_inputs(s.setup, a, "cLQG" if key[1] == "clqg" else "SISO")[:300]
    return fmu_check.replay(rebuilt, log)[0].tobytes() == fmu_check.replay(shipped, log)[0].tobytes()


def test_the_sources_compile_from_the_unpacked_fmu_alone_with_the_strict_warnings(written, paper, tmp_path):
    """The sources the FMU lists, compiled with -Werror and the project's warning set, and built by
    FMPy's own CMake project from the unpacked FMU, give libraries with the shipped numbers."""
    design, s, a = paper
    for key in ((2, "siso", "double"), (3, "clqg", "float"), (3, "truss")):
        folder = _unpacked(written[key], tmp_path / "_".join(map(str, key)))
        library = folder / written[key].binary
        done = run("cc", *build.FLAGS, "-fPIC", "-shared", "-fvisibility=hidden", *_listed_sources(folder),
                   "-o", library, "-lm")  # fmt: skip
        assert done.returncode == 0 and done.stderr == "", done.stderr
        rebuilt = _packed(folder, tmp_path / f"{written[key].identifier}.fmu")
        assert _same_numbers(key, rebuilt, written[key].path, s, a), key
    for key in ((2, "truss"), (3, "clqg", "double")):
        folder = _unpacked(written[key], tmp_path / ("cmake_" + "_".join(map(str, key))))
        (work := tmp_path / f"build_{key[0]}_{key[1]}").mkdir()
        build_platform_binary(folder, work, all_warnings=True)  # cmake with FMPy's CMakeLists, -Wall -Wextra -Wpedantic
        assert (folder / written[key].binary).is_file(), key
        rebuilt = _packed(folder, work / f"{written[key].identifier}.fmu")
        assert _same_numbers(key, rebuilt, written[key].path, s, a), key


def test_a_controller_fmu_links_the_law_and_each_instance_holds_its_own_parameters(written):
    """The model file does not include the law's source: the law is one of the sources the FMU
    compiles, and the tunables live in one <prefix>_<law>_params per instance, handed to _init."""
    for law in law_registry.NAMES:
        with zipfile.ZipFile(written[3, law, "double"].path) as archive:
            model = archive.read("sources/fmu_model.c").decode()
            listed = archive.read("sources/buildDescription.xml").decode()
        name = law_registry.law(law).c_name("smartjoint")
        assert f'#include "{name}.c"' not in model and f'#include "{name}.h"' in model
        assert f'<SourceFile name="{name}.c"/>' in listed, listed
        assert f"    {name}_params params;" in model
        assert f"{name}_init(&m->state, &m->params);" in model
        assert "TUNABLE" not in model


def _refused(instance: FmuInstance, call, *words: str) -> None:
    """``call()`` answers the FMI error status and logs one message with ``words``."""
    before = len(instance.messages)
    with pytest.raises(FMICallException) as raised:
        call()
    assert raised.value.status == 3  # fmi2Error = fmi3Error = 3
    logged = [text for status, text in instance.messages[before:] if status == 3]
    assert len(logged) == 1 and all(w in logged[0] for w in words), (logged, words)


@pytest.mark.parametrize("version", VERSIONS)
def test_bad_input_is_answered_with_the_fmi_error_status_and_a_message_never_a_crash(written, paper, version):
    design, s, a = paper
    with FmuInstance(written[version, "clqg", "double"].path) as controller:
        ref = {name: v.valueReference for name, v in controller.variables.items()}
        _refused(controller, lambda: controller.step(0.0, s.setup.sample_time), "DoStep", "instantiated")
        _refused(controller, lambda: controller.get_real([ref["SETPOINT_A1.normal_force"]]), "Get", "instantiated")
        controller.initialize()
        friction = ref["JOINT_A1.friction_force"]
        _refused(controller, lambda: controller.set_real([friction], [math.nan]), "JOINT_A1.friction_force", "nan")
        _refused(controller, lambda: controller.set_real([friction], [math.inf]), "inf", "finite")
        _refused(controller, lambda: controller.step(0.0, 2 * s.setup.sample_time), "communication step", "0.001")
        limits = [ref["JOINT_A1.normal_force_min"], ref["JOINT_A1.normal_force_max"], ref["boundary_layer"]]
        _refused(
            controller, lambda: controller.set_real(limits[:1], [500.0]), "normal_force_min", "500", "F_N^max = 400"
        )
        _refused(controller, lambda: controller.set_real(limits[1:2], [5.0]), "normal_force_max", "F_N^min = 10")
        _refused(controller, lambda: controller.set_real(limits[2:], [0.0]), "boundary_layer", "> 0")
        _refused(controller, lambda: controller.set_real([ref["SETPOINT_A1.normal_force"]], [1.0]), "output")
        _refused(controller, lambda: controller.set_real([9999], [1.0]), "9999")
        assert controller.get_real(limits).tolist() == [10.0, 400.0, 100.0]  # nothing refused was taken
        assert controller.get_real([friction])[0] == 0.0
        controller.step(0.0, s.setup.sample_time)  # and the instance goes on
        controller.fmu.terminate()
        _refused(controller, lambda: controller.step(0.001, s.setup.sample_time), "DoStep", "terminated")
    with FmuInstance(written[version, "siso", "float"].path) as single:
        single.initialize()
        velocity = single.references(["JOINT_A3.sliding_velocity"])
        _refused(single, lambda: single.set_real(velocity, [1e300]), "JOINT_A3.sliding_velocity", "1000 m/s")
        _refused(single, lambda: single.set_real(velocity, [1e30]), "sliding_velocity_limit")  # no measurement
        single.set_real(velocity, [10.0])  # beyond the plausible range (1 m/s), within the input's: the safe state
        assert single.get_integer(single.references(["CONTROLLER_STATUS.step_status"])) == [8]
    with FmuInstance(written[version, "truss"].path) as plant:
        ref = {name: v.valueReference for name, v in plant.variables.items()}
        plant.initialize()
        _refused(plant, lambda: plant.step(0.0, 1.5 * s.setup.plant_step), "communication step", "whole number")
        _refused(plant, lambda: plant.set_real([ref["SETPOINT_A2.normal_force"]], [-1.0]), "SETPOINT_A2", "0 <= value")
        _refused(plant, lambda: plant.set_real([ref["pulse.duration"]], [0.5]), "pulse.duration", "fixed parameter")
        _refused(plant, lambda: plant.step(0.5, s.setup.sample_time), "communication point", "0.5")
        plant.step(0.0, s.setup.sample_time)


def test_a_wrong_instantiation_token_is_refused_with_a_message(written, tmp_path):
    source = written[2, "siso", "double"].path
    forged = tmp_path / source.name
    with zipfile.ZipFile(source) as inside, zipfile.ZipFile(forged, "w") as outside:
        for item in inside.infolist():
            data = inside.read(item)
            if item.filename == "modelDescription.xml":
                data = data.replace(b'guid="{', b'guid="{0')
            outside.writestr(item, data)
    with pytest.raises(Exception, match="instantiate"):
        FmuInstance(forged)


@pytest.mark.parametrize("version", VERSIONS)
def test_tuned_limits_and_boundary_layer_are_the_law_generated_with_them(written, paper, tmp_path, version):
    """Tuning F_N^min, F_N^max and ε in the FMU gives, bit for bit, the FMU of an artefact
    designed with them; another instance of the same FMU keeps its own values."""
    design, s, a = paper
    tuned = dataclasses.replace(
        a,
        normal_force_min=np.array([20.0, 30.0, 40.0]),
        normal_force_max=np.array([300.0, 350.0, 390.0]),
        clqg_boundary_layer=60.0,
        safe_normal_force=np.array([300.0, 350.0, 390.0]),
        preset_force=np.array([300.0, 350.0, 390.0]),
        siso_normal_force_min=np.array([20.0, 30.0, 40.0]),
    )  # fmt: skip  (the safe force is the design's, not tunable: unused by these samples)
    built = fmu.controller_fmu(tuned, "clqg", tmp_path / "tuned.fmu", version)
    log = fmu_check.recorded_inputs(s.setup, a, "cLQG")[:400]
    expected, _ = fmu_check.replay(built.path, log)
    path = written[version, "clqg", "double"].path
    with FmuInstance(path, "tuned") as one, FmuInstance(path, "default") as other:
        names = [v.name for v in one.description.modelVariables if v.causality == "input"]
        parameters = {
            **{f"JOINT_{j}.normal_force_max": hi for j, hi in zip(a.joint_names, tuned.normal_force_max)},
            **{f"JOINT_{j}.normal_force_min": lo for j, lo in zip(a.joint_names, tuned.normal_force_min)},
            "boundary_layer": 60.0,
        }
        one.initialize(parameters=parameters)
        other.initialize()
        commands = one.references([f"SETPOINT_{j}.normal_force" for j in a.joint_names])
        got, untouched = [], []
        for k, (m, _) in enumerate(log):
            values = fmu_check.input_values(names, list(a.joint_names), m)
            for instance, into in ((one, got), (other, untouched)):
                instance.set_real(instance.references(names), values)
                into.append(instance.get_real(commands))
                instance.step(k * a.sample_time, a.sample_time)
    assert np.array(got).tobytes() == expected.tobytes()
    reference = np.array([forces for _, forces in log])
    assert np.array(untouched).tobytes() == reference.tobytes()


@pytest.mark.parametrize("version", VERSIONS)
def test_a_saved_fmu_state_restores_the_plant_and_the_controller_exactly(written, version):
    for key in ((version, "truss"), (version, "siso", "double")):
        with FmuInstance(written[key].path) as instance:
            instance.initialize()
            outputs = [v.valueReference for v in instance.description.modelVariables if v.causality == "output"]
            outputs = [r for r in outputs if r != instance.variables.get("CONTROLLER_STATUS.step_status", None)]
            reals = [
                v.valueReference
                for v in instance.description.modelVariables
                if v.causality == "output" and v.type in ("Real", "Float64")
            ]
            step = float(instance.description.defaultExperiment.stepSize)
            for k in range(60):
                instance.step(k * step, step)
            saved = instance.fmu.getFMUState() if version == 3 else instance.fmu.getFMUstate()
            serialized = (
                instance.fmu.serializeFMUState(saved) if version == 3 else instance.fmu.serializeFMUstate(saved)
            )
            first = []
            for k in range(60, 100):
                instance.step(k * step, step)
                first.append(instance.get_real(reals))
            restored = (
                instance.fmu.deserializeFMUState(serialized)
                if version == 3
                else instance.fmu.deSerializeFMUstate(serialized)
            )
            (instance.fmu.setFMUState if version == 3 else instance.fmu.setFMUstate)(restored)
            second = []
            for k in range(60, 100):
                instance.step(k * step, step)
                second.append(instance.get_real(reals))
            assert np.array(first).tobytes() == np.array(second).tobytes(), key


def test_the_command_writes_validated_fmus_and_refuses_bad_arguments_in_one_line(tmp_path):
    artefact = Path(__file__).parents[1] / "firmware" / "generated" / "controller.json"
    done = run_cli("fmu", str(artefact), "--law", "siso", "--fmi", "3", "-o", str(tmp_path / "siso.fmu"), "--json")
    assert done.returncode == 0, done.stderr
    assert '"validation_problems": []' in done.stdout and (tmp_path / "siso.fmu").is_file()
    assert "--law: required" in cli_error("fmu", str(artefact), "-o", str(tmp_path / "a.fmu"))
    assert "'a-b.fmu'" in cli_error("fmu", str(artefact), "--law", "clqg", "-o", str(tmp_path / "a-b.fmu"))
    assert "needs --plant" in cli_error(
        "fmu", str(artefact.with_suffix(".toml")), "--law", "clqg", "-o", str(tmp_path / "a.fmu")
    )
    design = Path(__file__).parents[1] / "design" / "data" / "three_type_a.toml"
    done = run_cli(
        "fmu", str(design), "--plant", "--no-update", "--fmi", "2", "-o", str(tmp_path / "truss.fmu"), "--json"
    )
    assert done.returncode == 0 and '"validation_problems": []' in done.stdout, done.stderr
    assert "a plant FMU has no law" in cli_error(
        "fmu", str(design), "--plant", "--law", "siso", "-o", str(tmp_path / "t.fmu")
    )
    (tmp_path / "folder.fmu").mkdir()
    assert "is a folder" in cli_error("fmu", str(artefact), "--law", "clqg", "-o", str(tmp_path / "folder.fmu"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder.fmu", "siso.fmu", "truss.fmu"]  # nothing half-written


def test_a_model_error_names_the_field():
    with pytest.raises(ModelError, match="--fmi: 4"):
        fmu.controller_fmu(None, "siso", "x.fmu", 4)
    with pytest.raises(ModelError, match="--law: 'lqr'"):
        fmu.controller_fmu(None, "lqr", "x.fmu", 2)
