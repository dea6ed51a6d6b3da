"""Ctrl-C on a sweep (issue 37): the terminal's SIGINT reaches every process of its group, the
Dask worker processes included; the command ends with one line and exit 130, no worker's traceback."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import tomli_w
from conftest import small_truss

# Far more samples than the test lets run: it is interrupted once the workers have written a batch.
LONG = """\
design = "small.toml"
laws = ["passive F_min", "SISO"]
samples = 5000
seed = 20
batch = 2
study_duration = 1.0

[uncertain]
pulse_amplitude = { distribution = "uniform", low = 180.0, high = 220.0 }

[grid]
siso_boundary_layer = [1e-4]
"""


def test_ctrl_c_on_a_sweep_is_one_line_and_exit_130_without_worker_tracebacks(tmp_path):
    """Ctrl-C reaches every process of the terminal's group, the Dask workers included: they start
    with SIGINT ignored, so only the command answers it (one line, exit 130) and shuts them down."""
    design = small_truss()
    design["control"] = {"modes": 4, "considered_modes": 10, "study_duration": 1.0}
    (tmp_path / "small.toml").write_text(tomli_w.dumps(design))
    (tmp_path / "long.toml").write_text(LONG)
    process = subprocess.Popen(
        [sys.executable, "-m", "smartjoint.cli", "sweep", "long.toml", "-o", "out", "--workers", "2"],
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own group, as a terminal's foreground job
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # not a background job's SIG_IGN
    )
    deadline = time.monotonic() + 300
    while not any(tmp_path.joinpath("out", "results").glob("batch-*.parquet")):  # the workers compute
        assert process.poll() is None and time.monotonic() < deadline, process.stderr.read()
        time.sleep(0.2)
    os.killpg(process.pid, signal.SIGINT)
    _, err = process.communicate(timeout=120)
    lines = [line for line in err.splitlines() if "samples/s" not in line]
    assert process.returncode == 130, err[-2000:]
    assert "Traceback" not in err and lines[-1] == "smartjoint sweep: interrupted (SIGINT)", lines[-5:]
