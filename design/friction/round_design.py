"""The design of a refinement round from the current estimate: the records it says are missing.

- micro-slip at ``MICRO_LEVELS`` of the estimated break-away while σ0 is wide;
- stick-slip at ``STICK_LEVEL`` of it with moving inertias that make it slide at
  ``STICK_SPEEDS``·v_s (``WIDE_SPEEDS`` while v_s itself is not pinned) while F_c, F_d or v_s is
  wide — that is where the Stribeck curve shows.

The inertia follows from the momentum m·v_peak the estimate predicts for the excitation
(``rig_campaign.stick_slip_peak_velocity``), corrected by how much faster the records so far
slid than that estimate predicts for them (``momentum_ratio``); the v_s it is designed for is
the last one the records bound (``design_basis``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from smartjoint.design.friction import lugre
from smartjoint.design.friction.identifiability import UNBOUNDED
from smartjoint.design.friction.rig import RigTest, breakaway
from smartjoint.design.friction.rig_campaign import RigDescription, stick_slip_peak_velocity

MICRO_LEVELS = ((400.0, 0.15), (200.0, 0.3))  # (F_N [N], amplitude / estimated break-away)
STICK_LEVEL = 1.3  # stick-slip amplitude / estimated break-away
STICK_SPEEDS = (2.0, 6.0)  # peak sliding velocity / v_s of the stick-slip records
WIDE_SPEEDS = (1.0, 4.0, 16.0)  # … while v_s is not pinned
STICK_SETTINGS = ((400.0, 10.0), (200.0, 20.0), (400.0, 20.0))  # (F_N [N], frequency [Hz]) in turn
MAX_SPEED_CORRECTION = 30.0  # the measured/predicted momentum of the records corrects inertias by at most ×/÷ this


def record_name(plan, test: RigTest) -> str:
    """The file stem of a planned test's record: ``round<k>_<test name>`` (rounds never clash)."""
    return f"round{plan.number}_{test.name}"


def design_summary(design: lugre.LuGreParameters) -> str:
    """What a round was designed from, in a plan's words: F_c, F_d, v_s and σ0."""
    return (
        f"F_c {design.coulomb:.4g}, F_d {design.stribeck:.4g}, v_s {design.stribeck_velocity:.4g}, "
        f"σ0 {design.sigma0:.4g}"
    )


def _inertia(amplitude: float, level: float, coulomb_level: float, frequency: float, speed: float, rig) -> float:
    momentum = stick_slip_peak_velocity(amplitude, level, coulomb_level, 2.0 * math.pi * frequency)
    return min(max(momentum / speed, rig.inertia[0]), rig.inertia[1])


def for_design(estimate: lugre.LuGreParameters) -> lugre.LuGreParameters:
    # A collapsed F_d would size the inertias from nothing: at least 0.1·F_c.
    return dataclasses.replace(estimate, stribeck=max(estimate.stribeck, 0.1 * estimate.coulomb))


def momentum_ratio(design: lugre.LuGreParameters, rounds: list) -> float:
    """How much more momentum m·v_peak the stick-slip records so far gained than ``design``
    predicts for their tests (``rig_campaign.stick_slip_peak_velocity``): the geometric mean over
    the records, within ×/÷ ``MAX_SPEED_CORRECTION``; 1 without records.

    A wrong F_c or F_d misjudges how fast a record slides, and a record sliding at 50·v_s shows
    no Stribeck drop: the next round's inertias are scaled by this ratio so that its records
    slide at the speeds they were designed for.
    """
    logs = []
    fraction = design.coulomb / (design.coulomb + design.stribeck)
    for r in rounds:
        tests = {record_name(r.plan, test): test for test in r.plan.tests}
        for record in r.stick:
            test = tests.get(record.name)
            if test is None:
                continue
            level = breakaway(design, test.normal_force)
            predicted = stick_slip_peak_velocity(
                test.amplitude, level, fraction * level, 2.0 * math.pi * test.frequency
            )
            measured = test.inertia * float(np.max(np.abs(record.sliding_velocity)))
            if predicted > 0.0 and measured > 0.0:
                logs.append(math.log(measured / predicted))
    if not logs:
        return 1.0
    limit = math.log(MAX_SPEED_CORRECTION)
    return math.exp(min(max(sum(logs) / len(logs), -limit), limit))


def refinement_tests(
    joint_type: str,
    estimate: lugre.LuGreParameters,
    wide: list[str],
    rig: RigDescription,
    noise: float,
    seed: int,
    cycles: float,
    momentum: float = 1.0,
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
    momentum : float
        The records' measured over predicted momentum (``momentum_ratio``): the stick-slip
        inertias are scaled by it.

    Returns
    -------
    tuple
        (the tests, what each is for)
    """
    design = for_design(estimate)
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
            speed = factor * design.stribeck_velocity / momentum
            inertia = _inertia(amplitude, level, fraction * level, frequency, speed, rig)
            add(normal_force, amplitude, frequency, inertia,
                f"stick-slip at {STICK_LEVEL:g}× the estimated break-away, sliding at about {factor:g}·v_s "
                "(F_c, F_d, v_s)")  # fmt: skip
    return tests, purpose


def design_basis(prior: lugre.LuGreParameters, rounds: list) -> tuple[lugre.LuGreParameters, str]:
    """What the next refinement round is designed from, and that in words: the last estimate whose
    v_s its records bound — else the prior.

    A v_s the records do not bound (an unbounded interval, or beyond the fastest sliding any record
    showed: the Stribeck drop was never seen) comes with an estimate that has collapsed (F_c or
    F_d near zero): it would size the next inertias and amplitudes from nothing, and the next
    records would again slide far from the drop, or not at all.
    """
    last = rounds[-1]
    for r in reversed(rounds):
        if r.identification is not None and _stribeck_bounded(r, rounds):
            if r is last:
                return r.identification.parameters, f"the estimate of round {r.plan.number}"
            why = f"round {last.plan.number}'s records do not bound v_s"
            return r.identification.parameters, f"the estimate of round {r.plan.number} ({why})"
    return prior, f"the prior (round {last.plan.number}'s records do not bound v_s)"


def _stribeck_bounded(r, rounds: list) -> bool:
    upto = rounds[: rounds.index(r) + 1]
    fastest = max((float(np.max(np.abs(x.sliding_velocity))) for q in upto for x in q.stick), default=0.0)
    velocity = r.identification.parameters.stribeck_velocity
    return r.half_widths.get("stribeck_velocity", math.inf) <= UNBOUNDED and 0.0 < velocity <= fastest


__all__ = [
    "MAX_SPEED_CORRECTION",
    "MICRO_LEVELS",
    "STICK_LEVEL",
    "STICK_SETTINGS",
    "STICK_SPEEDS",
    "WIDE_SPEEDS",
    "design_basis",
    "design_summary",
    "for_design",
    "momentum_ratio",
    "record_name",
    "refinement_tests",
]
