"""Stage 10 of ``smartjoint run``: a small robustness ensemble of the study (issue 20) — the
study's laws, passive and semi-active, and the best constant normal forces on plants drawn from
the physical spread of the structure (the design's ``[uncertainty]`` and its defaults,
``physical_spread``: each joint's friction, the modal frequencies and damping, the pulse, the
amplifier lag, the sensor noise), the identification's intervals on top. It runs the sweep
machinery (``bench.sweep``: Dask, the compiled closed loop, Parquet) on the run's own design and
writes the sweep and its report into ``ensemble/``; ``smartjoint sweep`` runs larger or other
ensembles."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from smartjoint import sweep_report
from smartjoint.bench.sweep import read_results, run_sweep
from smartjoint.design.control import study as closed_loop
from smartjoint.design.control import sweep_file, tuning
from smartjoint.design.control.ensemble import KEYS, METRICS
from smartjoint.design.control.friction_uncertainty import friction_spreads
from smartjoint.design.control.physical_spread import describe, physical_spread, with_identification
from smartjoint.design.control.sweep_file import Sweep
from smartjoint.stages import EnsembleStage

SAMPLES = 16
SEED = 2026
LAWS = tuple(law for law in sweep_file.LAWS if law != "active LQG")  # every law but the active reference


def stage_spread(design, study, spreads: dict[str, float] | None = None) -> list:
    """The stage's spread of ``design`` around ``study``: the design's physical spread (its
    ``[uncertainty]`` and the defaults, ``physical_spread``; the pulse around the study's) with the
    identification's intervals ``spreads`` (``friction_spreads``) on top."""
    entries = physical_spread(design, float(study.setup.pulse_amplitude))
    return with_identification(entries, spreads or {})


def stage_sweep(design, study, spreads: dict[str, float] | None = None) -> Sweep:
    """The stage's sweep of ``design`` (the run's controlled design) around ``study`` (its
    model-in-the-loop study): the inputs of `stage_spread`, Latin hypercube."""
    inputs = tuple(entry.input for entry in stage_spread(design, study, spreads))
    settings = {"design": design.sha256, "laws": LAWS, "samples": SAMPLES, "seed": SEED, "inputs": repr(inputs)}
    return Sweep(
        source="smartjoint run (stage 10)",
        sha256=hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest(),
        design=Path(str(design.source)),
        update=False,
        laws=LAWS,
        inputs=inputs,
        grid={},
        samples=SAMPLES,
        seed=SEED,
        sampler="latin-hypercube",
        batch=2,
        study_duration=None,
    )


def ensemble_stage(design, study, friction, staging: Path, progress) -> EnsembleStage:
    """Run the stage's sweep into ``staging/ensemble`` and report it.

    Parameters
    ----------
    design : Design
        The run's controlled design (placed joints, identified friction).
    study : design.control.study.Study
        Its model-in-the-loop study: the SISO ε it optimised is the ensemble's.
    friction : list of JointTypeFriction
        The friction stage's results: their 95 % intervals set the friction's spread.
    staging : Path
        The report folder being written.
    progress : callable

    Returns
    -------
    EnsembleStage
        Its summary entry (counts, time, the orderings' probabilities, the three inputs that
        drive each law's E(t_e), the best passive forces); ``ensemble_markdown`` renders it.
    """
    spreads = friction_spreads(friction)
    spread = stage_spread(design, study, spreads)
    sweep = stage_sweep(design, study, spreads)
    given = sum(entry.source == "design file" for entry in spread)
    progress(
        f"[10/12] robustness ensemble: {SAMPLES} plants drawn from the physical spread ({given} of {len(spread)} "
        f"inputs from the design's [uncertainty], the rest its defaults; the identification's intervals on top) "
        f"× {len(LAWS)} laws, on Dask"
    )
    tuned = tuning.with_settings(design, closed_loop.settings_figures(study.tunings))  # the study's settings
    folder = staging / "ensemble"
    out = run_sweep(
        sweep,
        folder,
        progress=lambda line: progress("      " + line.strip()),
        design=tuned,
        model=study.setup.model,  # the control stage's design model: the same design but its settings
    )
    table = read_results(folder)
    inputs = [name for name in table.column_names if name not in (*KEYS, *METRICS)]
    sweep_report.write(folder, table, inputs, "smartjoint run")
    columns = table.to_pydict()
    orderings = sweep_report.orderings(columns).get(0, {})
    drivers = {law: rhos for (_, law), rhos in sweep_report.sensitivity(columns, inputs).items()}
    law, force = np.asarray(columns["law"]), np.asarray(columns["passive_normal_force"], dtype=float)
    best = {name: float(np.median(force[law == name])) for name in ("best passive E", "best passive e")}
    summary = {
        "samples": SAMPLES,
        "friction_log_sigma": spreads,
        "spread": describe(spread),
        "laws": list(LAWS),
        "seconds": out["seconds"],
        "workers": out["workers"],
        "orderings": orderings,
        "drivers": {name: [[n, r] for n, r in rhos] for name, rhos in drivers.items()},
        "best_passive_normal_force_median": best,
        "results": "ensemble/results",
        "report": "ensemble/report.md",
        "plot": "ensemble/ecdf.png",
    }
    return EnsembleStage(summary)


def ensemble_markdown(stage: EnsembleStage) -> str:
    """The report's section of the stage."""
    summary = stage.summary
    sentences = {o.key: o.sentence for o in sweep_report.ORDERINGS}
    lines = [
        "## Robustness ensemble",
        "",
        f"{summary['samples']} plants drawn from the physical spread of the structure (Latin hypercube), the "
        "identification's 95 % intervals on top of each friction factor; the controllers stay those designed on "
        "the nominal model. The best passive settings search the constant F_N that minimises E(t_e) or e(t_e) on "
        "each plant. The probabilities below are for this spread (the design's `[uncertainty]`, or the default "
        "named; docs/design-file.md gives the sources). Whole report: [ensemble/report.md](ensemble/report.md).",
        "",
        "| drawn input | distribution — source |",
        "|---|---|",
        *(f"| `{line.split(': ', 1)[0]}` | {line.split(': ', 1)[1]} |" for line in summary.get("spread", [])),
        "",
        "| ordering | probability | MC standard error |",
        "|---|---:|---:|",
    ]
    for name, f in summary["orderings"].items():
        lines.append(f"| {sentences[name]} | {f['probability']:.2f} | {f['standard_error']:.2f} |")
    forces = summary["best_passive_normal_force_median"]
    lines += [
        "",
        f"Best constant F_N (median over the plants): {forces['best passive E']:.0f} N for E(t_e), "
        f"{forces['best passive e']:.0f} N for e(t_e).",
        "",
        "![ECDF of E(t_e)](ensemble/ecdf.png)",
        "",
    ]
    return "\n".join(lines)


__all__ = ["LAWS", "SAMPLES", "ensemble_markdown", "ensemble_stage", "stage_spread", "stage_sweep"]
