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

from dataclasses import dataclass
from typing import Any

from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError

TIME = 0  # value reference of the independent variable (FMI 3 requires one; FMI 2 carries it too)
UNITS = ("N", "m", "m/s", "s", "J", "1")
_SENSOR_UNITS = {"displacement": "m", "velocity": "m/s"}


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

    @property
    def settable(self) -> bool:
        return self.causality in ("parameter", "input")


def _numbered(rows: list[dict]) -> list[Variable]:
    """Variables from keyword rows, value references from 1 in order (0 is time)."""
    time = Variable("time", TIME, "independent", "continuous", "m->time", "s", "simulation time")
    return [time, *(Variable(reference=k, **row) for k, row in enumerate(rows, start=1))]


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
NOT_NEGATIVE: dict[str, Any] = dict(
    condition="value >= 0.0 && isfinite(value)", allowed="a finite number >= 0", minimum=0.0
)


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
        Names, units, start values and limits.
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
            *_controller_inputs(artifact, law, FLOAT_INPUT if real == "float" else {}),
            *_controller_outputs(artifact, law),
            *_controller_parameters(artifact, law),
        ]
    )


FLOAT_INPUT: dict[str, Any] = dict(
    condition="isfinite(value) && fabs(value) <= (double)FLT_MAX", allowed="a finite number within the float range"
)


def _controller_inputs(artifact, law: str, rules: dict) -> list[dict]:
    """The measurements the law reads, as the input struct of its step holds them."""
    fresh = "m->computed = 0;"
    rows = []
    inputs = law_registry.law(law).inputs
    if "sensors" in inputs:
        for r, (name, quantity) in enumerate(zip(artifact.sensor_names, artifact.sensor_quantities)):
            rows.append(_input(f"TIP_SENSORS.{name}", f"m->input.sensors[{r}]", sensor_unit(quantity),
                               f"tip sensor y_{r + 1} ({quantity})", fresh, **rules))  # fmt: skip
    quantities = [(quantity, *_JOINT_INPUTS[quantity]) for quantity in inputs if quantity in _JOINT_INPUTS]
    for j, name in enumerate(artifact.joint_names):
        for quantity, unit, what in quantities:
            rows.append(_input(f"JOINT_{name}.{quantity}", f"m->input.{quantity}[{j}]", unit, f"{what} of joint {name}",
                               fresh, **rules))  # fmt: skip
    return rows


# A joint's measurements a law may read (JOINT_<j> of the DBC): unit and description.
_JOINT_INPUTS = {
    "sliding_velocity": ("m/s", "sliding velocity v"),
    "friction_force": ("N", "measured friction force u_R"),
    "normal_force": ("N", "measured applied normal force F_N"),
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


def _controller_parameters(artifact, law: str) -> list[dict]:
    """The tunable normal-force limits and the law's settings (``Law.settings``), refused unless
    0 <= F^min < F^max and each setting > 0."""
    tuned = "tune(m);"
    entry = law_registry.law(law)
    fields = dict(entry.artifact)
    rows = []
    lowest = getattr(artifact, entry.lower_force_field())  # the law's own F_N^min (the SISO preload)
    for j, name in enumerate(artifact.joint_names):
        low, high = f"m->normal_force_min[{j}]", f"m->normal_force_max[{j}]"
        rows.append(_parameter(f"JOINT_{name}.normal_force_min", low, "N", f"F_N^min of joint {name}",
                               lowest[j], tuned, minimum=0.0,
                               condition=f"value >= 0.0 && value < {high}",
                               allowed="0 <= F_N^min < F_N^max = %g N (raise F_N^max first)",
                               allowed_value=high))  # fmt: skip
        rows.append(_parameter(f"JOINT_{name}.normal_force_max", high, "N", f"F_N^max of joint {name}",
                               artifact.normal_force_max[j], tuned, minimum=0.0,
                               condition=f"value > {low} && isfinite(value)",
                               allowed="F_N^min = %g N < F_N^max, finite", allowed_value=low))  # fmt: skip
        for setting in entry.settings:
            if setting.per_joint and not setting.lower_force:  # that one is F_N^min above
                rows.append(_parameter(f"JOINT_{name}.{setting.key}", f"m->{setting.key}[{j}]", setting.unit,
                                       f"{setting.key.replace('_', ' ')} of joint {name}",
                                       getattr(artifact, fields[setting.key])[j], tuned, **POSITIVE))  # fmt: skip
    for setting in entry.settings:
        if not setting.per_joint:
            rows.append(_parameter(setting.key, f"m->{setting.key}[0]", setting.unit,
                                   f"{setting.key.replace('_', ' ')} of the {entry.display} law",
                                   getattr(artifact, fields[setting.key]), tuned, **POSITIVE))  # fmt: skip
    return rows


def plant_variables(model, pulse_amplitude: float, pulse_duration: float, pulse_factors) -> list[Variable]:
    """The variables of the plant FMU of a reduced model (``design.structure.modal.ModalModel``).

    Parameters
    ----------
    model : ModalModel
        Joint, sensor and disturbance names and units.
    pulse_amplitude, pulse_duration : float
        The study's tip pulse (Section 4.3): peak [N] and length [s], the parameters' start values.
    pulse_factors : sequence of float
        Its factor per disturbance input.

    Returns
    -------
    list of Variable
    """
    disturbances = [_identifier(name, k) for k, name in enumerate(model.disturbance_names)]
    rows = []
    for j, name in enumerate(model.joint_names):
        rows.append(_input(f"SETPOINT_{name}.normal_force", f"m->normal_force_input[{j}]", "N",
                           f"normal force F_N applied to joint {name} from this communication point on",
                           "m->pending = 1;", **NOT_NEGATIVE))  # fmt: skip
    for k, name in enumerate(model.disturbance_names):
        rows.append(_input(f"DISTURBANCE.{disturbances[k]}", f"m->disturbance_input[{k}]", "N",
                           f"force along disturbance input {name} (column {k + 1} of H), held over a "
                           "communication step and added to the pulse", ""))  # fmt: skip
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
                   "at half its duration", amplitude, "", "fixed", **NOT_NEGATIVE),
        _parameter("pulse.duration", "m->pulse_duration", "s", "length of the tip pulse; no pulse force after it",
                   duration, "", "fixed", **POSITIVE),
    ]  # fmt: skip
    for k, name in enumerate(model.disturbance_names):
        rows.append(_parameter(f"pulse.factor_{disturbances[k]}", f"m->pulse_factor[{k}]", None,
                               f"the pulse's factor along disturbance input {name}", factors[k], "",
                               "fixed"))  # fmt: skip
    return rows


def _identifier(name: str, k: int) -> str:
    """A disturbance input's name as one FMI name part: letters, digits and '_' (else w<k+1>)."""
    text = "".join(c if c.isalnum() or c == "_" else "_" for c in str(name))
    return text if text and (text[0].isalpha() or text[0] == "_") else f"w{k + 1}"


def references(variables: list[Variable], causality: str) -> list[int]:
    """The value references of one causality, in order."""
    return [v.reference for v in variables if v.causality == causality]


__all__ = ["TIME", "UNITS", "Variable", "controller_variables", "plant_variables", "references", "sensor_unit"]
