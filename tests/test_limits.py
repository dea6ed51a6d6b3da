"""Sizes a design file controls are bounded before anything is allocated; the zero-energy
check is relative, so slender masts pass and real mechanisms are still refused.

The former hangs (a device as base file, 10⁹ or 2⁶³−1 bays, 10⁵ elements per tube) each run in
one child process whose address space is capped, so a regression fails here instead of filling
the machine; the child times each load call alone (numpy's import is not part of the 2 s) and
reports its peak resident memory after each case.
"""

from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
import textwrap
import tomllib

import numpy as np
import pytest
from conftest import design_file_error, small_truss

from smartjoint.design import DesignError, ModelError, build_model, load_design, parse_design
from smartjoint.design.structure import control_section, spec
from smartjoint.design.structure.files import anchor_paths
from smartjoint.design.structure.modal import count_zero_energy_modes, gross_energy, probe_zero_energy

SECONDS = 2.0
MEGABYTES = 500.0

_REFERENCE = str(spec.REFERENCE_DESIGN)
# name: (file text, key the one-line error must name); {base} is the reference truss.
CASES = {
    "base_dev_zero": ('base = "/dev/zero"\nname = "x"\n', "base"),
    "base_fifo": ('base = "pipe"\nname = "x"\n', "base"),
    "design_is_a_folder": (None, "<file>"),
    "bays_1e9_float": (
        'base = "{base}"\nname = "x"\n[truss]\nbays = 1e9\nbay_length = 1.0\nwidth = 1.0\n'
        'node_type = "m12_ball"\nsection = "tube_22x1_5"\n',
        "truss.bays",
    ),
    "bays_1e9": (
        'base = "{base}"\nname = "x"\n[truss]\nbays = 1000000000\nbay_length = 1.0\nwidth = 1.0\n'
        'node_type = "m12_ball"\nsection = "tube_22x1_5"\n',
        "truss.bays",
    ),
    "bays_2_63": (
        'base = "{base}"\nname = "x"\n[truss]\nbays = 9223372036854775807\nbay_length = 1.0\n'
        'width = 1.0\nnode_type = "m12_ball"\nsection = "tube_22x1_5"\n',
        "truss.bays",
    ),
    "mesh_tube_elements": ('base = "{base}"\nname = "x"\n[mesh]\ntube_elements = 100000\n', "mesh.tube_elements"),
    "truss_tube_elements": (
        'base = "{base}"\nname = "x"\n[truss]\nbays = 10\nbay_length = 1.0\nwidth = 1.0\n'
        'node_type = "m12_ball"\nsection = "tube_22x1_5"\ntube_elements = 100000\n',
        "truss.tube_elements",
    ),
    "dof_estimate": (
        'base = "{base}"\nname = "x"\n[truss]\nbays = 5000\nbay_length = 1.0\nwidth = 1.0\n'
        'node_type = "m12_ball"\nsection = "tube_22x1_5"\nconnector = "m12_screw"\n',
        "truss.bays",
    ),
    "file_too_large": (None, "<file>"),
    "considered_modes": (
        'base = "{base}"\nname = "x"\n[control]\nconsidered_modes = 1000000000\n',
        "control.considered_modes",
    ),
    "study_steps": (
        'base = "{base}"\nname = "x"\n[control]\nstudy_duration = 3000.0\nsample_time = 1e-5\n',
        "control.study_duration",
    ),
}

_CHILD = textwrap.dedent("""
    import json, resource, sys, time
    resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))  # a regression fails, not the machine
    from smartjoint.design import load_design
    from smartjoint.common.errors import SmartjointError
    for name, path in json.loads(sys.argv[1]).items():
        start = time.perf_counter()
        try:
            load_design(path)
            outcome = {"error": None}
        except SmartjointError as error:
            outcome = {"error": str(error), "type": type(error).__name__}
        except BaseException as error:
            outcome = {"error": repr(error), "type": "unexpected " + type(error).__name__}
        outcome["seconds"] = time.perf_counter() - start
        outcome["peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        print(json.dumps({name: outcome}), flush=True)
""")


@pytest.fixture(scope="module")
def former_hangs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("hangs")
    paths = {}
    for name, (text, _) in CASES.items():
        path = folder / f"{name}.toml"
        if text is not None:
            path.write_text(text.replace("{base}", _REFERENCE))
        paths[name] = str(path)
    os.mkfifo(folder / "pipe")  # opening it for reading would block until a writer comes
    (folder / "design_is_a_folder.toml").mkdir()
    with open(folder / "file_too_large.toml", "w") as handle:  # valid TOML, one comment too many
        handle.write('name = "x"\n#' + "x" * (spec.MAX_FILE_BYTES + 10) + "\n")
    done = subprocess.run(
        [sys.executable, "-c", _CHILD, json.dumps(paths)], capture_output=True, text=True, timeout=120
    )
    results = {}
    for line in done.stdout.splitlines():
        results.update(json.loads(line))
    assert done.returncode == 0, done.stderr[-2000:]
    return results


@pytest.mark.parametrize("case", sorted(CASES))
def test_former_hang_is_a_prompt_one_line_error(former_hangs, case):
    outcome = former_hangs[case]
    assert outcome["type"] == "DesignError", outcome
    message = outcome["error"]
    assert "\n" not in message and CASES[case][1] in message, message
    assert outcome["seconds"] < SECONDS, outcome
    assert outcome["peak_mb"] < MEGABYTES, outcome


def test_limit_errors_name_the_allowed_range(former_hangs):
    assert f"1 … {spec.MAX_BAYS}" in former_hangs["bays_2_63"]["error"]
    assert f"1 … {spec.MAX_ELEMENTS}" in former_hangs["mesh_tube_elements"]["error"]
    assert (
        "DOFs" in former_hangs["dof_estimate"]["error"]
        and f"at most {spec.MAX_DOFS}" in former_hangs["dof_estimate"]["error"]
    )
    assert "/dev/zero is a device" in former_hangs["base_dev_zero"]["error"]
    assert "is a FIFO" in former_hangs["base_fifo"]["error"]
    assert f"at most {spec.MAX_FILE_BYTES} bytes" in former_hangs["file_too_large"]["error"]


@pytest.mark.parametrize(
    "truss",
    [
        {},
        {"frame_diagonals": True, "root_battens": True, "tip_node": "diagonal"},
        {"tip_node": "none", "frame_diagonals": True},
    ],
)
def test_dof_estimate_is_the_model_size_before_supports(truss, monkeypatch):
    data = small_truss()
    data["truss"].update(truss)
    if truss.get("tip_node") == "none":
        for key in ("point_masses", "sensors", "disturbances"):
            data[key] = [dict(entry, node="N2_0") for entry in data[key]]
    design = parse_design(data)
    model = build_model(design, joints="released")
    supported = sum(len(s.dofs) for s in design.supports)
    assert spec.estimated_dofs(design.nodes, design.members, len(design.joints)) - supported == model.n_dof
    # the generator counts its mast before making it, the same way: exactly at the limit it
    # passes, one DOF below it is refused naming truss.bays
    generated = spec.estimated_dofs(design.nodes, design.members, 0)
    monkeypatch.setattr(spec, "MAX_DOFS", generated + len(design.joints))
    parse_design(data)
    monkeypatch.setattr(spec, "MAX_DOFS", generated - 1)
    with pytest.raises(DesignError, match=f"truss.bays: 2 — the mast would have {generated} DOFs"):
        parse_design(data)


def test_element_count_of_an_explicit_member_is_bounded():
    data = small_truss()
    data["nodes"] = [{"name": "X", "position": [5.0, 0.0, 0.0]}]
    data["members"] = [{"name": "extra", "start": "N2_0", "end": "X", "section": "tube", "elements": 10**6}]
    with pytest.raises(
        DesignError, match=rf"members\[0\].elements: 1000000 — must be an integer 1 … {spec.MAX_ELEMENTS}"
    ):
        parse_design(data)


def test_base_that_includes_itself_is_named_a_cycle(tmp_path):
    assert "a.toml → a.toml is a cycle" in design_file_error(tmp_path / "a.toml", 'base = "a.toml"\nname = "a"\n')


def test_base_cycle_through_two_files_is_named(tmp_path):
    (tmp_path / "b.toml").write_text('base = "./a.toml"\ndescription = "b"\n')
    message = design_file_error(tmp_path / "a.toml", 'base = "b.toml"\nname = "a"\n')
    assert "a.toml → b.toml → a.toml is a cycle" in message


def test_base_chain_depth_is_bounded_and_the_chain_shown(tmp_path):
    names = [f"level{i}.toml" for i in range(spec.MAX_BASE_DEPTH + 2)]
    for name, base in zip(names, names[1:]):
        (tmp_path / name).write_text(f'base = "{base}"\nname = "{name}"\n')
    (tmp_path / names[-1]).write_text(f'base = "{_REFERENCE}"\n')
    with pytest.raises(DesignError, match=f"at most {spec.MAX_BASE_DEPTH} levels"):
        load_design(tmp_path / names[0])
    design = load_design(tmp_path / names[2])  # a chain of 4 bases is fine
    assert design.name == names[2]


# --------------------------------------------------------------------------- [control] plausibility
def _control_error(**control) -> str:
    data = small_truss()
    data["control"] = control
    with pytest.raises(DesignError) as info:
        parse_design(data)
    return str(info.value)


def test_normal_force_max_above_what_a_piezo_joint_can_set_is_refused():
    message = _control_error(normal_force_max=1e12)
    assert (
        "control.normal_force_max: 1000000000000.0" in message
        and f"<= {control_section.MAX_NORMAL_FORCE:g} N" in message
    )
    message = _control_error(normal_force_max=[400.0, 2e5])
    assert "control.normal_force_max: 200000.0" in message and "entry 1" in message
    parse_design({**small_truss(), "control": {"normal_force_max": control_section.MAX_NORMAL_FORCE}})
    no_joints = {**small_truss(), "joints": [], "control": {"normal_force_max": 1e12}}
    with pytest.raises(DesignError, match="control.normal_force_max: 1000000000000.0"):
        parse_design(no_joints)  # a number for every joint is checked before there are any


def test_normal_force_min_above_max_is_refused_per_joint():
    message = _control_error(normal_force_min=[10.0, 300.0], normal_force_max=[400.0, 200.0])
    assert "control.normal_force_min: 300.0" in message and "F_N^max = 200 N (entry 1)" in message


def test_piezo_preload_above_the_least_normal_force_is_refused():
    message = _control_error(normal_force_min=[20.0, 10.0], piezo_preload=15.0)
    assert "control.piezo_preload: 15.0" in message and "preload <= F_N^min = 10 N" in message
    design = parse_design({**small_truss(), "control": {"normal_force_min": 10.0, "piezo_preload": 10.0}})
    assert design.control.piezo_preload == 10.0


def test_control_sizes_are_bounded():
    assert "control.krylov: 1000 — must be an integer 0 … 20" in _control_error(krylov=1000)
    assert "control.sample_time" in _control_error(sample_time=1e-9)
    assert "control.study_duration" in _control_error(study_duration=1e6)


# --------------------------------------------------------------------------- zero-energy motions
def _pinned_chain(links: int) -> dict:
    """Links along x, the first clamped, each further link hinged to the previous by a type B
    joint about z: a chain of ``links − 1`` free hinges once the joints are released."""
    nodes = [{"name": f"P{i}", "position": [float(i), 0.0, 0.0]} for i in range(links + 1)]
    members = [
        {"name": f"M{i}", "start": f"P{i}", "end": f"P{i + 1}", "section": "tube", "elements": 2} for i in range(links)
    ]
    joints = [
        {"name": f"H{i}", "member": f"M{i}", "end": "start", "type": "B", "axis": [0.0, 0.0, 1.0]}
        for i in range(1, links)
    ]
    data = small_truss()
    for key in ("truss", "point_masses", "sensors", "disturbances", "connectors", "node_types", "mesh"):
        data.pop(key)
    data.update(nodes=nodes, members=members, joints=joints, supports=[{"node": "P0", "dofs": "all"}])
    return data


@pytest.mark.parametrize(
    "name, data, count",
    [
        ("unsupported truss", {**small_truss(), "truss": {**small_truss()["truss"], "clamp_root": False}}, 6),
        (
            "truss pinned at one node",
            {
                **small_truss(),
                "truss": {**small_truss()["truss"], "clamp_root": False},
                "supports": [{"node": "N0_0", "dofs": ["ux", "uy", "uz"]}],
            },
            3,
        ),
        ("pinned chain", _pinned_chain(3), 2),
    ],
)
def test_real_mechanism_is_refused(name, data, count):
    design = parse_design(copy.deepcopy(data))
    with pytest.raises(ModelError, match=f"{count} zero-energy"):
        build_model(design)
    # and the count is the kinematics: the same motions, judged by the relative cut-off
    model = build_model(design, allow_mechanisms=True)
    assert count_zero_energy_modes(model)[0] == count


def test_locked_pinned_chain_is_a_structure():
    model = build_model(parse_design(_pinned_chain(3)), joints="locked")
    assert count_zero_energy_modes(model)[0] == 0


def _reference_mast(bays: int, tube_elements: int) -> dict:
    data = tomllib.loads(spec.REFERENCE_DESIGN.read_text())
    anchor_paths(data, spec.REFERENCE_DESIGN.parent)  # its [friction] files, beside it
    data["truss"]["bays"] = bays
    data["mesh"]["tube_elements"] = tube_elements
    data.pop("updating")
    for point_mass in data["point_masses"]:
        if point_mass["node"].startswith("N"):
            point_mass["node"] = f"N{bays}_{point_mass['node'].split('_')[1]}"
    return data


def test_thousand_bay_mast_is_accepted():
    """The reference mast at 1000 bays (one element per tube keeps the test cheap; the
    connectors, the stiffest elements and so the energy scale, are those of the full model):
    its 0.6 mHz first mode lies below the old absolute cut-off ω² < 1e-4 and well above the
    round-off of its energy. The probe is the one build_model's check runs (8 lowest modes)."""
    design = parse_design(_reference_mast(1000, 1))
    model = build_model(design, joints="locked", allow_mechanisms=True)
    values, vectors, zero = probe_zero_energy(model)
    frequency = np.sqrt(values[0]) / (2 * np.pi)
    assert 0.4e-3 < frequency < 0.8e-3 and values[0] < 1e-4
    ratio = values / gross_energy(model.stiffness, vectors) / np.finfo(float).eps
    assert not zero.any(), ratio
    assert ratio.min() > 3.0, ratio  # a safe distance from the cut-off (1 eps), not a near miss
