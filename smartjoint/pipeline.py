"""``smartjoint run``: the whole pipeline that exists, end to end, with a report.

Stages so far: load the design → build the FE model (joints locked, the conventional truss
of the modal survey) → update it to the measured eigenfrequencies → eigen solution of the
updated model, also with the joints released (the frictionless linear subsystem of Eq. 12)
→ friction joint: isolated-rig records (Table 1 type B, 1 % noise) and the two-step LuGre
identification of Eq. 3 plus the output-error step, with hysteresis loops like Fig. 5 → model
reduction (Section 4, Fig. 10)
→ semi-active control: the controller design artefact and the closed-loop study of Section 6
(Figs. 12–14) → generated C firmware, checked back to back against the Python reference → the
study through the CAN loop (software in the loop) → report (Markdown + PNG). Each later stage of
the design card joins here.

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
from smartjoint.codegen import backtoback, can_layer, generate, identifiers, output
from smartjoint.design import Design, build_model, load_design, solve_modes, updated_design
from smartjoint.design.control import artifact, artifact_building
from smartjoint.design.control import study as closed_loop
from smartjoint.design.friction import lugre, rig
from smartjoint.design.friction.identify import identify
from smartjoint.design.friction.record_screening import classify
from smartjoint.design.network import protocol
from smartjoint.design.reduction import reduction_study, study_summary
from smartjoint.design.structure.spec import REFERENCE_DESIGN
from smartjoint.report_control import control_markdown, plot_control_study
from smartjoint.report_folder import ReportFolder, iso, new_run_id, utc_now
from smartjoint.report_reduction import plot_study, study_markdown

FIG10_DESIGN = REFERENCE_DESIGN.parent / "fig10_three_joints.toml"
CONTROL_DESIGN = REFERENCE_DESIGN.parent / "three_type_a.toml"  # Fig. 11: three type A joints

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
_FILE_NAME = re.compile(r"[\w.@+-]+(/[\w.@+-]+)*\.(png|json|md|blf|dbc|c|h|toml|txt|csv)")


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

    design: Any = None
    model: Any = None
    result: Any = None  # the updating result, None without [updating]
    modes: Any = None
    released: Any = None  # modes with the joints released, None without joints
    identification: Any = None
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
    hysteresis: list = field(default_factory=list)


def _stages(design_path: str | None, staging: Path, progress):
    """Stages 1–9 into the folder ``staging``: the summary (without the run's id and times) and a
    function of the final summary that gives report.md."""
    r = _Results()
    _structure_stages(r, design_path, progress)
    _friction_stage(r, progress)
    _reduction_stage(r, progress)
    _control_stage(r, progress)
    _firmware_stage(r, progress)
    _sil_stage(r, staging, progress)
    progress("[9/9] report")
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
        f"[1/9] design {design.name!r} ({design.source}): {len(design.nodes)} nodes, "
        f"{len(design.members)} members, {len(design.joints)} joints"
    )
    model = build_model(design, joints="locked")
    progress(
        f"[2/9] FE model: {model.n_dof} DOFs, {len(model.element_kind)} beam elements, mass {model.total_mass:.2f} kg"
    )

    result = None
    if design.updating is not None:
        progress(
            f"[3/9] model updating: {len(design.updating.parameters)} parameters, "
            f"{len(design.updating.measured)} measured modes"
        )
        design, result = updated_design(
            design,
            lambda k, n, err: progress(f"      start {k}/{n}: worst error {err:.2f} %"),
            lambda message: progress(f"      warning: {message}"),
        )
        model = build_model(design, joints="locked")
    else:
        progress("[3/9] model updating: skipped (no [updating] section)")
    modes = solve_modes(model, min(REPORT_MODES, model.n_dof))
    released = None
    if design.joints:
        released_model = build_model(design, joints="released")
        released = solve_modes(released_model, min(REPORT_MODES, released_model.n_dof))
    r.design, r.model, r.result, r.modes, r.released = design, model, result, modes, released


def _friction_stage(r: _Results, progress) -> None:
    """Stage 4: isolated-rig records of a type B joint, then the LuGre identification."""
    progress(
        "[4/9] friction joint: isolated rig (Section 3.2), type B, 1 % noise → identification (Eq. 3 + output error)"
    )
    records = [rig.simulate(test) for test in rig.campaign("B", noise=0.01, cycles=8)]
    micro = [record for record in records if classify(record) == "micro-slip"]
    stick = [record for record in records if classify(record) == "stick-slip"]
    r.identification = identify(micro, stick, progress=lambda message: progress(f"      {message}"))


def _joint_design(r: _Results, bundled) -> Design:
    """The design a joint stage works on: the design itself when it has joints, else the bundled
    design ``bundled`` with the updated parameters, if the model was updated."""
    if r.design.joints:
        return r.design
    design = load_design(bundled)
    return design if r.result is None else design.with_parameters(r.result.parameters)


def _reduction_stage(r: _Results, progress) -> None:
    """Stage 5, reduction (Section 4.3): on the design's own joints, or — for a design without
    joints such as the bundled reference — on the Fig. 10 example (the same truss plus joints
    B1, A2, A3)."""
    example = _joint_design(r, FIG10_DESIGN)
    progress(
        f"[5/9] model reduction (Section 4, Fig. 10) on {example.name!r}: joints "
        f"{', '.join(j.name + ' (' + j.type + ')' for j in example.joints)}"
    )
    forces = np.array([400.0 if j.type == "B" else 0.0 for j in example.joints])
    if not forces.any():
        forces[0] = 400.0
    r.study = reduction_study(
        example, forces, krylov_joints=[int(np.argmax(forces))], progress=lambda message: progress(message)
    )


def _control_stage(r: _Results, progress) -> None:
    """Stage 6, control (Sections 5–6): on the design's joints, or for the reference truss on Fig. 11's."""
    controlled = _joint_design(r, CONTROL_DESIGN)
    progress(
        f"[6/9] semi-active control (Sections 5–6) on {controlled.name!r}: joints "
        f"{', '.join(j.name for j in controlled.joints)}, t_e = {controlled.control.study_duration:g} s"
    )
    control_study = closed_loop.run_study(controlled, progress=lambda message: progress(message))
    r.controlled, r.control_study = controlled, control_study
    r.controller = artifact_building.from_design(
        controlled, control_study.setup.model, control_study.lqg, control_study.boundary_layer
    )


def _firmware_stage(r: _Results, progress) -> None:
    """Stage 7: the generated C and its back-to-back check against the Python reference."""
    progress("[7/9] firmware: generated C (float and double), back-to-back on the study")
    r.firmware_files = generate.render(r.controller, "float")
    r.firmware_check = backtoback.back_to_back(
        r.control_study.setup, r.controller, progress=progress, study=r.control_study
    )


def _sil_stage(r: _Results, staging: Path, progress) -> None:
    """Stage 8: the study through the CAN loop, the demo faults and the safe-state fault matrix."""
    controller, control_study = r.controller, r.control_study
    progress("[8/9] software in the loop: the study through CAN (firmware, bus, amplifier models)")
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
    demo = sil.demo_faults(controller, control_study.setup.duration)
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
    plots.plot_spectrum(r.modes, measured, staging / "spectrum.png")
    if r.result is not None:
        plots.plot_updating(r.result, staging / "updating.png")
        if r.result.correlation is not None:  # EMA shapes: the MAC matrix of Fig. 7
            plots.plot_mac(r.result.correlation, staging / "mac.png")
    r.hysteresis = [p.name for p in plots.plot_hysteresis(r.identification, staging)]
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
    design, model, sil_check, safety_check = r.design, r.model, r.sil_check, r.safety_check
    source = os.path.abspath(design.source) if os.path.isfile(design.source) else design.source
    return {
        "smartjoint_version": __version__,
        "design": {"name": design.name, "source": source, "sha256": design.sha256},
        "fe_model": {"n_dof": model.n_dof, "elements": len(model.element_kind), "mass_kg": model.total_mass},
        "updating": r.result.as_dict() if r.result is not None else None,
        "modes_hz": [float(f) for f in r.modes.frequencies_hz],
        "modes_released_hz": [float(f) for f in r.released.frequencies_hz] if r.released is not None else None,
        "friction_identification": r.identification.as_dict(),
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
    }


def _report_markdown(r: _Results, final: dict) -> str:
    """report.md from the stages' results and the final summary."""
    return (
        _markdown(r.design, r.model, r.modes, r.released, r.result, final)
        + _friction_markdown(r.identification, r.hysteresis)
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
        "`bench replay`): " + ", ".join(f"`can/{n}`" for n in r.sil_logs) + "; protocol: `firmware/bus.dbc`.\n"
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


def _friction_markdown(identification, hysteresis: list[str]) -> str:
    truth = lugre.TABLE_1[identification.joint_type]
    lines = [
        "## Friction joint: identification from rig records (Section 3.2, Eq. 3 + output error)",
        "",
        f"Synthetic records of the isolated type {identification.joint_type} joint (paper Table 1 parameters, "
        "1 % measurement noise): two micro-slip and four stick-slip records at F_N = 200 and 400 N.",
        "",
        plots.identification_table(identification),
        "",
        "| parameter | Table 1 | identified | error [%] |",
        "|---|---:|---:|---:|",
    ]
    for name in ("sigma0", "sigma1", "sigma2", "coulomb", "stribeck", "stribeck_velocity"):
        true, found = getattr(truth, name), getattr(identification.parameters, name)
        lines.append(f"| {name} | {true:.4g} | {found:.4g} | {100 * (found / true - 1):+.1f} |")
    lines += [
        "",
        "Weakly identifiable (95 % interval wider than ±50 %) by the two Eq. 3 steps: "
        + (", ".join(identification.weak_by_equation_error) or "none")
        + " (the paper found σ1 and σ2).",
    ]
    if identification.refined is not None:
        lines += [
            "After the output-error step (rig model driven by the measured excitation force, "
            "docs/identification.md): " + (", ".join(identification.weakly_identifiable) or "none") + "."
        ]
    lines += ["Steps: " + "; ".join(identification.steps) + ".", ""]
    lines += [f"![{name}]({name})" for name in hysteresis]
    return "\n".join(lines) + "\n"


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
