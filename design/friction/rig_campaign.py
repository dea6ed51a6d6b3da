"""The test campaign on the isolated-joint rig (paper Section 3.2), designed as an experimenter would.

An experimenter does not know the LuGre parameters of the joint on the rig: the campaign is
designed from a stated **prior** (the parameters they believe: a design file's, a handbook
value) and the **rig description** (moving inertias it can carry, shaker force limit, sample
rate, normal forces, frequencies). The parameters that are then simulated enter only through
``rig.simulate(test, truth)``.

``campaign`` is robust to a prior that is off by a factor of about 2 in F_c + F_d, σ0 and v_s:

- a ladder of excitation amplitudes in units of the prior's break-away force
  B = r·F_N·(F_c + F_d): two at 0.12·B and 0.25·B (``MICRO_RUNGS``: at most half of any true
  break-away above 0.5·B — nearer to it, presliding bends towards sliding and step 1's σ0
  fit failed: −82 … −90 % from rungs at 0.4 and 0.8 of the true break-away) and six from
  0.6·B to 3.4·B (``STICK_RUNGS``, ratio about √2: for any true break-away in 0.5·B … 2·B at
  least one rung slides at 1.2–1.7× it);
- each rung's moving inertia sized so that the joint would slide at ``TARGET_VELOCITY``·v_s
  (prior's v_s) if that rung were ``DESIGN_RATIO`` times the true break-away: the peak sliding
  velocity of a harmonically driven stick-slip, m·v_peak = [A·(cos θ0 − cos θ1) − C·(θ1 − θ0)]/ω
  (θ0 = asin(B/A) where sliding starts, θ1 = π − asin(C/A) where the force falls below the
  Coulomb level C = r·F_N·F_c). Over the ×2 box the two lowest sliding rungs reach about
  2–20·v_s, the range where the Stribeck parameters show;
- ``run_campaign`` runs the rungs upwards as an experimenter would and sorts the records by the
  regime they show (``record_screening.classify``: whether the element slides), not by what
  the design expected. It stops above ``STICK_SPAN`` (1.5) times the lowest rung that slid:
  higher rungs slide at several times the break-away and far faster than v_s (type A from a
  prior ×2: 25–39·v_s, and F_d −55 %, v_s +144 % with them). Micro-slip records are those that
  stuck at most ``MICRO_SPAN`` (0.45) times that lowest sliding rung — below about 0.64 of the
  true break-away, which lies above the rung below (ladder ratio √2); stuck rungs nearer it are
  left out (one at 0.73 of it put σ0 off by +245 %, type B).

``standard_campaign`` is the set of earlier versions (micro-slip at 0.5·B, stick-slip at 1.1·B
and 1.3·B sliding at about 5·v_s): exact when the prior is the truth, and biased or without a
stick-slip record when it is not (docs/identification.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from smartjoint.design.friction import lugre
from smartjoint.design.friction.record_quantities import bound
from smartjoint.design.friction.record_screening import classify
from smartjoint.design.friction.records import Record
from smartjoint.design.friction.rig import RigError, RigTest, breakaway

# (F_N as a fraction of the rig's largest normal force, amplitude in units of the prior's
# break-away r·F_N·(F_c + F_d), frequency [Hz]): the rig's largest F_N and half of it (on the
# paper's rig 400 and 200 N; a design's own rig check uses its joints' F_N^max, ``stage._rig_check``).
MICRO_RUNGS = ((1.0, 0.12, 10.0), (0.5, 0.25, 10.0))
STICK_RUNGS = (
    (1.0, 0.6, 10.0),
    (1.0, 0.85, 20.0),
    (1.0, 1.2, 10.0),
    (0.5, 1.7, 20.0),
    (0.5, 2.4, 10.0),
    (0.5, 3.4, 20.0),
)
STICK_SPAN = 1.5  # stick-slip records up to 1.5× the lowest rung that slid (run_campaign)
MICRO_SPAN = 0.45  # micro-slip records up to 0.45× the lowest rung that slid (run_campaign)
DESIGN_RATIO = 1.3  # each stick-slip rung sized as if it were 1.3× the true break-away
TARGET_VELOCITY = 5.0  # … to slide at 5·v_s (the prior's v_s)


@dataclass(frozen=True)
class RigDescription:
    """What the rig can do, in the joint type's units (type B: rotary inertia, moment).

    ``inertia`` is the range of the moving inertia (the bare element is the lightest, added
    masses up to the heaviest): [kg] (type B [kg·m²]). ``excitation_limit`` is the largest
    excitation amplitude the shaker gives: [N] (type B [N·m]). ``normal_forces`` are the F_N
    the preload can be set to; a campaign uses the ones its rungs name.
    """

    inertia: tuple[float, float]
    excitation_limit: float
    sample_rate: float = 20_000.0  # [Hz]
    normal_forces: tuple[float, ...] = (200.0, 400.0)  # [N]


# Sensible rigs for the paper's joints: a 1 kg element with up to 300 kg added, a 2 kN shaker
# (type A); a 2e-3 kg·m² disk with up to 1 kg·m², 20 N·m (type B).
DEFAULT_RIGS = {
    "A": RigDescription(inertia=(1.0, 300.0), excitation_limit=2000.0),
    "B": RigDescription(inertia=(2e-3, 1.0), excitation_limit=20.0),
}


def stick_slip_peak_velocity(amplitude: float, level: float, coulomb_level: float, omega: float) -> float:
    """m·v_peak of a stick-slip under A·sin(ωt): sliding from A·sin θ0 = B until A·sin θ1 = C.

    Parameters
    ----------
    amplitude : float
        A, the excitation amplitude [N] (type B [N·m]).
    level : float
        B = r·F_N·(F_c + F_d), the break-away force.
    coulomb_level : float
        C = r·F_N·F_c, the friction while sliding fast.
    omega : float
        ω = 2πf [rad/s].

    Returns
    -------
    float
        m·v_peak [N·s] (type B [N·m·s]), the momentum gained from the start of sliding to the
        velocity peak; 0 when A ≤ B (no sliding).
    """
    if amplitude <= level:
        return 0.0
    start = math.asin(level / amplitude)
    peak = math.pi - math.asin(min(coulomb_level / amplitude, 1.0))
    return (amplitude * (math.cos(start) - math.cos(peak)) - coulomb_level * (peak - start)) / omega


def _check_prior(joint_type: str, prior: lugre.LuGreParameters) -> None:
    if joint_type not in ("A", "B"):
        raise RigError(f"joint_type: {joint_type!r} — allowed: 'A', 'B'")
    if not prior.stribeck > 0.0:
        raise RigError(
            f"stribeck: {prior.stribeck!r} — the campaign sizes the stick-slip inertia from F_d "
            "(sliding at about 5·v_s); must be > 0"
        )


def _check_rig(joint_type: str, description: RigDescription) -> None:
    lightest, heaviest = description.inertia
    unit = "kg" if joint_type == "A" else "kg*m^2"
    if not (math.isfinite(lightest) and math.isfinite(heaviest) and 0.0 < lightest <= heaviest):
        raise RigError(
            f"inertia: {description.inertia!r} — allowed: (lightest, heaviest) with 0 < lightest <= heaviest {unit}"
        )
    if heaviest > bound("inertia", joint_type):
        raise RigError(f"inertia: {heaviest!r} — allowed: <= {bound('inertia', joint_type):g} {unit}")
    for name in ("excitation_limit", "sample_rate"):
        value = getattr(description, name)
        if not (math.isfinite(value) and value > 0.0):
            raise RigError(f"{name}: {value!r} — must be a finite number > 0")


def campaign(
    joint_type: str,
    prior: lugre.LuGreParameters,
    rig_description: RigDescription | None = None,
    noise: float = 0.0,
    seed: int = 0,
    cycles: float = 4.0,
) -> list[RigTest]:
    """The micro-/stick-slip test set designed from a prior and the rig, robust to a prior off by ×2.

    Two micro-slip rungs (``MICRO_RUNGS``) on the lightest inertia and six stick-slip rungs
    (``STICK_RUNGS``) whose inertia makes them slide at about 5·v_s if they exceed the true
    break-away by 1.3× (module docstring); an inertia outside the rig's range is clipped to it.
    Which regime a record shows is measured, not designed (``record_screening.classify``).

    Parameters
    ----------
    joint_type : str
        'A' or 'B'.
    prior : LuGreParameters
        The parameters the experimenter believes (F_c, F_d, v_s; type B also r) — never the ones
        simulated, unless a caller says so.
    rig_description : RigDescription, optional
        Default ``DEFAULT_RIGS[joint_type]``.
    noise : float
        Measurement noise relative to RMS.
    seed : int
        Of the noise; test k gets seed + k + 1.
    cycles : float
        Excitation cycles per test.

    Returns
    -------
    list of RigTest
        Micro-slip rungs first, then the stick-slip rungs in increasing amplitude.

    Raises
    ------
    RigError
        For a prior with F_d = 0, an invalid rig description, a rung above the shaker's limit or
        a normal force the rig cannot set.
    """
    _check_prior(joint_type, prior)
    description = rig_description or DEFAULT_RIGS.get(joint_type)
    assert description is not None  # joint_type checked
    _check_rig(joint_type, description)
    lightest, heaviest = description.inertia
    fraction = prior.coulomb / (prior.coulomb + prior.stribeck)  # C/B of the prior
    tests = []
    for k, (share, rung, frequency) in enumerate(MICRO_RUNGS + STICK_RUNGS):
        normal_force = share * max(description.normal_forces)
        if normal_force not in description.normal_forces:
            raise RigError(
                f"normal_forces: {description.normal_forces!r} — the campaign needs F_N = {normal_force:g} N"
            )
        amplitude = rung * breakaway(prior, normal_force)
        if amplitude > description.excitation_limit:
            raise RigError(
                f"excitation_limit: {description.excitation_limit!r} — the campaign's rung {rung:g}× the prior's "
                f"break-away at F_N = {normal_force:g} N needs {amplitude:.4g}"
            )
        inertia = lightest
        if k >= len(MICRO_RUNGS):
            level = amplitude / DESIGN_RATIO  # the break-away for which this rung is sized
            momentum = stick_slip_peak_velocity(amplitude, level, fraction * level, 2.0 * math.pi * frequency)
            inertia = min(max(momentum / (TARGET_VELOCITY * prior.stribeck_velocity), lightest), heaviest)
        tests.append(
            RigTest(
                joint_type,
                normal_force,
                amplitude,
                frequency,
                cycles,
                inertia,
                sample_rate=description.sample_rate,
                noise=noise,
                seed=seed + k + 1,
            )
        )
    return tests


@dataclass
class CampaignRecords:
    """What ``run_campaign`` measured: the records for each identification step and the rest."""

    micro: list[Record] = field(default_factory=list)  # step 1 (σ0, σ1)
    stick: list[Record] = field(default_factory=list)  # step 2 (F_c, F_d, v_s, σ2)
    left_out: list[Record] = field(default_factory=list)  # stuck near the break-away
    not_run: list[RigTest] = field(default_factory=list)  # above STICK_SPAN × the lowest sliding rung


def run_campaign(
    tests: list[RigTest], prior: lugre.LuGreParameters, measure: Callable[[RigTest], Record]
) -> CampaignRecords:
    """Run a campaign's rungs upwards and sort the records by the regime they show.

    The rungs (amplitude over the prior's break-away r·F_N·(F_c + F_d)) run in increasing order
    until one exceeds ``STICK_SPAN`` times the lowest rung that slid. Stick-slip: every record
    that slid. Micro-slip: the records that stuck at no more than ``MICRO_SPAN`` times that
    lowest sliding rung (all of them when none slid: then ``identify`` says there is no
    stick-slip record).

    Parameters
    ----------
    tests : list of RigTest
        From `campaign` (or any tests on one joint).
    prior : LuGreParameters
        The prior the tests were designed from (gives each test's rung).
    measure : callable
        RigTest → Record: the rig (``lambda test: rig.simulate(test, truth)``, the only place
        the simulated parameters enter).

    Returns
    -------
    CampaignRecords
    """
    rungs = sorted(
        ((test.amplitude / breakaway(prior, test.normal_force), k) for k, test in enumerate(tests)),
    )
    measured: list[tuple[float, Record]] = []
    lowest_sliding = math.inf
    out = CampaignRecords()
    for rung, k in rungs:
        if rung > STICK_SPAN * lowest_sliding:
            out.not_run.append(tests[k])
            continue
        record = measure(tests[k])
        measured.append((rung, record))
        if classify(record) == "stick-slip":
            lowest_sliding = min(lowest_sliding, rung)
    for rung, record in measured:
        if classify(record) == "stick-slip":
            out.stick.append(record)
        elif rung <= MICRO_SPAN * lowest_sliding:
            out.micro.append(record)
        else:
            out.left_out.append(record)
    return out


def standard_campaign(
    joint_type: str,
    prior: lugre.LuGreParameters,
    noise: float = 0.0,
    seed: int = 0,
    cycles: float = 4.0,
) -> list[RigTest]:
    """The two-regime test set of earlier versions, at F_N = 200 and 400 N, designed from ``prior``.

    Micro-slip: half the prior's break-away amplitude at 10 Hz. Stick-slip: 1.1× and 1.3× the
    prior's break-away at 10 and 20 Hz, with the moving inertia chosen so that the joint slides
    at about 5·v_s — the velocities where the Stribeck parameters show (a heavier or a
    faster-sliding element hides F_d and v_s under the velocity noise). Exact when the prior is
    the truth; from a prior off by ×2 its stick-slip rungs may stick (true break-away higher) or
    slide far too fast (lower): use `campaign` then.

    Parameters
    ----------
    joint_type : str
        'A' or 'B'.
    prior : LuGreParameters
        The parameters the set is designed from (callers that pass the simulated ones say so).
    noise : float
        Measurement noise relative to RMS.
    seed : int
        Of the noise.
    cycles : float
        Excitation cycles per test.

    Returns
    -------
    list of RigTest
    """
    _check_prior(joint_type, prior)
    micro_inertia = DEFAULT_RIGS[joint_type].inertia[0]
    tests = []
    for normal_force in (200.0, 400.0):
        level = breakaway(prior, normal_force)
        seed += 1
        tests.append(
            RigTest(joint_type, normal_force, 0.5 * level, 10.0, cycles, micro_inertia, noise=noise, seed=seed)
        )
        for factor, frequency in ((1.1, 10.0), (1.3, 20.0)):
            inertia = (
                prior.moment_arm
                * normal_force
                * prior.stribeck
                / (2.0 * math.pi * frequency * TARGET_VELOCITY * prior.stribeck_velocity)
            )
            seed += 1
            tests.append(
                RigTest(joint_type, normal_force, factor * level, frequency, cycles, inertia, noise=noise, seed=seed)
            )
    return tests


__all__ = [
    "MICRO_SPAN",
    "STICK_SPAN",
    "CampaignRecords",
    "run_campaign",
    "DEFAULT_RIGS",
    "DESIGN_RATIO",
    "MICRO_RUNGS",
    "STICK_RUNGS",
    "TARGET_VELOCITY",
    "RigDescription",
    "campaign",
    "standard_campaign",
    "stick_slip_peak_velocity",
]
