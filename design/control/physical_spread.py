"""The physical spread of the structure: what real joints, modes, amplifiers, sensors and test
pulses differ by, as the robustness ensemble of ``smartjoint run`` (stage 10) and a sweep with
``[uncertain] from = "design"`` draw it.

The design file's ``[uncertainty]`` table (``design.structure.uncertainty``) gives any entry; what
it leaves out takes the default below, each with its source (docs/design-file.md cites them and
says where a default is a choice). The identification's 95 % intervals come on top, as further
factors ``identification.<joint>.<parameter>`` (``with_identification``): an estimate's precision
is not the spread of the joints it stands for.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from smartjoint.common import friction_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.structure.uncertainty import Distribution, UncertainInput, friction_parameters

# The defaults' widths (docs/design-file.md, "[uncertainty]", for the sources):
FRICTION_COEFFICIENT_STD = 0.10  # μ-like parameters (F_c, F_s): CoV 10 %, truncated ±25 % — a choice
FRICTION_COEFFICIENT_BOUND = 0.25
CONTACT_LOG_SIGMA = 0.35  # σ0, σ1, σ2, v_s: ×/÷2 at 95 %, truncated at ×/÷2 — a choice
CONTACT_BOUND = 2.0
FREQUENCY_STD = 0.01  # an updated model: 1 % scatter, truncated ±3 %
FREQUENCY_BOUND = 0.03
DAMPING_LOG_SIGMA = 0.5  # lightly damped modes: CoV ≈ 50 %, truncated at ×/÷4
DAMPING_BOUND = 4.0
PULSE_SPREAD = 0.10  # the test pulse's amplitude ±10 % (a hammer or shaker pulse) — a choice
LAG_OF_SAMPLE = 0.5  # the amplifier's first-order lag: up to half a controller sample — a choice
DISPLACEMENT_NOISE = 1e-6  # m: the tip sensors' white noise per sample, up to this std — a choice
VELOCITY_NOISE = 2e-5  # m/s: a scanning vibrometer's 1 µm/s/√Hz over 500 Hz — a choice


@dataclass(frozen=True)
class SpreadEntry:
    """One drawn input and where its distribution comes from (``"design file"`` or the default's
    source in a few words)."""

    input: UncertainInput
    source: str


def _friction_default(parameter) -> tuple[Distribution, str]:
    """The default of a friction parameter (``friction_registry.Parameter``): a coefficient (no
    unit: F_c, F_s − F_c of LuGre) spreads as the friction coefficient, the rest as contact
    parameters."""
    if parameter.units == ("", ""):
        low, high = 1.0 - FRICTION_COEFFICIENT_BOUND, 1.0 + FRICTION_COEFFICIENT_BOUND
        distribution = Distribution("normal", low, high, mean=1.0, std=FRICTION_COEFFICIENT_STD)
        return distribution, "default: joint-to-joint friction coefficient, CoV 10 % (a choice; VDI 2230 classes)"
    distribution = Distribution("lognormal", 1.0 / CONTACT_BOUND, CONTACT_BOUND, median=1.0, sigma=CONTACT_LOG_SIGMA)
    return distribution, "default: contact parameter, ×/÷2 at 95 % (a choice; no repeated identifications published)"


def default_spread(design, pulse_amplitude: float) -> list[SpreadEntry]:
    """The defaults for ``design``: every friction parameter of its joints' models, the modal
    frequencies and damping, the pulse of amplitude ``pulse_amplitude`` [N], the amplifier lag
    and the tip sensors' noise (by their quantity; none for a design mixing displacement and
    velocity sensors, whose one noise figure would mix units)."""
    damping = float(design.modal_damping)
    entries = [
        SpreadEntry(
            UncertainInput(
                "modal_frequency_scale",
                Distribution("normal", 1.0 - FREQUENCY_BOUND, 1.0 + FREQUENCY_BOUND, mean=1.0, std=FREQUENCY_STD),
            ),
            "default: 1 % frequency scatter of an updated model (Adhikari et al. 2009)",
        ),
        SpreadEntry(
            UncertainInput(
                "modal_damping",
                Distribution(
                    "lognormal",
                    damping / DAMPING_BOUND,
                    min(0.99, damping * DAMPING_BOUND),
                    median=damping,
                    sigma=DAMPING_LOG_SIGMA,
                ),
            ),
            "default: modal damping CoV ≈ 50 % around the design's ξ (Adhikari & Woodhouse 2001)",
        ),
        SpreadEntry(
            UncertainInput(
                "pulse_amplitude",
                Distribution("uniform", pulse_amplitude * (1 - PULSE_SPREAD), pulse_amplitude * (1 + PULSE_SPREAD)),
            ),
            "default: test pulse ±10 % (a choice)",
        ),
        SpreadEntry(
            UncertainInput(
                "amplifier_lag", Distribution("uniform", 0.0, LAG_OF_SAMPLE * float(design.control.sample_time))
            ),
            "default: amplifier lag up to half a sample (a choice; τ = R_out·C of the stack)",
        ),
    ]
    quantities = {sensor.quantity for sensor in design.sensors}
    if len(quantities) == 1:
        quantity = quantities.pop()
        noise = DISPLACEMENT_NOISE if quantity == "displacement" else VELOCITY_NOISE
        unit = "m" if quantity == "displacement" else "m/s"
        entries.append(
            SpreadEntry(
                UncertainInput("sensor_noise", Distribution("uniform", 0.0, noise)),
                f"default: {quantity} sensor noise up to {noise:g} {unit} per sample (a choice)",
            )
        )
    for parameter in _model_parameters(design):
        distribution, source = _friction_default(parameter)
        entries.append(SpreadEntry(UncertainInput(f"friction.{parameter.key}", distribution), source))
    return entries


def _model_parameters(design) -> list:
    """The parameters (``friction_registry.Parameter``) of the friction models the design's joints
    use (the default model's for a design without friction yet), each key once."""
    models = {design.joint_friction(joint).model for joint in design.joints if design.joint_friction(joint)}
    found: dict = {}
    for model in sorted(models) or [friction_registry.DEFAULT]:
        for parameter in friction_registry.friction_model(model).parameters:
            found.setdefault(parameter.key, parameter)
    return list(found.values())


def physical_spread(design, pulse_amplitude: float) -> list[SpreadEntry]:
    """The design's ``[uncertainty]`` with the defaults for what it leaves out (none with
    ``defaults = false``), in the defaults' order, then the file's own further entries.

    Parameters
    ----------
    design : Design
        Its ``uncertainty``, joints, damping, sensors and sample time.
    pulse_amplitude : float
        The study's pulse [N], the centre of the default pulse spread.

    Returns
    -------
    list of SpreadEntry

    Raises
    ------
    ModelError
        A per-joint friction entry naming no joint of the design (one placed by ``[placement]``
        is known only now).
    """
    joints = [joint.name for joint in design.joints]
    given = {entry.name: entry for entry in design.uncertainty.inputs}
    for name in given:
        parts = name.split(".")
        if len(parts) == 3 and parts[1] not in joints:
            raise ModelError(
                f"uncertainty.{name}: no joint {parts[1]!r} in the design — its joints: {', '.join(joints)}"
            )
    entries = []
    if design.uncertainty.defaults:
        for entry in default_spread(design, pulse_amplitude):
            name = entry.input.name
            found = given.pop(name, None)
            entries.append(entry if found is None else SpreadEntry(found, "design file"))
    entries.extend(SpreadEntry(found, "design file") for found in given.values())
    return entries


def with_identification(entries: list[SpreadEntry], spreads: dict[str, float]) -> list[SpreadEntry]:
    """``entries`` and, on top, each identified parameter's factor ``identification.<parameter>``
    (lognormal of median 1 and the identification's σ of the logarithm, truncated to its 95 %
    interval; ``friction_uncertainty.friction_spreads``), drawn per joint and multiplied into the
    physical factor."""
    from smartjoint.design.control.friction_uncertainty import Z95

    known = set(friction_parameters())
    out = list(entries)
    for parameter, sigma in spreads.items():
        if parameter in known and sigma > 0.0:
            low, high = math.exp(-Z95 * sigma), math.exp(Z95 * sigma)
            distribution = Distribution("lognormal", low, high, median=1.0, sigma=sigma)
            out.append(
                SpreadEntry(
                    UncertainInput(f"identification.{parameter}", distribution),
                    "the identification's 95 % interval (estimate precision, on top of the spread)",
                )
            )
    return out


def describe(entries: list[SpreadEntry]) -> list[str]:
    """One line per entry: the input, its distribution and its source (the report's table)."""
    lines = []
    for entry in entries:
        d = entry.input.distribution
        if d.kind == "uniform":
            text = f"uniform [{d.low:.4g}, {d.high:.4g}]"
        elif d.kind == "normal":
            text = f"normal mean {d.mean:.4g}, std {d.std:.4g}, within [{d.low:.4g}, {d.high:.4g}]"
        else:
            text = f"lognormal median {d.median:.4g}, σ_ln {d.sigma:.3g}, within [{d.low:.4g}, {d.high:.4g}]"
        lines.append(f"{entry.input.name}: {text} — {entry.source}")
    return lines


__all__ = [
    "SpreadEntry",
    "default_spread",
    "describe",
    "physical_spread",
    "with_identification",
]
