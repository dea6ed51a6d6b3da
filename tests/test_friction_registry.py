"""The friction-model registry (``common/friction_registry.py``): every table of a model's
parameters is derived from it, no module outside a model's own spells its parameters, and a
second model is an entry — shown with Dahl's model (Dahl 1968, LuGre's ancestor: φ̇ = v − σ0|v|φ/F_c,
μ = σ0·φ), registered here for the test only, which runs through the design file, the rig, the
plant and the report.
"""

from __future__ import annotations

import ast
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
from conftest import TABLE_1_A, TABLE_1_B, small_truss

from smartjoint.common import friction_registry
from smartjoint.common.errors import ModelError
from smartjoint.common.friction_registry import FrictionModel, Parameter
from smartjoint.design.friction import lugre, rig
from smartjoint.design.friction.model import joint_parameters, law_of, plant_laws
from smartjoint.design.friction.rig_integration import integrate
from smartjoint.design.plant.joints import JointLaws
from smartjoint.design.structure.spec import parse_design

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("common", "design", "codegen", "bench", "smartjoint")


def _spelled(tree: ast.AST, keys: set[str]) -> list[int]:
    """Lines where a parameter key is a string literal, an attribute or a keyword argument."""
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in keys:
            lines.append(node.lineno)
        elif isinstance(node, ast.Attribute) and node.attr in keys:
            lines.append(node.lineno)
        elif isinstance(node, ast.keyword) and node.arg in keys:
            lines.append(node.value.lineno)
    return lines


def test_no_module_but_a_models_own_spells_its_parameters():
    owners = {"smartjoint.common.friction_registry"}
    keys: set[str] = set()
    for model in friction_registry.MODELS.values():
        owners |= model.modules()
        keys |= set(model.keys)
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            relative = path.relative_to(ROOT).with_suffix("")
            name = ".".join(("smartjoint", *relative.parts)) if package != "smartjoint" else ".".join(relative.parts)
            if name.removesuffix(".__init__") in owners:
                continue
            lines = _spelled(ast.parse(path.read_text(encoding="utf-8")), keys)
            if lines:
                found[str(path.relative_to(ROOT))] = lines
    assert found == {}, f"a friction parameter spelled outside its model's modules: {found}"
    # the registry, and LuGre's reference, plant, rig and seven identification modules (Eq. 3's force,
    # its steps, output error, the ladder, the sequential campaign, its rounds' design, identifiability)
    assert len(owners) == 11


def test_the_tables_of_lugre_are_the_registry():
    model = friction_registry.LUGRE
    assert tuple(lugre.TYPE_A.values()) == model.keys
    assert tuple(lugre.PLAUSIBLE) == model.keys
    assert [f.name for f in dataclasses.fields(lugre.LuGreParameters)] == [*model.keys, "radius"]
    zero = {p.key for p in model.parameters if p.may_be_zero}
    for key in model.keys:  # the parameter set refuses what the registry does
        value = 0.0 if key in zero else -1.0
        with pytest.raises(ValueError, match=key):
            lugre.LuGreParameters(**{**lugre.TYPE_A.values(), key: value - (key in zero)})
        if key not in zero:
            with pytest.raises(ValueError, match=key):
                lugre.LuGreParameters(**{**lugre.TYPE_A.values(), key: 0.0})
    assert law_of(model.name) is lugre
    assert model.cited() == "Eq. 1–2"
    with pytest.raises(ModelError) as refused:
        friction_registry.friction_model("stribeck_curve", "[friction.A] model")
    assert str(refused.value) == "[friction.A] model: 'stribeck_curve' — allowed: lugre"


def test_the_design_file_refuses_an_unknown_model_in_one_line():
    from smartjoint.common.errors import DesignError

    data = small_truss()
    data["friction"]["A"] = {"model": "coulomb", **TABLE_1_A}
    with pytest.raises(DesignError) as refused:
        parse_design(data)
    assert "friction.A.model: 'coulomb' — allowed: 'lugre'" in str(refused.value)
    assert "\n" not in str(refused.value)


# ---------------------------------------------------------------------------------------------
# A second model as an entry: Dahl's, written as LuGre without damping, viscous part and
# Stribeck excess, so that the project's LuGre code is its exact reference.


@dataclass(frozen=True)
class DahlParameters:
    model: ClassVar[str] = "dahl"
    sigma0: float
    coulomb: float
    radius: float | None = None

    def __post_init__(self):
        if not (self.sigma0 > 0 and self.coulomb > 0):
            raise ValueError("Dahl parameters sigma0 and coulomb must be > 0")

    @property
    def moment_arm(self) -> float:
        return self.radius if self.radius is not None else 1.0

    def values(self) -> dict[str, float]:
        return {"sigma0": self.sigma0, "coulomb": self.coulomb}


def as_lugre(p: DahlParameters) -> lugre.LuGreParameters:
    return lugre.LuGreParameters(p.sigma0, 0.0, 0.0, p.coulomb, 0.0, 1.0, p.radius)


class DahlLaw:
    """The Python reference of the Dahl entry (``design.friction.model.FrictionLaw``)."""

    Parameters = DahlParameters
    TABLE_1: ClassVar[dict] = {}
    PLAUSIBLE: ClassVar[dict] = {
        "sigma0": ((0.0, 1e10, False), (0.0, 1e10, False)),
        "coulomb": ((0.0, 10.0, False), (0.0, 10.0, False)),
    }

    @staticmethod
    def friction_coefficient(p, velocity, state):
        return lugre.friction_coefficient(as_lugre(p), velocity, state)

    @staticmethod
    def friction_force(p, velocity, state, normal_force):
        return p.moment_arm * normal_force * p.sigma0 * np.asarray(state)

    @staticmethod
    def step(p, state, velocity, dt):
        return lugre.step(as_lugre(p), state, velocity, dt)

    @staticmethod
    def steady_state_coefficient(p, velocity):
        return np.sign(velocity) * p.coulomb

    @staticmethod
    def breakaway_coefficient(p):
        return p.coulomb


def dahl_plant(parameters):
    return JointLaws([as_lugre(p) for p in parameters])


def dahl_rig(p, *arguments):
    return integrate(as_lugre(p), *arguments)


DAHL = FrictionModel(
    name="dahl",
    display="Dahl",
    equations=(1, 2),
    state="bristle deflection φ [m] (type B: [rad])",
    parameters=(
        Parameter("sigma0", "σ0", "bristle stiffness", ("1/m", "1/rad")),
        Parameter("coulomb", "F_c", "Coulomb coefficient", ("", "")),
    ),
    reference="test_friction_registry:DahlLaw",
    plant="test_friction_registry:dahl_plant",
    rig="test_friction_registry:dahl_rig",
    identification=(),
)


@pytest.fixture
def dahl(monkeypatch):
    monkeypatch.setitem(friction_registry.MODELS, DAHL.name, DAHL)
    return DAHL


def _dahl_design():
    data = small_truss()
    data["friction"]["A"] = {"model": "dahl", "sigma0": TABLE_1_A["sigma0"], "coulomb": TABLE_1_A["coulomb"]}
    data["friction"]["B"] = {
        "model": "dahl",
        "sigma0": TABLE_1_B["sigma0"],
        "coulomb": TABLE_1_B["coulomb"],
        "radius": TABLE_1_B["radius"],
    }
    return parse_design(data)


def test_a_second_model_reaches_the_design_file_and_the_joints(dahl):
    design = _dahl_design()
    sets = joint_parameters(design)
    assert {type(p) for p in sets} == {DahlParameters}
    assert [p.radius is not None for p in sets] == [j.type == "B" for j in design.joints]
    assert design.joint_friction(design.joints[0]).values() == sets[0].values()
    data = small_truss()
    data["friction"]["A"] = {"model": "dahl", **TABLE_1_A}  # LuGre's keys are not Dahl's
    with pytest.raises(Exception, match="stribeck|sigma1"):
        parse_design(data)


def test_a_second_model_runs_in_the_plant_as_its_entry_says(dahl):
    """The plant reaches the model through its entry: Dahl's joints run the fixed-step C and
    Python kernels, bit for bit as LuGre with σ1 = σ2 = F_d = 0; a mix of models is refused."""
    from smartjoint.design import plant
    from smartjoint.design.structure import modal
    from smartjoint.design.structure.fem import build_model

    design = _dahl_design()
    sets = joint_parameters(design)
    fe = build_model(design, joints="released")
    model = modal.modal_model(fe, modal.solve_modes(fe, 8))
    x0 = np.zeros((model.n_coordinates, 2))
    x0[0, 1] = 1e-3
    normal_forces = np.full(len(sets), 50.0)
    runs = {}
    for name, joints in (("dahl", sets), ("lugre", [as_lugre(p) for p in sets])):
        for backend in ("c", "python"):
            controller = plant.ConstantNormalForce(normal_forces, 1e-3)
            result = plant.simulate(model, joints, controller, None, 0.05, 1e-4, initial_state=x0, backend=backend)
            runs[name, backend] = result
    for backend in ("c", "python"):
        for signal in ("sensors", "sliding_velocity", "friction_force", "deflection", "energy"):
            assert np.array_equal(getattr(runs["dahl", backend], signal), getattr(runs["lugre", backend], signal))
    assert np.max(np.abs(runs["dahl", "c"].friction_force)) > 0  # the joints act
    with pytest.raises(ValueError, match="dahl, lugre"):
        plant_laws([sets[0], as_lugre(sets[1])])


def test_a_second_model_runs_on_the_rig_and_in_the_report(dahl):
    from smartjoint.report_friction import friction_markdown

    chosen = rig.parameter_set("A", {"sigma0": TABLE_1_A["sigma0"], "coulomb": TABLE_1_A["coulomb"]}, "t", "dahl")
    assert isinstance(chosen.parameters, DahlParameters)
    assert chosen.describe().startswith("Dahl parameters (t, type A)")
    test = rig.RigTest("A", 400.0, 1.5 * rig.breakaway(chosen.parameters, 400.0), 10.0, cycles=1.0, sample_rate=5000.0)
    assert rig.breakaway(chosen.parameters, 400.0) == 400.0 * TABLE_1_A["coulomb"]
    dahl_record = rig.simulate(test, chosen.parameters, "t")
    lugre_record = rig.simulate(test, as_lugre(chosen.parameters), "t")
    assert np.array_equal(dahl_record.sliding_velocity, lugre_record.sliding_velocity)
    assert np.array_equal(dahl_record.friction_force, lugre_record.friction_force)
    assert dahl_record.metadata["regime"] == "stick-slip"
    with pytest.raises(rig.RigError, match="stribeck: unknown parameter — allowed: sigma0, coulomb"):
        rig.parameter_set("A", {"sigma0": 1e5, "coulomb": 0.5, "stribeck": 0.1}, "t", "dahl")
    with pytest.raises(rig.RigError, match="the paper gives no Dahl parameters"):
        rig.parameter_set("A", None, "t", "dahl")
    design = _dahl_design()
    report = friction_markdown(design, [], [])
    assert "Dahl parameters per unit normal force" in report
    assert "| joint | type | σ0 | F_c | r [m] | source |" in report
    row = next(line for line in report.splitlines() if line.startswith(f"| {design.joints[0].name} |"))
    assert f"{TABLE_1_A['sigma0']:.4g} | {TABLE_1_A['coulomb']:.4g}" in row


def test_the_artefact_refuses_a_model_it_cannot_hold(dahl):
    from smartjoint.design.control.artifact_building import friction_fields

    design = _dahl_design()
    with pytest.raises(ModelError) as refused:
        friction_fields(design, tuple(j.name for j in design.joints))
    message = str(refused.value)
    assert "model 'dahl'" in message and "LuGre parameters only" in message and "\n" not in message
