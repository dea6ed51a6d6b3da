"""Stage 9 of ``smartjoint run``: processor in the loop, the study with the firmware executing on
its target (QEMU's mps2-an386, ``bench/pil_study.py``), when the cross compiler and QEMU are
installed; otherwise the stage says which tool is missing and the report says it was skipped."""

from __future__ import annotations

from pathlib import Path

from smartjoint.bench import pil_study, target


def pil_stage(control_study, controller, staging: Path, progress) -> dict:
    """The study's SISO and cLQG runs on the target beside the host float build.

    Parameters
    ----------
    control_study : design.control.study.Study
        The model-in-the-loop study of the run (setup, passive and active runs).
    controller : ControllerArtifact
        The artefact the firmware was generated from.
    staging : Path
        The report folder being written: ``pil_energy.png`` and the image ``pil.elf`` go there.
    progress : callable

    Returns
    -------
    dict
        ``skipped`` (None, or why) and, when run, the summary of ``pil_study`` and its
        Markdown section (``markdown``) and plot.
    """
    reason = target.missing_tools()
    if reason:
        progress(f"[9/12] processor in the loop: skipped — {reason}")
        return {"skipped": reason, "markdown": _skipped_markdown(reason)}
    progress(f"[9/12] processor in the loop: the firmware on {target.BOARD} (QEMU) in lock-step with the plant")
    out = pil_study.pil_study(control_study, controller, progress=progress, image_folder=staging)
    pil_study.plot_pil(out, staging / "pil_energy.png")
    for law, figures in out["laws"].items():
        progress(
            f"      {law}: {figures['difference']['samples']} samples, "
            + ("bit for bit as the host float build" if pil_study.identical(figures["difference"]) else "DIFFERS")
            + f", step {figures['measured']['step']['instructions_mean']:.0f} instructions"
        )
    markdown = pil_study.pil_markdown(out) + "\n![PIL energy](pil_energy.png)\n"
    return {
        "skipped": None,
        **pil_study.summary(out),
        "image": "pil.elf",
        "plot": "pil_energy.png",
        "markdown": markdown,
    }


def _skipped_markdown(reason: str) -> str:
    return f"## Processor in the loop\n\nNot run: {reason}.\n"


def summary_of(stage: dict) -> dict:
    """The stage's entry of ``summary.json`` (its Markdown left out)."""
    return {k: v for k, v in stage.items() if k != "markdown"}
