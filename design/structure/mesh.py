"""The mesh of a truss (paper Fig. 6): the points and beam elements of every member, before any
matrix.

Every member runs node centre → connector seat (rigid offset, part of the rigid node) → end
connector (its own beam element) → tube (``elements`` beam elements) → end connector → seat →
node centre. Each element carries its stiffness terms by parameter key (``table.name.attribute``,
so that ``fem`` keeps K = Σ_p p·K_p apart) and its mass per length.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from smartjoint.design.structure.description import Design


def _parameter_key(table: str, name: str, attribute: str) -> str:
    """The key of a stiffness parameter, ``table.name.attribute`` (``fem`` reads it back)."""
    return f"{table}.{name}.{attribute}"


@dataclass
class Mesh:
    """The points and beam elements of every member (paper Fig. 6), before any matrix."""

    points: list[np.ndarray]  # node centres first, then the beam nodes of each member
    point_names: list[str]
    # Seats of every member end: (member, end) -> (point index, node index, axis into member).
    seats: dict[tuple[str, str], tuple[int, int, np.ndarray]] = field(default_factory=dict)
    element_a: list[int] = field(default_factory=list)
    element_b: list[int] = field(default_factory=list)
    element_member: list[str] = field(default_factory=list)
    element_kind: list[str] = field(default_factory=list)
    element_terms: list[list[tuple[str, str, float]]] = field(default_factory=list)
    element_mass: list[tuple[float, float]] = field(default_factory=list)
    element_reference: list[np.ndarray] = field(default_factory=list)


def discretise(design: Design, node_index: dict[str, int]) -> Mesh:
    """Discretise every member: node centre → seat → connector → tube elements → connector →
    seat → node centre (paper Fig. 6).

    Parameters
    ----------
    design : Design
        The truss: nodes, members, sections, materials, connectors and node types.
    node_index : dict of str to int
        The point index of every node centre (the first points of the mesh).

    Returns
    -------
    Mesh
        The points (node centres first), the seat of every member end and every beam element
        with its stiffness terms, mass per length and reference vector.

    Examples
    --------
    >>> mesh = discretise(design, {name: i for i, name in enumerate(design.nodes)})  # doctest: +SKIP
    """
    nodes = design.nodes
    mesh = Mesh([np.array(nodes[n].position, dtype=float) for n in nodes], list(nodes))
    points, point_names = mesh.points, mesh.point_names
    for member in design.members.values():
        start = np.array(nodes[member.start].position, dtype=float)
        end = np.array(nodes[member.end].position, dtype=float)
        axis = (end - start) / np.linalg.norm(end - start)
        radius_start = _seat_radius(design, member.start)
        radius_end = _seat_radius(design, member.end)
        connector = design.connectors[member.connector] if member.connector else None
        connector_length = connector.length if connector else 0.0
        seat_start = start + radius_start * axis
        seat_end = end - radius_end * axis
        stations = [seat_start]
        if connector:
            stations.append(seat_start + connector_length * axis)
        tube_start = stations[-1]
        tube_end = seat_end - connector_length * axis
        for k in range(1, member.elements):
            stations.append(tube_start + (tube_end - tube_start) * k / member.elements)
        stations.append(tube_end)
        if connector:
            stations.append(seat_end)
        first = len(points)
        for k, position in enumerate(stations):
            points.append(position)
            point_names.append(f"{member.name}:{k}")
        last = len(points) - 1
        mesh.seats[(member.name, "start")] = (first, node_index[member.start], axis)
        mesh.seats[(member.name, "end")] = (last, node_index[member.end], -axis)
        _add_elements(design, mesh, member, connector, first, len(stations) - 1, axis)
    return mesh


def _add_elements(design: Design, mesh: Mesh, member, connector, first: int, n_segments: int, axis: np.ndarray) -> None:
    """The beam elements of one member: the end connectors (if any) and the tube between them."""
    section = design.sections[member.section]
    material = design.materials[section.material]
    tube_terms = [
        (_parameter_key("materials", material.name, "youngs_modulus"), "axial", section.area),
        (_parameter_key("materials", material.name, "youngs_modulus"), "bending_y", section.second_moment),
        (_parameter_key("materials", material.name, "youngs_modulus"), "bending_z", section.second_moment),
        (_parameter_key("materials", material.name, "shear_modulus"), "torsion", section.polar_moment),
    ]
    tube_mass = (material.density * section.area, material.density * section.polar_moment)
    for k in range(n_segments):
        is_connector = connector is not None and (k == 0 or k == n_segments - 1)
        mesh.element_a.append(first + k)
        mesh.element_b.append(first + k + 1)
        mesh.element_member.append(member.name)
        mesh.element_reference.append(_member_reference(axis))
        if is_connector:
            mesh.element_kind.append("connector")
            mesh.element_terms.append(
                [
                    (_parameter_key("connectors", connector.name, "axial_stiffness"), "axial", 1.0),
                    (_parameter_key("connectors", connector.name, "bending_stiffness"), "bending_y", 1.0),
                    (_parameter_key("connectors", connector.name, "bending_stiffness"), "bending_z", 1.0),
                    (_parameter_key("connectors", connector.name, "torsional_stiffness"), "torsion", 1.0),
                ]
            )
            per_length = connector.mass / connector.length
            mesh.element_mass.append((per_length, per_length * connector.diameter**2 / 8.0))
        else:
            mesh.element_kind.append("tube")
            mesh.element_terms.append(tube_terms)
            mesh.element_mass.append(tube_mass)


def _seat_radius(design: Design, node_name: str) -> float:
    node = design.nodes[node_name]
    return design.node_types[node.type].seat_radius if node.type else 0.0


def _member_reference(axis: np.ndarray) -> np.ndarray:
    return np.array([0.0, 1.0, 0.0]) if abs(axis[2]) > 0.99 else np.array([0.0, 0.0, 1.0])


__all__ = ["Mesh", "discretise"]
