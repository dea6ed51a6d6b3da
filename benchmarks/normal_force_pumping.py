"""Energy a semi-active law pumps into the structure through the friction model (issue 33's finding).

The paper's premise is that a semi-active joint can only dissipate. The plant's joints follow
LuGre with the friction force proportional to the normal force, u_R = F_N·(σ0·z + σ1·ż + σ2·v):
raising F_N while a stuck joint's bristles are deflected raises u_R at once, with no work done
by the structure, and the bristles give that energy back to the structure as they relax. A
law that switches F_N at every sample in step with the joint's motion (the paper's SISO law at a
boundary layer ε that makes it a relay, with F_N^min raised towards F_N^max) can therefore drive
the structure. The plant's energy books measure it exactly: e(t) − e(0) = W_in − W_joints −
W_damping, W_joints = ∫ u_Rᵀv dt (design/plant/loop.py), so W_joints < 0 is energy the joints
gave the structure.

One SISO run of the study per (ε, F_N^min) with the books kept; prints e after the pulse, its
largest value, e(t_e), W_joints and the balance's error, writes
``benchmarks/normal_force_pumping.json`` and the plot ``benchmarks/normal_force_pumping.png``.

    python benchmarks/normal_force_pumping.py [DESIGN] [--settings 1e-6:10 1e-6:200 1e-2:200]
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
from machine import python_machine, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.common import package_data
from smartjoint.design.control import runs, siso_tuning, study
from smartjoint.design.control.runs import PULSE_DURATION
from smartjoint.design.structure.spec import load_design

HERE = Path(__file__).resolve().parent
DESIGN = package_data.path("smartjoint.design", "data/mast_30bay_twelve_a.toml")


def books(setup, boundary_layer: float, floor: float):
    """The SISO run at ε = ``boundary_layer`` and F_N^min = ``floor`` with its energy books."""
    floors = np.full_like(setup.normal_force_min, floor)
    law = siso_tuning.siso(dataclasses.replace(setup, normal_force_min=floors), boundary_layer)
    return runs.simulate_semi_active(setup, law, energy_books=True)


def figures(r) -> dict:
    """e after the pulse, its largest value and e(t_e); the three works and the balance's error."""
    after = int(np.searchsorted(r.time, PULSE_DURATION + 0.01))
    power = np.sum(r.friction_force * r.sliding_velocity, axis=1)[after:]
    return {
        "energy_after_pulse_J": float(r.energy[after]),
        "energy_largest_J": float(r.energy[after:].max()),
        "energy_end_J": float(r.energy[-1]),
        "work_in_J": float(r.work_in[-1]),
        "work_joints_J": float(r.work_joints[-1]),
        "work_damping_J": float(r.work_damping[-1]),
        "balance_error_J": float(np.max(np.abs(r.balance_error()))),
        "samples_joints_driving": float(np.mean(power < 0.0)),
    }


def _plot(results: list, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7.0, 5.0), sharex=True)
    for (epsilon, floor), r in results:
        label = f"SISO ε = {epsilon:g} m/s, F_N^min = {floor:g} N"
        top.semilogy(r.time, r.energy, label=label)
        bottom.plot(r.time, -np.asarray(r.work_joints), label=label)
    top.set_ylabel("e(t) [J]")
    top.legend(fontsize=7)
    bottom.axhline(0.0, color="k", linewidth=0.5)
    bottom.set_ylabel("−W_joints [J] (> 0: joints drove)")
    bottom.set_xlabel("t [s]")
    top.set_title("Energy the joints give the structure under normal-force switching", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("design", nargs="?", default=str(DESIGN))
    parser.add_argument("--settings", nargs="+", default=["1e-6:10", "1e-6:200", "1e-2:200"], help="ε:F_N^min")
    args = parser.parse_args()
    design = load_design(args.design)
    setup = runs.setup(design, study.design_model(design, progress=lambda line: None))
    results, rows = [], []
    for text in args.settings:
        epsilon, floor = (float(x) for x in text.split(":"))
        r = books(setup, epsilon, floor)
        row = {"boundary_layer": epsilon, "normal_force_min": floor, **figures(r)}
        print(
            f"ε = {epsilon:g} m/s, F_N^min = {floor:g} N: e {row['energy_after_pulse_J']:.3f} J after the pulse, "
            f"largest {row['energy_largest_J']:.3f} J, e(t_e) {row['energy_end_J']:.3f} J; W_joints "
            f"{row['work_joints_J']:+.3f} J, W_damping {row['work_damping_J']:.3f} J, W_in {row['work_in_J']:.3f} J "
            f"(balance error {row['balance_error_J']:.1e} J); joints driving the structure in "
            f"{100 * row['samples_joints_driving']:.1f} % of the samples"
        )
        results.append(((epsilon, floor), r))
        rows.append(row)
    _plot(results, HERE / "normal_force_pumping.png")
    write_json(
        HERE / "normal_force_pumping.json",
        {
            "machine": python_machine(),
            "command": "python benchmarks/normal_force_pumping.py",
            "design": Path(args.design).name,
            "runs": rows,
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
