"""Mode selection independent of the channels' units (Eq. 17–18, issue 18)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from smartjoint.design import reduction
from smartjoint.design.structure import modal
from smartjoint.design.structure.fem import build_model
from smartjoint.design.structure.spec import parse_design

pytestmark = pytest.mark.numerics  # run again by the portability leg (.ci/portability)

MILLI = 1000.0  # rad → mrad, m/s → mm/s: the column (row) of E (V, W) in the new unit


@pytest.fixture(scope="module")
def considered():
    """The first 30 modes of the small truss: joint JA of type A, JB of type B (about y),
    sensors tip_y (displacement) and tip_vz (velocity)."""
    from conftest import small_truss

    fe = build_model(parse_design(small_truss()), joints="released")
    return modal.modal_model(fe, modal.solve_modes(fe, 30))


def in_milli_units(model: modal.ModalModel) -> modal.ModalModel:
    """The same model with JB's rotation in mrad (torque in N·mm… its column of E × 1000) and
    tip_vz in mm/s (its row of W × 1000)."""
    joint_input = model.joint_input.copy()
    joint_input[:, model.joint_names.index("JB")] *= MILLI
    velocity_output = model.velocity_output.copy()
    velocity_output[model.sensor_names.index("tip_vz")] *= MILLI
    return dataclasses.replace(model, joint_input=joint_input, velocity_output=velocity_output)


def summed_selection(model: modal.ModalModel, n_keep: int) -> np.ndarray:
    """The former score: gramians summed over the channels in their own units."""
    w, xi = model.omega, model.damping
    control_u = np.sum(model.joint_input**2, axis=1) / (4 * xi * w)
    control_w = np.sum(model.disturbance_input**2, axis=1) / (4 * xi * w)
    observe_y = (w**2 * np.sum(model.velocity_output**2, axis=0) + np.sum(model.displacement_output**2, axis=0)) / (
        4 * xi * w**3
    )
    paths = [control_u, np.sqrt(control_w * observe_y), np.sqrt(control_u * observe_y), np.sqrt(control_w * control_u)]
    score = np.max([p / p.max() for p in paths], axis=0)
    return np.sort(np.argsort(-score, kind="stable")[:n_keep])


def test_the_selection_does_not_depend_on_the_units_of_a_joint_and_a_sensor(considered):
    milli = in_milli_units(considered)
    changed_before = []
    for n_keep in range(1, considered.n_coordinates + 1):
        for paths in (reduction.PATHS, ("uv",), ("wy",), ("uy",)):
            kept = reduction.select_modes(considered, n_keep, paths)
            assert np.array_equal(reduction.select_modes(milli, n_keep, paths), kept), (n_keep, paths)
        changed_before.append(not np.array_equal(summed_selection(milli, n_keep), summed_selection(considered, n_keep)))
    # The summed score this replaces did depend on them (JB weighs 10⁶ times more in mrad).
    assert sum(changed_before) >= 5
    scaled, plain = reduction.hankel_values(milli), reduction.hankel_values(considered)
    for path in reduction.PATHS:
        assert np.allclose(scaled[path], plain[path], rtol=1e-12, atol=0.0)


def test_channel_references_name_the_unit_and_scale_with_it(considered):
    references = {c.name: c for c in reduction.channel_references(considered)}
    assert [c.kind for c in reduction.channel_references(considered)] == [
        "joint",
        "joint",
        "disturbance",
        "sensor",
        "sensor",
    ]
    assert references["JA"].unit == "J/(s·N²)"
    assert references["JB"].unit == "J/(s·(N·m)²)"
    assert references["fy"].unit == "J/(s·N²)"
    assert references["tip_y"].unit == "m²·s/J"
    assert references["tip_vz"].unit == "(m/s)²·s/J"
    gramians = reduction.modal_gramians(considered)
    assert references["JB"].value == gramians["joint"][:, 1].max()
    assert references["JB"].mode == int(np.argmax(gramians["joint"][:, 1])) + 1
    milli = {c.name: c for c in reduction.channel_references(in_milli_units(considered))}
    assert milli["JB"].value == pytest.approx(MILLI**2 * references["JB"].value, rel=1e-12)
    assert milli["tip_vz"].value == pytest.approx(MILLI**2 * references["tip_vz"].value, rel=1e-12)
    assert milli["JA"].value == references["JA"].value


def test_a_model_without_units_still_ranks_per_channel(considered):
    bare = dataclasses.replace(considered, joint_units=[], sensor_units=[], disturbance_units=[])
    assert all(c.unit == "" for c in reduction.channel_references(bare))
    assert np.array_equal(reduction.select_modes(bare, 7), reduction.select_modes(considered, 7))
