"""The generated firmware measured on its target, QEMU's mps2-an386 (Cortex-M4F), not estimated.

``bench.target.run_selftest`` builds the self-test image (firmware/target/mps2_an386) from the
SIL bench's float sources and runs it with ``-icount shift=0`` (one instruction = 1 ns of virtual
time; SysTick on the 25 MHz SYSCLK ticks every 40 instructions; the mean over the sequence with
the loop around an empty step subtracted). Stack by painting, flash and RAM by
``arm-none-eabi-size``. Prints the figures and writes them as JSON.
"""

from __future__ import annotations

import argparse
import platform
import subprocess
import sys
from pathlib import Path

from machine import artifact_header, cpu_model, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.bench import target
from smartjoint.design.control import artifact as artifacts

ROOT = Path(__file__).resolve().parents[1]


def _version(command: list[str]) -> str:
    return subprocess.run(command, capture_output=True, text=True).stdout.splitlines()[0]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifact", default=str(ROOT / "firmware" / "generated" / "controller.json"))
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--json", default=str(Path(__file__).with_name("target.json")))
    args = parser.parse_args()
    reason = target.missing_tools()
    if reason:
        print(reason, file=sys.stderr)
        return 2
    a = artifacts.load(args.artifact)
    r = target.run_selftest(a, steps=args.steps)
    facts = {
        "platform": platform.platform(),
        "cpu": cpu_model(),
        "compiler": _version(["arm-none-eabi-gcc", "--version"]),
        "qemu": _version(["qemu-system-arm", "--version"]),
    }
    print(f"command: {r['command']}  (exit status {r['exit_code']}, {args.steps} steps)")
    for law, value in r["instructions"].items():
        print(f"{law}: {value:.1f} instructions per step (±{40 / args.steps:.2f})")
    print(f"stack: {r['stack']} B (loops below main; high water of the whole program)")
    print(f"size: {r['size']} B")
    write_json(
        args.json,
        {
            **artifact_header("target", facts, args.artifact, a),
            "command": r["command"],
            "steps": args.steps,
            "exit_code": r["exit_code"],
            "instructions_per_step": r["instructions"],
            "stack": r["stack"],
            "size": r["size"],
            "figures": r["figures"],
        },
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
