"""The wheel carries every data file the code opens (C kernels, firmware runtime, templates, bundled
designs), and the code finds them inside the installed package, not in a source tree beside it.

The data files are named once, in ``common/package_data.py``; these tests build the wheel from
the files ``pyproject.toml`` maps into the package and hold it against that list, the list against
the source tree, and the installed code against the list.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

from smartjoint.common import package_data

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
PACKAGE_DIRS: dict[str, str] = PYPROJECT["tool"]["setuptools"]["package-dir"]


def _pip_wheel(source: Path, dist: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", *extra, "-w", str(dist), str(source)],
        capture_output=True,
        text=True,
        timeout=600,
    )


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel built from a copy of exactly what pyproject.toml packages (a stray file in the
    work tree can neither help nor hurt)."""
    base = tmp_path_factory.mktemp("wheel")
    source, dist = base / "source", base / "dist"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, source / name)
    for folder in sorted(set(PACKAGE_DIRS.values())):
        shutil.copytree(ROOT / folder, source / folder, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    done = _pip_wheel(source, dist)
    if done.returncode != 0:  # no index for the isolated build environment: build with this environment's tools
        done = _pip_wheel(source, dist, "--no-build-isolation")
    assert done.returncode == 0, f"pip wheel failed:\n{done.stderr[-3000:]}"
    (built,) = dist.glob("smartjoint-*.whl")
    return built


def _source_folder(package: str) -> Path:
    """The source folder of an import package: its own package-dir entry, or its parent's plus the rest."""
    parent = max((name for name in PACKAGE_DIRS if package == name or package.startswith(name + ".")), key=len)
    return ROOT / PACKAGE_DIRS[parent] / Path(*package[len(parent) :].split(".")[1:])


def _data_folders(package: str) -> set[str]:
    return {str(Path(name).parent) for name in package_data.FILES[package]}


def test_the_wheel_holds_every_data_file_the_code_opens(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    missing = [inside for inside, _ in package_data.all_files() if inside not in names]
    assert not missing, f"data files missing from {wheel.name}: {missing}"
    # Each data file of the wheel is byte for byte the source file.
    with zipfile.ZipFile(wheel) as archive:
        for inside, on_disk in package_data.all_files():
            assert archive.read(inside) == on_disk.read_bytes(), inside


def test_every_data_file_of_the_source_tree_is_named_in_the_registry():
    """A new template, kernel or bundled design must be named in package_data.FILES, or the wheel
    check above would not see it."""
    for package, names in package_data.FILES.items():
        folder = _source_folder(package)
        for sub in _data_folders(package):
            present = {
                f"{sub}/{p.name}".removeprefix("./")
                for p in (folder / sub).iterdir()
                if p.is_file() and p.suffix not in (".py", ".pyc") and p.name != "README.md"
            }
            assert present <= set(names), f"{package}: not in package_data.FILES: {sorted(present - set(names))}"
        assert all((folder / name).is_file() for name in names), package


def test_no_module_locates_files_beside_its_own_source():
    """Files found through __file__ work in the source tree and break in a wheel with another
    layout; the package opens its data only through package_data."""
    offenders = []
    for folder in sorted(set(PACKAGE_DIRS.values())):
        for source in (ROOT / folder).rglob("*.py"):
            # Only modules the wheel installs: a tool in a folder that is no package (firmware/fuzz/
            # prepare.py works on the source tree's firmware/generated/) never runs from a wheel.
            if not all(
                (parent / "__init__.py").exists() for parent in source.parents if parent.is_relative_to(ROOT / folder)
            ):
                continue
            if "__file__" in source.read_text():
                offenders.append(str(source.relative_to(ROOT)))
    assert not offenders, f"modules that locate files through __file__: {offenders}"


CHECK = r"""
import json, sys
from pathlib import Path
root = Path(sys.argv[1]).resolve()
import smartjoint
from smartjoint import pipeline
from smartjoint.bench import e2e
from smartjoint.codegen import can_layer, generate, rendering
from smartjoint.common import package_data
from smartjoint.design.control import artifact
from smartjoint.design.friction import rig_integration
from smartjoint.design.structure import spec
found = {"package": smartjoint.__file__,
         "files": [str(p) for _, p in package_data.all_files()],
         "constants": [str(p) for p in (spec.REFERENCE_DESIGN, pipeline.__file__,
                                        rendering.TEMPLATES, can_layer.RUNTIME, e2e.RUNTIME)]}
# Open them the way the commands do: the templates, the runtime copied into the CAN layer, the
# E2E twin and the rig kernel compiled, the bundled design loaded.
controller = artifact.load(Path(sys.argv[2]))
files = {**generate.render(controller, "float"), **can_layer.render_can(controller)}
found["rendered"] = sorted(files)
found["crc"] = e2e.compiled().lib.sj_crc8_j1850(b"123456789", 9, 0xFF) ^ 0xFF
rig_integration.kernel()
found["nodes"] = len(spec.load_design().nodes)
print(json.dumps(found))
"""


def test_the_installed_wheel_opens_its_data_from_inside_itself(wheel, tmp_path):
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as archive:
        archive.extractall(site)
    # The unpacked wheel first on the path: its smartjoint shadows the editable one of this checkout.
    env = {**os.environ, "PYTHONPATH": str(site)}
    done = subprocess.run(
        [sys.executable, "-c", CHECK, str(site), str(ROOT / "firmware" / "generated" / "controller.json")],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    found = json.loads(done.stdout)
    assert Path(found["package"]).resolve().is_relative_to(site.resolve())
    for name in found["files"] + found["constants"]:
        assert Path(name).resolve().is_relative_to(site.resolve()) and Path(name).exists(), name
    assert {"sj_e2e.c", "sj_e2e.h", "bus.dbc"} <= set(found["rendered"])
    assert found["crc"] == 0x4B  # the CRC-8 SAE J1850 check value of "123456789"
    assert found["nodes"] > 0
