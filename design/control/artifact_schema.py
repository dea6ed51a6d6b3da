"""The schema of the controller design artefact (``schema_version`` 6,
``docs/controller-artifact.md``) and its validation: every field's kind, shape (symbols n, 2n,
l, n_y), unit and limits, checked with one-line errors that name the field and the value."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from smartjoint.common import friction_registry, law_registry
from smartjoint.common.errors import ModelError

# 2: the safe state and the plausibility ranges (docs/safety.md); 3: the joints' friction; 4: nested,
# one section per component (artifact_layout).
SCHEMA_VERSION = 7
# 5: four laws; 6: the SISO law's own F_N^min (``laws.siso.normal_force_min``, a preload): a
# version-5 file reads as version 6 with it equal to the joints' F_N^min (``migrated``); 7: the
# actuation check's tolerance (``safety.actuation_tolerance``): a version-6 file reads as version 7
# with the default, 0.1 × F_N^max.
# The model whose parameters the artefact's friction section holds (its columns, in order).
FRICTION_MODEL = friction_registry.LUGRE
# Plausibility bound on F_N^max: a bolted friction joint is clamped with kN, the largest piezo
# stacks block at ~100 kN; 1 MN is a typing error (an exponent too many), not a design.
NORMAL_FORCE_LIMIT = 1e6  # N


@dataclass(frozen=True)
class FieldSpec:
    """One key of the artefact: its kind, shape (symbols n, 2n, l, n_y), unit and meaning."""

    name: str
    kind: str  # "integer" | "string" | "names" (unique) | "strings" | "number" | "array"
    shape: tuple = ()
    unit: str = ""
    meaning: str = ""


def _law_settings() -> dict:
    """Artefact field → the law setting it holds (``Law.artifact`` maps a setting's key to it)."""
    out = {}
    for law in law_registry.LAWS.values():
        by_key = dict(law.artifact)
        for setting in law.settings:
            out[by_key[setting.key]] = setting
    return out


LAW_SETTINGS = _law_settings()
SCHEMA: tuple[FieldSpec, ...] = (
    FieldSpec("schema_version", "integer", meaning="format version of this file (1)"),
    FieldSpec("name", "string", meaning="design name"),
    FieldSpec("sample_time", "number", unit="s", meaning="controller sample time Δt (> 0)"),
    FieldSpec("joint_names", "names", ("l",), meaning="controlled joints: order of E/K columns and per-joint vectors"),
    FieldSpec("sensor_names", "names", ("ny",), meaning="sensors: order of the rows of C and of y"),
    FieldSpec("normal_force_min", "array", ("l",), "N", "F_N^min per joint, Eq. 30/34 (> 0)"),
    FieldSpec("normal_force_max", "array", ("l",), "N", "F_N^max per joint, Eq. 30/34 (>= F_N^min)"),
    *(  # each law's settings (common.law_registry), > 0
        FieldSpec(
            field,
            "array" if setting.per_joint else "number",
            ("l",) if setting.per_joint else (),
            setting.unit,
            f"{setting.meaning} (> 0)",
        )
        for field, setting in LAW_SETTINGS.items()
    ),  # fmt: skip
    FieldSpec("blocks", "array", ("n", 2, 2), meaning="Φ_i: 2×2 diagonal blocks of the discrete state matrix"),
    FieldSpec("gamma0", "array", ("n", 2), meaning="γ0_i: first-order-hold input weight of u_k"),
    FieldSpec("gamma1", "array", ("n", 2), meaning="γ1_i: first-order-hold input weight of u_k+1"),
    FieldSpec("joint_input", "array", ("n", "l"), meaning="E: modal joint input, friction acts as −E·u_R"),
    FieldSpec("output", "array", ("ny", "2n"), meaning="C: y = C·x, Eq. 10"),
    FieldSpec("feedback_gain", "array", ("l", "2n"), meaning="K: LQR gain, u_d = −K·x̂, Eq. 33"),
    FieldSpec("estimator_gain", "array", ("2n", "ny"), meaning="M: current-form Kalman gain, Eq. 33"),
    FieldSpec("modal_frequencies", "array", ("n",), "Hz", "ω_i/2π of the retained coordinates (information)"),
    FieldSpec("piezo_capacitance", "number", unit="F", meaning="capacitance of one piezo stack"),
    FieldSpec("piezo_force_per_volt", "number", unit="N/V", meaning="F_N = force_per_volt·V + preload"),
    FieldSpec("piezo_preload", "number", unit="N", meaning="normal force at 0 V (>= 0, <= F_N^min)"),
    FieldSpec("sensor_quantities", "strings", ("ny",), meaning="per sensor: displacement (m) or velocity (m/s)"),
    FieldSpec("joint_types", "strings", ("l",), meaning="per joint: A (axial slip) or B (rotation), paper Fig. 3"),
    FieldSpec(
        "friction_parameters",
        "array",
        ("l", len(FRICTION_MODEL.parameters)),
        "Table 1 units",
        f"per joint the {FRICTION_MODEL.display} {', '.join(p.symbol for p in FRICTION_MODEL.parameters)} per unit F_N "
        f"({FRICTION_MODEL.cited()}) the design was made with (information)",
    ),
    FieldSpec("friction_radius", "array", ("l",), "m", "per joint r of a type B joint, 0 for type A (information)"),
    FieldSpec("friction_sources", "strings", ("l",), meaning="per joint where its friction parameters came from"),
    FieldSpec(
        "safe_normal_force",
        "array",
        ("l",),
        "N",
        "F_N of every joint while the controller cannot act (within [F_N^min, F_N^max]; docs/safety.md)",
    ),
    FieldSpec("sliding_velocity_limit", "array", ("l",), "m/s", "|v| above is implausible (> 0)"),
    FieldSpec("friction_force_limit", "array", ("l",), "N", "|u_R| above is implausible (> 0)"),
    FieldSpec("measured_normal_force_min", "array", ("l",), "N", "a measured F_N below is implausible (<= 0)"),
    FieldSpec("measured_normal_force_max", "array", ("l",), "N", "a measured F_N above is implausible (>= F_N^max)"),
    FieldSpec("sensor_limit", "array", ("ny",), "m or m/s", "|y| above is implausible (> 0)"),
    FieldSpec("amplifier_temperature_limit", "number", unit="degC", meaning="amplifier temperature above is a fault"),
    FieldSpec("amplifier_current_limit", "number", unit="A", meaning="|amplifier current| above is a fault (> 0)"),
    FieldSpec(
        "tracking_tolerance", "number", unit="V", meaning="|monitor voltage − setpoint| above is a tracking fault (> 0)"
    ),
    FieldSpec(
        "actuation_tolerance",
        "array",
        ("l",),
        "N",
        "a measured F_N this far below the least of the last three commands: the joint does not follow "
        "(> 0, <= F_N^max)",
    ),
    FieldSpec(
        "timeout_cycles",
        "integer",
        meaning="an input whose newest frame is this many cycles old is missing "
        "(a whole number 2 … 7; firmware and amplifiers)",
    ),
    FieldSpec("recovery_cycles", "integer", meaning="fault-free cycles in a row before the safe state ends (1 … 255)"),
    FieldSpec(
        "design_source",
        "string",
        meaning="file name of the design (no folder: the text must not depend on where it lies)",
    ),
    FieldSpec("design_sha256", "string", meaning='SHA-256 of the design file bytes ("" for in-memory designs)'),
    FieldSpec("package_version", "string", meaning="smartjoint version that wrote the artefact"),
)
FIELDS = {spec.name: spec for spec in SCHEMA}
_HEX64 = re.compile(r"[0-9a-f]{64}")


def _shown(value) -> str:
    text = repr(value.tolist() if isinstance(value, np.ndarray) else value)
    return text if len(text) <= 60 else text[:57] + "..."


def field_error(field: str, value, allowed: str) -> ModelError:
    """A one-line error naming the field, the value (shortened) and what is allowed.

    Parameters
    ----------
    field : str
        The field (``joint_names[2]``).
    value : object
        The value found.
    allowed : str
        What the field accepts.

    Returns
    -------
    ModelError
        To be raised.
    """
    return ModelError(f"{field}: {_shown(value)} — {allowed}")


def validated(values: dict) -> dict:
    """Check every field (kind, shape, finiteness, limits); return them in stored form.

    Parameters
    ----------
    values : dict
        A value for every field of `SCHEMA`.

    Returns
    -------
    dict
        The fields in stored form: tuples of names, read-only float64 arrays, floats, ints.

    Raises
    ------
    ModelError
        Naming the first field that is wrong and what it accepts.
    """
    out: dict[str, Any] = {"schema_version": check_version(values["schema_version"])}
    for spec in SCHEMA:
        value = values[spec.name]
        if spec.kind == "string":
            if not isinstance(value, str):
                raise field_error(spec.name, value, "expected a string")
            out[spec.name] = value
        elif spec.kind == "number":
            out[spec.name] = _number(spec.name, value)
        elif spec.kind == "names":
            out[spec.name] = _names(spec.name, value)
        elif spec.kind == "strings":
            out[spec.name] = _strings(spec.name, value)
        elif spec.kind == "integer" and spec.name != "schema_version":
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
                raise field_error(spec.name, value, "expected a whole number")
            out[spec.name] = int(value)
        elif spec.kind == "array":
            out[spec.name] = _array(spec.name, value)
    for field in ("name", "package_version"):
        if not out[field]:
            raise field_error(field, out[field], "expected a non-empty string")
    if out["design_sha256"] and not _HEX64.fullmatch(out["design_sha256"]):
        raise field_error("design_sha256", out["design_sha256"], 'expected 64 lowercase hex digits or ""')
    scalars = [field for field, setting in LAW_SETTINGS.items() if not setting.per_joint]
    for field in ("sample_time", *scalars, "piezo_capacitance", "piezo_force_per_volt"):
        if out[field] <= 0:
            raise field_error(field, out[field], f"must be > 0 [{FIELDS[field].unit}]")
    if out["piezo_preload"] < 0:
        raise field_error("piezo_preload", out["piezo_preload"], "must be >= 0 [N]")
    _check_shapes(out)
    _check_joints(out)
    if np.any(out["modal_frequencies"] <= 0):
        raise field_error("modal_frequencies", out["modal_frequencies"], "must be > 0 [Hz]")
    _check_safety(out)
    return out


def _check_shapes(out: dict) -> None:
    """Every array of the shape its symbols give, with n from ``blocks`` and l, n_y from the names."""
    blocks = out["blocks"]
    if blocks.ndim != 3 or blocks.shape[0] < 1 or blocks.shape[1:] != (2, 2):
        raise ModelError(f"blocks: shape {blocks.shape} — expected (n, 2, 2) with n >= 1 retained coordinates")
    n, l, ny = blocks.shape[0], len(out["joint_names"]), len(out["sensor_names"])
    sizes = {"n": n, "2n": 2 * n, "l": l, "ny": ny}
    for field, count, what in (
        ("sensor_quantities", ny, "one per sensor (n_y"),
        ("joint_types", l, "one per joint (l"),
        ("friction_sources", l, "one per joint (l"),
    ):
        if len(out[field]) != count:
            raise ModelError(f"{field}: {len(out[field])} entries — expected {what} = {count})")
    for spec in SCHEMA:
        if spec.kind == "array":
            expected = tuple(sizes.get(s, s) for s in spec.shape)
            if out[spec.name].shape != expected:
                symbols = ", ".join(str(s) for s in spec.shape) + ("," if len(spec.shape) == 1 else "")
                raise ModelError(
                    f"{spec.name}: shape {out[spec.name].shape} — expected {expected} = ({symbols}) "
                    f"with n = {n} coordinates, l = {l} joints, n_y = {ny} sensors"
                )


def _check_joints(out: dict) -> None:
    """Per joint: 0 < F_N^min <= F_N^max within the plausible limit, the preload below F_N^min, ε > 0."""
    low, high = out["normal_force_min"], out["normal_force_max"]
    for j, joint in enumerate(out["joint_names"]):
        if not 0 < low[j] <= high[j]:
            raise ModelError(
                f"normal_force_min/normal_force_max: {float(low[j])!r}/{float(high[j])!r} N for joint "
                f"{joint!r} — need 0 < F_N^min <= F_N^max"
            )
        if high[j] > NORMAL_FORCE_LIMIT:
            raise ModelError(
                f"normal_force_max[{j}]: {float(high[j])!r} N for joint {joint!r} — at most "
                f"{NORMAL_FORCE_LIMIT:g} N (1 MN: far beyond any piezo-clamped friction joint)"
            )
        if out["piezo_preload"] > low[j]:
            raise ModelError(
                f"piezo_preload: {out['piezo_preload']!r} N — above normal_force_min[{j}] = "
                f"{float(low[j])!r} N of joint {joint!r}: at 0 V the stack already presses with the "
                "preload, so F_N^min is out of reach; need piezo_preload <= F_N^min"
            )
        _check_friction(out, j, joint)
        for field, setting in LAW_SETTINGS.items():
            value = float(out[field][j] if setting.per_joint else out[field])
            if setting.normal_force and not low[j] <= value <= high[j]:
                raise ModelError(
                    f"{field}: {value!r} N for joint {joint!r} — {setting.meaning} must lie within "
                    f"[normal_force_min, normal_force_max] = [{float(low[j])!r}, {float(high[j])!r}] N"
                )
            if setting.per_joint and out[field][j] <= 0:
                raise ModelError(
                    f"{field}: {float(out[field][j])!r} for joint {joint!r} — {setting.meaning} must be > 0 "
                    f"[{setting.unit}]"
                )


def _check_friction(out: dict, j: int, joint: str) -> None:
    """A joint's type, its friction parameters (each > 0, or >= 0 where the model allows zero) and its radius."""
    joint_type, values, radius = out["joint_types"][j], out["friction_parameters"][j], out["friction_radius"][j]
    if joint_type not in ("A", "B"):
        raise field_error(f"joint_types[{j}]", joint_type, f"joint {joint!r}: allowed: A, B")
    positive = np.array([not p.may_be_zero for p in FRICTION_MODEL.parameters])
    if np.any(values < 0) or np.any(values[positive] <= 0):
        symbols = [p.symbol for p in FRICTION_MODEL.parameters]
        strict = ", ".join(s for s, must in zip(symbols, positive) if must)
        zero = ", ".join(s for s, must in zip(symbols, positive) if not must)
        raise field_error(f"friction_parameters[{j}]", values, f"joint {joint!r}: {strict} must be > 0 and {zero} >= 0")
    if (joint_type == "B") != (radius > 0) or radius < 0:
        raise field_error(f"friction_radius[{j}]", float(radius), f"joint {joint!r}: > 0 [m] for type B, 0 for type A")


SENSOR_QUANTITIES = ("displacement", "velocity")


def _check_safety(out: dict) -> None:
    """The safe force within the limits, the plausibility ranges around what the law can see."""
    for i, quantity in enumerate(out["sensor_quantities"]):
        if quantity not in SENSOR_QUANTITIES:
            raise field_error(f"sensor_quantities[{i}]", quantity, "allowed: " + ", ".join(SENSOR_QUANTITIES))
    low, high = out["normal_force_min"], out["normal_force_max"]
    for j, joint in enumerate(out["joint_names"]):
        safe = float(out["safe_normal_force"][j])
        if not low[j] <= safe <= high[j]:
            raise ModelError(
                f"safe_normal_force[{j}]: {safe!r} N for joint {joint!r} — must lie within "
                f"[normal_force_min, normal_force_max] = [{float(low[j])!r}, {float(high[j])!r}] N"
            )
        for field in ("sliding_velocity_limit", "friction_force_limit"):
            if out[field][j] <= 0:
                raise ModelError(
                    f"{field}[{j}]: {float(out[field][j])!r} for joint {joint!r} — must be > 0 [{FIELDS[field].unit}]"
                )
        if out["measured_normal_force_min"][j] > 0:
            raise ModelError(
                f"measured_normal_force_min[{j}]: {float(out['measured_normal_force_min'][j])!r} N for "
                f"joint {joint!r} — must be <= 0 N (an unloaded joint reads 0 N)"
            )
        if not 0 < out["actuation_tolerance"][j] <= high[j]:
            raise ModelError(
                f"actuation_tolerance[{j}]: {float(out['actuation_tolerance'][j])!r} N for joint {joint!r} — "
                f"must be > 0 and <= normal_force_max = {float(high[j])!r} N"
            )
        if out["measured_normal_force_max"][j] < high[j]:
            raise ModelError(
                f"measured_normal_force_max[{j}]: {float(out['measured_normal_force_max'][j])!r} N for "
                f"joint {joint!r} — must be >= normal_force_max = {float(high[j])!r} N"
            )
    if np.any(out["sensor_limit"] <= 0):
        raise field_error("sensor_limit", out["sensor_limit"], "must be > 0 [m or m/s]")
    for field in ("amplifier_current_limit", "tracking_tolerance"):
        if out[field] <= 0:
            raise field_error(field, out[field], f"must be > 0 [{FIELDS[field].unit}]")
    for field, low, high in (("timeout_cycles", 2, 7), ("recovery_cycles", 1, 255)):
        if not low <= out[field] <= high:
            raise field_error(field, out[field], f"a whole number {low} … {high}")


# What an older artefact lacks, for its one-line refusal.
_OLDER = {
    1: "without the safe state and the plausibility ranges",
    2: "without the joints' friction",
    3: "flat, without the sections of version 4",
    4: "with three sections under laws, not one per law of the registry",
}


def check_version(value) -> int:
    """``value`` if it is the schema version this package reads, else an error (with a hint for 1).

    Parameters
    ----------
    value : object
        The ``schema_version`` found.

    Returns
    -------
    int
        ``SCHEMA_VERSION``.
    """
    if isinstance(value, bool) or not isinstance(value, int) or value != SCHEMA_VERSION:
        hint = (
            f" — schema_version {value} is "
            + _OLDER[value]
            + f": re-run `smartjoint design` to write version {SCHEMA_VERSION}"
            if value in _OLDER and not isinstance(value, bool)
            else ""
        )
        raise field_error("schema_version", value, f"unknown; this version reads schema_version {SCHEMA_VERSION}{hint}")
    return value


def _number(field: str, value) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise field_error(field, value, "expected a number")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        raise field_error(field, value, "expected a finite number")
    return number


def _names(field: str, value) -> tuple[str, ...]:
    if not isinstance(value, (list, tuple)) or not value:
        raise field_error(field, value, "expected a non-empty list of names")
    for i, name in enumerate(value):
        if not isinstance(name, str) or not name:
            raise field_error(f"{field}[{i}]", name, "expected a non-empty string")
        if value.index(name) != i:
            raise field_error(f"{field}[{i}]", name, f"duplicate name (also {field}[{value.index(name)}])")
    return tuple(value)


def _strings(field: str, value) -> tuple[str, ...]:
    if not isinstance(value, (list, tuple)):
        raise field_error(field, value, "expected a list of strings")
    for i, item in enumerate(value):
        if not isinstance(item, str):
            raise field_error(f"{field}[{i}]", item, "expected a string")
    return tuple(value)


def _array(field: str, value) -> np.ndarray:
    """A finite float64 array from an ndarray or nested lists of numbers; read-only."""
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "fiu":
            raise field_error(field, value, "expected numbers")
    else:

        def check(item):
            if isinstance(item, list):
                for element in item:
                    check(element)
            elif isinstance(item, bool) or not isinstance(item, (int, float)):
                raise field_error(field, item, "expected a (nested) list of numbers")

        if isinstance(value, tuple):
            value = list(value)
        check(value)
    try:
        array = np.array(value, dtype=np.float64, order="C")
    except OverflowError:
        raise field_error(field, value, "every entry must be a finite number") from None
    except ValueError:
        raise field_error(field, value, "expected a rectangular (nested) list of numbers") from None
    if not np.all(np.isfinite(array)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(array))[0])
        raise ModelError(f"{field}: {float(array[bad])!r} at index {bad} — every entry must be a finite number")
    array.setflags(write=False)
    return array


__all__ = [
    "FIELDS",
    "FieldSpec",
    "NORMAL_FORCE_LIMIT",
    "SCHEMA",
    "SCHEMA_VERSION",
    "SENSOR_QUANTITIES",
    "check_version",
    "field_error",
    "validated",
]
