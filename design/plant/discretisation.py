"""Exact discretisation of the linear plant parts (Van Loan 1978), in one place.

:func:`first_order_hold` is the single Van Loan first-order-hold discretisation of
ż = M·z + N·f with f linear over a step; it serves the fixed-step scheme (per 2×2 mode block,
as a stack, :func:`discretise`), the stick-exact scheme (the dense stuck-joint system) and the
LQG design of ``design/control/lqg.py`` (:func:`discretise` at the sample time).
:func:`work_coefficients` and :func:`step_works` are the exact work integrals of a step for the
energy books of the fixed-step scheme (Eq. 32's e(t) balance).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from smartjoint.design.structure.modal import ModalModel


def first_order_hold(system: np.ndarray, inputs: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact first-order-hold discretisation of ż = M·z + N·f, f linear over the step.

    One augmented matrix exponential (Van Loan 1978)::

        exp([[M·h, N·h, 0], [0, 0, I], [0, 0, 0]]) = [[Φ, Γa, Γb], …],
        z⁺ = Φ·z + (Γa − Γb)·f_k + Γb·f_k+1,

    with Γa = ∫ e^{M(h−τ)}N dτ and Γb = (1/h)∫ e^{M(h−τ)}N τ dτ.

    Parameters
    ----------
    system : numpy.ndarray
        M, (N, N) or a stack (k, N, N) of independent blocks (scipy's ``expm`` takes stacks).
    inputs : numpy.ndarray
        N, (N, q) or a stack (k, N, q).
    step : float
        The step h [s].

    Returns
    -------
    tuple of numpy.ndarray
        Φ (…, N, N), γ0 = Γa − Γb (…, N, q) and γ1 = Γb (…, N, q).

    Examples
    --------
    >>> phi, g0, g1 = first_order_hold(np.zeros((1, 1)), np.ones((1, 1)), 0.5)
    >>> float(phi[0, 0]), float(g0[0, 0]), float(g1[0, 0])
    (1.0, 0.25, 0.25)
    """
    n, q = system.shape[-1], inputs.shape[-1]
    augmented = np.zeros(system.shape[:-2] + (n + 2 * q, n + 2 * q))
    augmented[..., :n, :n] = system * step
    augmented[..., :n, n : n + q] = inputs * step
    augmented[..., n : n + q, n + q :] = np.eye(q)
    ex = scipy.linalg.expm(augmented)
    gamma_b = ex[..., :n, n + q :]
    return ex[..., :n, :n], ex[..., :n, n : n + q] - gamma_b, gamma_b


def discretise(model: ModalModel, step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact first-order-hold discretisation of every mode block for a unit modal force.

    Each mode of Eq. 12 in the states [η̇_i, ω_iη_i] is the block
    [[−2ξ_iω_i, −ω_i], [ω_i, 0]] with the modal force entering η̈_i.

    Parameters
    ----------
    model : ModalModel
        The modal model (ω, ξ per coordinate).
    step : float
        The step h [s].

    Returns
    -------
    tuple of numpy.ndarray
        Φ (n, 2, 2), γ0 (n, 2), γ1 (n, 2) with x⁺ = Φx + γ0·f_k + γ1·f_{k+1}.
    """
    n = model.n_coordinates
    system = np.zeros((n, 2, 2))
    system[:, 0, 0] = -2.0 * model.damping * model.omega
    system[:, 0, 1] = -model.omega
    system[:, 1, 0] = model.omega
    inputs = np.zeros((n, 2, 1))
    inputs[:, 0, 0] = 1.0  # the force enters η̈
    phi, gamma0, gamma1 = first_order_hold(system, inputs, step)
    return phi, gamma0[:, :, 0], gamma1[:, :, 0]


def work_coefficients(model: ModalModel, step: float) -> np.ndarray:
    """Exact work integrals of one step per mode, for the energy books.

    With y = [η̇, ωη, f_a, f_b] (state at the step start, modal force at both ends, linear in
    between) the exact modal motion gives η̇(t) = r(t)ᵀy, so over the step

        m0 = ∫ η̇ dt = c0ᵀy,   m1 = ∫ (t/h)·η̇ dt = c1ᵀy,   ∫ 2ξω η̇² dt = yᵀDy,

    and the work of any force p linear over the step is p_a·m0 + (p_b − p_a)·m1. Computed in
    normalised time τ = t/h by augmented matrix exponentials (Van Loan 1978): Γ1 = ∫₀¹e^{Ãτ}dτ,
    Γ2 = ∫₀¹(1−τ)e^{Ãτ}dτ and the Gram integral ∫₀¹e^{Ãᵀτ}e1e1ᵀe^{Ãτ}dτ, with Ã the mode block
    driven by f and its increment Δ = f_b − f_a as states.

    Parameters
    ----------
    model : ModalModel
        The modal model.
    step : float
        The step h [s].

    Returns
    -------
    numpy.ndarray
        (18, n): rows c0 (4), c1 (4), then D00, D11, D22, D33, 2D01, 2D02, 2D03, 2D12, 2D13, 2D23.
    """
    n = model.n_coordinates
    w, zeta = model.omega * step, 2.0 * model.damping * model.omega
    a = np.zeros((n, 4, 4))  # d/dτ [η̇, ωη, f, Δ]
    a[:, 0, 0], a[:, 0, 1], a[:, 1, 0], a[:, 0, 2], a[:, 2, 3] = -zeta * step, -w, w, step, 1.0
    eye = np.broadcast_to(np.eye(4), (n, 4, 4))
    linear = np.zeros((n, 12, 12))
    linear[:, :4, :4], linear[:, :4, 4:8], linear[:, 4:8, 8:] = a, eye, eye
    ex = scipy.linalg.expm(linear)
    gamma1, gamma2 = ex[:, :4, 4:8], ex[:, :4, 8:]
    to_ends = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, -1.0, 1.0]])  # y → [x, f_a, Δ]
    c0 = step * gamma1[:, 0, :] @ to_ends
    c1 = step * (gamma1[:, 0, :] - gamma2[:, 0, :]) @ to_ends
    gram_block = np.zeros((n, 8, 8))
    gram_block[:, :4, :4], gram_block[:, 4:, 4:] = -np.transpose(a, (0, 2, 1)), a
    gram_block[:, 0, 4] = 1.0
    ex = scipy.linalg.expm(gram_block)
    gram = np.transpose(ex[:, 4:, 4:], (0, 2, 1)) @ ex[:, :4, 4:]
    D = (zeta * step)[:, None, None] * (to_ends.T @ gram @ to_ends)
    D = 0.5 * (D + np.transpose(D, (0, 2, 1)))
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    rows = [c0.T, c1.T, np.stack([D[:, k, k] for k in range(4)]), np.stack([2.0 * D[:, i, j] for i, j in pairs])]
    return np.ascontiguousarray(np.concatenate(rows))


def step_works(c, y0, y1, f_a, f_b):
    """m0, m1 and the damping work per mode of one step, for the rows of :func:`work_coefficients`.

    Parameters
    ----------
    c : numpy.ndarray
        (18, …) the coefficients of :func:`work_coefficients`.
    y0, y1 : numpy.ndarray
        η̇ and ωη at the step start, per mode.
    f_a, f_b : numpy.ndarray
        The modal force at both step ends.

    Returns
    -------
    tuple of numpy.ndarray
        m0 = ∫ η̇ dt, m1 = ∫ (t/h)·η̇ dt and ∫ 2ξω η̇² dt per mode.
    """
    m0 = c[0] * y0 + c[1] * y1 + c[2] * f_a + c[3] * f_b
    m1 = c[4] * y0 + c[5] * y1 + c[6] * f_a + c[7] * f_b
    damping = (
        y0 * (c[8] * y0 + c[12] * y1 + c[13] * f_a + c[14] * f_b)
        + y1 * (c[9] * y1 + c[15] * f_a + c[16] * f_b)
        + f_a * (c[10] * f_a + c[17] * f_b)
        + c[11] * f_b * f_b
    )
    return m0, m1, damping


__all__ = ["discretise", "first_order_hold", "step_works", "work_coefficients"]
