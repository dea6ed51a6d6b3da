"""The SIL firmware's XCP port on a python-can bus (docs/xcp.md): frames of the master's
identifier go into the slave (``<prefix>_xcp_rx``), its answers and DTOs go out.

The bench is the firmware's clock: the slave answers whenever the bench services its port, and
samples its DAQ list at the event that follows each controller step (:meth:`XcpPort.sample`).
A master such as pyxcp waits on the wall clock, so a master's script runs in a thread of its own
while the bench holds the simulation at a sample and services the port (:meth:`XcpPort.serve`):
whatever the script does lands between two samples, at the sample the bench chose, and the run
stays reproducible.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Callable
from typing import Any

from smartjoint.bench.loop import SilLoop, open_bus
from smartjoint.common.errors import ModelError
from smartjoint.design.control import study as closed_loop


class XcpPort:
    """The slave side of XCP on one python-can bus.

    Parameters
    ----------
    firmware : bench.firmware.Firmware
        A firmware compiled with its XCP slave (``xcp=``).
    interface, channel : str
        The python-can bus the master is on (default the in-process ``virtual`` one).
    """

    def __init__(self, firmware, interface: str = "virtual", channel: str = "smartjoint-sil.xcp"):
        if firmware.xcp is None:
            raise ModelError("xcp: the firmware was compiled without its XCP slave (Firmware(..., xcp=Xcp()))")
        self.fw, self.interface, self.channel = firmware, interface, channel
        self.master_id, self.slave_id = firmware.xcp.master_id, firmware.xcp.slave_id
        self.bus: Any = None
        self.sent = 0  # frames the slave sent
        self.commands = 0  # frames of the master it took
        self.on_frame: Callable[[Any, int], None] | None = None  # (message, time_us): a bench log

    def open(self) -> XcpPort:
        """Open the bus (the firmware keeps its state: reset it yourself)."""
        if self.bus is None:
            self.bus = open_bus(self.interface, self.channel)
        return self

    def close(self) -> None:
        """Shut the bus."""
        bus, self.bus = self.bus, None
        if bus is not None:
            bus.shutdown()

    def __enter__(self) -> XcpPort:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def _send(self, frames: list[bytes], time_us: int) -> None:
        import can

        for data in frames:
            message = can.Message(arbitration_id=self.slave_id, data=data, is_extended_id=False, is_fd=True)
            self.bus.send(message)
            self.sent += 1
            if self.on_frame is not None:
                self.on_frame(message, time_us)

    def receive(self, time_us: int, timeout: float = 0.0) -> int:
        """Take every waiting frame of the master (each answered at once); returns how many."""
        taken = 0
        while True:
            message = self.bus.recv(timeout=timeout if taken == 0 else 0.0)
            if message is None:
                return taken
            if message.arbitration_id == self.master_id and not message.is_extended_id:
                if self.on_frame is not None:
                    self.on_frame(message, time_us)
                self.fw.xcp_rx(bytes(message.data), time_us)
                self._send(self.fw.xcp_tx(), time_us)
                taken += 1
                self.commands += 1

    def sample(self, time_us: int) -> None:
        """The sample boundary after a controller step: the slave's event, then its DTOs."""
        self.receive(time_us)
        self.fw.xcp_event(time_us)
        self._send(self.fw.xcp_tx(), time_us)

    def serve(self, script: Callable[[], Any], time_us: int = 0, timeout: float = 60.0) -> Any:
        """Run ``script()`` (a master's commands) in a thread while this thread answers it.

        Returns
        -------
        Any
            What the script returned; what it raised is raised here.
        """
        result: dict[str, Any] = {}

        def run() -> None:
            try:
                result["value"] = script()
            except BaseException as error:  # handed to the bench's thread
                result["error"] = error

        worker = threading.Thread(target=run, name="xcp-master", daemon=True)
        worker.start()
        deadline = time.monotonic() + timeout
        while worker.is_alive():
            self.receive(time_us, timeout=0.002)
            if time.monotonic() > deadline:
                raise ModelError(f"xcp: the master's script ran over {timeout:g} s")
        self.receive(time_us)
        if "error" in result:
            raise result["error"]
        return result.get("value")


class XcpLoop(SilLoop):
    """The SIL loop (``bench.loop.SilLoop``) with the firmware's XCP port on a bus of its own: the
    slave's event after every controller step, and master scripts run at chosen samples.

    Parameters
    ----------
    firmware : bench.firmware.Firmware
        Compiled with its XCP slave.
    port : XcpPort
        The port the master talks to (opened and closed with the loop).
    scripts : dict of int to callable, optional
        Sample index → ``script()``: run by :meth:`XcpPort.serve` before that sample's frames,
        so what it changes acts from that sample on.
    realtime : bool
        Hold every sample until the wall clock reaches it, so that a master in another process
        meets the firmware at its own pace (``serve_study``); a slower bench just runs late.
    **options
        As for ``SilLoop``.
    """

    def __init__(self, firmware, port: XcpPort, scripts: dict[int, Callable[[], Any]] | None = None,
                 realtime: bool = False, **options):  # fmt: skip
        super().__init__(firmware, **options)
        self.port, self.scripts, self.realtime = port, dict(scripts or {}), realtime
        self.results: dict[int, Any] = {}  # what each script returned, by sample
        self.started: float | None = None  # the wall clock at the first sample
        self.late = 0.0  # the largest lag behind the wall clock [s]

    def reset(self) -> None:
        super().reset()
        self.port.open()
        self.port.on_frame = None if self.writer is None else self._log_xcp

    def _log_xcp(self, message, time_us: int) -> None:
        """An XCP frame into the bench log, on the channel after the plan's buses (bench decode
        reads it with xcp.dbc), at the sample's time."""
        if self.writer is None:  # the log is closed: frames of the port's own shut-down go unlogged
            return
        message.timestamp = time_us * 1e-6
        message.channel = len(self.bus_names)
        message.is_rx = message.arbitration_id == self.port.slave_id
        self.writer.on_message_received(message)

    def close(self) -> None:
        if getattr(self, "port", None) is not None:
            self.port.on_frame = None  # the log closes with the buses; the port's last frames are not the run's
        super().close()
        if getattr(self, "port", None) is not None:
            self.port.close()

    def step(self, measurements):
        k = self.k
        if k in self.scripts:
            self.results[k] = self.port.serve(self.scripts[k], int(round(float(measurements.time) * 1e6)) & 0xFFFFFFFF)
        return super().step(measurements)

    def _firmware_sample(self, t: float, time_us: int):
        status = super()._firmware_sample(t, time_us)
        self.port.sample(time_us)
        if self.realtime:
            now = time.monotonic()
            if self.started is None:
                self.started = now - t
            ahead = self.started + t - now
            if ahead > 0.0:
                time.sleep(ahead)
            self.late = max(self.late, -ahead)
        return status


def serve_study(setup, image, interface: str, channel: str, progress=print) -> dict:
    """The study's closed loop with the image's XCP slave served on a python-can bus at the wall
    clock's pace, for a master outside the bench (``smartjoint bench xcp``, CANape, INCA).

    Parameters
    ----------
    setup : study.StudySetup
        The plant and the study; ``setup.duration`` is how long the slave is served.
    image : bench.firmware.Firmware or bench.pil.TargetFirmware
        Built with its XCP slave.
    interface, channel : str
        The python-can bus of the master: ``udp_multicast`` reaches other processes on this host.
    progress : callable

    Returns
    -------
    dict
        Frames the slave took and sent, how late the bench ran behind the wall clock, and the
        ``loop`` itself (its record: what the firmware commanded at every sample).
    """
    from smartjoint.bench.sil import run_loop

    port = XcpPort(image, interface, channel)
    loop = XcpLoop(image, port, realtime=True, excitation_end=closed_loop.PULSE_DURATION,
                   channel=f"serve-{id(port)}")  # fmt: skip
    progress(f"      XCP slave 0x{port.slave_id:X} (master 0x{port.master_id:X}) on {interface}:{channel} for "
             f"{setup.duration:g} s at the wall clock's pace …")  # fmt: skip
    result = run_loop(setup, loop)
    return {"seconds": float(result.time[-1]), "commands": port.commands, "frames_sent": port.sent,
            "late_s": float(loop.late), "loop": loop}  # fmt: skip


TARGET_FLAGS = ("-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard")  # the PIL image's Makefile


def target_description(firmware, bus=None):
    """The A2L of the PIL target's image (``bench.pil.TargetFirmware`` built with its slave): the
    linked ELF's symbol addresses (``arm-none-eabi-nm``) and the target compiler's layout; base 0.

    Parameters
    ----------
    firmware : bench.pil.TargetFirmware
    bus : design.structure.description.Bus, optional
        The bus XCP runs on; default a CAN FD bus of 1/5 Mbit/s.
    """
    return elf_description(firmware.artifact, firmware.files, firmware.elf, firmware.xcp, firmware.db, bus)


def elf_description(artifact, files: dict, elf, xcp, db, bus=None, prefix: str = "smartjoint", real: str = "float",
                    compiler: str = "arm-none-eabi-gcc", flags: tuple[str, ...] = TARGET_FLAGS,
                    where: str | None = None):  # fmt: skip
    """The A2L of a linked image: its symbols' addresses (the toolchain's ``nm``) and the layout
    that ``compiler`` with ``flags`` gives the generated ``files``; base 0.

    Parameters
    ----------
    artifact : ControllerArtifact
    files : dict of str to str
        The image's generated sources.
    elf : path
        The linked image.
    xcp : Xcp
    db : cantools.database.can.Database
        Every frame of the network (the raw signals' scales).
    bus : design.structure.description.Bus, optional
        The bus XCP runs on; default a CAN FD bus of 1/5 Mbit/s.
    prefix, real : str
        The generated sources' prefix and scalar type.
    compiler : str
        The image's C compiler (GCC-style; its ``nm`` and ``objcopy`` share its prefix).
    flags : tuple of str
        The compiler flags that fix the image's ABI (default the PIL target's Cortex-M4F).
    where : str, optional
        The A2L header's words for the addresses.
    """
    from pathlib import Path

    from smartjoint.bench.firmware import symbols
    from smartjoint.codegen import a2l
    from smartjoint.design.structure.description import Bus

    tools = compiler[: -len("gcc")] if compiler.endswith("gcc") else ""
    measured = a2l.measurements(artifact, db)
    layout = a2l.probe(files, prefix, sorted({m.member for m in measured}), compiler, f"{tools}objcopy", flags)
    return a2l.describe(
        artifact, real, prefix, xcp, symbols(str(elf), f"{tools}nm"), layout, measured, bus or Bus("xcp"),
        where or f"Cortex-M4F image {Path(elf).name} (mps2-an386): linked addresses",
    )  # fmt: skip


def elf_bytes(elf, address: int, length: int, objdump: str = "arm-none-eabi-objdump") -> bytes:
    """``length`` bytes of a linked image's contents at ``address`` (``objdump -s``)."""
    import subprocess

    try:
        command = [objdump, "-s", f"--start-address=0x{address:x}", f"--stop-address=0x{address + length:x}", str(elf)]
        text = subprocess.run(command, capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError) as error:
        raise ModelError(f"{elf}: {objdump} cannot read it ({error})") from None
    data = bytearray()
    for line in text.splitlines():  # " 338c 736d6172 746a6f69 6e742066 6c6f6174  smartjoint float"
        match = re.match(r"^ ([0-9a-f]+) ([0-9a-f ]{35})  ", line)
        if match and int(match.group(1), 16) == address + len(data):
            data += bytes.fromhex(match.group(2).replace(" ", ""))
    return bytes(data[:length])


def sil_description(firmware, bus=None):
    """The A2L of a SIL image (``codegen.a2l``): the shared library's symbol values, which the
    slave adds to its base (:attr:`bench.firmware.Firmware.xcp_base`), and the host compiler's layout.

    Parameters
    ----------
    firmware : bench.firmware.Firmware
        Compiled with its XCP slave.
    bus : design.structure.description.Bus, optional
        The bus XCP runs on (its bit rates); default a CAN FD bus of 1/5 Mbit/s.
    """
    from smartjoint.bench.firmware import symbols
    from smartjoint.codegen import a2l
    from smartjoint.design.structure.description import Bus

    measured = a2l.measurements(firmware.artifact, firmware.db)
    members = sorted({m.member for m in measured})
    layout = a2l.probe(firmware.files, firmware.prefix, members)
    real = "float" if "typedef float" in firmware.files[f"{firmware.prefix}_types.h"] else "double"
    return a2l.describe(
        firmware.artifact, real, firmware.prefix, firmware.xcp, symbols(firmware.library), layout, measured,
        bus or Bus("xcp"), f"SIL shared library {firmware.library}: addresses are offsets from its "
        "load address",
    )  # fmt: skip


__all__ = ["XcpLoop", "XcpPort", "elf_bytes", "elf_description", "serve_study", "sil_description", "target_description"]
