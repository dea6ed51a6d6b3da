"""What each law's templates see beyond the common context (``generate.render``): one function
per law of ``common.law_registry``, named by its entry (``codegen``), ``function(artifact, lit,
row) -> dict`` with ``lit`` a number's C literal and ``row`` an array's, in the build's scalar type.
"""

from __future__ import annotations

import numpy as np

from smartjoint.design.control import artifact as artifacts
from smartjoint.design.control.filter import FEEDBACK_LIMIT, HoldProducts, hold_products, output_terms


def siso(artifact: artifacts.ControllerArtifact, lit, row) -> dict:
    """The SISO law's context (Eq. 30–31): ε and the plausible sliding velocity per joint."""
    return {
        "boundary_layer": row(artifact.siso_boundary_layer),
        "sliding_velocity_limit": row(artifact.sliding_velocity_limit),
    }


def clqg(artifact: artifacts.ControllerArtifact, lit, row) -> dict:
    """The clipped LQG's context (Eq. 33–34): the 2×2 predictor blocks per coordinate and the gains."""
    return {
        "coordinates": int(np.asarray(artifact.blocks).shape[0]),
        "coordinate_models": _coordinate_models(artifact, row),
        # The components of each coordinate a sensor reads (0 velocity, 1 displacement): the
        # structural zeros of C are skipped at generation time (control.output_terms).
        "output_components": [
            [q for q in (0, 1) if used[q]] for used in output_terms(np.asarray(artifact.output, dtype=float))[:, :2]
        ],
        **_hold_context(artifact, row),
        "clqg_boundary_layer": lit(artifact.clqg_boundary_layer),
        "sensor_limit": row(artifact.sensor_limit),
        "feedback_limit": lit(FEEDBACK_LIMIT),
    }


def _coordinate_models(artifact: artifacts.ControllerArtifact, row) -> list[dict]:
    """One entry per coordinate i: its 2×2 block Φ_i by columns, γ0, γ1, row i of E, then the
    gains on its two states: M[2i:2i+2] by columns, and C[:, 2i+c], (K − KM·C)[:, 2i+c] for
    c = 0, 1 (control.hold_products) — the state's component outermost, so that each pair the
    step forms lies side by side."""
    output = np.asarray(artifact.output, dtype=float)
    estimator, feedback = np.asarray(artifact.estimator_gain, dtype=float), _products(artifact).feedback_prior
    return [
        {
            "phi": [row(np.asarray(artifact.blocks[i], dtype=float)[:, k]) for k in (0, 1)],
            "gamma0": row(artifact.gamma0[i]),
            "gamma1": row(artifact.gamma1[i]),
            "joint_input": row(artifact.joint_input[i]),
            "estimator_gain": [row(estimator[2 * i : 2 * i + 2, r]) for r in range(estimator.shape[1])],
            "output": [row(output[:, 2 * i + c]) for c in (0, 1)],
            "feedback_gain": [row(feedback[:, 2 * i + c]) for c in (0, 1)],
        }
        for i in range(len(artifact.blocks))
    ]


def _products(artifact: artifacts.ControllerArtifact) -> HoldProducts:
    """The constant products of the cLQG's two phases (control.hold_products)."""
    return hold_products(
        artifact.output, artifact.feedback_gain, artifact.estimator_gain, artifact.gamma1, artifact.joint_input
    )


def _hold_context(artifact: artifacts.ControllerArtifact, row) -> dict:
    """The small constant products of the cLQG's phases as table rows (control.hold_products)."""
    products = _products(artifact)
    return {
        "output_hold": [row(c) for c in products.output_hold],
        "feedback_hold": [row(k) for k in products.feedback_hold],
        "feedback_estimator": [row(k) for k in products.feedback_estimator],
    }


__all__ = ["clqg", "siso"]
