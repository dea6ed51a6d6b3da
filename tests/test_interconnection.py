"""One closed-loop interconnection (``design.control.interconnection.ClosedLoop``): the Python
plant loop, the compiled loop, the CAN loop (SIL) and the FMU master all take a law of the
registry by either name and give the same record — the run at the controller samples and the
samples in the safe state; the Python and the compiled loop the same numbers, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import small_study

from smartjoint.bench.interconnection import CanLoop, FmuLoop
from smartjoint.bench.rounding_spread import perturbed
from smartjoint.codegen.closed_loop import CompiledLoop
from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control.interconnection import ClosedLoop, PythonLoop
from smartjoint.design.control.runs import run_semi_active


@pytest.fixture(scope="module")
def study():
    """The small truss's study over 0.2 s and its artefact (ε = 3e-4 m/s)."""
    return small_study()


def test_every_interconnection_is_a_closed_loop(study, tmp_path):
    _, artifact = study
    for loop in (PythonLoop(artifact), CompiledLoop(artifact), CanLoop(artifact), FmuLoop(tmp_path / "p.fmu", {})):
        assert isinstance(loop, ClosedLoop), type(loop).__name__


@pytest.mark.numerics
def test_python_and_compiled_loops_give_the_same_record_for_every_law(study):
    s, artifact = study
    python, compiled = PythonLoop(artifact), CompiledLoop(artifact)
    for law in law_registry.LAWS.values():
        for name in (law.name, law.display):
            (a, a_safe), (b, b_safe) = python.run(s, name), compiled.run(s, name)
            assert a.name == b.name == law.display
            assert a.energy.tobytes() == b.energy.tobytes() and a_safe == b_safe, (law.name, name)
    passive = python.run_passive(s, "passive F_max", s.normal_force_max)
    assert passive.energy.tobytes() == compiled.run_passive(s, "passive F_max", s.normal_force_max).energy.tobytes()


@pytest.mark.numerics
def test_the_can_loop_gives_the_record_of_the_model_in_the_loop(study):
    """The host float build through the CAN loop: a run on the controller samples of the model
    in the loop, never in the safe state, its energy measure as close to the model in the loop's
    as a band measured here allows: twice the double build's deviation through the same loop (the
    frames' quantisation) plus ten times the spread of the model in the loop under 6e-8
    perturbations of its commands (the float build's rounding, ``rounding_spread.perturbed``)."""
    s, artifact = study
    python = PythonLoop(artifact)
    for entry in law_registry.LAWS.values():
        mil, _ = python.run(s, entry.name)
        single, single_safe = CanLoop(artifact, "float").run(s, entry.name)
        double, double_safe = CanLoop(artifact, "double").run(s, entry.display)
        np.testing.assert_array_equal(single.time, mil.time)
        assert single_safe == double_safe == 0 and single.name == double.name == entry.display
        spread = max(
            abs(run_semi_active(s, entry.display, perturbed(entry.python_reference(artifact), 6e-8, k)).energy_measure()
                / mil.energy_measure() - 1.0)
            for k in range(3)
        )  # fmt: skip
        band = 2.0 * abs(double.energy_measure() / mil.energy_measure() - 1.0) + 10.0 * spread
        assert abs(single.energy_measure() / mil.energy_measure() - 1.0) <= band, (entry.name, band)


def test_an_unknown_law_or_a_missing_fmu_is_one_line(study, tmp_path):
    s, artifact = study
    for loop in (PythonLoop(artifact), CompiledLoop(artifact), CanLoop(artifact)):
        with pytest.raises(ModelError, match=r"^law: 'lqr' — allowed: siso, clqg, preset, slipratio$"):
            loop.run(s, "lqr")
    with pytest.raises(ModelError, match=r"^law: 'clqg' — this FMU loop has controller FMUs of siso$"):
        FmuLoop(tmp_path / "p.fmu", {"siso": tmp_path / "siso.fmu"}).run(s, "cLQG")
