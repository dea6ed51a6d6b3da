"""An ECU's A2L as the bench's XCP master reads it (``smartjoint bench xcp``; docs/xcp.md):
the transport (XCP on CAN identifiers and bit rates, the DAQ event's cycle), the EPK that names
the image, and every MEASUREMENT and CHARACTERISTIC with its address, type, LINEAR conversion,
unit and limits.

The file is parsed by pya2l, an independent ASAM MCD-2 MC parser; this module only picks out of
its tree what a master needs. It reads any A2L of that shape, not only smartjoint's: scalars
(VALUE characteristics, measurements without ARRAY_SIZE) with IDENTICAL or LINEAR conversions.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from smartjoint.codegen.a2l import Described
from smartjoint.common.errors import ModelError

# XCP's DAQ time units (the EVENT's TIME_CYCLE unit, ASAM XCP part 2): code → seconds
_TIME_UNITS = {0: 1e-9, 1: 1e-8, 2: 1e-7, 3: 1e-6, 4: 1e-5, 5: 1e-4, 6: 1e-3, 7: 1e-2, 8: 1e-1, 9: 1.0}
_SIZES = {"UBYTE": 1, "SBYTE": 1, "UWORD": 2, "SWORD": 2, "ULONG": 4, "SLONG": 4, "FLOAT32_IEEE": 4,
          "FLOAT64_IEEE": 8}  # fmt: skip


@dataclass(frozen=True)
class EcuDescription:
    """What an A2L states of one ECU (one MODULE)."""

    path: str
    module: str
    epk: str | None
    epk_address: int | None
    master_id: int
    slave_id: int
    bitrate: int
    data_bitrate: int | None  # None: classical CAN
    event_cycle: float | None  # the first DAQ event's cycle [s], None when it states none
    measurements: dict[str, Described]
    characteristics: dict[str, Described]


def _number(node) -> float:
    """A number of the tree: its source text where it kept one (exact), else its value."""
    source = getattr(node, "Source", "")
    return float(source) if source else float(node.Value)


def _elements(generic) -> list:
    """A generic IF_DATA block's elements as Python values: str, int, or (name, [elements])."""
    out: list = []
    for element in generic.Element:
        kind = next((f.name for f, _ in element.ListFields()), "")
        if kind == "Generic":
            out.append((element.Generic.Name.Value, _elements(element.Generic)))
        elif kind == "Identifier":
            out.append(element.Identifier.Value)
        elif kind == "String":
            out.append(element.String.Value)
        elif kind in ("Long", "Int"):
            out.append(int(getattr(element, kind).Value))
        elif kind == "Float":
            out.append(float(element.Float.Value))
    return out


def _blocks(items: list, name: str) -> list[list]:
    """Every sub-block called ``name`` of parsed IF_DATA elements, depth first."""
    found = []
    for item in items:
        if isinstance(item, tuple):
            if item[0] == name:
                found.append(item[1])
            found += _blocks(item[1], name)
    return found


def _after(items: list, keyword: str):
    """The value that follows ``keyword`` in a block's elements, or None."""
    for k, item in enumerate(items[:-1]):
        if item == keyword:
            return items[k + 1]
    return None


def _transport(path: str, module) -> tuple[int, int, int, int | None, float | None]:
    """(master id, slave id, bit rate, data bit rate, event cycle) from the MODULE's IF_DATA XCP."""
    items: list = []
    for block in module.IF_DATA:
        if block.Name.Value == "XCP":
            items += [(b.Generic.Name.Value, _elements(b.Generic)) for b in block.Blob if b.HasField("Generic")]
    can = _blocks(items, "XCP_ON_CAN")
    if not can:
        raise ModelError(f"A2L {path}: no IF_DATA XCP with XCP_ON_CAN — not an XCP on CAN slave's description")
    master, slave, bitrate = (_after(can[0], key) for key in ("CAN_ID_MASTER", "CAN_ID_SLAVE", "BAUDRATE"))
    if master is None or slave is None:
        raise ModelError(f"A2L {path}: XCP_ON_CAN states no CAN_ID_MASTER / CAN_ID_SLAVE")
    fd = _blocks(can[0], "CAN_FD")
    data_bitrate = _after(fd[0], "CAN_FD_DATA_TRANSFER_BAUDRATE") if fd else None
    cycle = None
    for event in _blocks(items, "EVENT"):
        numbers = [x for x in event if isinstance(x, int)]
        if len(numbers) >= 4 and numbers[2] > 0:  # channel, max lists, cycle, unit, priority
            cycle = numbers[2] * _TIME_UNITS.get(numbers[3], float("nan"))
            break
    return int(master), int(slave), int(bitrate or 0), None if data_bitrate is None else int(data_bitrate), cycle


def _conversions(module) -> dict[str, tuple[float, float, str]]:
    """COMPU_METHOD name → (factor, offset, unit) of physical = factor · raw + offset."""
    out: dict[str, tuple[float, float, str]] = {"NO_COMPU_METHOD": (1.0, 0.0, "")}
    for method in module.COMPU_METHOD:
        unit = method.Unit.Value
        if method.ConversionType == "IDENTICAL":
            out[method.Name.Value] = (1.0, 0.0, unit)
        elif method.ConversionType == "LINEAR":
            out[method.Name.Value] = (_number(method.COEFFS_LINEAR.A), _number(method.COEFFS_LINEAR.B), unit)
    return out


def read(path) -> EcuDescription:
    """Read an A2L (pya2l) into an :class:`EcuDescription`.

    Parameters
    ----------
    path : path
        The A2L file.

    Raises
    ------
    ModelError
        One line: the file cannot be read or parsed, or it lacks what an XCP on CAN master needs.
    """
    from pya2l import parser

    path = Path(path)
    try:
        text = path.read_bytes()
    except OSError as error:
        raise ModelError(f"A2L {path}: cannot be read ({error.strerror or error})") from None
    try:
        with parser.A2lParser() as a2l_parser:
            tree = a2l_parser.tree_from_a2l(text)
        module = tree.PROJECT.MODULE[0]
    except Exception as error:  # pya2l raises its own kinds, and IndexError on an empty PROJECT
        raise ModelError(f"A2L {path}: does not parse as ASAM MCD-2 MC ({type(error).__name__}: {error})") from None
    master, slave, bitrate, data_bitrate, cycle = _transport(str(path), module)
    conversions = _conversions(module)
    layouts = {r.Name.Value: r.FNC_VALUES.DataType.Value for r in module.RECORD_LAYOUT if r.HasField("FNC_VALUES")}
    measurements = {}
    for m in module.MEASUREMENT:
        if m.HasField("ARRAY_SIZE") or m.HasField("MATRIX_DIM") or m.DataType.Value not in _SIZES:
            continue  # the master measures scalars
        factor, offset, unit = conversions.get(m.Conversion.Value, (1.0, 0.0, ""))
        address = int(m.ECU_ADDRESS.Address.Value)
        measurements[m.Name.Value] = Described(m.Name.Value, address, m.DataType.Value, 1, factor, offset, unit,
                                               _number(m.LowerLimit), _number(m.UpperLimit))  # fmt: skip
    characteristics = {}
    for c in module.CHARACTERISTIC:
        datatype = layouts.get(c.Deposit.Value)
        if c.Type != "VALUE" or datatype not in _SIZES or c.Conversion.Value not in conversions:
            continue  # the master calibrates scalars with a linear conversion
        factor, offset, unit = conversions[c.Conversion.Value]
        characteristics[c.Name.Value] = Described(c.Name.Value, int(c.Address.Value), datatype, 1, factor, offset,
                                                  unit, _number(c.LowerLimit), _number(c.UpperLimit))  # fmt: skip
    mod_par = module.MOD_PAR if module.HasField("MOD_PAR") else None
    epk = mod_par.EPK.Identifier.Value if mod_par is not None and mod_par.HasField("EPK") else None
    epk_address = int(mod_par.ADDR_EPK[0].Address.Value) if mod_par is not None and len(mod_par.ADDR_EPK) else None
    return EcuDescription(str(path), module.Name.Value, epk, epk_address, master, slave, bitrate, data_bitrate,
                          cycle, measurements, characteristics)  # fmt: skip


def size(datatype: str) -> int:
    """Bytes of an A2L data type (UBYTE … FLOAT64_IEEE)."""
    return _SIZES[datatype]


__all__ = ["EcuDescription", "read", "size"]
