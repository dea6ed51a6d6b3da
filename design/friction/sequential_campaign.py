"""The rig campaign as an experimenter runs it: rounds of records, each designed from what the
records so far have shown, until the parameters are pinned or the budget is spent.

Round 1 is the amplitude ladder of ``rig_campaign.campaign`` designed from the prior and run
upwards (``run_campaign``). After every round the records so far are identified (``identify``:
Eq. 3 and output error) and the next round is designed from the **estimate**, not the prior:

- when no rung slid (the prior's break-away far too low) or every rung slid (far too high), the
  ladder again from the prior with F_c and F_d scaled by ``LADDER_SHIFT`` up or down;
- otherwise the records the estimate says are missing (``round_design``): micro-slip while σ0
  is wide, stick-slip sliding at a few v_s while F_c, F_d or v_s is — with inertias corrected
  by how much faster than predicted the records so far slid, and v_s taken from the last round
  whose records bound it.

A round whose curvature intervals are all within ±``TARGET_HALF_WIDTH`` of their values is
judged by its parametric bootstrap (``bootstrap``: the intervals widened by the estimate's
bias); the campaign stops when the bootstrap agrees, or when ``MAX_ROUNDS`` rounds or
``MAX_RECORDS`` records are spent. What is then wider than the target is reported as not
identified (``Identification.accuracy``, ``identifiability``), never as a value.

The loop is the same with a real rig: ``plan_round`` designs the next round from the records
measured so far, and ``campaign_folder.plan_text`` writes it as a test plan a person follows
(``smartjoint campaign``); with the simulated rig ``run_sequential`` measures each plan.
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
from smartjoint.design.friction.rig import RigError, RigTest
from smartjoint.design.friction.rig_campaign import (
    DEFAULT_RIGS,
    CampaignRecords,
    RigDescription,
    campaign,
    run_campaign,
)
from smartjoint.design.friction.round_design import (
    design_basis,
    for_design,
    momentum_ratio,
    record_name,
    refinement_tests,
)

TARGETED = ("sigma0", "coulomb", "stribeck", "stribeck_velocity")  # σ0, F_c, F_d, v_s
TARGET_HALF_WIDTH = 0.03  # stop when every targeted 95 % interval is within ±3 % of its value
MAX_ROUNDS = 4  # the budget: rounds …
MAX_RECORDS = 20  # … and records measured
LADDER_SHIFT = 3.0  # the ladder's break-away scale when no rung slid (×3) or every rung slid (÷3)


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


def plan_round(
    joint_type: str,
    prior: lugre.LuGreParameters,
    rounds: list[Round],
    rig: RigDescription | None = None,
    noise: float = 0.0,
    seed: int = 0,
    cycles: float = 8.0,
    target: float = TARGET_HALF_WIDTH,
    max_records: int = MAX_RECORDS,
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
    target : float
        The relative 95 % half width every ``TARGETED`` parameter must reach.
    max_records : int
        The budget of records measured (at most ``MAX_RECORDS``).

    Returns
    -------
    Plan or None
    """
    rig = rig or DEFAULT_RIGS[joint_type]
    number = len(rounds) + 1
    if number > MAX_ROUNDS or _measured(rounds) >= max_records:
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
    wide = _wide(last.half_widths, target)
    if not wide:
        return None
    estimate, basis = design_basis(prior, rounds)
    momentum = momentum_ratio(for_design(estimate), rounds)
    tests, purpose = refinement_tests(joint_type, estimate, wide, rig, noise, round_seed + 1, cycles, momentum)
    room = max_records - _measured(rounds)
    if not tests or room <= 0:
        return None
    if abs(math.log(momentum)) > math.log(1.25):
        basis += f", inertias ×{momentum:.3g} (the records so far slid {momentum:.3g}× as fast as it predicts)"
    return Plan(number, tuple(tests[:room]), estimate, basis, False, tuple(purpose[:room]))


def _wide(widths: dict[str, float], target: float) -> list[str]:
    return [name for name, width in widths.items() if not width <= target]


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
    """Identify the records of every round so far (with this one's) and judge the widths.

    The output-error step also starts from what a refinement round was designed from
    (``round_design.design_basis``: never an estimate whose v_s its records did not bound — a
    collapsed estimate as a start keeps the fit in its collapse); a ladder round from the last
    estimate.
    """
    micro = [r for previous in rounds for r in previous.micro] + measured.micro
    stick = [r for previous in rounds for r in previous.stick] + measured.stick
    identification, failure, widths = None, None, {}
    try:
        previous = next((r.identification.parameters for r in reversed(rounds) if r.identification), None)
        previous = previous if plan.ladder else plan.designed_from
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
    target: float = TARGET_HALF_WIDTH,
    max_records: int = MAX_RECORDS,
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
        Of the parametric bootstrap (``bootstrap``; 0: curvature intervals) that judges a round
        whose curvature intervals are within target, and the final identification.
    target : float
        The relative 95 % half width of every ``TARGETED`` parameter: the campaign stops there,
        and what is wider at the end is reported as not identified (``Identification.accuracy``).
    max_records : int
        The budget of records (at most ``MAX_RECORDS``).

    Returns
    -------
    SequentialResult
    """
    rounds: list[Round] = []
    verdict = False  # whether the last round's intervals are the bootstrap's
    while len(rounds) < max_rounds:
        plan = plan_round(joint_type, prior, rounds, rig, noise, seed, cycles, target, max_records)
        if plan is None:
            break
        done = identify_round(plan, run_round(plan, measure), rounds)
        verdict = done.identification is not None and not _wide(done.half_widths, target)
        if verdict:
            # The curvature says done; the bootstrap, which widens the intervals by the estimate's
            # bias, has the last word — and the campaign goes on where it widens them beyond target.
            done = _bootstrapped(done, replicates, seed, progress)
        rounds.append(done)
        if progress:
            progress(_round_line(done))
    last = rounds[-1]
    if last.identification is None:
        return SequentialResult(tuple(rounds), False, f"not identified: {last.failure}")
    if not verdict:
        last = _bootstrapped(last, replicates, seed, progress)
    # What is wider than the target is reported as not identified (``identifiability``).
    accuracy = {name: target for name in TARGETED}
    final = last.identification
    assert final is not None  # a round's bootstrap keeps its identification
    last = rounds[-1] = dataclasses.replace(last, identification=dataclasses.replace(final, accuracy=accuracy))
    wide = _wide(last.half_widths, target)
    if not wide:
        return SequentialResult(tuple(rounds), True, f"every targeted interval within ±{100 * target:.3g} %")
    spent = f"{len(rounds)} rounds, {_measured(rounds)} records (budget {MAX_ROUNDS} rounds, {max_records} records)"
    widths = ", ".join(f"{_SYMBOLS[name]} ±{100 * last.half_widths[name]:.3g} %" for name in wide)
    return SequentialResult(
        tuple(rounds), False, f"stopped after {spent}; not identified to ±{100 * target:.3g} %: {widths}"
    )


_SYMBOLS = {"sigma0": "σ0", "coulomb": "F_c", "stribeck": "F_d", "stribeck_velocity": "v_s"}


def _bootstrapped(done: Round, replicates: int, seed: int, progress) -> Round:
    identification = with_bootstrap(done.identification, replicates, seed, progress)
    return dataclasses.replace(done, identification=identification, half_widths=half_widths(identification))


def _round_line(done: Round) -> str:
    widths = ", ".join(f"{_SYMBOLS[name]} ±{100 * w:.3g} %" for name, w in done.half_widths.items())
    bootstrap = " (bootstrap)" if done.identification is not None and done.identification.bootstrap else ""
    return (
        f"round {done.plan.number} (from {done.plan.basis}): {len(done.micro)} micro-slip, {len(done.stick)} "
        f"stick-slip records" + (f"; {done.failure}" if done.failure else f"; 95 % half widths{bootstrap} {widths}")
    )


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
    "plan_round",
    "run_round",
    "run_sequential",
]
