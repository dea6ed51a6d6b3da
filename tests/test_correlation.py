"""Measured mode shapes (issue 18): the MAC, pairing by MAC with swaps warned, updating with
shapes, effective modal masses, and the design file's EMA shapes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import beam_design, small_truss

from smartjoint.common.errors import DesignError
from smartjoint.design import build_model, parse_design, solve_modes, update_model
from smartjoint.design.structure.correlation import (
    ModeSwapWarning,
    correlate,
    measurement_matrix,
    modal_assurance_criterion,
    pair_modes,
)
from smartjoint.design.structure.description import DOF_NAMES, MeasuredDof, MeasuredMode, Updating
from smartjoint.design.structure.participation import effective_modal_mass, rigid_body_translation

PARAMETERS = ("connectors.c.axial_stiffness", "connectors.c.bending_stiffness", "materials.aluminium.youngs_modulus")
# FE modes 7 and 8 of the small truss lie 0.2 % apart (60.17 and 60.30 Hz) with MAC 0 between them.
MEASURED = (1, 3, 4, 5, 6, 7, 8)
SWAPPED = {7: 8, 8: 7}  # the EMA numbers them the other way round


def _unit(dof: str) -> tuple[float, ...]:
    return tuple(float(d == dof) for d in DOF_NAMES)


def _survey_dofs(design) -> tuple[MeasuredDof, ...]:
    """Every DOF of every free node centre (the 2-bay truss has few nodes: rotations count too)."""
    return tuple(MeasuredDof(n, _unit(dof)) for n in design.nodes if not n.startswith("N0_") for dof in DOF_NAMES)


def _swapped_survey(truth: dict[str, float], noise: float = 0.02, mac_weight: float = 0.0):
    """The small truss with a synthetic EMA of the truss at ``truth``: shapes plus noise, modes 7/8 swapped."""
    design = parse_design(small_truss())
    dofs = _survey_dofs(design)
    model = build_model(design.with_parameters(truth), joints="locked")
    modes = solve_modes(model, max(MEASURED))
    shapes = measurement_matrix(model, dofs) @ modes.shapes
    rng = np.random.default_rng(18)
    measured = []
    for number in MEASURED:
        source = SWAPPED.get(number, number) - 1
        shape = shapes[:, source] + noise * np.abs(shapes[:, source]).max() * rng.standard_normal(len(dofs))
        measured.append(MeasuredMode(number, float(modes.frequencies_hz[source]), None, tuple(-2.5 * shape)))
    updating = Updating(PARAMETERS, tuple(measured), (10.0,) * 3, dofs, mac_weight)
    return dataclasses.replace(design, updating=updating), shapes


def test_mac_of_a_shape_with_itself_is_one_and_ignores_scaling_and_sign():
    rng = np.random.default_rng(1)
    phi, psi = rng.standard_normal((12, 1)), rng.standard_normal((12, 1))
    assert modal_assurance_criterion(phi, phi)[0, 0] == pytest.approx(1.0)
    base = modal_assurance_criterion(phi, psi)[0, 0]
    for scale in (-1.0, 3.7, -1e-6, 1e6):
        assert modal_assurance_criterion(scale * phi, psi)[0, 0] == pytest.approx(base, rel=1e-12)
        assert modal_assurance_criterion(phi, scale * psi)[0, 0] == pytest.approx(base, rel=1e-12)
    orthogonal = np.eye(12)[:, :3]
    np.testing.assert_allclose(modal_assurance_criterion(orthogonal, orthogonal), np.eye(3), atol=1e-15)
    assert modal_assurance_criterion(phi, np.zeros((12, 1)))[0, 0] == 0.0  # no motion: no correlation


@pytest.mark.numerics
def test_mass_orthogonal_modes_have_low_mac_at_the_measured_dofs():
    design = parse_design(small_truss())
    model = build_model(design, joints="locked")
    modes = solve_modes(model, 10)
    restricted = measurement_matrix(model, _survey_dofs(design)) @ modes.shapes
    mac = modal_assurance_criterion(restricted, restricted)
    np.testing.assert_allclose(np.diag(mac), 1.0, rtol=1e-12)
    assert np.max(mac - np.diag(np.diag(mac))) < 0.5  # restricted to 54 DOFs, no longer exactly orthogonal
    assert mac[6, 7] < 1e-3  # the close pair 7/8 is told apart by its shapes


@pytest.mark.numerics
def test_pairing_by_mac_recovers_swapped_close_modes():
    design, _ = _swapped_survey({})
    model = build_model(design, joints="locked")
    modes = solve_modes(model, 10)
    correlation = correlate(
        design.updating, measurement_matrix(model, design.updating.measured_dofs) @ modes.shapes, modes.frequencies_hz
    )
    assert correlation.fe_modes.tolist() == [1, 3, 4, 5, 6, 8, 7]
    assert np.all(correlation.diagonal > 0.99), correlation.diagonal
    assert len(correlation.swaps) == 2
    assert "measured mode 7 pairs with FE mode 8" in correlation.swaps[0]
    assert "measured mode 8 pairs with FE mode 7" in correlation.swaps[1]


def test_pairing_breaks_a_mac_tie_by_frequency():
    mac = np.array([[0.9, 0.9], [0.2, 0.2]])
    assert pair_modes(mac, np.array([10.0, 20.0]), np.array([10.1, 19.0])).tolist() == [0, 1]
    assert pair_modes(mac, np.array([19.5, 10.0]), np.array([10.1, 19.0])).tolist() == [1, 0]


@pytest.mark.numerics
def test_updating_with_shapes_pairs_by_mac_and_warns_the_swap():
    truth = {
        "connectors.c.axial_stiffness": 2.0e6,
        "connectors.c.bending_stiffness": 1500.0,
        "materials.aluminium.youngs_modulus": 66.0e9,
    }
    design, _ = _swapped_survey(truth)
    with pytest.warns(ModeSwapWarning) as record:
        result = update_model(build_model(design, joints="locked"))
    messages = [str(w.message) for w in record]
    assert any("measured mode 7 pairs with FE mode 8" in m for m in messages), messages
    assert any("measured mode 8 pairs with FE mode 7" in m for m in messages), messages
    assert result.correlation is not None and result.initial_correlation is not None
    assert result.correlation.fe_modes.tolist() == [1, 3, 4, 5, 6, 8, 7]
    assert np.max(np.abs(result.error_pct)) < 1e-6
    for name, value in truth.items():
        assert result.parameters[name] == pytest.approx(value, rel=1e-4)
    summary = result.as_dict()["correlation"]
    assert [p["fe_mode"] for p in summary["updated"]["pairing"]] == [1, 3, 4, 5, 6, 8, 7]
    assert len(summary["updated"]["mac_matrix"]) == len(MEASURED)


def test_effective_masses_add_up_to_the_free_mass():
    for joints in ("locked", "released"):
        model = build_model(parse_design(small_truss()), joints=joints)
        modes = solve_modes(model, model.n_dof)
        participation = effective_modal_mass(model, modes.shapes)
        assert np.all(participation.effective_mass >= 0.0)
        np.testing.assert_allclose(participation.effective_mass.sum(axis=0), participation.free_mass, rtol=1e-9)
        np.testing.assert_allclose(participation.cumulative_fraction[-1], 1.0, rtol=1e-9)
        # r is the rigid translation of every free point: S·r moves each by one along its axis.
        motion = (model.S @ rigid_body_translation(model)).reshape(-1, 6, 3)
        assert set(np.unique(motion[:, :3, :])) <= {0.0, 1.0} and not motion[:, 3:, :].any()
        assert participation.free_mass.max() < model.total_mass  # the clamped root nodes do not move


def test_effective_mass_of_a_clamped_tube_is_analytical():
    """A clamped tube of n consistent elements: the free mass is ρAL less the mass-matrix entries
    of the clamped end, 2/3 of one element axially and 22/35 of one transversally."""
    n, length = 10, 2.0
    design = parse_design(beam_design(length, n))
    model = build_model(design, joints="locked")
    participation = effective_modal_mass(model, solve_modes(model, model.n_dof).shapes)
    section = design.sections["tube"]
    total = section.area * design.materials["aluminium"].density * length
    expected = [total - 2.0 / 3.0 * total / n] + [total - 22.0 / 35.0 * total / n] * 2
    np.testing.assert_allclose(participation.effective_mass.sum(axis=0), expected, rtol=1e-9)


def _with_updating(**updating):
    data = small_truss()
    data["updating"] = {"parameters": list(PARAMETERS), **updating}
    return data


def _one_dof(node: str = "TIP", direction="uy", shape=(1.0,)) -> dict:
    """[updating] with one measured DOF and one measured mode of that shape."""
    return {
        "measured_dofs": [{"node": node, "direction": direction}],
        "measured": [{"mode": 1, "frequency_hz": 30.0, "shape": list(shape)}],
    }


@pytest.mark.parametrize(
    ("updating", "key", "says"),
    [
        ({"measured": [{"mode": 1, "frequency_hz": 30.0, "shape": [1.0]}]}, "measured[0].shape", "measured_dofs"),
        (
            {"measured_dofs": [{"node": "TIP", "direction": "uy"}], "measured": [{"mode": 1, "frequency_hz": 30.0}]},
            "measured[0].shape",
            "required with updating.measured_dofs",
        ),
        (_one_dof(shape=[1.0, 2.0]), "measured[0].shape", "list of 1 finite numbers"),
        (_one_dof(shape=[0.0]), "measured[0].shape", "all zeros"),
        (_one_dof(shape=["a"]), "measured[0].shape", "finite numbers"),
        (_one_dof(node="NOPE"), "measured_dofs[0].node", "no node of that name"),
        (
            {
                "measured_dofs": [{"node": "TIP", "direction": "uy"}, {"node": "TIP", "direction": [0, 2, 0]}],
                "measured": [{"mode": 1, "frequency_hz": 30.0, "shape": [1.0, 1.0]}],
            },
            "measured_dofs[1].direction",
            "the same DOF as measured_dofs[0]",
        ),
        (_one_dof(direction="up"), "measured_dofs[0].direction", "allowed: ux"),
        ({"mac_weight": 1.0, "measured": [{"mode": 1, "frequency_hz": 30.0}]}, "mac_weight", "needs EMA shapes"),
        ({"measured_dofs": [], "measured": [{"mode": 1, "frequency_hz": 30.0}]}, "measured_dofs", "1 … 10000"),
    ],
)
def test_bad_ema_shapes_are_one_line_errors(updating, key, says):
    with pytest.raises(DesignError) as error:
        parse_design(_with_updating(**updating))
    message = str(error.value)
    assert "\n" not in message
    assert f"updating.{key}:" in message and says in message, message


def test_ema_shapes_are_read():
    design = parse_design(
        _with_updating(
            measured_dofs=[{"node": "TIP", "direction": "uy"}, {"node": "N2_0", "direction": [0.0, 0.0, 2.0]}],
            measured=[{"mode": 1, "frequency_hz": 30.0, "shape": [1.0, -0.5]}],
            mac_weight=0.5,
        )
    )
    updating = design.updating
    assert updating.has_shapes and updating.mac_weight == 0.5
    assert updating.measured[0].shape == (1.0, -0.5)
    assert updating.measured_dofs[1] == MeasuredDof("N2_0", (0.0, 0.0, 1.0, 0.0, 0.0, 0.0))


def _design_file(tmp_path, design_dict: dict, updating) -> str:
    """``design_dict`` with ``updating`` (an Updating with shapes) written as a design file."""
    import tomli_w

    data = dict(design_dict)
    data["updating"] = {
        "parameters": list(updating.parameters),
        "measured_dofs": [
            {"node": d.node, "direction": DOF_NAMES[d.direction.index(1.0)]} for d in updating.measured_dofs
        ],
        "measured": [
            {"mode": m.mode, "frequency_hz": m.frequency_hz, "shape": list(m.shape)} for m in updating.measured
        ],
    }
    path = tmp_path / "surveyed.toml"
    path.write_text(tomli_w.dumps(data))
    return str(path)


@pytest.mark.numerics
def test_modes_json_has_effective_masses_and_the_mac_pairing(tmp_path, capsys):
    import json

    from smartjoint.cli import main

    design, _ = _swapped_survey({})
    path = _design_file(tmp_path, small_truss(), design.updating)
    assert main(["modes", path, "--no-update", "-n", "8", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    first = out["modes"][0]
    assert set(first["effective_mass_kg"]) == {"x", "y", "z"}
    assert set(first["participation_factor"]) == set(first["cumulative_effective_mass_fraction"]) == {"x", "y", "z"}
    for d in "xyz":
        shares = [m["cumulative_effective_mass_fraction"][d] for m in out["modes"]]
        assert shares == sorted(shares) and 0.0 <= shares[-1] <= 1.0 + 1e-12
        assert first["effective_mass_kg"][d] == pytest.approx(first["participation_factor"][d] ** 2)
    assert [p["fe_mode"] for p in out["mac"]["pairing"]] == [1, 3, 4, 5, 6, 8, 7]
    assert len(out["mac"]["swaps"]) == 2


def test_mac_plot_is_written(tmp_path):
    from smartjoint.design.structure.correlation import ModeCorrelation
    from smartjoint.report import plot_mac

    mac = np.array([[0.98, 0.01, 0.0], [0.02, 0.1, 0.95]])
    correlation = ModeCorrelation(
        np.array([1, 2]), np.array([4.5, 20.6]), np.array([1, 3]), np.array([4.4, 19.0, 21.0]), mac, []
    )
    plot_mac(correlation, tmp_path / "mac.png")
    assert (tmp_path / "mac.png").stat().st_size > 1000


@pytest.mark.numerics
def test_the_run_report_shows_the_mac_table_and_matrix(tmp_path, capsys):
    """`smartjoint run` on the surveyed truss (without joints: the run ends after the structure):
    the report pairs the EMA by MAC like Fig. 7, warns the swap and draws the MAC matrix."""
    import json

    from smartjoint.cli import main

    truth = {"connectors.c.axial_stiffness": 2.0e6}
    design, _ = _swapped_survey(truth)
    bare = {k: v for k, v in small_truss().items() if k != "joints"}
    path = _design_file(tmp_path, bare, design.updating)
    assert main(["run", path, "-o", str(tmp_path / "report"), "--json"]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert [p["fe_mode"] for p in summary["updating"]["correlation"]["updated"]["pairing"]] == [1, 3, 4, 5, 6, 8, 7]
    assert "measured mode 7 pairs with FE mode 8" in captured.err + captured.out
    report = (tmp_path / "report" / "report.md").read_text()
    assert "MAC pairing of the EMA shapes" in report and "![MAC](mac.png)" in report
    assert (tmp_path / "report" / "mac.png").stat().st_size > 0
