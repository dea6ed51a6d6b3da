"""The ``linear`` scheme: the frictionless modal model driven directly by the controller's forces.

The fully active reference of Section 6 (``design/control/filter.py``'s ``ActiveLqg``): Eq. 12
with the joints frictionless and the controller's commands u applied as joint forces,

    ẋ = A·x − B·u + H·w,   u held over each sample (zero-order hold),

discretised exactly per mode block at the plant step (``discretisation.discretise``, first-order
hold on w: exact for the triangular pulse, whose corners lie on the sample grid). Run it through
the same loop as the friction schemes::

    simulate(model, [], ActiveLqg(design, hold_until=0.04), pulse, duration, step=sample_time,
             energy_books=False, scheme="linear")

The result's ``friction_force`` holds the joint forces acting (the held commands), its
``normal_force`` and ``deflection`` are zero (no friction), the energy books NaN.
"""

from __future__ import annotations

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.plant.discretisation import discretise
from smartjoint.design.plant.interface import Measurements
from smartjoint.design.plant.kernel import PlantRun, Recorder

FRICTION = False  # no LuGre joints: the controller commands the joint forces
COMPACT_DISTURBANCE = False


class _LinearKernel:
    """The frictionless modal model in numpy, the state x (n, 2) of mode-interleaved [η̇, ωη]."""

    name = "python"

    def __init__(self, run: PlantRun):
        model = run.model
        self.phi, self.g0, self.g1 = discretise(model, run.step)
        self.e, self.hw = model.joint_input, model.disturbance_input
        self.vy, self.dy = model.velocity_output, model.displacement_output / model.omega
        n, l = model.n_coordinates, self.e.shape[1]
        self.x = (
            np.zeros((n, 2)) if run.initial_state is None else np.array(run.initial_state, dtype=float).reshape(n, 2)
        )
        self.force = np.zeros(l)
        self.recorder = Recorder(run.rows, l, self.vy.shape[0])

    def _outputs(self) -> tuple[np.ndarray, np.ndarray]:
        sensors = self.vy @ self.x[:, 0] + self.dy @ self.x[:, 1]
        return sensors, self.e.T @ self.x[:, 0]

    def start(self, w0):
        self.recorder.works[:] = np.nan

    def measure(self, time: float) -> Measurements:
        sensors, velocity = self._outputs()
        return Measurements(time, sensors, velocity, self.force.copy(), np.zeros(self.force.size))

    def set_normal_force(self, normal_force):
        self.force = np.array(normal_force, dtype=float)  # here: the joint forces themselves

    def record_row(self, row):
        r = self.recorder
        r.sensors[row], r.v[row] = self._outputs()
        r.u[row], r.fn[row], r.phi[row] = self.force, 0.0, 0.0
        r.energy[row] = 0.5 * float(np.sum(self.x * self.x))
        r.works[row] = np.nan

    def run(self, w, steps, k0, record_every):
        e, hw, u = self.e, self.hw, self.force
        for k in range(steps):
            if (k0 + k) % record_every == 0:
                self.record_row((k0 + k) // record_every)
            fa, fb = hw @ w[k] - e @ u, hw @ w[k + 1] - e @ u
            self.x = np.einsum("nij,nj->ni", self.phi, self.x) + self.g0 * fa[:, None] + self.g1 * fb[:, None]


def check(run: PlantRun) -> None:
    """``Scheme.check`` (``kernel.py``): the linear run's own conditions, each a named error."""
    if len(run.joints):
        raise ModelError(
            f"joints: {len(run.joints)} LuGre parameter sets — the linear scheme is frictionless; "
            "pass joints=[] (the controller's forces act in the joints)"
        )
    if run.energy_books:
        raise ModelError("energy_books: True — the linear scheme keeps no energy books; pass energy_books=False")
    if run.stick_step is not None:
        raise ModelError("stick_step: the linear scheme has no stick-exact steps; leave stick_step out")
    if run.backend not in ("auto", "python"):
        raise ModelError(f"backend: {run.backend!r} — the linear scheme runs in numpy: 'auto' or 'python'")


def kernel(run: PlantRun) -> _LinearKernel:
    """``Scheme.kernel`` (``kernel.py``): the frictionless modal model in numpy, discretised at
    ``run.step``."""
    return _LinearKernel(run)


__all__ = ["COMPACT_DISTURBANCE", "FRICTION", "check", "kernel"]
