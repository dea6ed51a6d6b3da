"""Command line contracts: --help, --json shapes, exit codes, the run report."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from conftest import cli_error, count_model_calls, run_cli
from test_rig_cli import JOINT_B

from smartjoint.cli import main
from smartjoint.common import law_registry


def test_help_lists_commands():
    done = run_cli("--help")
    assert done.returncode == 0
    for command in ("run", "modes", "update", "export-model"):
        assert command in done.stdout


def test_modes_json_has_the_documented_shape():
    done = run_cli("modes", "--no-update", "-n", "5", "--json")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert [m["index"] for m in out["modes"]] == [1, 2, 3, 4, 5]
    frequencies = [m["frequency_hz"] for m in out["modes"]]
    assert frequencies == sorted(frequencies) and frequencies[0] > 1.0
    comparison = out["ema_comparison"]
    assert comparison[0] == {
        "index": 1,
        "ema_hz": 4.49,
        "fem_hz": comparison[0]["fem_hz"],
        "error_pct": pytest.approx(100 * (comparison[0]["fem_hz"] - 4.49) / 4.49),
    }
    assert [c["index"] for c in comparison] == [1, 2, 3, 4, 5, 7, 8, 12, 17]


def test_missing_design_file_is_one_line(tmp_path):
    done = run_cli("modes", tmp_path / "nope.toml")
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "cannot read design file" in done.stderr


# A user's joints, not the paper's: type A given inline, type B identified from its rig records.
USER_TYPE_A = {
    "sigma0": 2.1e5,
    "sigma1": 0.03,
    "sigma2": 0.015,
    "coulomb": 0.45,
    "stribeck": 0.2,
    "stribeck_velocity": 0.015,
}
USER_TYPE_B = JOINT_B  # test_rig_cli's type B joint, not Table 1's


class _Forbidden(dict):
    """The paper's Table 1, made to fail on any use."""

    def __getitem__(self, key):
        raise AssertionError(f"the run read the paper's Table 1 (type {key})")

    get = __getitem__


USER_FORCES = (12.0, 300.0)  # [N]: the user's F_N^min, F_N^max (the paper's are 10 and 400)


def _user_design(tmp_path, capsys) -> Path:
    """small_truss (not the paper's: 2 bays, a type B joint, a velocity sensor) with its own
    friction: type A inline, type B from the records `smartjoint rig` writes for USER_TYPE_B at
    1 % noise, the design file's own type B file a wrong prior the records replace."""
    import tomli_w
    from conftest import small_truss

    prior = tmp_path / "joint_b_prior.toml"  # the design file's wrong guess: the rig is designed from it
    prior.write_text(tomli_w.dumps({**USER_TYPE_B, "sigma0": 5e4, "coulomb": 0.5}))
    (tmp_path / "joint_b.toml").write_text(tomli_w.dumps({"joint_type": "B", **USER_TYPE_B}))
    rig = ["rig", "--parameters", str(tmp_path / "joint_b.toml"), "--prior", str(prior), "--campaign"]
    assert main([*rig, "--noise", "0.01", "--cycles", "8", "-o", str(tmp_path / "rig"), "--json"]) == 0
    capsys.readouterr()
    data = small_truss()
    data["friction"] = {"A": dict(USER_TYPE_A), "B": {"file": "joint_b_prior.toml"}, "records": ["rig/*.csv"]}
    data["control"] = {"normal_force_min": USER_FORCES[0], "normal_force_max": USER_FORCES[1]}  # not the paper's
    design = tmp_path / "small.toml"
    design.write_text(tomli_w.dumps(data))
    return design


def _firmware_folder_is_codegens(out) -> None:
    """The run's firmware folder is what `smartjoint codegen` writes: with the nodes and their supervisor."""
    names = {path.name for path in (out / "firmware").iterdir()}
    assert {"smartjoint_node.c", "smartjoint_node_config.c", "smartjoint_supervisor.c"} <= names


def test_run_writes_a_complete_report(tmp_path, capsys, monkeypatch):
    """The whole run on a user's truss that is not the paper's; nothing in it reads the paper's
    Table 1 or a bundled design, and the user's joints, friction and sensors reach the artefact
    and the report (the identified type B parameters within 5 % at 1 % noise)."""
    import io
    import os

    from smartjoint.common import package_data
    from smartjoint.design.friction import lugre

    design = _user_design(tmp_path, capsys)
    bundled = package_data.folder("smartjoint.design", "data").resolve()

    def guarded(opener):
        def open_outside_the_bundled_designs(path, *args, **kwargs):
            if isinstance(path, (str, os.PathLike)):
                assert bundled not in Path(path).resolve().parents, f"the run read the bundled {path}"
            return opener(path, *args, **kwargs)

        return open_outside_the_bundled_designs

    monkeypatch.setattr(os, "open", guarded(os.open))
    monkeypatch.setattr(io, "open", guarded(io.open))
    monkeypatch.setattr(lugre, "TABLE_1", _Forbidden())
    out = tmp_path / "report"
    calls = count_model_calls(monkeypatch)
    forces = _record_normal_forces(monkeypatch)
    assert main(["run", str(design), "-o", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    _forces_within_the_users_limits(forces, summary)
    # Every stage of the run on the structure stage's models: each FE model built once (locked,
    # released), each one's modes solved once, the reduction study's full reference apart.
    assert dict(calls) == {("build", "locked"): 1, ("build", "released"): 1, ("solve", False): 2, ("solve", True): 1}
    _user_friction_reaches_the_artifact(out, summary)
    for name in ("report.md", "mode_shapes.png", "spectrum.png", "summary.json"):
        assert (out / name).stat().st_size > 0
    assert summary["modes_released_hz"][0] < summary["modes_hz"][0]
    # The controllers' design model against balanced truncation at its order, in the report:
    # its static joint compliance is exact (quasi-static corrections keep their stiffness).
    compared = summary["reduction"]["design_model_comparison"]
    assert not compared["skipped"] and compared["order"] == summary["control"]["states"], compared
    static = compared["static_compliance_error"]
    assert static["design model"] < 1e-6 < static["bt"], static
    assert (out / "reduction_bode.png").stat().st_size > 0 and "against balanced truncation" in (
        out / "report.md"
    ).read_text()
    # Control study, controller artefact and generated firmware join the report.
    from smartjoint.design.control import artifact

    assert artifact.load(out / "controller.json").artifact_sha256 == summary["control"]["artifact_sha256"]
    assert set(summary["control"]["runs"]) == {"passive F_min", "passive F_max", *law_registry.DISPLAY, "active LQG"}
    assert (out / "control_energy.png").stat().st_size > 0 and (out / "firmware" / "smartjoint_clqg.c").exists()
    check = summary["firmware"]["back_to_back"]
    assert check["cLQG"]["double_identical_samples"] == check["cLQG"]["samples"]
    assert set(check["float_orderings"]) >= {"siso_below_both_passive", "clqg_tip_rms_below_siso"}
    assert "back-to-back" in (out / "report.md").read_text()
    sil_summary = summary["sil"]
    assert sil_summary["planned_bus_load"] < 0.7 and (out / "sil_energy.png").stat().st_size > 0
    for law in ("siso", "clqg"):
        assert sil_summary["laws"][law]["bus"]["e2e_errors"] == 0
        assert (out / "can" / f"sil_{law}.blf").stat().st_size > 0
    assert (out / "firmware" / "bus.dbc").exists() and "Software in the loop" in (out / "report.md").read_text()
    _firmware_folder_is_codegens(out)
    labels = [fault["fault"] for fault in sil_summary["faults"]["faults"]]  # the user's frames and joints
    assert labels == ["drop JOINT_JA", "corrupt_crc TIP_SENSORS", "amplifier JB over_temperature", "bus_off bus"], (
        labels
    )
    for fault in sil_summary["faults"]["faults"]:  # the demonstration faults: safe within 3 cycles, recovered
        assert fault["joints"] is not None and fault["joints"] <= 3 and fault["firmware"] <= 3, fault
        assert fault["recovery"] is not None
    assert (out / "sil_faults.png").stat().st_size > 0
    safety = sil_summary["safety"]  # every fault kind on every frame (docs/safety.md)
    assert safety["cases"] > 100 and safety["failed"] == [] and safety["worst_joint_cycles"] <= 3
    assert (out / "safety_cases.md").read_text().count("\n|") > safety["cases"]
    assert (out / "safety_cycles.png").stat().st_size > 0
    written = ["joint_b.toml", "joint_b_prior.toml", "report", "rig", "small.toml"]
    assert sorted(p.name for p in tmp_path.iterdir()) == written


def _forces_within_the_users_limits(forces: dict, summary: dict) -> None:
    """Every normal force the run held constant (reduction, passive runs, the pulse's hold) and the
    best constant forces of the ensemble lie within the user's limits: no paper value."""
    assert {"reduction", "passive", "hold"} <= set(forces), forces.keys()
    for where, values in forces.items():
        assert USER_FORCES[0] <= min(values) and max(values) <= USER_FORCES[1], (where, min(values), max(values))
    assert summary["reduction"]["normal_forces"] == [USER_FORCES[1], USER_FORCES[0]]
    for force in summary["ensemble"]["best_passive_normal_force_median"].values():
        assert USER_FORCES[0] <= force <= USER_FORCES[1], force


def _record_normal_forces(monkeypatch) -> dict:
    """Every constant F_N a run in this process holds: where → the forces."""
    from smartjoint.design import plant
    from smartjoint.design.reduction import study

    found: dict = {}

    def record(where, values):
        found.setdefault(where, []).extend(np.ravel(values).tolist())

    simulation = study._pulse_simulation
    monkeypatch.setattr(study, "_pulse_simulation", lambda d, f, *a: record("reduction", f) or simulation(d, f, *a))
    step, hold = plant.ConstantNormalForce.step, plant.HoldDuringExcitation.__init__
    monkeypatch.setattr(
        plant.ConstantNormalForce, "step", lambda self, m: record("passive", self.normal_forces) or step(self, m)
    )
    monkeypatch.setattr(
        plant.HoldDuringExcitation, "__init__", lambda self, i, u, f: record("hold", f) or hold(self, i, u, f)
    )
    return found


def _user_friction_reaches_the_artifact(out: Path, summary: dict) -> None:
    from smartjoint.design.control import artifact

    loaded = artifact.load(out / "controller.json")
    assert loaded.joint_names == ("JA", "JB") and loaded.joint_types == ("A", "B")
    assert loaded.sensor_names == ("tip_y", "tip_vz") and loaded.sensor_quantities == ("displacement", "velocity")
    names = ("sigma0", "sigma1", "sigma2", "coulomb", "stribeck", "stribeck_velocity")
    assert loaded.friction_parameters[0].tolist() == [USER_TYPE_A[n] for n in names]  # inline, as given
    identified = dict(zip(names, loaded.friction_parameters[1]))
    for name in ("sigma0", "coulomb", "stribeck", "stribeck_velocity"):  # identified from the records
        assert identified[name] == pytest.approx(USER_TYPE_B[name], rel=0.05), name
    assert loaded.friction_radius.tolist() == [0.0, 0.015]
    assert loaded.friction_sources[0] == "small.toml [friction.A]"
    records = len(list((out.parent / "rig").iterdir()))
    source = loaded.friction_sources[1]
    assert source.startswith(f"identified by this run from {records} rig records")
    # What the records do not determine comes from the design's own type B table, never the estimate.
    prior = tomllib.loads((out.parent / "joint_b_prior.toml").read_text())
    for name in ("sigma1", "sigma2"):
        if name in source:
            assert "not identified by them: the design's value" in source
            assert identified[name] == prior[name], name
    joints = summary["friction"]["joints"]
    assert joints["JB"]["file"] == "friction_B.toml" and (out / "friction_B.toml").exists()
    assert [joints["JB"][n] for n in names] == loaded.friction_parameters[1].tolist()
    report = (out / "report.md").read_text()
    for text in ("| JA | A | 2.1e+05 |", "| JB | B |", f"identified by this run from {records} rig records", "tip_vz"):
        assert text in report, text


def test_interrupt_while_the_command_line_imports_is_one_line_and_exit_130():
    """Ctrl-C during the seconds the console script spends importing numpy, scipy and the stages:
    one line, exit 130, no traceback (the interrupt is raised by the import of smartjoint.cli)."""
    code = (
        "import sys\n"
        "class Interrupting:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'smartjoint.cli':\n"
        "            raise KeyboardInterrupt\n"
        "sys.meta_path.insert(0, Interrupting())\n"
        "from smartjoint.console import main\n"
        "sys.exit(main())\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 130
    assert done.stderr.strip().splitlines() == ["smartjoint: interrupted (SIGINT) while starting"]


def test_the_console_script_runs_the_command_line():
    from importlib.metadata import entry_points

    (script,) = [e for e in entry_points(group="console_scripts") if e.name == "smartjoint"]
    assert script.value == "smartjoint.console:main"


@pytest.mark.parametrize("name", ["double", "counter", "_Tip"])
@pytest.mark.parametrize("command", [["run", "-o", "report"], ["design", "-o", "controller.json"]])
def test_a_sensor_name_the_firmware_cannot_carry_is_refused_before_any_work(tmp_path, name, command):
    """'double' is a C keyword, 'counter' an E2E signal of the sensor frame, '_Tip' a reserved
    identifier: refused at once with the design file's key, and nothing is written."""
    import tomli_w
    from conftest import small_truss

    data = small_truss()
    data["sensors"][0]["name"] = name
    design = tmp_path / "small.toml"
    design.write_text(tomli_w.dumps(data))
    line = cli_error(command[0], design, *command[1:], cwd=tmp_path, timeout=60)
    assert f"sensors[0].name: {name!r}" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small.toml"]


def test_update_without_an_updating_section_is_refused_before_the_fe_model(tmp_path, monkeypatch, capsys):
    """``smartjoint update`` on a design without [updating]: one line naming the file, and no FE
    model built first (17 s on the 1000-bay mast, issue 31)."""
    import tomli_w
    from conftest import count_model_calls, small_truss

    design = tmp_path / "small.toml"
    design.write_text(tomli_w.dumps(small_truss()))
    calls = count_model_calls(monkeypatch)
    assert main(["update", str(design)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "has no [updating] section" in err[0] and str(design) in err[0], err
    assert not calls, calls


def test_reduce_on_a_users_design_holds_only_the_users_normal_forces(tmp_path, capsys, monkeypatch):
    """`smartjoint reduce` on a truss that is not the paper's, F_N within 12 … 300 N: its load case
    (the first joint at the user's F_N^max, the other at F_N^min) and every force its simulations
    hold come from the design, no 400 N."""
    import tomli_w
    from conftest import small_truss

    data = small_truss()
    data["control"] = {"normal_force_min": USER_FORCES[0], "normal_force_max": USER_FORCES[1], "considered_modes": 20}
    (tmp_path / "user.toml").write_text(tomli_w.dumps(data))
    forces = _record_normal_forces(monkeypatch)
    argv = ["reduce", str(tmp_path / "user.toml"), "--modes", "8", "--duration", "0.05", "--json"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["normal_forces"] == [USER_FORCES[1], USER_FORCES[0]], summary["normal_forces"]
    assert forces["reduction"] and all(USER_FORCES[0] <= f <= USER_FORCES[1] for f in forces["reduction"])
