"""The whole float firmware image on the Cortex-M4F (a part of ``benchmarks/firmware_size.py``).

Both controllers, the CAN message layer, the E2E runtime and a minimal runtime — a ``main``
that feeds frames from the UART into ``<prefix>_can_rx``, runs ``<prefix>_can_step`` once per
sample and hands ``<prefix>_can_tx``'s frames back, with the committed startup, board support
and linker script of ``firmware/target/mps2_an386`` (compiled read-only) — built as the target
Makefile builds it: ``-O2 -ffunction-sections -fdata-sections``, newlib-nano,
``--gc-sections``. Reported: flash (every section the image loads into flash: vectors, .text,
.rodata, .ARM.exidx and the .data image), RAM (.data + .bss: the layer's state, controllers
included, and the frame buffer; the linker script's fixed stack region is not part of it — the
stack bound is), every double-precision routine linked (libgcc's soft-float ``__aeabi_d*`` and
``__*df*`` helpers and libm's double functions, from ``nm`` of the linked image and the map),
and the static stack bound of each CAN entry point (the deepest call chain, the controller
step included in ``step``).
"""

from __future__ import annotations

import re
from pathlib import Path

from elf_tools import BASE_FLAGS, TARGET, Disassembly, callgraph_ci, run, sections, stack_usage, worst_stack

from smartjoint.codegen import can_layer, generate, output, xcp_slave
from smartjoint.common import law_registry
from smartjoint.design.structure.description import Xcp

ROOT = Path(__file__).resolve().parents[1]
BOARD = ROOT / "firmware" / "target" / "mps2_an386"
FLASH_SECTIONS = (".vectors", ".text", ".rodata", ".ARM.exidx", ".data")
RAM_SECTIONS = (".data", ".bss")
LIMITS = {"flash": 8 * 1024, "ram": 512}
# The product image: the laws a shipped controller carries — the cLQG, the local slip-ratio law and
# the preset fall-back. The paper's SISO law is left out (``-D<PREFIX>_CAN_WITHOUT_SISO``): on the
# physical spread a preset force beats it (benchmarks/local_laws.py), and the four laws together
# (every law, measured beside it) do not fit 8 KiB. SIL, PIL and the FMUs still run every law.
PRODUCT_WITHOUT = ("siso",)
ENTRIES = ("init", "rx", "step", "tx")
# libm's double functions a C99 float build could pull in by mistake (floor instead of floorf …)
LIBM_DOUBLE = ("floor", "ceil", "fabs", "sqrt", "fmod", "rint", "nearbyint", "round", "trunc", "ldexp", "frexp")
DOUBLE_ROUTINE = re.compile(r"^(__aeabi_(d\w+|[a-z0-9]*2d)|__\w*df\d*)$")

MAIN = """/* Minimal runtime of the whole-image benchmark (benchmarks/firmware_image.py): frames from
 * the UART (id: 4 bytes little-endian, length, payload) into the CAN layer, a step per sample
 * when the host sends an empty frame, the step's frames back over the UART. */
#include <stdint.h>

#include "board.h"
#include "{prefix}_can.h"

static {prefix}_can_state state;
static uint8_t frame[64];

int main(void)
{{
    uint32_t now = 0u;
    uint32_t id = 0u;
    uint8_t length = 0u;
    (void){prefix}_can_init(&state, {PREFIX}_CAN_LAW_CLQG);
    for (;;) {{
        unsigned int k;
        id = sj_uart_get_u32();
        length = (uint8_t)sj_uart_getc();
        if (length == 0u) {{
            (void){prefix}_can_step(&state, now);
            while ({prefix}_can_tx(&state, &id, frame, &length) != 0) {{
                sj_uart_put_u32(id);
                sj_uart_putc((char)length);
                for (k = 0u; k < length; ++k) {{
                    sj_uart_putc((char)frame[k]);
                }}
            }}
            now += {PREFIX}_CAN_CYCLE_US;
            continue;
        }}
        for (k = 0u; k < length && k < sizeof frame; ++k) {{
            frame[k] = (uint8_t)sj_uart_getc();
        }}
        (void){prefix}_can_rx(&state, id, frame, length, now);
    }}
}}
"""


MAIN_XCP = """/* The whole-image benchmark's runtime with the XCP slave: frames of the master's identifier
 * into <prefix>_xcp_rx, the event after every step, the slave's frames after the layer's. */
#include <stdint.h>

#include "board.h"
#include "{prefix}_xcp.h"

static {prefix}_xcp_state xcp;
static uint8_t frame[64];

static void send(uint32_t id, uint8_t length)
{{
    unsigned int k;
    sj_uart_put_u32(id);
    sj_uart_putc((char)length);
    for (k = 0u; k < length; ++k) {{
        sj_uart_putc((char)frame[k]);
    }}
}}

int main(void)
{{
    uint32_t now = 0u;
    uint32_t id = 0u;
    uint8_t length = 0u;
    (void){prefix}_can_init(&{prefix}_controller, {PREFIX}_CAN_LAW_CLQG);
    (void){prefix}_xcp_init(&xcp, 0u);
    for (;;) {{
        unsigned int k;
        id = sj_uart_get_u32();
        length = (uint8_t)sj_uart_getc();
        if (length == 0u) {{
            (void){prefix}_can_step(&{prefix}_controller, now);
            {prefix}_xcp_event(&xcp, now);
            while ({prefix}_can_tx(&{prefix}_controller, &id, frame, &length) != 0) {{
                send(id, length);
            }}
            while ({prefix}_xcp_tx(&xcp, frame, &length) != 0) {{
                send({PREFIX}_XCP_ID_SLAVE, length);
            }}
            now += {PREFIX}_CAN_CYCLE_US;
            continue;
        }}
        for (k = 0u; k < length && k < sizeof frame; ++k) {{
            frame[k] = (uint8_t)sj_uart_getc();
        }}
        if (id == {PREFIX}_XCP_ID_MASTER) {{
            {prefix}_xcp_rx(&xcp, frame, length, now);
        }} else {{
            (void){prefix}_can_rx(&{prefix}_controller, id, frame, length, now);
        }}
    }}
}}
"""


def _compile_and_link(a, folder: Path, callgraph: bool, prefix: str, without=(), xcp: bool = False) -> list[str]:
    """The image's objects built and linked into ``image.elf`` (with ``image.map``), the laws
    ``without`` left out of the build, with ``xcp`` the XCP slave (at -Os, as the generated
    Makefile builds it) and a main that serves it; the names of the compiled modules."""
    files = {**generate.render(a, "float", prefix), **can_layer.render_can(a, prefix, real="float")}
    if xcp:
        files.update(xcp_slave.render_xcp(a, prefix, "float", Xcp()))
    output.write({k: v for k, v in files.items() if k.endswith((".c", ".h"))}, folder)
    (folder / "image_main.c").write_text((MAIN_XCP if xcp else MAIN).format(prefix=prefix, PREFIX=prefix.upper()))
    laws = [law.c_name(prefix) for law in law_registry.LAWS.values() if law.name not in without]
    slave = [f"{prefix}_xcp", f"{prefix}_xcp_key"] if xcp else []
    modules = [*laws, f"{prefix}_can", "sj_e2e", *slave, "image_main", "startup", "board"]
    flags = [*TARGET, "-O2", "-ffunction-sections", "-fdata-sections", "-fstack-usage", *BASE_FLAGS]
    flags += [f"-D{prefix.upper()}_CAN_WITHOUT_{name.upper()}" for name in without]
    flags += ["-fcallgraph-info=su"] if callgraph else []
    for name in modules:
        source = BOARD / f"{name}.c" if name in ("startup", "board") else folder / f"{name}.c"
        level = ["-Os"] if name in slave else []  # the last -O wins
        run(["arm-none-eabi-gcc", *flags, *level, f"-I{BOARD}", "-I.", "-c", str(source), "-o", f"{name}.o"],
            cwd=folder)  # fmt: skip
    run(
        [
            "arm-none-eabi-gcc",
            *TARGET,
            "--specs=nano.specs",
            "-nostartfiles",
            "-Wl,--gc-sections",
            f"-Wl,-T,{BOARD / 'mps2_an386.ld'}",
            "-Wl,-Map,image.map",
            *[f"{n}.o" for n in modules],
            "-lm",
            "-o",
            "image.elf",
        ],
        cwd=folder,
    )
    return modules


def double_routines(folder: Path) -> list[str]:
    """Every double-precision routine in the linked image (``nm``), and any the map names."""
    names = {line.split()[-1] for line in run(["arm-none-eabi-nm", "image.elf"], cwd=folder).splitlines() if line}
    found = {n for n in names if DOUBLE_ROUTINE.match(n) or n in LIBM_DOUBLE}
    mapped = (folder / "image.map").read_text()
    found |= {m for m in re.findall(r"\b(__aeabi_d\w+|__\w+df\d)\b", mapped) if m in names}
    return sorted(found)


def _code(obj: Path) -> int:
    """.text and .rodata of an object compiled with -ffunction-sections -fdata-sections (before
    --gc-sections drops what no entry point reaches)."""
    return sum(size for name, size in sections(obj).items() if name.startswith((".text", ".rodata")))


def measure_image(
    a, folder: Path, callgraph: bool, prefix: str = "smartjoint", without=PRODUCT_WITHOUT, xcp: bool = False
) -> dict:
    """Flash, RAM, double routines and the stack bound of each CAN entry point of the image with
    every law but ``without`` (default: the product image, :data:`PRODUCT_WITHOUT`), with ``xcp``
    its XCP slave."""
    folder.mkdir(parents=True)
    modules = _compile_and_link(a, folder, callgraph, prefix, tuple(without), xcp)
    image = Disassembly(folder / "image.elf")
    su: dict = {}
    graph: dict = {}
    for name in modules:
        su.update(stack_usage(folder / f"{name}.su"))
        graph.update(callgraph_ci(folder / f"{name}.ci") if callgraph else {})
    if not callgraph:
        graph = {f: image.callees(f) for f in su}
    frames = {f: size for f, (size, _) in su.items()}
    stacks = {}
    for entry in ENTRIES:
        depth, chain, _ = worst_stack(f"{prefix}_can_{entry}", frames, graph, image)
        stacks[entry] = {"bytes": depth, "chain": chain}
    parts = sections(folder / "image.elf")
    flash = sum(parts.get(s, 0) for s in FLASH_SECTIONS)
    ram = sum(parts.get(s, 0) for s in RAM_SECTIONS)
    symbols = {}
    for line in run(["arm-none-eabi-nm", "-S", "--size-sort", "image.elf"], cwd=folder).splitlines():
        fields = line.split()
        if len(fields) == 4 and fields[2] in "bBdD":
            symbols[fields[3]] = int(fields[1], 16)
    return {
        "flash": flash,
        "ram": ram,
        "sections": {s: parts.get(s, 0) for s in FLASH_SECTIONS + (".bss", ".stack")},
        "ram_symbols": dict(sorted(symbols.items(), key=lambda kv: -kv[1])),
        "double_routines": double_routines(folder),
        "stack": stacks,
        "stack_max": max(s["bytes"] for s in stacks.values()),
        "modules_code": {n: _code(folder / f"{n}.o") for n in modules},
        "laws_left_out": list(without),
        "limits_bytes": LIMITS,
        "targets_met": {"flash": flash <= LIMITS["flash"], "ram": ram <= LIMITS["ram"]},
        "flags": [*TARGET, "-O2", "-ffunction-sections", "-fdata-sections", *BASE_FLAGS],
        "link": "--specs=nano.specs -nostartfiles -Wl,--gc-sections -T mps2_an386.ld -lm",
    }


def print_whole_image(whole: dict) -> None:
    """Flash, RAM, double routines and stack bounds of the whole linked firmware image."""
    mark = lambda ok: "✔" if ok else "✘"  # noqa: E731
    left_out = ", ".join(whole["laws_left_out"])
    print(
        f"\nwhole firmware image (float -O2, --gc-sections: every law{' but ' + left_out if left_out else ''} + CAN "
        "layer + E2E + runtime main with firmware/target/mps2_an386 startup and board):"
    )
    s = whole["sections"]
    print(
        f"  flash {whole['flash']:5d} B {mark(whole['targets_met']['flash'])} ≤ {whole['limits_bytes']['flash']}  "
        + "("
        + ", ".join(f"{k} {s[k]}" for k in FLASH_SECTIONS)
        + "; modules' .text + .rodata before --gc-sections: "
        + ", ".join(f"{k} {v}" for k, v in whole["modules_code"].items())
        + ")"
    )
    top = ", ".join(f"{k} {v}" for k, v in list(whole["ram_symbols"].items())[:4])
    print(
        f"  RAM   {whole['ram']:5d} B {mark(whole['targets_met']['ram'])} ≤ {whole['limits_bytes']['ram']}  "
        f"(.data {s['.data']} + .bss {s['.bss']}: {top}; the {s['.stack']} B stack region apart)"
    )
    print(f"  double-precision routines linked: {', '.join(whole['double_routines']) or 'none'}")
    for entry, bound in whole["stack"].items():
        print(f"  stack bound {entry:5s} {bound['bytes']:4d} B  ({' → '.join(bound['chain'])})")


XCP_LIMITS = {"flash": 3 * 1024, "ram": 512}  # what the XCP slave may add (issue 34)


def print_xcp(whole: dict, with_xcp: dict) -> dict:
    """What the XCP slave adds to the product image (its main serving the slave too), against
    :data:`XCP_LIMITS`; returned for the JSON."""
    added = {"flash": with_xcp["flash"] - whole["flash"], "ram": with_xcp["ram"] - whole["ram"]}
    met = {k: added[k] <= XCP_LIMITS[k] for k in added}
    mark = lambda ok: "✔" if ok else "✘"  # noqa: E731
    top = ", ".join(f"{k} {v}" for k, v in with_xcp["ram_symbols"].items() if k not in whole["ram_symbols"])
    print(
        f"\nXCP slave (-Os) in the product image: flash +{added['flash']} B {mark(met['flash'])} ≤ "
        f"{XCP_LIMITS['flash']}, RAM +{added['ram']} B {mark(met['ram'])} ≤ {XCP_LIMITS['ram']} ({top}); stack "
        + ", ".join(f"{e} {b['bytes']} B" for e, b in with_xcp["stack"].items())
    )
    return {"added": added, "limits_bytes": XCP_LIMITS, "targets_met": met}
