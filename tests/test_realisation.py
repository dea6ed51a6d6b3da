"""The clipped LQG's realisation (control.realisation): the bundled design's mirror symmetry
found and used, an asymmetric design realised as it is (channels untouched), the real-Jordan
basis the same filter, and the generated C bit-identical to the reference either way."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from smartjoint.codegen import controllers
from smartjoint.design.control import artifact
from smartjoint.design.control.filter import clipped_lqg
from smartjoint.design.control.realisation import Channels, of_artifact

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def reference():
    return artifact.load(ROOT / "firmware" / "generated" / "controller.json")


def _realise(a):
    return of_artifact(a)


def _update_terms(r) -> int:
    """Multiply-adds of the update loops: E'·u twice, γ, M', Φ', C' (ones count), K' − K'M'C'."""
    total = 0
    for g in r.groups:
        per = 2 * len(g.joints) + 4 + 2 * len(g.sensors) + 4 + sum(len(c) for _, c in g.outputs)
        total += (g.stop - g.start) * (per + 2 * len(g.feedback_joints))
    return total


def test_the_bundled_design_is_realised_in_mirror_channels(reference):
    """Joints A1/A2 and the two tip sensors pair; the coordinates split into an odd group (the
    joints' difference, the sensors' sum) and an even one; the update needs far fewer terms."""
    r = _realise(reference)
    assert r.joints == Channels((0, 0, 2), (1, 1, -1), (1, -1, 1))
    assert r.sensors == Channels((0, 0), (1, 1), (1, -1))
    assert [(g.name, g.stop - g.start, g.joints, g.sensors) for g in r.groups] == [
        ("odd", 3, (1,), (0,)),
        ("even", 9, (0, 2), (1,)),
    ]
    assert r.rotation
    n, joints, sensors = len(reference.blocks), len(reference.joint_names), len(reference.sensor_names)
    dense = n * (4 * joints + 8 + 3 * sensors)  # the design's own: E twice, γ, Φ, M, one C term a sensor, K
    assert _update_terms(r) <= 0.7 * dense, (_update_terms(r), dense)


def test_a_coordinate_far_below_its_matrixs_scale_pairs_to_the_solvers_absolute_accuracy(reference):
    """The design's smallest Kalman gain row (a quasi-static correction coordinate's, about 1e-7 of
    the matrix's largest) mirrors only to the Riccati solver's absolute accuracy (about 1e-12 of that
    largest, 1e-5 of the row): the sensors still pair (SCALE_FLOOR), as the design needs; an
    asymmetry of the row's own size (1e-3 of it) breaks the pair."""
    m = np.asarray(reference.estimator_gain, dtype=float)
    top, rows = np.abs(m).max(), np.abs(m).max(axis=1)
    row = int(np.argmin(rows))
    assert rows[row] < 1e-6 * top  # the situation this test is about is the design's own
    solver = m.copy()
    solver[row, 0] += 1e-5 * rows[row]
    assert _realise(dataclasses.replace(reference, estimator_gain=solver.tolist())).sensors == Channels(
        (0, 0), (1, 1), (1, -1)
    )
    broken = m.copy()
    broken[row, 0] += 1e-3 * rows[row]
    assert _realise(dataclasses.replace(reference, estimator_gain=broken.tolist())).sensors.identity


def test_channels_transform_back_exactly():
    """Tᵀ·D⁻¹·T = I: the forces summed back from the channels are the joints' forces."""
    c = Channels((0, 0, 2), (1, 1, -1), (1, -1, 1))
    t = c.matrix()
    np.testing.assert_array_equal(t.T @ np.diag(1 / c.weights()) @ t, np.eye(3))
    g = np.array([0.5, -0.25, 2.0])
    np.testing.assert_array_equal(c.back(g), t.T @ g)
    np.testing.assert_array_equal(c.forward(np.array([1.0, 3.0, 5.0])), [4.0, -2.0, 5.0])


@pytest.mark.numerics
def test_an_asymmetric_design_keeps_its_channels_and_its_c_is_the_reference(reference):
    """E of joint A2 and C of the second sensor moved by 0.1 %: no pair, one group of every channel
    (only the real-Jordan basis), and the double build of it equals the reference bit for bit."""
    from test_codegen import _check_pair, _sequence

    e = np.asarray(reference.joint_input, dtype=float).copy()
    e[:, 1] *= 1.001
    c = np.asarray(reference.output, dtype=float).copy()
    c[1] *= 1.001
    changed = dataclasses.replace(reference, joint_input=e.tolist(), output=c.tolist())
    r = _realise(changed)
    assert r.joints.identity and r.sensors.identity and len(r.groups) == 1
    assert r.rotation and np.all(r.gamma1[:, 0] == 1.0)
    compiled = controllers.compile_controllers(changed, "double")
    assert "alpha" in compiled.files["smartjoint_clqg.c"]
    _check_pair(clipped_lqg(changed), compiled.law("clqg"), _sequence(changed, count=800), exact=True)


@pytest.mark.numerics
@pytest.mark.parametrize("source", ["bundled", "mast_12"])
def test_the_looped_step_is_the_reference_bit_for_bit(reference, source, monkeypatch):
    """Beyond law_contexts.UNROLLED_JOINTS the sums over joints are loops over index tables of the
    same terms in the same order: the double build equals the Python reference bit for bit — on
    the bundled design forced into loops, and on the 12-joint mast of benchmarks/joint_scaling —
    and the loops' code does not grow with the joints the way the written-out sums do."""
    from test_codegen import _check_pair, _sequence

    from smartjoint.codegen import law_contexts

    a = reference if source == "bundled" else artifact.load(ROOT / "benchmarks" / "joint_scaling" / "joints_12.json")
    monkeypatch.setattr(law_contexts, "UNROLLED_JOINTS", 1000)
    unrolled = controllers.compile_controllers(a, "double").files["smartjoint_clqg.c"]
    monkeypatch.setattr(law_contexts, "UNROLLED_JOINTS", 0)
    compiled = controllers.compile_controllers(a, "double")
    looped = compiled.files["smartjoint_clqg.c"]
    assert "channel_value(&joint_channel[j], input->friction_force)" in looped
    assert looped.count("MULTIPLY_ADD") < unrolled.count("MULTIPLY_ADD") or len(a.joint_names) <= 4
    _check_pair(clipped_lqg(a), compiled.law("clqg"), _sequence(a, count=800), exact=True)
