"""Sections of the design file that stand on their own: [safety], [updating], the axis of a
type B joint and the member-length check (docs/design-file.md)."""

from __future__ import annotations

import numpy as np

from smartjoint.common.errors import MISSING, DesignError
from smartjoint.design.structure.description import (
    UPDATABLE,
    Control,
    MeasuredDof,
    MeasuredMode,
    Member,
    Node,
    Placement,
    Safety,
    Updating,
    split_parameter,
)
from smartjoint.design.structure.table import DesignTable, direction, per_joint, reference

MAX_MODES = 1000  # considered_modes, updating mode numbers
MAX_MEASURED_DOFS = 10_000  # DOFs of a modal survey (a large EMA has some hundreds)
MAX_MAC_WEIGHT = 100.0  # weight of the (1 − MAC) residuals against the relative frequency errors
# Bounds of [safety]: beyond them a value is a typing error, not a design.
MAX_SLIDING_VELOCITY = 100.0  # m/s
MAX_FRICTION_COEFFICIENT = 10.0
MAX_TEMPERATURE = 200.0  # °C: above the Curie point of PZT stacks
MAX_CURRENT = 100.0  # A
MAX_TRACKING_TOLERANCE = 1e3  # V
MAX_DISPLACEMENT = 20.0  # m: what the TIP_SENSORS frame carries
MAX_PLACED_JOINTS = 50  # joints [placement] may ask for
MAX_TIMEOUT_CYCLES = 7  # frames echo a 4-bit heartbeat counter: ages of 8 and more read as "ahead"


def parse_safety(t: DesignTable, control: Control, joints) -> Safety:
    """The [safety] table: the safe normal force and the plausibility ranges of the inputs.

    Parameters
    ----------
    t : DesignTable
        The [safety] table (empty for the defaults).
    control : Control
        The parsed [control], whose normal-force range bounds the safe force.
    joints : sequence of Joint
        The design's joints (the controlled ones when [control] names none).

    Returns
    -------
    Safety
        The settings, each within its MAX_* bound.
    """
    count = len(control.joints) if control.joints is not None else len(joints)
    d = Safety()
    value = t.data.get("safe_normal_force", d.safe_normal_force)
    if isinstance(value, str):
        safe = t.string("safe_normal_force", d.safe_normal_force, choices=("max", "min"))
    else:
        safe = per_joint(t, "safe_normal_force", d.safe_normal_force, count, positive=True)
        low = np.broadcast_to(np.asarray(control.normal_force_min, dtype=float), (max(count, 1),))
        high = np.broadcast_to(np.asarray(control.normal_force_max, dtype=float), (max(count, 1),))
        forces = np.broadcast_to(np.asarray(safe, dtype=float), (max(count, 1),))
        for i in range(len(forces)):
            if not low[i] <= forces[i] <= high[i]:
                entry = f" (entry {i})" if isinstance(safe, tuple) else ""
                raise t.error(
                    "safe_normal_force",
                    float(forces[i]),
                    f'"max", "min" or newtons within [normal_force_min, normal_force_max] = '
                    f"[{low[i]:g}, {high[i]:g}] N{entry}",
                )
    safety = Safety(
        safe_normal_force=safe,
        sliding_velocity_limit=t.number(
            "sliding_velocity_limit", d.sliding_velocity_limit, positive=True, maximum=MAX_SLIDING_VELOCITY
        ),
        friction_coefficient_limit=t.number(
            "friction_coefficient_limit", d.friction_coefficient_limit, positive=True, maximum=MAX_FRICTION_COEFFICIENT
        ),
        normal_force_margin=t.number("normal_force_margin", d.normal_force_margin, non_negative=True, maximum=1.0),
        displacement_limit=(
            t.number("displacement_limit", positive=True, maximum=MAX_DISPLACEMENT)
            if "displacement_limit" in t.data
            else None
        ),
        velocity_limit=t.number("velocity_limit", d.velocity_limit, positive=True, maximum=MAX_SLIDING_VELOCITY),
        amplifier_temperature_limit=t.number(
            "amplifier_temperature_limit", d.amplifier_temperature_limit, positive=True, maximum=MAX_TEMPERATURE
        ),
        amplifier_current_limit=t.number(
            "amplifier_current_limit", d.amplifier_current_limit, positive=True, maximum=MAX_CURRENT
        ),
        tracking_tolerance=t.number(
            "tracking_tolerance", d.tracking_tolerance, positive=True, maximum=MAX_TRACKING_TOLERANCE
        ),
        actuation_tolerance=t.number("actuation_tolerance", d.actuation_tolerance, positive=True, maximum=1.0),
        timeout_cycles=t.integer("timeout_cycles", d.timeout_cycles, minimum=2, maximum=MAX_TIMEOUT_CYCLES),
        recovery_cycles=t.integer("recovery_cycles", d.recovery_cycles, minimum=1, maximum=255),
    )
    t.used.add("displacement_limit")  # optional without a default: listed among the allowed keys
    t.finish()
    return safety


def parse_updating(t: DesignTable, materials, connectors, nodes: dict[str, Node] | None = None) -> Updating:
    """The [updating] table: the parameters to fit, their bounds and the measured modes (EMA).

    Parameters
    ----------
    t : DesignTable
        The [updating] table.
    materials, connectors : dict
        The parsed tables, which the parameter keys must name.
    nodes : dict of str to Node, optional
        The nodes, which ``measured_dofs`` must name.

    Returns
    -------
    Updating
        Parameters, measured modes (strictly increasing mode numbers), max factors and, where
        given, the EMA shapes at ``measured_dofs`` and the MAC weight.
    """
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
            item = DesignTable(entry, t.key(f"parameters[{i}]"), t.source)
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
            table, name, _ = split_parameter(key)
        except DesignError:
            allowed = ", ".join(f"{tb}.<name>.{a}" for tb, attrs in UPDATABLE.items() for a in attrs)
            raise t.error(f"parameters[{i}]", key, f"allowed: {allowed}") from None
        known = materials if table == "materials" else connectors
        if name not in known:
            raise t.error(f"parameters[{i}]", key, f"no {table[:-1]} named {name!r}")
    measured_dofs = _measured_dofs(t, nodes or {})
    measured = _measured_modes(t, len(measured_dofs))
    mac_weight = t.number("mac_weight", 0.0, non_negative=True, maximum=MAX_MAC_WEIGHT)
    if mac_weight > 0.0 and not measured_dofs:
        raise t.error("mac_weight", mac_weight, "a MAC term needs EMA shapes: give updating.measured_dofs and shapes")
    t.finish()
    return Updating(tuple(parameters), tuple(measured), tuple(factors), measured_dofs, mac_weight)


def _measured_dofs(t: DesignTable, nodes: dict[str, Node]) -> tuple[MeasuredDof, ...]:
    """``measured_dofs``: the DOFs of the modal survey, each ``{ node, direction }`` once."""
    if "measured_dofs" not in t.data:
        return ()
    entries = t.tables("measured_dofs")
    if not entries or len(entries) > MAX_MEASURED_DOFS:
        raise t.error("measured_dofs", f"{len(entries)} DOFs", f"1 … {MAX_MEASURED_DOFS} {{ node, direction }} tables")
    dofs: list[MeasuredDof] = []
    for entry in entries:
        node = reference(entry, "node", entry.string("node"), nodes, "node")
        dof = MeasuredDof(node, direction(entry, "direction"))
        if dof in dofs:
            raise entry.error("direction", entry.data["direction"], f"the same DOF as measured_dofs[{dofs.index(dof)}]")
        dofs.append(dof)
        entry.finish()
    return tuple(dofs)


def _measured_modes(t: DesignTable, dof_count: int) -> list[MeasuredMode]:
    """``measured``: mode numbers (strictly increasing), frequencies, EMA MAC and, with
    ``measured_dofs``, the shape of every mode (one real component per measured DOF)."""
    measured = []
    for m in t.tables("measured"):
        shape = None
        if dof_count:
            if "shape" not in m.data:
                raise m.error("shape", MISSING, f"required with updating.measured_dofs: {dof_count} components")
            shape = m.vector("shape", dof_count)
            if not any(shape):
                raise m.error("shape", list(shape), "must not be all zeros (its MAC is undefined)")
        elif "shape" in m.data:
            raise m.error("shape", m.data["shape"], "give updating.measured_dofs, the DOFs of the components")
        measured.append(
            MeasuredMode(
                m.integer("mode", maximum=MAX_MODES),
                m.number("frequency_hz", positive=True),
                m.number("mac", None) if m.data.get("mac") is not None else None,
                shape,
            )
        )
        m.finish()
    if len(measured) < 1:
        raise t.error("measured", [], "give at least one [[updating.measured]] mode")
    modes = [m.mode for m in measured]
    if sorted(set(modes)) != modes:
        raise t.error("measured", modes, "mode numbers must be strictly increasing")
    return measured


def joint_axis(t: DesignTable, member: Member, nodes: dict[str, Node]) -> tuple[float, float, float]:
    """The rotation axis of a type B joint: its ``axis``, normalised, perpendicular to the member.

    Parameters
    ----------
    t : DesignTable
        The joint's table.
    member : Member
        The member the joint sits on.
    nodes : dict of str to Node
        The nodes, for the member's direction.

    Returns
    -------
    tuple of float
        The unit axis.
    """
    axis = np.array(t.vector("axis", 3), dtype=float)
    rod = np.subtract(nodes[member.end].position, nodes[member.start].position)
    rod /= np.linalg.norm(rod)
    if np.linalg.norm(axis) == 0.0:
        raise t.error("axis", list(axis), "must not be the zero vector")
    axis /= np.linalg.norm(axis)
    if abs(float(axis @ rod)) > 1e-6:
        raise t.error(
            "axis",
            [float(a) for a in axis],
            f"type B rotates about an axis perpendicular to the member (member direction {np.round(rod, 4).tolist()})",
        )
    return float(axis[0]), float(axis[1]), float(axis[2])


def check_member_lengths(members, nodes, node_types, connectors) -> None:
    """Refuse a member whose node seats and connectors leave no tube between them.

    Parameters
    ----------
    members, nodes, node_types, connectors : dict
        The parsed tables by name.
    """
    for member in members.values():
        length = float(np.linalg.norm(np.subtract(nodes[member.end].position, nodes[member.start].position)))
        rigid = sum(node_types[nodes[n].type].seat_radius if nodes[n].type else 0.0 for n in (member.start, member.end))
        flexible = 2.0 * connectors[member.connector].length if member.connector else 0.0
        if length - rigid - flexible <= 1e-9:
            raise DesignError(
                f"members.{member.name}",
                length,
                f"member length must exceed node seats + connectors ({rigid + flexible:.4g} m)",
            )


def parse_placement(t: DesignTable) -> Placement:
    """The [placement] table: the modes to damp and how many type A joints to place on a design
    without joints (a design that extends this one with its own [[joints]] keeps them).

    Parameters
    ----------
    t : DesignTable
        The [placement] table.

    Returns
    -------
    Placement
    """
    modes = t.get("modes")
    if not (
        isinstance(modes, list)
        and modes
        and all(isinstance(m, int) and not isinstance(m, bool) and 1 <= m <= MAX_MODES for m in modes)
    ):
        raise t.error("modes", modes, f"expected a non-empty list of mode numbers 1 … {MAX_MODES}")
    if len(set(modes)) != len(modes):
        raise t.error("modes", modes, "each mode once")
    count = t.integer("count", minimum=1, maximum=MAX_PLACED_JOINTS)
    t.finish()
    return Placement(tuple(sorted(modes)), count)


__all__ = [
    "MAX_MAC_WEIGHT",
    "MAX_MEASURED_DOFS",
    "MAX_MODES",
    "MAX_PLACED_JOINTS",
    "check_member_lengths",
    "joint_axis",
    "parse_placement",
    "parse_safety",
    "parse_updating",
]
