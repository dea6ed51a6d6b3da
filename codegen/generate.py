"""Render the controller design artefact into fixed-step C99 (jinja2 templates in ``templates/``).

One call gives a self-contained folder: ``<prefix>_types.h`` (the scalar type and status bits),
``<prefix>_siso.h/.c`` (Eq. 30–31 in every joint), ``<prefix>_clqg.h/.c`` (Eq. 33–34), an
example ``main.c``, and (``build_files.py``) a ``Makefile``, a ``CMakeLists.txt`` and a CMake
toolchain file for the host example and the Cortex-M4F image, with the image's self-check and
the board support it links. The C mirrors the Python reference
controllers of ``design/control/laws.py`` statement by statement (update order, clipping, boundary
layers, fault handling) and exploits the model's structure: the predictor is a 2×2 block per
coordinate. Rendering is deterministic: the same artefact and options give byte-identical
files; the banner names the generator version and the artefact hash, never a date
(``rendering.py``).

:func:`generate` is the whole ``smartjoint codegen`` pipeline on top: render the controllers
and the CAN layer (``can_layer.py``), optionally compile the set (``build.py``) and put it into
place (``output.py``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smartjoint.codegen import build, build_files, can_layer, joint_nodes, output, rendering, xcp_slave
from smartjoint.common import law_registry
from smartjoint.design.control import artifact as artifacts
from smartjoint.design.structure.description import Xcp


def _common_context(artifact: artifacts.ControllerArtifact, real: str, prefix: str, lit, row) -> dict:
    """What every template sees: names, the banner, the sample time and the ranges both laws check."""
    banner = rendering.banner(artifact.artifact_sha256, real)
    return {
        "prefix": prefix,
        "PREFIX": prefix.upper(),
        "real": real,
        "banner": banner,
        "banner_hash": "# " + banner[3:-3].replace("\n * ", "\n# "),
        "zero": lit(0.0),
        "one": lit(1.0),
        "sample_time": lit(artifact.sample_time),
        "joints": list(artifact.joint_names),
        "sensors": list(artifact.sensor_names),
        "normal_force_min": row(artifact.normal_force_min),
        "normal_force_range": row(np.asarray(artifact.normal_force_max) - np.asarray(artifact.normal_force_min)),
        # The safe state and the plausibility ranges (docs/safety.md): checked by both laws.
        "safe_normal_force": row(artifact.safe_normal_force),
        "friction_force_limit": row(artifact.friction_force_limit),
        "measured_normal_force_min": row(artifact.measured_normal_force_min),
        "measured_normal_force_max": row(artifact.measured_normal_force_max),
        # Every law of the registry, for the example loops; the CAN example runs the fault-matrix law.
        "laws": [
            {"name": law.name, "display": law.display, "inputs": law.inputs} for law in law_registry.LAWS.values()
        ],
        "example_law": law_registry.fault_matrix_law().name,
    }


def _limits(artifact: artifacts.ControllerArtifact, law: law_registry.Law, row) -> dict:
    """The law's normal-force limits: its own F_N^min (the SISO preload) where it has one."""
    low = np.asarray(getattr(artifact, law.lower_force_field()), dtype=float)
    return {
        "normal_force_min": row(low),
        "normal_force_range": row(np.asarray(artifact.normal_force_max, dtype=float) - low),
    }


def render(artifact: artifacts.ControllerArtifact, real: str = "float", prefix: str = "smartjoint") -> dict[str, str]:
    """Render the controllers of an artefact (Eq. 30–31 and Eq. 33–34) into C99 text.

    Parameters
    ----------
    artifact : ControllerArtifact
        The controller design artefact.
    real : str
        The scalar type of the build, ``"float"`` or ``"double"``.
    prefix : str
        The prefix of every C identifier and file name.

    Returns
    -------
    dict of str to str
        File name → text of the generated folder (see the module docstring).

    Raises
    ------
    ModelError
        What ``rendering.check`` refuses, before anything is rendered.

    Examples
    --------
    >>> sorted(render(artifact, "double"))  # doctest: +SKIP
    ['CMakeLists.txt', 'Makefile', 'main.c', 'smartjoint_clqg.c', 'smartjoint_clqg.h', ...]
    """
    rendering.check(artifact, real, prefix)
    lit = lambda value: rendering.literal(value, real)  # noqa: E731
    row = lambda values: ", ".join(lit(v) for v in np.asarray(values, dtype=float).reshape(-1))  # noqa: E731
    common = _common_context(artifact, real, prefix, lit, row)
    env = rendering.environment()
    files: dict[str, str] = {}
    files[f"{prefix}_types.h"] = env.get_template("types.h.j2").render(common)
    for law in law_registry.LAWS.values():  # each law's templates with the context its entry names
        name = law.c_name(prefix)
        context = {**common, "name": name, "NAME": name.upper(), **_limits(artifact, law, row)}
        context.update(law.codegen_context(artifact, lit, row))
        for kind in "hc":
            files[f"{name}.{kind}"] = env.get_template(f"{law.name}.{kind}.j2").render(context)
    example = {
        **common,
        "amplitude": lit(1e-3),
        "decay": lit(0.995),
        "friction_scale": lit(1e4),
        "sensor_scale": lit(10.0),
    }
    files["main.c"] = env.get_template("main.c.j2").render(example)
    files.update(build_files.render(example, artifact.artifact_sha256))
    return files


def firmware_files(
    artifact: artifacts.ControllerArtifact,
    real: str = "float",
    prefix: str = "smartjoint",
    xcp: Xcp | None = None,
    **can_options,
) -> dict[str, str]:
    """The whole generated folder of an artefact, file name → text: the controllers (:func:`render`),
    the CAN layer with its DBC files (``can_layer.render_can``; ``can_options`` such as the design's
    ``network`` plan), the joint nodes of local mode with their supervisor (``joint_nodes``) and
    the XCP slave (``xcp_slave``; ``xcp`` the design's ``[xcp]``, default its defaults)."""
    files = render(artifact, real, prefix)
    files.update(can_layer.render_can(artifact, prefix, real=real, nodes=True, **can_options))
    files.update(joint_nodes.render_nodes(artifact, prefix, real))
    files.update(xcp_slave.render_xcp(artifact, prefix, real, xcp, can_options.get("network")))
    return files


def generate(
    source,
    folder,
    real: str = "float",
    prefix: str = "smartjoint",
    can: bool = True,
    check: bool = False,
    progress=None,
    **can_options,
):
    """The ``smartjoint codegen`` pipeline: render, optionally compile, and place the folder.

    The artefact is loaded and validated, the controllers and (``can``) the CAN layer are
    rendered, the set is written into a temporary folder next to ``folder``, with ``check``
    compiled there (``build.check_folder``), and only then moved into place (``output.place``).
    Nothing is written when any check fails.

    Parameters
    ----------
    source : path or ControllerArtifact
        The artefact file or the loaded artefact.
    folder : path
        The output folder (created if missing; files codegen did not write stay untouched).
    real : str
        The scalar type, ``"float"`` or ``"double"``.
    prefix : str
        The prefix of every C identifier and file name.
    can : bool
        Also render the CAN message layer.
    check : bool
        Compile every header and source with ``build.FLAGS`` before the move.
    progress : callable, optional
        ``progress(message)`` hears when the compile check starts.
    **can_options
        Passed to ``can_layer.render_can`` (``amplifier``, ``full_codec``).

    Returns
    -------
    output.Placed
        The files written and left untouched; ``compiled`` is the check's summary (or None).

    Examples
    --------
    >>> generate("firmware/generated/controller.json", "out", check=True)  # doctest: +SKIP
    """
    artifact = source if isinstance(source, artifacts.ControllerArtifact) else artifacts.load(Path(source))
    files = firmware_files(artifact, real, prefix, **can_options) if can else render(artifact, real, prefix)
    compiled = {}

    def compile_all(staging: Path) -> None:
        if progress is not None:
            progress(f"compiling the generated C with {' '.join(build.FLAGS)} before they move into place …")
        compiled.update(build.check_folder(staging))

    placed = output.place(files, Path(folder), check=compile_all if check else None)
    placed.compiled = compiled or None
    return placed
