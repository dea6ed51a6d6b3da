"""Worst-case bus load of a CAN database from its frames, lengths and cycle times.

Frame lengths in bits with worst-case bit stuffing, 11-bit identifiers:

* classical CAN (Davis et al., Real-Time Systems 35, 2007): 8n + 47 + ⌊(34 + 8n − 1)/4⌋ bits at
  the bitrate, n data bytes (0…8);
* CAN FD with bit-rate switch (ISO 11898-1:2015): at the nominal (arbitration) rate SOF, the
  identifier and the control bits up to BRS (17 bits, ⌊16/4⌋ = 4 stuff bits), CRC delimiter,
  ACK slot and delimiter, EOF and interframe space (13 bits); at the data rate ESI, DLC and the
  data (5 + 8n bits, ⌊(5 + 8n − 1)/4⌋ stuff bits), the stuff count (4 bits) and the CRC (17 bits
  up to 16 data bytes, else 21) with its fixed stuff bits (one per 4 bits: 6 or 7).

Load = Σ frame time / cycle time. A frame longer than 8 bytes needs CAN FD.
"""

from __future__ import annotations

from dataclasses import dataclass

from smartjoint.common.errors import ModelError

CLASSICAL_RATES = (125_000, 250_000, 500_000, 1_000_000)
FD_DATA_RATES = (2_000_000, 4_000_000, 5_000_000, 8_000_000)
DEFAULT_LIMIT = 0.70


def classical_bits(length: int) -> int:
    """Worst-case bits of a classical CAN frame (Davis et al. 2007).

    Parameters
    ----------
    length : int
        Data bytes, 0…8.

    Returns
    -------
    int
        8n + 47 + ⌊(34 + 8n − 1)/4⌋.

    Examples
    --------
    >>> classical_bits(8)
    135
    """
    if not 0 <= length <= 8:
        raise ModelError(f"frame length {length} bytes: classical CAN carries 0…8 — use CAN FD (--data-bitrate)")
    return 8 * length + 47 + (34 + 8 * length - 1) // 4


def fd_bits(length: int) -> tuple[int, int]:
    """Worst-case bits of a CAN FD frame with bit-rate switch (ISO 11898-1:2015).

    Parameters
    ----------
    length : int
        Data bytes, a CAN FD length (0…8, 12, 16, 20, 24, 32, 48, 64).

    Returns
    -------
    tuple of (int, int)
        Bits at the nominal rate and bits at the data rate (module docstring).
    """
    if length not in (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64):
        raise ModelError(f"frame length {length} bytes: not a CAN FD length (0…8, 12, 16, 20, 24, 32, 48, 64)")
    crc = 17 if length <= 16 else 21
    nominal = 17 + 16 // 4 + 13
    data = 5 + 8 * length + (5 + 8 * length - 1) // 4 + 4 + crc + (6 if crc == 17 else 7)
    return nominal, data


@dataclass(frozen=True)
class FrameLoad:
    name: str
    frame_id: int
    length: int
    cycle_time: float  # s
    frame_time: float  # s, worst case

    @property
    def load(self) -> float:
        return self.frame_time / self.cycle_time


@dataclass(frozen=True)
class BusLoad:
    bitrate: int
    data_bitrate: int | None  # None: classical CAN
    frames: tuple[FrameLoad, ...]

    @property
    def load(self) -> float:
        return sum(f.load for f in self.frames)

    def table(self) -> str:
        """The Markdown table of the frames' loads and the total."""
        kind = "classical CAN" if self.data_bitrate is None else f"CAN FD, data {self.data_bitrate / 1e6:g} Mbit/s"
        lines = [
            f"bus load at {self.bitrate / 1e6:g} Mbit/s ({kind}), worst-case bit stuffing:",
            "",
            "| frame | id | bytes | cycle [ms] | worst-case time [µs] | load |",
            "|---|---|---:|---:|---:|---:|",
        ]
        for f in self.frames:
            lines.append(
                f"| {f.name} | 0x{f.frame_id:03X} | {f.length} | {1e3 * f.cycle_time:g} | "
                f"{1e6 * f.frame_time:.1f} | {100 * f.load:.1f} % |"
            )
        lines.append(f"| **total** | | | | | **{100 * self.load:.1f} %** |")
        return "\n".join(lines)


def frame_time(length: int, is_fd: bool, bitrate: int, data_bitrate: int | None) -> float:
    """Worst-case time of one frame on the bus.

    Parameters
    ----------
    length : int
        Data bytes.
    is_fd : bool
        A CAN FD frame (with bit-rate switch).
    bitrate : int
        The nominal (arbitration) bitrate [bit/s].
    data_bitrate : int or None
        The CAN FD data bitrate [bit/s]; None for a classical bus.

    Returns
    -------
    float
        Seconds; a classical frame on an FD bus runs entirely at the nominal rate.

    Raises
    ------
    ModelError
        A CAN FD frame on a classical bus.

    Examples
    --------
    >>> round(frame_time(8, False, 1_000_000, None) * 1e6, 1)
    135.0
    """
    if data_bitrate is None:
        if is_fd or length > 8:
            raise ModelError(f"a {length}-byte CAN FD frame cannot go on a classical CAN bus — give a data bitrate")
        return classical_bits(length) / bitrate
    if not is_fd:  # a classical frame on an FD bus runs entirely at the nominal rate
        return classical_bits(length) / bitrate
    nominal, data = fd_bits(length)
    return nominal / bitrate + data / data_bitrate


def bus_load(db, bitrate: int, data_bitrate: int | None = None) -> BusLoad:
    """Worst-case load of every frame of a database that has a cycle time.

    Parameters
    ----------
    db : cantools.database.can.Database
        The bus (``design.network.protocol.database``).
    bitrate : int
        The nominal bitrate [bit/s].
    data_bitrate : int, optional
        The CAN FD data bitrate [bit/s]; None for classical CAN.

    Returns
    -------
    BusLoad
        Per frame and in total (``load``: Σ frame time / cycle time).

    Raises
    ------
    ModelError
        A bitrate outside 10 kbit/s…20 Mbit/s or a data rate below the nominal one.
    """
    for name, value in (("bitrate", bitrate), ("data_bitrate", data_bitrate)):
        if value is not None and not (isinstance(value, int) and 10_000 <= value <= 20_000_000):
            raise ModelError(f"{name}: {value!r} — a whole number of bit/s between 10 000 and 20 000 000")
    if data_bitrate is not None and data_bitrate < bitrate:
        raise ModelError(f"data_bitrate {data_bitrate} < bitrate {bitrate}: the data phase is the fast one")
    frames = []
    for m in db.messages:
        if m.cycle_time is None:
            continue
        frames.append(
            FrameLoad(
                m.name,
                m.frame_id,
                m.length,
                m.cycle_time / 1000.0,
                frame_time(m.length, m.is_fd, bitrate, data_bitrate),
            )
        )
    return BusLoad(bitrate, data_bitrate, tuple(frames))


def check(db, bitrate: int, data_bitrate: int | None = None, limit: float = DEFAULT_LIMIT) -> BusLoad:
    """:func:`bus_load`, refused above ``limit`` with what would fit.

    Parameters
    ----------
    db : cantools.database.can.Database
        The bus.
    bitrate : int
        The nominal bitrate [bit/s].
    data_bitrate : int, optional
        The CAN FD data bitrate [bit/s]; None for classical CAN.
    limit : float
        The largest load allowed, a fraction in (0, 1].

    Returns
    -------
    BusLoad
        The load, at most ``limit``.

    Raises
    ------
    ModelError
        The load exceeds ``limit``; the message names the standard bitrates that would carry it.
    """
    if not (0 < limit <= 1):
        raise ModelError(f"max_load: {limit!r} — a fraction in (0, 1]")
    result = bus_load(db, bitrate, data_bitrate)
    if result.load <= limit:
        return result
    fits = []
    if data_bitrate is None:
        fits += [f"classical {r / 1e6:g} Mbit/s" for r in CLASSICAL_RATES if r > bitrate and _fits(db, r, None, limit)]
    for data in FD_DATA_RATES:
        if _fits(db, bitrate, data, limit):
            fits.append(f"CAN FD {bitrate / 1e6:g}/{data / 1e6:g} Mbit/s")
    slower = max((f.cycle_time for f in result.frames), default=0.0)
    hint = (
        ("; it fits at " + ", ".join(fits))
        if fits
        else "; no standard bitrate carries it — lengthen the sample time "
        f"(factor {result.load / limit:.2f}) or drop frames"
    )
    raise ModelError(
        f"bus load {100 * result.load:.1f} % at {bitrate / 1e6:g} Mbit/s"
        f"{'' if data_bitrate is None else f' (data {data_bitrate / 1e6:g} Mbit/s)'} exceeds the limit "
        f"{100 * limit:.0f} %{hint}" + ("" if slower else "")
    )


def _fits(db, bitrate, data_bitrate, limit) -> bool:
    try:
        return bus_load(db, bitrate, data_bitrate).load <= limit
    except ModelError:
        return False
