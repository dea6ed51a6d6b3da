"""`smartjoint run` on a design without joints: it places them by the design's [placement], or it
stops before the stages that need joints with the reason — it never substitutes another truss."""

from __future__ import annotations

import json

import tomli_w
from conftest import small_truss

from smartjoint.cli import main
from smartjoint.design import load_design, parse_design
from smartjoint.design.friction.stage import PLACED_DESIGN, place_joints


def _without_joints() -> dict:
    data = small_truss()
    del data["joints"]
    return data


def test_a_design_without_joints_or_placement_stops_after_the_structure(tmp_path, capsys):
    design = tmp_path / "bare.toml"
    design.write_text(tomli_w.dumps(_without_joints()))
    out = tmp_path / "report"
    assert main(["run", str(design), "-o", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert "no [[joints]] and no [placement]" in summary["skipped"]
    assert all(summary[stage] is None for stage in ("friction", "reduction", "control", "firmware", "sil"))
    assert summary["design"]["name"] == "small" and summary["modes_hz"]
    report = (out / "report.md").read_text()
    assert "# smartjoint report: small" in report and "Not run: the design has no [[joints]]" in report
    assert not (out / "controller.json").exists() and not (out / "firmware").exists()


def test_placement_puts_type_a_joints_on_the_design_and_writes_it(tmp_path):
    data = _without_joints()
    data["placement"] = {"modes": [1, 2], "count": 2}
    (tmp_path / "bare.toml").write_text(tomli_w.dumps(data))
    design = load_design(tmp_path / "bare.toml")
    lines = []
    placed, name = place_joints(design, tmp_path, lines.append)
    assert name == PLACED_DESIGN and [j.name for j in placed.joints] == ["A1", "A2"]
    assert {j.type for j in placed.joints} == {"A"} and len({j.member for j in placed.joints}) == 2
    assert "placed 2 type A joints by [placement] for modes 1, 2" in lines[0]
    written = load_design(tmp_path / PLACED_DESIGN)  # the file in the report reproduces the design
    assert [(j.member, j.end) for j in written.joints] == [(j.member, j.end) for j in placed.joints]
    assert written.friction == design.friction  # the design's own friction, through its base
    unchanged, none = place_joints(parse_design(small_truss()), tmp_path, lines.append)
    assert none is None and [j.name for j in unchanged.joints] == ["JA", "JB"]  # own joints kept
