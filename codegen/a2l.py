"""The ASAM MCD-2 MC description (A2L) of a firmware image with the XCP slave (docs/xcp.md):
what a calibration tool (CANape, INCA, pyxcp) needs to measure the controller by DAQ and to
calibrate the laws' tunables.

Addresses come from the image itself, never from a guess: the symbols' values from its ELF
symbol table (``nm``: a linked target image's addresses; a host shared library's offsets from
its load address, which the SIL bench hands the slave as its base), and the members' offsets,
sizes and kinds from a layout probe — ``offsetof``/``sizeof`` constants compiled by the image's
own compiler and read back from the object (``objcopy``), so a 32-bit target and a 64-bit host
each get their own struct layout.

* MEASUREMENTs: the controller instance ``<prefix>_controller``: each joint's measurements as
  the CAN layer holds them (raw, with the DBC's scale and offset as a LINEAR COMPU_METHOD), the
  tip sensors, the commanded normal forces, the setpoint voltages, the status and fault bits,
  the SISO law's memory and the cLQG filter's state.
* CHARACTERISTICs: every value of the calibration page (``codegen.xcp_slave.calibration_values``)
  with the limits the slave enforces.
"""

from __future__ import annotations

import re
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from smartjoint.codegen import rendering, xcp_slave
from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control.artifact import ControllerArtifact
from smartjoint.design.control.realisation import of_artifact
from smartjoint.design.structure.description import Xcp


@dataclass(frozen=True)
class Measured:
    """One MEASUREMENT: ``member`` of ``<prefix>_controller`` (a C member designator), its
    physical value ``factor`` · raw + ``offset`` in ``unit``, ``count`` elements from it."""

    name: str
    member: str
    unit: str
    description: str
    factor: float = 1.0
    offset: float = 0.0
    count: int = 1


@dataclass(frozen=True)
class Layout:
    """Offset, size and kind of a member as the image's compiler lays it out."""

    offset: int
    size: int
    signed: bool
    floating: bool

    @property
    def datatype(self) -> str:
        """The A2L data type."""
        if self.floating:
            return {4: "FLOAT32_IEEE", 8: "FLOAT64_IEEE"}[self.size]
        return {1: "BYTE", 2: "WORD", 4: "LONG"}[self.size].join(("S" if self.signed else "U", ""))


def _signal(db, frame: str, signal: str):
    return db.get_message_by_name(frame).get_signal_by_name(signal)


def measurements(artifact: ControllerArtifact, db) -> list[Measured]:
    """The MEASUREMENTs of the controller instance (module docstring), by joint and sensor name.

    Parameters
    ----------
    artifact : ControllerArtifact
    db : cantools.database.can.Database
        Every frame of the network (``codegen.can_layer.network_database``): the raw signals' scales.
    """
    rows: list[Measured] = []
    what = {"sliding_velocity": "sliding velocity v", "friction_force": "friction force u_R",
            "normal_force": "applied normal force F_N"}  # fmt: skip
    for j, joint in enumerate(artifact.joint_names):
        tag = joint.upper()
        for field, text in what.items():
            s = _signal(db, f"JOINT_{tag}", field)
            rows.append(Measured(f"{field}.{joint}", f"{field}[{j}]", s.unit or "", f"measured {text} of joint {joint}"
                                 " (JOINT frame, raw)", float(s.scale), float(s.offset)))  # fmt: skip
    for r, sensor in enumerate(artifact.sensor_names):
        s = _signal(db, "TIP_SENSORS", sensor.lower())
        rows.append(Measured(f"sensor.{sensor}", f"sensors[{r}]", s.unit or "", f"tip sensor y_{r + 1} (raw)",
                             float(s.scale), float(s.offset)))  # fmt: skip
    for j, joint in enumerate(artifact.joint_names):
        rows.append(Measured(f"command.{joint}", f"command[{j}]", "N", f"commanded normal force F_N of joint {joint}"))
        volts = _signal(db, f"SETPOINT_{joint.upper()}", "voltage") if f"SETPOINT_{joint.upper()}" in [
            m.name for m in db.messages] else None  # fmt: skip
        if volts is not None:
            rows.append(Measured(f"setpoint.{joint}", f"setpoint[{j}]", volts.unit or "V",
                                 f"piezo voltage setpoint of joint {joint} (raw)", float(volts.scale)))  # fmt: skip
    rows += [
        Measured("step_status", "step_status", "", "status bits of the last step (smartjoint_types.h, 0x10 safe)"),
        Measured("faults", "faults", "", "FAULT_ bits of the last step (CONTROLLER_STATUS.faults)"),
        Measured("safe", "safe", "", "1 while every joint holds the safe force"),
        Measured("missing", "missing", "", "inputs the law needs that are missing"),
        Measured("steps", "steps", "", "controller steps since power-up"),
        Measured("law", "law", "", "the law the CAN layer runs (CONTROLLER_STATUS.mode)"),
    ]
    coordinates = int(of_artifact(artifact).blocks.shape[0])  # the filter's (codegen.law_contexts)
    for law in law_registry.LAWS.values():
        for member, per, unit, meaning in law.memories:
            if per == "coordinate":
                rows.append(Measured(f"{law.name}.{member}", f"{law.name}.{member}[0]", unit,
                                     f"{law.display}: {meaning}", count=coordinates))  # fmt: skip
                continue
            for j, joint in enumerate(artifact.joint_names):
                rows.append(Measured(f"{law.name}.{member}.{joint}", f"{law.name}.{member}[{j}]", unit,
                                     f"{law.display}: {meaning}, joint {joint}"))  # fmt: skip
    return rows


def probe_source(prefix: str, members: list[str]) -> str:
    """The layout probe: per member of ``<prefix>_can_state`` its offset, size, signedness and
    whether it is floating, as one ``const uint32_t`` array the A2L generator reads back."""
    state = f"{prefix}_can_state"
    lines = []
    for m in members:
        field = f"((({state} *)0)->{m})"
        lines.append(f"    offsetof({state}, {m}), sizeof {field}, (__typeof__{field})-1 < 0, "
                     f"(__typeof__{field})0.5 != 0,")  # fmt: skip
    return "\n".join([
        "/* Layout probe of the A2L generator (codegen/a2l.py): not part of the firmware. */",
        "#include <stddef.h>", "#include <stdint.h>", "", f'#include "{prefix}_xcp.h"', "",
        f"const uint32_t {prefix}_a2l_layout[] = {{", *lines, "};", "",
    ])  # fmt: skip


def probe(
    files: dict[str, str],
    prefix: str,
    members: list[str],
    compiler: str = "cc",
    objcopy: str = "objcopy",
    flags: tuple[str, ...] = (),
) -> dict[str, Layout]:
    """Compile the layout probe with the image's compiler and read its numbers back.

    Parameters
    ----------
    files : dict of str to str
        The image's generated sources (the headers the probe includes).
    prefix : str
    members : list of str
        Member designators of ``<prefix>_can_state``.
    compiler, objcopy : str
        The image's compiler and binutils' objcopy (``arm-none-eabi-…`` for the target).
    flags : tuple of str
        The image's target flags (``-mcpu=…``).

    Returns
    -------
    dict of str to Layout
    """
    with tempfile.TemporaryDirectory(prefix="smartjoint-a2l-") as work:
        folder = Path(work)
        for name, text in files.items():
            if name.endswith(".h"):
                (folder / name).write_text(text)
        (folder / "probe.c").write_text(probe_source(prefix, members))
        section = f".rodata.{prefix}_a2l_layout"
        try:
            subprocess.run([compiler, "-std=gnu99", "-fdata-sections", *flags, "-c", "probe.c", "-o", "probe.o"],
                           cwd=folder, check=True, capture_output=True, text=True)  # fmt: skip
            subprocess.run([objcopy, "-O", "binary", f"--only-section={section}", "probe.o", "probe.bin"],
                           cwd=folder, check=True, capture_output=True, text=True)  # fmt: skip
        except (OSError, subprocess.CalledProcessError) as error:
            detail = getattr(error, "stderr", "") or str(error)
            raise ModelError(
                f"A2L layout probe: {compiler}/{objcopy} failed: {detail.strip().splitlines()[-1:]}"
            ) from None
        words = np.frombuffer((folder / "probe.bin").read_bytes(), dtype="<u4")
    if len(words) != 4 * len(members):
        raise ModelError(f"A2L layout probe: {len(words)} numbers for {len(members)} members")
    return {m: Layout(int(words[4 * k]), int(words[4 * k + 1]), bool(words[4 * k + 2]), bool(words[4 * k + 3]))
            for k, m in enumerate(members)}  # fmt: skip


@dataclass(frozen=True)
class Described:
    """One MEASUREMENT or CHARACTERISTIC as the A2L states it: its address in the image's XCP
    address space, A2L data type, element count, physical = factor · raw + offset, unit, limits."""

    name: str
    address: int
    datatype: str
    count: int
    factor: float
    offset: float
    unit: str
    lower: float
    upper: float
    value: float = 0.0  # a CHARACTERISTIC's design value (the reference page)


@dataclass(frozen=True)
class Description:
    """An image's A2L: its ``text`` and what it states, by name."""

    text: str
    measurements: dict[str, Described]
    characteristics: dict[str, Described]


def _name(text: str) -> str:
    """An A2L identifier: letters, digits, '_' and '.'."""
    return re.sub(r"[^A-Za-z0-9_.]", "_", text)


_GREEK = {"ε": "eps", "μ": "mu", "σ": "sigma", "η": "eta", "ω": "omega", "Δ": "Delta", "−": "-", "…": "..."}


def _ascii(text: str) -> str:
    """A2L text in ASCII (what every tool reads): Greek letters spelled out, anything else '?'.'"""
    for letter, word in _GREEK.items():
        text = text.replace(letter, word)
    return text.encode("ascii", "replace").decode("ascii").replace('"', "'")


def _number(value: float) -> str:
    return repr(float(value))


def _interface_lines(artifact, real: str, prefix: str, xcp: Xcp, bus, epk_address: int, page: int, page_size: int,
                     where: str) -> list[str]:  # fmt: skip
    """The A2L up to the MODULE's objects: MOD_COMMON, the XCP on CAN FD IF_DATA, MOD_PAR with
    the EPK and the calibration segment of two pages."""
    cycle, unit = xcp_slave.event_cycle(artifact.sample_time)
    optional = [c for c in xcp_slave.COMMANDS if c not in ("CONNECT", "DISCONNECT", "GET_STATUS", "SYNCH")]
    access = "ECU_ACCESS_DONT_CARE XCP_READ_ACCESS_DONT_CARE XCP_WRITE_ACCESS"
    return [
        "ASAP2_VERSION 1 71",
        f'/begin PROJECT {_name(prefix)} "smartjoint controller firmware"',
        f'  /begin HEADER "{_ascii(where)}" VERSION "{rendering.version()}" /end HEADER',
        f'  /begin MODULE {_name(prefix)} "controller of artefact {artifact.artifact_sha256[:16]} ({real} build)"',
        '    /begin MOD_COMMON ""',
        "      BYTE_ORDER MSB_LAST",
        "      ALIGNMENT_BYTE 1 ALIGNMENT_WORD 2 ALIGNMENT_LONG 4 ALIGNMENT_FLOAT32_IEEE 4 ALIGNMENT_FLOAT64_IEEE 8",
        "    /end MOD_COMMON",
        "    /begin IF_DATA XCP",
        "      /begin PROTOCOL_LAYER",
        "        0x0100 2000 2000 0 0 0 0 0 64 64 BYTE_ORDER_MSB_LAST ADDRESS_GRANULARITY_BYTE",
        *(f"        OPTIONAL_CMD {c}" for c in optional),
        "      /end PROTOCOL_LAYER",
        "      /begin PAG 1 /end PAG",
        "      /begin DAQ",
        "        DYNAMIC 1 1 0 OPTIMISATION_TYPE_DEFAULT ADDRESS_EXTENSION_FREE IDENTIFICATION_FIELD_TYPE_ABSOLUTE",
        "        GRANULARITY_ODT_ENTRY_SIZE_DAQ_BYTE 59 NO_OVERLOAD_INDICATION",
        "        PRESCALER_SUPPORTED",
        "        /begin TIMESTAMP_SUPPORTED 1 SIZE_DWORD UNIT_1US TIMESTAMP_FIXED /end TIMESTAMP_SUPPORTED",
        f'        /begin EVENT "{xcp_slave.EVENT_NAME}" "{xcp_slave.EVENT_NAME}" 0 DAQ 1 {cycle} {unit} 0 /end EVENT',
        "      /end DAQ",
        "      /begin XCP_ON_CAN",
        "        0x0100",
        f"        CAN_ID_MASTER 0x{xcp.master_id:X}",
        f"        CAN_ID_SLAVE 0x{xcp.slave_id:X}",
        f"        BAUDRATE {int(bus.bitrate)}",
        f"        /begin CAN_FD MAX_DLC 64 CAN_FD_DATA_TRANSFER_BAUDRATE {int(bus.data_bitrate)} /end CAN_FD",
        "      /end XCP_ON_CAN",
        "    /end IF_DATA",
        f'    /begin MOD_PAR "{_ascii(where)}"',
        f"      ADDR_EPK 0x{epk_address:X}",
        f'      EPK "{xcp_slave.epk(artifact, real, prefix)}"',
        f'      /begin MEMORY_SEGMENT calibration "calibration page: every law\'s tunables" DATA RAM INTERN '
        f"0x{page:X} 0x{page_size:X} -1 -1 -1 -1 -1",
        "        /begin IF_DATA XCP",
        "          /begin SEGMENT 0 2 0 0 0",
        "            /begin CHECKSUM XCP_CRC_32 MAX_BLOCK_SIZE 0xFFFF /end CHECKSUM",
        f"            /begin PAGE 0 {access}_NOT_ALLOWED /end PAGE",
        f"            /begin PAGE 1 {access}_DONT_CARE /end PAGE",
        "          /end SEGMENT",
        "        /end IF_DATA",
        "      /end MEMORY_SEGMENT",
        "    /end MOD_PAR",
    ]


def _limits(m: Measured, lay: Layout) -> tuple[float, float]:
    """A measurement's physical range: its type's whole range through its conversion."""
    if lay.floating:
        low, high = -3.4e38, 3.4e38
    else:
        bits = 8 * lay.size - (1 if lay.signed else 0)
        low, high = (-(2.0**bits) if lay.signed else 0.0), 2.0**bits - 1
    ends = sorted((m.factor * low + m.offset, m.factor * high + m.offset))
    return ends[0], ends[1]


def describe(
    artifact: ControllerArtifact,
    real: str,
    prefix: str,
    xcp: Xcp,
    symbols: dict[str, int],
    layout: dict[str, Layout],
    measured: list[Measured],
    bus,
    where: str,
) -> Description:
    """The A2L of one image.

    Parameters
    ----------
    artifact : ControllerArtifact
    real, prefix : str
    xcp : Xcp
        The design's ``[xcp]``.
    symbols : dict of str to int
        The image's symbol values (:func:`bench.firmware.symbols`).
    layout : dict of str to Layout
        The probe's numbers for every member of ``measured``.
    measured : list of Measured
    bus : design.structure.description.Bus
        The bus carrying XCP (bit rates).
    where : str
        What the addresses are, for the header ("Cortex-M4F image …", "SIL shared library …").

    Returns
    -------
    Description
    """
    for symbol in (f"{prefix}_controller", f"{prefix}_calibration_working", f"{prefix}_xcp_epk"):
        if symbol not in symbols:
            raise ModelError(f"A2L: the image has no symbol {symbol!r} — is the XCP slave linked?")
    controller, page = symbols[f"{prefix}_controller"], symbols[f"{prefix}_calibration_working"]
    size, real_type = (4, "FLOAT32_IEEE") if real == "float" else (8, "FLOAT64_IEEE")
    values = xcp_slave.calibration_values(artifact, real, xcp)
    lines = _interface_lines(artifact, real, prefix, xcp, bus, symbols[f"{prefix}_xcp_epk"], page,
                             size * len(values), where)  # fmt: skip
    lines.append(f"    /begin RECORD_LAYOUT RL_REAL FNC_VALUES 1 {real_type} COLUMN_DIR DIRECT /end RECORD_LAYOUT")
    methods: dict[tuple, str] = {}
    characteristics, measurements_out = {}, {}
    for k, v in enumerate(values):
        c = Described(_name(v.name), page + size * k, real_type, 1, 1.0, 0.0, v.unit, v.lower, v.upper, v.value)
        characteristics[c.name] = c
        method = methods.setdefault((1.0, 0.0, v.unit), f"CM_{len(methods)}")
        lines += [
            f'    /begin CHARACTERISTIC {c.name} "{_ascii(v.meaning)} ({v.law} law)" VALUE 0x{c.address:X} RL_REAL 0 '
            f"{method} {_number(v.lower)} {_number(v.upper)}",
            "    /end CHARACTERISTIC",
        ]
    for m in measured:
        lay = layout[m.member]
        low, high = _limits(m, lay)
        d = Described(_name(m.name), controller + lay.offset, lay.datatype, m.count, m.factor, m.offset, m.unit, low,
                      high)  # fmt: skip
        measurements_out[d.name] = d
        method = methods.setdefault((m.factor, m.offset, m.unit), f"CM_{len(methods)}")
        lines += [
            f'    /begin MEASUREMENT {d.name} "{_ascii(m.description)}" {lay.datatype} {method} 0 0 {_number(low)} '
            f"{_number(high)}",
            f"      ECU_ADDRESS 0x{d.address:X}",
            *([f"      MATRIX_DIM {m.count} 1 1"] if m.count > 1 else []),
            "      /begin IF_DATA XCP /begin DAQ_EVENT FIXED_EVENT_LIST EVENT 0 /end DAQ_EVENT /end IF_DATA",
            "    /end MEASUREMENT",
        ]
    for (factor, offset, unit_text), name in methods.items():
        lines += [
            f'    /begin COMPU_METHOD {name} "physical = {factor!r} * raw + {offset!r}" LINEAR "%.6g" '
            f'"{_ascii(unit_text)}"',
            f"      COEFFS_LINEAR {_number(factor)} {_number(offset)}",
            "    /end COMPU_METHOD",
        ]
    lines += ["  /end MODULE", "/end PROJECT", ""]
    return Description("\n".join(lines), measurements_out, characteristics)


__all__ = ["Described", "Description", "Layout", "Measured", "describe", "measurements", "probe", "probe_source"]
