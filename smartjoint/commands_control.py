"""The commands of the control and firmware stages (``study``, ``design``, ``codegen``, ``sil``,
``pil``)."""

from __future__ import annotations

import contextlib
from pathlib import Path

from smartjoint.commands import load_updated, report_progress, write_atomic, write_plots


def _control_design(args, *, firmware_names: bool = False):
    """The (updated) design the controllers are built for: the given one, or for the bundled
    reference truss (no joints) the paper's three type A joint design of Fig. 11."""
    from smartjoint.design.structure import spec

    if args.design is None:
        args.design = str(spec.REFERENCE_DESIGN.parent / "three_type_a.toml")
    design, _ = load_updated(args, firmware_names=firmware_names, friction=True)
    if args.duration is not None:
        import dataclasses

        if not (args.duration > 0):
            from smartjoint.common.errors import ModelError

            raise ModelError(f"--duration: {args.duration!r} — must be > 0 [s]")
        design = dataclasses.replace(design, control=dataclasses.replace(design.control, study_duration=args.duration))
    return design


def cmd_study(args) -> dict:
    from smartjoint.design.control import study as closed_loop
    from smartjoint.report_control import control_markdown, plot_control_study

    design = _control_design(args)
    report_progress(f"closed-loop study (Section 6) on {design.name!r}, t_e = {design.control.study_duration:g} s …")
    study = closed_loop.run_study(design, progress=report_progress)
    out = closed_loop.summary(study)
    out["design"] = {"name": design.name, "source": design.source, "sha256": design.sha256}
    write_plots(args, out, lambda folder: plot_control_study(study, folder))
    if not args.json:
        print(control_markdown(study))
    return out


def cmd_design(args) -> dict:
    from smartjoint.design.control import artifact, artifact_building, tuning
    from smartjoint.design.control import study as closed_loop

    design = _control_design(args, firmware_names=True)
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)  # fail early, not after the optimisation
    model = closed_loop.design_model(design, report_progress)
    s = closed_loop.setup(design, model)
    lqg = closed_loop.lqg_for(design, model)
    tunings = tuning.tuned_laws(design, s, report_progress)  # open settings tuned (the SISO ε optimised)
    result = artifact_building.from_design(design, model, lqg, {name: t.settings for name, t in tunings.items()})
    loads = _bus_loads(args, design, result)
    artifact.save(result, Path(args.output))
    poles = lqg.closed_loop_poles()
    out = {
        "artifact": args.output,
        "artifact_sha256": result.artifact_sha256,
        "design_sha256": design.sha256,
        "states": model.n_states,
        "joints": list(result.joint_names),
        "sensors": list(result.sensor_names),
        "sample_time": result.sample_time,
        **closed_loop.settings_figures(tunings),
        "lqg_max_pole_magnitude": float(abs(poles).max()),
        "lqg_stability_margin": float(1 - abs(poles).max()),
        "lqg_blind_modes_hz": closed_loop.blind_modes_hz(lqg, model),
        "bus_load": max(loads.values()),
        "bus_loads": loads,
        "tuning": {name: None if t.record is None else t.record.figures() for name, t in tunings.items()},
    }
    if not args.json:
        for key, value in out.items():
            print(f"{key}: {value}")
    return out


def _bus_loads(args, design, result) -> dict[str, float]:
    """The worst-case load of each bus: the design's [network] plan (``plan.plan``), or one bus of
    the command line's --bitrate, --data-bitrate and --max-load when any of them is given."""
    from smartjoint.design.network import busload, plan

    if args.bitrate is None and args.data_bitrate is None and args.max_load is None:
        result_plan = plan.plan(result, design.network)
        for p in result_plan.buses:
            report_progress(
                f"CAN bus {p.bus.name}: {', '.join(p.joints) or 'no joints'}, load {100 * p.load.load:.1f} % at "
                f"{p.bus.bitrate / 1e6:g}/{p.bus.data_bitrate / 1e6:g} Mbit/s (limit {100 * p.bus.limit:.0f} %)"
            )
        return {p.bus.name: p.load.load for p in result_plan.buses}
    bitrate = 1_000_000 if args.bitrate is None else args.bitrate
    data_bitrate = 5_000_000 if args.data_bitrate is None else args.data_bitrate
    limit = 0.7 if args.max_load is None else args.max_load
    load = busload.check(
        plan.at_rates(result, bitrate, data_bitrate or None).database, bitrate, data_bitrate or None, limit
    )
    report_progress(
        f"CAN bus load {100 * load.load:.1f} % at {bitrate / 1e6:g}"
        f"{'' if not data_bitrate else f'/{data_bitrate / 1e6:g}'} Mbit/s (limit {100 * limit:.0f} %)"
    )
    return {"can0": load.load}


def design_network(path: str, loaded):
    """The plan of an artefact's frames over the buses of a design file's [network] (codegen's
    --network); refused in one line when the design's controlled joints are not the artefact's."""
    from smartjoint.common.errors import ModelError
    from smartjoint.design.network import plan
    from smartjoint.design.structure.spec import load_design

    design = load_design(path)
    joints = list(design.control.joints) if design.control.joints is not None else [j.name for j in design.joints]
    if joints and joints != list(loaded.joint_names):
        raise ModelError(
            f"--network {path}: joints {', '.join(joints)} — the artefact's are {', '.join(loaded.joint_names)}"
        )
    return plan.plan(loaded, design.network)


def design_xcp(path: str | None):
    """The ``[xcp]`` of a design file (its identifiers, key, bus), or the defaults without one."""
    from smartjoint.design.structure.description import Xcp
    from smartjoint.design.structure.spec import load_design

    return Xcp() if path is None else load_design(path).xcp


def cmd_codegen(args) -> dict:
    from smartjoint.codegen import generate
    from smartjoint.design.control import artifact

    loaded = artifact.load(Path(args.artifact))
    can_options = {} if args.network is None else {"network": design_network(args.network, loaded)}
    can_options["xcp"] = design_xcp(args.network)  # the design's identifiers and key, not the defaults
    placed = generate.generate(
        loaded,
        Path(args.output),
        args.real,
        args.prefix,
        can=not args.no_can,
        check=args.check,
        progress=report_progress,
        **can_options,
    )
    a2l = (
        _codegen_a2l(loaded, args, can_options["xcp"], can_options.get("network"))
        if not args.no_can
        else "without the CAN layer there is no XCP slave"
    )
    out = {
        "artifact": args.artifact,
        "artifact_sha256": loaded.artifact_sha256,
        "real": args.real,
        "prefix": args.prefix,
        "files": [str(p) for p in placed.written],
        "untouched": [str(p) for p in placed.untouched],
        "a2l": a2l,
    }
    if args.check:
        out["compiled"] = True
        out["check"] = placed.compiled
    if not args.json:
        print(
            f"{len(placed.written)} files in {args.output} ({args.real}, artefact {loaded.artifact_sha256[:16]}…"
            f"{', compiled' if args.check else ''})"
        )
        for path in placed.written:
            print(f"  {path}")
        if placed.untouched:
            print(f"left untouched (not generated by this run): {', '.join(p.name for p in placed.untouched)}")
        print(f"A2L: {a2l}")
    return out


def _codegen_a2l(loaded, args, xcp, network=None) -> str:
    """``<prefix>.a2l`` beside the DBC: the XCP slave's description with the addresses of the
    Cortex-M4F image the PIL bench runs (linked here, float build); what was written, or why not."""
    import tempfile

    from smartjoint.bench import pil, target
    from smartjoint.bench.xcp_port import elf_description
    from smartjoint.codegen import can_layer, output
    from smartjoint.design.network import plan, xcp_bus

    if args.prefix != target.PREFIX or args.real != "float":
        return f"not written: the target image is the float build with prefix {target.PREFIX!r}"
    missing = target.missing_tools()
    if missing:
        return f"not written: {missing} (the A2L's addresses come from the linked target image)"
    if network is not None and len(network.buses) > 1:
        return (f"not written: the PIL target image has one bus, [network] {len(network.buses)}; link your image and "
                "run `smartjoint bench a2l` on it")  # fmt: skip
    report_progress("linking the Cortex-M4F image for the A2L's addresses …")
    with tempfile.TemporaryDirectory(prefix="smartjoint-a2l-") as work:
        elf = pil.build_image(loaded, Path(work), xcp=xcp)
        network = network or plan.plan(loaded)
        files = {**pil.firmware.sources(loaded, "float", target.PREFIX, xcp)}
        bus = xcp_bus.xcp_plan(network, xcp).bus
        text = elf_description(loaded, files, elf, xcp, can_layer.network_database(network), bus).text
    path = Path(args.output) / f"{args.prefix}.a2l"
    output.write({path.name: text}, path.parent)
    return str(path)


def _controller_artifact(args, design, model):
    """--artifact FILE (checked against the design), else designed now (ε optimised if absent)."""
    from smartjoint.common.errors import ModelError
    from smartjoint.design.control import artifact, artifact_building, tuning
    from smartjoint.design.control import study as closed_loop

    if getattr(args, "artifact", None):
        loaded = artifact.load(Path(args.artifact))
        if loaded.design_sha256 != design.sha256:
            raise ModelError(
                f"--artifact {args.artifact}: designed from design sha256 {loaded.design_sha256[:16]}…, "
                f"but {design.source} has {design.sha256[:16]}… — run `smartjoint design` again"
            )
        return loaded
    tunings = tuning.tuned_laws(design, closed_loop.setup(design, model), report_progress)
    settings = {name: t.settings for name, t in tunings.items()}
    return artifact_building.from_design(design, model, closed_loop.lqg_for(design, model), settings)


def _loop_inputs(args) -> tuple:
    """What sil and pil run: the design, its design model, the artefact, the faults and the laws."""
    from smartjoint.bench.faults import parse_fault
    from smartjoint.common import law_registry
    from smartjoint.design.control import study as closed_loop

    faults = [parse_fault(text) for text in args.fault or []]  # their spelling first: before any work
    design = _control_design(args, firmware_names=True)
    duration = design.control.study_duration
    for text, fault in zip(args.fault or [], faults):
        if not fault.start < duration:
            from smartjoint.common.errors import ModelError

            raise ModelError(
                f"--fault {text!r}: starts at {fault.start:g} s, not before the study's end t_e = {duration:g} s "
                "— it would never be injected"
            )
    model = closed_loop.design_model(design, report_progress)
    controller = _controller_artifact(args, design, model)
    return design, model, controller, faults, law_registry.NAMES if args.law == "all" else (args.law,)


def _xcp_runs(args, design, controller, laws, pil: bool = False, network=None) -> list[dict]:
    """The report's XCP demonstration per law with a boundary layer: DAQ of the whole study and
    the boundary layer × 3 at t = 1 s (``bench.xcp_study``); its A2L, MF4 and plot go to --plots."""
    from smartjoint.bench import firmware, xcp_study
    from smartjoint.bench import pil as target_bench
    from smartjoint.design.control import study as closed_loop

    setup = closed_loop.setup(design, closed_loop.design_model(design, lambda message: None))
    runs = []
    for law in (law for law in laws if law in xcp_study.CALIBRATED):
        if pil:
            with target_bench.TargetFirmware(controller, law, xcp=design.xcp) as image:
                runs.append(xcp_study.calibration_study(setup, image, law, "float", f"xcp-pil-{law}", args.plots,
                                                        report_progress))  # fmt: skip
        else:
            image = firmware.Firmware(controller, law, args.real, xcp=design.xcp, network=network)
            log = None if not args.log_folder else Path(args.log_folder) / f"xcp_sil_{law}.blf"
            runs.append(xcp_study.calibration_study(setup, image, law, args.real, f"xcp-sil-{law}", args.plots,
                                                    report_progress, log))  # fmt: skip
    return [xcp_study.json_ready(r) for r in runs]


def _xcp_serve_bus(args) -> tuple[str, str] | None:
    """sil/pil --xcp-serve's (interface, channel), checked before any work; None without it."""
    from smartjoint.common.errors import ModelError

    if args.xcp_serve is None:
        if args.xcp_a2l is not None:
            raise ModelError("--xcp-a2l: only with --xcp-serve INTERFACE:CHANNEL")
        return None
    interface, _, channel = args.xcp_serve.partition(":")
    if not interface or not channel:
        raise ModelError(f"--xcp-serve: {args.xcp_serve!r} — must be INTERFACE:CHANNEL (e.g. udp_multicast:239.0.0.1)")
    if not args.xcp_a2l:
        raise ModelError("--xcp-a2l: required with --xcp-serve (the file the served image's A2L goes to)")
    if args.law == "all":
        raise ModelError("--xcp-serve: serves one law — give --law")
    if args.fault:
        raise ModelError("--xcp-serve: serves the fault-free loop — drop --fault")
    return interface, channel


def _xcp_serve(args, bus, design, model, controller, pil: bool = False) -> dict:
    """sil/pil --xcp-serve: one law's image with its XCP slave on the given bus at the wall
    clock's pace, its A2L written first (``bench.xcp_port.serve_study``)."""
    from smartjoint.bench import firmware, xcp_port
    from smartjoint.bench import pil as target_bench
    from smartjoint.design.control import study as closed_loop

    interface, channel = bus
    laws = [args.law]
    setup = closed_loop.setup(design, model)
    image: target_bench.TargetFirmware | firmware.Firmware
    with contextlib.ExitStack() as stack:
        if pil:  # the emulator runs while the context lasts
            image = stack.enter_context(target_bench.TargetFirmware(controller, laws[0], xcp=design.xcp))
        else:
            image = firmware.Firmware(controller, laws[0], args.real, xcp=design.xcp)
        description = xcp_port.target_description(image) if pil else xcp_port.sil_description(image)
        write_atomic(Path(args.xcp_a2l), description.text)
        report_progress(f"A2L of the served image: {args.xcp_a2l}; a master: smartjoint bench xcp {args.xcp_a2l} "
                        f"--interface {interface} --channel {channel} --artifact … --measure all")  # fmt: skip
        out = xcp_port.serve_study(setup, image, interface, channel, report_progress)
    out.pop("loop")
    out.update(law=laws[0], a2l=args.xcp_a2l, bus=args.xcp_serve, where="PIL" if pil else f"SIL ({args.real})")
    if not args.json:
        print(f"served {out['seconds']:g} s: {out['commands']} commands taken, {out['frames_sent']} frames sent, "
              f"at most {out['late_s'] * 1e3:.0f} ms behind the wall clock")  # fmt: skip
    return out


def cmd_sil(args) -> dict:
    from smartjoint.bench import sil, xcp_study
    from smartjoint.design.control import study as closed_loop
    from smartjoint.design.structure.description import Network

    serve = _xcp_serve_bus(args)
    design, model, controller, faults, laws = _loop_inputs(args)
    if serve:
        return _xcp_serve(args, serve, design, model, controller)
    report_progress(
        f"software in the loop on {design.name!r}: {', '.join(laws)}, t_e = {design.control.study_duration:g} s"
    )
    out = sil.sil_study(
        closed_loop.setup(design, model),
        controller,
        laws,
        args.real,
        faults,
        args.log_folder,
        {"time_constant": args.amplifier_lag},
        args.bitrate,
        args.data_bitrate,
        args.spread,
        args.interface,
        args.channel,
        report_progress,
        network=None if design.network == Network() else design.network,  # the design's buses, if it has them
    )
    out["xcp"] = _xcp_runs(
        args, design, controller, laws, network=None if design.network == Network() else design.network
    )
    if not args.json:
        print(sil.sil_markdown(out) + "\n" + xcp_study.xcp_markdown(out["xcp"]))
    write_plots(args, out, lambda folder: sil.plot_sil(out, folder, out.get("mil_runs")))
    out.pop("mil_runs", None)
    for law in out["laws"].values():
        law.pop("record")
        law.pop("result")
    out["design"] = {"name": design.name, "sha256": design.sha256}
    out["artifact_sha256"] = controller.artifact_sha256
    return out


def cmd_pil(args) -> dict:
    from smartjoint.bench import pil, pil_study, safety, target, xcp_study
    from smartjoint.common import law_registry
    from smartjoint.common.errors import ModelError

    if not (args.clock > 0 and args.clock < float("inf")):
        raise ModelError(f"--clock: {args.clock!r} MHz — must be a finite number > 0")
    reason = target.missing_tools()
    if reason:
        raise ModelError(reason)
    serve = _xcp_serve_bus(args)
    design, model, controller, faults, laws = _loop_inputs(args)
    if serve:
        return _xcp_serve(args, serve, design, model, controller, pil=True)
    report_progress(
        f"processor in the loop on {design.name!r}: {', '.join(laws)} on {target.BOARD}, "
        f"t_e = {design.control.study_duration:g} s"
    )
    study = pil_study.mil_study(design, model, controller, report_progress)
    out = pil_study.pil_study(study, controller, laws, faults, args.clock * 1e6, report_progress)
    if args.fault_matrix:
        law = law_registry.fault_matrix_law()
        report_progress(f"      every case of the fault matrix on the target ({law.display}) …")
        with pil.TargetFirmware(controller, law.name) as image:
            out["fault_matrix"] = safety.fault_matrix(controller, progress=report_progress, image=image)
    xcp = _xcp_runs(args, design, controller, laws, pil=True)
    if not args.json:
        print(pil_study.pil_markdown(out) + "\n" + xcp_study.xcp_markdown(xcp))
    summary = pil_study.summary(out)
    summary["xcp"] = xcp
    write_plots(args, summary, lambda folder: [pil_study.plot_pil(out, Path(folder) / "pil_energy.png")])
    summary["design"] = {"name": design.name, "sha256": design.sha256}
    summary["artifact_sha256"] = controller.artifact_sha256
    return summary
