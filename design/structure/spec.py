"""The design file: a TOML description of a truss with friction joints, loaded into dataclasses.

The format is documented in ``docs/design-file.md``. Every check here fails with a
:class:`~smartjoint.common.errors.DesignError` that names the key path (``joints[2].type``),
the value found and what is allowed, so a user never meets a traceback from numpy.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import stat
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from smartjoint.common import package_data
from smartjoint.common.errors import MISSING, DesignError

SCHEMA = "smartjoint-design/1"
DOF_NAMES = ("ux", "uy", "uz", "rx", "ry", "rz")
JOINT_TYPES = ("A", "B")
SENSOR_QUANTITIES = ("displacement", "velocity")
DIAGONAL_PATTERNS = ("alternating", "parallel")
TIP_NODES = ("none", "cross", "diagonal")

REFERENCE_DESIGN = package_data.path("smartjoint.design", "data/meroform_10bay.toml")

# Limits on every size a design file controls, checked before anything of that size is
# allocated (docs/design-file.md). Each is generous for a real truss: a 1000-bay mast of the
# reference kind has 4 005 nodes, 12 004 members and 384 000 DOFs and solves in about a minute.
MAX_FILE_BYTES = 4 * 1024 * 1024  # one design file: some 50 000 explicit members, parsed in seconds
MAX_BASE_DEPTH = 4  # base files behind the file given
MAX_BAYS = 5000
MAX_ELEMENTS = 1000  # beam elements per tube (a cubic beam element needs a handful per wave)
MAX_NODES = 100_000
MAX_MEMBERS = 300_000
MAX_DOFS = 1_000_000  # about 5 GB for assembly plus 100 modes
MAX_MODES = 1000  # considered_modes, updating mode numbers
MAX_KRYLOV = 20  # Krylov correction vectors per joint
MAX_LANCZOS_BYTES = 4 * 1024**3  # the Lanczos basis of 2·considered_modes vectors of the DOF size
MIN_SAMPLE_TIME = 1e-6  # [s]: the firmware counts its cycle in whole microseconds
MAX_STUDY_DURATION = 3600.0  # [s] of simulated time in a closed-loop study (the paper: 4 s)
MAX_CONTROLLER_STEPS = 10_000_000  # study_duration / sample_time
# The largest normal force a piezo-actuated friction joint can plausibly set: the blocking
# force of the largest multilayer piezo stacks is some tens of kN, and the bolt of a truss joint
# (M12, property class 8.8: proof load 48 kN) holds no more. 1e5 N is above both.
MAX_NORMAL_FORCE = 1e5  # [N]


# --------------------------------------------------------------------------- dataclasses
@dataclass(frozen=True)
class Material:
    name: str
    youngs_modulus: float  # E [Pa]
    shear_modulus: float  # G [Pa]
    density: float  # ρ [kg/m³]


@dataclass(frozen=True)
class TubeSection:
    """Thin- or thick-walled circular tube."""

    name: str
    material: str
    outer_diameter: float  # [m]
    wall_thickness: float  # [m]

    @property
    def area(self) -> float:
        inner = self.outer_diameter - 2.0 * self.wall_thickness
        return math.pi / 4.0 * (self.outer_diameter**2 - inner**2)

    @property
    def second_moment(self) -> float:
        """I_y = I_z [m⁴]."""
        inner = self.outer_diameter - 2.0 * self.wall_thickness
        return math.pi / 64.0 * (self.outer_diameter**4 - inner**4)

    @property
    def polar_moment(self) -> float:
        """I_p = J = 2I for a circular tube [m⁴]."""
        return 2.0 * self.second_moment


@dataclass(frozen=True)
class Connector:
    """Screw end connector between a node and a tube: its own beam element.

    Its stiffnesses are given directly (they are what model updating identifies); its mass is
    spread along its length, with the rotary inertia of a solid cylinder of ``diameter``.
    """

    name: str
    length: float  # [m]
    mass: float  # [kg]
    diameter: float  # [m]
    axial_stiffness: float  # EA [N]
    bending_stiffness: float  # EI [N·m²]
    torsional_stiffness: float  # GJ [N·m²]


@dataclass(frozen=True)
class NodeType:
    """A perfectly rigid truss node (Meroform ball) with lumped mass and inertia."""

    name: str
    mass: float  # [kg]
    seat_radius: float  # centre to connector seat [m]
    inertia: float  # about any axis through the centre [kg·m²]


@dataclass(frozen=True)
class Node:
    name: str
    position: tuple[float, float, float]
    type: str | None  # None: a plain point without mass or offset


@dataclass(frozen=True)
class Member:
    name: str
    start: str
    end: str
    section: str
    connector: str | None
    elements: int  # tube elements


@dataclass(frozen=True)
class PointMass:
    node: str
    mass: float
    inertia: float


@dataclass(frozen=True)
class Support:
    node: str
    dofs: tuple[str, ...]


@dataclass(frozen=True)
class Joint:
    """A friction joint at one end of a member (paper Fig. 3).

    Type A releases the axial slip of the member end against the node; type B releases the
    rotation of the member end about ``axis`` (perpendicular to the member).
    """

    name: str
    member: str
    end: str  # "start" | "end"
    type: str  # "A" | "B"
    axis: tuple[float, float, float] | None


@dataclass(frozen=True)
class Sensor:
    """One measured output y (Eq. 10): a node's displacement or velocity along a direction."""

    name: str
    node: str
    direction: tuple[float, ...]  # 6-vector over DOF_NAMES
    quantity: str


@dataclass(frozen=True)
class Disturbance:
    """One disturbance input w (Eq. 5): a force/moment at a node along a direction."""

    name: str
    node: str
    direction: tuple[float, ...]  # 6-vector over DOF_NAMES


@dataclass(frozen=True)
class MeasuredMode:
    mode: int  # 1-based index in the ascending FE spectrum
    frequency_hz: float
    mac: float | None


@dataclass(frozen=True)
class Updating:
    parameters: tuple[str, ...]  # e.g. "connectors.m12.axial_stiffness"
    measured: tuple[MeasuredMode, ...]
    max_factors: tuple[float, ...]  # per parameter: bounds initial/max_factor .. initial·max_factor


@dataclass(frozen=True)
class Control:
    """Controller design inputs (paper Section 5; ``[control]``, all optional with defaults).

    Limits F_N^min..F_N^max per joint (a number applies to every joint), the controller sample
    time Δt, the reduced model the controllers are designed on (Section 4: ``modes`` of the
    first ``considered`` plus ``krylov`` correction vectors per joint), LQR weights
    (xᵀQx + uᵀRu with Q = state_weight·I — xᵀx is the energy of Eq. 32 — and R =
    control_weight·I), Kalman noise intensities (process: on the disturbance inputs w, N²;
    measurement: per sensor, m²), the boundary layers (SISO ε_j of Eq. 30 in m/s — optimised
    by ``smartjoint design`` when absent; cLQG in N), the piezo calibration used for the
    control power (F_N = force_per_volt·V + preload, capacitance per stack) and the study
    length t_e of Eq. 32."""

    joints: tuple[str, ...] | None = None  # controlled joints; None: all
    sample_time: float = 1e-3
    normal_force_min: tuple[float, ...] | float = 10.0
    normal_force_max: tuple[float, ...] | float = 400.0
    considered_modes: int = 100
    modes: int = 9
    krylov: int = 1
    state_weight: float = 1.0
    control_weight: float = 1e-6
    process_noise: float = 1e4
    measurement_noise: float = 1e-10
    siso_boundary_layer: tuple[float, ...] | float | None = None
    clqg_boundary_layer: float = 100.0
    piezo_capacitance: float = 1.8e-6
    piezo_force_per_volt: float = 8.0
    piezo_preload: float = 0.0
    study_duration: float = 4.0


@dataclass(frozen=True)
class Safety:
    """The safe state and the plausibility ranges of the firmware (``[safety]``, all optional;
    docs/safety.md says why each default is what it is).

    ``safe_normal_force``: the normal force every joint gets while the controller cannot act —
    "max" (F_N^max, the default: locked joints keep the truss as stiff and shape-accurate as
    its rigid design, and a constant F_N can never destabilise it), "min", or newtons (a number
    or one per controlled joint, within [F_N^min, F_N^max]). The same force holds in the
    controllers, the CAN layer, the amplifiers (power-up, silence, bus-off) and the reports.

    Plausibility: a measured value beyond its range is not physics but a broken sensor or
    frame. ``sliding_velocity_limit`` |v| [m/s]; ``friction_coefficient_limit`` |u_R| ≤ this ×
    the largest plausible F_N; ``normal_force_margin`` the measured F_N within [−m, 1 + m]·F_N^max;
    ``displacement_limit`` [m] / ``velocity_limit`` [m/s] for the sensors by quantity
    (displacement default: 5 % of the truss's largest extent); ``amplifier_temperature_limit``
    [°C], ``amplifier_current_limit`` [A]; ``tracking_tolerance`` [V] between the setpoint and
    the amplifier's monitor voltage.

    Timing, the same in the firmware and the amplifiers: an input whose newest frame is
    ``timeout_cycles`` controller cycles old is missing (2: a frame may come up to one cycle
    late), and the safe state ends after ``recovery_cycles`` fault-free cycles in a row."""

    safe_normal_force: tuple[float, ...] | float | str = "max"
    sliding_velocity_limit: float = 1.0
    friction_coefficient_limit: float = 1.5
    normal_force_margin: float = 0.1
    displacement_limit: float | None = None  # None: 5 % of the largest extent of the nodes
    velocity_limit: float = 2.0
    amplifier_temperature_limit: float = 85.0
    amplifier_current_limit: float = 2.5
    tracking_tolerance: float = 3.0
    timeout_cycles: int = 2
    recovery_cycles: int = 3


@dataclass(frozen=True)
class Design:
    name: str
    description: str
    materials: dict[str, Material]
    sections: dict[str, TubeSection]
    connectors: dict[str, Connector]
    node_types: dict[str, NodeType]
    nodes: dict[str, Node]
    members: dict[str, Member]
    point_masses: tuple[PointMass, ...]
    supports: tuple[Support, ...]
    joints: tuple[Joint, ...]
    sensors: tuple[Sensor, ...]
    disturbances: tuple[Disturbance, ...]
    modal_damping: float
    updating: Updating | None
    control: Control = field(default_factory=Control)
    safety: Safety = field(default_factory=Safety)
    source: str = "<memory>"
    sha256: str = ""
    truss: dict[str, Any] = field(default_factory=dict)

    def parameter(self, key: str) -> float:
        """Value of an updatable parameter ``table.name.field`` (see :data:`UPDATABLE`)."""
        table, name, attribute = _split_parameter(key)
        return float(getattr(getattr(self, table)[name], attribute))

    def with_parameters(self, values: dict[str, float]) -> "Design":
        """A copy with updatable parameters replaced (used by model updating)."""
        tables = {t: dict(getattr(self, t)) for t in ("materials", "connectors")}
        for key, value in values.items():
            table, name, attribute = _split_parameter(key)
            tables[table][name] = dataclasses.replace(tables[table][name], **{attribute: float(value)})
        return dataclasses.replace(self, **tables)


UPDATABLE = {
    "materials": ("youngs_modulus", "shear_modulus"),
    "connectors": ("axial_stiffness", "bending_stiffness", "torsional_stiffness"),
}


def _split_parameter(key: str) -> tuple[str, str, str]:
    parts = key.split(".")
    if len(parts) != 3 or parts[0] not in UPDATABLE or parts[2] not in UPDATABLE[parts[0]]:
        allowed = ", ".join(f"{t}.<name>.{a}" for t, attrs in UPDATABLE.items() for a in attrs)
        raise DesignError("updating.parameters", key, f"allowed: {allowed}")
    return parts[0], parts[1], parts[2]


# --------------------------------------------------------------------------- reading helpers
class _Table:
    """A TOML table with its key path, for reading values with precise error messages."""

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

    def number(self, name: str, default: object = MISSING, *, positive: bool = False,
               non_negative: bool = False, maximum: float | None = None) -> float:
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

    def integer(self, name: str, default: object = MISSING, *, minimum: int = 1,
                maximum: int | None = None) -> int:
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
        if (not isinstance(value, list) or len(value) != size
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
                or not all(math.isfinite(float(v)) for v in value)):
            raise self.error(name, value, f"expected a list of {size} finite numbers")
        return tuple(float(v) for v in value)

    def table(self, name: str, default: object = MISSING) -> "_Table":
        value = self.get(name, default)
        return _Table(value, self.key(name), self.source)

    def tables(self, name: str) -> list["_Table"]:
        value = self.get(name, [])
        if not isinstance(value, list):
            raise self.error(name, value, "expected an array of tables ([[" + name + "]])")
        return [_Table(item, f"{self.key(name)}[{i}]", self.source) for i, item in enumerate(value)]

    def named_tables(self, name: str) -> list[tuple[str, "_Table"]]:
        value = self.get(name, {})
        if not isinstance(value, dict):
            raise self.error(name, value, f"expected a table of named entries ([{name}.<name>])")
        return [(key, _Table(item, f"{self.key(name)}.{key}", self.source)) for key, item in value.items()]

    def finish(self) -> None:
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            raise self.error(unknown[0], self.data[unknown[0]], "unknown key; allowed: "
                             + ", ".join(sorted(self.used)))


def _reference(table: _Table, key: str, name: str, known: dict[str, Any], what: str) -> str:
    if name not in known:
        shown = ", ".join(sorted(known)[:8]) + (" …" if len(known) > 8 else "")
        raise table.error(key, name, f"no {what} of that name; known: {shown or 'none'}")
    return name


def _direction(table: _Table, key: str) -> tuple[float, ...]:
    """A direction: a DOF name (``"uy"``) or a 3-vector of a translation (normalised)."""
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


# --------------------------------------------------------------------------- loading
def load_design(path: str | Path | None = None) -> Design:
    """Load and validate a design file; ``None`` loads the bundled reference truss."""
    path = Path(path) if path is not None else REFERENCE_DESIGN
    source = str(path)
    raw = _read_file(path, "<file>", source, None)
    data, raw = _read_toml(path, source, raw, [path])
    design = parse_design(data, source=source)
    return dataclasses.replace(design, sha256=hashlib.sha256(raw).hexdigest())


def _read_file(path: Path, key: str, shown: str, source: str | None) -> bytes:
    """The bytes of a regular file of at most :data:`MAX_FILE_BYTES`.

    Opened without blocking and checked on the open descriptor: a FIFO would block the open
    and a device (``/dev/zero``) or a huge file would fill the memory before TOML sees it.
    """
    what = "base design file" if key == "base" else "design file"
    try:
        descriptor = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as error:
        raise DesignError(key, shown, f"cannot read {what} {path} ({error.strerror})", source) from None
    try:
        status = os.fstat(descriptor)
        if not stat.S_ISREG(status.st_mode):
            kind = ("a folder" if stat.S_ISDIR(status.st_mode) else "a FIFO" if stat.S_ISFIFO(status.st_mode)
                    else "a device" if stat.S_ISCHR(status.st_mode) or stat.S_ISBLK(status.st_mode)
                    else "a socket" if stat.S_ISSOCK(status.st_mode) else "not a regular file")
            raise DesignError(key, shown, f"{path} is {kind}; a {what} must be a regular file", source)
        limit = f"a {what} must be a regular file of at most {MAX_FILE_BYTES} bytes (4 MiB)"
        if status.st_size > MAX_FILE_BYTES:
            raise DesignError(key, shown, f"{path} has {status.st_size} bytes; {limit}", source)
        chunks, size = [], 0
        while size <= MAX_FILE_BYTES:
            chunk = os.read(descriptor, MAX_FILE_BYTES + 1 - size)
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        raw = b"".join(chunks)
    except OSError as error:
        raise DesignError(key, shown, f"cannot read {what} {path} ({error.strerror})", source) from None
    finally:
        os.close(descriptor)
    if len(raw) > MAX_FILE_BYTES:  # it grew after the size check
        raise DesignError(key, shown, f"{path} has more than {MAX_FILE_BYTES} bytes; {limit}", source)
    return raw


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _chain_names(chain: list[Path]) -> str:
    names = [p.name for p in chain]
    if len(set(names)) < len(set(map(str, chain))):  # file names alone are ambiguous
        names = [str(p) for p in chain]
    return " → ".join(names)


def _read_toml(path: Path, source: str, raw: bytes, chain: list[Path]) -> tuple[dict[str, Any], bytes]:
    """Parse a design file; ``base = "other.toml"`` (relative to the file) supplies every
    top-level key the file does not set itself. The hash covers the whole chain of bytes.
    ``chain`` lists the files read so far, this one last (for cycles and the depth limit)."""
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise DesignError("<file>", source, f"not valid TOML: {error}") from None
    if "base" not in data:
        return data, raw
    base = data.pop("base")
    if not isinstance(base, str) or not base:
        raise DesignError("base", base, "expected a path (string) to the design file this one extends", source)
    base_path = (path.parent / base) if not Path(base).is_absolute() else Path(base)
    for earlier in chain:
        if _same_file(earlier, base_path):
            cycle = chain[chain.index(earlier):] + [base_path]
            raise DesignError("base", base, f"{_chain_names(cycle)} is a cycle; a base chain must end in a "
                              "file without base", source)
    if len(chain) > MAX_BASE_DEPTH:
        raise DesignError("base", base, f"{_chain_names(chain + [base_path])}: at most {MAX_BASE_DEPTH} "
                          "levels of base files", source)
    base_raw = _read_file(base_path, "base", base, source)
    base_data, base_chain = _read_toml(base_path, str(base_path), base_raw, chain + [base_path])
    return {**base_data, **data}, base_chain + b"\0" + raw


def parse_design(data: dict[str, Any], source: str = "<memory>") -> Design:
    """Validate a design given as a (TOML-like) dictionary."""
    root = _Table(data, "", source)
    schema = root.string("schema", SCHEMA)
    if schema != SCHEMA:
        raise root.error("schema", schema, f"this version reads {SCHEMA!r}")
    name = root.string("name")
    description = root.get("description", "")
    if not isinstance(description, str):
        raise root.error("description", description, "expected a string")

    materials = {}
    for key, t in root.named_tables("materials"):
        youngs = t.number("youngs_modulus", positive=True)
        if "shear_modulus" in t.data and "poisson_ratio" in t.data:
            raise t.error("poisson_ratio", t.data["poisson_ratio"], "give shear_modulus or poisson_ratio, not both")
        if "poisson_ratio" in t.data:
            nu = t.number("poisson_ratio", non_negative=True, maximum=0.4999)
            shear = youngs / (2.0 * (1.0 + nu))
        else:
            shear = t.number("shear_modulus", positive=True)
        materials[key] = Material(key, youngs, shear, t.number("density", positive=True))
        t.finish()

    sections = {}
    for key, t in root.named_tables("sections"):
        material = _reference(t, "material", t.string("material"), materials, "material")
        outer = t.number("outer_diameter", positive=True)
        wall = t.number("wall_thickness", positive=True)
        if 2.0 * wall > outer:
            raise t.error("wall_thickness", wall, f"must be <= outer_diameter/2 = {outer / 2}")
        sections[key] = TubeSection(key, material, outer, wall)
        t.finish()

    connectors = {}
    for key, t in root.named_tables("connectors"):
        connectors[key] = Connector(
            key,
            length=t.number("length", positive=True),
            mass=t.number("mass", non_negative=True),
            diameter=t.number("diameter", positive=True),
            axial_stiffness=t.number("axial_stiffness", positive=True),
            bending_stiffness=t.number("bending_stiffness", positive=True),
            torsional_stiffness=t.number("torsional_stiffness", positive=True),
        )
        t.finish()

    node_types = {}
    for key, t in root.named_tables("node_types"):
        mass = t.number("mass", non_negative=True)
        radius = t.number("seat_radius", non_negative=True)
        inertia = t.number("inertia", 0.4 * mass * radius**2, non_negative=True)
        node_types[key] = NodeType(key, mass, radius, inertia)
        t.finish()

    mesh = root.table("mesh", {})
    default_elements = mesh.integer("tube_elements", 4, maximum=MAX_ELEMENTS)
    mesh.finish()

    nodes: dict[str, Node] = {}
    members: dict[str, Member] = {}
    truss_settings: dict[str, Any] = {}
    if "truss" in root.data:
        truss = root.table("truss")
        truss_settings = dict(truss.data)
        _generate_mast(truss, nodes, members, node_types, sections, connectors, default_elements)
        truss.finish()

    explicit_nodes = root.tables("nodes")
    if len(nodes) + len(explicit_nodes) > MAX_NODES:
        raise root.error("nodes", f"{len(nodes) + len(explicit_nodes)} nodes", f"at most {MAX_NODES} nodes")
    for t in explicit_nodes:
        node_name = t.string("name")
        if node_name in nodes:
            raise t.error("name", node_name, "duplicate node name")
        node_type = t.string("type", None)
        if node_type is not None:
            _reference(t, "type", node_type, node_types, "node type")
        nodes[node_name] = Node(node_name, t.vector("position", 3), node_type)
        t.finish()

    explicit_members = root.tables("members")
    if len(members) + len(explicit_members) > MAX_MEMBERS:
        raise root.error("members", f"{len(members) + len(explicit_members)} members", f"at most {MAX_MEMBERS} members")
    for t in explicit_members:
        member_name = t.string("name")
        if member_name in members:
            raise t.error("name", member_name, "duplicate member name")
        start = _reference(t, "start", t.string("start"), nodes, "node")
        end = _reference(t, "end", t.string("end"), nodes, "node")
        section = _reference(t, "section", t.string("section"), sections, "section")
        connector = t.string("connector", None)
        if connector is not None:
            _reference(t, "connector", connector, connectors, "connector")
        members[member_name] = Member(member_name, start, end, section, connector,
                                      t.integer("elements", default_elements, maximum=MAX_ELEMENTS))
        t.finish()
    if not members:
        raise root.error("members", [], "the design has no members (give [truss] or [[members]])")
    joint_entries = root.data.get("joints", [])
    dofs = estimated_dofs(nodes, members, len(joint_entries) if isinstance(joint_entries, list) else 0)
    if dofs > MAX_DOFS:
        raise DesignError("<model>", f"{dofs} DOFs", f"at most {MAX_DOFS} DOFs (6 per node and per inner beam node, "
                          "1 per joint); use fewer bays, members or [mesh] tube_elements", source)
    _check_member_lengths(members, nodes, node_types, connectors)

    point_masses = []
    for t in root.tables("point_masses"):
        node = _reference(t, "node", t.string("node"), nodes, "node")
        point_masses.append(PointMass(node, t.number("mass", non_negative=True),
                                      t.number("inertia", 0.0, non_negative=True)))
        t.finish()

    supports = []
    for t in root.tables("supports"):
        node = _reference(t, "node", t.string("node"), nodes, "node")
        supports.append(Support(node, _dof_list(t, "dofs")))
        t.finish()
    if "truss" in root.data and truss_settings.get("clamp_root", True):
        generated = {s.node for s in supports}
        supports.extend(Support(f"N0_{c}", DOF_NAMES) for c in range(4) if f"N0_{c}" not in generated)

    joints = []
    names: set[str] = set()
    for t in root.tables("joints"):
        joint_name = t.string("name")
        if joint_name in names:
            raise t.error("name", joint_name, "duplicate joint name")
        names.add(joint_name)
        member = _reference(t, "member", t.string("member"), members, "member")
        end = t.string("end", choices=("start", "end"))
        joint_type = t.string("type", choices=JOINT_TYPES)
        axis = None
        if joint_type == "B":
            axis = _joint_axis(t, members[member], nodes)
        elif "axis" in t.data:
            t.get("axis")
            raise t.error("axis", t.data["axis"], "type A slips along the member axis; axis is only for type B")
        joints.append(Joint(joint_name, member, end, joint_type, axis))
        t.finish()
    ends = [(j.member, j.end) for j in joints]
    for i, joint_end in enumerate(ends):
        if ends.index(joint_end) != i:
            raise DesignError(f"joints[{i}].end", joint_end[1], f"member {joint_end[0]!r} already has a joint at that end", source)

    sensors = []
    for t in root.tables("sensors"):
        node = _reference(t, "node", t.string("node"), nodes, "node")
        sensors.append(Sensor(t.string("name"), node, _direction(t, "direction"),
                              t.string("quantity", "displacement", choices=SENSOR_QUANTITIES)))
        t.finish()
    _unique([s.name for s in sensors], "sensors", source)

    disturbances = []
    for t in root.tables("disturbances"):
        node = _reference(t, "node", t.string("node"), nodes, "node")
        disturbances.append(Disturbance(t.string("name"), node, _direction(t, "direction")))
        t.finish()
    _unique([d.name for d in disturbances], "disturbances", source)

    damping = root.table("damping", {})
    modal_damping = damping.number("modal_ratio", 0.001, positive=True, maximum=0.99)
    damping.finish()

    updating = None
    if "updating" in root.data:
        updating = _parse_updating(root.table("updating"), materials, connectors)

    control = _parse_control(root.table("control", {}), joints, dofs)
    safety = _parse_safety(root.table("safety", {}), control, joints)

    root.finish()
    return Design(name, description, materials, sections, connectors, node_types, nodes, members,
                  tuple(point_masses), tuple(supports), tuple(joints), tuple(sensors),
                  tuple(disturbances), modal_damping, updating, control, safety, source=source,
                  truss=truss_settings)


# Bounds of [safety]: beyond them a value is a typing error, not a design.
MAX_SLIDING_VELOCITY = 100.0  # m/s
MAX_FRICTION_COEFFICIENT = 10.0
MAX_TEMPERATURE = 200.0  # °C: above the Curie point of PZT stacks
MAX_CURRENT = 100.0  # A
MAX_TRACKING_TOLERANCE = 1e3  # V
MAX_DISPLACEMENT = 20.0  # m: what the TIP_SENSORS frame carries
MAX_TIMEOUT_CYCLES = 7  # frames echo a 4-bit heartbeat counter: ages of 8 and more read as "ahead"


def _parse_safety(t: _Table, control: Control, joints) -> Safety:
    count = len(control.joints) if control.joints is not None else len(joints)
    d = Safety()
    value = t.data.get("safe_normal_force", d.safe_normal_force)
    if isinstance(value, str):
        safe = t.string("safe_normal_force", d.safe_normal_force, choices=("max", "min"))
    else:
        safe = _per_joint(t, "safe_normal_force", d.safe_normal_force, count, positive=True)
        low = np.broadcast_to(np.asarray(control.normal_force_min, dtype=float), (max(count, 1),))
        high = np.broadcast_to(np.asarray(control.normal_force_max, dtype=float), (max(count, 1),))
        forces = np.broadcast_to(np.asarray(safe, dtype=float), (max(count, 1),))
        for i in range(len(forces)):
            if not low[i] <= forces[i] <= high[i]:
                entry = f" (entry {i})" if isinstance(safe, tuple) else ""
                raise t.error("safe_normal_force", float(forces[i]),
                              f"\"max\", \"min\" or newtons within [normal_force_min, normal_force_max] = "
                              f"[{low[i]:g}, {high[i]:g}] N{entry}")
    safety = Safety(
        safe_normal_force=safe,
        sliding_velocity_limit=t.number("sliding_velocity_limit", d.sliding_velocity_limit, positive=True,
                                        maximum=MAX_SLIDING_VELOCITY),
        friction_coefficient_limit=t.number("friction_coefficient_limit", d.friction_coefficient_limit,
                                            positive=True, maximum=MAX_FRICTION_COEFFICIENT),
        normal_force_margin=t.number("normal_force_margin", d.normal_force_margin, non_negative=True, maximum=1.0),
        displacement_limit=(t.number("displacement_limit", positive=True, maximum=MAX_DISPLACEMENT)
                            if "displacement_limit" in t.data else None),
        velocity_limit=t.number("velocity_limit", d.velocity_limit, positive=True, maximum=MAX_SLIDING_VELOCITY),
        amplifier_temperature_limit=t.number("amplifier_temperature_limit", d.amplifier_temperature_limit,
                                             positive=True, maximum=MAX_TEMPERATURE),
        amplifier_current_limit=t.number("amplifier_current_limit", d.amplifier_current_limit, positive=True,
                                         maximum=MAX_CURRENT),
        tracking_tolerance=t.number("tracking_tolerance", d.tracking_tolerance, positive=True,
                                    maximum=MAX_TRACKING_TOLERANCE),
        timeout_cycles=t.integer("timeout_cycles", d.timeout_cycles, minimum=2, maximum=MAX_TIMEOUT_CYCLES),
        recovery_cycles=t.integer("recovery_cycles", d.recovery_cycles, minimum=1, maximum=255),
    )
    t.used.add("displacement_limit")  # optional without a default: listed among the allowed keys
    t.finish()
    return safety


def estimated_dofs(nodes: dict[str, Node], members: dict[str, Member], joints: int) -> int:
    """Upper bound of the model's DOF count (before supports), known before anything is built:
    6 per node centre and per beam node inside a member (tube nodes, connector–tube nodes), one
    per joint. The seats at the member ends move with their node and have none of their own."""
    inner = sum(m.elements - 1 + (2 if m.connector else 0) for m in members.values())
    return 6 * (len(nodes) + inner) + joints


def _per_joint(t: _Table, name: str, default, count: int, **checks):
    """A number for every joint, or a list with one number per controlled joint."""
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


def _parse_control(t: _Table, joints, dofs: int) -> Control:
    names = [j.name for j in joints]
    controlled = None
    if "joints" in t.data:
        value = t.get("joints")
        if not (isinstance(value, list) and value and all(isinstance(v, str) for v in value)):
            raise t.error("joints", value, "expected a non-empty list of joint names")
        for v in value:
            if v not in names:
                raise t.error("joints", v, "a joint of [[joints]]: " + (", ".join(names) or "(the design has none)"))
        if len(set(value)) != len(value):
            raise t.error("joints", value, "each joint once")
        controlled = tuple(value)
    count = len(controlled) if controlled is not None else len(joints)
    d = Control()
    control = Control(
        joints=controlled,
        sample_time=t.number("sample_time", d.sample_time, positive=True),
        normal_force_min=_per_joint(t, "normal_force_min", d.normal_force_min, count, non_negative=True),
        normal_force_max=_per_joint(t, "normal_force_max", d.normal_force_max, count, positive=True),
        considered_modes=t.integer("considered_modes", d.considered_modes, maximum=MAX_MODES),
        modes=t.integer("modes", d.modes, maximum=MAX_MODES),
        krylov=t.integer("krylov", d.krylov, minimum=0, maximum=MAX_KRYLOV),
        state_weight=t.number("state_weight", d.state_weight, positive=True),
        control_weight=t.number("control_weight", d.control_weight, positive=True),
        process_noise=t.number("process_noise", d.process_noise, positive=True),
        measurement_noise=t.number("measurement_noise", d.measurement_noise, positive=True),
        siso_boundary_layer=_per_joint(t, "siso_boundary_layer", None, count, positive=True),
        clqg_boundary_layer=t.number("clqg_boundary_layer", d.clqg_boundary_layer, positive=True),
        piezo_capacitance=t.number("piezo_capacitance", d.piezo_capacitance, positive=True),
        piezo_force_per_volt=t.number("piezo_force_per_volt", d.piezo_force_per_volt, positive=True),
        piezo_preload=t.number("piezo_preload", d.piezo_preload, non_negative=True),
        study_duration=t.number("study_duration", d.study_duration, positive=True),
    )
    _check_control_limits(t, control, count, dofs)
    t.finish()
    return control


def _check_control_limits(t: _Table, control: Control, count: int, dofs: int) -> None:
    """Ranges of [control] that single keys cannot express: sizes the study allocates or runs
    through, and the normal forces a piezo joint can set (F_N = force_per_volt·V + preload)."""
    if control.sample_time < MIN_SAMPLE_TIME:
        raise t.error("sample_time", control.sample_time, f"must be >= {MIN_SAMPLE_TIME:g} s (the firmware counts "
                      "its cycle in whole microseconds)")
    if control.study_duration > MAX_STUDY_DURATION:
        raise t.error("study_duration", control.study_duration, f"must be 0 < t_e <= {MAX_STUDY_DURATION:g} s")
    steps = control.study_duration / control.sample_time
    if steps > MAX_CONTROLLER_STEPS:
        raise t.error("study_duration", control.study_duration,
                      f"at most {MAX_CONTROLLER_STEPS} controller steps: t_e <= {MAX_CONTROLLER_STEPS:g} × "
                      f"sample_time = {MAX_CONTROLLER_STEPS * control.sample_time:g} s")
    lanczos_modes = MAX_LANCZOS_BYTES // (16 * max(dofs, 1))
    if min(control.considered_modes, dofs) > lanczos_modes:
        raise t.error("considered_modes", control.considered_modes,
                      f"with about {dofs} DOFs at most {lanczos_modes} (the Lanczos basis of 2 × considered_modes "
                      f"vectors must stay under {MAX_LANCZOS_BYTES // 1024**3} GiB)")
    if control.modes > control.considered_modes:
        raise t.error("modes", control.modes, f"must be <= considered_modes ({control.considered_modes})")
    # A number applies to every joint and is checked even when the design has none yet.
    count = count or int(not isinstance(control.normal_force_min, tuple)
                         and not isinstance(control.normal_force_max, tuple))
    low = np.broadcast_to(np.asarray(control.normal_force_min, dtype=float), (count,))
    high = np.broadcast_to(np.asarray(control.normal_force_max, dtype=float), (count,))
    for i in range(count):
        joint = f" (entry {i})" if isinstance(control.normal_force_max, tuple) else ""
        if high[i] > MAX_NORMAL_FORCE:
            raise t.error("normal_force_max", float(high[i]),
                          f"must be 0 < F_N^max <= {MAX_NORMAL_FORCE:g} N{joint}: more than the largest piezo "
                          "stacks push and the joint bolt holds")
    for i in range(count):
        joint = f" (entry {i})" if isinstance(control.normal_force_min, tuple) or isinstance(control.normal_force_max, tuple) else ""
        if low[i] > high[i]:
            raise t.error("normal_force_min", float(low[i]),
                          f"must be 0 <= F_N^min <= F_N^max = {high[i]:g} N{joint}")
    if count and control.piezo_preload > float(low.min()):
        raise t.error("piezo_preload", control.piezo_preload,
                      f"must be 0 <= preload <= F_N^min = {float(low.min()):g} N (at 0 V the stack "
                      "already presses with the preload, so no setting could reach F_N^min)")


def _unique(names: list[str], table: str, source: str) -> None:
    for i, name in enumerate(names):
        if names.index(name) != i:
            raise DesignError(f"{table}[{i}].name", name, "duplicate name", source)


def _dof_list(t: _Table, key: str) -> tuple[str, ...]:
    value = t.get(key)
    if value == "all":
        return DOF_NAMES
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise t.error(key, value, "expected \"all\" or a list of " + ", ".join(DOF_NAMES))
    for v in value:
        if v not in DOF_NAMES:
            raise t.error(key, v, "allowed: " + ", ".join(DOF_NAMES))
    return tuple(dict.fromkeys(value))


def _joint_axis(t: _Table, member: Member, nodes: dict[str, Node]) -> tuple[float, float, float]:
    axis = np.array(t.vector("axis", 3), dtype=float)
    rod = np.subtract(nodes[member.end].position, nodes[member.start].position)
    rod /= np.linalg.norm(rod)
    if np.linalg.norm(axis) == 0.0:
        raise t.error("axis", list(axis), "must not be the zero vector")
    axis /= np.linalg.norm(axis)
    if abs(float(axis @ rod)) > 1e-6:
        raise t.error("axis", [float(a) for a in axis],
                      f"type B rotates about an axis perpendicular to the member (member direction {np.round(rod, 4).tolist()})")
    return tuple(float(a) for a in axis)


def _check_member_lengths(members, nodes, node_types, connectors) -> None:
    for member in members.values():
        length = float(np.linalg.norm(np.subtract(nodes[member.end].position, nodes[member.start].position)))
        rigid = sum(node_types[nodes[n].type].seat_radius if nodes[n].type else 0.0 for n in (member.start, member.end))
        flexible = 2.0 * connectors[member.connector].length if member.connector else 0.0
        if length - rigid - flexible <= 1e-9:
            raise DesignError(f"members.{member.name}", length,
                              f"member length must exceed node seats + connectors ({rigid + flexible:.4g} m)")


def _parse_updating(t: _Table, materials, connectors) -> Updating:
    default_factor = t.number("max_factor", 10.0, positive=True)
    if default_factor <= 1.0:
        raise t.error("max_factor", default_factor, "must be > 1")
    entries = t.get("parameters")
    if not isinstance(entries, list) or not entries:
        raise t.error("parameters", entries, "expected a non-empty list of parameter keys or {name, max_factor} tables")
    parameters, factors = [], []
    for i, entry in enumerate(entries):
        if isinstance(entry, str):
            key, factor = entry, default_factor
        else:
            item = _Table(entry, t.key(f"parameters[{i}]"), t.source)
            key = item.string("name")
            factor = item.number("max_factor", default_factor, positive=True)
            if factor <= 1.0:
                raise item.error("max_factor", factor, "must be > 1")
            item.finish()
        if key in parameters:
            raise t.error(f"parameters[{i}]", key, "duplicate parameter")
        parameters.append(key)
        factors.append(factor)
    for i, key in enumerate(parameters):
        try:
            table, name, _ = _split_parameter(key)
        except DesignError:
            allowed = ", ".join(f"{tb}.<name>.{a}" for tb, attrs in UPDATABLE.items() for a in attrs)
            raise t.error(f"parameters[{i}]", key, f"allowed: {allowed}") from None
        known = materials if table == "materials" else connectors
        if name not in known:
            raise t.error(f"parameters[{i}]", key, f"no {table[:-1]} named {name!r}")
    measured = []
    for m in t.tables("measured"):
        measured.append(MeasuredMode(m.integer("mode", maximum=MAX_MODES), m.number("frequency_hz", positive=True),
                                     m.number("mac", None) if m.data.get("mac") is not None else None))
        m.finish()
    if len(measured) < 1:
        raise t.error("measured", [], "give at least one [[updating.measured]] mode")
    modes = [m.mode for m in measured]
    if sorted(set(modes)) != modes:
        raise t.error("measured", modes, "mode numbers must be strictly increasing")
    t.finish()
    return Updating(tuple(parameters), tuple(measured), tuple(factors))


# --------------------------------------------------------------------------- generator
def _generate_mast(t: _Table, nodes, members, node_types, sections, connectors, default_elements) -> None:
    """A regular square mast along x (paper Fig. 1/8): ``bays`` bays, corners N<i>_<c>.

    Stations i = 0..bays sit at x = i·bay_length; corners c = 0..3 at (y, z) = (∓w/2, ∓w/2)
    counter-clockwise. Members: longerons L<i>_<c>, battens B<i>_<c> (frame edges), face
    diagonals D<i>_<f> (one per side face and bay, ``diagonals`` = alternating | parallel),
    optional frame diagonals F<i>, and a centre node TIP in the last frame tied to the four
    corners (``tip_node = "cross"``) or splitting that frame's diagonal (``"diagonal"``) by T<c>.
    """
    bays = t.integer("bays", maximum=MAX_BAYS)
    bay_length = t.number("bay_length", positive=True)
    width = t.number("width", positive=True)
    pattern = t.string("diagonals", "alternating", choices=DIAGONAL_PATTERNS)
    frame_diagonals = t.boolean("frame_diagonals", False)
    root_battens = t.boolean("root_battens", False)
    tip_node = t.string("tip_node", "cross", choices=TIP_NODES)
    t.boolean("clamp_root", True)
    node_type = _reference(t, "node_type", t.string("node_type"), node_types, "node type")
    section = _reference(t, "section", t.string("section"), sections, "section")
    connector = t.string("connector", None)
    if connector is not None:
        _reference(t, "connector", connector, connectors, "connector")
    elements = t.integer("tube_elements", default_elements, maximum=MAX_ELEMENTS)
    # The mast's size before any of it is made (the same count as estimated_dofs).
    tip_spokes = {"none": 0, "cross": 4, "diagonal": 2}[tip_node]
    generated_nodes = 4 * (bays + 1) + (tip_node != "none")
    generated_members = 12 * bays + 4 * root_battens + tip_spokes + (
        bays - (tip_node == "diagonal") if frame_diagonals else 0)
    dofs = 6 * (generated_nodes + generated_members * (elements - 1 + (2 if connector else 0)))
    if dofs > MAX_DOFS:
        raise t.error("bays", bays, f"the mast would have {dofs} DOFs ({generated_nodes} nodes, {generated_members} "
                      f"members of {elements} tube elements); at most {MAX_DOFS}: fewer bays or tube_elements")

    corners = [(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)]
    for i in range(bays + 1):
        for c, (y, z) in enumerate(corners):
            nodes[f"N{i}_{c}"] = Node(f"N{i}_{c}", (i * bay_length, y * width, z * width), node_type)

    def add(name: str, a: str, b: str) -> None:
        members[name] = Member(name, a, b, section, connector, elements)

    for i in range(bays + 1):
        if i > 0 or root_battens:
            for c in range(4):
                add(f"B{i}_{c}", f"N{i}_{c}", f"N{i}_{(c + 1) % 4}")
        if i > 0 and frame_diagonals and not (i == bays and tip_node == "diagonal"):
            add(f"F{i}", f"N{i}_{i % 2}", f"N{i}_{i % 2 + 2}")
    for i in range(1, bays + 1):
        for c in range(4):
            add(f"L{i}_{c}", f"N{i - 1}_{c}", f"N{i}_{c}")
        for f in range(4):
            rising = pattern == "parallel" or (i + f) % 2 == 0
            if rising:
                add(f"D{i}_{f}", f"N{i - 1}_{f}", f"N{i}_{(f + 1) % 4}")
            else:
                add(f"D{i}_{f}", f"N{i - 1}_{(f + 1) % 4}", f"N{i}_{f}")
    if tip_node != "none":
        nodes["TIP"] = Node("TIP", (bays * bay_length, 0.0, 0.0), node_type)
        spokes = range(4) if tip_node == "cross" else (bays % 2, bays % 2 + 2)
        for c in spokes:
            add(f"T{c}", f"N{bays}_{c}", "TIP")
