"""What the bus's resolution of the inputs does to the laws in the model in the loop (issue 33).

The SIL row of the SISO law lies outside its band (docs/can.md): +18.0 % in E(t_e) in double against
a band of +0.8 … +3.8 % drawn by perturbing the commands at float rounding. This script runs the
Python reference of each law with its inputs rounded as the bus carries them (the scalings of the
artefact's ``JOINT_<j>`` and ``TIP_SENSORS`` signals, ``protocol.database``), then with only the
sliding velocity rounded, to steps from 1e-12 to 1e-8 m/s. Each row is the median over the
unperturbed run and ``--runs`` runs with the commands perturbed at float rounding (6e-8), so a
systematic shift stands apart from the chaos. Written to ``benchmarks/velocity_resolution.json``.

    python benchmarks/velocity_resolution.py [--artifact firmware/generated/controller.json] [--runs 3]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from machine import artifact_header, cpu_model, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.bench import bus_rounding, rounding_spread
from smartjoint.commands import load_updated
from smartjoint.common import law_registry
from smartjoint.design.control import artifact as artifacts
from smartjoint.design.control import study as closed_loop
from smartjoint.design.network import protocol

ROOT = Path(__file__).resolve().parents[1]
VELOCITY_STEPS = (1e-12, 1e-11, 1e-10, 1e-9, 1e-8)  # [m/s]; the bus carries 1e-9


def _steps(a, velocity: float, friction: float, normal: float, sensors: float) -> bus_rounding.InputSteps:
    """The same step for every joint (and every sensor), no range (0: as measured)."""
    joints = lambda step: ((step, -np.inf, np.inf),) * len(a.joint_names)  # noqa: E731
    return bus_rounding.InputSteps(
        joints(velocity), joints(friction), joints(normal), ((sensors, -np.inf, np.inf),) * len(a.sensor_names)
    )


def _energy(run) -> float:
    return float(np.trapezoid(2.0 * run.energy, run.time))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifact", default=str(ROOT / "firmware" / "generated" / "controller.json"))
    parser.add_argument("--design", default=str(ROOT / "design" / "data" / "three_type_a.toml"))
    parser.add_argument("--runs", type=int, default=3, help="perturbed runs per row besides the unperturbed one")
    parser.add_argument("--json", default=str(Path(__file__).with_name("velocity_resolution.json")))
    args = parser.parse_args()
    started = time.perf_counter()
    a = artifacts.load(args.artifact)
    design, _ = load_updated(SimpleNamespace(design=args.design, no_update=False), firmware_names=True, friction=True)
    setup = closed_loop.setup(design, closed_loop.design_model(design, lambda message: None))
    db = protocol.database(a)
    joint = db.get_message_by_name(f"JOINT_{a.joint_names[0].upper()}")
    scale = {s.name: float(s.scale) for s in joint.signals}
    sensors = float(db.get_message_by_name("TIP_SENSORS").signals[-1].scale)
    bus = (scale["sliding_velocity"], scale["friction_force"], scale["normal_force"], sensors)
    print(f"the bus's steps: v {bus[0]:g} m/s, u_R {bus[1]:g} N, F_N {bus[2]:g} N, y {bus[3]:g}")
    rows = {}
    for law in ("siso", "clqg"):
        reference = law_registry.LAWS[law].python_reference

        def median(steps):
            make = lambda: bus_rounding.Rounded(reference(a), _steps(a, *steps))  # noqa: E731
            runs = [_energy(closed_loop.run_semi_active(setup, law, make()))]
            for seed in range(args.runs):
                perturbed = rounding_spread.perturbed(make(), 6e-8, seed)
                runs.append(_energy(closed_loop.run_semi_active(setup, law, perturbed)))
            return float(np.median(runs)), runs

        base, base_runs = median((0.0, 0.0, 0.0, 0.0))
        rows[law] = {"as_measured": {"median": base, "runs": base_runs}}
        print(f"{law}: as measured E = {base:.5f} (runs {', '.join(f'{r:.5f}' for r in base_runs)})")
        cases = [("the bus's steps", bus)] + [(f"v step {v:g} m/s only", (v, 0.0, 0.0, 0.0)) for v in VELOCITY_STEPS]
        for label, steps in cases:
            value, runs = median(steps)
            rows[law][label] = {"steps": steps, "median": value, "runs": runs, "relative": value / base - 1.0}
            shown = ", ".join(f"{r:.5f}" for r in runs)
            print(f"{law}: {label}: E = {value:.5f}, {value / base - 1.0:+.2%} (runs {shown})")
    write_json(
        args.json,
        {
            **artifact_header("velocity_resolution", {"cpu": cpu_model()}, args.artifact, a),
            "design": args.design,
            "perturbed_runs": args.runs,
            "bus_steps": dict(zip(("sliding_velocity", "friction_force", "normal_force", "sensors"), bus)),
            "laws": rows,
            "seconds": time.perf_counter() - started,
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
