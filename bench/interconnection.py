"""The study's loop closed through the bench (``design.control.interconnection.ClosedLoop``):
the law's generated firmware on the CAN loop — its host build (software in the loop) or its image
on the emulated target (processor in the loop) — and the FMUs in the project's FMI master.

Each gives the record every interconnection gives: the :class:`~smartjoint.design.control.runs.Run`
at the controller samples and the samples in the safe state. Passive references have no law to
close the loop through; they run in the Python plant loop (the plant FMU reproduces it bit for
bit, ``fmu_check.constant_force_run``).
"""

from __future__ import annotations

from pathlib import Path

from smartjoint.bench import cosimulation, firmware, pil
from smartjoint.bench.local_loop import LocalLoop, LocalRecord
from smartjoint.bench.loop import SilLoop, SilRecord
from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control.runs import Run, StudySetup, run_passive, run_semi_active


class CanLoop:
    """The law's firmware (CAN layer + law + E2E) behind the CAN loop, the amplifier models on
    the bus, the study's plant around it.

    Parameters
    ----------
    artifact : ControllerArtifact
        The firmware's design.
    real : str
        The host build's scalar type ("float", the target's, or "double").
    target : bool
        Run the image on the emulated target (QEMU mps2-an386) instead of the host build.
    """

    def __init__(self, artifact, real: str = "float", target: bool = False):
        self.artifact, self.real, self.target = artifact, real, bool(target)
        self.record: SilRecord | None = None  # the last run's record (per sample: safe flag, status, commands)

    def run(self, s: StudySetup, law: str) -> tuple[Run, int]:
        entry = law_registry.law(law)
        if self.target:
            with pil.TargetFirmware(self.artifact, entry.name) as image:
                return self._through(s, entry, image)
        return self._through(s, entry, firmware.Firmware(self.artifact, entry.name, self.real))

    def _through(self, s: StudySetup, entry, image) -> tuple[Run, int]:
        loop = SilLoop(image, 0.0, channel=f"smartjoint-interconnection-{id(image)}")
        try:
            run = run_semi_active(s, entry.display, loop)
        finally:
            loop.close()
        self.record = loop.record
        return run, int(sum(bool(flag) for flag in loop.record.safe))

    def run_passive(self, s: StudySetup, name: str, normal_forces) -> Run:
        return run_passive(s, name, normal_forces)


class LocalNodesLoop:
    """Local mode (``bench.local_loop``): the node law on one generated joint node per joint,
    each driving its own amplifier model, a supervisor's heartbeat on the bus; the study's plant
    around them. Only the law the nodes run (``law_registry.node_law``) closes this loop.

    Parameters
    ----------
    artifact : ControllerArtifact
        The nodes' design.
    real : str
        The nodes' scalar type ("float", the target's, or "double").
    target_joints : sequence of int
        Joints whose node runs as its image on the emulated target (``LocalLoop``).
    """

    def __init__(self, artifact, real: str = "float", target_joints=()):
        self.artifact, self.real, self.target_joints = artifact, real, tuple(target_joints)
        self.record: LocalRecord | None = None

    def run(self, s: StudySetup, law: str) -> tuple[Run, int]:
        entry, node = law_registry.law(law), law_registry.node_law()
        if entry.name != node.name:
            raise ModelError(f"law: {entry.name!r} — the joint nodes run {node.name!r} only (local mode)")
        loop = LocalLoop(
            self.artifact, self.real, channel=f"smartjoint-local-{id(self)}", target_joints=self.target_joints
        )
        try:
            run = run_semi_active(s, entry.display, loop)
        finally:
            loop.close()
        self.record = loop.record
        safe = [any(f & 0b1101 for f in faults) for faults in loop.record.faults]  # input, recovering, safe
        return run, int(sum(safe))

    def run_passive(self, s: StudySetup, name: str, normal_forces) -> Run:
        return run_passive(s, name, normal_forces)


class FmuLoop:
    """The plant FMU and each law's controller FMU co-simulated (``cosimulation.cosimulate``).

    Parameters
    ----------
    plant : path-like
        The plant FMU of the study's set-up (``smartjoint fmu DESIGN --plant``).
    controllers : dict of str to path-like
        A controller FMU per law, by its registry name (``smartjoint fmu … --law NAME``).
    """

    def __init__(self, plant, controllers: dict):
        self.plant = Path(plant)
        self.controllers = {law_registry.law(name).name: Path(path) for name, path in controllers.items()}

    def run(self, s: StudySetup, law: str) -> tuple[Run, int]:
        entry = law_registry.law(law)
        if entry.name not in self.controllers:
            raise ModelError(
                f"law: {entry.name!r} — this FMU loop has controller FMUs of {', '.join(self.controllers)}"
            )
        return cosimulation.cosimulate(s, self.plant, self.controllers[entry.name], entry.display)

    def run_passive(self, s: StudySetup, name: str, normal_forces) -> Run:
        return run_passive(s, name, normal_forces)


__all__ = ["CanLoop", "FmuLoop"]
