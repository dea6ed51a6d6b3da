"""The [control] table of the design file and the limits on it (docs/design-file.md): the
sizes the closed-loop study allocates or runs through, and the normal forces a piezo-actuated
joint can set."""

from __future__ import annotations

import numpy as np

from smartjoint.common import law_registry
from smartjoint.design.structure.description import PAPER_VALUES, Control
from smartjoint.design.structure.sections import MAX_MODES
from smartjoint.design.structure.table import DesignTable, per_joint

# Limits on the sizes [control] sets, checked before anything of that size is allocated (the
# other limits of a design file are in `spec`, MAX_MODES in `sections`).
MAX_KRYLOV = 20  # Krylov correction vectors per joint
MAX_LANCZOS_BYTES = 4 * 1024**3  # the Lanczos basis of 2·considered_modes vectors of the DOF size
MIN_SAMPLE_TIME = 1e-6  # [s]: the firmware counts its cycle in whole microseconds
MAX_STUDY_DURATION = 3600.0  # [s] of simulated time in a closed-loop study (the paper: 4 s)
MAX_CONTROLLER_STEPS = 10_000_000  # study_duration / sample_time
# The largest normal force a piezo-actuated friction joint can plausibly set: the blocking
# force of the largest multilayer piezo stacks is some tens of kN, and the bolt of a truss joint
# (M12, property class 8.8: proof load 48 kN) holds no more. 1e5 N is above both.
MAX_NORMAL_FORCE = 1e5  # [N]
MAX_PULSE_AMPLITUDE = 1e6  # [N]: the study's tip pulse; far above any impact hammer's (some 10 kN)


def parse_control(t: DesignTable, joints, dofs: int) -> Control:
    """The [control] table: the controlled joints, the sample time, the normal-force range, the
    LQG weights and mode counts (Eq. 33), the boundary layers of Eq. 30 and 34, the piezo
    calibration and the study duration.

    Parameters
    ----------
    t : DesignTable
        The [control] table (empty for the defaults).
    joints : sequence of Joint
        The design's joints; ``joints = [...]`` names some of them.
    dofs : int
        The model's DOF bound (`spec.estimated_dofs`), which bounds ``considered_modes``.

    Returns
    -------
    Control
        The settings, each within its MAX_* bound.
    """
    names = [j.name for j in joints]
    controlled = None
    if "joints" in t.data:
        value = t.get("joints")
        if not (isinstance(value, list) and value and all(isinstance(v, str) for v in value)):
            raise t.error("joints", value, "expected a non-empty list of joint names")
        for v in value:
            if v not in names:
                raise t.error("joints", v, "a joint of [[joints]]: " + (", ".join(names) or "(the design has none)"))
        if len(set(value)) != len(value):
            raise t.error("joints", value, "each joint once")
        controlled = tuple(value)
    count = len(controlled) if controlled is not None else len(joints)
    d = Control()
    control = Control(
        joints=controlled,
        sample_time=t.number("sample_time", d.sample_time, positive=True),
        normal_force_min=per_joint(t, "normal_force_min", d.normal_force_min, count, non_negative=True),
        normal_force_max=per_joint(t, "normal_force_max", d.normal_force_max, count, positive=True),
        considered_modes=t.integer("considered_modes", d.considered_modes, maximum=MAX_MODES),
        modes=t.integer("modes", d.modes, maximum=MAX_MODES),
        krylov=t.integer("krylov", d.krylov, minimum=0, maximum=MAX_KRYLOV),
        state_weight=t.number("state_weight", d.state_weight, positive=True),
        control_weight=t.number("control_weight", d.control_weight, positive=True),
        process_noise=t.number("process_noise", d.process_noise, positive=True),
        measurement_noise=t.number("measurement_noise", d.measurement_noise, positive=True),
        law_settings=_law_settings(t, count),
        piezo_capacitance=t.number("piezo_capacitance", d.piezo_capacitance, positive=True),
        piezo_force_per_volt=t.number("piezo_force_per_volt", d.piezo_force_per_volt, positive=True),
        piezo_preload=t.number("piezo_preload", d.piezo_preload, non_negative=True),
        study_duration=t.number("study_duration", d.study_duration, positive=True),
        reduction_normal_force=per_joint(t, "reduction_normal_force", None, len(names), non_negative=True),
        pulse_amplitude=t.number("pulse_amplitude", d.pulse_amplitude, positive=True),
        paper_values=tuple(key for key in PAPER_VALUES if key not in t.data),
    )
    _check_control_limits(t, control, count, dofs, joints)
    t.finish()
    return control


def paper_values_note(control: Control) -> str | None:
    """One sentence naming the [control] settings a design left out and so runs with the paper's
    demonstrator values (``PAPER_VALUES``); None when it gives them all.

    Parameters
    ----------
    control : Control

    Returns
    -------
    str or None
    """
    if not control.paper_values:
        return None
    shown = {
        "sample_time": f"sample_time = {control.sample_time:g} s",
        "normal_force_min": f"normal_force_min = {control.normal_force_min} N",
        "normal_force_max": f"normal_force_max = {control.normal_force_max} N",
        "study_duration": f"study_duration = {control.study_duration:g} s",
        "pulse_amplitude": f"pulse_amplitude = {control.pulse_amplitude:g} N",
    }
    return (
        "[control] leaves out "
        + ", ".join(shown[key] for key in control.paper_values)
        + ": the paper's demonstrator values, not your joints' — give them in [control]"
    )


def _check_control_limits(t: DesignTable, control: Control, count: int, dofs: int, joints=()) -> None:
    """Ranges of [control] that single keys cannot express: sizes the study allocates or runs
    through, and the normal forces a piezo joint can set (F_N = force_per_volt·V + preload)."""
    if control.sample_time < MIN_SAMPLE_TIME:
        raise t.error(
            "sample_time",
            control.sample_time,
            f"must be >= {MIN_SAMPLE_TIME:g} s (the firmware counts its cycle in whole microseconds)",
        )
    if control.pulse_amplitude > MAX_PULSE_AMPLITUDE:
        raise t.error(
            "pulse_amplitude",
            control.pulse_amplitude,
            f"must be 0 < peak <= {MAX_PULSE_AMPLITUDE:g} N (a hammer pulse)",
        )
    if control.study_duration > MAX_STUDY_DURATION:
        raise t.error("study_duration", control.study_duration, f"must be 0 < t_e <= {MAX_STUDY_DURATION:g} s")
    steps = control.study_duration / control.sample_time
    if steps > MAX_CONTROLLER_STEPS:
        raise t.error(
            "study_duration",
            control.study_duration,
            f"at most {MAX_CONTROLLER_STEPS} controller steps: t_e <= {MAX_CONTROLLER_STEPS:g} × "
            f"sample_time = {MAX_CONTROLLER_STEPS * control.sample_time:g} s",
        )
    lanczos_modes = MAX_LANCZOS_BYTES // (16 * max(dofs, 1))
    if min(control.considered_modes, dofs) > lanczos_modes:
        raise t.error(
            "considered_modes",
            control.considered_modes,
            f"with about {dofs} DOFs at most {lanczos_modes} (the Lanczos basis of 2 × considered_modes "
            f"vectors must stay under {MAX_LANCZOS_BYTES // 1024**3} GiB)",
        )
    if control.modes > control.considered_modes:
        raise t.error("modes", control.modes, f"must be <= considered_modes ({control.considered_modes})")
    # A number applies to every joint and is checked even when the design has none yet.
    count = count or int(
        not isinstance(control.normal_force_min, tuple) and not isinstance(control.normal_force_max, tuple)
    )
    low = np.broadcast_to(np.asarray(control.normal_force_min, dtype=float), (count,))
    high = np.broadcast_to(np.asarray(control.normal_force_max, dtype=float), (count,))
    for i in range(count):
        joint = f" (entry {i})" if isinstance(control.normal_force_max, tuple) else ""
        if high[i] > MAX_NORMAL_FORCE:
            raise t.error(
                "normal_force_max",
                float(high[i]),
                f"must be 0 < F_N^max <= {MAX_NORMAL_FORCE:g} N{joint}: more than the largest piezo "
                "stacks push and the joint bolt holds",
            )
    for i in range(count):
        joint = (
            f" (entry {i})"
            if isinstance(control.normal_force_min, tuple) or isinstance(control.normal_force_max, tuple)
            else ""
        )
        if low[i] > high[i]:
            raise t.error("normal_force_min", float(low[i]), f"must be 0 <= F_N^min <= F_N^max = {high[i]:g} N{joint}")
    for law in law_registry.LAWS.values():  # a normal force among a law's settings: within the limits
        for setting in law.settings:
            value = control.law_settings.get(law.name, {}).get(setting.key)
            if not setting.normal_force or value is None:
                continue
            given = np.broadcast_to(np.asarray(value, dtype=float), (count,))
            for i in range(count):
                if not low[i] <= given[i] <= high[i]:
                    where = f" (entry {i})" if isinstance(value, tuple) else ""
                    raise t.error(
                        setting.design_key(law.name),
                        float(given[i]),
                        f"{setting.meaning} must lie within [F_N^min, F_N^max] = [{low[i]:g}, {high[i]:g}] N{where}",
                    )
    _check_reduction_load(t, control.reduction_normal_force, len(joints))
    if count and control.piezo_preload > float(low.min()):
        raise t.error(
            "piezo_preload",
            control.piezo_preload,
            f"must be 0 <= preload <= F_N^min = {float(low.min()):g} N (at 0 V the stack "
            "already presses with the preload, so no setting could reach F_N^min)",
        )


def _check_reduction_load(t: DesignTable, load, joints: int) -> None:
    """``reduction_normal_force``: within [0, MAX_NORMAL_FORCE] N, at least one joint > 0."""
    if load is None:
        return
    forces = np.broadcast_to(np.asarray(load, dtype=float), (max(joints, 1),))
    if float(forces.max()) > MAX_NORMAL_FORCE or not float(forces.max()) > 0:
        raise t.error(
            "reduction_normal_force",
            list(load) if isinstance(load, tuple) else load,
            f"one F_N per joint in [0, {MAX_NORMAL_FORCE:g}] N, at least one > 0 (the joint compared)",
        )


__all__ = [
    "MAX_CONTROLLER_STEPS",
    "MAX_KRYLOV",
    "MAX_LANCZOS_BYTES",
    "MAX_NORMAL_FORCE",
    "MAX_PULSE_AMPLITUDE",
    "MAX_STUDY_DURATION",
    "MIN_SAMPLE_TIME",
    "paper_values_note",
    "parse_control",
]


def _law_settings(t: DesignTable, count: int) -> dict:
    """The laws' settings the table gives (``<law>_<key>``, ``common.law_registry``): law → key →
    value, one number or one per joint where the setting is per joint; each must be > 0."""
    found: dict = {}
    for law in law_registry.LAWS.values():
        for setting in law.settings:
            key = setting.design_key(law.name)
            t.used.add(key)  # allowed, given or not
            if key in t.data:
                value = (
                    per_joint(t, key, None, count, positive=True) if setting.per_joint else t.number(key, positive=True)
                )
                found.setdefault(law.name, {})[setting.key] = value
    return found
