"""The closed-loop interconnection: one protocol for every way the study's loop is closed.

A study or a sweep runs a law of the registry (``common.law_registry``) on a study set-up
(``runs.StudySetup``: plant, LuGre joints, pulse, limits, timing) through a :class:`ClosedLoop`
and gets the same record whichever closes the loop: the :class:`Run` at the controller samples
and the number of samples the law spent in the safe state. The implementations:

- :class:`PythonLoop` — the Python plant loop with the law's Python reference (the executable
  specification), here;
- ``codegen.closed_loop.CompiledLoop`` — the plant kernel stepped from C with the generated law;
- ``bench.interconnection.CanLoop`` — the law's firmware through the CAN loop, the host build
  (software in the loop) or the target's (processor in the loop);
- ``bench.interconnection.FmuLoop`` — the plant FMU and the law's controller FMU in the
  project's FMI master.

Each also runs the passive references (a constant F_N after the pulse), so a sweep's rows come
from one interconnection.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from smartjoint.common import law_registry
from smartjoint.design.control.laws import STATUS_OK
from smartjoint.design.control.runs import Run, StudySetup, run_passive, run_semi_active


@runtime_checkable
class ClosedLoop(Protocol):
    """What closes the study's loop around a law."""

    def run(self, s: StudySetup, law: str) -> tuple[Run, int]:
        """One semi-active run of ``law`` (its registry name or display name) on ``s``, with
        F_N^max during the pulse: the run and the samples in the safe state."""
        ...

    def run_passive(self, s: StudySetup, name: str, normal_forces) -> Run:
        """A passive run: F_N^max during the pulse, then ``normal_forces``."""
        ...


class CountingSafeState:
    """A controller wrapper counting the samples whose status is not OK (the safe state).

    Parameters
    ----------
    inner : Controller
        A controller with a ``status`` after each step (the Python references have one).
    """

    def __init__(self, inner):
        self.inner, self.sample_time, self.count = inner, inner.sample_time, 0

    def reset(self) -> None:
        self.inner.reset()
        self.count = 0

    def step(self, measurements) -> np.ndarray:
        out = self.inner.step(measurements)
        self.count += int(getattr(self.inner, "status", STATUS_OK) != STATUS_OK)
        return out


class PythonLoop:
    """The Python plant loop (``design.plant.loop``) with each law's Python reference built
    from the artefact.

    Parameters
    ----------
    artifact : ControllerArtifact
        The laws' numbers.
    """

    def __init__(self, artifact):
        self.artifact = artifact

    def run(self, s: StudySetup, law: str) -> tuple[Run, int]:
        entry = law_registry.law(law)
        controller = CountingSafeState(entry.python_reference(self.artifact))
        return run_semi_active(s, entry.display, controller), controller.count

    def run_passive(self, s: StudySetup, name: str, normal_forces) -> Run:
        return run_passive(s, name, normal_forces)


__all__ = ["ClosedLoop", "CountingSafeState", "PythonLoop"]
