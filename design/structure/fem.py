"""Truss finite element model: beams, rigid nodes and joints by constraints (paper Eq. 4–5, 9–10).

Discretisation (paper Fig. 6): every member runs node centre → connector seat (rigid offset,
part of the rigid node) → end connector (its own beam element) → tube (``elements`` beam
elements) → end connector → seat → node centre. Meroform nodes are perfectly rigid bodies
with their mass and inertia lumped at the centre.

Unconstrained DOFs z̄ (6 per point: node centres, then every beam node of every member) are
tied to the independent DOFs z by the sparse constraint matrix S, z̄ = S·z (Eq. 4):

* a connector seat p of node n with offset r = p − c_n moves with the node,
  u_p = u_n + θ_n × r, θ_p = θ_n;
* a friction joint at that seat adds one independent DOF q (the relative motion it
  releases): type A, u_p += a·q with a the member axis pointing into the member;
  type B, θ_p += b·q with b the joint axis (perpendicular to the member);
* supported node DOFs have no column (they are zero).

Then M = SᵀM̄S, K = SᵀK̄S, E = SᵀĒ, F = SᵀF̄ (Eq. 4 → 5). Ē holds the action–reaction pair
of each joint force (on the seat and, opposite, on the node centre); E comes out as the unit
vector of the joint DOF, so the sliding velocities are v = Eᵀż (Eq. 9).

Sign convention: E is kinematic (v = Eᵀż, v > 0 when the member end moves along a, or turns
about b, relative to the node). The friction load on the structure is −E·u_R with
u_R = F_N·μ(v, φ) (Eq. 2), so u_R·v ≥ 0 in sliding and friction dissipates. The paper folds
this sign into E.

K is linear in every stiffness parameter (E and G of each material, EA, EI, GJ of each
connector), and the model keeps the parts apart: K = Σ_p p·K_p. Model updating changes p
without re-assembling anything.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from smartjoint.common.errors import ModelError
from smartjoint.design.structure import beam
from smartjoint.design.structure.description import DOF_NAMES, Design
from smartjoint.design.structure.mesh import Mesh, discretise

_TERM_INDEX = {name: i for i, name in enumerate(beam.STIFFNESS_TERMS)}


@dataclass
class FEModel:
    """Assembled truss model in independent coordinates z (N = ``n_dof``)."""

    design: Design
    joints_released: bool
    points: np.ndarray  # (n_points, 3) node centres first, then beam nodes
    point_names: list[str]
    element_points: np.ndarray  # (n_elements, 2) point indices
    element_member: list[str]
    element_kind: list[str]  # "tube" | "connector"
    element_properties: np.ndarray  # (n_elements, 6) EA, EIy, EIz, GJ, ρA, ρIp
    element_rotation: np.ndarray  # (n_elements, 3, 3)
    S: sp.csr_matrix  # (6·n_points, N)
    mass: sp.csr_matrix  # M (N, N)
    stiffness_parts: dict[str, sp.csr_matrix]  # K_p per parameter key, unit parameter value
    parameters: dict[str, float]  # current value of every stiffness parameter
    E: np.ndarray  # (N, n_joints) joint DOF selector (Eq. 5, 9)
    F: np.ndarray  # (N, n_disturbances) disturbance distribution (Eq. 5)
    V: np.ndarray  # (n_sensors, N) displacement outputs (Eq. 10)
    W: np.ndarray  # (n_sensors, N) velocity outputs (Eq. 10)
    dof_labels: list[tuple[str, str]]  # (point or joint name, DOF name) per z index
    joint_names: list[str] = field(default_factory=list)
    sensor_names: list[str] = field(default_factory=list)
    disturbance_names: list[str] = field(default_factory=list)
    rigid_links: list[dict] = field(default_factory=list)  # for export
    lumped_masses: list[dict] = field(default_factory=list)  # for export

    @property
    def n_dof(self) -> int:
        return self.mass.shape[0]

    @property
    def stiffness(self) -> sp.csr_matrix:
        return self.stiffness_with(self.parameters)

    def stiffness_with(self, parameters: dict[str, float]) -> sp.csr_matrix:
        """K = Σ_p p·K_p for the given parameter values (missing keys keep their value)."""
        values = {**self.parameters, **parameters}
        total, *rest = [part * values[key] for key, part in self.stiffness_parts.items()]
        for term in rest:
            total = total + term
        return total.tocsr()

    @property
    def total_mass(self) -> float:
        """Total structural mass [kg]: members plus lumped node and point masses."""
        return _rigid_mass(self)


def _rigid_mass(model: FEModel) -> float:
    lengths = np.linalg.norm(
        model.points[model.element_points[:, 1]] - model.points[model.element_points[:, 0]], axis=1
    )
    members = float(np.sum(model.element_properties[:, 4] * lengths))
    return members + sum(m["mass"] for m in model.lumped_masses)


def build_model(design: Design, *, joints: str = "released", allow_mechanisms: bool = False) -> FEModel:
    """Assemble M, K (by parts), S, E, F, V, W for a design (Eq. 4–5, 9–10).

    Parameters
    ----------
    design : Design
        The truss, its joints, sensors and disturbances.
    joints : {"released", "locked"}
        ``"released"`` gives each friction joint its DOF (the frictionless linear subsystem of
        Eq. 12, F_N = 0); ``"locked"`` builds the conventional rigid truss, as measured in the
        modal survey.
    allow_mechanisms : bool
        For tests of unsupported structures: skip `check_supported`.

    Returns
    -------
    FEModel
        The model in independent coordinates z.

    Raises
    ------
    ModelError
        For a structure with zero-energy motions (unless ``allow_mechanisms``).

    Examples
    --------
    >>> model = build_model(load_design(), joints="locked")  # doctest: +SKIP
    """
    if joints not in ("released", "locked"):
        raise ValueError(f"joints: {joints!r} — allowed: 'released', 'locked'")
    node_names = list(design.nodes)
    node_index = {name: i for i, name in enumerate(node_names)}
    mesh = discretise(design, node_index)
    points_array, element_points, lengths, rotation = _element_frames(mesh)
    n_bar = 6 * len(mesh.points)
    rows, cols = _element_entries(element_points)
    coefficients, parameter_values, global_terms = _stiffness_terms(design, mesh.element_terms, lengths, rotation)
    masses = np.array(mesh.element_mass)
    lumped_bar, lumped = _lumped_masses(design, node_names, node_index, n_bar)
    mass_bar = _element_mass_matrix(masses, lengths, rotation, rows, cols, n_bar) + lumped_bar  # node, point masses
    active_joints = list(design.joints) if joints == "released" else []
    S, labels, rigid_links, joint_pairs = _constraint_matrix(
        design, mesh, points_array, node_names, node_index, active_joints
    )
    St, mass, stiffness_parts = _independent_matrices(S, mass_bar, coefficients, global_terms, rows, cols)
    E, F, V, W = _inputs_outputs(design, node_index, S, St, joint_pairs, active_joints)
    model = FEModel(
        design=design,
        joints_released=joints == "released",
        points=points_array,
        point_names=mesh.point_names,
        element_points=element_points,
        element_member=mesh.element_member,
        element_kind=mesh.element_kind,
        element_properties=_element_properties(coefficients, parameter_values, masses),
        element_rotation=rotation,
        S=S,
        mass=mass,
        stiffness_parts=stiffness_parts,
        parameters=parameter_values,
        E=E,
        F=F,
        V=V,
        W=W,
        dof_labels=labels,
        joint_names=[j.name for j in active_joints],
        sensor_names=[s.name for s in design.sensors],
        disturbance_names=[d.name for d in design.disturbances],
        rigid_links=rigid_links,
        lumped_masses=lumped,
    )
    if not allow_mechanisms:
        check_supported(model)
    return model


def _element_frames(mesh: Mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The mesh's points as an array, the two point indices, length and rotation of every element."""
    points_array = np.array(mesh.points)
    element_points = np.column_stack([mesh.element_a, mesh.element_b]).astype(np.int64)
    lengths, rotation = beam.element_frames(
        points_array[element_points[:, 0]], points_array[element_points[:, 1]], np.array(mesh.element_reference)
    )
    return points_array, element_points, lengths, rotation


def _element_mass_matrix(masses, lengths, rotation, rows, cols, n_bar: int) -> sp.csr_matrix:
    """M̄ of the beam elements (without the lumped masses), from their ρA and ρI_p per length."""
    local_mass = beam.local_mass_terms(lengths)
    element_m = masses[:, 0, None, None] * local_mass["translation"] + masses[:, 1, None, None] * local_mass["torsion"]
    element_m = beam.to_global(element_m, rotation)
    return sp.coo_matrix((element_m.ravel(), (rows, cols)), shape=(n_bar, n_bar)).tocsr()


def _independent_matrices(S, mass_bar, coefficients, global_terms, rows, cols):
    """Sᵀ, M = SᵀM̄S and K_p = SᵀK̄_pS per stiffness parameter at unit value (Eq. 4 → 5), so that
    K = Σ_p p·K_p."""
    n_bar = S.shape[0]
    St = S.T.tocsr()
    stiffness_parts = {}
    for key, coefficient in coefficients.items():
        data = np.einsum("et,etij->eij", coefficient, global_terms).ravel()
        part_bar = sp.coo_matrix((data, (rows, cols)), shape=(n_bar, n_bar)).tocsr()
        stiffness_parts[key] = (St @ part_bar @ S).tocsr()
    mass = (St @ mass_bar @ S).tocsr()
    return St, mass, stiffness_parts


def _element_entries(element_points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row and column in z̄ of every entry of every 12 × 12 element matrix, for one COO assembly."""
    element_dofs = np.concatenate(
        [6 * element_points[:, [0]] + np.arange(6), 6 * element_points[:, [1]] + np.arange(6)], axis=1
    )
    rows = np.repeat(element_dofs, 12, axis=1).ravel()
    cols = np.tile(element_dofs, (1, 12)).ravel()
    return rows, cols


def _stiffness_terms(design: Design, element_terms, lengths, rotation):
    """Stiffness: one unit global matrix per element and term, scaled per parameter (K = Σ_p p·K_p).

    Returns the coefficient of every term per element and parameter key, the parameters' current
    values and the unit global element matrices (n_elements, 4, 12, 12)."""
    parameter_values: dict[str, float] = {}
    coefficients: dict[str, np.ndarray] = {}
    for e, terms in enumerate(element_terms):
        for key, term, factor in terms:
            if key not in coefficients:
                coefficients[key] = np.zeros((len(element_terms), 4))
                table, name, attribute = key.split(".")
                parameter_values[key] = float(getattr(getattr(design, table)[name], attribute))
            coefficients[key][e, _TERM_INDEX[term]] += factor
    local_terms = beam.local_stiffness_terms(lengths)
    global_terms = np.stack([beam.to_global(local_terms[t], rotation) for t in beam.STIFFNESS_TERMS], axis=1)
    return coefficients, parameter_values, global_terms


def _lumped_masses(design: Design, node_names: list[str], node_index: dict[str, int], n_bar: int):
    """The node and point masses lumped at the node centres, and their list for the export."""
    nodes = design.nodes
    lumped_rows, lumped_values, lumped = [], [], []
    for name in node_names:
        node = nodes[name]
        if node.type is None:
            continue
        node_type = design.node_types[node.type]
        i = node_index[name]
        lumped_rows += list(range(6 * i, 6 * i + 6))
        lumped_values += [node_type.mass] * 3 + [node_type.inertia] * 3
        lumped.append(
            {"node": name, "mass": node_type.mass, "inertia": node_type.inertia, "source": f"node_types.{node.type}"}
        )
    for point_mass in design.point_masses:
        i = node_index[point_mass.node]
        lumped_rows += list(range(6 * i, 6 * i + 6))
        lumped_values += [point_mass.mass] * 3 + [point_mass.inertia] * 3
        lumped.append(
            {"node": point_mass.node, "mass": point_mass.mass, "inertia": point_mass.inertia, "source": "point_masses"}
        )
    return sp.coo_matrix((lumped_values, (lumped_rows, lumped_rows)), shape=(n_bar, n_bar)).tocsr(), lumped


def _constraint_matrix(design: Design, mesh: Mesh, points_array, node_names, node_index, active_joints):
    """S of z̄ = S·z (Eq. 4) over the independent DOFs, with the label of every z, the rigid
    links (for the export) and Ē, the action–reaction pair of each joint force."""
    seat_points = {point: (node, axis, key) for key, (point, node, axis) in mesh.seats.items()}
    column, labels, joint_column = _independent_dofs(
        design, node_names, node_index, mesh.point_names, len(mesh.points), seat_points, active_joints
    )
    S, rigid_links, joint_pairs = _constraints(
        points_array, mesh.point_names, node_names, seat_points, column, labels, active_joints, joint_column
    )
    return S, labels, rigid_links, joint_pairs


def _independent_dofs(design: Design, node_names, node_index, point_names, n_points, seat_points, active_joints):
    """Independent DOFs: free node-centre DOFs, beam nodes that are not seats, joint DOFs.

    Returns the column of z per unconstrained DOF (−1: none), the label of every z and the
    column of each joint DOF by (member, end)."""
    supported = np.zeros((len(node_names), 6), dtype=bool)
    for support in design.supports:
        for dof in support.dofs:
            supported[node_index[support.node], DOF_NAMES.index(dof)] = True
    column = np.full(6 * n_points, -1, dtype=np.int64)
    labels: list[tuple[str, str]] = []
    for i, name in enumerate(node_names):
        for d in range(6):
            if not supported[i, d]:
                column[6 * i + d] = len(labels)
                labels.append((name, DOF_NAMES[d]))
    for p in range(len(node_names), n_points):
        if p in seat_points:
            continue
        for d in range(6):
            column[6 * p + d] = len(labels)
            labels.append((point_names[p], DOF_NAMES[d]))
    joint_column = {}
    for joint in active_joints:
        joint_column[(joint.member, joint.end)] = len(labels)
        labels.append((joint.name, "slip" if joint.type == "A" else "rotation"))
    return column, labels, joint_column


def _constraints(points_array, point_names, node_names, seat_points, column, labels, active_joints, joint_column):
    """S of z̄ = S·z (Eq. 4): seats move with their node, released joints add their DOF; with the
    rigid links (for the export) and Ē, the action–reaction pair of each joint force."""
    n_bar = column.size
    n_dof = len(labels)
    s_rows, s_cols, s_vals = [], [], []

    def tie(row: int, col: int, value: float) -> None:
        if col >= 0 and value != 0.0:
            s_rows.append(row)
            s_cols.append(col)
            s_vals.append(value)

    for i in range(n_bar):
        if column[i] >= 0:
            tie(i, column[i], 1.0)
    rigid_links = []
    joint_pairs = np.zeros((n_bar, len(active_joints)))
    joint_lookup = {(j.member, j.end): (k, j) for k, j in enumerate(active_joints)}
    for point, (node, axis, key) in seat_points.items():
        offset = points_array[point] - points_array[node]
        # u_p = u_n + θ_n × r  →  ∂u_p/∂θ_n = −skew(r)
        cross = -_skew(offset)
        for a in range(3):
            tie(6 * point + a, column[6 * node + a], 1.0)
            tie(6 * point + 3 + a, column[6 * node + 3 + a], 1.0)
            for b in range(3):
                tie(6 * point + a, column[6 * node + 3 + b], cross[a, b])
        link = {"point": point_names[point], "node": node_names[node], "offset": offset.tolist(), "release": None}
        if key in joint_lookup:
            k, joint = joint_lookup[key]
            q = joint_column[key]
            if joint.type == "A":
                direction, block = axis, 0
            else:
                direction, block = np.array(joint.axis), 3
            for a in range(3):
                tie(6 * point + block + a, q, float(direction[a]))
            # Ē: the joint force pair, on the seat and (reaction) on the node centre.
            joint_pairs[6 * point + block : 6 * point + block + 3, k] = direction
            joint_pairs[6 * node + block : 6 * node + block + 3, k] -= direction
            if block == 0:
                joint_pairs[6 * node + 3 : 6 * node + 6, k] -= np.cross(offset, direction)
            link["release"] = {"joint": joint.name, "type": joint.type, "direction": direction.tolist()}
        rigid_links.append(link)
    return sp.csr_matrix((s_vals, (s_rows, s_cols)), shape=(n_bar, n_dof)), rigid_links, joint_pairs


def _inputs_outputs(design: Design, node_index, S, St, joint_pairs, active_joints):
    """E = SᵀĒ (joints), F = SᵀF̄ (disturbances), V and W (displacement and velocity sensors)."""
    n_bar, n_dof = S.shape
    E = np.asarray(St @ joint_pairs) if active_joints else np.zeros((n_dof, 0))
    F_bar = np.zeros((n_bar, len(design.disturbances)))
    for k, disturbance in enumerate(design.disturbances):
        i = node_index[disturbance.node]
        F_bar[6 * i : 6 * i + 6, k] = disturbance.direction
    F = np.asarray(St @ F_bar)
    V = np.zeros((len(design.sensors), n_dof))
    W = np.zeros((len(design.sensors), n_dof))
    for k, sensor in enumerate(design.sensors):
        i = node_index[sensor.node]
        row = np.asarray(S[6 * i : 6 * i + 6].T @ np.array(sensor.direction)).ravel()
        (V if sensor.quantity == "displacement" else W)[k] = row
    return E, F, V, W


def _skew(r: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])


def _element_properties(coefficients, values, masses) -> np.ndarray:
    n = masses.shape[0]
    stiffness = np.zeros((n, 4))
    for key, coefficient in coefficients.items():
        stiffness += coefficient * values[key]
    # Columns: EA, EI_y, EI_z, GJ, ρA, ρI_p
    order = [_TERM_INDEX["axial"], _TERM_INDEX["bending_y"], _TERM_INDEX["bending_z"], _TERM_INDEX["torsion"]]
    return np.column_stack([stiffness[:, order], masses])


def check_supported(model: FEModel) -> None:
    """Refuse a structure whose stiffness matrix has zero-energy motions (rigid-body modes).

    The lowest modes are solved and each is judged against its own energy scale
    (:func:`~smartjoint.design.structure.modal.zero_energy`): a motion whose ω² is round-off of its gross
    strain energy costs no energy. A slender but supported mast passes however low its first
    mode (a 1000-bay mast: 0.6 mHz); the largest DOF of the first such motion says where the
    structure is loose.

    Parameters
    ----------
    model : FEModel
        The assembled model.

    Raises
    ------
    ModelError
        Naming the count of such motions and where the first sits.
    """
    from smartjoint.design.structure.modal import count_zero_energy_modes

    count, where = count_zero_energy_modes(model)
    if count:
        raise ModelError(
            f"{model.design.source}: structure has {count} zero-energy (rigid-body or mechanism) "
            f"motion(s), e.g. at {where}; add supports or lock the joints that free it"
        )


__all__ = ["build_model", "check_supported", "FEModel"]
