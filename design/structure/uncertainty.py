"""The design file's ``[uncertainty]`` table: the physical spread of the structure that the
robustness ensemble of ``smartjoint run`` and ``smartjoint sweep`` draw from (docs/design-file.md).

Its entries are those of a sweep file's ``[uncertain]`` (``docs/sweep.md``): the scalar inputs of
one sample (``SCALAR_INPUTS``) and factors on each friction parameter, for every joint
(``[uncertainty.friction.<parameter>]``) or for one joint (``[uncertainty.friction.<joint>.<parameter>]``,
which replaces the first for that joint). What the table leaves out takes the defaults of
``design.control.physical_spread``; ``defaults = false`` takes none.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from smartjoint.common import friction_registry
from smartjoint.common.errors import MISSING

DISTRIBUTIONS = ("uniform", "normal", "lognormal")


@dataclass(frozen=True)
class Support:
    """Where an uncertain input may lie: (low, high), ``low`` excluded, ``high`` included."""

    low: float
    high: float
    meaning: str

    def text(self) -> str:
        high = "∞)" if math.isinf(self.high) else f"{self.high:g}]"
        return f"({self.low:g}, {high}: {self.meaning}"


FACTOR = Support(0.0, math.inf, "a factor on the nominal value")
# The scalar uncertain inputs of one sample and their supports (friction factors: FACTOR).
SCALAR_INPUTS = {
    "modal_frequency_scale": Support(0.0, math.inf, "a factor on every modal frequency ω_i of the simulated plant"),
    "modal_damping": Support(
        0.0,
        0.99,
        "the modal damping ratio ξ of every mode of the simulated plant (not of the quasi-static corrections)",
    ),
    "pulse_amplitude": Support(0.0, math.inf, "the peak of the triangular tip pulse [N]"),
    "pulse_direction": Support(
        -360.0, 360.0, "the pulse's angle in the plane of the first two disturbance inputs [deg]; 45: the study's"
    ),
    "sensor_noise": Support(
        0.0, math.inf, "the standard deviation of white noise on every tip sensor at each sample [m or m/s]"
    ),
    "amplifier_lag": Support(0.0, math.inf, "the time constant of the piezo amplifiers' first-order lag [s]"),
    "sample_jitter": Support(
        0.0, math.inf, "the standard deviation of the controller's sampling instant, on the plant step's grid [s]"
    ),
}


@dataclass(frozen=True)
class Distribution:
    """One uncertain input's distribution, truncated to [low, high] (``normal`` always, the
    others where given): ``uniform`` on [low, high]; ``normal`` of ``mean`` and ``std``;
    ``lognormal`` of ``median`` and ``sigma`` (the standard deviation of its logarithm)."""

    kind: str
    low: float
    high: float
    mean: float = math.nan  # normal
    std: float = math.nan  # normal
    median: float = math.nan  # lognormal
    sigma: float = math.nan  # lognormal


@dataclass(frozen=True)
class UncertainInput:
    """An uncertain input: ``name`` is ``modal_frequency_scale``, ``modal_damping``,
    ``pulse_amplitude``, ``pulse_direction``, ``sensor_noise``, ``amplifier_lag``,
    ``sample_jitter`` or ``friction.<parameter>`` (a factor on that LuGre parameter, drawn for
    every joint independently)."""

    name: str
    distribution: Distribution


def distribution_of(t: Any, support: Support) -> Distribution:
    """One distribution table (``distribution = …`` and its parameters), its truncation inside
    the input's support.

    Parameters
    ----------
    t : DesignTable
        The table (read through its methods: no import of ``table``, which imports
        ``description``), e.g. ``uncertain.friction.sigma0``.
    support : Support
        Where the input may lie.

    Returns
    -------
    Distribution

    Raises
    ------
    DesignError
        For an unknown kind or key, a parameter out of range, or a range outside the support.
    """
    kind = t.string("distribution", choices=DISTRIBUTIONS)
    if kind == "uniform":
        d = Distribution(kind, t.number("low"), t.number("high"))
    elif kind == "normal":
        d = Distribution(
            kind, t.number("low"), t.number("high"), mean=t.number("mean"), std=t.number("std", positive=True)
        )
    else:
        if "high" not in t.data and not math.isinf(support.high):
            raise t.error("high", MISSING, f"required: the lognormal must end inside the support {support.text()}")
        d = Distribution(
            kind,
            t.number("low", 0.0),
            t.number("high") if "high" in t.data else math.inf,
            median=t.number("median", positive=True),
            sigma=t.number("sigma", positive=True),
        )
    # The lowest value of an open support is allowed where the density vanishes (lognormal at 0).
    if d.low < support.low or (d.low == support.low and kind != "lognormal"):
        raise t.error("low", d.low, f"outside the support {support.text()}")
    if d.high > support.high:
        raise t.error("high", d.high, f"outside the support {support.text()}")
    if not d.low < d.high:
        raise t.error("high", d.high, f"must be > low ({d.low:g})")
    t.finish()
    return d


@dataclass(frozen=True)
class Uncertainty:
    """The ``[uncertainty]`` table as given: its inputs (``UncertainInput``: a scalar input,
    ``friction.<parameter>`` for every joint or ``friction.<joint>.<parameter>`` for one) and
    whether the defaults fill in what it leaves out."""

    inputs: tuple[UncertainInput, ...] = ()
    defaults: bool = True


def friction_parameters() -> list[str]:
    """Every friction model's parameter keys (``common.friction_registry``)."""
    return [key for model in friction_registry.MODELS.values() for key in model.keys]


def parse_uncertainty(root: Any, joint_names) -> Uncertainty:
    """The ``[uncertainty]`` table of a design file.

    Parameters
    ----------
    root : DesignTable
        The design file's root table, whose ``[uncertainty]`` is read (absent: the defaults).
    joint_names : sequence of str
        The design's joints (a per-joint friction entry must name one; empty: a design whose
        joints ``[placement]`` places, checked when the ensemble is drawn).

    Returns
    -------
    Uncertainty

    Raises
    ------
    DesignError
        An unknown input, parameter or joint, or a distribution outside its input's support.
    """
    if "uncertainty" not in root.data:
        return Uncertainty()
    table = root.table("uncertainty")
    found: list[UncertainInput] = []
    defaults = table.boolean("defaults", True)
    keys = friction_parameters()
    for name in table.data:
        if name == "defaults":
            continue
        if name == "friction":
            friction = table.table("friction")
            for key in friction.data:
                if key in keys:
                    found.append(UncertainInput(f"friction.{key}", distribution_of(friction.table(key), FACTOR)))
                    continue
                if joint_names and key not in joint_names or not isinstance(friction.data[key], dict):
                    allowed = (
                        "a friction parameter (" + ", ".join(keys) + ") or a joint's name: " + ", ".join(joint_names)
                    )
                    raise friction.error(key, friction.data[key], allowed)
                joint = friction.table(key)
                for parameter in joint.data:
                    if parameter not in keys:
                        raise joint.error(parameter, joint.data[parameter], "allowed: " + ", ".join(keys))
                    distribution = distribution_of(joint.table(parameter), FACTOR)
                    found.append(UncertainInput(f"friction.{key}.{parameter}", distribution))
                joint.finish()
            friction.finish()
        elif name in SCALAR_INPUTS:
            found.append(UncertainInput(name, distribution_of(table.table(name), SCALAR_INPUTS[name])))
        else:
            allowed = "unknown input; allowed: " + ", ".join(["defaults", *SCALAR_INPUTS, "friction"])
            raise table.error(name, table.data[name], allowed)
    table.finish()
    return Uncertainty(tuple(found), defaults)


__all__ = [
    "DISTRIBUTIONS",
    "FACTOR",
    "SCALAR_INPUTS",
    "Distribution",
    "Support",
    "UncertainInput",
    "Uncertainty",
    "distribution_of",
    "friction_parameters",
    "parse_uncertainty",
]
