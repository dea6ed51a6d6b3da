"""Piezo amplifier as a CAN bus node: setpoint and heartbeat in, stack voltage out, status frames.

The amplifier is the last link to the joint, so it makes the joint safe on its own (policy:
docs/safety.md): it watches its ``SETPOINT_<j>`` frame and the controller's heartbeat
``CONTROLLER_STATUS`` with the same rules as the firmware — E2E check, ``timeout_cycles``
cycles without a frame is missing, a setpoint outside the design's normal-force range is
implausible — and drives the stack to the safe voltage V_safe = (F_safe − preload)/k whenever one of them fails, from
power-up until the first ``recovery_cycles`` fault-free cycles, and while the heartbeat says
the controller is in its safe state. The controller stamps every frame of a cycle with the same
alive counter, so a setpoint kept back behind its heartbeat (or the other way round) beyond the
bound is late too. Its status frame reports its own safe state (``safe_state``) and echoes the
last heartbeat counter (``sync``), from which the controller ages the frame.

Output dynamics per controller sample Δt (exact for a held target): first-order lag with time
constant τ (0: ideal) towards the target in [0, V_max], the change over one sample limited to
slew·Δt. The normal force the stack applies over the sample is F_N = k·V̄ + preload with V̄
the mean voltage over the sample (so the plant gets the right impulse).

Injectable faults: ``over_temperature`` and ``over_current`` (status bit and reading; the stage
holds the safe voltage, which a capacitive stack keeps without current), ``no_response`` (the CAN
transceiver is dead: no status frames, no frames received — the watchdog drives the safe
voltage), ``stuck_output`` (output frozen, status bit) and ``gain_error`` (the stage delivers half
its target, no bit: only the firmware's monitor-voltage check sees it). Those two are failed
output stages: no command can make that joint safe, the firmware detects them and makes the
others safe (:data:`OUTPUT_STAGE_FAULTS`). Three more fail past the amplifier, which reports
healthy — its voltage, monitor and status all as commanded — while the joint gets ``zero_force``
(0 N: a broken stack lead), ``half_force`` (half the force: a depolarised stack) or
``stuck_force`` (the force of the sample before the fault: a jammed joint). Only the firmware's
actuation check on the measured F_N sees them; it names the joint and the law runs on
(:data:`SILENT_FAULTS`, docs/safety.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from smartjoint.bench import e2e
from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.network.protocol import MODE_SAFE

SILENT_FAULTS = ("zero_force", "half_force", "stuck_force")  # past the amplifier, which reports healthy
FAULTS = ("over_temperature", "no_response", "stuck_output", "over_current", "gain_error", *SILENT_FAULTS)
OUTPUT_STAGE_FAULTS = ("stuck_output", "gain_error")  # the joint itself cannot reach the safe force
HOT_TEMPERATURE = 95.0  # °C reported under ``over_temperature``
HIGH_CURRENT = 2.9  # A reported under ``over_current``
GAIN_ERROR = 0.5  # output / target under ``gain_error``, force / force driven under ``half_force``
# What a heartbeat may say: a law's mode (common.law_registry) or the safe state.
CONTROLLER_MODES = (*(law.mode for law in law_registry.LAWS.values()), MODE_SAFE)


@dataclass
class FrameWatch:
    """Receiver side of one cyclic frame, the rules of the firmware's CAN layer: E2E check
    (stale frames ignored), cycles without a frame."""

    timeout_cycles: int
    last_counter: int | None = None  # the E2E receiver
    counter: int | None = None  # alive counter of the newest accepted frame
    silent: int = 0
    seen: bool = False
    healthy: bool = False
    failed: bool = False  # an E2E failure since the last tick
    followed: int | None = None  # the counter (a heartbeat's cycle) last followed, accepted or a jump …
    since_followed: int = 0  # … and the cycles since
    keeps_order: bool = False  # after a loss, still refuse a counter behind the last (a heartbeat's 12 bits)

    def receive(self, frame_id: int, data: bytes, length: int, cycle: int | None = None) -> bool:
        """Take one received frame: its length and E2E check; whether it was accepted.

        ``cycle``: the frame's whole cycle as read from the last heartbeat (a setpoint); its
        freshness byte is that cycle's and its step counts in 12 bits. None: a heartbeat, checked
        by the cycle it carries (``e2e.check_heartbeat``)."""
        if len(data) != length:
            self.failed, self.healthy = True, False
            return False
        if cycle is None:
            checked = e2e.check_heartbeat(frame_id, data, self.last_counter)
        else:
            checked = e2e.check(frame_id, data, self.last_counter, e2e.freshness(cycle), cycle)
        if checked.resynchronises:  # the receiver policy of sj_e2e.c
            self.last_counter = self.followed = checked.counter
            self.since_followed = 0
        if not checked.ok:
            if checked.reason != "counter stale":  # older than what we have: ignored
                self.failed, self.healthy = True, False
            return False
        self.counter, self.silent = checked.counter, 0
        self.seen = self.healthy = True
        return True

    @property
    def lost(self) -> bool:
        """Whether no frame was accepted for ``timeout_cycles`` cycles."""
        return self.seen and self.silent >= self.timeout_cycles

    def tick(self) -> str | None:
        """One controller cycle passed: the reason this frame cannot be used, or None."""
        silent, self.silent = self.silent, min(self.silent + 1, 255)
        self.since_followed = min(self.since_followed + 1, e2e.CYCLE_MODULO)
        failed, self.failed = self.failed, False
        if not self.seen or silent >= self.timeout_cycles:
            if self.seen and not self.keeps_order:
                self.last_counter = None  # the E2E check accepts whatever counter comes next
            return "timeout"
        if failed or not self.healthy:
            return "e2e"
        return None


def amplifier_options(artifact, amplifier: dict | None = None, local: bool = False) -> list[dict]:
    """Each joint's ``AmplifierModel`` arguments: the artefact's piezo calibration, limits and
    timeouts, and the bench's ``amplifier`` options (``time_constant``, ``slew_rate``,
    ``temperature``, ``voltage_max``); ``local``: driven by its joint node (local mode).

    Raises
    ------
    ModelError
        An option the model does not have.
    """
    options = dict(amplifier or {})
    unknown = sorted(set(options) - {"time_constant", "slew_rate", "temperature", "voltage_max"})
    if unknown:
        raise ModelError(
            f"amplifier option {unknown[0]!r} — allowed: time_constant, slew_rate, temperature, voltage_max"
        )
    a = artifact
    return [
        dict(
            force_per_volt=a.piezo_force_per_volt,
            preload=a.piezo_preload,
            capacitance=a.piezo_capacitance,
            safe_normal_force=float(a.safe_normal_force[j]),
            normal_force_min=float(a.normal_force_min[j]),
            normal_force_max=float(a.normal_force_max[j]),
            timeout_cycles=a.timeout_cycles,
            recovery_cycles=a.recovery_cycles,
            local=local,
            **options,
        )
        for j in range(len(a.joint_names))
    ]


@dataclass
class AmplifierModel:
    force_per_volt: float  # k [N/V]
    safe_normal_force: float  # F_safe [N]
    normal_force_min: float  # plausible setpoints: F^min … F^max (± setpoint_tolerance)
    normal_force_max: float
    preload: float = 0.0  # [N]
    voltage_max: float = 150.0  # [V]
    time_constant: float = 0.0  # τ [s]; 0: ideal (the SIL check isolates firmware and bus)
    slew_rate: float = 2e6  # [V/s]
    capacitance: float = 1.8e-6  # [F]
    temperature: float = 35.0  # [°C]
    timeout_cycles: int = 2
    recovery_cycles: int = 3
    setpoint_tolerance: float = 0.5  # [V] around the plausible setpoint range
    fault: str | None = None
    setpoints_received: int = 0
    local: bool = False  # driven by its joint node over a local link (``drive``), no frame watchdog
    voltage: float = field(init=False)
    setpoint: float = field(init=False)

    def __post_init__(self):
        for name in ("force_per_volt", "voltage_max", "slew_rate", "capacitance"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ModelError(f"amplifier {name}: {value!r} — must be a finite number > 0")
        if not (math.isfinite(self.time_constant) and self.time_constant >= 0):
            raise ModelError(f"amplifier time_constant: {self.time_constant!r} — must be >= 0 s (0: ideal)")
        self.safe_voltage = self.volts(self.safe_normal_force)
        self.voltage = self.setpoint = self.safe_voltage  # power-up: the safe force at once
        self.current = 0.0
        self.setpoint_watch = FrameWatch(self.timeout_cycles)
        # The heartbeat's 12-bit cycle keeps its order through a loss: a replayed heartbeat stream
        # (with its setpoints, a gateway replaying everything) stays behind and is never followed.
        self.heartbeat_watch = FrameWatch(self.timeout_cycles, keeps_order=True)
        self.controller_mode = None
        self.implausible = False
        self.own_safe = True
        self.started = False  # no valid command yet (power-up: holds the safe force, not a trip …
        self.waiting = 0  # … until it waited timeout_cycles: then its watchdog says so)
        self.clear_cycles = 0
        self.reasons: tuple[str, ...] = ("power-up",)
        self.force = self.force_per_volt * self.voltage + self.preload  # what the joint got last sample [N]
        self.stuck: float | None = None  # the force a ``stuck_force`` fault froze

    def volts(self, normal_force: float) -> float:
        """The setpoint voltage of a normal force [V] (F_N = force_per_volt·V + preload)."""
        return min(max((normal_force - self.preload) / self.force_per_volt, 0.0), self.voltage_max)

    @property
    def listening(self) -> bool:
        """Whether the amplifier takes frames (not under a ``no_response`` fault)."""
        return self.fault != "no_response"

    @property
    def echo_freshness(self) -> int:
        """The freshness byte of the heartbeat its status frame echoes (0 before any)."""
        return e2e.freshness(self.heartbeat_watch.counter or 0)

    def receive_setpoint(self, frame_id: int, data: bytes, length: int, decode) -> None:
        """A SETPOINT frame as it came off the bus; ``decode(data)`` gives its voltage.

        The controller sends it just before the heartbeat of its cycle: its cycle is the one with
        its counter's bits 0–3 nearest the cycle now (the heartbeat last followed and the cycles
        since), whose bits 4–11 its CRC must cover — a setpoint 9 to about 4 087 cycles old fails
        here, a younger one lags its heartbeat."""
        # The cycle now: the heartbeat last followed (a jump is followed, not taken) and the cycles
        # since, so a setpoint after a silence of the heartbeat is read at its own cycle.
        watch = self.heartbeat_watch
        now = 0 if watch.followed is None else watch.followed + watch.since_followed
        cycle = e2e.nearest_cycle(now, data[1] & 0x0F if len(data) > 1 else 0)
        if not self.listening or not self.setpoint_watch.receive(frame_id, data, length, cycle):
            return
        voltage = float(decode(bytes(data)))
        low = self.volts(self.normal_force_min) - self.setpoint_tolerance
        high = self.volts(self.normal_force_max) + self.setpoint_tolerance
        self.implausible = not low <= voltage <= high
        if not self.implausible:
            self.setpoint = voltage
            self.setpoints_received += 1

    def drive(self, normal_force: float) -> None:
        """Local mode: the joint node's command over its local link. No frame and no frame
        watchdog (the node has its own); an implausible command trips the amplifier as an
        implausible setpoint frame would."""
        voltage = (normal_force - self.preload) / self.force_per_volt
        low = self.volts(self.normal_force_min) - self.setpoint_tolerance
        high = self.volts(self.normal_force_max) + self.setpoint_tolerance
        self.implausible = not low <= voltage <= high  # NaN too
        if not self.implausible:
            self.setpoint = min(max(voltage, 0.0), self.voltage_max)
            self.setpoints_received += 1

    def receive_heartbeat(self, frame_id: int, data: bytes, length: int, decode) -> None:
        """A CONTROLLER_STATUS frame; ``decode(data)`` gives its mode.

        Its cycle must step on from the last one followed, also after a loss: a stream behind it
        (replayed, up to 2 047 cycles old) is ignored for as long as it lasts. Only a controller
        that has (re)started — SAFE at a cycle of 0 … 3, its CRC valid — is taken afresh once the
        heartbeat is lost."""
        watch = self.heartbeat_watch
        if not self.listening:
            return
        if watch.lost and len(data) == length:
            checked = e2e.check_heartbeat(frame_id, data, None)
            if checked.crc_ok and checked.counter <= e2e.MAX_COUNTER_STEP and int(decode(bytes(data))) == MODE_SAFE:
                watch.last_counter = None
        if watch.receive(frame_id, data, length):
            self.controller_mode = int(decode(bytes(data)))

    def _watchdog(self) -> None:
        self.waiting += not self.started  # power-up cycles without a valid command
        reasons = []
        watches = () if self.local else (("setpoint", self.setpoint_watch), ("heartbeat", self.heartbeat_watch))
        for name, watch in watches:
            reason = watch.tick()
            if reason:
                reasons.append(f"{name} {reason}")
        if not reasons and not self.local:
            # The controller stamps a setpoint and its heartbeat with the same cycle counter:
            # one kept back behind the other beyond the latency bound is late.
            lag = (self.setpoint_watch.counter - self.heartbeat_watch.counter + 8) % e2e.COUNTER_MODULO - 8
            if abs(lag) >= self.timeout_cycles:
                reasons.append("setpoint late" if lag < 0 else "heartbeat late")
        if self.implausible:
            reasons.append("implausible setpoint")
        if self.controller_mode is not None and self.controller_mode not in CONTROLLER_MODES:
            reasons.append("implausible heartbeat mode")  # the controller sends only its law or "safe"
        if reasons:
            self.own_safe, self.clear_cycles = True, 0
        else:
            self.clear_cycles += 1
            # power-up: the first valid command ends it; after a trip, recovery_cycles clean ones
            if self.clear_cycles >= self.recovery_cycles or not self.started:
                self.own_safe, self.started = False, True
        self.reasons = tuple(reasons)

    def advance(self, step: float) -> float:
        """One controller sample: the watchdog decides, the output moves; returns the mean normal
        force over the sample [N] the joint gets (past the amplifier under a ``SILENT_FAULTS`` one)."""
        driven = self._drive(step)
        if self.fault == "zero_force":
            force = 0.0
        elif self.fault == "half_force":
            force = GAIN_ERROR * driven
        elif self.fault == "stuck_force":
            force = self.force if self.stuck is None else self.stuck
            self.stuck = force
        else:
            force = driven
        if self.fault != "stuck_force":
            self.stuck = None
        self.force = force
        return force

    def _drive(self, step: float) -> float:
        """The amplifier's own sample: its output voltage moves; the mean force it drives [N]."""
        self._watchdog()
        start = self.voltage
        if self.fault == "stuck_output":
            self.current = 0.0
            return self.force_per_volt * start + self.preload
        holds_safe = (
            self.own_safe or self.controller_mode == MODE_SAFE or self.fault in ("over_temperature", "over_current")
        )
        target = self.safe_voltage if holds_safe else self.setpoint
        if self.fault == "gain_error":
            target *= GAIN_ERROR
        if self.time_constant > 0:
            decay = math.exp(-step / self.time_constant)
            end = target + (start - target) * decay
            mean = target + (start - target) * self.time_constant / step * (1.0 - decay)
        else:  # ideal: the target holds from the start of the sample
            end = mean = target
        limit = self.slew_rate * step
        if abs(end - start) > limit:  # slew-limited: a ramp over the sample
            end = start + math.copysign(limit, end - start)
            mean = 0.5 * (start + end)
        self.current = self.capacitance * (end - start) / step
        self.voltage = end
        return self.force_per_volt * mean + self.preload

    def status(self) -> dict | None:
        """Signals of the AMP_STATUS frame, or None while not responding."""
        if not self.listening:
            return None
        return {
            "monitor_voltage": self.voltage,
            "current": HIGH_CURRENT if self.fault == "over_current" else self.current,
            "temperature": HOT_TEMPERATURE if self.fault == "over_temperature" else self.temperature,
            "over_temperature": int(self.fault == "over_temperature"),
            "no_response": 0,
            "stuck_output": int(self.fault == "stuck_output"),
            "over_current": int(self.fault == "over_current"),
            "safe_state": int(self.own_safe and (self.started or self.waiting >= self.timeout_cycles)),
            "sync": (self.heartbeat_watch.counter or 0) & 0x0F,
        }
