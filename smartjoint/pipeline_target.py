"""Stage 9 of ``smartjoint run``: processor in the loop, the study with the firmware executing on
its target (QEMU's mps2-an386, ``bench/pil_study.py``), when the cross compiler and QEMU are
installed; otherwise the stage says which tool is missing and the report says it was skipped."""

from __future__ import annotations

from pathlib import Path

from smartjoint.bench import pil_study, target
from smartjoint.stages import PilStage


def pil_stage(control_study, controller, staging: Path, progress) -> PilStage:
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
    PilStage
        Why it was skipped, or ``pil_study``'s figures and the summary entry (with the image and
        the plot).
    """
    reason = target.missing_tools()
    if reason:
        progress(f"[9/12] processor in the loop: skipped — {reason}")
        return PilStage(reason, {}, {"skipped": reason})
    progress(f"[9/12] processor in the loop: the firmware on {target.BOARD} (QEMU) in lock-step with the plant")
    out = pil_study.pil_study(control_study, controller, progress=progress, image_folder=staging)
    pil_study.plot_pil(out, staging / "pil_energy.png")
    for law, figures in out["laws"].items():
        progress(
            f"      {law}: {figures['difference']['samples']} samples, "
            + ("bit for bit as the host float build" if pil_study.identical(figures["difference"]) else "DIFFERS")
            + f", step {figures['measured']['step']['instructions_mean']:.0f} instructions"
        )
    summary = {"skipped": None, **pil_study.summary(out), "image": "pil.elf", "plot": "pil_energy.png"}
    return PilStage(None, out, summary)


def pil_markdown(stage: PilStage) -> str:
    """The report's section of the stage: the figures and the plot, or why it did not run."""
    if stage.skipped:
        return f"## Processor in the loop\n\nNot run: {stage.skipped}.\n"
    return pil_study.pil_markdown(stage.result) + f"\n![PIL energy]({stage.summary['plot']})\n"


__all__ = ["pil_markdown", "pil_stage"]
