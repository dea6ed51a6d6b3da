"""End-to-end protection of every frame: CRC-8 SAE J1850 and a 4-bit alive counter.

CRC-8 SAE J1850: polynomial 0x1D, initial value 0xFF, final XOR 0xFF, no reflection; check value
0x4B for the ASCII bytes "123456789". The CRC of a frame covers the two bytes of its
identifier (low byte first, a "data ID" as in AUTOSAR E2E profiles, so a payload that arrives
under the wrong identifier fails) and every payload byte except byte 0, which holds the CRC.
The alive counter (bits 8–11, 0…15) advances by one per transmission and wraps; a receiver
accepts a step of 1…``MAX_COUNTER_STEP`` (lost frames in between) and flags a repeat (0), a jump
(4…7: frames lost, the sequence restarts there) or a stale frame (8…15: behind, a late frame —
the receiver does not follow it). ``firmware/runtime/sj_e2e.c`` is the C twin; the tests hold both to the same vectors.
"""

from __future__ import annotations

from dataclasses import dataclass

from smartjoint.codegen import build
from smartjoint.common import package_data

POLYNOMIAL = 0x1D
INITIAL = 0xFF
FINAL_XOR = 0xFF
CHECK_VALUE = 0x4B  # CRC of b"123456789"
COUNTER_MODULO = 16
MAX_COUNTER_STEP = 3  # accept up to two lost frames between two received ones


def _table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ POLYNOMIAL) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


TABLE = _table()


def crc8(data: bytes, initial: int = INITIAL, final_xor: int = FINAL_XOR) -> int:
    """CRC-8 SAE J1850 of a byte string.

    Parameters
    ----------
    data : bytes
        The bytes covered.
    initial, final_xor : int
        Start value and final XOR (0xFF, 0xFF for J1850).

    Returns
    -------
    int
        The CRC, 0…255.

    Examples
    --------
    >>> hex(crc8(b"123456789"))
    '0x4b'
    """
    crc = initial
    for byte in bytes(data):
        crc = TABLE[crc ^ byte]
    return crc ^ final_xor


def frame_crc(frame_id: int, payload: bytes | bytearray) -> int:
    """The CRC of byte 0 of a frame.

    Parameters
    ----------
    frame_id : int
        The frame's identifier (its two low bytes are covered, low byte first).
    payload : bytes
        The frame's payload; bytes 1… are covered.

    Returns
    -------
    int
        The CRC, 0…255.
    """
    return crc8(bytes((frame_id & 0xFF, (frame_id >> 8) & 0xFF)) + bytes(payload[1:]))


def protect(frame_id: int, payload: bytearray, counter: int) -> bytearray:
    """Write the alive counter (low nibble of byte 1) and then the CRC (byte 0) into a payload.

    Parameters
    ----------
    frame_id : int
        The frame's identifier.
    payload : bytearray
        The payload, at least 2 bytes; changed in place.
    counter : int
        The alive counter (taken modulo 16).

    Returns
    -------
    bytearray
        ``payload``.
    """
    if len(payload) < 2:
        raise ValueError(f"payload: {len(payload)} bytes — a protected frame needs at least 2 (CRC, counter)")
    payload[1] = (payload[1] & 0xF0) | (counter % COUNTER_MODULO)
    payload[0] = frame_crc(frame_id, payload)
    return payload


@dataclass(frozen=True)
class Check:
    """Result of checking one received frame."""

    crc_ok: bool
    counter: int
    counter_step: int | None  # steps since the last accepted counter; None for the first frame

    @property
    def ok(self) -> bool:
        return self.crc_ok and (self.counter_step is None or 1 <= self.counter_step <= MAX_COUNTER_STEP)

    @property
    def reason(self) -> str:
        if not self.crc_ok:
            return "crc"
        if self.counter_step == 0:
            return "counter repeated"
        if self.counter_step is not None and self.counter_step >= COUNTER_MODULO // 2:
            return "counter stale"
        if self.counter_step is not None and self.counter_step > MAX_COUNTER_STEP:
            return "counter jump"
        return "ok"

    @property
    def resynchronises(self) -> bool:
        """Whether a receiver follows this frame's counter (all but a bad CRC, a repeat, a stale frame)."""
        return self.crc_ok and self.reason not in ("counter repeated", "counter stale")


def check(frame_id: int, payload: bytes, last_counter: int | None) -> Check:
    """Check CRC and alive counter of a received frame against the last accepted counter.

    Parameters
    ----------
    frame_id : int
        The identifier the frame arrived under.
    payload : bytes
        The received payload.
    last_counter : int or None
        The receiver's last accepted counter; None before the first frame.

    Returns
    -------
    Check
        Whether the CRC holds, the counter, and its step from ``last_counter``.

    Examples
    --------
    >>> check(0x100, protect(0x100, bytearray(12), 5), 4).ok
    True
    """
    payload = bytes(payload)
    if len(payload) < 2:
        return Check(False, 0, None)
    counter = payload[1] & 0x0F
    step = None if last_counter is None else (counter - last_counter) % COUNTER_MODULO
    return Check(payload[0] == frame_crc(frame_id, payload), counter, step)


RUNTIME = package_data.folder("smartjoint.firmware", "runtime")


def compiled():
    """The C twin (``firmware/runtime/sj_e2e.c``, strict flags) loaded with cffi.

    The declarations come from ``sj_e2e.h`` itself (``codegen.build.declarations``).

    Returns
    -------
    module
        The cffi module: ``.ffi`` and ``.lib`` (``sj_crc8_j1850``, ``sj_e2e_frame_crc``,
        ``sj_e2e_protect``, ``sj_e2e_check``).

    Raises
    ------
    FileNotFoundError
        The runtime is missing from the installed package.
    """
    source = RUNTIME / "sj_e2e.c"
    if not source.exists():
        raise FileNotFoundError(f"{source}: the firmware runtime is missing from the installed package")
    files = {name: (RUNTIME / name).read_text() for name in ("sj_e2e.c", "sj_e2e.h")}
    return build.load("e2e", files, "sj_e2e.h", ("sj_e2e.c",))[1]
