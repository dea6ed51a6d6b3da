"""The calibration and measurement demonstration of the SIL and PIL reports (docs/xcp.md): the
study with pyxcp measuring every scalar of the A2L by DAQ at every sample and calibrating the
law's boundary layer at t = 1 s, judged against a MIL law that switches at the same sample.

Per run: the A2L of the image (SIL: the host library's symbol values; PIL: the linked target
image's), the DAQ measurement as MF4 with the A2L's units, DTOs lost (the slave's overrun counter
and the time stamps), and the MIL replay: the law's Python reference fed the inputs the firmware
decoded (its DAQ'd raw values, decoded as the DBC says), restarted wherever the firmware leaves
its safe state, its boundary layer switched to the downloaded value at the same sample. The
double build equals it bit for bit; the float build lies within ``FLOAT_BOUND`` · (F^max − F^min).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from smartjoint.bench import xcp_master
from smartjoint.bench.fmu_check import FLOAT_BOUND
from smartjoint.bench.xcp_port import XcpLoop, XcpPort, sil_description, target_description
from smartjoint.common import figures, law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control import study as closed_loop
from smartjoint.design.plant.interface import Measurements
from smartjoint.design.structure.description import Xcp

SWITCH_TIME = 1.0  # [s]: when the DOWNLOAD lands (half the study, when that is shorter)
# The laws with a boundary layer to calibrate (their Setting "boundary_layer").
CALIBRATED = tuple(
    law.name for law in law_registry.LAWS.values() if any(s.key == "boundary_layer" for s in law.settings)
)
FACTOR = 3.0  # the boundary layer after the DOWNLOAD, as a multiple of the design's


def daq_entries(description, odts: int = 4, entries: int = 32) -> list[tuple[str, int, str]]:
    """The scalar measurements of the A2L, in its order, as many as one DAQ list of the slave
    holds for certain: ``entries`` entries and ``odts`` ODTs of 59 bytes (the first ODT's time
    stamp counted in every one); (name, address, pyxcp type) each."""
    chosen: list[tuple[str, int, str]] = []
    size = 0
    for name, m in description.measurements.items():
        width = int(np.dtype(xcp_master.NUMPY_TYPES[xcp_master.A2L_TYPES[m.datatype]]).itemsize)
        if m.count != 1 or len(chosen) == entries or size + width > odts * 59:
            continue
        chosen.append((name, m.address, xcp_master.A2L_TYPES[m.datatype]))
        size += width
    return chosen


def demo(setup, artifact, folder, progress=print, law: str | None = None, real: str = "float", network=None,
         xcp: Xcp | None = None) -> dict:  # fmt: skip
    """The SIL report's XCP run: the fault-matrix law (default) in the shipped float build, its A2L,
    MF4 and plot in ``folder``; the figures (JSON-ready)."""
    from smartjoint.bench.firmware import Firmware

    law = law or law_registry.fault_matrix_law().name
    image = Firmware(artifact, law, real, xcp=xcp or Xcp(), network=network)
    return json_ready(calibration_study(setup, image, law, real, "smartjoint-xcp", folder, progress))


def _tunables(description, law: str) -> list:
    """The law's boundary layer(s) on the page, in page order (contiguous: one DOWNLOAD)."""
    found = [c for name, c in description.characteristics.items() if name.startswith(f"{law}.boundary_layer")]
    if not found:
        raise ModelError(f"law: {law!r} — it has no boundary layer to calibrate ({', '.join(CALIBRATED)} have)")
    return sorted(found, key=lambda c: c.address)


def _mil_switching(artifact, law: str, description, recorded, switch: int, new: list[float]) -> np.ndarray:
    """The law's Python reference on the inputs the firmware decoded, its boundary layer switched
    to ``new`` at sample ``switch`` (NaN where the firmware held the safe state)."""
    reference = law_registry.law(law).python_reference(artifact)
    joints = list(artifact.joint_names)

    def decoded(name):
        m = description.measurements[name]
        return recorded.column(name).astype(float) * m.factor + m.offset

    def by_joint(field):
        return np.stack([decoded(f"{field}.{j}") for j in joints], axis=1)

    sensors = np.stack([decoded(f"sensor.{s}") for s in artifact.sensor_names], axis=1)
    v, f, n = by_joint("sliding_velocity"), by_joint("friction_force"), by_joint("normal_force")
    safe = recorded.column("safe")
    out, held = np.full((len(safe), len(joints)), np.nan), True
    for k in range(len(safe)):
        if k == switch:
            layer = np.asarray(reference.boundary_layer, dtype=float)
            reference.boundary_layer = np.array(new) if layer.ndim else float(new[0])
        if safe[k]:
            held = True
            continue
        if held:
            reference.reset()
            held = False
        out[k] = reference.step(Measurements(k * artifact.sample_time, sensors[k], v[k], f[k], n[k]))
    return out


def _scripts(master, policy, seen: dict, address: int, new: list[float], real: str):
    """The master's three scripts: start (connect, identify, unlock, DAQ on), calibrate (one
    DOWNLOAD of the new boundary layers at ``address``) and stop (DAQ off, disconnect)."""

    def start():
        master.__enter__()
        master.connect()
        seen["epk"] = master.identifier(0)
        master.cond_unlock()
        policy.setup()
        policy.start()

    def calibrate():
        master.setMta(address)
        master.download(b"".join(struct.pack("<f" if real == "float" else "<d", value) for value in new))

    def stop():
        policy.stop()
        master.disconnect()
        master.__exit__(None, None, None)

    return start, calibrate, stop


def calibration_study(setup, image, law: str, real: str, channel: str, folder=None, progress=print,
                      log_path=None) -> dict:  # fmt: skip
    """The study with DAQ of every scalar measurement and the law's boundary layer × 3 at t = 1 s.

    Parameters
    ----------
    setup : study.StudySetup
    image : bench.firmware.Firmware or bench.pil.TargetFirmware
        Built with its XCP slave, running ``law``.
    law : str
        A law of :data:`CALIBRATED`.
    real : str
        The image's scalar type.
    channel : str
        The python-can channel stem of the loop (the XCP bus is ``<channel>.xcp``).
    folder : path, optional
        Where ``<name>.a2l`` and ``<name>_daq.mf4`` go (name ``xcp_<sil|pil>_<law>``).
    progress : callable
    log_path : path, optional
        The bench log of the run: the control buses' frames and, on the channel after them, XCP's.

    Returns
    -------
    dict
        The figures (JSON-ready) and, under ``"recorded"``/``"description"``, the measurement.
    """
    from smartjoint.bench.sil import run_loop

    artifact = image.artifact
    pil = not hasattr(image, "library")
    description = target_description(image) if pil else sil_description(image)
    entries = daq_entries(description, image.xcp_plan.odts, image.xcp.daq_entries)
    tunables = _tunables(description, law)
    new = [float(np.float32(FACTOR * c.value)) if real == "float" else FACTOR * c.value for c in tunables]
    switch = int(round(min(SWITCH_TIME, 0.5 * setup.duration) / artifact.sample_time))
    app = xcp_master.application(artifact, image.xcp, channel=f"{channel}.xcp", timeout=5.0)
    policy = xcp_master.recorder("sample", entries)
    seen: dict = {}
    start, calibrate, stop = _scripts(xcp_master.master(app, policy), policy, seen, tunables[0].address, new, real)
    port = XcpPort(image, channel=f"{channel}.xcp")
    loop = XcpLoop(image, port, {0: start, switch: calibrate}, excitation_end=closed_loop.PULSE_DURATION,
                   channel=channel, log_path=log_path)  # fmt: skip
    progress(f"      {law}: XCP on the {'target' if pil else 'SIL firmware'}: DAQ of {len(entries)} signals, "
             f"the boundary layer × {FACTOR:g} by DOWNLOAD at t = {switch * artifact.sample_time:g} s …")  # fmt: skip
    result = run_loop(setup, loop)
    with port:
        port.serve(stop)
    out = _figures(setup, image, law, real, policy.recorded, description, switch, tunables, new, loop, result)
    out.update(where="PIL (mps2-an386)" if pil else f"SIL ({real})", epk=seen.get("epk"), signals=len(entries))
    if folder is not None:
        out.update(_files(out, Path(folder), f"xcp_{'pil' if pil else 'sil'}_{law}"))
    return out


def _figures(setup, image, law, real, recorded, description, switch, tunables, new, loop, result) -> dict:
    """What a calibration study shows: DAQ completeness and the commands against MIL switching."""
    artifact = image.artifact
    pil = not hasattr(image, "library")
    mil = _mil_switching(artifact, law, description, recorded, switch, new)
    unswitched = _mil_switching(artifact, law, description, recorded, switch, [c.value for c in tunables])
    commands = np.stack([recorded.column(f"command.{j}") for j in artifact.joint_names], axis=1).astype(float)
    compared = ~np.isnan(mil[:, 0])
    span = float(np.min(np.asarray(artifact.normal_force_max) - np.asarray(artifact.normal_force_min)))
    deviation = float(np.max(np.abs(mil[compared] - commands[compared]))) if compared.any() else float("nan")
    stamps = np.diff(np.asarray(recorded.time_us, dtype=np.int64))
    samples = int(round(setup.duration / artifact.sample_time))
    gaps = int(np.sum(stamps // int(round(artifact.sample_time * 1e6)) - 1))  # samples between two DTO sets
    return {
        "bus": image.xcp_plan.row(),
        "law": law,
        "samples": samples,
        "daq_samples": len(recorded.rows),
        "lost_samples": gaps + samples - len(recorded.rows),
        "overruns": None if pil else int(image.xcp_overruns),
        "switch_sample": switch,
        "boundary_layer": {"before": [c.value for c in tunables], "after": new, "unit": tunables[0].unit},
        "mil_samples_compared": int(compared.sum()),
        "mil_deviation": deviation,
        "mil_bound": 0.0 if real == "double" else FLOAT_BOUND * span,
        "mil_equal": bool(deviation == 0.0) if real == "double" else bool(deviation <= FLOAT_BOUND * span),
        "unswitched_deviation_after": float(np.nanmax(np.abs(unswitched[switch:] - commands[switch:]))),
        "energy_measure": float(np.trapezoid(2.0 * result.energy, result.time)),
        "commands_equal_record": bool(np.array_equal(commands, np.array(loop.record.command, dtype=commands.dtype))),
        "step_instructions": image.measurements()["step"]["instructions_mean"] if pil else None,
        "recorded": recorded,
        "description": description,
        "result": result,
    }


def _files(out: dict, folder: Path, name: str) -> dict:
    """The A2L, the MF4 and the plot of a calibration study in ``folder``."""
    from smartjoint.codegen import output

    folder.mkdir(parents=True, exist_ok=True)
    output.write({f"{name}.a2l": out["description"].text}, folder)
    what = f"{out['where']}: {out['law']}, boundary layer × {FACTOR:g} at sample {out['switch_sample']}"
    mf4 = xcp_master.write_mf4(out["recorded"], out["description"], folder / f"{name}_daq.mf4", comment=what)
    plot = plot_calibration(out, folder / f"{name}.png")
    return {"a2l": f"{name}.a2l", "mf4": mf4.name, "plot": plot.name}  # beside the report or the plots


def plot_calibration(out: dict, path) -> Path:
    """The commanded F_N of the first joint as DAQ measured it, the boundary layer's step marked."""
    plt = figures.pyplot()
    recorded = out["recorded"]
    t = (np.asarray(recorded.time_us, dtype=float) - recorded.time_us[0]) * 1e-6
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 4.4), sharex=True)
    joint = next(n for n in recorded.names if n.startswith("command."))
    top.plot(t, recorded.column(joint), lw=0.6, color="tab:blue", label=f"{joint} (DAQ)")
    top.axvline(out["switch_sample"] * (t[1] - t[0]) if len(t) > 1 else 0.0, color="k", ls="--", lw=0.8)
    top.set_ylabel("F_N [N]")
    top.legend(fontsize=8, loc="upper right")
    switched = out["switch_sample"] * (t[1] - t[0]) if len(t) > 1 else 0.0
    top.set_title(f"XCP on the {out['where']}: boundary layer × {FACTOR:g} by DOWNLOAD at t = {switched:g} s")
    layer = np.where(np.arange(len(t)) < out["switch_sample"], out["boundary_layer"]["before"][0],
                     out["boundary_layer"]["after"][0])  # fmt: skip
    bottom.step(t, layer, where="post", color="tab:red")
    bottom.set_ylabel(f"ε [{out['boundary_layer']['unit']}]")
    bottom.set_xlabel("t [s]")
    figures.save(fig, Path(path), dpi=110)
    return Path(path)


def xcp_markdown(runs: list[dict]) -> str:
    """The report's XCP section: per run the DAQ and the calibration against MIL."""
    lines = [
        "## XCP: measurement and calibration on the running firmware",
        "",
        "pyxcp connects to the firmware's XCP slave, measures every scalar of the A2L by DAQ at every sample, "
        f"and multiplies the law's boundary layer by {FACTOR:g} with one DOWNLOAD at t = {SWITCH_TIME:g} s (half a "
        "shorter study). The MIL "
        "column feeds the law's Python reference the inputs the firmware decoded and switches it at the same "
        "sample (docs/xcp.md).",
        "",
        "| where | law | DAQ signals | samples (lost) | ε before → after | max \\|ΔF_N\\| vs MIL switching (bound) | "
        "without the switch | E(t_e) |",
        "|---|---|---:|---:|---|---:|---:|---:|",
    ]
    for r in runs:
        layer = r["boundary_layer"]
        lines.append(
            f"| {r['where']} | {r['law']} | {r['signals']} | {r['daq_samples']} ({r['lost_samples']}) | "
            f"{layer['before'][0]:.3g} → {layer['after'][0]:.3g} {layer['unit']} | {r['mil_deviation']:.3g} N "
            f"({r['mil_bound']:.3g}) {'✔' if r['mil_equal'] else '✘'} | {r['unswitched_deviation_after']:.3g} N | "
            f"{r['energy_measure']:.4g} J·s |"
        )
    lines += ["", "The XCP bus (`design.network.xcp_bus`: per sample one command and its answer and every ODT, "
              "64-byte frames, worst-case stuffing):", "",
              "| bus | bit rates | joints | frames | setpoints | worst-case load (limit) | busy per sample |",
              "|---|---|---|---:|---|---:|---:|", *sorted({r["bus"] for r in runs})]  # fmt: skip
    for r in runs:
        if r.get("a2l"):
            lines.append(f"\n{r['where']}: [A2L]({Path(r['a2l']).name}), [DAQ (MF4)]({Path(r['mf4']).name}), "
                         f"![calibration]({Path(r['plot']).name})")  # fmt: skip
    return "\n".join(lines) + "\n"


def json_ready(out: dict) -> dict:
    """A calibration study's figures without its arrays."""
    return {k: v for k, v in out.items() if k not in ("recorded", "description", "result")}


__all__ = [
    "CALIBRATED",
    "FACTOR",
    "SWITCH_TIME",
    "calibration_study",
    "daq_entries",
    "demo",
    "json_ready",
    "plot_calibration",
    "xcp_markdown",
]
