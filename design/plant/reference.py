"""The accuracy reference of the plant schemes: Eq. 12 with constant normal forces integrated by
scipy's Radau (``solve_ivp``) with an analytic Jacobian (tests/test_simulate.py,
tests/test_stick_exact.py and benchmarks/plant_sim.py compare the schemes against it)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.friction.model import FrictionParameters, plant_laws
from smartjoint.design.structure.modal import ModalModel


def reference_system(
    model: ModalModel,
    joints: list[FrictionParameters],
    normal_forces,
    disturbance: Callable[[float], np.ndarray] | None,
):
    """Eq. 12 with constant normal forces as an ODE z' = f(t, z), z = [x; φ], with its analytic
    Jacobian, for scipy.integrate.solve_ivp.

    Parameters
    ----------
    model : ModalModel
        The modal model.
    joints : list of FrictionParameters
        One LuGre law per joint (Eq. 1–2).
    normal_forces : array_like
        F_N per joint, constant over the run.
    disturbance : callable or None
        ``w(t)``.

    Returns
    -------
    tuple
        (rhs(t, z), jac(t, z), number of structural states, friction(Z) -> u_R).
    """
    l = model.joint_input.shape[1]
    law = plant_laws(joints)
    fn = np.asarray(normal_forces, dtype=float)
    A, B, H, Cv, _ = model.state_space()
    ns = A.shape[0]
    m = H.shape[1]
    w_fun = disturbance or (lambda t: np.zeros(m))

    def parts(v, phi):
        level = law.level(v)
        phidot = v - law.s0 * np.abs(v) / level * phi
        u = law.arm * fn * (law.s0 * phi + law.s1 * phidot + law.s2 * v)
        # ∂φ̇/∂v, ∂φ̇/∂φ (one-sided at v = 0)
        d_level = -2.0 * v / law.vs**2 * (level - law.fc)
        dphidot_dv = 1.0 - law.s0 * phi * (np.sign(v) * level - np.abs(v) * d_level) / level**2
        dphidot_dphi = -law.s0 * np.abs(v) / level
        du_dv = law.arm * fn * (law.s1 * dphidot_dv + law.s2)
        du_dphi = law.arm * fn * (law.s0 + law.s1 * dphidot_dphi)
        return u, phidot, du_dv, du_dphi, dphidot_dv, dphidot_dphi

    def rhs(t, z):
        x, phi = z[:ns], z[ns:]
        v = Cv @ x
        u, phidot, *_ = parts(v, phi)
        return np.concatenate([A @ x - B @ u + H @ np.asarray(w_fun(t), dtype=float), phidot])

    def jac(t, z):
        x, phi = z[:ns], z[ns:]
        v = Cv @ x
        _, _, du_dv, du_dphi, dpd_v, dpd_phi = parts(v, phi)
        J = np.zeros((ns + l, ns + l))
        J[:ns, :ns] = A - (B * du_dv[None, :]) @ Cv
        J[:ns, ns:] = -B * du_dphi[None, :]
        J[ns:, :ns] = dpd_v[:, None] * Cv
        J[ns:, ns:] = np.diag(dpd_phi)
        return J

    def friction(Z):
        Z = np.atleast_2d(Z)
        x, phi = Z[:, :ns], Z[:, ns:]
        return law.arm * fn * law.mu(x @ Cv.T, phi)

    return rhs, jac, ns, friction


def reference_simulation(
    model: ModalModel,
    joints: list[FrictionParameters],
    normal_forces,
    disturbance: Callable[[float], np.ndarray] | None,
    duration: float,
    times: np.ndarray,
    rtol: float = 1e-10,
    atol: float = 1e-13,
    method: str = "Radau",
):
    """Eq. 12 for constant normal forces through scipy.integrate.solve_ivp with an analytic
    Jacobian: the accuracy reference for ``loop.simulate``.

    Parameters
    ----------
    model, joints, normal_forces, disturbance
        As :func:`reference_system`.
    duration : float
        End time [s]; the integration restarts at the disturbance's ``breakpoints``.
    times : numpy.ndarray
        Output times in [0, duration].
    rtol, atol, method
        Passed to ``solve_ivp``.

    Returns
    -------
    tuple of numpy.ndarray
        (v, u_R, ½xᵀx) at ``times``.
    """
    from scipy.integrate import solve_ivp

    rhs, jac, ns, friction = reference_system(model, joints, normal_forces, disturbance)
    l = model.joint_input.shape[1]
    _, _, _, Cv, _ = model.state_space()
    breaks = sorted({0.0, duration, *[b for b in getattr(disturbance, "breakpoints", ()) if 0 < b < duration]})
    z = np.zeros(ns + l)
    out_z = []
    for a, b in zip(breaks[:-1], breaks[1:]):  # restart at the kinks of the pulse
        inside = times[(times >= a) & (times < b)] if b < duration else times[(times >= a) & (times <= b)]
        sol = solve_ivp(rhs, (a, b), z, method=method, jac=jac, rtol=rtol, atol=atol, dense_output=True)
        if not sol.success:
            raise ModelError(f"reference integration failed: {sol.message}")
        out_z.append(sol.sol(inside).T if inside.size else np.zeros((0, ns + l)))
        z = sol.y[:, -1]
    Z = np.concatenate(out_z)
    x = Z[:, :ns]
    return x @ Cv.T, friction(Z), 0.5 * np.sum(x * x, axis=1)


__all__ = ["reference_simulation", "reference_system"]
