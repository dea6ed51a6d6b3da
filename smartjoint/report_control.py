"""Report pieces of the closed-loop study (paper Section 6, Figs. 12–14): plots and Markdown."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smartjoint.common import figures, law_registry
from smartjoint.design.control import orderings as paper_orderings
from smartjoint.design.control import study as closed_loop
from smartjoint.report_reduction import save_figure

# How the report shows each sensor quantity: the unit and the factor from SI (m, m/s).
SHOWN = {"displacement": ("mm", 1e3, "Tip deflection"), "velocity": ("mm/s", 1e3, "Tip velocity")}
COLOURS = {
    "passive F_min": "tab:gray",
    "passive F_max": "k",
    **{law.display: law.colour for law in law_registry.LAWS.values()},
    "active LQG": "tab:green",
}


def plot_control_study(study: closed_loop.Study, folder) -> list[Path]:
    """Plot the closed-loop study (paper Section 6, Figs. 12–14).

    Parameters
    ----------
    study : closed_loop.Study
        The passive and controlled runs of the study.
    folder : path
        Where the figures go.

    Returns
    -------
    list of Path
        control_energy.png (Figs. 12–13), control_tip.png (Fig. 14), control_normal_force.png,
        and ``<law>_<setting>.png`` for each law setting that was tuned (:func:`tuning_plots`).
    """
    plt = figures.pyplot()
    folder = Path(folder)
    written = [
        _plot_energy(plt, study, folder),
        _plot_tip(plt, study, folder),
        _plot_normal_force(plt, study, folder),
    ]
    for name, tuning in study.tunings.items():
        if tuning.record is not None:
            written.append(_plot_tuning(plt, law_registry.LAWS[name], tuning.record, folder))
    return written


def tuning_plots(study: closed_loop.Study) -> list[str]:
    """The file names of the plots of the study's tuned settings (``<law>_<setting>.png``)."""
    return [f"{name}_{t.record.setting}.png" for name, t in study.tunings.items() if t.record is not None]


def _plot_energy(plt, study: closed_loop.Study, folder: Path) -> Path:
    """control_energy.png: the system energy of every run after the tip pulse (Figs. 12–13)."""
    fig, ax = plt.subplots(figsize=(7, 3.8))
    for r in study.runs:
        ax.semilogy(r.time, np.maximum(r.energy, 1e-12), color=COLOURS[r.name], lw=1.0, label=r.name)
    ax.axvline(closed_loop.PULSE_DURATION, color="0.7", lw=0.6)
    return save_figure(
        fig,
        ax,
        folder / "control_energy.png",
        "t [s]",
        "½xᵀx [J]",
        "System energy after the tip pulse (Figs. 12–13)",
    )


def _plot_tip(plt, study: closed_loop.Study, folder: Path) -> Path:
    """control_tip.png: the tip sensors of the runs, one panel per sensor in its unit (Fig. 14)."""
    fig, axes = plt.subplots(1, len(study.sensor_names), figsize=(10, 3.6), squeeze=False)
    for i, (ax, sensor, quantity) in enumerate(zip(axes[0], study.sensor_names, study.sensor_quantities)):
        unit, factor, what = SHOWN[quantity]
        for r in study.runs:
            if r.name == "passive F_min":
                continue  # its large slow swing hides the others
            ax.plot(r.time, factor * r.sensors[:, i], color=COLOURS[r.name], lw=0.8, label=r.name)
        ax.set_xlabel("t [s]")
        ax.set_ylabel(f"{sensor} [{unit}]")
        ax.set_title(f"{what} {sensor} (Fig. 14)")
        ax.legend(fontsize=7)
    figures.save(fig, folder / "control_tip.png", dpi=110)
    return folder / "control_tip.png"


def _plot_normal_force(plt, study: closed_loop.Study, folder: Path) -> Path:
    """control_normal_force.png: the controllers' normal force commands at the first joint."""
    fig, ax = plt.subplots(figsize=(7, 3.5))
    window = study.runs[0].time <= min(0.5, study.setup.duration)
    for r in study.runs:
        if r.name in law_registry.DISPLAY:
            ax.plot(
                r.time[window],
                r.normal_force[window, 0],
                color=COLOURS[r.name],
                lw=0.7,
                label=f"{r.name}, joint {study.joint_names[0]}",
            )
    return save_figure(
        fig, ax, folder / "control_normal_force.png", "t [s]", "F_N [N]", "Normal force commands (first 0.5 s)"
    )


def _plot_tuning(plt, law, record, folder: Path) -> Path:
    """<law>_<setting>.png: E(t_e) against the tuned setting (the SISO ε of Eq. 30, for Eq. 32)."""
    setting = next(x for x in law.settings if x.key == record.setting)
    # Each evaluation is (the setting, …, E(t_e)): a curve for one setting, points where the
    # tuning moved others as well (the slip-ratio law's rates).
    points = sorted(record.evaluations)
    style = ".-" if len(points[0]) == 2 else "."
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.semilogx([p[0] for p in points], [p[-1] for p in points], style, color="tab:blue", label="E(t_e), Eq. 32")
    ax.semilogx(
        [record.value],
        [record.energy_measure],
        "o",
        mfc="none",
        ms=10,
        color="tab:red",
        label=f"optimum {record.value:.3g} {setting.unit}",
    )
    what = setting.key.replace("_", " ")
    return save_figure(
        fig,
        ax,
        folder / f"{law.name}_{setting.key}.png",
        f"{what} [{setting.unit}]",
        "E(t_e) [J·s]",
        f"{law.display} {what} optimised for E(t_e) (Eq. 32)",
    )


def _runs_table(s: dict) -> list[str]:
    """The table of the runs' metrics: one RMS column per sensor in its unit (mm, mm/s), the peak
    tip deflection from the displacement sensors and, with velocity sensors, their peak.

    Parameters
    ----------
    s : dict
        The study's summary (``closed_loop.summary``).

    Returns
    -------
    list of str
        The Markdown lines, a blank line first.
    """
    sensors = list(zip(s["sensors"], s["sensor_quantities"]))
    velocity = any(quantity == "velocity" for _, quantity in sensors)
    lines = [
        "",
        "| run | e(t_e) [J] | e(t_e) / passive F^max | E(t_e) Eq. 32 [J·s] | "
        + " | ".join(f"RMS {name} [{SHOWN[quantity][0]}]" for name, quantity in sensors)
        + " | peak tip [mm] | "
        + ("peak tip velocity [mm/s] | " if velocity else "")
        + "settling to 10 % [s] | mean control power [W] |",
        "|---|" + "---:|" * (6 + len(sensors) + velocity),
    ]
    for name, m in s["runs"].items():
        # Each kind's figures come in sensor order: take them one by one as the columns go.
        figures = {"displacement": iter(m["tip_rms"] or ()), "velocity": iter(m["velocity_rms"] or ())}
        rms = [f"{SHOWN[quantity][1] * next(figures[quantity]):.2f}" for _, quantity in sensors]
        settle = "—" if m["settling_time"] is None else f"{m['settling_time']:.3f}"
        peak = "—" if m["tip_peak"] is None else f"{1e3 * max(m['tip_peak']):.1f}"
        peak += f" | {1e3 * max(m['velocity_peak']):.1f}" if velocity else ""
        lines.append(
            f"| {name} | {m['energy_end']:.3g} | {m['energy_end_relative']:.3g} | {m['energy_measure']:.4g} | "
            + " | ".join(rms)
            + f" | {peak} | {settle} | {m['control_power']:.3g} ({m['power_kind']}) |"
        )
    return lines


def _settings_lines(study: closed_loop.Study) -> list[str]:
    """One line per law setting: its value, and where it came from (the file, a default, tuned)."""
    lines = []
    for name, tuning in study.tunings.items():
        law = law_registry.LAWS[name]
        for setting in law.settings:
            what = f"- {law.display} {setting.key.replace('_', ' ')}{law.cited()}"
            value = tuning.settings[setting.key]
            if tuning.record is not None and tuning.record.setting == setting.key:
                lines.append(f"{what}: {tuning.record.describe()}.")
                continue
            shown = f"{value.tolist()}" if isinstance(value, np.ndarray) else f"{value:g}"
            if setting.key in tuning.given:
                source = "from the design file"
            elif tuning.record is not None:  # set by the law's tuning with the record's setting
                source = "set by the tuning above"
            else:
                source = "default"
            lines.append(f"{what}: {shown} {setting.unit} ({source}).")
    return lines


def _orderings_lines(c: dict) -> list[str]:
    """The paper's orderings (``orderings``) on one study, and the active LQG's power ratio."""
    mark = {True: "yes", False: "**no**", None: "— (no displacement sensor)"}
    lines = [f"- {o.sentence}: {mark[verdict]}" for o, verdict in paper_orderings.judged(c)]
    law = paper_orderings.clipping_law()
    if law is not None and f"power_ratio_active_to_{law.name}" in c:
        lines.append(f"- control power ratio active / {law.display} = {c[f'power_ratio_active_to_{law.name}']:.2f}")
    return lines


def _blind_lines(blind: dict[str, list[float]]) -> list[str]:
    """The design model's modes no sensor sees (the filter predicts them from the measured u_R
    alone) and no joint moves (the LQR leaves them alone), when there are any."""
    words = {"unseen": "no sensor sees", "unmoved": "no friction joint moves"}
    return [
        f"- The design model keeps {len(hz)} mode(s) {words[kind]} (to round-off): "
        + ", ".join(f"{f:.2f} Hz" for f in hz)
        + (" — the filter predicts them from the measured friction forces alone." if kind == "unseen" else ".")
        for kind, hz in blind.items()
        if hz
    ]


def control_markdown(study: closed_loop.Study) -> str:
    s = closed_loop.summary(study)
    lines = [
        "## Semi-active control (paper Sections 5–6, Figs. 12–14)",
        "",
        f"Design model {s['states']} states; controller sample time {1e3 * s['sample_time']:g} ms, plant step "
        f"{1e6 * s['plant_step']:g} µs; F_N^min/F_N^max = {s['normal_force_min']} / {s['normal_force_max']} N; "
        f"tip pulse {s['pulse_amplitude']:g} N over 40 ms in every disturbance direction, F_N^max during the pulse; "
        f"t_e = {s['duration']:g} s.",
        "",
        f"- LQG (Eq. 33): linear closed loop max|λ| = {s['lqg_max_pole_magnitude']:.6f} "
        f"(stability margin {s['lqg_stability_margin']:.2e}).",
        *_blind_lines(s["lqg_blind_modes_hz"]),
        *_settings_lines(study),
    ]
    lines += _runs_table(s)
    measures = [m["energy_measure"] for m in s["runs"].values()]
    lines += [
        "",
        # How far apart the runs are at all: on a structure whose joints see little of the pulse
        # within t_e (a 1000-bay mast: 1.5 %) no ordering below means much.
        f"E(t_e) spans {100 * (max(measures) / min(measures) - 1):.3g} % between the runs "
        f"({min(measures):.4g} … {max(measures):.4g} J·s).",
        "",
        "Orderings of the paper (Section 6):",
        "",
        *_orderings_lines(s["orderings"]),
        "",
        "Control power: semi-active runs — electrical energy to charge the piezo stacks, "
        "½C·max(0, V_k² − V_k−1²) with V = (F_N − preload)/k, no charge recovered; active LQG — mechanical "
        "actuator power Σ|u_d·v| (a lower bound for any actuator that delivers u_d).",
        "",
    ]
    return "\n".join(lines)
