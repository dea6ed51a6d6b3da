"""The ``smartjoint`` command line: a thin layer over the library.

Every command that reports numbers offers ``--json``. User errors (a bad design file, a
model that cannot be built) end with a one-line message on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
from types import SimpleNamespace

from smartjoint import __version__
from smartjoint.commands import (
    cmd_export_model,
    cmd_modes,
    cmd_place,
    cmd_reduce,
    cmd_run,
    cmd_simulate,
    cmd_update,
)
from smartjoint.commands_bench import add_bench_commands
from smartjoint.commands_control import cmd_codegen, cmd_design, cmd_pil, cmd_sil, cmd_study
from smartjoint.commands_fmu import cmd_fmu
from smartjoint.commands_friction import cmd_campaign, cmd_identify, cmd_rig
from smartjoint.commands_sweep import cmd_sweep
from smartjoint.common import friction_registry, law_registry
from smartjoint.common.errors import SmartjointError
from smartjoint.output_options import check_outputs

_LAWS_SHOWN = ", ".join(law.display for law in law_registry.LAWS.values())  # the laws, as a reader knows them


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} — must be a whole number >= 1")
    return value


def _parent(*flags, **options) -> argparse.ArgumentParser:
    """A parent parser holding one option, for the commands that share it (``parents=[…]``)."""
    parent = argparse.ArgumentParser(add_help=False)
    parent.add_argument(*flags, **options)
    return parent


def _bus_rates(bitrate_help: str | None = None, data_help: str | None = None) -> argparse.ArgumentParser:
    """--bitrate and --data-bitrate of the CAN (FD) bus; each command keeps its own help text."""
    parent = argparse.ArgumentParser(add_help=False)
    parent.add_argument("--bitrate", type=int, default=1_000_000, help=bitrate_help)
    parent.add_argument("--data-bitrate", type=int, default=5_000_000, help=data_help)
    return parent


def _bus_channel(interface_help: str | None = None) -> argparse.ArgumentParser:
    """--interface and --channel of the python-can bus."""
    parent = argparse.ArgumentParser(add_help=False)
    parent.add_argument("--interface", default="virtual", help=interface_help)
    parent.add_argument("--channel", default="smartjoint-sil")
    return parent


def _xcp_serve() -> argparse.ArgumentParser:
    """--xcp-serve and --xcp-a2l of sil and pil: the slave served to a master outside the bench."""
    parent = argparse.ArgumentParser(add_help=False)
    serve = "instead of the study: one law's XCP slave on this python-can bus at the wall clock's pace (docs/xcp.md)"
    parent.add_argument("--xcp-serve", metavar="INTERFACE:CHANNEL", help=serve)
    parent.add_argument("--xcp-a2l", metavar="FILE", help="with --xcp-serve: where the served image's A2L goes")
    return parent


def _shared_options() -> SimpleNamespace:
    """The options several commands take with the same meaning and help text."""
    return SimpleNamespace(
        design=_parent(
            "design", nargs="?", default=None, help="design file (TOML); default: the bundled 10-bay reference truss"
        ),
        no_update=_parent("--no-update", action="store_true", help="use the design's nominal parameters"),
        json_results=_parent("--json", action="store_true", help="print the results as JSON"),
        json_summary=_parent("--json", action="store_true", help="print the summary as JSON"),
        json=_parent("--json", action="store_true"),
        plant_step=_parent("--step", type=float, default=5e-5, help="plant step [s] (default: %(default)s)"),
    )


def _add_model_commands(sub, o: SimpleNamespace) -> None:
    """run, modes, update, export-model."""
    p = sub.add_parser(
        "run", parents=[o.design, o.json_results], help="run the whole pipeline on a design and write a report"
    )
    p.add_argument(
        "-o",
        "--output",
        default="smartjoint-report",
        help="report folder: new, empty, or the report of an earlier run, which is replaced; anything "
        "else is refused (default: %(default)s)",
    )
    p.set_defaults(func=cmd_run)

    p = sub.add_parser(
        "modes",
        parents=[o.design, o.no_update, o.json_results],
        help="eigenfrequencies, and the EMA comparison where the design has one",
    )
    p.add_argument("-n", "--count", type=_positive_int, default=20, help="number of modes (default: %(default)s)")
    p.set_defaults(func=cmd_modes)

    p = sub.add_parser(
        "update",
        parents=[o.design, o.json_results],
        help="fit the design's [updating] parameters to its measured frequencies",
    )
    p.set_defaults(func=cmd_update)

    p = sub.add_parser(
        "export-model",
        parents=[o.design, o.json_summary],
        help="write the FE model in the neutral JSON format (docs/model-format.md)",
    )
    p.add_argument("-o", "--output", required=True, help="output file (JSON)")
    p.add_argument(
        "--joints",
        choices=("locked", "released"),
        default="locked",
        help="locked: conventional truss; released: joint DOFs free (default: %(default)s)",
    )
    p.add_argument("--no-update", action="store_true", help="export the nominal (not updated) model")
    p.set_defaults(func=cmd_export_model)


def _add_campaign_command(sub, o: SimpleNamespace) -> None:
    """campaign: the sequential rig campaign over a folder (docs/identification.md)."""
    p = sub.add_parser(
        "campaign",
        parents=[o.json_summary],
        help="the sequential rig campaign in a folder: plan a round, identify what was measured, plan the next",
    )
    p.add_argument("folder", help="campaign folder: the records round<k>_<test>.csv and the plans round<k>_plan.md")
    p.add_argument("--prior", metavar="FILE", required=True, help="the parameters believed before the first record "
                   "(format of rig --parameters; docs/identification.md)")  # fmt: skip
    p.add_argument("--type", choices=("A", "B"), default=None, help="joint type (default: the prior's joint_type)")
    p.add_argument("--simulate", metavar="FILE", help="fill in missing records with the simulated rig of these "
                   "parameters (format of rig --parameters) instead of waiting for a person to measure "
                   "them")  # fmt: skip
    p.add_argument("--noise", type=float, default=0.01, help="with --simulate: relative noise (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="with --simulate: noise seed (default: %(default)s)")
    p.add_argument("--cycles", type=float, default=8.0, help="excitation cycles per record (default: %(default)s)")
    p.add_argument("-o", "--output", metavar="JOINT.toml", help="when the campaign is done: the result file "
                   "(as identify -o; parameters not identified are listed without a value)")  # fmt: skip
    p.set_defaults(func=cmd_campaign)


def _add_friction_commands(sub, o: SimpleNamespace) -> None:
    """rig, campaign, identify."""
    p = sub.add_parser(
        "rig",
        parents=[o.json_summary],
        help="simulate the isolated-joint test rig (Section 3.2) and write friction records",
    )
    p.add_argument(
        "--type", choices=("A", "B"), default=None, help="joint type (default: the parameter file's joint_type, else A)"
    )
    model = friction_registry.friction_model()
    p.add_argument(
        "--parameters",
        metavar="FILE",
        help=f"friction parameter set (TOML: {', '.join(model.keys)}, radius for type B, optional "
        f"joint_type, optional model (default {model.name}); docs/identification.md)",
    )
    lugre_flags = p.add_argument_group(
        f"{model.display} parameter set as flags (all {len(model.parameters)}, and --radius for type B; "
        "without flags or --parameters: the paper's Table 1)"
    )
    for parameter in model.parameters:
        units = parameter.units
        unit = f" [{units[0]}]" + (f" (type B: [{units[1]}])" if units[1] != units[0] else "") if units[0] else ""
        lugre_flags.add_argument(
            f"--{parameter.key.replace('_', '-')}", type=float, help=f"{parameter.meaning} {parameter.symbol}{unit}"
        )
    lugre_flags.add_argument("--radius", type=float, help="joint radius r [m] (type B only)")
    p.add_argument("--normal-force", type=float, help="F_N [N]")
    p.add_argument("--amplitude", type=float, help="shaker force [N] (type B: moment [N·m])")
    p.add_argument("--frequency", type=float, help="excitation frequency [Hz]")
    p.add_argument("--cycles", type=float, default=4.0, help="excitation cycles (default: %(default)s)")
    p.add_argument("--inertia", type=float, help="friction element inertia [kg] or [kg·m²] (default 1 / 2e-3)")
    p.add_argument("--noise", type=float, default=0.0, help="measurement noise, relative to RMS (0 … 1, e.g. 0.01)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--campaign",
        action="store_true",
        help="write the micro-/stick-slip campaign (amplitude ladder around the prior's break-away) into -o DIR",
    )
    p.add_argument(
        "--prior",
        metavar="FILE",
        help="with --campaign: the LuGre parameters the campaign is designed from (format of --parameters; "
        "default: the simulated parameters)",
    )
    p.add_argument("-o", "--output", required=True, help="record file (CSV), or folder with --campaign")
    p.set_defaults(func=cmd_rig)

    _add_campaign_command(sub, o)

    p = sub.add_parser(
        "identify",
        parents=[o.json_results],
        help="LuGre identification from friction records: two Eq. 3 steps, then output error on the rig model",
    )
    p.add_argument("records", nargs="+", help="record files (CSV, docs/identification.md)")
    p.add_argument(
        "--radius",
        type=float,
        help="joint radius r [m] of type B records that do not carry '# radius = … m' (no default)",
    )
    p.add_argument(
        "--no-output-error",
        action="store_true",
        help="stop after the two Eq. 3 steps (by default an output-error step follows when the "
        "stick-slip records carry excitation_force and inertia)",
    )
    p.add_argument("--plots", help="folder for hysteresis plots (PNG)")
    p.add_argument(
        "-o",
        "--output",
        metavar="JOINT.toml",
        help="write the result file a design names in [friction.X] file = … (parameters, 95 %% intervals, "
        "records used and a provenance hash; docs/design-file.md)",
    )
    p.set_defaults(func=cmd_identify)


def _add_dynamics_commands(sub, o: SimpleNamespace) -> None:
    """reduce, simulate, place."""
    p = sub.add_parser(
        "reduce",
        parents=[o.design, o.plant_step, o.no_update, o.json_results],
        help="balanced mode selection + Krylov vectors (Section 4), checked against the full model",
    )
    p.add_argument("--modes", type=_positive_int, default=60, help="modes to keep (default: %(default)s)")
    p.add_argument("--considered", type=_positive_int, default=100, help="modes to choose from (default: %(default)s)")
    p.add_argument("--krylov", type=int, default=2, help="Krylov vectors per joint (default: %(default)s)")
    p.add_argument("--krylov-joints", help="comma-separated joint names that get vectors (default: the active joint)")
    p.add_argument(
        "--normal-force",
        help="F_N per joint, comma-separated [N] (default: the design's load case, [control] reduction_normal_force)",
    )
    p.add_argument("--duration", type=float, default=0.5, help="simulated time [s] (default: %(default)s)")
    p.add_argument("--plots", help="folder for hankel.png, friction_moment.png, energy.png, reduction_bode.png")
    p.set_defaults(func=cmd_reduce)

    p = sub.add_parser(
        "simulate",
        parents=[o.design, o.plant_step, o.no_update, o.json_results],
        help="passive closed-loop run under the paper's tip pulse",
    )
    p.add_argument("--normal-force", required=True, help="F_N per joint, comma-separated [N]")
    p.add_argument("--duration", type=float, default=1.0, help="simulated time [s] (default: %(default)s)")
    p.add_argument("--sample-time", type=float, help="controller sample time [s] (default: the design's [control])")
    p.add_argument(
        "--stick-step",
        type=float,
        help="stick-exact scheme (reduced models): this long step while the "
        "joints stick, --step elsewhere; records every long step; no energy books",
    )
    p.add_argument("--reduced", help="KEEP:KRYLOV, e.g. 9:1, for a reduced model (default: the full model)")
    p.add_argument("--considered", type=_positive_int, default=100, help="modes to choose from with --reduced")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser(
        "place",
        parents=[o.design, o.no_update, o.json_results],
        help="rank end connectors by modal strain energy and place type A joints (Section 6)",
    )
    p.add_argument("--modes", default="1,2", help="modes to damp, comma-separated numbers (default: %(default)s)")
    p.add_argument("--count", type=_positive_int, default=3, help="joints to place (default: %(default)s)")
    p.add_argument("--top", type=_positive_int, default=10, help="ranking rows to show (default: %(default)s)")
    p.add_argument("-o", "--output", help="write a design file with the joints (extends DESIGN via base = …)")
    p.set_defaults(func=cmd_place)


def _add_control_commands(sub, o: SimpleNamespace) -> None:
    """design, codegen, sil, pil."""
    one_bus = "CAN (arbitration) bitrate (default: 1000000); any bus option: one such bus, not the design's [network]"
    rates = _bus_rates(one_bus, "CAN FD data bitrate, 0: classical CAN (default: 5000000)")
    p = sub.add_parser(
        "design",
        parents=[o.design, rates, o.no_update, o.json_summary],
        help="design the controllers (Section 5) and write the artefact codegen consumes",
    )
    p.add_argument("-o", "--output", default="controller.json", help="artefact file (default: %(default)s)")
    p.add_argument("--duration", type=float, help="t_e of Eq. 32 for the ε optimisation [s] (default: design file)")
    p.add_argument("--max-load", type=float, help="refuse a bus load above this (default: 0.7)")
    # Without the bus options the frames are planned over the design's [network] (plan.plan).
    p.set_defaults(func=cmd_design, bitrate=None, data_bitrate=None)

    p = sub.add_parser(
        "codegen",
        parents=[o.json_summary],
        help=f"generate the C99 controllers ({_LAWS_SHOWN}) from a controller artefact",
    )
    p.add_argument("artifact", help="controller design artefact (JSON, from `smartjoint design`)")
    p.add_argument(
        "-o",
        "--output",
        required=True,
        help="folder for the generated files: created, or one where codegen replaces only files it "
        "generated (others are left untouched)",
    )
    p.add_argument("--real", choices=("float", "double"), default="float", help="scalar type (default: %(default)s)")
    p.add_argument("--prefix", default="smartjoint", help="C name prefix of the modules (default: %(default)s)")
    p.add_argument(
        "--check",
        action="store_true",
        help="compile everything generated (headers alone, every .c, linked) with the strict warning set "
        "before it is moved into place",
    )
    p.add_argument("--no-can", action="store_true", help="controllers only, without the CAN message layer and DBC")
    network_help = "the CAN layer on the buses of this design's [network], a DBC each (default: one bus)"
    p.add_argument("--network", metavar="DESIGN", help=network_help)
    p.set_defaults(func=cmd_codegen)

    bus = [
        _bus_rates(data_help="CAN FD data phase [bit/s]"),
        _bus_channel("python-can interface (default: %(default)s)"),
    ]
    p = sub.add_parser(
        "sil",
        parents=[o.design, *bus, o.no_update, o.json_results, _xcp_serve()],
        help="the paper's study through the CAN loop: firmware, bus, amplifiers (software in the loop)",
    )
    p.add_argument("--artifact", help="controller artefact (default: designed from DESIGN now)")
    p.add_argument("--law", choices=(*law_registry.NAMES, "all"), default="all")
    p.add_argument("--real", choices=("float", "double"), default="float", help="firmware build (default: %(default)s)")
    p.add_argument("--duration", type=float, help="t_e [s] (default: the design's control.study_duration)")
    p.add_argument(
        "--fault",
        action="append",
        help="inject kind:target:start:end[:detail], repeatable; kinds: drop, delay (detail: seconds), "
        "duplicate, corrupt_crc, corrupt_counter, wrong_dlc, silent on any frame (the firmware's "
        "SETPOINT_* and CONTROLLER_STATUS too), implausible (target FRAME.signal, detail: the "
        "value), amplifier (target a joint, detail: over_temperature, no_response, stuck_output, "
        "over_current, gain_error), bus_off (no target); end may be inf",
    )
    p.add_argument("--log-folder", help="write the bus of each run as sil_<law>.blf here")
    p.add_argument("--plots", help="folder for sil_energy.png")
    p.add_argument("--amplifier-lag", type=float, default=0.0, help="amplifier time constant [s] (default 0: ideal)")
    p.add_argument(
        "--spread", type=int, default=6, help="perturbed MIL runs for the sensitivity band (default: %(default)s)"
    )
    p.set_defaults(func=cmd_sil)


def _add_fmu_command(sub, o: SimpleNamespace) -> None:
    """fmu."""
    p = sub.add_parser(
        "fmu",
        parents=[o.no_update, o.json_summary],
        help="a controller (artefact, --law) or the plant (design, --plant) as an FMI co-simulation FMU",
    )
    p.add_argument("source", help="controller artefact (JSON) for a controller FMU; design file (TOML) with --plant")
    p.add_argument("--plant", action="store_true", help="the design's reduced truss with its LuGre joints")
    p.add_argument("--law", choices=law_registry.NAMES, help="the controller's law (controller FMUs)")
    p.add_argument("-o", "--output", required=True, help="the FMU to write, <model identifier>.fmu")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version (default: %(default)s)")
    p.add_argument("--real", choices=("float", "double"), default="double", help="law build (default: %(default)s)")
    exchange = "controller FMUs: outputs from this point's inputs, or held from the last step (libcosim; docs/fmu.md)"
    p.add_argument("--exchange", choices=("feedthrough", "held"), default="feedthrough", help=exchange)
    p.add_argument("--stop-time", type=float, help="controller FMUs: the default experiment's stop time [s], your "
                   "design's control.study_duration (default: that setting's default)")  # fmt: skip
    p.set_defaults(func=cmd_fmu)


def _add_target_commands(sub, o: SimpleNamespace) -> None:
    """pil."""
    p = sub.add_parser(
        "pil",
        parents=[o.design, o.no_update, o.json_results, _xcp_serve()],
        help="the study with the firmware on its target: QEMU mps2-an386 (Cortex-M4F) in lock-step with "
        "the plant (processor in the loop)",
    )
    p.add_argument("--artifact", help="controller artefact (default: designed from DESIGN now)")
    p.add_argument("--law", choices=(*law_registry.NAMES, "all"), default="all")
    p.add_argument("--duration", type=float, help="t_e [s] (default: the design's control.study_duration)")
    p.add_argument("--fault", action="append", help="inject a fault as `sil --fault` takes it, repeatable")
    p.add_argument(
        "--fault-matrix",
        action="store_true",
        help=f"also run every case of the SIL fault matrix on the target ({law_registry.fault_matrix_law().display})",
    )
    p.add_argument("--clock", type=float, default=168.0, help="processor clock of the budget [MHz] (default: 168)")
    p.add_argument("--plots", help="folder for pil_energy.png")
    p.set_defaults(func=cmd_pil)


def _add_study_command(sub, o: SimpleNamespace) -> None:
    """study, sweep."""
    p = sub.add_parser(
        "study",
        parents=[o.design, o.no_update, o.json_results],
        help=f"the paper's closed-loop study (Section 6): passive, {_LAWS_SHOWN}, active LQG",
    )
    p.add_argument("--duration", type=float, help="t_e [s] (default: the design's control.study_duration)")
    p.add_argument("--plots", help="folder for control_energy.png, control_tip.png, … (PNG)")
    p.set_defaults(func=cmd_study)
    p = sub.add_parser(
        "sweep",
        parents=[o.json_results],
        help="a robustness ensemble or design sweep of the closed-loop study on Dask (docs/sweep.md)",
    )
    p.add_argument("sweep", help="sweep file (TOML)")
    p.add_argument("-o", "--output", help="results folder (default: SWEEP's name + -results, here)")
    p.add_argument("--scheduler", help="address of a running Dask scheduler (default: a LocalCluster here)")
    p.add_argument("--workers", type=_positive_int, help="LocalCluster worker processes (default: one per core)")
    p.add_argument("--resume", action="store_true", help="continue the results in -o: run only the missing batches")
    p.set_defaults(func=cmd_sweep)


def build_parser() -> argparse.ArgumentParser:
    """The parser of the ``smartjoint`` command line, one subcommand per command.

    Returns
    -------
    argparse.ArgumentParser
        Parsed arguments carry ``func``, the command to call with them.
    """
    parser = argparse.ArgumentParser(prog="smartjoint", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"smartjoint {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    shared = _shared_options()
    _add_model_commands(sub, shared)
    _add_friction_commands(sub, shared)
    _add_dynamics_commands(sub, shared)
    _add_control_commands(sub, shared)
    _add_fmu_command(sub, shared)
    _add_target_commands(sub, shared)
    add_bench_commands(sub, shared, _bus_rates, _bus_channel)
    _add_study_command(sub, shared)
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
        check_outputs(args)
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
