"""The design file drives the joints' friction: [friction] by type, a joint's own, parameter
files relative to the file that names them, records, and never the paper's Table 1 by default."""

from __future__ import annotations

import copy

import pytest
import tomli_w
from conftest import TABLE_1_A, TABLE_1_B, small_truss

from smartjoint.common.errors import DesignError
from smartjoint.design import load_design, parse_design
from smartjoint.design.friction import lugre, rig
from smartjoint.design.friction.model import joint_parameters
from smartjoint.design.friction.records import write_record

OTHER_A = {"sigma0": 2.0e5, "sigma1": 0.01, "sigma2": 0.0, "coulomb": 0.3, "stribeck": 0.0, "stribeck_velocity": 0.05}


def _laws(data: dict) -> list[lugre.LuGreParameters]:
    return joint_parameters(parse_design(data))


def test_each_joint_gets_its_types_parameters_or_its_own():
    data = small_truss()
    assert _laws(data) == [lugre.LuGreParameters(**TABLE_1_A), lugre.LuGreParameters(**TABLE_1_B)]
    data["joints"][0]["friction"] = dict(OTHER_A)
    laws = _laws(data)
    assert laws[0] == lugre.LuGreParameters(**OTHER_A) and laws[1].radius == TABLE_1_B["radius"]
    assert parse_design(data).joint_friction(parse_design(data).joints[0]).source == "<memory> [joints[0].friction]"


def test_a_joint_without_parameters_is_named_and_nothing_falls_back_to_table_1():
    data = small_truss()
    del data["friction"]["B"]
    design = parse_design(data)  # the structure needs no friction
    with pytest.raises(
        DesignError, match=r"joints\[1\]\.friction: missing — joint 'JB' \(type B\) has no friction parameters"
    ):
        joint_parameters(design)


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda f: f["A"].pop("coulomb"), r"friction\.A\.coulomb: missing"),
        (lambda f: f["A"].update(sigma0=-1.0), r"friction\.A\.sigma0: -1\.0 — .*> 0"),
        (lambda f: f["A"].update(radius=0.01), r"friction\.A\.radius: 0\.01 — a type A joint has no radius"),
        (lambda f: f["B"].pop("radius"), r"friction\.B\.radius: missing"),
        (lambda f: f["A"].update(mu=0.3), r"friction\.A.*mu"),
        (lambda f: f.update(C=dict(TABLE_1_A)), r"friction.*C"),
        (lambda f: f.update(records=[]), r"friction\.records: \[\] — expected a non-empty list"),
        (lambda f: f.update(records=["/nonexistent/*.csv"]), r"friction\.records: '/nonexistent/\*\.csv' — matches no"),
    ],
)
def test_bad_friction_is_a_one_line_error(edit, message):
    data = small_truss()
    edit(data["friction"])
    with pytest.raises(DesignError, match=message) as error:
        parse_design(data)
    assert "\n" not in str(error.value)


def test_parameter_files_are_read_relative_to_the_file_that_names_them(tmp_path):
    """A base design in another folder names its parameter file; the design extending it, and
    its own joint's file, are resolved where each was written."""
    (tmp_path / "base" / "joints").mkdir(parents=True)
    (tmp_path / "user").mkdir()
    base = small_truss()
    base["friction"] = {"A": {"file": "joints/a.toml"}, "B": {"file": "joints/b.toml"}}
    (tmp_path / "base" / "joints" / "a.toml").write_text(tomli_w.dumps({"joint_type": "A", **TABLE_1_A}))
    (tmp_path / "base" / "joints" / "b.toml").write_text(tomli_w.dumps(TABLE_1_B))
    (tmp_path / "base" / "design.toml").write_text(tomli_w.dumps(base))
    joints = copy.deepcopy(base["joints"])
    joints[0]["friction"] = "own_a.toml"
    (tmp_path / "user" / "own_a.toml").write_text(tomli_w.dumps(OTHER_A))
    user = {"base": "../base/design.toml", "name": "user", "joints": joints}
    (tmp_path / "user" / "design.toml").write_text(tomli_w.dumps(user))
    design = load_design(tmp_path / "user" / "design.toml")
    laws = joint_parameters(design)
    assert laws == [lugre.LuGreParameters(**OTHER_A), lugre.LuGreParameters(**TABLE_1_B)]
    assert design.friction["B"].source == str(tmp_path / "base" / "joints" / "b.toml")
    assert len(design.friction["B"].sha256) == 64


def test_a_parameter_file_of_the_other_type_is_refused(tmp_path):
    (tmp_path / "b.toml").write_text(tomli_w.dumps({"joint_type": "B", **TABLE_1_B}))
    data = small_truss()
    data["friction"]["A"] = {"file": str(tmp_path / "b.toml")}
    with pytest.raises(DesignError, match="holds type 'B' parameters, for type A joints"):
        parse_design(data)


def test_records_are_found_by_pattern_in_sorted_order(tmp_path):
    record = rig.simulate(rig.RigTest("B", 200.0, 0.5, 10.0, cycles=1.0, inertia=2e-3, sample_rate=2000.0))
    (tmp_path / "rig").mkdir()
    for name in ("r2.csv", "r1.csv"):
        write_record(record, tmp_path / "rig" / name)
    data = small_truss()
    data["friction"]["records"] = [str(tmp_path / "rig" / "*.csv"), str(tmp_path / "rig" / "r1.csv")]
    design = parse_design(data)
    assert design.friction_records == (str(tmp_path / "rig" / "r1.csv"), str(tmp_path / "rig" / "r2.csv"))


def test_a_design_named_by_a_relative_path_gives_absolute_file_names(tmp_path, monkeypatch):
    """The run reports records and parameter files from its own folder: they must not depend on
    the working directory the design was named from."""
    record = rig.simulate(rig.RigTest("B", 200.0, 0.5, 10.0, cycles=1.0, inertia=2e-3, sample_rate=2000.0))
    (tmp_path / "rig").mkdir()
    write_record(record, tmp_path / "rig" / "r1.csv")
    data = small_truss()
    data["friction"]["records"] = ["rig/*.csv"]
    (tmp_path / "design.toml").write_text(tomli_w.dumps(data))
    monkeypatch.chdir(tmp_path)
    assert load_design("design.toml").friction_records == (str(tmp_path / "rig" / "r1.csv"),)
