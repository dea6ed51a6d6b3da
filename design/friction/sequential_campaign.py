"""The rig campaign as an experimenter runs it: rounds of records, each designed from what the
records so far have shown, until the parameters are pinned or the budget is spent.

Round 1 is the amplitude ladder of ``rig_campaign.campaign`` designed from the prior and run
upwards (``run_campaign``). After every round the records so far are identified (``identify``:
Eq. 3 and output error) and the next round is designed from the **estimate**, not the prior:

- when no rung slid (the prior's break-away far too low) or every rung slid (far too high), the
  ladder again from the prior with F_c and F_d scaled by ``LADDER_SHIFT`` up or down;
- otherwise the records the estimate says are missing (``refinement_tests``): micro-slip at
  ``MICRO_LEVELS`` of the estimated break-away while σ0 is wide, and stick-slip at
  ``STICK_LEVEL`` of it with moving inertias that make it slide at ``STICK_SPEEDS``·v_s (the
  estimate's v_s; a wider spread while v_s itself is not pinned) while F_c, F_d or v_s is wide —
  that is where the Stribeck curve shows.

It stops when every parameter of ``TARGETED`` has a 95 % interval within ±``TARGET_HALF_WIDTH``
of its value, or when ``MAX_ROUNDS`` rounds or ``MAX_RECORDS`` records are spent; the final
estimate's intervals are then widened by its parametric bootstrap (``bootstrap``), and what is
wider than ±50 % is reported as not identified (``identifiability``), never as a value.

The loop is the same with a real rig: ``plan_round`` designs the next round from the records
measured so far, and ``plan_text`` writes it as a test plan a person follows
(``smartjoint campaign``, ``campaign_folder``); with the simulated rig ``run_sequential``
measures each plan.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

from smartjoint.common.errors import SmartjointError
from smartjoint.design.friction import lugre
from smartjoint.design.friction.bootstrap import REPLICATES, with_bootstrap
from smartjoint.design.friction.identify import Identification, identify
from smartjoint.design.friction.record_screening import classify
from smartjoint.design.friction.records import Record
from smartjoint.design.friction.rig import RigError, RigTest, breakaway
from smartjoint.design.friction.rig_campaign import (
    DEFAULT_RIGS,
    STICK_SPAN,
    CampaignRecords,
    RigDescription,
    campaign,
    run_campaign,
    stick_slip_peak_velocity,
)

TARGETED = ("sigma0", "coulomb", "stribeck", "stribeck_velocity")  # σ0, F_c, F_d, v_s
TARGET_HALF_WIDTH = 0.05  # stop when every targeted 95 % interval is within ±5 % of its value
MAX_ROUNDS = 4  # the budget: rounds …
MAX_RECORDS = 20  # … and records measured
LADDER_SHIFT = 3.0  # the ladder's break-away scale when no rung slid (×3) or every rung slid (÷3)
MICRO_LEVELS = ((400.0, 0.15), (200.0, 0.3))  # (F_N [N], amplitude / estimated break-away)
STICK_LEVEL = 1.3  # stick-slip amplitude / estimated break-away
STICK_SPEEDS = (2.0, 6.0)  # peak sliding velocity / v_s of the stick-slip records
WIDE_SPEEDS = (1.0, 4.0, 16.0)  # … while v_s is not pinned
STICK_SETTINGS = ((400.0, 10.0), (200.0, 20.0), (400.0, 20.0))  # (F_N [N], frequency [Hz]) in turn


@dataclass(frozen=True)
class Plan:
    """One round's tests and what they were designed from.

    ``ladder`` rounds run upwards and stop above ``rig_campaign.STICK_SPAN`` times the lowest rung
    that slid (``run_campaign``); refinement rounds run every test.
    """

    number: int
    tests: tuple[RigTest, ...]
    designed_from: lugre.LuGreParameters
    basis: str  # in words: "the prior", "the estimate of round 2", …
    ladder: bool
    purpose: tuple[str, ...]  # per test: what it is for


@dataclass(frozen=True)
class Round:
    """A round as run: its plan, the records it gave, the identification of all records so far."""

    plan: Plan
    micro: tuple[Record, ...]
    stick: tuple[Record, ...]
    left_out: tuple[Record, ...]
    not_run: tuple[RigTest, ...]
    identification: Identification | None
    failure: str | None  # why the records so far could not be identified
    half_widths: dict[str, float]  # relative 95 % half width of each targeted parameter


@dataclass(frozen=True)
class SequentialResult:
    """The whole campaign: its rounds, the final identification and why it stopped."""

    rounds: tuple[Round, ...]
    converged: bool
    stop: str

    @property
    def identification(self) -> Identification | None:
        return self.rounds[-1].identification if self.rounds else None

    @property
    def records(self) -> int:
        """Records measured (every round's, the ones left out included)."""
        return sum(len(r.micro) + len(r.stick) + len(r.left_out) for r in self.rounds)

    def as_dict(self) -> dict:
        """JSON-ready: per round its basis, tests, records by regime, failure and widths."""
        return {
            "converged": self.converged,
            "stop": self.stop,
            "records": self.records,
            "rounds": [
                {
                    "round": r.plan.number,
                    "designed_from": r.plan.basis,
                    "tests": [dataclasses.asdict(t) | {"name": t.name} for t in r.plan.tests],
                    "micro_slip": [x.name for x in r.micro],
                    "stick_slip": [x.name for x in r.stick],
                    "left_out": [x.name for x in r.left_out],
                    "not_run": [t.name for t in r.not_run],
                    "failure": r.failure,
                    "half_widths": r.half_widths,
                }
                for r in self.rounds
            ],
        }


def half_widths(identification: Identification) -> dict[str, float]:
    """Relative 95 % half width max(upper/value − 1, 1 − lower/value) of each ``TARGETED`` parameter."""
    entries = identification.parameter_entries()
    out = {}
    for name in TARGETED:
        value = entries[name]["value"]
        lower, upper = entries[name]["ci95"]
        out[name] = max(upper / value - 1.0, 1.0 - lower / value) if value > 0.0 else math.inf
    return out


def _inertia(amplitude: float, level: float, coulomb_level: float, frequency: float, speed: float, rig) -> float:
    momentum = stick_slip_peak_velocity(amplitude, level, coulomb_level, 2.0 * math.pi * frequency)
    return min(max(momentum / speed, rig.inertia[0]), rig.inertia[1])


def refinement_tests(
    joint_type: str,
    estimate: lugre.LuGreParameters,
    wide: list[str],
    rig: RigDescription,
    noise: float,
    seed: int,
    cycles: float,
) -> tuple[list[RigTest], list[str]]:
    """The records an estimate says are missing: micro-slip while σ0 is wide, stick-slip around
    the Stribeck range while F_c, F_d or v_s is (module docstring).

    Parameters
    ----------
    joint_type : str
        'A' or 'B'.
    estimate : LuGreParameters
        The current estimate (its F_d raised to at least 0.1·F_c for the design: a collapsed
        F_d would size the inertia from nothing).
    wide : list of str
        The targeted parameters whose intervals are still wide.
    rig : RigDescription
    noise, seed, cycles
        As in ``rig_campaign.campaign``; test k gets seed + k.

    Returns
    -------
    tuple
        (the tests, what each is for)
    """
    design = dataclasses.replace(estimate, stribeck=max(estimate.stribeck, 0.1 * estimate.coulomb))
    fraction = design.coulomb / (design.coulomb + design.stribeck)
    tests: list[RigTest] = []
    purpose: list[str] = []

    def add(normal_force, amplitude, frequency, inertia, why):
        if normal_force not in rig.normal_forces or amplitude > rig.excitation_limit:
            return
        tests.append(
            RigTest(joint_type, normal_force, amplitude, frequency, cycles, inertia, rig.sample_rate, noise,
                    seed + len(tests))
        )  # fmt: skip
        purpose.append(why)

    if "sigma0" in wide:
        for normal_force, level in MICRO_LEVELS:
            add(normal_force, level * breakaway(design, normal_force), 10.0, rig.inertia[0],
                f"micro-slip at {level:g}× the estimated break-away (σ0)")  # fmt: skip
    if any(name in wide for name in ("coulomb", "stribeck", "stribeck_velocity")):
        speeds = STICK_SPEEDS if "stribeck_velocity" not in wide else WIDE_SPEEDS
        for k, factor in enumerate(speeds):
            normal_force, frequency = STICK_SETTINGS[k % len(STICK_SETTINGS)]
            level = breakaway(design, normal_force)
            amplitude = STICK_LEVEL * level
            inertia = _inertia(amplitude, level, fraction * level, frequency, factor * design.stribeck_velocity, rig)
            add(normal_force, amplitude, frequency, inertia,
                f"stick-slip at {STICK_LEVEL:g}× the estimated break-away, sliding at about {factor:g}·v_s "
                "(F_c, F_d, v_s)")  # fmt: skip
    return tests, purpose


def plan_round(
    joint_type: str,
    prior: lugre.LuGreParameters,
    rounds: list[Round],
    rig: RigDescription | None = None,
    noise: float = 0.0,
    seed: int = 0,
    cycles: float = 8.0,
) -> Plan | None:
    """The next round's plan from the rounds so far; None when the campaign is done (converged,
    out of budget, or nothing left that a record could fix).

    Parameters
    ----------
    joint_type : str
        'A' or 'B'.
    prior : LuGreParameters
        What the experimenter believed before the first record.
    rounds : list of Round
        The rounds run so far (empty: plan round 1).
    rig : RigDescription, optional
        Default ``rig_campaign.DEFAULT_RIGS[joint_type]``.
    noise, seed, cycles
        Of the simulated records (a real rig ignores them); round k's tests get seeds from
        seed + 100·(k − 1) + 1.

    Returns
    -------
    Plan or None
    """
    rig = rig or DEFAULT_RIGS[joint_type]
    number = len(rounds) + 1
    if number > MAX_ROUNDS or _measured(rounds) >= MAX_RECORDS:
        return None
    round_seed = seed + 100 * (number - 1)
    if not rounds:
        tests = campaign(joint_type, prior, rig, noise=noise, seed=round_seed, cycles=cycles)
        return Plan(number, tuple(tests), prior, "the prior", True, tuple("ladder rung" for _ in tests))
    last = rounds[-1]
    if last.identification is None:
        shift = _ladder_shift(rounds)
        if shift is None:
            return None
        scale = shift * (last.plan.designed_from.coulomb / prior.coulomb if last.plan.ladder else 1.0)
        shifted = dataclasses.replace(prior, coulomb=prior.coulomb * scale, stribeck=prior.stribeck * scale)
        try:
            tests = campaign(joint_type, shifted, rig, noise=noise, seed=round_seed, cycles=cycles)
        except RigError:
            return None  # the shifted ladder is beyond the rig (shaker limit)
        basis = f"the prior with F_c and F_d ×{scale:.3g} ({last.failure})"
        return Plan(number, tuple(tests), shifted, basis, True, tuple("ladder rung" for _ in tests))
    wide = [name for name, width in last.half_widths.items() if not width <= TARGET_HALF_WIDTH]
    if not wide:
        return None
    estimate = last.identification.parameters
    tests, purpose = refinement_tests(joint_type, estimate, wide, rig, noise, round_seed + 1, cycles)
    room = MAX_RECORDS - _measured(rounds)
    if not tests or room <= 0:
        return None
    return Plan(number, tuple(tests[:room]), estimate, f"the estimate of round {number - 1}", False,
                tuple(purpose[:room]))  # fmt: skip


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
        f"Designed from {plan.basis}: F_c {plan.designed_from.coulomb:.4g}, F_d {plan.designed_from.stribeck:.4g}, "
        f"v_s {plan.designed_from.stribeck_velocity:.4g}, σ0 {plan.designed_from.sigma0:.4g}.",
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


def _measured(rounds: list[Round]) -> int:
    return sum(len(r.micro) + len(r.stick) + len(r.left_out) for r in rounds)


def _ladder_shift(rounds: list[Round]) -> float | None:
    """×LADDER_SHIFT when nothing has slid yet, ÷LADDER_SHIFT when nothing has stuck; None else."""
    micro = sum(len(r.micro) for r in rounds)
    stick = sum(len(r.stick) for r in rounds)
    if not stick:
        return LADDER_SHIFT
    if not micro:
        return 1.0 / LADDER_SHIFT
    return None


class NotMeasured(SmartjointError):
    """A planned record is not there yet (a real rig: the person measures it next). A ``measure``
    raises it with the record's name; `run_round` adds the plan."""

    def __init__(self, name: str, plan: Plan | None = None):
        where = f"round {plan.number}: " if plan is not None else ""
        super().__init__(f"{where}record {name} not measured yet")
        self.plan = plan
        self.name = name


def record_name(plan: Plan, test: RigTest) -> str:
    """The file stem of a planned test's record: ``round<k>_<test name>`` (rounds never clash)."""
    return f"round{plan.number}_{test.name}"


def run_round(plan: Plan, measure: Callable[[RigTest, str], Record]) -> CampaignRecords:
    """Measure a plan: a ladder upwards with ``run_campaign``'s stop rule, a refinement in full.

    ``measure(test, name)`` is the rig: it returns the record of ``test`` named ``name``
    (`record_name`), or raises `NotMeasured` when it is not there yet.
    """

    def named(test: RigTest) -> Record:
        name = record_name(plan, test)
        try:
            record = measure(test, name)
        except NotMeasured as missing:
            raise NotMeasured(missing.name, plan) from None
        return dataclasses.replace(record, name=name)

    tests = list(plan.tests)
    if plan.ladder:
        return run_campaign(tests, plan.designed_from, named)
    out = CampaignRecords()
    for test, purpose in zip(tests, plan.purpose):
        record = named(test)
        regime = classify(record)
        wanted = "micro-slip" if purpose.startswith("micro-slip") else "stick-slip"
        if regime != wanted:
            out.left_out.append(record)  # it did not show the regime it was designed for
        elif regime == "stick-slip":
            out.stick.append(record)
        else:
            out.micro.append(record)
    return out


def identify_round(plan: Plan, measured: CampaignRecords, rounds: list[Round], progress=None) -> Round:
    """Identify the records of every round so far (with this one's) and judge the widths."""
    micro = [r for previous in rounds for r in previous.micro] + measured.micro
    stick = [r for previous in rounds for r in previous.stick] + measured.stick
    identification, failure, widths = None, None, {}
    try:
        previous = next((r.identification.parameters for r in reversed(rounds) if r.identification), None)
        identification = identify(micro, stick, progress=progress, previous=previous)
        widths = half_widths(identification)
    except SmartjointError as error:
        failure = str(error)
    return Round(plan, tuple(measured.micro), tuple(measured.stick), tuple(measured.left_out),
                 tuple(measured.not_run), identification, failure, widths)  # fmt: skip


def run_sequential(
    joint_type: str,
    prior: lugre.LuGreParameters,
    measure: Callable[[RigTest, str], Record],
    rig: RigDescription | None = None,
    noise: float = 0.0,
    seed: int = 0,
    cycles: float = 8.0,
    max_rounds: int = MAX_ROUNDS,
    progress=None,
    replicates: int = REPLICATES,
) -> SequentialResult:
    """Round after round: plan, measure, identify, until ``plan_round`` says done.

    Parameters
    ----------
    joint_type : str
        'A' or 'B'.
    prior : LuGreParameters
        The experimenter's belief before the first record (never the simulated truth).
    measure : callable
        (RigTest, record name) → Record: the rig (``lambda test, name: rig.simulate(test, truth)``),
        or the files a person measured (raising `NotMeasured` for the next one to measure).
    rig : RigDescription, optional
    noise, seed, cycles
        Of the simulated records.
    max_rounds : int
        At most ``MAX_ROUNDS``; 1 runs the ladder alone.
    progress : callable, optional
        Receives a line per round.
    replicates : int
        Of the final identification's parametric bootstrap (``bootstrap``; 0: curvature intervals).

    Returns
    -------
    SequentialResult
    """
    rounds: list[Round] = []
    while len(rounds) < max_rounds:
        plan = plan_round(joint_type, prior, rounds, rig, noise, seed, cycles)
        if plan is None:
            break
        done = identify_round(plan, run_round(plan, measure), rounds)
        rounds.append(done)
        if progress:
            widths = ", ".join(f"{name} ±{100 * w:.3g} %" for name, w in done.half_widths.items())
            progress(
                f"round {plan.number} (from {plan.basis}): {len(done.micro)} micro-slip, {len(done.stick)} "
                f"stick-slip records" + (f"; {done.failure}" if done.failure else f"; 95 % half widths {widths}")
            )
    last = rounds[-1]
    if last.identification is None:
        return SequentialResult(tuple(rounds), False, f"not identified: {last.failure}")
    # The verdict on the honest intervals: the final estimate's bootstrap widens them by its bias.
    identification = with_bootstrap(last.identification, replicates, seed, progress)
    last = rounds[-1] = dataclasses.replace(
        last, identification=identification, half_widths=half_widths(identification)
    )
    wide = [name for name, width in last.half_widths.items() if not width <= TARGET_HALF_WIDTH]
    if not wide:
        return SequentialResult(tuple(rounds), True, f"every targeted interval within ±{TARGET_HALF_WIDTH:.0%}")
    spent = f"{len(rounds)} rounds, {_measured(rounds)} records of at most {MAX_ROUNDS}, {MAX_RECORDS}"
    return SequentialResult(tuple(rounds), False, f"stopped after {spent}; still wide: {', '.join(wide)}")


__all__ = [
    "MAX_RECORDS",
    "MAX_ROUNDS",
    "TARGETED",
    "TARGET_HALF_WIDTH",
    "Plan",
    "Round",
    "SequentialResult",
    "half_widths",
    "NotMeasured",
    "identify_round",
    "plan_text",
    "record_name",
    "plan_round",
    "refinement_tests",
    "run_round",
    "run_sequential",
]
