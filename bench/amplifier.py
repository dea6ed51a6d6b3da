"""Piezo amplifier as a CAN bus node: voltage setpoint in, stack voltage out, status frames.

Output dynamics per controller sample Δt (exact for a held setpoint): first-order lag with time
constant τ (0: ideal) towards the saturated setpoint V_set ∈ [0, V_max], the change over one sample limited
to slew·Δt. The normal force the stack applies over the sample is F_N = k·V̄ + preload with V̄
the mean voltage over the sample (so the plant gets the right impulse). Status frames report the
monitor voltage, the current C·dV/dt, the temperature and the fault bits. Injectable faults:
``over_temperature`` (status bit, output ramps to 0 V), ``no_response`` (no status frames,
setpoints ignored, output held), ``stuck_output`` (output frozen, status bit set).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..design.errors import ModelError

FAULTS = ("over_temperature", "no_response", "stuck_output")


@dataclass
class AmplifierModel:
    force_per_volt: float  # k [N/V]
    preload: float = 0.0  # [N]
    voltage_max: float = 150.0  # [V]
    time_constant: float = 0.0  # τ [s]; 0: ideal (the SIL check isolates firmware and bus)
    slew_rate: float = 2e6  # [V/s]
    capacitance: float = 1.8e-6  # [F]
    temperature: float = 35.0  # [°C]
    voltage: float = 0.0
    setpoint: float = 0.0
    fault: str | None = None
    setpoints_received: int = 0

    def __post_init__(self):
        for name in ("force_per_volt", "voltage_max", "slew_rate", "capacitance"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ModelError(f"amplifier {name}: {value!r} — must be a finite number > 0")
        if not (math.isfinite(self.time_constant) and self.time_constant >= 0):
            raise ModelError(f"amplifier time_constant: {self.time_constant!r} — must be >= 0 s (0: ideal)")

    def receive(self, voltage: float) -> None:
        """A decoded setpoint frame (already E2E-checked by the caller)."""
        if self.fault == "no_response":
            return
        self.setpoint = min(max(float(voltage), 0.0), self.voltage_max)
        self.setpoints_received += 1

    def advance(self, step: float) -> float:
        """Move the output over one sample; returns the mean normal force over it [N]."""
        start = self.voltage
        if self.fault == "stuck_output" or self.fault == "no_response":
            return self.force_per_volt * start + self.preload
        target = 0.0 if self.fault == "over_temperature" else self.setpoint
        if self.time_constant > 0:
            decay = math.exp(-step / self.time_constant)
            end = target + (start - target) * decay
            mean = target + (start - target) * self.time_constant / step * (1.0 - decay)
        else:  # ideal: the setpoint holds from the start of the sample
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
        if self.fault == "no_response":
            return None
        return {"monitor_voltage": self.voltage, "current": getattr(self, "current", 0.0),
                "temperature": 95.0 if self.fault == "over_temperature" else self.temperature,
                "over_temperature": int(self.fault == "over_temperature"), "no_response": 0,
                "stuck_output": int(self.fault == "stuck_output"), "over_current": 0}
