"""The fault injector between a sender and the bus: what each frame fault does to a frame.

``SilLoop`` hands every frame it puts on a bus to :meth:`FaultInjector.alter`, which returns the
frames that really go out (none, the frame, an altered frame, a copy more) and keeps what a
fault holds back (``delay``) until :meth:`FaultInjector.due`. A frame the injector alters keeps
its sender's E2E protection: it is re-protected with the freshness byte its own CRC tells
(``e2e.freshness_of``), so the receiver sees a sender that misbehaves, not a damaged frame —
except under ``corrupt_crc``. The fault kinds and their spelling: ``bench/faults.py``.
"""

from __future__ import annotations

from collections import defaultdict, deque

from smartjoint.bench import e2e
from smartjoint.bench.faults import Fault
from smartjoint.common.errors import ModelError

# The lengths a CAN (FD) frame can have: ``wrong_dlc`` sends the next shorter one.
FRAME_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


class FaultInjector:
    """The frame faults of a run, applied frame by frame.

    Parameters
    ----------
    faults : list of Fault
        The run's faults (checked: ``bench.faults.check_faults``).
    db : cantools.database.can.Database
        Every frame of the bus (its messages give the signals of ``implausible``).
    frame : callable
        ``frame(frame_id, data, t)`` → a ``can.Message`` as the loop sends it.
    """

    def __init__(self, faults, db, frame) -> None:
        self.faults = list(faults)
        self.db = db
        self.frame = frame
        self.stats: defaultdict[str, int] = defaultdict(int)
        self.delayed: list[tuple] = []  # (due time, bus handle, message, bus index)
        self.frozen_counters: dict = {}  # corrupt_counter: the counter each fault froze
        depth = max((f.age + 1 for f in self.faults if f.kind == "replay"), default=0)
        # replay: per frame and bus the frames its sender sent, newest last (what a replay repeats)
        self.sent: defaultdict[tuple, deque] = defaultdict(lambda: deque(maxlen=depth))

    def alter(self, bus, message, name: str, t: float, index: int) -> list:
        """The frames that go out on bus ``index`` for ``message`` (frame ``name``) sent at ``t``.

        Parameters
        ----------
        bus : can.BusABC
            The sender's handle (a delayed frame goes out from it later).
        message : can.Message
            The frame as its sender made it.
        name : str
            The frame's name.
        t : float
            The sample time [s].
        index : int
            The bus's index in the plan.

        Returns
        -------
        list of can.Message
            What goes on the bus now.
        """
        history = self.sent[name, index] if self._replays(name) else None
        if history is not None:
            history.append(message)  # what the sender sent, before any fault
        frame, copies = message, 1
        for f in self.faults:  # in order; the first that withholds the frame ends it
            if f.target != name or not f.active(t):
                continue
            self.stats[f"injected_{f.kind}"] += 1
            if f.kind in ("drop", "silent"):
                return []
            if f.kind == "delay":
                self.delayed.append((t + f.lateness, bus, frame, index))
                return []
            if f.kind == "duplicate":
                copies = 2
            else:
                frame = self._altered(frame, f, t, history)
                if frame is None:  # a replay before its sender has sent that many frames
                    return []
        return [frame] * copies

    def _replays(self, name: str) -> bool:
        return any(f.kind == "replay" and f.target == name for f in self.faults)

    def _altered(self, message, f: Fault, t: float, history):
        """``message`` under a fault that changes its bytes (or replaces it: ``replay``)."""
        import can

        if f.kind == "corrupt_crc":
            data = bytearray(message.data)
            data[-1] ^= 0x5A
            return self.frame(message.arbitration_id, bytes(data), t)
        if f.kind == "corrupt_counter":  # a sender whose counter froze: valid CRC, the same counter again
            frozen = self.frozen_counters.setdefault(id(f), message.data[1] & 0x0F)
            return self._reprotected(message, bytearray(message.data), frozen, t)
        if f.kind == "wrong_dlc":
            shorter = max(n for n in FRAME_LENGTHS if n < len(message.data))
            return can.Message(
                arbitration_id=message.arbitration_id,
                data=bytes(message.data[:shorter]),
                is_fd=message.is_fd,
                bitrate_switch=message.bitrate_switch,
                timestamp=t,
            )
        if f.kind == "implausible":
            return self._implausible(message, f, t)
        if f.kind == "replay":  # the frame its sender sent f.age frames ago, as it was; none before then
            if history is None or len(history) <= f.age:
                return None
            old = history[-1 - f.age]
            return self.frame(old.arbitration_id, bytes(old.data), t)
        return message

    def _reprotected(self, message, data: bytearray, counter: int, t: float):
        # The byte its CRC holds with: the sender's own when the frame is intact (as it is under
        # these faults, which act on the sender's frames; a damaged frame maps to some byte too).
        fresh = e2e.freshness_of(message.arbitration_id, bytes(message.data))
        data = e2e.protect(message.arbitration_id, data, counter, 0 if fresh is None else fresh)
        return self.frame(message.arbitration_id, bytes(data), t)

    def _implausible(self, message, f: Fault, t: float):
        """The frame with ``f.value`` in ``f.signal``, re-protected with its own counter: a sender
        whose sensor or stage is broken, not a damaged frame."""
        m = self.db.get_message_by_frame_id(message.arbitration_id)
        values = m.decode(bytes(message.data), decode_choices=False, scaling=True)
        values[f.signal] = f.value
        signal = m.get_signal_by_name(f.signal)
        raw = round((f.value - signal.offset) / signal.scale)
        low = -(2 ** (signal.length - 1)) if signal.is_signed else 0
        high = 2 ** (signal.length - 1) - 1 if signal.is_signed else 2**signal.length - 1
        if not low <= raw <= high:
            raise ModelError(
                f"fault implausible: value {f.value!r} — {m.name}.{f.signal} carries "
                f"{low * signal.scale + signal.offset:g} … {high * signal.scale + signal.offset:g}"
            )
        data = bytearray(m.encode(values, strict=False, scaling=True))
        return self._reprotected(message, data, message.data[1] & 0x0F, t)

    def due(self, t: float, senders) -> list[tuple]:
        """The delayed frames of the ``senders``' side due by ``t``: (bus handle, message, index)."""
        mine = lambda bus, when: any(bus is s for s in senders) and when <= t + 1e-12  # noqa: E731
        out = [(bus, m, k) for when, bus, m, k in self.delayed if mine(bus, when)]
        self.delayed = [d for d in self.delayed if not mine(d[1], d[0])]
        return out
