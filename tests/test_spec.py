"""Malformed design files get one clear line naming the key, the value and what is allowed."""

from __future__ import annotations

import pytest
from conftest import cli_error, design_file_error, small_truss

from smartjoint.design import DesignError, ModelError, build_model, load_design, parse_design


def _error(data) -> str:
    with pytest.raises(DesignError) as info:
        parse_design(data)
    return str(info.value)


def test_reference_design_loads():
    design = load_design()
    assert design.name == "meroform-10bay"
    assert len(design.nodes) == 45  # 11 frames of 4 corners + the tip node: five free-end nodes
    assert sum(p.mass for p in design.point_masses) == pytest.approx(2.5)
    assert len(design.sha256) == 64


def test_missing_key():
    data = small_truss()
    del data["materials"]["aluminium"]["density"]
    assert "materials.aluminium.density: missing — required key" in _error(data)


def test_wrong_type():
    data = small_truss()
    data["truss"]["bays"] = "ten"
    message = _error(data)
    assert "truss.bays: 'ten'" in message and "integer" in message


def test_unknown_joint_type():
    data = small_truss()
    data["joints"][0]["type"] = "C"
    message = _error(data)
    assert "joints[0].type: 'C'" in message and "'A', 'B'" in message


def test_member_to_missing_node():
    data = small_truss()
    data["nodes"] = [{"name": "X", "position": [5.0, 0.0, 0.0], "type": "ball"}]
    data["members"] = [{"name": "extra", "start": "X", "end": "NOPE", "section": "tube"}]
    message = _error(data)
    assert "members[0].end: 'NOPE'" in message and "no node of that name" in message


def test_zero_length_member():
    data = small_truss()
    data["nodes"] = [{"name": "X", "position": [0.0, -0.5, -0.5], "type": "ball"}]
    data["members"] = [{"name": "short", "start": "X", "end": "N0_0", "section": "tube", "connector": "c"}]
    message = _error(data)
    assert "members.short: 0.0" in message and "must exceed" in message


def test_unknown_key_is_named():
    data = small_truss()
    data["truss"]["bay_lenght"] = 1.0
    message = _error(data)
    assert "truss.bay_lenght" in message and "unknown key" in message


def test_type_b_axis_must_be_perpendicular():
    data = small_truss()
    data["joints"][1]["axis"] = [1.0, 0.0, 1.0]
    assert "joints[1].axis" in _error(data)


def test_negative_and_non_finite_numbers():
    data = small_truss()
    data["connectors"]["c"]["axial_stiffness"] = -1.0
    assert "connectors.c.axial_stiffness: -1.0 — must be > 0" in _error(data)
    data = small_truss()
    data["materials"]["aluminium"]["youngs_modulus"] = float("nan")
    assert "finite" in _error(data)


def test_unsupported_structure_is_refused():
    data = small_truss()
    data["truss"]["clamp_root"] = False
    with pytest.raises(ModelError, match="zero-energy"):
        build_model(parse_design(data))


def test_not_toml(tmp_path):
    assert "not valid TOML" in design_file_error(tmp_path / "bad.toml", "name = [unclosed\n")


def test_command_line_reports_one_line(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('schema = "smartjoint-design/1"\nname = "x"\n[truss]\nbays = 0\n')
    assert "truss.bays: 0" in cli_error("modes", path)


def test_base_file_supplies_the_keys_a_design_does_not_set(tmp_path):
    from smartjoint.design.structure.spec import REFERENCE_DESIGN, load_design

    child = tmp_path / "child.toml"
    child.write_text(f'base = "{REFERENCE_DESIGN}"\nname = "child"\n')
    design = load_design(child)
    reference = load_design()
    assert design.name == "child" and design.members == reference.members and design.sha256 != reference.sha256
    assert "base" in design_file_error(child, 'base = "missing.toml"\nname = "child"\n')


@pytest.mark.parametrize(
    "argument, expected",
    [
        ("/dev/zero", "/dev/zero is a device; a design file must be a regular file"),
        ("{folder}", "is a folder; a design file must be a regular file"),
        ("{cycle}", "cycle.toml → cycle.toml is a cycle"),
        ("{huge}", "truss.bays: 9223372036854775807 — must be an integer 1 … 5000"),
    ],
)
def test_command_line_refuses_unbounded_inputs_in_one_line(tmp_path, argument, expected):
    (tmp_path / "cycle.toml").write_text('base = "cycle.toml"\nname = "x"\n')
    (tmp_path / "huge.toml").write_text('name = "x"\n[truss]\nbays = 9223372036854775807\n')
    path = argument.format(folder=tmp_path, cycle=tmp_path / "cycle.toml", huge=tmp_path / "huge.toml")
    line = cli_error("modes", path, timeout=60)
    assert expected in line, line


def test_integer_keys_state_their_range():
    data = small_truss()
    data["mesh"]["tube_elements"] = 0
    assert "mesh.tube_elements: 0 — must be an integer 1 … 1000" in _error(data)
    data = small_truss()
    data["truss"]["bays"] = 2.0
    assert "truss.bays: 2.0 — expected an integer 1 … 5000" in _error(data)
