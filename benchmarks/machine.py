"""The machine facts every benchmark writes next to its figures."""

from __future__ import annotations

import json
import platform
from pathlib import Path


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo), else what platform knows."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        lines = []
    model = next((line.split(":", 1)[1].strip() for line in lines if line.startswith("model name")), "")
    return model or platform.processor()


def python_machine(**extra) -> dict:
    """Python, numpy and scipy versions, CPU, core count and the 1-minute load average.

    Parameters
    ----------
    **extra
        Further facts of the benchmark (e.g. ``blas_threads``), added before the load average.

    Returns
    -------
    dict
    """
    import os

    import numpy
    import scipy

    return {
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "scipy": scipy.__version__,
        "machine": platform.machine(),
        "cpu": cpu_model(),
        "cpus": os.cpu_count(),
        **extra,
        "load_average_1min": os.getloadavg()[0],
    }


def artifact_header(benchmark: str, facts: dict, artifact_path, artifact) -> dict:
    """The entries that open the JSON of a benchmark run on a controller artefact.

    Parameters
    ----------
    benchmark : str
        The benchmark's name.
    facts : dict
        The machine facts the benchmark gathered.
    artifact_path : path-like
        The artefact file as given on the command line.
    artifact : ControllerArtifact
        The artefact read from it (its SHA-256 pins the exact controller measured).

    Returns
    -------
    dict
        ``benchmark``, ``machine``, ``artifact`` and ``artifact_sha256``, in that order.
    """
    return {
        "benchmark": benchmark,
        "machine": facts,
        "artifact": str(artifact_path),
        "artifact_sha256": artifact.artifact_sha256,
    }


def write_json(path, results: dict) -> None:
    """Write a benchmark's results (JSON, one-space indent, final newline) and say where.

    Parameters
    ----------
    path : path-like
        The JSON file.
    results : dict
        What the benchmark measured.
    """
    Path(path).write_text(json.dumps(results, indent=1) + "\n")
    print(f"\nwrote {path}")
