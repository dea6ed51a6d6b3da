"""The generated firmware (controllers + CAN message layer + E2E runtime) compiled with cffi.

``Firmware`` is what the SIL bench talks to: frames in (``rx``), one ``step`` per sample, frames
out (``tx``), exactly the C entry points of the target. The generated sources are compiled alone
with the strict warning set (``codegen.build.FLAGS``); only cffi's glue is compiled without it.
"""

from __future__ import annotations

import hashlib

import numpy as np

from smartjoint.codegen import build, can_layer, generate
from smartjoint.common import native
from smartjoint.design.control.artifact import ControllerArtifact
from smartjoint.common.errors import ModelError
from smartjoint.design.network import protocol

LAWS = {"siso": 1, "clqg": 2}


def _cdef(prefix: str, messages) -> str:
    name = f"{prefix}_can"
    out = []
    for m in messages:
        fields = " ".join(f"double {s.name};" for s in sorted(m.signals, key=lambda s: s.start))
        lower = m.name.lower()
        out.append(f"typedef struct {{ {fields} }} {name}_{lower}_t;")
        out.append(f"void {name}_pack_{lower}(const {name}_{lower}_t *signals, uint8_t *data);")
        out.append(f"void {name}_unpack_{lower}(const uint8_t *data, {name}_{lower}_t *signals);")
    out.append(_opaque(prefix))
    return "\n".join(out)


def _opaque(prefix: str) -> str:
    """Prototypes of the opaque-state accessors (cffi declarations and C glue alike)."""
    n = f"{prefix}_can"
    return f"""size_t {n}_state_size(void);
int {n}_init_opaque(uint8_t *state, int law);
unsigned int {n}_rx_opaque(uint8_t *state, uint32_t id, const uint8_t *data, uint8_t length, uint32_t time_us);
unsigned int {n}_step_opaque(uint8_t *state, uint32_t time_us);
int {n}_tx_opaque(uint8_t *state, uint32_t *id, uint8_t *data, uint8_t *length);
int {n}_safe(const uint8_t *state);
unsigned int {n}_faults(const uint8_t *state);
double {n}_command(const uint8_t *state, int joint);
uint32_t {n}_counter(const uint8_t *state, int which);
void {n}_set_steps(uint8_t *state, uint32_t steps);
"""


def _prototypes(prefix: str) -> str:
    return f'#include "{prefix}_can.h"\n\n' + _opaque(prefix)


def _driver(prefix: str) -> str:
    """Opaque-state accessors for Python (not part of the firmware)."""
    n = f"{prefix}_can"
    return _prototypes(prefix) + f"""
size_t {n}_state_size(void) {{ return sizeof({n}_state); }}
int {n}_init_opaque(uint8_t *state, int law) {{ return {n}_init(({n}_state *)(void *)state, ({n}_law)law); }}
unsigned int {n}_rx_opaque(uint8_t *state, uint32_t id, const uint8_t *data, uint8_t length, uint32_t time_us)
{{
    return {n}_rx(({n}_state *)(void *)state, id, data, length, time_us);
}}
unsigned int {n}_step_opaque(uint8_t *state, uint32_t time_us) {{ return {n}_step(({n}_state *)(void *)state, time_us); }}
int {n}_tx_opaque(uint8_t *state, uint32_t *id, uint8_t *data, uint8_t *length)
{{
    return {n}_tx(({n}_state *)(void *)state, id, data, length);
}}
int {n}_safe(const uint8_t *state) {{ return ((const {n}_state *)(const void *)state)->safe; }}
unsigned int {n}_faults(const uint8_t *state) {{ return ((const {n}_state *)(const void *)state)->faults; }}
double {n}_command(const uint8_t *state, int joint) {{ return ((const {n}_state *)(const void *)state)->command[joint]; }}
void {n}_set_steps(uint8_t *state, uint32_t steps) {{ (({n}_state *)(void *)state)->steps = steps; }}
uint32_t {n}_counter(const uint8_t *state, int which)
{{
    const {n}_state *s = (const {n}_state *)(const void *)state;
    switch (which) {{
    case 0: return s->rx_frames;
    case 1: return s->crc_errors;
    case 2: return s->counter_errors;
    case 3: return s->length_errors;
    case 4: return s->unknown_ids;
    case 5: return s->timeouts;
    case 6: return s->implausible_frames;
    default: return s->steps;
    }}
}}
"""


COUNTERS = ("rx_frames", "crc_errors", "counter_errors", "length_errors", "unknown_ids", "timeouts",
            "implausible_frames", "steps")


class Firmware:
    """One compiled firmware image (controllers + CAN layer) and one instance of its state."""

    def __init__(self, artifact: ControllerArtifact, law: str = "siso", real: str = "float",
                 prefix: str = "smartjoint", **can_options):
        if law not in LAWS:
            raise ModelError(f"law: {law!r} — allowed: {', '.join(LAWS)}")
        files = {**generate.render(artifact, real, prefix),
                 **can_layer.render_can(artifact, prefix, full_codec=True, **can_options)}
        files[f"_{prefix}_can_driver.c"] = _driver(prefix)
        digest = hashlib.sha256("\0".join(f"{k}\0{v}" for k, v in sorted(files.items())).encode()).hexdigest()[:16]
        folder = native.cache_dir() / f"firmware-{prefix}-{real}-{digest}"
        if not all((folder / k).exists() and (folder / k).read_text() == v for k, v in files.items()):
            generate.write(files, folder)
        objects = tuple(build.compile_object(folder / name, build.FLAGS) for name in
                        (f"{prefix}_siso.c", f"{prefix}_clqg.c", f"{prefix}_can.c", "sj_e2e.c",
                         f"_{prefix}_can_driver.c"))
        glue = folder / "_glue.c"
        glue_text = _prototypes(prefix)
        if not glue.exists() or glue.read_text() != glue_text:
            generate.write({"_glue.c": glue_text}, folder)
        self.db = protocol.load_dbc(files["bus.dbc"])
        module = native.load(f"firmware_{real}", _cdef(prefix, self.db.messages), glue, objects=objects,
                             includes=(folder,))
        self.ffi, self.lib, self.prefix, self.artifact, self.law = module.ffi, module.lib, prefix, artifact, law
        self.folder, self.files = folder, files
        self._name = f"{prefix}_can"
        self._state = self.ffi.new("uint8_t[]", int(getattr(self.lib, f"{self._name}_state_size")()))
        self._id = self.ffi.new("uint32_t *")
        self._data = self.ffi.new("uint8_t[64]")
        self._length = self.ffi.new("uint8_t *")
        self.reset()

    def _call(self, suffix, *args):
        return getattr(self.lib, f"{self._name}_{suffix}")(*args)

    def reset(self) -> None:
        if self._call("init_opaque", self._state, LAWS[self.law]) != 0:
            raise ModelError(f"firmware: the CAN layer refused law {self.law!r}")

    def rx(self, frame_id: int, data: bytes, time_us: int) -> int:
        return int(self._call("rx_opaque", self._state, frame_id & 0xFFFFFFFF, bytes(data), len(data) & 0xFF,
                              time_us & 0xFFFFFFFF))

    def step(self, time_us: int) -> int:
        return int(self._call("step_opaque", self._state, time_us & 0xFFFFFFFF))

    def tx(self) -> list[tuple[int, bytes]]:
        frames = []
        while self._call("tx_opaque", self._state, self._id, self._data, self._length):
            frames.append((int(self._id[0]), bytes(self.ffi.buffer(self._data, self._length[0]))))
        return frames

    @property
    def safe(self) -> bool:
        return bool(self._call("safe", self._state))

    @property
    def faults(self) -> int:
        """FAULT_ bits of the last step (bench/protocol.CONTROLLER_FAULTS in bit order)."""
        return int(self._call("faults", self._state))

    def fault_names(self) -> list[str]:
        bits = self.faults
        return [name for k, name in enumerate(protocol.CONTROLLER_FAULTS) if bits >> k & 1]

    @property
    def command(self) -> np.ndarray:
        return np.array([self._call("command", self._state, j) for j in range(len(self.artifact.joint_names))])

    @property
    def counters(self) -> dict[str, int]:
        return {name: int(self._call("counter", self._state, k)) for k, name in enumerate(COUNTERS)}

    def pack(self, message: str, values: dict) -> bytes:
        m = self.db.get_message_by_name(message)
        signals = self.ffi.new(f"{self._name}_{message.lower()}_t *")
        for key, value in values.items():
            setattr(signals, key, float(value))
        data = self.ffi.new("uint8_t[]", m.length)
        self._call(f"pack_{message.lower()}", signals, data)
        return bytes(self.ffi.buffer(data, m.length))

    def unpack(self, message: str, data: bytes) -> dict:
        m = self.db.get_message_by_name(message)
        signals = self.ffi.new(f"{self._name}_{message.lower()}_t *")
        self._call(f"unpack_{message.lower()}", bytes(data), signals)
        return {s.name: getattr(signals, s.name) for s in m.signals}
