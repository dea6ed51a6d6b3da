"""The build files generated beside the sources: a ``Makefile`` and a ``CMakeLists.txt`` that
build the host example and, for the Cortex-M4F of QEMU's ``mps2-an386``, the firmware library
and an image, the CMake toolchain file of that target, the image's self-check ``target_main.c``
and the board support it links, copied from ``firmware/target/mps2_an386``.

The board support (startup code and vector table, UART/SysTick/semihosting, linker script) is
copied into the output folder with the generator's banner in front, as the CAN layer copies the
E2E runtime, so the folder builds for its target as it stands; the Makefile's ``BOARD_DIR`` and
CMake's ``<PREFIX>_BOARD_DIR`` point the target build at another board's files instead.

The build files list no source by name but every ``.c`` of the folder less the target's own
(:data:`TARGET_SOURCES`): they build what the set holds, the controllers alone or with the CAN
layer (``firmware/README.md``, "Building for the target").
"""

from __future__ import annotations

from smartjoint.codegen import rendering
from smartjoint.common import package_data
from smartjoint.common.errors import ModelError

BOARD = "mps2_an386"  # the board support copied: firmware/target/<BOARD>
BOARD_FILES = ("startup.c", "board.c", "board.h", f"{BOARD}.ld")
TARGET_MAIN = "target_main.c"
TOOLCHAIN = "cortex-m4.cmake"
# What only the target image compiles: a host build (the example, `codegen --check`) leaves them out.
TARGET_SOURCES = ("startup.c", "board.c", TARGET_MAIN)


def board_support(banner: str) -> dict[str, str]:
    """The board's files, each with ``banner`` in front (a C comment, which the linker script
    takes too).

    Parameters
    ----------
    banner : str
        The generator's banner (``rendering.banner``).

    Returns
    -------
    dict of str to str
        File name → text, for every name of :data:`BOARD_FILES`.

    Raises
    ------
    ModelError
        A board file is missing from the installation.
    """
    folder = package_data.folder("smartjoint.firmware", f"target/{BOARD}")
    files = {}
    for name in BOARD_FILES:
        source = folder / name
        if not source.exists():
            raise ModelError(f"{source}: the board support is missing (it ships with the source tree)")
        note = f"/* Copied from smartjoint's firmware/target/{BOARD}/{name}. */\n"
        files[name] = f"{banner}\n{note}{source.read_text()}"
    return files


def render(context: dict, digest: str) -> dict[str, str]:
    """Render the build files, the target's self-check and the board support.

    Parameters
    ----------
    context : dict
        The example's template context (``generate.render``): ``prefix``, ``PREFIX``, ``real``,
        ``banner``, ``banner_hash`` and the example's stimulus literals.
    digest : str
        The artefact's sha256, named in the board files' banner (they do not depend on the
        scalar type, so their banner does not name one).

    Returns
    -------
    dict of str to str
        ``Makefile``, ``CMakeLists.txt``, :data:`TOOLCHAIN`, :data:`TARGET_MAIN` and the
        :data:`BOARD_FILES`.
    """
    env = rendering.environment()
    build = {
        **context,
        "board": BOARD,
        "target_name": "cortex-m4",
        "board_name": BOARD.replace("_", "-"),
        "board_sources": [n for n in BOARD_FILES if n.endswith(".c")],
        "linker_script": f"{BOARD}.ld",
        "target_main": TARGET_MAIN,
        "toolchain": TOOLCHAIN,
        "target_only": list(TARGET_SOURCES),
        "cpu_flags": "-mcpu=cortex-m4 -mthumb -mfpu=fpv4-sp-d16 -mfloat-abi=hard",
        "warnings": "-Wall -Wextra -Wpedantic -Wconversion -Wdouble-promotion -Wshadow",
    }
    files = {
        "Makefile": env.get_template("Makefile.j2").render(build),
        "CMakeLists.txt": env.get_template("CMakeLists.txt.j2").render(build),
        TOOLCHAIN: env.get_template("toolchain.cmake.j2").render(build),
        TARGET_MAIN: env.get_template("target_main.c.j2").render(build),
    }
    files.update(board_support(rendering.banner(digest, part=f"codegen, board support {BOARD}")))
    return files
