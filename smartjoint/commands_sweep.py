"""``smartjoint sweep``: a robustness ensemble or design sweep of the closed-loop study on Dask
(``docs/sweep.md``)."""

from __future__ import annotations

from pathlib import Path

from smartjoint.commands import report_progress


def cmd_sweep(args) -> dict:
    from smartjoint.bench.sweep import run_sweep
    from smartjoint.bench.sweep_folder import check_output
    from smartjoint.design.control.sweep_file import load_sweep

    folder = Path(args.output) if args.output else Path(f"{Path(args.sweep).stem}-results")
    check_output(folder, args.resume)  # the output rule before the sweep file is even read
    sweep = load_sweep(args.sweep)
    out = run_sweep(sweep, folder, args.scheduler, args.workers, args.resume, report_progress)
    from smartjoint.bench.sweep import read_results
    from smartjoint.design.control.ensemble import KEYS, METRICS
    from smartjoint.sweep_report import write

    table = read_results(folder)
    inputs = [name for name in table.column_names if name not in (*KEYS, *sweep.grid, *METRICS)]
    out["report"] = str(write(folder, table, inputs, Path(args.sweep).name))
    if not args.json:
        for key, value in out.items():
            print(f"{key}: {value}")
    return out


__all__ = ["cmd_sweep"]
