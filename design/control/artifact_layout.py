"""The nested layout of the controller design artefact (``schema_version`` 5): one section per
component, as acados and other generators nest one block per solver part.

```
{"schema_version": 4,
 "common":   names, sample time, sensors, joints, force limits, provenance,
 "safety":   the safe state and the plausibility ranges (docs/safety.md),
 "friction": the joints' LuGre parameters the design was made with,
 "network":  the piezo amplifiers' calibration (volts on the bus),
 "laws":     {"<law>": its own fields, for every law of ``common.law_registry``}}
```

A field keeps one name in Python (``ControllerArtifact.siso_boundary_layer``) and is found in
the file under its section and key (``laws.siso.boundary_layer``). :func:`nest` lays the flat
fields out, :func:`flatten` reads a nested object back with one-line errors naming the key
path; :func:`json_schema` writes the JSON Schema of the layout (shipped as
``controller-artifact.schema.json``, checked in the tests).
"""

from __future__ import annotations

from typing import Any

from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control.artifact_schema import FIELDS, SCHEMA_VERSION, field_error

# Section → (key in the file, field in Python). "laws.<name>" sections are the laws' own.
LAYOUT: dict[str, tuple[tuple[str, str], ...]] = {
    "common": tuple(
        (name, name)
        for name in (
            "name",
            "sample_time",
            "joint_names",
            "sensor_names",
            "sensor_quantities",
            "joint_types",
            "normal_force_min",
            "normal_force_max",
            "design_source",
            "design_sha256",
            "package_version",
        )
    ),  # fmt: skip
    "safety": tuple(
        (name, name)
        for name in (
            "safe_normal_force",
            "sliding_velocity_limit",
            "friction_force_limit",
            "measured_normal_force_min",
            "measured_normal_force_max",
            "sensor_limit",
            "amplifier_temperature_limit",
            "amplifier_current_limit",
            "tracking_tolerance",
            "actuation_tolerance",
            "timeout_cycles",
            "recovery_cycles",
        )
    ),  # fmt: skip
    "friction": (("parameters", "friction_parameters"), ("radius", "friction_radius"), ("sources", "friction_sources")),
    "network": tuple((name, name) for name in ("piezo_capacitance", "piezo_force_per_volt", "piezo_preload")),
    # Each law's own section, as its registry entry lays it out.
    **{f"laws.{law.name}": law.artifact for law in law_registry.LAWS.values()},
}
LAWS_SECTION = "laws"


def _check_layout() -> None:
    """Every field of the schema in exactly one section; a section for every registered law."""
    placed = [field for keys in LAYOUT.values() for _, field in keys]
    expected = [name for name in FIELDS if name != "schema_version"]
    if sorted(placed) != sorted(expected):
        raise RuntimeError(f"artefact layout: fields {sorted(set(expected) ^ set(placed))} placed wrongly")
    laws = {section.split(".", 1)[1] for section in LAYOUT if section.startswith(LAWS_SECTION + ".")}
    if laws != set(law_registry.NAMES):
        raise RuntimeError(f"artefact layout: law sections {sorted(laws)}, registry {sorted(law_registry.NAMES)}")


_check_layout()


def path_of(field: str) -> str:
    """The key path of a Python field in the file (``siso_boundary_layer`` → ``laws.siso.boundary_layer``)."""
    for section, keys in LAYOUT.items():
        for key, name in keys:
            if name == field:
                return f"{section}.{key}"
    raise KeyError(field)


def nest(flat: dict[str, Any]) -> dict[str, Any]:
    """The nested object of flat fields (values as given).

    Parameters
    ----------
    flat : dict
        ``schema_version`` and every field of ``artifact_schema.SCHEMA``.

    Returns
    -------
    dict
        ``{"schema_version": …, "common": {…}, …, "laws": {"siso": {…}, …}}``.
    """
    out: dict[str, Any] = {"schema_version": flat["schema_version"]}
    for section, keys in LAYOUT.items():
        target = out
        for part in section.split("."):
            target = target.setdefault(part, {})
        for key, field in keys:
            target[key] = flat[field]
    return out


def _section(data: dict, path: str) -> dict:
    """The object at ``path`` (``laws.siso``) of the file, or a one-line error naming the path."""
    value: Any = data
    walked: list[str] = []
    for part in path.split("."):
        if not isinstance(value, dict):
            raise field_error(".".join(walked), value, "expected a JSON object (a section)")
        walked.append(part)
        if part not in value:
            raise ModelError(f"{'.'.join(walked)}: missing — required section (docs/controller-artifact.md)")
        value = value[part]
    if not isinstance(value, dict):
        raise field_error(path, value, "expected a JSON object (a section)")
    return value


def flatten(data: dict[str, Any]) -> dict[str, Any]:
    """The flat fields of a nested artefact object; every key checked, none left over.

    Parameters
    ----------
    data : dict
        The parsed JSON object (``schema_version`` already checked).

    Returns
    -------
    dict
        ``schema_version`` and every field, by its Python name.

    Raises
    ------
    ModelError
        A missing or unknown section or key, named by its path.
    """
    flat: dict[str, Any] = {"schema_version": data["schema_version"]}
    for section, keys in LAYOUT.items():
        values = _section(data, section)
        missing = [f"{section}.{key}" for key, _ in keys if key not in values]
        if missing:
            also = f" (also missing: {', '.join(missing[1:])})" if len(missing) > 1 else ""
            raise ModelError(f"{missing[0]}: missing — required field{also}")
        unknown = sorted(set(values) - {key for key, _ in keys})
        if unknown:
            raise field_error(f"{section}.{unknown[0]}", values[unknown[0]], _unknown(section))
        flat.update({field: values[key] for key, field in keys})
    tops = {section.split(".")[0] for section in LAYOUT} | {"schema_version"}
    for extra in sorted(set(data) - tops):
        raise field_error(extra, data[extra], f"unknown section in schema_version {SCHEMA_VERSION}")
    allowed = ", ".join(law_registry.NAMES)
    for extra in sorted(set(data[LAWS_SECTION]) - set(law_registry.NAMES)):
        raise field_error(f"{LAWS_SECTION}.{extra}", data[LAWS_SECTION][extra], f"unknown law; allowed: {allowed}")
    return flat


def _unknown(section: str) -> str:
    return f"unknown key in section {section} of schema_version {SCHEMA_VERSION}"


_JSON_TYPES: dict[str, dict[str, Any]] = {
    "integer": {"type": "integer"},
    "string": {"type": "string"},
    "names": {"type": "array", "items": {"type": "string", "minLength": 1}, "minItems": 1, "uniqueItems": True},
    "strings": {"type": "array", "items": {"type": "string"}},
    "number": {"type": "number"},
}


def _array_schema(depth: int) -> dict:
    schema: dict = {"type": "number"}
    for _ in range(depth):
        schema = {"type": "array", "items": schema}
    return schema


def json_schema() -> dict:
    """The JSON Schema (draft 2020-12) of the layout: sections, keys, kinds and array depths;
    the checks across fields (shapes, limits) are ``artifact_schema.validated``'s.

    Returns
    -------
    dict
    """

    def field_schema(field: str) -> dict:
        spec = FIELDS[field]
        schema = dict(_array_schema(len(spec.shape)) if spec.kind == "array" else _JSON_TYPES[spec.kind])
        described = spec.meaning + (f" [{spec.unit}]" if spec.unit else "")
        return {**schema, "description": described} if described else schema

    def section_schema(keys) -> dict:
        return {
            "type": "object",
            "properties": {key: field_schema(field) for key, field in keys},
            "required": [key for key, _ in keys],
            "additionalProperties": False,
        }

    laws = {s.split(".", 1)[1]: section_schema(keys) for s, keys in LAYOUT.items() if s.startswith(LAWS_SECTION + ".")}
    properties: dict[str, Any] = {"schema_version": {"const": SCHEMA_VERSION}}
    properties.update({s: section_schema(keys) for s, keys in LAYOUT.items() if "." not in s})
    properties[LAWS_SECTION] = {
        "type": "object",
        "properties": laws,
        "required": list(laws),
        "additionalProperties": False,
    }
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": "smartjoint-controller-artifact-4",
        "title": "smartjoint controller design artefact",
        "type": "object",
        "properties": properties,
        "required": list(properties),
        "additionalProperties": False,
    }


__all__ = ["LAYOUT", "LAWS_SECTION", "flatten", "json_schema", "nest", "path_of"]
