"""Correlation of measured (EMA) and FE mode shapes: the MAC matrix of the paper's Fig. 7, the
pairing of the measured modes with FE modes by MAC, and the swaps that pairing reveals.

The modal assurance criterion (Allemang & Brown) between a measured shape φ_a and an FE shape
φ_e, both at the measured DOFs,

    MAC(φ_a, φ_e) = |φ_aᵀ φ_e|² / ((φ_aᵀ φ_a)(φ_eᵀ φ_e)),

is 1 for proportional shapes (whatever their scaling and sign) and near 0 for unrelated ones.
Each measured mode is paired with one FE mode, no FE mode twice, so that the sum of the paired
MACs is largest (`scipy.optimize.linear_sum_assignment`); a small term in the relative
frequency distance breaks ties, e.g. between the two shapes of a degenerate bending pair that
the EMA sees with the same MAC. A pairing that differs from the mode numbers of the design is a
mode swap, reported by name (:class:`ModeSwapWarning`).

The shapes are real (normal) modes: a complex EMA shape is given by its real-valued
normalisation (e.g. rotated so that its largest component is real, then the real part).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize

from smartjoint.common.errors import ModelError
from smartjoint.design.structure.description import MeasuredDof, Updating

# Weight of the relative frequency distance |f_e − f_a|/f_a in the pairing cost −MAC + w·distance:
# a 10 % frequency difference weighs as much as a MAC difference of 0.001, so it only decides
# between shapes the EMA cannot tell apart.
TIE_BREAK = 0.01


class ModeSwapWarning(UserWarning):
    """Measured modes pair by MAC with FE modes other than those their numbers name."""


def measurement_matrix(model, dofs: tuple[MeasuredDof, ...]) -> np.ndarray:
    """The matrix D that takes an FE shape in z to its components at the measured DOFs, D·φ.

    Row k is the motion of node ``dofs[k].node`` along ``dofs[k].direction`` through the
    constraint matrix S (z̄ = S·z, Eq. 4), as for a sensor's row of V (Eq. 10).

    Parameters
    ----------
    model : FEModel
        The FE model (any joint setting).
    dofs : tuple of MeasuredDof
        The DOFs of the modal survey.

    Returns
    -------
    ndarray
        D, (len(dofs), N).
    """
    node_index = {name: i for i, name in enumerate(model.design.nodes)}
    rows = np.zeros((len(dofs), model.n_dof))
    for k, dof in enumerate(dofs):
        i = node_index[dof.node]
        rows[k] = np.asarray(model.S[6 * i : 6 * i + 6].T @ np.array(dof.direction)).ravel()
    return rows


def modal_assurance_criterion(measured: np.ndarray, analytical: np.ndarray) -> np.ndarray:
    """The MAC matrix between two sets of shapes at the same DOFs (paper Fig. 7).

    MAC_ij = |φ_a,iᵀ φ_e,j|² / ((φ_a,iᵀ φ_a,i)(φ_e,jᵀ φ_e,j)); a shape without any component
    (an FE mode that does not move the measured DOFs) has MAC 0 with every other.

    Parameters
    ----------
    measured : ndarray
        Measured shapes φ_a, one per column, (n_dofs, n_a).
    analytical : ndarray
        FE shapes φ_e at the same DOFs, one per column, (n_dofs, n_e).

    Returns
    -------
    ndarray
        MAC, (n_a, n_e), each entry in [0, 1].
    """
    measured = np.asarray(measured, dtype=float)
    analytical = np.asarray(analytical, dtype=float)
    if measured.ndim != 2 or analytical.ndim != 2 or measured.shape[0] != analytical.shape[0]:
        raise ModelError(
            f"MAC: shapes {measured.shape} and {analytical.shape} — expected (DOFs, modes) arrays with the same DOFs"
        )
    cross = measured.T @ analytical
    norms = np.outer(np.einsum("ij,ij->j", measured, measured), np.einsum("ij,ij->j", analytical, analytical))
    with np.errstate(invalid="ignore", divide="ignore"):
        mac = np.where(norms > 0.0, cross**2 / np.where(norms > 0.0, norms, 1.0), 0.0)
    return np.clip(mac, 0.0, 1.0)


def pair_modes(mac: np.ndarray, measured_hz: np.ndarray, fe_hz: np.ndarray, tie_break: float = TIE_BREAK) -> np.ndarray:
    """Pair every measured mode with a different FE mode, largest total MAC first.

    Minimises Σ_i (−MAC_i,p(i) + tie_break·|f_p(i) − f̂_i|/f̂_i) over the one-to-one maps p
    (`scipy.optimize.linear_sum_assignment`).

    Parameters
    ----------
    mac : ndarray
        MAC matrix (n_a, n_e) with n_a ≤ n_e.
    measured_hz, fe_hz : ndarray
        Measured frequencies f̂ (n_a,) and FE frequencies f (n_e,).
    tie_break : float
        Weight of the relative frequency distance.

    Returns
    -------
    ndarray of int
        p(i), the 0-based FE mode of each measured mode.
    """
    n_measured, n_fe = mac.shape
    if n_measured > n_fe:
        raise ModelError(f"MAC pairing: {n_measured} measured modes but only {n_fe} FE modes to pair them with")
    distance = np.abs(fe_hz[None, :] - measured_hz[:, None]) / measured_hz[:, None]
    rows, columns = scipy.optimize.linear_sum_assignment(-mac + tie_break * distance)
    paired = np.empty(n_measured, dtype=int)
    paired[rows] = columns
    return paired


@dataclass
class ModeCorrelation:
    """The MAC matrix of the measured modes against the FE modes, the pairing and its swaps.

    ``mac`` has one row per measured mode and one column per FE mode 1 … n_e; ``fe_modes`` the
    paired FE mode numbers (1-based); ``swaps`` one sentence per measured mode whose pair is not
    the FE mode of its number.
    """

    measured_modes: np.ndarray  # the numbers the design gives (1-based)
    measured_hz: np.ndarray
    fe_modes: np.ndarray  # paired FE mode numbers (1-based)
    fe_hz: np.ndarray  # frequencies of all FE modes considered
    mac: np.ndarray  # (n_a, n_e)
    swaps: list[str]

    @property
    def diagonal(self) -> np.ndarray:
        """MAC of each measured mode with its paired FE mode."""
        return self.mac[np.arange(self.mac.shape[0]), self.fe_modes - 1]

    @property
    def paired_hz(self) -> np.ndarray:
        """FE frequency of each measured mode's pair."""
        return self.fe_hz[self.fe_modes - 1]

    def as_dict(self) -> dict:
        return {
            "pairing": [
                {"measured_mode": int(m), "fe_mode": int(e), "mac": float(d)}
                for m, e, d in zip(self.measured_modes, self.fe_modes, self.diagonal)
            ],
            "mac_matrix": [[float(v) for v in row] for row in self.mac],
            "swaps": list(self.swaps),
        }


def swap_messages(numbers: np.ndarray, paired: np.ndarray, mac: np.ndarray, fe_hz: np.ndarray) -> list[str]:
    """One sentence per measured mode whose MAC pair differs from the FE mode of its number.

    Parameters
    ----------
    numbers : ndarray of int
        The measured modes' numbers from the design (1-based).
    paired : ndarray of int
        Their pairs by MAC (0-based, as `pair_modes` returns them).
    mac : ndarray
        The MAC matrix.
    fe_hz : ndarray
        The FE frequencies.

    Returns
    -------
    list of str
        Empty when the pairing follows the numbers.
    """
    messages = []
    for i, (number, column) in enumerate(zip(numbers, paired)):
        if column + 1 == number:
            continue
        own = f"MAC {mac[i, number - 1]:.2f}" if number - 1 < mac.shape[1] else "not solved"
        messages.append(
            f"measured mode {number} pairs with FE mode {column + 1} ({fe_hz[column]:.2f} Hz, "
            f"MAC {mac[i, column]:.2f}), not FE mode {number} ({own})"
        )
    return messages


def correlate(updating: Updating, restricted_shapes: np.ndarray, fe_hz: np.ndarray) -> ModeCorrelation:
    """MAC matrix, pairing and swaps of the design's EMA shapes against FE shapes.

    Parameters
    ----------
    updating : Updating
        The [updating] section, with shapes (``has_shapes``).
    restricted_shapes : ndarray
        The FE shapes at the measured DOFs, D·Φ (`measurement_matrix`), (n_dofs, n_e).
    fe_hz : ndarray
        The FE frequencies (n_e,).

    Returns
    -------
    ModeCorrelation
        The correlation of the measured modes with FE modes 1 … n_e.
    """
    measured_shapes = np.array([m.shape for m in updating.measured], dtype=float).T
    numbers = np.array([m.mode for m in updating.measured])
    measured_hz = np.array([m.frequency_hz for m in updating.measured])
    mac = modal_assurance_criterion(measured_shapes, restricted_shapes)
    paired = pair_modes(mac, measured_hz, fe_hz)
    return ModeCorrelation(
        numbers, measured_hz, paired + 1, np.asarray(fe_hz), mac, swap_messages(numbers, paired, mac, fe_hz)
    )


__all__ = [
    "ModeCorrelation",
    "ModeSwapWarning",
    "TIE_BREAK",
    "correlate",
    "measurement_matrix",
    "modal_assurance_criterion",
    "pair_modes",
    "swap_messages",
]
