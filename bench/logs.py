"""CAN bench logs: record any python-can bus, read a log with everything it had to skip counted,
decode it to signals with the DBC, write and plot them. Replaying a log through the firmware is
``bench/replay.py``.

Formats are python-can's (by file suffix: .blf, .asc, .mf4, .csv, .log, .trc …), so logs open in
the tools engineers already use; ``can.logconvert`` converts between them.
"""

from __future__ import annotations

import csv
import math
import re
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO, cast

import numpy as np

from smartjoint.bench import e2e
from smartjoint.common import figures, output_path
from smartjoint.common.errors import ModelError


def record(bus, path, duration: float | None = None, max_bytes: int = 0, stop=None, progress=None) -> dict:
    """Write every frame of a bus to a log file until a time passes, ``stop()`` says so or Ctrl-C.

    The writer is stopped (flushed, closed) whatever happens, so nothing beyond the last flush
    is lost.

    Parameters
    ----------
    bus : can.BusABC
        Any python-can bus.
    path : path
        The log file; its suffix chooses the format (.blf, .asc, .mf4, .csv, .log, .trc).
    duration : float, optional
        Seconds to record; None: until ``stop`` or Ctrl-C.
    max_bytes : int
        With > 0 the file rotates at that size (python-can SizedRotatingLogger).
    stop : callable, optional
        ``stop()`` returns True to end the recording.
    progress : callable, optional
        ``progress(message)`` hears how many frames were written.

    Returns
    -------
    dict
        What was recorded (frames, seconds, the file).

    Raises
    ------
    ModelError
        A suffix python-can does not write, or MF4 without asammdf.
    """
    import can

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        writer = can.SizedRotatingLogger(str(path), max_bytes=max_bytes) if max_bytes > 0 else can.Logger(str(path))
    except ValueError as error:
        raise ModelError(
            f"log file {path}: {error} — use a suffix python-can writes (.blf, .asc, .mf4, .csv, .log, .trc)"
        ) from None
    except (ImportError, NotImplementedError) as error:  # .mf4 needs asammdf
        raise ModelError(
            f"log file {path}: {error} — `pip install 'smartjoint[mf4]'` (asammdf) for MF4, or use .blf / .asc"
        ) from None
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
_STRUCTURE = re.compile(
    r"\s*($|//|begin\s+triggerblock|end\s+triggerblock|\d+\.\d+\s+start\s+of\s+measurement)", re.IGNORECASE
)
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
        return {
            "frames": len(self.messages),
            "truncated": self.truncated,
            "unparseable_lines": self.unparseable_lines,
            "first_unparseable": self.first_unparseable,
            "cut_frames": self.cut_frames,
            "non_finite_times": self.non_finite_times,
            "negative_times": self.negative_times,
            "backwards_times": self.backwards_times,
            "error_frames": self.error_frames,
            "remote_frames": self.remote_frames,
        }

    def problem(self) -> str | None:
        """One line naming every kind of damage with its count, or None for a clean log."""
        parts = [f"truncated: {self.truncated}"] if self.truncated else []
        if self.unparseable_lines:
            parts.append(f"{self.unparseable_lines} unparseable line(s) skipped (first: {self.first_unparseable})")
        for count, what in (
            (self.cut_frames, "frame(s) cut short"),
            (self.non_finite_times, "non-finite time stamp(s)"),
            (self.negative_times, "negative time stamp(s)"),
            (self.backwards_times, "time stamp(s) earlier than the frame before"),
        ):
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
            for message in can.ASCReader(cast(TextIO, source)):  # the reader only iterates its file
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
    """All frames of a log with what had to be skipped, counted by kind.

    Parameters
    ----------
    path : path
        The log file (ASC read line by line, other formats through python-can's LogReader).

    Returns
    -------
    LogContent
        The frames and the damage found.

    Raises
    ------
    ModelError
        The file does not exist or cannot be opened.
    """
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
        out.truncated = (
            f"{path.stat().st_size} of {size} bytes, the reader stopped after {len(out.messages)} of {expected} frames"
        )
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
    """All frames of a log and, if it is damaged, a line saying what was skipped.

    Parameters
    ----------
    path : path
        The log file.

    Returns
    -------
    tuple of (list of can.Message, str or None)
        The frames and :meth:`LogContent.problem`.
    """
    content = load(path)
    return content.messages, content.problem()


@dataclass
class Decoded:
    """Signal values of a decoded log and the frames it skipped, counted by kind."""

    rows: list = field(default_factory=list)  # (time, frame, signal, value)
    units: dict = field(default_factory=dict)  # (frame, signal) -> the DBC's unit, where it gives one
    frames: int = 0
    unknown_ids: dict = field(default_factory=lambda: defaultdict(int))
    wrong_length: dict = field(default_factory=lambda: defaultdict(int))
    bad_e2e: dict = field(default_factory=lambda: defaultdict(int))
    # Frames the DBC gives no signals (XCP_CMD, XCP_RES: their layout is XCP's): counted, not decoded.
    without_signals: dict = field(default_factory=lambda: defaultdict(int))
    error_frames: int = 0
    remote_frames: int = 0
    non_finite_times: int = 0
    problem: str | None = None
    log: dict | None = None  # LogContent.skipped() of the file

    def skipped(self) -> int:
        """Frames not decoded, whatever the reason."""
        return (
            sum(self.unknown_ids.values())
            + sum(self.wrong_length.values())
            + sum(self.bad_e2e.values())
            + self.error_frames
            + self.remote_frames
            + self.non_finite_times
        )

    def summary(self) -> dict:
        """The counts as a JSON-ready dict."""
        return {
            "frames": self.frames,
            "signal_values": len(self.rows),
            "frames_skipped": self.skipped(),
            "unknown_ids": {f"0x{k:03X}": v for k, v in sorted(self.unknown_ids.items())},
            "wrong_length": dict(self.wrong_length),
            "bad_e2e": dict(self.bad_e2e),
            "frames_without_signals": dict(self.without_signals),
            "error_frames": self.error_frames,
            "remote_frames": self.remote_frames,
            "non_finite_times": self.non_finite_times,
            "log_problem": self.problem,
            "log": self.log,
        }


def _by_bus(db, bus_names) -> list[tuple[str | None, dict]]:
    """Per bus: the label its frames get where a name is on several buses, and its frames by id."""
    databases = list(db) if isinstance(db, (list, tuple)) else [db]
    names = list(bus_names) if bus_names is not None else [str(b) for b in range(len(databases))]
    if len(names) != len(databases):
        raise ModelError(f"bus names: {names} — one per database ({len(databases)})")
    return [
        (None if len(databases) == 1 else names[b], {m.frame_id: m for m in d.messages})
        for b, d in enumerate(databases)
    ]


def decode(messages, db, problem: str | None = None, bus_names=None) -> Decoded:
    """Signals of every frame the DBC knows, skipping and counting the rest by kind.

    Skipped: unknown identifier (on its bus), wrong length, bad CRC, error and remote frames,
    frames without a finite time stamp.

    Parameters
    ----------
    messages : list of can.Message or LogContent
        The frames (a ``LogContent`` carries its damage along).
    db : cantools.database.can.Database or list of them
        The bus, or one database per bus of a plan: a frame's bus is its log channel (0, 1, …,
        as ``smartjoint sil`` writes them). A frame whose name is on several buses (the
        heartbeat) is labelled ``NAME@bus``.
    problem : str, optional
        What reading the log found damaged.
    bus_names : sequence of str, optional
        The buses' names for those labels (default their indices).

    Returns
    -------
    Decoded
        (time, frame, signal, value) rows, the signals' units and the counts.
    """
    out = Decoded(problem=problem)
    if isinstance(messages, LogContent):
        out.problem, out.log, messages = problem or messages.problem(), messages.skipped(), messages.messages
    buses = _by_bus(db, bus_names)
    shared = Counter(m.name for _, known in buses for m in known.values())
    label = lambda bus, name: name if bus is None or shared[name] == 1 else f"{name}@{bus}"  # noqa: E731
    out.units = {(label(b, m.name), s.name): s.unit for b, k in buses for m in k.values() for s in m.signals if s.unit}
    fresh = e2e.LogFreshness(
        (f for _, k in buses for f, m in k.items() if any(s.name == "sync" for s in m.signals)),
        next((m.cycle_time / 1000.0 for _, k in buses for m in k.values() if m.cycle_time), None),
    )
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
        channel = message.channel if len(buses) > 1 else 0
        bus, known = buses[channel] if isinstance(channel, int) and 0 <= channel < len(buses) else (None, {})
        m = known.get(message.arbitration_id)
        if m is None:
            out.unknown_ids[message.arbitration_id] += 1
            continue
        if not m.signals:
            out.without_signals[label(bus, m.name)] += 1
            continue
        data = bytes(message.data)
        if len(data) != m.length:
            out.wrong_length[m.name] += 1
            continue
        if not fresh.crc_ok(m.frame_id, data, float(message.timestamp)):
            out.bad_e2e[m.name] += 1
            continue
        for name, value in m.decode(data, decode_choices=False).items():
            out.rows.append((float(message.timestamp), label(bus, m.name), name, float(value)))
    return out


def write_csv(decoded: Decoded, path) -> None:
    """Write decoded signals as CSV (time_s, frame, signal, value), through a temporary sibling.

    Parameters
    ----------
    decoded : Decoded
        What :func:`decode` returned.
    path : path
        The CSV file.
    """
    with output_path.writing(path) as stream:
        writer = csv.writer(stream)
        writer.writerow(["time_s", "frame", "signal", "value"])
        for row in decoded.rows:
            writer.writerow([repr(row[0]), row[1], row[2], repr(row[3])])


def plot(decoded: Decoded, folder, frames=None) -> list[Path]:
    """One PNG per frame with its physical signals over time in the DBC's units (E2E bytes left out;
    a TIP_SENSORS signal in m or m/s by its sensor's quantity).

    Parameters
    ----------
    decoded : Decoded
        What :func:`decode` returned.
    folder : path
        Where the figures go (created if missing).
    frames : iterable of str, optional
        Only these frames.

    Returns
    -------
    list of Path
        One ``<frame>.png`` per frame drawn, in the frames' alphabetical order.
    """
    plt = figures.pyplot()
    folder = figures.folder_for(folder)
    series: defaultdict[str, defaultdict[str, list]] = defaultdict(lambda: defaultdict(list))
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
            unit = decoded.units.get((frame, signal))
            ax.set_ylabel(f"{signal} [{unit}]" if unit else signal, fontsize=7)
        axes[-1, 0].set_xlabel("t [s]")
        axes[0, 0].set_title(frame)
        path = folder / f"{frame}.png"
        figures.save(fig, path, dpi=100)
        written.append(path)
    return written
