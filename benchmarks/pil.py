"""Processor in the loop on QEMU's mps2-an386: the study with the firmware on its target.

Runs ``bench.pil_study`` on the committed reference artefact (the bundled three type A joint
design, its whole study unless ``--duration``): per law the host float build and the target in
lock-step, compared sample by sample; the target's instructions per ``_can_step`` (controller
included), per received and per sent frame (SysTick under ``-icount shift=0``, the measurement's
overhead subtracted) and the share of a sample at 168 MHz; the painted stack high-water mark
against the static bound of ``benchmarks/firmware_image.py`` (the deepest CAN entry point,
computed from the same compiler's frame sizes and call graph); and the wall time of a sample in
the loop against the SIL loop around the host float build (the named baseline, run side by side).

    python benchmarks/pil.py [--duration 4.0] [--json benchmarks/pil.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from firmware_image import measure_image  # benchmarks/ (the script's folder is on sys.path)
from machine import artifact_header, cpu_model, write_json

from smartjoint.bench import firmware, pil, pil_study, target
from smartjoint.common import law_registry
from smartjoint.design import load_design, updated_design
from smartjoint.design.control import artifact as artifacts
from smartjoint.design.control import study as closed_loop
from smartjoint.design.structure import spec

ROOT = Path(__file__).resolve().parents[1]


def _version(command: list[str]) -> str:
    return subprocess.run(command, capture_output=True, text=True).stdout.splitlines()[0]


def _study(a, duration: float | None):
    # The reference artefact names its bundled design file (design/data).
    design, _ = updated_design(load_design(spec.REFERENCE_DESIGN.parent / Path(a.design_source).name))
    if duration is not None:
        design = dataclasses.replace(design, control=dataclasses.replace(design.control, study_duration=duration))
    model = closed_loop.design_model(design, lambda line: None)
    return pil_study.mil_study(design, model, a, progress=lambda line: None)


def _timed(study, image, law: str) -> float:
    start = time.perf_counter()
    pil_study.loop_run(study.setup, image, law)
    return time.perf_counter() - start


def _law(study, a, law: str) -> dict:
    out = pil_study.law_on_target(study.setup, a, law)
    samples = out["difference"]["samples"]
    baseline = _timed(study, firmware.Firmware(a, law, "float"), law)  # side by side: SIL, then PIL
    with pil.TargetFirmware(a, law) as image:
        on_target = _timed(study, image, law)
    return {
        "samples": samples,
        "bit_identical": pil_study.identical(out["difference"]),
        "difference": out["difference"],
        "measured": out["measured"],
        "frames_per_sample": out["frames_per_sample"],
        "budget": out["budget"],
        "size": out["size"],
        "energy_measure": out["run"].energy_measure(),
        "wall_per_sample_ms": {
            "pil": 1e3 * on_target / samples,
            "sil_host_float": 1e3 * baseline / samples,
        },
        "pil_over_sil": on_target / baseline,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifact", default=str(ROOT / "firmware" / "generated" / "controller.json"))
    parser.add_argument("--duration", type=float, help="t_e [s] (default: the design's study duration)")
    parser.add_argument("--json", default=str(Path(__file__).with_name("pil.json")))
    args = parser.parse_args()
    reason = target.missing_tools()
    if reason:
        print(reason, file=sys.stderr)
        return 2
    a = artifacts.load(args.artifact)
    study = _study(a, args.duration)
    with tempfile.TemporaryDirectory() as scratch:
        static = measure_image(a, Path(scratch) / "image", callgraph=True, without=())  # as the target builds it
    laws = {law.name: _law(study, a, law.name) for law in law_registry.LAWS.values() if not law.constant}
    high_water = max(f["measured"]["stack_high_water"] for f in laws.values())
    results = {
        **artifact_header(
            "pil",
            {
                "platform": platform.platform(),
                "cpu": cpu_model(),
                "compiler": _version(["arm-none-eabi-gcc", "--version"]),
                "qemu": _version(["qemu-system-arm", "--version"]),
            },
            args.artifact,
            a,
        ),  # fmt: skip
        "duration": study.setup.duration,
        "laws": laws,
        "stack": {
            "painted_high_water": high_water,
            "static_bound": static["stack_max"],
            "static_chains": static["stack"],
            "difference": static["stack_max"] - high_water,
        },  # fmt: skip
    }
    for law, f in laws.items():
        m, b = f["measured"], f["budget"]
        print(
            f"{law}: {f['samples']} samples, {'bit for bit' if f['bit_identical'] else 'DIFFERENT'}; step "
            f"{m['step']['instructions_mean']:.1f} (largest {m['step']['instructions_largest']:.0f}), rx "
            f"{m['rx']['instructions_mean']:.1f}, tx {m['tx']['instructions_mean']:.1f} instructions; "
            f"{100 * b['share_mean']:.2f} % (worst {100 * b['share_worst']:.2f} %) of a sample at 168 MHz; "
            f"{f['wall_per_sample_ms']['pil']:.2f} ms a sample (SIL host float "
            f"{f['wall_per_sample_ms']['sil_host_float']:.3f} ms)"
        )
    s = results["stack"]
    print(f"stack: painted high water {s['painted_high_water']} B, static bound {s['static_bound']} B")
    write_json(args.json, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
