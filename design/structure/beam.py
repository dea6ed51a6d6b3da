"""3D cubic Euler–Bernoulli beam element (12 DOF), paper Section 3.3 / Fig. 6.

Every tube and every end connector of the truss is one or more of these two-node elements.
Node DOF order is ``[ux, uy, uz, rx, ry, rz]``; the element vector is node 1 then node 2.

The element matrices are written in the element frame (local x along the axis) as a sum of
*unit terms*, one per section property::

    K_e = EA·K_axial + GJ·K_torsion + EI_y·K_bend_y + EI_z·K_bend_z
    M_e = ρA·M_translation + ρI_p·M_torsion

Keeping the terms apart lets model updating (``updating.py``) scale a single stiffness
property of a group of elements exactly (K is linear in EA, GJ, EI), which gives the
analytic eigenvalue sensitivities it needs.

Bending rotary inertia is neglected (Euler–Bernoulli); the torsional inertia ρI_p is kept.
All functions are vectorised over elements: lengths of shape (n,) give arrays (n, 12, 12).
"""

from __future__ import annotations

import numpy as np

STIFFNESS_TERMS = ("axial", "torsion", "bending_y", "bending_z")
MASS_TERMS = ("translation", "torsion")

_AXIAL = (0, 6)
_TORSION = (3, 9)
# Bending in the local x–y plane (about z, EI_z): v1, θz1, v2, θz2.
_BEND_Z = (1, 5, 7, 11)
# Bending in the local x–z plane (about y, EI_y): w1, θy1, w2, θy2 (coupling signs flip).
_BEND_Y = (2, 4, 8, 10)


def _place(target: np.ndarray, dofs: tuple[int, ...], block: np.ndarray) -> None:
    index = np.ix_(range(target.shape[0]), dofs, dofs)
    target[index] += block


def _two_node(length: np.ndarray, diagonal: float, off_diagonal: float) -> np.ndarray:
    block = np.empty((length.size, 2, 2))
    block[:, 0, 0] = block[:, 1, 1] = diagonal
    block[:, 0, 1] = block[:, 1, 0] = off_diagonal
    return block


def _bending_stiffness(length: np.ndarray, sign: float) -> np.ndarray:
    L = length[:, None, None]
    s = sign
    pattern = np.array(
        [
            [12.0, 6.0 * s, -12.0, 6.0 * s],
            [6.0 * s, 4.0, -6.0 * s, 2.0],
            [-12.0, -6.0 * s, 12.0, -6.0 * s],
            [6.0 * s, 2.0, -6.0 * s, 4.0],
        ]
    )
    power = np.array([[3, 2, 3, 2], [2, 1, 2, 1], [3, 2, 3, 2], [2, 1, 2, 1]])
    return pattern[None] / L ** power[None]


def _bending_mass(length: np.ndarray, sign: float) -> np.ndarray:
    L = length[:, None, None]
    s = sign
    pattern = np.array(
        [
            [156.0, 22.0 * s, 54.0, -13.0 * s],
            [22.0 * s, 4.0, 13.0 * s, -3.0],
            [54.0, 13.0 * s, 156.0, -22.0 * s],
            [-13.0 * s, -3.0, -22.0 * s, 4.0],
        ]
    )
    power = np.array([[0, 1, 0, 1], [1, 2, 1, 2], [0, 1, 0, 1], [1, 2, 1, 2]])
    return pattern[None] * L ** power[None] * L / 420.0


def local_stiffness_terms(length: np.ndarray) -> dict[str, np.ndarray]:
    """Unit stiffness terms in the element frame, keyed by :data:`STIFFNESS_TERMS`.

    Multiply ``axial`` by EA [N], ``torsion`` by GJ [N·m²], ``bending_y`` by EI_y and
    ``bending_z`` by EI_z [N·m²].

    Parameters
    ----------
    length : ndarray
        Element lengths L (n,) [m]; the terms go with 1/L (axial, torsion) and 1/L³ … 1/L (bending).

    Returns
    -------
    dict of str to ndarray
        One (n, 12, 12) matrix per term.
    """
    length = np.asarray(length, dtype=float)
    n = length.size
    terms = {name: np.zeros((n, 12, 12)) for name in STIFFNESS_TERMS}
    _place(terms["axial"], _AXIAL, _two_node(length, 1.0, -1.0) / length[:, None, None])
    _place(terms["torsion"], _TORSION, _two_node(length, 1.0, -1.0) / length[:, None, None])
    _place(terms["bending_z"], _BEND_Z, _bending_stiffness(length, +1.0))
    _place(terms["bending_y"], _BEND_Y, _bending_stiffness(length, -1.0))
    return terms


def local_mass_terms(length: np.ndarray) -> dict[str, np.ndarray]:
    """Unit consistent-mass terms: ``translation`` × ρA [kg/m], ``torsion`` × ρI_p [kg·m].

    Parameters
    ----------
    length : ndarray
        Element lengths L (n,) [m]; the consistent mass goes with L … L³.

    Returns
    -------
    dict of str to ndarray
        One (n, 12, 12) matrix per term of :data:`MASS_TERMS`.
    """
    length = np.asarray(length, dtype=float)
    n = length.size
    terms = {name: np.zeros((n, 12, 12)) for name in MASS_TERMS}
    translation = terms["translation"]
    _place(translation, _AXIAL, _two_node(length, 2.0, 1.0) * length[:, None, None] / 6.0)
    _place(translation, _BEND_Z, _bending_mass(length, +1.0))
    _place(translation, _BEND_Y, _bending_mass(length, -1.0))
    _place(terms["torsion"], _TORSION, _two_node(length, 2.0, 1.0) * length[:, None, None] / 6.0)
    return terms


def element_frames(start: np.ndarray, end: np.ndarray, reference: np.ndarray | None = None):
    """Element lengths and rotation matrices R (rows = local axes in global coordinates).

    The local x axis runs from ``start`` to ``end``. The local y axis is the component of the
    ``reference`` vector (default: global z, or global y for elements nearly parallel to z)
    normal to x; local z = x × y.

    Parameters
    ----------
    start, end : ndarray
        End points (n, 3) [m].
    reference : ndarray, optional
        A vector per element (n, 3) that fixes the local y axis.

    Returns
    -------
    tuple
        ``(length (n,), R (n, 3, 3))``.
    """
    start = np.atleast_2d(np.asarray(start, dtype=float))
    end = np.atleast_2d(np.asarray(end, dtype=float))
    axis = end - start
    length = np.linalg.norm(axis, axis=1)
    if np.any(length <= 0.0):
        raise ValueError("element of zero length")
    ex = axis / length[:, None]
    if reference is None:
        reference = np.tile([0.0, 0.0, 1.0], (ex.shape[0], 1))
        nearly_z = np.abs(ex[:, 2]) > 0.99
        reference[nearly_z] = [0.0, 1.0, 0.0]
    reference = np.broadcast_to(np.asarray(reference, dtype=float), ex.shape)
    ey = reference - np.sum(reference * ex, axis=1)[:, None] * ex
    ey /= np.linalg.norm(ey, axis=1)[:, None]
    ez = np.cross(ex, ey)
    rotation = np.stack([ex, ey, ez], axis=1)
    return length, rotation


def to_global(local: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Transform element matrices (n, 12, 12) from element to global frame: Tᵀ·K·T.

    Parameters
    ----------
    local : ndarray
        Element matrices (n, 12, 12) in the element frame.
    rotation : ndarray
        R (n, 3, 3) of `element_frames`.

    Returns
    -------
    ndarray
        The matrices (n, 12, 12) in global coordinates.
    """
    n = rotation.shape[0]
    transform = np.zeros((n, 12, 12))
    for block in range(4):
        s = slice(3 * block, 3 * block + 3)
        transform[:, s, s] = rotation
    return np.einsum("nji,njk,nkl->nil", transform, local, transform, optimize=True)


__all__ = ["element_frames", "local_mass_terms", "local_stiffness_terms", "MASS_TERMS", "STIFFNESS_TERMS", "to_global"]
