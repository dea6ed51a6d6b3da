"""The data files the package opens at run time, named in one place.

C kernels, the hand-written firmware runtime, the code generator's templates and the bundled
designs ship inside the package (``pyproject.toml``, ``[tool.setuptools.package-data]``), so an
installed wheel runs from any folder. Every module that opens one of them asks :func:`path` or
:func:`folder` here instead of locating it beside its own source file; ``tests/test_packaging.py``
builds the wheel and checks it against :data:`FILES`.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from smartjoint.common import law_registry

# Import package → the files it owns, relative to the package folder.
FILES: dict[str, tuple[str, ...]] = {
    "smartjoint": ("py.typed",),
    "smartjoint.design.plant": ("plant_kernel.c", "plant_kernel.h"),
    "smartjoint.design.friction": ("rig_kernel.c",),
    "smartjoint.design.control": ("controller-artifact.schema.json",),
    "smartjoint.design": (
        "data/meroform_10bay.toml",
        "data/fig10_three_joints.toml",
        "data/three_type_a.toml",
        "data/paper_table1_type_a.toml",
        "data/paper_table1_type_b.toml",
        "data/mast_30bay.toml",
        "data/mast_30bay_twelve_a.toml",
    ),
    "smartjoint.codegen": tuple(
        f"templates/{name}"
        for name in (
            "CMakeLists.txt.j2",
            "Makefile.j2",
            "can.c.j2",
            "can.h.j2",
            "closed_loop.c.j2",
            "closed_loop.h.j2",
            "example_laws.c.j2",
            "main.c.j2",
            "main_can.c.j2",
            "node.c.j2",
            "node.h.j2",
            "node_config.c.j2",
            "supervisor.c.j2",
            "supervisor.h.j2",
            *(f"{law}.{kind}.j2" for law in sorted(law_registry.NAMES) for kind in "ch"),
            "target_main.c.j2",
            "toolchain.cmake.j2",
            "types.h.j2",
            "xcp.c.j2",
            "xcp.h.j2",
            "xcp_key.c.j2",
            *(
                f"fmu/{name}"
                for name in (
                    "buildDescription.xml.j2",
                    "documentation.html.j2",
                    "fmi2_functions.c.j2",
                    "fmi3_functions.c.j2",
                    "fmu_access.c.j2",
                    "fmu_controller.c.j2",
                    "fmu_model.h.j2",
                    "fmu_plant.c.j2",
                    "fmu_state.c.j2",
                    "modelDescription2.xml.j2",
                    "modelDescription3.xml.j2",
                )
            ),
        )
    ),
    "smartjoint.firmware": (
        "runtime/sj_e2e.c",
        "runtime/sj_e2e.h",
        "runtime/replay.c",
        *(
            f"target/mps2_an386/{name}"
            for name in ("Makefile", "board.c", "board.h", "mps2_an386.ld", "pil.c", "selftest.c", "startup.c")
        ),
    ),
}


def _root(package: str) -> Path:
    if package not in FILES:
        raise KeyError(f"{package!r} owns no data files; packages with data: {', '.join(sorted(FILES))}")
    try:
        root = resources.files(package)
    except ModuleNotFoundError:
        raise ModuleNotFoundError(
            f"{package} is not installed: the installed smartjoint predates it; reinstall it (pip install -e .)"
        ) from None
    # Regular packages on disk (a wheel or an editable install): the traversable is a Path.
    return Path(str(root))


def path(package: str, name: str) -> Path:
    """The data file ``name`` of ``package`` on disk.

    Parameters
    ----------
    package : str
        A key of :data:`FILES`, e.g. ``"smartjoint.design"``.
    name : str
        One of its data files, e.g. ``"data/meroform_10bay.toml"``.

    Returns
    -------
    Path

    Raises
    ------
    KeyError
        When ``name`` is not one of the package's data files (they must be listed to be packaged).
    """
    if name not in FILES.get(package, ()):
        raise KeyError(f"{package}: {name!r} is not one of its data files (common/package_data.py FILES)")
    return _root(package) / name


def folder(package: str, name: str) -> Path:
    """The folder ``name`` of ``package`` that holds some of its data files, on disk, as
    :func:`path` finds a file; a ``KeyError`` when it holds none of them.

    Parameters
    ----------
    package : str
        A key of :data:`FILES`.
    name : str
        A folder of it, e.g. ``"runtime"``.
    """
    if not any(f.startswith(name.rstrip("/") + "/") for f in FILES.get(package, ())):
        raise KeyError(f"{package}: {name!r} holds none of its data files (common/package_data.py FILES)")
    return _root(package) / name


def all_files() -> list[tuple[str, Path]]:
    """Every data file of the package.

    Returns
    -------
    list of (str, Path)
        The path inside the package tree (e.g. ``smartjoint/design/friction/rig_kernel.c``) and
        the path on disk.
    """
    return [
        (f"{package.replace('.', '/')}/{name}", path(package, name))
        for package, names in FILES.items()
        for name in names
    ]
