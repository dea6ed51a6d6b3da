"""The friction-joint stages of ``smartjoint run`` and of sweeps: placing them on a design
without joints (``[placement]``, paper Section 6) and the friction stage (Section 3.2, Eq. 3).

Everything comes from the design file. The friction stage identifies the rig records the design
names (``[friction] records``) and hands the identified parameters to every later stage; without
records it simulates the rig for each of the design's joint types with the design's own
parameters and identifies them back — a check of the identification, the design's parameters
stay in use. A design without joints and without ``[placement]`` stops before the stages that
need joints; no stage substitutes another truss or the paper's Table 1.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from smartjoint.common.errors import MISSING, DesignError
from smartjoint.design.friction import rig
from smartjoint.design.friction.identifiability import not_identified
from smartjoint.design.friction.identify import Identification, identify
from smartjoint.design.friction.model import joint_parameters
from smartjoint.design.friction.parameter_file import file_hashes, provenance, result_text
from smartjoint.design.friction.record_screening import classify
from smartjoint.design.friction.records import Record, read_record
from smartjoint.design.friction.rig_campaign import DEFAULT_RIGS, campaign, run_campaign
from smartjoint.design.structure import placement
from smartjoint.design.structure.description import Design, Joint, JointFriction
from smartjoint.design.structure.fem import build_model
from smartjoint.design.structure.solved import SolvedModel, solved_model
from smartjoint.design.structure.spec import load_design

PLACED_DESIGN = "placed_design.toml"
RIG_NOISE = 0.01  # relative measurement noise of the simulated rig records
RIG_CYCLES = 8  # excitation cycles per record


@dataclass
class JointTypeFriction:
    """The friction stage's result for one joint type: the identification, the parameters the
    later stages use (``used``) and what the design file stated (``stated``; None when records
    were identified for a type the design gave no parameters for)."""

    joint_type: str
    identification: Identification
    used: JointFriction
    stated: JointFriction | None
    records: list[str]  # record files identified, or the names of the simulated records
    simulated: bool
    result_file: str | None  # the identification result in the report folder (records named only)

    def as_dict(self) -> dict:
        """JSON-ready: the source of the parameters used, the comparison and the result file."""
        return {
            "joint_type": self.joint_type,
            "simulated_records": self.simulated,
            "records": list(self.records),
            "used": {**self.used.values(), "radius": self.used.radius, "source": self.used.source},
            "stated": None if self.stated is None else {**self.stated.values(), "radius": self.stated.radius},
            "result_file": self.result_file,
            "identification": self.identification.as_dict(),
        }


def check_friction_given(design: Design) -> None:
    """Refuse, before any FE work, a design whose joints (or the type A joints its
    ``[placement]`` will put on it) have no friction: neither the joint's own nor its type's
    ``[friction.X]`` parameters, nor rig records of that type among ``[friction] records``.

    Raises
    ------
    DesignError
        The same one line as ``model.joint_parameters``, for the first joint without friction.
    """
    joints = list(design.joints)
    if not joints and design.placement is not None:  # placement puts type A joints (placement.design_text)
        joints = [Joint("A1 (placed)", "", "start", "A", None)]
    missing = [(k, j) for k, j in enumerate(joints) if design.joint_friction(j) is None]
    if not missing:
        return
    recorded = {read_record(path).joint_type for path in design.friction_records}
    for index, joint in missing:
        if joint.type not in recorded:
            where = f"joints[{index}].friction" if design.joints else "placement"
            raise DesignError(
                where,
                MISSING,
                f"joint {joint.name!r} (type {joint.type}) has no friction parameters and no rig records of its type — "
                f"give [friction.{joint.type}] (inline or file = …), the joint's own friction, or records",
                design.source,
            )


def place_joints(
    design: Design, staging: Path, progress, locked: SolvedModel | None = None
) -> tuple[Design, str | None]:
    """Type A joints by ``[placement]`` on a design without joints, written as a design file
    into the report (``placed_design.toml``, extending the design file).

    Parameters
    ----------
    design : Design
        The (updated) design; returned unchanged when it has joints or no ``[placement]``.
    staging : Path
        The report folder being written.
    progress : callable
    locked : SolvedModel, optional
        The design's FE model with its joints locked and its modes, solved by the structure
        stage (at least up to the highest placement mode); built and solved here when None.

    Returns
    -------
    tuple
        (the design with the placed joints, the placed design's file name or None).
    """
    if design.joints or design.placement is None:
        return design, None
    targets = [m - 1 for m in design.placement.modes]
    if locked is None:
        locked = solved_model(build_model(design, joints="locked"), max(targets) + 1)
    fe, modes = locked.fe, locked.first(max(targets) + 1)
    chosen = placement.choose(placement.connector_energy(fe, modes, targets), design.placement.count)
    source = Path(design.source).resolve()
    text = placement.design_text(str(source), f"{design.name}-placed", chosen, targets, writer="smartjoint run")
    (staging / PLACED_DESIGN).write_text(text, encoding="utf-8")
    placed = load_design(staging / PLACED_DESIGN)
    # Updating ran on the design without joints: the same parameters hold for the placed truss.
    updated = {key: design.parameter(key) for key in design.updating.parameters} if design.updating else {}
    placed = dataclasses.replace(placed.with_parameters(updated), source=PLACED_DESIGN)
    progress(
        f"      no [[joints]]: placed {len(chosen)} type A joints by [placement] for modes "
        f"{', '.join(map(str, design.placement.modes))}: "
        + ", ".join(f"{j.name} at {j.member} {j.end}" for j in placed.joints)
        + f" → {PLACED_DESIGN}"
    )
    return placed, PLACED_DESIGN


def friction_stage(design: Design, staging: Path, progress) -> tuple[Design, list[JointTypeFriction]]:
    """Each joint type's friction: the design's records identified, or its parameters checked
    on simulated rig records; the identification results written into the report.

    Parameters
    ----------
    design : Design
        The design with joints.
    staging : Path
        The report folder being written: the result files ``friction_A.toml``, … go there.
    progress : callable
        Receives the identification's progress lines.

    Returns
    -------
    design : Design
        The design with the identified parameters in place of the design file's.
    results : list of JointTypeFriction
        One per joint type, in A, B order.
    """
    types = sorted({j.type for j in design.joints})
    named: dict[str, list[tuple[str, Record]]] = {}
    for path in design.friction_records:
        record = read_record(path)
        named.setdefault(record.joint_type, []).append((path, record))
    unused = sorted(set(named) - set(types))
    if unused:
        progress(f"      records of joint type {', '.join(unused)}: the design has no such joint, not identified")
    results = {}
    for joint_type in types:
        if joint_type in named:
            results[joint_type] = _identify_records(design, joint_type, named[joint_type], staging, progress)
            design = design.with_friction(results[joint_type].used)
    joint_parameters(design)  # every other joint has parameters in the design file: one line if not
    for joint_type in types:
        if joint_type not in results:
            results[joint_type] = _rig_check(design, joint_type, progress)
    return design, [results[t] for t in types]


def _identify_records(design: Design, joint_type: str, named, staging: Path, progress) -> JointTypeFriction:
    """The design's own rig records of one joint type, identified; the result replaces the
    design file's parameters of that type."""
    paths = [path for path, _ in named]
    progress(f"      type {joint_type}: identifying {len(paths)} rig records named by the design")
    identification = _identify([record for _, record in named], progress)
    hashes = file_hashes(paths)
    name = f"friction_{joint_type}.toml"
    (staging / name).write_text(result_text(identification, hashes), encoding="utf-8")
    p = identification.parameters
    stated = design.friction.get(joint_type)
    values, taken = _fill_not_identified(joint_type, p.values(), not_identified(identification), stated)
    source = f"identified by this run from {len(paths)} rig records"
    if taken and stated is not None:
        source += f"; {', '.join(taken)} not identified by them: the design's value ({Path(stated.source).name})"
    used = JointFriction(
        joint_type,
        tuple(values.items()),
        radius=p.radius,
        source=source,
        sha256=provenance(identification, hashes, True),
        model=p.model,
    )
    if taken:
        progress(f"      type {joint_type}: {', '.join(taken)} not identified by the records — the design's value used")
    return JointTypeFriction(joint_type, identification, used, stated, [str(x) for x in paths], False, name)


def _fill_not_identified(
    joint_type: str, values: dict[str, float], missing: dict[str, str], stated: JointFriction | None
) -> tuple[dict[str, float], list[str]]:
    """The identified values with each parameter the records do not determine taken from the
    design's own parameters of the type; without them, a one-line refusal naming the parameter,
    why the records miss it and what fixes it (no estimate the records cannot back is used)."""
    values = dict(values)
    for parameter, reason in missing.items():
        if stated is None:
            raise DesignError(
                "friction.records",
                f"type {joint_type}",
                f"{parameter} not identified by the records ({reason}); state it in [friction.{joint_type}] "
                "or add the record that covers that regime",
            )
        values[parameter] = stated.values()[parameter]
    return values, list(missing)


def _rig_check(design: Design, joint_type: str, progress) -> JointTypeFriction:
    """No records: the rig simulated with the design's parameters of ``joint_type`` (1 % noise)
    and identified back; the design's parameters stay in use. The campaign is designed from the
    same parameters as its prior (a check of the identification, not an experiment)."""
    joint = next(j for j in design.joints if j.type == joint_type)
    stated = design.joint_friction(joint)
    assert stated is not None  # joint_parameters checked every joint
    truth = joint_parameters(dataclasses.replace(design, joints=(joint,)))[0]
    progress(
        f"      type {joint_type}: no records named — the rig simulated with the design's parameters "
        f"({os.path.basename(stated.source)}; prior = the simulated parameters), {RIG_NOISE:.0%} noise, "
        "then identified back"
    )
    # The rig set to the joints' own F_N^max and half of it (the paper's rig: 400 and 200 N).
    largest = min(_largest_normal_forces(design, joint_type))
    described = dataclasses.replace(DEFAULT_RIGS[joint_type], normal_forces=(0.5 * largest, largest))
    tests = campaign(joint_type, prior=truth, rig_description=described, noise=RIG_NOISE, cycles=RIG_CYCLES)
    measured = run_campaign(tests, truth, lambda test: rig.simulate(test, truth, source=stated.source))
    records = measured.micro + measured.stick
    identification = _identify(records, progress)
    return JointTypeFriction(joint_type, identification, stated, stated, [r.name for r in records], True, None)


def _largest_normal_forces(design: Design, joint_type: str) -> list[float]:
    """F_N^max of each controlled joint of ``joint_type`` (every joint of it when none is controlled)."""
    c = design.control
    controlled = list(c.joints) if c.joints is not None else [j.name for j in design.joints]
    high = np.broadcast_to(np.asarray(c.normal_force_max, dtype=float), (len(controlled),))
    types = {j.name: j.type for j in design.joints}
    found = [float(f) for name, f in zip(controlled, high) if types[name] == joint_type]
    return found or [float(np.max(high))]


def _identify(records: list[Record], progress) -> Identification:
    micro = [record for record in records if classify(record) == "micro-slip"]
    stick = [record for record in records if classify(record) == "stick-slip"]
    return identify(micro, stick, progress=lambda message: progress(f"      {message}"))


def friction_entries(design: Design, results: list[JointTypeFriction], staging: Path) -> dict[str, dict]:
    """Each joint's LuGre parameters and where they came from, JSON-ready; the parameter files
    the design names are copied into the report (``friction/``) so that it says what was used.

    Parameters
    ----------
    design : Design
        The design of the later stages (identified parameters in place).
    results : list of JointTypeFriction
        The friction stage's results (the identification result files).
    staging : Path
        The report folder being written.

    Returns
    -------
    dict
        Joint name → type, the six parameters, radius, ``source`` (what it is), ``file`` (in the
        report, or None for parameters inline in the design file) and ``sha256``.
    """
    identified = {id(r.used): r.result_file for r in results if not r.simulated}
    entries = {}
    for joint in design.joints:
        friction = design.joint_friction(joint)
        assert friction is not None  # the friction stage checked every joint
        source, file = friction.source, None
        if friction.sha256 and Path(friction.source).is_file():
            file = f"friction/{Path(friction.source).name}"
            (staging / "friction").mkdir(exist_ok=True)
            (staging / file).write_bytes(Path(friction.source).read_bytes())
            source = "parameter file (copied into the report)"
        elif id(friction) in identified:  # identified by this run: its result file is in the report
            file = identified[id(friction)]
        entries[joint.name] = {
            "type": joint.type,
            **friction.values(),
            "radius": friction.radius,
            "source": source,
            "file": file,
            "sha256": friction.sha256,
        }
    return entries


__all__ = ["PLACED_DESIGN", "JointTypeFriction", "friction_entries", "friction_stage", "place_joints"]
