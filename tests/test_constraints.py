"""The constraint formulation of Eq. 4: rigid nodes, supports and joint DOFs are exact."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from conftest import ALUMINIUM, TUBE, small_truss

from smartjoint.design import build_model, parse_design
from smartjoint.design.structure import beam
from smartjoint.design.structure.modal import eigensolve

pytestmark = pytest.mark.numerics  # run again by the portability leg (.ci/portability)

ARMS = [[1.0, 0.0, 0.0], [0.0, 1.2, 0.0], [0.3, 0.4, 0.9]]


def _star(seat_radius: float, clamp: bool = True, joints=(), node_mass: float = 0.0) -> dict:
    """Three members from a centre node C to clamped (or free) feet along ARMS."""
    design = {
        "name": "star",
        "materials": {"aluminium": dict(ALUMINIUM)},
        "sections": {"tube": dict(TUBE)},
        "node_types": {"ball": {"mass": node_mass, "seat_radius": seat_radius, "inertia": node_mass * 1e-4}},
        "nodes": [{"name": "C", "position": [0.0, 0.0, 0.0], "type": "ball"}]
        + [{"name": f"F{k}", "position": arm} for k, arm in enumerate(ARMS)],
        "members": [
            {"name": f"M{k}", "start": "C", "end": f"F{k}", "section": "tube", "elements": 3} for k in range(len(ARMS))
        ],
        "joints": list(joints),
    }
    if clamp:
        design["supports"] = [{"node": f"F{k}", "dofs": "all"} for k in range(len(ARMS))]
    return design


def _merged_frequencies(count: int) -> np.ndarray:
    """The same star assembled by hand with the members sharing one beam node at C."""
    section_area = np.pi / 4 * (0.022**2 - 0.019**2)
    second = np.pi / 64 * (0.022**4 - 0.019**4)
    E, G, rho = ALUMINIUM["youngs_modulus"], ALUMINIUM["shear_modulus"], ALUMINIUM["density"]
    points = [np.zeros(3)]
    elements = []
    for arm in ARMS:
        previous = 0  # every arm starts at the shared centre point
        for k in range(1, 4):
            points.append(np.array(arm) * k / 3)
            elements.append((previous, len(points) - 1))
            previous = len(points) - 1
    points = np.array(points)
    a = np.array([e[0] for e in elements])
    b = np.array([e[1] for e in elements])
    length, rotation = beam.element_frames(points[a], points[b])
    k_local = beam.local_stiffness_terms(length)
    m_local = beam.local_mass_terms(length)
    ke = beam.to_global(
        E * section_area * k_local["axial"]
        + G * 2 * second * k_local["torsion"]
        + E * second * (k_local["bending_y"] + k_local["bending_z"]),
        rotation,
    )
    me = beam.to_global(rho * section_area * m_local["translation"] + rho * 2 * second * m_local["torsion"], rotation)
    n = 6 * len(points)
    K = np.zeros((n, n))
    M = np.zeros((n, n))
    for e, (i, j) in enumerate(elements):
        dofs = np.r_[6 * i : 6 * i + 6, 6 * j : 6 * j + 6]
        K[np.ix_(dofs, dofs)] += ke[e]
        M[np.ix_(dofs, dofs)] += me[e]
    feet = [3, 6, 9]
    keep = np.setdiff1d(np.arange(n), np.concatenate([np.arange(6 * f, 6 * f + 6) for f in feet]))
    values, _ = eigensolve(sp.csr_matrix(K[np.ix_(keep, keep)]), sp.csr_matrix(M[np.ix_(keep, keep)]), count)
    return np.sqrt(values)


def test_rigid_node_equals_merged_nodes():
    model = build_model(parse_design(_star(seat_radius=0.0)))
    values, _ = eigensolve(model.stiffness, model.mass, 12)
    np.testing.assert_allclose(np.sqrt(values), _merged_frequencies(12), rtol=1e-10)


def test_rigid_offsets_carry_rigid_body_motion_exactly():
    model = build_model(parse_design(_star(seat_radius=0.05, clamp=False)), allow_mechanisms=True)
    # Six rigid-body motions of the free star, written in the independent DOFs z (node C and
    # every interior beam node): the offset constraints must make them strain-free.
    rigid = np.zeros((model.n_dof, 6))
    for index, (point, dof) in enumerate(model.dof_labels):
        position = model.points[model.point_names.index(point)]
        d = "xyz".index(dof[1])
        if dof[0] == "u":
            rigid[index, d] = 1.0
            rotation_part = np.cross(np.eye(3), position)[:, d]  # (θ × r)_d for unit θ along each axis
            rigid[index, 3:] = rotation_part
        else:
            rigid[index, 3 + d] = 1.0
    K = model.stiffness
    residual = np.abs(K @ rigid).max() / abs(K).max()
    assert residual < 1e-12
    values, _ = eigensolve(K, model.mass, 8)
    assert np.sum(values < 1e-4) == 6


def test_released_joint_adds_exactly_one_zero_energy_direction():
    for joint in (
        {"name": "J", "member": "M0", "end": "start", "type": "A"},
        {"name": "J", "member": "M1", "end": "start", "type": "B", "axis": [0.0, 0.0, 1.0]},
    ):
        # One member alone, free in space: 6 rigid-body modes; its joint end released: 7.
        design = _star(seat_radius=0.05, clamp=False, joints=[joint], node_mass=0.2)
        design["members"] = [m for m in design["members"] if m["name"] == joint["member"]]
        design["nodes"] = [n for n in design["nodes"] if n["name"] in ("C", "F" + joint["member"][1])]
        locked = build_model(parse_design(design), joints="locked", allow_mechanisms=True)
        released = build_model(parse_design(design), joints="released", allow_mechanisms=True)
        assert released.n_dof == locked.n_dof + 1
        count_locked = np.sum(eigensolve(locked.stiffness, locked.mass, 10)[0] < 1e-4)
        count_released = np.sum(eigensolve(released.stiffness, released.mass, 10)[0] < 1e-4)
        assert (count_locked, count_released) == (6, 7)


def test_joint_matrix_is_the_unit_vector_of_the_joint_dof():
    model = build_model(parse_design(small_truss()), joints="released")
    assert model.E.shape == (model.n_dof, 2)
    for k, name in enumerate(model.joint_names):
        index = [i for i, label in enumerate(model.dof_labels) if label[0] == name]
        expected = np.zeros(model.n_dof)
        expected[index] = 1.0
        np.testing.assert_allclose(model.E[:, k], expected, atol=1e-14)  # E = SᵀĒ (Eq. 4)


def test_released_joints_lower_the_spectrum_and_keep_it_supported():
    design = parse_design(small_truss())
    locked = eigensolve(build_model(design, joints="locked").stiffness, build_model(design, joints="locked").mass, 10)[
        0
    ]
    released_model = build_model(design, joints="released")
    released = eigensolve(released_model.stiffness, released_model.mass, 10)[0]
    # Releasing a DOF removes a constraint: every eigenvalue can only go down (interlacing).
    assert np.all(released <= locked * (1 + 1e-10))
    assert released[0] > 1.0


def test_outputs_and_disturbances_select_the_tip_node():
    model = build_model(parse_design(small_truss()))
    tip_uy = model.dof_labels.index(("TIP", "uy"))
    tip_uz = model.dof_labels.index(("TIP", "uz"))
    assert model.F[:, 0].nonzero()[0].tolist() == [tip_uy]
    assert model.V[0].nonzero()[0].tolist() == [tip_uy] and not model.W[0].any()
    assert model.W[1].nonzero()[0].tolist() == [tip_uz] and not model.V[1].any()


def test_mass_matrix_carries_the_total_mass():
    design = parse_design(small_truss())
    design_free = {**small_truss(), "truss": {**small_truss()["truss"], "clamp_root": False}}
    model = build_model(parse_design(design_free), allow_mechanisms=True)
    translation = np.zeros(model.n_dof)
    for index, (_point, dof) in enumerate(model.dof_labels):
        if dof == "ux":
            translation[index] = 1.0
    assert abs(translation @ model.mass @ translation - model.total_mass) < 1e-9 * model.total_mass
    assert model.total_mass > 0 and design.name == "small"
