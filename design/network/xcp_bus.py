"""XCP on the network (docs/xcp.md): the bus that carries the firmware's XCP slave, its two
frames as a DBC, and the DAQ that bus has room for.

Per sample the worst case is one command and its answer (a 64-byte DOWNLOAD and an 8-byte
answer, or an 8-byte UPLOAD and a 64-byte answer: the longer pair) and every ODT of the one DAQ
list as a 64-byte DTO; on a bus the plan also gives control frames (``[xcp] bus``), those too.
The ODTs per event are as many as keep that within the bus's limit (at most
:data:`MAX_ODTS`, what the slave allocates); a bus without room for one is refused in one line.
By default XCP has a bus of its own (``xcp``, the first bus's bit rates and limit): on the
reference truss the control bus carries 64.3 % of its 70 %, and one DTO per millisecond is 17 %.
"""

from __future__ import annotations

from dataclasses import dataclass

from cantools.database import can

from smartjoint.common.errors import ModelError
from smartjoint.design.network import busload, protocol
from smartjoint.design.structure.description import Bus, Xcp

MAX_ODTS = 4  # the slave's ODTs per event, at most
MASTER = "XCP_MASTER"  # the DBC node of the calibration tool


@dataclass
class XcpPlan:
    """The bus XCP runs on, its frames, the ODTs per event and the worst-case load with them."""

    bus: Bus
    shared: bool  # a bus of the plan that carries control frames too
    database: can.Database
    odts: int
    load: float  # worst case per sample: control frames (shared) + a command pair + the ODTs
    sample_time: float

    @property
    def dbc(self) -> str:
        return protocol.dbc_text(self.database)

    def row(self) -> str:
        """The plan's row in the network table (``NetworkPlan.table``'s columns)."""
        rates = f"{self.bus.bitrate / 1e6:g}/{self.bus.data_bitrate / 1e6:g} Mbit/s"
        share = "shared with its control frames" if self.shared else "its own bus"
        return (
            f"| {self.bus.name} (XCP, {share}) | {rates} | — | 2 | {self.odts} DAQ ODTs per sample | "
            f"{self.load:.1%} ({self.bus.limit:.0%}) | {self.load * self.sample_time * 1e6:.0f} µs of "
            f"{self.sample_time * 1e6:.0f} |"
        )


def database(xcp: Xcp) -> can.Database:
    """The XCP frames as a database: XCP_CMD (master → slave) and XCP_RES (answers and DTOs),
    64-byte CAN FD, no signals (their layout is the XCP packet's, not the DBC's)."""
    messages = [
        can.Message(xcp.master_id, "XCP_CMD", 64, [], senders=[MASTER], is_fd=True,
                    comment="XCP commands (CTO) of the calibration tool to the controller's slave (docs/xcp.md)"),
        can.Message(xcp.slave_id, "XCP_RES", 64, [], senders=[protocol.CONTROLLER], is_fd=True,
                    comment="XCP answers, events and DAQ DTOs of the controller's slave (docs/xcp.md)"),
    ]  # fmt: skip
    db = can.Database(messages, [can.Node(MASTER), can.Node(protocol.CONTROLLER)],
                      dbc_specifics=protocol.fd_specifics())  # fmt: skip
    db.refresh()
    return db


def xcp_plan(network, xcp: Xcp) -> XcpPlan:
    """The bus of XCP (``xcp.bus``: a bus of ``network``, a ``design.network.plan.NetworkPlan``;
    None: one of its own) and the ODTs per event its limit leaves room for.

    Raises
    ------
    ModelError
        One line: the bus, the load one ODT would give it, its limit.
    """
    sample = float(network.sample_time)
    shared = next((p for p in network.buses if p.bus.name == xcp.bus), None) if xcp.bus is not None else None
    if xcp.bus is not None and shared is None:
        names = ", ".join(p.bus.name for p in network.buses)
        raise ModelError(f"[xcp] bus: {xcp.bus!r} — a bus of [network]: {names}")
    first = network.buses[0].bus
    bus = shared.bus if shared is not None else Bus("xcp", first.bitrate, first.data_bitrate, first.limit)
    control = shared.load.load * sample if shared is not None else 0.0

    def time(length: int) -> float:
        return busload.frame_time(length, True, bus.bitrate, bus.data_bitrate)

    pair = time(64) + time(8)
    odts = int((bus.limit * sample - control - pair) // time(64))
    if odts < 1:
        load = (control + pair + time(64)) / sample
        raise ModelError(
            f"[xcp] bus: bus {bus.name} would carry {load:.1%} with XCP's commands and one DAQ ODT per sample "
            f"(limit {bus.limit:.0%}) — give XCP a bus of its own (leave [xcp] bus out)"
        )
    odts = min(odts, MAX_ODTS)
    load = (control + pair + odts * time(64)) / sample
    return XcpPlan(bus, shared is not None, database(xcp), odts, load, sample)


__all__ = ["MASTER", "MAX_ODTS", "XcpPlan", "database", "xcp_plan"]
