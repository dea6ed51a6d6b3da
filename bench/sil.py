"""Software-in-the-loop bench: plant ↔ sensor frames ↔ compiled firmware ↔ setpoint frames ↔
amplifier models ↔ normal forces, on a python-can bus, one controller sample at a time.

Per sample t_k (the plant simulation calls ``SilLoop.step`` as its controller):

1. the sensor nodes send ``JOINT_<j>`` (v, u_R, F_N) and ``TIP_SENSORS`` (y), each amplifier its
   ``AMP_STATUS`` — all E2E-protected; the fault injector may drop, delay,
   duplicate or corrupt them, silence a node, take the bus off;
2. the firmware takes every frame waiting for it (``rx``), runs ``step`` and sends what ``tx``
   gives (the setpoints, every 10th sample its status);
3. each amplifier checks and decodes its setpoint, and its output over [t_k, t_k+1) sets the
   normal force of its joint (the mean over the sample; F_N^max while the study's pulse acts,
   the protocol of Section 6);
4. a logger on the same bus writes every frame with the simulated time stamp (python-can
   writers: .blf, .asc, .mf4 …).

The default bus is python-can's in-process ``virtual`` interface; any other python-can interface
name (and channel) runs the same code against real hardware.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from ..design.errors import ModelError
from ..design.simulate import Measurements
from . import e2e
from .amplifier import FAULTS as AMPLIFIER_FAULTS
from .amplifier import AmplifierModel

FRAME_FAULTS = ("drop", "delay", "duplicate", "corrupt_crc", "corrupt_counter", "wrong_dlc", "silent")
BUS_FAULTS = ("bus_off",)


@dataclass(frozen=True)
class Fault:
    """One injected fault on [start, end) s. ``target``: a frame name for frame faults (e.g.
    "JOINT_A1", "TIP_SENSORS"), a joint name for ``amplifier`` (with ``amplifier_fault``)."""

    kind: str
    start: float
    end: float
    target: str = ""
    amplifier_fault: str = ""
    delay: float = 0.005  # s, for "delay"

    def active(self, t: float) -> bool:
        return self.start - 1e-12 <= t < self.end - 1e-12


def check_faults(faults, frame_names, joint_names) -> None:
    for f in faults:
        if f.kind in FRAME_FAULTS:
            if f.target not in frame_names:
                raise ModelError(f"fault {f.kind}: target {f.target!r} — a frame the bench sends: "
                                 f"{', '.join(sorted(frame_names))}")
        elif f.kind == "amplifier":
            if f.target not in joint_names or f.amplifier_fault not in AMPLIFIER_FAULTS:
                raise ModelError(f"fault amplifier: target {f.target!r} / {f.amplifier_fault!r} — a joint "
                                 f"({', '.join(joint_names)}) and one of {', '.join(AMPLIFIER_FAULTS)}")
        elif f.kind not in BUS_FAULTS:
            raise ModelError(f"fault kind {f.kind!r} — allowed: {', '.join(FRAME_FAULTS + ('amplifier',) + BUS_FAULTS)}")
        if not (math.isfinite(f.start) and math.isfinite(f.end) and 0 <= f.start < f.end):
            raise ModelError(f"fault {f.kind}: window [{f.start!r}, {f.end!r}) — need 0 <= start < end")


def open_bus(interface: str, channel: str, **kwargs):
    """A python-can bus, with a clear message when the interface is not installed."""
    import can

    try:
        return can.Bus(interface=interface, channel=channel, **kwargs)
    except (ImportError, can.CanInterfaceNotImplementedError, can.CanInitializationError, ValueError, OSError) as error:
        known = ", ".join(sorted(can.interfaces.VALID_INTERFACES))
        raise ModelError(f"bench interface {interface!r} (channel {channel!r}) cannot be opened: {error} — "
                         f"python-can knows: {known}") from None


@dataclass
class SilRecord:
    """Per controller sample: firmware safe flag, step status, commanded and applied F_N."""

    time: list = field(default_factory=list)
    safe: list = field(default_factory=list)
    status: list = field(default_factory=list)
    command: list = field(default_factory=list)
    applied: list = field(default_factory=list)


class SilLoop:
    """The CAN loop behind the simulation's controller interface."""

    def __init__(self, firmware, excitation_end: float = 0.0, excitation_force=None, faults=(),
                 interface: str = "virtual", channel: str = "smartjoint-sil", log_path=None,
                 amplifier: dict | None = None):
        self.fw = firmware
        self.db = firmware.db
        a = firmware.artifact
        self.sample_time = float(a.sample_time)
        self.joints = [j.upper() for j in a.joint_names]
        self.sensor_signals = [s.lower() for s in a.sensor_names]
        self.excitation_end = float(excitation_end)
        self.excitation_force = np.asarray(a.normal_force_max if excitation_force is None else excitation_force, float)
        names = {m.name for m in self.db.messages}
        check_faults(faults, names, [j for j in a.joint_names])
        self.faults = list(faults)
        self.interface, self.channel, self.log_path = interface, channel, log_path
        self.amplifier_options = dict(force_per_volt=a.piezo_force_per_volt, preload=a.piezo_preload,
                                      capacitance=a.piezo_capacitance, **(amplifier or {}))
        self.frames = {m.name: m for m in self.db.messages}
        self.buses = []

    # ------------------------------------------------------------------ set-up and tear-down
    def reset(self) -> None:
        self.close()
        self.node_bus = open_bus(self.interface, self.channel, preserve_timestamps=True)
        self.firmware_bus = open_bus(self.interface, self.channel, preserve_timestamps=True)
        self.log_bus = open_bus(self.interface, self.channel, preserve_timestamps=True)
        self.buses = [self.node_bus, self.firmware_bus, self.log_bus]
        self.writer = None
        if self.log_path is not None:
            import can

            self.writer = can.Logger(str(self.log_path))
        self.fw.reset()
        self.amplifiers = [AmplifierModel(**self.amplifier_options) for _ in self.joints]
        self.counters = defaultdict(int)
        self.setpoint_last = [None] * len(self.joints)
        self.delayed = []  # (due time, message)
        self.k = 0
        self.record = SilRecord()
        self.stats = defaultdict(int)
        self.frame_counts = defaultdict(int)
        self.amplifier_e2e_errors = 0

    def close(self) -> None:
        for bus in self.buses:
            bus.shutdown()
        self.buses = []
        if getattr(self, "writer", None) is not None:
            self.writer.stop()
            self.writer = None

    # ------------------------------------------------------------------------------ frames
    def _message(self, name: str, values: dict, t: float):
        import can

        m = self.frames[name]
        counter = self.counters[name]
        self.counters[name] = (counter + 1) % e2e.COUNTER_MODULO
        signals = {s.name: 0 for s in m.signals}
        signals.update(values)
        for s in m.signals:  # clamp to the signal's range before packing, as the firmware does
            if s.minimum is not None:
                signals[s.name] = min(max(signals[s.name], s.minimum), s.maximum)
        data = e2e.protect(m.frame_id, bytearray(m.encode(signals, strict=False)), counter)
        return can.Message(arbitration_id=m.frame_id, data=bytes(data), is_extended_id=False, is_fd=m.is_fd,
                           bitrate_switch=m.is_fd, timestamp=t)

    def _send_from_nodes(self, message, t: float) -> None:
        import can

        name = self.db.get_message_by_frame_id(message.arbitration_id).name
        if any(f.kind == "bus_off" and f.active(t) for f in self.faults):
            self.stats["frames_lost_bus_off"] += 1
            return
        for f in self.faults:
            if f.target != name or not f.active(t):
                continue
            self.stats[f"injected_{f.kind}"] += 1
            if f.kind in ("drop", "silent"):
                return
            if f.kind == "delay":
                self.delayed.append((t + f.delay, message))
                return
            if f.kind == "duplicate":
                self.node_bus.send(message)
            elif f.kind == "corrupt_crc":
                data = bytearray(message.data)
                data[-1] ^= 0x5A
                message = can.Message(arbitration_id=message.arbitration_id, data=bytes(data), is_fd=message.is_fd,
                                      bitrate_switch=message.bitrate_switch, timestamp=t)
            elif f.kind == "corrupt_counter":
                data = bytearray(message.data)
                data = e2e.protect(message.arbitration_id, data, (data[1] + 7) & 0x0F)  # valid CRC, wrong counter
                message = can.Message(arbitration_id=message.arbitration_id, data=bytes(data), is_fd=message.is_fd,
                                      bitrate_switch=message.bitrate_switch, timestamp=t)
            elif f.kind == "wrong_dlc":
                message = can.Message(arbitration_id=message.arbitration_id, data=bytes(message.data[:8]),
                                      is_fd=False, timestamp=t)
        self.node_bus.send(message)
        self.frame_counts[name] += 1

    def _drain(self, bus) -> list:
        out = []
        while True:
            message = bus.recv(timeout=0.0)
            if message is None:
                return out
            out.append(message)

    # ------------------------------------------------------------------------------ a sample
    def step(self, measurements: Measurements) -> np.ndarray:
        import can

        t = float(measurements.time)
        time_us = int(round(t * 1e6))
        for j, joint in enumerate(self.joints):
            self._send_from_nodes(self._message(f"JOINT_{joint}", {
                "sliding_velocity": float(measurements.sliding_velocity[j]),
                "friction_force": float(measurements.friction_force[j]),
                "normal_force": float(measurements.normal_force[j])}, t), t)
        self._send_from_nodes(self._message("TIP_SENSORS", dict(zip(self.sensor_signals,
                                                                  map(float, measurements.sensors))), t), t)
        for j, joint in enumerate(self.joints):  # amplifier status every sample: faults seen within a cycle
            fault = next((f.amplifier_fault for f in self.faults
                          if f.kind == "amplifier" and f.target.upper() == joint and f.active(t)), None)
            self.amplifiers[j].fault = fault
            status = self.amplifiers[j].status()
            if status is not None:
                self._send_from_nodes(self._message(f"AMP_STATUS_{joint}", status, t), t)
        due = [m for when, m in self.delayed if when <= t + 1e-12]
        self.delayed = [(when, m) for when, m in self.delayed if when > t + 1e-12]
        for message in due:
            message.timestamp = t
            self.node_bus.send(message)

        bus_off = any(f.kind == "bus_off" and f.active(t) for f in self.faults)
        for message in self._drain(self.firmware_bus):
            self.fw.rx(message.arbitration_id, bytes(message.data), time_us)
        status = self.fw.step(time_us)
        for frame_id, data in self.fw.tx():
            if bus_off:
                continue
            m = self.db.get_message_by_frame_id(frame_id)
            self.firmware_bus.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False,
                                               is_fd=m.is_fd, bitrate_switch=m.is_fd, timestamp=t))
            self.frame_counts[m.name] += 1

        for message in self._drain(self.node_bus):
            name = self.db.get_message_by_frame_id(message.arbitration_id).name
            if not name.startswith("SETPOINT_"):
                continue
            j = self.joints.index(name[len("SETPOINT_"):])
            checked = e2e.check(message.arbitration_id, message.data, self.setpoint_last[j])
            if not checked.ok or len(message.data) != self.frames[name].length:
                self.amplifier_e2e_errors += 1
                continue
            self.setpoint_last[j] = checked.counter
            voltage = self.frames[name].decode(bytes(message.data), decode_choices=False)["voltage"]
            self.amplifiers[j].receive(voltage)
        applied = np.array([a.advance(self.sample_time) for a in self.amplifiers])
        if t < self.excitation_end - 1e-12:
            applied = self.excitation_force.copy()  # the study's protocol: F_N^max while the pulse acts
        if self.writer is not None:
            for message in self._drain(self.log_bus):
                self.writer.on_message_received(message)
        else:
            self._drain(self.log_bus)
        r = self.record
        r.time.append(t)
        r.safe.append(self.fw.safe)
        r.status.append(status)
        r.command.append(self.fw.command)
        r.applied.append(applied)
        self.k += 1
        return np.maximum(applied, 0.0)

    def statistics(self, duration: float, bitrate: int, data_bitrate: int | None) -> dict:
        """Frames per name, measured worst-case bus load over the run, E2E errors, timeouts."""
        from .busload import _frame_time

        busy = sum(count * _frame_time(self.frames[name].length, self.frames[name].is_fd, bitrate, data_bitrate)
                   for name, count in self.frame_counts.items())
        counters = self.fw.counters
        return {"frames": dict(sorted(self.frame_counts.items())), "frames_total": int(sum(self.frame_counts.values())),
                "bus_load": busy / duration, "bitrate": bitrate, "data_bitrate": data_bitrate,
                "firmware": counters,
                "e2e_errors": counters["crc_errors"] + counters["counter_errors"] + counters["length_errors"],
                "amplifier_e2e_errors": self.amplifier_e2e_errors,
                "safe_samples": int(sum(self.record.safe)), "injected": dict(self.stats)}
