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
from pathlib import Path

import numpy as np

from smartjoint import run_report
from smartjoint.bench import safety, sil, xcp_study
from smartjoint.bench.faults import demo_faults
from smartjoint.codegen import backtoback, generate, identifiers
from smartjoint.common.errors import SmartjointError
from smartjoint.design import build_model, load_design, updated_design
from smartjoint.design.control import artifact_building
from smartjoint.design.control import study as closed_loop
from smartjoint.design.friction.stage import check_friction_given, friction_stage, place_joints
from smartjoint.design.network import plan, protocol
from smartjoint.design.reduction import load_case, reduction_study
from smartjoint.design.reduction.study import DENSE_REFERENCE_DOFS, REFERENCE_MODES_PER_CONSIDERED
from smartjoint.design.structure.control_section import paper_values_note
from smartjoint.design.structure.description import Network
from smartjoint.design.structure.solved import solved_model
from smartjoint.pipeline_ensemble import ensemble_stage
from smartjoint.pipeline_fmu import fmu_stage
from smartjoint.pipeline_local import local_mode_run
from smartjoint.pipeline_target import pil_stage
from smartjoint.report_folder import ReportFolder, iso, new_run_id, utc_now
from smartjoint.run_report import RunStages
from smartjoint.stages import (
    BenchStage,
    ControlStage,
    FirmwareStage,
    FrictionStage,
    StructureStage,
)

NO_JOINTS = (
    "the design has no [[joints]] and no [placement]: friction, reduction, control, firmware and SIL need "
    "friction joints — add [[joints]] or a [placement] table (docs/design-file.md)"
)

# The stage a run stops at, by the number of joint stages that finished before it.
STAGE_NAMES = ((4, "friction"), (5, "reduction"), (6, "control"), (7, "firmware"), (8, "software in the loop"),
               (9, "processor in the loop"), (10, "ensemble"), (11, "FMUs"))  # fmt: skip


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


def _stages(design_path: str | None, staging: Path, progress):
    """Stages 1–12 into the folder ``staging``: the summary (without the run's id and times) and a
    function of the final summary that gives report.md."""
    structure = _structure_stage(design_path, staging, progress)
    if structure.design.joints:
        r = _joint_stages(structure, staging, progress)
    else:
        r = RunStages(structure, skipped=NO_JOINTS)
        progress(f"[4/12]–[11/12] skipped: {NO_JOINTS}")
    progress("[12/12] report")
    files = run_report.write_files(r, staging)
    return run_report.summary(r, files), lambda final: run_report.markdown(r, files, final)


def _joint_stages(structure: StructureStage, staging: Path, progress) -> RunStages:
    """Stages 4–11. A stage's one-line error (a design that cannot be controlled at its sample
    time, say) stops the run there: the report keeps every stage that finished before it."""
    done: dict = {}
    try:
        friction = done["friction"] = _friction_stage(structure, staging, progress)
        done["reduction"] = _reduction_stage(structure, friction, progress)
        control = done["control"] = _control_stage(structure, friction, progress)
        done["firmware"] = _firmware_stage(control, progress)
        done["bench"] = _bench_stage(control, staging, progress)
        done["pil"] = pil_stage(control.study, control.artifact, staging, progress)
        done["ensemble"] = ensemble_stage(control.design, control.study, list(friction.types), staging, progress)
        done["fmu"] = fmu_stage(control.design, control.study, control.artifact, staging, progress)
    except SmartjointError as error:
        number, name = STAGE_NAMES[len(done)]
        stopped = f"stage {number} ({name}): {error}"
        progress(f"[{number}/12] stopped: {error}")
        return RunStages(structure, stopped=stopped, **done)
    return RunStages(structure, **done)


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
    check_friction_given(design)  # stage 4 needs it: one line now, not after the FE work
    progress(
        f"[1/12] design {design.name!r} ({design.source}): {len(design.nodes)} nodes, "
        f"{len(design.members)} members, {len(design.joints)} joints"
    )
    note = paper_values_note(design.control)
    if note and (design.joints or design.placement is not None):
        progress(f"      {note}")
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
    count = max((run_report.REPORT_MODES, *targets))
    progress(f"      the lowest {min(count, model.n_dof)} modes of the locked truss ({model.n_dof} DOFs) …")
    locked = solved_model(model, count)
    placed, placed_design = place_joints(design, staging, progress, locked)
    released = None
    if placed.joints:
        # One solution of the released truss: the spectrum and the design model (the reduction
        # study takes its FE model and solves every mode for its full-model reference).
        released_model = build_model(placed, joints="released")
        count = max(run_report.REPORT_MODES, placed.control.considered_modes)
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
    """Stage 5, reduction (Section 4.3, Fig. 10) on the design's joints, in the design's load case
    (``reduction.load_case``: its ``reduction_normal_force``, else the first controlled joint at
    F_N^max and the others at F_N^min), Krylov vectors for the joint of the largest force."""
    design = friction.design
    progress(
        f"[5/12] model reduction (Section 4, Fig. 10) on {design.name!r}: joints "
        f"{', '.join(j.name + ' (' + j.type + ')' for j in design.joints)}"
    )
    forces = load_case(design)
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
