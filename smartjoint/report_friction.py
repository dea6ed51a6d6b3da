"""The friction section of the ``smartjoint run`` report: where each joint's LuGre parameters
came from, and each joint type's identification (paper Section 3.2, Eq. 3, Fig. 5)."""

from __future__ import annotations

from smartjoint import report as plots
from smartjoint.common import friction_registry


def friction_markdown(design, results, hysteresis: list[str]) -> str:
    """Markdown: the parameters every joint uses with their source, then per joint type the
    identification and its comparison with what the design file stated.

    Parameters
    ----------
    design : Design
        The design the later stages use (identified parameters in place).
    results : list of JointTypeFriction
        The friction stage's result per joint type.
    hysteresis : list of str
        The hysteresis plots in the report folder.

    Returns
    -------
    str
    """
    lines = ["## Friction joints (Section 3.2, Eq. 1–3)", ""]
    frictions = [design.joint_friction(joint) for joint in design.joints]
    for name in dict.fromkeys(f.model for f in frictions):
        model = friction_registry.friction_model(name)
        lines += [
            f"{model.display} parameters per unit normal force used by every later stage (reduction, control "
            "design, study, SIL):",
            "",
            f"| joint | type | {' | '.join(p.symbol for p in model.parameters)} | r [m] | source |",
            "|---|---|" + "---:|" * len(model.parameters) + "---:|---|",
        ]
        for joint, f in zip(design.joints, frictions):
            if f.model == name:
                lines.append(_joint_row(joint, f))
    lines.append("")
    for result in results:
        lines += _identification_lines(result)
    lines += [f"![{name}]({name})" for name in hysteresis]
    return "\n".join(lines) + "\n"


def _joint_row(joint, f) -> str:
    """A joint's row of the parameter table: its values, its radius, their source."""
    values = " | ".join(f"{v:.4g}" for v in f.values().values())
    radius = f"{f.radius:.4g}" if f.radius is not None else "—"
    return f"| {joint.name} | {joint.type} | {values} | {radius} | {_source(f)} |"


def _source(friction) -> str:
    """The source as the report shows it: the file name (and its hash) rather than a full path."""
    name = friction.source.replace("\\", "/").rsplit("/", 1)[-1]
    return f"`{name}`" + (f" (sha256 `{friction.sha256[:12]}…`)" if friction.sha256 else "")


def _identification_lines(result) -> list[str]:
    identification = result.identification
    if result.simulated:
        heading = (
            f"### Type {result.joint_type}: identification check on simulated rig records\n\n"
            f"The design names no rig records of type {result.joint_type}: the rig was simulated with the "
            "design's parameters (1 % measurement noise) and identified back; the design's parameters stay "
            "in use."
        )
        reference = "design"
    else:
        heading = (
            f"### Type {result.joint_type}: identified from the design's rig records\n\n"
            f"{len(result.records)} records named in the design's [friction] records; the identified parameters "
            f"replace the design file's for every type {result.joint_type} joint (result file `{result.result_file}`)."
        )
        reference = "design file"
    lines = [heading, "", plots.identification_table(identification), ""]
    if result.stated is not None:
        lines += [f"| parameter | {reference} | identified | difference [%] |", "|---|---:|---:|---:|"]
        stated_values, found_values = result.stated.values(), identification.parameters.values()
        for name in friction_registry.friction_model(result.stated.model).keys:
            stated, found = stated_values[name], found_values[name]
            difference = f"{100 * (found / stated - 1):+.1f}" if stated else "—"
            lines.append(f"| {name} | {stated:.4g} | {found:.4g} | {difference} |")
        lines.append("")
    lines += [
        "Weakly identifiable (95 % interval wider than ±50 %) by the two Eq. 3 steps: "
        + (", ".join(identification.weak_by_equation_error) or "none")
        + " (the paper found σ1 and σ2)."
    ]
    if identification.refined is not None:
        lines += [
            "After the output-error step (rig model driven by the measured excitation force, "
            "docs/identification.md): " + (", ".join(identification.weakly_identifiable) or "none") + "."
        ]
    lines += ["Steps: " + "; ".join(identification.steps) + ".", ""]
    return lines


__all__ = ["friction_markdown"]
