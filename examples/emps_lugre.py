"""LuGre on real measured friction: the EMPS positioning axis (../shared/data/emps).

The EMPS benchmark axis runs in closed loop; its measured position q_m and motor force
F = g_tau·v_ir are given at 1 kHz. Inverse model with known-form rigid body (mass M and an
offset identified too) and the friction of the axis (F_N = 1, so F_c, F_d come out in N):

    F(t) = M·a(t) + u_R(v(t), φ) + offset            (LuGre, Eq. 1–2 with F_N = 1)
    F(t) = M·a(t) + F_v·v + F_c·sign(v) + offset      (Coulomb + viscous baseline, linear LSQ)

v and a come from the measured position by a zero-phase low-pass (Butterworth, 4th order,
``CUTOFF_HZ``) and central differences, as the benchmark description does. The LuGre state
is simulated from the measured velocity with the exact-exponential step (equation error,
Eq. 3). Both models are judged by the force NRMSE on the same record.

Run:  python examples/emps_lugre.py [path/to/DATA_EMPS.mat] [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
import scipy.io
import scipy.optimize
from scipy.signal import butter, sosfiltfilt

from smartjoint.design.friction import lugre
from smartjoint.design.friction.equation_error import simulate_friction
from smartjoint.design.friction.fitting import nrmse

DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "data" / "emps" / "DATA_EMPS.mat"
CUTOFF_HZ = 100.0  # the benchmark's parameters (M ≈ 95 kg, Fv ≈ 204, Fc ≈ 20.3) come out from 50 Hz up


def load(path: Path):
    data = scipy.io.loadmat(path)
    t = data["t"].ravel()
    position = data["qm"].ravel()
    force = float(data["gtau"].ravel()[0]) * data["vir"].ravel()
    dt = float(np.median(np.diff(t)))
    sos = butter(4, CUTOFF_HZ, fs=1.0 / dt, output="sos")
    smooth = sosfiltfilt(sos, position)
    velocity = np.gradient(smooth, dt)
    acceleration = np.gradient(velocity, dt)
    return t, force, velocity, acceleration


def coulomb_viscous(force, velocity, acceleration):
    regressors = np.column_stack([acceleration, velocity, np.sign(velocity), np.ones_like(velocity)])
    coefficients, *_ = np.linalg.lstsq(regressors, force, rcond=None)
    model = regressors @ coefficients
    return dict(zip(("mass", "viscous", "coulomb", "offset"), coefficients.tolist())), model


def initial_guess(baseline: dict) -> dict:
    """LuGre start from the Coulomb + viscous fit: stiff bristles, a modest Stribeck bump."""
    coulomb = max(baseline["coulomb"], 1.0)
    return {
        "sigma0": 1e6,
        "sigma1": 1e3,
        "sigma2": max(baseline["viscous"], 1.0),
        "coulomb": coulomb,
        "stribeck": 0.2 * coulomb,
        "stribeck_velocity": 0.01,
    }


def lugre_fit(t, force, velocity, acceleration, start, max_nfev: int = 300):
    """Nonlinear least squares over [σ0, σ1, σ2, F_c, F_d, v_s] (log) plus M and offset (linear),
    at most ``max_nfev`` evaluations of the residual."""
    names = ("sigma0", "sigma1", "sigma2", "coulomb", "stribeck", "stribeck_velocity")
    normal = np.ones_like(t)

    def split(theta):
        return lugre.LuGreParameters(**{n: math.exp(x) for n, x in zip(names, theta)})

    def solve_linear(p):
        friction = simulate_friction(p, t, velocity, normal, 0.0)
        regressors = np.column_stack([acceleration, np.ones_like(t)])
        coefficients, *_ = np.linalg.lstsq(regressors, force - friction, rcond=None)
        return friction + regressors @ coefficients, coefficients

    def residual(theta):
        model, _ = solve_linear(split(theta))
        return (model - force) / np.sqrt(np.mean(force**2))

    theta0 = np.log([start[n] for n in names])
    solution = scipy.optimize.least_squares(
        residual, theta0, bounds=(theta0 - 7.0, theta0 + 7.0), diff_step=1e-6, max_nfev=max_nfev
    )
    p = split(solution.x)
    model, (mass, offset) = solve_linear(p)
    return p, float(mass), float(offset), model


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mat", nargs="?", default=str(DEFAULT))
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    t, force, velocity, acceleration = load(Path(args.mat))
    baseline, baseline_model = coulomb_viscous(force, velocity, acceleration)
    p, mass, offset, model = lugre_fit(t, force, velocity, acceleration, initial_guess(baseline))
    result = {
        "samples": int(t.size),
        "coulomb_viscous": {**baseline, "nrmse": nrmse(force, baseline_model)},
        "lugre": {
            "sigma0": p.sigma0,
            "sigma1": p.sigma1,
            "sigma2": p.sigma2,
            "coulomb": p.coulomb,
            "stribeck": p.stribeck,
            "stribeck_velocity": p.stribeck_velocity,
            "mass": mass,
            "offset": offset,
            "nrmse": nrmse(force, model),
        },
    }
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        b, lg = result["coulomb_viscous"], result["lugre"]
        print(f"EMPS estimation record, {t.size} samples")
        print(
            f"Coulomb + viscous: M = {b['mass']:.2f} kg, Fv = {b['viscous']:.1f} N·s/m, Fc = {b['coulomb']:.2f} N, "
            f"offset = {b['offset']:.2f} N  →  force NRMSE {b['nrmse']:.4f}"
        )
        print(
            f"LuGre (F_N = 1):   M = {lg['mass']:.2f} kg, σ0 = {lg['sigma0']:.3g} N/m, σ1 = {lg['sigma1']:.3g}, "
            f"σ2 = {lg['sigma2']:.1f}, Fc = {lg['coulomb']:.2f} N, Fd = {lg['stribeck']:.2f} N, "
            f"vs = {lg['stribeck_velocity']:.3g} m/s, offset = {lg['offset']:.2f} N  →  force NRMSE {lg['nrmse']:.4f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
