"""Plots (PNG, matplotlib Agg) and Markdown tables for the report of ``smartjoint run``."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Line3DCollection  # type: ignore[import-untyped]  # noqa: E402

from smartjoint import __version__  # noqa: E402
from smartjoint.common import figures  # noqa: E402
from smartjoint.design.structure.correlation import ModeCorrelation  # noqa: E402
from smartjoint.design.structure.fem import FEModel  # noqa: E402
from smartjoint.design.structure.modal import Modes  # noqa: E402
from smartjoint.design.structure.updating import UpdatingResult  # noqa: E402


def updating_table(result: UpdatingResult) -> str:
    """Markdown tables: per mode EMA / FEM / error, per parameter initial / updated / sensitivity."""
    lines = [
        "| mode | EMA [Hz] | FEM initial [Hz] | FEM updated [Hz] | error [%] | EMA MAC |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for i, mode in enumerate(result.modes):
        mac = "" if result.mac is None or np.isnan(result.mac[i]) else f"{result.mac[i]:.2f}"
        lines.append(
            f"| {mode} | {result.measured_hz[i]:.2f} | {result.initial_hz[i]:.3f} | "
            f"{result.updated_hz[i]:.3f} | {result.error_pct[i]:+.2f} | {mac} |"
        )
    lines += ["", "| parameter | initial | updated | ratio | sensitivity ‖∂ln f/∂ln p‖ |", "|---|---:|---:|---:|---:|"]
    for k, name in enumerate(result.parameter_names):
        lines.append(
            f"| `{name}` | {result.initial[k]:.4g} | {result.updated[k]:.4g} | "
            f"{result.updated[k] / result.initial[k]:.3f} | {np.linalg.norm(result.sensitivity[:, k]):.3f} |"
        )
    lines += [
        "",
        f"Worst error {np.max(np.abs(result.error_pct)):.2f} % "
        f"({result.evaluations} eigen solutions, {result.starts} polished starts).",
    ]
    return "\n".join(lines)


def correlation_table(result: UpdatingResult) -> str:
    """Markdown: the MAC pairing of every measured mode before and after updating (EMA shapes).

    Parameters
    ----------
    result : UpdatingResult
        An updating result with ``correlation`` (the design carries EMA shapes).

    Returns
    -------
    str
        One row per measured mode: its number, the paired FE mode and MAC, nominal and updated.
    """
    updated, initial = result.correlation, result.initial_correlation
    assert updated is not None and initial is not None
    lines = [
        "| EMA mode | EMA [Hz] | FE mode, nominal | MAC, nominal | FE mode, updated | FE updated [Hz] | MAC, updated |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for i, number in enumerate(updated.measured_modes):
        mark = "" if updated.fe_modes[i] == number else " (swap)"
        lines.append(
            f"| {number} | {updated.measured_hz[i]:.2f} | {initial.fe_modes[i]} | {initial.diagonal[i]:.3f} | "
            f"{updated.fe_modes[i]}{mark} | {updated.paired_hz[i]:.3f} | {updated.diagonal[i]:.3f} |"
        )
    swaps = updated.swaps or ["none: every measured mode pairs with the FE mode of its number"]
    lines += ["", "Swaps: " + "; ".join(swaps) + f". Pairing changes during the fit: {result.pairing_changes}."]
    return "\n".join(lines)


def plot_mac(correlation: ModeCorrelation, path: Path) -> None:
    """The MAC matrix of the measured against the FE modes as an image with its values (paper Fig. 7).

    Parameters
    ----------
    correlation : ModeCorrelation
        The MAC matrix and pairing (`UpdatingResult.correlation`).
    path : Path
        The PNG written.
    """
    mac = correlation.mac
    n_measured, n_fe = mac.shape
    fig, ax = plt.subplots(figsize=(1.0 + 0.5 * n_fe, 1.2 + 0.5 * n_measured))
    image = ax.imshow(mac, vmin=0.0, vmax=1.0, cmap="Blues", aspect="equal")
    for i in range(n_measured):
        for j in range(n_fe):
            paired = correlation.fe_modes[i] == j + 1
            ax.text(
                j,
                i,
                f"{mac[i, j]:.2f}",
                ha="center",
                va="center",
                fontsize=7,
                fontweight="bold" if paired else "normal",
                color="white" if mac[i, j] > 0.6 else "black",
            )
    ax.set_xticks(range(n_fe), [str(j + 1) for j in range(n_fe)], fontsize=8)
    ax.set_yticks(
        range(n_measured),
        [f"{m} ({f:.2f} Hz)" for m, f in zip(correlation.measured_modes, correlation.measured_hz)],
        fontsize=8,
    )
    ax.set_xlabel("FE mode")
    ax.set_ylabel("EMA mode")
    ax.set_title("MAC, EMA against the updated FE model (paired in bold)", fontsize=10)
    fig.colorbar(image, ax=ax, fraction=0.03, pad=0.02)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def sensitivity_table(result: UpdatingResult) -> str:
    """Normalised sensitivities ∂ln f_i / ∂ln p_k at the updated parameters."""
    short = [name.split(".", 1)[1] for name in result.parameter_names]
    lines = ["| mode | " + " | ".join(short) + " |", "|---:|" + "---:|" * len(short)]
    for i, mode in enumerate(result.modes):
        lines.append(f"| {mode} | " + " | ".join(f"{v:+.3f}" for v in result.sensitivity[i]) + " |")
    return "\n".join(lines)


def plot_updating(result: UpdatingResult, path: Path) -> None:
    x = np.arange(len(result.modes))
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    width = 0.27
    top.bar(x - width, result.measured_hz, width, label="EMA (paper Fig. 7)")
    top.bar(x, result.initial_hz, width, label="FEM nominal")
    top.bar(x + width, result.updated_hz, width, label="FEM updated")
    top.set_ylabel("frequency [Hz]")
    top.legend(loc="upper left")
    bottom.axhspan(-2, 2, color="0.9", label="±2 % target")
    bottom.plot(x, result.initial_error_pct, "o--", label="nominal")
    bottom.plot(x, result.error_pct, "s-", label="updated")
    bottom.axhline(0.0, color="k", lw=0.6)
    bottom.set_ylabel("error vs EMA [%]")
    bottom.set_xticks(x, [str(m) for m in result.modes])
    bottom.set_xlabel("mode number")
    bottom.legend(loc="upper right")
    fig.suptitle("Model updating to the measured eigenfrequencies")
    figures.save(fig, path, dpi=110)


def member_polylines(model: FEModel) -> dict[str, list[int]]:
    """Point indices of each member from node centre to node centre, for drawing."""
    by_member: dict[str, list[int]] = {}
    for e, member in enumerate(model.element_member):
        a, b = (int(v) for v in model.element_points[e])
        chain = by_member.setdefault(member, [a])
        chain.append(b)
    node_index = {name: i for i, name in enumerate(model.design.nodes)}
    for name, chain in by_member.items():
        ends = model.design.members[name]
        chain.insert(0, node_index[ends.start])
        chain.append(node_index[ends.end])
    return by_member


def plot_mode_shapes(model: FEModel, modes: Modes, path: Path, count: int = 6) -> None:
    """The first ``count`` mode shapes, undeformed truss in grey."""
    count = min(count, len(modes))
    chains = member_polylines(model)
    points = model.points
    span = float(np.ptp(points, axis=0).max())
    columns = 3
    rows = int(np.ceil(count / columns))
    fig = plt.figure(figsize=(4.2 * columns, 3.6 * rows))
    for k in range(count):
        displacement = (model.S @ modes.shapes[:, k]).reshape(-1, 6)[:, :3]
        scale = 0.08 * span / max(np.abs(displacement).max(), 1e-300)
        deformed = points + scale * displacement
        ax = fig.add_subplot(rows, columns, k + 1, projection="3d")
        # One collection per drawing, not a line per member: a 1000-bay mast has 12 000 members.
        ax.add_collection3d(Line3DCollection([points[c] for c in chains.values()], colors="0.8", linewidths=0.6))
        ax.add_collection3d(Line3DCollection([deformed[c] for c in chains.values()], colors="C0", linewidths=0.9))
        low, high = np.vstack([points, deformed]).min(axis=0), np.vstack([points, deformed]).max(axis=0)
        ax.set(xlim=(low[0], high[0]), ylim=(low[1], high[1]), zlim=(low[2], high[2]))
        ax.set_title(f"mode {k + 1}: {modes.frequencies_hz[k]:.4g} Hz", fontsize=10)
        ax.set_box_aspect(np.ptp(np.vstack([points, deformed]), axis=0) + 1e-9)
        ax.view_init(elev=22, azim=-58)
        ax.set_axis_off()
    figures.save(fig, path, dpi=100)


def plot_spectrum(modes: Modes, measured: list[tuple[int, float]], path: Path, updated: bool = True) -> None:
    """The eigenfrequencies by mode number, with the measured ones (EMA) where given.

    Parameters
    ----------
    modes : Modes
    measured : list of (int, float)
        Mode number and frequency [Hz] of the measured modes.
    path : Path
        The PNG written.
    updated : bool
        Whether model updating ran (the legend says which model is shown).
    """
    fig, ax = plt.subplots(figsize=(8, 3.6))
    index = np.arange(1, len(modes) + 1)
    ax.plot(index, modes.frequencies_hz, ".-", label="FEM (updated)" if updated else "FEM (nominal, not updated)")
    if measured:
        ax.plot([m for m, _ in measured], [f for _, f in measured], "rx", ms=9, label="EMA")
    ax.set_xlabel("mode number")
    ax.set_ylabel("frequency [Hz]")
    ax.grid(alpha=0.3)
    ax.legend()
    figures.save(fig, path, dpi=110)


def _interval(lower: float, upper: float) -> str:
    """A 95 % interval; bounds the data do not constrain (clipped at ±700 in log) read as 0 and ∞."""
    low = "0" if lower < 1e-290 else f"{lower:.4g}"
    high = "∞" if upper > 1e290 else f"{upper:.4g}"
    return f"[{low}, {high}]"


def identification_table(result) -> str:
    """Markdown: identified LuGre parameters with 95 % intervals, NRMSE per record."""
    data = result.as_dict()
    lines = ["| parameter | value | 95 % interval | step |", "|---|---:|---|---|"]
    for name, entry in data["parameters"].items():
        if name in data["not_identified"]:  # no point value for what the records do not determine
            lines.append(f"| {name} | not identified | — | {entry['step']} |")
            continue
        interval = "given" if entry["ci95"] is None else _interval(*entry["ci95"])
        lines.append(f"| {name} | {entry['value']:.4g} | {interval} | {entry['step']} |")
    if data["not_identified"]:
        lines += ["", "Not identified:", ""] + [f"- {reason}" for reason in data["not_identified"].values()]
    velocity = data.get("velocity_nrmse", {})
    lines += ["", "| record | friction NRMSE (Eq. 3) | velocity NRMSE (output error) |", "|---|---:|---:|"]
    lines += [
        f"| {name} | {value:.4f} | {velocity[name]:.4f} |" if name in velocity else f"| {name} | {value:.4f} | — |"
        for name, value in data["nrmse"].items()
    ]
    return "\n".join(lines)


def plot_hysteresis(result, folder: Path) -> list[Path]:
    """Measured vs model friction over displacement (micro-slip) or velocity (stick-slip)."""
    from smartjoint.design.friction.equation_error import model_friction

    paths = []
    stick_names = set(result.stick.nrmse)  # record names of step 2
    for name, record in result.records.items():
        stick = name in stick_names
        model = model_friction(result.parameters, record, result.filtered[name])
        displacement = np.concatenate(
            [
                [0.0],
                np.cumsum(0.5 * (record.sliding_velocity[1:] + record.sliding_velocity[:-1]) * np.diff(record.time)),
            ]
        )
        x = record.sliding_velocity if stick else (displacement - displacement.mean()) * 1e6
        fig, ax = plt.subplots(figsize=(5.5, 4))
        ax.plot(x, record.friction_force, color="0.6", lw=0.8, label="measured")
        ax.plot(x, model, color="C3", lw=1.0, label="LuGre model")
        ax.set_xlabel("sliding velocity" if stick else "displacement [µm or µrad]")
        ax.set_ylabel("friction force u_R")
        ax.set_title(f"{name}: NRMSE {({**result.micro.nrmse, **result.stick.nrmse})[name]:.3f}", fontsize=9)
        ax.legend()
        path = folder / f"hysteresis_{name}.png"
        figures.save(fig, path, dpi=100)
        paths.append(path)
    return paths


def structure_markdown(design, model, modes, released, result, summary) -> str:
    """The report's head: the design, its FE model, the run, model updating (Fig. 7), the
    eigenfrequencies (Eq. 7) locked and released, and the mode shapes."""
    lines = [
        f"# smartjoint report: {design.name}",
        "",
        f"{design.description}",
        "",
        f"- design file `{design.source}` (sha256 `{summary['design']['sha256'][:16]}…`), smartjoint {__version__}",
        f"- FE model: {model.n_dof} independent DOFs, {len(model.element_kind)} Euler–Bernoulli beam elements, "
        f"{len(design.nodes)} rigid nodes, total mass {model.total_mass:.2f} kg",
        f"- modal damping ξ = {design.modal_damping:.2%} for every mode",
        f"- run `{summary['run_id']}`: {summary['started_utc']} to {summary['finished_utc']} (UTC), "
        f"{summary['seconds']:.1f} s",
        "",
        "## Model updating (paper Section 3.3, Fig. 7)",
        "",
    ]
    if result is not None:
        lines += [
            updating_table(result),
            "",
            "![updating](updating.png)",
            "",
            "Normalised sensitivities ∂ln f / ∂ln p at the updated parameters:",
            "",
            sensitivity_table(result),
            "",
        ]
        if result.correlation is not None:
            lines += ["MAC pairing of the EMA shapes:", "", correlation_table(result), "", "![MAC](mac.png)", ""]
    else:
        lines += ["The design carries no measured frequencies; the nominal model is used.", ""]
    lines += [
        "## Eigenfrequencies (Eq. 7)",
        "",
        "![spectrum](spectrum.png)",
        "",
        "| mode | joints locked [Hz] |" + (" joints released, F_N = 0 [Hz] |" if released is not None else ""),
        "|---:|---:|" + ("---:|" if released is not None else ""),
    ]
    for i, f in enumerate(modes.frequencies_hz):
        extra = f" {released.frequencies_hz[i]:.3f} |" if released is not None and i < len(released) else ""
        lines.append(f"| {i + 1} | {f:.3f} |{extra}")
    lines += ["", "## Mode shapes", "", "![mode shapes](mode_shapes.png)", ""]
    return "\n".join(lines)
