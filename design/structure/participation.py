"""Modal participation factors and effective modal masses of the translations (base excitation).

For mass-normalised modes (φ_iᵀ M φ_j = δ_ij, Eq. 7) and the influence vector r_d of a unit
rigid translation along direction d, the participation factor and the effective modal mass are

    Γ_id = φ_iᵀ M r_d,        m_eff,id = Γ_id²,

and over all N modes Σ_i m_eff,id = r_dᵀ M Φ Φᵀ M r_d = r_dᵀ M r_d (Φ Φᵀ = M⁻¹): the free mass
along d, the mass that moves when the supports move. The cumulative fraction of that mass over
the kept modes says whether they carry the truss's response to a base or body-force excitation
along d.

r_d in the independent coordinates z (z̄ = S·z, Eq. 4): 1 at every translational DOF along d of a
node centre or a beam node, 0 at rotations and at joint DOFs (a rigid translation does not slip
any joint). Connector seats follow their node through S (u_p = u_n + θ_n × r with θ_n = 0), and
supported DOFs have no column in z, so S·r_d is the rigid translation of every point that is
free to move along d, and r_dᵀ M r_d = (S r_d)ᵀ M̄ (S r_d).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DIRECTIONS = ("x", "y", "z")
_TRANSLATIONS = {"ux": 0, "uy": 1, "uz": 2}


def rigid_body_translation(model) -> np.ndarray:
    """The influence vectors r_x, r_y, r_z of unit rigid translations, in z.

    Parameters
    ----------
    model : FEModel
        The FE model (joints locked or released).

    Returns
    -------
    ndarray
        (N, 3): column d is 1 at the translational DOFs along d, else 0.
    """
    r = np.zeros((model.n_dof, 3))
    for k, (_, dof) in enumerate(model.dof_labels):
        if dof in _TRANSLATIONS:
            r[k, _TRANSLATIONS[dof]] = 1.0
    return r


@dataclass
class ModalParticipation:
    """Participation factors Γ_id, effective masses m_eff,id = Γ_id² and their cumulative share
    of the free mass r_dᵀ M r_d, per mode i and direction d (x, y, z)."""

    participation: np.ndarray  # Γ (n_modes, 3) [√kg]
    effective_mass: np.ndarray  # m_eff (n_modes, 3) [kg]
    free_mass: np.ndarray  # r_dᵀ M r_d (3,) [kg]

    @property
    def cumulative_fraction(self) -> np.ndarray:
        """Σ_{j ≤ i} m_eff,jd / (r_dᵀ M r_d), (n_modes, 3); 0 along a direction without free mass."""
        total = np.where(self.free_mass > 0.0, self.free_mass, 1.0)
        return np.cumsum(self.effective_mass, axis=0) / total


def effective_modal_mass(model, shapes: np.ndarray) -> ModalParticipation:
    """Participation factors Γ_i = φ_iᵀ M r and effective modal masses m_eff,i = Γ_i² along x, y, z.

    Parameters
    ----------
    model : FEModel
        The FE model whose mass matrix M the shapes are normalised to.
    shapes : ndarray
        Mass-normalised mode shapes Φ (N, n_modes), Φᵀ M Φ = I (`Modes.shapes`).

    Returns
    -------
    ModalParticipation
        Γ, m_eff and the free mass per direction; over all N modes Σ_i m_eff,i = r_dᵀ M r_d.
    """
    r = rigid_body_translation(model)
    mass_r = np.asarray(model.mass @ r)
    participation = shapes.T @ mass_r
    return ModalParticipation(participation, participation**2, np.einsum("ij,ij->j", r, mass_r))


__all__ = ["DIRECTIONS", "ModalParticipation", "effective_modal_mass", "rigid_body_translation"]
