"""The firmware's XCP slave (issue 34, docs/xcp.md) against pyxcp, the open-source master, on the
SIL bench: identification and uploads equal the artefact, calibration that cannot hurt the
structure, a DOWNLOAD mid-study equal to a MIL law switching at the same sample, DAQ of the whole
study equal to the firmware's own variables, and the generated A2L parsed by pya2l."""

from __future__ import annotations

import dataclasses
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pyxcp")

from test_can_layer import REFERENCE  # noqa: E402

from smartjoint.bench import sil, target, xcp_master, xcp_study  # noqa: E402
from smartjoint.bench.firmware import Firmware, symbols  # noqa: E402
from smartjoint.bench.fmu_check import FLOAT_BOUND  # noqa: E402
from smartjoint.bench.pil import TargetFirmware  # noqa: E402
from smartjoint.bench.xcp_port import XcpLoop, XcpPort, sil_description, target_description  # noqa: E402
from smartjoint.codegen import xcp_slave  # noqa: E402
from smartjoint.design.control import artifact, laws  # noqa: E402
from smartjoint.design.control import study as closed_loop  # noqa: E402
from smartjoint.design.plant.interface import Measurements  # noqa: E402
from smartjoint.design.structure.description import Xcp  # noqa: E402

ERR_ACCESS_LOCKED, ERR_OUT_OF_RANGE, ERR_WRITE_PROTECTED, ERR_ACCESS_DENIED = 0x25, 0x22, 0x23, 0x24
ERR_TEMPORARILY_NOT_ACCESSIBLE = 0x33
SWITCH = 1000  # the sample of t = 1 s, where the calibration lands


@pytest.fixture(scope="module")
def reference():
    return artifact.load(REFERENCE)


@pytest.fixture(scope="module")
def images(reference):
    """Per build the SIL firmware with its slave and its A2L description."""
    out = {}
    for real in ("double", "float"):
        fw = Firmware(reference, "siso", real, xcp=Xcp())
        out[real] = fw, sil_description(fw)
    return out


@pytest.fixture(scope="module")
def study_setup(three_type_a):
    design, model = three_type_a
    return closed_loop.setup(design, model)


def _code(error) -> int:
    return int(error.get_error_code())


def _session(fw, script, channel: str):
    """``script(master)`` against the slave, this thread answering; connected first, closed after."""
    app = xcp_master.application(fw.artifact, fw.xcp, channel=channel, timeout=1.0)
    x = xcp_master.master(app)

    def run():
        with x:
            x.connect()
            return script(x)

    with XcpPort(fw, channel=channel) as port:
        return port.serve(run)


def _refused(call) -> int:
    from pyxcp.types import XcpResponseError

    try:
        call()
    except XcpResponseError as error:
        return _code(error)
    return 0


def _page(x, description, real: str) -> bytes:
    first = min(c.address for c in description.characteristics.values())
    x.setMta(first)
    return bytes(x.fetch(len(description.characteristics) * (8 if real == "double" else 4)))


def test_identification_and_uploads_equal_the_artefact(images, reference):
    fw, description = images["double"]
    fw.reset()
    values = xcp_slave.calibration_values(reference, "double", Xcp())

    def script(x):
        epk, name = x.identifier(0), x.identifier(1)
        uploaded = {n: struct.unpack("<d", bytes(x.shortUpload(8, c.address)))[0]
                    for n, c in description.characteristics.items()}  # fmt: skip
        page = _page(x, description, "double")
        x.setMta(min(c.address for c in description.characteristics.values()))
        checksum = x.buildChecksum(len(page))
        return epk, name, uploaded, page, checksum

    epk, name, uploaded, page, checksum = _session(fw, script, "xcp-identification")
    assert epk == xcp_slave.epk(reference, "double", "smartjoint") and name == "smartjoint"
    assert len(uploaded) == len(values) == 36
    assert [uploaded[v.name] for v in values] == [v.value for v in values]  # every tunable, bit for bit
    assert uploaded["siso.boundary_layer.A1"] == float(reference.siso_boundary_layer[0])
    assert uploaded["clqg.boundary_layer"] == float(reference.clqg_boundary_layer)
    assert page == struct.pack(f"<{len(values)}d", *[v.value for v in values])
    assert checksum.checksumType == "XCP_CRC_32" and checksum.checksum == zlib.crc32(page)


def test_without_unlock_or_with_a_wrong_key_nothing_is_written(images):
    fw, description = images["double"]
    fw.reset()

    def script(x):
        before = _page(x, description, "double")
        codes = []
        for c in description.characteristics.values():
            x.setMta(c.address)
            codes.append(_refused(lambda c=c: x.download(struct.pack("<d", c.lower))))
        seed = bytes(x.getSeed(0, 0x01).seed)
        wrong = bytearray(xcp_slave.key_from_seed(seed, xcp_slave.secret(fw.artifact, Xcp())))
        wrong[0] ^= 1
        unlock = _refused(lambda: x.unlock(8, bytes(wrong)))
        x.connect()  # a wrong key ends the session; a new one starts locked
        status = x.getStatus().resourceProtectionStatus
        return codes, unlock, status.calpag and status.daq, before, _page(x, description, "double")

    codes, unlock, locked, before, after = _session(fw, script, "xcp-locked")
    assert set(codes) == {ERR_ACCESS_LOCKED} and len(codes) == 36
    assert unlock == ERR_ACCESS_LOCKED and locked and after == before


def _pack(value: float, real: str) -> bytes:
    return struct.pack("<d" if real == "double" else "<f", value)


def _refusals(fw, description, real: str):
    """The DOWNLOADs the slave must refuse while the controller runs, with their codes."""
    c = description.characteristics
    table = symbols(fw.library)
    eps, low, span = c["siso.boundary_layer.A1"], c["siso.normal_force_min.A1"], c["siso.normal_force_range.A1"]
    controller = table["smartjoint_controller"]
    return [
        ("above its upper limit", eps.address, _pack(eps.upper * 1.01, real), ERR_OUT_OF_RANGE),
        ("below its lower limit", eps.address, _pack(eps.lower * 0.99, real), ERR_OUT_OF_RANGE),
        ("NaN", eps.address, _pack(float("nan"), real), ERR_OUT_OF_RANGE),
        ("part of a value", eps.address, _pack(eps.upper, real)[:2], ERR_OUT_OF_RANGE),
        ("F_N^min + range above F_N^max", low.address, _pack(low.upper, real), ERR_OUT_OF_RANGE),
        ("both, one out", low.address, _pack(low.lower, real) * 3 + _pack(span.upper * 2, real), ERR_OUT_OF_RANGE),
        ("the flash reference page", table["smartjoint_calibration_reference"], _pack(1.0, real), ERR_WRITE_PROTECTED),
        ("the controller's state", controller, _pack(1.0, real), ERR_WRITE_PROTECTED),
        ("a safety limit (friction range)", table["friction_force_limit"], _pack(1.0, real), ERR_ACCESS_DENIED),
        ("nowhere", 0x10, _pack(1.0, real), ERR_ACCESS_DENIED),
    ]


def test_refused_downloads_change_no_byte_and_not_the_study(images, study_setup, tmp_path):
    """In the safe state every DOWNLOAD is refused; while the law runs, one out of range, part of
    a value, past F_N^max, to flash, to the state or to a safety limit is refused: the page's
    bytes stay (UPLOAD, checksum) and the study's commands equal those of a run without XCP.
    The bench log holds the XCP frames on the channel after the control bus's."""
    fw, description = images["double"]
    setup = dataclasses.replace(study_setup, duration=0.3)
    app = xcp_master.application(fw.artifact, fw.xcp, channel="xcp-refusals.xcp", timeout=1.0)
    x = xcp_master.master(app)
    eps = description.characteristics["siso.boundary_layer.A1"]
    seen = {}

    def safe_state():
        x.__enter__()
        x.connect()
        x.cond_unlock()
        seen["before"] = _page(x, description, "double")
        x.setMta(eps.address)
        seen["safe"] = _refused(lambda: x.download(_pack(eps.value * 2, "double")))

    def running():
        seen["refused"] = []
        for _, address, data, _ in _refusals(fw, description, "double"):
            x.setMta(address)
            seen["refused"].append(_refused(lambda data=data: x.download(data)))
        seen["after"] = _page(x, description, "double")
        x.disconnect()
        x.__exit__(None, None, None)

    port = XcpPort(fw, channel="xcp-refusals.xcp")
    loop = XcpLoop(fw, port, {0: safe_state, 100: running}, excitation_end=closed_loop.PULSE_DURATION,
                   channel="xcp-refusals", log_path=tmp_path / "bench.blf")  # fmt: skip
    sil.run_loop(setup, loop)
    _assert_logged(tmp_path / "bench.blf", port, loop)
    assert seen["safe"] == ERR_TEMPORARILY_NOT_ACCESSIBLE
    assert seen["refused"] == [code for *_, code in _refusals(fw, description, "double")]
    assert seen["after"] == seen["before"]
    plain = XcpLoop(fw, XcpPort(fw, channel="xcp-plain.xcp"), {}, excitation_end=closed_loop.PULSE_DURATION,
                    channel="xcp-plain")  # fmt: skip
    sil.run_loop(setup, plain)
    assert not loop.record.safe[100] and np.array_equal(np.array(loop.record.command), np.array(plain.record.command))


def _assert_logged(path, port, loop) -> None:
    """The log's XCP frames: every command the slave took and every frame it sent, on channel 1,
    each within the run; the control frames stay on channel 0."""
    from smartjoint.bench import logs
    from smartjoint.design.network import xcp_bus

    content = logs.load(str(path))
    xcp = [m for m in content.messages if m.channel == 1]
    assert sum(m.arbitration_id == port.master_id for m in xcp) == port.commands > 0
    assert sum(m.arbitration_id == port.slave_id for m in xcp) == port.sent > 0
    assert len(xcp) == port.commands + port.sent and all(0.0 <= m.timestamp <= loop.record.time[-1] for m in xcp)
    assert {m.channel for m in content.messages} == {0, 1}
    (bus_db,) = loop.fw.databases  # the firmware's one bus, as its bus.dbc says
    decoded = logs.decode(content, [bus_db, xcp_bus.database(loop.fw.xcp)])  # as bench decode --dbc … --dbc xcp.dbc
    assert decoded.skipped() == 0 and sum(decoded.without_signals.values()) == len(xcp)


def _calibrated_run(fw, description, setup, real: str, channel: str):
    """The study with DAQ of every scalar measurement from sample 0 and ε of joint A1 tripled by
    DOWNLOAD at sample 1000; per sample also the controller's bytes as the firmware holds them."""
    entries = xcp_study.daq_entries(description, fw.xcp_plan.odts)  # what the XCP bus has room for
    app = xcp_master.application(fw.artifact, fw.xcp, channel=f"{channel}.xcp", timeout=2.0)
    policy = xcp_master.recorder("sample", entries)
    x = xcp_master.master(app, policy)
    eps = description.characteristics["siso.boundary_layer.A1"]
    new = float(np.float32(3.0 * eps.value))

    def start():
        x.__enter__()
        x.connect()
        x.cond_unlock()
        policy.setup()
        policy.start()

    def calibrate():
        x.setMta(eps.address)
        x.download(_pack(new, real))

    class Snapshots(XcpLoop):
        def _firmware_sample(self, t, time_us):
            status = super()._firmware_sample(t, time_us)
            self.snapshots.append(bytes(fw.ffi.buffer(fw._state, size)))
            return status

    size = int(fw.lib.smartjoint_can_state_size())
    port = XcpPort(fw, channel=f"{channel}.xcp")
    loop = Snapshots(fw, port, {0: start, SWITCH: calibrate}, excitation_end=closed_loop.PULSE_DURATION,
                     channel=channel)  # fmt: skip
    loop.snapshots = []
    sil.run_loop(setup, loop)
    _finish(port, x, policy)
    return loop, policy.recorded, new, entries


def _finish(port, x, policy) -> None:
    """After the study: the master stops DAQ and disconnects, the port answering."""

    def stop():
        policy.stop()
        x.disconnect()
        x.__exit__(None, None, None)

    with port:
        port.serve(stop)


def _mil_switching(reference, description, recorded, new: float):
    """The SISO law's Python reference on the inputs the firmware decoded (its DAQ'd raw values),
    restarted where the firmware leaves the safe state, ε_A1 switched to ``new`` at sample 1000."""
    law = laws.siso_law(reference)
    joints = list(reference.joint_names)

    def decoded(field):
        return np.stack([recorded.column(f"{field}.{j}") * description.measurements[f"{field}.{j}"].factor
                         for j in joints], axis=1)  # fmt: skip

    v, f, n = decoded("sliding_velocity"), decoded("friction_force"), decoded("normal_force")
    safe = recorded.column("safe")
    out, held = np.full((len(safe), len(joints)), np.nan), True
    for k in range(len(safe)):
        if k == SWITCH:
            law.boundary_layer = law.boundary_layer.copy()
            law.boundary_layer[0] = new
        if safe[k]:
            held = True
            continue
        if held:
            law.reset()
            held = False
        out[k] = law.step(Measurements(k * reference.sample_time, np.zeros(2), v[k], f[k], n[k]))
    return out


@pytest.mark.numerics
@pytest.mark.parametrize("real", ["double", "float"])
def test_calibration_mid_study_equals_mil_switching_and_daq_equals_the_firmware(images, reference, study_setup,
                                                                                real, tmp_path):  # fmt: skip
    fw, description = images[real]
    loop, recorded, new, entries = _calibrated_run(fw, description, study_setup, real, f"xcp-study-{real}")
    samples = int(round(study_setup.duration / reference.sample_time))
    # DAQ: >= 20 signals every sample of the study, none lost, each the firmware's variable then.
    assert len(entries) >= 20 and len(recorded.rows) == len(loop.record.time) == samples
    assert fw.xcp_overruns == 0 and np.all(np.diff(recorded.time_us) == 1000)
    controller = symbols(fw.library)["smartjoint_controller"]
    for name, address, kind in entries:
        offset, dtype = address - controller, np.dtype(xcp_master.NUMPY_TYPES[kind])
        own = [np.frombuffer(s[offset : offset + dtype.itemsize], dtype)[0] for s in loop.snapshots]
        assert np.array_equal(recorded.column(name), np.array(own)), name
    commands = np.stack([recorded.column(f"command.{j}") for j in reference.joint_names], axis=1)
    assert np.array_equal(commands, np.array(loop.record.command))
    # Calibration: from sample 1000 on the law runs with the new ε, as a MIL law switched there.
    mil = _mil_switching(reference, description, recorded, new)
    compared = ~np.isnan(mil[:, 0])
    assert compared[SWITCH:].all()
    deviation = np.max(np.abs(mil[compared] - commands[compared]))
    span = float(np.min(reference.normal_force_max - reference.normal_force_min))
    assert deviation == 0.0 if real == "double" else deviation <= FLOAT_BOUND * span
    unswitched = _mil_switching(reference, description, recorded, float(reference.siso_boundary_layer[0]))
    assert np.max(np.abs(unswitched[SWITCH:] - commands[SWITCH:])) > 1.0  # the switch is seen in the commands
    # The measurement as MF4 with the A2L's units.
    from asammdf import MDF

    path = xcp_master.write_mf4(recorded, description, tmp_path / "daq.mf4")
    with MDF(path) as mdf:
        signal = mdf.get("command.A1")
        velocity = mdf.get("sliding_velocity.A1")
    assert signal.unit == "N" and velocity.unit == "m/s" and len(signal.samples) == samples
    assert np.array_equal(signal.samples, commands[:, 0])
    assert np.allclose(velocity.samples, recorded.column("sliding_velocity.A1") * 1e-9, rtol=0, atol=1e-18)


@pytest.fixture(scope="module")
def a2l_parser():
    parser = pytest.importorskip("pya2l.parser")
    with parser.A2lParser() as p:
        yield p


def test_the_a2l_parses_and_states_the_image(a2l_parser, images, reference):
    fw, description = images["float"]
    tree = a2l_parser.tree_from_a2l(description.text.encode())
    module = tree.PROJECT.MODULE[0]
    measured = {m.Name.Value: m for m in module.MEASUREMENT}
    calibrated = {c.Name.Value: c for c in module.CHARACTERISTIC}
    assert set(measured) == set(description.measurements) and set(calibrated) == set(description.characteristics)
    for name, m in measured.items():
        assert m.ECU_ADDRESS.Address.Value == description.measurements[name].address
        assert m.DataType.Value == description.measurements[name].datatype
    for name, c in calibrated.items():
        stated = description.characteristics[name]
        assert (c.Address.Value, c.LowerLimit.Value, c.UpperLimit.Value) == (stated.address, stated.lower, stated.upper)
    assert module.MOD_PAR.EPK.Identifier.Value == xcp_slave.epk(reference, "float", "smartjoint")
    assert module.MOD_PAR.ADDR_EPK[0].Address.Value == symbols(fw.library)["smartjoint_xcp_epk"]
    assert [m for m in measured if m.startswith("clqg.q")] == ["clqg.q0", "clqg.q1"]


@pytest.mark.skipif(target.missing_tools() is not None, reason=f"{target.missing_tools()} (CI installs them)")
def test_pil_target_identification_calibration_and_daq(reference, study_setup):
    """pyxcp to the slave on the emulated Cortex-M4F (its frames over the target's SLCAN link):
    the identification and the page equal the artefact; DAQ of every scalar measurement at every
    sample equals the commands the target reported; a DOWNLOAD at sample 250 is in the page."""
    setup = dataclasses.replace(study_setup, duration=0.5)
    values = xcp_slave.calibration_values(reference, "float", Xcp())
    with TargetFirmware(reference, "siso", xcp=Xcp()) as fw:
        description = target_description(fw)
        entries = xcp_study.daq_entries(description, fw.xcp_plan.odts)
        app = xcp_master.application(reference, Xcp(), channel="xcp-pil.xcp", timeout=5.0)
        policy = xcp_master.recorder("sample", entries)
        x = xcp_master.master(app, policy)
        eps = description.characteristics["siso.boundary_layer.A1"]
        seen = {}

        def start():
            x.__enter__()
            x.connect()
            seen["epk"] = x.identifier(0)
            seen["page"] = _page(x, description, "float")
            x.cond_unlock()
            policy.setup()
            policy.start()

        def calibrate():
            x.setMta(eps.address)
            x.download(_pack(3.0 * eps.value, "float"))
            seen["eps"] = struct.unpack("<f", bytes(x.shortUpload(4, eps.address)))[0]

        port = XcpPort(fw, channel="xcp-pil.xcp")
        loop = XcpLoop(fw, port, {0: start, 250: calibrate}, excitation_end=closed_loop.PULSE_DURATION,
                       channel="xcp-pil")  # fmt: skip
        sil.run_loop(setup, loop)
        _finish(port, x, policy)
    assert seen["epk"] == xcp_slave.epk(reference, "float", "smartjoint")
    assert seen["page"] == struct.pack(f"<{len(values)}f", *[v.value for v in values])
    assert seen["eps"] == float(np.float32(3.0 * eps.value))
    recorded = policy.recorded
    assert len(recorded.rows) == len(loop.record.time) == 500 and np.all(np.diff(recorded.time_us) == 1000)
    commands = np.stack([recorded.column(f"command.{j}") for j in reference.joint_names], axis=1)
    assert np.array_equal(commands, np.array(loop.record.command, dtype=np.float32))


def test_the_committed_a2l_describes_the_committed_firmware(a2l_parser, reference):
    """firmware/generated/smartjoint.a2l (``smartjoint codegen``: the PIL image's linked
    addresses) parses, names the reference artefact's EPK, every tunable with the slave's limits
    and every measurement, all in the target's RAM."""
    text = (Path(REFERENCE).parent / "smartjoint.a2l").read_text(encoding="ascii")
    module = a2l_parser.tree_from_a2l(text.encode()).PROJECT.MODULE[0]
    assert module.MOD_PAR.EPK.Identifier.Value == xcp_slave.epk(reference, "float", "smartjoint")
    values = xcp_slave.calibration_values(reference, "float", Xcp())
    limits = {c.Name.Value: (c.LowerLimit.Value, c.UpperLimit.Value) for c in module.CHARACTERISTIC}
    assert limits == {v.name: (v.lower, v.upper) for v in values}
    addresses = [m.ECU_ADDRESS.Address.Value for m in module.MEASUREMENT] + [
        c.Address.Value for c in module.CHARACTERISTIC
    ]
    assert len(module.MEASUREMENT) >= 20 and all(0x20000000 <= a < 0x20400000 for a in addresses)


@pytest.mark.parametrize(
    "line, key",
    [
        ("master_id = 0x100", "xcp.master_id"),  # among the control protocol's identifiers
        ("slave_id = 0x7F0", "xcp.slave_id"),  # the master's
        ('key = "0123"', "xcp.key"),
        ("daq_entries = 0", "xcp.daq_entries"),
        ("calibration_decades = 9", "xcp.calibration_decades"),
        ("speed = 1", "xcp.speed"),
    ],
)
def test_a_bad_xcp_table_is_refused_in_one_line(tmp_path, line, key):
    from conftest import design_file_error

    from smartjoint.design.structure import spec

    base = (spec.REFERENCE_DESIGN.parent / "three_type_a.toml").as_posix()
    message = design_file_error(tmp_path / "d.toml", f'base = "{base}"\n[xcp]\n{line}\n')
    assert key in message and "\n" not in message


def test_xcp_has_a_bus_of_its_own_with_the_room_it_plans(reference, tmp_path):
    """By default XCP gets a bus of its own at the control bus's rates and limit: one command pair
    and 2 DTOs of 64 bytes per sample stay within 70 %; sharing the reference's control bus
    (55.7 % of 70 %, the default plan's) is refused in one line before any work; xcp.dbc loads in
    cantools."""
    from conftest import design_file_error  # noqa: F401 (the design file's refusals: above)

    from smartjoint.common.errors import ModelError
    from smartjoint.design.network import plan, protocol, xcp_bus

    network = plan.plan(reference)
    room = xcp_bus.xcp_plan(network, Xcp())
    assert (room.bus.name, room.shared, room.odts) == ("xcp", False, 2) and room.load <= room.bus.limit
    frames = {m.name: (m.frame_id, m.length, m.is_fd) for m in protocol.load_dbc(room.dbc).messages}
    assert frames == {"XCP_CMD": (0x7F0, 64, True), "XCP_RES": (0x7F1, 64, True)}
    with pytest.raises(ModelError) as refused:
        xcp_bus.xcp_plan(network, dataclasses.replace(Xcp(), bus="can0"))
    assert "bus can0 would carry" in str(refused.value) and "\n" not in str(refused.value)
    files = xcp_slave.render_xcp(reference)
    assert "#define SMARTJOINT_XCP_DAQ_ODTS 2 " in files["smartjoint_xcp.h"] and files["xcp.dbc"] == room.dbc
