"""Which LuGre parameters the records do not determine, and why (the regime that is missing).

A parameter is **not identified** when its 95 % interval is wider than ±``fitting.WEAK_RELATIVE_WIDTH``
of its value, unbounded, or held at the search box's edge — or wider than the accuracy the
identification was asked for (``Identification.accuracy``, a campaign's target): the records then
do not pin it to what was required, and
no point value of it is presented as a result (``smartjoint identify`` prints the reason,
``-o joint.toml`` lists it under ``[identification.not_identified]`` without a value, and a
design refuses it unless the design file states the value itself).

The reason names what the records lack, from the records themselves:

- σ0 (presliding stiffness): micro-slip records well below the break-away;
- F_c, F_d, v_s (the Stribeck curve): stick-slip records that slide at a few v_s — their
  speeds are compared with the estimate's v_s;
- σ1 (micro-damping): it shows only in the damping of the bristle resonance at the stick–slip
  transitions, which the rig's records seldom resolve (the paper's σ1 is weak as well);
- σ2 (viscous friction): sliding fast enough that σ2·v stands out of the force noise.
"""

from __future__ import annotations

import numpy as np

from smartjoint.design.friction.fitting import WEAK_RELATIVE_WIDTH


def half_width(value: float, lower: float, upper: float) -> float:
    """Relative 95 % half width max(upper/value − 1, 1 − lower/value); inf when unbounded."""
    if not value > 0.0:
        return float("inf")
    with np.errstate(over="ignore"):
        return float(max(upper / value - 1.0, 1.0 - lower / value))


def not_identified(identification) -> dict[str, str]:
    """The parameters the records do not determine, each with the reason in one sentence.

    Parameters
    ----------
    identification : Identification
        The result of ``identify`` (the final step's intervals decide; ``identify`` imports this
        module, so the type is not imported here).

    Returns
    -------
    dict of str to str
        Parameter → why, in the order of the result's parameters; empty when all are identified.
    """
    entries = identification.parameter_entries()
    wide = {
        name: half_width(entry["value"], *entry["ci95"]) for name, entry in entries.items() if entry["ci95"] is not None
    }
    limits = {name: min(WEAK_RELATIVE_WIDTH, identification.accuracy.get(name, WEAK_RELATIVE_WIDTH)) for name in wide}
    wide = {name: w for name, w in wide.items() if not w <= limits[name]}
    return {name: _reason(name, width, limits[name], identification) for name, width in wide.items()}


SLOWEST_NEEDED = 3.0  # stick-slip records all sliding faster than this many v_s barely show the drop
UNBOUNDED = 100.0  # a relative half width beyond ×100: the records do not bound the parameter


def _interval(width: float, limit: float) -> str:
    if not width <= UNBOUNDED:
        return "unbounded"
    text = f"±{100 * width:.3g} %"
    return text if limit >= WEAK_RELATIVE_WIDTH else f"{text}, wider than the required ±{100 * limit:.3g} %"


def _reason(name: str, width: float, limit: float, identification) -> str:
    p = identification.parameters
    arm = p.moment_arm
    unit = "m/s" if identification.joint_type == "A" else "rad/s"
    micro = [r for r in identification.records.values() if r.name in identification.micro.nrmse]
    stick = [r for r in identification.records.values() if r.name in identification.stick.nrmse]
    interval = _interval(width, limit)
    if name == "sigma0":
        levels = [
            float(np.max(np.abs(r.friction_force)) / (arm * np.median(r.normal_force) * (p.coulomb + p.stribeck)))
            for r in micro
        ]
        shown = ", ".join(f"{level:.2f}" for level in levels) or "none"
        return (
            f"σ0 (presliding stiffness), 95 % interval {interval}: the micro-slip records reach {shown}× the "
            "estimated break-away — a record that sticks at 0.1–0.3× it (lightest inertia) pins σ0"
        )
    if name in ("coulomb", "stribeck", "stribeck_velocity"):
        speeds = [float(np.max(np.abs(r.sliding_velocity))) for r in stick]
        vs = p.stribeck_velocity
        span = f"{min(speeds):.3g}–{max(speeds):.3g} {unit}" if speeds else "no stick-slip record"
        ratio = f" ({min(speeds) / vs:.3g}–{max(speeds) / vs:.3g}× the estimated v_s)" if speeds and vs > 0 else ""
        slow = bool(speeds) and vs > 0 and min(speeds) > SLOWEST_NEEDED * vs
        fix = (
            f"none slides below {SLOWEST_NEEDED:g}·v_s: a heavier moving inertia (beyond the rig's range, or a "
            "lower F_N) makes one slide near v_s, where the Stribeck drop shows"
            if slow
            else "records at about 1.3× the break-away whose inertia makes them slide at 1–16·v_s show the "
            "Stribeck drop (smartjoint rig --plan designs them)"
        )
        return (
            f"{_symbol(name)} (Stribeck curve), 95 % interval {interval}: the stick-slip records slide at "
            f"{span}{ratio} — {fix}"
        )
    if name == "sigma1":
        return (
            f"σ1 (micro-damping), 95 % interval {interval}: it shows only in the damping of the bristle "
            "resonance at the stick–slip transitions, which these records do not resolve — state it from "
            "elsewhere (a design file value) or measure the presliding resonance's decay"
        )
    speeds = [float(np.max(np.abs(r.sliding_velocity))) for r in stick]
    top = f"{max(speeds):.3g} {unit}" if speeds else "no sliding"
    return (
        f"σ2 (viscous friction), 95 % interval {interval}: at the records' sliding speeds (up to {top}) σ2·v "
        "stays within the force noise — records that slide faster (lighter inertia, larger amplitude) pin it"
    )


def _symbol(name: str) -> str:
    return {"coulomb": "F_c", "stribeck": "F_d", "stribeck_velocity": "v_s"}[name]


__all__ = ["UNBOUNDED", "half_width", "not_identified"]
