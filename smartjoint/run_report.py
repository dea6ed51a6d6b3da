"""The report of ``smartjoint run`` (``pipeline``): its files, ``summary.json`` and ``report.md``
from the stages' results (``RunStages``). A run whose design has no joints reports the structure
and why the rest was skipped; a run that a stage stopped with a one-line error reports every stage
that finished before it and the error (issue 36), so a design that cannot be controlled at its
sample time still gets its structure, friction and reduction figures."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from smartjoint import __version__
from smartjoint import report as plots
from smartjoint.bench import safety_report, sil, xcp_study
from smartjoint.codegen import backtoback, generate, output
from smartjoint.design.control import artifact
from smartjoint.design.control import study as closed_loop
from smartjoint.design.friction.stage import friction_entries
from smartjoint.design.network import joint_node
from smartjoint.design.reduction import study_summary
from smartjoint.design.structure.control_section import paper_values_note
from smartjoint.design.structure.description import Network
from smartjoint.pipeline_ensemble import ensemble_markdown
from smartjoint.pipeline_fmu import fmu_markdown
from smartjoint.pipeline_local import local_mode_markdown
from smartjoint.pipeline_target import pil_markdown
from smartjoint.report_control import control_markdown, plot_control_study, tuning_plots
from smartjoint.report_friction import friction_markdown
from smartjoint.report_reduction import plot_study, study_markdown
from smartjoint.stages import (
    BenchStage,
    ControlStage,
    EnsembleStage,
    FirmwareStage,
    FmuStage,
    FrictionStage,
    PilStage,
    StructureStage,
)

REPORT_MODES = 30
JOINT_STAGES = ("friction", "reduction", "control", "firmware", "sil", "pil", "ensemble", "fmu")


@dataclass(frozen=True)
class RunStages:
    """Every stage's result of one run; the summary and the report read it. The stages after the
    structure are None where the design has no joints (``skipped`` says why) and from the stage
    that stopped the run on (``stopped``: "stage N (name): the error")."""

    structure: StructureStage
    skipped: str | None = None
    friction: FrictionStage | None = None
    reduction: dict | None = None  # the reduction study (design.reduction.reduction_study)
    control: ControlStage | None = None
    firmware: FirmwareStage | None = None
    bench: BenchStage | None = None
    pil: PilStage | None = None
    ensemble: EnsembleStage | None = None
    fmu: FmuStage | None = None
    stopped: str | None = None

    @property
    def complete(self) -> bool:
        """Every stage ran."""
        stages = (self.friction, self.reduction, self.control, self.firmware, self.bench, self.pil)
        return all(s is not None for s in (*stages, self.ensemble, self.fmu))


@dataclass(frozen=True)
class ReportFiles:
    """What writing the report's files adds to the summary: the hysteresis plots and the joints'
    friction entries (with the parameter files they wrote)."""

    hysteresis: tuple[str, ...] = ()
    friction_entries: dict = field(default_factory=dict)


def write_files(r: RunStages, staging: Path) -> ReportFiles:
    """Stage 9: the plots, the artefact, the firmware and the fault tables into the report."""
    structure = r.structure
    design, locked = structure.design, structure.locked
    spectrum = locked.first(REPORT_MODES)
    plots.plot_mode_shapes(locked.fe, spectrum, staging / "mode_shapes.png")
    measured = [(m.mode, m.frequency_hz) for m in design.updating.measured] if design.updating else []
    plots.plot_spectrum(spectrum, measured, staging / "spectrum.png", updated=structure.updating is not None)
    if structure.updating is not None:
        plots.plot_updating(structure.updating, staging / "updating.png")
        if structure.updating.correlation is not None:  # EMA shapes: the MAC matrix of Fig. 7
            plots.plot_mac(structure.updating.correlation, staging / "mac.png")
    if r.friction is None:
        return ReportFiles()
    hysteresis = tuple(p.name for f in r.friction.types for p in plots.plot_hysteresis(f.identification, staging))
    entries = friction_entries(r.friction.design, list(r.friction.types), staging)
    if r.reduction is not None:
        plot_study(r.reduction, staging)
    if r.control is not None:
        plot_control_study(r.control.study, staging)
        artifact.save(r.control.artifact, staging / "controller.json")
    if not r.complete:
        return ReportFiles(hysteresis, entries)
    assert r.control and r.bench
    network = None if r.control.design.network == Network() else r.bench.network  # the buses SIL ran on
    firmware = generate.firmware_files(r.control.artifact, xcp=r.control.design.xcp, network=network)
    output.write(firmware, staging / "firmware")
    sil.plot_sil(r.bench.sil, staging, r.bench.sil.get("mil_runs"))
    sil.plot_faults(r.bench.faults, staging / "sil_faults.png")
    safety_report.plot_matrix(r.bench.safety, staging / "safety_cycles.png")
    (staging / "safety_cases.md").write_text(safety_report.matrix_markdown(r.bench.safety), encoding="utf-8")
    return ReportFiles(hysteresis, entries)


def spectra(structure: StructureStage):
    """The report's modes: the locked truss's and the released truss's (None without joints)."""
    released = structure.released.first(REPORT_MODES) if structure.released is not None else None
    return structure.locked.first(REPORT_MODES), released


def summary(r: RunStages, files: ReportFiles) -> dict:
    """summary.json without the run's id and times."""
    structure = r.structure
    design, model = structure.source_design, structure.locked.fe
    modes, released = spectra(structure)
    source = os.path.abspath(design.source) if os.path.isfile(design.source) else design.source
    updating = structure.updating
    out = {
        "smartjoint_version": __version__,
        "design": {"name": design.name, "source": source, "sha256": design.sha256, "placed": structure.placed_design},
        "fe_model": {"n_dof": model.n_dof, "elements": len(model.element_kind), "mass_kg": model.total_mass},
        "updating": updating.as_dict() if updating is not None else None,
        "modes_hz": [float(f) for f in modes.frequencies_hz],
        "modes_released_hz": [float(f) for f in released.frequencies_hz] if released is not None else None,
        "skipped": r.skipped,
        "stopped": r.stopped,
    }
    if r.complete:
        return {**out, **_joint_stages_summary(r, files)}
    return {
        **out,
        **dict.fromkeys(JOINT_STAGES),
        "friction": _friction_summary(r, files) if r.friction is not None else None,
        "reduction": study_summary(r.reduction) if r.reduction is not None else None,
        "control": _control_summary(r) if r.control is not None else None,
    }


def _friction_summary(r: RunStages, files: ReportFiles) -> dict:
    assert r.friction is not None
    return {"joints": files.friction_entries, "types": [f.as_dict() for f in r.friction.types]}


def _control_summary(r: RunStages) -> dict:
    assert r.control is not None
    return {
        **closed_loop.summary(r.control.study),
        "design": r.control.design.name,
        "artifact": "controller.json",
        "artifact_sha256": r.control.artifact.artifact_sha256,
    }


def _joint_stages_summary(r: RunStages, files: ReportFiles) -> dict:
    """The summary of stages 4–11, which run on a design with joints."""
    assert r.friction and r.control and r.firmware and r.bench and r.reduction is not None
    assert r.pil is not None and r.ensemble is not None and r.fmu is not None
    sil_check, safety_check = r.bench.sil, r.bench.safety
    return {
        "friction": _friction_summary(r, files),
        "reduction": study_summary(r.reduction),
        "control": _control_summary(r),
        "firmware": {
            "folder": "firmware",
            "real": "float",
            "files": [f"firmware/{n}" for n in sorted(r.firmware.files)],
            "back_to_back": r.firmware.check,
        },
        "sil": {
            **{k: v for k, v in sil_check.items() if k not in ("laws", "mil_runs")},
            "laws": {
                law: {k: v for k, v in f.items() if k not in ("record", "result")}
                for law, f in sil_check["laws"].items()
            },
            "logs": [f"can/{name}" for name in r.bench.logs],
            "faults": {k: v for k, v in r.bench.faults.items() if k not in ("result", "record")},
            "safety": {
                "cases": safety_check["cases"],
                "failed": safety_check["failed"],
                "worst_firmware_cycles": safety_check["worst_firmware"],
                "worst_joint_cycles": safety_check["worst_joints"],
                "worst_recovery_cycles": safety_check["worst_recovery"],
                "table": "safety_cases.md",
                "plot": "safety_cycles.png",
            },
        },
        "pil": r.pil.summary,
        "ensemble": r.ensemble.summary,
        "fmu": r.fmu.summary,
    }


def markdown(r: RunStages, files: ReportFiles, final: dict) -> str:
    """report.md from the stages' results and the final summary."""
    structure = r.structure
    modes, released = spectra(structure)
    head = plots.structure_markdown(
        structure.source_design, structure.locked.fe, modes, released, structure.updating, final
    )
    if structure.placed_design:
        head += (
            f"The design has no friction joints: [placement] placed {len(structure.design.joints)} type A joints "
            f"(paper Section 6), written as `{structure.placed_design}`; every later stage runs on it.\n\n"
        )
    note = paper_values_note(structure.design.control)
    if note and structure.design.joints:
        head += f"Note: {note}.\n\n"
    if r.skipped:
        return head + f"\n## Friction joints, reduction, control, firmware and SIL\n\nNot run: {r.skipped}.\n"
    if not r.complete:
        return head + _finished_sections(r, files) + f"\n## Stopped\n\nThe run stopped at {r.stopped}\n"
    assert r.control and r.firmware and r.bench
    assert r.pil is not None and r.ensemble is not None and r.fmu is not None
    bench = r.bench
    return (
        head
        + _finished_sections(r, files)
        + "\n"
        + backtoback.markdown(r.firmware.check, r.control.artifact)
        + "\nFiles (float build for the Cortex-M4F): `firmware/` — "
        + ", ".join(f"`{name}`" for name in sorted(r.firmware.files))
        + ".\n\n"
        + sil.sil_markdown(bench.sil)
        + local_mode_markdown(bench.sil)
        + xcp_study.xcp_markdown(bench.sil["xcp"])
        + "\n![SIL energy](sil_energy.png)\n\n"
        + "\n\n".join(f"Bus `{p.bus.name}`:\n\n{p.load.table()}" for p in bench.network.buses)
        + "\n\nNetwork plan of the design's `[network]` (`design.network.plan`: "
        + f"{joint_node.NODE_LAW.display} law {r.control.design.network.siso}; "
        + "setpoints packed where that lowers the load; busy = one sample's "
        + "frames back to back, the worst-case latency of the last):\n\n"
        + bench.network.table()
        + "\n\n"
        + sil.fault_markdown(bench.faults)
        + "\n![faults](sil_faults.png)\n\n"
        + safety_report.summary_markdown(bench.safety, "safety_cases.md")
        + "\n![cycles to the safe state](safety_cycles.png)\n\n"
        + "Bus logs (BLF, simulated time stamps; `smartjoint bench decode` / "
        "`bench replay`): "
        + ", ".join(f"`can/{n}`" for n in bench.logs)
        + "; protocol: `firmware/bus.dbc`.\n\n"
        + pil_markdown(r.pil)
        + "\n"
        + ensemble_markdown(r.ensemble)
        + "\n"
        + fmu_markdown(r.fmu)
    )


def _finished_sections(r: RunStages, files: ReportFiles) -> str:
    """The sections of stages 4–6 that finished: friction, reduction, control."""
    text = ""
    if r.friction is not None:
        text += friction_markdown(r.friction.design, list(r.friction.types), list(files.hysteresis)) + "\n"
    if r.reduction is not None:
        text += study_markdown(r.reduction) + "\n"
    if r.control is not None:
        text += _control_section(r.control.study, r.control.artifact)
    return text


def _control_section(study, controller) -> str:
    return (
        control_markdown(study)
        + "\n![energy](control_energy.png)\n\n![tip](control_tip.png)\n\n"
        + "".join(f"![tuning]({name})\n\n" for name in tuning_plots(study))
        + "![normal forces](control_normal_force.png)\n\n"
        f"Controller design artefact: `controller.json` (schema {controller.schema_version}, "
        f"sha256 `{controller.artifact_sha256[:16]}…`, docs/controller-artifact.md) — the input of the "
        "firmware generator.\n"
    )


__all__ = ["JOINT_STAGES", "REPORT_MODES", "ReportFiles", "RunStages", "markdown", "spectra", "summary", "write_files"]
