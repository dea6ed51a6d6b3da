"""The generated firmware (controllers + CAN message layer + E2E runtime) compiled with cffi.

``Firmware`` is what the SIL bench talks to: frames in (``rx``), one ``step`` per sample, frames
out (``tx``), exactly the C entry points of the target. The generated sources are compiled alone
with the strict warning set (``codegen.build.FLAGS``); only cffi's glue is compiled without it.
"""

from __future__ import annotations

import numpy as np

from smartjoint.codegen import build, can_codec, can_layer, generate, xcp_slave
from smartjoint.common import law_registry, native
from smartjoint.common.errors import ModelError
from smartjoint.design.control.artifact import ControllerArtifact
from smartjoint.design.network import plan, protocol, xcp_bus
from smartjoint.design.structure.description import Xcp

LAWS = {law.name: law.mode for law in law_registry.LAWS.values()}  # the CAN layer's law ids


def _driver_header(prefix: str) -> str:
    """The header of the opaque-state accessors: the CAN layer's header and their prototypes
    (cffi declarations and C driver alike)."""
    n = f"{prefix}_can"
    guard = f"{n.upper()}_BENCH_DRIVER_H"
    return f"""/* Opaque-state accessors of the CAN layer for Python (not part of the firmware). */
#ifndef {guard}
#define {guard}

#include "{n}.h"

size_t {n}_state_size(void);
int {n}_init_opaque(uint8_t *state, int law);
unsigned int {n}_rx_opaque(uint8_t *state, uint32_t id, const uint8_t *data, uint8_t length, uint32_t time_us);
unsigned int {n}_rx_bus_opaque(uint8_t *state, uint8_t bus, uint32_t id, const uint8_t *data, uint8_t length,
                                uint32_t time_us);
int {n}_bus_off_opaque(uint8_t *state, uint8_t bus, int off);
unsigned int {n}_step_opaque(uint8_t *state, uint32_t time_us);
int {n}_tx_opaque(uint8_t *state, uint32_t *id, uint8_t *data, uint8_t *length);
int {n}_tx_bus_opaque(uint8_t *state, uint8_t *bus, uint32_t *id, uint8_t *data, uint8_t *length);
int {n}_safe(const uint8_t *state);
int {n}_bus_safe(const uint8_t *state, int bus);
unsigned int {n}_faults(const uint8_t *state);
double {n}_command(const uint8_t *state, int joint);
uint32_t {n}_counter(const uint8_t *state, int which);
void {n}_set_steps(uint8_t *state, uint32_t steps);

#endif
"""


def _driver(prefix: str) -> str:
    """Opaque-state accessors for Python (not part of the firmware)."""
    n = f"{prefix}_can"
    return (
        f'#include "_{n}_driver.h"\n'
        + f"""

size_t {n}_state_size(void) {{ return sizeof({n}_state); }}
int {n}_init_opaque(uint8_t *state, int law) {{ return {n}_init(({n}_state *)(void *)state, ({n}_law)law); }}
unsigned int {n}_rx_opaque(uint8_t *state, uint32_t id, const uint8_t *data, uint8_t length, uint32_t time_us)
{{
    return {n}_rx(({n}_state *)(void *)state, id, data, length, time_us);
}}
unsigned int {n}_rx_bus_opaque(uint8_t *state, uint8_t bus, uint32_t id, const uint8_t *data, uint8_t length,
                                uint32_t time_us)
{{
    return {n}_rx_bus(({n}_state *)(void *)state, bus, id, data, length, time_us);
}}
int {n}_bus_off_opaque(uint8_t *state, uint8_t bus, int off)
{{
    return {n}_bus_off(({n}_state *)(void *)state, bus, off != 0);
}}
unsigned int {n}_step_opaque(uint8_t *state, uint32_t time_us)
{{ return {n}_step(({n}_state *)(void *)state, time_us); }}
int {n}_tx_opaque(uint8_t *state, uint32_t *id, uint8_t *data, uint8_t *length)
{{
    return {n}_tx(({n}_state *)(void *)state, id, data, length);
}}
int {n}_tx_bus_opaque(uint8_t *state, uint8_t *bus, uint32_t *id, uint8_t *data, uint8_t *length)
{{
    return {n}_tx_bus(({n}_state *)(void *)state, bus, id, data, length);
}}
int {n}_safe(const uint8_t *state) {{ return ((const {n}_state *)(const void *)state)->safe; }}
int {n}_bus_safe(const uint8_t *state, int bus) {{ return ((const {n}_state *)(const void *)state)->bus_safe[bus]; }}
unsigned int {n}_faults(const uint8_t *state) {{ return ((const {n}_state *)(const void *)state)->faults; }}
double {n}_command(const uint8_t *state, int joint)
{{ return (double)((const {n}_state *)(const void *)state)->command[joint]; }}
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
    )


def _xcp_driver(prefix: str) -> tuple[str, str]:
    """Header and source of the XCP slave's opaque-state accessors (not part of the firmware)."""
    n = f"{prefix}_xcp"
    header = f"""/* Opaque-state accessors of the XCP slave for Python (not part of the firmware). */
#ifndef {n.upper()}_BENCH_DRIVER_H
#define {n.upper()}_BENCH_DRIVER_H

#include "_{prefix}_can_driver.h"
#include "{n}.h"

size_t {n}_state_size(void);
uint8_t *{n}_controller_bytes(void);
int {n}_init_opaque(uint8_t *xcp, uintptr_t base);
void {n}_rx_opaque(uint8_t *xcp, const uint8_t *data, uint8_t length, uint32_t time_us);
void {n}_event_opaque(uint8_t *xcp, uint32_t time_us);
int {n}_tx_opaque(uint8_t *xcp, uint8_t *data, uint8_t *length);
uint32_t {n}_overruns(const uint8_t *xcp);

#endif
"""
    source = f"""#include "_{n}_driver.h"

#define SLAVE(p) (({n}_state *)(void *)(p))
size_t {n}_state_size(void) {{ return sizeof({n}_state); }}
uint8_t *{n}_controller_bytes(void) {{ return (uint8_t *)(void *)&{prefix}_controller; }}
int {n}_init_opaque(uint8_t *xcp, uintptr_t base) {{ return {n}_init(SLAVE(xcp), base); }}
void {n}_rx_opaque(uint8_t *xcp, const uint8_t *data, uint8_t length, uint32_t time_us)
{{
    {n}_rx(SLAVE(xcp), data, length, time_us);
}}
void {n}_event_opaque(uint8_t *xcp, uint32_t time_us) {{ {n}_event(SLAVE(xcp), time_us); }}
int {n}_tx_opaque(uint8_t *xcp, uint8_t *data, uint8_t *length) {{ return {n}_tx(SLAVE(xcp), data, length); }}
uint32_t {n}_overruns(const uint8_t *xcp) {{ return ((const {n}_state *)(const void *)xcp)->overruns; }}
"""
    return header, source


def sources(
    artifact: ControllerArtifact, real: str = "float", prefix: str = "smartjoint", xcp: Xcp | None = None, **can_options
) -> dict:
    """The generated sources of the firmware image (controllers + CAN layer + E2E runtime, and
    with ``xcp`` the XCP slave), file name → text: what the SIL bench compiles on the host and
    the target self-test on the target (``bench/target.py``). Arguments as for :class:`Firmware`."""
    files = {
        **generate.render(artifact, real, prefix),
        **can_layer.render_can(artifact, prefix, full_codec=True, real=real, **can_options),
    }
    if xcp is not None:
        files.update(xcp_slave.render_xcp(artifact, prefix, real, xcp, can_options.get("network")))
    return files


def symbols(path: str, tool: str = "nm") -> dict[str, int]:
    """The defined symbols of an ELF file and their values (``nm``): a shared library's are
    offsets from its load address, a linked image's are its addresses."""
    import subprocess

    try:
        text = subprocess.run([tool, "--defined-only", "-P", path], capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError) as error:
        raise ModelError(f"symbols of {path}: {tool} failed ({error}) — binutils' nm reads them") from None
    table = {}
    for line in text.splitlines():
        parts = line.split()
        if len(parts) >= 3:
            table[parts[0]] = int(parts[2], 16)
    return table


COUNTERS = (
    "rx_frames",
    "crc_errors",
    "counter_errors",
    "length_errors",
    "unknown_ids",
    "timeouts",
    "implausible_frames",
    "steps",
)


class Firmware:
    """One compiled firmware image (controllers + CAN layer) and one instance of its state.

    Parameters
    ----------
    artifact : ControllerArtifact
        The controller design artefact the controllers and the CAN layer are generated from.
    law : str
        The law the CAN layer runs, by its registry name (``common.law_registry``).
    real, prefix : str
        The controllers' scalar type and the prefix of every C identifier and file name, as
        ``codegen.generate.render`` takes them.
    xcp : Xcp, optional
        Link the XCP slave (``codegen.xcp_slave``; the design's ``[xcp]``). The CAN layer's state
        is then the slave's ``<prefix>_controller``, a global of the image, so one image holds
        one such firmware at a time; :meth:`xcp_rx`, :meth:`xcp_event` and :meth:`xcp_tx` serve
        its port, and :attr:`xcp_base` is the address XCP address 0 stands for.
    **can_options
        Passed to ``codegen.can_layer.render_can`` (``amplifier``; ``network``: the plan of the
        buses, default the artefact's one-bus plan).
    """

    def __init__(
        self,
        artifact: ControllerArtifact,
        law: str = law_registry.NAMES[0],
        real: str = "float",
        prefix: str = "smartjoint",
        xcp: Xcp | None = None,
        **can_options,
    ):
        if law not in LAWS:
            raise ModelError(f"law: {law!r} — allowed: {', '.join(LAWS)}")
        files = sources(artifact, real, prefix, xcp, **can_options)
        files[f"_{prefix}_can_driver.h"] = _driver_header(prefix)
        files[f"_{prefix}_can_driver.c"] = _driver(prefix)
        header, extra = f"_{prefix}_can_driver.h", ()  # type: tuple[str, tuple[str, ...]]
        if xcp is not None:
            header = f"_{prefix}_xcp_driver.h"
            files[header], files[f"_{prefix}_xcp_driver.c"] = _xcp_driver(prefix)
            extra = (f"{prefix}_xcp.c", f"{prefix}_xcp_key.c", f"_{prefix}_xcp_driver.c")
        # The generated sources and the driver compile with the strict flags; the declarations
        # come from the generated headers through the driver's header.
        folder, module = build.load(
            f"firmware_{prefix}_{real}" + ("_xcp" if xcp is not None else ""),
            files,
            header,
            (
                *(f"{prefix}_{law}.c" for law in law_registry.NAMES),
                f"{prefix}_can.c",
                "sj_e2e.c",
                f"_{prefix}_can_driver.c",
                *extra,
            ),
        )
        self.network = can_options.get("network") or plan.one_bus(artifact, protocol.load_dbc(files["bus.dbc"]))
        self.databases = [protocol.load_dbc(p.dbc) for p in self.network.buses]  # one per bus, as the DBCs say
        self.db = can_layer.network_database(self.network)  # every frame once: lookups by name or id
        self.ffi, self.lib, self.prefix, self.artifact, self.law = module.ffi, module.lib, prefix, artifact, law
        self.module = module
        self.folder, self.files = folder, files
        self._name = f"{prefix}_can"
        self.xcp = xcp
        self.xcp_plan = None if xcp is None else xcp_bus.xcp_plan(self.network, xcp)  # its bus and DAQ room
        if xcp is None:
            self._state = self.ffi.new("uint8_t[]", int(getattr(self.lib, f"{self._name}_state_size")()))
        else:  # the slave's controller: the A2L's addresses point into it
            self._state = getattr(self.lib, f"{prefix}_xcp_controller_bytes")()
            self._slave = self.ffi.new("uint8_t[]", int(getattr(self.lib, f"{prefix}_xcp_state_size")()))
            self._slave_data = self.ffi.new("uint8_t[64]")
        self._id = self.ffi.new("uint32_t *")
        self._data = self.ffi.new("uint8_t[64]")
        self._length = self.ffi.new("uint8_t *")
        self._bus = self.ffi.new("uint8_t *")
        self.reset()

    def _call(self, suffix, *args):
        return getattr(self.lib, f"{self._name}_{suffix}")(*args)

    def reset(self) -> None:
        """Power-up: the CAN layer's ``init`` with the law (the safe state until inputs arrive),
        then the XCP slave's (which points the laws at its calibration page)."""
        if self._call("init_opaque", self._state, LAWS[self.law]) != 0:
            raise ModelError(f"firmware: the CAN layer refused law {self.law!r}")
        if self.xcp is not None:
            getattr(self.lib, f"{self.prefix}_xcp_init_opaque")(self._slave, self.xcp_base)

    @property
    def xcp_base(self) -> int:
        """The address in this process that XCP address 0 stands for: the image's load address,
        so the A2L's addresses are the image's symbol values (``codegen.a2l``)."""
        symbol = f"{self.prefix}_controller"
        runtime = int(self.ffi.cast("uintptr_t", self.ffi.addressof(self.lib, symbol)))
        return runtime - symbols(self.library)[symbol]

    @property
    def library(self) -> str:
        """The shared library of the compiled image."""
        return str(native.library(self.module))

    def xcp_rx(self, data: bytes, time_us: int) -> None:
        """One frame of the XCP master into the slave (``<prefix>_xcp_rx``)."""
        getattr(self.lib, f"{self.prefix}_xcp_rx_opaque")(
            self._slave, bytes(data), len(data) & 0xFF, time_us & 0xFFFFFFFF
        )

    def xcp_event(self, time_us: int) -> None:
        """The sample boundary of the slave (``<prefix>_xcp_event``), after :meth:`step`."""
        getattr(self.lib, f"{self.prefix}_xcp_event_opaque")(self._slave, time_us & 0xFFFFFFFF)

    def xcp_tx(self) -> list[bytes]:
        """Every frame the slave has to send (the answer, then the event's DTOs) until ``<prefix>_xcp_tx`` gives 0."""
        frames = []
        tx = getattr(self.lib, f"{self.prefix}_xcp_tx_opaque")
        while tx(self._slave, self._slave_data, self._length):
            frames.append(bytes(self.ffi.buffer(self._slave_data, self._length[0])))
        return frames

    @property
    def xcp_overruns(self) -> int:
        """DAQ events whose ODTs were not all sent before the next one (lost ODTs)."""
        return int(getattr(self.lib, f"{self.prefix}_xcp_overruns")(self._slave))

    def rx(self, frame_id: int, data: bytes, time_us: int, bus: int | None = None) -> int:
        """One received frame into the CAN layer (``<prefix>_can_rx``, or ``<prefix>_can_rx_bus``
        with the bus it came from).

        Parameters
        ----------
        frame_id : int
            The frame's identifier.
        data : bytes
            Its payload.
        time_us : int
            The receive time [µs] (wraps at 2^32; diagnostics only).
        bus : int, optional
            The index of the bus in the plan; None: the bus its identifier belongs to.

        Returns
        -------
        int
            The RX result bits of the generated header.
        """
        if bus is not None:
            return int(
                self._call(
                    "rx_bus_opaque",
                    self._state,
                    bus & 0xFF,
                    frame_id & 0xFFFFFFFF,
                    bytes(data),
                    len(data) & 0xFF,
                    time_us & 0xFFFFFFFF,
                )
            )
        return int(
            self._call(
                "rx_opaque", self._state, frame_id & 0xFFFFFFFF, bytes(data), len(data) & 0xFF, time_us & 0xFFFFFFFF
            )
        )

    def step(self, time_us: int) -> int:
        """One controller sample (``<prefix>_can_step``): the law or the safe state; returns its status bits."""
        return int(self._call("step_opaque", self._state, time_us & 0xFFFFFFFF))

    def tx(self) -> list[tuple[int, bytes]]:
        """Every frame the last step queued, as (identifier, payload), until ``<prefix>_can_tx`` returns 0."""
        frames = []
        while self._call("tx_opaque", self._state, self._id, self._data, self._length):
            frames.append((int(self._id[0]), bytes(self.ffi.buffer(self._data, self._length[0]))))
        return frames

    def tx_bus(self) -> list[tuple[int, int, bytes]]:
        """Every frame the last step queued, as (bus, identifier, payload), until
        ``<prefix>_can_tx_bus`` returns 0."""
        frames = []
        while self._call("tx_bus_opaque", self._state, self._bus, self._id, self._data, self._length):
            frames.append((int(self._bus[0]), int(self._id[0]), bytes(self.ffi.buffer(self._data, self._length[0]))))
        return frames

    def bus_off(self, bus: int, off: bool = True) -> None:
        """Report bus ``bus`` off (or back) to the CAN layer (``<prefix>_can_bus_off``)."""
        if self._call("bus_off_opaque", self._state, bus & 0xFF, int(off)) != 0:
            raise ModelError(f"bus: {bus!r} — the plan has buses 0 … {len(self.network.buses) - 1}")

    @property
    def bus_safe(self) -> list[bool]:
        """Per bus of the plan whether its joints hold the safe force."""
        return [bool(self._call("bus_safe", self._state, b)) for b in range(len(self.network.buses))]

    @property
    def safe(self) -> bool:
        """Whether the CAN layer holds the safe state."""
        return bool(self._call("safe", self._state))

    @property
    def faults(self) -> int:
        """FAULT_ bits of the last step (design/network/protocol.CONTROLLER_FAULTS in bit order)."""
        return int(self._call("faults", self._state))

    def fault_names(self) -> list[str]:
        """The names of the fault bits of the last step (design/network/protocol.CONTROLLER_FAULTS)."""
        bits = self.faults
        return [name for k, name in enumerate(protocol.CONTROLLER_FAULTS) if bits >> k & 1]

    @property
    def command(self) -> np.ndarray:
        """The normal forces commanded by the last step [N]."""
        return np.array([self._call("command", self._state, j) for j in range(len(self.artifact.joint_names))])

    @property
    def counters(self) -> dict[str, int]:
        """The CAN layer's diagnostic counters (:data:`COUNTERS`)."""
        return {name: int(self._call("counter", self._state, k)) for k, name in enumerate(COUNTERS)}

    def _layout(self, message: str):
        """(the frame, the C name of its layout, a new struct of its raw fields)."""
        m = self.db.get_message_by_name(message)
        layout = f"{self._name}_{can_codec.layout_name(m.name, list(self.artifact.joint_names))}"
        return m, layout, self.ffi.new(f"struct {layout}_t *")

    def pack(self, message: str, values: dict) -> bytes:
        """Pack signal values into a frame's payload with the generated codec: each value
        through its signal's ``encode`` (in the build's scalar type), then the layout's ``pack``.

        Parameters
        ----------
        message : str
            The frame's name (``JOINT_A1``, …).
        values : dict of str to float
            Physical signal values; signals not given encode 0.

        Returns
        -------
        bytes
            The payload.
        """
        m, layout, raw = self._layout(message)
        for s in m.signals:
            setattr(raw, s.name, getattr(self.lib, f"{layout}_{s.name}_encode")(float(values.get(s.name, 0.0))))
        return self.pack_raw(message, raw)

    def pack_raw(self, message: str, raw) -> bytes:
        """Pack raw signal values (a dict, or the layout's struct) with the layout's ``pack``.

        Returns
        -------
        bytes
            The payload.
        """
        m, layout, fields = self._layout(message)
        if isinstance(raw, dict):
            for name, value in raw.items():
                setattr(fields, name, int(value))
        else:
            fields = raw
        data = self.ffi.new("uint8_t[]", m.length)
        written = getattr(self.lib, f"{layout}_pack")(data, fields, m.length)
        if written != m.length:
            raise ModelError(f"{message}: pack returned {written} for a {m.length}-byte frame")
        return bytes(self.ffi.buffer(data, m.length))

    def unpack_raw(self, message: str, data: bytes) -> dict:
        """The raw signal values of a payload (the layout's ``unpack``), by signal name."""
        m, layout, raw = self._layout(message)
        read = getattr(self.lib, f"{layout}_unpack")(raw, bytes(data), len(data))
        if read != m.length:
            raise ModelError(f"{message}: unpack returned {read} for {len(data)} bytes (frame length {m.length})")
        return {s.name: int(getattr(raw, s.name)) for s in m.signals}

    def unpack(self, message: str, data: bytes) -> dict:
        """Unpack a frame's payload with the generated codec: the layout's ``unpack``, then each
        raw value through its signal's ``decode``.

        Parameters
        ----------
        message : str
            The frame's name.
        data : bytes
            The payload.

        Returns
        -------
        dict of str to float
            The value of every signal.
        """
        _, layout, _ = self._layout(message)
        raw = self.unpack_raw(message, data)
        return {name: float(getattr(self.lib, f"{layout}_{name}_decode")(value)) for name, value in raw.items()}
