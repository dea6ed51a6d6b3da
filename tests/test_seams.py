"""The seams of docs/architecture.md beyond imports, on the source text alone (``ast``): no module
reads the state of another module's private class. A kernel handed from the plant to the
compiled closed loop offers its C structs through a public method; reading its attributes
directly (``kernel.cp``) ties the loop to the kernel's inside (issue 29).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

from tests.test_architecture import _import_statements, _is_private, _module_names, _nodes, _relative, _tree, modules


def _on_self(node: ast.AST) -> bool:
    return isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "self"


def _instance_attributes(path: Path) -> dict[str, set[str]]:
    """Per class of a module, the attributes its methods set on ``self``."""
    found: dict[str, set[str]] = {}
    for node in _nodes(path):
        if isinstance(node, ast.ClassDef):
            found[node.name] = {
                target.attr
                for inner in ast.walk(node)
                if isinstance(inner, (ast.Assign, ast.AnnAssign))
                for target in (inner.targets if isinstance(inner, ast.Assign) else [inner.target])
                for target in ast.walk(target)
                if _on_self(target)
            }
    return found


def _class_fields(path: Path) -> set[str]:
    """The names a module's class bodies bind (dataclass fields, class attributes)."""
    return {
        target.id
        for node in _nodes(path)
        if isinstance(node, ast.ClassDef)
        for statement in node.body
        if isinstance(statement, (ast.Assign, ast.AnnAssign))
        for target in (statement.targets if isinstance(statement, ast.Assign) else [statement.target])
        if isinstance(target, ast.Name)
    }


def private_state_uses() -> list[str]:
    """The state of another module's private class read from outside: ``x.cp`` where only a
    private class (``_CKernel``) of another module sets ``self.cp``, and no public class, function
    or module-level name of the project has that name. Such an object is handed on only to be
    used through its public methods."""
    private: dict[str, set[str]] = {}  # attribute → the modules whose private classes alone set it
    public: set[str] = set()
    for name, path in modules().items():
        for cls, attributes in _instance_attributes(path).items():
            for attribute in attributes:
                (private.setdefault(attribute, set()).add(name) if _is_private(cls) else public.add(attribute))
        public |= _module_names(_tree(path))
        public |= {n.name for n in _nodes(path) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))}
        public |= _class_fields(path)
    # Names every object of the language has (``text.count``), never a project object's state.
    kinds = (str, bytes, list, dict, set, tuple, int, float, object, re.Pattern, re.Match)
    public |= {name for kind in kinds for name in dir(kind)}
    owned = {attribute: owners for attribute, owners in private.items() if attribute not in public}
    # Per module, the names it binds to modules outside the project (``re.sub`` is no object's state).
    foreign = {
        name: {
            (alias.asname or alias.name).split(".")[0]
            for node in _import_statements(path)
            if isinstance(node, ast.Import)
            for alias in node.names
            if not alias.name.startswith("smartjoint")
        }
        for name, path in modules().items()
    }
    uses = []
    for name, path in modules().items():
        for node in _nodes(path):
            if (
                isinstance(node, ast.Attribute)
                and node.attr in owned
                and name not in owned[node.attr]
                and not (isinstance(node.value, ast.Name) and node.value.id in ("self", *foreign[name]))
            ):
                owners = ", ".join(sorted(owned[node.attr]))
                uses.append(f"{name} reads .{node.attr} of {owners} ({_relative(path)}:{node.lineno})")
    return sorted(set(uses))


def test_no_module_reads_the_state_of_another_modules_private_class():
    uses = private_state_uses()
    assert not uses, "another module's private object read from outside (offer a public method):\n" + "\n".join(uses)


# What the command line never loads itself: the sweep engine (``bench/sweep.py``) owns them.
ENGINE_PACKAGES = ("dask", "distributed", "pyarrow")


def command_line_engine_imports() -> list[str]:
    """Imports of the sweep engine's packages by a module of the command-line package
    (``smartjoint.<module>``, not a subpackage), at any depth."""
    found = []
    for name, path in modules().items():
        in_command_line = name == "smartjoint" or (name.count(".") == 1 and path.name != "__init__.py")
        if not in_command_line:
            continue
        for node in _import_statements(path):
            targets = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            for target in targets:
                if target.split(".")[0] in ENGINE_PACKAGES:
                    found.append(f"{name} imports {target} ({_relative(path)}:{node.lineno})")
    return found


def test_the_command_line_package_imports_no_dask_or_parquet():
    assert not command_line_engine_imports(), "\n".join(command_line_engine_imports())
    # The check sees the modules it is about: the sweep engine does import them.
    engine = modules()["smartjoint.bench.sweep"]
    assert any(
        (a.name if isinstance(node, ast.Import) else node.module or "").split(".")[0] in ENGINE_PACKAGES
        for node in _import_statements(engine)
        for a in node.names
    )
