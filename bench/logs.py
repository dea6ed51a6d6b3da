"""CAN bench logs: record any python-can bus, decode a log to signals with the DBC, replay the
recorded sensor frames through the firmware and compare its setpoints with the recorded ones.

Formats are python-can's (by file suffix: .blf, .asc, .mf4, .csv, .log, .trc …), so logs open in
the tools engineers already use; ``can.logconvert`` converts between them.
"""

from __future__ import annotations

import csv
import math
import re
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.bench import e2e


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


_HEADER = re.compile(r"\s*(date\s|base\s|//|(no)?\s*internal\s+events\s+logged)", re.IGNORECASE)
_EVENTS_LINE = re.compile(r"\s*(no)?\s*internal\s+events\s+logged", re.IGNORECASE)
_STRUCTURE = re.compile(r"\s*($|//|begin\s+triggerblock|end\s+triggerblock|\d+\.\d+\s+start\s+of\s+measurement)",
                        re.IGNORECASE)
_END = re.compile(r"\s*end\s+triggerblock", re.IGNORECASE)


@dataclass
class LogContent:
    """The frames of a log and everything that reading had to skip or found suspicious, by kind."""

    path: str
    messages: list = field(default_factory=list)
    truncated: str | None = None  # why the reader stopped before the end of the file
    unparseable_lines: int = 0  # ASC lines that are neither a frame nor the file's structure
    first_unparseable: str | None = None
    cut_frames: int = 0  # frames with fewer data bytes than their length says (a line cut short)
    non_finite_times: int = 0
    negative_times: int = 0
    backwards_times: int = 0  # earlier than the frame before
    error_frames: int = 0
    remote_frames: int = 0

    def skipped(self) -> dict:
        """The counts by kind (all of them, zeros included, so a report shows what was checked)."""
        return {"frames": len(self.messages), "truncated": self.truncated,
                "unparseable_lines": self.unparseable_lines, "first_unparseable": self.first_unparseable,
                "cut_frames": self.cut_frames, "non_finite_times": self.non_finite_times,
                "negative_times": self.negative_times, "backwards_times": self.backwards_times,
                "error_frames": self.error_frames, "remote_frames": self.remote_frames}

    def problem(self) -> str | None:
        """One line naming every kind of damage with its count, or None for a clean log."""
        parts = [f"truncated: {self.truncated}"] if self.truncated else []
        if self.unparseable_lines:
            parts.append(f"{self.unparseable_lines} unparseable line(s) skipped (first: {self.first_unparseable})")
        for count, what in ((self.cut_frames, "frame(s) cut short"),
                            (self.non_finite_times, "non-finite time stamp(s)"),
                            (self.negative_times, "negative time stamp(s)"),
                            (self.backwards_times, "time stamp(s) earlier than the frame before")):
            if count:
                parts.append(f"{count} {what}")
        return "; ".join(parts) or None


class _Lines:
    """Lines handed to python-can's ASCReader one at a time, so that we know which line gave
    which frame and which ones the reader passed over (it skips what it cannot match silently)."""

    def __init__(self, lines, prelude, start):
        self.lines, self.prelude, self.index = lines, list(prelude), start

    def __iter__(self):
        return self

    def __next__(self):
        if self.prelude:
            return self.prelude.pop(0)
        if self.index >= len(self.lines):
            raise StopIteration
        self.index += 1
        return self.lines[self.index - 1]

    def close(self):
        pass


def _read_asc(path: Path, out: LogContent) -> None:
    """An ASC file through python-can's ASCReader, line by line: a line it passes over is counted
    and named, a line it chokes on (it would stop there and lose the rest) is counted and the
    reading resumes after it; a file without its closing ``End TriggerBlock`` is truncated."""
    import can

    try:
        lines = path.read_text(errors="replace").splitlines(keepends=True)
    except OSError as error:
        raise ModelError(f"log file {path}: cannot read ({error.strerror})") from None
    header = 0
    while header < len(lines) and _HEADER.match(lines[header]):
        header += 1
        if _EVENTS_LINE.match(lines[header - 1]):
            break
    # python-can's header parser swallows the first line after a header without an events line.
    ended = header and _EVENTS_LINE.match(lines[header - 1])
    prelude = lines[:header] + ([] if ended else ["internal events logged\n"])

    def passed_over(first, last):
        for number in range(first, last):
            if not _STRUCTURE.match(lines[number]):
                out.unparseable_lines += 1
                if out.first_unparseable is None:
                    out.first_unparseable = f"line {number + 1}: {lines[number].strip()[:60]!r}"

    start = header
    while start < len(lines):
        source = _Lines(lines, prelude, start)
        done = source.index
        try:
            for message in can.ASCReader(source):
                passed_over(done, source.index - 1)
                out.messages.append(message)
                done = source.index
        except Exception:  # a line the reader matched but could not parse: skip it, go on after it
            passed_over(done, source.index)
            start = max(source.index, start + 1)
            continue
        passed_over(done, source.index)
        break
    last = next((line for line in reversed(lines) if line.strip()), None)
    if last is not None and not _END.match(last):
        out.truncated = f"no 'End TriggerBlock' at the end: the file stops after {len(out.messages)} frames"


def load(path) -> LogContent:
    """All frames of a log with what had to be skipped, counted by kind (``LogContent``)."""
    import can

    path = Path(path)
    if not path.exists():
        raise ModelError(f"log file {path}: not found")
    out = LogContent(str(path))
    if path.suffix.lower() == ".asc":
        _read_asc(path, out)
    else:
        _read_generic(path, out)
    _check_frames(out)
    return out


def _read_generic(path: Path, out: LogContent) -> None:
    """Any other format through python-can's LogReader; an exception ends the reading early."""
    import can

    try:
        reader = can.LogReader(str(path))
    except Exception as error:  # unknown suffix, an empty or damaged header, a missing reader package …
        raise ModelError(f"log file {path}: cannot open ({type(error).__name__}: {error})") from None
    try:
        for message in reader:
            out.messages.append(message)
    except Exception as error:  # python-can's readers raise several types on damaged files
        out.truncated = f"the reader stopped after {len(out.messages)} frames ({type(error).__name__}: {error})"
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
    if out.truncated is None and size and path.stat().st_size < size:
        out.truncated = (f"{path.stat().st_size} of {size} bytes, the reader stopped after {len(out.messages)} of "
                         f"{expected} frames")
    elif out.truncated is None and expected and len(out.messages) < expected:
        out.truncated = f"incomplete: {len(out.messages)} of {expected} frames read"


def _check_frames(out: LogContent) -> None:
    """Count what the frames themselves get wrong: time stamps, cut payloads, error/remote frames."""
    previous = -math.inf
    for message in out.messages:
        t = float(message.timestamp)
        if not math.isfinite(t):
            out.non_finite_times += 1
        else:
            if t < 0:
                out.negative_times += 1
            if t < previous:
                out.backwards_times += 1
            previous = t
        if message.is_error_frame:
            out.error_frames += 1
        elif message.is_remote_frame:
            out.remote_frames += 1
        elif (message.is_fd or message.dlc <= 8) and len(message.data) < message.dlc:
            out.cut_frames += 1


def read(path) -> tuple[list, str | None]:
    """All frames of a log and, if it is damaged, a line saying what was skipped (``load``)."""
    content = load(path)
    return content.messages, content.problem()


@dataclass
class Decoded:
    rows: list = field(default_factory=list)  # (time, frame, signal, value)
    frames: int = 0
    unknown_ids: dict = field(default_factory=lambda: defaultdict(int))
    wrong_length: dict = field(default_factory=lambda: defaultdict(int))
    bad_e2e: dict = field(default_factory=lambda: defaultdict(int))
    error_frames: int = 0
    remote_frames: int = 0
    non_finite_times: int = 0
    problem: str | None = None
    log: dict | None = None  # LogContent.skipped() of the file

    def skipped(self) -> int:
        """Frames not decoded, whatever the reason."""
        return (sum(self.unknown_ids.values()) + sum(self.wrong_length.values()) + sum(self.bad_e2e.values())
                + self.error_frames + self.remote_frames + self.non_finite_times)

    def summary(self) -> dict:
        return {"frames": self.frames, "signal_values": len(self.rows), "frames_skipped": self.skipped(),
                "unknown_ids": {f"0x{k:03X}": v for k, v in sorted(self.unknown_ids.items())},
                "wrong_length": dict(self.wrong_length), "bad_e2e": dict(self.bad_e2e),
                "error_frames": self.error_frames, "remote_frames": self.remote_frames,
                "non_finite_times": self.non_finite_times, "log_problem": self.problem, "log": self.log}


def decode(messages, db, problem: str | None = None) -> Decoded:
    """Signals of every frame the DBC knows, skipping and counting the rest by kind: unknown id,
    wrong length, bad CRC, error and remote frames, frames without a finite time stamp.
    ``messages``: a list of python-can messages or a ``LogContent`` (its damage is carried along)."""
    out = Decoded(problem=problem)
    if isinstance(messages, LogContent):
        out.problem, out.log, messages = problem or messages.problem(), messages.skipped(), messages.messages
    known = {m.frame_id: m for m in db.messages}
    for message in messages:
        out.frames += 1
        if message.is_error_frame:
            out.error_frames += 1
            continue
        if message.is_remote_frame:
            out.remote_frames += 1
            continue
        if not math.isfinite(float(message.timestamp)):
            out.non_finite_times += 1
            continue
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


def _grid_origin(times, step: float) -> float:
    """The controller sample nearest the earliest frame, on the grid whose phase is the circular
    mean of the time stamps modulo the sample time: jitter on both sides of the true sample times
    averages out (the earliest frame alone may be up to half a cycle early, which would shift
    every sample by as much)."""
    first, earliest = times[0], min(times)
    angles = [2 * math.pi * math.fmod(t - first, step) / step for t in times]
    phase = step * math.atan2(sum(map(math.sin, angles)), sum(map(math.cos, angles))) / (2 * math.pi)
    grid = first + phase
    return grid + step * math.floor((earliest - grid) / step + 0.5)


MAX_SAMPLES = 100_000_000  # ~28 h at 1 ms: beyond that a wild time stamp is likelier than a real log


def replay(messages, firmware, tolerance: float = 0.0, sample_time: float | None = None) -> dict:
    """Replay a log through ``firmware`` and compare its setpoints with the recorded ones.

    The controller samples are t0 + k·Δt, k = 0, 1, … (Δt: ``sample_time``, default the
    artefact's; t0 the sample of the earliest frame on the grid that fits all time stamps best);
    each frame belongs to its nearest sample (a rig's time stamps jitter within the cycle, the
    SIL's sit on the grid). Every sample from the first to the last is
    stepped, also those without any frame (a bus-off, a silent bus): the firmware's timeouts and
    recovery then replay exactly. Per sample the recorded sensor and amplifier frames go to
    ``rx``, then ``step``, then the ``SETPOINT_*`` frames of ``tx`` are paired with the recorded
    ones of that sample and their voltages compared.

    Only samples where the log holds a setpoint can be compared: what the firmware sent while it
    was off the bus never reached the log. So a replayed setpoint without a recorded one is
    counted (``replayed_not_recorded``, split into samples with and without other traffic) but is
    no failure; a recorded setpoint without a replayed one (``recorded_not_replayed``) is.
    Recorded setpoints that fail their length or CRC are counted and not compared.

    Raises ModelError for a log without frames the firmware's protocol knows, for time stamps
    that are not finite and for a time span beyond ``MAX_SAMPLES`` samples.
    """
    if isinstance(messages, LogContent):
        messages = messages.messages
    db = firmware.db
    known = {m.frame_id: m for m in db.messages}
    step = float(sample_time or firmware.artifact.sample_time)
    usable = [m for m in messages if not (m.is_error_frame or m.is_remote_frame)]
    bad_times = sum(1 for m in usable if not math.isfinite(float(m.timestamp)))
    if bad_times:
        raise ModelError(f"log: {bad_times} frame(s) with a time stamp that is not finite (NaN or infinite) — a "
                         "replay needs every frame on the sample grid")
    if not any(m.arbitration_id in known for m in usable):
        raise ModelError(f"log: {len(usable)} frame(s), none with an identifier of the artefact's protocol "
                         f"({', '.join(f'0x{k:03X}' for k in sorted(known))}) — nothing to replay")
    start = _grid_origin([float(m.timestamp) for m in usable], step)
    groups = defaultdict(list)
    for message in usable:
        groups[int(math.floor((float(message.timestamp) - start) / step + 0.5))].append(message)
    samples = max(groups) + 1
    if samples > MAX_SAMPLES:
        raise ModelError(f"log: time stamps span {(samples - 1) * step:.6g} s = {samples} samples of {step:g} s "
                         f"(at most {MAX_SAMPLES}) — a wild time stamp?")
    start_us = int(round(start * 1e6))
    firmware.reset()
    compared, differences, worst = 0, [], 0.0
    counts = defaultdict(int)
    unknown = 0
    for k in range(samples):
        time_us = start_us + int(round(k * step * 1e6))
        recorded = defaultdict(list)
        frames = groups.get(k, ())
        for message in frames:
            m = known.get(message.arbitration_id)
            if m is None:
                unknown += 1  # the firmware counts and rejects it, as on the bus
            elif m.name.startswith("SETPOINT_"):
                data = bytes(message.data)
                if len(data) != m.length:
                    counts["recorded_wrong_length"] += 1
                elif not e2e.check(m.frame_id, data, None).crc_ok:
                    counts["recorded_bad_crc"] += 1
                else:
                    recorded[m.name].append(m.decode(data, decode_choices=False)["voltage"])
                continue
            elif m.name == "CONTROLLER_STATUS":  # the firmware's own frame, not an input
                continue
            firmware.rx(message.arbitration_id, bytes(message.data), time_us)
        firmware.step(time_us)
        replayed = defaultdict(list)
        for frame_id, data in firmware.tx():
            m = known.get(frame_id)
            if m is not None and m.name.startswith("SETPOINT_"):
                replayed[m.name].append(m.decode(data, decode_choices=False)["voltage"])
        t = start + k * step
        for name in sorted(set(recorded) | set(replayed)):
            ours, theirs = replayed[name], recorded[name]
            for a, b in zip(ours, theirs):
                compared += 1
                deviation = abs(a - b)
                worst = max(worst, deviation)
                if not deviation <= tolerance:
                    differences.append({"time": t, "frame": name, "kind": "differs", "recorded_V": b,
                                        "replayed_V": a})
            if len(theirs) > len(ours):
                counts["recorded_not_replayed"] += len(theirs) - len(ours)
                differences.append({"time": t, "frame": name, "kind": "recorded, not replayed",
                                    "recorded_V": theirs[len(ours)], "replayed_V": None})
            elif len(ours) > len(theirs):
                key = "replayed_not_recorded_in_silent_samples" if not frames else "replayed_not_recorded"
                counts[key] += len(ours) - len(theirs)
        if not frames:
            counts["silent_samples"] += 1
    differing = sum(1 for d in differences if d["kind"] == "differs")
    out = {"samples": samples, "silent_samples": counts["silent_samples"], "setpoints_compared": compared,
           "differing": differing, "recorded_not_replayed": counts["recorded_not_replayed"],
           "replayed_not_recorded": counts["replayed_not_recorded"],
           "replayed_not_recorded_in_silent_samples": counts["replayed_not_recorded_in_silent_samples"],
           "recorded_setpoints_bad_crc": counts["recorded_bad_crc"],
           "recorded_setpoints_wrong_length": counts["recorded_wrong_length"],
           "unknown_id_frames": unknown, "max_difference_V": worst, "tolerance_V": tolerance,
           "first_differences": differences[:20]}
    out["ok"] = compared > 0 and differing == 0 and out["recorded_not_replayed"] == 0
    return out
