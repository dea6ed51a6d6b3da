"""Render the XCP slave of the firmware (``templates/xcp.*.j2``, ``xcp_key.c.j2``; docs/xcp.md):
the calibration page of every law's tunables with the limits a DOWNLOAD must keep, the
identification (EPK), the DAQ memory and the seed & key of one artefact.

:func:`calibration_values` is the one description of the page: the C struct's values in order,
each with its name, unit and limits, from which the C slave checks a DOWNLOAD and the A2L
(``codegen.a2l``) declares its CHARACTERISTICs, so the two cannot disagree.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from smartjoint.codegen import rendering
from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control.artifact import ControllerArtifact
from smartjoint.design.network import plan, xcp_bus
from smartjoint.design.structure.description import Xcp

# Bytes of each command the slave serves (ASAM XCP 1.x; a shorter frame is ERR_CMD_SYNTAX).
COMMANDS = {
    "CONNECT": 2, "DISCONNECT": 1, "GET_STATUS": 1, "SYNCH": 1, "GET_COMM_MODE_INFO": 1, "GET_ID": 2,
    "GET_SEED": 3, "UNLOCK": 2, "SET_MTA": 8, "UPLOAD": 2, "SHORT_UPLOAD": 8, "BUILD_CHECKSUM": 8,
    "DOWNLOAD": 2, "SET_CAL_PAGE": 4, "GET_CAL_PAGE": 3, "SET_DAQ_PTR": 6, "WRITE_DAQ": 8,
    "SET_DAQ_LIST_MODE": 8, "START_STOP_DAQ_LIST": 4, "START_STOP_SYNCH": 2, "GET_DAQ_PROCESSOR_INFO": 1,
    "GET_DAQ_RESOLUTION_INFO": 1, "FREE_DAQ": 1, "ALLOC_DAQ": 4, "ALLOC_ODT": 5,
    "ALLOC_ODT_ENTRY": 6,
}  # fmt: skip
EVENT_NAME = "sample"  # the one event channel: the controller's sample


@dataclass(frozen=True)
class CalibrationValue:
    """One value of the calibration page (a ``<prefix>_real``), in struct order.

    ``law``, ``field`` and ``joint`` (None for a law-wide value) locate it in the laws' ``_params``;
    ``value`` is the design's, [``lower``, ``upper``] what a DOWNLOAD may write (in the build's
    precision, so the slave and the A2L state the same numbers)."""

    law: str
    field: str
    joint: str | None
    unit: str
    meaning: str
    value: float
    lower: float
    upper: float

    @property
    def name(self) -> str:
        """Its name in the A2L: ``<law>.<field>`` or ``<law>.<field>.<joint>``."""
        return f"{self.law}.{self.field}" + (f".{self.joint}" if self.joint is not None else "")


def _rounded(values, real: str) -> np.ndarray:
    """Values as the build holds them (float32 or float64), returned as float64."""
    return np.asarray(values, dtype=np.float32 if real == "float" else np.float64).astype(np.float64)


def calibration_values(artifact: ControllerArtifact, real: str, xcp: Xcp) -> list[CalibrationValue]:
    """The calibration page's values in struct order: per law of the registry its ``_params``
    (F_N^min, F_N^max − F_N^min per joint, then its settings), with their limits.

    F_N^min of a law lies within the joints' [F_N^min, F_N^max], its range within [0, F_N^max −
    F_N^min], a setting that is a normal force within [F_N^min, F_N^max], any other setting within
    ``xcp.calibration_decades`` decades of the design's value either side.
    """
    low = np.asarray(artifact.normal_force_min, dtype=float)
    high = np.asarray(artifact.normal_force_max, dtype=float)
    decades = 10.0 ** float(xcp.calibration_decades)
    values: list[CalibrationValue] = []

    def add(law, field, joints, unit, meaning, design, lowers, uppers):
        design, lowers, uppers = (_rounded(np.atleast_1d(v), real) for v in (design, lowers, uppers))
        for k, joint in enumerate(joints):
            values.append(CalibrationValue(law, field, joint, unit, meaning, design[k], lowers[k], uppers[k]))

    for law in law_registry.LAWS.values():
        joints = list(artifact.joint_names)
        lowest = np.asarray(getattr(artifact, law.lower_force_field()), dtype=float)
        add(law.name, "normal_force_min", joints, "N", "lowest normal force F_N,j^min", lowest, low, high)
        add(law.name, "normal_force_range", joints, "N", "F_N,j^max - F_N,j^min", high - lowest, 0 * low, high - low)
        fields = dict(law.artifact)
        for setting in law.settings:
            if setting.lower_force:
                continue  # it is normal_force_min above
            design = np.asarray(getattr(artifact, fields[setting.key]), dtype=float).reshape(-1)
            if np.any(~(design > 0)):
                raise ModelError(f"{fields[setting.key]}: {design.tolist()!r} — a tunable must be > 0 to calibrate")
            names = joints if setting.per_joint else [None]
            lowers, uppers = (low, high) if setting.normal_force else (design / decades, design * decades)
            add(law.name, setting.key, names, setting.unit, setting.meaning, design, lowers, uppers)
    return values


def _limit_tables(values: list[CalibrationValue], artifact: ControllerArtifact, real: str) -> dict:
    """The slave's limit tables: the distinct ranges, each value's range, per law the index of its
    F_N^min[0], and per joint the largest F_N^min + range: its F_N^max, or the reference page's own
    sum where the build's rounding lifts it above."""
    scalar = np.float32 if real == "float" else np.float64
    lit = lambda value: rendering.literal(value, real)  # noqa: E731
    ranges: dict[tuple[float, float], int] = {}
    what: dict[tuple[float, float], list[str]] = {}
    range_of = []
    for v in values:
        key = (v.lower, v.upper)
        range_of.append(ranges.setdefault(key, len(ranges)))
        what.setdefault(key, []).append(v.name)
    index = {(v.law, v.field, v.joint): k for k, v in enumerate(values)}
    joints = list(artifact.joint_names)
    first = [index[(law, "normal_force_min", joints[0])] for law in law_registry.LAWS]
    limits = []
    for j in range(len(joints)):
        sums = [scalar(values[f + j].value) + scalar(values[f + j + len(joints)].value) for f in first]
        limits.append(lit(max(float(scalar(artifact.normal_force_max[j])), *map(float, sums))))
    if len(ranges) > 255 or max(first) > 255:
        raise ModelError(
            f"calibration page: {len(values)} values, {len(ranges)} ranges — the slave indexes them with one "
            "byte: at most 255 ranges, each law's F_N^min within the first 256 values"
        )
    rows = [(law, [r for v, r in zip(values, range_of) if v.law == law]) for law in law_registry.LAWS]
    return {
        "ranges": [{"lower": lit(lo), "upper": lit(hi), "what": _ranged(what[(lo, hi)])} for lo, hi in ranges],
        "range_rows": rows,
        "force_sum_limit": limits,
    }


def _ranged(names: list[str]) -> str:
    """The values a range holds, for its comment: "siso.boundary_layer.A1 …" shortened by joint."""
    stems = sorted({n.rsplit(".", 1)[0] if n.count(".") > 1 else n for n in names})
    return ", ".join(stems)


def secret(artifact: ControllerArtifact, xcp: Xcp) -> tuple[int, int, int, int]:
    """The 128-bit key of the seed & key algorithm as four 32-bit words: ``xcp.key`` (32 hex
    digits), else the first 16 bytes of SHA-256 over the artefact's hash, so each artefact has its own."""
    if xcp.key is not None:
        raw = bytes.fromhex(xcp.key)
    else:
        raw = hashlib.sha256(f"smartjoint-xcp-key:{artifact.artifact_sha256}".encode()).digest()[:16]
    return tuple(int.from_bytes(raw[4 * k : 4 * k + 4], "little") for k in range(4))  # type: ignore[return-value]


def key_from_seed(seed: bytes, words: tuple[int, int, int, int]) -> bytes:
    """The key of an 8-byte seed: XTEA (32 cycles) under ``words``, as ``<prefix>_xcp_key`` computes it."""
    mask = 0xFFFFFFFF
    v0, v1 = int.from_bytes(seed[:4], "little"), int.from_bytes(seed[4:8], "little")
    total = 0
    for _ in range(32):
        v0 = (v0 + ((((v1 << 4) ^ (v1 >> 5)) + v1) ^ (total + words[total & 3]))) & mask
        total = (total + 0x9E3779B9) & mask
        v1 = (v1 + ((((v0 << 4) ^ (v0 >> 5)) + v0) ^ (total + words[(total >> 11) & 3]))) & mask
    return v0.to_bytes(4, "little") + v1.to_bytes(4, "little")


def epk(artifact: ControllerArtifact, real: str, prefix: str) -> str:
    """The EPK: the image's identification that the A2L repeats (GET_ID type 0)."""
    return f"{prefix} {real} {artifact.artifact_sha256[:16]} smartjoint {rendering.version()}"


def event_cycle(sample_time: float) -> tuple[int, int]:
    """(cycle, unit code) of the event channel: the smallest XCP time unit (1 ns · 10^unit) in
    which the sample time is a whole number of at most 255 units."""
    for unit in range(10):
        ticks = sample_time / 10.0 ** (unit - 9)
        if ticks <= 255 and abs(ticks - round(ticks)) < 1e-9 * max(ticks, 1.0):
            return int(round(ticks)), unit
    raise ModelError(f"sample_time: {sample_time!r} s — an XCP event cycle is 1…255 units of 1 ns … 1 s")


def render_xcp(
    artifact: ControllerArtifact,
    prefix: str = "smartjoint",
    real: str = "float",
    xcp: Xcp | None = None,
    network=None,
) -> dict[str, str]:
    """The slave's files ``<prefix>_xcp.h``, ``<prefix>_xcp.c`` and ``<prefix>_xcp_key.c``.

    Parameters
    ----------
    artifact : ControllerArtifact
    prefix, real : str
        As for ``codegen.generate.render``.
    xcp : Xcp, optional
        The design's ``[xcp]`` (identifiers, key, DAQ memory, bus); default :class:`Xcp` ().
    network : design.network.plan.NetworkPlan, optional
        The controller's buses (default the artefact's one-bus plan): the XCP bus's room sets the
        slave's ODTs per event (``design.network.xcp_bus``).

    Returns
    -------
    dict of str to str
        The slave's sources and ``xcp.dbc``, its two frames.
    """
    xcp = xcp or Xcp()
    room = xcp_bus.xcp_plan(network or plan.plan(artifact), xcp)
    daq_odts = room.odts
    name = f"{prefix}_xcp"
    lit = lambda value: rendering.literal(value, real)  # noqa: E731
    values = calibration_values(artifact, real, xcp)
    fields: list[dict[str, Any]] = []
    for v in values:
        if fields and (fields[-1]["law"], fields[-1]["name"]) == (v.law, v.field):
            fields[-1]["items"].append(lit(v.value))
        else:
            fields.append({"law": v.law, "name": v.field, "unit": v.unit, "array": v.joint is not None,
                           "items": [lit(v.value)]})  # fmt: skip
    for f in fields:
        f["text"] = ", ".join(f["items"])
    cycle, unit = event_cycle(artifact.sample_time)
    context = {
        **rendering.naming(rendering.banner(artifact.artifact_sha256, real, "codegen, XCP slave"), prefix, name),
        "laws": list(law_registry.LAWS),
        "page_fields": fields,
        "values": values,
        "joints": list(artifact.joint_names),
        **_limit_tables(values, artifact, real),
        "epk": epk(artifact, real, prefix),
        "event_name": EVENT_NAME,
        "event_cycle": cycle,
        "event_unit": unit,
        "master_id": xcp.master_id,
        "slave_id": xcp.slave_id,
        "daq_odts": int(daq_odts),
        "daq_entries": int(xcp.daq_entries),
        "command_lengths": list(COMMANDS.items()),
        "secret": ", ".join(f"0x{w:08X}u" for w in secret(artifact, xcp)),
    }
    env = rendering.environment()
    return {
        f"{name}.h": env.get_template("xcp.h.j2").render(context),
        f"{name}.c": env.get_template("xcp.c.j2").render(context),
        f"{name}_key.c": env.get_template("xcp_key.c.j2").render(context),
        "xcp.dbc": room.dbc,
    }


__all__ = ["COMMANDS", "CalibrationValue", "calibration_values", "epk", "key_from_seed", "render_xcp", "secret"]
