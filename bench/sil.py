"""The paper's study through the CAN loop (``bench/loop.py``): per law the software-in-the-loop
run of the compiled firmware against the model-in-the-loop run of the Python reference
controllers (:func:`sil_study`), a run with a sequence of injected faults (:func:`fault_run`,
:func:`demo_faults` by default), and their report tables and figures.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from smartjoint.bench import bus_rounding, firmware, rounding_spread, safety
from smartjoint.bench.faults import check_faults, demo_faults
from smartjoint.bench.loop import SilLoop
from smartjoint.bench.rounding_spread import band_cell, verdict_cell, within_band
from smartjoint.codegen import can_layer
from smartjoint.common import figures, law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design import plant
from smartjoint.design.control import study as closed_loop
from smartjoint.design.network import busload, plan


def run_loop(setup, loop: SilLoop):
    """The study's plant with the CAN loop as its controller; the buses closed whatever happens.

    Parameters
    ----------
    setup : study.StudySetup
        The plant, pulse, duration and plant step of the study.
    loop : bench.loop.SilLoop
        The CAN loop (firmware, bus, amplifier models), closed when the run ends.

    Returns
    -------
    plant result
        What ``plant.simulate`` returned; the loop keeps its record.
    """
    try:
        return plant.simulate(
            setup.plant,
            setup.laws,
            loop,
            setup.pulse(),
            setup.duration,
            setup.plant_step,
            record_every=closed_loop.PLANT_STEPS_PER_SAMPLE,
            energy_books=False,
        )
    finally:
        loop.close()


def _check_faults_against(network, artifact, faults) -> None:
    """Refuse faults that mean nothing on the artefact's buses (``network``, a plan): their
    frames, joints, signals and names."""
    db = can_layer.network_database(network)
    check_faults(
        faults,
        {m.name for m in db.messages},
        list(artifact.joint_names),
        {m.name: [s.name for s in m.signals if s.name not in ("crc", "counter")] for m in db.messages},
        [p.bus.name for p in network.buses],
    )


def _study_header(network, bitrate: int, data_bitrate: int | None, real: str, amplifier: dict | None) -> dict[str, Any]:
    """The study's figures before any run: the buses' bitrates and planned load (the busiest bus
    of the plan ``network``), the scalar type."""
    planned = max(busload.check(p.database, bitrate, data_bitrate).load for p in network.buses)
    return {
        "bitrate": bitrate,
        "data_bitrate": data_bitrate,
        "planned_bus_load": planned,
        "buses": [p.bus.name for p in network.buses],
        "real": real,
        "amplifier": dict(amplifier or {}),
        "laws": {},
    }


def _sil_run(setup, artifact, law, real, faults, log_folder, amplifier, interface, channel, network=None):
    """One law's compiled firmware through the CAN loop: the loop, the plant's result, the log path."""
    image = firmware.Firmware(artifact, law, real, network=network)
    log_path = None if log_folder is None else Path(log_folder) / f"sil_{law}.blf"
    if log_path is not None:
        log_path.parent.mkdir(parents=True, exist_ok=True)
    loop = SilLoop(
        image,
        closed_loop.PULSE_DURATION,
        faults=faults,
        interface=interface,
        channel=channel,
        log_path=log_path,
        amplifier=amplifier,
    )
    result = run_loop(setup, loop)
    return loop, result, log_path


def _law_figures(setup, artifact, faults, mil, spread, loop, result, log_path, bitrate, data_bitrate) -> dict:
    """One law's MIL against SIL figures (Eq. 32), bus statistics and injected faults' figures."""
    energy_measure = float(np.trapezoid(2.0 * result.energy, result.time))
    return {
        "energy_measure_mil": mil.energy_measure(),
        "energy_measure_sil": energy_measure,
        "energy_measure_difference": energy_measure / mil.energy_measure() - 1.0,
        "energy_end_mil": float(mil.energy[-1]),
        "energy_end_sil": float(result.energy[-1]),
        "mil_spread_under_float_rounding": [min(spread), max(spread)] if spread else None,
        "within_band": within_band(energy_measure / mil.energy_measure() - 1.0, spread),
        "max_energy_sil": float(result.energy.max()),
        "bus": loop.statistics(setup.duration, bitrate, data_bitrate),
        "log": None if log_path is None else str(log_path),
        "faults": [{"fault": f.label(), **safety.measure(loop.record, (f,), artifact)} for f in faults],
        "record": loop.record,
        "result": result,
    }


def sil_study(
    setup,
    artifact,
    laws=law_registry.NAMES,
    real: str = "float",
    faults=(),
    log_folder=None,
    amplifier: dict | None = None,
    bitrate: int = 1_000_000,
    data_bitrate: int | None = 5_000_000,
    spread_runs: int = 6,
    interface: str = "virtual",
    channel: str = "smartjoint-sil",
    progress=print,
    network=None,
) -> dict:
    """The paper's study through the CAN loop, per law against the model-in-the-loop run.

    The Python reference controllers run the study (MIL), then the compiled firmware through the
    bus and the amplifier models (SIL): E(t_e) (Eq. 32) and e(t_e) differences, bus statistics,
    and whether SIL lies in the band of MIL's own spread (``bench.rounding_spread``).

    Parameters
    ----------
    setup : study.StudySetup
        The plant, pulse and duration of the study (paper Section 6).
    artifact : ControllerArtifact
        The design artefact the firmware is generated from.
    laws : tuple of str
        ``"siso"`` and/or ``"clqg"``.
    real : str
        The firmware's scalar type.
    faults : iterable of Fault
        Faults injected in every SIL run.
    log_folder : path, optional
        Where ``sil_<law>.blf`` logs go.
    amplifier : dict, optional
        Options of the amplifier models.
    bitrate, data_bitrate : int
        The bus's nominal and CAN FD data bitrates [bit/s] (data None: classical).
    spread_runs : int
        Perturbed MIL runs of the spread (``rounding_spread.confirmed``: more for a run outside).
    interface, channel : str
        The python-can bus (a plan of several buses: channel ``<channel>.<bus name>`` each).
    progress : callable
        ``progress(message)`` hears what runs.
    network : Network, optional
        The buses (a design's ``[network]``): the firmware is built for their plan and the bench
        runs one python-can bus per bus; default the plan of one bus (its setpoints packed where that
        lowers the load).

    Returns
    -------
    dict
        The planned bus load and, per law, the MIL and SIL figures, bus statistics, the
        injected faults' figures (``safety.measure``), the SIL record and result.
    """
    planned = plan.plan(artifact, network)
    _check_faults_against(planned, artifact, faults)
    out = _study_header(planned, bitrate, data_bitrate, real, amplifier)
    steps = bus_rounding.bus_steps([p.database for p in planned.buses], artifact)
    for law in laws:
        progress(f"      {law}: model in the loop (Python reference, its inputs as the bus carries them) …")
        reference = partial(_rounded_reference, law, artifact, steps)
        mil, spread = rounding_spread.mil_runs(setup, law, reference, spread_runs)
        progress(
            f"      {law}: software in the loop ({real} firmware, CAN {bitrate / 1e6:g}"
            f"{'' if data_bitrate is None else f'/{data_bitrate / 1e6:g}'} Mbit/s) …"
        )
        loop, result, log_path = _sil_run(
            setup, artifact, law, real, faults, log_folder, amplifier, interface, channel, planned
        )
        if not faults:  # a run outside the band of a few perturbed runs is judged on more
            energy = float(np.trapezoid(2.0 * result.energy, result.time))
            spread = rounding_spread.confirmed(setup, law, reference, mil, spread, energy, progress)
        out.setdefault("mil_runs", {})[law] = mil
        out["laws"][law] = _law_figures(
            setup, artifact, faults, mil, spread, loop, result, log_path, bitrate, data_bitrate
        )
    return out


def _rounded_reference(law: str, artifact, steps):
    """A new Python reference of ``law`` that sees its inputs as the firmware does (bus_rounding)."""
    (reference,) = [entry.python_reference for entry in law_registry.LAWS.values() if entry.name == law]
    return bus_rounding.Rounded(reference(artifact), steps)


def fault_lines(rows: list) -> list[str]:
    """The table rows of injected faults (Markdown).

    Per fault: cycles to the safe state at the firmware and at the joints (the force the
    amplifiers really apply), and to recovery after its end.

    Parameters
    ----------
    rows : list of dict
        Per fault the figures of ``safety.measure`` with ``fault`` (its label).

    Returns
    -------
    list of str
        The table's lines.
    """

    def cell(value):
        return "—" if value is None else str(value)

    lines = [
        "| fault | window [cycles] | firmware safe [cycles] | joints at F_safe [cycles] | recovery [cycles] |",
        "|---|---|---:|---:|---:|",
    ]
    for r in rows:
        window = f"{r['start']}–{'∞' if r['end'] is None else r['end']}"
        note = "" if r.get("observable", True) else " (never showed)"
        note += f" (output stage of {', '.join(r['failed_output_stage'])} failed)" if r["failed_output_stage"] else ""
        lines.append(
            f"| {r['fault']}{note} | {window} | {cell(r['firmware'])} | {cell(r['joints'])} | {cell(r['recovery'])} |"
        )
    return lines


def sil_markdown(out: dict) -> str:
    """The report section of a SIL study.

    Parameters
    ----------
    out : dict
        What :func:`sil_study` returned.

    Returns
    -------
    str
        Markdown: the bus settings and planned load, one table row per law (E(t_e) of MIL and SIL,
        their difference beside the MIL spread, the bus figures), then the injected faults per law.
    """
    lines = [
        "## Software in the loop: the study through CAN (firmware + bus + amplifiers)",
        "",
        f"{out['real']} firmware, CAN FD {out['bitrate'] / 1e6:g}/{(out['data_bitrate'] or 0) / 1e6:g} Mbit/s, "
        f"planned worst-case bus load {100 * out['planned_bus_load']:.1f} %. The MIL runs see their inputs as the "
        "bus carries them (each rounded to its frame's step), as the firmware does.",
        "",
        "| law | E(t_e) MIL | E(t_e) SIL | difference | MIL spread under 6e-8 perturbations | within the band? | "
        "e(t_e) MIL / SIL | frames | bus load | E2E errors | timeouts | safe samples |",
        "|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|",
    ]
    for law, f in out["laws"].items():
        bus = f["bus"]
        spread = f["mil_spread_under_float_rounding"]
        lines.append(
            f"| {law} | {f['energy_measure_mil']:.4g} | {f['energy_measure_sil']:.4g} | "
            f"{100 * f['energy_measure_difference']:+.2f} % | {band_cell(spread)} | "
            f"{verdict_cell(f.get('within_band'), spread)} | {f['energy_end_mil']:.3g} / "
            f"{f['energy_end_sil']:.3g} | {bus['frames_total']} | {100 * bus['bus_load']:.1f} % | "
            f"{bus['e2e_errors']} | {bus['firmware']['timeouts']} | {bus['safe_samples']} |"
        )
    for law, f in out["laws"].items():
        if f.get("faults"):
            lines += ["", f"Injected faults ({law}):", ""] + fault_lines(f["faults"])
    return "\n".join(lines) + "\n"


def plot_sil(out: dict, folder, mil_runs: dict | None = None) -> list:
    """Plot sil_energy.png: e(t) of the SIL run per law (the MIL run dashed, when given).

    Parameters
    ----------
    out : dict
        What :func:`sil_study` returned.
    folder : path
        The folder of ``sil_energy.png``, created if missing.
    mil_runs : dict, optional
        Per law the MIL run.

    Returns
    -------
    list of Path
        ``sil_energy.png`` in ``folder``.
    """
    plt = figures.pyplot()
    folder = figures.folder_for(folder)
    fig, ax = plt.subplots(figsize=(7, 3.6))
    colours = dict(zip(law_registry.NAMES, ("tab:blue", "tab:red", "tab:green", "tab:purple")))
    for law, f in out["laws"].items():
        r = f["result"]
        ax.semilogy(
            r.time,
            np.maximum(r.energy, 1e-12),
            color=colours.get(law, "k"),
            lw=1.0,
            label=f"{law} SIL ({100 * f['energy_measure_difference']:+.2f} % E(t_e))",
        )
        if mil_runs and law in mil_runs:
            m = mil_runs[law]
            ax.semilogy(
                m.time, np.maximum(m.energy, 1e-12), "--", color=colours.get(law, "k"), lw=0.8, label=f"{law} MIL"
            )
        safe = np.array(f["record"].safe)
        if safe.any():
            t = np.array(f["record"].time)
            ax.plot(t[safe], np.full(int(safe.sum()), ax.get_ylim()[0] * 2), "|", color="k", ms=4, label="safe state")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("½xᵀx [J]")
    ax.set_title("Study through the CAN loop (software in the loop)")
    ax.legend(fontsize=8)
    path = folder / "sil_energy.png"
    figures.save(fig, path, dpi=110)
    return [path]


def fault_run(setup, artifact, law: str | None = None, faults=None, real: str = "float", network=None) -> dict:
    """One SIL run of the study with a sequence of faults.

    Parameters
    ----------
    setup : study.StudySetup
        The closed-loop study.
    artifact : ControllerArtifact
        The controller design artefact.
    law : str, optional
        A law of the registry by name; default the fault-matrix law (``law_registry.fault_matrix_law``).
    faults : iterable of Fault, optional
        Default :func:`demo_faults`.
    real : str
        The firmware's scalar type.
    network : Network, optional
        The buses (default one bus, one SETPOINT frame per joint); a ``bus_off`` fault may name one.

    Returns
    -------
    dict
        Per fault the figures of ``safety.measure``, the largest energy after the pulse (bounded:
        the safe state is passive), samples in the safe state, the record, result and statistics.
    """
    law = law_registry.fault_matrix_law().name if law is None else law
    faults = demo_faults(artifact, setup.duration) if faults is None else tuple(faults)
    planned = plan.plan(artifact, network)
    _check_faults_against(planned, artifact, faults)
    late = [f.label() for f in faults if not f.start < setup.duration]
    if late:  # it would never act, and its cycles could not be counted
        raise ModelError(f"faults {', '.join(late)}: start at or after the study's end t_e = {setup.duration:g} s")
    loop = SilLoop(firmware.Firmware(artifact, law, real, network=planned), closed_loop.PULSE_DURATION, faults=faults)
    result = run_loop(setup, loop)
    rows = [
        {
            "fault": f.label(),
            "kind": f.kind,
            "target": f.target or "bus",
            "start_s": f.start,
            "end_s": f.end,
            **safety.measure(loop.record, (f,), artifact),
        }
        for f in faults
    ]
    after = result.time > closed_loop.PULSE_DURATION
    return {
        "law": law,
        "faults": rows,
        "max_energy_after_pulse": float(result.energy[after].max()),
        "energy_end": float(result.energy[-1]),
        "safe_samples": int(np.sum(loop.record.safe)),
        "result": result,
        "record": loop.record,
        "statistics": loop.statistics(setup.duration, 1_000_000, 5_000_000),
    }


def fault_markdown(run: dict) -> str:
    """The report section of a fault run: the table and the run's figures.

    Parameters
    ----------
    run : dict
        A fault run, as :func:`fault_run` returns it.

    Returns
    -------
    str
        Markdown: the heading, one table row per fault (:func:`fault_lines`), then the largest
        energy after the pulse, the samples in the safe state and the firmware's error counters.
    """
    lines = [f"### Injected faults in the study (SIL, {run['law']}): safe state and recovery", ""]
    lines += fault_lines(run["faults"])
    s = run["statistics"]
    lines += [
        "",
        f"Largest energy after the pulse {run['max_energy_after_pulse']:.3g} J (bounded; e(t_e) = "
        f"{run['energy_end']:.3g} J); {run['safe_samples']} samples in the safe state; firmware counters: "
        f"CRC errors {s['firmware']['crc_errors']}, counter errors {s['firmware']['counter_errors']}, "
        f"timeouts {s['firmware']['timeouts']}, implausible frames {s['firmware']['implausible_frames']}.",
        "",
    ]
    return "\n".join(lines)


def plot_faults(run: dict, path) -> Path:
    """Plot the energy and the applied normal forces of a fault run, faults and safe state shaded.

    Parameters
    ----------
    run : dict
        A fault run, as :func:`fault_run` returns it.
    path : path
        The figure file.

    Returns
    -------
    Path
        ``path``.
    """
    plt = figures.pyplot()
    r, record = run["result"], run["record"]
    time = np.array(record.time)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 4.6), sharex=True)
    top.semilogy(r.time, np.maximum(r.energy, 1e-12), lw=0.9)
    top.set_ylabel("½xᵀx [J]")
    top.set_title("SIL with injected faults (orange), safe state (grey)")
    applied = np.array(record.amplifier_force)
    for j in range(applied.shape[1]):
        bottom.plot(time, applied[:, j], lw=0.6, label=f"F_N applied, joint {j + 1}")
    safe = np.array(record.safe)
    for ax in (top, bottom):
        for f in run["faults"]:
            ax.axvspan(f["start_s"], min(f["end_s"], time[-1]), color="tab:orange", alpha=0.25, lw=0)
        ax.fill_between(time, 0, 1, where=safe, transform=ax.get_xaxis_transform(), color="k", alpha=0.12, lw=0)
    bottom.set_xlabel("t [s]")
    bottom.set_ylabel("F_N by the amplifier [N]")
    bottom.legend(fontsize=7)
    figures.save(fig, path, dpi=110)
    return Path(path)
