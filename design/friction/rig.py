"""The isolated-joint test rig of paper Section 3.2, as a model that produces records.

The friction element (inertia m: mass for type A, rotary inertia for type B) sits on a rigid
foundation and is driven harmonically by a shaker, F_exc = A·sin(2πf·t); the joint transmits
u_R = r·F_N·μ(v, φ) (Eq. 2, r = 1 for type A)::

    m·v̇ = F_exc − u_R,   ẋ = v,   φ̇ = f(v, φ)   (Eq. 1)

A below the break-away force r·F_N·(F_c + F_d) gives micro-slip (presliding hysteresis),
above it stick-slip — the two regimes the two identification steps need. The stiff bristle
dynamics are integrated by the implicit trapezoidal rule (A-stable, second order, no
numerical damping of the lightly damped bristle resonance) with a Newton solve on the
analytic Jacobian at ``SUBSTEPS`` steps per sample (C kernel ``rig_kernel.c``, with the Python
loop kept as its reference); the rig "measures"
sliding velocity and excitation force at ``sample_rate`` with optional Gaussian noise
(relative to each signal's RMS), like the paper's shaker tests.

The rig simulates any LuGre parameter set (``parameter_set``: from numbers, a TOML file or
the paper's Table 1 when the caller asks for nothing else); every record it writes carries the
joint type, the radius of a type B joint and the name of the parameter set.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from smartjoint.common.errors import SmartjointError
from smartjoint.design.friction import lugre
from smartjoint.design.friction.records import MIN_RADIUS, Record, bound, friction_from_excitation


class RigError(SmartjointError, ValueError):
    """A rig test or a LuGre parameter set for the rig is not valid."""


MAX_SAMPLES = 500_000  # per record: 25 s at 20 kHz, a CSV of about 35 MB (records.MAX_BYTES is 64 MiB)
# Plausible LuGre parameters per unit normal force (Table 1 units; type A, type B): (lower, upper,
# lower allowed). Table 1 sits well inside; outside, the record bounds would be left or the
# rig's 20 kHz sampling could not follow the bristles.
PARAMETER_BOUNDS = {
    "sigma0": ((0.0, 1e10, False), (0.0, 1e10, False)),  # [1/m] / [1/rad]
    "sigma1": ((0.0, 1e4, True), (0.0, 1e4, True)),  # [s/m] / [s/rad]
    "sigma2": ((0.0, 1e4, True), (0.0, 1e4, True)),
    "coulomb": ((0.0, 10.0, False), (0.0, 10.0, False)),  # dimensionless
    "stribeck": ((0.0, 10.0, True), (0.0, 10.0, True)),
    "stribeck_velocity": ((0.0, bound("sliding_velocity", "A"), False), (0.0, bound("sliding_velocity", "B"), False)),
}
PARAMETER_UNITS = {"sigma0": ("1/m", "1/rad"), "sigma1": ("s/m", "s/rad"), "sigma2": ("s/m", "s/rad"),
                   "coulomb": ("", ""), "stribeck": ("", ""), "stribeck_velocity": ("m/s", "rad/s")}
LUGRE_NAMES = tuple(PARAMETER_BOUNDS)
TABLE_1_SOURCE = "paper Table 1"


@dataclass(frozen=True)
class ParameterSet:
    """LuGre parameters for the rig and where they came from (``source``, shown in the output)."""

    joint_type: str
    parameters: lugre.LuGreParameters
    source: str

    def as_dict(self) -> dict:
        values = {n: getattr(self.parameters, n) for n in LUGRE_NAMES}
        if self.parameters.radius is not None:
            values["radius"] = self.parameters.radius
        return {"source": self.source, "joint_type": self.joint_type, "values": values}

    def describe(self) -> str:
        values = ", ".join(f"{n} = {v:g}" for n, v in self.as_dict()["values"].items())
        return f"LuGre parameters ({self.source}, type {self.joint_type}): {values}"


def parameter_set(joint_type: str, values: dict | None = None, source: str = "command line") -> ParameterSet:
    """Check a LuGre parameter set for the rig: all six parameters, plus ``radius`` [m] for type B.

    Parameters
    ----------
    joint_type : str
        'A' or 'B'.
    values : dict, optional
        The parameters by name; None gives the paper's Table 1 — only then.
    source : str
        The origin named in the errors (``joint.toml``, ``command line``).

    Returns
    -------
    ParameterSet
    """
    if joint_type not in ("A", "B"):
        raise RigError(f"{source}: joint_type: {joint_type!r} — allowed: 'A', 'B'")
    if values is None:
        return ParameterSet(joint_type, lugre.TABLE_1[joint_type], TABLE_1_SOURCE)
    allowed = LUGRE_NAMES + (("radius",) if joint_type == "B" else ())
    for key in values:
        if key == "radius" and joint_type == "A":
            raise RigError(f"{source}: radius: a type A joint has no radius — allowed only for type B")
        if key not in allowed:
            raise RigError(f"{source}: {key}: unknown parameter — allowed: {', '.join(allowed)}")
    checked = {}
    for key in allowed:
        if key not in values:
            raise RigError(f"{source}: {key}: missing — give all of {', '.join(allowed)} (or none for "
                           f"{TABLE_1_SOURCE})")
        value = values[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise RigError(f"{source}: {key}: {value!r} — must be a finite number")
        if key == "radius":
            lower, upper, inclusive, unit = MIN_RADIUS, bound("radius", "B"), True, "m"
        else:
            lower, upper, inclusive = PARAMETER_BOUNDS[key][0 if joint_type == "A" else 1]
            unit = PARAMETER_UNITS[key][0 if joint_type == "A" else 1]
        if not ((value >= lower if inclusive else value > lower) and value <= upper):
            relation = ">=" if inclusive else ">"
            raise RigError(f"{source}: {key}: {value!r} — allowed: {relation} {lower:g} and <= {upper:g}"
                           f"{' ' + unit if unit else ''}")
        checked[key] = float(value)
    return ParameterSet(joint_type, lugre.LuGreParameters(**checked), source)


def load_parameter_set(path: str | Path, joint_type: str | None = None) -> ParameterSet:
    """A parameter set from a TOML file: the six LuGre keys, ``radius`` for type B and an
    optional ``joint_type`` (must agree with ``joint_type`` when both are given).

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
    declared = values.pop("joint_type", None)
    if declared is not None and declared not in ("A", "B"):
        raise RigError(f"{source}: joint_type: {declared!r} — allowed: 'A', 'B'")
    if declared is not None and joint_type is not None and declared != joint_type:
        raise RigError(f"{source}: joint_type: {declared!r}, but --type {joint_type} was given — make them agree")
    return parameter_set(declared or joint_type or "A", values, source)


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

    @property
    def name(self) -> str:
        return f"rig_{self.joint_type}_FN{self.normal_force:g}_A{self.amplitude:g}_f{self.frequency:g}"


def breakaway(parameters: lugre.LuGreParameters, normal_force: float) -> float:
    """Static friction level r·F_N·(F_c + F_d): the excitation amplitude between the regimes.

    Parameters
    ----------
    parameters : LuGreParameters
        The joint.
    normal_force : float
        F_N [N].

    Returns
    -------
    float
        [N] (type B: [N·m]).
    """
    return parameters.moment_arm * normal_force * (parameters.coulomb + parameters.stribeck)


def check_test(test: RigTest, parameters: lugre.LuGreParameters) -> None:
    """``RigError`` unless the test can be run and its record written (finite, positive, bounded).

    Parameters
    ----------
    test : RigTest
        The test.
    parameters : LuGreParameters
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
        raise RigError(f"amplitude: {test.amplitude!r} — allowed: <= {bound('excitation_force', test.joint_type):g} "
                       f"{'N' if test.joint_type == 'A' else 'N*m'}")
    if test.inertia > bound("inertia", test.joint_type):
        raise RigError(f"inertia: {test.inertia!r} — allowed: <= {bound('inertia', test.joint_type):g} "
                       f"{'kg' if test.joint_type == 'A' else 'kg*m^2'}")
    if not (math.isfinite(test.noise) and 0.0 <= test.noise <= 1.0):
        raise RigError(f"noise: {test.noise!r} — allowed: 0 … 1 (relative to each signal's RMS)")
    samples = test.cycles / test.frequency * test.sample_rate
    if not samples <= MAX_SAMPLES:
        raise RigError(f"cycles: {test.cycles!r} at {test.frequency:g} Hz gives {samples:.3g} samples at "
                       f"{test.sample_rate:g} Hz — allowed: at most {MAX_SAMPLES} samples per record")
    if samples < 3:
        raise RigError(f"cycles: {test.cycles!r} at {test.frequency:g} Hz gives {samples:.3g} samples — need at "
                       "least 3")
    if test.joint_type == "B" and parameters.radius is None:
        raise RigError("radius: missing — a type B joint needs its radius in the parameter set")
    if test.joint_type == "A" and parameters.radius is not None:
        raise RigError(f"radius: {parameters.radius!r} — a type A joint has no radius")


def simulate(test: RigTest, parameters: lugre.LuGreParameters | None = None, source: str | None = None) -> Record:
    """Run the rig and return the (noisy) record; the friction column is F_exc − m·a.

    Parameters
    ----------
    test : RigTest
        The test.
    parameters : LuGreParameters, optional
        None: the paper's Table 1 for the test's joint type.
    source : str, optional
        The parameter set's name in the record's metadata (default: Table 1 or "given").

    Returns
    -------
    Record
    """
    if test.joint_type not in ("A", "B"):
        raise RigError(f"joint_type: {test.joint_type!r} — allowed: 'A', 'B'")
    p = parameters or lugre.TABLE_1[test.joint_type]
    if source is None:
        source = TABLE_1_SOURCE if parameters is None else "given"
    check_test(test, p)
    gain = p.moment_arm * test.normal_force
    omega = 2.0 * np.pi * test.frequency
    duration = test.cycles / test.frequency
    time = np.arange(0.0, duration, 1.0 / test.sample_rate)
    fine = np.linspace(0.0, time[-1], (time.size - 1) * SUBSTEPS + 1)
    velocity, deflection = integrate(p, gain, test.inertia, test.amplitude * np.sin(omega * fine), time, SUBSTEPS)
    force = test.amplitude * np.sin(omega * time)
    true_friction = gain * lugre.friction_coefficient(p, velocity, deflection)
    rng = np.random.default_rng(test.seed)
    if test.noise > 0:
        velocity = velocity + test.noise * np.sqrt(np.mean(velocity**2)) * rng.standard_normal(time.size)
        force = force + test.noise * np.sqrt(np.mean(force**2)) * rng.standard_normal(time.size)
    friction = friction_from_excitation(time, velocity, force, test.inertia)
    return Record(test.name, time, velocity, friction, np.full(time.size, test.normal_force), test.joint_type,
                  test.inertia, force, {"regime": "micro-slip" if test.amplitude < breakaway(p, test.normal_force)
                                        else "stick-slip", "noise": f"{test.noise:g}",
                                        "parameter_set": source,
                                        "true_friction_rms": f"{np.sqrt(np.mean(true_friction**2)):.6g}"},
                  radius=p.radius if test.joint_type == "B" else None)


SUBSTEPS = 8
ITERATIONS = 20  # Newton iterations per substep (SJ_RIG_ITERATIONS in rig_kernel.c)
_C_FAILURE: list[str] = []  # why the C kernel is unavailable on this machine (reported once)
DECLARATIONS = """
typedef struct {
    double sigma0, sigma1, sigma2, coulomb, stribeck, stribeck_velocity, max_deflection;
    double inertia;
} sj_rig;
long sj_rig_integrate(const sj_rig *p, const double *time, long samples, int substeps, const double *force,
                      const double *gain, double velocity0, double deflection0, double *velocity,
                      double *deflection);
"""


def integrate(p, gain, inertia, force, time, substeps, velocity0: float = 0.0, deflection0: float = 0.0,
              backend: str = "auto"):
    """Implicit trapezoidal rule for (v, φ) of the rig (Eq. 1–2) under an excitation ``force``.

    Parameters
    ----------
    p : LuGreParameters
        The joint.
    gain : float or ndarray
        r·F_N, a number or one value per substep node.
    inertia : float
        The moving inertia [kg] (type B: [kg·m²]).
    force : ndarray
        The excitation at every substep node: (len(time) − 1)·substeps + 1 values.
    time : ndarray
        The sample times [s].
    substeps : int
        Substeps per sample.
    velocity0, deflection0 : float
        The start.
    backend : str
        'c' (rig_kernel.c), 'python' (the reference loop) or 'auto' (C, else Python with a warning).

    Returns
    -------
    tuple of ndarray
        Velocity and bristle deflection at the sample times (x is not needed).
    """
    time = np.ascontiguousarray(time, dtype=float)
    nodes = (time.size - 1) * substeps + 1
    force = np.ascontiguousarray(force, dtype=float)
    gain = np.asarray(gain, dtype=float)
    if force.shape != (nodes,):
        raise ValueError(f"force: {force.shape} values — need (len(time) − 1)·substeps + 1 = {nodes}")
    if gain.shape not in ((), (nodes,)):
        raise ValueError(f"gain: {gain.shape} values — need one number or {nodes}, one per substep node")
    gain = np.ascontiguousarray(np.broadcast_to(gain, (nodes,)))
    from smartjoint.common import native

    module = native.choose(backend, "rig integration", kernel, lambda: None, _C_FAILURE, stacklevel=2)
    if module is None:
        return _integrate_python(p, gain, inertia, force, time, substeps, velocity0, deflection0)
    return _integrate_c(module, p, gain, inertia, force, time, substeps, velocity0, deflection0)


def kernel():
    """The compiled rig kernel (cffi module; ``ModelError`` when it cannot be built).

    Returns
    -------
    module
        The cffi module of ``rig_kernel.c``.
    """
    from smartjoint.common import native, package_data

    return native.load("rig", DECLARATIONS, package_data.path("smartjoint.design.friction", "rig_kernel.c"))


def _integrate_c(module, p, gain, inertia, force, time, substeps, velocity0, deflection0):
    ffi, lib = module.ffi, module.lib
    rig = ffi.new("sj_rig *", dict(sigma0=p.sigma0, sigma1=p.sigma1, sigma2=p.sigma2, coulomb=p.coulomb,
                                   stribeck=p.stribeck, stribeck_velocity=p.stribeck_velocity,
                                   max_deflection=p.max_deflection, inertia=float(inertia)))
    velocity = np.empty(time.size)
    deflection = np.empty(time.size)

    def pointer(array):
        return ffi.cast("double *", ffi.from_buffer(array))

    lib.sj_rig_integrate(rig, pointer(time), time.size, int(substeps), pointer(force), pointer(gain),
                         float(velocity0), float(deflection0), pointer(velocity), pointer(deflection))
    return velocity, deflection


def _integrate_python(p, gain, inertia, force, time, substeps, velocity0, deflection0):
    """Reference loop: rig_kernel.c mirrors it statement for statement."""
    force = force.tolist()
    gain = gain.tolist()
    s0, s1, s2 = p.sigma0, p.sigma1, p.sigma2
    fc, fd, vs = p.coulomb, p.stribeck, p.stribeck_velocity

    def rates(excitation, scale, v, phi):
        ratio = v / vs
        level = fc + fd * math.exp(-(ratio * ratio))
        phidot = v - s0 * abs(v) / level * phi
        mu = s0 * phi + s1 * phidot + s2 * v
        return (excitation - scale * mu) / inertia, phidot, level

    velocity = np.zeros(time.size)
    deflection = np.zeros(time.size)
    v, phi = float(velocity0), float(deflection0)
    velocity[0], deflection[0] = v, phi
    node = 0
    for k in range(1, time.size):
        h = float(time[k] - time[k - 1]) / substeps
        for _ in range(substeps):
            a0, d0, _ = rates(force[node], gain[node], v, phi)
            node += 1
            v1, phi1 = v + h * a0, phi + h * d0  # explicit predictor, then Newton
            for _ in range(ITERATIONS):
                a1, d1, level = rates(force[node], gain[node], v1, phi1)
                r_v = v1 - v - 0.5 * h * (a0 + a1)
                r_p = phi1 - phi - 0.5 * h * (d0 + d1)
                # ∂φ̇/∂φ, ∂φ̇/∂v (sign(v) kink handled one-sidedly) and ∂a/∂·
                f_phi = -s0 * abs(v1) / level
                d_level = -2.0 * v1 / (vs * vs) * (level - fc)
                sign = 1.0 if v1 > 0 else (-1.0 if v1 < 0 else 0.0)
                f_v = 1.0 - s0 * phi1 * (sign * level - abs(v1) * d_level) / (level * level)
                a_v = -gain[node] * (s1 * f_v + s2) / inertia
                a_phi = -gain[node] * (s0 + s1 * f_phi) / inertia
                j11, j12 = 1.0 - 0.5 * h * a_v, -0.5 * h * a_phi
                j21, j22 = -0.5 * h * f_v, 1.0 - 0.5 * h * f_phi
                det = j11 * j22 - j12 * j21
                dv = (r_v * j22 - j12 * r_p) / det
                dp = (j11 * r_p - j21 * r_v) / det
                v1 -= dv
                phi1 -= dp
                if abs(dv) <= 1e-13 * (1.0 + abs(v1)) and abs(dp) <= 1e-12 * p.max_deflection:
                    break
            v, phi = v1, phi1
        velocity[k] = v
        deflection[k] = phi
    return velocity, deflection


def campaign(joint_type: str, parameters: lugre.LuGreParameters | None = None, noise: float = 0.0, seed: int = 0,
             cycles: float = 4.0) -> list[RigTest]:
    """The standard two-regime test set of Section 3.2 at two normal forces.

    Micro-slip: half the break-away amplitude at 10 Hz. Stick-slip: 1.1× and 1.3× the
    break-away amplitude at 10 and 20 Hz, with the moving inertia chosen so that the joint
    slides at about 5·v_s — the velocities where the Stribeck parameters show (a heavier or a
    faster-sliding element hides F_d and v_s under the velocity noise).

    Parameters
    ----------
    joint_type : str
        'A' or 'B'.
    parameters : LuGreParameters, optional
        Default: Table 1.
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
    p = parameters or lugre.TABLE_1[joint_type]
    if not p.stribeck > 0.0:
        raise RigError(f"stribeck: {p.stribeck!r} — the campaign sizes the stick-slip inertia from F_d "
                       "(sliding at about 5·v_s); must be > 0")
    micro_inertia = 1.0 if joint_type == "A" else 2e-3
    tests = []
    for normal_force in (200.0, 400.0):
        level = breakaway(p, normal_force)
        seed += 1
        tests.append(RigTest(joint_type, normal_force, 0.5 * level, 10.0, cycles, micro_inertia, noise=noise, seed=seed))
        for factor, frequency in ((1.1, 10.0), (1.3, 20.0)):
            inertia = p.moment_arm * normal_force * p.stribeck / (2.0 * np.pi * frequency * 5.0 * p.stribeck_velocity)
            seed += 1
            tests.append(RigTest(joint_type, normal_force, factor * level, frequency, cycles, inertia, noise=noise,
                                 seed=seed))
    return tests


__all__ = ["DECLARATIONS", "ITERATIONS", "LUGRE_NAMES", "MAX_SAMPLES", "PARAMETER_BOUNDS", "PARAMETER_UNITS",
           "ParameterSet", "RigError", "RigTest", "SUBSTEPS", "TABLE_1_SOURCE", "breakaway", "campaign",
           "check_test", "integrate", "kernel", "load_parameter_set", "parameter_set", "simulate"]
