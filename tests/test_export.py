"""The neutral model format rebuilds the same model, independently of smartjoint's assembly."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.linalg
from conftest import run_cli, small_truss

from smartjoint.design import build_model, parse_design
from smartjoint.design.structure import beam
from smartjoint.design.structure.export import export_model
from smartjoint.design.structure.modal import eigensolve

pytestmark = pytest.mark.numerics  # run again by the portability leg (.ci/portability)


def _rebuild(document: dict) -> tuple[np.ndarray, np.ndarray]:
    """A minimal FE code reading only the JSON: assemble, tie rigid links, drop supports."""
    points = np.array([p["position"] for p in document["points"]])
    names = [p["name"] for p in document["points"]]
    n_bar = 6 * len(points)
    K = np.zeros((n_bar, n_bar))
    M = np.zeros((n_bar, n_bar))
    for element in document["elements"]:
        a, b = element["points"]
        length, rotation = beam.element_frames(points[[a]], points[[b]], np.array([element["local_y"]]))
        k = beam.local_stiffness_terms(length)
        m = beam.local_mass_terms(length)
        ke = beam.to_global(
            element["EA"] * k["axial"]
            + element["GJ"] * k["torsion"]
            + element["EIy"] * k["bending_y"]
            + element["EIz"] * k["bending_z"],
            rotation,
        )[0]
        me = beam.to_global(
            element["mass_per_length"] * m["translation"] + element["polar_inertia_per_length"] * m["torsion"], rotation
        )[0]
        dofs = np.r_[6 * a : 6 * a + 6, 6 * b : 6 * b + 6]
        K[np.ix_(dofs, dofs)] += ke
        M[np.ix_(dofs, dofs)] += me
    for lumped in document["lumped_masses"]:
        i = names.index(lumped["node"])
        M[6 * i : 6 * i + 3, 6 * i : 6 * i + 3] += lumped["mass"] * np.eye(3)
        M[6 * i + 3 : 6 * i + 6, 6 * i + 3 : 6 * i + 6] += lumped["inertia"] * np.eye(3)
    # Constraint matrix: every rigid link's point follows its node; a release adds a DOF.
    dependent = {names.index(link["point"]) for link in document["rigid_links"]}
    fixed = {
        6 * names.index(s["node"]) + document["dof_order"].index(d) for s in document["supports"] for d in s["dofs"]
    }
    columns = [d for p in range(len(points)) if p not in dependent for d in range(6 * p, 6 * p + 6) if d not in fixed]
    releases = [link for link in document["rigid_links"] if link["release"]]
    S = np.zeros((n_bar, len(columns) + len(releases)))
    S[columns, np.arange(len(columns))] = 1.0
    for link in document["rigid_links"]:
        p, n = names.index(link["point"]), names.index(link["node"])
        r = np.array(link["offset"])
        S[6 * p : 6 * p + 6] = S[6 * n : 6 * n + 6]
        S[6 * p : 6 * p + 3] += np.cross(S[6 * n + 3 : 6 * n + 6].T, r).T  # u_p = u_n + θ_n × r
    for k, link in enumerate(releases):
        p = names.index(link["point"])
        block = 0 if link["release"]["type"] == "A" else 3
        S[6 * p + block : 6 * p + block + 3, len(columns) + k] = link["release"]["direction"]
    return S.T @ K @ S, S.T @ M @ S


def test_export_rebuilds_the_same_frequencies():
    """The JSON alone rebuilds our eigenvalues to within the rounding of the eigen solution.

    Both sides are backward-stable solutions of the same K φ = ω² M φ, so each ω²_i carries an
    error of order ε·ω²_max (the LAPACK bound for the symmetric-definite problem, ε·‖K‖‖M⁻¹‖),
    whatever the machine. Relative to the lowest ω² of the released model that is ~1e-9 (the
    stiff connectors put ω²_max at 7e10 (rad/s)²) and the last bits of the solvers differ per
    CPU, so a fixed relative tolerance would encode one machine. Ten times the bound is still
    far below any export error (a wrong EA, mass or offset moves ω² by percents)."""
    for joints in ("locked", "released"):
        model = build_model(parse_design(small_truss()), joints=joints)
        document = json.loads(json.dumps(export_model(model)))
        K, M = _rebuild(document)
        assert K.shape[0] == model.n_dof
        rebuilt = scipy.linalg.eigh(K, M, eigvals_only=True, subset_by_index=[0, 19])
        ours, _ = eigensolve(model.stiffness, model.mass, 20)
        largest = scipy.linalg.eigh(K, M, eigvals_only=True, subset_by_index=[K.shape[0] - 1] * 2)[0]
        rounding = 10.0 * np.finfo(float).eps * largest
        assert rounding < 1e-6 * ours[0]  # the bound is far below what an export error would show
        np.testing.assert_allclose(rebuilt, ours, rtol=0.0, atol=rounding)


def test_export_model_command(tmp_path):
    target = tmp_path / "model.json"
    done = run_cli("export-model", "--no-update", "-o", target, "--json")
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    document = json.loads(target.read_text())
    assert document["schema"] == "smartjoint-model/1"
    assert summary["elements"] == len(document["elements"]) == 744
    assert not list(tmp_path.glob("*.partial"))
