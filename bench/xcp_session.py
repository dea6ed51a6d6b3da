"""A bench session with a running ECU through its A2L (``smartjoint bench xcp``; docs/xcp.md):
identify it, read its calibration, calibrate within the A2L's limits and measure by DAQ, with
pyxcp as the master on any python-can bus.

A session opens two connections. The first identifies the image (the EPK it answers against the
A2L's: a wrong A2L would point DOWNLOADs at the wrong bytes, so nothing is written before they
agree), reads the characteristics, and, to measure, asks the slave how many ODTs and entries its
DAQ list holds (an ALLOC that does not fit is refused and changes nothing). The second carries
the DAQ list from start to stop and the DOWNLOADs, either before the measurement or at a chosen
time into it, so their effect is in the recording.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from smartjoint.bench import a2l_file, xcp_master
from smartjoint.codegen import xcp_slave
from smartjoint.common.errors import ModelError

_FORMATS = {"UBYTE": "B", "SBYTE": "b", "UWORD": "H", "SWORD": "h", "ULONG": "I", "SLONG": "i",
            "FLOAT32_IEEE": "f", "FLOAT64_IEEE": "d"}  # fmt: skip
_PID_AND_STAMP = 5  # a DTO's PID and, in its list's first ODT, the 4-byte time stamp


def key_function(artifact=None, key_hex: str | None = None) -> Callable | None:
    """The seed & key algorithm of smartjoint's slave: XTEA under ``key_hex`` (the design's
    ``[xcp] key``, 32 hex digits) or under the key derived from ``artifact``; None without either."""
    from smartjoint.design.structure.description import Xcp

    if key_hex is None and artifact is None:
        return None
    if key_hex is not None:
        text = key_hex.strip()
        if len(text) != 32 or any(c not in "0123456789abcdefABCDEF" for c in text):
            raise ModelError(f"--key: {key_hex!r} — must be 32 hex digits (the design's [xcp] key)")
    words = xcp_slave.secret(artifact, Xcp(key=key_hex.strip() if key_hex else None))
    return lambda resource, seed: xcp_slave.key_from_seed(bytes(seed), words)


def raw_value(quantity, physical: float):
    """The raw value a DOWNLOAD writes for ``physical``: (physical − offset) / factor in the
    quantity's type (float32 rounded, integers rounded to the nearest)."""
    raw = (float(physical) - quantity.offset) / quantity.factor
    if quantity.datatype == "FLOAT32_IEEE":
        return float(np.float32(raw))
    if quantity.datatype == "FLOAT64_IEEE":
        return raw
    return int(round(raw))


def check_settings(description, settings: dict[str, float]) -> dict[str, float]:
    """Each setting by name, checked against the A2L before any frame: a known CHARACTERISTIC,
    a finite value, and — as the DOWNLOAD would write it — within its limits."""
    checked = {}
    for name, value in settings.items():
        if name not in description.characteristics:
            known = ", ".join(list(description.characteristics)[:6])
            raise ModelError(f"--set {name}: not a CHARACTERISTIC of {description.path} (e.g. {known}, …)")
        c = description.characteristics[name]
        written = raw_value(c, value) * c.factor + c.offset if np.isfinite(value) else value
        if not (np.isfinite(value) and c.lower <= written <= c.upper):
            raise ModelError(
                f"--set {name}={value!r}: outside the A2L's limits [{c.lower:.6g}, {c.upper:.6g}] {c.unit}"
            )
        checked[name] = float(value)
    return checked


def _response(error: BaseException, what: str, description) -> ModelError:
    """One line for what pyxcp raised."""
    name = type(error).__name__
    if name == "XcpTimeoutError":
        return ModelError(f"xcp: no answer from slave 0x{description.slave_id:X} to {what} — is the ECU on this bus, "
                          "with this A2L's identifiers?")  # fmt: skip
    if name == "XcpResponseError":
        code = error.args[0] if error.args else "?"
        return ModelError(f"xcp: the slave refused {what}: {code}")
    return ModelError(f"xcp: {what} failed: {name}: {error}")


@dataclass
class Session:
    """An ECU on a python-can bus, described by its A2L.

    Parameters
    ----------
    description : bench.a2l_file.EcuDescription
    interface, channel : str
        The python-can bus the ECU is on.
    key : callable, optional
        ``key(resource, seed)``; without it nothing that needs UNLOCK can be done.
    timeout : float
        Seconds per command.
    """

    description: a2l_file.EcuDescription
    interface: str
    channel: str
    key: Callable | None = None
    timeout: float = 2.0
    epk: str | None = None
    log: list[str] = field(default_factory=list)

    def connect(self, policy=None):
        """A pyxcp master, connected to the slave whose EPK is the A2L's (``policy``: its DAQ
        policy, if it will measure); :meth:`close` ends it."""
        master = self._open(policy)
        try:
            self._connect(master)
        except BaseException:
            self.close(master)
            raise
        return master

    def _open(self, policy=None):
        d = self.description
        app = xcp_master.configure(self.interface, self.channel, d.master_id, d.slave_id, self.key, self.timeout,
                                   d.bitrate or None, d.data_bitrate or 0)  # fmt: skip
        try:
            master = xcp_master.master(app, policy)
            master.__enter__()
        except Exception as error:  # python-can's and pyxcp's own kinds
            raise ModelError(
                f"xcp: cannot open {self.interface}:{self.channel} ({type(error).__name__}: {error})"
            ) from None
        return master

    def _call(self, what: str, function, *args):
        try:
            return function(*args)
        except ModelError:
            raise
        except Exception as error:
            raise _response(error, what, self.description) from None

    def _connect(self, master) -> None:
        self._call("CONNECT", master.connect)
        self.epk = self._call("GET_ID", master.identifier, 0)
        expected = self.description.epk
        if expected is not None and self.epk != expected:
            raise ModelError(
                f"xcp: the ECU's EPK {self.epk!r} is not the A2L's {expected!r} ({self.description.path}): "
                "wrong image or wrong A2L — nothing written"
            )

    def close(self, master) -> None:
        """DISCONNECT and close the bus."""
        try:
            master.disconnect()
        except Exception:  # the session's result stands; the slave drops a silent master itself
            pass
        master.__exit__(None, None, None)

    def upload(self, master, names) -> dict[str, float]:
        """Physical values of quantities (CHARACTERISTICs or MEASUREMENTs) by UPLOAD."""
        out = {}
        for name in names:
            q = self.description.characteristics.get(name) or self.description.measurements[name]
            self._call(f"SET_MTA 0x{q.address:X}", master.setMta, q.address)
            data = self._call(f"UPLOAD of {name}", master.upload, a2l_file.size(q.datatype))
            raw = struct.unpack("<" + _FORMATS[q.datatype], bytes(data)[: a2l_file.size(q.datatype)])[0]
            out[name] = raw * q.factor + q.offset  # the answer is padded to a CAN FD length
        return out

    def download(self, master, settings: dict[str, float]) -> dict[str, float]:
        """DOWNLOAD each setting (UNLOCK first); returns what UPLOAD reads back."""
        if settings and self.key is None:
            raise ModelError("xcp: calibration needs UNLOCK — give --artifact or --key (the seed & key's key)")
        self._call("UNLOCK", master.cond_unlock)
        for name, value in settings.items():
            c = self.description.characteristics[name]
            data = struct.pack("<" + _FORMATS[c.datatype], raw_value(c, value))
            self._call(f"SET_MTA 0x{c.address:X}", master.setMta, c.address)
            self._call(f"DOWNLOAD of {name}={value:g}", master.download, data)
        return self.upload(master, settings)

    def capacity(self, master) -> tuple[int, int]:
        """(ODTs, entries) the slave's DAQ list holds: the largest ALLOC_ODT and ALLOC_ODT_ENTRY
        it accepts (bisection; a refused ALLOC changes nothing, FREE_DAQ starts each try over)."""
        self._call("UNLOCK", master.cond_unlock)

        def fits(odts: int, entries: int) -> bool:
            self._call("FREE_DAQ", master.freeDaq)
            self._call("ALLOC_DAQ", master.allocDaq, 1)
            try:
                master.allocOdt(0, odts)
                if entries:
                    master.allocOdtEntry(0, 0, entries)
                return True
            except Exception as error:
                if type(error).__name__ != "XcpResponseError":
                    raise _response(error, "ALLOC_ODT", self.description) from None
                return False

        def largest(test) -> int:
            low, high = 0, 255  # the ALLOC counts are bytes
            while low < high:
                middle = (low + high + 1) // 2
                low, high = (middle, high) if test(middle) else (low, middle - 1)
            return low

        odts = largest(lambda n: fits(n, 0))
        entries = largest(lambda n: fits(1, n)) if odts else 0
        self._call("FREE_DAQ", master.freeDaq)
        return odts, entries


def choose(description, names: list[str], odts: int, entries: int) -> tuple[list[tuple[str, int, str]], list[str]]:
    """The DAQ list's entries (name, address, pyxcp type) for ``names`` ("all": every scalar
    MEASUREMENT in the A2L's order) as far as ``odts`` ODTs of MAX_DTO 64 and ``entries`` entries
    hold them; and the names left out."""
    wanted = list(description.measurements) if names == ["all"] else names
    for name in wanted:
        if name not in description.measurements:
            known = ", ".join(list(description.measurements)[:6])
            raise ModelError(f"--measure {name}: not a MEASUREMENT of {description.path} (e.g. {known}, …)")
    chosen: list[tuple[str, int, str]] = []
    left: list[str] = []
    used = 0
    capacity = odts * (64 - _PID_AND_STAMP)
    for name in wanted:
        m = description.measurements[name]
        width = a2l_file.size(m.datatype)
        if len(chosen) == entries or used + width > capacity:
            left.append(name)
            continue
        chosen.append((name, m.address, xcp_master.A2L_TYPES[m.datatype]))
        used += width
    if names != ["all"] and left:
        raise ModelError(f"--measure: {len(wanted)} signals do not fit the slave's DAQ list ({odts} ODTs, {entries} "
                         f"entries): {', '.join(left)} left over")  # fmt: skip
    return chosen, left


def elapsed_us(time_us: list[int]) -> np.ndarray:
    """Slave time stamps [µs] from the first, unwrapped (the 32-bit counter wraps every 71.6 min)."""
    stamps = np.asarray(time_us, dtype=np.int64)
    if len(stamps) == 0:
        return stamps
    steps = np.diff(stamps) % (1 << 32)
    return np.concatenate([[0], np.cumsum(steps)])


def run_daq(session: Session, entries, duration: float, prescaler: int = 1, settings=None, at: float = 0.0,
            idle: float = 5.0, progress=print) -> dict:  # fmt: skip
    """Measure ``entries`` on the slave's event for ``duration`` seconds of slave time, with
    ``settings`` downloaded ``at`` seconds into the measurement; stops early when no DTO came
    for ``idle`` seconds (the ECU stopped).

    Returns
    -------
    dict
        ``recorded`` (xcp_master.Recorded), ``read_back`` (the settings as uploaded), ``set_at_us``
        (slave time of the download, from the first sample), ``stopped`` ("duration" or "idle").
    """
    policy = xcp_master.recorder("sample", entries, prescaler)
    master = session.connect(policy)
    out: dict = {"read_back": {}, "set_at_us": None, "stopped": "duration"}
    try:
        session._call("UNLOCK", master.cond_unlock)
        session._call("the DAQ list's set-up", policy.setup)
        session._call("START_STOP_SYNCH", policy.start)
        last_rows, last_change = 0, time.monotonic()
        pending = dict(settings or {})
        while True:
            time.sleep(0.02)
            recorded = policy.recorded
            rows = 0 if recorded is None else len(recorded.rows)
            now = time.monotonic()
            if rows != last_rows:
                last_rows, last_change = rows, now
                progress(f"      DAQ: {rows} samples …")
            span = elapsed_us(recorded.time_us)[-1] * 1e-6 if rows else 0.0
            if pending and rows and span >= at:
                out["read_back"] = session.download(master, pending)
                out["set_at_us"] = int(elapsed_us(policy.recorded.time_us)[-1])
                pending = {}
            if rows and span >= duration:
                break
            if now - last_change > idle:
                out["stopped"] = "idle"
                break
        session._call("START_STOP_SYNCH (stop)", policy.stop)
    finally:
        session.close(master)
    if policy.recorded is None:
        raise ModelError(f"xcp: no DTO from slave 0x{session.description.slave_id:X} within {idle:g} s of starting DAQ")
    out["recorded"] = policy.recorded
    return out


def physical(recorded, description, name: str) -> np.ndarray:
    """One recorded signal in physical units (the A2L's conversion)."""
    m = description.measurements[name]
    return recorded.column(name).astype(float) * m.factor + m.offset


def daq_summary(daq: dict, description, prescaler: int, capacity: tuple[int, int], left: list[str]) -> dict:
    """What a DAQ measurement holds: samples, lost samples (from the slave's time stamps and the
    event's cycle), each signal's unit and range, and when the settings went in."""
    recorded = daq["recorded"]
    stamps = elapsed_us(recorded.time_us)
    step = None if description.event_cycle is None else int(round(description.event_cycle * 1e6)) * prescaler
    lost = None if step is None else int(np.sum(np.diff(stamps) // step - 1)) if len(stamps) > 1 else 0
    signals = {}
    for name in recorded.names:
        values = physical(recorded, description, name)
        signals[name] = {"unit": description.measurements[name].unit, "min": float(values.min()),
                         "max": float(values.max())}  # fmt: skip
    return {
        "samples": len(recorded.rows),
        "seconds": float(stamps[-1] * 1e-6) if len(stamps) else 0.0,
        "lost_samples": lost,
        "stopped": daq["stopped"],
        "set_at_s": None if daq["set_at_us"] is None else daq["set_at_us"] * 1e-6,
        "daq_list": {"odts": capacity[0], "entries": capacity[1]},
        "left_out": left,
        "signals": signals,
    }


def plot_daq(daq: dict, description, path):
    """The measurement, one panel per unit (at most six), the DOWNLOAD's time marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    recorded = daq["recorded"]
    time_s = elapsed_us(recorded.time_us) * 1e-6
    units: dict[str, list[str]] = {}
    for name in recorded.names:
        units.setdefault(description.measurements[name].unit or "-", []).append(name)
    shown = list(units.items())[:6]
    fig, axes = plt.subplots(len(shown), 1, figsize=(9, 1.9 * len(shown) + 0.6), sharex=True, squeeze=False)
    for ax, (unit, names) in zip(axes[:, 0], shown, strict=True):
        for name in names:
            ax.plot(time_s, physical(recorded, description, name), lw=0.8, label=name)
        if daq["set_at_us"] is not None:
            ax.axvline(daq["set_at_us"] * 1e-6, color="k", ls="--", lw=0.8)
        ax.set_ylabel(unit)
        ax.legend(fontsize=6, ncol=3, loc="upper right")
    axes[-1, 0].set_xlabel("time since the first DAQ sample [s] (dashed: the DOWNLOAD)")
    fig.suptitle(f"XCP DAQ of {description.module}: {len(recorded.names)} signals", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def session_text(out: dict, description) -> str:
    """``bench xcp``'s report: the ECU, its calibration, what was set, the measurement."""
    lines = [f"ECU {out['epk']!r} on {out['bus']}: EPK matches {out['a2l']}", "calibration (before):"]
    for name, value in out["calibration"].items():
        c = description.characteristics[name]
        lines.append(f"  {name:<34} {value:>14.7g} {c.unit:<5} [{c.lower:.6g}, {c.upper:.6g}]")
    for name, value in out["read_back"].items():
        lines.append(f"set {name} = {out['set'][name]:.7g} → reads back {value:.7g}")
    daq = out.get("daq")
    if daq:
        at = "" if daq["set_at_s"] is None else f", settings in at {daq['set_at_s']:.3f} s"
        lines.append(f"DAQ: {len(daq['signals'])} signals, {daq['samples']} samples over {daq['seconds']:.3f} s, "
                     f"{daq['lost_samples']} lost (stopped by {daq['stopped']}){at}")  # fmt: skip
        if daq["left_out"]:
            lines.append(f"  left out (the DAQ list holds {daq['daq_list']}): {', '.join(daq['left_out'])}")
    if out.get("mf4"):
        lines.append(f"MF4: {out['mf4']}")
    return "\n".join(lines)


__all__ = [
    "Session",
    "check_settings",
    "choose",
    "daq_summary",
    "elapsed_us",
    "key_function",
    "physical",
    "plot_daq",
    "raw_value",
    "run_daq",
    "session_text",
]
