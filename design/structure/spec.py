"""The design file: a TOML description of a truss with friction joints, loaded into dataclasses.

The format is documented in ``docs/design-file.md``. Every check here fails with a
:class:`~smartjoint.common.errors.DesignError` that names the key path (``joints[2].type``),
the value found and what is allowed, so a user never meets a traceback from numpy. The values
are the dataclasses of `description`; the tables are read through `table.DesignTable`, [control]
by `control_section` and [safety] and [updating] by `sections`.
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path
from typing import Any

from smartjoint.common import package_data
from smartjoint.common.errors import DesignError
from smartjoint.design.structure.control_section import parse_control
from smartjoint.design.structure.description import (
    DOF_NAMES,
    JOINT_TYPES,
    SENSOR_QUANTITIES,
    Connector,
    Design,
    Disturbance,
    Joint,
    Material,
    Member,
    Node,
    NodeType,
    PointMass,
    Sensor,
    Support,
    TubeSection,
)
from smartjoint.design.structure.files import read_file, read_toml
from smartjoint.design.structure.friction_section import joint_own_friction, parse_friction
from smartjoint.design.structure.network_section import parse_network, parse_xcp
from smartjoint.design.structure.sections import (
    check_member_lengths,
    joint_axis,
    parse_placement,
    parse_safety,
    parse_updating,
)
from smartjoint.design.structure.table import DesignTable, direction, dof_list, reference, unique
from smartjoint.design.structure.uncertainty import parse_uncertainty

SCHEMA = "smartjoint-design/1"
DIAGONAL_PATTERNS = ("alternating", "parallel")
TIP_NODES = ("none", "cross", "diagonal")

REFERENCE_DESIGN = package_data.path("smartjoint.design", "data/meroform_10bay.toml")

# Limits on every size a design file controls, checked before anything of that size is
# allocated (docs/design-file.md; MAX_MODES with [updating] in `sections`, the limits of [control]
# in `control_section`). Each is generous for a real truss: a 1000-bay mast of the reference
# kind has 4 005 nodes, 12 004 members and 384 000 DOFs and solves in about a minute.
MAX_FILE_BYTES = 4 * 1024 * 1024  # one design file: some 50 000 explicit members, parsed in seconds
MAX_BASE_DEPTH = 4  # base files behind the file given
MAX_BAYS = 5000
MAX_ELEMENTS = 1000  # beam elements per tube (a cubic beam element needs a handful per wave)
MAX_NODES = 100_000
MAX_MEMBERS = 300_000
MAX_DOFS = 1_000_000  # about 5 GB for assembly plus 100 modes


def load_design(path: str | Path | None = None) -> Design:
    """Load and validate a design file; ``None`` loads the bundled reference truss.

    Parameters
    ----------
    path : str or Path, optional
        The design file (TOML, docs/design-file.md); its ``base = …`` chain is read too.

    Returns
    -------
    Design
        The validated design, ``sha256`` over the bytes of the whole chain.

    Raises
    ------
    DesignError
        Naming the key path, the value and what is allowed.

    Examples
    --------
    >>> design = load_design()  # the bundled 10-bay reference truss
    >>> design.name  # doctest: +SKIP
    """
    path = Path(path) if path is not None else REFERENCE_DESIGN
    source = str(path)
    raw = read_file(path, "<file>", source, None, MAX_FILE_BYTES)
    origins: dict[str, str] = {}
    data, raw = read_toml(path, source, raw, [path], MAX_FILE_BYTES, MAX_BASE_DEPTH, origins)
    design = parse_design(data, source=source, origins=origins)
    return dataclasses.replace(design, sha256=hashlib.sha256(raw).hexdigest())


def parse_design(data: dict[str, Any], source: str = "<memory>", origins: dict[str, str] | None = None) -> Design:
    """Validate a design given as a (TOML-like) dictionary.

    Parameters
    ----------
    data : dict
        The tables of a design file (docs/design-file.md), ``base`` already merged.
    source : str
        Where it came from, for the messages.
    origins : dict, optional
        The file each top-level key was written in (a base chain); ``source`` for the others.

    Returns
    -------
    Design
        The validated design (``sha256`` empty: `load_design` hashes the file).

    Raises
    ------
    DesignError
        Naming the key path, the value and what is allowed.
    """
    root = DesignTable(data, "", source)
    schema = root.string("schema", SCHEMA)
    if schema != SCHEMA:
        raise root.error("schema", schema, f"this version reads {SCHEMA!r}")
    name = root.string("name")
    description = root.get("description", "")
    if not isinstance(description, str):
        raise root.error("description", description, "expected a string")

    materials, sections, connectors, node_types = _parse_components(root)
    nodes, members, truss_settings, dofs = _parse_geometry(root, node_types, sections, connectors)
    point_masses, supports = _parse_attachments(root, nodes, truss_settings)
    origins = origins or {}
    joints = _parse_joints(root, members, nodes, origins.get("joints", source))
    friction, friction_records = parse_friction(root, origins.get("friction", source))
    placement = parse_placement(root.table("placement")) if "placement" in root.data else None
    sensors, disturbances = _parse_signals(root, nodes)

    damping = root.table("damping", {})
    modal_damping = damping.number("modal_ratio", 0.001, positive=True, maximum=0.99)
    damping.finish()

    has_updating = "updating" in root.data
    updating = parse_updating(root.table("updating"), materials, connectors, nodes) if has_updating else None

    control = parse_control(root.table("control", {}), joints, dofs)
    safety = parse_safety(root.table("safety", {}), control, joints)
    uncertainty = parse_uncertainty(root, [j.name for j in joints])
    network = parse_network(root.table("network", {}))
    xcp = parse_xcp(root.table("xcp", {}), network)
    root.finish()
    return Design(
        name,
        description,
        materials,
        sections,
        connectors,
        node_types,
        nodes,
        members,
        tuple(point_masses),
        tuple(supports),
        tuple(joints),
        tuple(sensors),
        tuple(disturbances),
        modal_damping,
        updating,
        control,
        safety,
        source=source,
        truss=truss_settings,
        friction=friction,
        friction_records=friction_records,
        placement=placement,
        uncertainty=uncertainty,
        network=network,
        xcp=xcp,
    )


def _parse_components(root: DesignTable):
    """[materials], [sections], [connectors] and [node_types], each by name."""
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
        material = reference(t, "material", t.string("material"), materials, "material")
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
    return materials, sections, connectors, node_types


def _named_tables(root: DesignTable, key: str, existing: dict, limit: int, noun: str):
    """The [[key]] tables of ``root`` with their names, once they and the ``existing`` entries
    (those [truss] generated) are at most ``limit``; a name already in ``existing`` is refused
    when its table comes up, so the caller adds each entry before the next table is read.

    Parameters
    ----------
    root : DesignTable
        The design file's top table.
    key : str
        The array of tables, ``"nodes"`` or ``"members"``.
    existing : dict
        The entries so far by name, filled by the caller.
    limit : int
        The most entries allowed.
    noun : str
        One entry, in the error messages.

    Yields
    ------
    tuple of (DesignTable, str)
        Each table and its name.
    """
    tables = root.tables(key)
    if len(existing) + len(tables) > limit:
        raise root.error(key, f"{len(existing) + len(tables)} {key}", f"at most {limit} {key}")
    for t in tables:
        name = t.string("name")
        if name in existing:
            raise t.error("name", name, f"duplicate {noun} name")
        yield t, name


def _parse_geometry(root: DesignTable, node_types, sections, connectors):
    """[mesh], the generated [truss], [[nodes]] and [[members]], checked against the size
    limits before the model is built; returns them with the [truss] settings and the DOF bound."""
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

    for t, node_name in _named_tables(root, "nodes", nodes, MAX_NODES, "node"):
        node_type = t.string("type", None)
        if node_type is not None:
            reference(t, "type", node_type, node_types, "node type")
        nodes[node_name] = Node(node_name, t.vector3("position"), node_type)
        t.finish()

    for t, member_name in _named_tables(root, "members", members, MAX_MEMBERS, "member"):
        start = reference(t, "start", t.string("start"), nodes, "node")
        end = reference(t, "end", t.string("end"), nodes, "node")
        section = reference(t, "section", t.string("section"), sections, "section")
        connector = t.string("connector", None)
        if connector is not None:
            reference(t, "connector", connector, connectors, "connector")
        members[member_name] = Member(
            member_name, start, end, section, connector, t.integer("elements", default_elements, maximum=MAX_ELEMENTS)
        )
        t.finish()
    if not members:
        raise root.error("members", [], "the design has no members (give [truss] or [[members]])")
    joint_entries = root.data.get("joints", [])
    dofs = estimated_dofs(nodes, members, len(joint_entries) if isinstance(joint_entries, list) else 0)
    if dofs > MAX_DOFS:
        raise DesignError(
            "<model>",
            f"{dofs} DOFs",
            f"at most {MAX_DOFS} DOFs (6 per node and per inner beam node, "
            "1 per joint); use fewer bays, members or [mesh] tube_elements",
            root.source,
        )
    check_member_lengths(members, nodes, node_types, connectors)
    return nodes, members, truss_settings, dofs


def _parse_attachments(root: DesignTable, nodes, truss_settings):
    """[[point_masses]] and [[supports]]; a generated mast is clamped at its root unless
    ``clamp_root = false``."""
    point_masses = []
    for t in root.tables("point_masses"):
        node = reference(t, "node", t.string("node"), nodes, "node")
        point_masses.append(
            PointMass(node, t.number("mass", non_negative=True), t.number("inertia", 0.0, non_negative=True))
        )
        t.finish()

    supports = []
    for t in root.tables("supports"):
        node = reference(t, "node", t.string("node"), nodes, "node")
        supports.append(Support(node, dof_list(t, "dofs")))
        t.finish()
    if "truss" in root.data and truss_settings.get("clamp_root", True):
        generated = {s.node for s in supports}
        supports.extend(Support(f"N0_{c}", DOF_NAMES) for c in range(4) if f"N0_{c}" not in generated)
    return point_masses, supports


def _parse_joints(root: DesignTable, members, nodes, written_in: str) -> list[Joint]:
    """[[joints]]: unique names, at most one joint per member end, the axis of type B."""
    joints = []
    names: set[str] = set()
    for t in root.tables("joints"):
        joint_name = t.string("name")
        if joint_name in names:
            raise t.error("name", joint_name, "duplicate joint name")
        names.add(joint_name)
        member = reference(t, "member", t.string("member"), members, "member")
        end = t.string("end", choices=("start", "end"))
        joint_type = t.string("type", choices=JOINT_TYPES)
        axis = None
        if joint_type == "B":
            axis = joint_axis(t, members[member], nodes)
        elif "axis" in t.data:
            t.get("axis")
            raise t.error("axis", t.data["axis"], "type A slips along the member axis; axis is only for type B")
        joints.append(Joint(joint_name, member, end, joint_type, axis, joint_own_friction(t, joint_type, written_in)))
        t.finish()
    ends = [(j.member, j.end) for j in joints]
    for i, joint_end in enumerate(ends):
        if ends.index(joint_end) != i:
            raise DesignError(
                f"joints[{i}].end",
                joint_end[1],
                f"member {joint_end[0]!r} already has a joint at that end",
                root.source,
            )
    return joints


def _parse_signals(root: DesignTable, nodes):
    """[[sensors]] and [[disturbances]], each with unique names."""
    sensors = []
    for t in root.tables("sensors"):
        node = reference(t, "node", t.string("node"), nodes, "node")
        sensors.append(
            Sensor(
                t.string("name"),
                node,
                direction(t, "direction"),
                t.string("quantity", "displacement", choices=SENSOR_QUANTITIES),
            )
        )
        t.finish()
    unique([s.name for s in sensors], "sensors", root.source)

    disturbances = []
    for t in root.tables("disturbances"):
        node = reference(t, "node", t.string("node"), nodes, "node")
        disturbances.append(Disturbance(t.string("name"), node, direction(t, "direction")))
        t.finish()
    unique([d.name for d in disturbances], "disturbances", root.source)
    return sensors, disturbances


def estimated_dofs(nodes: dict[str, Node], members: dict[str, Member], joints: int) -> int:
    """Upper bound of the model's DOF count (before supports), known before anything is built.

    6 per node centre and per beam node inside a member (tube nodes, connector–tube nodes), one
    per joint. The seats at the member ends move with their node and have none of their own.

    Parameters
    ----------
    nodes : dict of str to Node
        The nodes.
    members : dict of str to Member
        The members.
    joints : int
        The number of joints.

    Returns
    -------
    int
        The DOF bound, checked against MAX_DOFS.
    """
    inner = sum(m.elements - 1 + (2 if m.connector else 0) for m in members.values())
    return 6 * (len(nodes) + inner) + joints


def _generate_mast(t: DesignTable, nodes, members, node_types, sections, connectors, default_elements) -> None:
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
    node_type = reference(t, "node_type", t.string("node_type"), node_types, "node type")
    section = reference(t, "section", t.string("section"), sections, "section")
    connector = t.string("connector", None)
    if connector is not None:
        reference(t, "connector", connector, connectors, "connector")
    elements = t.integer("tube_elements", default_elements, maximum=MAX_ELEMENTS)
    # The mast's size before any of it is made (the same count as estimated_dofs).
    tip_spokes = {"none": 0, "cross": 4, "diagonal": 2}[tip_node]
    generated_nodes = 4 * (bays + 1) + (tip_node != "none")
    generated_members = (
        12 * bays + 4 * root_battens + tip_spokes + (bays - (tip_node == "diagonal") if frame_diagonals else 0)
    )
    dofs = 6 * (generated_nodes + generated_members * (elements - 1 + (2 if connector else 0)))
    if dofs > MAX_DOFS:
        raise t.error(
            "bays",
            bays,
            f"the mast would have {dofs} DOFs ({generated_nodes} nodes, {generated_members} "
            f"members of {elements} tube elements); at most {MAX_DOFS}: fewer bays or tube_elements",
        )

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


__all__ = [
    "MAX_BASE_DEPTH",
    "MAX_BAYS",
    "MAX_DOFS",
    "MAX_ELEMENTS",
    "MAX_FILE_BYTES",
    "MAX_MEMBERS",
    "MAX_NODES",
    "REFERENCE_DESIGN",
    "SCHEMA",
    "estimated_dofs",
    "load_design",
    "parse_design",
]
