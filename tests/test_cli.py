"""Command line contracts: --help, --json shapes, exit codes, the run report."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from conftest import cli_error, run_cli

from smartjoint.cli import main


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


def test_run_writes_a_complete_report(tmp_path, capsys):
    import tomli_w
    from conftest import small_truss

    design = tmp_path / "small.toml"
    design.write_text(tomli_w.dumps(small_truss()))
    out = tmp_path / "report"
    assert main(["run", str(design), "-o", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    for name in ("report.md", "mode_shapes.png", "spectrum.png", "summary.json"):
        assert (out / name).stat().st_size > 0
    assert summary["modes_released_hz"][0] < summary["modes_hz"][0]
    # Control study, controller artefact and generated firmware join the report.
    from smartjoint.design.control import artifact

    assert artifact.load(out / "controller.json").artifact_sha256 == summary["control"]["artifact_sha256"]
    assert set(summary["control"]["runs"]) == {"passive F_min", "passive F_max", "SISO", "cLQG", "active LQG"}
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
    for fault in sil_summary["faults"]["faults"]:  # the demonstration faults: safe within 3 cycles, recovered
        assert fault["joints"] is not None and fault["joints"] <= 3 and fault["firmware"] <= 3, fault
        assert fault["recovery"] is not None
    assert (out / "sil_faults.png").stat().st_size > 0
    safety = sil_summary["safety"]  # every fault kind on every frame (docs/safety.md)
    assert safety["cases"] > 100 and safety["failed"] == [] and safety["worst_joint_cycles"] <= 3
    assert (out / "safety_cases.md").read_text().count("\n|") > safety["cases"]
    assert (out / "safety_cycles.png").stat().st_size > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report", "small.toml"]  # no staging or claim left


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
