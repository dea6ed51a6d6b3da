"""The isolated-joint test rig of paper Section 3.2, as a model that produces records.

The friction element (inertia m: mass for type A, rotary inertia for type B) sits on a rigid
foundation and is driven harmonically by a shaker, F_exc = A·sin(2πf·t); the joint transmits
u_R = r·F_N·μ(v, φ) (Eq. 2, r = 1 for type A)::

    m·v̇ = F_exc − u_R,   ẋ = v,   φ̇ = f(v, φ)   (Eq. 1)

A below the break-away force r·F_N·(F_c + F_d) gives micro-slip (presliding hysteresis),
above it stick-slip — the two regimes the two identification steps need. The stiff bristle
dynamics are integrated by ``rig_integration`` (implicit trapezoidal rule, C kernel
``rig_kernel.c``); the rig "measures" sliding velocity and excitation force at ``sample_rate``
with optional Gaussian noise (relative to each signal's RMS), like the paper's shaker tests.

The test sets are designed in ``rig_campaign`` from a prior the experimenter believes and the
rig description; the parameters simulated enter only here, through ``simulate``. A record's
``regime`` is the one it shows (``record_screening.classify``: whether the element slides).

The rig simulates any parameter set of a friction model of the registry
(``common/friction_registry.py``; LuGre by default): ``parameter_set`` checks it against the
model's parameters and the plausible ranges of its law (``PLAUSIBLE``), from numbers, a TOML file
or the paper's Table 1 when the caller asks for nothing else; the record is integrated by the
model's ``rig`` entry. Every record it writes carries the joint type, the radius of a type B
joint and the name of the parameter set.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from smartjoint.common import friction_registry
from smartjoint.common.errors import SmartjointError
from smartjoint.design.friction import rig_imperfections as imperfect
from smartjoint.design.friction.model import FrictionParameters, law_of
from smartjoint.design.friction.record_quantities import MIN_RADIUS, bound
from smartjoint.design.friction.record_screening import MAX_FRICTION_COEFFICIENT, classify
from smartjoint.design.friction.records import Record, friction_from_excitation
from smartjoint.design.friction.rig_imperfections import IDEAL, RigImperfections
from smartjoint.design.friction.rig_integration import SUBSTEPS


class RigError(SmartjointError, ValueError):
    """A rig test or a LuGre parameter set for the rig is not valid."""


# F_c + F_d of a simulated joint: its records peak a little above it (campaigns with 10 % noise:
# 1.54 at 1.5), so up to 1.5 every record stays below what the screening accepts
# (record_screening.MAX_FRICTION_COEFFICIENT, 2), and a rig never writes records identify refuses.
MAX_BREAKAWAY_COEFFICIENT = 1.5
MAX_SAMPLES = 500_000  # per record: 25 s at 20 kHz, a CSV of about 35 MB (records.MAX_BYTES is 64 MiB)
TABLE_1_SOURCE = "paper Table 1"


@dataclass(frozen=True)
class ParameterSet:
    """A friction model's parameters for the rig and where they came from (``source``, shown in
    the output)."""

    joint_type: str
    parameters: FrictionParameters
    source: str

    def as_dict(self) -> dict:
        values = self.parameters.values()
        if self.parameters.radius is not None:
            values["radius"] = self.parameters.radius
        return {"source": self.source, "joint_type": self.joint_type, "values": values}

    def describe(self) -> str:
        values = ", ".join(f"{n} = {v:g}" for n, v in self.as_dict()["values"].items())
        display = friction_registry.friction_model(self.parameters.model).display
        return f"{display} parameters ({self.source}, type {self.joint_type}): {values}"


def parameter_set(
    joint_type: str, values: dict | None = None, source: str = "command line", model: str = friction_registry.DEFAULT
) -> ParameterSet:
    """Check a parameter set of ``model`` for the rig: all its parameters, plus ``radius`` [m] for type B.

    Parameters
    ----------
    joint_type : str
        'A' or 'B'.
    values : dict, optional
        The parameters by name; None gives the paper's Table 1 — only then.
    source : str
        The origin named in the errors (``joint.toml``, ``command line``).
    model : str
        The friction model of the registry.

    Returns
    -------
    ParameterSet
    """
    entry = friction_registry.friction_model(model, f"{source}: model")
    law = law_of(entry.name)
    if joint_type not in ("A", "B"):
        raise RigError(f"{source}: joint_type: {joint_type!r} — allowed: 'A', 'B'")
    if values is None:
        if joint_type not in law.TABLE_1:
            raise RigError(f"{source}: the paper gives no {entry.display} parameters — give them")
        return ParameterSet(joint_type, law.TABLE_1[joint_type], TABLE_1_SOURCE)
    allowed = entry.keys + (("radius",) if joint_type == "B" else ())
    for key in values:
        if key == "radius" and joint_type == "A":
            raise RigError(f"{source}: radius: a type A joint has no radius — allowed only for type B")
        if key not in allowed:
            raise RigError(f"{source}: {key}: unknown parameter — allowed: {', '.join(allowed)}")
    checked = {}
    for key in allowed:
        if key not in values:
            raise RigError(
                f"{source}: {key}: missing — give all of {', '.join(allowed)} (or none for {TABLE_1_SOURCE})"
            )
        value = values[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise RigError(f"{source}: {key}: {value!r} — must be a finite number")
        if key == "radius":
            lower, upper, inclusive, unit = MIN_RADIUS, bound("radius", "B"), True, "m"
        else:
            lower, upper, inclusive = law.PLAUSIBLE[key][0 if joint_type == "A" else 1]
            unit = entry.parameter(key).unit(joint_type)
        if not ((value >= lower if inclusive else value > lower) and value <= upper):
            relation = ">=" if inclusive else ">"
            raise RigError(
                f"{source}: {key}: {value!r} — allowed: {relation} {lower:g} and <= {upper:g}"
                f"{' ' + unit if unit else ''}"
            )
        checked[key] = float(value)
    return ParameterSet(joint_type, law.Parameters(**checked), source)


def load_parameter_set(path: str | Path, joint_type: str | None = None) -> ParameterSet:
    """A parameter set from a TOML file: the model's keys (``model``, default LuGre's six),
    ``radius`` for type B and an optional ``joint_type`` (must agree with ``joint_type`` when
    both are given).

    Parameters
    ----------
    path : str or Path
        The TOML file.
    joint_type : str, optional
        'A' or 'B'.

    Returns
    -------
    ParameterSet
    """
    path = Path(path)
    source = str(path)
    if path.exists() and not path.is_file():
        raise RigError(f"{source}: not a regular file — a parameter set is a TOML file")
    try:
        with path.open("rb") as handle:
            data = handle.read(1 << 20)
            if handle.read(1):
                raise RigError(f"{source}: larger than 1 MiB — a parameter set is a few lines of TOML")
    except OSError as error:
        raise RigError(f"{source}: cannot read parameter set ({error.strerror or error})") from None
    try:
        values = tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError as error:
        raise RigError(f"{source}: byte {error.start}: not UTF-8 — a parameter set is TOML text") from None
    except tomllib.TOMLDecodeError as error:
        raise RigError(f"{source}: not valid TOML ({error})") from None
    values.pop("identification", None)  # how an `identify -o` result was found: not a parameter
    declared = values.pop("joint_type", None)
    if declared is not None and declared not in ("A", "B"):
        raise RigError(f"{source}: joint_type: {declared!r} — allowed: 'A', 'B'")
    if declared is not None and joint_type is not None and declared != joint_type:
        raise RigError(f"{source}: joint_type: {declared!r}, but --type {joint_type} was given — make them agree")
    model = values.pop("model", friction_registry.DEFAULT)
    if model not in friction_registry.MODELS:
        raise RigError(f"{source}: model: {model!r} — allowed: {', '.join(friction_registry.MODELS)}")
    return parameter_set(declared or joint_type or "A", values, source, model)


@dataclass(frozen=True)
class RigTest:
    joint_type: str  # "A" | "B"
    normal_force: float  # F_N [N]
    amplitude: float  # excitation force [N] or moment [N·m]
    frequency: float  # [Hz]
    cycles: float = 4.0
    inertia: float = 0.5  # [kg] or [kg·m²]
    sample_rate: float = 20_000.0  # [Hz]: well above the bristle resonance sqrt(σ0·F_N·r²/m)
    noise: float = 0.0  # relative to the RMS of each measured signal
    seed: int = 0
    imperfections: RigImperfections = IDEAL  # harmonics, F_N drift, sensor resolution and floor

    @property
    def name(self) -> str:
        return f"rig_{self.joint_type}_FN{self.normal_force:g}_A{self.amplitude:g}_f{self.frequency:g}"


def breakaway(parameters: FrictionParameters, normal_force: float) -> float:
    """Static friction level r·F_N·F_s (LuGre: F_s = F_c + F_d): the excitation amplitude between the regimes.

    Parameters
    ----------
    parameters : FrictionParameters
        The joint.
    normal_force : float
        F_N [N].

    Returns
    -------
    float
        [N] (type B: [N·m]).
    """
    return parameters.moment_arm * normal_force * law_of(parameters.model).breakaway_coefficient(parameters)


def check_test(test: RigTest, parameters: FrictionParameters) -> None:
    """``RigError`` unless the test can be run and its record written (finite, positive, bounded).

    Parameters
    ----------
    test : RigTest
        The test.
    parameters : FrictionParameters
        The joint it runs on.
    """
    if test.joint_type not in ("A", "B"):
        raise RigError(f"joint_type: {test.joint_type!r} — allowed: 'A', 'B'")
    for name in ("normal_force", "amplitude", "frequency", "cycles", "inertia", "sample_rate"):
        value = getattr(test, name)
        if not (math.isfinite(value) and value > 0):
            raise RigError(f"{name}: {value!r} — must be a finite number > 0")
    if test.normal_force > bound("normal_force", test.joint_type):
        raise RigError(f"normal_force: {test.normal_force!r} — allowed: <= {bound('normal_force', 'A'):g} N")
    if test.amplitude > bound("excitation_force", test.joint_type):
        raise RigError(
            f"amplitude: {test.amplitude!r} — allowed: <= {bound('excitation_force', test.joint_type):g} "
            f"{'N' if test.joint_type == 'A' else 'N*m'}"
        )
    if test.inertia > bound("inertia", test.joint_type):
        raise RigError(
            f"inertia: {test.inertia!r} — allowed: <= {bound('inertia', test.joint_type):g} "
            f"{'kg' if test.joint_type == 'A' else 'kg*m^2'}"
        )
    if not (math.isfinite(test.noise) and 0.0 <= test.noise <= 1.0):
        raise RigError(f"noise: {test.noise!r} — allowed: 0 … 1 (relative to each signal's RMS)")
    samples = test.cycles / test.frequency * test.sample_rate
    if not samples <= MAX_SAMPLES:
        raise RigError(
            f"cycles: {test.cycles!r} at {test.frequency:g} Hz gives {samples:.3g} samples at "
            f"{test.sample_rate:g} Hz — allowed: at most {MAX_SAMPLES} samples per record"
        )
    if samples < 3:
        raise RigError(
            f"cycles: {test.cycles!r} at {test.frequency:g} Hz gives {samples:.3g} samples — need at least 3"
        )
    try:
        test.imperfections.check()
    except SmartjointError as error:
        raise RigError(str(error)) from None
    if test.joint_type == "B" and parameters.radius is None:
        raise RigError("radius: missing — a type B joint needs its radius in the parameter set")
    if test.joint_type == "A" and parameters.radius is not None:
        raise RigError(f"radius: {parameters.radius!r} — a type A joint has no radius")


def simulate(test: RigTest, parameters: FrictionParameters | None = None, source: str | None = None) -> Record:
    """Run the rig and return the (noisy) record; the friction column is F_exc − m·a.

    Parameters
    ----------
    test : RigTest
        The test.
    parameters : FrictionParameters, optional
        None: the paper's Table 1 (LuGre) for the test's joint type.
    source : str, optional
        The parameter set's name in the record's metadata (default: Table 1 or "given").

    Returns
    -------
    Record
    """
    if test.joint_type not in ("A", "B"):
        raise RigError(f"joint_type: {test.joint_type!r} — allowed: 'A', 'B'")
    p = parameters or law_of(friction_registry.DEFAULT).TABLE_1[test.joint_type]
    entry = friction_registry.friction_model(p.model)
    if source is None:
        source = TABLE_1_SOURCE if parameters is None else "given"
    static = law_of(p.model).breakaway_coefficient(p)
    if static > MAX_BREAKAWAY_COEFFICIENT:  # a prior may say so; a simulated joint may not
        raise RigError(
            f"{source}: break-away coefficient {static:g} — allowed: <= {MAX_BREAKAWAY_COEFFICIENT:g} for a simulated "
            f"joint (its records would peak near the friction coefficient {MAX_FRICTION_COEFFICIENT:g} that identify "
            "refuses)"
        )
    check_test(test, p)
    real = test.imperfections
    omega = 2.0 * np.pi * test.frequency
    duration = test.cycles / test.frequency
    time = np.arange(0.0, duration, 1.0 / test.sample_rate)
    fine = np.linspace(0.0, time[-1], (time.size - 1) * SUBSTEPS + 1)
    integrate = entry.rig_integration()
    gain = p.moment_arm * (
        test.normal_force if real.ideal else imperfect.normal_force(real, test.normal_force, fine, duration)
    )
    drive = imperfect.excitation(real, test.amplitude, omega, fine)
    velocity, deflection = integrate(p, gain, test.inertia, drive, time, SUBSTEPS)
    force = imperfect.excitation(real, test.amplitude, omega, time)
    preload = imperfect.normal_force(real, test.normal_force, time, duration)
    true_friction = p.moment_arm * preload * law_of(p.model).friction_coefficient(p, velocity, deflection)
    rng = np.random.default_rng(test.seed)
    if test.noise > 0:
        velocity = velocity + test.noise * np.sqrt(np.mean(velocity**2)) * rng.standard_normal(time.size)
        force = force + test.noise * np.sqrt(np.mean(force**2)) * rng.standard_normal(time.size)
    if not real.ideal:  # the sensors' floor and resolution; F_N as its load cell records it
        velocity, force, preload = (
            imperfect.measured(x, k, real, rng) for k, x in enumerate((velocity, force, preload))
        )
    friction = friction_from_excitation(time, velocity, force, test.inertia)
    record = Record(
        test.name,
        time,
        velocity,
        friction,
        preload,
        test.joint_type,
        test.inertia,
        force,
        {
            "noise": f"{test.noise:g}",
            "parameter_set": source,
            "true_friction_rms": f"{np.sqrt(np.mean(true_friction**2)):.6g}",
            **({} if real.ideal else {"imperfections": repr(real)}),
        },
        radius=p.radius if test.joint_type == "B" else None,
    )
    # The regime the record shows (as on a real rig), not the one the amplitude was meant for.
    record.metadata = {"regime": classify(record), **record.metadata}
    return record


__all__ = [
    "MAX_SAMPLES",
    "ParameterSet",
    "RigError",
    "RigTest",
    "TABLE_1_SOURCE",
    "breakaway",
    "check_test",
    "load_parameter_set",
    "parameter_set",
    "simulate",
]
