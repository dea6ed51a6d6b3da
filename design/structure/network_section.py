"""The [network] table of the design file (docs/design-file.md): the CAN FD buses the network
plan fills, where the SISO law runs and the supervision period of local mode."""

from __future__ import annotations

from smartjoint.common import law_registry
from smartjoint.design.structure.description import Bus, Network, Xcp
from smartjoint.design.structure.table import DesignTable

PLACES = ("central", "local")  # where the node law runs
MIN_BITRATE, MAX_BITRATE = 10_000, 20_000_000  # [bit/s]: what python-can and CAN FD controllers set
MAX_BUSES = 16
MAX_SUPERVISION_CYCLES = 1000  # a status frame at least every 1000 samples
XCP_LOWEST_ID = 0x400  # the control protocol's identifiers lie in 0x080 … 0x3FF (design.network.protocol)


def parse_network(t: DesignTable) -> Network:
    """The [network] table: ``siso``, ``supervision_cycles`` and ``[[network.buses]]`` (each with
    ``name``, ``bitrate``, ``data_bitrate`` >= ``bitrate`` and ``limit`` in (0, 1]).

    Parameters
    ----------
    t : DesignTable
        The [network] table (empty for the defaults).

    Returns
    -------
    Network
    """
    d = Network()
    # The key is the node law's name (``[network] siso``): where that law runs.
    siso = t.string(law_registry.node_law().name, d.siso, choices=PLACES)
    cycles = t.integer("supervision_cycles", d.supervision_cycles, minimum=1, maximum=MAX_SUPERVISION_CYCLES)
    tables = t.tables("buses")
    if len(tables) > MAX_BUSES:
        raise t.error("buses", f"{len(tables)} buses", f"at most {MAX_BUSES}")
    buses: list[Bus] = []
    for bus in tables:
        name = bus.string("name")
        bitrate = bus.integer("bitrate", Bus.bitrate, minimum=MIN_BITRATE, maximum=MAX_BITRATE)
        data = bus.integer("data_bitrate", Bus.data_bitrate, minimum=bitrate, maximum=MAX_BITRATE)
        limit = bus.number("limit", Bus.limit, positive=True, maximum=1.0)
        bus.finish()
        if any(b.name == name for b in buses):
            raise bus.error("name", name, "a name no other bus has")
        buses.append(Bus(name, bitrate, data, limit))
    t.finish()
    return Network(tuple(buses) or d.buses, siso, cycles)


def parse_xcp(t: DesignTable, network: Network | None = None) -> Xcp:
    """The [xcp] table (docs/xcp.md): ``master_id``/``slave_id`` (distinct 11-bit identifiers above
    the control protocol's 0x080 … 0x3FF, so XCP never delays a control frame), ``key`` (32 hex
    digits), ``daq_entries`` (1 … 255), ``calibration_decades`` (0 … 6] and ``bus`` (a bus of
    ``network`` to share; left out: a bus of its own)."""
    d = Xcp()
    master = t.integer("master_id", d.master_id, minimum=XCP_LOWEST_ID, maximum=0x7FF)
    slave = t.integer("slave_id", d.slave_id, minimum=XCP_LOWEST_ID, maximum=0x7FF)
    if slave == master:
        raise t.error("slave_id", slave, f"an identifier other than master_id {master:#x}")
    key = t.string("key", None)
    if key is not None and (len(key) != 32 or any(c not in "0123456789abcdefABCDEF" for c in key)):
        raise t.error("key", key, "32 hex digits (a 128-bit key)")
    entries = t.integer("daq_entries", d.daq_entries, minimum=1, maximum=255)
    decades = t.number("calibration_decades", d.calibration_decades, positive=True, maximum=6.0)
    names = [b.name for b in (network or Network()).buses]
    bus = t.string("bus", None, choices=tuple(names))
    t.finish()
    return Xcp(master_id=master, slave_id=slave, key=key, bus=bus, daq_entries=entries, calibration_decades=decades)


__all__ = ["PLACES", "parse_network", "parse_xcp"]
