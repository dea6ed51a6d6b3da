"""The ``smartjoint`` command line: a thin layer over the library.

Every command that reports numbers offers ``--json``. User errors (a bad design file, a
model that cannot be built) end with a one-line message on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
from pathlib import Path

from smartjoint import __version__
from smartjoint.common.errors import SmartjointError


def _progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} — must be a whole number >= 1")
    return value


def _add_design(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("design", nargs="?", default=None,
                        help="design file (TOML); default: the bundled 10-bay reference truss")


def _model(args, *, joints: str = "locked"):
    """Load the design, build the FE model and, unless --no-update, update it to the EMA."""
    from smartjoint.design import build_model

    design, result = _updated(args)
    return build_model(design, joints=joints), result


def _updated(args, *, firmware_names: bool = False):
    """The design, updated to its EMA unless --no-update, and the updating result (or None).
    The updated parameters also hold for a design that adds joints to an updated base.
    ``firmware_names``: refuse, before any work, joint and sensor names the firmware cannot carry."""
    from smartjoint.design import load_design, updated_design

    design = load_design(args.design)
    if firmware_names:
        check_firmware_names(design)
    if design.updating is None or getattr(args, "no_update", False):
        return design, None
    _progress(f"updating {len(design.updating.parameters)} parameters to {len(design.updating.measured)} measured modes …")
    return updated_design(design, lambda k, n, err: _progress(f"  start {k}/{n}: worst error {err:.2f} %"))


def cmd_modes(args) -> dict:
    from smartjoint.design import solve_modes

    model, result = _model(args)
    modes = solve_modes(model, min(args.count, model.n_dof))
    out = {"design": model.design.name, "n_dof": model.n_dof, "updated": result is not None,
           "modes": [{"index": i + 1, "frequency_hz": float(f)} for i, f in enumerate(modes.frequencies_hz)]}
    spec = model.design.updating
    if spec is not None:
        n = max(m.mode for m in spec.measured)
        frequencies = modes.frequencies_hz if n <= len(modes) else solve_modes(model, n).frequencies_hz
        out["ema_comparison"] = [
            {"index": m.mode, "ema_hz": m.frequency_hz, "fem_hz": float(frequencies[m.mode - 1]),
             "error_pct": float(100.0 * (frequencies[m.mode - 1] - m.frequency_hz) / m.frequency_hz)}
            for m in spec.measured
        ]
    if not args.json:
        print(f"{model.design.name}: {model.n_dof} DOFs ({'updated' if result else 'as designed'})")
        print(" mode  frequency [Hz]")
        for m in out["modes"]:
            print(f"{m['index']:5d}  {m['frequency_hz']:12.4f}")
        if "ema_comparison" in out:
            print("\n mode   EMA [Hz]   FEM [Hz]  error [%]")
            for c in out["ema_comparison"]:
                print(f"{c['index']:5d} {c['ema_hz']:10.3f} {c['fem_hz']:10.3f} {c['error_pct']:+10.2f}")
    return out


def cmd_update(args) -> dict:
    model, result = _model(args)
    if result is None:
        raise SmartjointError(f"{model.design.source}: the design has no [updating] section")
    out = result.as_dict()
    if not args.json:
        from smartjoint.report import updating_table

        print(updating_table(result))
    return out


def cmd_export_model(args) -> dict:
    from smartjoint.design.structure.export import export_model

    model, _ = _model(args, joints=args.joints)
    document = export_model(model)
    _write_atomic(Path(args.output), json.dumps(document, indent=1, sort_keys=True) + "\n")
    summary = {"output": str(args.output), "points": len(document["points"]), "elements": len(document["elements"]),
               "rigid_links": len(document["rigid_links"]), "n_dof": model.n_dof}
    if not args.json:
        print(f"wrote {args.output}: {summary['points']} points, {summary['elements']} elements, "
              f"{summary['rigid_links']} rigid links, {summary['n_dof']} independent DOFs")
    return summary


def cmd_run(args) -> dict:
    from smartjoint.report_folder import inspect

    inspect(Path(args.output))  # refuse a file or a foreign folder before the pipeline even loads
    from smartjoint.pipeline import run

    result = run(args.design, Path(args.output), progress=_progress)
    if not args.json:
        print(f"report: {result['report']}")
    return result


_LUGRE_FLAGS = ("sigma0", "sigma1", "sigma2", "coulomb", "stribeck", "stribeck_velocity", "radius")


def _rig_parameters(args):
    """The rig's parameter set: --parameters FILE, or all the LuGre flags, or (neither) Table 1."""
    from smartjoint.design.friction import rig

    flags = {n: getattr(args, n) for n in _LUGRE_FLAGS if getattr(args, n) is not None}
    if args.parameters is not None:
        if flags:
            raise SmartjointError(f"--{next(iter(flags)).replace('_', '-')} together with --parameters — give "
                                  "the parameter set either as flags or as a file")
        return rig.load_parameter_set(args.parameters, args.type)
    joint_type = args.type or "A"
    if not flags:
        return rig.parameter_set(joint_type)
    values = {n: v for n, v in flags.items()}
    for name in _LUGRE_FLAGS:
        if name not in values and (name != "radius" or joint_type == "B"):
            raise SmartjointError(f"--{name.replace('_', '-')} missing — give all of --sigma0, --sigma1, "
                                  "--sigma2, --coulomb, --stribeck, --stribeck-velocity"
                                  f"{', --radius' if joint_type == 'B' else ''} (or --parameters FILE, or none of "
                                  f"them for {rig.TABLE_1_SOURCE})")
    if "radius" in values and joint_type == "A":
        raise SmartjointError("--radius: a type A joint has no radius — allowed only with --type B")
    return rig.parameter_set(joint_type, values, "command line")


def _rig_test(args, joint_type, normal_force, amplitude, frequency, seed):
    from smartjoint.design.friction.rig import RigTest

    inertia = args.inertia if args.inertia is not None else (1.0 if joint_type == "A" else 2e-3)
    return RigTest(joint_type, normal_force, amplitude, frequency, cycles=args.cycles, inertia=inertia,
                   noise=args.noise, seed=seed)


def cmd_rig(args) -> dict:
    from smartjoint.design.friction import rig
    from smartjoint.design.friction.records import write_record

    output = Path(args.output)
    chosen = _rig_parameters(args)
    parameters, joint_type = chosen.parameters, chosen.joint_type
    if args.campaign:
        if output.exists() and not output.is_dir():
            raise SmartjointError(f"-o {output}: exists and is not a folder — --campaign writes its records "
                                  "into a folder")
        tests = rig.campaign(joint_type, parameters, noise=args.noise, seed=args.seed, cycles=args.cycles)
        paths = [output / f"{t.name}.csv" for t in tests]
    else:
        missing = [n for n in ("normal_force", "amplitude", "frequency") if getattr(args, n) is None]
        if missing:
            raise SmartjointError(f"give --{missing[0].replace('_', '-')} (or --campaign)")
        if output.is_dir():
            raise SmartjointError(f"-o {output}: is a folder — give a record file name (or --campaign)")
        tests = [_rig_test(args, joint_type, args.normal_force, args.amplitude, args.frequency, args.seed)]
        paths = [output]
    for test in tests:  # every test is checked before anything is written
        rig.check_test(test, parameters)
    if not args.json:
        print(chosen.describe())
    if args.campaign:
        try:
            output.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise SmartjointError(f"-o {output}: cannot create folder ({error.strerror or error})") from None
    written = []
    for test, path in zip(tests, paths):
        record = rig.simulate(test, parameters, chosen.source)
        write_record(record, path)
        written.append({"file": str(path), "regime": record.metadata["regime"], "samples": int(record.time.size),
                        "max_velocity": float(abs(record.sliding_velocity).max())})
        if not args.json:
            print(f"wrote {path} ({record.metadata['regime']}, {record.time.size} samples)")
    return {"parameters": chosen.as_dict(), "records": written}


def cmd_identify(args) -> dict:
    from smartjoint.design.friction.identify import classify, identify
    from smartjoint.design.friction.records import read_record
    from smartjoint.report import identification_table, plot_hysteresis

    records = [read_record(path, args.radius) for path in args.records]
    micro = [r for r in records if classify(r, args.radius) == "micro-slip"]
    stick = [r for r in records if classify(r, args.radius) == "stick-slip"]
    result = identify(micro, stick, radius=args.radius, progress=_progress, output_error=not args.no_output_error)
    out = result.as_dict()
    _plots(args, out, lambda folder: plot_hysteresis(result, folder))
    if not args.json:
        print("\n".join(f"step: {step}" for step in result.steps) + "\n")
        print(identification_table(result))
    return out


def _plots(args, out: dict, draw) -> None:
    """With --plots DIR: create DIR, let ``draw(folder)`` write its PNGs, list them in ``out``."""
    if args.plots:
        folder = Path(args.plots)
        folder.mkdir(parents=True, exist_ok=True)
        out["plots"] = [str(p) for p in draw(folder)]


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

    from smartjoint.common.errors import ModelError

    try:
        values = np.array([float(v) for v in text.split(",")], dtype=float)
    except ValueError:
        raise ModelError(f"--normal-force: {text!r} — expected comma-separated numbers [N], one per joint") from None
    if values.size != len(design.joints) or not np.all(np.isfinite(values)) or np.any(values < 0):
        raise ModelError(f"--normal-force: {text!r} — need {len(design.joints)} finite values >= 0 "
                         f"(joints {', '.join(j.name for j in design.joints)})")
    return values


def cmd_reduce(args) -> dict:
    import numpy as np

    from smartjoint.design.reduction import reduction_study, study_summary
    from smartjoint.report_reduction import plot_study

    design, _ = _updated(args)
    forces = parse_normal_forces(args.normal_force, design) if args.normal_force else \
        np.array([400.0 if j.type == "B" else 0.0 for j in design.joints]) if design.joints else None
    if forces is not None and not forces.any():
        forces[0] = 400.0
    joints = None
    if args.krylov_joints:
        names = [j.name for j in design.joints]
        unknown = [n for n in args.krylov_joints.split(",") if n not in names]
        if unknown:
            from smartjoint.common.errors import ModelError
            raise ModelError(f"--krylov-joints: {unknown[0]!r} — joints are {', '.join(names)}")
        joints = [names.index(n) for n in args.krylov_joints.split(",")]
    elif forces is not None:
        joints = [int(np.argmax(forces))]
    study = reduction_study(design, forces if forces is not None else np.zeros(0), args.considered, args.modes,
                            tuple(sorted({0, args.krylov})), joints, args.duration, args.step, _progress)
    out = study_summary(study)
    _plots(args, out, lambda folder: plot_study(study, folder))
    if not args.json:
        from smartjoint.report_reduction import study_markdown
        print(study_markdown(study))
    return out


def cmd_simulate(args) -> dict:
    import numpy as np

    from smartjoint.design import build_model
    from smartjoint.design.structure import modal
    from smartjoint.design import reduction
    from smartjoint.design.plant import simulate
    from smartjoint.design.friction.lugre import joint_laws

    design, _ = _updated(args)
    forces = parse_normal_forces(args.normal_force, design)
    fe = build_model(design, joints="released")
    if args.reduced:
        keep, krylov = (int(v) for v in args.reduced.split(":"))
        model = reduction.reduce(fe, modal.solve_modes(fe, min(args.considered, fe.n_dof)), keep, krylov).model
    else:
        model = modal.modal_model(fe, modal.solve_modes(fe, fe.n_dof))
    scheme = f"stick-exact, {args.stick_step:g} s while the joints stick" if args.stick_step else "fixed step"
    _progress(f"simulating {model.n_states} states for {args.duration:g} s at {args.step:g} s ({scheme}) …")
    stick = {} if args.stick_step is None else {"stick_step": args.stick_step, "energy_books": False,
                                                 "record_every": int(round(args.stick_step / args.step))}
    result = simulate.simulate(model, joint_laws(design), simulate.ConstantNormalForce(forces, args.sample_time),
                               simulate.triangular_pulse(directions=np.ones(len(design.disturbances))), args.duration,
                               args.step, progress=_progress, **stick)
    after = result.time >= 0.04
    books = args.stick_step is None  # the stick-exact scheme keeps no energy books
    out = {"design": design.name, "states": model.n_states, "normal_forces": forces.tolist(), "scheme": scheme,
           "energy_measure_eq32": result.energy_measure(), "final_energy": float(result.energy[-1]),
           "peak_energy": float(result.energy.max()), "energy_balance_error": result.balance_error() if books else None,
           "dissipated_by_joints": float(result.work_joints[-1]) if books else None,
           "input_work": float(result.work_in[-1]) if books else None,
           "tip_rms_after_pulse": dict(zip(result.sensor_names, np.sqrt(np.mean(result.sensors[after] ** 2, axis=0)).tolist())),
           "joints": {name: {"peak_friction": float(np.abs(result.friction_force[:, j]).max()),
                             "peak_sliding_velocity": float(np.abs(result.sliding_velocity[:, j]).max())}
                      for j, name in enumerate(result.joint_names)}}
    if not args.json:
        for key, value in out.items():
            print(f"{key}: {value}")
    return out


def check_firmware_names(design) -> None:
    """Joint and sensor names of ``design`` that the generated C and the CAN layer cannot carry
    (C keywords, reserved names, the E2E signals) — one line naming ``sensors[i].name``."""
    from smartjoint.design.network import protocol
    from smartjoint.codegen import identifiers

    identifiers.check_names([j.name for j in design.joints], [s.name for s in design.sensors],
                            members=protocol.E2E_SIGNALS, fields=identifiers.DESIGN_FIELDS)


def _control_design(args, *, firmware_names: bool = False):
    """The (updated) design the controllers are built for: the given one, or for the bundled
    reference truss (no joints) the paper's three type A joint design of Fig. 11."""
    from smartjoint.design import load_design
    from smartjoint.design.structure import spec

    if args.design is None:
        args.design = str(spec.REFERENCE_DESIGN.parent / "three_type_a.toml")
    design, _ = _updated(args, firmware_names=firmware_names)
    if args.duration is not None:
        import dataclasses

        if not (args.duration > 0):
            from smartjoint.common.errors import ModelError
            raise ModelError(f"--duration: {args.duration!r} — must be > 0 [s]")
        design = dataclasses.replace(design, control=dataclasses.replace(design.control, study_duration=args.duration))
    return design


def cmd_study(args) -> dict:
    from smartjoint.report_control import control_markdown, plot_control_study
    from smartjoint.design.control import study as closed_loop

    design = _control_design(args)
    _progress(f"closed-loop study (Section 6) on {design.name!r}, t_e = {design.control.study_duration:g} s …")
    study = closed_loop.run_study(design, progress=_progress)
    out = closed_loop.summary(study)
    out["design"] = {"name": design.name, "source": design.source, "sha256": design.sha256}
    _plots(args, out, lambda folder: plot_control_study(study, folder))
    if not args.json:
        print(control_markdown(study))
    return out


def cmd_design(args) -> dict:
    from smartjoint.design.control import artifact
    from smartjoint.design.control import study as closed_loop

    design = _control_design(args, firmware_names=True)
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)  # fail early, not after the optimisation
    model = closed_loop.design_model(design, _progress)
    s = closed_loop.setup(design, model)
    lqg = closed_loop.lqg_for(design, model)
    width = design.control.siso_boundary_layer
    optimum = None
    if width is None:
        _progress("SISO boundary layer ε: optimising E(t_e) of Eq. 32 …")
        optimum = closed_loop.optimise_boundary_layer(s, lambda m: _progress(m))
        width = optimum.boundary_layer
    result = artifact.from_design(design, model, lqg, width)
    from smartjoint.bench import busload
    from smartjoint.design.network import protocol

    load = busload.check(protocol.database(result), args.bitrate, args.data_bitrate or None, args.max_load)
    _progress(f"CAN bus load {100 * load.load:.1f} % at {args.bitrate / 1e6:g}"
              f"{'' if not args.data_bitrate else f'/{args.data_bitrate / 1e6:g}'} Mbit/s (limit {100 * args.max_load:.0f} %)")
    artifact.save(result, Path(args.output))
    poles = lqg.closed_loop_poles()
    out = {"artifact": args.output, "artifact_sha256": result.artifact_sha256, "design_sha256": design.sha256,
           "states": model.n_states, "joints": list(result.joint_names), "sensors": list(result.sensor_names),
           "sample_time": result.sample_time, "siso_boundary_layer": result.siso_boundary_layer.tolist(),
           "clqg_boundary_layer": result.clqg_boundary_layer,
           "lqg_max_pole_magnitude": float(abs(poles).max()), "lqg_stability_margin": float(1 - abs(poles).max()),
           "bus_load": load.load,
           "boundary_layer_optimisation": None if optimum is None else {
               "optimum": optimum.boundary_layer, "energy_measure": optimum.energy_measure,
               "energy_measure_tenth": optimum.tenth, "energy_measure_tenfold": optimum.tenfold}}
    if not args.json:
        for key, value in out.items():
            print(f"{key}: {value}")
    return out


def cmd_codegen(args) -> dict:
    from smartjoint.codegen import generate
    from smartjoint.design.control import artifact

    loaded = artifact.load(Path(args.artifact))
    placed = generate.generate(loaded, Path(args.output), args.real, args.prefix, can=not args.no_can,
                               check=args.check, progress=_progress)
    out = {"artifact": args.artifact, "artifact_sha256": loaded.artifact_sha256, "real": args.real,
           "prefix": args.prefix, "files": [str(p) for p in placed.written],
           "untouched": [str(p) for p in placed.untouched]}
    if args.check:
        out["compiled"] = True
        out["check"] = placed.compiled
    if not args.json:
        print(f"{len(placed.written)} files in {args.output} ({args.real}, artefact {loaded.artifact_sha256[:16]}…"
              f"{', compiled' if args.check else ''})")
        for path in placed.written:
            print(f"  {path}")
        if placed.untouched:
            print(f"left untouched (not generated by this run): {', '.join(p.name for p in placed.untouched)}")
    return out


def cmd_place(args) -> dict:
    import os

    from smartjoint.design import build_model, solve_modes
    from smartjoint.design.structure import placement
    from smartjoint.common.errors import ModelError

    design, _ = _updated(args)
    if design.joints:
        raise ModelError(f"design {design.name!r} already has joints ({', '.join(j.name for j in design.joints)}): "
                         "place joints on the conventional truss (a design without [[joints]])")
    try:
        targets = sorted({int(v) - 1 for v in args.modes.split(",")})
    except ValueError:
        raise ModelError(f"--modes: {args.modes!r} — expected comma-separated mode numbers, e.g. 1,2") from None
    fe = build_model(design, joints="locked")
    modes = solve_modes(fe, max(targets) + 1 if targets and targets[0] >= 0 else 1)
    candidates = placement.connector_energy(fe, modes, targets)
    chosen = placement.choose(candidates, args.count)
    ranking = placement.rank(candidates)[:args.top]
    out = {"design": design.name, "target_modes": [i + 1 for i in targets],
           "target_frequencies_hz": [float(modes.frequencies_hz[i]) for i in targets],
           "chosen": [{"member": c.member, "end": c.end, "score": c.score, "fractions": list(c.fractions)}
                      for c in chosen],
           "ranking": [{"member": c.member, "end": c.end, "score": c.score} for c in ranking]}
    if args.output:
        target = Path(args.output)
        source = Path(design.source)
        base = os.path.relpath(source.resolve(), target.resolve().parent) if source.exists() else str(source)
        _write_atomic(target, placement.design_text(base, f"{design.name}-placed", chosen, targets))
        out["written"] = str(target)
    if not args.json:
        print(f"modes {', '.join(str(i + 1) for i in targets)} "
              f"({', '.join(f'{f:.2f}' for f in out['target_frequencies_hz'])} Hz): best end connectors")
        print("| rank | member | end | strain-energy fraction (sum over the modes) |\n|---:|---|---|---:|")
        for k, c in enumerate(ranking, start=1):
            mark = " ← joint" if any(c.member == j.member and c.end == j.end for j in chosen) else ""
            print(f"| {k} | {c.member} | {c.end} | {c.score:.4g}{mark} |")
        if args.output:
            print(f"design with {len(chosen)} type A joints written to {args.output}")
    return out


def _controller_artifact(args, design, model):
    """--artifact FILE (checked against the design), else designed now (ε optimised if absent)."""
    from smartjoint.design.control import artifact
    from smartjoint.design.control import study as closed_loop
    from smartjoint.common.errors import ModelError

    if getattr(args, "artifact", None):
        loaded = artifact.load(Path(args.artifact))
        if loaded.design_sha256 != design.sha256:
            raise ModelError(f"--artifact {args.artifact}: designed from design sha256 {loaded.design_sha256[:16]}…, "
                             f"but {design.source} has {design.sha256[:16]}… — run `smartjoint design` again")
        return loaded
    s = closed_loop.setup(design, model)
    width = design.control.siso_boundary_layer
    if width is None:
        _progress("SISO boundary layer ε: optimising E(t_e) of Eq. 32 …")
        width = closed_loop.optimise_boundary_layer(s, _progress).boundary_layer
    return artifact.from_design(design, model, closed_loop.lqg_for(design, model), width)


def cmd_sil(args) -> dict:
    from smartjoint.bench import sil
    from smartjoint.design.control import study as closed_loop

    design = _control_design(args, firmware_names=True)
    model = closed_loop.design_model(design, _progress)
    controller = _controller_artifact(args, design, model)
    faults = [sil.parse_fault(text) for text in args.fault or []]
    laws = ("siso", "clqg") if args.law == "both" else (args.law,)
    _progress(f"software in the loop on {design.name!r}: {', '.join(laws)}, t_e = {design.control.study_duration:g} s")
    out = sil.sil_study(closed_loop.setup(design, model), controller, laws, args.real, faults, args.log_folder,
                        {"time_constant": args.amplifier_lag}, args.bitrate, args.data_bitrate, args.spread,
                        args.interface, args.channel, _progress)
    if not args.json:
        print(sil.sil_markdown(out))
    _plots(args, out, lambda folder: sil.plot_sil(out, folder, out.get("mil_runs")))
    out.pop("mil_runs", None)
    for law in out["laws"].values():
        law.pop("record")
        law.pop("result")
    out["design"] = {"name": design.name, "sha256": design.sha256}
    out["artifact_sha256"] = controller.artifact_sha256
    return out


def _bench_database(args):
    from smartjoint.design.network import protocol
    from smartjoint.design.control import artifact
    from smartjoint.common.errors import ModelError

    if args.dbc:
        try:
            return protocol.load_dbc(Path(args.dbc).read_text())
        except OSError as error:
            raise ModelError(f"--dbc {args.dbc}: cannot read ({error.strerror})") from None
    if args.artifact:
        return protocol.database(artifact.load(Path(args.artifact)))
    raise ModelError("give the protocol: --dbc FILE or --artifact controller.json")


def cmd_bench(args) -> dict:
    from smartjoint.bench import logs, sil
    from smartjoint.design.network import protocol
    from smartjoint.design.control import artifact

    if args.bench_command == "dbc":
        loaded = artifact.load(Path(args.artifact))
        db = protocol.database(loaded)
        from smartjoint.bench import busload

        load = busload.check(db, args.bitrate, args.data_bitrate, args.max_load)
        _write_atomic(Path(args.output), protocol.dbc_text(db))
        out = {"dbc": args.output, "frames": len(db.messages), "bus_load": load.load}
        if not args.json:
            print(load.table())
            print(f"DBC written to {args.output}")
        return out
    if args.bench_command == "log":
        bus = sil.open_bus(args.interface, args.channel)
        try:
            _progress(f"recording {args.interface}:{args.channel} to {args.output} (Ctrl-C stops) …")
            out = logs.record(bus, args.output, args.duration, args.rotate_bytes, progress=_progress)
        finally:
            bus.shutdown()
        if not args.json:
            print(f"{out['frames']} frames in {out['seconds']:.1f} s → {out['file']}")
        return out
    if args.bench_command == "decode":
        return _bench_decode(args)
    return _bench_replay(args)


def _bench_log(args):
    """The log of ``bench decode`` / ``bench replay``, its damage on stderr (counts by kind)."""
    from smartjoint.bench import logs
    from smartjoint.common.errors import ModelError

    content = logs.load(args.log)
    if not content.messages:
        raise ModelError(f"log file {args.log}: no frames"
                         + (f" ({content.problem()})" if content.problem() else "") + " — nothing to "
                         + args.bench_command)
    problem = content.problem()
    if problem:
        early = " ends early and" if content.truncated else ""
        _progress(f"warning: {args.log}{early} is damaged — {problem}; using the {len(content.messages)} frames read")
    return content


def _bench_decode(args) -> dict:
    from smartjoint.bench import logs

    content = _bench_log(args)
    decoded = logs.decode(content, _bench_database(args))
    out = decoded.summary()
    if args.output:
        logs.write_csv(decoded, args.output)
        out["csv"] = args.output
    _plots(args, out, lambda folder: logs.plot(decoded, folder))
    if decoded.skipped():
        _progress(f"warning: {decoded.skipped()} of {decoded.frames} frames not decoded: "
                  f"unknown ids {sum(decoded.unknown_ids.values())}, "
                  f"wrong length {sum(decoded.wrong_length.values())}, "
                  f"bad CRC {sum(decoded.bad_e2e.values())}, error frames {decoded.error_frames}, remote frames "
                  f"{decoded.remote_frames}, non-finite time stamps {decoded.non_finite_times}")
    if not args.json:
        for key, value in out.items():
            print(f"{key}: {value}")
    return out


def _bench_replay(args) -> dict:
    """Exit 1 (after the report) when a setpoint differs or a recorded one was not replayed."""
    from smartjoint.bench import firmware, logs
    from smartjoint.design.control import artifact
    from smartjoint.common.errors import ModelError

    content = _bench_log(args)
    loaded = artifact.load(Path(args.artifact))
    out = logs.replay(content, firmware.Firmware(loaded, args.law, args.real), args.tolerance)
    out["log_problem"] = content.problem()
    out["log"] = content.skipped()
    if out["setpoints_compared"] == 0 and out["recorded_not_replayed"] == 0:
        raise ModelError(f"log file {args.log}: no recorded SETPOINT_* frame to compare "
                         f"({out['samples']} samples replayed) — a log of the controller's bus is needed")
    line = (f"{out['samples']} samples ({out['silent_samples']} without frames), {out['setpoints_compared']} "
            f"setpoints compared, {out['differing']} differ beyond {args.tolerance:g} V (max "
            f"{out['max_difference_V']:.3g} V), {out['recorded_not_replayed']} recorded but not replayed, "
            f"{out['replayed_not_recorded'] + out['replayed_not_recorded_in_silent_samples']} replayed but not "
            f"recorded ({out['replayed_not_recorded_in_silent_samples']} of them in samples without frames)")
    skipped = out["recorded_setpoints_bad_crc"] + out["recorded_setpoints_wrong_length"]
    if skipped:
        line += (f"; {skipped} recorded setpoints not compared (bad CRC {out['recorded_setpoints_bad_crc']}, wrong "
                 f"length {out['recorded_setpoints_wrong_length']})")
    if out["ok"]:
        if not args.json:  # main prints the JSON
            print(line)
        return out
    print(json.dumps(out, indent=1) if args.json else line)  # main does not get to print: the exit is 1
    print(f"smartjoint bench replay: FAILED: {line}", file=sys.stderr)
    for d in out["first_differences"][:10]:
        replayed = "nothing" if d["replayed_V"] is None else f"{d['replayed_V']:.9g} V"
        print(f"  t = {d['time']:.6f} s {d['frame']} {d['kind']}: recorded {d['recorded_V']:.9g} V, replayed "
              f"{replayed}", file=sys.stderr)
    raise SystemExit(1)


def _write_atomic(path: Path, text: str) -> None:
    """Write through a temporary file so that a failure never leaves half a file behind."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".partial")
    temporary.write_text(text)
    temporary.replace(path)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="smartjoint", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"smartjoint {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("run", help="run the whole pipeline on a design and write a report")
    _add_design(p)
    p.add_argument("-o", "--output", default="smartjoint-report",
                   help="report folder: new, empty, or the report of an earlier run, which is replaced; anything "
                        "else is refused (default: %(default)s)")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("modes", help="eigenfrequencies, and the EMA comparison where the design has one")
    _add_design(p)
    p.add_argument("-n", "--count", type=_positive_int, default=20, help="number of modes (default: %(default)s)")
    p.add_argument("--no-update", action="store_true", help="use the design's nominal parameters")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=cmd_modes)

    p = sub.add_parser("update", help="fit the design's [updating] parameters to its measured frequencies")
    _add_design(p)
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=cmd_update)

    p = sub.add_parser("export-model", help="write the FE model in the neutral JSON format (docs/model-format.md)")
    _add_design(p)
    p.add_argument("-o", "--output", required=True, help="output file (JSON)")
    p.add_argument("--joints", choices=("locked", "released"), default="locked",
                   help="locked: conventional truss; released: joint DOFs free (default: %(default)s)")
    p.add_argument("--no-update", action="store_true", help="export the nominal (not updated) model")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=cmd_export_model)

    p = sub.add_parser("rig", help="simulate the isolated-joint test rig (Section 3.2) and write friction records")
    p.add_argument("--type", choices=("A", "B"), default=None,
                   help="joint type (default: the parameter file's joint_type, else A)")
    p.add_argument("--parameters", metavar="FILE", help="LuGre parameter set (TOML: sigma0, sigma1, sigma2, coulomb, "
                                                        "stribeck, stribeck_velocity, radius for type B, optional "
                                                        "joint_type; docs/identification.md)")
    lugre_flags = p.add_argument_group("LuGre parameter set as flags (all six, and --radius for type B; "
                                       "without flags or --parameters: the paper's Table 1)")
    lugre_flags.add_argument("--sigma0", type=float, help="bristle stiffness σ0 [1/m] (type B: [1/rad])")
    lugre_flags.add_argument("--sigma1", type=float, help="bristle damping σ1 [s/m]")
    lugre_flags.add_argument("--sigma2", type=float, help="viscous friction σ2 [s/m]")
    lugre_flags.add_argument("--coulomb", type=float, help="Coulomb coefficient F_c")
    lugre_flags.add_argument("--stribeck", type=float, help="Stribeck excess F_d = F_s − F_c")
    lugre_flags.add_argument("--stribeck-velocity", type=float, help="Stribeck velocity v_s [m/s] (type B: [rad/s])")
    lugre_flags.add_argument("--radius", type=float, help="joint radius r [m] (type B only)")
    p.add_argument("--normal-force", type=float, help="F_N [N]")
    p.add_argument("--amplitude", type=float, help="shaker force [N] (type B: moment [N·m])")
    p.add_argument("--frequency", type=float, help="excitation frequency [Hz]")
    p.add_argument("--cycles", type=float, default=4.0, help="excitation cycles (default: %(default)s)")
    p.add_argument("--inertia", type=float, help="friction element inertia [kg] or [kg·m²] (default 1 / 2e-3)")
    p.add_argument("--noise", type=float, default=0.0, help="measurement noise, relative to RMS (0 … 1, e.g. 0.01)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--campaign", action="store_true", help="write the standard micro-/stick-slip set into -o DIR")
    p.add_argument("-o", "--output", required=True, help="record file (CSV), or folder with --campaign")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=cmd_rig)

    p = sub.add_parser("identify", help="LuGre identification from friction records: two Eq. 3 steps, then "
                                       "output error on the rig model")
    p.add_argument("records", nargs="+", help="record files (CSV, docs/identification.md)")
    p.add_argument("--radius", type=float, help="joint radius r [m] of type B records that do not carry "
                                                "'# radius = … m' (no default)")
    p.add_argument("--no-output-error", action="store_true",
                   help="stop after the two Eq. 3 steps (by default an output-error step follows when the "
                        "stick-slip records carry excitation_force and inertia)")
    p.add_argument("--plots", help="folder for hysteresis plots (PNG)")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=cmd_identify)

    p = sub.add_parser("reduce", help="balanced mode selection + Krylov vectors (Section 4), checked against the full model")
    _add_design(p)
    p.add_argument("--modes", type=_positive_int, default=60, help="modes to keep (default: %(default)s)")
    p.add_argument("--considered", type=_positive_int, default=100, help="modes to choose from (default: %(default)s)")
    p.add_argument("--krylov", type=int, default=2, help="Krylov vectors per joint (default: %(default)s)")
    p.add_argument("--krylov-joints", help="comma-separated joint names that get vectors (default: the active joint)")
    p.add_argument("--normal-force", help="F_N per joint, comma-separated [N] (default: 400 for type B, else 0)")
    p.add_argument("--duration", type=float, default=0.5, help="simulated time [s] (default: %(default)s)")
    p.add_argument("--step", type=float, default=5e-5, help="plant step [s] (default: %(default)s)")
    p.add_argument("--plots", help="folder for hankel.png, friction_moment.png, energy.png")
    p.add_argument("--no-update", action="store_true", help="use the design's nominal parameters")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=cmd_reduce)

    p = sub.add_parser("simulate", help="passive closed-loop run under the paper's tip pulse")
    _add_design(p)
    p.add_argument("--normal-force", required=True, help="F_N per joint, comma-separated [N]")
    p.add_argument("--duration", type=float, default=1.0, help="simulated time [s] (default: %(default)s)")
    p.add_argument("--step", type=float, default=5e-5, help="plant step [s] (default: %(default)s)")
    p.add_argument("--sample-time", type=float, default=1e-3, help="controller sample time [s] (default: %(default)s)")
    p.add_argument("--stick-step", type=float, help="stick-exact scheme (reduced models): this long step while the "
                   "joints stick, --step elsewhere; records every long step; no energy books")
    p.add_argument("--reduced", help="KEEP:KRYLOV, e.g. 9:1, for a reduced model (default: the full model)")
    p.add_argument("--considered", type=_positive_int, default=100, help="modes to choose from with --reduced")
    p.add_argument("--no-update", action="store_true", help="use the design's nominal parameters")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("place", help="rank end connectors by modal strain energy and place type A joints (Section 6)")
    _add_design(p)
    p.add_argument("--modes", default="1,2", help="modes to damp, comma-separated numbers (default: %(default)s)")
    p.add_argument("--count", type=_positive_int, default=3, help="joints to place (default: %(default)s)")
    p.add_argument("--top", type=_positive_int, default=10, help="ranking rows to show (default: %(default)s)")
    p.add_argument("-o", "--output", help="write a design file with the joints (extends DESIGN via base = …)")
    p.add_argument("--no-update", action="store_true", help="use the design's nominal parameters")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=cmd_place)

    p = sub.add_parser("design", help="design the controllers (Section 5) and write the artefact codegen consumes")
    _add_design(p)
    p.add_argument("-o", "--output", default="controller.json", help="artefact file (default: %(default)s)")
    p.add_argument("--duration", type=float, help="t_e of Eq. 32 for the ε optimisation [s] (default: design file)")
    p.add_argument("--bitrate", type=int, default=1_000_000, help="CAN (arbitration) bitrate (default: %(default)s)")
    p.add_argument("--data-bitrate", type=int, default=5_000_000, help="CAN FD data bitrate, 0: classical CAN")
    p.add_argument("--max-load", type=float, default=0.7, help="refuse a bus load above this (default: %(default)s)")
    p.add_argument("--no-update", action="store_true", help="use the design's nominal parameters")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=cmd_design)

    p = sub.add_parser("codegen", help="generate the C99 controllers (SISO, clipped LQG) from a controller artefact")
    p.add_argument("artifact", help="controller design artefact (JSON, from `smartjoint design`)")
    p.add_argument("-o", "--output", required=True,
                   help="folder for the generated files: created, or one where codegen replaces only files it "
                        "generated (others are left untouched)")
    p.add_argument("--real", choices=("float", "double"), default="float", help="scalar type (default: %(default)s)")
    p.add_argument("--prefix", default="smartjoint", help="C name prefix of the modules (default: %(default)s)")
    p.add_argument("--check", action="store_true",
                   help="compile everything generated (headers alone, every .c, linked) with the strict warning set "
                        "before it is moved into place")
    p.add_argument("--no-can", action="store_true", help="controllers only, without the CAN message layer and DBC")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=cmd_codegen)

    p = sub.add_parser("sil", help="the paper's study through the CAN loop: firmware, bus, amplifiers (software in the loop)")
    _add_design(p)
    p.add_argument("--artifact", help="controller artefact (default: designed from DESIGN now)")
    p.add_argument("--law", choices=("siso", "clqg", "both"), default="both")
    p.add_argument("--real", choices=("float", "double"), default="float", help="firmware build (default: %(default)s)")
    p.add_argument("--duration", type=float, help="t_e [s] (default: the design's control.study_duration)")
    p.add_argument("--fault", action="append",
                   help="inject kind:target:start:end[:detail], repeatable; kinds: drop, delay (detail: seconds), "
                        "duplicate, corrupt_crc, corrupt_counter, wrong_dlc, silent on any frame (the firmware's "
                        "SETPOINT_* and CONTROLLER_STATUS too), implausible (target FRAME.signal, detail: the "
                        "value), amplifier (target a joint, detail: over_temperature, no_response, stuck_output, "
                        "over_current, gain_error), bus_off (no target); end may be inf")
    p.add_argument("--log-folder", help="write the bus of each run as sil_<law>.blf here")
    p.add_argument("--plots", help="folder for sil_energy.png")
    p.add_argument("--amplifier-lag", type=float, default=0.0, help="amplifier time constant [s] (default 0: ideal)")
    p.add_argument("--bitrate", type=int, default=1_000_000)
    p.add_argument("--data-bitrate", type=int, default=5_000_000, help="CAN FD data phase [bit/s]")
    p.add_argument("--spread", type=int, default=6, help="perturbed MIL runs for the sensitivity band (default: %(default)s)")
    p.add_argument("--interface", default="virtual", help="python-can interface (default: %(default)s)")
    p.add_argument("--channel", default="smartjoint-sil")
    p.add_argument("--no-update", action="store_true", help="use the design's nominal parameters")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=cmd_sil)

    p = sub.add_parser("bench", help="CAN bench tools: dbc, log, decode, replay")
    bench = p.add_subparsers(dest="bench_command", required=True, metavar="TOOL")
    q = bench.add_parser("dbc", help="write the DBC of a controller artefact after the bus-load check")
    q.add_argument("artifact")
    q.add_argument("-o", "--output", required=True)
    q.add_argument("--bitrate", type=int, default=1_000_000)
    q.add_argument("--data-bitrate", type=int, default=5_000_000)
    q.add_argument("--max-load", type=float, default=0.7, help="refuse above this load (default: %(default)s)")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_bench)
    q = bench.add_parser("log", help="record a python-can bus to ASC/BLF/MF4 (by suffix)")
    q.add_argument("-o", "--output", required=True)
    q.add_argument("--interface", default="virtual")
    q.add_argument("--channel", default="smartjoint-sil")
    q.add_argument("--duration", type=float, help="seconds (default: until Ctrl-C)")
    q.add_argument("--rotate-bytes", type=int, default=0, help="rotate the file at this size (0: never)")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_bench)
    q = bench.add_parser("decode", help="decode a log to signals (CSV) and plots with the DBC")
    q.add_argument("log")
    q.add_argument("--dbc")
    q.add_argument("--artifact")
    q.add_argument("-o", "--output", help="CSV file (time_s, frame, signal, value)")
    q.add_argument("--plots", help="folder for one PNG per frame")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_bench)
    q = bench.add_parser("replay", help="feed a log's sensor frames through the firmware; compare its setpoints")
    q.add_argument("log")
    q.add_argument("--artifact", required=True)
    q.add_argument("--law", choices=("siso", "clqg"), default="siso")
    q.add_argument("--real", choices=("float", "double"), default="float")
    q.add_argument("--tolerance", type=float, default=0.0, help="volts counted as equal (default 0: bit-exact)")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_bench)

    p = sub.add_parser("study", help="the paper's closed-loop study (Section 6): passive, SISO, cLQG, active LQG")
    _add_design(p)
    p.add_argument("--duration", type=float, help="t_e [s] (default: the design's control.study_duration)")
    p.add_argument("--plots", help="folder for control_energy.png, control_tip.png, … (PNG)")
    p.add_argument("--no-update", action="store_true", help="use the design's nominal parameters")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=cmd_study)
    return parser


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C's KeyboardInterrupt so that the same clean-up runs."""


def _terminate(signum, frame) -> None:
    raise Terminated()


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        previous = signal.signal(signal.SIGTERM, _terminate)
    except ValueError:  # not the main thread (an embedding program): it keeps its own handling
        previous = None
    try:
        out = args.func(args)
        if args.json:
            print(json.dumps(out, indent=1))
    except SmartjointError as error:
        print(f"smartjoint {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as interrupt:  # the clean-up of every stage (its finally blocks) ran on the way here
        name = "SIGTERM" if isinstance(interrupt, Terminated) else "SIGINT"
        print(f"smartjoint {args.command}: interrupted ({name})", file=sys.stderr)
        return 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
