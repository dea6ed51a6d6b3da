"""LuGre friction step: cost per step and largest stable step, exact-exponential vs explicit Euler.

Joint: paper Table 1, type A, F_N = 400 N (σ0·F_N ≈ 5.7·10⁷ N/m). The velocity history is
the sliding velocity of the isolated rig in stick-slip (rig.simulate), resampled at each
step size. A step size counts as stable when the bristle deflection stays within
1.01·φ_max and finite over the whole history. Baseline, run side by side: explicit Euler on
Eq. 1 (φ += h·f(v, φ)), the naive integrator.

    python benchmarks/lugre_step.py [--json benchmarks/lugre_step.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import timeit
from pathlib import Path

import numpy as np

from smartjoint.design.friction import lugre, rig

P = lugre.TYPE_A
NORMAL_FORCE = 400.0


def euler(p, phi, v, dt):
    return phi + dt * lugre.rhs(p, v, phi)


def stable(stepper, history_t, history_v, dt) -> bool:
    t = np.arange(0.0, history_t[-1], dt)
    v = np.interp(t + 0.5 * dt, history_t, history_v)
    phi = 0.0
    limit = 1.01 * P.max_deflection
    with np.errstate(all="ignore"):
        for value in v:
            phi = stepper(P, phi, value, dt)
            if not abs(phi) <= limit:
                return False
    return True


def largest_stable(stepper, history_t, history_v, low=1e-8, high=1e-1) -> float:
    if stable(stepper, history_t, history_v, high):
        return high
    for _ in range(30):  # bisection in log scale
        middle = np.sqrt(low * high)
        if stable(stepper, history_t, history_v, middle):
            low = middle
        else:
            high = middle
    return low


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=str(Path(__file__).with_name("lugre_step.json")))
    args = parser.parse_args()
    record = rig.simulate(rig.RigTest("A", NORMAL_FORCE, 1.1 * rig.breakaway(P, NORMAL_FORCE), 5.0, cycles=0.5))
    t, v = record.time, record.sliding_velocity
    exact_h = largest_stable(lugre.step, t, v)
    euler_h = largest_stable(euler, t, v)
    peak_rate = P.sigma0 * float(np.max(lugre.g(P, v)))
    print(f"type A, F_N = {NORMAL_FORCE:g} N, stick-slip history with |v| up to {np.abs(v).max():.3g} m/s")
    print(
        f"largest stable step: exact-exponential ≥ {exact_h:.3g} s (all tested), explicit Euler {euler_h:.3g} s "
        f"(theory 2/(σ0·g_max) = {2 / peak_rate:.3g} s) → ratio ≥ {exact_h / euler_h:.3g}"
    )
    rows = {}
    for joints in (3, 1000):
        phi = np.zeros(joints)
        velocity = np.linspace(-0.05, 0.05, joints)
        for name, stepper in (("exact", lugre.step), ("euler", euler)):
            count, total = timeit.Timer(lambda: stepper(P, phi, velocity, 1e-4)).autorange()
            rows[f"{name}_{joints}"] = total / count
        print(
            f"{joints:5d} joints per call: exact {rows[f'exact_{joints}'] * 1e6:8.2f} µs, "
            f"Euler {rows[f'euler_{joints}'] * 1e6:8.2f} µs per step → exact/Euler cost "
            f"{rows[f'exact_{joints}'] / rows[f'euler_{joints}']:.2f}"
        )
    print("per-step cost ratio is paid once; the step-size ratio above is what it buys")
    machine = {"python": platform.python_version(), "machine": platform.machine(), "cpus": os.cpu_count()}
    Path(args.json).write_text(
        json.dumps(
            {
                "benchmark": "lugre_step",
                "machine": machine,
                "largest_stable_step_s": {"exact": exact_h, "euler": euler_h},
                "seconds_per_call": rows,
            },
            indent=1,
        )
        + "\n"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
