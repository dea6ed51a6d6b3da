"""Reading the tables of a design file with precise errors: every value is checked where it is
read, and a failure names the key path (``joints[2].type``), the value found and what is
allowed (:class:`~smartjoint.common.errors.DesignError`)."""

from __future__ import annotations

import math
from typing import Any

from smartjoint.common.errors import MISSING, DesignError
from smartjoint.design.structure.description import DOF_NAMES


class DesignTable:
    """A TOML table with its key path, for reading values with precise error messages.

    Every reader marks its key as used; `finish` then refuses any key no reader asked for.

    Parameters
    ----------
    data : dict
        The table's content.
    path : str
        Its key path (``joints[2]``), empty for the root.
    source : str
        The file it came from, for the messages.

    Raises
    ------
    DesignError
        When ``data`` is not a table.
    """

    def __init__(self, data: Any, path: str, source: str):
        if not isinstance(data, dict):
            raise DesignError(path or "<root>", data, "expected a table", source)
        self.data = data
        self.path = path
        self.source = source
        self.used: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.path}.{name}" if self.path else name

    def error(self, name: str, value: object, allowed: str) -> DesignError:
        return DesignError(self.key(name), value, allowed, self.source)

    def get(self, name: str, default: object = MISSING) -> Any:
        self.used.add(name)
        if name not in self.data:
            if default is MISSING:
                raise self.error(name, MISSING, "required key")
            return default
        return self.data[name]

    def string(self, name: str, default: object = MISSING, choices: tuple[str, ...] | None = None) -> str:
        value = self.get(name, default)
        if value is None and default is None:
            return None  # type: ignore[return-value]
        if not isinstance(value, str) or not value:
            raise self.error(name, value, "expected a non-empty string")
        if choices is not None and value not in choices:
            raise self.error(name, value, "allowed: " + ", ".join(repr(c) for c in choices))
        return value

    def number(
        self,
        name: str,
        default: object = MISSING,
        *,
        positive: bool = False,
        non_negative: bool = False,
        maximum: float | None = None,
    ) -> float:
        value = self.get(name, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(name, value, "expected a number")
        value = float(value)
        if not math.isfinite(value):
            raise self.error(name, value, "expected a finite number")
        if positive and value <= 0.0:
            raise self.error(name, value, "must be > 0")
        if non_negative and value < 0.0:
            raise self.error(name, value, "must be >= 0")
        if maximum is not None and value > maximum:
            raise self.error(name, value, f"must be <= {maximum}")
        return value

    def integer(self, name: str, default: object = MISSING, *, minimum: int = 1, maximum: int | None = None) -> int:
        value = self.get(name, default)
        allowed = f"an integer {minimum} … {maximum}" if maximum is not None else f"an integer >= {minimum}"
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(name, value, "expected " + allowed)
        if value < minimum or (maximum is not None and value > maximum):
            raise self.error(name, value, "must be " + allowed)
        return value

    def boolean(self, name: str, default: object = MISSING) -> bool:
        value = self.get(name, default)
        if not isinstance(value, bool):
            raise self.error(name, value, "expected true or false")
        return value

    def vector(self, name: str, size: int, default: object = MISSING) -> tuple[float, ...]:
        value = self.get(name, default)
        if value is None:
            return None  # type: ignore[return-value]
        if (
            not isinstance(value, list)
            or len(value) != size
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            or not all(math.isfinite(float(v)) for v in value)
        ):
            raise self.error(name, value, f"expected a list of {size} finite numbers")
        return tuple(float(v) for v in value)

    def vector3(self, name: str) -> tuple[float, float, float]:
        """A required list of three finite numbers, such as a position (see :meth:`vector`)."""
        x, y, z = self.vector(name, 3)
        return x, y, z

    def table(self, name: str, default: object = MISSING) -> DesignTable:
        value = self.get(name, default)
        return DesignTable(value, self.key(name), self.source)

    def tables(self, name: str) -> list[DesignTable]:
        value = self.get(name, [])
        if not isinstance(value, list):
            raise self.error(name, value, "expected an array of tables ([[" + name + "]])")
        return [DesignTable(item, f"{self.key(name)}[{i}]", self.source) for i, item in enumerate(value)]

    def named_tables(self, name: str) -> list[tuple[str, DesignTable]]:
        value = self.get(name, {})
        if not isinstance(value, dict):
            raise self.error(name, value, f"expected a table of named entries ([{name}.<name>])")
        return [(key, DesignTable(item, f"{self.key(name)}.{key}", self.source)) for key, item in value.items()]

    def finish(self) -> None:
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            raise self.error(unknown[0], self.data[unknown[0]], "unknown key; allowed: " + ", ".join(sorted(self.used)))


def reference(table: DesignTable, key: str, name: str, known: dict[str, Any], what: str) -> str:
    """``name`` if it is a key of ``known``, else an error listing (some of) the known names.

    Parameters
    ----------
    table : DesignTable
        The table holding the reference.
    key : str
        Its key, for the message.
    name : str
        The name referred to.
    known : dict
        The names that exist.
    what : str
        What they name (``"material"``), for the message.

    Returns
    -------
    str
        ``name``.
    """
    if name not in known:
        shown = ", ".join(sorted(known)[:8]) + (" …" if len(known) > 8 else "")
        raise table.error(key, name, f"no {what} of that name; known: {shown or 'none'}")
    return name


def direction(table: DesignTable, key: str) -> tuple[float, ...]:
    """A direction: a DOF name (``"uy"``) or a 3-vector of a translation (normalised).

    Parameters
    ----------
    table : DesignTable
        The table holding it.
    key : str
        Its key.

    Returns
    -------
    tuple of float
        Six components over DOF_NAMES (rotations zero for a vector).
    """
    value = table.get(key)
    if isinstance(value, str):
        if value not in DOF_NAMES:
            raise table.error(key, value, "allowed: " + ", ".join(DOF_NAMES) + " or [x, y, z]")
        vector = [0.0] * 6
        vector[DOF_NAMES.index(value)] = 1.0
        return tuple(vector)
    vector3 = table.vector(key, 3)
    norm = math.sqrt(sum(v * v for v in vector3))
    if norm == 0.0:
        raise table.error(key, value, "direction must not be the zero vector")
    return tuple(v / norm for v in vector3) + (0.0, 0.0, 0.0)


def dof_list(t: DesignTable, key: str) -> tuple[str, ...]:
    """``"all"`` or a list of DOF names, each once in the order given.

    Parameters
    ----------
    t : DesignTable
        The table holding the key.
    key : str
        The key.

    Returns
    -------
    tuple of str
        Names of DOF_NAMES.
    """
    value = t.get(key)
    if value == "all":
        return DOF_NAMES
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise t.error(key, value, 'expected "all" or a list of ' + ", ".join(DOF_NAMES))
    for v in value:
        if v not in DOF_NAMES:
            raise t.error(key, v, "allowed: " + ", ".join(DOF_NAMES))
    return tuple(dict.fromkeys(value))


def unique(names: list[str], table: str, source: str) -> None:
    """Refuse the first name of an array of tables ([[table]]) that repeats an earlier one.

    Parameters
    ----------
    names : list of str
        The names in file order.
    table : str
        The array's key, for the message.
    source : str
        The file, for the message.
    """
    for i, name in enumerate(names):
        if names.index(name) != i:
            raise DesignError(f"{table}[{i}].name", name, "duplicate name", source)


def per_joint(t: DesignTable, name: str, default, count: int, **checks):
    """A number for every joint, or a list with one number per controlled joint.

    Parameters
    ----------
    t : DesignTable
        The table holding the key.
    name : str
        The key.
    default : float or None
        Its default.
    count : int
        The controlled joints (the length a list must have).
    **checks
        ``positive`` / ``non_negative`` as for `DesignTable.number`.

    Returns
    -------
    float, tuple of float or None
        The number, one per joint, or None where the default is None and the key absent.
    """
    value = t.data.get(name, default)
    if isinstance(value, list):
        values = t.vector(name, count)
        for i, v in enumerate(values):
            if checks.get("positive") and v <= 0:
                raise t.error(name, value, f"entry {i} must be > 0")
            if v < 0:
                raise t.error(name, value, f"entry {i} must be >= 0")
        return values
    if value is None:
        t.get(name, None)
        return None
    return t.number(name, default, **checks)


__all__ = ["DesignTable", "direction", "dof_list", "per_joint", "reference", "unique"]
