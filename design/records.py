"""Friction records: the measured time series identification works on (paper Section 3.2).

A record is a CSV file with a header line that names every column with its unit in
brackets, and optional ``# key = value unit`` metadata lines before it::

    # smartjoint friction record
    # joint_type = A
    # inertia = 0.5 kg
    time [s],sliding_velocity [m/s],excitation_force [N],normal_force [N]
    0.0,0.0,0.0,400.0
    …

Required columns: ``time``, ``sliding_velocity``, ``normal_force`` and either
``friction_force`` or ``excitation_force`` (then the friction force is the excitation minus
inertia × acceleration, with the ``inertia`` metadata, as in the paper). Type B records give
velocities in rad/s and forces as moments in N·m. Units are converted to SI on reading; an
unknown unit, a missing column, NaN, a non-increasing time or a row of the wrong length is an
error naming the file, the column or row, and what is allowed.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter

from .errors import SmartjointError


class RecordError(SmartjointError, ValueError):
    """A friction record is malformed."""


# unit → factor to SI, per quantity kind
_UNITS = {
    "time": {"s": 1.0, "ms": 1e-3},
    "velocity": {"m/s": 1.0, "mm/s": 1e-3, "rad/s": 1.0, "mrad/s": 1e-3},
    "force": {"N": 1.0, "kN": 1e3, "N*m": 1.0, "N·m": 1.0, "Nm": 1.0},
    "mass": {"kg": 1.0, "g": 1e-3, "kg*m^2": 1.0, "kg·m²": 1.0, "kg m2": 1.0},
}
COLUMNS = {
    "time": "time",
    "sliding_velocity": "velocity",
    "friction_force": "force",
    "excitation_force": "force",
    "normal_force": "force",
}


@dataclass
class Record:
    """One measured (or simulated) record in SI units."""

    name: str
    time: np.ndarray
    sliding_velocity: np.ndarray
    friction_force: np.ndarray  # generalised u_R (N, or N·m for type B)
    normal_force: np.ndarray
    joint_type: str = "A"
    inertia: float | None = None
    excitation_force: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)

    @property
    def sample_time(self) -> float:
        return float(np.median(np.diff(self.time)))


def friction_from_excitation(time, velocity, excitation, inertia):
    """u_R = F_exc − m·a, the acceleration from a Savitzky–Golay derivative of the velocity."""
    dt = float(np.median(np.diff(time)))
    window = min(len(velocity) - (1 - len(velocity) % 2), 11)
    if window < 5:
        acceleration = np.gradient(velocity, time)
    else:
        acceleration = savgol_filter(velocity, window, 3, deriv=1, delta=dt)
    return excitation - inertia * acceleration


def read_record(path: str | Path) -> Record:
    path = Path(path)
    name = str(path)
    try:
        text = path.read_text()
    except OSError as error:
        raise RecordError(f"{name}: cannot read record ({error.strerror})") from None
    metadata: dict[str, tuple[str, str]] = {}
    lines = text.splitlines()
    body_start = 0
    for number, line in enumerate(lines):
        if line.startswith("#"):
            if "=" in line:
                key, _, value = line[1:].partition("=")
                metadata[key.strip()] = tuple((value.strip().split(None, 1) + [""])[:2])
            continue
        body_start = number
        break
    else:
        raise RecordError(f"{name}: no header line (expected e.g. 'time [s],sliding_velocity [m/s],…')")
    reader = csv.reader(lines[body_start:])
    header = next(reader)
    columns: dict[str, tuple[int, float]] = {}
    for index, cell in enumerate(header):
        cell = cell.strip()
        if "[" not in cell or not cell.endswith("]"):
            raise RecordError(f"{name}: column {cell!r} has no unit — write it as 'name [unit]'")
        column, unit = cell[:-1].split("[", 1)
        column, unit = column.strip(), unit.strip()
        if column not in COLUMNS:
            continue  # extra columns are allowed and ignored
        allowed = _UNITS[COLUMNS[column]]
        if unit not in allowed:
            raise RecordError(f"{name}: column {column!r}: unit {unit!r} unknown; allowed: {', '.join(allowed)}")
        columns[column] = (index, allowed[unit])
    for required in ("time", "sliding_velocity", "normal_force"):
        if required not in columns:
            raise RecordError(f"{name}: column {required!r} missing; header has {', '.join(h.strip() for h in header)}")
    if "friction_force" not in columns and "excitation_force" not in columns:
        raise RecordError(f"{name}: needs column 'friction_force' or 'excitation_force' (with '# inertia = …')")
    rows = []
    for row_number, row in enumerate(reader, start=body_start + 2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise RecordError(f"{name}: row {row_number} has {len(row)} fields, the header {len(header)}")
        rows.append(row)
    if len(rows) < 3:
        raise RecordError(f"{name}: {len(rows)} data rows — need at least 3")
    data = {}
    for column, (index, factor) in columns.items():
        try:
            values = np.array([float(r[index]) for r in rows]) * factor
        except ValueError as error:
            raise RecordError(f"{name}: column {column!r}: not a number ({error})") from None
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise RecordError(f"{name}: column {column!r}: NaN or infinite value at data row {bad[0] + 1}")
        data[column] = values
    if np.any(np.diff(data["time"]) <= 0):
        first = int(np.flatnonzero(np.diff(data["time"]) <= 0)[0])
        raise RecordError(f"{name}: column 'time' does not increase at data row {first + 2}")
    joint_type = metadata.get("joint_type", ("A", ""))[0]
    if joint_type not in ("A", "B"):
        raise RecordError(f"{name}: joint_type {joint_type!r} — allowed: A, B")
    inertia = None
    if "inertia" in metadata:
        value, unit = metadata["inertia"]
        if unit not in _UNITS["mass"]:
            raise RecordError(f"{name}: inertia unit {unit!r} unknown; allowed: {', '.join(_UNITS['mass'])}")
        try:
            inertia = float(value) * _UNITS["mass"][unit]
        except ValueError:
            raise RecordError(f"{name}: inertia {value!r} is not a number") from None
        if not (math.isfinite(inertia) and inertia >= 0):
            raise RecordError(f"{name}: inertia {value!r} must be a finite number >= 0")
    if "friction_force" in data:
        friction = data["friction_force"]
    else:
        if inertia is None:
            raise RecordError(f"{name}: column 'excitation_force' needs the '# inertia = <value> kg' metadata line")
        friction = friction_from_excitation(data["time"], data["sliding_velocity"], data["excitation_force"], inertia)
    return Record(path.stem, data["time"], data["sliding_velocity"], friction, data["normal_force"], joint_type,
                  inertia, data.get("excitation_force"), {k: " ".join(v).strip() for k, v in metadata.items()})


def write_record(record: Record, path: str | Path) -> None:
    """Write a record as CSV (atomically: through a temporary file)."""
    path = Path(path)
    rotational = record.joint_type == "B"
    velocity_unit, force_unit = ("rad/s", "N*m") if rotational else ("m/s", "N")
    lines = ["# smartjoint friction record", f"# joint_type = {record.joint_type}"]
    if record.inertia is not None:
        lines.append(f"# inertia = {record.inertia!r} {'kg*m^2' if rotational else 'kg'}")
    for key, value in sorted(record.metadata.items()):
        if key not in ("joint_type", "inertia"):
            lines.append(f"# {key} = {value}")
    columns = [("time [s]", record.time), (f"sliding_velocity [{velocity_unit}]", record.sliding_velocity)]
    if record.excitation_force is not None:
        columns.append((f"excitation_force [{force_unit}]", record.excitation_force))
    else:
        columns.append((f"friction_force [{force_unit}]", record.friction_force))
    columns.append(("normal_force [N]", record.normal_force))
    lines.append(",".join(c for c, _ in columns))
    matrix = np.column_stack([v for _, v in columns])
    lines += [",".join(repr(float(x)) for x in row) for row in matrix]
    temporary = path.with_name(path.name + ".partial")
    temporary.write_text("\n".join(lines) + "\n")
    temporary.replace(path)
