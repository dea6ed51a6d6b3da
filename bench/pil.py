"""Processor in the loop: the generated firmware executing on its target, QEMU's ``mps2-an386``
(Cortex-M4 with FPU), in lock-step with the Python plant.

:class:`TargetFirmware` is the SIL bench's firmware (``bench.firmware.Firmware``: ``reset``,
``rx``, ``step``, ``tx``, ``safe``, ``faults``, ``command``, ``counters``) with the compiled image
replaced by the target: ``firmware/target/mps2_an386/pil.c`` makes the board an SLCAN adapter on
its UART 0, QEMU serves that UART on a local TCP port, and the bench talks to it through
python-can's own ``slcan`` interface (``socket://`` channel of pyserial). So
``bench.loop.SilLoop`` runs unchanged, faults included, and every frame the target sees is one a
python-can bus carried. The bench is the target's sample clock: a ``TICK`` frame (extended id
0x1FFFFF01, the sample time in µs) runs ``<prefix>_can_step`` and every ``<prefix>_can_tx``;
the target answers with its frames, the commanded normal forces (raw bytes of its state) and a
``SAMPLE`` frame (status, fault bits, safe state). The firmware is the float build of exactly the
sources the SIL bench compiles (``bench.firmware.sources``); instructions are counted by SysTick
under ``-icount shift=0`` and the stack by painting (``pil.c``).
"""

from __future__ import annotations

import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from smartjoint.bench import firmware, target
from smartjoint.codegen import can_layer
from smartjoint.common import law_registry, package_data
from smartjoint.common.errors import ModelError
from smartjoint.design.control.artifact import ControllerArtifact
from smartjoint.design.network import plan, protocol, xcp_bus
from smartjoint.design.structure.description import Xcp

ID_TIME, ID_TICK, ID_RESET, ID_QUERY, ID_EXIT = 0x1FFFFF00, 0x1FFFFF01, 0x1FFFFF02, 0x1FFFFF03, 0x1FFFFF04
ID_READY, ID_SAMPLE, ID_COUNTERS, ID_MEASURED, ID_COMMAND = 0x1FFFFF10, 0x1FFFFF11, 0x1FFFFF12, 0x1FFFFF13, 0x1FFFFF20
ID_XCP_DONE = 0x1FFFFF14  # after the XCP slave's answer to one command
ENTRY_POINTS = ("rx", "step", "tx", "empty")  # the MEASURED frame's timings, in order


def build_image(artifact: ControllerArtifact, work: Path, timeout: float = 180.0, xcp: Xcp | None = None) -> Path:
    """Make ``pil.elf`` in ``work`` from the SIL bench's generated float sources.

    Parameters
    ----------
    artifact : ControllerArtifact
        The controller design artefact the firmware is generated from.
    work : Path
        An empty folder for the sources and the build.
    timeout : float
        Seconds for the build.
    xcp : Xcp, optional
        Link the XCP slave (``codegen.xcp_slave``) and serve it (``pil.c``'s SMARTJOINT_PIL_XCP).

    Returns
    -------
    Path
        The image.
    """
    reason = target.missing_tools()
    if reason:
        raise ModelError(reason)
    generated = work / "generated"
    generated.mkdir(parents=True)
    for name, text in firmware.sources(artifact, "float", target.PREFIX, xcp).items():
        (generated / name).write_text(text)
    board = package_data.folder("smartjoint.firmware", "target/mps2_an386")
    command = ["make", "-s", "-C", str(board), f"GENERATED={generated}", f"BUILD={work / 'build'}", "pil"]
    if xcp is not None:
        command.append("PIL_DEFINES=-DSMARTJOINT_PIL_XCP")
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise ModelError(f"target {target.BOARD}: the PIL build did not finish within {timeout:g} s") from None
    if done.returncode != 0:
        raise ModelError(f"target {target.BOARD}: the PIL build failed:\n{(done.stderr or done.stdout).strip()}")
    return work / "build" / "pil.elf"


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now (the emulator serves its UART there)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def emulator_command(elf, port) -> list[str]:
    """QEMU's command line for the PIL image: the self-test's (``target.qemu_command``) with
    UART 0 served on ``127.0.0.1:port`` (QEMU waits for the bench to connect; no Nagle delay)."""
    command = target.qemu_command(elf)
    at = command.index("-nographic") + 1
    command[at:at] = ["-serial", f"tcp:127.0.0.1:{port},server=on,wait=on,nodelay=on"]
    return command


class TargetFirmware:
    """The firmware image running on the emulated target, behind a python-can ``slcan`` bus.

    Parameters
    ----------
    artifact : ControllerArtifact
        The controller design artefact the firmware is generated from.
    law : str
        ``"siso"`` or ``"clqg"``.
    timeout : float
        Seconds the target may take to answer one request before the run is stopped.
    xcp : Xcp, optional
        Link and serve the XCP slave: :meth:`xcp_rx`, :meth:`xcp_event` and :meth:`xcp_tx`
        carry its frames over the SLCAN link (``bench.xcp_port.XcpPort`` serves them to a master).

    Notes
    -----
    ``rx`` returns 0: the target's RX result bits are counted in its ``counters``, not sent back
    frame by frame (a round trip per frame would not change what the loop does). Close it (or use
    it as a context manager): that ends the emulation.
    """

    def __init__(
        self,
        artifact: ControllerArtifact,
        law: str = law_registry.NAMES[0],
        timeout: float = 30.0,
        xcp: Xcp | None = None,
    ):
        if law not in firmware.LAWS:
            raise ModelError(f"law: {law!r} — allowed: {', '.join(firmware.LAWS)}")
        self.artifact, self.law, self.timeout, self.xcp = artifact, law, float(timeout), xcp
        self.files = firmware.sources(artifact, "float", target.PREFIX, xcp)
        self.prefix = target.PREFIX
        self._xcp_frames: list[bytes] = []
        # the target is built for one bus: the default plan (design.network.plan.plan)
        self.network = plan.plan(artifact)
        self.xcp_plan = None if xcp is None else xcp_bus.xcp_plan(self.network, xcp)
        self.db = can_layer.network_database(self.network)
        self._scratch = tempfile.TemporaryDirectory(prefix="smartjoint-pil-")
        self.elf = build_image(artifact, Path(self._scratch.name), xcp=xcp)
        self.process: subprocess.Popen | None = None
        self.bus: Any = None  # the python-can slcan bus while the emulator runs
        self._start()
        try:
            self.reset()
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ the emulator and its bus
    def _start(self) -> None:
        import can

        port = free_port()
        command = emulator_command(self.elf, port)
        self.process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + self.timeout
        while True:
            try:
                self.bus = can.Bus(interface="slcan", channel=f"socket://127.0.0.1:{port}", sleep_after_open=0.0)
                # Small frames both ways: without TCP_NODELAY, Nagle's algorithm against delayed
                # ACKs holds each SLCAN line up to 40 ms (pyserial's socket:// does not set it).
                self.bus.serialPortOrig._socket.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                return
            except Exception as error:  # QEMU not listening yet
                if self.process.poll() is not None or time.monotonic() > deadline:
                    self.close()
                    raise ModelError(f"target {target.BOARD}: cannot reach the emulated UART ({error})") from None
                time.sleep(0.05)

    def close(self) -> None:
        """End the emulation (EXIT frame, then kill if it does not end) and shut the bus."""
        process, self.process = self.process, None
        bus, self.bus = self.bus, None
        if bus is not None:
            try:
                self._send(ID_EXIT, b"\x00", bus)
            except Exception:
                pass
        if process is not None:
            try:
                process.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            for stream in (process.stdout, process.stderr):
                if stream is not None:
                    stream.close()
        if bus is not None:
            try:
                bus.shutdown()
            except Exception:
                pass
        self._scratch.cleanup()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _lost(self, what: str, error) -> ModelError:
        """The error of a target that can no longer be reached (the emulator ended or hung)."""
        status = None if self.process is None else self.process.poll()
        ended = "" if status is None else f"; the emulator ended with status {status}"
        return ModelError(f"target {target.BOARD}: no answer to {what} ({error}){ended}")

    def _send(self, frame_id: int, data: bytes, bus=None, what: str = "a frame") -> None:
        import can

        extended = frame_id > 0x7FF
        message = can.Message(arbitration_id=frame_id, is_extended_id=extended, data=data, is_fd=len(data) > 8)
        try:
            (bus or self.bus).send(message)
        except can.CanError as error:
            raise self._lost(what, error) from None

    def _until(self, frame_id: int, what: str) -> list:
        """Every frame the target sends up to and including ``frame_id``."""
        import can

        frames = []
        deadline = time.monotonic() + self.timeout
        while True:
            try:
                message = self.bus.recv(timeout=0.5)
            except can.CanError as error:
                raise self._lost(what, error) from None
            if message is not None:
                frames.append(message)
                if message.is_extended_id and message.arbitration_id == frame_id:
                    return frames
            elif time.monotonic() > deadline or (self.process is not None and self.process.poll() is not None):
                raise ModelError(f"target {target.BOARD}: no answer to {what} within {self.timeout:g} s")

    # ------------------------------------------------------------------ the firmware interface
    def reset(self) -> None:
        """Power-up of the CAN layer with the law (``<prefix>_can_init``); clears the measurements."""
        self._time_us: int | None = None
        self._frames: list[tuple[int, bytes]] = []
        frames = self._until_sample(ID_RESET, bytes([firmware.LAWS[self.law]]), "RESET")
        ready = next(m for m in frames if m.is_extended_id and m.arbitration_id == ID_READY)
        if ready.data[0] != 0:
            raise ModelError(f"firmware: the CAN layer on the target refused law {self.law!r}")

    def _until_sample(self, frame_id: int, data: bytes, what: str) -> list:
        self._send(frame_id, data, what=what)
        frames = self._until(ID_SAMPLE, what)
        commands = range(ID_COMMAND, ID_COMMAND + 64)
        chunks = [bytes(m.data) for m in frames if m.is_extended_id and m.arbitration_id in commands]
        sample = bytes(frames[-1].data)
        self.status = int.from_bytes(sample[0:4], "little")
        self._faults = int.from_bytes(sample[4:8], "little")
        self._safe = bool(sample[8])
        size = sample[10]
        joints = len(self.artifact.joint_names)
        raw = b"".join(chunks)[: size * joints]
        self._command = np.frombuffer(raw, dtype=np.float32 if size == 4 else np.float64).astype(float)
        standard = [(m.arbitration_id, bytes(m.data)) for m in frames if not m.is_extended_id]
        slave = None if self.xcp is None else self.xcp.slave_id
        self._frames = [(i, d) for i, d in standard if i != slave]
        self._xcp_frames += [d for i, d in standard if i == slave]
        if len(standard) != sample[9]:
            raise ModelError(f"target {target.BOARD}: {sample[9]} frames sent, {len(self._frames)} received")
        return frames

    def rx(self, frame_id: int, data: bytes, time_us: int, bus: int | None = None) -> int:
        """One frame to the target's ``<prefix>_can_rx`` (after a TIME frame when the time changed);
        ``bus`` is 0 or None: the target has one bus."""
        if time_us != self._time_us:
            self._send(ID_TIME, int(time_us & 0xFFFFFFFF).to_bytes(4, "little"))
            self._time_us = time_us
        self._send(frame_id, bytes(data))
        return 0

    def step(self, time_us: int) -> int:
        """One sample on the target: ``<prefix>_can_step`` and every ``<prefix>_can_tx``; returns the status."""
        self._until_sample(ID_TICK, int(time_us & 0xFFFFFFFF).to_bytes(4, "little"), f"TICK at {time_us} µs")
        self._time_us = time_us
        return self.status

    def xcp_rx(self, data: bytes, time_us: int) -> None:
        """One frame of the XCP master to the target's slave; its answer waits for :meth:`xcp_tx`."""
        if self.xcp is None:
            raise ModelError("xcp: the target image was built without its XCP slave (TargetFirmware(..., xcp=Xcp()))")
        if time_us != self._time_us:
            self._send(ID_TIME, int(time_us & 0xFFFFFFFF).to_bytes(4, "little"))
            self._time_us = time_us
        self._send(self.xcp.master_id, bytes(data))
        frames = self._until(ID_XCP_DONE, "an XCP command")
        self._xcp_frames += [bytes(m.data) for m in frames if not m.is_extended_id]

    def xcp_event(self, time_us: int) -> None:
        """Nothing: the target runs its slave's event with every TICK, after the step."""

    def xcp_tx(self) -> list[bytes]:
        """The slave's frames since the last call: answers, then the DTOs of the last event."""
        frames, self._xcp_frames = self._xcp_frames, []
        return frames

    def tx(self) -> list[tuple[int, bytes]]:
        """The frames of the last step, as (identifier, payload)."""
        frames, self._frames = self._frames, []
        return frames

    def tx_bus(self) -> list[tuple[int, int, bytes]]:
        """The frames of the last step, as (bus, identifier, payload): all on the one bus."""
        return [(0, frame_id, data) for frame_id, data in self.tx()]

    @property
    def bus_safe(self) -> list[bool]:
        """The one bus's joints hold the safe force."""
        return [self._safe]

    @property
    def safe(self) -> bool:
        return self._safe

    @property
    def faults(self) -> int:
        return self._faults

    def fault_names(self) -> list[str]:
        return [name for k, name in enumerate(protocol.CONTROLLER_FAULTS) if self._faults >> k & 1]

    @property
    def command(self) -> np.ndarray:
        return self._command.copy()

    def _query(self) -> tuple[bytes, bytes]:
        self._send(ID_QUERY, b"")
        frames = self._until(ID_MEASURED, "QUERY")
        counters = next(m for m in frames if m.is_extended_id and m.arbitration_id == ID_COUNTERS)
        return bytes(counters.data), bytes(frames[-1].data)

    @property
    def counters(self) -> dict[str, int]:
        raw = self._query()[0]
        return {name: int.from_bytes(raw[4 * k : 4 * k + 4], "little") for k, name in enumerate(firmware.COUNTERS)}

    def measurements(self) -> dict:
        """What the target measured since the last reset: per entry point the calls and the
        instructions (mean with the measurement's own overhead subtracted, and the largest
        single call), the stack's high-water mark below ``main``, the stack's size and the
        CAN state's size.

        Returns
        -------
        dict
        """
        words = np.frombuffer(self._query()[1], dtype="<u4").astype(int)
        per_tick = int(words[14])
        timing = {name: words[3 * k : 3 * k + 3] for k, name in enumerate(ENTRY_POINTS)}
        overhead = timing["empty"][1] / max(timing["empty"][0], 1)
        out: dict = {}
        for name in ("rx", "step", "tx"):
            calls, ticks, largest = (int(v) for v in timing[name])
            out[name] = {
                "calls": calls,
                "instructions_mean": per_tick * (ticks / calls - overhead) if calls else None,
                "instructions_largest": per_tick * (largest - overhead) if calls else None,
            }
        out["stack_high_water"] = int(words[12])
        out["stack_size"] = int(words[13])
        out["instructions_per_tick"] = per_tick
        out["can_state_size"] = int(words[15])
        return out
