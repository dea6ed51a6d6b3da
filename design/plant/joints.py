"""The LuGre friction laws of the plant's joints (Eq. 1–2), vectorised over the joints: the
``plant`` of the registry's ``lugre`` model (``common/friction_registry.py``)."""

from __future__ import annotations

import numpy as np

from smartjoint.design.friction import lugre

SERIES = 1e-4  # ρh below which φ1, φ2 use their Taylor series


class JointLaws:
    """Vectorised LuGre laws (Eq. 1–2) of the l joints (per unit normal force, times r·F_N).

    Shared by the fixed-step and stick-exact schemes and the Radau reference."""

    def __init__(self, parameters: list[lugre.LuGreParameters]):
        self.s0 = np.array([p.sigma0 for p in parameters])
        self.s1 = np.array([p.sigma1 for p in parameters])
        self.s2 = np.array([p.sigma2 for p in parameters])
        self.fc = np.array([p.coulomb for p in parameters])
        self.fd = np.array([p.stribeck for p in parameters])
        self.vs = np.array([p.stribeck_velocity for p in parameters])
        self.arm = np.array([p.moment_arm for p in parameters])
        self.bound = np.array([p.max_deflection for p in parameters])

    def level(self, v):
        return self.fc + self.fd * np.exp(-(v / self.vs) * (v / self.vs))

    def advance(self, phi, v_start, v_end, h, derivative=False):
        """φ⁺ of Eq. 1, φ̇ = v − ρφ with ρ = σ0|v|/(F_c + F_d·e^{−(v/v_s)²}) frozen at the
        midpoint velocity and v linear over the step — solved exactly (exponential integrator
        with first-order hold):

            φ⁺ = e^{−ρh}φ + h·[(φ1(ρh) − φ2(ρh))·v_k + φ2(ρh)·v_{k+1}],
            φ1(x) = (1 − e^{−x})/x,  φ2(x) = (1 − φ1(x))/x.

        Unlike the midpoint-velocity step of ``lugre.step`` it keeps second order when ρh ≫ 1
        (fast sliding: φ follows φ_ss(v(t)), not φ_ss of the midpoint), and it is the
        trapezoidal rule for ρh → 0. |φ| is clipped to φ_max, the bound of the exact solution.
        With ``derivative`` also returns ∂φ⁺/∂v_{k+1} (for the Newton solve).
        """
        mid = 0.5 * (v_start + v_end)
        g = self.level(mid)
        x = self.s0 * np.abs(mid) / g * h
        small = x < SERIES
        xs = np.where(small, 1.0, x)
        decay_minus_one = np.expm1(-x)  # one call serves both e^{−x} and φ1 (as the C kernel)
        decay = 1.0 + decay_minus_one
        phi1 = np.where(small, 1.0 - x / 2.0 + x * x / 6.0, -decay_minus_one / xs)
        phi2 = np.where(small, 0.5 - x / 6.0 + x * x / 24.0, (1.0 - phi1) / xs)
        raw = decay * phi + h * ((phi1 - phi2) * v_start + phi2 * v_end)
        out = np.clip(raw, -self.bound, self.bound)
        if not derivative:
            return out
        dg = -2.0 * mid / self.vs**2 * (g - self.fc)
        dx = 0.5 * self.s0 * h * (np.sign(mid) * g - np.abs(mid) * dg) / (g * g)
        dphi1 = np.where(small, -0.5 + x / 3.0, (decay - phi1) / xs)
        dphi2 = np.where(small, -1.0 / 6.0 + x / 12.0, (-dphi1 - phi2) / xs)
        d_out = (-decay * phi + h * ((dphi1 - dphi2) * v_start + dphi2 * v_end)) * dx + h * phi2
        return out, np.where(np.abs(raw) > self.bound, 0.0, d_out)

    def mu(self, v, phi):
        phidot = v - self.s0 * np.abs(v) / self.level(v) * phi
        return self.s0 * phi + self.s1 * phidot + self.s2 * v

    def force(self, v, phi, normal_force):
        return self.arm * normal_force * self.mu(v, phi)

    def force_derivatives(self, v, phi, normal_force):
        """u_R of Eq. 2 with ∂u_R/∂v and ∂u_R/∂φ."""
        g = self.level(v)
        dg = -2.0 * v / self.vs**2 * (g - self.fc)
        scale = self.arm * normal_force
        dphidot_dv = 1.0 - self.s0 * phi * (np.sign(v) * g - np.abs(v) * dg) / (g * g)
        d_v = scale * (self.s1 * dphidot_dv + self.s2)
        d_phi = scale * (self.s0 - self.s1 * self.s0 * np.abs(v) / g)
        return self.force(v, phi, normal_force), d_v, d_phi


__all__ = ["SERIES", "JointLaws"]
