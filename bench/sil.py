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
   and its output over [t_k, t_k+1) sets the normal force of its joint (the mean over the sample; F_N^max while the study's pulse acts,
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
from pathlib import Path

import numpy as np

from smartjoint.common.errors import ModelError
from smartjoint.design.plant.interface import Measurements
from smartjoint.bench import e2e
from smartjoint.bench.amplifier import FAULTS as AMPLIFIER_FAULTS
from smartjoint.bench.amplifier import AmplifierModel

FRAME_FAULTS = ("drop", "delay", "duplicate", "corrupt_crc", "corrupt_counter", "wrong_dlc", "silent")
BUS_FAULTS = ("bus_off",)
KINDS = FRAME_FAULTS + ("implausible", "amplifier") + BUS_FAULTS
NEVER = math.inf  # the end of a fault that never ends
DEFAULT_DELAY = 0.005  # s


@dataclass(frozen=True)
class Fault:
    """One injected fault on [start, end) s (``end`` = inf: it never ends).

    ``target``: a frame name for frame faults and ``implausible`` (any frame the bus carries,
    the firmware's own ``SETPOINT_<j>`` and ``CONTROLLER_STATUS`` included — those are faulted on
    their way to the amplifiers), a joint name for ``amplifier`` (with ``amplifier_fault``),
    nothing for ``bus_off``. ``delay`` [s] only for ``delay``; ``signal`` and ``value`` only for
    ``implausible`` (the sender puts that value into the signal, with a valid E2E protection)."""

    kind: str
    start: float
    end: float = NEVER
    target: str = ""
    amplifier_fault: str = ""
    delay: float | None = None
    signal: str = ""
    value: float | None = None

    def active(self, t: float) -> bool:
        return self.start - 1e-12 <= t < self.end - 1e-12

    @property
    def lateness(self) -> float:
        return (DEFAULT_DELAY if self.delay is None else self.delay) if self.kind == "delay" else 0.0

    def label(self) -> str:
        detail = {"delay": f" {1e3 * self.lateness:g} ms", "amplifier": f" {self.amplifier_fault}",
                  "implausible": f".{self.signal} = {self.value:g}" if self.value is not None else ""}.get(self.kind, "")
        return f"{self.kind} {self.target or 'bus'}{detail}"


def check_faults(faults, frame_names, joint_names, signals=None) -> None:
    """Every field of every fault means something: known kind, existing target, a detail only
    where the kind has one, a window 0 <= start < end (end may be inf)."""
    signals = signals or {}
    for f in faults:
        what = f"fault {f.kind}"
        if f.kind not in KINDS:
            raise ModelError(f"fault kind {f.kind!r} — allowed: {', '.join(KINDS)}")
        if f.kind in FRAME_FAULTS + ("implausible",):
            if f.target not in frame_names:
                raise ModelError(f"{what}: target {f.target!r} — a frame on the bus: {', '.join(sorted(frame_names))}")
        elif f.kind == "amplifier":
            if f.target not in joint_names or f.amplifier_fault not in AMPLIFIER_FAULTS:
                raise ModelError(f"{what}: target {f.target!r} / {f.amplifier_fault!r} — a joint "
                                 f"({', '.join(joint_names)}) and one of {', '.join(AMPLIFIER_FAULTS)}")
        elif f.target:
            raise ModelError(f"{what}: target {f.target!r} — bus_off takes the whole bus off: give no target")
        if f.amplifier_fault and f.kind != "amplifier":
            raise ModelError(f"{what}: amplifier_fault {f.amplifier_fault!r} — only for kind amplifier")
        if f.delay is not None and f.kind != "delay":
            raise ModelError(f"{what}: delay {f.delay!r} — only for kind delay")
        if f.kind == "delay" and not (f.delay is None or (math.isfinite(f.delay) and f.delay > 0)):
            raise ModelError(f"{what}: delay {f.delay!r} — a time > 0 s")
        if f.kind == "implausible":
            names = signals.get(f.target)
            if names is not None and f.signal not in names:
                raise ModelError(f"{what}: signal {f.signal!r} of {f.target} — one of {', '.join(names)}")
            if f.value is None or not math.isfinite(f.value):
                raise ModelError(f"{what}: value {f.value!r} — the finite value the sender puts into {f.signal}")
        elif f.signal or f.value is not None:
            raise ModelError(f"{what}: signal/value {f.signal!r}/{f.value!r} — only for kind implausible")
        if not (math.isfinite(f.start) and 0 <= f.start < f.end and not math.isnan(f.end)):
            raise ModelError(f"{what}: window [{f.start!r}, {f.end!r}) — need 0 <= start < end (end may be inf)")


def parse_fault(text: str) -> Fault:
    """``kind:target:start:end[:detail]`` → Fault. ``end``: seconds or ``inf`` (never ends);
    detail: the delay [s] (``delay``, default 5 ms), the amplifier fault (``amplifier``), the
    value (``implausible``, target ``FRAME.signal``); ``bus_off`` has no target and no detail."""
    parts = text.split(":")
    example = ("e.g. drop:JOINT_A1:1.0:1.2, delay:JOINT_A1:1.0:1.2:0.002, amplifier:A1:1.0:inf:over_temperature, "
               "implausible:JOINT_A1.sliding_velocity:1.0:1.2:2.1, bus_off::1.0:1.05")
    if len(parts) not in (4, 5):
        raise ModelError(f"--fault {text!r}: expected kind:target:start:end[:detail], {example}")
    kind, target, detail = parts[0], parts[1], parts[4] if len(parts) == 5 else None
    try:
        start, end = float(parts[2]), float(parts[3])
    except ValueError:
        raise ModelError(f"--fault {text!r}: start and end must be numbers [s] (end may be inf)") from None
    if kind not in KINDS:
        raise ModelError(f"--fault {text!r}: kind {kind!r} — allowed: {', '.join(KINDS)}")
    fields: dict = {}
    if kind == "delay" and detail is not None:
        try:
            fields["delay"] = float(detail)
        except ValueError:
            raise ModelError(f"--fault {text!r}: the delay {detail!r} must be a number [s]") from None
    elif kind == "amplifier":
        fields["amplifier_fault"] = detail or ""
    elif kind == "implausible":
        target, _, fields["signal"] = target.partition(".")
        try:
            fields["value"] = float(detail) if detail is not None else None
        except ValueError:
            raise ModelError(f"--fault {text!r}: the value {detail!r} must be a number") from None
    elif detail is not None:
        raise ModelError(f"--fault {text!r}: kind {kind} takes no detail (got {detail!r})")
    return Fault(kind, start, end, target, **fields)


def open_bus(interface: str, channel: str, **kwargs):
    """A python-can bus, with a clear message when the interface is not installed."""
    import can

    try:
        return can.Bus(interface=interface, channel=channel, fd=True, **kwargs)  # the protocol is CAN FD
    except (ImportError, can.CanInterfaceNotImplementedError, can.CanInitializationError, ValueError, OSError) as error:
        known = ", ".join(sorted(can.interfaces.VALID_INTERFACES))
        raise ModelError(f"bench interface {interface!r} (channel {channel!r}) cannot be opened: {error} — "
                         f"python-can knows: {known}") from None


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
        signals = {m.name: [s.name for s in m.signals if s.name not in ("crc", "counter")] for m in self.db.messages}
        check_faults(faults, names, [j for j in a.joint_names], signals)
        self.faults = list(faults)
        self.interface, self.channel, self.log_path = interface, channel, log_path
        options = dict(amplifier or {})
        unknown = sorted(set(options) - {"time_constant", "slew_rate", "temperature", "voltage_max"})
        if unknown:
            raise ModelError(f"amplifier option {unknown[0]!r} — allowed: time_constant, slew_rate, temperature, "
                             "voltage_max")
        self.amplifier_options = [dict(force_per_volt=a.piezo_force_per_volt, preload=a.piezo_preload,
                                       capacitance=a.piezo_capacitance, safe_normal_force=float(a.safe_normal_force[j]),
                                       normal_force_min=float(a.normal_force_min[j]),
                                       normal_force_max=float(a.normal_force_max[j]),
                                       timeout_cycles=a.timeout_cycles, recovery_cycles=a.recovery_cycles,
                                       **options) for j in range(len(self.joints))]
        self.frames = {m.name: m for m in self.db.messages}
        self.buses = []
        self.writer = None

    # ------------------------------------------------------------------ set-up and tear-down
    def reset(self) -> None:
        self.close()
        try:
            for _ in range(3):
                self.buses.append(open_bus(self.interface, self.channel, preserve_timestamps=True))
        except BaseException:
            self.close()
            raise
        self.node_bus, self.firmware_bus, self.log_bus = self.buses
        self.writer = None
        if self.log_path is not None:
            import can

            self.writer = can.Logger(str(self.log_path))
        self.fw.reset()
        self.amplifiers = [AmplifierModel(**options) for options in self.amplifier_options]
        self.counters = defaultdict(int)
        self.delayed = []  # (due time, bus, message)
        self.frozen_counters = {}  # corrupt_counter: the counter each fault froze
        self.node_echo = 0  # heartbeat counter the sensor nodes last saw
        self.k = 0
        self.record = SilRecord()
        self.stats = defaultdict(int)
        self.frame_counts = defaultdict(int)
        self.amplifier_e2e_errors = 0

    def close(self) -> None:
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
    def _message(self, name: str, values: dict, t: float):
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
        data = e2e.protect(m.frame_id, bytearray(m.encode(signals, strict=False)), counter)
        return self._frame(m.frame_id, bytes(data), t)

    def _frame(self, frame_id: int, data: bytes, t: float):
        import can

        m = self.db.get_message_by_frame_id(frame_id)
        return can.Message(arbitration_id=frame_id, data=data, is_extended_id=False, is_fd=m.is_fd,
                           bitrate_switch=m.is_fd, timestamp=t)

    def _implausible(self, message, f: Fault, t: float):
        """The frame with ``f.value`` in ``f.signal``, re-protected with its own counter: a sender
        whose sensor or stage is broken, not a damaged frame."""
        m = self.db.get_message_by_frame_id(message.arbitration_id)
        values = m.decode(bytes(message.data), decode_choices=False, scaling=True)
        values[f.signal] = f.value
        signal = m.get_signal_by_name(f.signal)
        raw = round((f.value - signal.offset) / signal.scale)
        low = -(2 ** (signal.length - 1)) if signal.is_signed else 0
        high = 2 ** (signal.length - 1) - 1 if signal.is_signed else 2 ** signal.length - 1
        if not low <= raw <= high:
            raise ModelError(f"fault implausible: value {f.value!r} — {m.name}.{f.signal} carries "
                             f"{low * signal.scale + signal.offset:g} … {high * signal.scale + signal.offset:g}")
        data = bytearray(m.encode(values, strict=False, scaling=True))
        return self._frame(m.frame_id, bytes(e2e.protect(m.frame_id, data, message.data[1] & 0x0F)), t)

    def _bus_off(self, t: float) -> bool:
        return any(f.kind == "bus_off" and f.active(t) for f in self.faults)

    def _transmit(self, bus, message, t: float) -> None:
        """Put ``message`` on the bus from ``bus``'s side, through the fault injector."""
        import can

        name = self.db.get_message_by_frame_id(message.arbitration_id).name
        if self._bus_off(t):
            self.stats["frames_lost_bus_off"] += 1
            return
        copies = 1
        for f in self.faults:
            if f.target != name or not f.active(t):
                continue
            self.stats[f"injected_{f.kind}"] += 1
            if f.kind in ("drop", "silent"):
                return
            if f.kind == "delay":
                self.delayed.append((t + f.lateness, bus, message))
                return
            if f.kind == "duplicate":
                copies = 2
            elif f.kind == "corrupt_crc":
                data = bytearray(message.data)
                data[-1] ^= 0x5A
                message = self._frame(message.arbitration_id, bytes(data), t)
            elif f.kind == "corrupt_counter":  # a sender whose counter froze: valid CRC, the same counter again
                frozen = self.frozen_counters.setdefault(id(f), message.data[1] & 0x0F)
                data = e2e.protect(message.arbitration_id, bytearray(message.data), frozen)
                message = self._frame(message.arbitration_id, bytes(data), t)
            elif f.kind == "wrong_dlc":  # the next shorter length a CAN (FD) frame can have
                shorter = max(n for n in (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48) if n < len(message.data))
                message = can.Message(arbitration_id=message.arbitration_id, data=bytes(message.data[:shorter]),
                                      is_fd=message.is_fd, bitrate_switch=message.bitrate_switch, timestamp=t)
            elif f.kind == "implausible":
                message = self._implausible(message, f, t)
        for _ in range(copies):
            bus.send(message)
            self.frame_counts[name] += 1

    def _release_delayed(self, t: float, sender) -> None:
        """Late frames of ``sender``'s side go out at the first sample after their delay."""
        due = [(bus, m) for when, bus, m in self.delayed if bus is sender and when <= t + 1e-12]
        self.delayed = [(w, bus, m) for w, bus, m in self.delayed if not (bus is sender and w <= t + 1e-12)]
        for bus, message in due:
            if self._bus_off(t):
                self.stats["frames_lost_bus_off"] += 1
                continue
            message.timestamp = t
            bus.send(message)
            self.frame_counts[self.db.get_message_by_frame_id(message.arbitration_id).name] += 1

    def _drain(self, bus) -> list:
        out = []
        while True:
            message = bus.recv(timeout=0.0)
            if message is None:
                return out
            out.append(message)

    # ------------------------------------------------------------------------------ a sample
    def step(self, measurements: Measurements) -> np.ndarray:
        t = float(measurements.time)
        time_us = int(round(t * 1e6)) & 0xFFFFFFFF
        # 1. The sensor nodes and the amplifiers send.
        self._release_delayed(t, self.node_bus)  # due since the last sample: before this sample's frames
        echo = self.node_echo  # the sensor nodes sample on the controller's heartbeat and say which
        for j, joint in enumerate(self.joints):
            self._transmit(self.node_bus, self._message(f"JOINT_{joint}", {
                "sliding_velocity": float(measurements.sliding_velocity[j]),
                "friction_force": float(measurements.friction_force[j]),
                "normal_force": float(measurements.normal_force[j]), "sync": echo}, t), t)
        self._transmit(self.node_bus, self._message("TIP_SENSORS", {"sync": echo, **dict(
            zip(self.sensor_signals, map(float, measurements.sensors)))}, t), t)
        for j, joint in enumerate(self.joints):  # amplifier status every sample: faults seen within a cycle
            fault = next((f.amplifier_fault for f in self.faults
                          if f.kind == "amplifier" and f.target.upper() == joint and f.active(t)), None)
            self.amplifiers[j].fault = fault
            status = self.amplifiers[j].status()
            if status is not None:
                self._transmit(self.node_bus, self._message(f"AMP_STATUS_{joint}", status, t), t)

        # 2. The firmware: receive, step, send (setpoints and heartbeat).
        for message in self._drain(self.firmware_bus):
            self.fw.rx(message.arbitration_id, bytes(message.data), time_us)
        status = self.fw.step(time_us)
        self._release_delayed(t, self.firmware_bus)
        for frame_id, data in self.fw.tx():
            self._transmit(self.firmware_bus, self._frame(frame_id, data, t), t)

        # 3. The amplifiers take their setpoint and the heartbeat, and drive their stacks.
        heartbeat = self.frames["CONTROLLER_STATUS"]
        mode = lambda data: heartbeat.decode(data, decode_choices=False)["mode"]  # noqa: E731
        for message in self._drain(self.node_bus):
            name = self.db.get_message_by_frame_id(message.arbitration_id).name
            data = bytes(message.data)
            if name == "CONTROLLER_STATUS":
                for amplifier in self.amplifiers:
                    amplifier.receive_heartbeat(message.arbitration_id, data, heartbeat.length, mode)
                if len(data) == heartbeat.length and e2e.check(message.arbitration_id, data, None).crc_ok:
                    self.node_echo = data[1] & 0x0F
            elif name.startswith("SETPOINT_"):
                j = self.joints.index(name[len("SETPOINT_"):])
                m = self.frames[name]
                before = self.amplifiers[j].setpoint_watch.failed
                self.amplifiers[j].receive_setpoint(
                    message.arbitration_id, data, m.length,
                    lambda d, m=m: m.decode(d, decode_choices=False)["voltage"])
                self.amplifier_e2e_errors += int(self.amplifiers[j].setpoint_watch.failed and not before)
        amplifier_force = np.array([a.advance(self.sample_time) for a in self.amplifiers])
        applied = amplifier_force.copy()
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
        r.faults.append(self.fw.faults)
        r.command.append(self.fw.command)
        r.amplifier_force.append(amplifier_force)
        r.amplifier_safe.append([a.own_safe for a in self.amplifiers])
        r.applied.append(applied)
        self.k += 1
        return np.maximum(applied, 0.0)

    def statistics(self, duration: float, bitrate: int, data_bitrate: int | None) -> dict:
        """Frames per name, measured worst-case bus load over the run, E2E errors, timeouts."""
        from smartjoint.bench.busload import _frame_time

        busy = sum(count * _frame_time(self.frames[name].length, self.frames[name].is_fd, bitrate, data_bitrate)
                   for name, count in self.frame_counts.items())
        counters = self.fw.counters
        return {"frames": dict(sorted(self.frame_counts.items())), "frames_total": int(sum(self.frame_counts.values())),
                "bus_load": busy / duration, "bitrate": bitrate, "data_bitrate": data_bitrate,
                "firmware": counters,
                "e2e_errors": counters["crc_errors"] + counters["counter_errors"] + counters["length_errors"],
                "amplifier_e2e_errors": self.amplifier_e2e_errors,
                "safe_samples": int(sum(self.record.safe)), "injected": dict(self.stats)}

def perturbed(controller, relative: float, seed: int):
    """``controller`` with its normal-force commands multiplied by 1 + relative·N(0, 1): the
    sensitivity reference of the SIL comparison (float rounding is ~6e-8 relative)."""

    class Perturbed:
        sample_time = controller.sample_time

        def __init__(self):
            self.rng = np.random.default_rng(seed)

        def reset(self):
            controller.reset()
            self.rng = np.random.default_rng(seed)

        def step(self, measurements):
            out = np.asarray(controller.step(measurements), dtype=float)
            return out * (1.0 + relative * self.rng.standard_normal(out.size))

    return Perturbed()


def sil_study(setup, artifact, laws=("siso", "clqg"), real: str = "float", faults=(), log_folder=None,
              amplifier: dict | None = None, bitrate: int = 1_000_000, data_bitrate: int | None = 5_000_000,
              spread_runs: int = 6, interface: str = "virtual", channel: str = "smartjoint-sil", progress=print) -> dict:
    """The paper's study through the CAN loop, per law against the model-in-the-loop run of the
    Python reference controllers: E(t_e) (Eq. 32) and e(t_e) differences, bus statistics, and the
    spread of the MIL run itself under float-rounding-sized perturbations of its commands (the
    stick–slip closed loop is chaotic: that spread bounds what any faithful re-implementation
    can match)."""
    from smartjoint.design.control import artifact as artifacts
    from smartjoint.design import plant as simulate
    from smartjoint.design.control import study as closed_loop
    from smartjoint.bench import busload, firmware, safety
    from smartjoint.design.network import protocol

    python = {"siso": artifacts.siso_law, "clqg": artifacts.clipped_lqg}
    db = protocol.database(artifact)
    check_faults(faults, {m.name for m in db.messages}, list(artifact.joint_names),
                 {m.name: [s.name for s in m.signals if s.name not in ("crc", "counter")] for m in db.messages})
    planned = busload.check(db, bitrate, data_bitrate)
    out = {"bitrate": bitrate, "data_bitrate": data_bitrate, "planned_bus_load": planned.load, "real": real,
           "amplifier": dict(amplifier or {}), "laws": {}}
    for law in laws:
        progress(f"      {law}: model in the loop (Python reference) …")
        mil = closed_loop.run_semi_active(setup, law, python[law](artifact))
        spread = []
        for seed in range(spread_runs):
            run = closed_loop.run_semi_active(setup, law, perturbed(python[law](artifact), 6e-8, seed))
            spread.append(run.energy_measure() / mil.energy_measure() - 1.0)
        progress(f"      {law}: software in the loop ({real} firmware, CAN {bitrate / 1e6:g}"
                 f"{'' if data_bitrate is None else f'/{data_bitrate / 1e6:g}'} Mbit/s) …")
        image = firmware.Firmware(artifact, law, real)
        log_path = None if log_folder is None else Path(log_folder) / f"sil_{law}.blf"
        if log_path is not None:
            log_path.parent.mkdir(parents=True, exist_ok=True)
        loop = SilLoop(image, closed_loop.PULSE_DURATION, faults=faults, interface=interface, channel=channel,
                       log_path=log_path, amplifier=amplifier)
        try:
            result = simulate.simulate(setup.plant, setup.laws, loop, setup.pulse(), setup.duration, setup.plant_step,
                                       record_every=closed_loop.PLANT_STEPS_PER_SAMPLE, energy_books=False)
        finally:
            loop.close()
        energy_measure = float(np.trapezoid(2.0 * result.energy, result.time))
        out.setdefault("mil_runs", {})[law] = mil
        out["laws"][law] = {
            "energy_measure_mil": mil.energy_measure(), "energy_measure_sil": energy_measure,
            "energy_measure_difference": energy_measure / mil.energy_measure() - 1.0,
            "energy_end_mil": float(mil.energy[-1]), "energy_end_sil": float(result.energy[-1]),
            "mil_spread_under_float_rounding": [min(spread), max(spread)] if spread else None,
            "max_energy_sil": float(result.energy.max()),
            "bus": loop.statistics(setup.duration, bitrate, data_bitrate),
            "log": None if log_path is None else str(log_path),
            "faults": [{"fault": f.label(), **safety.measure(loop.record, (f,), artifact)} for f in faults],
            "record": loop.record, "result": result,
        }
    return out


def fault_lines(rows: list) -> list[str]:
    """Per injected fault: cycles to the safe state at the firmware and at the joints (the force
    the amplifiers really apply), and to recovery after its end."""
    def cell(value):
        return "—" if value is None else str(value)

    lines = ["| fault | window [cycles] | firmware safe [cycles] | joints at F_safe [cycles] | recovery [cycles] |",
             "|---|---|---:|---:|---:|"]
    for r in rows:
        window = f"{r['start']}–{'∞' if r['end'] is None else r['end']}"
        note = "" if r.get("observable", True) else " (never showed)"
        note += f" (output stage of {', '.join(r['failed_output_stage'])} failed)" if r["failed_output_stage"] else ""
        lines.append(f"| {r['fault']}{note} | {window} | {cell(r['firmware'])} | {cell(r['joints'])} | "
                     f"{cell(r['recovery'])} |")
    return lines


def sil_markdown(out: dict) -> str:
    lines = ["## Software in the loop: the study through CAN (firmware + bus + amplifiers)", "",
             f"{out['real']} firmware, CAN FD {out['bitrate'] / 1e6:g}/{(out['data_bitrate'] or 0) / 1e6:g} Mbit/s, "
             f"planned worst-case bus load {100 * out['planned_bus_load']:.1f} %.", "",
             "| law | E(t_e) MIL | E(t_e) SIL | difference | MIL spread under 6e-8 perturbations | e(t_e) MIL / SIL | "
             "frames | bus load | E2E errors | timeouts | safe samples |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for law, f in out["laws"].items():
        bus = f["bus"]
        spread = f["mil_spread_under_float_rounding"]
        band = "—" if spread is None else f"{100 * spread[0]:+.1f} … {100 * spread[1]:+.1f} %"
        lines.append(f"| {law} | {f['energy_measure_mil']:.4g} | {f['energy_measure_sil']:.4g} | "
                     f"{100 * f['energy_measure_difference']:+.2f} % | {band} | {f['energy_end_mil']:.3g} / "
                     f"{f['energy_end_sil']:.3g} | {bus['frames_total']} | {100 * bus['bus_load']:.1f} % | "
                     f"{bus['e2e_errors']} | {bus['firmware']['timeouts']} | {bus['safe_samples']} |")
    for law, f in out["laws"].items():
        if f.get("faults"):
            lines += ["", f"Injected faults ({law}):", ""] + fault_lines(f["faults"])
    return "\n".join(lines) + "\n"


def plot_sil(out: dict, folder, mil_runs: dict | None = None) -> list:
    """sil_energy.png: e(t) of the SIL run per law (the MIL run dashed, when given)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(7, 3.6))
    colours = {"siso": "tab:blue", "clqg": "tab:red"}
    for law, f in out["laws"].items():
        r = f["result"]
        ax.semilogy(r.time, np.maximum(r.energy, 1e-12), color=colours.get(law, "k"), lw=1.0,
                    label=f"{law} SIL ({100 * f['energy_measure_difference']:+.2f} % E(t_e))")
        if mil_runs and law in mil_runs:
            m = mil_runs[law]
            ax.semilogy(m.time, np.maximum(m.energy, 1e-12), "--", color=colours.get(law, "k"), lw=0.8,
                        label=f"{law} MIL")
        safe = np.array(f["record"].safe)
        if safe.any():
            t = np.array(f["record"].time)
            ax.plot(t[safe], np.full(int(safe.sum()), ax.get_ylim()[0] * 2), "|", color="k", ms=4, label="safe state")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("½xᵀx [J]")
    ax.set_title("Study through the CAN loop (software in the loop)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = folder / "sil_energy.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]


def demo_faults(artifact, duration: float) -> tuple:
    """Four faults in sequence for the report, on the design's own frames and joints: a dropped
    joint frame, a damaged sensor frame, an over-heated amplifier, the bus off — at 1/8, 1/4,
    3/8 and 1/2 of the study."""
    joints = list(artifact.joint_names)
    at = lambda fraction, length: (fraction * duration, fraction * duration + length)  # noqa: E731
    return (Fault("drop", *at(0.125, 0.1), f"JOINT_{joints[0].upper()}"),
            Fault("corrupt_crc", *at(0.25, 0.05), "TIP_SENSORS"),
            Fault("amplifier", *at(0.375, 0.1), joints[len(joints) // 2], amplifier_fault="over_temperature"),
            Fault("bus_off", *at(0.5, 0.05)))


def fault_run(setup, artifact, law: str = "clqg", faults=None, real: str = "float") -> dict:
    """One SIL run of the study with a sequence of faults (default :func:`demo_faults`): per
    fault the figures of ``bench/safety.measure``, and the largest energy after the pulse
    (bounded: the safe state is passive)."""
    from smartjoint.design import plant as simulate
    from smartjoint.design.control import study as closed_loop
    from smartjoint.bench import firmware, safety

    faults = demo_faults(artifact, setup.duration) if faults is None else tuple(faults)
    loop = SilLoop(firmware.Firmware(artifact, law, real), closed_loop.PULSE_DURATION, faults=faults)
    try:
        result = simulate.simulate(setup.plant, setup.laws, loop, setup.pulse(), setup.duration, setup.plant_step,
                                   record_every=closed_loop.PLANT_STEPS_PER_SAMPLE, energy_books=False)
    finally:
        loop.close()
    rows = [{"fault": f.label(), "kind": f.kind, "target": f.target or "bus", "start_s": f.start, "end_s": f.end,
             **safety.measure(loop.record, (f,), artifact)} for f in faults]
    after = result.time > closed_loop.PULSE_DURATION
    return {"law": law, "faults": rows, "max_energy_after_pulse": float(result.energy[after].max()),
            "energy_end": float(result.energy[-1]), "safe_samples": int(np.sum(loop.record.safe)), "result": result,
            "record": loop.record, "statistics": loop.statistics(setup.duration, 1_000_000, 5_000_000)}


def fault_markdown(run: dict) -> str:
    lines = [f"### Injected faults in the study (SIL, {run['law']}): safe state and recovery", ""]
    lines += fault_lines(run["faults"])
    s = run["statistics"]
    lines += ["", f"Largest energy after the pulse {run['max_energy_after_pulse']:.3g} J (bounded; e(t_e) = "
              f"{run['energy_end']:.3g} J); {run['safe_samples']} samples in the safe state; firmware counters: "
              f"CRC errors {s['firmware']['crc_errors']}, counter errors {s['firmware']['counter_errors']}, "
              f"timeouts {s['firmware']['timeouts']}, implausible frames {s['firmware']['implausible_frames']}.", ""]
    return "\n".join(lines)


def plot_faults(run: dict, path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r, record = run["result"], run["record"]
    time = np.array(record.time)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 4.6), sharex=True)
    top.semilogy(r.time, np.maximum(r.energy, 1e-12), lw=0.9)
    top.set_ylabel("½xᵀx [J]")
    top.set_title("SIL with injected faults (orange), safe state (grey)")
    applied = np.array(record.amplifier_force)
    for j in range(applied.shape[1]):
        bottom.plot(time, applied[:, j], lw=0.6, label=f"F_N applied, joint {j + 1}")
    safe = np.array(record.safe)
    for ax in (top, bottom):
        for f in run["faults"]:
            ax.axvspan(f["start_s"], min(f["end_s"], time[-1]), color="tab:orange", alpha=0.25, lw=0)
        ax.fill_between(time, 0, 1, where=safe, transform=ax.get_xaxis_transform(), color="k", alpha=0.12, lw=0)
    bottom.set_xlabel("t [s]")
    bottom.set_ylabel("F_N by the amplifier [N]")
    bottom.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
