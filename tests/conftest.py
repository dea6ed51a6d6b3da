"""Shared helpers: small design dictionaries built in code (validated by parse_design), commands
and the command line run in a fresh process, a quiet joint frame, and the portability leg's
``--perturb-inputs`` option (see tests/perturbation/sitecustomize.py)."""

from __future__ import annotations

import copy
import importlib.util
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

PERTURBATION = Path(__file__).with_name("perturbation")


def pytest_addoption(parser):
    parser.addoption(
        "--perturb-inputs",
        type=float,
        default=0.0,
        metavar="RELATIVE",
        help="multiply the model's physical inputs (designs, Table 1) by 1 + RELATIVE·r, r in [-1, 1] "
        "fixed per input, in this process and its Python subprocesses: another machine's last bits "
        "(the portability leg, .ci/portability, uses 1e-12 on the tests marked 'numerics')",
    )


def pytest_configure(config):
    if getattr(config.option, "numprocesses", None) and "PYTEST_XDIST_WORKER" not in os.environ:
        # One BLAS thread per worker (inherited by the workers started after this): n workers ×
        # OpenBLAS's one thread per core would oversubscribe the cores and spin.
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    relative = config.getoption("perturb_inputs")
    if relative == 0.0:
        return
    if not (math.isfinite(relative) and 0.0 < relative <= 1e-6):
        raise pytest.UsageError(f"--perturb-inputs: {relative!r} — must be a relative size in (0, 1e-6]")
    # Before the test modules are imported, so that names they import are the perturbed ones.
    module_spec = importlib.util.spec_from_file_location(
        "smartjoint_test_perturbation", PERTURBATION / "sitecustomize.py"
    )
    module = importlib.util.module_from_spec(module_spec)
    module_spec.loader.exec_module(module)
    module.install(relative)
    os.environ[module.VARIABLE] = repr(relative)
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(PERTURBATION), os.environ.get("PYTHONPATH")]))


def pytest_report_header(config):
    relative = config.getoption("perturb_inputs")
    if relative:
        return f"model inputs perturbed by up to {relative:g} relative (--perturb-inputs)"


# The paper's Table 1, given explicitly: a design without friction parameters has none.
TABLE_1_A = {
    "sigma0": 1.42e5,
    "sigma1": 0.02,
    "sigma2": 0.01,
    "coulomb": 0.61,
    "stribeck": 0.14,
    "stribeck_velocity": 0.01,
}
TABLE_1_B = {
    "sigma0": 6.5e4,
    "sigma1": 0.02,
    "sigma2": 0.01,
    "coulomb": 0.49,
    "stribeck": 0.08,
    "stribeck_velocity": 0.02,
    "radius": 0.011,
}
ALUMINIUM = {"youngs_modulus": 70.0e9, "shear_modulus": 26.0e9, "density": 2700.0}
TUBE = {"material": "aluminium", "outer_diameter": 0.022, "wall_thickness": 0.0015}


def beam_design(length: float = 2.0, elements: int = 10, clamp: bool = True) -> dict:
    """A single straight tube from A (clamped) to B along x, no connectors, massless nodes."""
    design = {
        "name": "beam",
        "materials": {"aluminium": dict(ALUMINIUM)},
        "sections": {"tube": dict(TUBE)},
        "nodes": [{"name": "A", "position": [0.0, 0.0, 0.0]}, {"name": "B", "position": [length, 0.0, 0.0]}],
        "members": [{"name": "M", "start": "A", "end": "B", "section": "tube", "elements": elements}],
    }
    if clamp:
        design["supports"] = [{"node": "A", "dofs": "all"}]
    return design


def small_truss() -> dict:
    """A 2-bay mast with connectors, rigid nodes, tip node, sensors and disturbances."""
    return {
        "name": "small",
        "materials": {"aluminium": dict(ALUMINIUM)},
        "sections": {"tube": dict(TUBE)},
        "connectors": {
            "c": {
                "length": 0.05,
                "mass": 0.06,
                "diameter": 0.022,
                "axial_stiffness": 5e6,
                "bending_stiffness": 800.0,
                "torsional_stiffness": 600.0,
            }
        },
        "node_types": {"ball": {"mass": 0.25, "seat_radius": 0.023}},
        "mesh": {"tube_elements": 2},
        "truss": {
            "bays": 2,
            "bay_length": 1.0,
            "width": 1.0,
            "node_type": "ball",
            "section": "tube",
            "connector": "c",
            "tip_node": "cross",
        },
        "point_masses": [{"node": "TIP", "mass": 0.5}],
        "sensors": [
            {"name": "tip_y", "node": "TIP", "direction": "uy"},
            {"name": "tip_vz", "node": "TIP", "direction": "uz", "quantity": "velocity"},
        ],
        "disturbances": [{"name": "fy", "node": "TIP", "direction": "uy"}],
        "joints": [
            {"name": "JA", "member": "L2_0", "end": "end", "type": "A"},
            {"name": "JB", "member": "D1_1", "end": "start", "type": "B", "axis": [0.0, 1.0, 0.0]},
        ],
        "friction": {"A": dict(TABLE_1_A), "B": dict(TABLE_1_B)},
    }


def triangular_mast(bays: int = 6) -> dict:
    """A triangular mast (not the paper's square one): ``bays`` bays of 0.8 m, three corners on a
    0.4 m radius, battens, longerons and one diagonal per face and bay, a tip node on the axis
    joined to the last frame, clamped at x = 0; the small truss's components; tip sensors and
    pulses along y and z, F_N within 5 … 200 N, three joints placed for the first bending pair
    (issue 36's case). Its axial modes are symmetric, so the tip sensors see some not at all."""
    data = small_truss()
    for key in ("truss", "joints"):
        del data[key]
    corners, length, radius = 3, 0.8, 0.4
    nodes = [
        {
            "name": f"N{i}_{c}",
            "position": [i * length, radius * math.cos(2 * math.pi * c / 3), radius * math.sin(2 * math.pi * c / 3)],
            "type": "ball",
        }
        for i in range(bays + 1)
        for c in range(corners)
    ]
    nodes.append({"name": "TIP", "position": [bays * length, 0.0, 0.0], "type": "ball"})
    ends = []
    for i in range(bays + 1):
        for c in range(corners):
            ends.append((f"B{i}_{c}", f"N{i}_{c}", f"N{i}_{(c + 1) % corners}"))
            if i < bays:
                ends.append((f"L{i + 1}_{c}", f"N{i}_{c}", f"N{i + 1}_{c}"))
                ends.append((f"D{i + 1}_{c}", f"N{i}_{c}", f"N{i + 1}_{(c + 1) % corners}"))
    ends += [(f"S{c}", f"N{bays}_{c}", "TIP") for c in range(corners)]
    data["nodes"] = nodes
    data["members"] = [{"name": n, "start": a, "end": b, "section": "tube", "connector": "c"} for n, a, b in ends]
    data["supports"] = [{"node": f"N0_{c}", "dofs": "all"} for c in range(corners)]
    data["sensors"] = [{"name": f"tip_{d}", "node": "TIP", "direction": f"u{d}"} for d in ("y", "z")]
    data["disturbances"] = [{"name": f"f{d}", "node": "TIP", "direction": f"u{d}"} for d in ("y", "z")]
    data["placement"] = {"modes": [1, 2], "count": 3}
    data["control"] = {"normal_force_min": 5.0, "normal_force_max": 200.0}
    data["name"] = "triangular-mast"
    return data


# The slip-ratio law's settings of the small truss (given: its tuning runs an ensemble).
SLIP_RATIO_LAW = {"velocity": 1e-3, "rise": 85.0, "decay": 15.0}
SLIP_RATIO_SETTINGS = {f"slipratio_{key}": value for key, value in SLIP_RATIO_LAW.items()}


def small_control_truss(duration: float, **control) -> dict:
    """The small truss with a quick control section: 4 of 12 modes, F_N 5–100 N, a short study,
    the slip-ratio law's settings given."""
    data = small_truss()
    data["control"] = {
        "considered_modes": 12,
        "modes": 4,
        "normal_force_min": 5.0,
        "normal_force_max": 100.0,
        "study_duration": duration,
        **SLIP_RATIO_SETTINGS,
        **control,
    }
    return data


@pytest.fixture
def truss_dict():
    return copy.deepcopy(small_truss())


@pytest.fixture(scope="session")
def three_type_a():
    """The paper's configuration (Fig. 11), updated to the EMA, and its 24-state design model."""
    from smartjoint.design import load_design, updated_design
    from smartjoint.design.control import study
    from smartjoint.design.structure import spec

    design, _ = updated_design(load_design(spec.REFERENCE_DESIGN.parent / "three_type_a.toml"))
    return design, study.design_model(design, lambda message: None)


def run(*command, **options) -> subprocess.CompletedProcess:
    """Run ``command`` (compiler, checker, tool) to its end, stdout and stderr captured as text."""
    return subprocess.run([str(part) for part in command], capture_output=True, text=True, **options)


def run_cli(*args, **options) -> subprocess.CompletedProcess:
    """``python -m smartjoint.cli ARGS`` in a fresh process of this interpreter, output captured as text."""
    return run(sys.executable, "-m", "smartjoint.cli", *args, **options)


def cli_error(*args, **options) -> str:
    """Run the command line where it must refuse: exit 2, one line on stderr and no traceback; that line."""
    done = run_cli(*args, **options)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1 and "Traceback" not in done.stderr, (done.returncode, done.stderr)
    return lines[0]


def design_file_error(path: Path, text: str) -> str:
    """Write ``text`` to the design file ``path``; the message of the DesignError load_design refuses it with."""
    from smartjoint.common.errors import DesignError
    from smartjoint.design import load_design

    path.write_text(text)
    with pytest.raises(DesignError) as refused:
        load_design(path)
    return str(refused.value)


def quiet_joint_frame(message, counter: int) -> bytearray:
    """A JOINT frame of ``message`` at rest (no sliding, no friction, F_N = 100 N), E2E-protected with ``counter``."""
    from smartjoint.bench import e2e

    signals = {"crc": 0, "counter": 0, "sync": 0, "sliding_velocity": 0.0, "friction_force": 0.0, "normal_force": 100.0}
    return e2e.protect(message.frame_id, bytearray(message.encode(signals)), counter)


def small_study():
    """The small truss's study over 0.2 s and its artefact (ε = 3e-4 m/s): (setup, artefact)."""
    from smartjoint.design.control import ensemble
    from smartjoint.design.control.runs import setup
    from smartjoint.design.control.study import design_model, lqg_for
    from smartjoint.design.structure.spec import parse_design

    d = small_truss()
    d["control"] = {"modes": 4, "considered_modes": 10, "study_duration": 0.2, "siso_boundary_layer": 3e-4}
    design = parse_design(d)
    model = design_model(design, lambda line: None)
    return setup(design, model), ensemble.point_artifact(design, model, lqg_for(design, model), {})


def plausible_measurements(a, count: int, seed: int, sensor: float, slip: float, friction: float) -> list:
    """``count`` samples of measurements well inside every range of artefact ``a``: sensors, sliding
    velocities and friction forces normal with these standard deviations, F_N uniform in 10…400 N."""
    import numpy as np

    from smartjoint.design import plant

    rng = np.random.default_rng(seed)
    l, ny = len(a.joint_names), len(a.sensor_names)
    return [
        plant.Measurements(
            k * a.sample_time,
            rng.normal(0, sensor, ny),
            rng.normal(0, slip, l),
            rng.normal(0, friction, l),
            rng.uniform(10, 400, l),
        )
        for k in range(count)
    ]


def artifact_fields(a) -> dict:
    """The JSON values of a controller artefact by their Python names (the sections flattened),
    for a test that changes fields and writes the text again with :func:`artifact_text`."""
    import json

    from smartjoint.design.control import artifact, artifact_layout

    return artifact_layout.flatten(json.loads(artifact.dumps(a)))


def artifact_text(fields: dict) -> str:
    """The artefact's JSON text of fields by their Python names, laid out in sections."""
    import json

    from smartjoint.design.control import artifact_layout

    return json.dumps(artifact_layout.nest(fields))


def count_model_calls(monkeypatch):
    """Wrap ``fem.build_model`` and ``modal.solve_modes`` wherever a module of the project holds
    them; the counter gets (function, joints or mode count) per call."""
    import importlib
    import sys
    from collections import Counter

    from smartjoint.design.structure import fem, modal

    # Every module of a run loaded first, so that each binding of the two functions is wrapped
    # (a function-level import later reads the wrapped attribute of fem or modal itself).
    for name in ("smartjoint.pipeline", "smartjoint.bench.sweep", "smartjoint.commands"):
        importlib.import_module(name)
    calls: Counter = Counter()
    build, solve = fem.build_model, modal.solve_modes

    def counted_build(design, *args, joints="released", **kwargs):
        calls["build", joints] += 1
        return build(design, *args, joints=joints, **kwargs)

    def counted_solve(model, n_modes, *args, **kwargs):
        calls["solve", n_modes == model.n_dof] += 1
        return solve(model, n_modes, *args, **kwargs)

    for name, module in list(sys.modules.items()):
        if name.startswith("smartjoint") and module is not None:
            for attribute, value in list(vars(module).items()):
                if value is build:
                    monkeypatch.setattr(module, attribute, counted_build)
                elif value is solve:
                    monkeypatch.setattr(module, attribute, counted_solve)
    return calls
