"""The constant products of the clipped LQG's two phases (Eq. 33 split where the new measurement
enters): computed once, in the generated C's order, from the matrices of the filter's realisation."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from smartjoint.design.control.ordered_sums import ordered_matrix_product


class HoldProducts(NamedTuple):
    """The constant products of the two-phase filter, with Γ1·E the 2n × l matrix of rows
    γ1[i, c]·E[i, :]: C·Γ1·E (n_y × l, the update phase's innovation), KM·CΓ1E − K·Γ1·E (l × l)
    and K·M (l × n_y), the output phase's, and K − KM·C (l × 2n), the update phase's gain on q."""

    output_hold: np.ndarray
    feedback_hold: np.ndarray
    feedback_estimator: np.ndarray
    feedback_prior: np.ndarray


def hold_products(output, feedback_gain, estimator_gain, gamma1, joint_input) -> HoldProducts:
    """The constant products of the two-phase filter (:class:`HoldProducts`). Computed once in a
    fixed order; the generated C holds these very numbers, so both sum them the same way.

    Returns
    -------
    HoldProducts
        (output_hold, feedback_hold, feedback_estimator, feedback_prior).
    """
    gamma1, joint_input = np.asarray(gamma1, dtype=float), np.asarray(joint_input, dtype=float)
    hold = (gamma1[:, :, None] * joint_input[:, None, :]).reshape(-1, joint_input.shape[1])
    output, feedback_gain = np.asarray(output, dtype=float), np.asarray(feedback_gain, dtype=float)
    feedback_estimator = ordered_matrix_product(feedback_gain, np.asarray(estimator_gain, dtype=float))
    output_hold = ordered_matrix_product(output, hold)
    return HoldProducts(
        output_hold,
        ordered_matrix_product(feedback_estimator, output_hold) - ordered_matrix_product(feedback_gain, hold),
        feedback_estimator,
        feedback_gain - ordered_matrix_product(feedback_estimator, output),
    )


def step_products(realisation) -> HoldProducts:
    """The products the two phases use (:func:`hold_products` of the realisation's matrices) with
    the gains negated — −(KM·CΓ1E − KΓ1E), −KM and −(K − KM·C) — so that the output phase's sums
    are u_d itself: x + (−a)·b = −(−x + a·b) exactly in IEEE arithmetic, so the forces are the
    same numbers, one negation per joint fewer."""
    r = realisation
    p = hold_products(r.output, r.feedback_gain, r.estimator_gain, r.gamma1, r.joint_input)
    return HoldProducts(p.output_hold, -p.feedback_hold, -p.feedback_estimator, -p.feedback_prior)


__all__ = ["HoldProducts", "hold_products", "step_products"]
