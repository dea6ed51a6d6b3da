"""Every generated C file builds with clang as well as with gcc, under the documented strict
warning set (any warning an error): the firmware folder of both builds (controllers, CAN layer,
joint nodes, supervisor, XCP slave, the example's main), the FMUs' sources, and the compiled closed
loop with its plant kernel. Compilers differ in what they warn of (clang 14 found a float NAN
promoted to double in the plant kernel that gcc let pass); CI installs clang, so there this test
runs."""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest
from test_can_layer import REFERENCE

from smartjoint.codegen import build, closed_loop, fmu, generate
from smartjoint.design.control import artifact
from smartjoint.design.control import study as closed_loop_study


def _clang() -> str:
    found = shutil.which("clang") or next(
        (shutil.which(f"clang-{v}") for v in range(20, 10, -1) if shutil.which(f"clang-{v}")), None
    )
    if found is None:
        if os.environ.get("CI") or os.environ.get("SMARTJOINT_REQUIRE_FUZZ"):
            pytest.fail("clang is not installed — required here (CI / SMARTJOINT_REQUIRE_FUZZ)")
        pytest.skip("clang is not installed")
    return found


@pytest.fixture
def clang(monkeypatch):
    compiler = _clang()
    monkeypatch.setenv("CC", compiler)  # codegen's --check, the FMU build and the loop read CC
    return compiler


@pytest.mark.parametrize("real", ["float", "double"])
def test_the_firmware_folder_builds_with_clang(clang, real, tmp_path):
    placed = generate.generate(REFERENCE, tmp_path / real, real, check=True)
    assert placed.compiled["compiler"] == clang
    assert len(placed.compiled["sources"]) >= 10 and any("xcp" in s for s in placed.compiled["sources"])


def test_the_fmu_sources_and_the_compiled_loop_build_with_clang(clang, three_type_a, tmp_path):
    loaded = artifact.load(REFERENCE)
    for law in fmu.LAWS:
        for real in ("float", "double"):
            written = fmu.controller_fmu(loaded, law, tmp_path / f"{law}_{real}.fmu", 2, real)
            assert written.path.stat().st_size > 0
    design, model = three_type_a
    assert fmu.plant_fmu(closed_loop_study.setup(design, model), design, tmp_path / "truss.fmu", 3).path.exists()
    files = closed_loop.render(loaded)
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    for source in (name for name in files if name.endswith(".c")):
        done = subprocess.run([clang, *build.FLAGS, "-fsyntax-only", str(tmp_path / source)], capture_output=True,
                              text=True)  # fmt: skip
        assert done.returncode == 0, done.stderr
