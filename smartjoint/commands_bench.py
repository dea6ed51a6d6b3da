"""``smartjoint bench``: the CAN bench's tools — a DBC after the bus-load check, recording a
bus, decoding a log, replaying it through the firmware, and an XCP session with a running ECU
from its A2L (docs/can.md, docs/xcp.md)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from types import SimpleNamespace

from smartjoint.commands import report_progress, write_atomic, write_plots
from smartjoint.commands_control import design_network, design_xcp
from smartjoint.common import law_registry


def add_bench_commands(sub, o: SimpleNamespace, bus_rates, bus_channel) -> None:
    """bench dbc, log, decode, replay, xcp (``bus_rates``/``bus_channel``: the command line's
    parent parsers of a bus's bit rates and of a python-can bus)."""
    p = sub.add_parser("bench", help="CAN bench tools: dbc, log, decode, replay, xcp")
    bench = p.add_subparsers(dest="bench_command", required=True, metavar="TOOL")
    q = bench.add_parser(
        "dbc", parents=[bus_rates(), o.json], help="write the DBC of a controller artefact after the bus-load check"
    )
    q.add_argument("artifact")
    q.add_argument("-o", "--output", required=True)
    q.add_argument("--max-load", type=float, default=0.7, help="refuse above this load (default: %(default)s)")
    q = bench.add_parser(
        "log", parents=[bus_channel(), o.json], help="record a python-can bus to ASC/BLF/MF4 (by suffix)"
    )
    q.add_argument("-o", "--output", required=True)
    q.add_argument("--duration", type=float, help="seconds (default: until Ctrl-C)")
    q.add_argument("--rotate-bytes", type=int, default=0, help="rotate the file at this size (0: never)")
    q = bench.add_parser("decode", parents=[o.json], help="decode a log to signals (CSV) and plots with the DBC")
    q.add_argument("log")
    q.add_argument("--dbc", action="append", help="the bus's DBC; several: one per bus, in the log's channel order")
    q.add_argument("--artifact")
    q.add_argument("--network", help="design file: the artefact's frames on its [network]'s buses (with --artifact)")
    q.add_argument("-o", "--output", help="CSV file (time_s, frame, signal, value)")
    q.add_argument("--plots", help="folder for one PNG per frame")
    q = bench.add_parser(
        "replay", parents=[o.json], help="feed a log's sensor frames through the firmware; compare its setpoints"
    )
    q.add_argument("log")
    q.add_argument("--artifact", required=True)
    q.add_argument("--network", help="design file: the firmware on its [network]'s buses (log channel = bus)")
    q.add_argument("--law", choices=law_registry.NAMES, default=law_registry.NAMES[0])
    q.add_argument("--real", choices=("float", "double"), default="float")
    q.add_argument("--tolerance", type=float, default=0.0, help="volts counted as equal (default 0: bit-exact)")
    _add_xcp_command(bench, o, bus_channel)
    q = bench.add_parser(
        "a2l", parents=[o.json], help="the A2L of your own image of the generated sources, from its linked ELF"
    )
    q.add_argument("elf", help="the linked image (with <prefix>_xcp.c)")
    q.add_argument("--artifact", required=True, help="the controller artefact the sources were generated from")
    q.add_argument("--design", help="design file: its [network] and [xcp] (default: one bus, [xcp]'s defaults)")
    q.add_argument("--prefix", default="smartjoint", help="codegen's --prefix (default: %(default)s)")
    q.add_argument("--real", choices=("float", "double"), default="float", help="codegen's --real (default: float)")
    q.add_argument("--compiler", default="arm-none-eabi-gcc", help="the image's GCC (default: %(default)s)")
    q.add_argument("--cflags", default="-mcpu=cortex-m4 -mthumb -mfpu=fpv4-sp-d16 -mfloat-abi=hard",
                   help="the flags that fix the image's ABI (default: %(default)s)")  # fmt: skip
    q.add_argument("-o", "--output", required=True, help="the A2L file")
    for tool in bench.choices.values():
        tool.set_defaults(func=cmd_bench)


def _add_xcp_command(bench, o: SimpleNamespace, bus_channel) -> None:
    q = bench.add_parser(
        "xcp",
        parents=[bus_channel("python-can interface of the ECU's bus (default: %(default)s)"), o.json],
        help="identify, read, calibrate and measure (DAQ → MF4) a running ECU from its A2L with pyxcp",
    )
    q.add_argument("a2l", help="the ECU's A2L (smartjoint codegen / sil / pil write it)")
    q.add_argument("--artifact", help="controller artefact: the seed & key's key derived from it")
    q.add_argument("--key", help="the design's [xcp] key (32 hex digits) instead of --artifact's")
    q.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="DOWNLOAD a CHARACTERISTIC (physical value, A2L limits), repeatable")  # fmt: skip
    q.add_argument("--set-at", type=float, metavar="SECONDS", help="download --set this far into the measurement")
    q.add_argument("--measure", action="append", default=[], metavar="NAME",
                   help="a MEASUREMENT to record by DAQ, repeatable; 'all': as many as the DAQ list holds")  # fmt: skip
    q.add_argument("--duration", type=float, default=1.0, help="DAQ time [s of the ECU's clock] (default: 1)")
    q.add_argument("--prescaler", type=int, default=1, help="record every n-th sample (default: 1)")
    q.add_argument("--timeout", type=float, default=2.0, help="seconds per command (default: 2)")
    q.add_argument("-o", "--output", help="the measurement as MF4 (asammdf, the A2L's units)")
    q.add_argument("--plots", help="folder for xcp_daq.png")


def _bench_database(args):
    from smartjoint.common.errors import ModelError
    from smartjoint.design.control import artifact
    from smartjoint.design.network import plan, protocol

    if args.dbc and (args.artifact or args.network):
        raise ModelError("--dbc: give the DBCs or --artifact (with --network), not both")
    if args.dbc:
        databases = []
        for path in args.dbc:
            try:
                databases.append(protocol.load_dbc(Path(path).read_text()))
            except OSError as error:
                raise ModelError(f"--dbc {path}: cannot read ({error.strerror})") from None
        return databases, None
    if args.artifact:
        loaded = artifact.load(Path(args.artifact))
        if args.network is None:
            return [p.database for p in plan.plan(loaded).buses], None
        network = design_network(args.network, loaded)
        return [p.database for p in network.buses], [p.bus.name for p in network.buses]
    raise ModelError("give the protocol: --dbc FILE (one per bus) or --artifact controller.json [--network DESIGN]")


def cmd_bench(args) -> dict:
    from smartjoint.bench import logs, loop
    from smartjoint.design.control import artifact
    from smartjoint.design.network import protocol

    if args.bench_command == "dbc":
        from smartjoint.design.network import busload, plan

        loaded = artifact.load(Path(args.artifact))
        db = plan.at_rates(loaded, args.bitrate, args.data_bitrate).database
        load = busload.check(db, args.bitrate, args.data_bitrate, args.max_load)
        write_atomic(Path(args.output), protocol.dbc_text(db))
        out = {"dbc": args.output, "frames": len(db.messages), "bus_load": load.load}
        if not args.json:
            print(load.table())
            print(f"DBC written to {args.output}")
        return out
    if args.bench_command == "log":
        bus = loop.open_bus(args.interface, args.channel)
        try:
            report_progress(f"recording {args.interface}:{args.channel} to {args.output} (Ctrl-C stops) …")
            out = logs.record(bus, args.output, args.duration, args.rotate_bytes, progress=report_progress)
        finally:
            bus.shutdown()
        if not args.json:
            print(f"{out['frames']} frames in {out['seconds']:.1f} s → {out['file']}")
        return out
    if args.bench_command == "decode":
        return _bench_decode(args)
    if args.bench_command == "xcp":
        return _bench_xcp(args)
    if args.bench_command == "a2l":
        return _bench_a2l(args)
    return _bench_replay(args)


def _bench_log(args):
    """The log of ``bench decode`` / ``bench replay``, its damage on stderr (counts by kind)."""
    from smartjoint.bench import logs
    from smartjoint.common.errors import ModelError

    content = logs.load(args.log)
    if not content.messages:
        raise ModelError(
            f"log file {args.log}: no frames"
            + (f" ({content.problem()})" if content.problem() else "")
            + " — nothing to "
            + args.bench_command
        )
    problem = content.problem()
    if problem:
        early = " ends early and" if content.truncated else ""
        report_progress(
            f"warning: {args.log}{early} is damaged — {problem}; using the {len(content.messages)} frames read"
        )
    return content


def _bench_decode(args) -> dict:
    from smartjoint.bench import logs

    content = _bench_log(args)
    databases, names = _bench_database(args)
    decoded = logs.decode(content, databases, bus_names=names)
    out = decoded.summary()
    if args.output:
        logs.write_csv(decoded, args.output)
        out["csv"] = args.output
    write_plots(args, out, lambda folder: logs.plot(decoded, folder))
    if decoded.skipped():
        report_progress(
            f"warning: {decoded.skipped()} of {decoded.frames} frames not decoded: "
            f"unknown ids {sum(decoded.unknown_ids.values())}, "
            f"wrong length {sum(decoded.wrong_length.values())}, "
            f"bad CRC {sum(decoded.bad_e2e.values())}, error frames {decoded.error_frames}, remote frames "
            f"{decoded.remote_frames}, non-finite time stamps {decoded.non_finite_times}"
        )
    if not args.json:
        for key, value in out.items():
            print(f"{key}: {value}")
    return out


def _bench_replay(args) -> dict:
    """Exit 1 (after the report) when a setpoint differs or a recorded one was not replayed."""
    from smartjoint.bench import firmware
    from smartjoint.bench.replay import replay
    from smartjoint.common.errors import ModelError
    from smartjoint.design.control import artifact

    if not (args.tolerance >= 0 and args.tolerance < float("inf")):
        raise ModelError(f"--tolerance: {args.tolerance!r} V — must be a finite number >= 0")
    content = _bench_log(args)
    loaded = artifact.load(Path(args.artifact))
    network = None if args.network is None else design_network(args.network, loaded)
    out = replay(content, firmware.Firmware(loaded, args.law, args.real, network=network), args.tolerance)
    out["log_problem"] = content.problem()
    out["log"] = content.skipped()
    if out["setpoints_compared"] == 0 and out["recorded_not_replayed"] == 0:
        raise ModelError(
            f"log file {args.log}: no recorded setpoint frame (SETPOINT_*, SETPOINTS_*) to compare "
            f"({out['samples']} samples replayed) — a log of the controller's bus is needed"
        )
    line = (
        f"{out['samples']} samples ({out['silent_samples']} without frames), {out['setpoints_compared']} "
        f"setpoints compared, {out['differing']} differ beyond {args.tolerance:g} V (max "
        f"{out['max_difference_V']:.3g} V), {out['recorded_not_replayed']} recorded but not replayed, "
        f"{out['replayed_not_recorded'] + out['replayed_not_recorded_in_silent_samples']} replayed but not "
        f"recorded ({out['replayed_not_recorded_in_silent_samples']} of them in samples without frames)"
    )
    skipped = out["recorded_setpoints_bad_crc"] + out["recorded_setpoints_wrong_length"]
    if skipped:
        line += (
            f"; {skipped} recorded setpoints not compared (bad CRC {out['recorded_setpoints_bad_crc']}, wrong "
            f"length {out['recorded_setpoints_wrong_length']})"
        )
    if out["sent_never_logged"]:
        line += f"; sent by the firmware but never in the log: {', '.join(out['sent_never_logged'])}"
    if out["ok"]:
        if not args.json:  # main prints the JSON
            print(line)
        return out
    print(json.dumps(out, indent=1) if args.json else line)  # main does not get to print: the exit is 1
    print(f"smartjoint bench replay: FAILED: {line}", file=sys.stderr)
    for d in out["first_differences"][:10]:
        replayed = "nothing" if d["replayed_V"] is None else f"{d['replayed_V']:.9g} V"
        print(
            f"  t = {d['time']:.6f} s {d['frame']} {d['kind']}: recorded {d['recorded_V']:.9g} V, replayed {replayed}",
            file=sys.stderr,
        )
    raise SystemExit(1)


def _xcp_options(args):
    """The checked options of ``bench xcp``: (description, settings, key, names); one line per
    bad value, before any frame."""
    from smartjoint.bench import a2l_file, xcp_session
    from smartjoint.common.errors import ModelError
    from smartjoint.design.control import artifact

    if not (math.isfinite(args.duration) and args.duration > 0):
        raise ModelError(f"--duration: {args.duration!r} s — must be a finite number > 0")
    if not 1 <= args.prescaler <= 255:
        raise ModelError(f"--prescaler: {args.prescaler} — must be 1 … 255")
    if not (math.isfinite(args.timeout) and 0 < args.timeout <= 60):
        raise ModelError(f"--timeout: {args.timeout!r} s — must be > 0 and at most 60")
    if args.set_at is not None and not (args.measure and 0 <= args.set_at <= args.duration):
        raise ModelError(f"--set-at: {args.set_at!r} s — needs --measure and must lie in 0 … --duration")
    if args.output and (Path(args.output).suffix.lower() != ".mf4" or Path(args.output).is_dir()):
        raise ModelError(f"--output: {args.output!r} — must name an .mf4 file")
    settings = {}
    for text in args.set:
        name, _, value = text.partition("=")
        try:
            settings[name.strip()] = float(value)
        except ValueError:
            raise ModelError(f"--set: {text!r} — must be NAME=VALUE with a number") from None
    description = a2l_file.read(args.a2l)
    settings = xcp_session.check_settings(description, settings)
    loaded = artifact.load(Path(args.artifact)) if args.artifact else None
    key = xcp_session.key_function(loaded, args.key)
    names = ["all"] if "all" in args.measure else list(dict.fromkeys(args.measure))
    xcp_session.choose(description, names, 255, 255)  # an unknown name is refused before any frame
    return description, settings, key, names


def _bench_xcp(args) -> dict:
    """Connect, identify (EPK), read the calibration, DOWNLOAD --set now or at --set-at, and
    record --measure by DAQ to MF4 and a plot."""
    from smartjoint.bench import xcp_master, xcp_session

    description, settings, key, names = _xcp_options(args)
    session = xcp_session.Session(description, args.interface, args.channel, key, args.timeout)
    master = session.connect()
    try:
        before = session.upload(master, description.characteristics)
        capacity = session.capacity(master) if names else (0, 0)
        now = settings if args.set_at is None else {}
        read_back = session.download(master, now) if now else {}
    finally:
        session.close(master)
    out = {"a2l": args.a2l, "bus": f"{args.interface}:{args.channel}", "epk": session.epk,
           "calibration": before, "set": settings, "read_back": read_back}  # fmt: skip
    if names:
        entries, left = xcp_session.choose(description, names, *capacity)
        report_progress(f"DAQ of {len(entries)} signals for {args.duration:g} s (prescaler {args.prescaler}) …")
        daq = xcp_session.run_daq(session, entries, args.duration, args.prescaler,
                                  settings if args.set_at is not None else None, args.set_at or 0.0, 5.0,
                                  lambda message: None)  # fmt: skip
        out["read_back"].update(daq["read_back"])
        out["daq"] = xcp_session.daq_summary(daq, description, args.prescaler, capacity, left)
        if args.output:
            xcp_master.write_mf4(daq["recorded"], description, args.output, 0.0,
                                 f"smartjoint bench xcp: {session.epk}")  # fmt: skip
            out["mf4"] = args.output
        write_plots(args, out, lambda folder: [xcp_session.plot_daq(daq, description, Path(folder) / "xcp_daq.png")])
    if not args.json:
        print(xcp_session.session_text(out, description))
    return out


def _bench_a2l(args) -> dict:
    """The A2L of a user's linked image: the artefact's sources as codegen gave them, the ELF's
    symbols, the layout the image's compiler gives; refused when the ELF's EPK is not theirs."""
    import shlex

    from smartjoint.bench import firmware, xcp_port
    from smartjoint.codegen import can_layer, xcp_slave
    from smartjoint.common.errors import ModelError
    from smartjoint.design.control import artifact
    from smartjoint.design.network import plan, xcp_bus

    elf = Path(args.elf)
    if not elf.is_file():
        raise ModelError(f"ELF {args.elf}: not a file")
    loaded = artifact.load(Path(args.artifact))
    network = design_network(args.design, loaded) if args.design else plan.plan(loaded)
    xcp = design_xcp(args.design)
    tools = args.compiler[: -len("gcc")] if args.compiler.endswith("gcc") else ""
    symbol = f"{args.prefix}_xcp_epk"
    address = firmware.symbols(str(elf), f"{tools}nm").get(symbol)
    if address is None:
        raise ModelError(f"ELF {args.elf}: no symbol {symbol} — link {args.prefix}_xcp.c (or give codegen's --prefix)")
    expected = xcp_slave.epk(loaded, args.real, args.prefix)
    found = xcp_port.elf_bytes(elf, address, len(expected) + 1, f"{tools}objdump").split(b"\0")[0]
    if found != expected.encode():
        raise ModelError(f"ELF {args.elf}: its EPK {found.decode(errors='replace')!r} is not {expected!r} (this "
                         "artefact, --real and --prefix) — built from other sources")  # fmt: skip
    files = firmware.sources(loaded, args.real, args.prefix, xcp, network=network)
    description = xcp_port.elf_description(
        loaded, files, elf, xcp, can_layer.network_database(network), xcp_bus.xcp_plan(network, xcp).bus,
        args.prefix, args.real, args.compiler, tuple(shlex.split(args.cflags)),
        f"image {elf.name} ({args.compiler} {args.cflags}): linked addresses",
    )  # fmt: skip
    write_atomic(Path(args.output), description.text)
    out = {"a2l": args.output, "epk": expected, "measurements": len(description.measurements),
           "characteristics": len(description.characteristics)}  # fmt: skip
    if not args.json:
        print(f"{args.output}: {out['measurements']} MEASUREMENTs, {out['characteristics']} CHARACTERISTICs at the "
              f"addresses of {args.elf} (EPK {expected!r})")  # fmt: skip
    return out


__all__ = ["add_bench_commands", "cmd_bench"]
