"""The commands of the friction stage (``rig``, ``identify``): records of the isolated-joint rig
of paper Section 3.2 simulated from a LuGre parameter set (Table 1, a file or the command line),
and the parameters identified from such records (Eq. 3).
"""

from __future__ import annotations

from pathlib import Path

from smartjoint.commands import report_progress, write_atomic, write_plots
from smartjoint.common import friction_registry, output_path
from smartjoint.common.errors import SmartjointError

_MODEL = friction_registry.friction_model()  # the rig's flags are the default model's parameters
_FLAGS = (*_MODEL.keys, "radius")


def _rig_parameters(args):
    """The rig's parameter set: --parameters FILE, or all the LuGre flags, or (neither) Table 1."""
    from smartjoint.design.friction import rig

    flags = {n: getattr(args, n) for n in _FLAGS if getattr(args, n) is not None}
    if args.parameters is not None:
        if flags:
            raise SmartjointError(
                f"--{next(iter(flags)).replace('_', '-')} together with --parameters — give "
                "the parameter set either as flags or as a file"
            )
        return rig.load_parameter_set(args.parameters, args.type)
    joint_type = args.type or "A"
    if not flags:
        return rig.parameter_set(joint_type)
    values = {n: v for n, v in flags.items()}
    for name in _FLAGS:
        if name not in values and (name != "radius" or joint_type == "B"):
            every = ", ".join(f"--{key.replace('_', '-')}" for key in _MODEL.keys)
            raise SmartjointError(
                f"--{name.replace('_', '-')} missing — give all of {every}"
                f"{', --radius' if joint_type == 'B' else ''} (or --parameters FILE, or none of "
                f"them for {rig.TABLE_1_SOURCE})"
            )
    if "radius" in values and joint_type == "A":
        raise SmartjointError("--radius: a type A joint has no radius — allowed only with --type B")
    return rig.parameter_set(joint_type, values, "command line")


def _campaign_prior(args, chosen):
    """The parameter set a campaign is designed from: --prior FILE, else the simulated one."""
    from smartjoint.design.friction import rig

    if args.prior is None:
        return chosen
    prior = rig.load_parameter_set(args.prior, chosen.joint_type)
    return rig.ParameterSet(prior.joint_type, prior.parameters, f"prior: {prior.source}")


def _run_campaign(tests, prior, measure, args):
    """The campaign's records to write, rung by rung upwards (`rig_campaign.run_campaign`); says
    which rungs stuck near the break-away (not written) and which did not run."""
    from smartjoint.design.friction.rig_campaign import MICRO_SPAN, STICK_SPAN, run_campaign

    measured = run_campaign(tests, prior, measure)
    if not args.json:
        for record in measured.left_out:
            print(
                f"left out {record.name}: stuck above {MICRO_SPAN:g}× the lowest rung that slid (near the break-away)"
            )
        for test in measured.not_run:
            print(f"not run {test.name}: above {STICK_SPAN:g}× the lowest rung that slid")
    return measured.micro + measured.stick


def _rig_test(args, joint_type, normal_force, amplitude, frequency, seed):
    from smartjoint.design.friction.rig import RigTest

    inertia = args.inertia if args.inertia is not None else (1.0 if joint_type == "A" else 2e-3)
    return RigTest(
        joint_type, normal_force, amplitude, frequency, cycles=args.cycles, inertia=inertia, noise=args.noise, seed=seed
    )


def _is_rig_record(entry: Path) -> bool:
    """A record `smartjoint rig --campaign` wrote (``rig_<type>_FN….csv``): replaced by name."""
    return output_path.kind(entry) == "file" and entry.name.startswith("rig_") and entry.suffix == ".csv"


def cmd_rig(args) -> dict:
    """``smartjoint rig``: simulate one rig test, or the whole campaign, and write the records.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed ``rig`` options (parameter set, test or ``--campaign``, ``-o``, ``--json``).

    Returns
    -------
    dict
        ``"parameters"`` (the set used) and ``"records"`` (file, regime, samples and peak sliding
        velocity of each record written).
    """
    from smartjoint.design.friction import rig
    from smartjoint.design.friction.records import write_record
    from smartjoint.design.friction.rig_campaign import campaign

    output = Path(args.output)
    chosen = _rig_parameters(args)
    parameters, joint_type = chosen.parameters, chosen.joint_type
    if args.campaign:
        # The output rule (common.output_path): a folder of rig records at most, replaced by name.
        output_path.check_folder(output, "-o", ours=_is_rig_record)
        prior = _campaign_prior(args, chosen)
        tests = campaign(joint_type, prior.parameters, noise=args.noise, seed=args.seed, cycles=args.cycles)
    else:
        missing = [n for n in ("normal_force", "amplitude", "frequency") if getattr(args, n) is None]
        if missing:
            raise SmartjointError(f"give --{missing[0].replace('_', '-')} (or --campaign)")
        output_path.check_file(output, "-o")
        if args.prior is not None:
            raise SmartjointError("--prior: designs a campaign — give it with --campaign")
        tests = [_rig_test(args, joint_type, args.normal_force, args.amplitude, args.frequency, args.seed)]
    for test in tests:  # every test is checked before anything is written
        rig.check_test(test, parameters)
    if not args.json:
        print(chosen.describe())
        if args.campaign:
            print(prior.describe() if args.prior is not None else "prior = the simulated parameters")
    if args.campaign:
        try:
            output.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise SmartjointError(f"-o {output}: cannot create folder ({error.strerror or error})") from None
    if args.campaign:
        records = _run_campaign(
            tests, prior.parameters, lambda test: rig.simulate(test, parameters, chosen.source), args
        )
    else:
        records = [rig.simulate(tests[0], parameters, chosen.source)]
    written = []
    for record in records:
        path = output / f"{record.name}.csv" if args.campaign else output
        write_record(record, path)
        written.append(
            {
                "file": str(path),
                "regime": record.metadata["regime"],
                "samples": int(record.time.size),
                "max_velocity": float(abs(record.sliding_velocity).max()),
            }
        )
        if not args.json:
            print(f"wrote {path} ({record.metadata['regime']}, {record.time.size} samples)")
    summary = {"parameters": chosen.as_dict(), "records": written}
    if args.campaign:
        summary["prior"] = prior.as_dict() if args.prior is not None else "the simulated parameters"
    return summary


def cmd_identify(args) -> dict:
    """``smartjoint identify``: the LuGre parameters from micro-slip and stick–slip records (Eq. 3).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed ``identify`` options (record files, ``--radius``, ``--no-output-error``,
        ``--plots``, ``--json``).

    Returns
    -------
    dict
        The identification result (``Identification.as_dict``), with ``"plots"`` under
        ``--plots``.
    """
    from smartjoint.design.friction import parameter_file
    from smartjoint.design.friction.identify import identify
    from smartjoint.design.friction.record_screening import check_friction_coefficient, classify
    from smartjoint.design.friction.records import read_record
    from smartjoint.report import identification_table, plot_hysteresis

    records = [read_record(path, args.radius) for path in args.records]
    for path, record in zip(args.records, records):  # identify screens again, naming the records only
        check_friction_coefficient(record, args.radius, str(path))
    micro = [r for r in records if classify(r, args.radius) == "micro-slip"]
    stick = [r for r in records if classify(r, args.radius) == "stick-slip"]
    result = identify(micro, stick, radius=args.radius, progress=report_progress, output_error=not args.no_output_error)
    out = result.as_dict()
    write_plots(args, out, lambda folder: plot_hysteresis(result, folder))
    if args.output:
        text = parameter_file.result_text(
            result, parameter_file.file_hashes(args.records), output_error=not args.no_output_error
        )
        write_atomic(Path(args.output), text)
        out["written"] = str(args.output)
    if not args.json:
        print("\n".join(f"step: {step}" for step in result.steps) + "\n")
        print(identification_table(result))
        if args.output:
            print(f"\nresult written to {args.output} (a design names it in [friction.{result.joint_type}] file = …)")
    return out


def cmd_campaign(args) -> dict:
    """``smartjoint campaign``: the sequential campaign over a folder of records (``campaign_folder``).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed ``campaign`` options (folder, ``--prior``, ``--type``, ``--simulate``, ``-o``).

    Returns
    -------
    dict
        ``"state"`` ('waiting' for records, or 'done'), the plan file and the records still to
        measure, or the rounds, the stop reason and the identification.
    """
    from smartjoint.design.friction import lugre, parameter_file, rig
    from smartjoint.design.friction.campaign_folder import run_folder
    from smartjoint.report import identification_table

    if not 0.0 <= args.noise <= 1.0:
        raise SmartjointError(f"--noise: {args.noise!r} — allowed: 0 … 1 (relative to each signal's RMS)")
    if not (args.cycles > 0.0 and args.cycles <= 1000.0):
        raise SmartjointError(f"--cycles: {args.cycles!r} — allowed: > 0 and <= 1000")
    prior = rig.load_parameter_set(args.prior, args.type)
    if not isinstance(prior.parameters, lugre.LuGreParameters):
        raise SmartjointError(f"--prior {args.prior}: model {prior.parameters.model!r} — the sequential campaign "
                              "designs its records from the LuGre parameters; allowed: a LuGre prior")  # fmt: skip
    simulate = None if args.simulate is None else rig.load_parameter_set(args.simulate, prior.joint_type)
    folder = Path(args.folder)
    if not args.json:
        print(f"prior: {prior.describe()}")
        if simulate is not None:
            print(f"simulated rig: {simulate.describe()}, noise {args.noise:g}, seed {args.seed}")
    done = run_folder(
        folder, prior.joint_type, prior.parameters, simulate, args.noise, args.seed, args.cycles,
        None if args.json else print,
    )  # fmt: skip
    if done.result is None:
        assert done.pending is not None and done.plan_file is not None
        if not args.json:
            print(f"round {done.pending.number}: measure up to {len(done.missing)} record(s) as planned in "
                  f"{done.plan_file} (first: {done.missing[0]}), then run this command again")  # fmt: skip
        return {"state": "waiting", "round": done.pending.number, "plan": str(done.plan_file),
                "missing": list(done.missing)}  # fmt: skip
    result = done.result
    out: dict = {"state": "done", **result.as_dict(), "simulated_records": [str(p) for p in done.simulated]}
    identification = result.identification
    if not args.json:
        print(f"campaign {'converged' if result.converged else 'stopped'}: {result.stop}")
    if identification is None:
        raise SmartjointError(f"campaign {folder}: {result.stop}")
    out["identification"] = identification.as_dict()
    if args.output:
        paths = sorted(folder / f"{name}.csv" for name in identification.records)
        text = parameter_file.result_text(identification, parameter_file.file_hashes(paths))
        write_atomic(Path(args.output), text)
        out["written"] = str(args.output)
    if not args.json:
        print(identification_table(identification))
        if args.output:
            print(f"\nresult written to {args.output}")
    return out
