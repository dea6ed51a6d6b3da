"""Step cost of the generated controllers on x86-64 (double build, -O2): time, instructions, Python.

Inputs: ROWS random rows at recorded-like scales (tip sensors ~1 mm, sliding velocities
~1 mm/s, friction forces ~50 N, applied normal forces in [10, 400] N; no NaN/Inf, so every
step takes the normal path), seeded. The artefact is firmware/generated/controller.json
(``--artifact`` to change it).

- C step time: ``Controllers(a, "double").law("clqg").run(rows)`` and ``.law("siso").run(rows)``
  (the loop runs inside C; the figure includes the wrapper's copies in and out of the struct
  arrays), best of REPEATS, per step; also the bare batch loop (``lib.<prefix>_<law>_run`` on
  buffers filled once) to show what the copies cost.
- Instructions per step: the generated .c files + a bench main (written to a temporary folder,
  nothing committed) compiled with ``cc`` and ``codegen.build.FLAGS``, run under ``valgrind
  --tool=callgrind`` for two step counts; the inclusive Ir of ``<prefix>_<law>_step``
  (``callgrind_annotate --inclusive=yes``) differenced over ΔN, so start-up, file reading and
  the first (filter-not-started) step drop out. The whole program's ΔIr/ΔN is shown as well.
- Structural minimum: the multiply-adds a step cannot avoid, from the artefact sizes (n
  coordinates, l joints, n_y sensors); instructions per multiply-add (target ≤ 4 for the cLQG).
- Python reference: ``artifact.clipped_lqg(a).step`` / ``artifact.siso_law(a).step`` on the first
  PY_ROWS of the same inputs (Measurements built beforehand), best of 3; the first rows are
  checked to equal the C double build bit for bit (so the same computation is timed).

    python benchmarks/step_time.py [--artifact firmware/generated/controller.json] [--json benchmarks/step_time.json]
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from machine import artifact_header, cpu_model, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.codegen import build, controllers, generate, output
from smartjoint.common import law_registry
from smartjoint.design.control import artifact as artifacts
from smartjoint.design.control.ordered_sums import output_terms
from smartjoint.design.plant.interface import Measurements

ROOT = Path(__file__).resolve().parents[1]
ROWS = 200_000
REPEATS = 7
PY_ROWS = 5_000
CALLGRIND_STEPS = (20_000, 60_000)
PREFIX = "smartjoint"
INSTRUCTIONS_PER_MAC_TARGET = 3.5

BENCH_MAIN = r"""/* Step-count benchmark (benchmarks/step_time.py): argv = steps, SISO rows, cLQG rows (raw double
 * input structs). Reads both files whole, then runs `steps` steps of each law over the rows. */
#include <stdio.h>
#include <stdlib.h>

#include "PREFIX_clqg.h"
#include "PREFIX_siso.h"

static void *load(const char *path, size_t size, size_t *count)
{
    FILE *stream = fopen(path, "rb");
    void *data;
    long bytes;
    if (stream == NULL || fseek(stream, 0, SEEK_END) != 0 || (bytes = ftell(stream)) <= 0) {
        exit(2);
    }
    rewind(stream);
    *count = (size_t)bytes / size;
    data = malloc((size_t)bytes);
    if (data == NULL || fread(data, size, *count, stream) != *count) {
        exit(3);
    }
    fclose(stream);
    return data;
}

int main(int argc, char **argv)
{
    static PREFIX_siso_state siso_state;
    static PREFIX_clqg_state clqg_state;
    PREFIX_siso_output siso_output;
    PREFIX_clqg_output clqg_output;
    const PREFIX_siso_input *siso_rows;
    const PREFIX_clqg_input *clqg_rows;
    size_t siso_count, clqg_count;
    long steps, k;
    unsigned int status = 0u;
    double checksum = 0.0;
    if (argc != 4) {
        return 1;
    }
    steps = strtol(argv[1], NULL, 10);
    siso_rows = load(argv[2], sizeof *siso_rows, &siso_count);
    clqg_rows = load(argv[3], sizeof *clqg_rows, &clqg_count);
    PREFIX_siso_init(&siso_state, NULL);
    PREFIX_clqg_init(&clqg_state, NULL);
    for (k = 0; k < steps; ++k) {
        status |= PREFIX_siso_step(&siso_state, &siso_rows[(size_t)k % siso_count], &siso_output);
        checksum += siso_output.normal_force[0];
    }
    for (k = 0; k < steps; ++k) {
        status |= PREFIX_clqg_step(&clqg_state, &clqg_rows[(size_t)k % clqg_count], &clqg_output);
        checksum += clqg_output.normal_force[0];
    }
    printf("status %u checksum %.17g\n", status, checksum);
    return 0;
}
"""


def run(command: list[str], cwd: Path | None = None) -> subprocess.CompletedProcess:
    done = subprocess.run(command, cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"error: {' '.join(command)} failed:\n{done.stderr.strip()}")
    return done


def machine(compiler: str) -> dict:
    return {
        "platform": platform.platform(),
        "cpu": cpu_model(),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "compiler": run([compiler, "--version"]).stdout.splitlines()[0],
    }


def inputs(a, count: int, seed: int = 11):
    """Measurements-equivalent arrays: sensors (count, n_y), velocity, friction, normal force (count, l)."""
    rng = np.random.default_rng(seed)
    l, ny = len(a.joint_names), len(a.sensor_names)
    t = np.arange(count)[:, None] * a.sample_time
    sensors = 1e-3 * np.sin(2 * np.pi * 5.0 * t + np.arange(ny)) + rng.normal(0, 1e-4, (count, ny))
    velocity = 1e-3 * np.sin(2 * np.pi * 5.0 * t + np.arange(l)) + rng.normal(0, 1e-4, (count, l))
    friction = 50.0 * np.sign(velocity) + rng.normal(0, 5.0, (count, l))
    normal = rng.uniform(10.0, 400.0, (count, l))
    return sensors, velocity, friction, normal


def structural_macs(n: int, l: int, ny: int, output_nonzero: int) -> dict:
    """The multiply-adds a step needs, by phase: the output phase forms the command from the new
    measurement with the constant products KM·CΓ1E − KΓ1E and KM and the r = (K − KM·C)·q the
    last update left; the update phase forms the innovation and sums C·q over the nonzero entries
    of C only (the generated step skips its structural zeros, ``output_nonzero`` of n_y·2n).
    "counted": with every entry of C; "one phase": the minimum of the earlier single-phase step."""
    output_phase = {
        "(KM·CΓ1E − KΓ1E)·u_k (output phase)": l * l,
        "KM·y_k (output phase)": l * ny,
        "clipped law (e·sgn/ε, F^min + ΔF·r) (output phase)": 2 * l,
    }
    update_phase = {
        "ν = y − (C·q − CΓ1E·u_k)": ny * l,
        "u⁺ = u_R·F_N/F_applied": l,
        "E·u_k and E·u_k+": 2 * n * l,
        "γ1, γ0 terms": 4 * n,
        "M·ν": 2 * n * ny,
        "blocks Φ_i (2×2 per coordinate)": 4 * n,
        "C·q (nonzero entries of C)": output_nonzero,
        "(K − KM·C)·q": l * 2 * n,
    }
    clqg = {**output_phase, **update_phase}
    siso = {"μ = u_R/F_N, μ·v/ε, F^min + ΔF·r": 3 * l}
    return {
        "clqg": {
            "terms": clqg,
            "total": sum(clqg.values()),
            "output_phase": sum(output_phase.values()),
            "counted": sum(clqg.values()) - output_nonzero + ny * 2 * n,
            "one_phase": 4 * n + 2 * n * l + 4 * n + output_nonzero + 2 * n * ny + l * 2 * n + 3 * l,
            "formula": "(l² + l·n_y + 2l) + (n_y·l + l + 2·n·l + 4n + 2n·n_y + 4n + nnz(C) + l·2n)",
        },
        "siso": {"terms": siso, "total": sum(siso.values()), "formula": "3l"},
    }


def realised_macs(a) -> dict:
    """The multiply-adds the generated cLQG step does, counted from its generator context
    (``codegen.law_contexts.clqg``: the realisation's channels, coordinate groups and the nonzero
    terms of the constant products), by the same rules as :func:`structural_macs`: products
    only, the channels' sums and differences and the additions of C's unit entries not counted."""
    from smartjoint.codegen import law_contexts

    context = law_contexts.clqg(a, lambda value: "0", lambda values: "0")
    l = len(a.joint_names)
    output_phase = sum(len(t) for t in context["feedback_hold_terms"] + context["feedback_estimator_terms"]) + 2 * l
    update = l + sum(len(t) for t in context["output_hold_terms"])
    for g in context["groups"]:
        per_coordinate = (
            2 * len(g["joints"])  # E'_i over the group's channels, at u_k and u+
            + (1 if g["unit_gamma1"] else 2)  # Γ1
            + 2 * len(g["sensors"])  # M'
            + 6  # Φ_i and Γ0
            + sum(1 for t in g["output_terms"] if t[2] is not None)  # C' entries other than 1
            + 2 * len(g["feedback_joints"])  # (K' − K'M'C')
        )
        update += per_coordinate * (g["stop"] - g["start"])
    return {"total": output_phase + update, "output_phase": output_phase, "update_phase": update}


def best_time(action, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        action()
        best = min(best, time.perf_counter() - start)
    return best


def c_timing(c, rows: dict[str, np.ndarray]) -> dict:
    out = {}
    ffi, lib = c.ffi, c.lib
    for law in rows:  # issue 19's two laws: the preset has no step worth timing
        controller = c.law(law)
        data = rows[law]
        count = data.shape[0]

        def public():
            controller.reset()
            controller.run(data)

        wrapped = best_time(public, REPEATS)
        state = ffi.new(f"{PREFIX}_{law}_state *")
        in_buffer = ffi.new(f"{PREFIX}_{law}_input[]", count)
        out_buffer = ffi.new(f"{PREFIX}_{law}_output[]", count)
        status = ffi.new("unsigned int[]", count)
        np.frombuffer(ffi.buffer(in_buffer), dtype=np.float64).reshape(count, -1)[:] = data
        init, loop = getattr(lib, f"{PREFIX}_{law}_init"), getattr(lib, f"{PREFIX}_{law}_run")

        def bare():
            init(state, ffi.NULL)
            loop(state, in_buffer, out_buffer, status, count)

        out[law] = {
            "run_ns_per_step": wrapped / count * 1e9,
            "bare_loop_ns_per_step": best_time(bare, REPEATS) / count * 1e9,
        }
    return out


def python_timing(a, measurements: list[Measurements], c, rows: dict[str, np.ndarray]) -> dict:
    out = {}
    l = len(a.joint_names)
    for law in rows:
        reference = law_registry.law(law).python_reference(a)
        results: list[np.ndarray] = []

        def steps():
            reference.reset()
            results.clear()
            for m in measurements:
                results.append(reference.step(m))

        seconds = best_time(steps, 3)
        controller = c.law(law)
        outputs, _ = controller.run(rows[law][: len(measurements)])
        identical = np.asarray(results).tobytes() == np.ascontiguousarray(outputs[:, :l]).tobytes()
        if not identical:
            raise SystemExit(
                f"error: {law}: the C double build and the Python reference differ on these inputs — "
                "the timings would not compare the same computation"
            )
        out[law] = {"ns_per_step": seconds / len(measurements) * 1e9, "bit_identical_to_c": identical}
    return out


def callgrind(a, rows: dict[str, np.ndarray], compiler: str, folder: Path) -> dict:
    output.write(generate.render(a, "double", PREFIX), folder)
    (folder / "bench_main.c").write_text(BENCH_MAIN.replace("PREFIX", PREFIX))
    for law in ("siso", "clqg"):
        np.ascontiguousarray(rows[law][: max(CALLGRIND_STEPS)], dtype=np.float64).tofile(folder / f"{law}.bin")
    run(
        [compiler, *build.FLAGS, "-o", "bench", f"{PREFIX}_siso.c", f"{PREFIX}_clqg.c", "bench_main.c", "-lm"],
        cwd=folder,
    )
    counts = {}
    for steps in CALLGRIND_STEPS:
        out = folder / f"callgrind.{steps}"
        run(
            [
                "valgrind",
                "--tool=callgrind",
                f"--callgrind-out-file={out}",
                "./bench",
                str(steps),
                "siso.bin",
                "clqg.bin",
            ],
            cwd=folder,
        )
        text = run(["callgrind_annotate", "--inclusive=yes", "--threshold=100", str(out)]).stdout
        total = int(re.search(r"^\s*([\d,]+)\s.*PROGRAM TOTALS", text, re.M).group(1).replace(",", ""))
        counts[steps] = {"total": total}
        for law, function in (("siso", "siso_step"), ("clqg", "clqg_step"), ("clqg_output", "clqg_output_phase")):
            m = re.search(rf"^\s*([\d,]+)\s.*[\s:]{PREFIX}_{function}\b", text, re.M)
            if m is None:
                raise SystemExit(f"error: {PREFIX}_{function} not found in the callgrind_annotate output")
            counts[steps][law] = int(m.group(1).replace(",", ""))
    low, high = CALLGRIND_STEPS
    delta = high - low
    return {
        "steps": list(CALLGRIND_STEPS),
        "ir": {str(k): v for k, v in counts.items()},
        "siso_ir_per_step": (counts[high]["siso"] - counts[low]["siso"]) / delta,
        "clqg_ir_per_step": (counts[high]["clqg"] - counts[low]["clqg"]) / delta,
        "clqg_output_phase_ir_per_step": (counts[high]["clqg_output"] - counts[low]["clqg_output"]) / delta,
        "program_ir_per_step_both_laws": (counts[high]["total"] - counts[low]["total"]) / delta,
    }


def _check_tools() -> str:
    """valgrind and callgrind_annotate on PATH, and the C compiler ($CC, else cc), which it returns."""
    missing = [t for t in ("valgrind", "callgrind_annotate") if shutil.which(t) is None]
    if missing:
        raise SystemExit(
            f"error: {', '.join(missing)} not found on PATH — the instruction counts need valgrind "
            "(Debian/Ubuntu: apt-get install valgrind)"
        )
    compiler = os.environ.get("CC", "cc")
    if shutil.which(compiler) is None:
        raise SystemExit(f"error: C compiler {compiler!r} not found (set CC)")
    return compiler


def _print_table(timing: dict, counts: dict, macs: dict, python: dict) -> dict:
    """One line per law: C time per step, instructions per step and per multiply-add, Python
    time and the C speed-up; the last two per law as the summary."""
    header = (
        f"{'controller':12s} {'C run() [ns]':>12s} {'C bare loop [ns]':>16s} {'Ir/step':>8s} {'min MACs':>8s} "
        f"{'Ir/MAC':>6s} {'Python [µs]':>11s} {'C vs Python':>11s}"
    )
    print(header + "\n" + "-" * len(header))
    summary = {}
    for law, title in (("siso", "SISO"), ("clqg", "clipped LQG")):
        ir = counts[f"{law}_ir_per_step"]
        per_mac = ir / macs[law]["total"]
        speedup = python[law]["ns_per_step"] / timing[law]["run_ns_per_step"]
        summary[law] = {"instructions_per_mac": per_mac, "c_vs_python_speedup": speedup}
        print(
            f"{title:12s} {timing[law]['run_ns_per_step']:12.1f} {timing[law]['bare_loop_ns_per_step']:16.1f} "
            f"{ir:8.1f} {macs[law]['total']:8d} {per_mac:6.2f} {python[law]['ns_per_step'] / 1e3:11.2f} "
            f"{speedup:10.0f}×"
        )
    return summary


def _print_structural_minimum(macs: dict, n: int, l: int, ny: int) -> None:
    """The multiply-adds a step of each law needs at least, term by term."""
    print(f"\nstructural minimum per step (multiply-adds), n = {n}, l = {l}, n_y = {ny}:")
    for law, title in (("clqg", "cLQG"), ("siso", "SISO")):
        terms = " + ".join(f"{v}" for v in macs[law]["terms"].values())
        terms = f" = {terms}" if len(macs[law]["terms"]) > 1 else ""
        print(f"  {title}: {macs[law]['formula']}{terms} = {macs[law]['total']}")
        if "counted" in macs[law]:
            print(
                f"      (output phase {macs[law]['output_phase']}; with every entry of C: {macs[law]['counted']}; "
                f"the single-phase step needed {macs[law]['one_phase']})"
            )
        for name, value in macs[law]["terms"].items():
            print(f"      {value:4d}  {name}")


def _print_target(summary: dict, counts: dict) -> bool:
    """Whether the clipped LQG meets the instructions-per-multiply-add target, printed, with the
    output phase's share of the step (the instructions between the measurements and the command)."""
    met = summary["clqg"]["instructions_per_mac"] <= INSTRUCTIONS_PER_MAC_TARGET
    output, step = counts["clqg_output_phase_ir_per_step"], counts["clqg_ir_per_step"]
    summary["clqg"]["output_phase_share"] = output / step
    print(f"cLQG output phase: {output:.1f} of {step:.1f} Ir/step ({100 * output / step:.1f} %), update phase the rest")
    print(
        f"target: cLQG instructions per multiply-add ≤ {INSTRUCTIONS_PER_MAC_TARGET:g} at -O2 on x86-64 — "
        f"{summary['clqg']['instructions_per_mac']:.2f} {'✔' if met else '✘'}"
    )
    return met


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifact", default=str(ROOT / "firmware" / "generated" / "controller.json"))
    parser.add_argument("--json", default=str(Path(__file__).with_name("step_time.json")))
    args = parser.parse_args()
    compiler = _check_tools()
    a = artifacts.load(Path(args.artifact))
    n, l, ny = len(a.blocks), len(a.joint_names), len(a.sensor_names)
    facts = machine(compiler)
    print(
        f"machine: {facts['platform']}, {facts['cpu']} ({facts['cpus']} CPUs); compiler: {facts['compiler']}; "
        f"Python {facts['python']}, numpy {facts['numpy']}"
    )
    print(
        f"artefact: {args.artifact} (n = {n} coordinates, l = {l} joints, n_y = {ny} sensors); double build, "
        f"{' '.join(build.FLAGS)}"
    )

    sensors, velocity, friction, normal = inputs(a, ROWS)
    rows = {"siso": np.hstack([velocity, friction, normal]), "clqg": np.hstack([sensors, friction, normal])}
    c = controllers.compile_controllers(a, "double", PREFIX)
    timing = c_timing(c, rows)
    statuses = {law: int(np.count_nonzero(c.law(law).run(rows[law])[1])) for law in rows}
    measurements = [
        Measurements(k * a.sample_time, sensors[k], velocity[k], friction[k], normal[k]) for k in range(PY_ROWS)
    ]
    python = python_timing(a, measurements, c, rows)
    with tempfile.TemporaryDirectory(prefix="step_time-") as temporary:
        counts = callgrind(a, rows, compiler, Path(temporary))
    macs = structural_macs(n, l, ny, int(np.count_nonzero(output_terms(np.asarray(a.output, dtype=float)))))

    print(
        f"\n{ROWS} steps per run, best of {REPEATS} (steps with a non-OK status: {statuses}); Python on the first "
        f"{PY_ROWS} rows, best of 3, bit-identical to C: "
        f"{all(p['bit_identical_to_c'] for p in python.values())}"
    )
    summary = _print_table(timing, counts, macs, python)
    _print_structural_minimum(macs, n, l, ny)
    realised = realised_macs(a)
    print(
        f"  the realised cLQG step (codegen.law_contexts, control.realisation) does {realised['total']} "
        f"(output phase {realised['output_phase']}, update phase {realised['update_phase']}): "
        f"{counts['clqg_ir_per_step'] / realised['total']:.2f} Ir per multiply-add it does"
    )
    print(
        f"whole bench program: ΔIr/ΔN = {counts['program_ir_per_step_both_laws']:.1f} per step of both laws "
        f"(loop, checksum and row indexing included); callgrind steps {CALLGRIND_STEPS}"
    )
    met = _print_target(summary, counts)
    write_json(
        args.json,
        {
            **artifact_header("step_time", facts, args.artifact, a),
            "flags": build.FLAGS,
            "sizes": {"n": n, "l": l, "n_y": ny},
            "rows": ROWS,
            "repeats": REPEATS,
            "python_rows": PY_ROWS,
            "non_ok_status_steps": statuses,
            "c_ns_per_step": timing,
            "callgrind": counts,
            "structural_macs": macs,
            "realised_macs": realised,
            "python_ns_per_step": python,
            "summary": summary,
            "instructions_per_mac_target": INSTRUCTIONS_PER_MAC_TARGET,
            "target_met": met,
        },
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
