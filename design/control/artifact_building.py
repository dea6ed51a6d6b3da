"""Building the controller artefact from a design: the controlled joints, the LQG designed on
the reduced modal model, the limits and piezo calibration of [control] and the safe state and
plausibility ranges of [safety] (``docs/controller-artifact.md``)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control import artifact_schema, tuning
from smartjoint.design.control.artifact import ControllerArtifact, installed_version
from smartjoint.design.control.artifact_schema import SCHEMA_VERSION, field_error
from smartjoint.design.control.lqg import LqgDesign
from smartjoint.design.friction.model import joint_parameters
from smartjoint.design.structure.sections import MAX_DISPLACEMENT


def _per_joint(field: str, value, joints: tuple[str, ...]) -> np.ndarray:
    """A number for every joint or one per joint (broadcast)."""
    array = np.array(value, dtype=float)
    if array.ndim == 0:
        return np.full(len(joints), float(array))
    if array.shape != (len(joints),):
        raise field_error(
            field, value, f"expected a number or {len(joints)} numbers, one per joint ({', '.join(joints)})"
        )
    return array


def _check_match(design, model, lqg: LqgDesign, joints: tuple[str, ...], sensors: tuple[str, ...]) -> None:
    """The LQG and the model fit the design: its controlled joints and sensors, in that order,
    the model's coordinates and the design's sample time."""
    control = design.control
    n = lqg.blocks.shape[0]
    if lqg.joint_input.shape[1:] != (len(joints),):
        raise ModelError(
            f"lqg.joint_input: shape {lqg.joint_input.shape} — expected {len(joints)} columns, "
            f"one per controlled joint ({', '.join(joints) or 'none'})"
        )
    if lqg.output.shape[:1] != (len(sensors),):
        raise ModelError(
            f"lqg.output: shape {lqg.output.shape} — expected {len(sensors)} rows, "
            f"one per sensor ({', '.join(sensors) or 'none'})"
        )
    if tuple(model.joint_names) != joints or tuple(model.sensor_names) != sensors:
        raise ModelError(
            f"model: joints {list(model.joint_names)}, sensors {list(model.sensor_names)} — the design "
            f"controls joints {list(joints)} with sensors {list(sensors)}, in this order"
        )
    if model.n_coordinates != n or not np.array_equal(model.joint_input, lqg.joint_input):
        raise ModelError(
            f"lqg: {n} coordinates — not designed on this model ({model.n_coordinates} coordinates, "
            "joint_input must be equal)"
        )
    if lqg.sample_time != control.sample_time:
        raise ModelError(
            f"lqg.sample_time: {lqg.sample_time!r} s — the design's [control] sample_time is {control.sample_time!r} s"
        )


def law_fields(design, joints: tuple[str, ...], settings=None) -> dict:
    """The artefact fields of every law's settings (``Law.artifact`` names each key's field).

    Parameters
    ----------
    design : Design
    joints : tuple of str
        The controlled joints, in artefact order (a per-joint setting has one value each).
    settings : dict, optional
        Law name → setting key → value (``Study.settings()``); a law or a setting left out gets
        the design file's value or its default (``tuning.tuned``, nothing tuned).

    Returns
    -------
    dict
        Artefact field → value.
    """
    settings = dict(settings or {})
    fields = {}
    for law in law_registry.LAWS.values():
        if law.name in settings:
            values = {**tuning.untuned(law, design), **settings[law.name]}
        else:
            values = tuning.tuned(law, design).settings
        by_key = dict(law.artifact)
        for setting in law.settings:
            field, value = by_key[setting.key], values[setting.key]
            fields[field] = _per_joint(field, value, joints) if setting.per_joint else float(value)
    return fields


def from_design(design, model, lqg: LqgDesign, settings=None) -> ControllerArtifact:
    """The artefact of ``design`` with the LQG ``lqg`` designed on the reduced modal ``model``.

    Controlled joints: ``design.control.joints`` in that order, else every joint of the design;
    the model's joint/sensor order must be that order.

    Parameters
    ----------
    design : Design
        The design (limits, piezo calibration, [safety]).
    model : ModalModel
        The reduced modal model the LQG was designed on.
    lqg : LqgDesign
        The discrete LQG (Eq. 33).
    settings : dict, optional
        Each law's settings, law → key → value (:func:`law_fields`; ``Study.settings()``).

    Returns
    -------
    ControllerArtifact
        Validated.
    """
    control = design.control
    joints = tuple(control.joints) if control.joints is not None else tuple(j.name for j in design.joints)
    sensors = tuple(s.name for s in design.sensors)
    _check_match(design, model, lqg, joints, sensors)
    return ControllerArtifact(
        schema_version=SCHEMA_VERSION,
        name=design.name,
        sample_time=lqg.sample_time,
        joint_names=joints,
        sensor_names=sensors,
        normal_force_min=_per_joint("normal_force_min", control.normal_force_min, joints),
        normal_force_max=_per_joint("normal_force_max", control.normal_force_max, joints),
        **law_fields(design, joints, settings),
        blocks=lqg.blocks,
        gamma0=lqg.gamma0,
        gamma1=lqg.gamma1,
        joint_input=lqg.joint_input,
        output=lqg.output,
        feedback_gain=lqg.feedback_gain,
        estimator_gain=lqg.estimator_gain,
        modal_frequencies=np.asarray(model.omega, dtype=float) / (2.0 * math.pi),
        piezo_capacitance=control.piezo_capacitance,
        piezo_force_per_volt=control.piezo_force_per_volt,
        piezo_preload=control.piezo_preload,
        **safety_fields(design, joints),
        **friction_fields(design, joints),
        design_source=Path(str(design.source)).name,
        design_sha256=design.sha256,
        package_version=installed_version(),
    )


def friction_fields(design, joints: tuple[str, ...]) -> dict:
    """The controlled joints' types and the LuGre parameters the design was made with.

    Parameters
    ----------
    design : Design
        The design (identified parameters in place where ``smartjoint run`` identified them).
    joints : tuple of str
        The controlled joints, in artefact order.

    Returns
    -------
    dict
        ``joint_types``, ``friction_parameters`` (l × 6), ``friction_radius`` and ``friction_sources``.
    """
    by_name = {j.name: j for j in design.joints}
    laws = dict(zip([j.name for j in design.joints], joint_parameters(design)))
    held = artifact_schema.FRICTION_MODEL
    for name in joints:
        if laws[name].model != held.name:
            raise ModelError(
                f"joints.{name}.friction: model {laws[name].model!r} — the controller artefact (schema "
                f"{SCHEMA_VERSION}) records {held.display} parameters only (friction.parameters)"
            )
    sources = []
    for name in joints:
        friction = design.joint_friction(by_name[name])
        in_file = bool(friction.sha256) and Path(friction.source).is_file()
        sources.append(Path(friction.source).name if in_file else friction.source)  # never a folder
    return {
        "joint_types": tuple(by_name[name].type for name in joints),
        "friction_parameters": np.array([list(laws[name].values().values()) for name in joints], dtype=float).reshape(
            len(joints), len(artifact_schema.FRICTION_MODEL.parameters)
        ),
        "friction_radius": np.array([laws[name].radius or 0.0 for name in joints], dtype=float),
        "friction_sources": tuple(sources),
    }


# Default displacement plausibility: 5 % of the truss's largest extent, at most MAX_DISPLACEMENT
# (what the TIP_SENSORS frame carries: on a 1000-bay mast 5 % would be 50 m).
DISPLACEMENT_FRACTION = 0.05


def safety_fields(design, joints: tuple[str, ...]) -> dict:
    """The artefact's safe state and plausibility ranges from the design's ``[safety]``.

    Parameters
    ----------
    design : Design
        The design.
    joints : tuple of str
        The controlled joints, in artefact order.

    Returns
    -------
    dict
        The safety fields of the schema.
    """
    control, safety = design.control, design.safety
    low = _per_joint("normal_force_min", control.normal_force_min, joints)
    high = _per_joint("normal_force_max", control.normal_force_max, joints)
    if safety.safe_normal_force == "max":
        safe = high
    elif safety.safe_normal_force == "min":
        safe = low
    else:
        safe = _per_joint("safe_normal_force", safety.safe_normal_force, joints)
    margin = safety.normal_force_margin
    displacement = safety.displacement_limit
    if displacement is None:
        positions = np.array([n.position for n in design.nodes.values()], dtype=float).reshape(-1, 3)
        extent = float(np.max(np.ptp(positions, axis=0))) if len(positions) else 0.0
        displacement = min(DISPLACEMENT_FRACTION * extent, MAX_DISPLACEMENT) if extent > 0 else 1.0
    quantities = tuple(s.quantity for s in design.sensors)
    return dict(
        sensor_quantities=quantities,
        safe_normal_force=safe,
        sliding_velocity_limit=np.full(len(joints), safety.sliding_velocity_limit),
        friction_force_limit=safety.friction_coefficient_limit * (high + margin * high),
        measured_normal_force_min=-margin * high,
        measured_normal_force_max=high + margin * high,
        sensor_limit=np.array(
            [displacement if q == "displacement" else safety.velocity_limit for q in quantities], dtype=float
        ),
        amplifier_temperature_limit=safety.amplifier_temperature_limit,
        amplifier_current_limit=safety.amplifier_current_limit,
        tracking_tolerance=safety.tracking_tolerance,
        actuation_tolerance=safety.actuation_tolerance * high,
        timeout_cycles=safety.timeout_cycles,
        recovery_cycles=safety.recovery_cycles,
    )


__all__ = [
    "DISPLACEMENT_FRACTION",
    "from_design",
    "safety_fields",
]
