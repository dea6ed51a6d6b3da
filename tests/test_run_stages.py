"""``smartjoint run`` hands its stages' results on: one run of the bundled reference truss builds
each FE model once and solves its modes once (issue 29). Counted by wrapping the two functions
in every module that holds them, however the module imported them."""

from __future__ import annotations

from conftest import count_model_calls


def test_the_bundled_truss_builds_each_model_once_and_solves_its_modes_once(tmp_path, monkeypatch):
    """The bundled truss (with [updating] and [placement]) through every stage that used to build
    or solve a model — structure, placement, friction, reduction, control and the ensemble; the
    firmware, SIL, PIL and FMU stages take the control stage's study and artefact only (the
    whole pipeline is counted on a user's design in ``test_cli``)."""
    from smartjoint import pipeline
    from smartjoint.pipeline_ensemble import ensemble_stage

    calls = count_model_calls(monkeypatch)
    quiet = lambda line: None  # noqa: E731
    structure = pipeline._structure_stage(None, tmp_path, quiet)
    assert structure.placed_design == "placed_design.toml"  # the path with updating and placement
    friction = pipeline._friction_stage(structure, tmp_path, quiet)
    pipeline._reduction_stage(structure, friction, quiet)
    control = pipeline._control_stage(structure, friction, quiet)
    ensemble_stage(control.design, control.study, list(friction.types), tmp_path, quiet)
    # The nominal truss (updating starts from it), the updated one, the one with its joints released.
    assert {k: n for k, n in calls.items() if k[0] == "build"} == {("build", "locked"): 2, ("build", "released"): 1}
    # Each model's modes once; the reduction study's full-model reference (every mode, dense) apart.
    assert {k: n for k, n in calls.items() if k[0] == "solve"} == {("solve", False): 2, ("solve", True): 1}
