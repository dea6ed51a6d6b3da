"""The registry of friction models: one entry per contact law a joint may have, carrying what
every stage needs to know of it.

LuGre (paper Eq. 1–2) is the one model. Its six parameter names used to be spelled in eleven
modules (the design file, the parameter files, the rig, the identification, the plant's joint
laws, the artefact, the sweeps, the command line); each reads them from :data:`MODELS` now, so a
second model is an entry here and its own modules (docs/architecture.md, "How to add a friction
model").

An entry names the model once (``name``: the design file's ``model = …`` of a ``[friction.X]``
table), lists its parameters per unit normal force (``Parameter``: the key in the design file, a
parameter file, the artefact's ``friction.parameters`` columns and a sweep's
``uncertain.friction.<key>``; its symbol, units by joint type and sign), and names the code of
its own by import path (``module`` or ``module:attribute``, as a package's entry points are):

- ``reference``: the scalar law (:class:`smartjoint.design.friction.model.FrictionLaw`): the
  parameter set, the friction force, the exact state step, the steady sliding curve, the
  break-away level, the rig's plausible ranges;
- ``plant``: the joint laws of the closed-loop plant vectorised over the joints (what the fixed-step and
  stick-exact schemes, the Radau reference and the C plant kernel's structs hold);
- ``rig``: the isolated-joint rig's integration of one record;
- ``identification``: the modules of the identification of rig records (Eq. 3): its fit, its
  output-error step and the design of its rig campaign from a prior.

The registry is data: of the project it imports only ``common.errors``, so the design file's
parser (``design.structure``) and the command line read it without loading numpy.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

from smartjoint.common.errors import ModelError


@dataclass(frozen=True)
class Parameter:
    """A parameter of a friction model, per unit normal force.

    Attributes
    ----------
    key : str
        Its key in the design file's ``[friction.X]`` table, a parameter file, a sweep file
        (``uncertain.friction.<key>``), the command line (``--<key>``, ``_`` as ``-``), and its
        column of the artefact's ``friction.parameters``.
    symbol : str
        The paper's symbol.
    meaning : str
        What it is, for the help, the documentation and the errors.
    units : tuple of str
        Its unit for a type A joint (translation) and a type B joint (rotation).
    may_be_zero : bool
        Zero is allowed (no damping, no viscous part); else it must be > 0.
    """

    key: str
    symbol: str
    meaning: str
    units: tuple[str, str]
    may_be_zero: bool = False

    def unit(self, joint_type: str) -> str:
        """Its unit for a joint of ``joint_type`` ("A" or "B")."""
        return self.units[0 if joint_type == "A" else 1]


@dataclass(frozen=True)
class FrictionModel:
    """One friction model of the joints.

    Attributes
    ----------
    name : str
        The one spelling in code and in the design file (``model = "lugre"``).
    display : str
        Its name in the report and the help.
    equations : tuple of int
        The paper's equations it is.
    state : str
        Its internal state, per joint (one number).
    parameters : tuple of Parameter
        Its parameters per unit normal force, in the order of the artefact's columns.
    reference, plant, rig : str
        Its own code by import path (see the module docstring).
    identification : tuple of str
        The modules of its identification (see the module docstring).
    """

    name: str
    display: str
    equations: tuple[int, ...]
    state: str
    parameters: tuple[Parameter, ...]
    reference: str
    plant: str
    rig: str
    identification: tuple[str, ...]

    @property
    def keys(self) -> tuple[str, ...]:
        """The parameters' keys, in order."""
        return tuple(p.key for p in self.parameters)

    def parameter(self, key: str) -> Parameter:
        """The parameter of ``key``."""
        return {p.key: p for p in self.parameters}[key]

    def modules(self) -> set[str]:
        """The modules of its own code (they may spell its parameters' keys)."""
        return {path.split(":")[0] for path in (self.reference, self.plant, self.rig, *self.identification)}

    def python_reference(self) -> Any:
        """The scalar law (``reference``), a :class:`~smartjoint.design.friction.model.FrictionLaw`."""
        return _resolve(self.reference)

    def rig_integration(self) -> Any:
        """The rig's integration of one record (``rig``)."""
        return _resolve(self.rig)

    def plant_laws(self, parameters: list) -> Any:
        """The plant's joint laws over ``parameters`` (one parameter set per joint)."""
        return _resolve(self.plant)(parameters)

    def cited(self) -> str:
        """ "Eq. 1–2": its equations, for the documentation and the report."""
        first, last = self.equations[0], self.equations[-1]
        return f"Eq. {first}" if first == last else f"Eq. {first}–{last}"


def _resolve(path: str) -> Any:
    """The object an import path ``module`` or ``module:attribute`` names."""
    module, _, attribute = path.partition(":")
    loaded = importlib.import_module(module)
    return getattr(loaded, attribute) if attribute else loaded


LUGRE = FrictionModel(
    name="lugre",
    display="LuGre",
    equations=(1, 2),
    state="bristle deflection φ [m] (type B: [rad])",
    parameters=(
        Parameter("sigma0", "σ0", "bristle stiffness", ("1/m", "1/rad")),
        Parameter("sigma1", "σ1", "bristle damping", ("s/m", "s/rad"), may_be_zero=True),
        Parameter("sigma2", "σ2", "viscous friction", ("s/m", "s/rad"), may_be_zero=True),
        Parameter("coulomb", "F_c", "Coulomb coefficient", ("", "")),
        Parameter("stribeck", "F_d", "Stribeck excess F_s − F_c", ("", ""), may_be_zero=True),
        Parameter("stribeck_velocity", "v_s", "Stribeck velocity", ("m/s", "rad/s")),
    ),
    reference="smartjoint.design.friction.lugre",
    plant="smartjoint.design.plant.joints:JointLaws",
    rig="smartjoint.design.friction.rig_integration:integrate",
    identification=(
        "smartjoint.design.friction.identify",
        "smartjoint.design.friction.output_error",
        "smartjoint.design.friction.rig_campaign",
        "smartjoint.design.friction.equation_error",
        "smartjoint.design.friction.sequential_campaign",
        "smartjoint.design.friction.round_design",
        "smartjoint.design.friction.identifiability",
    ),
)

MODELS: dict[str, FrictionModel] = {model.name: model for model in (LUGRE,)}
DEFAULT = LUGRE.name  # a friction table without ``model`` is LuGre's (the paper's)


def friction_model(name: str = DEFAULT, field: str = "model") -> FrictionModel:
    """The model of ``name``.

    Parameters
    ----------
    name : str
        The model's name.
    field : str
        The input that named it, for the error.

    Raises
    ------
    ModelError
        One line naming the field, the value and the models there are.
    """
    if name not in MODELS:
        raise ModelError(f"{field}: {name!r} — allowed: {', '.join(MODELS)}")
    return MODELS[name]


__all__ = ["DEFAULT", "LUGRE", "MODELS", "FrictionModel", "Parameter", "friction_model"]
