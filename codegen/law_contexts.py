"""What each law's templates see beyond the common context (``generate.render``): one function
per law of ``common.law_registry``, named by its entry (``codegen``), ``function(artifact, lit,
row) -> dict`` with ``lit`` a number's C literal and ``row`` an array's, in the build's scalar type.
"""

from __future__ import annotations

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.control import artifact as artifacts
from smartjoint.design.control.filter import FEEDBACK_LIMIT
from smartjoint.design.control.hold_products import HoldProducts, step_products
from smartjoint.design.control.realisation import Realisation, of_artifact


def siso(artifact: artifacts.ControllerArtifact, lit, row) -> dict:
    """The SISO law's context (Eq. 30–31): ε and the plausible sliding velocity per joint."""
    return {
        "boundary_layer": row(artifact.siso_boundary_layer),
        "sliding_velocity_limit": row(artifact.sliding_velocity_limit),
    }


# Up to this many joints the cLQG's sums over joints are written out term by term (the fastest
# step, and the code of a few joints); beyond it they are loops over index tables of the same
# terms in the same order, so the code stays the same size per joint and the numbers are the
# same bit for bit (benchmarks/joint_scaling.py).
UNROLLED_JOINTS = 4


def clqg(artifact: artifacts.ControllerArtifact, lit, row) -> dict:
    """The clipped LQG's context (Eq. 33–34) in its realisation (``control.realisation``): the
    joint and sensor channels, the coordinate groups with a table row per coordinate, and the
    small constant products of the two phases with their nonzero entries; for more than
    ``UNROLLED_JOINTS`` joints also the index tables of the loops (``looped``)."""
    realisation = of_artifact(artifact)
    products = _products(realisation)
    count = len(artifact.joint_names)
    if max(count, len(artifact.sensor_names)) > 255:
        raise ModelError(
            f"joints: {count}, sensors: {len(artifact.sensor_names)} — the generated cLQG indexes them "
            "with one byte: at most 255 each"
        )
    joint_labels = _labels(realisation.joints, artifact.joint_names)
    sensor_labels = _labels(realisation.sensors, artifact.sensor_names)
    return {
        "coordinates": int(realisation.blocks.shape[0]),
        "joint_channels": realisation.joints.terms(),
        "joint_forces": realisation.joints.back_terms(),
        "sensor_channels": realisation.sensors.terms(),
        "adapted": realisation.adapted,
        "groups": [_group(realisation, products, g, lit, row, joint_labels, sensor_labels) for g in realisation.groups],
        "output_hold": [row(c) for c in products.output_hold],
        "feedback_hold": [row(k) for k in products.feedback_hold],
        "feedback_estimator": [row(k) for k in products.feedback_estimator],
        # The entries the phases sum: a product's exact zeros (other parity) are skipped.
        "output_hold_terms": [np.flatnonzero(c).tolist() for c in products.output_hold],
        "feedback_hold_terms": [np.flatnonzero(k).tolist() for k in products.feedback_hold],
        "feedback_estimator_terms": [np.flatnonzero(k).tolist() for k in products.feedback_estimator],
        "looped": count > UNROLLED_JOINTS,
        "channel_table": {
            "joint_channel": _channel_rows(realisation.joints.terms()),
            "joint_force": _channel_rows(realisation.joints.back_terms()),
            "sensor_channel": _channel_rows(realisation.sensors.terms()),
        },
        "term_tables": {
            "feedback_hold": _term_table(products.feedback_hold, row),
            "feedback_estimator": _term_table(products.feedback_estimator, row),
            "output_hold": _term_table(products.output_hold, row),
        },
        "clqg_boundary_layer": lit(artifact.clqg_boundary_layer),
        "sensor_limit": row(artifact.sensor_limit),
        "feedback_limit": lit(FEEDBACK_LIMIT),
    }


def _channel_rows(terms) -> str:
    """A channel table's initialisers: {first, second, sign}, sign 0 for a value alone."""
    return ", ".join(f"{{{a}, {a if b < 0 else b}, {0 if b < 0 else int(sign)}}}" for a, b, sign in terms)


def _term_table(matrix, row) -> dict:
    """The nonzero entries of each row of ``matrix`` as the loops read them: row r's are
    ``gain[k]`` with ``index[k]``, k = ``first[r]`` … ``first[r + 1] − 1``, in column order (the
    written-out form's). ``gain`` and ``index`` are never empty: C99 has no zero-length array, so
    an empty table holds one unread 0."""
    matrix = np.asarray(matrix, dtype=float)
    rows = [np.flatnonzero(r).tolist() for r in matrix]
    first = np.concatenate([[0], np.cumsum([len(r) for r in rows])]).astype(int).tolist()
    index = [k for r in rows for k in r]
    gain = [matrix[r, k] for r, columns in enumerate(rows) for k in columns]
    return {
        "first": ", ".join(map(str, first)),
        "index": ", ".join(map(str, index or [0])),
        "gain": row(gain or [0.0]),
        "count": max(len(index), 1),
    }


def _title(realisation: Realisation, group) -> str:
    """The group's comment: which coordinates, and their parity when the mirror gives one."""
    if len(realisation.groups) == 1:
        return "The model one coordinate i at a time"
    where = f"Coordinates {group.start} to {group.stop - 1} of the realisation"
    parity = {"even": "even under the mirror (paired joints act alike)", "odd": "odd under the mirror"}
    return f"{where}, {parity[group.name]}" if group.name in parity else where


def _labels(channels, names) -> list[str]:
    """A channel's name for the comments: "A1 + A2", "A1 - A2", or the joint's (sensor's) own."""
    return [
        names[a] if b < 0 else f"{names[a]} {'+' if sign > 0 else '-'} {names[b]}" for a, b, sign in channels.terms()
    ]


def _products(realisation: Realisation) -> HoldProducts:
    """The constant products of the cLQG's two phases in the realisation, gains negated
    (control.step_products)."""
    return step_products(realisation)


def _group(realisation: Realisation, products: HoldProducts, group, lit, row, joint_labels, sensor_labels) -> dict:
    """One coordinate group: its channels and one initialiser per coordinate, the fields in the
    order of the template's struct — Φ_i by columns, γ0, γ1, E'_i over the group's joints, M'
    rows 2i and 2i + 1 by sensor, C' over the (sensor, component) terms, and (K' − K'M'C') on
    each of the two states over the group's feedback joints (the state's component outermost)."""
    r = realisation
    output_terms = [(sensor, c) for sensor, components in group.outputs for c in components]
    rotation = realisation.rotation
    span = range(group.start, group.stop)
    rotation = realisation.rotation
    unit_gamma1 = all(r.gamma1[i, 0] == 1.0 for i in span)
    # Terms of C' that are 1 in every coordinate of the group (control.realisation.real_jordan): added, not stored.
    unit_outputs = [all(r.output[s, 2 * i + c] == 1.0 for i in span) for s, c in output_terms]
    stored_outputs = [t for t, unit in zip(output_terms, unit_outputs) if not unit]
    rows = []
    for i in span:
        if rotation:  # Φ_i' = [[α, −β], [β, α]]
            fields = [lit(r.blocks[i][0, 0]), lit(r.blocks[i][1, 0])]
        else:
            fields = ["{" + ", ".join("{" + row(r.blocks[i][:, k]) + "}" for k in (0, 1)) + "}"]
        fields.append("{" + row(r.gamma0[i]) + "}")
        fields.append(lit(r.gamma1[i, 1]) if unit_gamma1 else "{" + row(r.gamma1[i]) + "}")
        if group.joints:
            fields.append("{" + row(r.joint_input[i, list(group.joints)]) + "}")
        if group.sensors:
            pairs = (r.estimator_gain[2 * i : 2 * i + 2, s] for s in group.sensors)
            fields.append("{" + ", ".join("{" + row(p) + "}" for p in pairs) + "}")
        if stored_outputs:
            fields.append("{" + row([r.output[s, 2 * i + c] for s, c in stored_outputs]) + "}")
        if group.feedback_joints:
            gains = products.feedback_prior[list(group.feedback_joints)]
            fields.append("{" + ", ".join("{" + row(gains[:, 2 * i + c]) + "}" for c in (0, 1)) + "}")
        rows.append("{" + ", ".join(fields) + "}")
    stored = iter(range(len(stored_outputs)))
    return {
        "name": group.name,
        "start": group.start,
        "stop": group.stop,
        "joints": list(group.joints),
        "feedback_joints": list(group.feedback_joints),
        "feedback_identity": list(group.feedback_joints) == list(range(len(group.feedback_joints))),
        "sensors": list(group.sensors),
        "output_terms": [(s, c, None if unit else next(stored)) for (s, c), unit in zip(output_terms, unit_outputs)],
        "stored_outputs": len(stored_outputs),
        "rotation": rotation,
        "unit_gamma1": unit_gamma1,
        "rows": rows,
        "title": _title(realisation, group),
        "joint_labels": ", ".join(joint_labels[j] for j in group.joints),
        "feedback_labels": ", ".join(joint_labels[j] for j in group.feedback_joints),
        "sensor_labels": ", ".join(sensor_labels[s] for s in group.sensors),
        "output_labels": [(s, c, sensor_labels[s]) for (s, c), unit in zip(output_terms, unit_outputs) if not unit],
    }


__all__ = ["clqg", "siso"]
