"""The commands of the structure and reduction stages (``modes``, ``update``, ``export-model``,
``run``, ``reduce``, ``simulate``, ``place``) and the helpers every command shares: progress on
stderr, the updated design, plots and atomic writes (the friction stage's commands are in
``commands_friction``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from smartjoint.common import figures, output_path
from smartjoint.common.errors import ModelError, SmartjointError


def report_progress(message: str) -> None:
    """Print a progress line on stderr, flushed (stdout carries the results and the JSON).

    Parameters
    ----------
    message : str
        One line.
    """
    # One write with its newline: print() writes the line and the newline apart, and a Ctrl-C or
    # SIGTERM between the two would put the command's last line on the end of this one.
    sys.stderr.write(f"{message}\n")
    sys.stderr.flush()


def load_updated(args, *, firmware_names: bool = False, friction: bool = False):
    """The design, updated to its EMA unless --no-update, and the updating result (or None).

    The updated parameters also hold for a design that adds joints to an updated base.

    Parameters
    ----------
    args : argparse.Namespace
        ``design`` (a path or None for the bundled reference) and, where the command has it,
        ``no_update``.
    firmware_names : bool
        Refuse, before any work, joint and sensor names the firmware cannot carry.
    friction : bool
        Refuse, before any work, joints without friction parameters or records.

    Returns
    -------
    tuple
        (Design, UpdatingResult or None).
    """
    from smartjoint.design import load_design, updated_design

    design = load_design(args.design)
    if firmware_names:
        check_firmware_names(design)
    if friction:
        from smartjoint.design.friction.stage import check_friction_given

        check_friction_given(design)
    if design.updating is None or getattr(args, "no_update", False):
        return design, None
    report_progress(
        f"updating {len(design.updating.parameters)} parameters to {len(design.updating.measured)} measured modes …"
    )
    return updated_design(
        design,
        lambda k, n, err: report_progress(f"  start {k}/{n}: worst error {err:.2f} %"),
        lambda message: report_progress(f"warning: {message}"),
    )


def check_firmware_names(design) -> None:
    """Refuse joint and sensor names of ``design`` that the generated C and the CAN layer cannot
    carry (C keywords, reserved names, the E2E signals) — one line naming ``sensors[i].name``.

    Parameters
    ----------
    design : Design
        The design whose names are checked.

    Raises
    ------
    SmartjointError
        For the first name the firmware cannot carry.
    """
    from smartjoint.codegen import identifiers
    from smartjoint.design.network import protocol

    identifiers.check_names(
        [j.name for j in design.joints],
        [s.name for s in design.sensors],
        members=protocol.E2E_SIGNALS,
        fields=identifiers.DESIGN_FIELDS,
    )


def write_plots(args, out: dict, draw) -> None:
    """With --plots DIR: create DIR, let ``draw(folder)`` write its PNGs, list them in ``out``.

    Parameters
    ----------
    args : argparse.Namespace
        Its ``plots`` is the folder, or None for no plots.
    out : dict
        The command's result; gets ``"plots"``, the files written.
    draw : callable
        ``draw(folder)`` writes the PNGs and returns their paths.
    """
    if args.plots:
        folder = figures.folder_for(args.plots)
        out["plots"] = [str(p) for p in draw(folder)]


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` whole, by the output rule (`common.output_path.write_file`).

    Parameters
    ----------
    path : Path
        The file; its folder is created.
    text : str
        The content.
    """
    output_path.write_file(path, text)


def _model(args, *, joints: str = "locked"):
    """Load the design, build the FE model and, unless --no-update, update it to the EMA."""
    from smartjoint.design import build_model

    design, result = load_updated(args)
    return build_model(design, joints=joints), result


def cmd_modes(args) -> dict:
    """``smartjoint modes``: the lowest modes, their effective masses along x, y, z and, with
    measured data, the EMA comparison (by number) and the MAC pairing (with EMA shapes)."""
    from smartjoint.design import solve_modes
    from smartjoint.design.structure.correlation import correlate, measurement_matrix
    from smartjoint.design.structure.participation import DIRECTIONS, effective_modal_mass
    from smartjoint.design.structure.updating import PAIRING_MARGIN

    model, result = _model(args)
    modes = solve_modes(model, min(args.count, model.n_dof))
    participation = effective_modal_mass(model, modes.shapes)
    out = {
        "design": model.design.name,
        "n_dof": model.n_dof,
        "updated": result is not None,
        "modes": [
            {"index": i + 1, "frequency_hz": float(f), **_mode_participation(participation, i)}
            for i, f in enumerate(modes.frequencies_hz)
        ],
        "free_mass_kg": dict(zip(DIRECTIONS, participation.free_mass.tolist())),
    }
    spec = model.design.updating
    if spec is not None:
        n = max(m.mode for m in spec.measured)
        if spec.has_shapes:
            n = min(model.n_dof, n + PAIRING_MARGIN)
        solved = modes if n <= len(modes) else solve_modes(model, n)
        frequencies = solved.frequencies_hz
        out["ema_comparison"] = [
            {
                "index": m.mode,
                "ema_hz": m.frequency_hz,
                "fem_hz": float(frequencies[m.mode - 1]),
                "error_pct": float(100.0 * (frequencies[m.mode - 1] - m.frequency_hz) / m.frequency_hz),
            }
            for m in spec.measured
        ]
        if spec.has_shapes:
            restricted = measurement_matrix(model, spec.measured_dofs) @ solved.shapes[:, :n]
            out["mac"] = correlate(spec, restricted, frequencies[:n]).as_dict()
    if not args.json:
        _print_modes(model, result, out)
    return out


def _mode_participation(participation, i: int) -> dict:
    """The JSON of mode i's participation factors, effective masses and cumulative mass fractions."""
    from smartjoint.design.structure.participation import DIRECTIONS

    return {
        "participation_factor": dict(zip(DIRECTIONS, participation.participation[i].tolist())),
        "effective_mass_kg": dict(zip(DIRECTIONS, participation.effective_mass[i].tolist())),
        "cumulative_effective_mass_fraction": dict(zip(DIRECTIONS, participation.cumulative_fraction[i].tolist())),
    }


def _print_modes(model, result, out: dict) -> None:
    """The text of ``smartjoint modes``: the table of modes, the EMA comparison, the MAC pairing."""
    from smartjoint.design.structure.participation import DIRECTIONS

    print(f"{model.design.name}: {model.n_dof} DOFs ({'updated' if result else 'as designed'})")
    print(" mode  frequency [Hz]   effective mass x / y / z [kg]   cumulative x / y / z [%]")
    for m in out["modes"]:
        mass = " ".join(f"{m['effective_mass_kg'][d]:9.3f}" for d in DIRECTIONS)
        share = " ".join(f"{100 * m['cumulative_effective_mass_fraction'][d]:6.1f}" for d in DIRECTIONS)
        print(f"{m['index']:5d}  {m['frequency_hz']:12.4f}   {mass}   {share}")
    free = ", ".join(f"{d} {out['free_mass_kg'][d]:.2f}" for d in DIRECTIONS)
    print(f"free mass (moves with the supports) [kg]: {free}")
    if "ema_comparison" in out:
        print("\n mode   EMA [Hz]   FEM [Hz]  error [%]")
        for c in out["ema_comparison"]:
            print(f"{c['index']:5d} {c['ema_hz']:10.3f} {c['fem_hz']:10.3f} {c['error_pct']:+10.2f}")
    if "mac" in out:
        print("\n EMA mode  FE mode (MAC pair)    MAC")
        for p in out["mac"]["pairing"]:
            swap = "  swap" if p["fe_mode"] != p["measured_mode"] else ""
            print(f"{p['measured_mode']:9d} {p['fe_mode']:8d} {p['mac']:19.3f}{swap}")
        for swap in out["mac"]["swaps"]:
            report_progress(f"warning: {swap}")


def cmd_update(args) -> dict:
    from smartjoint.design import load_design

    design = load_design(args.design)
    if design.updating is None:  # refused before the FE model is built (17 s on a 1000-bay mast)
        raise SmartjointError(f"{design.source}: the design has no [updating] section")
    model, result = _model(args)
    assert result is not None  # the design has an [updating] section
    out = result.as_dict()
    if not args.json:
        from smartjoint.report import correlation_table, updating_table

        print(updating_table(result))
        if result.correlation is not None:
            print("\nMAC pairing (EMA shapes):\n")
            print(correlation_table(result))
    return out


def cmd_export_model(args) -> dict:
    from smartjoint.design.structure.export import export_model

    model, _ = _model(args, joints=args.joints)
    document = export_model(model)
    write_atomic(Path(args.output), json.dumps(document, indent=1, sort_keys=True) + "\n")
    summary = {
        "output": str(args.output),
        "points": len(document["points"]),
        "elements": len(document["elements"]),
        "rigid_links": len(document["rigid_links"]),
        "n_dof": model.n_dof,
    }
    if not args.json:
        print(
            f"wrote {args.output}: {summary['points']} points, {summary['elements']} elements, "
            f"{summary['rigid_links']} rigid links, {summary['n_dof']} independent DOFs"
        )
    return summary


def cmd_run(args) -> dict:
    from smartjoint.report_folder import inspect

    inspect(Path(args.output))  # refuse a file or a foreign folder before the pipeline even loads
    from smartjoint.pipeline import run

    result = run(args.design, Path(args.output), progress=report_progress)
    if result.get("stopped"):  # the report of the stages before it is written; the run failed
        if args.json:
            print(json.dumps(result, indent=1))
        raise ModelError(f"{result['stopped']} — the report up to it: {result['report']}")
    if not args.json:
        print(f"report: {result['report']}")
    return result


def parse_normal_forces(text: str, design):
    """``--normal-force "400,0,0"`` → one F_N per joint, in the design's joint order.

    Parameters
    ----------
    text : str
        Comma-separated normal forces [N].
    design : Design
        The design whose joints the values are for.

    Returns
    -------
    ndarray
        One finite F_N ≥ 0 per joint.

    Raises
    ------
    ModelError
        For values that are no numbers, of the wrong count, not finite or negative.
    """
    import numpy as np

    try:
        values = np.array([float(v) for v in text.split(",")], dtype=float)
    except ValueError:
        raise ModelError(f"--normal-force: {text!r} — expected comma-separated numbers [N], one per joint") from None
    if values.size != len(design.joints) or not np.all(np.isfinite(values)) or np.any(values < 0):
        raise ModelError(
            f"--normal-force: {text!r} — need {len(design.joints)} finite values >= 0 "
            f"(joints {', '.join(j.name for j in design.joints)})"
        )
    return values


def _released_for_reduction(design, considered: int):
    """Above the study's dense limit, one sparse solution of the released truss serves the design
    model and the study's reference (2 × the considered modes); None below it or without joints."""
    if not design.joints:
        return None
    from smartjoint.design import build_model
    from smartjoint.design.reduction.study import DENSE_REFERENCE_DOFS, REFERENCE_MODES_PER_CONSIDERED
    from smartjoint.design.structure.solved import solved_model

    fe = build_model(design, joints="released")
    if fe.n_dof <= DENSE_REFERENCE_DOFS:
        return None
    count = min(REFERENCE_MODES_PER_CONSIDERED * max(considered, design.control.considered_modes), fe.n_dof - 2)
    report_progress(f"      the lowest {count} modes of the released truss ({fe.n_dof} DOFs, sparse) …")
    return solved_model(fe, count)


def cmd_reduce(args) -> dict:
    import numpy as np

    from smartjoint.design.reduction import load_case, reduction_study, study_summary
    from smartjoint.report_reduction import plot_study

    design, _ = load_updated(args, friction=True)
    forces = (
        (parse_normal_forces(args.normal_force, design) if args.normal_force else load_case(design))
        if design.joints
        else None
    )
    if forces is not None and not forces.any():
        raise ModelError(f"--normal-force: {args.normal_force!r} — at least one joint > 0 N (the joint compared)")
    joints = None
    if args.krylov_joints:
        names = [j.name for j in design.joints]
        unknown = [n for n in args.krylov_joints.split(",") if n not in names]
        if unknown:
            raise ModelError(f"--krylov-joints: {unknown[0]!r} — joints are {', '.join(names)}")
        joints = [names.index(n) for n in args.krylov_joints.split(",")]
    elif forces is not None:
        joints = [int(np.argmax(forces))]
    released = _released_for_reduction(design, args.considered)
    model = None
    if design.joints and design.sensors and design.disturbances:
        from smartjoint.design.control.study import design_model

        model = design_model(design, report_progress, released)  # compared with balanced truncation to Nyquist
    study = reduction_study(
        design,
        forces if forces is not None else np.zeros(0),
        args.considered,
        args.modes,
        tuple(sorted({0, args.krylov})),
        joints,
        args.duration,
        args.step,
        report_progress,
        released=released,
        design_model=model,
    )
    out = study_summary(study)
    write_plots(args, out, lambda folder: plot_study(study, folder))
    if not args.json:
        from smartjoint.report_reduction import study_markdown

        print(study_markdown(study))
    return out


def cmd_simulate(args) -> dict:
    import numpy as np

    from smartjoint.design import build_model, plant, reduction
    from smartjoint.design.friction.model import joint_parameters
    from smartjoint.design.structure import modal

    if args.sample_time is not None and not (np.isfinite(args.sample_time) and args.sample_time > 0):
        raise ModelError(f"--sample-time: {args.sample_time!r} — must be a finite number > 0 [s]")
    design, _ = load_updated(args, friction=True)
    forces = parse_normal_forces(args.normal_force, design)
    fe = build_model(design, joints="released")
    if args.reduced:
        keep, krylov = (int(v) for v in args.reduced.split(":"))
        model = reduction.reduce(fe, modal.solve_modes(fe, min(args.considered, fe.n_dof)), keep, krylov).model
    else:
        model = modal.modal_model(fe, modal.solve_modes(fe, fe.n_dof))
    scheme = f"stick-exact, {args.stick_step:g} s while the joints stick" if args.stick_step else "fixed step"
    report_progress(f"simulating {model.n_states} states for {args.duration:g} s at {args.step:g} s ({scheme}) …")
    stick = (
        {}
        if args.stick_step is None
        else {
            "stick_step": args.stick_step,
            "energy_books": False,
            "record_every": int(round(args.stick_step / args.step)),
        }
    )
    result = plant.simulate(
        model,
        joint_parameters(design),
        plant.ConstantNormalForce(forces, args.sample_time if args.sample_time else design.control.sample_time),
        plant.triangular_pulse(design.control.pulse_amplitude, directions=np.ones(len(design.disturbances))),
        args.duration,
        args.step,
        progress=report_progress,
        **stick,
    )
    after = result.time >= 0.04
    books = args.stick_step is None  # the stick-exact scheme keeps no energy books
    out = {
        "design": design.name,
        "states": model.n_states,
        "normal_forces": forces.tolist(),
        "scheme": scheme,
        "energy_measure_eq32": result.energy_measure(),
        "final_energy": float(result.energy[-1]),
        "peak_energy": float(result.energy.max()),
        "energy_balance_error": result.balance_error() if books else None,
        "dissipated_by_joints": float(result.work_joints[-1]) if books else None,
        "input_work": float(result.work_in[-1]) if books else None,
        "tip_rms_after_pulse": dict(
            zip(result.sensor_names, np.sqrt(np.mean(result.sensors[after] ** 2, axis=0)).tolist())
        ),
        "joints": {
            name: {
                "peak_friction": float(np.abs(result.friction_force[:, j]).max()),
                "peak_sliding_velocity": float(np.abs(result.sliding_velocity[:, j]).max()),
            }
            for j, name in enumerate(result.joint_names)
        },
    }
    if not args.json:
        for key, value in out.items():
            print(f"{key}: {value}")
    return out


def cmd_place(args) -> dict:
    import os

    from smartjoint.design import build_model, solve_modes
    from smartjoint.design.structure import placement

    design, _ = load_updated(args)
    if design.joints:
        raise ModelError(
            f"design {design.name!r} already has joints ({', '.join(j.name for j in design.joints)}): "
            "place joints on the conventional truss (a design without [[joints]])"
        )
    try:
        targets = sorted({int(v) - 1 for v in args.modes.split(",")})
    except ValueError:
        raise ModelError(f"--modes: {args.modes!r} — expected comma-separated mode numbers, e.g. 1,2") from None
    fe = build_model(design, joints="locked")
    count = max(targets) + 1 if targets and targets[0] >= 0 else 1
    report_progress(f"      the lowest {min(count, fe.n_dof)} modes of the locked truss ({fe.n_dof} DOFs) …")
    modes = solve_modes(fe, count)
    candidates = placement.connector_energy(fe, modes, targets)
    chosen = placement.choose(candidates, args.count)
    ranking = placement.rank(candidates)[: args.top]
    out = {
        "design": design.name,
        "target_modes": [i + 1 for i in targets],
        "target_frequencies_hz": [float(modes.frequencies_hz[i]) for i in targets],
        "chosen": [
            {"member": c.member, "end": c.end, "score": c.score, "fractions": list(c.fractions)} for c in chosen
        ],
        "ranking": [{"member": c.member, "end": c.end, "score": c.score} for c in ranking],
    }
    if args.output:
        target = Path(args.output)
        source = Path(design.source)
        base = os.path.relpath(source.resolve(), target.resolve().parent) if source.exists() else str(source)
        write_atomic(target, placement.design_text(base, f"{design.name}-placed", chosen, targets))
        out["written"] = str(target)
    if not args.json:
        print(
            f"modes {', '.join(str(i + 1) for i in targets)} "
            f"({', '.join(f'{f:.2f}' for f in out['target_frequencies_hz'])} Hz): best end connectors"
        )
        print("| rank | member | end | strain-energy fraction (sum over the modes) |\n|---:|---|---|---:|")
        for k, c in enumerate(ranking, start=1):
            mark = " ← joint" if any(c.member == j.member and c.end == j.end for j in chosen) else ""
            print(f"| {k} | {c.member} | {c.end} | {c.score:.4g}{mark} |")
        if args.output:
            print(f"design with {len(chosen)} type A joints written to {args.output}")
    return out
