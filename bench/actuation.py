"""The actuation check seen from the SIL bench: when a fault past the amplifier (a joint that gets
less force than driven while its amplifier reports healthy, ``bench.amplifier.SILENT_FAULTS``)
shows in the measured F_N, and when the firmware's heartbeat names the joint (docs/safety.md).
``bench.safety.measure`` judges a case with it."""

from __future__ import annotations

import numpy as np

from smartjoint.bench.amplifier import SILENT_FAULTS


def silent_fault(fault) -> bool:
    """Whether ``fault`` (a ``bench.faults.Fault``) acts past the amplifier, which reports healthy:
    nothing is to stop, the actuation check is to name the joint."""
    return fault.kind == "amplifier" and fault.amplifier_fault in SILENT_FAULTS


def actuation_figures(record, faults, artifact, limit: int) -> dict | None:
    """The actuation check's figures for the faults past the amplifier (``SILENT_FAULTS``) of a
    case; None when it has none.

    A joint's force over sample i reaches the firmware at step i + 1; it falls short where it lies
    more than the artefact's ``actuation_tolerance`` below the least of the commands of steps i,
    i − 1, i − 2 (0 before the first), while its amplifier holds no safe force of its own — the
    firmware's rule (codegen/templates/can.c.j2, ``check_actuation``). Returns ``shows`` (the first
    of two short samples in a row, None: never, e.g. commands within the tolerance), ``actuation`` (cycles from it
    until the firmware's heartbeat names the joint), ``named`` (the joints it ever named) and
    ``ok``: named within ``limit`` cycles where it shows, and no other joint named.
    """
    silent = [f for f in faults if silent_fault(f)]
    if not silent:
        return None
    dt = float(artifact.sample_time)
    joints = [j.upper() for j in artifact.joint_names]
    force = np.array(record.amplifier_force, dtype=float)
    command = np.array(record.command, dtype=float)
    own_safe = np.array(record.amplifier_safe, dtype=bool)
    failed = np.array(record.failed, dtype=bool).reshape(len(force), -1)
    earlier = np.vstack([np.zeros((2, command.shape[1])), command])
    least = np.minimum(np.minimum(earlier[2:], earlier[1:-1]), earlier[:-2])
    short = (force < least - np.asarray(artifact.actuation_tolerance, dtype=float)) & ~own_safe
    short[1:] &= short[:-1]  # two short samples in a row (the firmware's ACTUATION_FRAMES), marked at the second
    faulted = sorted({joints.index(f.target.upper()) for f in silent})
    start = min(int(round(f.start / dt)) for f in silent)
    shows, cycles, ok = None, None, True
    for j in faulted:
        hits = np.flatnonzero(short[start:, j])
        if not hits.size:
            continue
        first = start + int(hits[0]) - 1  # the first short sample of the pair
        named = np.flatnonzero(failed[first:, j])
        delay = int(named[0]) if named.size else None
        shows = first if shows is None else min(shows, first)
        cycles = delay if cycles is None or delay is None else max(cycles, delay)
        ok = ok and delay is not None and delay <= limit
    others = [k for k in range(len(joints)) if k not in faulted]
    ok = ok and not failed[:, others].any()
    return {
        "shows": shows,
        "actuation": cycles,
        "named": [artifact.joint_names[k] for k in np.flatnonzero(failed.any(axis=0))],
        "ok": bool(ok),
    }


__all__ = ["actuation_figures", "silent_fault"]
