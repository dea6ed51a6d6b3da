"""Errors that reach the user: one line naming the place, the value and what is allowed."""

from __future__ import annotations


class SmartjointError(Exception):
    """Base class for every error the command line reports as a one-line message."""


class DesignError(SmartjointError, ValueError):
    """A design file (or a design object) is malformed.

    ``path`` is the key path inside the file (``joints[2].type``), ``value`` the offending
    value and ``allowed`` says what would be accepted.
    """

    def __init__(self, path: str, value: object, allowed: str, source: str | None = None):
        self.path = path
        self.value = value
        self.allowed = allowed
        self.source = source
        where = f"{source}: " if source else ""
        shown = _show(value)
        super().__init__(f"{where}{path}: {shown} — {allowed}")


class ModelError(SmartjointError, ValueError):
    """The structure described is valid text but not a valid mechanical model."""


class OutputError(SmartjointError, ValueError):
    """An output path a command must not write: a link, a FIFO, a device, a path below a file, a
    folder holding a user's files (``common.output_path``)."""


def _show(value: object) -> str:
    if value is _MISSING:
        return "missing"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class _Missing:
    def __repr__(self) -> str:  # pragma: no cover - only used in messages
        return "missing"


_MISSING = _Missing()
MISSING = _MISSING
