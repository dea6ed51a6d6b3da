"""Closed-loop plant simulation speed: our fixed-step kernel vs scipy solve_ivp(LSODA), side by side.

Models (issue 4): the reference truss with three type A joints (design/data/three_type_a.toml,
nominal parameters, F_N = 400 N each, the paper's tip pulse 200 N / 40 ms in y and z):

* full  — the 600 lowest modes of the released truss (1200 states + 3 bristle states)
* 24    — the paper's 24-state model: 9 Hankel-selected modes of 100 + one Krylov vector per joint

Accuracy first, on the eventful first 0.2 s (friction force RMS error over all joints, relative to
the RMS of the most loaded joint): ours at the benchmark step, LSODA at the benchmark tolerance,
both against a tight reference (24: Radau rtol 1e-10; full: our scheme at step/8, which agrees
with Radau at second order, tests/test_simulate.py). Then speed over 10 s simulated time, trajectory only (as LSODA), and once more with the exact
per-step energy books.
LSODA gets a wall-clock budget; if it runs out, the ratio is reported as a lower bound.

Run: python benchmarks/plant_sim.py [--budget SECONDS]   (writes benchmarks/plant_sim.json)
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from smartjoint.design import fem, modal, reduction, simulate, spec
from smartjoint.studies import joint_laws

DESIGN = Path(__file__).resolve().parents[1] / "design" / "data" / "three_type_a.toml"
DURATION = 10.0
WINDOW = 0.2  # accuracy window [s]
STEP = 5e-5  # our plant step
RTOL = 1e-4  # LSODA tolerance with an accuracy comparable to ours (see the accuracy lines)
NORMAL_FORCE = 400.0


def friction_error(u, u_ref) -> float:
    return float(np.sqrt(np.mean((u - u_ref) ** 2, axis=0)).max() / np.sqrt(np.mean(u_ref**2, axis=0)).max())


def ours(model, laws, pulse, duration, step, record=1e-3, books=True):
    controller = simulate.ConstantNormalForce(np.full(len(laws), NORMAL_FORCE), 1e-3)
    every = int(round(record / step))
    start = time.perf_counter()
    result = simulate.simulate(model, laws, controller, pulse, duration, step, record_every=every, backend="c",
                                 energy_books=books)
    return result, time.perf_counter() - start


def lsoda(model, laws, pulse, duration, times, rtol, budget):
    """solve_ivp(LSODA, analytic Jacobian) in windows (restarts at the pulse kinks, then every
    0.5 s) until done or the wall-clock budget is spent. Returns (u at the times reached, seconds,
    simulated time reached)."""
    rhs, jac, ns, friction = simulate.reference_system(model, laws, np.full(len(laws), NORMAL_FORCE), pulse)
    edges = sorted({0.0, duration, *[e for e in (*pulse.breakpoints, *np.arange(0.5, duration, 0.5)) if e < duration]})
    z = np.zeros(ns + len(laws))
    out, reached = [], 0.0
    start = time.perf_counter()
    for a, b in zip(edges[:-1], edges[1:]):
        inside = times[(times >= a) & ((times < b) if b < duration else (times <= b))]
        sol = solve_ivp(rhs, (a, b), z, method="LSODA", jac=jac, rtol=rtol, atol=rtol * 1e-3, dense_output=True)
        if not sol.success:
            raise RuntimeError(f"LSODA failed: {sol.message}")
        out.append(friction(sol.sol(inside).T) if inside.size else np.zeros((0, len(laws))))
        z, reached = sol.y[:, -1], b
        if time.perf_counter() - start > budget:
            break
    return np.concatenate(out), time.perf_counter() - start, reached


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", type=float, default=600.0, help="LSODA wall-clock budget per model [s]")
    args = parser.parse_args()

    design = spec.load_design(DESIGN)
    fe = fem.build_model(design, joints="released")
    laws = joint_laws(design)
    pulse = simulate.triangular_pulse(directions=np.ones(len(design.disturbances)))
    models = {
        "full": modal.modal_model(fe, modal.solve_modes(fe, 600)),
        "24": reduction.reduce(fe, modal.solve_modes(fe, 100), 9, 1, krylov_joints=[0, 1, 2]).model,
    }
    window_times = np.arange(0.0, WINDOW + 1e-12, 1e-3)
    times = np.arange(0.0, DURATION + 1e-12, 1e-3)
    rows = {}
    for name, model in models.items():
        print(f"[{name}] {model.n_states} states, highest frequency {model.omega.max() / 2 / np.pi:.0f} Hz")
        # Accuracy on the first 0.2 s.
        if name == "24":
            _, u_ref, _ = simulate.reference_simulation(model, laws, np.full(3, NORMAL_FORCE), pulse, WINDOW,
                                                        window_times)
            reference = "Radau rtol 1e-10"
        else:
            fine, _ = ours(model, laws, pulse, WINDOW, STEP / 8)
            u_ref, reference = fine.friction_force, f"ours at {STEP / 8:g} s"
        short, _ = ours(model, laws, pulse, WINDOW, STEP)
        u_lsoda, _, _ = lsoda(model, laws, pulse, WINDOW, window_times, RTOL, float("inf"))
        error_ours, error_lsoda = friction_error(short.friction_force, u_ref), friction_error(u_lsoda, u_ref)
        print(f"  accuracy 0–{WINDOW} s vs {reference}: ours (step {STEP:g} s) {100 * error_ours:.2f} %, "
              f"LSODA (rtol {RTOL:g}) {100 * error_lsoda:.2f} %")
        # Speed over 10 s (ours: median of 3), trajectory only like LSODA; then with the exact energy books.
        seconds = sorted(ours(model, laws, pulse, DURATION, STEP, books=False)[1] for _ in range(3))[1]
        seconds_books = sorted(ours(model, laws, pulse, DURATION, STEP)[1] for _ in range(3))[1]
        _, lsoda_seconds, reached = lsoda(model, laws, pulse, DURATION, times, RTOL, args.budget)
        finished = bool(reached >= DURATION - 1e-9)
        ratio = lsoda_seconds / seconds
        print(f"  {DURATION:g} s simulated: ours {seconds:.3f} s ({DURATION / seconds:.0f}x real time), "
              f"LSODA {lsoda_seconds:.1f} s{'' if finished else f' for only {reached:g} s (budget spent)'} "
              f"→ ours {'≥ ' if not finished else ''}{ratio:.0f}x faster; with energy books {seconds_books:.3f} s "
              f"({DURATION / seconds_books:.0f}x real time)")
        rows[name] = dict(states=model.n_states, accuracy_reference=reference, friction_error_ours=error_ours,
                          friction_error_lsoda=error_lsoda, ours_seconds=seconds, real_time_factor=DURATION / seconds,
                          ours_seconds_with_books=seconds_books,
                          lsoda_seconds=lsoda_seconds, lsoda_simulated=reached, lsoda_finished=finished,
                          speedup=ratio, speedup_is_lower_bound=not finished)
    out = dict(command="python benchmarks/plant_sim.py", step=STEP, rtol=RTOL, duration=DURATION,
               normal_force=NORMAL_FORCE, machine=f"{platform.machine()}, {platform.python_version()}", models=rows)
    Path(__file__).with_suffix(".json").write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
