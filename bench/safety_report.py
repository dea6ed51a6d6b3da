"""The safe-state fault matrix of ``safety`` as the report shows it: the table of every case
(safety_cases.md), the report's paragraph and the figure of cycles to the safe state and to
recovery (safety_cycles.png). Policy and figures: docs/safety.md.
"""

from __future__ import annotations

import numpy as np

from smartjoint.bench.safety import DETECTION_LIMIT, REPLAY_AGES
from smartjoint.common import figures


def _cell(value) -> str:
    """A figure in the table or the paragraph: — where the case never got there."""
    return "—" if value is None else str(value)


def _heading(out: dict) -> str:
    """The heading of the table and of the report's paragraph: the law and the firmware run."""
    return f"### Safe state under every fault ({out['law']}, {out['real']} firmware, SIL bench)"


def matrix_markdown(out: dict) -> str:
    """The table of all cases (grouped per timing) and the worst figures.

    Parameters
    ----------
    out : dict
        What :func:`smartjoint.bench.safety.fault_matrix` returned.

    Returns
    -------
    str
        Markdown.
    """

    lines = [
        _heading(out),
        "",
        f"{out['cases']} cases; worst cycles to the safe state: firmware {_cell(out['worst_firmware'])}, "
        f"force at every joint {_cell(out['worst_joints'])} (limit {DETECTION_LIMIT}); worst recovery "
        f"{_cell(out['worst_recovery'])} cycles after the fault ends; "
        + (
            "every case passes."
            if not out["failed"]
            else f"**{len(out['failed'])} fail**: " + "; ".join(out["failed"][:10])
        ),
        "",
        "| fault | timing | firmware safe [cycles] | joints at F_safe [cycles] | holds | recovery [cycles] | ok |",
        "|---|---|---:|---:|---|---:|---|",
    ]
    for r in out["rows"]:
        note = (
            f" (output stage of {', '.join(r['failed_output_stage'])} failed: that joint cannot)"
            if r["failed_output_stage"]
            else ""
        )
        if r["tolerated"]:
            lines.append(
                f"| {r['case']} | {r['timing']} | no safe state (used late) | — | — | — | "
                f"{'yes' if r['ok'] else '**no**'} |"
            )
            continue
        lines.append(
            f"| {r['case']}{note} | {r['timing']} | {_cell(r['firmware'])} | {_cell(r['joints'])} | "
            f"{'yes' if r['holds'] else '**no**'} | {_cell(r['recovery'])} | {'yes' if r['ok'] else '**no**'} |"
        )
    return "\n".join(lines) + "\n"


def _buses_sentence(out: dict) -> str:
    """On several buses: what each case had to stop (``bench.fault_scope``); and the frames on the
    buses that the controller does not read."""
    unread = out.get("unread", [])
    text = (
        f" {len(unread)} frames on the buses are not the controller's to read ({', '.join(unread[:4])}"
        f"{' …' if len(unread) > 4 else ''}: a supervisor's); a fault on them must leave it undisturbed."
        if unread
        else ""
    )
    buses = out.get("buses", [])
    if len(buses) < 2:
        return text
    scoped = any(r.get("scope") not in (None, []) for r in out["rows"])
    return text + (
        f" On the plan's {len(buses)} buses ({', '.join(buses)}), each also off alone: under {out['law']} a "
        + (
            "fault must stop the joints of the buses it touches while every other bus and its amplifiers run "
            "on (bench.fault_scope)."
            if scoped
            else "fault anywhere must stop every joint (the law reads every joint and the tip sensors)."
        )
    )


def summary_markdown(out: dict, table: str) -> str:
    """The report's paragraph: what was run, the worst figures, the failing cases (if any).

    Parameters
    ----------
    out : dict
        What :func:`smartjoint.bench.safety.fault_matrix` returned.
    table : str
        The file of the full table (linked).

    Returns
    -------
    str
        Markdown.
    """

    timings = sorted({r["timing"] for r in out["rows"]})
    replays = sum(r["case"].startswith("replay ") for r in out["rows"])
    ages = f"{min(REPLAY_AGES)} to {max(REPLAY_AGES)}"
    replayed = f" ({replays} of them seamless replays of a frame, {ages} cycles old)" if replays else ""
    lines = [
        _heading(out),
        "",
        f"{out['cases']} cases{replayed} — every fault kind on every frame, every implausible signal, every amplifier "
        f"fault and the bus off, timed {', '.join(timings)}. Worst cycles until the safe state holds: "
        f"firmware {_cell(out['worst_firmware'])}, the force at every joint {_cell(out['worst_joints'])} (limit "
        f"{DETECTION_LIMIT}); worst recovery {_cell(out['worst_recovery'])} cycles after a fault ends. "
        + (
            "Every case passes."
            if not out["failed"]
            else f"**{len(out['failed'])} cases fail:** " + "; ".join(out["failed"][:20]) + "."
        )
        + _buses_sentence(out)
        + f" All cases: [{table}]({table}).",
        "",
    ]
    return "\n".join(lines)


def plot_matrix(out: dict, path):
    """Plot safety_cycles.png: how many cases reach the safe state or recover after how many cycles.

    Parameters
    ----------
    out : dict
        What :func:`smartjoint.bench.safety.fault_matrix` returned.
    path : path
        The figure file.

    Returns
    -------
    path
        ``path``.
    """
    plt = figures.pyplot()
    checked = [r for r in out["rows"] if not r["tolerated"] and r.get("observable", True)]
    fig, ax = plt.subplots(figsize=(7, 3.4))
    width = 0.27
    for offset, key, label in (
        (-width, "firmware", "firmware safe"),
        (0.0, "joints", "F_safe at every joint"),
        (width, "recovery", "recovered after the fault"),
    ):
        values = [r[key] for r in checked if r[key] is not None]
        if not values:
            continue
        counts = np.bincount(values)
        ax.bar(np.arange(counts.size) + offset, counts, width, label=f"{label} ({len(values)} cases)")
    ax.axvline(DETECTION_LIMIT + 0.5, color="k", lw=0.8, ls="--")
    ax.text(DETECTION_LIMIT + 0.55, ax.get_ylim()[1] * 0.9, "limit", fontsize=8)
    ax.set_xlabel("controller cycles after the fault (or its end, for recovery)")
    ax.set_ylabel("cases")
    ax.set_title(f"{out['cases']} fault cases on the SIL bench ({out['law']})")
    ax.legend(fontsize=8)
    figures.save(fig, path, dpi=110)
    return path
