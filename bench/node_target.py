"""A joint node's firmware on its target, QEMU's mps2-an386 (Cortex-M4F), measured, not estimated.

Two images per joint, both from the float build of ``codegen.joint_nodes`` with the committed
startup, board support and linker script of ``firmware/target/mps2_an386``, built as the target
Makefile builds (``-O2 -ffunction-sections -fdata-sections``, newlib-nano, ``--gc-sections``):

* the **node image**: the node and a minimal runtime whose UART stands in for the ADC and the CAN
  controller (a frame: id, length, payload into ``<prefix>_node_rx``; a sample: the three
  measurements into ``<prefix>_node_step``, the command, the node's faults and status and any
  status frame back, then an end mark). Its flash (vectors, .text, .rodata, .ARM.exidx, .data
  image) and RAM (.data + .bss; the linker script's stack region apart) are the node's figures.
  :class:`TargetNode` runs it in the emulator beside the SIL bench (processor in the loop: the
  local loop's ``target_joints``);
* the **self-test**: a valid heartbeat of the node law's mode, then ``steps`` seeded samples timed
  with SysTick under ``-icount shift=0`` (40 instructions a tick), the loop around an empty step
  subtracted, and every command printed for the host to compare with its own float build.
"""

from __future__ import annotations

import socket
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from smartjoint.bench import e2e, target
from smartjoint.codegen import generate, joint_nodes, output
from smartjoint.common import package_data
from smartjoint.common.errors import ModelError
from smartjoint.design.network import joint_node

BOARD = package_data.folder("smartjoint.firmware", "target/mps2_an386")
CFLAGS = [
    "-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard", "-std=c99", "-O2",
    "-ffp-contract=off", "-ffunction-sections", "-fdata-sections",
    "-Wall", "-Wextra", "-Wpedantic", "-Wconversion", "-Wdouble-promotion", "-Wshadow", "-Werror",
]  # fmt: skip
LDFLAGS = [
    "-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard",
    "--specs=nano.specs", "-nostartfiles", "-Wl,--gc-sections",
]  # fmt: skip
FLASH_SECTIONS = (".vectors", ".text", ".rodata", ".ARM.exidx", ".data")
RAM_SECTIONS = (".data", ".bss")
LIMITS = {"flash": 4096, "ram": 256, "instructions": 200}  # issue 33's targets for a node

RUNTIME = """/* Minimal runtime of a joint node image (bench/node_target.py): the UART stands in for the
 * ADC and the CAN controller. In: id (4 bytes, little-endian), length, payload; length 0 is a
 * sample, followed by v, u_R, F_N (4-byte floats). Out: the command, the node's faults and
 * status (4 bytes each), each status frame (id, length, payload), then the end mark 0xFFFFFFFF. */
#include <stdint.h>
#include <string.h>

#include "board.h"
#include "{name}.h"

#define END_MARK 0xFFFFFFFFu /* no frame has this id: CAN ids are 29 bits at most */

static {name}_state state;
static uint8_t frame[64];

static float get_float(void)
{{
    const uint32_t bits = sj_uart_get_u32();
    float value;
    memcpy(&value, &bits, sizeof value);
    return value;
}}

int main(void)
{{
    {name}_input input;
    uint32_t id, bits;
    uint8_t length;
    float command;
    unsigned int k;
    {name}_init(&state, &{name}_{joint}_config);
    for (;;) {{
        id = sj_uart_get_u32();
        length = (uint8_t)sj_uart_getc();
        if (length == 0u) {{
            input.sliding_velocity = get_float();
            input.friction_force = get_float();
            input.normal_force = get_float();
            command = {name}_step(&state, &input);
            memcpy(&bits, &command, sizeof bits);
            sj_uart_put_u32(bits);
            sj_uart_put_u32(state.faults);
            sj_uart_put_u32(state.status);
            while ({name}_tx(&state, &id, frame, &length) != 0) {{
                sj_uart_put_u32(id);
                sj_uart_putc((char)length);
                for (k = 0u; k < length; ++k) {{
                    sj_uart_putc((char)frame[k]);
                }}
            }}
            sj_uart_put_u32(END_MARK);
            continue;
        }}
        for (k = 0u; k < length && k < sizeof frame; ++k) {{
            frame[k] = (uint8_t)sj_uart_getc();
        }}
        (void){name}_rx(&state, id, frame, length);
    }}
}}
"""

SELFTEST = """/* Self-test of a joint node (bench/node_target.py): a heartbeat, then the timed samples. */
#include <stdint.h>
#include <string.h>

#include "board.h"
#include "{name}.h"
#include "node_inputs.h"

static {name}_state state;
static float commands[SJ_NODE_STEPS];

typedef float (*step_fn)({name}_state *, const {name}_input *);

__attribute__((noinline)) static float empty({name}_state *node, const {name}_input *input)
{{
    __asm__ volatile("" : : "r"(node), "r"(input) : "memory");
    return 0.0f;
}}

__attribute__((noinline)) static uint32_t loop(step_fn step)
{{
    uint32_t start;
    int k;
    {name}_init(&state, &{name}_{joint}_config);
    (void){name}_rx(&state, {NAME}_HEARTBEAT_ID, sj_node_heartbeat, (uint8_t)sizeof sj_node_heartbeat);
    start = sj_ticks();
    for (k = 0; k < SJ_NODE_STEPS; ++k) {{
        commands[k] = step(&state, &sj_node_inputs[k]);
    }}
    return sj_ticks() - start;
}}

int main(void)
{{
    uint32_t empty_ticks, step_ticks, bits;
    int k;
    sj_ticks_start();
    empty_ticks = loop(empty);
    step_ticks = loop({name}_step);
    sj_uart_puts("SJ-NODE\\n");
    for (k = 0; k < SJ_NODE_STEPS; ++k) {{
        memcpy(&bits, &commands[k], sizeof bits);
        sj_uart_puts("command ");
        sj_uart_hex32(bits);
        sj_uart_putc('\\n');
    }}
    sj_uart_puts("ticks ");
    sj_uart_dec(step_ticks);
    sj_uart_puts("\\nempty ");
    sj_uart_dec(empty_ticks);
    sj_uart_puts("\\nEND\\n");
    return 0;
}}
"""


def node_inputs(artifact, joint: int, steps: int, seed: int) -> np.ndarray:
    """Seeded samples (v, u_R, F_N) of joint ``joint``, every one usable, around its boundary
    layer (μ·v/ε between the clip's ends for most), as float32."""
    rng = np.random.default_rng(seed)
    config = joint_node.node_config(artifact, joint)
    rows = np.column_stack(
        [
            rng.normal(0.0, 3.0 * config.boundary_layer, steps),
            rng.normal(0.0, 0.1 * config.friction_force_limit, steps),
            rng.uniform(config.normal_force_min, config.normal_force_max, steps),
        ]
    )
    return rows.astype(np.float32)


def heartbeat() -> bytes:
    """A valid heartbeat commanding the node law (alive counter 1)."""
    payload = bytearray(joint_node.HEARTBEAT_LENGTH)
    payload[2] = joint_node.NODE_LAW.mode
    return bytes(e2e.protect(joint_node.HEARTBEAT_ID, payload, 1))


def _inputs_header(rows: np.ndarray, name: str) -> str:
    lines = [
        "#ifndef NODE_INPUTS_H",
        "#define NODE_INPUTS_H",
        f"#define SJ_NODE_STEPS {len(rows)}",
        "static const uint8_t sj_node_heartbeat[] = {" + ", ".join(f"{b}u" for b in heartbeat()) + "};",
        f"static const {name}_input sj_node_inputs[SJ_NODE_STEPS] = {{",
    ]
    lines += ["    {" + ", ".join(f"{float(v)!r}f" for v in row) + "}," for row in rows]
    lines += ["};", "#endif"]
    return "\n".join(lines) + "\n"


def _run(command: list[str], cwd: Path, timeout: float = 120.0) -> str:
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout, cwd=cwd)
    except subprocess.TimeoutExpired:
        raise ModelError(f"{command[0]}: did not finish within {timeout:g} s") from None
    if done.returncode != 0:
        raise ModelError(f"{command[0]} failed: {(done.stderr or done.stdout).strip().splitlines()[-1:]}")
    return done.stdout


def _link(folder: Path, sources: list[str], elf: str) -> None:
    objects = []
    for source in sources:
        path = BOARD / source if source in ("startup.c", "board.c") else folder / source
        obj = f"{Path(source).stem}.o"
        _run(["arm-none-eabi-gcc", *CFLAGS, f"-I{BOARD}", "-I.", "-c", str(path), "-o", obj], folder)
        objects.append(obj)
    _run(["arm-none-eabi-gcc", *LDFLAGS, f"-Wl,-T,{BOARD / 'mps2_an386.ld'}", *objects, "-lm", "-o", elf], folder)


def _sections(elf: Path) -> dict[str, int]:
    out = {}
    for line in _run(["arm-none-eabi-size", "-A", str(elf)], elf.parent).splitlines():
        words = line.split()
        if len(words) >= 2 and words[0].startswith(".") and words[1].isdigit():
            out[words[0]] = int(words[1])
    return out


def _write_node_sources(artifact, joint: int, folder: Path, prefix: str) -> list[str]:
    """The float node firmware, its E2E runtime and the UART runtime of joint ``joint`` into
    ``folder``; the sources of the node image but its ``main`` (``node_main.c`` for the image)."""
    name = f"{prefix}_node"
    files = joint_nodes.render_nodes(artifact, prefix, "float")
    files[f"{prefix}_types.h"] = generate.render(artifact, "float", prefix)[f"{prefix}_types.h"]
    for runtime in ("sj_e2e.c", "sj_e2e.h"):
        files[runtime] = (e2e.RUNTIME / runtime).read_text()
    output.write({k: v for k, v in files.items() if k.endswith((".c", ".h"))}, folder)
    (folder / "node_main.c").write_text(RUNTIME.format(name=name, joint=artifact.joint_names[joint].lower()))
    return [f"{name}.c", f"{name}_config.c", "sj_e2e.c", "startup.c", "board.c"]


class TargetNode:
    """One joint's node image running in the emulator, behind ``JointNode``'s interface
    (``receive``, ``step``, ``transmit``, ``faults``, ``status``): processor in the loop for a
    node of local mode. The bench talks to the image's UART over TCP (the runtime's protocol,
    module docstring). Close it (or use it as a context manager): that ends the emulation.

    Parameters
    ----------
    artifact : ControllerArtifact
        The design the node firmware is generated from (float build, the target's).
    joint : int
        The joint whose node it is.
    timeout : float
        Seconds the target may take to answer one request before the run is stopped.
    """

    END_MARK = 0xFFFFFFFF

    def __init__(self, artifact, joint: int, prefix: str = "smartjoint", timeout: float = 30.0):
        from smartjoint.bench import pil

        reason = target.missing_tools()
        if reason:
            raise ModelError(reason)
        self.timeout = float(timeout)
        self._scratch = tempfile.TemporaryDirectory(prefix="sj-node-pil-")
        folder = Path(self._scratch.name)
        _link(folder, [*_write_node_sources(artifact, joint, folder, prefix), "node_main.c"], "node.elf")
        self._port = pil.free_port()
        self._command = pil.emulator_command(folder / "node.elf", self._port)
        self.process: subprocess.Popen | None = None
        self.socket: socket.socket | None = None
        self.reset()

    def reset(self) -> None:
        """A new emulation: the node powered up as after reset."""
        import time

        self._stop()
        self._pending: list[tuple[int, bytes]] = []
        self.faults = self.status = 0
        self.process = subprocess.Popen(self._command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + self.timeout
        while True:
            try:
                self.socket = socket.create_connection(("127.0.0.1", self._port), timeout=self.timeout)
                self.socket.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                return
            except OSError as error:
                if self.process.poll() is not None or time.monotonic() > deadline:
                    self._stop()
                    raise ModelError(f"target {target.BOARD}: cannot reach the node's UART ({error})") from None
                time.sleep(0.05)

    def _read(self, count: int) -> bytes:
        data = b""
        while len(data) < count:
            chunk = self.socket.recv(count - len(data)) if self.socket is not None else b""
            if not chunk:
                raise ModelError(f"target {target.BOARD}: the node image stopped answering")
            data += chunk
        return data

    def _word(self) -> int:
        return int.from_bytes(self._read(4), "little")

    def receive(self, frame_id: int, data: bytes) -> bool:
        """A frame from the bus into the node (its RX result stays on the target)."""
        assert self.socket is not None
        self.socket.sendall(int(frame_id).to_bytes(4, "little") + bytes([len(data)]) + bytes(data))
        return True

    def step(self, velocity: float, friction: float, applied: float) -> float:
        """One sample: the three measurements in, the command out (and the node's status frames)."""
        assert self.socket is not None
        payload = np.array([velocity, friction, applied], dtype="<f4").tobytes()
        self.socket.sendall(b"\0\0\0\0\0" + payload)
        command = float(np.frombuffer(self._read(4), dtype="<f4")[0])
        self.faults, self.status = self._word(), self._word()
        while (frame_id := self._word()) != self.END_MARK:
            length = self._read(1)[0]
            self._pending.append((frame_id, self._read(length)))
        return command

    def transmit(self) -> tuple[int, bytes] | None:
        return self._pending.pop(0) if self._pending else None

    def _stop(self) -> None:
        sock, self.socket = self.socket, None
        if sock is not None:
            sock.close()
        process, self.process = self.process, None
        if process is not None:
            process.kill()
            process.wait(timeout=10.0)
            if process.stderr is not None:
                process.stderr.close()

    def close(self) -> None:
        """End the emulation and remove the image."""
        self._stop()
        self._scratch.cleanup()

    def __enter__(self) -> TargetNode:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def measure(artifact, joint: int = 0, steps: int = 500, seed: int = 33, prefix: str = "smartjoint") -> dict:
    """The node image of joint ``joint``: flash and RAM, instructions per step on the target
    (mean over ``steps``), and the commands the target computed (float32), with the inputs.

    Raises
    ------
    ModelError
        A missing tool, a failed build or a self-test that did not run to its end.
    """
    reason = target.missing_tools()
    if reason:
        raise ModelError(reason)
    name = f"{prefix}_node"
    joint_name = artifact.joint_names[joint].lower()
    rows = node_inputs(artifact, joint, steps, seed)
    with tempfile.TemporaryDirectory(prefix="sj-node-") as work:
        folder = Path(work)
        node = _write_node_sources(artifact, joint, folder, prefix)
        (folder / "node_selftest.c").write_text(SELFTEST.format(name=name, NAME=name.upper(), joint=joint_name))
        (folder / "node_inputs.h").write_text(_inputs_header(rows, name))
        _link(folder, [*node, "node_main.c"], "node.elf")
        _link(folder, [*node, "node_selftest.c"], "selftest.elf")
        parts = _sections(folder / "node.elf")
        done = subprocess.run(target.qemu_command(folder / "selftest.elf"), capture_output=True, text=True, timeout=120)
    lines = done.stdout.replace("\r", "").splitlines()
    if "SJ-NODE" not in lines or "END" not in lines:
        raise ModelError(f"target {target.BOARD}: the node self-test did not run to its end: {lines[-3:]}")
    body = lines[lines.index("SJ-NODE") + 1 : lines.index("END")]
    commands = np.array([int(line.split()[1], 16) for line in body if line.startswith("command")], dtype=np.uint32)
    figures = {line.split()[0]: int(line.split()[1]) for line in body if not line.startswith("command")}
    per_tick = 40  # board.h: SJ_INSTRUCTIONS_PER_TICK at -icount shift=0 and a 25 MHz SysTick
    return {
        "joint": artifact.joint_names[joint],
        "flash": sum(parts.get(s, 0) for s in FLASH_SECTIONS),
        "ram": sum(parts.get(s, 0) for s in RAM_SECTIONS),
        "sections": {s: parts.get(s, 0) for s in (*FLASH_SECTIONS, ".bss", ".stack")},
        "instructions_per_step": per_tick * (figures["ticks"] - figures["empty"]) / steps,
        "resolution": per_tick / steps,
        "steps": steps,
        "commands": commands.view(np.float32),
        "inputs": rows,
        "limits": LIMITS,
    }


__all__ = ["LIMITS", "TargetNode", "heartbeat", "measure", "node_inputs"]
