"""``smartjoint run``: the whole pipeline that exists, end to end, with a report.

Stages: load the design → build the FE model (joints locked, the conventional truss of the modal
survey) → update it to the measured eigenfrequencies → eigen solution of the updated model → the
joints: the design's own, or type A joints placed by ``[placement]`` on a design without any
(Section 6), with the modes of the released joints (the frictionless linear subsystem of Eq. 12)
→ friction joints: the rig records the design names identified (Eq. 3 plus the output-error
step) and used by every later stage, or the design's own parameters checked on simulated rig
records, with hysteresis loops like Fig. 5 → model reduction (Section 4, Fig. 10) → semi-active
control: the controller design artefact and the closed-loop study of Section 6 (Figs. 12–14) →
generated C firmware, checked back to back against the Python reference → the study through the
CAN loop (software in the loop) → the same firmware executing on its target in the loop
(processor in the loop, QEMU's mps2-an386, when installed) → a small robustness ensemble on
plants drawn around the design (Dask, the compiled closed loop) → the controllers and the plant as FMI
co-simulation units, co-simulated in FMPy against the study → report (Markdown + PNG). The design
file drives every stage; a design without joints and without [placement] stops after the
structure with the reason.

The report folder (``smartjoint/report_folder.py``) is checked before any work: a new or empty
folder, or the report of an earlier run, and nothing else. The run writes into a staging folder
beside it and moves the finished report into place at the end, so an interrupted or failed run
leaves the earlier report as it was and nothing half written; ``summary.json`` names the run
(id, start and end in UTC) and holds only paths that exist, relative to the report folder.
"""

from __future__ import annotations

import json
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from smartjoint import __version__
from smartjoint import report as plots
from smartjoint.bench import busload, safety, safety_report, sil
from smartjoint.bench.faults import demo_faults
from smartjoint.codegen import backtoback, can_layer, generate, identifiers, output
from smartjoint.design import build_model, load_design, solve_modes, updated_design
from smartjoint.design.control import artifact, artifact_building
from smartjoint.design.control import study as closed_loop
from smartjoint.design.friction.stage import friction_entries, friction_stage, place_joints
from smartjoint.design.network import protocol
from smartjoint.design.reduction import reduction_study, study_summary
from smartjoint.pipeline_ensemble import ensemble_stage
from smartjoint.pipeline_fmu import fmu_stage
from smartjoint.pipeline_target import pil_stage
from smartjoint.pipeline_target import summary_of as pil_summary
from smartjoint.report_control import control_markdown, plot_control_study
from smartjoint.report_folder import ReportFolder, iso, new_run_id, utc_now
from smartjoint.report_friction import friction_markdown
from smartjoint.report_reduction import plot_study, study_markdown

NO_JOINTS = (
    "the design has no [[joints]] and no [placement]: friction, reduction, control, firmware and SIL need "
    "friction joints — add [[joints]] or a [placement] table (docs/design-file.md)"
)

REPORT_MODES = 30


def run(design_path: str | None, output: Path, progress=print) -> dict:
    """Run every stage on the design and write the report folder ``output``; the summary.

    ``output`` is refused (``ReportFolderError``) before any work unless it is new, empty or the
    report of an earlier run. Paths in the summary are relative to ``output``, except
    ``design.source`` (absolute) and ``report`` (returned only, not written).

    Parameters
    ----------
    design_path : str or None
        The design file; the bundled reference truss when None.
    output : Path
        The report folder.
    progress : callable
        Receives one line per stage and step.

    Returns
    -------
    dict
        The summary written to ``summary.json`` (figures of every stage, file names, timing).
    """
    started, clock = utc_now(), time.perf_counter()
    run_id = new_run_id(started)
    folder = ReportFolder(Path(output), run_id)
    for name in folder.stale_removed:
        progress(f"removed {name}.*, left beside {folder.output} by a run that was killed")
    with folder:
        summary, markdown = _stages(design_path, folder.staging, progress)
        summary = {
            "run_id": run_id,
            "started_utc": iso(started),
            "finished_utc": iso(utc_now()),
            **summary,
            "seconds": time.perf_counter() - clock,
        }
        dangling = [path for path in _paths(summary) if not (folder.staging / path).exists()]
        if dangling:  # a stage named a file it did not write into the report
            raise RuntimeError(f"summary.json names files that are not in the report: {dangling}")
        (folder.staging / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
        (folder.staging / "report.md").write_text(markdown(summary))
        folder.commit()
    return {**summary, "report": str(folder.output / "report.md")}


# A string in the summary that names a file: a report file name or any absolute path.
_FILE_NAME = re.compile(r"[\w.@+-]+(/[\w.@+-]+)*\.(png|json|md|blf|dbc|c|h|toml|txt|csv|fmu)")


def _paths(value) -> list[str]:
    """Every string of the nested ``value`` that names a file (the check that they all exist)."""
    if isinstance(value, dict):
        return [p for item in value.values() for p in _paths(item)]
    if isinstance(value, (list, tuple)):
        return [p for item in value for p in _paths(item)]
    if isinstance(value, str) and (os.path.isabs(value) or _FILE_NAME.fullmatch(value)):
        return [value]
    return []


@dataclass
class _Results:
    """What the stages produce, filled stage by stage; the report and the summary read it."""

    design: Any = None  # the design of stages 4–8: with placed joints, identified friction
    source_design: Any = None  # the design file's (updated) design
    model: Any = None
    result: Any = None  # the updating result, None without [updating]
    modes: Any = None
    released: Any = None  # modes with the joints released, None without joints
    placed_design: str | None = None  # the design file [placement] wrote into the report
    skipped: str | None = None  # why the stages after the structure did not run
    friction: list = field(default_factory=list)  # per joint type (design.friction.stage.JointTypeFriction)
    friction_entries: dict = field(default_factory=dict)  # per joint: parameters and source
    study: Any = None  # the reduction study
    controlled: Any = None  # the design the controllers are built for
    control_study: Any = None
    controller: Any = None
    firmware_files: dict = field(default_factory=dict)
    firmware_check: Any = None
    sil_check: Any = None
    sil_logs: list = field(default_factory=list)
    bus_load: Any = None
    fault_check: Any = None
    safety_check: Any = None
    pil: Any = None  # stage 9 (pipeline_target.pil_stage)
    ensemble: Any = None  # stage 10 (pipeline_ensemble.ensemble_stage)
    fmu: Any = None  # stage 11 (pipeline_fmu.fmu_stage)
    hysteresis: list = field(default_factory=list)


def _stages(design_path: str | None, staging: Path, progress):
    """Stages 1–12 into the folder ``staging``: the summary (without the run's id and times) and a
    function of the final summary that gives report.md."""
    r = _Results()
    _structure_stages(r, design_path, progress)
    _joints(r, staging, progress)
    if r.design.joints:
        _friction_stage(r, staging, progress)
        _reduction_stage(r, progress)
        _control_stage(r, progress)
        _firmware_stage(r, progress)
        _sil_stage(r, staging, progress)
        r.pil = pil_stage(r.control_study, r.controller, staging, progress)
        r.ensemble = ensemble_stage(r.controlled, r.control_study, r.friction, staging, progress)
        r.fmu = fmu_stage(r.controlled, r.control_study, r.controller, staging, progress)
    else:
        r.skipped = NO_JOINTS
        progress(f"[4/12]–[11/12] skipped: {NO_JOINTS}")
    progress("[12/12] report")
    _write_report_files(r, staging)
    return _summary(r), lambda final: _report_markdown(r, final)


def _structure_stages(r: _Results, design_path: str | None, progress) -> None:
    """Stages 1–3: the design, its FE model, model updating and the modes (locked and released)."""
    design = load_design(design_path)
    # Stage 7 generates C from these names: refuse them now, not after minutes of work.
    identifiers.check_names(
        [j.name for j in design.joints],
        [s.name for s in design.sensors],
        members=protocol.E2E_SIGNALS,
        fields=identifiers.DESIGN_FIELDS,
    )
    progress(
        f"[1/12] design {design.name!r} ({design.source}): {len(design.nodes)} nodes, "
        f"{len(design.members)} members, {len(design.joints)} joints"
    )
    model = build_model(design, joints="locked")
    progress(
        f"[2/12] FE model: {model.n_dof} DOFs, {len(model.element_kind)} beam elements, mass {model.total_mass:.2f} kg"
    )

    result = None
    if design.updating is not None:
        progress(
            f"[3/12] model updating: {len(design.updating.parameters)} parameters, "
            f"{len(design.updating.measured)} measured modes"
        )
        design, result = updated_design(
            design,
            lambda k, n, err: progress(f"      start {k}/{n}: worst error {err:.2f} %"),
            lambda message: progress(f"      warning: {message}"),
        )
        model = build_model(design, joints="locked")
    else:
        progress("[3/12] model updating: skipped (no [updating] section)")
    modes = solve_modes(model, min(REPORT_MODES, model.n_dof))
    r.design, r.source_design, r.model, r.result, r.modes = design, design, model, result, modes


def _joints(r: _Results, staging: Path, progress) -> None:
    """The design's joints, or those [placement] puts on a design without any; the modes with
    the joints released (the frictionless linear subsystem of Eq. 12)."""
    r.design, r.placed_design = place_joints(r.design, staging, progress)
    if r.design.joints:
        released_model = build_model(r.design, joints="released")
        r.released = solve_modes(released_model, min(REPORT_MODES, released_model.n_dof))


def _friction_stage(r: _Results, staging: Path, progress) -> None:
    """Stage 4: the friction of each joint type, identified from the design's rig records or
    checked on simulated ones (``design.friction.stage.friction_stage``)."""
    types = ", ".join(sorted({j.type for j in r.design.joints}))
    progress(f"[4/12] friction joints (Section 3.2, Eq. 3 + output error): joint types {types}")
    r.design, r.friction = friction_stage(r.design, staging, progress)


def _reduction_stage(r: _Results, progress) -> None:
    """Stage 5, reduction (Section 4.3, Fig. 10) on the design's joints: the largest normal force
    at the type B joints (else the first joint), Krylov vectors for that joint."""
    design = r.design
    progress(
        f"[5/12] model reduction (Section 4, Fig. 10) on {design.name!r}: joints "
        f"{', '.join(j.name + ' (' + j.type + ')' for j in design.joints)}"
    )
    forces = np.array([400.0 if j.type == "B" else 0.0 for j in design.joints])
    if not forces.any():
        forces[0] = 400.0
    r.study = reduction_study(
        design, forces, krylov_joints=[int(np.argmax(forces))], progress=lambda message: progress(message)
    )


def _control_stage(r: _Results, progress) -> None:
    """Stage 6, control (Sections 5–6) on the design's joints."""
    controlled = r.design
    progress(
        f"[6/12] semi-active control (Sections 5–6) on {controlled.name!r}: joints "
        f"{', '.join(j.name for j in controlled.joints)}, t_e = {controlled.control.study_duration:g} s"
    )
    control_study = closed_loop.run_study(controlled, progress=lambda message: progress(message))
    r.controlled, r.control_study = controlled, control_study
    r.controller = artifact_building.from_design(
        controlled, control_study.setup.model, control_study.lqg, control_study.boundary_layer
    )


def _firmware_stage(r: _Results, progress) -> None:
    """Stage 7: the generated C and its back-to-back check against the Python reference."""
    progress("[7/12] firmware: generated C (float and double), back-to-back on the study")
    r.firmware_files = generate.render(r.controller, "float")
    r.firmware_check = backtoback.back_to_back(
        r.control_study.setup, r.controller, progress=progress, study=r.control_study
    )


def _sil_stage(r: _Results, staging: Path, progress) -> None:
    """Stage 8: the study through the CAN loop, the demo faults and the safe-state fault matrix."""
    controller, control_study = r.controller, r.control_study
    progress("[8/12] software in the loop: the study through CAN (firmware, bus, amplifier models)")
    # The bus logs go straight into the report (no temporary folder to leave behind).
    sil_check = sil.sil_study(
        control_study.setup, controller, spread_runs=4, log_folder=staging / "can", progress=progress
    )
    r.sil_logs = sorted(p.name for p in (staging / "can").iterdir())
    for law in sil_check["laws"].values():
        if law.get("log") is not None:
            law["log"] = Path(law["log"]).relative_to(staging).as_posix()
    r.sil_check = sil_check
    r.bus_load = busload.check(protocol.database(controller), sil_check["bitrate"], sil_check["data_bitrate"])
    demo = demo_faults(controller, control_study.setup.duration)
    progress("      injected faults in the study: " + ", ".join(f.label() for f in demo))
    r.fault_check = sil.fault_run(control_study.setup, controller, faults=demo)
    progress("      safe state under every fault kind on every frame (docs/safety.md) …")
    safety_check = safety.fault_matrix(controller, progress=progress)
    progress(
        f"      {safety_check['cases']} fault cases: worst {safety_check['worst_joints']} cycles to the safe force "
        f"at every joint, {len(safety_check['failed'])} failing"
    )
    r.safety_check = safety_check


def _write_report_files(r: _Results, staging: Path) -> None:
    """Stage 9: the plots, the artefact, the firmware and the fault tables into the report."""
    design = r.design
    plots.plot_mode_shapes(r.model, r.modes, staging / "mode_shapes.png")
    measured = [(m.mode, m.frequency_hz) for m in design.updating.measured] if design.updating else []
    plots.plot_spectrum(r.modes, measured, staging / "spectrum.png", updated=r.result is not None)
    if r.result is not None:
        plots.plot_updating(r.result, staging / "updating.png")
        if r.result.correlation is not None:  # EMA shapes: the MAC matrix of Fig. 7
            plots.plot_mac(r.result.correlation, staging / "mac.png")
    if r.skipped:
        return
    r.hysteresis = [p.name for f in r.friction for p in plots.plot_hysteresis(f.identification, staging)]
    r.friction_entries = friction_entries(r.design, r.friction, staging)
    plot_study(r.study, staging)
    plot_control_study(r.control_study, staging)
    artifact.save(r.controller, staging / "controller.json")
    output.write({**r.firmware_files, **can_layer.render_can(r.controller)}, staging / "firmware")
    sil.plot_sil(r.sil_check, staging, r.sil_check.get("mil_runs"))
    sil.plot_faults(r.fault_check, staging / "sil_faults.png")
    safety_report.plot_matrix(r.safety_check, staging / "safety_cycles.png")
    (staging / "safety_cases.md").write_text(safety_report.matrix_markdown(r.safety_check), encoding="utf-8")


def _summary(r: _Results) -> dict:
    """summary.json without the run's id and times."""
    design, model = r.source_design, r.model
    source = os.path.abspath(design.source) if os.path.isfile(design.source) else design.source
    out = {
        "smartjoint_version": __version__,
        "design": {"name": design.name, "source": source, "sha256": design.sha256, "placed": r.placed_design},
        "fe_model": {"n_dof": model.n_dof, "elements": len(model.element_kind), "mass_kg": model.total_mass},
        "updating": r.result.as_dict() if r.result is not None else None,
        "modes_hz": [float(f) for f in r.modes.frequencies_hz],
        "modes_released_hz": [float(f) for f in r.released.frequencies_hz] if r.released is not None else None,
        "skipped": r.skipped,
    }
    if r.skipped:
        return {
            **out,
            **dict.fromkeys(("friction", "reduction", "control", "firmware", "sil", "pil", "ensemble", "fmu")),
        }
    return {**out, **_joint_stages_summary(r)}


def _joint_stages_summary(r: _Results) -> dict:
    """The summary of stages 4–8, which run on a design with joints."""
    sil_check, safety_check = r.sil_check, r.safety_check
    return {
        "friction": {
            "joints": r.friction_entries,
            "types": [f.as_dict() for f in r.friction],
        },
        "reduction": study_summary(r.study),
        "control": {
            **closed_loop.summary(r.control_study),
            "design": r.controlled.name,
            "artifact": "controller.json",
            "artifact_sha256": r.controller.artifact_sha256,
        },
        "firmware": {
            "folder": "firmware",
            "real": "float",
            "files": [f"firmware/{n}" for n in sorted(r.firmware_files)],
            "back_to_back": r.firmware_check,
        },
        "sil": {
            **{k: v for k, v in sil_check.items() if k not in ("laws", "mil_runs")},
            "laws": {
                law: {k: v for k, v in f.items() if k not in ("record", "result")}
                for law, f in sil_check["laws"].items()
            },
            "logs": [f"can/{name}" for name in r.sil_logs],
            "faults": {k: v for k, v in r.fault_check.items() if k not in ("result", "record")},
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
        "pil": pil_summary(r.pil),
        "ensemble": pil_summary(r.ensemble),
        "fmu": pil_summary(r.fmu),
    }


def _report_markdown(r: _Results, final: dict) -> str:
    """report.md from the stages' results and the final summary."""
    head = _markdown(r.source_design, r.model, r.modes, r.released, r.result, final)
    if r.placed_design:
        head += (
            f"The design has no friction joints: [placement] placed {len(r.design.joints)} type A joints "
            f"(paper Section 6), written as `{r.placed_design}`; every later stage runs on it.\n\n"
        )
    if r.skipped:
        return head + f"\n## Friction joints, reduction, control, firmware and SIL\n\nNot run: {r.skipped}.\n"
    return (
        head
        + friction_markdown(r.design, r.friction, r.hysteresis)
        + "\n"
        + study_markdown(r.study)
        + "\n"
        + _control_section(r.control_study, r.controller)
        + "\n"
        + backtoback.markdown(r.firmware_check, r.controller)
        + "\nFiles (float build for the Cortex-M4F): `firmware/` — "
        + ", ".join(f"`{name}`" for name in sorted(r.firmware_files))
        + ".\n\n"
        + sil.sil_markdown(r.sil_check)
        + "\n![SIL energy](sil_energy.png)\n\n"
        + r.bus_load.table()
        + "\n\n"
        + sil.fault_markdown(r.fault_check)
        + "\n![faults](sil_faults.png)\n\n"
        + safety_report.summary_markdown(r.safety_check, "safety_cases.md")
        + "\n![cycles to the safe state](safety_cycles.png)\n\n"
        + "Bus logs (BLF, simulated time stamps; `smartjoint bench decode` / "
        "`bench replay`): "
        + ", ".join(f"`can/{n}`" for n in r.sil_logs)
        + "; protocol: `firmware/bus.dbc`.\n\n"
        + r.pil["markdown"]
        + "\n"
        + r.ensemble["markdown"]
        + "\n"
        + r.fmu["markdown"]
    )


def _markdown(design, model, modes, released, result, summary) -> str:
    lines = [
        f"# smartjoint report: {design.name}",
        "",
        f"{design.description}",
        "",
        f"- design file `{design.source}` (sha256 `{summary['design']['sha256'][:16]}…`), smartjoint {__version__}",
        f"- FE model: {model.n_dof} independent DOFs, {len(model.element_kind)} Euler–Bernoulli beam elements, "
        f"{len(design.nodes)} rigid nodes, total mass {model.total_mass:.2f} kg",
        f"- modal damping ξ = {design.modal_damping:.2%} for every mode",
        f"- run `{summary['run_id']}`: {summary['started_utc']} to {summary['finished_utc']} (UTC), "
        f"{summary['seconds']:.1f} s",
        "",
        "## Model updating (paper Section 3.3, Fig. 7)",
        "",
    ]
    if result is not None:
        lines += [
            plots.updating_table(result),
            "",
            "![updating](updating.png)",
            "",
            "Normalised sensitivities ∂ln f / ∂ln p at the updated parameters:",
            "",
            plots.sensitivity_table(result),
            "",
        ]
        if result.correlation is not None:
            lines += ["MAC pairing of the EMA shapes:", "", plots.correlation_table(result), "", "![MAC](mac.png)", ""]
    else:
        lines += ["The design carries no measured frequencies; the nominal model is used.", ""]
    lines += [
        "## Eigenfrequencies (Eq. 7)",
        "",
        "![spectrum](spectrum.png)",
        "",
        "| mode | joints locked [Hz] |" + (" joints released, F_N = 0 [Hz] |" if released is not None else ""),
        "|---:|---:|" + ("---:|" if released is not None else ""),
    ]
    for i, f in enumerate(modes.frequencies_hz):
        extra = f" {released.frequencies_hz[i]:.3f} |" if released is not None and i < len(released) else ""
        lines.append(f"| {i + 1} | {f:.3f} |{extra}")
    lines += ["", "## Mode shapes", "", "![mode shapes](mode_shapes.png)", ""]
    return "\n".join(lines)


def _control_section(study, controller) -> str:
    return (
        control_markdown(study)
        + "\n![energy](control_energy.png)\n\n![tip](control_tip.png)\n\n"
        + ("![ε optimisation](siso_boundary_layer.png)\n\n" if study.optimum is not None else "")
        + "![normal forces](control_normal_force.png)\n\n"
        f"Controller design artefact: `controller.json` (schema {controller.schema_version}, "
        f"sha256 `{controller.artifact_sha256[:16]}…`, docs/controller-artifact.md) — the input of the "
        "firmware generator.\n"
    )
