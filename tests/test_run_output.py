"""``smartjoint run``'s report folder loses nothing: a folder or file it did not write is refused
before any work and left byte for byte; an earlier report is replaced only whole; an interrupt
(SIGINT, SIGTERM) ends with one line and exit 130 and leaves neither a partial report nor a
temporary folder; what a killed run left is cleared by the next one, and only that.

The pipeline's stages are replaced by a small stand-in where only the folder handling is under
test (a real run takes a minute); the interrupt and kill tests run the real command on a small
design and stop it in the middle of its stages.
"""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from datetime import datetime
from pathlib import Path

import pytest

from smartjoint import pipeline, report_folder
from smartjoint.cli import main


@pytest.fixture(autouse=True)
def interruptible():
    """Ctrl-C's usual handler in this process, and so SIG_DFL in the children it starts: a suite
    started as a background job (``pytest &`` without job control) inherits SIGINT ignored,
    which would make every interrupt here a no-op."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def _snapshot(root: Path) -> dict:
    """Every entry below ``root`` with its bytes (files), target (links) and modification time."""
    out = {}
    for path in sorted(root.rglob("*")):
        key = path.relative_to(root).as_posix()
        if path.is_symlink():
            out[key] = ("link", os.readlink(path))
        elif path.is_file():
            out[key] = ("file", path.read_bytes(), path.stat().st_mtime_ns)
        else:
            out[key] = ("folder", path.stat().st_mtime_ns)
    return out


def _stand_in(extra: dict[str, bytes] | None = None):
    """Stages that write a few report files (and the paths the real summary names) quickly."""
    files = {
        "mode_shapes.png": b"\x89PNG fake",
        "can/sil_siso.blf": b"LOGG",
        "firmware/smartjoint_siso.c": b"/* */\n",
        **(extra or {}),
    }

    def stages(design_path, staging, progress):
        for name, data in files.items():
            (staging / name).parent.mkdir(parents=True, exist_ok=True)
            (staging / name).write_bytes(data)
        summary = {
            "firmware": {"folder": "firmware", "files": ["firmware/smartjoint_siso.c"]},
            "sil": {"logs": ["can/sil_siso.blf"], "laws": {"siso": {"log": "can/sil_siso.blf"}}},
        }
        return summary, lambda final: f"# report of run {final['run_id']}\n"

    return stages


@pytest.fixture
def no_work(monkeypatch):
    """Any stage starting fails the test: a refusal must come before the work."""

    def work(*args, **kwargs):
        raise AssertionError("the pipeline started working")

    monkeypatch.setattr(pipeline, "_stages", work)
    monkeypatch.setattr(pipeline, "load_design", work)


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err.strip()


def _refuse(folder: Path, capsys) -> str:
    begin = time.perf_counter()
    assert main(["run", "-o", str(folder)]) == 2
    assert time.perf_counter() - begin < 2.0
    return _one_error_line(capsys)


def _filled(folder: Path) -> None:
    (folder / "data").mkdir(parents=True)
    (folder / "notes.txt").write_text("my notes\n")
    (folder / "data" / "measurement.bin").write_bytes(bytes(range(256)) * 10)
    (folder / "link").symlink_to("notes.txt")


def test_a_prefilled_folder_is_refused_untouched_before_any_work(tmp_path, no_work, capsys):
    folder = tmp_path / "work"
    _filled(folder)
    before = _snapshot(tmp_path)
    line = _refuse(folder, capsys)
    assert line.startswith(f"smartjoint run: error: -o {folder}:") and "smartjoint-manifest.json" in line
    assert _snapshot(tmp_path) == before  # nothing beside it either (no staging, no claim)


def test_an_earlier_report_with_a_file_added_or_changed_is_refused(tmp_path, monkeypatch, capsys):
    folder = tmp_path / "report"
    monkeypatch.setattr(pipeline, "_stages", _stand_in())
    assert main(["run", "-o", str(folder)]) == 0
    capsys.readouterr()
    (folder / "my_notes.md").write_text("added by hand\n")
    before = _snapshot(tmp_path)
    monkeypatch.setattr(pipeline, "_stages", lambda *a: pytest.fail("the pipeline started working"))
    assert "'my_notes.md', which no smartjoint run wrote" in _refuse(folder, capsys)
    assert _snapshot(tmp_path) == before
    (folder / "my_notes.md").unlink()
    (folder / "report.md").write_text("edited by hand\n")
    assert "'report.md', changed since run" in _refuse(folder, capsys)
    assert (folder / "report.md").read_text() == "edited by hand\n"


def test_a_forged_or_foreign_manifest_does_not_make_a_folder_replaceable(tmp_path, no_work, capsys):
    folder = tmp_path / "work"
    _filled(folder)
    (folder / report_folder.MANIFEST).write_text('{"kind": "something else", "files": {}}')
    before = _snapshot(tmp_path)
    assert "not a smartjoint run manifest" in _refuse(folder, capsys)
    assert _snapshot(tmp_path) == before


def test_an_existing_file_is_refused_untouched(tmp_path, no_work, capsys):
    target = tmp_path / "report"
    target.write_bytes(b"not a folder\x00\xff")
    before = _snapshot(tmp_path)
    assert "is a file — name a folder" in _refuse(target, capsys)
    assert _snapshot(tmp_path) == before
    assert "is a file" in _refuse(target / "inside", capsys)  # a path below a file
    assert _snapshot(tmp_path) == before


def test_an_earlier_report_is_replaced_whole_and_an_empty_folder_taken(tmp_path, monkeypatch, capsys):
    folder = tmp_path / "report"
    folder.mkdir()
    monkeypatch.setattr(pipeline, "_stages", _stand_in({"only_in_the_first.png": b"first"}))
    assert main(["run", "-o", str(folder), "--json"]) == 0
    first = json.loads(capsys.readouterr().out)
    assert (folder / "only_in_the_first.png").exists()
    monkeypatch.setattr(pipeline, "_stages", _stand_in())
    assert main(["run", "-o", str(folder), "--json"]) == 0
    second = json.loads(capsys.readouterr().out)
    assert second["run_id"] != first["run_id"]
    assert json.loads((folder / "summary.json").read_text())["run_id"] == second["run_id"]
    assert not (folder / "only_in_the_first.png").exists()  # replaced whole, not merged
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]  # no staging, claim or old copy beside it


def _file_names(value) -> list[str]:
    """Strings of the summary that name a file (an extension, or an absolute path)."""
    if isinstance(value, dict):
        return [n for v in value.values() for n in _file_names(v)]
    if isinstance(value, list):
        return [n for v in value for n in _file_names(v)]
    if isinstance(value, str) and (value.startswith("/") or re.search(r"\.[a-z]{1,4}$", value)):
        return [value]
    return []


def test_summary_names_the_run_its_times_and_only_files_that_exist(tmp_path, monkeypatch, capsys):
    folder = tmp_path / "report"
    monkeypatch.setattr(pipeline, "_stages", _stand_in())
    before = datetime.now().astimezone()
    assert main(["run", "-o", str(folder)]) == 0
    summary = json.loads((folder / "summary.json").read_text())
    assert re.fullmatch(r"\d{8}T\d{6}Z-[0-9a-f]{8}", summary["run_id"])
    started = datetime.fromisoformat(summary["started_utc"])
    finished = datetime.fromisoformat(summary["finished_utc"])
    assert summary["started_utc"].endswith("Z") and started.utcoffset().total_seconds() == 0
    assert before.timestamp() - 1 <= started.timestamp() <= finished.timestamp() <= time.time() + 1
    names = _file_names(summary)
    assert "can/sil_siso.blf" in names
    assert all((folder / name).exists() for name in names), names
    manifest = json.loads((folder / report_folder.MANIFEST).read_text())
    assert manifest["run_id"] == summary["run_id"] and "summary.json" in manifest["files"]


def test_a_summary_naming_a_file_outside_the_report_is_not_put_in_place(tmp_path, monkeypatch):
    """The real stages' paths go through the same check on every run (tests/test_cli.py, .ci/wheel)."""
    stages = _stand_in()

    def dangling(design_path, staging, progress):
        summary, markdown = stages(design_path, staging, progress)
        summary["sil"]["laws"]["siso"]["log"] = "/tmp/smartjoint-sil-gone/sil_siso.blf"
        return summary, markdown

    monkeypatch.setattr(pipeline, "_stages", dangling)
    with pytest.raises(RuntimeError, match="smartjoint-sil-gone"):
        pipeline.run(None, tmp_path / "report", progress=lambda message: None)
    assert list(tmp_path.iterdir()) == []


def test_signals_are_held_back_for_the_renames_and_delivered_after():
    events = []
    with pytest.raises(KeyboardInterrupt):
        with report_folder.signals_held():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
            events.append("renames finished")
    assert events == ["renames finished"]


# --------------------------------------------------------------------------- the real command, stopped


@pytest.fixture
def small_design(tmp_path) -> Path:
    import tomli_w
    from conftest import small_truss

    path = tmp_path / "small.toml"
    path.write_text(tomli_w.dumps(small_truss()))
    return path


class _Run:
    """``smartjoint run`` in a child process; its stderr read line by line on a thread (so no wait blocks)."""

    def __init__(self, design: Path, output: Path, temporary: Path):
        from smartjoint.design.friction import rig_integration

        rig_integration.kernel()  # compiled beforehand: a signal must not land in a compiler the child started
        temporary.mkdir(exist_ok=True)
        env = {**os.environ, "TMPDIR": str(temporary)}  # where a temporary folder would appear
        self.process = subprocess.Popen(
            [sys.executable, "-m", "smartjoint.cli", "run", str(design), "-o", str(output)],
            stderr=subprocess.PIPE,
            text=True,
            env=env,
            cwd=design.parent,
        )
        self.lines: queue.Queue = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.process.stderr:
            self.lines.put(line)
        self.lines.put(None)

    def wait_for(self, marker: str, timeout: float = 300.0) -> list[str]:
        """stderr lines up to the one starting with ``marker`` (the run is then inside that stage)."""
        lines, deadline = [], time.monotonic() + timeout
        while True:
            try:
                line = self.lines.get(timeout=max(deadline - time.monotonic(), 0.01))
            except queue.Empty:
                self.process.kill()
                pytest.fail(f"no {marker!r} within {timeout:g} s: {''.join(lines)}")
            assert line is not None, f"the run ended before {marker!r}: {''.join(lines)}"
            lines.append(line)
            if line.startswith(marker):
                return lines

    def finish(self, timeout: float = 120.0) -> tuple[int, list[str]]:
        """Exit code and the remaining stderr lines."""
        code = self.process.wait(timeout=timeout)
        rest = []
        while (line := self.lines.get(timeout=timeout)) is not None:
            rest.append(line)
        return code, rest


@pytest.mark.parametrize("number, name", [(signal.SIGINT, "SIGINT"), (signal.SIGTERM, "SIGTERM")])
def test_an_interrupted_run_ends_with_one_line_and_leaves_the_earlier_report(
    tmp_path, small_design, monkeypatch, number, name
):
    output, temporary = tmp_path / "report", tmp_path / "tmp"
    monkeypatch.setattr(pipeline, "_stages", _stand_in())
    assert main(["run", "-o", str(output)]) == 0  # an earlier, finished report
    earlier = _snapshot(output)
    run = _Run(small_design, output, temporary)
    progress = run.wait_for("[4/12]")  # friction identification: seconds of work ahead
    time.sleep(0.5)
    assert any(p.name.endswith(".staging") for p in tmp_path.iterdir())  # it was writing beside the report
    run.process.send_signal(number)
    code, rest = run.finish()
    assert code == 130
    assert "Traceback" not in "".join(rest) and rest and rest[-1] == f"smartjoint run: interrupted ({name})\n"
    lines = progress + rest
    # Besides the progress lines ("[k/10] …" and their indented details) exactly one line: the last.
    assert [line for line in lines if not line.startswith(("[", " "))] == [lines[-1]]
    assert _snapshot(output) == earlier  # the earlier report as it was, no partial one
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report", "small.toml", "tmp"]
    assert list(temporary.iterdir()) == []


def test_what_a_killed_run_left_is_cleared_by_the_next_and_only_that(tmp_path, small_design, monkeypatch):
    output, temporary = tmp_path / "report", tmp_path / "tmp"
    run = _Run(small_design, output, temporary)
    run.wait_for("[2/12]")
    run.process.kill()
    run.finish()
    left = sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".report.smartjoint-"))
    assert [n.rsplit(".", 1)[1] for n in left] == ["run", "staging"]
    # Look-alikes that cannot be proved a dead run's: no claim, and a claim of a live process (this one).
    lookalike = tmp_path / ".report.smartjoint-20200101T000000Z-0badc0de.staging"
    (lookalike / "keep").mkdir(parents=True)
    live = "20200101T000000Z-00a11ce0"
    claim = tmp_path / f".report.smartjoint-{live}.run"
    claim.write_text(json.dumps({**report_folder._claim(), "run_id": live, "output": "report"}))
    (tmp_path / f".report.smartjoint-{live}.staging").mkdir()
    monkeypatch.setattr(pipeline, "_stages", _stand_in())
    assert main(["run", "-o", str(output)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["report", "small.toml", "tmp", lookalike.name, claim.name, f".report.smartjoint-{live}.staging"]
    )
    assert (lookalike / "keep").is_dir()
    assert lookalike.exists() and claim.exists()


def test_a_run_killed_while_swapping_reports_gets_the_earlier_one_back(tmp_path, monkeypatch):
    output = tmp_path / "report"
    monkeypatch.setattr(pipeline, "_stages", _stand_in())
    pipeline.run(None, output, progress=lambda message: None)
    earlier = _snapshot(output)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    run_id = "20200101T000000Z-0000dead"
    stem = tmp_path / f".report.smartjoint-{run_id}"
    Path(f"{stem}.run").write_text(
        json.dumps(
            {**report_folder._claim(), "pid": dead.pid, "process_start": "0", "run_id": run_id, "output": "report"}
        )
    )
    os.rename(output, f"{stem}.previous")  # the state between the two renames of the swap
    Path(f"{stem}.staging").mkdir()
    assert report_folder.clean_stale(output) == [stem.name]
    assert _snapshot(output) == earlier
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]


def test_a_run_that_fails_leaves_nothing_not_even_the_parent_folders_it_made(tmp_path, capsys):
    design = tmp_path / "bad.toml"
    design.write_text("[nodes\n")
    assert main(["run", str(design), "-o", str(tmp_path / "a" / "b" / "report")]) == 2
    assert "not valid TOML" in _one_error_line(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]
