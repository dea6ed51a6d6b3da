"""Cortex-M4F footprint of the generated controllers: flash, RAM and worst-case stack per controller.

The float build of the artefact (default: the committed reference configuration,
firmware/generated/controller.json) is rendered into a temporary folder and each controller
module is compiled for the target with ``arm-none-eabi-gcc -mcpu=cortex-m4 -mthumb
-mfpu=fpv4-sp-d16 -mfloat-abi=hard -O2 -fstack-usage -fcallgraph-info=su`` plus the strict
warning set of ``codegen.build.FLAGS``. Per controller (every law of the registry):

- flash: .text + .rodata + .data of the module object (``arm-none-eabi-size``), and of a
  linked image (entry = ``<name>_step``, ``--gc-sections``) that adds the library routines the
  module calls (memset; the soft-float double routines of libgcc in the double build);
  the target applies to the linked figure;
- RAM: static (.data + .bss) + the caller-owned structs (sizeof state + input + output,
  measured by compiling a probe for the same target and reading its .rodata back);
- worst-case stack: the sum of the frames along the deepest call chain from ``<name>_step``
  (frames from the .su files; the call graph from gcc's -fcallgraph-info, or the objdump
  ``bl`` targets when the compiler lacks it; library routines from the disassembly of the
  linked image: every push/vpush/sub sp in the routine, and any branch out of it counted as a
  nested call — an upper bound).

Targets: flash ≤ 8 KiB, RAM ≤ 1 KiB, stack ≤ 512 B. Baselines, built side by side: the same
modules in the double build at -O2 (every double operation a libgcc soft-float call on the
single-precision FPU — the alternative a firmware author would actually choose: the ratio
shows what the float build buys), and the float build at -O0 (what the optimiser buys).

Then the whole image (``benchmarks/firmware_image.py``): controllers + CAN layer + E2E + a
minimal runtime main with the target's startup and board support, float -O2, --gc-sections:
flash, RAM (.data + .bss), the double-precision routines linked (none is the target) and the
static stack bound of each CAN entry point (init, rx, step with the controller step, tx), with
the machinery above (``benchmarks/elf_tools.py``). Targets: flash ≤ 8 KiB, RAM ≤ 512 B.

    python benchmarks/firmware_size.py [--artifact firmware/generated/controller.json] \
        [--json benchmarks/firmware_size.json]
"""

from __future__ import annotations

import argparse
import platform
import sys
import tempfile
from pathlib import Path

from elf_tools import (  # benchmarks/elf_tools.py (the script's folder is on sys.path)
    BASE_FLAGS,
    TARGET,
    Disassembly,
    berkeley,
    callgraph_ci,
    check_tools,
    run,
    sections,
    stack_usage,
    supports_callgraph_info,
    worst_stack,
)
from firmware_image import measure_image, print_whole_image, print_xcp
from machine import artifact_header, cpu_model, write_json  # benchmarks/machine.py

from smartjoint.codegen import generate, output
from smartjoint.common import law_registry
from smartjoint.design.control import artifact as artifacts

ROOT = Path(__file__).resolve().parents[1]
LAWS = tuple((law.name, law.display) for law in law_registry.LAWS.values())  # every law of the registry
BUILDS = (("float", "-O2"), ("double", "-O2"), ("float", "-O0"))  # ours first, then the two baselines
LIMITS = {"flash": 8 * 1024, "ram": 1024, "stack": 512}


def struct_sizes(folder: Path, prefix: str) -> dict[str, dict[str, int]]:
    """sizeof of every caller-owned struct, compiled for the target and read back from .rodata."""
    names = [(law, kind) for law, _ in LAWS for kind in ("state", "input", "output")]
    text = "".join(f'#include "{prefix}_{law}.h"\n' for law, _ in LAWS)
    text += (
        f"extern const unsigned long size_probe[{len(names)}];\nconst unsigned long size_probe[{len(names)}] = {{"
        + ", ".join(f"sizeof({prefix}_{law}_{kind})" for law, kind in names)
        + "};\n"
    )
    (folder / "size_probe.c").write_text(text)
    run(["arm-none-eabi-gcc", *TARGET, "-O2", *BASE_FLAGS, "-c", "size_probe.c", "-o", "size_probe.o"], cwd=folder)
    run(["arm-none-eabi-objcopy", "-O", "binary", "-j", ".rodata", "size_probe.o", "size_probe.bin"], cwd=folder)
    data = (folder / "size_probe.bin").read_bytes()
    values = [int.from_bytes(data[4 * i : 4 * i + 4], "little") for i in range(len(names))]
    out: dict[str, dict[str, int]] = {}
    for (law, kind), value in zip(names, values):
        out.setdefault(law, {})[kind] = value
    return out


def measure(a, real: str, level: str, folder: Path, callgraph: bool, prefix: str = "smartjoint") -> dict:
    folder.mkdir(parents=True)
    output.write(generate.render(a, real, prefix), folder)
    structs = struct_sizes(folder, prefix)
    out = {}
    for law, _ in LAWS:
        name = f"{prefix}_{law}"
        extra = ["-fstack-usage"] + (["-fcallgraph-info=su"] if callgraph else [])
        run(
            ["arm-none-eabi-gcc", *TARGET, level, *extra, *BASE_FLAGS, "-c", f"{name}.c", "-o", f"{name}.o"], cwd=folder
        )
        run(
            [
                "arm-none-eabi-gcc",
                *TARGET,
                "-nostartfiles",
                "-Wl,--gc-sections",
                f"-Wl,--entry={name}_step",
                f"-Wl,--undefined={name}_init",
                f"{name}.o",
                "-lm",  # the float build's fmaf: a vfma.f32 at -O2, a libm call in the -O0 baseline
                "-o",
                f"{name}.elf",
            ],
            cwd=folder,
        )
        image = Disassembly(folder / f"{name}.elf")
        su = stack_usage(folder / f"{name}.su")
        if callgraph:
            graph = callgraph_ci(folder / f"{name}.ci")
        else:  # objdump bl targets of the module's own functions, in the linked image
            graph = {f: image.callees(f) for f in su}
        dynamic = sorted(f for f, (_, q) in su.items() if q != "static")
        if dynamic:
            raise SystemExit(f"error: {', '.join(dynamic)}: frame size not static ({su[dynamic[0]][1]})")
        stack, chain, reached = worst_stack(f"{name}_step", {f: s for f, (s, _) in su.items()}, graph, image)
        obj, elf = berkeley(folder / f"{name}.o"), berkeley(folder / f"{name}.elf")
        parts = sections(folder / f"{name}.o")
        library = [n for n in reached if n not in su]
        state = structs[law]
        static_ram = obj["data"] + obj["bss"]
        out[law] = {
            "sections": {s: parts.get(s, 0) for s in (".text", ".rodata", ".data", ".bss")},
            "flash_module": obj["text"] + obj["data"],
            "flash_linked": elf["text"] + elf["data"],
            "library_routines": library,  # reached from <name>_step; the linked figure also holds their section mates
            "static_ram": static_ram,
            "structs": state,
            "ram": static_ram + sum(state.values()),
            "stack": stack,
            "stack_chain": chain,
            "frames": {f: s for f, (s, _) in su.items()},
            "call_graph": {k: sorted(v) for k, v in graph.items()},
        }
    return out


def machine() -> dict:
    return {
        "platform": platform.platform(),
        "cpu": cpu_model(),
        "python": platform.python_version(),
        "compiler": run(["arm-none-eabi-gcc", "--version"]).splitlines()[0],
    }


def mark(value: int, limit: int) -> str:
    return "✔" if value <= limit else "✘"


def _print_table(results: dict) -> None:
    """One line per controller law and build: sections, flash, caller-owned structs, RAM and stack."""
    header = (
        f"{'controller':12s} {'build':10s} {'.text':>6s} {'.rodata':>7s} {'.data':>5s} {'.bss':>4s} "
        f"{'flash obj':>9s} {'flash linked':>12s} {'structs':>7s} {'RAM':>5s} {'stack':>5s}"
    )
    print("\n" + header + "\n" + "-" * len(header))
    for law, title in LAWS:
        for key in results:
            r = results[key][law]
            s = r["sections"]
            print(
                f"{title:12s} {key:10s} {s['.text']:6d} {s['.rodata']:7d} {s['.data']:5d} {s['.bss']:4d} "
                f"{r['flash_module']:9d} {r['flash_linked']:12d} {sum(r['structs'].values()):7d} {r['ram']:5d} "
                f"{r['stack']:5d}"
            )


def _print_targets(results: dict, ours: str, baselines: tuple[str, ...]) -> dict:
    """Our build of each law against the limits and the baseline builds; which targets it meets."""
    verdict = {}
    print(
        f"\ntargets (float -O2 build; flash = linked image incl. library routines, RAM = .data + .bss + "
        f"caller-owned structs): flash ≤ {LIMITS['flash']} B, RAM ≤ {LIMITS['ram']} B, stack ≤ {LIMITS['stack']} B"
    )
    for law, title in LAWS:
        r = results[ours][law]
        st = r["structs"]
        verdict[law] = {
            "flash": r["flash_linked"] <= LIMITS["flash"],
            "ram": r["ram"] <= LIMITS["ram"],
            "stack": r["stack"] <= LIMITS["stack"],
        }
        print(f"{title}:")
        print(
            f"  flash {r['flash_linked']:5d} B {mark(r['flash_linked'], LIMITS['flash'])}  (module "
            f"{r['flash_module']} B: .text {r['sections']['.text']} + .rodata {r['sections']['.rodata']} + .data "
            f"{r['sections']['.data']}; library: {', '.join(r['library_routines']) or 'none'})"
        )
        print(
            f"  RAM   {r['ram']:5d} B {mark(r['ram'], LIMITS['ram'])}  (static {r['static_ram']} B + state "
            f"{st['state']} + input {st['input']} + output {st['output']} B)"
        )
        print(f"  stack {r['stack']:5d} B {mark(r['stack'], LIMITS['stack'])}  ({' → '.join(r['stack_chain'])})")
        for base in baselines:
            b = results[base][law]
            ratios = ", ".join(
                f"{what} {b[field]} B ({b[field] / r[field]:.2f}×)"
                for what, field in (("flash", "flash_linked"), ("RAM", "ram"), ("stack", "stack"))
            )
            print(f"  baseline {base}: {ratios}")
    return verdict


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifact", default=str(ROOT / "firmware" / "generated" / "controller.json"))
    parser.add_argument("--json", default=str(Path(__file__).with_name("firmware_size.json")))
    args = parser.parse_args()
    check_tools()
    a = artifacts.load(Path(args.artifact))
    facts = machine()
    print(f"machine: {facts['platform']}, {facts['cpu']}; compiler: {facts['compiler']}")
    print(
        f"artefact: {args.artifact} (sha256 {a.artifact_sha256[:12]}…, n = {len(a.blocks)} coordinates, "
        f"l = {len(a.joint_names)} joints, n_y = {len(a.sensor_names)} sensors)"
    )
    with tempfile.TemporaryDirectory(prefix="firmware_size-") as temporary:
        root = Path(temporary)
        callgraph = supports_callgraph_info(root)
        print(
            f"flags: arm-none-eabi-gcc {' '.join(TARGET)} <-O2|-O0> -fstack-usage"
            f"{' -fcallgraph-info=su' if callgraph else ''} {' '.join(BASE_FLAGS)}"
        )
        print(f"call graph from: {'gcc -fcallgraph-info' if callgraph else 'objdump bl targets'}")
        results = {
            f"{real} {level}": measure(a, real, level, root / f"{real}{level}", callgraph) for real, level in BUILDS
        }

    _print_table(results)
    ours, baselines = "float -O2", ("double -O2", "float -O0")
    verdict = _print_targets(results, ours, baselines)
    with tempfile.TemporaryDirectory(prefix="firmware_image-") as temporary:
        whole = measure_image(a, Path(temporary) / "image", callgraph)
        every = measure_image(a, Path(temporary) / "every", callgraph, without=())
        with_xcp = measure_image(a, Path(temporary) / "xcp", callgraph, xcp=True)
    print_whole_image(whole)
    print_whole_image(every)
    xcp = print_xcp(whole, with_xcp)
    write_json(
        args.json,
        {
            "whole_image": whole,
            "every_law_image": every,
            "xcp_image": with_xcp,
            "xcp_added": xcp,
            **artifact_header("firmware_size", facts, args.artifact, a),
            "target_flags": TARGET + BASE_FLAGS,
            "limits_bytes": LIMITS,
            "call_graph_source": "gcc -fcallgraph-info" if callgraph else "objdump bl targets",
            "builds": results,
            "ours": ours,
            "baselines": list(baselines),
            "targets_met": verdict,
        },
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
