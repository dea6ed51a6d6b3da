"""The seam between the joints' friction model and the stages that use it.

A friction model is an entry of ``common/friction_registry.py`` (its name, its parameters, its
own code by import path). What its scalar Python law provides is :class:`FrictionLaw`; the
stages reach it through this module: the parameter sets of a design's joints
(:func:`joint_parameters`), a model's law (:func:`law_of`) and the plant's joint laws over the
joints (:func:`plant_laws`). LuGre (``lugre.py``, Eq. 1–2) is the one model.
"""

from __future__ import annotations

from typing import Any, Protocol

from smartjoint.common import friction_registry
from smartjoint.common.errors import MISSING, DesignError


class FrictionParameters(Protocol):
    """A joint's parameter set of a model, per unit normal force."""

    @property
    def model(self) -> str:
        """Its model's name in the registry."""
        ...

    @property
    def radius(self) -> float | None:
        """r [m] of a type B joint, None for type A."""
        ...

    @property
    def moment_arm(self) -> float:
        """r for type B, 1 for type A: u_R = moment_arm·F_N·μ."""
        ...

    def values(self) -> dict[str, float]:
        """The parameters by key, in the registry's order."""
        ...


class FrictionLaw(Protocol):
    """What a friction model's Python reference (its registry entry's ``reference``) provides.

    The state z is one number per joint (LuGre: the bristle deflection φ); each function works
    elementwise on arrays of velocities and states.
    """

    Parameters: Any  # the parameter set's class: Parameters(**values, radius=…)
    TABLE_1: dict  # the paper's parameter set by joint type, where the paper gives one; else {}
    PLAUSIBLE: dict  # key → ((lower, upper, lower allowed) for type A, … for type B): the rig's ranges

    def friction_coefficient(self, p: Any, velocity: Any, state: Any) -> Any:
        """μ(v, z): u_R = r·F_N·μ."""
        ...

    def friction_force(self, p: Any, velocity: Any, state: Any, normal_force: Any) -> Any:
        """u_R = r·F_N·μ(v, z)."""
        ...

    def step(self, p: Any, state: Any, velocity: Any, dt: float) -> Any:
        """z after a step ``dt`` with ``velocity`` held, stable for any step."""
        ...

    def steady_state_coefficient(self, p: Any, velocity: Any) -> Any:
        """μ of steady sliding at ``velocity``: the friction curve."""
        ...

    def breakaway_coefficient(self, p: Any) -> float:
        """The static level per unit r·F_N, where sticking turns into sliding."""
        ...


def law_of(model: str) -> FrictionLaw:
    """The Python reference of the registry's model ``model``."""
    return friction_registry.friction_model(model).python_reference()


def joint_parameters(design) -> list:
    """The parameter set of each joint of a design, as its design file gives them.

    Parameters
    ----------
    design : Design
        The design whose ``joints`` are read in order; each joint's own ``friction`` or its
        type's ``[friction.X]`` table, of the model that table names.

    Returns
    -------
    list
        One parameter set (:class:`FrictionParameters`) per joint.

    Raises
    ------
    DesignError
        For a joint without parameters: nothing falls back to the paper's Table 1.
    """
    sets = []
    for index, joint in enumerate(design.joints):
        friction = design.joint_friction(joint)
        if friction is None:
            raise DesignError(
                f"joints[{index}].friction",
                MISSING,
                f"joint {joint.name!r} (type {joint.type}) has no friction parameters — give [friction.{joint.type}] "
                "(inline or file = …) or the joint's own friction",
                design.source,
            )
        sets.append(law_of(friction.model).Parameters(**friction.values(), radius=friction.radius))
    return sets


def plant_laws(parameters: list) -> Any:
    """The plant's joint laws over the joints' parameter sets (the model's ``plant`` entry).

    Parameters
    ----------
    parameters : list
        One parameter set per joint, all of one model.

    Raises
    ------
    ValueError
        For joints of different models: the plant's kernels hold one model's arrays.
    """
    models = sorted({p.model for p in parameters}) or [friction_registry.DEFAULT]
    if len(models) > 1:
        raise ValueError(f"joint friction models: {', '.join(models)} — the plant holds one model for all joints")
    return friction_registry.friction_model(models[0]).plant_laws(parameters)


__all__ = ["FrictionLaw", "FrictionParameters", "joint_parameters", "law_of", "plant_laws"]
