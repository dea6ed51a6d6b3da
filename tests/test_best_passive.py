"""The best passive setting (design/control/best_passive.py, issue 20): the constant F_N that
minimises E(t_e) or e(t_e) is at least as good as every force of an independent grid, the
compiled loop and the Python loop find the same force and run, and impossible limits are one line."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import small_truss

from smartjoint.codegen.closed_loop import CompiledLoop
from smartjoint.common.errors import ModelError
from smartjoint.design.control import ensemble
from smartjoint.design.control.best_passive import best_passive, figure
from smartjoint.design.control.runs import run_passive, setup
from smartjoint.design.control.study import design_model, lqg_for
from smartjoint.design.structure.spec import parse_design


@pytest.fixture(scope="module")
def study():
    d = small_truss()
    d["control"] = {"modes": 4, "considered_modes": 10, "study_duration": 0.4, "siso_boundary_layer": 3e-4}
    design = parse_design(d)
    model = design_model(design, lambda line: None)
    artifact = ensemble.point_artifact(design, model, lqg_for(design, model), {})
    return setup(design, model), CompiledLoop(artifact)


@pytest.mark.parametrize("metric", ["energy_measure", "energy_end"])
def test_the_best_force_beats_every_force_of_an_independent_grid(study, metric):
    s, compiled = study
    run, force = best_passive(s, "best", metric, compiled.run_passive)
    assert run.name == "best" and 10.0 <= force <= 400.0
    assert np.all(run.normal_force[41:] == force)
    grid = np.linspace(10.0, 400.0, 14)  # none of these is a point of the search's own grid
    values = [figure(compiled.run_passive(s, "grid", np.full(2, f)), metric) for f in grid]
    assert figure(run, metric) <= min(values)


def test_the_compiled_and_the_python_loop_find_the_same_force_and_run(study):
    s, compiled = study
    cache: dict = {}
    c_run, c_force = best_passive(s, "best", "energy_measure", compiled.run_passive, cache)
    p_run, p_force = best_passive(s, "best", "energy_measure", run_passive)
    assert c_force == p_force and len(cache) >= 9
    np.testing.assert_array_equal(c_run.energy, p_run.energy)
    again, _ = best_passive(s, "best", "energy_end", compiled.run_passive, cache)  # reuses the runs
    assert any(again.energy is r.energy for r in cache.values())


def test_limits_without_a_common_force_and_unknown_metrics_are_one_line(study):
    s, compiled = study
    apart = dataclasses.replace(s, normal_force_min=np.array([10.0, 300.0]), normal_force_max=np.array([200.0, 400.0]))
    with pytest.raises(ModelError, match=r"^normal-force limits: no constant F_N lies in every joint's"):
        best_passive(apart, "best", "energy_end", compiled.run_passive)
    with pytest.raises(ModelError, match=r"^metric: 'rms' — must be one of energy_measure, energy_end$"):
        best_passive(s, "best", "rms", compiled.run_passive)
