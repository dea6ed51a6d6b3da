"""``smartjoint run`` hands its stages' results on: one run of the bundled reference truss builds
each FE model once and solves its modes once (issue 29). Counted by wrapping the two functions
in every module that holds them, however the module imported them."""

from __future__ import annotations

import sys
from collections import Counter

from smartjoint.design.structure import fem, modal


def _count_calls(monkeypatch) -> Counter:
    """Wrap ``fem.build_model`` and ``modal.solve_modes`` wherever a module of the project holds
    them; the counter gets (function, joints or mode count) per call."""
    calls: Counter = Counter()
    build, solve = fem.build_model, modal.solve_modes

    def counted_build(design, *args, joints="released", **kwargs):
        calls["build", joints] += 1
        return build(design, *args, joints=joints, **kwargs)

    def counted_solve(model, n_modes, *args, **kwargs):
        calls["solve", n_modes == model.n_dof] += 1
        return solve(model, n_modes, *args, **kwargs)

    for name, module in list(sys.modules.items()):
        if name.startswith("smartjoint") and module is not None:
            for attribute, value in list(vars(module).items()):
                if value is build:
                    monkeypatch.setattr(module, attribute, counted_build)
                elif value is solve:
                    monkeypatch.setattr(module, attribute, counted_solve)
    return calls


def test_the_bundled_run_builds_each_model_once_and_solves_its_modes_once(tmp_path, monkeypatch):
    from smartjoint import pipeline

    calls = _count_calls(monkeypatch)
    summary = pipeline.run(None, tmp_path / "report", progress=lambda line: None)
    assert summary["design"]["placed"] == "placed_design.toml"  # the path with updating and placement
    builds = {key: n for key, n in calls.items() if key[0] == "build"}
    # The nominal truss (updating starts from it), the updated one, the one with its joints released.
    assert builds == {("build", "locked"): 2, ("build", "released"): 1}, calls
    solves = {key: n for key, n in calls.items() if key[0] == "solve"}
    # Each model's modes once; the reduction study's full-model reference (every mode) apart.
    assert solves == {("solve", False): 2, ("solve", True): 1}, calls
