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


def test_joints_without_friction_are_refused_before_any_fe_work(tmp_path, capsys, monkeypatch):
    """No [friction.A], no joint's own and no records: `run`, `design` and `reduce` stop in one line
    naming the joint, before the FE model is built and without writing anything; a design whose
    [placement] would put type A joints on it is refused the same way."""
    from smartjoint.design.structure import fem

    def no_fe_work(*args, **kwargs):
        raise AssertionError("FE work before the friction check")

    monkeypatch.setattr(fem.FEModel, "__init__", no_fe_work)  # every build_model ends in one
    data = small_truss()
    del data["friction"]
    placed = _without_joints()
    del placed["friction"]
    placed["placement"] = {"modes": [1], "count": 1}
    for name, design, where in (("bare.toml", data, "joints[0].friction"), ("placed.toml", placed, "placement")):
        (tmp_path / name).write_text(tomli_w.dumps(design))
        for command in (
            ["run", "-o", str(tmp_path / "report")],
            ["design", "-o", str(tmp_path / "c.json")],
            ["reduce"],
        ):
            assert main([command[0], str(tmp_path / name), *command[1:]]) == 2
            err = capsys.readouterr().err.strip()
            assert err.count("\n") == 0 and f"{where}: missing" in err and "no friction parameters" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bare.toml", "placed.toml"]


def test_records_of_the_joints_type_stand_in_for_its_parameters(tmp_path):
    from smartjoint.design.friction.stage import check_friction_given

    record = tmp_path / "a.csv"
    record.write_text(
        "# joint_type = A\n# inertia = 1 kg\ntime [s],sliding_velocity [m/s],friction_force [N],normal_force [N]\n"
        + "".join(f"{k * 1e-3},{1e-3 * k},{0.3 * k},400.0\n" for k in range(50))
    )
    data = small_truss()
    data["friction"] = {"B": data["friction"]["B"], "records": [str(record)]}
    (tmp_path / "d.toml").write_text(tomli_w.dumps(data))
    check_friction_given(load_design(tmp_path / "d.toml"))  # type A from the records, type B given


def test_a_stage_that_stops_the_run_leaves_the_report_of_the_stages_before_it(tmp_path, capsys):
    """A sample time too coarse for the retained modes stops stage 6 in one line that names the
    choices; the report folder holds the structure, friction and reduction and says where it stopped."""
    data = small_truss()
    data["control"] = {"sample_time": 0.02}
    (tmp_path / "coarse.toml").write_text(tomli_w.dumps(data))
    out = tmp_path / "report"
    assert main(["run", str(tmp_path / "coarse.toml"), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("smartjoint run: error: stage 6 (control): sample_time: 0.02 s is too coarse"), err
    assert "use Δt <" in err and "retain fewer modes" in err and str(out / "report.md") in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stopped"].startswith("stage 6 (control)") and summary["control"] is None
    assert summary["friction"]["types"] and summary["reduction"]["normal_forces"]
    report = (out / "report.md").read_text()
    assert "## Stopped" in report and "The run stopped at stage 6 (control)" in report
    assert (out / "reduction_bode.png").is_file() and not (out / "controller.json").exists()


def test_the_placed_triangular_mast_gets_its_controller_and_the_mode_no_sensor_sees_is_named(tmp_path):
    """Issue 36's case: a 6-bay triangular mast with F_N^max = 200 N and its joints placed by
    [placement]. Stage 6 stopped on it ("no sensor sees mode 9 … drop it from the reduced model",
    with no setting to do so); its axial modes are symmetric, the tip sensors see one of them not at
    all. The design model keeps it, the LQG exists and is stable, and the design names it; the
    reduction study's forces come from the design's own limits (`smartjoint run` on it: a full
    report, every constant F_N within 5 … 200 N)."""
    from conftest import triangular_mast

    from smartjoint.design.control import study as closed_loop
    from smartjoint.design.reduction.study import load_case

    (tmp_path / "mast.toml").write_text(tomli_w.dumps(triangular_mast()))
    placed, _ = place_joints(load_design(tmp_path / "mast.toml"), tmp_path, lambda line: None)
    assert [j.type for j in placed.joints] == ["A", "A", "A"]
    assert load_case(placed).tolist() == [200.0, 5.0, 5.0]
    model = closed_loop.design_model(placed, lambda line: None)
    lqg = closed_loop.lqg_for(placed, model)
    blind = closed_loop.blind_modes_hz(lqg, model)
    assert len(blind["unseen"]) >= 1 and blind["unmoved"] == [], blind
    assert all(f > 0 for f in blind["unseen"])
    assert abs(lqg.closed_loop_poles()).max() < 1.0
