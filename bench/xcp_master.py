"""The bench's XCP master: pyxcp over python-can, configured from the artefact and the design's
``[xcp]`` (identifiers, CAN FD, the seed & key of this artefact; docs/xcp.md), and its DAQ
measurement as arrays.

pyxcp is imported on first use: it installs its own traceback printer when imported.
"""

from __future__ import annotations

import logging
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from smartjoint.codegen import xcp_slave
from smartjoint.design.structure.description import Xcp

RESOURCES = {0x01: "calpag", 0x04: "daq"}
NUMPY_TYPES = {"U8": "<u1", "I8": "<i1", "U16": "<u2", "I16": "<i2", "U32": "<u4", "I32": "<i4", "F32": "<f4",
               "F64": "<f8"}  # fmt: skip
A2L_TYPES = {"UBYTE": "U8", "SBYTE": "I8", "UWORD": "U16", "SWORD": "I16", "ULONG": "U32", "SLONG": "I32",
             "FLOAT32_IEEE": "F32", "FLOAT64_IEEE": "F64"}  # fmt: skip


class _ClosedSocket(logging.Filter):
    """Drops pyxcp's "Error in CAN listen thread: [Errno 9] Bad file descriptor": its listener
    reads once more after the bus's socket was closed (udp_multicast), which is no error."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "[Errno 9]" not in record.getMessage()


def _pyxcp() -> None:
    """Import pyxcp and undo what its import does to the process: it installs rich's traceback
    printer as ``sys.excepthook`` (the command line prints its own one-line errors)."""
    hook = sys.excepthook
    import pyxcp  # noqa: F401

    sys.excepthook = hook


def application(artifact, xcp: Xcp, interface: str = "virtual", channel: str = "smartjoint-sil.xcp",
                timeout: float = 2.0, key=None):  # fmt: skip
    """A pyxcp application (its traitlets configuration) for the slave of ``artifact``.

    Parameters
    ----------
    artifact : ControllerArtifact
        Its hash gives the seed & key's key (unless ``xcp.key`` or ``key`` say otherwise).
    xcp : Xcp
        The design's ``[xcp]``: the identifiers.
    interface, channel : str
        The python-can bus of the slave.
    timeout : float
        Seconds per command.
    key : callable, optional
        ``key(resource, seed) -> bytes``: a user's own algorithm; default this artefact's XTEA.
    """
    words = xcp_slave.secret(artifact, xcp)
    return configure(interface, channel, xcp.master_id, xcp.slave_id,
                     key or (lambda resource, seed: xcp_slave.key_from_seed(bytes(seed), words)), timeout)  # fmt: skip


def configure(interface: str, channel: str, master_id: int, slave_id: int, key=None, timeout: float = 2.0,
              bitrate: int | None = None, data_bitrate: int | None = None):  # fmt: skip
    """A pyxcp application for an XCP on CAN (FD) slave on a python-can bus.

    Parameters
    ----------
    interface, channel : str
        The python-can bus.
    master_id, slave_id : int
        The slave's identifiers (11-bit).
    key : callable, optional
        ``key(resource, seed) -> bytes``, the seed & key algorithm (None: no UNLOCK possible).
    timeout : float
        Seconds per command.
    bitrate, data_bitrate : int, optional
        The bus's bit rates for an interface that sets them (a real adapter); ``data_bitrate``
        None is classical CAN.
    """
    _pyxcp()
    from pyxcp.config import General, PyXCP, Transport, set_application
    from traitlets.config import Config

    c = Config()
    c.Transport.layer = "CAN"
    c.Transport.timeout = float(timeout)
    c.Transport.Can.interface = interface
    c.Transport.Can.channel = channel
    c.Transport.Can.can_id_master = int(master_id)
    c.Transport.Can.can_id_slave = int(slave_id)
    c.Transport.Can.fd = data_bitrate != 0
    if bitrate:
        c.Transport.Can.bitrate = int(bitrate)
    if data_bitrate:
        c.Transport.Can.data_bitrate = int(data_bitrate)
    c.Transport.Can.max_dlc_required = False
    c.Transport.Can.pid_off = False  # an unset value reads as true in pyxcp's DAQ set-up
    c.General.disable_error_handling = True  # negative answers raise XcpResponseError
    if key is not None:
        c.General.seed_n_key_function = key
    app = PyXCP(config=c)
    # python-can's virtual bus takes no bit rates: pyxcp warns of it on every connect.
    logging.getLogger("pyxcp").setLevel(logging.ERROR)
    transport_log = logging.getLogger("pyxcp.transport")
    if not any(isinstance(f, _ClosedSocket) for f in transport_log.filters):
        transport_log.addFilter(_ClosedSocket())
    app.general = General(config=app.config, parent=app)
    app.transport = Transport(parent=app)
    set_application(app)  # the DAQ policy looks the application up
    return app


@dataclass
class Recorded:
    """The DTOs of one DAQ list as arrays: per sample the slave's time stamp [µs] and each
    measurement's raw value (in the slave's type)."""

    names: list[str]
    time_us: list[int] = field(default_factory=list)
    rows: list[list] = field(default_factory=list)

    def column(self, name: str) -> np.ndarray:
        k = self.names.index(name)
        return np.array([row[k] for row in self.rows])


def recorder(name: str, entries: list[tuple[str, int, str]], prescaler: int = 1):
    """A DAQ policy of one list on the slave's one event: ``entries`` are (name, address, pyxcp
    type "F32"/"U8"/…), recorded as :class:`Recorded` (``policy.recorded``)."""
    _pyxcp()
    from pyxcp.daq_stim import DaqList, DaqOnlinePolicy

    class Policy(DaqOnlinePolicy):
        def initialize(self) -> None:
            self.lock = threading.Lock()
            self.recorded: Recorded | None = None

        def on_daq_list(self, daq_list: int, ts0: int, ts1: int, payload: list) -> None:
            with self.lock:
                if self.recorded is None:
                    self.recorded = Recorded([h[0] for h in self.daq_lists[0].headers])
                recorded = self.recorded
                recorded.time_us.append(int(ts1) // 1000)
                recorded.rows.append(list(payload))

        def finalize(self) -> None:
            pass

    daq = DaqList(name=name, event_num=0, stim=False, enable_timestamps=True,
                  measurements=[(n, a, 0, t) for n, a, t in entries], priority=0, prescaler=prescaler)  # fmt: skip
    policy = Policy([daq])
    policy.initialize()
    return policy


def write_mf4(recorded: Recorded, description, path, start: float = 0.0, comment: str = "") -> Path:
    """The DAQ measurement as an MF4 file (asammdf): one channel group, the slave's time stamps
    [s] from ``start`` as its time base, each signal raw with the A2L's LINEAR conversion and unit.

    Parameters
    ----------
    recorded : Recorded
        One DAQ list's samples (:func:`recorder`).
    description : codegen.a2l.Description
        The image's A2L (each measurement's conversion and unit).
    path : path
        The file to write (written whole to a temporary file, then moved into place).
    start : float
        The study time of the first sample [s].
    comment : str
        The file's comment.

    Returns
    -------
    Path
    """
    from asammdf import MDF, Signal

    path = Path(path)
    stamps = np.asarray(recorded.time_us, dtype=np.int64)
    time = start + (stamps - stamps[0]) * 1e-6 if len(stamps) else np.zeros(0)
    signals = []
    for name in recorded.names:
        m = description.measurements[name]
        raw = recorded.column(name)
        conversion = None if (m.factor, m.offset) == (1.0, 0.0) else {"a": m.factor, "b": m.offset}
        signals.append(Signal(raw, time, unit=m.unit, name=name, conversion=conversion, comment=m.name))
    temporary = path.with_name(f".{path.stem}.partial.mf4")  # asammdf keeps a name ending in .mf4
    with MDF(version="4.10") as mdf:
        mdf.append(signals, acq_name="XCP DAQ, event sample", comment=comment or "smartjoint XCP DAQ")
        written = Path(mdf.save(temporary, overwrite=True))
    written.replace(path)
    return path


def master(app, policy=None) -> Any:
    """A pyxcp master on the configured bus (``with master(app) as x: x.connect() …``)."""
    _pyxcp()
    from pyxcp.master import Master

    return Master("can", config=app, policy=policy)


__all__ = ["A2L_TYPES", "NUMPY_TYPES", "Recorded", "application", "configure", "master", "recorder", "write_mf4"]
