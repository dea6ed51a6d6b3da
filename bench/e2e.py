"""End-to-end protection of every frame: CRC-8 SAE J1850, a 4-bit alive counter and an implicit
freshness byte.

CRC-8 SAE J1850: polynomial 0x1D, initial value 0xFF, final XOR 0xFF, no reflection; check value
0x4B for the ASCII bytes "123456789". The CRC of a frame covers the two bytes of its
identifier (low byte first, a "data ID" as in AUTOSAR E2E profiles, so a payload that arrives
under the wrong identifier fails), one **freshness byte** and every payload byte except byte 0,
which holds the CRC. The freshness byte is bits 4–11 of the controller cycle the frame belongs
to (:func:`freshness`): for the controller's frames the cycle they are sent in, for a node's the
heartbeat it echoes. It is not sent — the 4-bit counter or echo carries bits 0–3 and the receiver
knows the rest — so a frame replayed or kept back 16 to 4 095 cycles fails its CRC: the two
freshness bytes differ, and a CRC-8 detects every difference within 8 adjacent bits. The heartbeat
carries bits 4–11 in the clear as well (``CONTROLLER_STATUS.cycle_high``), which is how the nodes
learn them.
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
CYCLE_MODULO = 4096  # the cycle the counter (bits 0–3) and the freshness byte (bits 4–11) tell
HEARTBEAT_ID = 0x080  # CONTROLLER_STATUS (design.network.protocol.CONTROLLER_ID)
HEARTBEAT_CYCLE_BYTE = 6  # CONTROLLER_STATUS.cycle_high: the heartbeat's bits 4–11 in the clear


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


def freshness(cycle: int) -> int:
    """The freshness byte of a frame of controller cycle ``cycle``: its bits 4–11.

    Examples
    --------
    >>> freshness(0x1234)
    35
    """
    return (cycle >> 4) & 0xFF


def echoed_cycle(heartbeat: int, echo: int) -> int:
    """The cycle a node's frame echoes: the latest cycle up to ``heartbeat`` (the receiver's newest
    heartbeat) whose bits 0–3 are ``echo`` — the frame is taken to be 0…15 cycles old, and its CRC
    fails if it is older (up to 4 095 cycles).

    Examples
    --------
    >>> echoed_cycle(0x123, 0x2), echoed_cycle(0x123, 0x4)
    (290, 276)
    """
    return (heartbeat - ((heartbeat - echo) % COUNTER_MODULO)) % CYCLE_MODULO


def nearest_cycle(reference: int, counter: int) -> int:
    """The cycle with bits 0–3 ``counter`` nearest to ``reference`` (−8 … +7 cycles): an amplifier's
    reading of a setpoint's cycle from its last heartbeat.

    Examples
    --------
    >>> nearest_cycle(0x10F, 0x1), nearest_cycle(0x110, 0xF)
    (273, 271)
    """
    return (reference + (counter - reference + 8) % COUNTER_MODULO - 8) % CYCLE_MODULO


def frame_crc(frame_id: int, payload: bytes | bytearray, fresh: int = 0) -> int:
    """The CRC of byte 0 of a frame.

    Parameters
    ----------
    frame_id : int
        The frame's identifier (its two low bytes are covered, low byte first).
    payload : bytes
        The frame's payload; bytes 1… are covered.
    fresh : int
        The freshness byte (:func:`freshness` of the frame's cycle), covered after the identifier.

    Returns
    -------
    int
        The CRC, 0…255.
    """
    return crc8(bytes((frame_id & 0xFF, (frame_id >> 8) & 0xFF, fresh & 0xFF)) + bytes(payload[1:]))


def freshness_of(frame_id: int, payload: bytes | bytearray) -> int | None:
    """The freshness byte a frame's CRC holds with; None for a frame too short to carry one.

    One byte of a CRC-8's input maps one to one onto the CRC, so every frame has exactly one such
    byte — for an intact frame the one its sender protected it with, for a damaged one some byte.
    Fault injection uses it to re-protect a sender's frame it alters as the sender would have.
    """
    if len(payload) < 2:
        return None
    return next(f for f in range(256) if payload[0] == frame_crc(frame_id, payload, f))


def protect(frame_id: int, payload: bytearray, counter: int, fresh: int = 0) -> bytearray:
    """Write the alive counter (low nibble of byte 1) and then the CRC (byte 0) into a payload.

    Parameters
    ----------
    frame_id : int
        The frame's identifier.
    payload : bytearray
        The payload, at least 2 bytes; changed in place.
    counter : int
        The alive counter (taken modulo 16).
    fresh : int
        The freshness byte (:func:`freshness`).

    Returns
    -------
    bytearray
        ``payload``.
    """
    if len(payload) < 2:
        raise ValueError(f"payload: {len(payload)} bytes — a protected frame needs at least 2 (CRC, counter)")
    payload[1] = (payload[1] & 0xF0) | (counter % COUNTER_MODULO)
    payload[0] = frame_crc(frame_id, payload, fresh)
    return payload


@dataclass(frozen=True)
class Check:
    """Result of checking one received frame."""

    crc_ok: bool
    counter: int
    counter_step: int | None  # steps since the last accepted counter; None for the first frame
    modulo: int = COUNTER_MODULO  # 16 for the alive counter, 4096 for a heartbeat's cycle

    @property
    def ok(self) -> bool:
        return self.crc_ok and (self.counter_step is None or 1 <= self.counter_step <= MAX_COUNTER_STEP)

    @property
    def reason(self) -> str:
        if not self.crc_ok:
            return "crc"
        if self.counter_step == 0:
            return "counter repeated"
        if self.counter_step is not None and self.counter_step >= self.modulo // 2:
            return "counter stale"
        if self.counter_step is not None and self.counter_step > MAX_COUNTER_STEP:
            return "counter jump"
        return "ok"

    @property
    def resynchronises(self) -> bool:
        """Whether a receiver follows this frame's counter (all but a bad CRC, a repeat, a stale frame)."""
        return self.crc_ok and self.reason not in ("counter repeated", "counter stale")


def check(frame_id: int, payload: bytes, last_counter: int | None, fresh: int = 0, cycle: int | None = None) -> Check:
    """Check CRC and alive counter of a received frame against the last accepted counter.

    Parameters
    ----------
    frame_id : int
        The identifier the frame arrived under.
    payload : bytes
        The received payload.
    last_counter : int or None
        The receiver's last accepted counter; None before the first frame.
    fresh : int
        The freshness byte the receiver expects.
    cycle : int, optional
        The frame's whole 12-bit cycle as the receiver reads it (bits 0–3 the counter's): its
        step from ``last_counter`` is then taken modulo 4096, so a stream that steps back by
        8…15 cycles is not read as a jump ahead.

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
    counter, modulo = (payload[1] & 0x0F, COUNTER_MODULO) if cycle is None else (cycle % CYCLE_MODULO, CYCLE_MODULO)
    step = None if last_counter is None else (counter - last_counter) % modulo
    return Check(payload[0] == frame_crc(frame_id, payload, fresh), counter, step, modulo)


def check_heartbeat(frame_id: int, payload: bytes, last_cycle: int | None) -> Check:
    """Check a heartbeat: its CRC with the freshness byte it carries in the clear, and its whole
    12-bit cycle (``cycle_high``·16 + counter) against the last accepted one (``last_cycle``,
    None before the first; ``frame_id`` and ``payload`` as for :func:`check`).

    A step of 1…3 is fresh; a repeat, a jump of 4…2047 and a cycle behind (2048…4095 ahead) are
    not — so a heartbeat stream replayed 16·m cycles old, whose 4-bit counter runs on as if
    fresh, is stale here. The returned ``counter`` is the heartbeat's 12-bit cycle and
    ``counter_step`` its step, modulo 4096.
    """
    payload = bytes(payload)
    if len(payload) <= HEARTBEAT_CYCLE_BYTE:
        return Check(False, 0, None, CYCLE_MODULO)
    fresh = payload[HEARTBEAT_CYCLE_BYTE]
    return check(frame_id, payload, last_cycle, fresh, fresh << 4 | payload[1] & 0x0F)


class LogFreshness:
    """The freshness byte of each frame of a recorded stream, from the heartbeats in it.

    Fed the frames in the order they were logged. A heartbeat (its CRC holding with the byte it
    carries) sets the cycle; between two, the cycle runs on with the time stamps (one per
    ``sample_time``). A frame that echoes the heartbeat (``echoes``: the identifiers with a
    ``sync`` signal) belongs to the latest cycle with its echo's bits 0–3, any other frame to the
    cycle with its counter's bits nearest the running cycle (the controller sends its setpoints
    just before the heartbeat of the same cycle), and a valid one sets the cycle too. Before the
    first heartbeat the cycle is 0, which is right for a log from power-up; a log started later
    has the frames before its first heartbeat counted as failing their CRC, as is a node frame
    that echoes a heartbeat 16 or more cycles old.

    Parameters
    ----------
    echoes : iterable of int
        The identifiers of the frames that carry the heartbeat echo.
    sample_time : float, optional
        The controller's sample time [s]; None: the cycle moves only with the frames.
    """

    def __init__(self, echoes=(), sample_time: float | None = None):
        self.echoes = frozenset(echoes)
        self.sample_time = sample_time
        self.cycle = 0
        self.time: float | None = None  # when the cycle was last set

    def _running(self, time: float | None) -> int:
        if time is None or self.time is None or not self.sample_time:
            return self.cycle
        return (self.cycle + max(round((time - self.time) / self.sample_time), 0)) % CYCLE_MODULO

    def _set(self, cycle: int, time: float | None) -> None:
        self.cycle = cycle
        self.time = time if time is not None else self.time

    def crc_ok(self, frame_id: int, payload: bytes, time: float | None = None) -> bool:
        """Whether a logged frame's CRC holds with the freshness byte of its place in the log
        (``time``: its time stamp [s])."""
        payload = bytes(payload)
        if len(payload) < 2:
            return False
        if frame_id == HEARTBEAT_ID:
            checked = check_heartbeat(frame_id, payload, None)
            # Once the cycle is known, a heartbeat more than 8 cycles from it is a stale or
            # replayed one: it fails, and the cycle stays.
            running = self._running(time)
            near = self.time is None or (checked.counter - running + 8) % CYCLE_MODULO < 16
            if checked.crc_ok and near:
                self._set(checked.counter, time)
            return checked.crc_ok and near
        running = self._running(time)
        if frame_id in self.echoes:
            return payload[0] == frame_crc(frame_id, payload, freshness(echoed_cycle(running, payload[1] >> 4)))
        cycle = nearest_cycle(running, payload[1] & 0x0F)
        ok = payload[0] == frame_crc(frame_id, payload, freshness(cycle))
        if ok:
            self._set(cycle, time)
        return ok


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
