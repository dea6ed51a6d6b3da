"""The architecture of docs/architecture.md, checked on the source text alone (``ast``; nothing of
the project is imported, so a broken module cannot hide a broken rule).

- No import cycle between modules, nor between top-level packages: module-level and
  function-level imports alike, relative imports resolved, ``from package import submodule`` taken
  as an import of the submodule.
- The layering: ``common`` ← ``design`` ← ``codegen`` ← ``bench`` ← the command line
  (``smartjoint``), and inside ``design`` the stage order ``structure`` ← ``friction`` ←
  ``reduction`` ← ``plant`` ← ``control`` ← ``network`` (which may take only the controller
  artefact from ``control``). A module imports its own layer or lower ones, never a higher one.
- No module imports a private name of another module (public functions are the seams), nor
  reads the state of another module's private class (``tests/test_seams.py``).
- Every import of ``smartjoint.…`` anywhere in the tree names a module or a name that exists
  (no import path left behind by a move).
- Sizes: no module over 500 lines, no function over 80 lines, outside generated code and templates.
- Every subpackage ``__init__`` has a docstring, and an ``__all__`` naming only what it defines or
  imports.

Module names come from the folders through pyproject.toml's package-dir (``design/`` is
``smartjoint.design``), as the wheel installs them.
"""

from __future__ import annotations

import ast
import os
import tomllib
from dataclasses import dataclass
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE_DIRS: dict[str, str] = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]

# Top-level packages from the bottom up; a module may import its own layer and those below it.
LAYERS = (
    ("smartjoint.common", "smartjoint.firmware"),
    ("smartjoint.design",),
    ("smartjoint.codegen",),
    ("smartjoint.bench",),
    ("smartjoint",),  # the command line, the pipeline and the report
)
# The stages of smartjoint.design in pipeline order; a stage imports its own or earlier ones.
# The plant simulates any modal model, full or reduced; the reduction study (Fig. 10) runs both
# through it, so reduction comes after plant.
STAGES = ("structure", "friction", "plant", "reduction", "control", "network")
# Stage pairs that are allowed only through the named modules.
NARROW = {("network", "control"): {"smartjoint.design.control.artifact"}}

MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 80
# Not written by hand: the code generator's reference output (templates are not .py files).
GENERATED = ("firmware/generated",)
# Folders that are not the project's source: tools' caches, builds, virtual environments.
NOT_SOURCE = {"build", "dist", "__pycache__", "smartjoint-report"}


@dataclass(frozen=True)
class Import:
    """One import statement's target: the project module it runs, and the name taken from it."""

    importer: str  # the importing module, or the file's path for a file outside the package
    target: str  # the module that the statement runs (the deepest existing one)
    name: str | None  # ``from target import name`` where name is no submodule; else None
    where: str  # path:line


def _relative(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


@cache
def modules() -> dict[str, Path]:
    """Every module of the import package, by name, from the folders package-dir maps."""
    found: dict[str, Path] = {}
    for package, folder in PACKAGE_DIRS.items():
        base = ROOT / folder
        for source in sorted(base.rglob("*.py")):
            parts = source.relative_to(base).parts
            # A module only inside folders that are packages (firmware/fuzz/ is a folder of tools).
            if not all((base.joinpath(*parts[:i]) / "__init__.py").is_file() for i in range(len(parts))):
                continue
            name = ".".join((package, *parts[:-1], *([] if parts[-1] == "__init__.py" else [source.stem])))
            found[name] = source
    return found


def source_files() -> list[Path]:
    """Every Python file of the tree written by hand: the package, tests, benchmarks, examples, tools."""
    files = []
    for folder, subfolders, names in os.walk(ROOT):
        here = Path(folder)
        # Pruned in place, so that os.walk never enters a virtual environment or a build.
        subfolders[:] = sorted(
            name
            for name in subfolders
            if not (name.startswith(".") or name in NOT_SOURCE or name.endswith(".egg-info"))
            and _relative(here / name) not in GENERATED
        )
        files.extend(here / name for name in sorted(names) if name.endswith(".py"))
    return files


@cache
def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), filename=str(path))


@cache
def _nodes(path: Path) -> list[ast.AST]:
    """Every node of a file's syntax tree (walked once: the checks share it)."""
    return list(ast.walk(_tree(path)))


@cache
def _import_statements(path: Path) -> list[ast.Import | ast.ImportFrom]:
    """Every import statement of a file, at any depth (module level and inside functions)."""
    return [node for node in _nodes(path) if isinstance(node, (ast.Import, ast.ImportFrom))]


def _is_package(module: str) -> bool:
    return modules()[module].name == "__init__.py"


def _deepest_module(dotted: str) -> str | None:
    """The deepest project module that ``import dotted`` runs (None: not the project's)."""
    parts = dotted.split(".")
    for end in range(len(parts), 0, -1):
        if ".".join(parts[:end]) in modules():
            return ".".join(parts[:end])
    return None


def _package_of(importer: str) -> str:
    """The package that relative imports of ``importer`` start from."""
    return importer if importer in modules() and _is_package(importer) else importer.rpartition(".")[0]


def _origin(node: ast.ImportFrom, importer: str) -> str:
    """The absolute module name a ``from … import …`` statement takes its names from."""
    if not node.level:
        return node.module or ""
    base = _package_of(importer).split(".")
    base = base[: len(base) - node.level + 1]  # one level up per dot after the first
    return ".".join(base + ([node.module] if node.module else []))


def imports_of(path: Path, importer: str | None = None) -> list[Import]:
    """The project imports of one file, at any depth (module level and inside functions)."""
    importer = importer or _relative(path)
    found, relative = [], _relative(path)
    for node in _import_statements(path):
        where = f"{relative}:{node.lineno}"
        if isinstance(node, ast.Import):
            for alias in node.names:
                if (target := _deepest_module(alias.name)) is not None:
                    found.append(Import(importer, target, None, where))
        elif isinstance(node, ast.ImportFrom):
            origin = _origin(node, importer)
            if (target := _deepest_module(origin)) is None:
                continue
            for alias in node.names:
                if f"{origin}.{alias.name}" in modules():  # from package import submodule
                    found.append(Import(importer, f"{origin}.{alias.name}", None, where))
                else:
                    found.append(Import(importer, target, alias.name if target == origin else None, where))
    return found


@cache
def graph() -> dict[str, list[Import]]:
    """Module → its imports of other project modules."""
    return {name: [edge for edge in imports_of(path, name) if edge.target != name] for name, path in modules().items()}


def find_cycle(edges: dict[str, set[str]]) -> list[str] | None:
    """One cycle of a directed graph as [a, b, …, a], or None (iterative depth-first search)."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    for start in sorted(edges):
        if start in state:
            continue
        path, stack = [start], [iter(sorted(edges.get(start, ())))]
        state[start] = 1
        while stack:
            following = next(stack[-1], None)
            if following is None:
                state[path.pop()] = 2
                stack.pop()
            elif state.get(following) == 1:
                return path[path.index(following) :] + [following]
            elif following not in state:
                state[following] = 1
                path.append(following)
                stack.append(iter(sorted(edges.get(following, ()))))
    return None


def find_cycles(edges: dict[str, set[str]], most: int = 10) -> list[list[str]]:
    """Up to ``most`` cycles: each found one is broken at its closing edge before the next search."""
    remaining = {node: set(targets) for node, targets in edges.items()}
    cycles = []
    while len(cycles) < most and (cycle := find_cycle(remaining)) is not None:
        cycles.append(cycle)
        remaining[cycle[-2]].discard(cycle[-1])
    return cycles


def _describe(cycles: list[list[str]]) -> str:
    """Each cycle step by step, with the file and line of the import that makes each step."""
    lines = []
    for cycle in cycles:
        lines.append("  " + " → ".join(cycle))
        for importer, target in zip(cycle, cycle[1:]):
            where = next(
                e.where
                for name, edges in graph().items()
                if _owner(name, cycle) == importer
                for e in edges
                if _owner(e.target, cycle) == target
            )
            lines.append(f"      {importer} → {target}   ({where})")
    return "\n".join(lines)


def _owner(module: str, names: list[str]) -> str:
    """The longest of ``names`` that is ``module`` or one of its packages."""
    return max((n for n in names if module == n or module.startswith(n + ".")), key=len, default=module)


def test_no_import_cycle_between_modules():
    cycles = find_cycles({name: {edge.target for edge in edges} for name, edges in graph().items()})
    assert not cycles, "import cycles between modules:\n" + _describe(cycles)


def test_no_import_cycle_between_top_level_packages():
    packages = [name for layer in LAYERS for name in layer]
    edges: dict[str, set[str]] = {}
    for name, imports in graph().items():
        for edge in imports:
            if (source := _owner(name, packages)) != (target := _owner(edge.target, packages)):
                edges.setdefault(source, set()).add(target)
    cycles = find_cycles(edges)
    assert not cycles, "import cycles between top-level packages:\n" + _describe(cycles)


def _layer(module: str) -> int:
    owner = _owner(module, [name for layer in LAYERS for name in layer])
    return next(rank for rank, layer in enumerate(LAYERS) if owner in layer)


def _stage(module: str) -> str | None:
    """The stage of a module of smartjoint.design; None for the package itself (the facade above
    all stages)."""
    rest = module.removeprefix("smartjoint.design")
    return rest.split(".")[1] if rest else None


def layering_violations() -> list[str]:
    """Every import against the layering, as 'importer → target (path:line): why'."""
    violations = []
    for name, imports in graph().items():
        for edge in imports:
            line = f"{name} → {edge.target} ({edge.where})"
            if _layer(edge.target) > _layer(name):
                violations.append(f"{line}: a lower layer imports a higher one")
            elif _layer(name) == _layer(edge.target) == _layer("smartjoint.design"):
                ours, theirs = _stage(name), _stage(edge.target)
                if ours is not None and ours not in STAGES:
                    violations.append(f"{line}: {name} belongs to no stage of {STAGES}")
                elif theirs is None and ours is not None:
                    violations.append(f"{line}: a stage imports the design package's facade")
                elif ours is None or theirs is None or ours == theirs or theirs not in STAGES:
                    continue
                elif STAGES.index(theirs) > STAGES.index(ours):
                    violations.append(f"{line}: stage {ours} imports the later stage {theirs}")
                elif (ours, theirs) in NARROW and edge.target not in NARROW[ours, theirs]:
                    allowed = ", ".join(sorted(NARROW[ours, theirs]))
                    violations.append(f"{line}: stage {ours} may take from {theirs} only {allowed}")
    return sorted(set(violations))


def test_no_import_against_the_layering():
    violations = layering_violations()
    assert not violations, "imports against the layering (docs/architecture.md):\n" + "\n".join(violations)


@cache
def _module_names(tree: ast.Module) -> set[str]:
    """The names a module binds at its top level (definitions, assignments, imports), looking into
    if/try/with/for blocks but not into functions or classes."""
    names: set[str] = set()
    pending: list[ast.stmt] = list(tree.body)
    while pending:
        node = pending.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((alias.asname or alias.name).split(".")[0] for alias in node.names)
        elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign, ast.For, ast.With)):
            targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
            targets += [item.optional_vars for item in getattr(node, "items", ()) if item.optional_vars]
            names.update(n.id for t in targets if t is not None for n in ast.walk(t) if isinstance(n, ast.Name))
        for field in ("body", "orelse", "finalbody", "handlers"):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                pending.extend(getattr(node, field, ()))
    return names


def _is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def private_uses() -> list[str]:
    """Private names of one module used by another: ``from m import _x``, and ``m._x`` where m is
    a project module bound by an import."""
    uses = []
    for name, path in modules().items():
        bound: dict[str, str] = {}  # local name → the project module it is
        relative = _relative(path)
        for node in _import_statements(path):
            where = f"{relative}:{node.lineno}"
            if isinstance(node, ast.ImportFrom) and _deepest_module(origin := _origin(node, name)) is not None:
                for alias in node.names:
                    if f"{origin}.{alias.name}" in modules():
                        bound[alias.asname or alias.name] = f"{origin}.{alias.name}"
                    elif _is_private(alias.name) and origin != name:
                        uses.append(f"{name} imports {origin}.{alias.name} ({where})")
            elif isinstance(node, ast.Import):
                bound.update({a.asname: a.name for a in node.names if a.asname and a.name in modules()})
        for node in _nodes(path):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and _is_private(node.attr):
                if bound.get(node.value.id, name) != name:
                    uses.append(f"{name} uses {bound[node.value.id]}.{node.attr} ({relative}:{node.lineno})")
    return sorted(set(uses))


def test_no_module_uses_another_modules_private_names():
    uses = private_uses()
    assert not uses, "private names used across modules (make them public functions):\n" + "\n".join(uses)


def test_every_project_import_names_something_that_exists():
    """After a move, no import path may be left behind: tests, benchmarks, examples and tools included."""
    missing = []
    for path in source_files():
        importer = {p: name for name, p in modules().items()}.get(path)
        for node in _import_statements(path):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and not node.level and node.module:
                names = [node.module]
            for dotted in names:
                if dotted.split(".")[0] == "smartjoint" and dotted not in modules():
                    missing.append(f"{dotted} is no module ({_relative(path)}:{node.lineno})")
        for edge in imports_of(path, importer):
            if edge.name is not None and edge.name != "*":
                defined = _module_names(_tree(modules()[edge.target]))
                if edge.name not in defined and "__getattr__" not in defined:
                    missing.append(f"{edge.target} has no name {edge.name} ({edge.where})")
    assert not missing, "imports of things that do not exist:\n" + "\n".join(sorted(set(missing)))


def long_modules() -> list[str]:
    return [
        f"{_relative(path)}: {lines} lines"
        for path in source_files()
        if (lines := len(path.read_text().splitlines())) > MAX_MODULE_LINES
    ]


def long_functions() -> list[str]:
    found = []
    for path in source_files():
        for node in _nodes(path):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                start = min([node.lineno] + [decorator.lineno for decorator in node.decorator_list])
                if (lines := node.end_lineno - start + 1) > MAX_FUNCTION_LINES:
                    found.append(f"{_relative(path)}:{node.lineno} {node.name}: {lines} lines")
    return found


def test_no_module_over_500_lines():
    offenders = long_modules()
    assert not offenders, f"modules over {MAX_MODULE_LINES} lines:\n" + "\n".join(offenders)


def test_no_function_over_80_lines():
    offenders = long_functions()
    assert not offenders, f"functions over {MAX_FUNCTION_LINES} lines:\n" + "\n".join(offenders)


def init_problems() -> list[str]:
    """Subpackage __init__ modules without a docstring, without ``__all__``, or whose ``__all__``
    names what they neither define nor import."""
    problems = []
    for name, path in modules().items():
        if path.name != "__init__.py" or name == "smartjoint":
            continue
        tree = _tree(path)
        if ast.get_docstring(tree) is None:
            problems.append(f"{name} ({_relative(path)}): no docstring")
        assigned = [
            node.value
            for node in tree.body
            if (
                isinstance(node, ast.Assign)
                and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets)
            )
            or (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.target.id == "__all__")
        ]
        if not assigned:
            problems.append(f"{name} ({_relative(path)}): no __all__")
            continue
        value = assigned[-1]
        if not isinstance(value, (ast.List, ast.Tuple)) or not all(
            isinstance(e, ast.Constant) and isinstance(e.value, str) for e in value.elts
        ):
            problems.append(f"{name} ({_relative(path)}): __all__ is not a literal list of strings")
            continue
        listed = [e.value for e in value.elts]
        if len(set(listed)) != len(listed):
            problems.append(f"{name} ({_relative(path)}): __all__ names some names twice")
        unknown = sorted(set(listed) - _module_names(tree))
        if unknown:
            problems.append(f"{name} ({_relative(path)}): __all__ names what it neither defines nor imports: {unknown}")
    return problems


def test_every_subpackage_init_has_a_docstring_and_an_honest_all():
    problems = init_problems()
    assert not problems, "subpackage __init__ modules:\n" + "\n".join(problems)


def test_the_checks_see_the_whole_package():
    """The checks above are vacuous if the module map goes wrong: every mapped folder has modules,
    every module has its layer, and the graph has edges."""
    assert {name for name in modules() if _is_package(name)} >= set(PACKAGE_DIRS)
    assert all(_layer(name) is not None for name in modules())
    assert sum(len(edges) for edges in graph().values()) > len(modules())
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
