"""Stage 11 of ``smartjoint run``: the design's controllers and plant as FMI co-simulation units.

The FMUs go into ``fmu/fmi2/`` and ``fmu/fmi3/`` of the report (``truss.fmu``, ``siso.fmu``,
``clqg.fmu`` in the double build, ``siso_float.fmu``, ``clqg_float.fmu`` as the firmware's float
build), each validated by FMPy, each controller replayed with the study's measurements, and the
plant with either controller co-simulated in FMPy beside the model-in-the-loop run
(``bench/fmu_check.py``); ``fmu/cosimulation.png`` and ``.csv`` hold both trajectories.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smartjoint.bench import fmu_check
from smartjoint.stages import FmuStage


def fmu_stage(design, control_study, controller, staging: Path, progress) -> FmuStage:
    """Write and check the FMUs of the run's design.

    Parameters
    ----------
    design : Design
        The design the controllers were built for.
    control_study : design.control.study.Study
        The model-in-the-loop study.
    controller : ControllerArtifact
        The artefact the firmware was generated from.
    staging : Path
        The report folder being written.
    progress : callable

    Returns
    -------
    FmuStage
        Its summary entry; ``fmu_markdown`` renders it.
    """
    progress("[11/12] FMU export: the controllers and the plant as FMI 2 and 3 co-simulation units (FMPy)")
    folder = staging / "fmu"
    checked = fmu_check.fmu_study(control_study, design, controller, folder, progress)
    runs = checked.pop("runs")
    _write_trajectories(runs, folder)
    versions = {}
    for version, figures in checked["versions"].items():
        fmus = {
            key: {"path": Path(f["path"]).relative_to(staging).as_posix(), "problems": f["problems"]}
            for key, f in figures["fmus"].items()
        }
        versions[str(version)] = {**figures, "fmus": fmus}
    summary = {
        "float_bound": checked["float_bound"],
        "versions": versions,
        "plot": "fmu/cosimulation.png",
        "trajectories": "fmu/cosimulation.csv",
    }
    return FmuStage(summary)


def _write_trajectories(runs: dict, folder: Path) -> None:
    """e(t) of each law co-simulated and in the MIL study: a CSV and a plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(runs)
    time = runs[names[0]][1].time
    columns = [time] + [r.energy for name in names for r in runs[name]]
    header = "time_s," + ",".join(f"{name}_{kind}_energy_J" for name in names for kind in ("cosimulation", "mil"))
    np.savetxt(folder / "cosimulation.csv", np.column_stack(columns), delimiter=",", header=header, comments="")
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(7.5, 5.5), sharex=True)
    for name in names:
        run, mil = runs[name]
        (line,) = top.semilogy(mil.time, mil.energy, label=f"{name}: MIL")
        top.semilogy(run.time, run.energy, ".", markevery=80, color=line.get_color(), label=f"{name}: FMUs in FMPy")
        bottom.plot(run.time, run.energy - mil.energy, color=line.get_color(), label=name)
    top.set_ylabel("e(t) [J]")
    top.legend(fontsize=8)
    bottom.set_ylabel("e(t): FMUs − MIL [J]")
    bottom.set_xlabel("t [s]")
    bottom.legend(fontsize=8)
    figure.suptitle("Plant FMU + controller FMU co-simulated against the model-in-the-loop study")
    figure.tight_layout()
    figure.savefig(folder / "cosimulation.png", dpi=110)
    plt.close(figure)


def fmu_markdown(stage: FmuStage) -> str:
    """The report's section of the stage."""
    summary = stage.summary
    lines = [
        "## FMU export (FMI co-simulation)",
        "",
        "The firmware's generated laws and the plant kernel with the design's reduced truss as FMUs "
        "(`smartjoint fmu`; how to use them in other tools: docs/fmu.md). Replay: each controller FMU driven "
        "through FMPy with the measurements the Python reference saw in the study; co-simulation: the plant FMU "
        "and the controller FMU (double build) in an FMPy master, against the MIL study.",
        "",
        "| FMI | law | FMPy validation problems | replay, double: bit-identical samples | replay, float: max abs(ΔF_N) "
        "[N] | co-simulation = MIL | E(t_e) co-simulated | E(t_e) MIL |",
        "|---|---|---:|---:|---:|---|---:|---:|",
    ]
    for version, figures in summary["versions"].items():
        problems = sum(len(f["problems"]) for f in figures["fmus"].values())
        for name in fmu_check.LAWS:
            f = figures[name]
            lines.append(
                f"| {version} | {name} | {problems} | {f['double_identical_samples']} of {f['samples']} | "
                f"{f['float_max_deviation']:.3g} (bound {summary['float_bound']:.3g}) | "
                f"{'every number' if f['cosimulation_identical'] else '**differs**'} | "
                f"{f['cosimulation_energy_measure']:.6g} | {f['mil_energy_measure']:.6g} |"
            )
    lines.append("")
    for version, figures in summary["versions"].items():
        held = [k for k, v in figures["orderings"].items() if v is True]
        failed = [k for k, v in figures["orderings"].items() if v is False]
        lines.append(
            f"FMI {version}, the paper's orderings with the co-simulated runs — hold: {', '.join(held) or 'none'}"
            + (f"; fail: {', '.join(failed)}." if failed else ".")
        )
        lines.append("")
    first = next(iter(summary["versions"].values()))
    lines.append(
        "FMUs: " + ", ".join(f"`{f['path']}`" for f in first["fmus"].values()) + " (and the same in `fmu/fmi3/`)."
    )
    lines += ["", "![co-simulation](fmu/cosimulation.png)", ""]
    return "\n".join(lines)


__all__ = ["fmu_markdown", "fmu_stage"]
