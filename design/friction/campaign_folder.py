"""The sequential campaign in a folder: the records a person (or the simulated rig) measured,
the next round's test plan, and the identification once the campaign is done.

Every run replays the campaign from the prior over the records in the folder
(``sequential_campaign.run_sequential``; its plans are a deterministic function of the prior
and the records): where a planned record ``round<k>_<test>.csv`` is missing, the round's plan
is written as ``round<k>_plan.md`` and the run stops — the person measures those records and
runs the command again. With ``simulate`` the rig fills in every missing record instead (and
writes it, exactly as a person would save it), so the loop runs to its end in one call.
Nothing but the plans and simulated records is written; an existing file is never replaced
except a plan this module wrote.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from smartjoint.common import output_path
from smartjoint.common.errors import SmartjointError
from smartjoint.design.friction import lugre, rig
from smartjoint.design.friction.records import Record, read_record, write_record
from smartjoint.design.friction.rig import breakaway
from smartjoint.design.friction.rig_campaign import STICK_SPAN
from smartjoint.design.friction.round_design import design_summary, record_name
from smartjoint.design.friction.sequential_campaign import (
    NotMeasured,
    Plan,
    SequentialResult,
    run_sequential,
)

PLAN_MARK = "# Rig test plan, round"  # the first line of every plan file this module writes


@dataclass(frozen=True)
class FolderCampaign:
    """One run over a campaign folder: the campaign so far, or the plan still to measure."""

    result: SequentialResult | None  # None while a round waits for records
    pending: Plan | None  # the round whose records are missing
    plan_file: Path | None  # where its plan was written
    missing: tuple[str, ...]  # the record files still to measure (the first one at least)
    simulated: tuple[Path, ...]  # records the simulated rig wrote in this run


def run_folder(
    folder: Path,
    joint_type: str,
    prior: lugre.LuGreParameters,
    simulate: rig.ParameterSet | None = None,
    noise: float = 0.0,
    seed: int = 0,
    cycles: float = 8.0,
    progress=None,
) -> FolderCampaign:
    """Replay the campaign over ``folder``'s records; plan the next round or finish.

    Parameters
    ----------
    folder : Path
        The campaign folder (created when missing).
    joint_type : str
        'A' or 'B'.
    prior : LuGreParameters
        The experimenter's belief before the first record.
    simulate : rig.ParameterSet, optional
        Fill in missing records with the simulated rig of these parameters.
    noise, seed, cycles
        Of the simulated records.
    progress : callable, optional
        One line per round.

    Returns
    -------
    FolderCampaign
    """
    # The output rule (common.output_path): a folder — the experimenter's own records live in it, so
    # its other files are kept, never replaced — not a file, link, FIFO, device or a path below a file.
    output_path.check_folder(folder, "campaign folder", ours=lambda entry: True)
    folder.mkdir(parents=True, exist_ok=True)
    simulated: list[Path] = []

    def measure(test: rig.RigTest, name: str) -> Record:
        path = folder / f"{name}.csv"
        if path.is_file():
            return read_record(path, prior.radius if joint_type == "B" else None)
        if path.exists():
            raise SmartjointError(f"{path}: exists and is not a record file")
        if simulate is None:
            raise NotMeasured(name)
        record = dataclasses.replace(rig.simulate(test, simulate.parameters, simulate.source), name=name)
        write_record(record, path)
        simulated.append(path)
        # What a replay reads: the plans that follow must come out the same from the files alone.
        return read_record(path, prior.radius if joint_type == "B" else None)

    try:
        result = run_sequential(joint_type, prior, measure, noise=noise, seed=seed, cycles=cycles, progress=progress)
    except NotMeasured as waiting:
        plan = waiting.plan
        assert plan is not None  # run_round names the round
        measured = {p.stem for p in folder.glob("round*.csv")}
        names = [f"round{plan.number}_{t.name}" for t in plan.tests]
        plan_file = folder / f"round{plan.number}_plan.md"
        _write_plan(plan_file, plan_text(plan, joint_type, measured))
        missing = tuple(f"{n}.csv" for n in names if n not in measured)
        return FolderCampaign(None, plan, plan_file, missing, tuple(simulated))
    return FolderCampaign(result, None, None, (), tuple(simulated))


def _write_plan(path: Path, text: str) -> None:
    """Write a plan, replacing only a plan file this module wrote."""
    if path.exists():
        if not path.is_file() or not path.read_text(encoding="utf-8", errors="replace").startswith(PLAN_MARK):
            raise SmartjointError(f"{path}: exists and is not a plan this command wrote — move it away")
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as stream:
            stream.write(text)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def plan_text(plan: Plan, joint_type: str, measured: set[str]) -> str:
    """A round's test plan as Markdown a person follows at the rig.

    Parameters
    ----------
    plan : Plan
        The round.
    joint_type : str
        'A' or 'B' (the units of amplitude and inertia).
    measured : set of str
        The record names already there (marked done).

    Returns
    -------
    str
    """
    force, inertia = ("N", "kg") if joint_type == "A" else ("N·m", "kg·m²")
    lines = [
        f"# Rig test plan, round {plan.number} (type {joint_type} joint)",
        "",
        f"Designed from {plan.basis}: {design_summary(plan.designed_from)}.",
        "",
        "Excitation A·sin(2πft) for the stated cycles at the stated sample rate; record time, sliding velocity, "
        "normal force (measured), excitation force, and the friction force if the rig gives it; the moving "
        "inertia in the record's `# inertia = …` line (docs/identification.md, Records). Save each record as "
        "the file named in its row, in this folder, then run the same command again.",
        "",
    ]
    if plan.ladder:
        lines += [
            "Run the rows **in order**. After each, note whether the element slid (gross motion, not only "
            f"presliding); skip every later row whose rung exceeds {STICK_SPAN:g}× the rung of the first row that "
            "slid (the command reads the records by the same rule and asks for no more).",
            "",
        ]
    lines += [
        f"| # | file | F_N [N] | amplitude [{force}] | f [Hz] | cycles | inertia [{inertia}] | sample rate [Hz] "
        "| for | status |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---|---|",
    ]

    def purpose(k: int) -> str:
        if not plan.ladder:
            return plan.purpose[k]
        rung = plan.tests[k].amplitude / breakaway(plan.designed_from, plan.tests[k].normal_force)
        return f"ladder rung {rung:.3g}× the break-away above"

    order = sorted(range(len(plan.tests)), key=lambda k: plan.tests[k].amplitude / breakaway(plan.designed_from,
                   plan.tests[k].normal_force)) if plan.ladder else range(len(plan.tests))  # fmt: skip
    for row, k in enumerate(order, 1):
        test = plan.tests[k]
        name = record_name(plan, test)
        lines.append(
            f"| {row} | `{name}.csv` | {test.normal_force:g} | {test.amplitude:.6g} | {test.frequency:g} | "
            f"{test.cycles:g} | {test.inertia:.4g} | {test.sample_rate:g} | {purpose(k)} | "
            f"{'measured' if name in measured else 'to measure'} |"
        )
    return "\n".join(lines) + "\n"


__all__ = ["PLAN_MARK", "FolderCampaign", "plan_text", "run_folder"]
