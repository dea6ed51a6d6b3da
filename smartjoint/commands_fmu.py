"""``smartjoint fmu``: a controller artefact's law, or a design's plant, as an FMI co-simulation FMU."""

from __future__ import annotations

import math
from pathlib import Path

from smartjoint.commands import load_updated, report_progress
from smartjoint.common.errors import ModelError


def cmd_fmu(args) -> dict:
    from fmpy.validation import validate_fmu

    from smartjoint.codegen import fmu

    fmu.identifier_of(args.output)  # refuse a bad name before any work
    if args.plant:
        written = _plant(args)
    else:
        written = _controller(args)
    problems = validate_fmu(str(written.path))
    out = {
        "fmu": str(written.path),
        "model_identifier": written.identifier,
        "fmi_version": written.fmi,
        "kind": "plant" if args.plant else args.law,
        "variables": {
            causality: [v.name for v in written.variables if v.causality == causality]
            for causality in ("input", "output", "parameter")
        },
        "binary": written.binary,
        "sources": [m for m in written.members if m.startswith("sources/")],
        "validation_problems": problems,
    }
    if not args.json:
        counts = ", ".join(f"{len(names)} {kind}s" for kind, names in out["variables"].items())
        print(
            f"{written.path}: FMI {written.fmi} co-simulation, {out['kind']}, {counts}; {written.binary} and sources/"
        )
        print(f"fmpy.validation.validate_fmu: {len(problems)} problems" + "".join(f"\n  {p}" for p in problems))
    return out


def _controller(args):
    from smartjoint.codegen import fmu
    from smartjoint.common import law_registry
    from smartjoint.design.control import artifact

    if args.law is None:
        raise ModelError(f"--law: required for a controller FMU — allowed: {', '.join(law_registry.NAMES)}")
    source = Path(args.source)
    if source.suffix.lower() != ".json":
        raise ModelError(
            f"{args.source}: a controller FMU is made from an artefact (JSON); a design file needs --plant"
        )
    from smartjoint.design.structure.description import Control

    stop_time = Control.study_duration if args.stop_time is None else args.stop_time
    if not (math.isfinite(stop_time) and stop_time > 0):
        raise ModelError(f"--stop-time: {stop_time!r} s — must be a finite number > 0")
    return fmu.controller_fmu(artifact.load(source), args.law, args.output, args.fmi, args.real,
                              stop_time=stop_time, exchange=args.exchange)  # fmt: skip


def _plant(args):
    from smartjoint.codegen import fmu
    from smartjoint.design.control import study as closed_loop

    if args.law is not None:
        raise ModelError(f"--law: {args.law!r} — a plant FMU has no law (leave --law out with --plant)")
    if args.exchange != "feedthrough":
        raise ModelError(f"--exchange: {args.exchange!r} — a controller FMU's timing; the plant has none to choose")
    args.design = args.source
    design, _ = load_updated(args, firmware_names=True)  # the names become FMI variable names
    if not design.joints:
        raise ModelError(
            f"{args.source}: the design has no [[joints]] — the plant FMU is the truss with its friction joints"
        )
    model = closed_loop.design_model(design, report_progress)
    return fmu.plant_fmu(closed_loop.setup(design, model), design, args.output, args.fmi)


__all__ = ["cmd_fmu"]
