"""Tools on Cortex-M4F objects and images for the firmware benchmarks: the target flags, section
sizes (``arm-none-eabi-size``), gcc's stack usage (.su) and call graph (-fcallgraph-info), the
disassembly of a linked image (frames and callees of library routines) and the static stack
bound of an entry point (the deepest call chain; recursion refused)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

from smartjoint.codegen import build

TARGET = ["-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard"]
BASE_FLAGS = [f for f in build.FLAGS if f != "-O2"]
TOOLS = (
    "arm-none-eabi-gcc",
    "arm-none-eabi-size",
    "arm-none-eabi-objdump",
    "arm-none-eabi-objcopy",
    "arm-none-eabi-nm",
)


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
            if len(parts) == 4 and parts[2] in "TtWw":  # W: libgcc's weak aliases (__aeabi_dmul of __muldf3)
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
