"""Screening friction records before the identification (paper Section 3.2).

What ``identify`` asks of its records before Eq. 3 is fitted: enough finite samples that
measure something (``check_records``), one joint's radius for type B records
(``joint_radius``), and which of the two regimes a record belongs to — micro-slip for step 1,
stick-slip for step 2 (``classify``, by the record's ``regime`` metadata or by whether it
``slides``).
"""

from __future__ import annotations

import math

import numpy as np

from smartjoint.design.friction.fitting import smoothed_friction
from smartjoint.design.friction.record_quantities import MIN_RADIUS, bound
from smartjoint.design.friction.records import Record, RecordError

# Fewest samples per record: the 11-point Savitzky–Golay window of the friction column and the
# spectrum that finds the excitation frequency need a few times that.
MIN_SAMPLES = 50


def joint_radius(records: list[Record], joint_type: str, radius: float | None) -> float | None:
    """The radius of type B records: ``radius`` if given, else the one every record carries.

    Never a default: a type B record without a radius is refused (Table 1's 11 mm would put
    σ0, F_c and σ2 off by the ratio of the radii).

    Parameters
    ----------
    records : list of Record
        The records of one joint.
    joint_type : str
        'A' or 'B', the type every record has.
    radius : float, optional
        [m]: the radius given by the caller (type B only).

    Returns
    -------
    float or None
        The joint radius [m]; None for type A.

    Raises
    ------
    RecordError
        For a radius given to type A records, one out of range or disagreeing with a record's,
        a type B record without one, or records carrying different radii.
    """
    if joint_type == "A":
        if radius is not None:
            raise RecordError(
                f"identify: radius {radius!r} m given, but the records are type A — a type A joint has no radius"
            )
        return None
    if radius is not None:
        if not (
            isinstance(radius, (int, float)) and math.isfinite(radius) and MIN_RADIUS <= radius <= bound("radius", "B")
        ):
            raise RecordError(f"identify: radius {radius!r} m — allowed: {MIN_RADIUS:g} … {bound('radius', 'B'):g} m")
        for record in records:
            if record.radius is not None and record.radius != radius:
                raise RecordError(
                    f"identify: radius {radius!r} m given, but record {record.name} carries "
                    f"radius = {record.radius!r} m — give one radius"
                )
        return float(radius)
    carried: dict[float, str] = {}
    for record in records:
        if record.radius is None:
            raise RecordError(
                f"{record.name}: type B record without a radius — add '# radius = <r> m' to the record "
                "(or pass the radius to identify / --radius); no default is assumed"
            )
        carried.setdefault(record.radius, record.name)
    if len(carried) > 1:
        (first, one), (second, other) = list(carried.items())[:2]
        raise RecordError(
            f"identify: records {one} (radius {first!r} m) and {other} (radius {second!r} m) are not "
            "of one joint — identify one joint's records at a time"
        )
    return next(iter(carried))


def check_records(records: list[Record]) -> None:
    """One-line errors for records the fit cannot use (too short, nothing measured).

    Parameters
    ----------
    records : list of Record
        The micro-slip and stick-slip records.

    Raises
    ------
    RecordError
        For fewer than ``MIN_SAMPLES`` samples, a velocity or friction column that is not finite
        or zero throughout, a time that is not finite and increasing, or an F_N that is not > 0.
    """
    for record in records:
        if record.time.size < MIN_SAMPLES:
            raise RecordError(
                f"{record.name}: {record.time.size} samples — identify needs at least {MIN_SAMPLES} per record"
            )
        for column in ("sliding_velocity", "friction_force"):
            values = getattr(record, column)
            if not np.all(np.isfinite(values)):
                raise RecordError(f"{record.name}: column {column!r}: not finite — allowed: finite numbers")
            if not np.any(values != 0.0):
                raise RecordError(f"{record.name}: column {column!r} is zero throughout — nothing to identify from")
        if not (np.all(np.isfinite(record.time)) and np.all(np.diff(record.time) > 0.0)):
            raise RecordError(f"{record.name}: column 'time' must be finite and increase")
        if not np.all(np.isfinite(record.normal_force) & (record.normal_force > 0.0)):
            raise RecordError(f"{record.name}: column 'normal_force': F_N must be > 0 and finite")


def slides(record: Record, radius: float | None = None) -> bool:
    """Gross sliding: the element moves by far more than any bristle deflection μ/σ0 could.

    Parameters
    ----------
    record : Record
        Its velocity gives the displacement, its friction and normal force μ.
    radius : float, optional
        [m]: the moment arm r of μ = u_R/(r·F_N) for a type B record that carries none.

    Returns
    -------
    bool
    """
    arm = 1.0 if record.joint_type == "A" else (radius if radius is not None else record.moment_arm)
    # Smoothed: a heavy element's friction column F_exc − m·a carries m·a noise far above μ (type A,
    # 300 kg, 3 % noise: a sliding record read as presliding).
    mu = float(np.max(np.abs(smoothed_friction(record) / (arm * record.normal_force))))
    if record.excitation_force is not None:
        # Even smoothed, m·a noise can put μ far above the friction (300 kg, 3 % noise: μ 8 where
        # it is 1.1, and a record sliding at 4·v_s read as presliding); the friction never
        # exceeds the excitation while sticking, nor the break-away it overcame while sliding.
        mu = min(mu, float(np.max(np.abs(record.excitation_force) / (arm * record.normal_force))))
    displacement = np.ptp(np.cumsum(record.sliding_velocity) * record.sample_time)
    return bool(displacement * 1e4 > mu and displacement > 1e-4)


def classify(record: Record, radius: float | None = None) -> str:
    """'stick-slip' or 'micro-slip': the record's ``regime`` metadata, else whether it slides.

    Parameters
    ----------
    record : Record
        A record with or without ``# regime = …``.
    radius : float, optional
        Passed to `slides` when the record names no regime.

    Returns
    -------
    str
    """
    if "regime" in record.metadata:
        return record.metadata["regime"]
    return "stick-slip" if slides(record, radius) else "micro-slip"


__all__ = ["MIN_SAMPLES", "check_records", "classify", "joint_radius", "slides"]
