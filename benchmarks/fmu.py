"""The FMU co-simulation of the bundled study against the project's own loops (issue 21).

The bundled three type A design (updated to its EMA), its 4-s study: each semi-active law run
side by side as
  * the Python loop with the Python reference law (``run_semi_active``, the MIL study),
  * the compiled closed loop (``codegen.closed_loop``, one C call per run),
  * the plant FMU and the controller FMU (double build) in FMPy's ctypes API, FMI 2 and FMI 3
    (``bench.cosimulation``: load, instantiate, every sample's calls, free),
best of ``--repeats`` wall-clock runs each, with the check that every co-simulated number is the
MIL study's. Also the cost of writing each FMU (render, compile, pack).

    python benchmarks/fmu.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from machine import python_machine, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.bench.cosimulation import cosimulate
from smartjoint.codegen import closed_loop, fmu
from smartjoint.design import load_design, updated_design
from smartjoint.design.control import artifact_building
from smartjoint.design.control import study as closed_loop_study
from smartjoint.design.control.filter import clipped_lqg
from smartjoint.design.control.laws import siso_law
from smartjoint.design.control.runs import run_semi_active
from smartjoint.design.structure import spec

LAWS = {"SISO": "siso", "cLQG": "clqg"}


def best(action, repeats: int) -> tuple[float, object]:
    """The shortest wall-clock time of ``repeats`` calls and the last result."""
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = action()
        times.append(time.perf_counter() - start)
    return min(times), result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", default=str(Path(__file__).with_name("fmu.json")))
    args = parser.parse_args()
    design, _ = updated_design(load_design(spec.REFERENCE_DESIGN.parent / "three_type_a.toml"))
    study = closed_loop_study.run_study(design, progress=lambda message: None)
    s = study.setup
    artifact = artifact_building.from_design(design, s.model, study.lqg, study.settings())
    references = {"SISO": siso_law(artifact), "cLQG": clipped_lqg(artifact)}  # the MIL laws
    compiled = closed_loop.CompiledLoop(artifact)
    results: dict = {"benchmark": "fmu", "machine": python_machine(), "samples": s.samples, "laws": {}, "writing": {}}
    with tempfile.TemporaryDirectory(prefix="smartjoint-bench-fmu-") as scratch:
        folder = Path(scratch)
        plants = {}
        for version in fmu.VERSIONS:
            seconds, written = best(lambda v=version: fmu.plant_fmu(s, design, folder / f"truss{v}.fmu", v), 1)
            plants[version] = written.path
            results["writing"][f"plant_fmi{version}"] = {"seconds": seconds, "bytes": written.path.stat().st_size}
        print(
            f"{'law':6} {'Python loop':>12} {'compiled loop':>14} {'FMI 2 in FMPy':>14} {'FMI 3 in FMPy':>14}",
            "identical",
        )
        for name, law in LAWS.items():
            python_seconds, mil = best(lambda n=name: run_semi_active(s, n, references[n]), args.repeats)
            compiled_seconds, _ = best(lambda n=name: compiled.run(s, n), args.repeats)
            row = {"python_loop_s": python_seconds, "compiled_loop_s": compiled_seconds}
            identical = True
            for version in fmu.VERSIONS:
                path = folder / f"{law}{version}.fmu"
                seconds, written = best(lambda p=path, v=version, lw=law: fmu.controller_fmu(artifact, lw, p, v), 1)
                results["writing"][f"{law}_fmi{version}"] = {"seconds": seconds, "bytes": path.stat().st_size}
                cosim_seconds, (run, _) = best(
                    lambda p=path, v=version, n=name: cosimulate(s, plants[v], p, n), args.repeats
                )
                identical &= all(
                    np.array_equal(getattr(run, f), getattr(mil, f))
                    for f in ("energy", "sensors", "normal_force", "joint_force", "sliding_velocity")
                )
                row[f"fmi{version}_cosimulation_s"] = cosim_seconds
                row[f"fmi{version}_per_sample_us"] = 1e6 * cosim_seconds / s.samples
            row["identical_to_mil"] = identical
            row["fmi2_over_python_loop"] = row["fmi2_cosimulation_s"] / python_seconds
            row["fmi2_over_compiled_loop"] = row["fmi2_cosimulation_s"] / compiled_seconds
            results["laws"][name] = row
            print(
                f"{name:6} {python_seconds:11.3f}s {compiled_seconds:13.3f}s {row['fmi2_cosimulation_s']:13.3f}s "
                f"{row['fmi3_cosimulation_s']:13.3f}s  {identical}"
            )
    write_json(args.json, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
