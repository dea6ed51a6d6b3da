"""The fuzzing leg (.ci/fuzz, docs/fuzzing.md): the harnesses build, run clean, and can fail.

Needs clang with libFuzzer (Debian: clang and libclang-rt-<version>-dev). Without it the test
is skipped on a developer machine, but fails where a fuzz run is required (``CI`` or
``SMARTJOINT_REQUIRE_FUZZ`` set), so CI cannot pass it by accident.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / ".ci" / "fuzz"


def _clang() -> str | None:
    if shutil.which("clang"):
        return "clang"
    versions = sorted(
        (
            p
            for d in os.environ.get("PATH", "").split(os.pathsep)
            if d and Path(d).is_dir()
            for p in Path(d).glob("clang-[0-9]*")
            if p.name[6:].isdigit()
        ),
        key=lambda p: int(p.name[6:]),
    )
    return str(versions[-1]) if versions else None


def _require_clang() -> None:
    if _clang() is None:
        message = "clang with libFuzzer not installed (apt-get install clang libclang-rt-14-dev)"
        if os.environ.get("CI") or os.environ.get("SMARTJOINT_REQUIRE_FUZZ"):
            pytest.fail(message + " — required here (CI / SMARTJOINT_REQUIRE_FUZZ)")
        pytest.skip(message)


def _run(tmp_path, *args, **env):
    environment = {**os.environ, "PYTHON": sys.executable, "TMPDIR": str(tmp_path), **env}
    environment.pop("FUZZ_WORK", None)
    environment.pop("FUZZ_KEEP", None)
    return subprocess.run(
        [str(SCRIPT), *args], cwd=tmp_path, env=environment, capture_output=True, text=True, timeout=300
    )


def test_fuzz_finds_the_planted_e2e_bug_and_the_real_runtime_is_clean(tmp_path):
    _require_clang()
    done = _run(tmp_path, "5", FUZZ_HARNESSES="e2e")
    assert done.returncode == 0, done.stdout + done.stderr
    # The mutated copy (3-bit alive counter) was caught by the reference comparison ...
    found = re.search(r"planted bug e2e_counter_mask found after (\d+) executions.*fuzz finding \(e2e\)", done.stdout)
    assert found, done.stdout
    # ... and the real runtime ran clean for a measured number of executions.
    clean = re.search(r"^fuzz: e2e: (\d+) executions, 0 findings$", done.stdout, re.MULTILINE)
    assert clean and int(clean.group(1)) > 1000, done.stdout
    # Builds, corpora and crash files of the mutant went to a temporary folder, now removed.
    assert list(tmp_path.iterdir()) == []


def test_fuzz_refuses_a_bad_time_box_in_one_line(tmp_path):
    for bad, key in (("3x", "SECONDS"), ("2", "SECONDS")):
        done = _run(tmp_path, bad)
        assert done.returncode == 2
        assert done.stderr.count("\n") == 1 and f"fuzz: error: {key}: '{bad}'" in done.stderr
    done = _run(tmp_path, "5", FUZZ_HARNESSES="e2e nonsense")
    assert done.returncode == 2 and "FUZZ_HARNESSES: 'nonsense'" in done.stderr and done.stderr.count("\n") == 1
