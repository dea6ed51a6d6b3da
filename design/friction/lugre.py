"""LuGre friction law of the joints (paper Eq. 1–2; Canudas de Wit et al. 1995).

Bristle deflection φ and friction force with the normal force F_N as a time-varying input::

    φ̇ = f(v, φ) = v − σ0·g(v)·φ,   g(v) = |v| / (F_c + F_d·exp(−(v/v_s)²))        (Eq. 1)
    u_R = F_N·μ(v, φ),   μ = σ0·φ + σ1·φ̇ + σ2·v                                  (Eq. 2)

The parameters are per unit normal force (Table 1: F_c, F_d dimensionless, σ0 in 1/m …); a
type B (rotational) joint gives the moment M_R = r·F_N·μ with v an angular velocity.

Discrete step (:func:`step`): for a velocity held constant over the step, Eq. 1 is linear in
φ and has the exact solution

    φ(t+h) = φ_ss + (φ(t) − φ_ss)·exp(−σ0·g(v)·h),   φ_ss = v/(σ0·g(v)) = sign(v)·(F_c + F_d·e^{−(v/v_s)²})/σ0

(φ(t+h) = φ(t) for v = 0). The update is a convex combination of φ(t) and φ_ss, so it is
unconditionally stable and never leaves [−φ_max, φ_max], φ_max = (F_c + F_d)/σ0, for any step h
and any σ0 — where explicit Euler needs h < 2/(σ0·g) (microseconds at Table 1 values). Its
accuracy for a time-varying v: with v taken at the step midpoint the local error is O(h³)
and the global error O(h²) (second order); with v held from the step start (zero-order hold)
it is first order. Both are exact for constant v. g(v) has a kink at v = 0, so a step
that contains a velocity reversal has a local error O(h²) (tests/test_lugre.py measures
both orders against a Radau reference).

The functions of Eq. 1–2 take the joint's parameters ``p`` (:class:`LuGreParameters`), the
velocity v [m/s] and, where they need it, the bristle deflection φ [m] (type B: [rad/s], [rad]),
each a number or an array (elementwise: several joints or samples at once), and return a number
or an array; each docstring says what it reads of ``p``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from smartjoint.common.friction_registry import LUGRE
from smartjoint.design.friction.record_quantities import bound


@dataclass(frozen=True)
class LuGreParameters:
    """LuGre parameters per unit normal force (paper Table 1 units): the parameter set of the
    registry's ``lugre`` model (``common/friction_registry.py``), its fields its keys."""

    model: ClassVar[str] = LUGRE.name

    sigma0: float  # bristle stiffness σ0 [1/m] (type B: [1/rad])
    sigma1: float  # bristle damping σ1 [s/m]
    sigma2: float  # viscous friction σ2 [s/m]
    coulomb: float  # F_c (dimensionless friction coefficient)
    stribeck: float  # F_d = F_s − F_c, Stribeck excess
    stribeck_velocity: float  # v_s [m/s] (type B: [rad/s])
    radius: float | None = None  # r [m] of a type B joint: moment = r·F_R

    def __post_init__(self):
        for parameter in LUGRE.parameters:
            value = getattr(self, parameter.key)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0.0):
                raise ValueError(f"LuGre parameter {parameter.key}: {value!r} — must be a finite number >= 0")
            if value <= 0.0 and not parameter.may_be_zero:
                raise ValueError(f"LuGre parameter {parameter.key}: {value!r} — must be > 0")
        if self.radius is not None and not (math.isfinite(self.radius) and self.radius > 0.0):
            raise ValueError(f"LuGre parameter radius: {self.radius!r} — must be > 0 for a type B joint")

    @property
    def max_deflection(self) -> float:
        """φ_max = (F_c + F_d)/σ0: no solution of Eq. 1 started inside leaves [−φ_max, φ_max]."""
        return (self.coulomb + self.stribeck) / self.sigma0

    @property
    def moment_arm(self) -> float:
        """Factor from F_N·μ to the generalised force u_R: r for type B, 1 for type A."""
        return self.radius if self.radius is not None else 1.0

    def values(self) -> dict[str, float]:
        """The parameters by key, in the registry's order (the radius apart)."""
        return {key: getattr(self, key) for key in LUGRE.keys}


Parameters = LuGreParameters  # the model's parameter set (``design.friction.model.FrictionLaw``)


# Paper Table 1 (identified on the isolated joints).
TYPE_A = LuGreParameters(sigma0=1.42e5, sigma1=0.02, sigma2=0.01, coulomb=0.61, stribeck=0.14, stribeck_velocity=0.01)
TYPE_B = LuGreParameters(
    sigma0=6.5e4, sigma1=0.02, sigma2=0.01, coulomb=0.49, stribeck=0.08, stribeck_velocity=0.02, radius=0.011
)
TABLE_1 = {"A": TYPE_A, "B": TYPE_B}
# Canudas de Wit et al. (1995) reference set, with F_N = 1 N: forces in N.
CANUDAS_1995 = LuGreParameters(
    sigma0=1e5, sigma1=math.sqrt(1e5), sigma2=0.4, coulomb=1.0, stribeck=0.5, stribeck_velocity=1e-3
)


# The rig's plausible ranges per unit normal force (type A, type B): (lower, upper, lower
# allowed). Table 1 sits well inside; outside, the record bounds would be left or the rig's
# 20 kHz sampling could not follow the bristles.
PLAUSIBLE = {
    "sigma0": ((0.0, 1e10, False), (0.0, 1e10, False)),
    "sigma1": ((0.0, 1e4, True), (0.0, 1e4, True)),
    "sigma2": ((0.0, 1e4, True), (0.0, 1e4, True)),
    "coulomb": ((0.0, 10.0, False), (0.0, 10.0, False)),
    "stribeck": ((0.0, 10.0, True), (0.0, 10.0, True)),
    "stribeck_velocity": ((0.0, bound("sliding_velocity", "A"), False), (0.0, bound("sliding_velocity", "B"), False)),
}


def breakaway_coefficient(p: LuGreParameters) -> float:
    """F_s = F_c + F_d: the static friction coefficient, the break-away level per unit r·F_N.

    Reads F_c and F_d of ``p``.
    """
    return p.coulomb + p.stribeck


def stribeck_level(p: LuGreParameters, velocity):
    """F_c + F_d·exp(−(v/v_s)²): the steady sliding friction coefficient without viscous part
    (dimensionless).

    Reads F_c, F_d and v_s of ``p``; the arguments as in the module docstring.
    """
    return p.coulomb + p.stribeck * np.exp(-((np.asarray(velocity, dtype=float) / p.stribeck_velocity) ** 2))


def g(p: LuGreParameters, velocity):
    """g(v) of Eq. 1 [1/s per unit φ·σ0]: |v| / (F_c + F_d·exp(−(v/v_s)²)), zero at v = 0.

    Reads the Stribeck level of ``p`` (`stribeck_level`); the arguments as in the module docstring.
    """
    return np.abs(velocity) / stribeck_level(p, velocity)


def rhs(p: LuGreParameters, velocity, deflection):
    """φ̇ = f(v, φ) of Eq. 1.

    Reads σ0 and g(v) of ``p``; the arguments as in the module docstring.
    """
    return velocity - p.sigma0 * g(p, velocity) * deflection


def rhs_jacobian(p: LuGreParameters, velocity, deflection):
    """Analytic partial derivatives (∂f/∂φ, ∂f/∂v) of Eq. 1, a tuple.

    Reads σ0, and F_c, F_d, v_s of ``p`` for ∂g/∂v; the arguments as in the module docstring.
    """
    v = np.asarray(velocity, dtype=float)
    level = stribeck_level(p, v)
    d_level = -2.0 * v / p.stribeck_velocity**2 * (level - p.coulomb)
    d_g = (np.sign(v) * level - np.abs(v) * d_level) / level**2
    return -p.sigma0 * np.abs(v) / level, 1.0 - p.sigma0 * d_g * deflection


def friction_coefficient(p: LuGreParameters, velocity, deflection):
    """μ(v, φ) = σ0·φ + σ1·φ̇ + σ2·v of Eq. 2.

    Reads σ0, σ1, σ2 of ``p``, and f of Eq. 1 for φ̇; the arguments as in the module docstring.
    """
    return p.sigma0 * deflection + p.sigma1 * rhs(p, velocity, deflection) + p.sigma2 * velocity


def friction_force(p: LuGreParameters, velocity, deflection, normal_force):
    """Generalised friction force u_R = r·F_N·μ (r = 1 for type A), Eq. 2.

    Parameters
    ----------
    p : LuGreParameters
        μ of Eq. 2 and the moment arm r.
    velocity, deflection : float or ndarray
        v and φ [m/s, m] (type B: [rad/s, rad]); arrays work elementwise.
    normal_force : float or ndarray
        F_N [N].

    Returns
    -------
    float or ndarray
        u_R [N] (type B: the moment [N·m]).
    """
    return p.moment_arm * normal_force * friction_coefficient(p, velocity, deflection)


def steady_state_deflection(p: LuGreParameters, velocity):
    """φ_ss(v) = sign(v)·(F_c + F_d·e^{−(v/v_s)²})/σ0 (0 at v = 0): the deflection of steady sliding.

    Reads σ0 and the Stribeck level of ``p``; the arguments as in the module docstring.
    """
    return np.sign(velocity) * stribeck_level(p, velocity) / p.sigma0


def steady_state_coefficient(p: LuGreParameters, velocity):
    """Steady sliding μ_ss(v) = sign(v)·(F_c + F_d·e^{−(v/v_s)²}) + σ2·v: the friction curve of
    steady sliding at the velocity v.

    Reads σ2 and the Stribeck level of ``p``; the arguments as in the module docstring.
    """
    return np.sign(velocity) * stribeck_level(p, velocity) + p.sigma2 * np.asarray(velocity, dtype=float)


def step(p: LuGreParameters, deflection, velocity, dt: float):
    """φ after a step ``dt`` with ``velocity`` held constant: the exact solution of Eq. 1.

    Pass the midpoint velocity for second order accuracy (see the module docstring).
    Works elementwise on arrays (several joints at once).

    Parameters
    ----------
    p : LuGreParameters
        σ0, g(v) and φ_ss(v).
    deflection : float or ndarray
        φ at the step start.
    velocity : float or ndarray
        The velocity held over the step.
    dt : float
        The step [s].

    Returns
    -------
    ndarray
        φ at the step end, within [−φ_max, φ_max].

    Examples
    --------
    >>> float(step(TYPE_A, 0.0, 0.0, 1e-3))  # no motion: φ stays
    0.0
    """
    v = np.asarray(velocity, dtype=float)
    decay_rate = p.sigma0 * g(p, v)
    target = steady_state_deflection(p, v)
    # -expm1 keeps the weight accurate when σ0·g·h is tiny (v ≈ 0): then φ moves by ≈ v·h.
    weight = -np.expm1(-decay_rate * dt)
    moving = decay_rate > 0.0
    return np.where(moving, deflection + (target - deflection) * weight, deflection + v * dt)


__all__ = [
    "CANUDAS_1995",
    "LuGreParameters",
    "PLAUSIBLE",
    "Parameters",
    "TABLE_1",
    "TYPE_A",
    "TYPE_B",
    "breakaway_coefficient",
    "friction_coefficient",
    "friction_force",
    "g",
    "rhs",
    "rhs_jacobian",
    "steady_state_coefficient",
    "steady_state_deflection",
    "step",
    "stribeck_level",
]
