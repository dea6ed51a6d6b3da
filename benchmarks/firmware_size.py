"""Cortex-M4F footprint of the generated controllers: flash, RAM and worst-case stack per controller.

The float build of the artefact (default: the committed reference configuration,
firmware/generated/controller.json) is rendered into a temporary folder and each controller
module is compiled for the target with ``arm-none-eabi-gcc -mcpu=cortex-m4 -mthumb
-mfpu=fpv4-sp-d16 -mfloat-abi=hard -O2 -fstack-usage -fcallgraph-info=su`` plus the strict
warning set of ``codegen.build.FLAGS``. Per controller (SISO, clipped LQG):

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

    python benchmarks/firmware_size.py [--artifact firmware/generated/controller.json] \
        [--json benchmarks/firmware_size.json]
"""

from __future__ import annotations

import argparse
import platform
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from machine import artifact_header, cpu_model, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.codegen import build, generate, output
from smartjoint.design.control import artifact as artifacts

ROOT = Path(__file__).resolve().parents[1]
TARGET = ["-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard"]
BASE_FLAGS = [f for f in build.FLAGS if f != "-O2"]
TOOLS = (
    "arm-none-eabi-gcc",
    "arm-none-eabi-size",
    "arm-none-eabi-objdump",
    "arm-none-eabi-objcopy",
    "arm-none-eabi-nm",
)
LAWS = (("siso", "SISO"), ("clqg", "clipped LQG"))
BUILDS = (("float", "-O2"), ("double", "-O2"), ("float", "-O0"))  # ours first, then the two baselines
LIMITS = {"flash": 8 * 1024, "ram": 1024, "stack": 512}


def run(command: list[str], cwd: Path | None = None) -> str:
    done = subprocess.run(command, cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"error: {' '.join(command)} failed:\n{done.stderr.strip()}")
    return done.stdout


def check_tools() -> None:
    missing = [t for t in TOOLS if shutil.which(t) is None]
    if missing:
        raise SystemExit(
            f"error: {', '.join(missing)} not found on PATH — this benchmark needs the GNU Arm "
            "Embedded toolchain with newlib (Debian/Ubuntu: apt-get install gcc-arm-none-eabi "
            "binutils-arm-none-eabi libnewlib-arm-none-eabi)"
        )


def supports_callgraph_info(folder: Path) -> bool:
    probe = folder / "cg_probe.c"
    probe.write_text("int cg_probe(void);\nint cg_probe(void) { return 0; }\n")
    done = subprocess.run(
        ["arm-none-eabi-gcc", *TARGET, "-fcallgraph-info=su", "-c", str(probe), "-o", str(folder / "cg_probe.o")],
        cwd=folder,
        capture_output=True,
        text=True,
    )
    return done.returncode == 0


def sections(path: Path) -> dict[str, int]:
    """``arm-none-eabi-size -A``: section name → bytes."""
    out = {}
    for line in run(["arm-none-eabi-size", "-A", str(path)]).splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0].startswith(".") and parts[1].isdigit():
            out[parts[0]] = int(parts[1])
    return out


def berkeley(path: Path) -> dict[str, int]:
    """``arm-none-eabi-size`` (Berkeley): text (incl. .rodata), data, bss."""
    line = run(["arm-none-eabi-size", str(path)]).splitlines()[1].split()
    return {"text": int(line[0]), "data": int(line[1]), "bss": int(line[2])}


def stack_usage(su: Path) -> dict[str, tuple[int, str]]:
    """function → (frame bytes, qualifier) from a gcc .su file."""
    out = {}
    for line in su.read_text().splitlines():
        location, size, qualifier = line.rsplit("\t", 2)
        out[location.rsplit(":", 1)[-1]] = (int(size), qualifier)
    return out


def callgraph_ci(ci: Path) -> dict[str, set[str]]:
    """caller → callees from gcc's -fcallgraph-info (VCG); static functions lose their file prefix."""
    name = lambda title: title.rsplit(":", 1)[-1]  # noqa: E731
    graph: dict[str, set[str]] = {}
    for source, target in re.findall(r'edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"', ci.read_text()):
        graph.setdefault(name(source), set()).add(name(target))
    return graph


class Disassembly:
    """Functions of a linked Thumb image: address ranges (``nm -S``), instructions (objdump)."""

    def __init__(self, elf: Path):
        self.symbols: dict[str, tuple[int, int]] = {}
        for line in run(["arm-none-eabi-nm", "-S", str(elf)]).splitlines():
            parts = line.split()
            if len(parts) == 4 and parts[2] in "Tt":
                self.symbols[parts[3]] = (int(parts[0], 16) & ~1, int(parts[1], 16))
        self.instructions: list[tuple[int, str, str]] = []
        for line in run(["arm-none-eabi-objdump", "-d", "--no-show-raw-insn", str(elf)]).splitlines():
            m = re.match(r"\s+([0-9a-f]+):\s+(\S+)\s*(.*)$", line)
            if m:
                self.instructions.append((int(m.group(1), 16), m.group(2), m.group(3)))

    def body(self, name: str) -> list[tuple[int, str, str]]:
        start, size = self.symbols[name]
        return [i for i in self.instructions if start <= i[0] < start + size]

    def owner(self, address: int) -> str | None:
        """The symbol starting at ``address``, else the smallest one containing it."""
        exact = sorted(n for n, (s, _) in self.symbols.items() if s == address and not n.startswith("$"))
        if exact:
            return exact[0]
        inside = [(size, n) for n, (s, size) in self.symbols.items() if s <= address < s + size]
        return min(inside)[1] if inside else None

    def frame(self, name: str) -> int:
        """Upper bound of the bytes the routine puts on the stack: every push/vpush/stmdb sp!/sub sp."""
        total = 0
        for _, op, args in self.body(name):
            op = op.split(".")[0]
            if op in ("push", "vpush") or (op == "stmdb" and args.startswith("sp!")):
                registers = re.search(r"\{([^}]*)\}", args).group(1)
                for item in (r.strip() for r in registers.split(",")):
                    width = 8 if item.startswith("d") else 4
                    if "-" in item:
                        low, high = (int(re.sub(r"\D", "", x)) for x in item.split("-"))
                        total += width * (high - low + 1)
                    else:
                        total += width
            elif op in ("sub", "subw") and re.match(r"sp,\s*(sp,\s*)?#", args):
                total += int(re.search(r"#(\d+)", args).group(1))
        return total

    def callees(self, name: str) -> set[str]:
        """bl/blx targets, and branch targets outside the routine (tail jumps into shared code)."""
        start, size = self.symbols[name]
        out = set()
        for _, op, args in self.body(name):
            m = re.match(r"([0-9a-f]+) <", args)
            if not m or not op.startswith("b") or op.startswith(("bic", "bfc", "bfi")):
                continue
            target = int(m.group(1), 16)
            if op.startswith("bl") or not start <= target < start + size:
                owner = self.owner(target)
                if owner and owner != name:
                    out.add(owner)
        return out


def worst_stack(entry: str, frames: dict[str, int], graph: dict[str, set[str]], image: Disassembly):
    """(bytes, chain) of the deepest call chain from ``entry``; library routines are looked up
    in the linked image. Recursion has no bound: refuse it."""
    memo: dict[str, tuple[int, list[str]]] = {}

    def visit(name: str, path: tuple[str, ...]):
        if name in path:
            raise SystemExit(f"error: recursion {' → '.join(path + (name,))}: no static stack bound")
        if name in memo:
            return memo[name]
        if name in frames:
            own, callees = frames[name], graph.get(name, set())
        elif name in image.symbols:
            own, callees = image.frame(name), image.callees(name)
        else:
            raise SystemExit(f"error: {name} is called from the module but is not in the linked image")
        best = (0, [])
        for callee in sorted(callees):
            depth = visit(callee, path + (name,))
            if depth[0] > best[0]:
                best = depth
        memo[name] = (own + best[0], [f"{name} ({own} B)"] + best[1])
        return memo[name]

    depth, chain = visit(entry, ())
    return depth, chain, sorted(memo)


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


def measure_image(a, folder: Path, callgraph: bool, prefix: str = "smartjoint") -> dict:
    """The whole float firmware at -O2: both controllers, the CAN message layer and the E2E
    runtime, linked from the CAN entry points (rx, step, tx, init). The layer packs and unpacks
    in double (bit-exact with cantools), which pulls libgcc's soft-float routines on this FPU."""
    from smartjoint.codegen import can_layer

    folder.mkdir(parents=True)
    files = {**generate.render(a, "float", prefix), **can_layer.render_can(a, prefix)}
    output.write({k: v for k, v in files.items() if k.endswith((".c", ".h"))}, folder)
    sources = [f"{prefix}_siso", f"{prefix}_clqg", f"{prefix}_can", "sj_e2e"]
    extra = ["-fstack-usage"] + (["-fcallgraph-info=su"] if callgraph else [])
    for name in sources:
        run(
            ["arm-none-eabi-gcc", *TARGET, "-O2", *extra, *BASE_FLAGS, "-c", f"{name}.c", "-o", f"{name}.o"], cwd=folder
        )
    entries = [f"{prefix}_can_{e}" for e in ("step", "rx", "tx", "init")]
    run(
        [
            "arm-none-eabi-gcc",
            *TARGET,
            "-nostartfiles",
            "-Wl,--gc-sections",
            f"-Wl,--entry={entries[0]}",
            *[f"-Wl,--undefined={e}" for e in entries[1:]],
            *[f"{n}.o" for n in sources],
            "-lm",
            "-o",
            "image.elf",
        ],
        cwd=folder,
    )
    image = Disassembly(folder / "image.elf")
    su: dict = {}
    graph: dict = {}
    for name in sources:
        su.update(stack_usage(folder / f"{name}.su"))
        graph.update(callgraph_ci(folder / f"{name}.ci") if callgraph else {})
    if not callgraph:
        graph = {f: image.callees(f) for f in su}
    frames = {f: size for f, (size, _) in su.items()}
    stacks = {e: worst_stack(e, frames, graph, image)[:2] for e in entries}
    worst = max(stacks, key=lambda e: stacks[e][0])
    (folder / "probe.c").write_text(
        f'#include "{prefix}_can.h"\nextern const unsigned long probe;\n'
        f"const unsigned long probe = sizeof({prefix}_can_state);\n"
    )
    run(["arm-none-eabi-gcc", *TARGET, "-O2", *BASE_FLAGS, "-c", "probe.c", "-o", "probe.o"], cwd=folder)
    run(["arm-none-eabi-objcopy", "-O", "binary", "-j", ".rodata", "probe.o", "probe.bin"], cwd=folder)
    state = int.from_bytes((folder / "probe.bin").read_bytes()[:4], "little")
    elf = berkeley(folder / "image.elf")
    return {
        "flash": elf["text"] + elf["data"],
        "static_ram": elf["data"] + elf["bss"],
        "state": state,
        "ram": elf["data"] + elf["bss"] + state + 64 + 64,  # + one rx and one tx frame buffer
        "stack": stacks[worst][0],
        "stack_chain": stacks[worst][1],
        "modules": {n: berkeley(folder / f"{n}.o")["text"] for n in sources},
    }


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


def _print_whole_image(whole: dict) -> None:
    """Flash, RAM and stack of the whole linked firmware image."""
    print("\nwhole firmware image (float -O2: SISO + clipped LQG + CAN layer + E2E, linked from the CAN entry points):")
    print(
        f"  flash {whole['flash']:5d} B  (modules .text: "
        + ", ".join(f"{k} {v}" for k, v in whole["modules"].items())
        + "; the rest: libgcc soft-float for the "
        "double codec, libm floor)"
    )
    print(
        f"  RAM   {whole['ram']:5d} B  (static {whole['static_ram']} B + state {whole['state']} B + two 64-byte "
        "frame buffers)"
    )
    print(f"  stack {whole['stack']:5d} B  ({' → '.join(whole['stack_chain'])})")


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
    _print_whole_image(whole)
    write_json(
        args.json,
        {
            "whole_image": whole,
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
