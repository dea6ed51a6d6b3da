"""How the generated firmware grows with the number of joints: 3, 6 and 12 (issue 33).

For each controller artefact given (by default the three of ``--folder``: ``joints_3.json``,
``joints_6.json``, ``joints_12.json``, designed by ``smartjoint design`` from the bundled
30-bay mast with 3, 6 and 12 placed joints), the same measurements as ``step_time.py`` and
``target.py`` side by side:

- x86-64: the inclusive Ir per step of ``<prefix>_clqg_step`` and of its output phase under
  callgrind (double build, ``codegen.build.FLAGS``; ``step_time.callgrind``);
- the target, QEMU mps2-an386 (Cortex-M4F, ``-icount shift=0``): instructions per step of every
  law and of the cLQG's output phase, the step as a share of a 1 ms sample at 168 MHz
  (168 000 instructions at one per cycle, the optimistic side: wait states add to it), and the
  flash and RAM of the firmware objects and of the whole self-test image (``target.run_selftest``);
- the flash of each generated source apart, compiled as the target's Makefile compiles it, split
  into code (``.text``) and constants (``.rodata``: gain matrices, limits, tables) by
  ``arm-none-eabi-size -A``: a dense l × l gain is l² constants whatever the code does, so
  linear growth is asked of the code;
- the same for the other form of the cLQG's sums over joints side by side: up to
  ``law_contexts.UNROLLED_JOINTS`` joints the generator writes them out term by term, beyond it
  it loops over index tables; each artefact is measured in both forms (``form``);
- the needed multiply-adds of a cLQG step from the artefact's sizes (``step_time.structural_macs``),
  and the flash per joint from one row to the next: linear growth keeps it about constant.

    python benchmarks/joint_scaling.py [--folder DIR] [--json benchmarks/joint_scaling.json] [ARTIFACT ...]
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from machine import cpu_model, write_json  # benchmarks/machine.py (the script's folder is on sys.path)
from step_time import _check_tools, callgrind, inputs, machine, realised_macs, structural_macs

from smartjoint.bench import firmware, target
from smartjoint.codegen import law_contexts
from smartjoint.design.control import artifact as artifacts
from smartjoint.design.control.ordered_sums import output_terms

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_INSTRUCTIONS = 168_000  # 1 ms at 168 MHz, one instruction per cycle
CALLGRIND_ROWS = 4000
MAKEFILE = ROOT / "firmware" / "target" / "mps2_an386" / "Makefile"


def _target_flags() -> list[str]:
    """TARGET and CFLAGS of the target's Makefile (continuation lines joined)."""
    text = MAKEFILE.read_text().replace("\\\n", " ")
    found = {k: v.split() for k, v in re.findall(r"^(TARGET|CFLAGS) = (.*)$", text, re.M)}
    return [flag for flag in found["CFLAGS"] if flag != "$(TARGET)"] + found["TARGET"]


def source_sizes(a, folder: Path) -> dict[str, dict[str, int]]:
    """Per generated source (float build): code (.text*) and constants (.rodata*) in flash, RAM
    (.data + .bss), compiled with the target's flags."""
    sources = firmware.sources(a, "float")
    for name, text in sources.items():
        (folder / name).write_text(text)
    sizes = {}
    for name in sorted(n for n in sources if n.endswith(".c")):
        obj = folder / (name[:-2] + ".o")
        subprocess.run(["arm-none-eabi-gcc", *_target_flags(), "-c", name, "-o", obj.name], cwd=folder, check=True)
        sections = subprocess.run(
            ["arm-none-eabi-size", "-A", obj.name], cwd=folder, check=True, capture_output=True, text=True
        ).stdout
        row = {"code": 0, "constants": 0, "ram": 0}
        for line in sections.splitlines():
            words = line.split()
            if len(words) >= 2 and words[1].isdigit():
                if words[0].startswith(".text"):
                    row["code"] += int(words[1])
                elif words[0].startswith(".rodata"):
                    row["constants"] += int(words[1])
                elif words[0].startswith((".data", ".bss")):
                    row["ram"] += int(words[1])
        sizes[name] = row
    return sizes


def measure(path: Path, compiler: str, form: str) -> dict:
    """One artefact's row of the table, its cLQG's sums over joints ``form`` ("written out" or
    "loops")."""
    saved = law_contexts.UNROLLED_JOINTS
    law_contexts.UNROLLED_JOINTS = 10**6 if form == "written out" else 0
    try:
        return _measure(path, compiler) | {"form": form, "generator_default": _default_form(path, saved)}
    finally:
        law_contexts.UNROLLED_JOINTS = saved


def _default_form(path: Path, unrolled_joints: int) -> str:
    return "written out" if len(artifacts.load(path).joint_names) <= unrolled_joints else "loops"


def _measure(path: Path, compiler: str) -> dict:
    a = artifacts.load(path)
    n, l, ny = len(a.blocks), len(a.joint_names), len(a.sensor_names)
    sensors, velocity, friction, normal = inputs(a, CALLGRIND_ROWS)
    rows = {"siso": np.hstack([velocity, friction, normal]), "clqg": np.hstack([sensors, friction, normal])}
    with tempfile.TemporaryDirectory(prefix="joint_scaling-") as temporary:
        counts = callgrind(a, rows, compiler, Path(temporary))
    with tempfile.TemporaryDirectory(prefix="joint_scaling-") as temporary:
        sources = source_sizes(a, Path(temporary))
    on_target = target.run_selftest(a, steps=1000)
    if on_target["exit_code"] != 0:
        raise SystemExit(f"error: the self-test of {path} exited with {on_target['exit_code']}")
    macs = structural_macs(n, l, ny, int(np.count_nonzero(output_terms(np.asarray(a.output, dtype=float)))))
    clqg = on_target["instructions"]["clqg"]
    return {
        "artifact": str(path),
        "sha256": a.artifact_sha256,
        "sizes": {"n": n, "l": l, "n_y": ny},
        "x86_clqg_ir": counts["clqg_ir_per_step"],
        "x86_clqg_output_phase_ir": counts["clqg_output_phase_ir_per_step"],
        "x86_siso_ir": counts["siso_ir_per_step"],
        "target_instructions": on_target["instructions"],
        "target_clqg_share_of_sample": clqg / SAMPLE_INSTRUCTIONS,
        "size": on_target["size"],
        "stack": on_target["stack"],
        "clqg_needed_macs": macs["clqg"]["total"],
        "clqg_realised_macs": realised_macs(a)["total"],
        "sources": sources,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("artifacts", nargs="*", help="controller artefacts (default: joints_{3,6,12}.json of --folder)")
    parser.add_argument("--folder", default=str(ROOT / "benchmarks" / "joint_scaling"))
    parser.add_argument("--json", default=str(Path(__file__).with_name("joint_scaling.json")))
    args = parser.parse_args()
    reason = target.missing_tools()
    if reason:
        print(reason, file=sys.stderr)
        return 2
    compiler = _check_tools()
    paths = [Path(p) for p in args.artifacts] or [Path(args.folder) / f"joints_{k}.json" for k in (3, 6, 12)]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        print(f"error: artefact not found: {', '.join(missing)}", file=sys.stderr)
        return 2
    facts = {**machine(compiler), "cpu": cpu_model()}
    rows = []
    for form in ("written out", "loops"):
        for path in paths:
            print(f"{path}, cLQG sums over joints {form} …", flush=True)
            rows.append(measure(path, compiler, form))
    print(
        "\n| form | joints l | coordinates n | sensors | needed MACs (design basis / realised) | x86 cLQG Ir | "
        "target cLQG instr. | share of 1 ms at 168 MHz | output phase | target SISO instr. | firmware flash | "
        "image flash | image RAM |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        s, t = r["sizes"], r["target_instructions"]
        print(
            f"| {r['form']}{' (default)' if r['form'] == r['generator_default'] else ''} | {s['l']} | {s['n']} | "
            f"{s['n_y']} | {r['clqg_needed_macs']} / {r['clqg_realised_macs']} | {r['x86_clqg_ir']:.1f} | "
            f"{t['clqg']:.1f} | "
            f"{r['target_clqg_share_of_sample']:.2%} | {t['clqg_output_phase'] / t['clqg']:.1%} | {t['siso']:.1f} | "
            f"{r['size']['firmware_flash']} | {r['size']['image_flash']} | {r['size']['image_ram']} |"
        )
    print("\nflash of each source (code + constants, bytes; float build with the target's flags):\n")
    names = sorted({name for r in rows for name in r["sources"]})
    growth = []
    for form in ("written out", "loops"):
        growth += _flash_table(names, [r for r in rows if r["form"] == form], form)
    write_json(args.json, {"benchmark": "joint_scaling", "machine": facts, "rows": rows, "code_growth": growth})
    return 0


def _flash_table(names: list[str], rows: list[dict], form: str) -> list[dict]:
    """The per-source flash table of one form; the code per added joint from row to row."""
    print(f"\ncLQG sums over joints {form}:\n")
    print("| source | " + " | ".join(f"{r['sizes']['l']} joints" for r in rows) + " | code per joint |")
    print("|---|" + "---:|" * (len(rows) + 1))
    growth = []
    for name in names:
        cells = [r["sources"].get(name, {"code": 0, "constants": 0}) for r in rows]
        slopes = [
            (after["code"] - before["code"]) / (r2["sizes"]["l"] - r1["sizes"]["l"])
            for before, after, r1, r2 in zip(cells, cells[1:], rows, rows[1:])
        ]
        growth.append({"form": form, "source": name, "code_per_joint": slopes})
        print(
            f"| {name} | "
            + " | ".join(f"{c['code']} + {c['constants']}" for c in cells)
            + " | "
            + " → ".join(f"{slope:.0f}" for slope in slopes)
            + " |"
        )
    return growth


if __name__ == "__main__":
    raise SystemExit(main())
