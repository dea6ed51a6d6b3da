"""The quantities of a friction record: their units and physically plausible bounds (SI).

``UNITS`` maps every unit a record may be written in to its factor to SI, per kind of
quantity; ``COLUMNS`` gives each known column's kind. ``BOUNDS`` are the plausible magnitudes
per joint type that ``records`` checks every value against (``bound``), ``si_unit`` the SI unit
a quantity is stored in. Type B records give velocities in rad/s and forces as moments in N·m.
"""

from __future__ import annotations

# unit → factor to SI, per quantity kind
UNITS = {
    "time": {"s": 1.0, "ms": 1e-3},
    "velocity": {"m/s": 1.0, "mm/s": 1e-3, "rad/s": 1.0, "mrad/s": 1e-3},
    "force": {"N": 1.0, "kN": 1e3, "N*m": 1.0, "N·m": 1.0, "Nm": 1.0},
    "mass": {"kg": 1.0, "g": 1e-3, "kg*m^2": 1.0, "kg·m²": 1.0, "kg m2": 1.0},
    "length": {"m": 1.0, "mm": 1e-3},
}
COLUMNS = {
    "time": "time",
    "sliding_velocity": "velocity",
    "friction_force": "force",
    "excitation_force": "force",
    "normal_force": "force",
}

# Physically plausible magnitudes in SI units, per joint type: (type A, type B). Generous for
# a bolted or clamped friction joint of a truss (the paper's joints: F_N 200–400 N, velocities
# of mm/s … m/s, r = 11 mm), but they catch unit slips (kN written as N × 1000, µm as m) and
# values such as 1e308 that would overflow the fit.
BOUNDS = {
    "time": (1e6, 1e6),  # |t| [s]: 11.6 days
    "time_step": (1e-9, 1e-9),  # smallest sample spacing [s]: 1 GHz sampling
    "sliding_velocity": (100.0, 1e4),  # |v| [m/s] (type A), |ω| [rad/s] (type B, ≈ 95 000 rpm)
    "friction_force": (1e7, 1e5),  # |u_R| [N] (type A), [N·m] (type B)
    "excitation_force": (1e7, 1e5),
    "normal_force": (1e6, 1e6),  # 1 mN ≤ F_N ≤ 1 MN (a fully preloaded M36 bolt is ≈ 0.6 MN)
    "inertia": (1e6, 1e4),  # 0 ≤ m ≤ 1000 t (type A), ≤ 1e4 kg·m² (type B)
    "radius": (10.0, 10.0),  # 1e-4 m ≤ r ≤ 10 m (type B only)
}
MIN_RADIUS = 1e-4  # [m]
MIN_NORMAL_FORCE = 1e-3  # [N]: μ = u_R/F_N is meaningless below (and a zero F_N divides by zero)
_SI = {
    "time": "s",
    "sliding_velocity": ("m/s", "rad/s"),
    "friction_force": ("N", "N*m"),
    "excitation_force": ("N", "N*m"),
    "normal_force": "N",
    "inertia": ("kg", "kg*m^2"),
    "radius": "m",
}


def bound(quantity: str, joint_type: str) -> float:
    """The plausible magnitude limit of ``quantity`` (a ``BOUNDS`` key) for a joint type, in SI.

    Parameters
    ----------
    quantity : str
        A key of ``BOUNDS``.
    joint_type : str
        'A' or 'B'.

    Returns
    -------
    float
    """
    return BOUNDS[quantity][0 if joint_type == "A" else 1]


def si_unit(quantity: str, joint_type: str) -> str:
    """The SI unit a record quantity is stored in, for a joint type (type B: angular, moments).

    Parameters
    ----------
    quantity : str
        A column or metadata name.
    joint_type : str
        'A' or 'B'.

    Returns
    -------
    str
    """
    unit = _SI[quantity]
    return unit if isinstance(unit, str) else unit[0 if joint_type == "A" else 1]


__all__ = ["BOUNDS", "COLUMNS", "MIN_NORMAL_FORCE", "MIN_RADIUS", "UNITS", "bound", "si_unit"]
