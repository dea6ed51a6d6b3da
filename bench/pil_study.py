"""The paper's study with the firmware on its target (processor in the loop).

Per law, the CAN loop of the SIL bench (``bench/loop.py``: sensor nodes, bus, amplifier models,
the injected faults) runs twice on the same plant: around the host float build
(``bench.firmware.Firmware``) and around the same sources executing on the emulated Cortex-M4F
(``bench.pil.TargetFirmware``). Both see the same frames as long as they command the same forces,
so the comparison is sample by sample and exact: the first sample where the normal forces, the
status, the fault bits or the safe state differ (none, when the target computes as the host).
The target's measurements (instructions per entry point, stack high water) are set against the
sample time at a stated clock, and the paper's orderings (``Study.orderings``) are evaluated with
the target's SISO and cLQG runs in place of the Python ones.
"""

from __future__ import annotations

import dataclasses
import subprocess
from pathlib import Path

import numpy as np

from smartjoint.bench import firmware, pil, target
from smartjoint.bench.loop import SilLoop
from smartjoint.common import figures
from smartjoint.common.errors import ModelError
from smartjoint.design.control import runs as study_runs
from smartjoint.design.control import study as closed_loop

RUN_NAMES = {"siso": "SISO", "clqg": "cLQG"}  # the Study's run names of the laws
CLOCK_HZ = 168e6  # the budget's stated clock: an STM32F4-class Cortex-M4F at its top speed


def reference_runs(setup, lqg, artifact) -> list:
    """The study's runs that need no firmware: passive F^min, passive F^max, active LQG.

    Parameters
    ----------
    setup : study.StudySetup
    lqg : LqgDesign
        The LQR and Kalman gains of the active reference.
    artifact : ControllerArtifact
        Its force limits are the passive settings.

    Returns
    -------
    list of Run
    """
    return [
        study_runs.run_passive(setup, "passive F_min", artifact.normal_force_min),
        study_runs.run_passive(setup, "passive F_max", artifact.normal_force_max),
        study_runs.run_active(setup, lqg),
    ]


def _loop_run(setup, image, law: str, faults) -> tuple:
    """One law through the CAN loop around ``image``: the Run and the loop's record."""
    loop = SilLoop(image, 0.0, faults=faults, channel=f"smartjoint-pil-{id(image)}")
    try:
        run = study_runs.run_semi_active(setup, RUN_NAMES[law], loop)
    finally:
        loop.close()
    return run, loop.record


def first_difference(host, on_target) -> dict:
    """Where two loop records part: the first differing sample of each quantity (None: never).

    Parameters
    ----------
    host, on_target : bench.loop.SilRecord
        The records of the host float build and of the target.

    Returns
    -------
    dict
        ``samples`` and, per quantity (``command``, ``status``, ``faults``, ``safe``), the index
        of the first sample where the two differ or None; ``command_max_difference`` [N].
    """
    out: dict = {"samples": len(host.time)}
    for name in ("command", "status", "faults", "safe"):
        a, b = np.asarray(getattr(host, name)), np.asarray(getattr(on_target, name))
        if a.shape != b.shape:
            out[name] = 0
            continue
        differs = np.flatnonzero((a != b).reshape(len(a), -1).any(axis=1))
        out[name] = int(differs[0]) if differs.size else None
    a, b = np.asarray(host.command, float), np.asarray(on_target.command, float)
    out["command_max_difference"] = float(np.max(np.abs(a - b))) if a.shape == b.shape and a.size else None
    return out


def budget(measured: dict, sample_time: float, frames_per_sample: dict, clock_hz: float = CLOCK_HZ) -> dict:
    """The firmware's share of a sample at ``clock_hz``, one cycle per instruction assumed.

    Parameters
    ----------
    measured : dict
        ``TargetFirmware.measurements()``.
    sample_time : float
        The controller's sample time [s].
    frames_per_sample : dict
        Frames received (``rx``) and sent (``tx``) per sample.
    clock_hz : float
        The processor clock the budget is stated for.

    Returns
    -------
    dict
        Instructions per sample (``mean`` and ``worst``: the largest step and the largest frame
        handling, every frame of the sample), the sample's cycles and the shares of it.
    """
    cycles = clock_hz * sample_time

    def per_sample(kind: str) -> float:
        key = f"instructions_{kind}"
        return float(
            measured["step"][key]
            + frames_per_sample["rx"] * (measured["rx"][key] or 0.0)
            + frames_per_sample["tx"] * (measured["tx"][key] or 0.0)
        )

    mean, worst = per_sample("mean"), per_sample("largest")
    return {
        "clock_hz": clock_hz,
        "cycles_per_sample": cycles,
        "instructions_mean": mean,
        "instructions_worst": worst,
        "share_mean": mean / cycles,
        "share_worst": worst / cycles,
    }


def image_size(elf: Path) -> dict:
    """Flash (vectors, code, read-only data, the load image of .data) and RAM (.data, .bss) of
    the PIL image, without the stack reservation, from ``arm-none-eabi-size -A``."""
    done = subprocess.run(["arm-none-eabi-size", "-A", str(elf)], capture_output=True, text=True, check=True)
    sections = {}
    for line in done.stdout.splitlines():
        words = line.split()
        if len(words) == 3 and words[0].startswith(".") and words[1].isdigit():
            sections[words[0]] = int(words[1])
    flash = sum(sections.get(name, 0) for name in (".vectors", ".text", ".rodata", ".ARM.exidx", ".data"))
    return {"flash": flash, "ram": sections.get(".data", 0) + sections.get(".bss", 0), "stack": sections.get(".stack")}


def law_on_target(setup, artifact, law: str, faults=(), clock_hz: float = CLOCK_HZ, timeout: float = 30.0) -> dict:
    """One law's PIL run beside the host float build's, compared sample by sample.

    Parameters
    ----------
    setup : study.StudySetup
    artifact : ControllerArtifact
    law : str
        ``"siso"`` or ``"clqg"``.
    faults : iterable of Fault
        Injected into both runs alike.
    clock_hz : float
        The clock of the budget.
    timeout : float
        Seconds the target may take to answer one request.

    Returns
    -------
    dict
        The target's ``run`` and ``record``, the host's, ``difference`` (:func:`first_difference`),
        ``measured`` (instructions, stack), ``counters``, ``budget``, ``size`` and the QEMU command.
    """
    host_run, host_record = _loop_run(setup, firmware.Firmware(artifact, law, "float"), law, faults)
    with pil.TargetFirmware(artifact, law, timeout=timeout) as image:
        run, record = _loop_run(setup, image, law, faults)
        measured, counters = image.measurements(), image.counters
        size, command = image_size(image.elf), image.qemu_command
    samples = max(len(record.time), 1)
    frames = {"rx": measured["rx"]["calls"] / samples, "tx": measured["tx"]["calls"] / samples}
    return {
        "run": run,
        "record": record,
        "host_run": host_run,
        "host_record": host_record,
        "difference": first_difference(host_record, record),
        "measured": measured,
        "frames_per_sample": frames,
        "counters": counters,
        "budget": budget(measured, setup.sample_time, frames, clock_hz),
        "size": size,
        "command": command,
    }


def pil_study(study, artifact, laws=("siso", "clqg"), faults=(), clock_hz: float = CLOCK_HZ, progress=print) -> dict:
    """The study with each law's firmware on the target; the orderings with the target's runs.

    Parameters
    ----------
    study : design.control.study.Study
        The model-in-the-loop study: its setup, and its passive and active runs for the orderings.
    artifact : ControllerArtifact
        The design artefact the firmware is generated from.
    laws : tuple of str
    faults : iterable of Fault
        Injected in every run (host and target alike).
    clock_hz : float
        The clock of the budget.
    progress : callable

    Returns
    -------
    dict
        Per law :func:`law_on_target`'s figures (runs and records included) and its metrics;
        ``orderings`` of the study with the target's runs (None for a law not run) and ``board``.
    """
    reason = target.missing_tools()
    if reason:
        raise ModelError(reason)
    out: dict = {"board": target.BOARD, "clock_hz": clock_hz, "laws": {}}
    runs = {r.name: r for r in study.runs}
    for law in laws:
        progress(f"      {law}: host float build and the target ({target.BOARD}) in lock-step …")
        figures_ = law_on_target(study.setup, artifact, law, faults, clock_hz)
        runs[RUN_NAMES[law]] = figures_["run"]
        out["laws"][law] = figures_
    reference = runs["passive F_max"]
    for run in runs.values():
        run.metrics = closed_loop.metrics(run, reference, study.sensor_quantities)
    with_target = dataclasses.replace(study, runs=list(runs.values()))
    out["orderings"] = with_target.orderings() if set(laws) == set(RUN_NAMES) else None
    for law, figures_ in out["laws"].items():
        figures_["metrics"] = runs[RUN_NAMES[law]].metrics
    return out


def plot_pil(out: dict, path) -> Path:
    """e(t) of each law on the target and on the host float build (one line when identical)."""
    fig, ax = figures.pyplot().subplots(figsize=(7.0, 3.6))
    for law, f in out["laws"].items():
        ax.semilogy(f["host_run"].time, f["host_run"].energy, lw=3.0, alpha=0.35, label=f"{law}: host float build")
        ax.semilogy(f["run"].time, f["run"].energy, lw=1.0, label=f"{law}: on {out['board']}")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("e(t) = ½xᵀx")
    ax.legend(fontsize=8)
    figures.save(fig, path, dpi=110)
    return Path(path)
