"""Report pieces of the reduction study (paper Section 4.3, Figs. 9–10): plots and Markdown."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smartjoint.common import figures
from smartjoint.design.reduction import channel_references, hankel_values, modal_gramians, study_summary
from smartjoint.design.structure import modal


def plot_study(study: dict, folder) -> list:
    """hankel.png (Fig. 9), friction_moment.png (Fig. 10), energy.png."""
    plt = figures.pyplot()
    folder = Path(folder)
    written = []
    first = study["first"]
    fe = study["fe"]
    considered = modal.modal_model(fe, first)
    fig, ax = plt.subplots(figsize=(7, 3.5))
    # Each joint's gramian over its reference: the scale the selection ranks on (unit-free).
    references = [c.value for c in channel_references(considered) if c.kind == "joint"]
    control_u = modal_gramians(considered)["joint"] / np.asarray(references)
    for j, name in enumerate(study["joint_names"]):
        ax.semilogy(np.arange(1, first.omega.size + 1), control_u[:, j], ".", label=f"joint {name}")
    kept = study["runs"][0]["reduction"].kept_modes
    ax.semilogy(
        kept + 1, hankel_values(considered)["uv"][kept], "o", mfc="none", color="k", label=f"kept ({kept.size})"
    )
    written.append(
        save_figure(
            fig,
            ax,
            folder / "hankel.png",
            "mode",
            "w_ij^c / r_j (Eq. 17)",
            "Controllability of the modes by each joint (Fig. 9)",
        )
    )

    ref = study["reference"]
    a = study["active"]
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(ref.time, ref.friction_force[:, a], "k", lw=1.2, label=f"full ({study['full'].n_states} states)")
    for r in study["runs"]:
        ax.plot(
            r["result"].time,
            r["result"].friction_force[:, a],
            lw=0.9,
            label=f"{study['keep']} modes + {r['krylov_per_joint']} Krylov ({r['states']} states)",
        )
    written.append(
        save_figure(
            fig,
            ax,
            folder / "friction_moment.png",
            "t [s]",
            f"u_R of {study['joint_names'][a]}",
            "Friction moment: full vs reduced (Fig. 10)",
        )
    )

    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.semilogy(ref.time, np.maximum(ref.energy, 1e-12), "k", label="full")
    for r in study["runs"]:
        ax.semilogy(
            r["result"].time,
            np.maximum(r["result"].energy, 1e-12),
            lw=0.9,
            label=f"{study['keep']} modes + {r['krylov_per_joint']} Krylov",
        )
    written.append(
        save_figure(fig, ax, folder / "energy.png", "t [s]", "½xᵀx [J]", "Structural energy after the tip pulse")
    )
    written += _plot_comparison(study, folder)
    return written


def _plot_comparison(study: dict, folder: Path) -> list:
    """reduction_bode.png: σ_max of u_R → v of the full model, the design model and balanced
    truncation to the Nyquist frequency (none without a comparison)."""
    plt = figures.pyplot()
    written = []
    compared = study.get("comparison")
    if compared is not None and compared.gains:
        fig, ax = plt.subplots(figsize=(7, 3.5))
        f = compared.grid / (2 * np.pi)
        for key, label, style in (
            ("full", f"full ({study['full'].n_states} states)", "k-"),
            ("design model", f"design model ({compared.order} states)", "C0-"),
            ("bt", f"balanced truncation ({compared.order} states)", "C2:"),
        ):
            if key in compared.gains:
                ax.semilogy(f, compared.gains[key], style, lw=1, label=label)
        ax.axvline(compared.band_hz, color="0.6", lw=0.8, ls="--")
        ax.set_xlim(0.0, compared.nyquist_hz)
        written.append(
            save_figure(
                fig,
                ax,
                folder / "reduction_bode.png",
                "frequency [Hz]",
                "σ_max of u_R → v [m/(N·s)]",
                "Design model to the Nyquist frequency (dashed: the considered band)",
            )
        )
    return written


def comparison_markdown(study: dict) -> list[str]:
    """The report lines of the design model against balanced truncation (none without one)."""
    compared = study.get("comparison")
    if compared is None:
        return []
    lines = [
        "### The controllers' design model against balanced truncation",
        "",
    ]
    if compared.skipped:
        return lines + [f"Not compared: {compared.skipped}.", ""]
    norms = compared.norms
    lines += [
        f"The {compared.order}-state design model (its corrections quasi-static at 4× the Nyquist frequency) "
        f"and balanced truncation of the full model at the same order (given the {compared.balanced_modes} modes "
        f"below {compared.cut:g}× Nyquist; that cut alone loses u_R → v H∞ "
        f"{100 * norms['nyquist']['uv']['cut_alone']['hinf_relative']:.3f} % to Nyquist). "
        "Errors relative to the full model's peak; the ratio is the design model's error over BT's.",
        "",
        "| path, band | design model | balanced truncation | ratio |",
        "|---|---:|---:|---:|",
    ]
    for band, band_label in (("band", f"0–{compared.band_hz:.0f} Hz"), ("nyquist", f"0–{compared.nyquist_hz:.4g} Hz")):
        for path, path_label in (("uv", "u_R → v"), ("wy", "w → y")):
            entry = norms[band][path]
            lines.append(
                f"| {path_label}, {band_label} H∞ | {100 * entry['design model']['hinf_relative']:.3g} % | "
                f"{100 * entry['bt']['hinf_relative']:.3g} % | {compared.ratio(band, path, 'design model'):.2f}× |"
            )
    static = compared.static_compliance_error
    lines += [
        f"| static joint compliance | {static['design model']:.2g} | {static['bt']:.2g} | "
        f"{static['design model'] / static['bt']:.1e}× |",
        "",
        "![design model to Nyquist](reduction_bode.png)",
        "",
    ]
    return lines


def save_figure(fig, ax, path, xlabel: str, ylabel: str, title: str):
    """Label, title and legend ``ax``, write ``fig`` to ``path`` (PNG, 110 dpi) and close it.

    Parameters
    ----------
    fig, ax : matplotlib Figure and Axes
        The plot.
    path : path-like
        Where the PNG goes.
    xlabel, ylabel, title : str
        The axis labels and the title.

    Returns
    -------
    path-like
        ``path``.
    """
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=8)
    figures.save(fig, path, dpi=110)
    return path


def study_markdown(study: dict) -> str:
    """The report section of a reduction study: a table per Krylov count and the three plots.

    Parameters
    ----------
    study : dict
        A result of `reduction_study`; its `study_summary` fills the table.

    Returns
    -------
    str
        Markdown.
    """
    s = study_summary(study)
    lines = [
        "## Model reduction (paper Section 4, Figs. 9–10)",
        "",
        f"Joints {', '.join(s['joints'])} with F_N = {s['normal_forces']} N, tip pulse {s['pulse_amplitude']:g} N "
        f"over 40 ms along {', '.join(s['disturbances'])}. "
        + (
            f"Full model: all modes of the released truss ({s['full_states']} states); "
            if s["reference_band_hz"] is None
            else f"Full model: the modes of the released truss to {s['reference_band_hz']:.4g} Hz plus the static "
            f"residual of every joint and disturbance input ({s['full_states']} states; errors measured to "
            f"{s['reference_band_hz']:.4g} Hz); "
        )
        + f"reduced: {s['kept_modes']} "
        f"of the first {s['considered_modes']} modes by Hankel singular values, plus Krylov vectors for the "
        f"active joint {s['active_joint']}, quasi-static at {s['correction_frequency_hz']:.0f} Hz "
        f"(4× the controller's Nyquist frequency: no pseudo-mode in its band). Plant step {s['step_s']:g} s.",
        "",
        "Each channel of the Hankel ranking is scaled by its largest modal gramian (mode): "
        + ", ".join(f"{c['name']} {c['value']:.3g} {c['unit']} ({c['mode']})" for c in s["hankel_references"])
        + ".",
        "",
        "| Krylov vectors | states | friction RMS error "
        + " | ".join(f"0–{w} s" for w in s["runs"][0]["friction_rms_error"])
        + " | static compliance error | H∞ u→v (rel., band) | H∞ u→v (rel., to Nyquist) | H∞ w→y (rel.) |",
        "|---:|---:|" + "---:|" * (len(s["runs"][0]["friction_rms_error"]) + 4),
    ]
    convergence = s["reference_convergence"]

    def converged(window: str) -> bool:
        return convergence is None or convergence[window] <= s["reference_converged_below"]

    for r in s["runs"]:
        m = r["metrics"]
        lines.append(
            f"| {r['krylov_per_joint']} | {r['states']} | "
            + " | ".join(
                f"{100 * e:.1f} %" if converged(w) else "not measured" for w, e in r["friction_rms_error"].items()
            )
            + f" | {100 * m['static_compliance']['relative_error']:.2f} % | {100 * m['uv']['hinf_relative']:.1f} %"
            f" | {100 * m['uv_nyquist']['hinf_relative']:.1f} % ({m['nyquist_hz']:.0f} Hz)"
            f" | {100 * m['wy']['hinf_relative']:.2f} % |"
        )
    if convergence is not None:
        lines += [
            "",
            "The reference rebuilt from half its modes moves by "
            + ", ".join(f"{100 * e:.1f} % (0–{w} s)" for w, e in convergence.items())
            + f"; a window where it moves by more than {100 * s['reference_converged_below']:.0f} % is not "
            "converged and its friction error is not measured (on a long truss the pulse has not reached the "
            "joint yet, and no truncated modal model, reference or reduced, represents a travelling front).",
        ]
    lines += [
        "",
        "The stick–slip trajectory is sensitive: small model differences shift the stick/slip instants, "
        "so the error grows with the window (docs/simulation.md).",
        "",
        "![hankel](hankel.png)",
        "",
        "![friction moment](friction_moment.png)",
        "",
        "![energy](energy.png)",
        "",
        *comparison_markdown(study),
    ]
    return "\n".join(lines)
