"""The law registry (``common/law_registry.py``): every table of a law is derived from it, its
entries agree with the generated C and the Python references, and no module spells a law's name
on its own (a ratchet: the modules still listed below are what remains of issue 29).
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import re
from pathlib import Path

import numpy as np
import pytest

from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError

ROOT = Path(__file__).resolve().parents[1]
ARTIFACT = ROOT / "firmware" / "generated" / "controller.json"


def test_every_law_table_is_the_registry():
    from smartjoint.bench import amplifier, firmware, fmu_check, target
    from smartjoint.codegen import closed_loop, controllers, fmu
    from smartjoint.design.control import sweep_file
    from smartjoint.design.network import protocol

    laws = law_registry.LAWS.values()
    assert list(fmu.LAWS) == list(law_registry.NAMES)
    assert firmware.LAWS == {law.name: law.mode for law in laws}
    assert closed_loop.LAWS == {law.display: law.name for law in laws}
    assert {name: law for name, (law, _) in fmu_check.LAWS.items()} == closed_loop.LAWS
    assert target.INPUT_FIELDS == {law.name: law.inputs for law in laws}
    assert set(amplifier.CONTROLLER_MODES) == {law.mode for law in laws} | {protocol.MODE_SAFE}
    assert all(law.display in sweep_file.LAWS for law in laws)
    assert protocol.MODES == {0: "INIT", **{law.mode: law.name.upper() for law in laws}, protocol.MODE_SAFE: "SAFE"}
    assert controllers.law_registry is law_registry  # the compiled wrapper reads the entries


def test_entries_are_complete_and_distinct():
    from smartjoint.design.plant.interface import Measurements

    fields = {f.name for f in dataclasses.fields(Measurements)}
    names = [law.name for law in law_registry.LAWS.values()]
    assert len(set(names)) == len(names) and all(re.fullmatch(r"[a-z][a-z0-9]*", n) for n in names)
    assert len({law.display for law in law_registry.LAWS.values()}) == len(names)
    modes = [law.mode for law in law_registry.LAWS.values()]
    assert len(set(modes)) == len(modes) and not {law_registry.MODE_INIT, law_registry.MODE_SAFE} & set(modes)
    for law in law_registry.LAWS.values():
        assert set(law.inputs) <= fields, law.name
        assert law.outputs[0] == "normal_force"
        module, function = law.codegen.split(":")
        assert callable(getattr(importlib.import_module(module), function)), law.codegen


def test_lookup_by_either_name_and_a_one_line_refusal():
    for law in law_registry.LAWS.values():
        assert law_registry.law(law.name) is law_registry.law(law.display) is law
    with pytest.raises(ModelError) as refused:
        law_registry.law("lqr", "--law")
    assert str(refused.value) == f"--law: 'lqr' — allowed: {', '.join(law_registry.NAMES)}"


def test_the_generated_structs_hold_what_the_entries_say():
    """Each law's C input and output structs have the entry's fields in the entry's order."""
    from smartjoint.codegen import generate
    from smartjoint.design.control import artifact

    files = generate.render(artifact.load(ARTIFACT), "double", "smartjoint")
    for law in law_registry.LAWS.values():
        header = files[f"{law.c_name('smartjoint')}.h"]
        for kind, expected in (("input", law.inputs), ("output", law.outputs)):
            body = re.search(r"typedef struct \{([^}]*)\} " + law.c_name("smartjoint") + "_" + kind + ";", header)
            assert body is not None, (law.name, kind)
            assert tuple(re.findall(r"(\w+)\[", body.group(1))) == expected, (law.name, kind)


def test_the_python_reference_is_a_controller_of_the_artefact():
    from smartjoint.design.control import artifact
    from tests.conftest import plausible_measurements

    a = artifact.load(ARTIFACT)
    samples = plausible_measurements(a, 5, 3, 1e-5, 1e-4, 10.0)
    for law in law_registry.LAWS.values():
        controller = law.python_reference(a)
        assert controller.sample_time == a.sample_time
        controller.reset()
        for m in samples:
            command = controller.step(m)
            assert command.shape == (len(a.joint_names),)
            assert np.all((command >= a.normal_force_min) & (command <= a.normal_force_max))


def test_the_command_line_offers_the_registry():
    from smartjoint import cli

    parser = cli.build_parser() if hasattr(cli, "build_parser") else None
    if parser is None:
        pytest.skip("the command line builds its parser inside main()")
    text = parser.format_help()
    assert text


# --------------------------------------------------------------------------- no law's name elsewhere
# Python modules of the package that spell a law's name in a string literal of their own: none.
REMAINING: dict[str, int] = {}
# The registry and each law's own code: the modules its entry names (``Law.modules``: its tuning,
# its study controller, what its templates see, its Python reference).
OWN = {"common/law_registry.py"} | {
    "/".join(module.split(".")[1:]) + ".py" for law in law_registry.LAWS.values() for module in law.modules()
}
_NAME = re.compile(
    r"(?<![A-Za-z])(" + "|".join(re.escape(n) for law in law_registry.LAWS.values() for n in (law.name, law.display))
    + r")(?![a-z])"
)  # fmt: skip


def _package_files() -> list[Path]:
    import tomllib

    folders = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"].values()
    files = []
    for folder in folders:
        for path in sorted((ROOT / folder).rglob("*.py")):
            relative = path.relative_to(ROOT).as_posix()
            if not relative.startswith(("firmware/generated", "firmware/fuzz")):
                files.append(path)
    return files


def _law_literals(path: Path) -> int:
    """String literals (f-string parts too) of a module that spell a law's name, docstrings aside."""
    tree = ast.parse(path.read_text())
    docstrings = {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
        and node.body
        and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    }
    return sum(
        1
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant)
        and isinstance(node.value, str)
        and id(node) not in docstrings
        and _NAME.search(node.value)
    )


def test_no_module_spells_a_law_name_beyond_what_remains():
    found = {}
    for path in _package_files():
        relative = path.relative_to(ROOT).as_posix()
        if relative not in OWN:
            count = _law_literals(path)
            if count:
                found[relative] = count
    grown = {k: (v, REMAINING.get(k, 0)) for k, v in found.items() if v > REMAINING.get(k, 0)}
    assert not grown, f"law names spelled outside the registry (found, allowed): {grown}"
    fallen = {k: (found.get(k, 0), v) for k, v in REMAINING.items() if found.get(k, 0) < v}
    assert not fallen, f"fewer law names than REMAINING says — lower it (found, listed): {fallen}"
