"""The FMI standard's C headers, from the installed FMPy (never copied into the repository).

An FMU's sources compile against the headers of its FMI version; ``codegen.fmu`` puts them into
the FMU beside the generated files, so the unpacked FMU compiles alone. The FMI 3 header of
function types also gives the exact prototypes of the functions a co-simulation FMU does not
offer but must export (:func:`unsupported_fmi3`).
"""

from __future__ import annotations

import importlib.util
import re
from dataclasses import dataclass
from pathlib import Path

from smartjoint.common.errors import ModelError

HEADERS = {
    2: ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"),
    3: ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h"),
}


def folder() -> Path:
    """FMPy's folder of FMI headers (``fmpy/c-code``).

    Raises
    ------
    ModelError
        FMPy is not installed, or ships no headers.
    """
    spec = importlib.util.find_spec("fmpy")
    if spec is None or spec.origin is None:
        raise ModelError("fmu: FMPy is not installed (pip install fmpy) — its FMI headers build the FMU")
    path = Path(spec.origin).parent / "c-code"
    if not (path / HEADERS[3][0]).is_file():
        raise ModelError(f"fmu: FMPy at {path.parent} ships no FMI headers in c-code/")
    return path


def files(version: int) -> dict[str, str]:
    """The headers of FMI ``version`` (2 or 3): file name → text."""
    if version not in HEADERS:
        raise ModelError(f"--fmi: {version!r} — allowed: 2, 3")
    return {name: (folder() / name).read_text() for name in HEADERS[version]}


@dataclass(frozen=True)
class Prototype:
    """A function of the FMI 3 API: its return type, name, parameter list (C text) and the
    parameters' names after the first (the instance)."""

    returns: str
    name: str
    parameters: str
    names: tuple[str, ...]
    why: str


_TYPEDEF = re.compile(r"typedef\s+(fmi3Status)\s+(fmi3\w+)TYPE\s*\(([^;]*?)\)\s*;", re.S)
_WHY = (
    ("Clock", "this FMU has no clocks"),
    ("Interval", "this FMU has no clocks"),
    ("Shift", "this FMU has no clocks"),
    ("Derivative", "this FMU provides no partial derivatives"),
    ("Configuration", "this FMU has no structural parameters"),
    ("Event", "this FMU has no event mode"),
    ("DiscreteStates", "this FMU has no event mode"),
    ("ModelPartition", "this FMU is for co-simulation only"),
)


def _reason(name: str) -> str:
    for part, why in _WHY:
        if part in name:
            return why
    kind = re.match(r"fmi3[GS]et(Float32|U?Int(8|16|32|64)|Boolean|String|Binary)$", name)
    if kind:
        return f"this FMU has no {kind.group(1)} variables"
    return "this FMU is for co-simulation only"


def unsupported_fmi3(implemented: set[str]) -> list[Prototype]:
    """The FMI 3 functions returning ``fmi3Status`` that are not in ``implemented``, with their
    prototypes as the header declares them (for stubs that refuse).

    Parameters
    ----------
    implemented : set of str
        The names the FMU's own template defines.

    Returns
    -------
    list of Prototype
        In the header's order.
    """
    text = re.sub(r"/\*.*?\*/", " ", files(3)["fmi3FunctionTypes.h"], flags=re.S)
    out = []
    for returns, name, parameters in _TYPEDEF.findall(text):
        if name in implemented:
            continue
        parts = [" ".join(p.split()) for p in parameters.split(",")]
        names = tuple(re.sub(r"\[\s*\]$", "", p).split()[-1].lstrip("*") for p in parts)
        if not parts or not parts[0].startswith("fmi3Instance"):
            raise ModelError(f"fmu: {name} in FMPy's fmi3FunctionTypes.h does not take the instance first")
        out.append(Prototype(returns, name, ", ".join(parts), names[1:], _reason(name)))
    return out


__all__ = ["HEADERS", "Prototype", "files", "folder", "unsupported_fmi3"]
