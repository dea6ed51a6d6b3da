"""Screening friction records before the identification (paper Section 3.2).

What ``identify`` asks of its records before Eq. 3 is fitted: enough finite samples that
measure something (``check_records``), one joint's radius for type B records
(``joint_radius``), a friction coefficient a metal contact can have
(``check_friction_coefficient``), and which of the two regimes a record belongs to — micro-slip
for step 1, stick-slip for step 2 (``classify``, by the record's ``regime`` metadata or by
whether it ``slides``).

A record that fails a check is refused in one line naming it, what is wrong and what is
allowed (``RecordError``): identify never drops a record silently, nor fits the rest without it.
"""

from __future__ import annotations

import math

import numpy as np

from smartjoint.design.friction.fitting import dominant_frequency, smoothed_friction
from smartjoint.design.friction.record_quantities import MIN_RADIUS, bound
from smartjoint.design.friction.records import Record, RecordError

# Fewest samples per record: the 11-point Savitzky–Golay window of the friction column and the
# spectrum that finds the excitation frequency need a few times that.
MIN_SAMPLES = 50
# The largest friction coefficient μ = |u_R|/(r·F_N) a record may show. Dry friction of metal
# contacts stays below about 1.5 (steel on steel in air 0.5–0.8, clean aluminium up to about
# 1.4; the firmware's [safety] friction_coefficient_limit defaults to 1.5 for the same reason).
# 2 leaves a third above that for measurement noise and the damping force σ1·φ̇ at the
# break-away, and lies far below the slips it catches: a normal force in daN read as N (×10), a
# force column in kN read as N or a friction moment in N·mm (×1000), an inertia in g read as kg
# (F_exc − m·a of a sliding record then is mostly m·a), μ = 100. Measured
# (`friction_coefficient_peak`) on every record `rig --campaign` writes — types A and B, Table 1
# and a joint at the top of metal contacts (F_c + F_d = 1.5: type A's F_c, F_d doubled, type
# B's 1.3 and 0.2), priors ×0.5 … ×2, five seeds: Table 1 peaks at 0.69 (type A, ≤ 3 % noise) and
# 0.73 (10 %), 2.7× below the bound; F_c + F_d = 1.5 at 1.41 (≤ 3 %) and 1.54 (10 %, type B),
# 1.3× below. tests/test_records.py holds these.
MAX_FRICTION_COEFFICIENT = 2.0
# A record with its excitation force has the friction column F_exc − m·a, the acceleration
# differentiated from the noisy velocity: sample by sample its m·a noise is far above the
# friction (300 kg, 3 % noise: μ 8 where it is 1.1; Table 1, 3 % noise: 6.5 where it is 0.74).
# Averaged over a window of duration T the m·a term is m·Δv/T, its noise divided by T, while the
# friction keeps one sign for about half an excitation period: over a quarter period centred on
# its peak it keeps 0.9 of a sine's peak and 0.93 of a stick-slip's (Table 1 type A: 0.68 of
# 0.74). A tenth of the period left the fastest rungs (3.4× the break-away) at μ 1.2 for 3 %
# noise. A record with a friction column of its own is screened sample by sample.
COEFFICIENT_WINDOW = 0.25  # of the excitation period
SAVITZKY_GOLAY_WINDOW = 11  # samples: the window of the derived friction column (records.friction_from_excitation)


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


def check_records(records: list[Record], radius: float | None = None) -> None:
    """One-line errors for records the fit cannot use (too short, nothing measured, a friction
    coefficient no metal contact has).

    Parameters
    ----------
    records : list of Record
        The micro-slip and stick-slip records.
    radius : float, optional
        [m]: the moment arm of type B records that carry none (``joint_radius``).

    Raises
    ------
    RecordError
        For fewer than ``MIN_SAMPLES`` samples, a velocity or friction column that is not finite
        or zero throughout, a time that is not finite and increasing, an F_N that is not > 0, or
        a friction coefficient above ``MAX_FRICTION_COEFFICIENT`` (``check_friction_coefficient``).
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
        check_friction_coefficient(record, radius)


def friction_coefficient_peak(record: Record, radius: float | None = None) -> tuple[float, float, int]:
    """The record's largest friction coefficient μ = |u_R|/(r·F_N), from its friction column.

    From the friction force only, never the excitation (which carries the inertia force m·a).
    A friction column F_exc − m·a (a record with its excitation force and inertia) is averaged
    over ``COEFFICIENT_WINDOW`` of the excitation period first (at least the 11 samples its
    acceleration is differentiated over): its m·a noise is not friction. Any other friction
    column counts sample by sample.

    Parameters
    ----------
    record : Record
        A record whose columns are finite, with F_N > 0 (``check_records``).
    radius : float, optional
        [m]: the moment arm r of a type B record that carries none.

    Returns
    -------
    tuple
        (μ at its peak, the time of the peak [s] — the middle of the window, the window's samples).
    """
    arm = 1.0 if record.joint_type == "A" else (radius if radius is not None else record.moment_arm)
    friction, normal = record.friction_force, record.normal_force
    window = 1
    if record.excitation_force is not None and record.inertia:
        frequency = dominant_frequency(record.excitation_force, record.sample_time)
        window = round(COEFFICIENT_WINDOW / (frequency * record.sample_time)) if frequency > 0.0 else friction.size
        window = min(max(window, SAVITZKY_GOLAY_WINDOW), friction.size)
        friction, normal = (_moving_average(x, window) for x in (friction, normal))
    mu = np.abs(friction) / (arm * normal)
    peak = int(np.argmax(mu))
    return float(mu[peak]), float(record.time[peak + window // 2]), window


def _moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """The means of ``window`` consecutive samples (O(n) by a running sum; n − window + 1 of them)."""
    total = np.concatenate(([0.0], np.cumsum(values)))
    return (total[window:] - total[:-window]) / window


def check_friction_coefficient(record: Record, radius: float | None = None, source: str | None = None) -> None:
    """One-line ``RecordError`` for a friction coefficient above ``MAX_FRICTION_COEFFICIENT``.

    Parameters
    ----------
    record : Record
        A record whose columns are finite, with F_N > 0.
    radius : float, optional
        [m]: the moment arm of a type B record that carries none.
    source : str, optional
        The record's file, named in the message (default: the record's name).

    Raises
    ------
    RecordError
        Naming the record, the time of the peak, μ there and the bound.
    """
    mu, time, window = friction_coefficient_peak(record, radius)
    if mu <= MAX_FRICTION_COEFFICIENT:
        return
    averaged = "" if window == 1 else f", averaged over {window} samples = {window * record.sample_time:.3g} s"
    ratio = "|u_R|/(r·F_N)" if record.joint_type == "B" else "|F_R|/F_N"
    raise RecordError(
        f"{source or record.name}: friction coefficient {ratio} = {mu:.4g} at t = {time:.6g} s (its peak{averaged}) "
        f"— allowed: <= {MAX_FRICTION_COEFFICIENT:g} (dry friction of metal contacts stays below about 1.5; check "
        "the units of the force columns and the inertia)"
    )


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


__all__ = [
    "COEFFICIENT_WINDOW",
    "MAX_FRICTION_COEFFICIENT",
    "MIN_SAMPLES",
    "check_friction_coefficient",
    "check_records",
    "classify",
    "friction_coefficient_peak",
    "joint_radius",
    "slides",
]
