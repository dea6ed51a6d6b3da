"""Model reduction against balanced truncation, side by side on the same full model (issue 31).

Per design: the full model (every mode of the released truss), the project's controller design
model (``study.design_model``: ``control.modes`` modes by Hankel values plus ``control.krylov``
corrections per joint, quasi-static above 4× the Nyquist frequency), the same model with Eq. 26's
corrections as the paper has them, and balanced truncation (``design/reduction/balanced.py``,
square-root method on exact modal gramians, tested equal to python-control's ``balred``) of the
full model at the same order, all inputs [u_R, w] and outputs [v, y] together. Balanced
truncation is given the modes below ``--cut`` × the Nyquist frequency (a dense balanced
truncation of all 3969 modes would take about 10 minutes per design here, ``balred`` about 19 h);
the in-band error of that cut itself is printed beside it and is orders below balanced
truncation's own error. Figures: u→v and w→y H∞ and H2 errors in the considered band (the
highest considered mode) and across the band to the controller's Nyquist frequency, the static
joint compliance error, and the friction RMS error of Fig. 10 (60 modes + 2 Krylov vectors for
the active joint, 0–50 ms and 0–0.5 s) for the paper's and the quasi-static corrections.

    python benchmarks/reduction.py [--designs bundled fig10_three_joints three_type_a] [--cut 4]
        [--json benchmarks/reduction.json] [--plots benchmarks]

``bundled`` is the reference truss with the joints its ``[placement]`` chooses (what
``smartjoint run`` designs on); ``three_type_a`` is the design of firmware/generated/controller.json.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from machine import python_machine, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.design import build_model, load_design, updated_design
from smartjoint.design.control import study as control_study
from smartjoint.design.reduction import comparison, metrics, reduce, study
from smartjoint.design.reduction.krylov import quasi_static_corrections
from smartjoint.design.structure import modal

DATA = Path(__file__).resolve().parents[1] / "design" / "data"


def load(name: str):
    """The design as ``smartjoint run`` / ``smartjoint design`` see it: updated, joints placed."""
    if name == "bundled":
        from smartjoint.pipeline import _structure_stage  # the run's own structure stage

        return _structure_stage(None, Path(tempfile.mkdtemp()), lambda line: None).design
    design = load_design(str(DATA / f"{name}.toml"))
    if design.updating is not None:
        design, _ = updated_design(design, lambda *a: None, lambda message: None)
    return design


def frequency_figures(design, cut: float, plots: Path | None) -> dict:
    """The side-by-side norms of one design (`comparison.compare_with_balanced_truncation`)."""
    start = time.perf_counter()
    fe = build_model(design, joints="released")
    modes = modal.solve_modes(fe, fe.n_dof)
    full = modal.modal_model(fe, modes)
    ours = control_study.design_model(design, lambda line: None)
    c = design.control
    first = modal.Modes(
        modes.omega[: c.considered_modes], modes.shapes[:, : c.considered_modes], modes.damping[: c.considered_modes]
    )
    paper = reduce(fe, first, min(c.modes, c.considered_modes), c.krylov).model
    nyquist = np.pi / c.sample_time
    result = comparison.compare_with_balanced_truncation(
        full, {"ours": ours, "paper": paper}, metrics.static_compliance(fe), float(first.omega[-1]), nyquist, cut,
        max_modes=fe.n_dof,
    )  # fmt: skip
    out = {
        "design": design.name,
        "dofs": fe.n_dof,
        "full_states": full.n_states,
        "order": ours.n_states,
        "band_hz": result.band_hz,
        "nyquist_hz": result.nyquist_hz,
        "bt_modes_given": result.balanced_modes,
        "comparison_seconds": result.seconds,
        "corrections_hz": {
            "paper": (paper.omega[c.modes :] / (2 * np.pi)).tolist(),
            "ours": (ours.omega[c.modes :] / (2 * np.pi)).tolist(),
        },
        "static_compliance_error": result.static_compliance_error,
    }
    for label in ("band", "nyquist"):
        for path in comparison.PATHS:
            out[f"{path}_{label}"] = result.norms[label][path]
    if plots is not None:
        _bode(result, paper, design.name, plots / f"reduction_bode_{design.name}.png")
    out["seconds"] = time.perf_counter() - start
    return out


def _bode(result, paper, name, path) -> None:
    """|G_uv| (largest singular value) of full, ours, the paper's corrections and BT to Nyquist."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    f = result.grid / (2 * np.pi)
    for key, label, style in (
        ("full", "full", "k-"),
        ("paper", "Eq. 26 corrections (paper)", "C3--"),
        ("ours", "quasi-static corrections (ours)", "C0-"),
        ("bt", "balanced truncation", "C2:"),
    ):
        ax.semilogy(f, result.gains[key], style, lw=1, label=label)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("σ_max of u_R → v [m/(N·s)]")
    ax.set_title(f"{name}: u_R → v to the Nyquist frequency, {result.order} states")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def friction_figures(design) -> dict:
    """Fig. 10: 60 modes + 2 Krylov vectors for the active joint under the pulse, the paper's
    corrections and the quasi-static ones, friction RMS error against the full model."""
    forces = study.load_case(design)
    active = int(np.argmax(forces))
    fe, full, first, _, _ = study._full_model(
        design, 100, lambda line: None, None, study.correction_frequency(design.control.sample_time)
    )
    simulate = study._pulse_simulation(design, forces, 0.5, 5e-5)
    reference = simulate(full)
    out = {}
    for label, frequency in (("paper", None), ("ours", study.correction_frequency(design.control.sample_time))):
        model = reduce(fe, first, 60, 2, krylov_joints=[active], correction_frequency=frequency).model
        result = simulate(model)
        out[label] = study._friction_rms_errors(result.friction_force[:, active], reference, active, 0.5)
    return out


SENSITIVITY_MULTIPLES = (1.0, 2.0, 4.0, 8.0, 16.0)  # ω_q / Nyquist
SENSITIVITY_DAMPING = (0.5, 0.7, 1.0, 2.0)  # ξ of the quasi-static coordinates


def sensitivity_figures(design) -> list[dict]:
    """Fig. 10's friction RMS error (60 modes + 2 Krylov vectors, active joint) with the corrections
    quasi-static at each of ``SENSITIVITY_MULTIPLES`` × Nyquist and each ξ of
    ``SENSITIVITY_DAMPING``: how much of a 0–50 ms figure is the choice of ω_q and ξ."""
    forces = study.load_case(design)
    active = int(np.argmax(forces))
    nyquist = np.pi / design.control.sample_time
    fe, full, first, _, _ = study._full_model(design, 100, lambda line: None, None, 4.0 * nyquist)
    simulate = study._pulse_simulation(design, forces, 0.5, 5e-5)
    reference = simulate(full)
    paper = reduce(fe, first, 60, 2, krylov_joints=[active]).model
    rows = []
    for multiple in SENSITIVITY_MULTIPLES:
        for damping in SENSITIVITY_DAMPING:
            model = quasi_static_corrections(paper, multiple * nyquist, damping)
            result = simulate(model)
            errors = study._friction_rms_errors(result.friction_force[:, active], reference, active, 0.5)
            rows.append({"nyquist_multiple": multiple, "damping": damping, "friction_rms_error": errors})
            print(
                f"  ω_q {multiple:g}× Nyquist, ξ {damping:g}: 0–50 ms {100 * errors['0.05']:.2f} %, "
                f"0–0.5 s {100 * errors['0.5']:.2f} %",
                flush=True,
            )
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--designs", nargs="+", default=["bundled", "fig10_three_joints", "three_type_a"])
    parser.add_argument("--cut", type=float, default=4.0, help="BT is given the modes below cut × Nyquist")
    parser.add_argument("--json", default=str(Path(__file__).with_name("reduction.json")))
    parser.add_argument("--plots", default=str(Path(__file__).parent))
    parser.add_argument("--no-friction", action="store_true", help="skip the Fig. 10 simulations")
    parser.add_argument(
        "--sensitivity", action="store_true", help="Fig. 10 only, for several ω_q and ξ of the quasi-static corrections"
    )
    args = parser.parse_args()
    results = []
    if args.sensitivity:
        for name in args.designs:
            print(f"{name}: Fig. 10 friction RMS error against ω_q and ξ of the quasi-static corrections", flush=True)
            results.append({"name": name, "sensitivity": sensitivity_figures(load(name))})
        path = Path(args.json).with_name("reduction_sensitivity.json")
        write_json(str(path), {"benchmark": "reduction sensitivity", "machine": python_machine(), "results": results})
        return 0
    for name in args.designs:
        design = load(name)
        figures = frequency_figures(design, args.cut, Path(args.plots))
        if not args.no_friction:
            figures["friction_rms_error"] = friction_figures(design)
        figures["name"] = name
        results.append(figures)
        u, b = figures["uv_nyquist"], figures["uv_band"]
        s = figures["static_compliance_error"]
        print(
            f"{name}: {figures['order']} states; u→v H∞ to {figures['nyquist_hz']:.0f} Hz ours {u['ours']['hinf']:.4g} "
            f"= {u['ours']['hinf'] / u['bt']['hinf']:.2f}× BT {u['bt']['hinf']:.4g} (paper's corrections "
            f"{u['paper']['hinf'] / u['bt']['hinf']:.1f}×; BT's cut alone {u['cut_alone']['hinf']:.2g}); in band "
            f"0–{figures['band_hz']:.0f} Hz {b['ours']['hinf'] / b['bt']['hinf']:.2f}× BT (H2 "
            f"{b['ours']['h2'] / b['bt']['h2']:.2f}×); static compliance {s['ours']:.2g} vs BT {s['bt']:.2g} "
            f"({s['ours'] / s['bt']:.1e}×)"
            + (
                "; Fig. 10 friction RMS 0–50 ms / 0–0.5 s: "
                + ", ".join(
                    f"{k} {100 * v['0.05']:.2f} % / {100 * v['0.5']:.2f} %"
                    for k, v in figures["friction_rms_error"].items()
                )
                if "friction_rms_error" in figures
                else ""
            ),
            flush=True,
        )
        write_json(args.json, {"benchmark": "reduction", "cut": args.cut, "results": results})
    write_json(args.json, {"benchmark": "reduction", "cut": args.cut, "machine": python_machine(), "results": results})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
