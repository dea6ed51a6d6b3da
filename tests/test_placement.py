"""Joint placement by the axial modal strain energy of the end connectors (Section 6, Fig. 11)."""

from __future__ import annotations

import pytest
from conftest import cli_error, run_cli

# `fem` is the design package: its folder holds data/ (the bundled designs), and it exports build_model.
from smartjoint import design as fem
from smartjoint.common.errors import ModelError
from smartjoint.design.structure import modal, placement, spec

pytestmark = pytest.mark.numerics  # run again by the portability leg (.ci/portability)


@pytest.fixture(scope="module")
def reference():
    fe = fem.build_model(spec.load_design(), joints="locked")
    return fe, modal.solve_modes(fe, 6)


def test_fractions_are_bounded_and_follow_the_mode_shapes(reference):
    """Each fraction is a share of ½ω² (0 < s < 1); the bending mode in one diagonal plane strains
    the two longerons in that plane equally (symmetry) and the other two not at all."""
    fe, modes = reference
    candidates = {(c.member, c.end): c for c in placement.connector_energy(fe, modes, [0, 1])}
    total = sum(c.fractions[0] for c in candidates.values())
    assert 0 < total < 1
    first = candidates[("L1_0", "start")].fractions
    assert first[0] == pytest.approx(candidates[("L1_2", "start")].fractions[0], rel=1e-6)
    assert first[1] < 1e-12 * first[0]
    assert candidates[("L1_1", "start")].fractions[1] > 0.5 * first[0]


def test_bundled_three_joint_design_is_the_placement_result(reference):
    fe, modes = reference
    chosen = placement.choose(placement.connector_energy(fe, modes, [0, 1]), 3)
    design = spec.load_design(spec.REFERENCE_DESIGN.with_name("three_type_a.toml"))
    assert [(c.member, c.end) for c in chosen] == [(j.member, j.end) for j in design.joints]
    assert all(j.type == "A" for j in design.joints)


def test_bad_targets_are_named(reference):
    fe, modes = reference
    with pytest.raises(ModelError, match=r"target modes: \[7\] — must be between 1 and 6"):
        placement.connector_energy(fe, modes, [6])
    with pytest.raises(ModelError, match="joints: 500 requested"):
        placement.choose(placement.connector_energy(fe, modes, [0]), 500)


def test_place_command_writes_a_loadable_design_with_the_ranked_joints(tmp_path):
    import json

    target = tmp_path / "placed" / "three.toml"
    done = run_cli("place", "--no-update", "--modes", "1,2", "--count", "3", "-o", str(target), "--json")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    placed = spec.load_design(target)
    bundled = spec.load_design(spec.REFERENCE_DESIGN.with_name("three_type_a.toml"))
    assert [(j.member, j.end, j.type) for j in placed.joints] == [(j.member, j.end, j.type) for j in bundled.joints]
    assert [c["member"] for c in out["chosen"]] == [j.member for j in placed.joints]
    # The tie rule, not a float sort: mirror-image connectors score equal up to rounding that
    # differs per machine (~1e-11 relative, either sign), so their order must come from the names.
    # Distinct positions of this truss are >= 3.6e-5 apart, far outside the tie tolerance, so
    # every pair is either tied (name order) or clearly ordered (score order) on any machine.
    ranking = out["ranking"]
    for i, first in enumerate(ranking):
        for second in ranking[i + 1 :]:
            if placement.tied(first["score"], second["score"]):
                assert (first["member"], first["end"]) < (second["member"], second["end"]), (first, second)
            else:
                assert first["score"] > second["score"], (first, second)
    mirrors = [
        (a["member"], b["member"]) for a, b in zip(ranking, ranking[1:]) if placement.tied(a["score"], b["score"])
    ]
    assert ("L1_0", "L1_2") in mirrors and ("L1_1", "L1_3") in mirrors  # the rule is exercised, not vacuous
    assert "already has joints" in cli_error("place", str(target), "--no-update")
    assert "--modes" in cli_error("place", "--no-update", "--modes", "x")
