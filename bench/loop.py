"""Software-in-the-loop bench: plant ↔ sensor frames ↔ compiled firmware ↔ setpoint frames ↔
amplifier models ↔ normal forces, on a python-can bus, one controller sample at a time.

Per sample t_k (the plant simulation calls ``SilLoop.step`` as its controller):

1. the sensor nodes send ``JOINT_<j>`` (v, u_R, F_N) and ``TIP_SENSORS`` (y), each amplifier its
   ``AMP_STATUS`` — all E2E-protected, echoing the last heartbeat; the fault injector may drop,
   delay, duplicate, corrupt or fill with implausible values any frame (the firmware's too),
   silence a node, take the bus off;
2. the firmware takes every frame waiting for it (``rx``), runs ``step`` and sends what ``tx``
   gives (the setpoints and the heartbeat, every sample);
3. each amplifier checks its setpoint and the heartbeat (its own watchdog: ``bench/amplifier.py``),
   and its output over [t_k, t_k+1) sets the normal force of its joint (the mean over the sample;
   F_N^max while the study's pulse acts, the protocol of Section 6);
4. a logger on the same bus writes every frame with the simulated time stamp (python-can
   writers: .blf, .asc, .mf4 …).

The default bus is python-can's in-process ``virtual`` interface; any other python-can interface
name (and channel) runs the same code against real hardware. A firmware built for several buses
(``design.network.plan``) gets one python-can bus per bus of its plan, channel
``<channel>.<bus name>`` (one bus: ``<channel>`` itself): each joint's node and amplifier on the
bus of its joint, the tip sensors on the first, the heartbeat on every bus.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from smartjoint.bench import e2e
from smartjoint.bench.amplifier import AmplifierModel, amplifier_options
from smartjoint.bench.fault_injection import FaultInjector
from smartjoint.bench.faults import check_faults
from smartjoint.common.errors import ModelError
from smartjoint.design.network import busload
from smartjoint.design.plant.interface import Measurements

HEARTBEAT = "CONTROLLER_STATUS"  # the controller's heartbeat: on every bus


def open_bus(interface: str, channel: str, **kwargs):
    """Open a python-can bus (CAN FD), with a clear message when the interface is not installed.

    Parameters
    ----------
    interface : str
        A python-can interface name (``virtual``, ``socketcan``, …).
    channel : str
        The channel of that interface.
    **kwargs
        Passed to ``can.Bus``.

    Returns
    -------
    can.BusABC
        The open bus.

    Raises
    ------
    ModelError
        The interface cannot be opened; the message lists what python-can knows.
    """
    import can

    try:
        return can.Bus(interface=interface, channel=channel, fd=True, **kwargs)  # the protocol is CAN FD
    except (ImportError, can.CanInterfaceNotImplementedError, can.CanInitializationError, ValueError, OSError) as error:
        known = ", ".join(sorted(can.interfaces.VALID_INTERFACES))
        raise ModelError(
            f"bench interface {interface!r} (channel {channel!r}) cannot be opened: {error} — python-can knows: {known}"
        ) from None


@dataclass
class SilRecord:
    """Per controller sample: firmware safe flag, step status and fault bits, commanded F_N,
    the F_N the amplifiers really apply, their own safe state, and F_N as the plant gets it
    (the study's pulse protocol holds F_N^max while the pulse acts)."""

    time: list = field(default_factory=list)
    safe: list = field(default_factory=list)
    status: list = field(default_factory=list)
    faults: list = field(default_factory=list)
    command: list = field(default_factory=list)
    amplifier_force: list = field(default_factory=list)
    amplifier_safe: list = field(default_factory=list)
    applied: list = field(default_factory=list)
    bus_safe: list = field(default_factory=list)  # per bus of the plan: its joints hold the safe force
    failed: list = field(default_factory=list)  # per joint: its heartbeat's failed_<joint> (actuation check)


class SilLoop:
    """The CAN loop behind the simulation's controller interface.

    Parameters
    ----------
    firmware : bench.firmware.Firmware
        The compiled firmware image.
    excitation_end : float
        End of the study's pulse [s]: until then the plant gets ``excitation_force``.
    excitation_force : array_like, optional
        F_N while the pulse acts [N]; default the artefact's F_N^max.
    faults : iterable of Fault
        The faults to inject (``bench/faults.py``).
    interface, channel : str
        The python-can bus (default the in-process ``virtual`` one).
    log_path : path, optional
        A log file every frame is written to (python-can writers by suffix).
    amplifier : dict, optional
        Options of the amplifier models (``time_constant``, ``slew_rate``, ``temperature``,
        ``voltage_max``).
    """

    def __init__(
        self,
        firmware,
        excitation_end: float = 0.0,
        excitation_force=None,
        faults=(),
        interface: str = "virtual",
        channel: str = "smartjoint-sil",
        log_path=None,
        amplifier: dict | None = None,
    ):
        self.fw = firmware
        self.db = firmware.db
        a = firmware.artifact
        self.sample_time = float(a.sample_time)
        self.joints = [j.upper() for j in a.joint_names]
        self.sensor_signals = [s.lower() for s in a.sensor_names]
        self.excitation_end = float(excitation_end)
        self.excitation_force = np.asarray(a.normal_force_max if excitation_force is None else excitation_force, float)
        names = {m.name for m in self.db.messages}
        signals = {m.name: [s.name for s in m.signals if s.name not in ("crc", "counter")] for m in self.db.messages}
        self.bus_names = [p.bus.name for p in firmware.network.buses]
        check_faults(faults, names, [j for j in a.joint_names], signals, self.bus_names)
        self.faults = list(faults)
        self.interface, self.channel, self.log_path = interface, channel, log_path
        self.amplifier_options = amplifier_options(a, amplifier)
        self.frames = {m.name: m for m in self.db.messages}
        # the bus of every joint, and of every frame but the heartbeat (which is on every bus)
        self.joint_bus = [next(b for b, p in enumerate(firmware.network.buses) if j in p.joints) for j in a.joint_names]
        self.frame_bus = {
            m.name: b for b, p in enumerate(firmware.network.buses) for m in p.database.messages if m.name != HEARTBEAT
        }
        self.buses: list = []
        self.writer: Any = None  # a python-can writer while a log is kept

    # ------------------------------------------------------------------ set-up and tear-down
    def reset(self) -> None:
        """Open the buses, reset the firmware and the amplifiers: a run starts."""
        self.close()
        channels = [self.channel] if len(self.bus_names) == 1 else [f"{self.channel}.{n}" for n in self.bus_names]
        try:
            for channel in channels:  # per bus: the nodes' side, the firmware's side, the logger
                for _ in range(3):
                    self.buses.append(open_bus(self.interface, channel, preserve_timestamps=True))
        except BaseException:
            self.close()
            raise
        self.node_buses, self.firmware_buses, self.log_buses = self.buses[0::3], self.buses[1::3], self.buses[2::3]
        self.writer = None
        if self.log_path is not None:
            import can

            self.writer = can.Logger(str(self.log_path))
        self.fw.reset()
        self.amplifiers = [AmplifierModel(**options) for options in self.amplifier_options]
        self.counters: defaultdict[str, int] = defaultdict(int)
        self.injector = FaultInjector(self.faults, self.db, self._frame)
        # per bus: the heartbeat's counter (its bits 0-3) and cycle_high (bits 4-11) its sensor nodes last saw
        self.node_echo = [0] * len(self.bus_names)
        self.node_freshness = [0] * len(self.bus_names)
        self.k = 0
        self.record = SilRecord()
        self.stats = self.injector.stats
        self.frame_counts: defaultdict[str, int] = defaultdict(int)
        self.bus_frame_counts: list[defaultdict[str, int]] = [defaultdict(int) for _ in self.bus_names]
        self.amplifier_e2e_errors = 0
        self.failed = [False] * len(self.joints)

    def close(self) -> None:
        """Shut the buses and stop the log writer (whatever fails, the others are still closed)."""
        buses, self.buses = self.buses, []
        writer, self.writer = getattr(self, "writer", None), None
        try:
            for bus in buses:
                try:
                    bus.shutdown()
                except Exception:  # keep closing the others
                    pass
        finally:
            if writer is not None:
                writer.stop()

    # ------------------------------------------------------------------------------ frames
    def _message(self, name: str, values: dict, t: float, fresh: int = 0):
        m = self.frames[name]
        counter = self.counters[name]
        self.counters[name] = (counter + 1) % e2e.COUNTER_MODULO
        signals = {s.name: 0 for s in m.signals}
        signals.update(values)
        for s in m.signals:  # clamp to the signal's range before packing, as the firmware does
            if signals[s.name] != signals[s.name]:  # NaN packs as raw 0
                signals[s.name] = s.offset
            elif s.minimum is not None:
                signals[s.name] = min(max(signals[s.name], s.minimum), s.maximum)
        data = e2e.protect(m.frame_id, bytearray(m.encode(signals, strict=False)), counter, fresh)
        return self._frame(m.frame_id, bytes(data), t)

    def _frame(self, frame_id: int, data: bytes, t: float):
        import can

        m = self.db.get_message_by_frame_id(frame_id)
        return can.Message(
            arbitration_id=frame_id, data=data, is_extended_id=False, is_fd=m.is_fd, bitrate_switch=m.is_fd, timestamp=t
        )

    def _bus_off(self, t: float, index: int) -> bool:
        """Bus ``index`` is off at ``t``: a ``bus_off`` fault on it, or on every bus (no target)."""
        return any(f.kind == "bus_off" and f.target in ("", self.bus_names[index]) and f.active(t) for f in self.faults)

    def _count(self, name: str, index: int) -> None:
        self.frame_counts[name] += 1
        self.bus_frame_counts[index][name] += 1

    def _transmit(self, bus, message, t: float, index: int = 0) -> None:
        """Put ``message`` on bus ``index`` from ``bus``'s side, through the fault injector."""
        name = self.db.get_message_by_frame_id(message.arbitration_id).name
        if self._bus_off(t, index):
            self.stats["frames_lost_bus_off"] += 1
            return
        for copy in self.injector.alter(bus, message, name, t, index):
            bus.send(copy)
            self._count(name, index)

    def _release_delayed(self, t: float, senders) -> None:
        """Late frames of the ``senders``' side go out at the first sample after their delay."""
        for bus, message, index in self.injector.due(t, senders):
            if self._bus_off(t, index):
                self.stats["frames_lost_bus_off"] += 1
                continue
            message.timestamp = t
            bus.send(message)
            self._count(self.db.get_message_by_frame_id(message.arbitration_id).name, index)

    def _drain(self, bus) -> list:
        out: list = []
        while True:
            message = bus.recv(timeout=0.0)
            if message is None:
                return out
            out.append(message)

    # ------------------------------------------------------------------------------ a sample
    def step(self, measurements: Measurements) -> np.ndarray:
        """One controller sample through the loop (steps 1–4 of the module docstring).

        Parameters
        ----------
        measurements : Measurements
            What the sensor nodes measure at this sample.

        Returns
        -------
        numpy.ndarray
            The normal forces the plant gets over the next sample [N].
        """
        t = float(measurements.time)
        time_us = int(round(t * 1e6)) & 0xFFFFFFFF
        # 1. The sensor nodes and the amplifiers send.
        self._release_delayed(t, self.node_buses)  # due since the last sample: before this sample's frames
        self._send_sensor_frames(measurements, t)
        self._send_amplifier_status(t)

        # 2. The firmware: receive, step, send (setpoints and heartbeat).
        status = self._firmware_sample(t, time_us)

        # 3. The amplifiers take their setpoint and the heartbeat, and drive their stacks.
        self._deliver_to_amplifiers()
        amplifier_force = np.array([a.advance(self.sample_time) for a in self.amplifiers])
        applied = amplifier_force.copy()
        if t < self.excitation_end - 1e-12:
            applied = self.excitation_force.copy()  # the study's protocol: F_N^max while the pulse acts
        self._drain_log()
        self._record_sample(t, status, amplifier_force, applied)
        self.k += 1
        return np.maximum(applied, 0.0)

    def _send_sensor_frames(self, measurements: Measurements, t: float) -> None:
        # the sensor nodes sample on the controller's heartbeat on their bus and say which
        for j, joint in enumerate(self.joints):
            b = self.joint_bus[j]
            echo = self.node_echo[b]
            self._transmit(
                self.node_buses[b],
                self._message(
                    f"JOINT_{joint}",
                    {
                        "sliding_velocity": float(measurements.sliding_velocity[j]),
                        "friction_force": float(measurements.friction_force[j]),
                        "normal_force": float(measurements.normal_force[j]),
                        "sync": echo,
                    },
                    t,
                    self.node_freshness[b],
                ),
                t,
                b,
            )
        b = self.frame_bus["TIP_SENSORS"]
        self._transmit(
            self.node_buses[b],
            self._message(
                "TIP_SENSORS",
                {"sync": self.node_echo[b], **dict(zip(self.sensor_signals, map(float, measurements.sensors)))},
                t,
                self.node_freshness[b],
            ),
            t,
            b,
        )

    def _send_amplifier_status(self, t: float) -> None:
        for j, joint in enumerate(self.joints):  # amplifier status every sample: faults seen within a cycle
            fault = next(
                (
                    f.amplifier_fault
                    for f in self.faults
                    if f.kind == "amplifier" and f.target.upper() == joint and f.active(t)
                ),
                None,
            )
            self.amplifiers[j].fault = fault
            status = self.amplifiers[j].status()
            if status is not None:
                b = self.joint_bus[j]
                frame = self._message(f"AMP_STATUS_{joint}", status, t, self.amplifiers[j].echo_freshness)
                self._transmit(self.node_buses[b], frame, t, b)

    def _firmware_sample(self, t: float, time_us: int):
        for b, bus in enumerate(self.firmware_buses):
            for message in self._drain(bus):
                self.fw.rx(message.arbitration_id, bytes(message.data), time_us, b)
        status = self.fw.step(time_us)
        self._release_delayed(t, self.firmware_buses)
        for b, frame_id, data in self.fw.tx_bus():
            if frame_id == self.frames[HEARTBEAT].frame_id and b == 0:  # what the firmware tells of its joints
                sent = self.frames[HEARTBEAT].decode(bytes(data), decode_choices=False)
                self.failed = [bool(sent[f"failed_{joint.lower()}"]) for joint in self.joints]
            self._transmit(self.firmware_buses[b], self._frame(frame_id, data, t), t, b)
        return status

    def _setpoint(self, j: int, message, signal: str) -> None:
        """Amplifier ``j`` takes ``signal`` of a setpoint frame (``SETPOINT_<j>``, ``SETPOINTS_<J>``)."""
        m = self.frames[self.db.get_message_by_frame_id(message.arbitration_id).name]
        before = self.amplifiers[j].setpoint_watch.failed
        self.amplifiers[j].receive_setpoint(
            message.arbitration_id,
            bytes(message.data),
            m.length,
            lambda d, m=m: m.decode(d, decode_choices=False)[signal],
        )
        self.amplifier_e2e_errors += int(self.amplifiers[j].setpoint_watch.failed and not before)

    def _deliver_to_amplifiers(self) -> None:
        heartbeat = self.frames[HEARTBEAT]
        mode = lambda data: heartbeat.decode(data, decode_choices=False)["mode"]  # noqa: E731
        for b, bus in enumerate(self.node_buses):
            for message in self._drain(bus):
                name = self.db.get_message_by_frame_id(message.arbitration_id).name
                data = bytes(message.data)
                if name == HEARTBEAT:
                    for j, amplifier in enumerate(self.amplifiers):
                        if self.joint_bus[j] == b:
                            amplifier.receive_heartbeat(message.arbitration_id, data, heartbeat.length, mode)
                    if len(data) == heartbeat.length and e2e.check_heartbeat(message.arbitration_id, data, None).crc_ok:
                        self.node_echo[b], self.node_freshness[b] = data[1] & 0x0F, data[e2e.HEARTBEAT_CYCLE_BYTE]
                elif name.startswith("SETPOINTS_"):
                    for s in self.frames[name].signals:
                        if s.name.startswith("voltage_"):
                            self._setpoint(self.joints.index(s.name[len("voltage_") :].upper()), message, s.name)
                elif name.startswith("SETPOINT_"):
                    self._setpoint(self.joints.index(name[len("SETPOINT_") :]), message, "voltage")

    def _drain_log(self) -> None:
        for index, bus in enumerate(self.log_buses):
            for message in self._drain(bus):
                if self.writer is not None:
                    message.channel = index  # the bus's index in the plan: bench decode/replay read it
                    self.writer.on_message_received(message)

    def _record_sample(self, t: float, status, amplifier_force: np.ndarray, applied: np.ndarray) -> None:
        r = self.record
        r.time.append(t)
        r.safe.append(self.fw.safe)
        r.status.append(status)
        r.faults.append(self.fw.faults)
        r.command.append(self.fw.command)
        r.amplifier_force.append(amplifier_force)
        r.amplifier_safe.append([a.own_safe for a in self.amplifiers])
        r.applied.append(applied)
        r.bus_safe.append(self.fw.bus_safe)
        r.failed.append(list(self.failed))

    def statistics(self, duration: float, bitrate: int, data_bitrate: int | None) -> dict:
        """Frames per name, measured bus load over the run, E2E errors, timeouts.

        Parameters
        ----------
        duration : float
            The run's length [s].
        bitrate : int
            The nominal bitrate [bit/s].
        data_bitrate : int or None
            The CAN FD data bitrate [bit/s].

        Returns
        -------
        dict
            Frame counts, the bus load, the firmware's counters, E2E errors at the firmware and the
            amplifiers, samples in the safe state and what the fault injector did.
        """
        loads = [
            sum(
                count * busload.frame_time(self.frames[name].length, self.frames[name].is_fd, bitrate, data_bitrate)
                for name, count in counts.items()
            )
            / duration
            for counts in self.bus_frame_counts
        ]
        counters = self.fw.counters
        return {
            "frames": dict(sorted(self.frame_counts.items())),
            "frames_total": int(sum(self.frame_counts.values())),
            "bus_load": max(loads),  # the busiest bus
            "buses": [
                {"name": n, "frames_total": int(sum(c.values())), "bus_load": load}
                for n, c, load in zip(self.bus_names, self.bus_frame_counts, loads)
            ],
            "bitrate": bitrate,
            "data_bitrate": data_bitrate,
            "firmware": counters,
            "e2e_errors": counters["crc_errors"] + counters["counter_errors"] + counters["length_errors"],
            "amplifier_e2e_errors": self.amplifier_e2e_errors,
            "safe_samples": int(sum(self.record.safe)),
            "injected": dict(self.stats),
        }
