"""The build files generated beside the sources (codegen/build_files.py): the Makefile and the
CMakeLists.txt build the host example and, with arm-none-eabi-gcc and newlib-nano, the firmware
library and the image of QEMU's mps2-an386 (Cortex-M4F), CMake through the generated toolchain
file; every warning is an error; the image links, its flash and RAM are printed, and it passes
its self-check in the emulator with the host example's numbers."""

from __future__ import annotations

import re
import shutil
import struct
from pathlib import Path

import pytest
from conftest import run

from smartjoint.codegen import build, build_files, generate, output
from smartjoint.common import law_registry, package_data
from smartjoint.common.errors import ModelError
from smartjoint.design.control import artifact
from smartjoint.design.network import joint_node

ROOT = Path(__file__).resolve().parents[1]
CROSS = shutil.which("arm-none-eabi-gcc") is not None
NO_CROSS = "arm-none-eabi-gcc not installed (CI installs gcc-arm-none-eabi)"
NO_CMAKE = "cmake not installed (CI installs it)"
NO_QEMU = "qemu-system-arm not installed (CI installs it)"
IMAGE = "smartjoint_mps2_an386"
# One line of arm-none-eabi-size's Berkeley table: text, data, bss, dec, hex, file.
SIZE_LINE = re.compile(r"^\s*(\d+)\s+(\d+)\s+(\d+)\s+\d+\s+[0-9a-f]+\s+(\S+)$", re.M)


@pytest.fixture(scope="module")
def reference():
    return artifact.load(ROOT / "firmware" / "generated" / "controller.json")


@pytest.fixture
def folder(reference, tmp_path):
    """The whole generated set (controllers, CAN layer, build files, board support) as codegen writes it."""
    generate.generate(reference, tmp_path / "firmware")
    return tmp_path / "firmware"


def qemu(elf: Path) -> object:
    return run(
        "qemu-system-arm", "-M", "mps2-an386", "-nographic", "-monitor", "none",
        "-semihosting-config", "enable=on,target=native", "-kernel", elf, timeout=60,
    )  # fmt: skip


def image_size(text: str, name: str) -> tuple[int, int]:
    """Flash (text + data) and RAM (data + bss) of ``name`` from arm-none-eabi-size's table."""
    for text_, data, bss, file in SIZE_LINE.findall(text):
        if file.endswith(name):
            return int(text_) + int(data), int(data) + int(bss)
    raise AssertionError(f"no size line of {name} in:\n{text}")


def check_self_check(elf: Path, host_output: str) -> None:
    """The image exits 0 with PASS, and its last commands are the host example's numbers."""
    if shutil.which("qemu-system-arm") is None:
        pytest.skip(NO_QEMU)
    done = qemu(elf)
    assert done.returncode == 0 and done.stdout.rstrip().endswith("PASS"), (done.returncode, done.stdout)
    assert "status 0\n" in host_output, host_output
    for law in law_registry.LAWS.values():  # every law's last command, on the target and the host
        bits = re.search(rf" {law.name} ([0-9a-f]{{8}})", done.stdout)
        host = re.search(rf"{re.escape(law.display)} F_N\[0\] = (\S+) N,", host_output)
        assert bits and host, (law.name, done.stdout, host_output)
        assert f"{struct.unpack('>f', bytes.fromhex(bits.group(1)))[0]:g}" == host.group(1)


def test_build_files_are_deterministic_bannered_and_held_to_the_tested_warnings(reference):
    first, again = generate.render(reference, "float"), generate.render(reference, "float")
    assert first == again
    names = {"Makefile", "CMakeLists.txt", build_files.TOOLCHAIN, build_files.TARGET_MAIN, *build_files.BOARD_FILES}
    assert names <= set(first)
    for name in names:
        assert first[name].startswith(output.BANNERS), name
        assert reference.artifact_sha256 in first[name].split("\n", 1)[0], name
    board = package_data.folder("smartjoint.firmware", f"target/{build_files.BOARD}")
    for name in build_files.BOARD_FILES:  # the board's files as they are, below the banner
        assert first[name].endswith((board / name).read_text()), name
    warnings = " ".join(build.WARNINGS)
    assert f"{warnings.replace(' -Werror', '')} -Werror" in first["Makefile"]
    assert "-ffp-contract=off" in first["Makefile"] and "-ffp-contract=off" in first["CMakeLists.txt"]
    toolchain = first[build_files.TOOLCHAIN]
    for line in ("set(CMAKE_SYSTEM_NAME Generic)", "set(CMAKE_SYSTEM_PROCESSOR arm)",
                 "set(CMAKE_TRY_COMPILE_TARGET_TYPE STATIC_LIBRARY)", "--specs=nano.specs",
                 "-mcpu=cortex-m4 -mthumb -mfpu=fpv4-sp-d16 -mfloat-abi=hard"):  # fmt: skip
        assert line in toolchain, line
    double = generate.render(reference, "double")
    assert "library call" in double["Makefile"] and "library call" not in first["Makefile"]


def test_make_builds_the_host_example(folder, reference):
    done = run("make", "-C", folder)
    assert done.returncode == 0, done.stderr
    assert "-Werror" in done.stdout and "target_main.c" not in done.stdout and "startup.c" not in done.stdout
    example = run(folder / "example")
    assert example.returncode == 0 and "status 0" in example.stdout
    # Local mode as the example runs it: the supervisor and every node on a bus in memory, a status
    # from each node every SUPERVISION_CYCLES samples, every node healthy under the law.
    line = r"local mode: 100 samples, (\d+) node statuses taken, node 0 F_N = (\S+) N, health of the nodes: (\d+)"
    local = re.search(line, example.stdout)
    assert local, example.stdout
    assert int(local[1]) == len(reference.joint_names) * 100 // joint_node.SUPERVISION_CYCLES and local[3] == "0"


@pytest.mark.skipif(not CROSS, reason=NO_CROSS)
def test_make_target_builds_links_and_sizes_the_cortex_m4_image(folder):
    done = run("make", "-C", folder, "TARGET=cortex-m4")
    assert done.returncode == 0, done.stderr
    build_dir = folder / "build" / "cortex-m4"
    for flag in ("-mcpu=cortex-m4", "-mfloat-abi=hard", "--specs=nano.specs", "-Wl,--gc-sections",
                 "-ffunction-sections", "-fdata-sections", "-Werror", "-DSMARTJOINT_TARGET_CAN"):  # fmt: skip
        assert flag in done.stdout, flag
    flash, ram = image_size(done.stdout, f"{IMAGE}.elf")
    assert 4096 < flash < 65536 and ram >= 8192  # the linker script reserves an 8 KiB stack
    assert "smartjoint_can.o (ex" in done.stdout  # the library's members are sized too
    for suffix in (".elf", ".map", ".hex", ".bin"):
        assert (build_dir / f"{IMAGE}{suffix}").stat().st_size > 0, suffix
    assert "sj_reset_handler" in (build_dir / f"{IMAGE}.map").read_text()
    assert run("make", "-C", folder).returncode == 0  # the host example beside it
    check_self_check(build_dir / f"{IMAGE}.elf", run(folder / "example").stdout)
    assert run("make", "-C", folder, "clean").returncode == 0 and not build_dir.exists()


@pytest.mark.skipif(not CROSS, reason=NO_CROSS)
def test_every_warning_is_an_error_on_host_and_target(folder):
    (folder / "extra.c").write_text("int extra(int x);\nint extra(int x)\n{\n    int unused;\n    return x;\n}\n")
    host = run("make", "-C", folder)
    assert host.returncode != 0 and "unused" in host.stderr
    target = run("make", "-C", folder, "target")
    assert target.returncode != 0 and "unused" in target.stderr
    assert run("make", "-C", folder, "TARGET=risc-v").returncode != 0  # an unknown target is refused


@pytest.mark.skipif(not CROSS, reason=NO_CROSS)
def test_controllers_alone_build_against_another_board_folder(reference, tmp_path):
    """No CAN layer, and the board support taken from BOARD_DIR (here the source tree's own)."""
    folder = tmp_path / "controllers"
    output.write(generate.render(reference, "float"), folder)
    for name in build_files.BOARD_FILES:
        (folder / name).unlink()
    board = package_data.folder("smartjoint.firmware", f"target/{build_files.BOARD}")
    done = run("make", "-C", folder, "target", f"BOARD_DIR={board}")
    assert done.returncode == 0, done.stderr
    assert "TARGET_CAN" not in done.stdout and f"-T,{board}/{build_files.BOARD}.ld" in done.stdout
    assert run("make", "-C", folder).returncode == 0
    check_self_check(folder / "build" / "cortex-m4" / f"{IMAGE}.elf", run(folder / "example").stdout)


@pytest.mark.skipif(shutil.which("cmake") is None, reason=NO_CMAKE)
def test_cmake_builds_the_host_example(folder, tmp_path):
    assert run("cmake", "-S", folder, "-B", tmp_path / "host").returncode == 0
    done = run("cmake", "--build", tmp_path / "host", "--verbose")
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr
    assert "-Werror" in done.stdout and "-std=c99" in done.stdout and "target_main.c" not in done.stdout
    example = run(tmp_path / "host" / "smartjoint_example")
    assert example.returncode == 0 and "status 0" in example.stdout


@pytest.mark.skipif(shutil.which("cmake") is None, reason=NO_CMAKE)
@pytest.mark.skipif(not CROSS, reason=NO_CROSS)
def test_cmake_with_the_toolchain_file_builds_the_cortex_m4_image(folder, tmp_path):
    cross = tmp_path / "cross"
    configure = run("cmake", "-S", folder, "-B", cross, f"-DCMAKE_TOOLCHAIN_FILE={folder / build_files.TOOLCHAIN}")
    assert configure.returncode == 0, configure.stdout[-3000:] + configure.stderr
    assert "arm-none-eabi-gcc" in (cross / "CMakeCache.txt").read_text()
    done = run("cmake", "--build", cross, "--verbose")
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr
    for flag in ("-mcpu=cortex-m4", "-mfpu=fpv4-sp-d16", "--specs=nano.specs", "-Wl,--gc-sections", "-Werror"):
        assert flag in done.stdout, flag
    flash, ram = image_size(done.stdout, f"{IMAGE}.elf")
    assert 4096 < flash < 65536 and ram >= 8192
    made = run("make", "-C", folder, "target")  # the same image as the Makefile's, within a few bytes
    assert made.returncode == 0, made.stderr
    assert abs(image_size(made.stdout, f"{IMAGE}.elf")[0] - flash) <= 64
    assert (cross / f"{IMAGE}.map").stat().st_size > 0 and (cross / f"{IMAGE}.hex").stat().st_size > 0
    assert run("make", "-C", folder).returncode == 0
    check_self_check(cross / f"{IMAGE}.elf", run(folder / "example").stdout)


def test_codegen_refuses_to_replace_a_board_file_it_did_not_write(reference, tmp_path):
    """The board support is copied under the board's own names: a hand-written startup.c in the
    output folder stops codegen (nothing written), as any file of the set it did not write."""
    (tmp_path / "startup.c").write_text("/* my startup */\n")
    with pytest.raises(ModelError, match="startup.c: not written by smartjoint codegen"):
        generate.generate(reference, tmp_path)
    assert [p.name for p in tmp_path.iterdir()] == ["startup.c"]
