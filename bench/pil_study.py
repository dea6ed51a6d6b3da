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
import shutil
import subprocess
from pathlib import Path

import numpy as np

from smartjoint.bench import firmware, pil, target
from smartjoint.bench.loop import SilLoop
from smartjoint.common import figures, law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control import orderings as paper_orderings
from smartjoint.design.control import runs as study_runs
from smartjoint.design.control import study as closed_loop
from smartjoint.design.control import tuning

RUN_NAMES = {law.name: law.display for law in law_registry.LAWS.values()}  # the Study's run names of the laws
COMPARED = ("command", "status", "faults", "safe")  # what the target and the host must agree on
CLOCK_HZ = 168e6  # the budget's stated clock: an STM32F4-class Cortex-M4F at its top speed


def mil_study(design, model, artifact, progress=print):
    """The model-in-the-loop study of an artefact: the five runs of Section 6 with the Python
    reference controllers of the artefact (its ε, its gains), no ε optimisation.

    Parameters
    ----------
    design : Design
        The (updated) design the artefact was made from.
    model : ModalModel
        Its design model.
    artifact : ControllerArtifact
    progress : callable

    Returns
    -------
    design.control.study.Study
    """
    s = closed_loop.setup(design, model)
    lqg = closed_loop.lqg_for(design, model)
    laws = {law.display: law.python_reference(artifact) for law in law_registry.LAWS.values()}
    progress(f"      model in the loop: passive, {', '.join(laws)}, active LQG ({s.duration:g} s each) …")
    runs = [
        study_runs.run_passive(s, "passive F_min", s.normal_force_min),
        study_runs.run_passive(s, "passive F_max", s.normal_force_max),
        *(study_runs.run_semi_active(s, name, law) for name, law in laws.items()),
        study_runs.run_active(s, lqg),
    ]
    quantities = closed_loop.sensor_quantities(design, model)
    for run in runs:
        run.metrics = closed_loop.metrics(run, runs[1], quantities)
    return closed_loop.Study(
        s, lqg, tuning.from_artifact(artifact), runs, list(model.sensor_names), list(model.joint_names), quantities
    )


def loop_run(setup, image, law: str, faults=()) -> tuple:
    """One law through the CAN loop around ``image`` (a host or a target firmware): the Run and
    the loop's record."""
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
    for name in COMPARED:
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


def law_on_target(
    setup, artifact, law: str, faults=(), clock_hz: float = CLOCK_HZ, timeout: float = 30.0, image_folder=None
) -> dict:
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
    image_folder : path, optional
        Where a copy of the image, ``pil.elf``, goes.

    Returns
    -------
    dict
        The target's ``run`` and ``record``, the host's, ``difference`` (:func:`first_difference`),
        ``measured`` (instructions, stack), ``counters``, ``budget``, ``size`` and the QEMU arguments
        (``emulator``).
    """
    host_run, host_record = loop_run(setup, firmware.Firmware(artifact, law, "float"), law, faults)
    with pil.TargetFirmware(artifact, law, timeout=timeout) as image:
        run, record = loop_run(setup, image, law, faults)
        measured, counters = image.measurements(), image.counters
        size = image_size(image.elf)
        if image_folder is not None:  # the image beside the report, for the command shown
            Path(image_folder).mkdir(parents=True, exist_ok=True)
            shutil.copyfile(image.elf, Path(image_folder) / "pil.elf")
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
        # The emulator's arguments (a list: the image, its last word, is a file of the report).
        "emulator": pil.emulator_command("pil.elf", "PORT"),
    }


def pil_study(
    study, artifact, laws=law_registry.NAMES, faults=(), clock_hz: float = CLOCK_HZ, progress=print, image_folder=None
) -> dict:
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
    image_folder : path, optional
        Where a copy of the image, ``pil.elf``, goes.

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
        figures_ = law_on_target(study.setup, artifact, law, faults, clock_hz, image_folder=image_folder)
        runs[RUN_NAMES[law]] = figures_["run"]
        out["laws"][law] = figures_
    reference = runs["passive F_max"]
    for run in runs.values():
        run.metrics = closed_loop.metrics(run, reference, study.sensor_quantities)
    with_target = dataclasses.replace(study, runs=list(runs.values()))
    out["orderings"] = with_target.orderings() if set(laws) == set(RUN_NAMES) else None
    for law, figures_ in out["laws"].items():
        figures_["metrics"] = runs[RUN_NAMES[law]].metrics
        figures_["energy_measure_mil"] = study.run(RUN_NAMES[law]).metrics["energy_measure"]
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


def summary(out: dict) -> dict:
    """The JSON-ready figures of :func:`pil_study` (runs and records left out).

    Parameters
    ----------
    out : dict
        What :func:`pil_study` returned (a ``fault_matrix`` entry too, when one was run).

    Returns
    -------
    dict
    """
    keep = ("difference", "measured", "frames_per_sample", "counters", "budget", "size", "emulator", "metrics",
            "energy_measure_mil")  # fmt: skip
    laws = {law: {key: f[key] for key in keep} for law, f in out["laws"].items()}
    for law, f in out["laws"].items():
        laws[law]["bit_identical"] = identical(f["difference"])
    matrix = out.get("fault_matrix")
    if matrix is not None:
        matrix = {k: v for k, v in matrix.items() if k != "rows"}
    return {"board": out["board"], "clock_hz": out["clock_hz"], "laws": laws, "orderings": out["orderings"],
            "fault_matrix": matrix}  # fmt: skip


def identical(difference: dict) -> bool:
    """Whether the target and the host float build agreed on every sample (forces, status, faults, safe state)."""
    return all(difference[name] is None for name in COMPARED)


def _law_rows(out: dict) -> list[str]:
    lines = [
        "| law | samples | same as the host float build | E(t_e) (Eq. 32) PIL / MIL | e(t_e) "
        "| step: instructions mean / largest | per frame received / sent | frames in / out per sample "
        "| share of a sample (mean / worst) | stack |",
        "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for law, f in out["laws"].items():
        d, m, b = f["difference"], f["measured"], f["budget"]
        parted = [d[name] for name in COMPARED if d[name] is not None]
        same = "bit for bit, every sample" if not parted else f"**no**: first at sample {min(parted)}"
        lines.append(
            f"| {law} | {d['samples']} | {same} | "
            f"{f['metrics']['energy_measure']:.4g} / {f['energy_measure_mil']:.4g} | "
            f"{f['metrics']['energy_end']:.3g} | {m['step']['instructions_mean']:.0f} / "
            f"{m['step']['instructions_largest']:.0f} | {m['rx']['instructions_mean']:.0f} / "
            f"{m['tx']['instructions_mean']:.0f} | {f['frames_per_sample']['rx']:.1f} / "
            f"{f['frames_per_sample']['tx']:.1f} | {100 * b['share_mean']:.1f} / {100 * b['share_worst']:.1f} % | "
            f"{m['stack_high_water']} B |"
        )
    return lines


def pil_markdown(out: dict) -> str:
    """The report section of a PIL study.

    Parameters
    ----------
    out : dict
        What :func:`pil_study` returned.

    Returns
    -------
    str
        Markdown: one row per law (agreement with the host float build, E(t_e), the target's
        instructions, budget and stack), the image's size, the orderings and the fault matrix.
    """
    any_law = next(iter(out["laws"].values()))
    size = any_law["size"]
    lines = [
        f"## Processor in the loop: the firmware on its target ({out['board']}, Cortex-M4F, float build)",
        "",
        "The same sources as SIL, built with arm-none-eabi-gcc -O2 and run in QEMU in lock-step with the plant; "
        "the bench reaches the target through python-can's `slcan` interface on the emulated UART "
        f"(`{' '.join(any_law['emulator'])}`). Instructions are counted on the target "
        "(SysTick under `-icount shift=0`), "
        f"the budget is stated at {out['clock_hz'] / 1e6:g} MHz with one cycle per instruction "
        "(a real part adds wait states), the stack is the painted high-water mark below `main`.",
        "",
        *_law_rows(out),
        "",
        f"Image (firmware + SLCAN harness + startup): {size['flash']} B flash, {size['ram']} B RAM "
        f"(+ {size['stack']} B stack reserved).",
    ]
    c = out["orderings"]
    if c is not None:
        mark = {True: "yes", False: "**no**", None: "— (no displacement sensor)"}
        lines += [
            "",
            f"Orderings of the paper (Section 6) with the target's {', '.join(RUN_NAMES.values())} runs:",
            "",
            *(f"- {o.sentence}: {mark[verdict]}" for o, verdict in paper_orderings.judged(c)),
        ]
    matrix = out.get("fault_matrix")
    if matrix is not None:
        lines += [
            "",
            f"Fault matrix on the target ({matrix['law']}): {matrix['cases']} cases, worst "
            f"{matrix['worst_joints']} cycles to the safe force at every joint (firmware: {matrix['worst_firmware']}), "
            f"worst recovery {matrix['worst_recovery']} cycles, {len(matrix['failed'])} failing"
            + (": " + ", ".join(matrix["failed"]) if matrix["failed"] else "."),
        ]
    return "\n".join(lines) + "\n"
