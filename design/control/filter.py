"""The LQG controllers of paper Section 5.2 at run time: the Kalman filter of Eq. 33 and the
two ways of using its desired forces.

* ``ClippedLqg`` — Eq. 33–34: a Kalman filter on the tip sensors with the measured friction
  forces as known input, the LQR forces u_d = −K·x̂ and the clipped normal-force law.
* ``ActiveLqg`` — the fully active reference: the same LQG, u_d applied directly as forces (run
  it on the plant's frictionless ``linear`` scheme).

Both are executable specifications of the generated C (``ordered_product``: its summation order).
The gains come from ``lqg.design_lqg``.
"""

from __future__ import annotations

import math

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.control.artifact import lqg_design
from smartjoint.design.control.hold_products import step_products
from smartjoint.design.control.laws import (
    STATUS_ESTIMATE_RESET,
    STATUS_OK,
    any_status,
    boundary_layer,
    check_limits,
    input_status,
    magnitude_limit,
    measured_range,
    safe_force,
    safe_state_options,
)
from smartjoint.design.control.lqg import LqgDesign
from smartjoint.design.control.ordered_sums import multiply_add, ordered_product
from smartjoint.design.control.realisation import realise
from smartjoint.design.plant.interface import Measurements


class _Lqg:
    """Shared Kalman filter of ``ClippedLqg`` and ``ActiveLqg``. At sample k::

        x̂⁻ = Φ·x̂_k−1 − Γ0·E·u_k−1 − Γ1·E·u_k    (time update, first-order hold on the
                                                 applied joint forces; skipped at k = 0: x̂⁻ = 0)
        x̂_k = x̂⁻ + M·(y_k − C·x̂⁻)               (measurement update)
        u_d = −K·x̂_k                             (Eq. 33)

    u is the joint force that acts on the structure: the measured friction force for the
    clipped controller, the previous command for the active one.

    Computed in two phases, as the generated C (``<prefix>_clqg_output_phase``, ``_update_phase``):
    the update phase after sample k−1 has sent its command precomputes q = Φ·x̂_k−1 − Γ0·E·u_k−1,
    C·q and r = (K − KM·C)·q; the output phase at sample k needs only the products that involve
    the new measurement (``hold_products``: the small constant matrices)::

        u_d = −(r + (KM·CΓ1E − KΓ1E)·u_k + KM·y_k)

    and the update phase then forms ν = y_k − (C·q − CΓ1E·u_k), x̂_k = (q − Γ1·E·u_k) + M·ν and
    the next q. Every sum is a chain of multiply-adds in a fixed order (``multiply_add``), the
    generated C's: its double build reproduces this reference bit for bit."""

    def __init__(self, design: LqgDesign):
        self.design = design
        self.sample_time = design.sample_time
        self.realisation = r = realise(
            design.blocks,
            design.gamma0,
            design.gamma1,
            design.joint_input,
            design.output,
            design.estimator_gain,
            design.feedback_gain,
        )
        self.products = step_products(r)
        self.output_used = r.output_terms()
        self.estimator_used = r.estimator_terms()
        self.feedback_used = r.feedback_terms()
        self.input_used = r.joint_input != 0.0
        for g in r.groups:  # a group's joints are terms even where an entry is 0 (fixed loops)
            self.input_used[g.start : g.stop, list(g.joints)] = True
        self.hold_used = {name: np.asarray(v) != 0.0 for name, v in self.products._asdict().items()}
        self.reset()

    def reset(self) -> None:
        d = self.design
        self.estimate = np.zeros(d.output.shape[1])  # x̂ in the design's state order and basis
        self.propagated = np.zeros(d.output.shape[1])  # q = Φ·x̂ − Γ0·E·u⁺, the realisation's order
        self.predicted = np.zeros(d.output.shape[0])  # C'·q, adapted sensor channels
        self.feedback = np.zeros(d.feedback_gain.shape[0])  # −(K' − K'M'·C')·q, adapted joint channels
        self.previous_force = np.zeros(d.joint_input.shape[1])
        self.force = np.zeros(d.joint_input.shape[1])  # u_k of the pending update
        self.sensors = np.zeros(d.output.shape[0])  # y_k of the pending update
        self.innovation = np.zeros(d.output.shape[0])  # adapted sensor channels
        self.started = False
        self.pending = False

    def _output(self, sensors: np.ndarray, force: np.ndarray) -> np.ndarray:
        """The output phase: u_d from the new measurement and the precomputed r = (K' − K'M'·C')·q
        (zero before the first sample, which has no prior and no hold term), in the adapted
        channels (``realisation``), turned back into the joints' forces by sums."""
        p, used, r = self.products, self.hold_used, self.realisation
        sensors, force = np.array(sensors, dtype=float), np.array(force, dtype=float)
        feedback = self.feedback
        if self.started:
            feedback = multiply_add(feedback, p.feedback_hold, r.joints.forward(force), used["feedback_hold"])
        feedback = multiply_add(feedback, p.feedback_estimator, r.sensors.forward(sensors), used["feedback_estimator"])
        self.sensors, self.force, self.pending = sensors, force, True
        return r.joints.back(feedback)  # the gains are negated (step_products): this is −Tᵀ·(K'·x̂)

    def _update(self) -> None:
        """The update phase (after the command is sent): ν, x̂_k, then q, C'·q and (K' − K'M'·C')·q
        for the next sample with u⁺ = ``previous_force``. Nothing without a pending output phase."""
        if not self.pending:
            return
        r = self.realisation
        n = r.blocks.shape[0]
        sensors = r.sensors.forward(self.sensors)
        if self.started:
            force, q = r.joints.forward(self.force), self.propagated.reshape(n, 2)
            self.innovation = sensors - multiply_add(
                self.predicted, -self.products.output_hold, force, self.hold_used["output_hold"]
            )
        else:  # the first sample has no prior: q = 0, no hold term, ν = y
            force, q = np.zeros(self.force.size), np.zeros((n, 2))
            self.innovation = sensors
        end = ordered_product(r.joint_input, force, self.input_used)
        prior = np.stack([q[:, 0] - r.gamma1[:, 0] * end, q[:, 1] - r.gamma1[:, 1] * end], axis=1).reshape(2 * n)
        estimate = multiply_add(prior, r.estimator_gain, self.innovation, self.estimator_used)
        self.estimate = r.to_design(estimate)
        x = estimate.reshape(n, 2)
        start = ordered_product(r.joint_input, r.joints.forward(self.previous_force), self.input_used)
        b = r.blocks
        out = np.empty((n, 2))
        out[:, 0] = (b[:, 0, 0] * x[:, 0] + b[:, 0, 1] * x[:, 1]) - r.gamma0[:, 0] * start
        out[:, 1] = (b[:, 1, 0] * x[:, 0] + b[:, 1, 1] * x[:, 1]) - r.gamma0[:, 1] * start
        self.propagated = out.reshape(2 * n)
        self.predicted = multiply_add(np.zeros(r.output.shape[0]), r.output, self.propagated, self.output_used)
        self.feedback = multiply_add(
            np.zeros(r.feedback_gain.shape[0]), self.products.feedback_prior, self.propagated, self.feedback_used
        )
        self.started, self.pending = True, False


# |(K − KM·C)·q| beyond this [N] is a diverged estimate: far beyond any force a joint can take,
# and small enough that r plus the output phase's measurement terms stays finite in single precision.
FEEDBACK_LIMIT = 1e30


class ClippedLqg(_Lqg):
    """Clipped-optimal LQG, Eq. 33–34. Reading of Eq. 34, with e_j = u_d,j − u_R,j::

        F_N,j = F_N^min + (F_N^max − F_N^min)·clip(e_j·sgn(u_R,j) / ε, 0, 1)

    The paper's F^min + F^max·H[e_j·u_R,j] would exceed the stated bound F^max; scaling by
    (F^max − F^min) keeps F^min ≤ F_N ≤ F^max. H[e·u_R] has the sign of e·sgn(u_R), so the
    boundary layer is laid over that quantity and ε is a force [N]: the normal force rises when
    the friction force is smaller than the desired force in the same direction and falls to
    F^min when it is larger or opposes it. u_R,j = 0 counts as sgn = 0 (F^min: nothing to steer).

    Faults (``status``): a measurement that is NaN/±Inf (``STATUS_INPUT_INVALID``) or a number
    outside its plausible range (``STATUS_INPUT_IMPLAUSIBLE``; plausible are |y_r| <=
    sensor_limit, |u_R,j| <= friction_force_limit and measured_normal_force_min <= F_N,j <=
    measured_normal_force_max, limits included) → every joint at ``safe_normal_force``, u_d = 0,
    and the filter restarts; an estimate whose feedback (K − KM·C)·q exceeds ``FEEDBACK_LIMIT``
    (or is NaN) → the same with ``STATUS_ESTIMATE_RESET``. Each input is checked where it is
    used: the sensors and friction forces by the output phase (the command uses them: the safe
    state at once); the measured normal forces, which only the update uses, and the new estimate
    by the update phase, which restarts the filter and leaves the fault for the next output phase
    (the safe state one sample later; on the bus the CAN layer checks every signal on receipt).
    Without the safety arguments: safe force F_N^max, no ranges beyond finiteness
    (:func:`clipped_lqg` passes the artefact's).
    """

    def __init__(
        self,
        design: LqgDesign,
        normal_force_min,
        normal_force_max,
        boundary_layer_width: float,
        *,
        safe_normal_force=None,
        sensor_limit=None,
        friction_force_limit=None,
        measured_normal_force_min=None,
        measured_normal_force_max=None,
    ):
        super().__init__(design)
        self.normal_force_min = np.array(normal_force_min, dtype=float)
        self.normal_force_max = np.array(normal_force_max, dtype=float)
        check_limits(self.normal_force_min, self.normal_force_max)
        count = design.joint_input.shape[1]
        if self.normal_force_min.size != count:
            raise ModelError(f"normal_force_min: {self.normal_force_min.size} values for {count} joints")
        if not (math.isfinite(boundary_layer_width) and boundary_layer_width > 0):
            raise ModelError(f"clqg_boundary_layer: {boundary_layer_width!r} — must be finite and > 0 [N]")
        self.boundary_layer = float(boundary_layer_width)
        self.normal_force_range = self.normal_force_max - self.normal_force_min
        self.desired_force = np.zeros(self.normal_force_min.size)
        self.safe_normal_force = safe_force(safe_normal_force, self.normal_force_min, self.normal_force_max)
        self.sensor_limit = magnitude_limit("sensor_limit", sensor_limit, design.output.shape[0])
        self.friction_force_limit = magnitude_limit("friction_force_limit", friction_force_limit, count)
        self.measured_normal_force_min, self.measured_normal_force_max = measured_range(
            measured_normal_force_min, measured_normal_force_max, count
        )

    def reset(self) -> None:
        super().reset()
        self.desired_force = np.zeros(self.design.joint_input.shape[1])
        self.applied = np.zeros(self.design.joint_input.shape[1])  # F_N measured at the pending update
        self.command = np.zeros(self.design.joint_input.shape[1])  # F_N commanded at the pending update
        self.status = STATUS_OK
        self.fault = STATUS_OK  # found by an update phase, the status of the next output phase

    def _restart(self, fault: int) -> None:
        """A fault the update phase found: the filter restarts, the next output phase reports it."""
        status, desired = self.status, self.desired_force  # this sample's output stays as sent
        self.reset()
        self.status, self.desired_force, self.fault = status, desired, fault

    def _fault(self, status: int) -> np.ndarray:
        self.reset()
        self.status = status
        return self.safe_normal_force.copy()

    def step(self, measurements: Measurements) -> np.ndarray:
        """``output`` then ``update``: one sample (the generated C's ``<prefix>_clqg_step``)."""
        normal_force = self.output(measurements)
        self.update()
        return normal_force

    def output(self, measurements: Measurements) -> np.ndarray:
        """The output phase: the command F_N from the new measurement (``<prefix>_clqg_output_phase``)."""
        sensors = np.asarray(measurements.sensors, dtype=float)
        friction = np.asarray(measurements.friction_force, dtype=float)
        applied = np.asarray(measurements.normal_force, dtype=float)
        used = any_status(
            input_status(sensors, -self.sensor_limit, self.sensor_limit),
            input_status(friction, -self.friction_force_limit, self.friction_force_limit),
        )
        if self.fault != STATUS_OK or used != STATUS_OK:
            every = any_status(np.array([used]), self._applied_status(applied))
            return self._fault(self.fault | every)
        # |r| <= FEEDBACK_LIMIT (the update's test) and bounded inputs: every force is finite.
        self.desired_force = self._output(sensors, friction)
        self.status = STATUS_OK
        error = self.desired_force - friction
        normal_force = self.normal_force_min + self.normal_force_range * boundary_layer(
            error * np.sign(friction), self.boundary_layer
        )
        self.applied, self.command = applied, normal_force
        return normal_force

    def _applied_status(self, applied: np.ndarray) -> np.ndarray:
        return input_status(applied, self.measured_normal_force_min, self.measured_normal_force_max)

    def update(self) -> None:
        """The update phase, after the command of ``output`` is sent (the generated C's
        ``<prefix>_clqg_update_phase``): the measured normal forces checked, the time update and
        the products of the next output phase, the new estimate checked."""
        if not self.pending:
            return
        fault = any_status(self._applied_status(self.applied))
        if fault != STATUS_OK:
            self._restart(fault)
            return
        # The friction force just after the sample: u_R = F_N·μ with μ continuous, so it scales
        # with the new normal force — the start value of the next time update's first-order hold.
        applied, friction = self.applied, self.force
        self.previous_force = np.where(
            applied > 0.0, friction * self.command / np.where(applied > 0.0, applied, 1.0), friction
        )
        with np.errstate(all="ignore"):
            self._update()
        # Written as "within", false for NaN: a feedback beyond the bound is a diverged estimate.
        if not np.all(np.abs(self.feedback) <= FEEDBACK_LIMIT):
            self._restart(STATUS_ESTIMATE_RESET)


class ActiveLqg(_Lqg):
    """The fully active reference: u_d = −K·x̂ applied directly as joint forces (zero-order hold).

    ``step`` returns the forces; run it on the plant's frictionless ``linear`` scheme. While
    the excitation acts (t < ``hold_until``) the actuators hold zero force — the semi-active
    runs hold F_N^max then, which the active system has no analogue of; the filter keeps
    running, and the force it is told was applied (its ``previous_force``) is the zero held.
    """

    def __init__(self, design: LqgDesign, hold_until: float = 0.0):
        super().__init__(design)
        self.hold_until = float(hold_until)

    def step(self, measurements: Measurements) -> np.ndarray:
        command = self._output(measurements.sensors, self.previous_force)
        if measurements.time < self.hold_until - 1e-12:
            command = np.zeros(command.size)
        self.previous_force = command.copy()
        self._update()
        return command


def clipped_lqg(artifact) -> ClippedLqg:
    """The clipped-optimal LQG's Python reference from a controller artefact alone (Eq. 33–34),
    with the artefact's safe normal force and plausibility ranges (what the generated C checks).

    Parameters
    ----------
    artifact : ControllerArtifact
        Its LQG, limits, ε of Eq. 34, safe force and plausibility ranges.

    Returns
    -------
    ClippedLqg
    """
    return ClippedLqg(
        lqg_design(artifact),
        artifact.normal_force_min,
        artifact.normal_force_max,
        artifact.clqg_boundary_layer,
        sensor_limit=artifact.sensor_limit,
        **safe_state_options(artifact),
    )


def active_lqg(artifact) -> ActiveLqg:
    """The fully active LQG reference of an artefact (u_d = −K·x̂ of Eq. 33 applied as forces).

    Parameters
    ----------
    artifact : ControllerArtifact
        Its LQG (``artifact.lqg_design``).

    Returns
    -------
    ActiveLqg
    """
    return ActiveLqg(lqg_design(artifact))


def controller(setup, lqg: LqgDesign, settings: dict) -> ClippedLqg:
    """The clipped LQG the closed-loop study runs: the study's limits, ε of Eq. 34 from the
    law's ``settings`` (``tuning.Tuning.settings``), no safe-state ranges beyond finiteness."""
    return ClippedLqg(lqg, setup.normal_force_min, setup.normal_force_max, settings["boundary_layer"])


__all__ = [
    "FEEDBACK_LIMIT",
    "ActiveLqg",
    "ClippedLqg",
    "active_lqg",
    "clipped_lqg",
    "controller",
]
