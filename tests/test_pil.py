"""Processor in the loop (bench/pil.py, bench/pil_study.py, firmware/target/mps2_an386/pil.c): the
firmware executing on the emulated Cortex-M4F behind python-can's slcan interface commands, in
the study's closed loop, exactly what the host float build commands, sample by sample; injected
faults reach the safe force within three cycles on the target too; a target that stops answering
is an error within its timeout, never a hang; without the tools the stage says why it is skipped."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import cli_error, run_cli

from smartjoint.bench import firmware, pil, pil_study, safety, target
from smartjoint.common.errors import ModelError
from smartjoint.design.control import artifact
from smartjoint.design.network import plan
from smartjoint.pipeline_target import pil_markdown, pil_stage

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = artifact.load(ROOT / "firmware" / "generated" / "controller.json")
REASON = target.missing_tools()
needs_target = pytest.mark.skipif(REASON is not None, reason=f"{REASON} (CI installs them)")


@pytest.fixture(scope="module")
def short_study(three_type_a):
    """The MIL study of the reference artefact over its first 0.25 s (pulse and stick–slip onset)."""
    design, model = three_type_a
    design = dataclasses.replace(design, control=dataclasses.replace(design.control, study_duration=0.25))
    return pil_study.mil_study(design, model, REFERENCE, progress=lambda line: None)


@needs_target
def test_the_target_powers_up_in_the_safe_state_and_counts_nothing(tmp_path):
    with pil.TargetFirmware(REFERENCE, "clqg") as image:
        assert image.safe and np.array_equal(image.command, REFERENCE.safe_normal_force)
        assert all(value == 0 for value in image.counters.values())
        measured = image.measurements()
        assert measured["step"]["calls"] == 0 and 0 < measured["stack_high_water"] < measured["stack_size"]
        host = firmware.Firmware(REFERENCE, "clqg", "float")
        assert image.faults == host.faults and image.safe == host.safe


@needs_target
@pytest.mark.parametrize("law", ["siso", "clqg"])
def test_the_target_commands_what_the_host_float_build_commands_at_every_sample(short_study, law):
    """Same frames in, same forces out: both loops stay on one trajectory, so any difference in
    the target's arithmetic would show at the first sample it matters and part them."""
    figures = pil_study.law_on_target(short_study.setup, REFERENCE, law)
    difference = figures["difference"]
    assert difference["samples"] == round(short_study.setup.duration / REFERENCE.sample_time)
    assert pil_study.identical(difference) and difference["command_max_difference"] == 0.0, difference
    assert np.array_equal(figures["run"].energy, figures["host_run"].energy)
    command = np.array(figures["record"].command)
    assert np.ptp(command[len(command) // 2 :], axis=0).max() > 0  # the law acts, not only the safe state
    measured, counters = figures["measured"], figures["counters"]
    samples = difference["samples"]
    assert measured["step"]["calls"] == samples == counters["steps"]
    assert measured["rx"]["calls"] == counters["rx_frames"] == samples * (len(REFERENCE.joint_names) * 2 + 1)
    assert counters["crc_errors"] == counters["counter_errors"] == counters["timeouts"] == 0
    for entry in ("rx", "step", "tx"):
        assert 0 < measured[entry]["instructions_mean"] <= measured[entry]["instructions_largest"]
    assert 0 < figures["budget"]["share_mean"] <= figures["budget"]["share_worst"] < 1
    assert 0 < measured["stack_high_water"] < measured["stack_size"]


def _one_case_per_fault_kind():
    cases = safety.cases(REFERENCE, plan.plan(REFERENCE).buses[0].database, timings=("mid-run",))
    seen, chosen = set(), []
    for case in cases:
        kinds = tuple(f.kind for f in case.faults)
        if kinds not in seen:
            seen.add(kinds)
            chosen.append(case)
    return chosen


@needs_target
def test_every_fault_kind_reaches_the_safe_force_within_three_cycles_on_the_target():
    cases = _one_case_per_fault_kind()
    assert len(cases) >= 10
    seen = safety.signals(None, REFERENCE, max(c.cycles for c in cases))
    host = firmware.Firmware(REFERENCE, "clqg", "float")
    with pil.TargetFirmware(REFERENCE, "clqg") as image:
        for case in cases:
            on_target = safety.run_case_loop(image, case, seen).record
            row = safety.measure(on_target, case.faults, REFERENCE, case.tolerated)
            assert row["ok"] and row["joints"] <= safety.DETECTION_LIMIT, (case.name, row)
            assert row["firmware"] <= safety.DETECTION_LIMIT, (case.name, row)
            on_host = safety.run_case_loop(host, case, seen).record
            assert pil_study.identical(pil_study.first_difference(on_host, on_target)), case.name


@needs_target
def test_a_target_that_stops_answering_is_an_error_within_the_timeout():
    image = pil.TargetFirmware(REFERENCE, "siso", timeout=2.0)
    try:
        image.process.kill()
        image.process.wait()
        start = time.monotonic()
        with pytest.raises(ModelError, match="no answer to TICK"):
            image.step(1000)
        assert time.monotonic() - start < 5.0
    finally:
        image.close()
    assert image.process is None and not Path(image.elf).exists()  # emulator gone, scratch folder removed


def test_without_the_tools_the_stage_is_skipped_with_the_reason(monkeypatch, tmp_path):
    reason = "target mps2-an386: qemu-system-arm not installed (Debian/Ubuntu: apt-get install qemu-system-arm)"
    monkeypatch.setattr(target, "missing_tools", lambda: reason)
    lines = []
    stage = pil_stage(None, REFERENCE, tmp_path, lines.append)
    assert stage.skipped == reason and reason in pil_markdown(stage) and reason in lines[0]
    assert stage.summary == {"skipped": reason}
    assert list(tmp_path.iterdir()) == []


def test_the_command_refuses_a_bad_clock_and_missing_tools_in_one_line():
    for clock in ("0", "inf", "nan", "-5"):
        line = cli_error("pil", "--clock", clock)
        assert "--clock" in line and "must be a finite number > 0" in line, line


def test_a_fault_after_the_study_and_a_bad_replay_tolerance_are_one_line():
    """Issue 37: a fault that starts at or after t_e would never be injected; a replay tolerance
    that is negative or not a number compares nothing."""
    done = run_cli("sil", "--fault", "drop:JOINT_A1:5:6", "--law", "siso", "--no-update")
    line = done.stderr.strip().splitlines()[-1]
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "--fault 'drop:JOINT_A1:5:6': starts at 5 s, not before the study's end t_e = 4 s" in line, line
    for tolerance in ("-1", "nan", "inf"):
        line = cli_error(
            "bench",
            "replay",
            "missing.blf",
            "--artifact",
            str(ROOT / "firmware" / "generated" / "controller.json"),
            "--tolerance",
            tolerance,
        )
        assert line.endswith("must be a finite number >= 0") and "--tolerance" in line, line


def test_the_budget_adds_every_frame_of_a_sample():
    measured = {
        "step": {"instructions_mean": 1000.0, "instructions_largest": 1200.0},
        "rx": {"instructions_mean": 100.0, "instructions_largest": 150.0},
        "tx": {"instructions_mean": 50.0, "instructions_largest": 60.0},
    }
    out = pil_study.budget(measured, 1e-3, {"rx": 7, "tx": 4}, clock_hz=168e6)
    assert out["instructions_mean"] == 1000 + 7 * 100 + 4 * 50 and out["instructions_worst"] == 1200 + 7 * 150 + 4 * 60
    assert out["share_mean"] == pytest.approx(1900 / 168_000)
