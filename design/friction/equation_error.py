"""The model friction force of paper Eq. 3: û_R(t_k) simulated from a record's measured sliding
velocity and normal force (Eq. 2 with Eq. 1 integrated by the exact-exponential step of
``lugre.py`` at the midpoint velocity), in C (``sj_equation_error_friction`` of
``rig_kernel.c``) with its Python reference loop."""

from __future__ import annotations

import math

import numpy as np

from smartjoint.design.friction import lugre
from smartjoint.design.friction.records import Record
from smartjoint.design.friction.rig_integration import kernel

_C_FAILURE: list[str] = []  # why the C kernel is unavailable on this machine (reported once)


def simulate_friction(
    p: lugre.LuGreParameters, time, velocity, normal_force, initial_force: float = 0.0, backend: str = "auto"
):
    """û_R at the sample times for a measured velocity (midpoint exact-exponential step, Eq. 1–2).

    The same step as ``lugre.step`` and ``lugre.friction_coefficient``, run in C
    (``sj_equation_error_friction`` of ``rig_kernel.c``: the fit calls it for every sample
    thousands of times) with the Python loop on floats as its reference.

    Parameters
    ----------
    p : LuGreParameters
        The parameters.
    time, velocity, normal_force : ndarray
        The measured series (SI).
    initial_force : float
        The friction force at the first sample, for a consistent start deflection.
    backend : str
        'c', 'python' (the reference loop) or 'auto' (C, else Python with a warning).

    Returns
    -------
    ndarray
        û_R per sample.
    """
    from smartjoint.common import native

    module = native.choose(backend, "equation-error friction", kernel, lambda: None, _C_FAILURE, stacklevel=2)
    if module is None:
        return _simulate_friction_python(p, time, velocity, normal_force, initial_force)
    ffi, lib = module.ffi, module.lib
    time = np.ascontiguousarray(time, dtype=float)
    velocity = np.ascontiguousarray(velocity, dtype=float)
    gain = np.ascontiguousarray(p.moment_arm * np.asarray(normal_force, dtype=float))
    if not (velocity.shape == gain.shape == time.shape):
        raise ValueError(f"time, velocity, normal_force: shapes {time.shape}, {velocity.shape}, {gain.shape} differ")
    joint = {name: getattr(p, name) for name, _ in ffi.typeof("sj_rig").fields if name != "inertia"}
    out = np.empty(time.size)
    if time.size:
        bound = p.max_deflection
        phi = min(max(initial_force / (float(gain[0]) * p.sigma0), -bound), bound)  # consistent start

        def pointer(array):
            return ffi.cast("double *", ffi.from_buffer(array))

        lib.sj_equation_error_friction(
            ffi.new("sj_rig *", dict(joint, inertia=0.0)),
            pointer(time),
            time.size,
            pointer(velocity),
            pointer(gain),
            phi,
            pointer(out),
        )
    return out


def _simulate_friction_python(p, time, velocity, normal_force, initial_force):
    """Reference loop of ``simulate_friction`` on Python floats (``sj_equation_error_friction`` mirrors it)."""
    s0, s1, s2 = p.sigma0, p.sigma1, p.sigma2
    fc, fd, vs = p.coulomb, p.stribeck, p.stribeck_velocity
    arm = p.moment_arm
    out = np.empty(len(time))
    bound = p.max_deflection
    phi = min(max(initial_force / (arm * normal_force[0] * s0), -bound), bound)  # consistent start
    previous_v = float(velocity[0])
    for k in range(len(time)):
        v = float(velocity[k])
        if k:
            dt = float(time[k] - time[k - 1])
            mid = 0.5 * (v + previous_v)
            level = fc + fd * math.exp(-((mid / vs) ** 2))
            rate = s0 * abs(mid) / level
            if rate > 0.0:
                target = math.copysign(level / s0, mid)
                phi = phi + (target - phi) * -math.expm1(-rate * dt)
        level = fc + fd * math.exp(-((v / vs) ** 2))
        phidot = v - s0 * abs(v) / level * phi
        out[k] = arm * float(normal_force[k]) * (s0 * phi + s1 * phidot + s2 * v)
        previous_v = v
    return out


def model_friction(p: lugre.LuGreParameters, record: Record, velocity) -> np.ndarray:
    """û_R of Eq. 3 for a record, from the (possibly filtered) measured ``velocity``.

    Parameters
    ----------
    p : LuGreParameters
        The parameters.
    record : Record
        The record (time, normal force, first friction force).
    velocity : ndarray
        The velocity fed to the model.

    Returns
    -------
    ndarray
        û_R per sample.
    """
    return simulate_friction(p, record.time, velocity, record.normal_force, record.friction_force[0])


__all__ = ["model_friction", "simulate_friction"]
