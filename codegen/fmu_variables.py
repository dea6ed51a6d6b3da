"""The variables of the FMUs (``codegen.fmu``): names, value references, causality and units.

A controller FMU's variables are named as the controller artefact and the bus database (DBC)
name them: the inputs are the signals the controller receives (``TIP_SENSORS.tip_y``,
``JOINT_A1.friction_force``, ``JOINT_A1.normal_force``, ``JOINT_A1.sliding_velocity``), the
outputs the command it sends (``SETPOINT_A1.normal_force``, as a force where the bus carries the
piezo voltage; the cLQG's ``SETPOINT_A1.desired_force``) and the step's status bits
(``CONTROLLER_STATUS.step_status``). The plant FMU reads what the controller sends and outputs
what it receives under the same names, so a master connects the two by name. Every variable
carries the C expression of its value in the model's struct, from which the templates render
the get/set functions, and the XML its ``<ScalarVariable>``/``<Float64>``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control.artifact_schema import NORMAL_FORCE_LIMIT
from smartjoint.design.structure.control_section import MAX_PULSE_AMPLITUDE, MAX_STUDY_DURATION

TIME = 0  # value reference of the independent variable (FMI 3 requires one; FMI 2 carries it too)
UNITS = ("N", "m", "m/s", "s", "J", "1")
_SENSOR_UNITS = {"displacement": "m", "velocity": "m/s"}
# A controller's measurement input is taken within this many times the artefact's plausibility
# limit on it: between the limit and the bound it is the law's to judge (a broken sensor: the
# safe state, status bits, a warning), beyond the bound it is no measurement but a master's error.
INPUT_RANGE_FACTOR = 1000.0
PULSE_FACTOR_LIMIT = 2.0  # |pulse.factor_<name>|: the study's directions reach sqrt(2) (runs.StudySetup.pulse)


@dataclass(frozen=True)
class Variable:
    """One FMU variable.

    ``kind`` is "real" (FMI 2 Real, FMI 3 Float64) or "integer" (Integer, Int32); ``value`` the C
    lvalue in the model (``m->...``); ``start`` None for outputs, which are calculated. A set is
    refused unless the C ``condition`` on ``value`` holds; ``allowed`` says what is allowed (its
    ``%g`` printed from the C expression ``allowed_value``); ``after`` runs once it is taken.
    """

    name: str
    reference: int
    causality: str  # "independent", "parameter", "input" or "output"
    variability: str  # "continuous", "discrete", "tunable" or "fixed"
    value: str
    unit: str | None
    description: str
    start: float | None = None
    kind: str = "real"
    condition: str = "isfinite(value)"
    allowed: str = "a finite number"
    allowed_value: str | None = None
    after: str = ""
    minimum: float | None = None
    maximum: float | None = None

    @property
    def settable(self) -> bool:
        return self.causality in ("parameter", "input")


def _c(value: float) -> str:
    """A double as a C literal that parses back to it (repr, with '.0' where it has no point)."""
    text = repr(float(value))
    return text if any(c in text for c in ".en") else text + ".0"


def _within(low: float | None, high: float, unit: str, why: str, strict_low: bool = False) -> dict[str, Any]:
    """The rules of a value within [low, high] (or |value| <= high without ``low``); NaN fails
    every comparison, so no ``isfinite`` is needed."""
    units = f" {unit}" if unit else ""
    if low is None:
        condition, allowed, low = f"fabs(value) <= {_c(high)}", f"|value| <= {high:g}{units} ({why})", -high
    else:
        relation = ">" if strict_low else ">="
        condition = f"value {relation} {_c(low)} && value <= {_c(high)}"
        allowed = f"{low:g} {'<' if strict_low else '<='} value <= {high:g}{units} ({why})"
    return dict(condition=condition, allowed="a finite number, " + allowed, minimum=float(low), maximum=float(high))


def _numbered(rows: list[dict]) -> list[Variable]:
    """Variables from keyword rows, value references from 1 in order (0 is time). A start value
    outside its own range is refused: the FMU's first state would be one it refuses to restore."""
    time = Variable("time", TIME, "independent", "continuous", "m->time", "s", "simulation time")
    variables = [time, *(Variable(reference=k, **row) for k, row in enumerate(rows, start=1))]
    for v in variables:
        if v.start is None or (v.minimum is None and v.maximum is None):
            continue
        if not (v.minimum is None or v.start >= v.minimum) or not (v.maximum is None or v.start <= v.maximum):
            raise ModelError(f"{v.name}: start {v.start!r} — outside its range [{v.minimum}, {v.maximum}]")
    return variables


def _input(name: str, value: str, unit: str | None, description: str, after: str, **rules) -> dict:
    return dict(
        name=name,
        causality="input",
        variability="continuous",
        value=value,
        unit=unit,
        description=description,
        start=0.0,
        after=after,
        **rules,
    )


def _output(name: str, value: str, unit: str | None, description: str, variability: str = "continuous") -> dict:
    return dict(name=name, causality="output", variability=variability, value=value, unit=unit, description=description)


def _parameter(
    name: str,
    value: str,
    unit: str | None,
    description: str,
    start: float,
    after: str,
    variability: str = "tunable",
    **rules,
) -> dict:
    return dict(
        name=name,
        causality="parameter",
        variability=variability,
        value=value,
        unit=unit,
        description=description,
        start=float(start),
        after=after,
        **rules,
    )


POSITIVE: dict[str, Any] = dict(condition="value > 0.0 && isfinite(value)", allowed="a finite number > 0", minimum=0.0)
_APPLIED = "F_N^max (1 + normal_force_margin) of the design"  # the plant's normal-force inputs: at most
_DIRECTIONS = "the study's directions reach sqrt(2)"  # a pulse factor's bound
# A disturbance force: no larger than the largest tip pulse a design may give.
_PULSE_FORCE = _within(None, MAX_PULSE_AMPLITUDE, "N", "control_section.MAX_PULSE_AMPLITUDE")


def sensor_unit(quantity: str) -> str:
    """The unit of a tip sensor from its quantity ("displacement" or "velocity")."""
    if quantity not in _SENSOR_UNITS:
        raise ModelError(f"sensor_quantities: {quantity!r} — allowed: {', '.join(_SENSOR_UNITS)}")
    return _SENSOR_UNITS[quantity]


def controller_variables(artifact, law: str, real: str = "double") -> list[Variable]:
    """The variables of a controller FMU of ``law`` (a law of ``common.law_registry``).

    Parameters
    ----------
    artifact : ControllerArtifact
        Names, units, start values and limits: the plausibility limits bound the measurement
        inputs (``INPUT_RANGE_FACTOR`` times them), ``measured_normal_force_max`` and
        ``artifact_schema.NORMAL_FORCE_LIMIT`` the tunable normal forces.
    law : str
    real : str
        The law's scalar type: a float build refuses inputs beyond the float range too (the
        conversion of such a double to float is undefined in C).

    Returns
    -------
    list of Variable
    """
    status = _output("CONTROLLER_STATUS.step_status", "m->shown_status", None, "status bits of the law's step (0: all "
                     "inputs used; smartjoint_types.h)", "discrete")  # fmt: skip
    return _numbered(
        [
            dict(status, kind="integer"),
            *_controller_inputs(artifact, law, real),
            *_controller_outputs(artifact, law),
            *_controller_parameters(artifact, law),
        ]
    )


_FLOAT_MAX = float(np.finfo(np.float32).max)  # FLT_MAX, exact in a double


def _measurement(limit: float, field: str, unit: str, real: str) -> dict[str, Any]:
    """A measurement input's rules: |value| within INPUT_RANGE_FACTOR times the artefact's
    plausibility limit ``field`` (and the float range in a float build)."""
    bound = INPUT_RANGE_FACTOR * float(limit)
    if real == "float" and bound > _FLOAT_MAX:
        return _within(None, _FLOAT_MAX, unit, "the float range")
    return _within(None, bound, unit, f"{INPUT_RANGE_FACTOR:g} x the artefact's {field}")


def _controller_inputs(artifact, law: str, real: str) -> list[dict]:
    """The measurements the law reads, as the input struct of its step holds them."""
    fresh = "m->computed = 0;"
    rows = []
    inputs = law_registry.law(law).inputs
    if "sensors" in inputs:
        for r, (name, quantity) in enumerate(zip(artifact.sensor_names, artifact.sensor_quantities)):
            unit = sensor_unit(quantity)
            rules = _measurement(artifact.sensor_limit[r], "sensor_limit", unit, real)
            rows.append(_input(f"TIP_SENSORS.{name}", f"m->input.sensors[{r}]", unit,
                               f"tip sensor y_{r + 1} ({quantity})", fresh, **rules))  # fmt: skip
    quantities = [(quantity, *_JOINT_INPUTS[quantity]) for quantity in inputs if quantity in _JOINT_INPUTS]
    for j, name in enumerate(artifact.joint_names):
        for quantity, unit, what, field in quantities:
            limit = max(abs(float(np.asarray(getattr(artifact, f))[j])) for f in field.split("|"))
            rows.append(_input(f"JOINT_{name}.{quantity}", f"m->input.{quantity}[{j}]", unit, f"{what} of joint {name}",
                               fresh, **_measurement(limit, field.split("|")[-1], unit, real)))  # fmt: skip
    return rows


# A joint's measurements a law may read (JOINT_<j> of the DBC): unit, description and the
# artefact's plausibility limits on it (the largest magnitude of those named bounds the input).
_JOINT_INPUTS = {
    "sliding_velocity": ("m/s", "sliding velocity v", "sliding_velocity_limit"),
    "friction_force": ("N", "measured friction force u_R", "friction_force_limit"),
    "normal_force": ("N", "measured applied normal force F_N", "measured_normal_force_min|measured_normal_force_max"),
}


def _controller_outputs(artifact, law: str) -> list[dict]:
    """The command of each joint (and the cLQG's LQR force u_d)."""
    entry = law_registry.law(law)
    rows = []
    for j, name in enumerate(artifact.joint_names):
        what = f"commanded normal force F_N of joint {name}{entry.cited()}"
        rows.append(_output(f"SETPOINT_{name}.normal_force", f"m->shown.normal_force[{j}]", "N", what, "discrete"))
        if "desired_force" in entry.outputs:
            rows.append(_output(f"SETPOINT_{name}.desired_force", f"m->shown.desired_force[{j}]", "N",
                                f"LQR force u_d = -(K x_hat) of joint {name} (Eq. 33)", "discrete"))  # fmt: skip
    return rows


def normal_force_limit(artifact, j: int) -> tuple[float, str]:
    """The largest F_N^max joint ``j`` may be tuned to, and where it comes from: the artefact's
    ``measured_normal_force_max`` (F_N^max (1 + normal_force_margin) of the design: a larger
    command would read back as implausible) within ``artifact_schema.NORMAL_FORCE_LIMIT``."""
    measured = float(artifact.measured_normal_force_max[j])
    if measured <= NORMAL_FORCE_LIMIT:
        return measured, "the artefact's measured_normal_force_max"
    return NORMAL_FORCE_LIMIT, "artifact_schema.NORMAL_FORCE_LIMIT"


def _setting_rules(artifact, setting, j: int | None) -> dict[str, Any]:
    """A setting's range: a normal force within (0, the F_N^max limit], a rate bounded by the
    sample time, else any finite number > 0."""
    if setting.normal_force:
        joints = range(len(artifact.joint_names)) if j is None else [j]
        limit, why = min(normal_force_limit(artifact, k) for k in joints)
        return _within(0.0, limit, setting.unit, why, strict_low=True)
    if setting.per_sample_rate:  # dt r < 1 (``law_registry.Setting``)
        dt = float(artifact.sample_time)
        allowed = f"0 < value < 1/dt = {1.0 / dt:g} {setting.unit} (F_N would turn negative in one sample)"
        return dict(condition=f"value > 0.0 && {_c(dt)} * value < 1.0", minimum=0.0, maximum=1.0 / dt, allowed=allowed)
    return POSITIVE


def _controller_parameters(artifact, law: str) -> list[dict]:
    """The tunable normal-force limits and the law's settings (``Law.settings``), refused unless
    0 < F^min < F^max <= the limit (:func:`normal_force_limit`) and each setting is in its range."""
    tuned = "tune(m);"
    entry = law_registry.law(law)
    fields = dict(entry.artifact)
    rows = []
    lowest = getattr(artifact, entry.lower_force_field())  # the law's own F_N^min (the SISO preload)
    for j, name in enumerate(artifact.joint_names):
        low, high = f"m->normal_force_min[{j}]", f"m->normal_force_max[{j}]"
        limit, why = normal_force_limit(artifact, j)
        rows.append(_parameter(f"JOINT_{name}.normal_force_min", low, "N", f"F_N^min of joint {name}",
                               lowest[j], tuned, minimum=0.0, maximum=limit,
                               condition=f"value > 0.0 && value < {high}",
                               allowed="0 < F_N^min < F_N^max = %g N (raise F_N^max first)",
                               allowed_value=high))  # fmt: skip
        rows.append(_parameter(f"JOINT_{name}.normal_force_max", high, "N", f"F_N^max of joint {name}",
                               artifact.normal_force_max[j], tuned, minimum=0.0, maximum=limit,
                               condition=f"value > {low} && value <= {_c(limit)}",
                               allowed=f"F_N^min = %g N < F_N^max <= {limit:g} N ({why})",
                               allowed_value=low))  # fmt: skip
        for setting in entry.settings:
            if setting.per_joint and not setting.lower_force:  # that one is F_N^min above
                rows.append(_parameter(f"JOINT_{name}.{setting.key}", f"m->{setting.key}[{j}]", setting.unit,
                                       f"{setting.key.replace('_', ' ')} of joint {name}",
                                       getattr(artifact, fields[setting.key])[j], tuned,
                                       **_setting_rules(artifact, setting, j)))  # fmt: skip
    for setting in entry.settings:
        if not setting.per_joint:
            rows.append(_parameter(setting.key, f"m->{setting.key}[0]", setting.unit,
                                   f"{setting.key.replace('_', ' ')} of the {entry.display} law",
                                   getattr(artifact, fields[setting.key]), tuned,
                                   **_setting_rules(artifact, setting, None)))  # fmt: skip
    return rows


def plant_variables(model, pulse_amplitude: float, pulse_duration: float, pulse_factors,
                    normal_force_limit) -> list[Variable]:  # fmt: skip
    """The variables of the plant FMU of a reduced model (``design.structure.modal.ModalModel``).

    Parameters
    ----------
    model : ModalModel
        Joint, sensor and disturbance names and units.
    pulse_amplitude, pulse_duration : float
        The study's tip pulse (Section 4.3): peak [N] and length [s], the parameters' start values.
    pulse_factors : sequence of float
        Its factor per disturbance input.
    normal_force_limit : sequence of float
        Per joint, the largest normal force the plant takes: the design's F_N^max (1 +
        normal_force_margin), the artefact's ``measured_normal_force_max``. A disturbance input
        is taken within ``control_section.MAX_PULSE_AMPLITUDE``.

    Returns
    -------
    list of Variable
    """
    disturbances = [_identifier(name, k) for k, name in enumerate(model.disturbance_names)]
    rows = []
    for j, name in enumerate(model.joint_names):
        rows.append(_input(f"SETPOINT_{name}.normal_force", f"m->normal_force_input[{j}]", "N",
                           f"normal force F_N applied to joint {name} from this communication point on",
                           "m->pending = 1;", **_within(0.0, float(normal_force_limit[j]), "N", _APPLIED)))  # fmt: skip
    for k, name in enumerate(model.disturbance_names):
        rows.append(_input(f"DISTURBANCE.{disturbances[k]}", f"m->disturbance_input[{k}]", "N",
                           f"force along disturbance input {name} (column {k + 1} of H), held over a "
                           "communication step and added to the pulse", "", **_PULSE_FORCE))  # fmt: skip
    for r, name in enumerate(model.sensor_names):
        unit = model.sensor_units[r] if r < len(model.sensor_units) and model.sensor_units[r] else None
        rows.append(_output(f"TIP_SENSORS.{name}", f"m->sensors[{r}]", unit, f"tip sensor y_{r + 1}"))
    joint_outputs = [("sliding_velocity", "v", "m/s", "sliding velocity v"),
                     ("friction_force", "u", "N", "friction force u_R (LuGre, Eq. 1)"),
                     ("normal_force", "fn", "N", "normal force F_N acting")]  # fmt: skip
    for j, name in enumerate(model.joint_names):
        for quantity, state, unit, what in joint_outputs:
            rows.append(_output(f"JOINT_{name}.{quantity}", f"m->{state}[{j}]", unit, f"{what} in joint {name}"))
    rows.append(_output("energy", "m->energy", "J", "e(t) = x^T x / 2, the vibration energy (Eq. 32's integrand)"))
    return _numbered(rows + _pulse_parameters(model, disturbances, pulse_amplitude, pulse_duration, pulse_factors))


def _pulse_parameters(model, disturbances, amplitude: float, duration: float, factors) -> list[dict]:
    """The tip pulse of Section 4.3 as fixed parameters: amplitude, duration, factor per input."""
    rows = [
        _parameter("pulse.amplitude", "m->pulse_amplitude", "N", "peak of the triangular tip pulse (Section 4.3), "
                   "at half its duration", amplitude, "", "fixed",
                   **_within(0.0, MAX_PULSE_AMPLITUDE, "N", "control_section.MAX_PULSE_AMPLITUDE")),
        _parameter("pulse.duration", "m->pulse_duration", "s", "length of the tip pulse; no pulse force after it",
                   duration, "", "fixed",
                   **_within(0.0, MAX_STUDY_DURATION, "s", "control_section.MAX_STUDY_DURATION", strict_low=True)),
    ]  # fmt: skip
    for k, name in enumerate(model.disturbance_names):
        rows.append(_parameter(f"pulse.factor_{disturbances[k]}", f"m->pulse_factor[{k}]", None,
                               f"the pulse's factor along disturbance input {name}", factors[k], "", "fixed",
                               **_within(None, PULSE_FACTOR_LIMIT, "", _DIRECTIONS)))  # fmt: skip
    return rows


def _identifier(name: str, k: int) -> str:
    """A disturbance input's name as one FMI name part: letters, digits and '_' (else w<k+1>)."""
    text = "".join(c if c.isalnum() or c == "_" else "_" for c in str(name))
    return text if text and (text[0].isalpha() or text[0] == "_") else f"w{k + 1}"


_FIELD = re.compile(r"(?P<type>(?:const )?(?:unsigned )?\w+) ?(?P<pointer>\*?) ?(?P<name>\w+) ?(?P<size>\[[^\]]+\])?")


def law_fields(header: str, prefix: str, name: str, struct: str) -> list[dict]:
    """The fields of the law's ``<name>_<struct>`` (its state or output) in its generated header,
    each with the check the value in a saved FMU state must pass.

    Parameters
    ----------
    header : str
        The law's ``<name>.h``.
    prefix, name : str
        The generated code's prefix and the law's C name ``<prefix>_<law>``.
    struct : str
        "state" or "output".

    Returns
    -------
    list of dict
        ``name``, ``array`` (a C array), ``kind``: "real" (finite), "flag" (an ``int``: 0 or 1),
        "status" (an ``unsigned int``: the step's status bits) or "pointer" (none: the model
        points it to its own parameters before every step).

    Raises
    ------
    ModelError
        The struct is not there, or a field of a type whose saved values the FMU cannot check.
    """
    end = header.find(f"}} {name}_{struct};")
    start = header.rfind("typedef struct {", 0, end)
    if end < 0 or start < 0:
        raise ModelError(f"fmu: {name}.h has no struct {name}_{struct}")
    body = re.sub(r"/\*.*?\*/", " ", header[start + len("typedef struct {") : end], flags=re.S)
    kinds = {f"{prefix}_real": "real", "int": "flag", "unsigned int": "status"}
    fields = []
    for statement in (" ".join(part.split()) for part in body.split(";")):
        if not statement:
            continue
        match = _FIELD.fullmatch(statement)
        kind = "pointer" if match and match["pointer"] else kinds.get(match["type"] if match else "")
        if match is None or kind is None:
            raise ModelError(f"fmu: {name}_{struct} field {statement!r} — the FMU cannot check it in a saved state")
        fields.append({"name": match["name"], "array": bool(match["size"]), "kind": kind})
    return fields


def references(variables: list[Variable], causality: str) -> list[int]:
    """The value references of one causality, in order."""
    return [v.reference for v in variables if v.causality == causality]


__all__ = [
    "INPUT_RANGE_FACTOR",
    "PULSE_FACTOR_LIMIT",
    "TIME",
    "UNITS",
    "Variable",
    "controller_variables",
    "law_fields",
    "normal_force_limit",
    "plant_variables",
    "references",
    "sensor_unit",
]
