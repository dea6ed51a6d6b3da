"""The controller design artefact: one JSON file with everything the firmware generator needs.

The artefact freezes a controller design — limits, boundary layers, the discrete LQG of
``control.design_lqg`` and the piezo calibration — together with where it came from (design
file, its SHA-256, package version); ``artifact_building.from_design`` builds it from a design.
The C generator reads only this file, and each law's Python reference is rebuilt from it alone
(``Law.python_reference``), so firmware and reference are checked against the same numbers.

Schema (``schema_version`` 6, documented in ``docs/controller-artifact.md``): a JSON object of
sections — ``common``, ``safety``, ``friction``, ``network`` and ``laws.<law>`` per law of the
registry (``artifact_layout``) — whose keys are the fields of :data:`SCHEMA` (``artifact_schema``),
SI units; in Python every field is one attribute of :class:`ControllerArtifact`. Sizes: l controlled joints
(``joint_names``: the column order of E and K and the order of every per-joint vector),
n_y sensors (``sensor_names``: the rows of C), n retained coordinates, state
x = [η̇_1, ω_1η_1, η̇_2, ω_2η_2, …] (2n, mode-interleaved). Arrays are nested lists, row-major.

The text is canonical (``dumps``): sorted keys, two-space indent, innermost arrays on one
line, floats written with ``repr`` (float64 round-trips exactly), ASCII, newline at the end,
and nothing that depends on the time of writing — the same inputs give the same bytes and
``artifact_sha256`` is the SHA-256 of those bytes (= ``sha256sum`` of a saved file).
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from smartjoint.common import output_path
from smartjoint.common.errors import ModelError
from smartjoint.design.control import artifact_layout
from smartjoint.design.control.artifact_migration import migrated
from smartjoint.design.control.artifact_schema import (
    LAW_SETTINGS,
    SCHEMA,
    SCHEMA_VERSION,
    check_version,
    field_error,
    validated,
)
from smartjoint.design.control.lqg import LqgDesign


def installed_version() -> str:
    """The installed smartjoint version, "unknown" when running from an uninstalled tree.

    Returns
    -------
    str
    """
    try:
        return importlib.metadata.version("smartjoint")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


@dataclass(frozen=True, eq=False)
class ControllerArtifact:
    """A validated controller design (fields: see :data:`SCHEMA`). Arrays are read-only float64;
    ``==`` compares them exactly. Built by ``artifact_building.from_design`` or :func:`loads`."""

    schema_version: int
    name: str
    sample_time: float
    joint_names: tuple[str, ...]
    sensor_names: tuple[str, ...]
    normal_force_min: np.ndarray
    normal_force_max: np.ndarray
    blocks: np.ndarray
    gamma0: np.ndarray
    gamma1: np.ndarray
    joint_input: np.ndarray
    output: np.ndarray
    feedback_gain: np.ndarray
    estimator_gain: np.ndarray
    modal_frequencies: np.ndarray
    piezo_capacitance: float
    piezo_force_per_volt: float
    piezo_preload: float
    sensor_quantities: tuple[str, ...]
    joint_types: tuple[str, ...]  # "A" | "B", per joint
    friction_parameters: np.ndarray  # (l, 6): σ0, σ1, σ2, F_c, F_d, v_s per unit F_N
    friction_radius: np.ndarray  # (l,) [m], 0 for type A
    friction_sources: tuple[str, ...]  # where each joint's parameters came from
    safe_normal_force: np.ndarray
    sliding_velocity_limit: np.ndarray
    friction_force_limit: np.ndarray
    measured_normal_force_min: np.ndarray
    measured_normal_force_max: np.ndarray
    sensor_limit: np.ndarray
    amplifier_temperature_limit: float
    amplifier_current_limit: float
    tracking_tolerance: float
    actuation_tolerance: np.ndarray
    timeout_cycles: int
    recovery_cycles: int
    design_source: str
    design_sha256: str
    package_version: str
    # Each law's settings (common.law_registry: ``Law.settings``, field by ``Law.artifact``), last:
    # siso_boundary_layer (ε_j, m/s), clqg_boundary_layer (ε, N), … — a law's entry adds its own.
    __annotations__.update({field: np.ndarray if s.per_joint else float for field, s in LAW_SETTINGS.items()})
    if TYPE_CHECKING:  # the settings' fields are the registry's, unknown to a type checker

        def __getattr__(self, name: str) -> Any: ...

    def __post_init__(self):
        for field, value in validated(self.__dict__).items():
            object.__setattr__(self, field, value)

    def __eq__(self, other) -> bool:
        if not isinstance(other, ControllerArtifact):
            return NotImplemented
        for spec in SCHEMA:
            a, b = getattr(self, spec.name), getattr(other, spec.name)
            if not (np.array_equal(a, b) if spec.kind == "array" else a == b):
                return False
        return True

    # Unhashable, as a class defining __eq__ is (arrays: equal artefacts need not share a hash)

    @property
    def artifact_sha256(self) -> str:
        """SHA-256 of the canonical text ``dumps(self)``: the identity of this exact design."""
        return hashlib.sha256(dumps(self).encode("ascii")).hexdigest()


# --------------------------------------------------------------------------- text
def _encode(value, indent: str) -> str:
    if isinstance(value, dict):
        inner = indent + "  "
        items = [f"{inner}{json.dumps(key)}: {_encode(value[key], inner)}" for key in sorted(value)]
        return "{\n" + ",\n".join(items) + "\n" + indent + "}"
    if isinstance(value, list):
        if value and isinstance(value[0], list):  # rows on their own lines
            inner = indent + "  "
            return "[\n" + ",\n".join(inner + _encode(v, inner) for v in value) + "\n" + indent + "]"
        return "[" + ", ".join(_encode(v, indent) for v in value) + "]"
    if isinstance(value, float):
        return repr(value)  # shortest text that parses back to the same float64
    return json.dumps(value)  # int, str (ASCII, escaped)


def dumps(artifact: ControllerArtifact) -> str:
    """Canonical JSON text (see the module docstring): same artefact, same bytes.

    Parameters
    ----------
    artifact : ControllerArtifact
        The artefact to write, every field of `SCHEMA`.

    Returns
    -------
    str
        ASCII text ending in a newline.
    """
    data: dict = {}
    for spec in SCHEMA:
        value = getattr(artifact, spec.name)
        data[spec.name] = (
            value.tolist() if spec.kind == "array" else list(value) if spec.kind in ("names", "strings") else value
        )
    return _encode(artifact_layout.nest(data), "") + "\n"


def save(artifact: ControllerArtifact, path) -> Path:
    """Write ``dumps(artifact)`` atomically: a temporary file in the same folder, then
    ``os.replace`` — ``path`` holds either the old or the new complete text, never a part.

    Parameters
    ----------
    artifact : ControllerArtifact
        The artefact to write.
    path : str or Path
        The file.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    try:
        if not path.parent.is_dir():  # the library never makes folders; the command line does
            raise FileNotFoundError(2, f"no folder {path.parent}")
        return output_path.write_file(path, dumps(artifact))  # the output rule
    except OSError as error:
        raise ModelError(f"{path}: cannot write controller artefact ({error.strerror or error})") from None


def _object(pairs):
    keys = [key for key, _ in pairs]
    for i, key in enumerate(keys):
        if keys.index(key) != i:
            raise field_error(key, pairs[i][1], "duplicate key")
    return dict(pairs)


def loads(text: str) -> ControllerArtifact:
    """Parse and validate an artefact; every problem is a ModelError naming the field.

    Parameters
    ----------
    text : str
        The artefact's JSON text, as written by :func:`dumps`.

    Returns
    -------
    ControllerArtifact
        The artefact, every field checked against ``SCHEMA``.

    Raises
    ------
    ModelError
        Not JSON or not an object, a duplicate, missing or unknown field, another schema
        version, or a field value the schema refuses.
    """
    try:
        data = json.loads(text, object_pairs_hook=_object)
    except json.JSONDecodeError as error:
        raise ModelError(f"<artefact>: not valid JSON ({error})") from None
    except RecursionError:
        raise ModelError("<artefact>: not valid JSON (nested too deeply)") from None
    if not isinstance(data, dict):
        raise field_error("<artefact>", data, "expected a JSON object")
    if "schema_version" not in data:
        raise ModelError(f"schema_version: missing — required field; this version reads {SCHEMA_VERSION}")
    data = migrated(data)  # versions 5 and 6 read as 7 (artifact_migration)
    check_version(data["schema_version"])  # first: another version may have other fields
    return ControllerArtifact(**artifact_layout.flatten(data))


def load(path) -> ControllerArtifact:
    """Read and validate an artefact file; errors are prefixed with the path.

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    ControllerArtifact

    Examples
    --------
    >>> controller = load("controller.json")  # doctest: +SKIP
    >>> controller.sample_time  # doctest: +SKIP
    0.001
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise ModelError(
            f"{path}: cannot read controller artefact ({getattr(error, 'strerror', None) or error})"
        ) from None
    try:
        return loads(text)
    except ModelError as error:
        raise ModelError(f"{path}: {error}") from None


# --------------------------------------------------------------------------- reference controllers
def lqg_design(artifact: ControllerArtifact) -> LqgDesign:
    """The ``LqgDesign`` of the artefact. The Riccati solutions are not stored: they are NaN
    arrays of the right shape (the controllers and ``closed_loop_poles`` never read them).

    Parameters
    ----------
    artifact : ControllerArtifact
        Its blocks, FOH weights, E, C and the two gains.

    Returns
    -------
    LqgDesign
    """
    n2 = artifact.output.shape[1]
    unknown = np.full((n2, n2), np.nan)
    return LqgDesign(
        artifact.sample_time,
        artifact.blocks,
        artifact.gamma0,
        artifact.gamma1,
        artifact.joint_input,
        artifact.output,
        artifact.feedback_gain,
        artifact.estimator_gain,
        unknown,
        unknown.copy(),
    )


__all__ = [
    "ControllerArtifact",
    "dumps",
    "installed_version",
    "load",
    "loads",
    "lqg_design",
    "save",
]
