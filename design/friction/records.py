"""Friction records: the measured time series identification works on (paper Section 3.2).

A record is a UTF-8 CSV file with a header line that names every column with its unit in
brackets, and optional ``# key = value unit`` metadata lines before it::

    # smartjoint friction record
    # joint_type = B
    # radius = 0.011 m
    # inertia = 0.002 kg*m^2
    time [s],sliding_velocity [rad/s],excitation_force [N*m],normal_force [N]
    0.0,0.0,0.0,400.0
    …

Required columns: ``time``, ``sliding_velocity``, ``normal_force`` and either
``friction_force`` or ``excitation_force`` (then the friction force is the excitation minus
inertia × acceleration, with the ``inertia`` metadata, as in the paper). Type B records give
velocities in rad/s and forces as moments in N·m, and must give the joint ``radius`` (the
moment arm r of u_R = r·F_N·μ): no default is assumed for a user's joint. Units are converted
to SI on reading.

Every value is checked (``record_quantities.BOUNDS``): a record that is not UTF-8 text, an unknown unit, a
missing or repeated column, a row of the wrong length, a cell that is not a finite number, a
time that does not increase, a normal force that is not > 0 or a magnitude beyond the
physically plausible bounds is a one-line ``RecordError`` naming the file, the row (its line
number in the file), the column, the value and what is allowed.
"""

from __future__ import annotations

import csv
import math
from array import array
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter

from smartjoint.common import output_path
from smartjoint.common.errors import SmartjointError
from smartjoint.design.friction.record_quantities import COLUMNS, MIN_NORMAL_FORCE, MIN_RADIUS, UNITS, bound, si_unit


class RecordError(SmartjointError, ValueError):
    """A friction record is malformed."""


REGIMES = ("micro-slip", "stick-slip")
MAX_BYTES = 64 * 1024 * 1024  # 64 MiB: about 900 000 rows of four full-precision columns


@dataclass
class Record:
    """One measured (or simulated) record in SI units.

    ``radius`` is the moment arm r [m] of a type B joint (None for type A).
    """

    name: str
    time: np.ndarray
    sliding_velocity: np.ndarray
    friction_force: np.ndarray  # generalised u_R (N, or N·m for type B)
    normal_force: np.ndarray
    joint_type: str = "A"
    inertia: float | None = None
    excitation_force: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)
    radius: float | None = None

    @property
    def sample_time(self) -> float:
        return float(np.median(np.diff(self.time)))

    @property
    def moment_arm(self) -> float:
        """r for a type B record, 1 for type A (``RecordError`` for type B without a radius)."""
        if self.joint_type == "A":
            return 1.0
        if self.radius is None:
            raise RecordError(
                f"{self.name}: type B record without a radius — add '# radius = <r> m' to the "
                "record (or pass the radius to identify / --radius)"
            )
        return self.radius


def friction_from_excitation(time, velocity, excitation, inertia):
    """u_R = F_exc − m·a, the acceleration from a Savitzky–Golay derivative of the velocity.

    Parameters
    ----------
    time, velocity, excitation : ndarray
        The record's columns (SI).
    inertia : float
        m [kg] (type B: [kg·m²]).

    Returns
    -------
    ndarray
        The friction force u_R.
    """
    dt = float(np.median(np.diff(time)))
    window = min(len(velocity) - (1 - len(velocity) % 2), 11)
    if window < 5:
        acceleration = np.gradient(velocity, time)
    else:
        acceleration = savgol_filter(velocity, window, 3, deriv=1, delta=dt)
    return excitation - inertia * acceleration


def _read_text(path: Path, name: str) -> str:
    """The file as UTF-8 text, at most ``MAX_BYTES`` (a device or a pipe is read no further)."""
    if path.exists() and not path.is_file():
        raise RecordError(f"{name}: not a regular file — a record is a CSV file")
    try:
        with path.open("rb") as handle:
            data = handle.read(MAX_BYTES + 1)
    except OSError as error:
        raise RecordError(f"{name}: cannot read record ({error.strerror or error})") from None
    if len(data) > MAX_BYTES:
        raise RecordError(
            f"{name}: larger than {MAX_BYTES // 2**20} MiB — allowed: records up to that size "
            "(split a longer measurement)"
        )
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        line = data.count(b"\n", 0, error.start) + 1
        column = error.start - (data.rfind(b"\n", 0, error.start) + 1) + 1
        raise RecordError(
            f"{name}: row {line}, character {column}: byte 0x{data[error.start]:02x} is not UTF-8 — "
            "a record must be UTF-8 text (CSV; re-save it as UTF-8)"
        ) from None
    del data
    if "\x00" in text:
        line = text.count("\n", 0, text.index("\x00")) + 1
        raise RecordError(f"{name}: row {line}: NUL byte — a record must be text (CSV), not a binary file")
    return text


def _number(text: str, unit: str, what: str, name: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise RecordError(f"{name}: {what}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise RecordError(f"{name}: {what}: {text!r} — must be a finite number")
    return value


def _metadata_length(
    metadata, key: str, joint_type: str, name: str, lower: float, upper: float, lower_inclusive: bool, kind: str
) -> float | None:
    if key not in metadata:
        return None
    value, unit = metadata[key]
    allowed = UNITS[kind]
    if unit not in allowed:
        raise RecordError(
            f"{name}: metadata {key}: unit {unit!r} unknown — write '# {key} = <value> <unit>' "
            f"with unit one of {', '.join(allowed)}"
        )
    number = _number(value, unit, f"metadata {key}", name) * allowed[unit]
    low_ok = number >= lower if lower_inclusive else number > lower
    if not (low_ok and number <= upper):
        relation = ">=" if lower_inclusive else ">"
        raise RecordError(
            f"{name}: metadata {key}: {value} {unit} — allowed: {relation} {lower:g} and <= "
            f"{upper:g} {si_unit(key, joint_type)}"
        )
    return number


def read_record(path: str | Path, radius: float | None = None) -> Record:
    """Read and check a record (module docstring); ``RecordError`` names what is wrong and where.

    Parameters
    ----------
    path : str or Path
        The record file (CSV).
    radius : float, optional
        [m]: the joint radius of a type B record that does not give one itself (a record that
        does must agree with it). No radius at all for a type B record is an error.

    Returns
    -------
    Record
        The series in SI units; the friction force from the excitation when the record gives
        that instead.

    Raises
    ------
    RecordError
        Naming the file, the row, the column, the value and what is allowed.
    """
    path = Path(path)
    name = str(path)
    text = _read_text(path, name)
    lines = text.splitlines()
    metadata, body_start = _metadata(lines, name)
    joint_type, inertia, radius = _joint_properties(metadata, name, radius)
    reader = csv.reader(lines[body_start:])
    header = next(reader)
    header_row = body_start + 1
    columns = _header_columns(header, header_row, name)
    values, row_numbers = _read_rows(reader, header, columns, body_start, name)

    def cell(column: str, k: int) -> str:
        """The text of data row ``k`` in ``column``, as written (for the messages)."""
        return next(csv.reader([lines[row_numbers[k] - 1]]))[columns[column][0]].strip()

    data = {}
    for column, (_, factor, unit) in columns.items():
        column_values = np.frombuffer(values.pop(column), dtype=float) * factor
        _check_column(
            name, column, column_values, unit, factor, joint_type, row_numbers, lambda k, column=column: cell(column, k)
        )
        data[column] = column_values
    steps = np.diff(data["time"])
    smallest = bound("time_step", joint_type)
    if np.any(steps < smallest):
        first = int(np.flatnonzero(steps < smallest)[0]) + 1
        raise RecordError(
            f"{name}: row {row_numbers[first]}, column 'time': {cell('time', first)} after "
            f"{cell('time', first - 1)} — time does not increase (allowed: each row at least "
            f"{smallest:g} s after the one before)"
        )
    if "friction_force" in data:
        friction = data["friction_force"]
    else:
        if inertia is None:
            raise RecordError(f"{name}: column 'excitation_force' needs the '# inertia = <value> kg' metadata line")
        friction = friction_from_excitation(data["time"], data["sliding_velocity"], data["excitation_force"], inertia)
    return Record(
        path.stem,
        data["time"],
        data["sliding_velocity"],
        friction,
        data["normal_force"],
        joint_type,
        inertia,
        data.get("excitation_force"),
        {k: " ".join(v).strip() for k, v in metadata.items()},
        radius,
    )


def _metadata(lines: list[str], name: str) -> tuple[dict[str, tuple[str, ...]], int]:
    """The ``# key = value unit`` lines before the header, and the header's line index."""
    metadata: dict[str, tuple[str, ...]] = {}
    body_start = 0
    for number, line in enumerate(lines):
        if line.startswith("#"):
            if "=" in line:
                key, _, value = line[1:].partition("=")
                if not value.strip():
                    raise RecordError(
                        f"{name}: line {number + 1}, metadata {key.strip()}: empty — write "
                        f"'# {key.strip()} = <value> [unit]' or leave the line out"
                    )
                metadata[key.strip()] = tuple((value.strip().split(None, 1) + [""])[:2])
            continue
        body_start = number
        break
    else:
        raise RecordError(f"{name}: no header line (expected e.g. 'time [s],sliding_velocity [m/s],…')")
    return metadata, body_start


def _joint_properties(metadata, name: str, given: float | None) -> tuple[str, float | None, float | None]:
    """Joint type, inertia and radius from the metadata; ``given`` is the radius passed in."""
    joint_type = metadata.get("joint_type", ("A", ""))[0]
    if joint_type not in ("A", "B"):
        raise RecordError(f"{name}: metadata joint_type: {joint_type!r} — allowed: A, B")
    regime = " ".join(metadata["regime"]).strip() if "regime" in metadata else None
    if regime is not None and regime not in REGIMES:
        raise RecordError(
            f"{name}: metadata regime: {regime!r} — allowed: {', '.join(REGIMES)} (or no regime line: "
            "then identify classifies the record by whether it slides)"
        )
    inertia = _metadata_length(metadata, "inertia", joint_type, name, 0.0, bound("inertia", joint_type), True, "mass")
    radius = _metadata_length(
        metadata, "radius", joint_type, name, MIN_RADIUS, bound("radius", joint_type), True, "length"
    )
    if joint_type == "A" and (radius is not None or given is not None):
        raise RecordError(
            f"{name}: {'metadata radius' if radius is not None else f'radius {given!r} m given'}: a "
            "type A joint has no radius — allowed only with '# joint_type = B'"
        )
    if joint_type == "B" and given is not None:
        if not (math.isfinite(given) and MIN_RADIUS <= given <= bound("radius", "B")):
            raise RecordError(
                f"{name}: radius {given!r} m given — allowed: {MIN_RADIUS:g} … {bound('radius', 'B'):g} m"
            )
        if radius is not None and radius != given:
            raise RecordError(
                f"{name}: metadata radius: {radius!r} m, but radius {given!r} m was given — the record's "
                "own radius and the given one must agree (or give none)"
            )
        radius = float(given)
    if joint_type == "B" and radius is None:
        raise RecordError(
            f"{name}: metadata radius: missing — a type B record must give its joint radius, e.g. "
            f"'# radius = 0.011 m' (allowed: {MIN_RADIUS:g} … {bound('radius', 'B'):g} m), or pass "
            "it (identify --radius); no default is assumed"
        )
    return joint_type, inertia, radius


def _header_columns(header: list[str], header_row: int, name: str) -> dict[str, tuple[int, float, str]]:
    """The known columns of the header: (index, factor to SI, unit) by column name."""
    columns: dict[str, tuple[int, float, str]] = {}
    for index, cell in enumerate(header):
        cell = cell.strip()
        if "[" not in cell or not cell.endswith("]"):
            raise RecordError(f"{name}: row {header_row}: column {cell!r} has no unit — write it as 'name [unit]'")
        column, unit = cell[:-1].split("[", 1)
        column, unit = column.strip(), unit.strip()
        if column not in COLUMNS:
            continue  # extra columns are allowed and ignored
        if column in columns:
            raise RecordError(f"{name}: row {header_row}: column {column!r} appears twice — allowed: once")
        allowed = UNITS[COLUMNS[column]]
        if unit not in allowed:
            raise RecordError(
                f"{name}: row {header_row}, column {column!r}: unit {unit!r} unknown; allowed: {', '.join(allowed)}"
            )
        columns[column] = (index, allowed[unit], unit)
    for required in ("time", "sliding_velocity", "normal_force"):
        if required not in columns:
            raise RecordError(
                f"{name}: row {header_row}: column {required!r} missing; header has "
                f"{', '.join(h.strip() for h in header)}"
            )
    if "friction_force" not in columns and "excitation_force" not in columns:
        raise RecordError(
            f"{name}: row {header_row}: needs column 'friction_force' or 'excitation_force' (with '# inertia = …')"
        )
    return columns


def _read_rows(reader, header: list[str], columns, body_start: int, name: str):
    """The data rows, column by column, and the file line number of each row."""
    # Column by column into float arrays as the rows come: no cell strings are kept, so a
    # record of MAX_BYTES needs a few hundred MB at most.
    values = {column: array("d") for column in columns}
    row_numbers = array("q")
    for row in reader:
        if not row or all(not c.strip() for c in row):
            continue
        line_number = body_start + reader.line_num
        if len(row) != len(header):
            raise RecordError(f"{name}: row {line_number} has {len(row)} fields, the header {len(header)}")
        for column, (index, _, _) in columns.items():
            try:
                values[column].append(float(row[index]))
            except ValueError:
                raise RecordError(
                    f"{name}: row {line_number}, column {column!r}: {row[index].strip()} — not a "
                    "number (allowed: a finite number)"
                ) from None
        row_numbers.append(line_number)
    if len(row_numbers) < 3:
        raise RecordError(f"{name}: {len(row_numbers)} data rows — need at least 3")
    return values, row_numbers


def _check_column(name, column, values, unit, factor, joint_type, row_numbers, cells=None) -> None:
    """Finite values within ``BOUNDS``; F_N > 0. Names the first offending row."""
    limit = bound(column, joint_type)
    shown = f"{limit / factor:g} {unit}"
    if column == "normal_force":
        bad = ~(np.isfinite(values) & (values >= MIN_NORMAL_FORCE) & (values <= limit))
        allowed = f"F_N must be > 0: allowed {MIN_NORMAL_FORCE / factor:g} … {shown}"
    else:
        bad = ~(np.isfinite(values) & (np.abs(values) <= limit))
        allowed = f"allowed: a finite number with magnitude <= {shown}"
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        shown_value = cells(first) if cells is not None else repr(float(values[first] / factor))
        raise RecordError(f"{name}: row {row_numbers[first]}, column {column!r}: {shown_value} {unit} — {allowed}")


def write_record(record: Record, path: str | Path) -> None:
    """Write a record as CSV (atomically: through a temporary file, removed on failure).

    A type B record must carry its radius, so that the file reads back as it was written.

    Parameters
    ----------
    record : Record
        The record.
    path : str or Path
        The file.
    """
    path = Path(path)
    rotational = record.joint_type == "B"
    if rotational and record.radius is None:
        raise RecordError(f"{path}: type B record {record.name!r} without a radius — cannot be written readably")
    velocity_unit, force_unit = ("rad/s", "N*m") if rotational else ("m/s", "N")
    lines = ["# smartjoint friction record", f"# joint_type = {record.joint_type}"]
    if rotational:
        lines.append(f"# radius = {record.radius!r} m")
    if record.inertia is not None:
        lines.append(f"# inertia = {record.inertia!r} {'kg*m^2' if rotational else 'kg'}")
    for key, value in sorted(record.metadata.items()):
        if key not in ("joint_type", "inertia", "radius"):
            lines.append(f"# {key} = {' '.join(str(value).split())}")
    columns = [("time [s]", record.time), (f"sliding_velocity [{velocity_unit}]", record.sliding_velocity)]
    if record.excitation_force is not None:
        columns.append((f"excitation_force [{force_unit}]", record.excitation_force))
    else:
        columns.append((f"friction_force [{force_unit}]", record.friction_force))
    columns.append(("normal_force [N]", record.normal_force))
    lines.append(",".join(c for c, _ in columns))
    first_row = len(lines) + 1
    for title, values in columns:
        column, unit = title[:-1].split(" [")
        _check_column(
            str(path),
            column,
            np.asarray(values, dtype=float),
            unit,
            1.0,
            record.joint_type,
            range(first_row, first_row + len(values)),
        )
    matrix = np.column_stack([v for _, v in columns])
    lines += [",".join(repr(float(x)) for x in row) for row in matrix]
    try:
        output_path.write_file(path, "\n".join(lines) + "\n")
    except OSError as error:
        raise RecordError(f"{path}: cannot write record ({error.strerror or error})") from None


__all__ = [
    "MAX_BYTES",
    "REGIMES",
    "Record",
    "RecordError",
    "friction_from_excitation",
    "read_record",
    "write_record",
]
