"""The friction of a design's joints (docs/design-file.md): the friction parameters of each
joint — of the model its table names (``model``, default ``lugre``: paper Eq. 1–2, the columns of
Table 1; the models and their parameters are ``common/friction_registry.py``'s) — and the rig
records that ``smartjoint run`` identifies.

::

    [friction]
    records = ["rig/*.csv"]        # optional: rig records (Section 3.2) identified by `run`

    [friction.A]                   # every type A joint, inline …
    sigma0 = 1.42e5
    sigma1 = 0.02
    sigma2 = 0.01
    coulomb = 0.61
    stribeck = 0.14
    stribeck_velocity = 0.01

    [friction.B]                   # … or a parameter file: `smartjoint identify -o` writes one
    file = "joint_b.toml"

A joint may carry its own (``friction = "file.toml"`` or an inline table in its ``[[joints]]``
entry). Nothing falls back to the paper's Table 1: a joint without parameters is reported by the
first stage that needs them (``friction.model.joint_parameters``). Only sign and finiteness are
checked here; the rig's plausible ranges are the friction stage's.
"""

from __future__ import annotations

import glob
import hashlib
import tomllib
from pathlib import Path

from smartjoint.common import friction_registry
from smartjoint.common.errors import DesignError
from smartjoint.design.structure.description import JOINT_TYPES, JointFriction
from smartjoint.design.structure.files import read_file
from smartjoint.design.structure.table import DesignTable

MAX_PARAMETER_FILE_BYTES = 1 << 20  # a parameter or identification file: a few dozen lines
MAX_RECORDS = 200  # rig records named by one design
# Identification metadata a parameter file may carry beside the values (`smartjoint identify -o`).
METADATA_TABLES = ("identification",)


def parse_friction(root: DesignTable, written_in: str) -> tuple[dict[str, JointFriction], tuple[str, ...]]:
    """The ``[friction]`` table: LuGre parameters by joint type and the rig records.

    Parameters
    ----------
    root : DesignTable
        The design's root table.
    written_in : str
        The file the table was written in (a base of the design, maybe), named as the source of
        inline parameters.

    Returns
    -------
    tuple
        (parameters by joint type, the record files in sorted order per pattern).
    """
    if "friction" not in root.data:
        return {}, ()
    t = root.table("friction")
    by_type = {}
    for joint_type in JOINT_TYPES:
        if joint_type in t.data:
            by_type[joint_type] = joint_friction(t.table(joint_type), joint_type, written_in)
    records = _records(t) if "records" in t.data else ()
    t.finish()
    return by_type, records


def joint_friction(t: DesignTable, joint_type: str, written_in: str) -> JointFriction:
    """One set of LuGre parameters: inline in ``t`` or in the file ``t.file``.

    Parameters
    ----------
    t : DesignTable
        ``[friction.A]``, ``[friction.B]`` or a joint's ``friction`` table.
    joint_type : str
        The type the parameters are for.
    written_in : str
        The design file ``t`` was written in.

    Returns
    -------
    JointFriction
    """
    if "file" in t.data:
        name = t.string("file")
        # Beside a file, the table may state what the file's records did not identify.
        keys = friction_registry.MODELS[friction_registry.DEFAULT].keys
        stated = {key: t.number(key, non_negative=True) for key in keys if key in t.data}
        t.finish()
        return _parameter_file(Path(name), joint_type, t.key("file"), t.source, stated, t.path)
    friction = _values(t, joint_type, f"{Path(written_in).name} [{t.path}]", "")
    t.finish()
    return friction


def joint_own_friction(t: DesignTable, joint_type: str, written_in: str) -> JointFriction | None:
    """A joint's own LuGre parameters: ``friction = "file.toml"`` or an inline table.

    Parameters
    ----------
    t : DesignTable
        The joint's ``[[joints]]`` entry.
    joint_type : str
        Its type.
    written_in : str
        The design file the entry was written in.

    Returns
    -------
    JointFriction or None
        None when the joint takes its type's parameters.
    """
    if "friction" not in t.data:
        return None
    value = t.get("friction")
    if isinstance(value, str):
        value = {"file": value}
    return joint_friction(DesignTable(value, t.key("friction"), t.source), joint_type, written_in)


def _values(t: DesignTable, joint_type: str, source: str, sha256: str) -> JointFriction:
    """The model's parameters (and the radius of type B) from ``t``, each finite and of its sign."""
    name = t.string("model", friction_registry.DEFAULT, tuple(friction_registry.MODELS))
    model = friction_registry.MODELS[name]
    values = []
    for parameter in model.parameters:
        zero = parameter.may_be_zero
        values.append((parameter.key, t.number(parameter.key, non_negative=zero, positive=not zero)))
    radius = None
    if joint_type == "B":
        radius = t.number("radius", positive=True)
    elif "radius" in t.data:
        raise t.error("radius", t.data["radius"], "a type A joint has no radius — allowed only for type B")
    return JointFriction(joint_type, tuple(values), radius=radius, source=source, sha256=sha256, model=name)


def _parameter_file(
    path: Path, joint_type: str, key: str, source: str, stated: dict | None = None, table_path: str = ""
) -> JointFriction:
    """A parameter file (``smartjoint rig --parameters`` or ``identify -o``) for ``joint_type``;
    ``stated`` (the design table's own values) fills in the parameters the file lists as not
    identified, and only those."""
    raw = read_file(path, key, str(path), source, MAX_PARAMETER_FILE_BYTES)
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise DesignError(key, str(path), f"not a valid TOML parameter file: {error}", source) from None
    declared = data.pop("joint_type", joint_type)
    if declared != joint_type:
        raise DesignError(key, str(path), f"holds type {declared!r} parameters, for type {joint_type} joints", source)
    missing = data.get("identification", {}).get("not_identified", {})
    for name in METADATA_TABLES:
        data.pop(name, None)
    for parameter, value in (stated or {}).items():
        if parameter not in missing:
            allowed = f"{path} identified it — beside file = … state only what the file lists as not identified"
            raise DesignError(f"{table_path}.{parameter}", value, allowed, source)
        data[parameter] = value
    for parameter, reason in missing.items():
        if parameter not in data:
            fix = f"state {parameter} = … in [{table_path}] beside file = …, or measure that record"
            raise DesignError(key, str(path), f"{parameter} not identified by its records ({reason}); {fix}", source)
    table = DesignTable(data, "", str(path))
    friction = _values(table, joint_type, str(path), hashlib.sha256(raw).hexdigest())
    table.finish()
    return friction


def _records(t: DesignTable) -> tuple[str, ...]:
    """``records``: file names or glob patterns, each matching at least one file."""
    patterns = t.get("records")
    if not (isinstance(patterns, list) and patterns and all(isinstance(p, str) and p for p in patterns)):
        raise t.error("records", patterns, "expected a non-empty list of record files or patterns (rig/*.csv)")
    found: list[str] = []
    for pattern in patterns:
        matches = sorted(glob.glob(pattern)) if glob.has_magic(pattern) else [pattern]
        matches = [m for m in matches if Path(m).is_file()]
        if not matches:
            raise t.error("records", pattern, "matches no record file")
        found.extend(m for m in matches if m not in found)
    if len(found) > MAX_RECORDS:
        raise t.error("records", f"{len(found)} files", f"at most {MAX_RECORDS} records")
    return tuple(found)


__all__ = ["MAX_PARAMETER_FILE_BYTES", "MAX_RECORDS", "joint_friction", "joint_own_friction", "parse_friction"]
