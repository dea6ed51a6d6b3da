"""The typed results of ``smartjoint run``'s stages, each handed on to the next.

structure → friction → reduction → control → firmware → bench: every stage takes what the
stages before it produced instead of rebuilding it from the design, so one run builds each FE
model once and solves its modes once (the reduction study's full-model reference, every mode of
the released truss, is the one other eigen solution). The results are frozen: a later stage
cannot reassign what an earlier one found (the figures' dicts inside are not copied: no stage
writes into another's), and the report (``pipeline``, ``report_*``) renders
them.
"""

from __future__ import annotations

from dataclasses import dataclass

from smartjoint.design.control.artifact import ControllerArtifact
from smartjoint.design.control.study import Study
from smartjoint.design.friction.stage import JointTypeFriction
from smartjoint.design.network.plan import NetworkPlan
from smartjoint.design.structure.description import Design
from smartjoint.design.structure.solved import SolvedModel
from smartjoint.design.structure.updating import UpdatingResult


@dataclass(frozen=True)
class StructureStage:
    """Stages 1–3 and the joints: the design, its FE models and their modes.

    Attributes
    ----------
    source_design : Design
        The design file's design, updated to its EMA where it has ``[updating]``.
    design : Design
        The same with the joints ``[placement]`` placed (itself when it has joints).
    locked : SolvedModel
        The conventional truss (joints locked) and its modes: the spectrum, placement.
    updating : UpdatingResult or None
        Model updating, None without ``[updating]``.
    released : SolvedModel or None
        The truss with the joints released (Eq. 6) and its modes: the spectrum and the
        controllers' design model (the reduction study takes its FE model); None without joints.
    placed_design : str or None
        The design file ``[placement]`` wrote into the report.
    """

    source_design: Design
    design: Design
    locked: SolvedModel
    updating: UpdatingResult | None
    released: SolvedModel | None
    placed_design: str | None


@dataclass(frozen=True)
class FrictionStage:
    """Stage 4: the design with the friction every later stage uses, per joint type."""

    design: Design
    types: tuple[JointTypeFriction, ...]


@dataclass(frozen=True)
class ControlStage:
    """Stage 6: the controlled design, its closed-loop study and its controller artefact."""

    design: Design
    study: Study
    artifact: ControllerArtifact


@dataclass(frozen=True)
class FirmwareStage:
    """Stage 7: the generated C (float build) and its back-to-back check."""

    files: dict[str, str]
    check: dict


@dataclass(frozen=True)
class BenchStage:
    """Stage 8: the study through the CAN loop, its bus logs, the demo faults, the safe-state fault
    matrix and the network plan (each bus's frames and load)."""

    sil: dict
    logs: tuple[str, ...]
    faults: dict
    safety: dict
    network: NetworkPlan  # the design's [network]: frames over its buses, each load proven


@dataclass(frozen=True)
class PilStage:
    """Stage 9: the study's laws on the target (``bench.pil_study``), or why it did not run.

    Attributes
    ----------
    skipped : str or None
        The missing tools; None when it ran.
    result : dict
        ``pil_study``'s figures (empty when skipped): the report's section is rendered from it.
    summary : dict
        The stage's entry of ``summary.json``.
    """

    skipped: str | None
    result: dict
    summary: dict


@dataclass(frozen=True)
class EnsembleStage:
    """Stage 10: the robustness ensemble around the design; ``summary`` its figures (the
    orderings' probabilities, the drivers, the best passive forces, its files)."""

    summary: dict


@dataclass(frozen=True)
class FmuStage:
    """Stage 11: the FMUs, replayed and co-simulated against the study; ``summary`` its figures
    per FMI version and law."""

    summary: dict


__all__ = [
    "BenchStage",
    "ControlStage",
    "EnsembleStage",
    "FirmwareStage",
    "FmuStage",
    "FrictionStage",
    "PilStage",
    "StructureStage",
]
