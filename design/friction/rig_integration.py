"""The rig's integrator: the implicit trapezoidal rule for (v, φ) of Eq. 1–2 under an excitation.

The stiff bristle dynamics of the isolated-joint rig (``rig``) and of the output-error step
(``output_error``) are integrated by the implicit trapezoidal rule (A-stable, second order, no
numerical damping of the lightly damped bristle resonance) with a Newton solve on the analytic
Jacobian at ``SUBSTEPS`` steps per sample: in the C kernel ``rig_kernel.c`` (``kernel``), with
the Python loop kept as its reference.
"""

from __future__ import annotations

import math

import numpy as np

SUBSTEPS = 8
ITERATIONS = 20  # Newton iterations per substep (SJ_RIG_ITERATIONS in rig_kernel.c)
_C_FAILURE: list[str] = []  # why the C kernel is unavailable on this machine (reported once)
DECLARATIONS = """
typedef struct {
    double sigma0, sigma1, sigma2, coulomb, stribeck, stribeck_velocity, max_deflection;
    double inertia;
} sj_rig;
long sj_rig_integrate(const sj_rig *p, const double *time, long samples, int substeps, const double *force,
                      const double *gain, double velocity0, double deflection0, double *velocity,
                      double *deflection);
void sj_equation_error_friction(const sj_rig *p, const double *time, long samples, const double *velocity,
                                const double *gain, double deflection0, double *friction);
"""


def integrate(
    p, gain, inertia, force, time, substeps, velocity0: float = 0.0, deflection0: float = 0.0, backend: str = "auto"
):
    """Implicit trapezoidal rule for (v, φ) of the rig (Eq. 1–2) under an excitation ``force``.

    Parameters
    ----------
    p : LuGreParameters
        The joint.
    gain : float or ndarray
        r·F_N, a number or one value per substep node.
    inertia : float
        The moving inertia [kg] (type B: [kg·m²]).
    force : ndarray
        The excitation at every substep node: (len(time) − 1)·substeps + 1 values.
    time : ndarray
        The sample times [s].
    substeps : int
        Substeps per sample.
    velocity0, deflection0 : float
        The start.
    backend : str
        'c' (rig_kernel.c), 'python' (the reference loop) or 'auto' (C, else Python with a warning).

    Returns
    -------
    tuple of ndarray
        Velocity and bristle deflection at the sample times (x is not needed).
    """
    time = np.ascontiguousarray(time, dtype=float)
    nodes = (time.size - 1) * substeps + 1
    force = np.ascontiguousarray(force, dtype=float)
    gain = np.asarray(gain, dtype=float)
    if force.shape != (nodes,):
        raise ValueError(f"force: {force.shape} values — need (len(time) − 1)·substeps + 1 = {nodes}")
    if gain.shape not in ((), (nodes,)):
        raise ValueError(f"gain: {gain.shape} values — need one number or {nodes}, one per substep node")
    gain = np.ascontiguousarray(np.broadcast_to(gain, (nodes,)))
    from smartjoint.common import native

    module = native.choose(backend, "rig integration", kernel, lambda: None, _C_FAILURE, stacklevel=2)
    if module is None:
        return _integrate_python(p, gain, inertia, force, time, substeps, velocity0, deflection0)
    return _integrate_c(module, p, gain, inertia, force, time, substeps, velocity0, deflection0)


def kernel():
    """The compiled rig kernel (cffi module; ``ModelError`` when it cannot be built).

    Returns
    -------
    module
        The cffi module of ``rig_kernel.c``.
    """
    from smartjoint.common import native, package_data

    return native.load("rig", DECLARATIONS, package_data.path("smartjoint.design.friction", "rig_kernel.c"))


def _integrate_c(module, p, gain, inertia, force, time, substeps, velocity0, deflection0):
    ffi, lib = module.ffi, module.lib
    # sj_rig's fields (DECLARATIONS) are the joint's LuGreParameters by their own names, and the inertia
    joint = {name: getattr(p, name) for name, _ in ffi.typeof("sj_rig").fields if name != "inertia"}
    rig = ffi.new("sj_rig *", dict(joint, inertia=float(inertia)))
    velocity = np.empty(time.size)
    deflection = np.empty(time.size)

    def pointer(array):
        return ffi.cast("double *", ffi.from_buffer(array))

    lib.sj_rig_integrate(
        rig,
        pointer(time),
        time.size,
        int(substeps),
        pointer(force),
        pointer(gain),
        float(velocity0),
        float(deflection0),
        pointer(velocity),
        pointer(deflection),
    )
    return velocity, deflection


def _integrate_python(p, gain, inertia, force, time, substeps, velocity0, deflection0):
    """Reference loop: rig_kernel.c mirrors it statement for statement."""
    force = force.tolist()
    gain = gain.tolist()
    s0, s1, s2 = p.sigma0, p.sigma1, p.sigma2
    fc, fd, vs = p.coulomb, p.stribeck, p.stribeck_velocity

    def rates(excitation, scale, v, phi):
        ratio = v / vs
        level = fc + fd * math.exp(-(ratio * ratio))
        phidot = v - s0 * abs(v) / level * phi
        mu = s0 * phi + s1 * phidot + s2 * v
        return (excitation - scale * mu) / inertia, phidot, level

    velocity = np.zeros(time.size)
    deflection = np.zeros(time.size)
    v, phi = float(velocity0), float(deflection0)
    velocity[0], deflection[0] = v, phi
    node = 0
    for k in range(1, time.size):
        h = float(time[k] - time[k - 1]) / substeps
        for _ in range(substeps):
            a0, d0, _ = rates(force[node], gain[node], v, phi)
            node += 1
            v1, phi1 = v + h * a0, phi + h * d0  # explicit predictor, then Newton
            for _ in range(ITERATIONS):
                a1, d1, level = rates(force[node], gain[node], v1, phi1)
                r_v = v1 - v - 0.5 * h * (a0 + a1)
                r_p = phi1 - phi - 0.5 * h * (d0 + d1)
                # ∂φ̇/∂φ, ∂φ̇/∂v (sign(v) kink handled one-sidedly) and ∂a/∂·
                f_phi = -s0 * abs(v1) / level
                d_level = -2.0 * v1 / (vs * vs) * (level - fc)
                sign = 1.0 if v1 > 0 else (-1.0 if v1 < 0 else 0.0)
                f_v = 1.0 - s0 * phi1 * (sign * level - abs(v1) * d_level) / (level * level)
                a_v = -gain[node] * (s1 * f_v + s2) / inertia
                a_phi = -gain[node] * (s0 + s1 * f_phi) / inertia
                j11, j12 = 1.0 - 0.5 * h * a_v, -0.5 * h * a_phi
                j21, j22 = -0.5 * h * f_v, 1.0 - 0.5 * h * f_phi
                det = j11 * j22 - j12 * j21
                dv = (r_v * j22 - j12 * r_p) / det
                dp = (j11 * r_p - j21 * r_v) / det
                v1 -= dv
                phi1 -= dp
                if abs(dv) <= 1e-13 * (1.0 + abs(v1)) and abs(dp) <= 1e-12 * p.max_deflection:
                    break
            v, phi = v1, phi1
        velocity[k] = v
        deflection[k] = phi
    return velocity, deflection


__all__ = ["DECLARATIONS", "ITERATIONS", "SUBSTEPS", "integrate", "kernel"]
