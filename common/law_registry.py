"""The registry of normal-force laws: one entry per law that runs in firmware, carrying all
that every stage needs to know of it.

A law's identity used to live in nine tables (the generated files, the compiled loop, the FMU,
the sweep file, the SIL firmware, the CAN modes, the amplifier's heartbeat check, the target's
input fields, the command line's choices). Each of them is derived from :data:`LAWS` now, so a
new law is an entry here, its Python reference and its templates (docs/architecture.md, "How
to add a law").

An entry names the law once (``name``: the C identifiers ``<prefix>_<name>_*``, the file names,
``--law``), shows it once (``display``: the study's run, the report's row, the sweep file's
``laws``), and carries its CAN mode id, the measurements its step reads (the C input struct's
fields, in struct order, each a field of ``interface.Measurements``), its outputs, its boundary
layer (the artefact field, unit and whether it is per joint: the FMU's tunable), the sweep grid
variables it answers to, and its Python reference built from the artefact alone.

The registry is data: of the project it imports only ``common.errors``, so the command line
reads it without loading numpy, and every layer above may use it. The Python reference is named by its import
path (``module:function``, as a package's entry points are) and loaded on first use.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

from smartjoint.common.errors import ModelError

# The CAN layer's modes that are no law (CONTROLLER_STATUS.mode; design.network.protocol).
MODE_INIT, MODE_SAFE = 0, 3


@dataclass(frozen=True)
class BoundaryLayer:
    """A law's boundary layer ε: where the artefact keeps it and what it is.

    Attributes
    ----------
    field : str
        The artefact field holding ε.
    unit : str
        Its unit ("m/s" for a velocity layer, "N" for a force layer).
    per_joint : bool
        One ε per joint (True) or one for the whole law.
    equation : int
        The paper's equation the layer smooths.
    """

    field: str
    unit: str
    per_joint: bool
    equation: int


@dataclass(frozen=True)
class Law:
    """One normal-force law of the firmware.

    Attributes
    ----------
    name : str
        The one spelling of the law in code: C identifiers ``<prefix>_<name>_*``, file names,
        templates ``<name>.h.j2``/``<name>.c.j2``, ``--law``.
    display : str
        The law's name to a reader: the study's run, the report's row, the sweep file's ``laws``.
    title : str
        One line naming the law and its equations (the FMU's description).
    mode : int
        Its mode id in CONTROLLER_STATUS.mode and in the CAN layer's RESET frame.
    inputs : tuple of str
        The measurements its step reads, in the order of its C input struct; each is a field
        of ``interface.Measurements``.
    outputs : tuple of str
        The fields of its C output struct, in order (``normal_force`` first).
    equation : int
        The equation of its command F_N.
    boundary_layer : BoundaryLayer
        Its tunable boundary layer.
    grid : tuple of str
        The sweep grid variables that re-design this law (beyond the common limits).
    artifact : tuple of (str, str)
        Its section ``laws.<name>`` of the controller artefact: (key in the file, field of
        ``ControllerArtifact``) per entry, in the file's order.
    codegen : str
        ``module:function`` giving what its templates ``<name>.h.j2``/``<name>.c.j2`` see beyond
        the common context, ``function(artifact, lit, row) -> dict`` (:meth:`codegen_context`).
    reference : str
        ``module:function`` of the Python reference, ``function(artifact) -> Controller``
        (``design.plant.interface``): the executable specification that the generated C
        matches sample by sample (:meth:`python_reference`).
    """

    name: str
    display: str
    title: str
    mode: int
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    equation: int
    boundary_layer: BoundaryLayer
    grid: tuple[str, ...]
    artifact: tuple[tuple[str, str], ...]
    codegen: str
    reference: str

    def python_reference(self, artifact: Any) -> Any:
        """The law's Python reference controller, built from a controller artefact alone.

        Parameters
        ----------
        artifact : ControllerArtifact

        Returns
        -------
        Controller
            ``reset()``, ``step(measurements) -> normal_forces``, ``sample_time``.
        """
        return _resolve(self.reference)(artifact)

    def codegen_context(self, artifact: Any, lit: Any, row: Any) -> dict:
        """What the law's templates see beyond the common context (the ``codegen`` function)."""
        return dict(_resolve(self.codegen)(artifact, lit, row))

    def c_name(self, prefix: str) -> str:
        """The law's C identifier stem, ``<prefix>_<name>`` (``<stem>_step``, ``<stem>.c``)."""
        return f"{prefix}_{self.name}"


def _resolve(path: str) -> Any:
    """The function at ``module:function``, imported on first use."""
    module, function = path.split(":")
    return getattr(importlib.import_module(module), function)


LAWS: dict[str, Law] = {
    law.name: law
    for law in (
        Law(
            name="siso",
            display="SISO",
            title="SISO law (Eq. 30-31)",
            mode=1,
            inputs=("sliding_velocity", "friction_force", "normal_force"),
            outputs=("normal_force",),
            equation=30,
            boundary_layer=BoundaryLayer("siso_boundary_layer", "m/s", per_joint=True, equation=30),
            grid=("siso_boundary_layer",),
            artifact=(("boundary_layer", "siso_boundary_layer"),),
            codegen="smartjoint.codegen.law_contexts:siso",
            reference="smartjoint.design.control.artifact:siso_law",
        ),
        Law(
            name="clqg",
            display="cLQG",
            title="clipped-optimal LQG (Eq. 33-34)",
            mode=2,
            inputs=("sensors", "friction_force", "normal_force"),
            outputs=("normal_force", "desired_force"),
            equation=34,
            boundary_layer=BoundaryLayer("clqg_boundary_layer", "N", per_joint=False, equation=34),
            grid=(),
            artifact=(
                ("boundary_layer", "clqg_boundary_layer"),
                *((field, field) for field in ("blocks", "gamma0", "gamma1", "joint_input", "output")),
                *((field, field) for field in ("feedback_gain", "estimator_gain", "modal_frequencies")),
            ),
            codegen="smartjoint.codegen.law_contexts:clqg",
            reference="smartjoint.design.control.artifact:clipped_lqg",
        ),
    )
}
NAMES = tuple(LAWS)  # every law by name, in registry order
DISPLAY = {law.display: law for law in LAWS.values()}  # the study's run name → its law


def law(name: str, field: str = "law") -> Law:
    """The law registered as ``name`` (its code name or its display name).

    Parameters
    ----------
    name : str
        A key of :data:`LAWS` ("siso") or a law's display name ("SISO").
    field : str
        What the caller calls it, for the error.

    Returns
    -------
    Law

    Raises
    ------
    ModelError
        An unknown law, in one line naming the allowed ones.

    Examples
    --------
    >>> law("siso").mode
    1
    >>> law("cLQG").name
    'clqg'
    """
    found = LAWS.get(name) or DISPLAY.get(name)
    if found is None:
        raise ModelError(f"{field}: {name!r} — allowed: {', '.join(LAWS)}")
    return found


def by_mode() -> dict[int, str]:
    """CONTROLLER_STATUS.mode's values and their names: INIT, every law's, SAFE."""
    modes = {MODE_INIT: "INIT", MODE_SAFE: "SAFE"}
    for entry in LAWS.values():
        if entry.mode in modes:
            raise ModelError(f"law {entry.name!r}: mode {entry.mode} is taken by {modes[entry.mode]}")
        modes[entry.mode] = entry.name.upper()
    return dict(sorted(modes.items()))


__all__ = ["DISPLAY", "LAWS", "MODE_INIT", "MODE_SAFE", "NAMES", "BoundaryLayer", "Law", "by_mode", "law"]
