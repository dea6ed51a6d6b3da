"""An FE model with its lowest modes, solved once and handed on.

The stages of ``smartjoint run`` need the same eigen solution several times: the report's
spectrum, joint placement, the reduction study's basis, the controllers' design model, the
ensemble. Each used to build the FE model from the design and solve its modes anew; a
:class:`SolvedModel` is built once by the structure stage and handed on: placement and the
controllers' design model take the modes they need from it (:meth:`SolvedModel.first`), the
reduction study its FE model (it solves every mode for its full-model reference), and the
ensemble the design model built from it.
"""

from __future__ import annotations

from dataclasses import dataclass

from smartjoint.common.errors import ModelError
from smartjoint.design.structure.fem import FEModel
from smartjoint.design.structure.modal import Modes, solve_modes


@dataclass(frozen=True)
class SolvedModel:
    """An FE model and its lowest modes (Eq. 5–7).

    Attributes
    ----------
    fe : FEModel
        The model (its joints locked or released, as it was built).
    modes : Modes
        Its lowest ``len(modes)`` modes.
    """

    fe: FEModel
    modes: Modes

    def first(self, count: int) -> Modes:
        """The lowest ``count`` modes of the solution (never more than were solved).

        Parameters
        ----------
        count : int
            How many, at most the DOFs; a number above ``len(modes)`` is an error, not a new solve.

        Returns
        -------
        Modes
        """
        count = min(count, self.fe.n_dof)
        if count > len(self.modes):
            raise ModelError(f"modes: {count} asked of a solution of {len(self.modes)} — solve more first")
        if count == len(self.modes):
            return self.modes
        m = self.modes
        return Modes(m.omega[:count], m.shapes[:, :count], m.damping[:count])


def solved_model(fe: FEModel, count: int) -> SolvedModel:
    """Solve the lowest ``count`` modes of ``fe`` (capped at its DOFs) once.

    Parameters
    ----------
    fe : FEModel
    count : int

    Returns
    -------
    SolvedModel
    """
    return SolvedModel(fe, solve_modes(fe, min(count, fe.n_dof)))


__all__ = ["SolvedModel", "solved_model"]
