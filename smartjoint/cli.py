"""The ``smartjoint`` command line: a thin layer over the library.

Every command that reports numbers offers ``--json``. User errors (a bad design file, a
model that cannot be built) end with a one-line message on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from . import __version__
from .design.errors import SmartjointError


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
    from .design import build_model, load_design, update_model

    design = load_design(args.design)
    model = build_model(design, joints=joints)
    result = None
    if design.updating is not None and not getattr(args, "no_update", False):
        _progress(f"updating {len(design.updating.parameters)} parameters to {len(design.updating.measured)} measured modes …")
        result = update_model(model, progress=lambda k, n, err: _progress(f"  start {k}/{n}: worst error {err:.2f} %"))
        design = design.with_parameters(result.parameters)
        model = build_model(design, joints=joints)
    return model, result


def cmd_modes(args) -> dict:
    from .design import solve_modes

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
        from .report import updating_table

        print(updating_table(result))
    return out


def cmd_export_model(args) -> dict:
    from .design.export import export_model

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
    from .pipeline import run

    result = run(args.design, Path(args.output), progress=_progress)
    if not args.json:
        print(f"report: {result['report']}")
    return result


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
    p.add_argument("-o", "--output", default="smartjoint-report", help="report folder (default: %(default)s)")
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
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        out = args.func(args)
    except SmartjointError as error:
        print(f"smartjoint {args.command}: error: {error}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
