"""The generated firmware on its target: QEMU's ``mps2-an386`` (Cortex-M4 with FPU).

:func:`run_selftest` builds the target self-test (``firmware/target/mps2_an386``: startup, board
support, self-test) with ``arm-none-eabi-gcc`` from the same generated sources the SIL bench
compiles (``bench.firmware.sources``, float build), runs it in ``qemu-system-arm`` with
``-icount shift=0`` (one instruction is one nanosecond of virtual time) and reads what it prints
over UART 0: every output word of both controllers for a fixed input sequence, SysTick ticks of
the step loops, and stack depths by painting. Flash and RAM come from the ELF
(``arm-none-eabi-size``). Everything is built in a temporary folder; the source tree is only read.

This is the target half of processor-in-the-loop: the closed loop over a transport (issue 19's
``smartjoint pil``) is not here yet.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from smartjoint.bench import firmware
from smartjoint.common import law_registry, package_data
from smartjoint.common.errors import ModelError
from smartjoint.design.control.artifact import ControllerArtifact

BOARD = "mps2-an386"
TOOLS = ("arm-none-eabi-gcc", "arm-none-eabi-size", "arm-none-eabi-nm", "make", "qemu-system-arm")
PREFIX = "smartjoint"  # the self-test calls the controllers by this prefix
# The laws of the registry by name, in the self-test's order, and the fields of their input structs.
INPUT_FIELDS = {name: law_registry.LAWS[name].inputs for name in sorted(law_registry.LAWS)}
FIRMWARE_OBJECTS = (*(f"{PREFIX}_{law}.o" for law in INPUT_FIELDS), f"{PREFIX}_can.o", "sj_e2e.o")
# The self-test's own arrays (the sequence and what it gave), not firmware.
SEQUENCE_TABLES = tuple(
    f"{kind.format(law)}" for kind in ("sj_{}_inputs", "{}_outputs", "{}_status") for law in INPUT_FIELDS
)
# The random measurements of the sequence (before the scale) that not every law reads: standard
# deviation, drawn in this order, so that every law's rows come from one set of draws.
_DRAWS = {"sensors": 1e-4, "sliding_velocity": 1e-3}


def qemu_command(elf: Path) -> list[str]:
    """The emulator's command line for an image: the board, UART 0 on stdout, semihosting for
    the exit status, and instruction counting (one instruction per nanosecond)."""
    return [
        "qemu-system-arm", "-M", BOARD, "-nographic", "-monitor", "none",
        "-semihosting-config", "enable=on,target=native", "-icount", "shift=0", "-kernel", str(elf),
    ]  # fmt: skip


def missing_tools() -> str | None:
    """One line naming the tools the target needs that are not installed, or None."""
    missing = [tool for tool in TOOLS if shutil.which(tool) is None]
    if not missing:
        return None
    return (
        f"target {BOARD}: {', '.join(missing)} not installed "
        "(Debian/Ubuntu: apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm make)"
    )


def sequence(artifact: ControllerArtifact, steps: int = 200, seed: int = 19) -> dict[str, np.ndarray]:
    """A fixed input sequence of both laws (float32 rows, the input struct's fields in order):
    random measurements at scales from 1e-3 to 1 times (0.1 mm tip, 1 mm/s slip, 50 N
    friction), small enough that most commands lie between the force limits, none of them NaN."""
    rng = np.random.default_rng(seed)
    l, ny = len(artifact.joint_names), len(artifact.sensor_names)
    scale = 10.0 ** rng.uniform(-3, 0, (steps, 1))
    drawn = {"friction_force": rng.normal(0, 50, (steps, l)) * scale, "normal_force": rng.uniform(0, 400, (steps, l))}
    for field, deviation in _DRAWS.items():
        drawn[field] = rng.normal(0, deviation, (steps, ny if field == "sensors" else l)) * scale
    return {
        law: np.hstack([drawn[field] for field in fields]).astype(np.float32) for law, fields in INPUT_FIELDS.items()
    }


def inputs_header(artifact: ControllerArtifact, rows: dict[str, np.ndarray]) -> str:
    """``selftest_inputs.h``: the laws' headers and X-macro lists (``SJ_LAWS``, ``SJ_PHASED_LAWS``),
    the CAN layer's law, and the sequence as C99 hexadecimal float literals (exact)."""
    sizes = {"sensors": len(artifact.sensor_names)}
    steps = len(next(iter(rows.values())))
    laws = law_registry.LAWS.values()
    out = ["/* Input sequence of the target self-test and its laws, written by bench/target.py. */",
           *(f'#include "{law.c_name(PREFIX)}.h"' for law in laws),
           f"#define SJ_LAWS(X) {' '.join(f'X({law.name})' for law in laws)}",
           f"#define SJ_PHASED_LAWS(X) {' '.join(f'X({law.name})' for law in laws if law.phased)}",
           f"#define SJ_CAN_LAW {PREFIX.upper()}_CAN_LAW_{law_registry.fault_matrix_law().name.upper()}",
           f"#define SJ_SELFTEST_STEPS {steps}"]  # fmt: skip
    for law, fields in INPUT_FIELDS.items():
        out.append(f"static const {PREFIX}_{law}_input sj_{law}_inputs[SJ_SELFTEST_STEPS] = {{")
        for row in rows[law]:
            at, parts = 0, []
            for field in fields:
                n = sizes.get(field, len(artifact.joint_names))
                values = ", ".join(f"{float(v).hex()}f" for v in row[at : at + n])
                parts.append(f".{field} = {{{values}}}")
                at += n
            out.append(f"    {{{', '.join(parts)}}},")
        out.append("};")
    return "\n".join(out) + "\n"


def _run(command: list[str], what: str, timeout: float, cwd: Path | None = None) -> subprocess.CompletedProcess:
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout, cwd=cwd)
    except subprocess.TimeoutExpired:
        raise ModelError(f"target {BOARD}: {what} did not finish within {timeout:g} s") from None
    return done


def _sizes(elf: Path, objects: list[Path]) -> dict[str, int]:
    """Flash (text + data) and RAM (data + bss) of the firmware objects alone and of the linked
    image (startup, board support, self-test, library routines) without the self-test's sequence
    tables and the stack reservation (``stack_reserved``; the stack's use is measured apart)."""

    def berkeley(paths: list[Path]) -> np.ndarray:
        lines = _run(["arm-none-eabi-size", *map(str, paths)], "arm-none-eabi-size", 60).stdout.splitlines()[1:]
        return np.array([[int(word) for word in line.split()[:3]] for line in lines]).sum(axis=0)

    tables = {"flash": 0, "ram": 0}
    for line in _run(["arm-none-eabi-nm", "-S", str(elf)], "arm-none-eabi-nm", 60).stdout.splitlines():
        words = line.split()
        if len(words) == 4 and words[3] in SEQUENCE_TABLES:
            tables["flash" if words[2] in "rR" else "ram"] += int(words[1], 16)
    image, own = berkeley([elf]), berkeley(objects)
    stack = int(
        _run(["arm-none-eabi-size", "-A", str(elf)], "arm-none-eabi-size", 60).stdout.split(".stack")[1].split()[0]
    )
    return {
        "firmware_flash": int(own[0] + own[1]),
        "firmware_ram": int(own[1] + own[2]),
        "image_flash": int(image[0] + image[1]) - tables["flash"],
        "image_ram": int(image[1] + image[2]) - tables["ram"] - stack,
        "sequence_tables": tables["flash"] + tables["ram"],
        "stack_reserved": stack,
    }


def parse(text: str) -> dict:
    """The self-test's UART output: output words and status per law and step, and the figures."""
    words: dict[str, list[list[int]]] = {law: [] for law in INPUT_FIELDS}
    status: dict[str, list[int]] = {law: [] for law in INPUT_FIELDS}
    figures: dict[str, int] = {}
    lines = text.replace("\r", "").splitlines()
    if "SJ-SELFTEST mps2-an386" not in lines or "END" not in lines:
        tail = " | ".join(lines[-3:]) or "no output"
        raise ModelError(f"target {BOARD}: the self-test did not run to its end: {tail}")
    for line in lines[lines.index("SJ-SELFTEST mps2-an386") + 1 : lines.index("END")]:
        name, *fields = line.split()
        if name in words:
            status[name].append(int(fields[0], 16))
            words[name].append([int(word, 16) for word in fields[1:]])
        else:
            figures[name] = int(fields[0])
    outputs = {law: np.array(rows, dtype=np.uint32).view(np.float32) for law, rows in words.items()}
    return {"outputs": outputs, "status": {law: np.array(s) for law, s in status.items()}, "figures": figures}


def _build(artifact: ControllerArtifact, rows: dict[str, np.ndarray], work: Path, timeout: float) -> Path:
    """Make the self-test image in ``work`` from the SIL bench's generated float sources."""
    generated = work / "generated"
    generated.mkdir()
    for name, text in firmware.sources(artifact, "float", PREFIX).items():
        (generated / name).write_text(text)
    (work / "selftest_inputs.h").write_text(inputs_header(artifact, rows))
    board = package_data.folder("smartjoint.firmware", "target/mps2_an386")
    done = _run(
        ["make", "-s", "-C", str(board), f"GENERATED={generated}", f"BUILD={work / 'build'}", f"INPUTS={work}"],
        "make",
        timeout,
    )
    if done.returncode != 0:
        raise ModelError(f"target {BOARD}: the build failed:\n{(done.stderr or done.stdout).strip()}")
    return work / "build" / "selftest.elf"


def run_selftest(artifact: ControllerArtifact, steps: int = 200, seed: int = 19, timeout: float = 120.0) -> dict:
    """Build the self-test image, run it in QEMU and return what it measured.

    Parameters
    ----------
    artifact : ControllerArtifact
        The controller design artefact the firmware is generated from.
    steps, seed : int
        Length and seed of the fixed input sequence (:func:`sequence`).
    timeout : float
        Seconds for the build and for the emulation, each.

    Returns
    -------
    dict
        ``inputs`` and ``outputs`` per law (float32 rows), ``status`` per law, ``exit_code``,
        ``instructions`` per step per law (mean over the sequence, the empty loop subtracted;
        ``clqg_output_phase``: the cLQG's output phase alone, less an empty function's call),
        ``stack`` (bytes below main's frame: the ``clqg`` and ``siso`` loops, the ``can`` entry
        points; ``high_water`` of the whole program),
        ``size`` (bytes, :func:`_sizes`), ``command`` and the raw ``figures``.

    Raises
    ------
    ModelError
        A tool is missing (one line), the build failed, or the program did not run to its end.
    """
    reason = missing_tools()
    if reason:
        raise ModelError(reason)
    rows = sequence(artifact, steps, seed)
    with tempfile.TemporaryDirectory(prefix="smartjoint-target-") as scratch:
        work = Path(scratch)
        elf = _build(artifact, rows, work, timeout)
        command = qemu_command(elf)
        done = _run(command, "the emulation", timeout)
        result = parse(done.stdout)
        size = _sizes(elf, [work / "build" / name for name in FIRMWARE_OBJECTS])
    figures = result["figures"]
    per_tick = figures["instructions_per_tick"]
    instructions = {
        law: per_tick * (figures[f"ticks_{law}"] - figures[f"ticks_{law}_empty"]) / figures["steps"]
        for law in INPUT_FIELDS
    }
    # A phased law's loop that runs its output phase once more, less the one with an empty call there.
    for law in law_registry.LAWS.values():
        if law.phased:
            phase = f"{law.name}_output_phase"
            instructions[phase] = per_tick * figures[f"ticks_{phase}"] / figures["steps"]
    stack = {law: figures[f"stack_{law}"] for law in (*INPUT_FIELDS, "can")}
    stack["high_water"] = figures["stack_high_water"]
    command[-1] = "selftest.elf"
    return {
        **result,
        "inputs": rows,
        "exit_code": done.returncode,
        "instructions": instructions,
        "stack": stack,
        "size": size,
        "command": " ".join(command),
    }
