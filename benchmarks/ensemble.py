"""Robustness ensemble of the bundled study on Dask: throughput and 1 → 2 worker scaling (issue 20).

The sweep: the bundled three type A design (updated to its EMA), SISO and cLQG over the study's
4 s, each joint's five LuGre parameters ±5 % (uniform), modal frequencies ±1 % and modal damping
around 0.1 % (lognormal), the tip pulse ±10 %, Latin hypercube. The semi-active laws run in the
compiled closed loop (``codegen.closed_loop``). Prints samples per core-second and the share of
the workers' time spent outside the simulations (Dask's task stream); the scaling leg runs the
same smaller sweep on one and on two workers side by side and gives the speed-up.

    python benchmarks/ensemble.py [--samples 10000] [--scaling-samples 400] [--batch 50]
"""

from __future__ import annotations

import argparse
import io
import tempfile
import time
from pathlib import Path

import pyarrow.parquet as pq
from machine import python_machine, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.bench.sweep import read_results, run_sweep
from smartjoint.common import package_data
from smartjoint.design.control.sweep_file import load_sweep

SWEEP = """\
schema = "smartjoint-sweep/1"
design = "{design}"
laws = ["SISO", "cLQG"]
samples = {samples}
seed = 2026
sampler = "latin-hypercube"
batch = {batch}
study_duration = 4.0

[uncertain]
modal_frequency_scale = {{ distribution = "uniform", low = 0.99, high = 1.01 }}
modal_damping = {{ distribution = "lognormal", median = 0.001, sigma = 0.3, high = 0.005 }}
pulse_amplitude = {{ distribution = "uniform", low = 180.0, high = 220.0 }}

[uncertain.friction]
sigma0 = {{ distribution = "uniform", low = 0.95, high = 1.05 }}
sigma1 = {{ distribution = "uniform", low = 0.95, high = 1.05 }}
coulomb = {{ distribution = "uniform", low = 0.95, high = 1.05 }}
stribeck = {{ distribution = "uniform", low = 0.95, high = 1.05 }}
stribeck_velocity = {{ distribution = "uniform", low = 0.95, high = 1.05 }}

[grid]
siso_boundary_layer = [3.16e-6]
"""


def _sweep(folder: Path, samples: int, batch: int):
    path = folder / f"sweep-{samples}.toml"
    design = package_data.path("smartjoint.design", "data/three_type_a.toml")
    path.write_text(SWEEP.format(design=design, samples=samples, batch=batch))
    return load_sweep(path)


def _parquet_bytes(table) -> bytes:
    """The table as Parquet bytes (``Table.equals`` holds NaN unequal to itself)."""
    buffer = io.BytesIO()
    pq.write_table(table, buffer)
    return buffer.getvalue()


def _run(folder: Path, samples: int, batch: int, workers: int) -> dict:
    started = time.perf_counter()
    out = run_sweep(
        _sweep(folder, samples, batch), folder / f"out-{samples}-{workers}", workers=workers, progress=lambda line: None
    )
    out["wall_seconds_with_preparation"] = time.perf_counter() - started
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--scaling-samples", type=int, default=400)
    parser.add_argument("--batch", type=int, default=50)
    parser.add_argument("--json", default=str(Path(__file__).with_name("ensemble.json")))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as temporary:
        folder = Path(temporary)
        one = _run(folder, args.scaling_samples, args.batch, 1)
        two = _run(folder, args.scaling_samples, args.batch, 2)
        same = _parquet_bytes(read_results(one["output"])) == _parquet_bytes(read_results(two["output"]))
        speedup = one["seconds"] / two["seconds"]
        print(
            f"scaling, {args.scaling_samples} samples: 1 worker {one['seconds']:.1f} s, 2 workers "
            f"{two['seconds']:.1f} s — speed-up {speedup:.2f}× (target ≥ 1.8); tables identical: {same}"
        )
        big = _run(folder, args.samples, args.batch, 2)
        print(
            f"throughput, {args.samples} samples × 2 laws × 4 s on 2 workers: {big['seconds']:.0f} s "
            f"({big['wall_seconds_with_preparation']:.0f} s with the design's updating and the build; target ≤ 900 s), "
            f"{big['samples_per_core_second']:.2f} samples per core-second, outside the simulation "
            f"{100 * big['outside_share']:.1f} % (target ≤ 5 %)"
        )
    for out in (one, two, big):
        out.pop("output")
    write_json(
        args.json,
        {
            "benchmark": "ensemble",
            "machine": python_machine(),
            "command": "python benchmarks/ensemble.py",
            "scaling": {"one_worker": one, "two_workers": two, "speedup": speedup, "tables_identical": same},
            "throughput": big,
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
