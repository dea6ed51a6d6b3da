"""Replay a CAN log through the compiled firmware and compare its setpoints with the recorded
ones: the recorded sensor and amplifier frames go to ``rx`` on the controller's sample grid (on
their bus, for a firmware of several), the setpoint frames of ``tx`` are paired with the recorded
ones of the same sample.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field

from smartjoint.bench import e2e
from smartjoint.bench.logs import LogContent
from smartjoint.common.errors import ModelError


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


def _samples(messages, known: dict, step: float) -> tuple[float, dict, int]:
    """The usable frames of a log on the controller's sample grid: (t0, sample → frames, count)."""
    usable = [m for m in messages if not (m.is_error_frame or m.is_remote_frame)]
    bad_times = sum(1 for m in usable if not math.isfinite(float(m.timestamp)))
    if bad_times:
        raise ModelError(
            f"log: {bad_times} frame(s) with a time stamp that is not finite (NaN or infinite) — a "
            "replay needs every frame on the sample grid"
        )
    if not any(m.arbitration_id in known for m in usable):
        raise ModelError(
            f"log: {len(usable)} frame(s), none with an identifier of the artefact's protocol "
            f"({', '.join(f'0x{k:03X}' for k in sorted(known))}) — nothing to replay"
        )
    start = _grid_origin([float(m.timestamp) for m in usable], step)
    groups = defaultdict(list)
    for message in usable:
        groups[int(math.floor((float(message.timestamp) - start) / step + 0.5))].append(message)
    samples = max(groups) + 1
    if samples > MAX_SAMPLES:
        raise ModelError(
            f"log: time stamps span {(samples - 1) * step:.6g} s = {samples} samples of {step:g} s "
            f"(at most {MAX_SAMPLES}) — a wild time stamp?"
        )
    return start, groups, samples


@dataclass
class _Comparison:
    """What the replay has compared so far."""

    compared: int = 0
    worst: float = 0.0
    unknown: int = 0
    differences: list = field(default_factory=list)
    counts: defaultdict = field(default_factory=lambda: defaultdict(int))
    logged: set = field(default_factory=set)  # (bus, frame name) of every known frame in the log
    sent: set = field(default_factory=set)  # … of every frame the firmware sent in a sample with traffic
    fresh: e2e.LogFreshness = field(default_factory=e2e.LogFreshness)  # the logged frames' freshness bytes


def _bus_of(message, buses: int) -> int | None:
    """The plan's bus a logged frame was on: its log channel (0, 1, …, as ``smartjoint sil``
    writes them) when there are several, else the one bus; None: a channel of no bus."""
    if buses == 1:
        return 0
    channel = message.channel
    return channel if isinstance(channel, int) and 0 <= channel < buses else None


def _setpoints(m, data: bytes) -> dict:
    """The voltages a setpoint frame carries: ``SETPOINT_<j>.voltage`` or each ``voltage_<j>`` of a
    packed ``SETPOINTS_<J>`` frame (design.network.plan), by signal."""
    return {k: v for k, v in m.decode(data, decode_choices=False).items() if k.startswith("voltage")}


def _is_setpoint(m) -> bool:
    return m.name.startswith(("SETPOINT_", "SETPOINTS_"))


def _replay_sample(firmware, buses: list, frames, time_us: int, t: float, tolerance: float, seen: _Comparison) -> None:
    """One sample: the recorded inputs to ``rx`` (on their bus), ``step``, the replayed setpoints
    of ``tx`` paired with the recorded ones of the sample, frame by frame and signal by signal."""
    recorded = defaultdict(list)
    for message in frames:
        bus = _bus_of(message, len(buses))
        m = None if bus is None else buses[bus].get(message.arbitration_id)
        if m is None:
            seen.unknown += 1  # the firmware counts and rejects it, as on the bus
            continue
        seen.logged.add((bus, m.name))
        if _is_setpoint(m):
            data = bytes(message.data)
            if len(data) != m.length:
                seen.counts["recorded_wrong_length"] += 1
            elif not seen.fresh.crc_ok(m.frame_id, data, t):
                seen.counts["recorded_bad_crc"] += 1
            else:
                for signal, volts in _setpoints(m, data).items():
                    recorded[bus, m.name, signal].append(volts)
            continue
        elif m.name == "CONTROLLER_STATUS":  # the firmware's own frame, not an input: its cycle
            seen.fresh.crc_ok(m.frame_id, bytes(message.data), t)
            continue
        if len(buses) == 1:
            firmware.rx(message.arbitration_id, bytes(message.data), time_us)
        else:
            firmware.rx(message.arbitration_id, bytes(message.data), time_us, bus=bus)
    firmware.step(time_us)
    replayed = defaultdict(list)
    sent = firmware.tx_bus() if len(buses) > 1 else [(0, frame_id, data) for frame_id, data in firmware.tx()]
    for bus, frame_id, data in sent:
        m = buses[bus].get(frame_id)
        if m is not None and frames:
            seen.sent.add((bus, m.name))
        if m is not None and _is_setpoint(m):
            for signal, volts in _setpoints(m, data).items():
                replayed[bus, m.name, signal].append(volts)
    for key in sorted(set(recorded) | set(replayed)):
        _compare(key, replayed[key], recorded[key], bool(frames), t, tolerance, seen)
    if not frames:
        seen.counts["silent_samples"] += 1


def _compare(key, ours: list, theirs: list, heard: bool, t: float, tolerance: float, seen: _Comparison) -> None:
    """One setpoint signal of a sample: replayed ``ours`` against recorded ``theirs``."""
    _, frame, signal = key
    name = frame if signal == "voltage" else f"{frame}.{signal}"
    for a, b in zip(ours, theirs):
        seen.compared += 1
        deviation = abs(a - b)
        seen.worst = max(seen.worst, deviation)
        if not deviation <= tolerance:
            seen.differences.append({"time": t, "frame": name, "kind": "differs", "recorded_V": b, "replayed_V": a})
    if len(theirs) > len(ours):
        seen.counts["recorded_not_replayed"] += len(theirs) - len(ours)
        seen.differences.append(
            {
                "time": t,
                "frame": name,
                "kind": "recorded, not replayed",
                "recorded_V": theirs[len(ours)],
                "replayed_V": None,
            }
        )
    elif len(ours) > len(theirs):
        seen.counts["replayed_not_recorded" if heard else "replayed_not_recorded_in_silent_samples"] += len(ours) - len(
            theirs
        )


def _summary(seen: _Comparison, samples: int, tolerance: float, buses: int) -> dict:
    """What :func:`replay` returns, from what it compared (``buses``: how many)."""
    counts, differences = seen.counts, seen.differences
    differing = sum(1 for d in differences if d["kind"] == "differs")
    out = {
        "samples": samples,
        "silent_samples": counts["silent_samples"],
        "setpoints_compared": seen.compared,
        "differing": differing,
        "recorded_not_replayed": counts["recorded_not_replayed"],
        "replayed_not_recorded": counts["replayed_not_recorded"],
        "replayed_not_recorded_in_silent_samples": counts["replayed_not_recorded_in_silent_samples"],
        "recorded_setpoints_bad_crc": counts["recorded_bad_crc"],
        "recorded_setpoints_wrong_length": counts["recorded_wrong_length"],
        "unknown_id_frames": seen.unknown,
        "max_difference_V": seen.worst,
        "tolerance_V": tolerance,
        "first_differences": differences[:20],
    }
    # Sent while the bus carried traffic, never in the log (every SETPOINT_A1 or heartbeat cut out).
    out["sent_never_logged"] = sorted(
        f"{name}" + (f" (bus {bus})" if buses > 1 else "") for bus, name in seen.sent - seen.logged
    )
    # A recorded setpoint that fails its CRC is damaged, or not of the cycle its place in the log
    # says (the freshness byte): the log cannot vouch for what the firmware sent there.
    out["ok"] = (
        seen.compared > 0
        and differing == 0
        and out["recorded_not_replayed"] == 0
        and out["recorded_setpoints_bad_crc"] == 0
        and not out["sent_never_logged"]
    )
    return out


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
    Recorded setpoints that fail their length or CRC are counted and not compared; one that fails
    its CRC — checked with the freshness byte of its place in the log (``e2e.LogFreshness``) —
    fails the replay.

    Parameters
    ----------
    messages : list of can.Message or LogContent
        The recorded frames (``load`` / ``read``).
    firmware : bench.firmware.Firmware
        The compiled firmware image to replay through (reset first); one of a single bus needs
        only ``db``, ``rx``, ``step`` and ``tx``.
    tolerance : float
        Largest setpoint difference [V] that still counts as equal.
    sample_time : float, optional
        The controller sample time [s]; default the artefact's.

    Returns
    -------
    dict
        Samples, setpoints compared, differing, the counts above, the largest difference and
        the first 20 differences; ``ok`` when something was compared, nothing differs and no
        recorded setpoint failed its CRC.

    Raises
    ------
    ModelError
        A log without frames the firmware's protocol knows, time stamps that are not finite, a
        time span beyond ``MAX_SAMPLES`` samples.
    """
    if isinstance(messages, LogContent):
        messages = messages.messages
    buses = [{m.frame_id: m for m in db.messages} for db in getattr(firmware, "databases", [firmware.db])]
    known = {frame_id: m for bus in buses for frame_id, m in bus.items()}
    step = float(sample_time or firmware.artifact.sample_time)
    start, groups, samples = _samples(messages, known, step)
    start_us = int(round(start * 1e6))
    firmware.reset()
    echoes = (f for bus in buses for f, m in bus.items() if any(s.name == "sync" for s in m.signals))
    seen = _Comparison(fresh=e2e.LogFreshness(echoes, step))
    for k in range(samples):
        _replay_sample(
            firmware, buses, groups.get(k, ()), start_us + int(round(k * step * 1e6)), start + k * step, tolerance, seen
        )
    return _summary(seen, samples, tolerance, len(buses))
