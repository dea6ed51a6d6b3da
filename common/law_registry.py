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
fields, in struct order, each a field of ``interface.Measurements``), its outputs, its settings
(``Setting``: the design file's ``[control] <law>_<key>``, the artefact's ``laws.<law>.<key>``,
a sweep grid variable and an FMU tunable each), the paper's orderings it takes part in, and the
functions of its own code by import path: its tuning, the controller the study runs, what its
templates see and its Python reference built from the artefact alone.

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
class Setting:
    """A setting of a law that the design file may give: ``[control] <law>_<key>``, and the key
    ``laws.<law>.<key>`` of the artefact (``Law.artifact`` names its field there).

    Attributes
    ----------
    key : str
        Its key in the law's artefact section; the design file's key is ``<law>_<key>``.
    unit : str
        Its unit.
    per_joint : bool
        One value per controlled joint (a single number in the file is every joint's).
    meaning : str
        What it is, for the documentation and the errors.
    default : float, str or None
        The value when the design file leaves it out: a number, the name of a ``[control]``
        field whose value it takes ("normal_force_max"), or None: the law's ``tune`` settles it
        (the SISO ε is optimised) or the setting is required.
    normal_force : bool
        It is a normal force: within [F_N^min, F_N^max] of its joint (else only > 0).
    lower_force : bool
        It is the lowest normal force the law commands, in place of the joints' F_N^min
        (:meth:`Law.lower_force_field`): the law's templates, its FMU's tunable
        ``JOINT_<j>.normal_force_min`` and the joint nodes take it as the law's F_N^min.
    per_sample_rate : bool
        A rate r [1/s] the law applies once per sample: Δt·r < 1, or F_N turns negative in one
        sample (the FMU's tunable refuses it).
    """

    key: str
    unit: str
    per_joint: bool
    meaning: str
    default: float | str | None = None
    normal_force: bool = False
    lower_force: bool = False
    per_sample_rate: bool = False

    def design_key(self, law: str) -> str:
        """Its key in the design file's ``[control]`` table, ``<law>_<key>``."""
        return f"{law}_{self.key}"


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
    equation : int or None
        The paper's equation of its command F_N (None: a law the paper writes no equation for).
    artifact : tuple of (str, str)
        Its section ``laws.<name>`` of the controller artefact: (key in the file, field of
        ``ControllerArtifact``) per entry, in the file's order.
    settings : tuple of Setting
        What the design file may set of it (``[control] <name>_<key>``); each is also a sweep
        grid variable of that name.
    tune : str
        ``module:function`` settling the settings the design file leaves open for a study,
        ``function(design, settings, setup, progress) -> (settings, record)``, or "" when each
        setting's default does (``design.control.tuning.tuned`` calls it).
    controller : str
        ``module:function`` of the controller the study runs, ``function(setup, lqg, settings)
        -> Controller``, built from the setup and the tuned settings (no artefact yet).
    colour : str
        Its line colour in the report's plots (a matplotlib colour).
    beats : tuple of str
        The laws (by name) whose RMS tip deflection the paper finds above this law's
        (Section 6): orderings the study, the sweep and PIL check.
    clips_active : bool
        The law clips the active LQG's force (Eq. 34), so the active LQG is judged against it.
    phased : bool
        Its step is also offered as an output phase and an update phase
        (``<prefix>_<name>_output_phase``/``_update_phase``: the command first, the rest after).
    fault_matrix : bool
        The law the SIL/PIL fault matrix runs on by default (its step reads the sensor frames as
        well as the joints': every fault of the matrix reaches it).
    constant : bool
        The law is itself a constant normal force (a fall-back, not a controller): the paper's
        claims against the passive settings and the best constant F_N are not made for it.
    node : bool
        The law the joint nodes run on their own joint in local mode (``design.network.joint_node``:
        the paper's first concept, Section 5.1); it reads only its own joint's measurements.
    memories : tuple of (str, str, str, str)
        What the A2L measures of its C state (``codegen.a2l``): (member, "joint" or "coordinate"
        — one value per joint or an array over the filter's coordinates —, unit, meaning).
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
    equation: int | None
    artifact: tuple[tuple[str, str], ...]
    settings: tuple[Setting, ...]
    controller: str
    colour: str
    codegen: str
    reference: str
    tune: str = ""
    beats: tuple[str, ...] = ()
    clips_active: bool = False
    phased: bool = False
    fault_matrix: bool = False
    constant: bool = False
    node: bool = False
    memories: tuple[tuple[str, str, str, str], ...] = ()

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

    def study_controller(self, setup: Any, lqg: Any, settings: dict) -> Any:
        """The controller the study runs with the tuned ``settings`` (the ``controller`` function)."""
        return _resolve(self.controller)(setup, lqg, settings)

    def modules(self) -> set[str]:
        """The modules of the law's own code: those its entry names (``module:function``)."""
        paths = (self.tune, self.controller, self.codegen, self.reference)
        return {path.split(":")[0] for path in paths if path}

    def codegen_context(self, artifact: Any, lit: Any, row: Any) -> dict:
        """What the law's templates see beyond the common context (the ``codegen`` function)."""
        return dict(_resolve(self.codegen)(artifact, lit, row))

    def lower_force_field(self) -> str:
        """The artefact field holding the lowest normal force the law commands per joint: its
        ``lower_force`` setting's field (the SISO law's preload), else the joints' ``normal_force_min``."""
        fields = dict(self.artifact)
        return next((fields[s.key] for s in self.settings if s.lower_force), "normal_force_min")

    def cited(self) -> str:
        """Its equation as the reports cite it: " (Eq. 30)", or "" without one."""
        return "" if self.equation is None else f" (Eq. {self.equation})"

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
            artifact=(("boundary_layer", "siso_boundary_layer"), ("normal_force_min", "siso_normal_force_min")),
            settings=(
                Setting("boundary_layer", "m/s", True, "the boundary layer ε_j of Eq. 30"),
                # A preload: the law's F_N^min of Eq. 30 raised above the joints' own (issue 33,
                # benchmarks/mast_siso_grid.py); by default the joints' F_N^min, the paper's law.
                Setting(
                    "normal_force_min",
                    "N",
                    True,
                    "the lowest normal force F_N,j^min the SISO law commands (Eq. 30)",
                    "normal_force_min",
                    normal_force=True,
                    lower_force=True,
                ),
            ),
            tune="smartjoint.design.control.siso_tuning:tuned",
            controller="smartjoint.design.control.siso_tuning:controller",
            colour="tab:blue",
            codegen="smartjoint.codegen.law_contexts:siso",
            reference="smartjoint.design.control.laws:siso_law",
            node=True,
            memories=(
                ("previous_friction", "joint", "N", "u_R at the previous sample (Eq. 31)"),
                ("previous_normal_force", "joint", "N", "F_N at the previous sample (Eq. 31)"),
            ),
        ),
        Law(
            name="clqg",
            display="cLQG",
            title="clipped-optimal LQG (Eq. 33-34)",
            mode=2,
            inputs=("sensors", "friction_force", "normal_force"),
            outputs=("normal_force", "desired_force"),
            equation=34,
            artifact=(
                ("boundary_layer", "clqg_boundary_layer"),
                *((field, field) for field in ("blocks", "gamma0", "gamma1", "joint_input", "output")),
                *((field, field) for field in ("feedback_gain", "estimator_gain", "modal_frequencies")),
            ),
            settings=(Setting("boundary_layer", "N", False, "the boundary layer ε of Eq. 34", 100.0),),
            controller="smartjoint.design.control.filter:controller",
            colour="tab:red",
            codegen="smartjoint.codegen.law_contexts:clqg",
            reference="smartjoint.design.control.filter:clipped_lqg",
            beats=("siso",),
            clips_active=True,
            phased=True,
            fault_matrix=True,
            memories=(
                ("q0", "coordinate", "", "filter state q, first component per coordinate (Eq. 33)"),
                ("q1", "coordinate", "", "filter state q, second component per coordinate (Eq. 33)"),
                ("feedback", "joint", "N", "-(K - K M C) q, the LQR force's predicted part (Eq. 33)"),
            ),
        ),
        Law(
            name="preset",
            display="preset",
            title="preset normal force (a fixed F_N per joint)",
            mode=4,
            inputs=("normal_force",),
            outputs=("normal_force",),
            equation=None,
            artifact=(("force", "preset_force"),),
            settings=(Setting("force", "N", True, "the preset normal force F_N,j", "normal_force_max", True),),
            controller="smartjoint.design.control.preset:controller",
            colour="tab:purple",
            codegen="smartjoint.design.control.preset:context",
            reference="smartjoint.design.control.preset:preset_law",
            constant=True,
        ),
        Law(
            name="slipratio",
            display="slip ratio",
            title="slip-ratio law (F_N integrates each joint's slip, issue 32)",
            mode=5,
            inputs=("sliding_velocity", "normal_force"),
            outputs=("normal_force",),
            equation=None,
            artifact=(
                ("velocity", "slipratio_velocity"),
                ("rise", "slipratio_rise"),
                ("decay", "slipratio_decay"),
            ),
            settings=(
                Setting("velocity", "m/s", True, "the sliding speed v*_j above which a joint counts as slipping"),
                Setting("rise", "1/s", False, "the relative rate r_rise at which F_N grows while a joint slips"),
                Setting(
                    "decay",
                    "1/s",
                    False,
                    "the relative rate r_decay at which F_N relaxes while a joint sticks",
                    per_sample_rate=True,
                ),
            ),
            tune="smartjoint.design.control.slip_ratio:tuned",
            controller="smartjoint.design.control.slip_ratio:controller",
            colour="tab:green",
            codegen="smartjoint.design.control.slip_ratio:context",
            reference="smartjoint.design.control.slip_ratio:slip_ratio_law",
            memories=(("command", "joint", "N", "the law's last F_N, its memory"),),
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


def fault_matrix_law() -> Law:
    """The law the fault matrix runs on by default (``Law.fault_matrix``)."""
    return next(entry for entry in LAWS.values() if entry.fault_matrix)


def node_law() -> Law:
    """The law the joint nodes run locally (``Law.node``)."""
    return next(entry for entry in LAWS.values() if entry.node)


def by_mode() -> dict[int, str]:
    """CONTROLLER_STATUS.mode's values and their names: INIT, every law's, SAFE."""
    modes = {MODE_INIT: "INIT", MODE_SAFE: "SAFE"}
    for entry in LAWS.values():
        if entry.mode in modes:
            raise ModelError(f"law {entry.name!r}: mode {entry.mode} is taken by {modes[entry.mode]}")
        modes[entry.mode] = entry.name.upper()
    return dict(sorted(modes.items()))


__all__ = [
    "DISPLAY",
    "LAWS",
    "MODE_INIT",
    "MODE_SAFE",
    "NAMES",
    "Law",
    "Setting",
    "by_mode",
    "node_law",
    "fault_matrix_law",
    "law",
]
