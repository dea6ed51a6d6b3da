"""Stage 10 of ``smartjoint run``: a small robustness ensemble of the study (issue 20) — the
study's laws, passive and semi-active, and the best constant normal forces on plants drawn
around the design: each joint's LuGre parameters, the modal frequencies and damping and the
pulse. It runs the sweep machinery (``bench.sweep``: Dask, the compiled closed loop, Parquet)
on the run's own design and writes the sweep and its report into ``ensemble/``. Every spread is
relative to the design's own values; ``smartjoint sweep`` runs larger or other ensembles."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np

from smartjoint import sweep_report
from smartjoint.bench.sweep import read_results, run_sweep
from smartjoint.design.control import study as closed_loop
from smartjoint.design.control import sweep_file, tuning
from smartjoint.design.control.ensemble import KEYS, METRICS
from smartjoint.design.control.friction_uncertainty import Z95, friction_inputs, friction_spreads
from smartjoint.design.control.sweep_file import Distribution, Sweep, UncertainInput
from smartjoint.stages import EnsembleStage

SAMPLES = 16
SEED = 2026
LAWS = tuple(law for law in sweep_file.LAWS if law != "active LQG")  # every law but the active reference
FREQUENCY_SPREAD, PULSE_SPREAD, DAMPING_SIGMA = 0.01, 0.10, 0.3


def stage_sweep(design, study, spreads: dict[str, float] | None = None) -> Sweep:
    """The stage's sweep of ``design`` (the run's controlled design) around ``study`` (its
    model-in-the-loop study): the friction factors of ``spreads`` (``friction_spreads``; ±5 %
    uniform for a parameter without), uniform factors on the modal frequencies and the pulse,
    lognormal damping around the design model's median, Latin hypercube."""
    damping = float(np.median(study.setup.model.damping))
    pulse = float(study.setup.pulse_amplitude)

    def uniform(spread: float, centre: float = 1.0) -> Distribution:
        return Distribution("uniform", centre * (1.0 - spread), centre * (1.0 + spread))

    inputs = (
        UncertainInput("modal_frequency_scale", uniform(FREQUENCY_SPREAD)),
        UncertainInput(
            "modal_damping",
            Distribution("lognormal", 0.0, min(0.99, 5.0 * damping), median=damping, sigma=DAMPING_SIGMA),
        ),
        UncertainInput("pulse_amplitude", uniform(PULSE_SPREAD, pulse)),
        *friction_inputs(spreads or {}),
    )
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
    sweep = stage_sweep(design, study, spreads)
    shown = ", ".join(f"{name} ×/÷{math.exp(Z95 * sigma):.4g}" for name, sigma in spreads.items()) or "±5 %"
    progress(
        f"[10/12] robustness ensemble: {SAMPLES} plants around the design (LuGre within the identification's 95 % "
        f"intervals: {shown}; modal frequencies ±1 %, damping, pulse ±10 %) × {len(LAWS)} laws, on Dask"
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
        f"{summary['samples']} plants drawn around the design (Latin hypercube: each joint's LuGre parameters "
        "lognormal within the identification's 95 % intervals, the widest over the joint types (σ of the "
        "logarithm: "
        + (", ".join(f"{n} {v:.3g}" for n, v in summary["friction_log_sigma"].items()) or "none; ±5 %")
        + "), modal frequencies ±1 %, modal damping lognormal around the model's, the pulse ±10 %); the "
        "controllers stay those designed on the nominal model. The best passive settings search the constant "
        "F_N that minimises E(t_e) or e(t_e) on each plant. Whole report: [ensemble/report.md](ensemble/report.md).",
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


__all__ = ["LAWS", "SAMPLES", "ensemble_markdown", "ensemble_stage", "stage_sweep"]
