"""CAN bench logs: record any python-can bus, decode a log to signals with the DBC, replay the
recorded sensor frames through the firmware and compare its setpoints with the recorded ones.

Formats are python-can's (by file suffix: .blf, .asc, .mf4, .csv, .log, .trc …), so logs open in
the tools engineers already use; ``can.logconvert`` converts between them.
"""

from __future__ import annotations

import csv
import math
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..design.errors import ModelError
from . import e2e


def record(bus, path, duration: float | None = None, max_bytes: int = 0, stop=None, progress=None) -> dict:
    """Write every frame of ``bus`` to ``path`` until ``duration`` seconds pass, ``stop()`` returns
    True or Ctrl-C; with ``max_bytes`` > 0 the file rotates (python-can SizedRotatingLogger). The
    writer is stopped (flushed, closed) whatever happens, so nothing beyond the last flush is lost."""
    import can

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        writer = can.SizedRotatingLogger(str(path), max_bytes=max_bytes) if max_bytes > 0 else can.Logger(str(path))
    except ValueError as error:
        raise ModelError(f"log file {path}: {error} — use a suffix python-can writes (.blf, .asc, .mf4, .csv, .log, "
                         ".trc)") from None
    except (ImportError, NotImplementedError) as error:  # .mf4 needs asammdf
        raise ModelError(f"log file {path}: {error} — `pip install 'smartjoint[mf4]'` (asammdf) for MF4, or use "
                         ".blf / .asc") from None
    count, started = 0, time.monotonic()
    try:
        while True:
            if duration is not None and time.monotonic() - started >= duration:
                break
            if stop is not None and stop():
                break
            message = bus.recv(timeout=0.05)
            if message is not None:
                writer.on_message_received(message)
                count += 1
                if progress and count % 10000 == 0:
                    progress(f"{count} frames")
    except KeyboardInterrupt:
        pass
    finally:
        writer.stop()
    return {"frames": count, "seconds": time.monotonic() - started, "file": str(path)}


def read(path) -> tuple[list, str | None]:
    """All frames of a log and, if it ends early (truncated or corrupted), why."""
    import can

    path = Path(path)
    if not path.exists():
        raise ModelError(f"log file {path}: not found")
    messages = []
    try:
        reader = can.LogReader(str(path))
    except Exception as error:  # unknown suffix, an empty or damaged header, a missing reader package …
        raise ModelError(f"log file {path}: cannot open ({type(error).__name__}: {error})") from None
    problem = None
    try:
        for message in reader:
            messages.append(message)
    except Exception as error:  # python-can's readers raise several types on damaged files
        problem = f"{type(error).__name__}: {error}"
    finally:
        stop = getattr(reader, "stop", None)
        if stop:
            try:
                stop()
            except Exception:
                pass
    # BLF headers carry the object count and the file size: a cut file reads short without an error.
    expected = getattr(reader, "object_count", None)
    size = getattr(reader, "file_size", None)
    if problem is None and size and path.stat().st_size < size:
        problem = f"truncated: {path.stat().st_size} of {size} bytes, {len(messages)} of {expected} frames read"
    elif problem is None and expected and len(messages) < expected:
        problem = f"incomplete: {len(messages)} of {expected} frames read"
    return messages, problem


@dataclass
class Decoded:
    rows: list = field(default_factory=list)  # (time, frame, signal, value)
    frames: int = 0
    unknown_ids: dict = field(default_factory=lambda: defaultdict(int))
    wrong_length: dict = field(default_factory=lambda: defaultdict(int))
    bad_e2e: dict = field(default_factory=lambda: defaultdict(int))
    problem: str | None = None

    def summary(self) -> dict:
        return {"frames": self.frames, "signal_values": len(self.rows),
                "unknown_ids": {f"0x{k:03X}": v for k, v in sorted(self.unknown_ids.items())},
                "wrong_length": dict(self.wrong_length), "bad_e2e": dict(self.bad_e2e), "log_problem": self.problem}


def decode(messages, db, problem: str | None = None) -> Decoded:
    """Signals of every frame the DBC knows, skipping (and counting) malformed ones: unknown id,
    wrong length, bad CRC."""
    out = Decoded(problem=problem)
    known = {m.frame_id: m for m in db.messages}
    for message in messages:
        if message.is_error_frame or message.is_remote_frame:
            continue
        out.frames += 1
        m = known.get(message.arbitration_id)
        if m is None:
            out.unknown_ids[message.arbitration_id] += 1
            continue
        data = bytes(message.data)
        if len(data) != m.length:
            out.wrong_length[m.name] += 1
            continue
        if not e2e.check(m.frame_id, data, None).crc_ok:
            out.bad_e2e[m.name] += 1
            continue
        for name, value in m.decode(data, decode_choices=False).items():
            out.rows.append((float(message.timestamp), m.name, name, float(value)))
    return out


def write_csv(decoded: Decoded, path) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".partial")
    with temporary.open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["time_s", "frame", "signal", "value"])
        for row in decoded.rows:
            writer.writerow([repr(row[0]), row[1], row[2], repr(row[3])])
    temporary.replace(path)


def plot(decoded: Decoded, folder, frames=None) -> list[Path]:
    """One PNG per frame with its physical signals over time (E2E bytes left out)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    series = defaultdict(lambda: defaultdict(list))
    for t, frame, signal, value in decoded.rows:
        if signal in ("crc", "counter"):
            continue
        series[frame][signal].append((t, value))
    written = []
    for frame in sorted(series):
        if frames and frame not in frames:
            continue
        signals = series[frame]
        fig, axes = plt.subplots(len(signals), 1, figsize=(7, 1.6 * len(signals) + 0.6), squeeze=False, sharex=True)
        for ax, (signal, points) in zip(axes[:, 0], sorted(signals.items())):
            t, v = np.array(points).T
            ax.plot(t, v, lw=0.8)
            ax.set_ylabel(signal, fontsize=7)
        axes[-1, 0].set_xlabel("t [s]")
        axes[0, 0].set_title(frame)
        fig.tight_layout()
        path = folder / f"{frame}.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        written.append(path)
    return written


def replay(messages, firmware, tolerance: float = 0.0, sample_time: float | None = None) -> dict:
    """Feed the recorded sensor and amplifier frames through ``firmware`` sample by sample and
    compare its setpoints with the recorded ``SETPOINT_*`` frames of the same sample. Frames are
    grouped per controller sample (default: the artefact's sample time), counted from the first
    frame: a rig's time stamps jitter within a sample, the SIL's sit on the grid."""
    db = firmware.db
    names = {m.frame_id: m.name for m in db.messages}
    step = float(sample_time or firmware.artifact.sample_time)
    usable = [m for m in messages if not (m.is_error_frame or m.is_remote_frame)]
    start = min((float(m.timestamp) for m in usable), default=0.0)
    groups = defaultdict(list)
    for message in usable:
        groups[start + step * math.floor((float(message.timestamp) - start) / step + 0.5)].append(message)
    firmware.reset()
    compared, differences, worst = 0, [], 0.0
    for t in sorted(groups):
        time_us = int(round(t * 1e6))
        recorded = {}
        for message in groups[t]:
            name = names.get(message.arbitration_id, "")
            if name.startswith("SETPOINT_") or name == "CONTROLLER_STATUS":
                if name.startswith("SETPOINT_") and len(message.data) == db.get_message_by_name(name).length:
                    recorded[name] = db.get_message_by_name(name).decode(bytes(message.data))["voltage"]
                continue
            firmware.rx(message.arbitration_id, bytes(message.data), time_us)
        firmware.step(time_us)
        for frame_id, data in firmware.tx():
            name = names[frame_id]
            if name in recorded:
                ours = db.get_message_by_name(name).decode(data)["voltage"]
                compared += 1
                deviation = abs(ours - recorded[name])
                worst = max(worst, deviation)
                if deviation > tolerance:
                    differences.append({"time": t, "frame": name, "recorded_V": recorded[name], "replayed_V": ours})
    return {"samples": len(groups), "setpoints_compared": compared, "differing": len(differences),
            "max_difference_V": worst, "first_differences": differences[:20]}


def parse_fault(text: str):
    """``kind:target:start:end[:detail]`` → sil.Fault (detail: the amplifier fault or the delay [s])."""
    from .sil import Fault

    parts = text.split(":")
    if len(parts) not in (4, 5):
        raise ModelError(f"--fault {text!r}: expected kind:target:start:end[:detail], e.g. drop:JOINT_A1:1.0:1.2 or "
                         "amplifier:A1:1.0:1.5:over_temperature")
    kind, target = parts[0], parts[1]
    try:
        start, end = float(parts[2]), float(parts[3])
    except ValueError:
        raise ModelError(f"--fault {text!r}: start and end must be numbers [s]") from None
    detail = parts[4] if len(parts) == 5 else ""
    if kind == "delay":
        try:
            delay = float(detail) if detail else 0.005
        except ValueError:
            raise ModelError(f"--fault {text!r}: the delay must be a number [s]") from None
        if not (math.isfinite(delay) and delay > 0):
            raise ModelError(f"--fault {text!r}: the delay must be > 0 s")
        return Fault(kind, start, end, target, delay=delay)
    return Fault(kind, start, end, target, amplifier_fault=detail)
