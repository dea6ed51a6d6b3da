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

import numpy as np

from smartjoint import __version__
from smartjoint import report as plots
from smartjoint.bench import safety, safety_report, sil, xcp_study
from smartjoint.bench.faults import demo_faults
from smartjoint.codegen import backtoback, generate, identifiers, output
from smartjoint.design import build_model, load_design, updated_design
from smartjoint.design.control import artifact, artifact_building
from smartjoint.design.control import study as closed_loop
from smartjoint.design.friction.stage import friction_entries, friction_stage, place_joints
from smartjoint.design.network import joint_node, plan, protocol
from smartjoint.design.reduction import reduction_study, study_summary
from smartjoint.design.reduction.study import DENSE_REFERENCE_DOFS, REFERENCE_MODES_PER_CONSIDERED
from smartjoint.design.structure.description import Network
from smartjoint.design.structure.solved import solved_model
from smartjoint.pipeline_ensemble import ensemble_markdown, ensemble_stage
from smartjoint.pipeline_fmu import fmu_markdown, fmu_stage
from smartjoint.pipeline_local import local_mode_markdown, local_mode_run
from smartjoint.pipeline_target import pil_markdown, pil_stage
from smartjoint.report_control import control_markdown, plot_control_study, tuning_plots
from smartjoint.report_folder import ReportFolder, iso, new_run_id, utc_now
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


@dataclass(frozen=True)
class _Run:
    """Every stage's result of one run; the summary and the report read it. The stages after the
    structure are None where the design has no joints (``skipped`` says why)."""

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


@dataclass(frozen=True)
class _ReportFiles:
    """What writing the report's files adds to the summary: the hysteresis plots and the joints'
    friction entries (with the parameter files they wrote)."""

    hysteresis: tuple[str, ...] = ()
    friction_entries: dict = field(default_factory=dict)


def _stages(design_path: str | None, staging: Path, progress):
    """Stages 1–12 into the folder ``staging``: the summary (without the run's id and times) and a
    function of the final summary that gives report.md."""
    structure = _structure_stage(design_path, staging, progress)
    if structure.design.joints:
        friction = _friction_stage(structure, staging, progress)
        reduction = _reduction_stage(structure, friction, progress)
        control = _control_stage(structure, friction, progress)
        firmware = _firmware_stage(control, progress)
        bench = _bench_stage(control, staging, progress)
        pil = pil_stage(control.study, control.artifact, staging, progress)
        ensemble = ensemble_stage(control.design, control.study, list(friction.types), staging, progress)
        fmu = fmu_stage(control.design, control.study, control.artifact, staging, progress)
        r = _Run(structure, None, friction, reduction, control, firmware, bench, pil, ensemble, fmu)
    else:
        r = _Run(structure, skipped=NO_JOINTS)
        progress(f"[4/12]–[11/12] skipped: {NO_JOINTS}")
    progress("[12/12] report")
    files = _write_report_files(r, staging)
    return _summary(r, files), lambda final: _report_markdown(r, files, final)


def _structure_stage(design_path: str | None, staging: Path, progress) -> StructureStage:
    """Stages 1–3: the design, its FE model, model updating and the modes (locked and released),
    and the joints: the design's own, or those [placement] puts on a design without any."""
    design = load_design(design_path)
    # Stage 7 generates C from these names: refuse them now, not after minutes of work.
    identifiers.check_names(
        [j.name for j in design.joints],
        [s.name for s in design.sensors],
        members=protocol.E2E_SIGNALS,
        fields=identifiers.DESIGN_FIELDS,
    )
    plan.check_design(design)  # and the frames on the buses of [network] (one line when they do not fit)
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
            model=model,
        )
        model = build_model(design, joints="locked")
    else:
        progress("[3/12] model updating: skipped (no [updating] section)")
    # One solution of the locked truss: the report's spectrum and the placement's target modes.
    targets = design.placement.modes if design.placement is not None and not design.joints else ()
    count = max((REPORT_MODES, *targets))
    progress(f"      the lowest {min(count, model.n_dof)} modes of the locked truss ({model.n_dof} DOFs) …")
    locked = solved_model(model, count)
    placed, placed_design = place_joints(design, staging, progress, locked)
    released = None
    if placed.joints:
        # One solution of the released truss: the spectrum and the design model (the reduction
        # study takes its FE model and solves every mode for its full-model reference).
        released_model = build_model(placed, joints="released")
        count = max(REPORT_MODES, placed.control.considered_modes)
        if released_model.n_dof > DENSE_REFERENCE_DOFS:  # the reduction study's sparse reference too
            count = REFERENCE_MODES_PER_CONSIDERED * count
        progress(
            f"      the lowest {min(count, released_model.n_dof)} modes of the released truss "
            f"({released_model.n_dof} DOFs) …"
        )
        released = solved_model(released_model, count)
    return StructureStage(design, placed, locked, result, released, placed_design)


def _friction_stage(structure: StructureStage, staging: Path, progress) -> FrictionStage:
    """Stage 4: the friction of each joint type, identified from the design's rig records or
    checked on simulated ones (``design.friction.stage.friction_stage``)."""
    design = structure.design
    types = ", ".join(sorted({j.type for j in design.joints}))
    progress(f"[4/12] friction joints (Section 3.2, Eq. 3 + output error): joint types {types}")
    design, results = friction_stage(design, staging, progress)
    return FrictionStage(design, tuple(results))


def _reduction_stage(structure: StructureStage, friction: FrictionStage, progress) -> dict:
    """Stage 5, reduction (Section 4.3, Fig. 10) on the design's joints: the largest normal force
    at the type B joints (else the first joint), Krylov vectors for that joint."""
    design = friction.design
    progress(
        f"[5/12] model reduction (Section 4, Fig. 10) on {design.name!r}: joints "
        f"{', '.join(j.name + ' (' + j.type + ')' for j in design.joints)}"
    )
    forces = np.array([400.0 if j.type == "B" else 0.0 for j in design.joints])
    if not forces.any():
        forces[0] = 400.0
    # The controllers' design model, compared with balanced truncation to the Nyquist frequency.
    model = None
    if design.sensors and design.disturbances:
        model = closed_loop.design_model(design, progress, structure.released)
    return reduction_study(
        design,
        forces,
        krylov_joints=[int(np.argmax(forces))],
        progress=lambda message: progress(message),
        released=structure.released,
        design_model=model,
    )


def _control_stage(structure: StructureStage, friction: FrictionStage, progress) -> ControlStage:
    """Stage 6, control (Sections 5–6) on the design's joints, designed on the structure stage's
    released modes."""
    controlled = friction.design
    progress(
        f"[6/12] semi-active control (Sections 5–6) on {controlled.name!r}: joints "
        f"{', '.join(j.name for j in controlled.joints)}, t_e = {controlled.control.study_duration:g} s"
    )
    model = closed_loop.design_model(controlled, lambda message: progress(message), structure.released)
    study = closed_loop.run_study(controlled, model, progress=lambda message: progress(message))
    controller = artifact_building.from_design(controlled, study.setup.model, study.lqg, study.settings())
    return ControlStage(controlled, study, controller)


def _firmware_stage(control: ControlStage, progress) -> FirmwareStage:
    """Stage 7: the generated C and its back-to-back check against the Python reference."""
    progress("[7/12] firmware: generated C (float and double), back-to-back on the study")
    check = backtoback.back_to_back(control.study.setup, control.artifact, progress=progress, study=control.study)
    return FirmwareStage(generate.render(control.artifact, "float"), check)


def _bench_stage(control: ControlStage, staging: Path, progress) -> BenchStage:
    """Stage 8: the study through the CAN loop (and XCP), the demo faults and the fault matrix."""
    controller, control_study = control.artifact, control.study
    progress("[8/12] software in the loop: the study through CAN (firmware, bus, amplifier models)")
    buses = None if control.design.network == Network() else control.design.network  # else firmware/bus.dbc's bus
    sil_check = sil.sil_study(
        control_study.setup, controller, spread_runs=4, log_folder=staging / "can", progress=progress, network=buses
    )
    if control.design.network.siso == "local":
        sil_check["local"] = local_mode_run(control.artifact, control.study.setup, sil_check, progress)
    sil_check["xcp"] = [xcp_study.demo(control_study.setup, controller, staging, progress, network=buses)]
    logs = tuple(sorted(p.name for p in (staging / "can").iterdir()))
    for law in sil_check["laws"].values():
        if law.get("log") is not None:
            law["log"] = Path(law["log"]).relative_to(staging).as_posix()
    demo = demo_faults(controller, control_study.setup.duration)
    progress("      injected faults in the study: " + ", ".join(f.label() for f in demo))
    fault_check = sil.fault_run(control_study.setup, controller, faults=demo, network=buses)
    progress("      safe state under every fault kind on every frame (docs/safety.md) …")
    safety_check = safety.fault_matrix(controller, progress=progress, network=buses)
    cases, worst, failing = safety_check["cases"], safety_check["worst_joints"], len(safety_check["failed"])
    progress(f"      {cases} fault cases: worst {worst} cycles to the safe force at every joint, {failing} failing")
    network = plan.plan(controller, control.design.network)
    progress(
        f"      network plan ([network]): {len(network.buses)} bus(es), worst-case load "
        + ", ".join(f"{p.bus.name} {p.load.load:.1%}" for p in network.buses)
    )
    return BenchStage(sil_check, logs, fault_check, safety_check, network)


def _write_report_files(r: _Run, staging: Path) -> _ReportFiles:
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
    if r.skipped:
        return _ReportFiles()
    assert r.friction and r.control and r.firmware and r.bench and r.reduction is not None
    hysteresis = tuple(p.name for f in r.friction.types for p in plots.plot_hysteresis(f.identification, staging))
    entries = friction_entries(r.friction.design, list(r.friction.types), staging)
    plot_study(r.reduction, staging)
    plot_control_study(r.control.study, staging)
    artifact.save(r.control.artifact, staging / "controller.json")
    network = None if r.control.design.network == Network() else r.bench.network  # the buses SIL ran on
    firmware = generate.firmware_files(r.control.artifact, xcp=r.control.design.xcp, network=network)
    output.write(firmware, staging / "firmware")
    sil.plot_sil(r.bench.sil, staging, r.bench.sil.get("mil_runs"))
    sil.plot_faults(r.bench.faults, staging / "sil_faults.png")
    safety_report.plot_matrix(r.bench.safety, staging / "safety_cycles.png")
    (staging / "safety_cases.md").write_text(safety_report.matrix_markdown(r.bench.safety), encoding="utf-8")
    return _ReportFiles(hysteresis, entries)


def _spectra(structure: StructureStage):
    """The report's modes: the locked truss's and the released truss's (None without joints)."""
    released = structure.released.first(REPORT_MODES) if structure.released is not None else None
    return structure.locked.first(REPORT_MODES), released


def _summary(r: _Run, files: _ReportFiles) -> dict:
    """summary.json without the run's id and times."""
    structure = r.structure
    design, model = structure.source_design, structure.locked.fe
    modes, released = _spectra(structure)
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
    }
    if r.skipped:
        return {
            **out,
            **dict.fromkeys(("friction", "reduction", "control", "firmware", "sil", "pil", "ensemble", "fmu")),
        }
    return {**out, **_joint_stages_summary(r, files)}


def _joint_stages_summary(r: _Run, files: _ReportFiles) -> dict:
    """The summary of stages 4–11, which run on a design with joints."""
    assert r.friction and r.control and r.firmware and r.bench and r.reduction is not None
    assert r.pil is not None and r.ensemble is not None and r.fmu is not None
    sil_check, safety_check = r.bench.sil, r.bench.safety
    return {
        "friction": {
            "joints": files.friction_entries,
            "types": [f.as_dict() for f in r.friction.types],
        },
        "reduction": study_summary(r.reduction),
        "control": {
            **closed_loop.summary(r.control.study),
            "design": r.control.design.name,
            "artifact": "controller.json",
            "artifact_sha256": r.control.artifact.artifact_sha256,
        },
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


def _report_markdown(r: _Run, files: _ReportFiles, final: dict) -> str:
    """report.md from the stages' results and the final summary."""
    structure = r.structure
    modes, released = _spectra(structure)
    head = plots.structure_markdown(
        structure.source_design, structure.locked.fe, modes, released, structure.updating, final
    )
    if structure.placed_design:
        head += (
            f"The design has no friction joints: [placement] placed {len(structure.design.joints)} type A joints "
            f"(paper Section 6), written as `{structure.placed_design}`; every later stage runs on it.\n\n"
        )
    if r.skipped:
        return head + f"\n## Friction joints, reduction, control, firmware and SIL\n\nNot run: {r.skipped}.\n"
    assert r.friction and r.control and r.firmware and r.bench and r.reduction is not None
    assert r.pil is not None and r.ensemble is not None and r.fmu is not None
    bench = r.bench
    return (
        head
        + friction_markdown(r.friction.design, list(r.friction.types), list(files.hysteresis))
        + "\n"
        + study_markdown(r.reduction)
        + "\n"
        + _control_section(r.control.study, r.control.artifact)
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
