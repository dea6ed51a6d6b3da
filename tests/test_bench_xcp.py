"""``smartjoint bench xcp``: a master outside the bench (pyxcp over python-can) that knows the
ECU only by its A2L — identification against the EPK, the calibration read back, a DOWNLOAD
within the A2L's limits at a chosen time of a DAQ measurement, the MF4 — against a SIL image
served at the wall clock's pace (``sil --xcp-serve``), and every refusal in one line."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pyxcp")
pytest.importorskip("pya2l")

from test_can_layer import REFERENCE  # noqa: E402

from smartjoint import cli  # noqa: E402
from smartjoint.bench import a2l_file, xcp_port  # noqa: E402
from smartjoint.bench.firmware import Firmware  # noqa: E402
from smartjoint.design.control import artifact  # noqa: E402
from smartjoint.design.control import study as closed_loop  # noqa: E402
from smartjoint.design.structure.description import Xcp  # noqa: E402

FACTOR = 3.0  # the new ε against the artefact's, inside the A2L's limits (two decades either way)


def _designed(fw, joint: int) -> float:
    """The artefact's ε of a joint as the float build holds it."""
    return float(np.float32(np.asarray(fw.artifact.siso_boundary_layer, dtype=float)[joint]))


@pytest.fixture(scope="module")
def served_image(tmp_path_factory):
    """The float SIL image of the reference artefact with its slave, and its A2L on disk."""
    fw = Firmware(artifact.load(REFERENCE), "siso", "float", xcp=Xcp())
    path = tmp_path_factory.mktemp("bench_xcp") / "sil.a2l"
    path.write_text(xcp_port.sil_description(fw).text)
    return fw, path


def _bench(*argv) -> tuple[int, str, str]:
    """``smartjoint bench xcp …`` in this process: (exit code, stdout, stderr)."""
    return _run_cli(["bench", "xcp", *argv])


def test_the_a2l_reads_back_as_codegen_stated_it(served_image):
    fw, path = served_image
    stated = xcp_port.sil_description(fw)
    read = a2l_file.read(path)
    assert (read.master_id, read.slave_id) == (fw.xcp.master_id, fw.xcp.slave_id)
    assert (read.bitrate, read.data_bitrate) == (1_000_000, 5_000_000)
    assert read.event_cycle == pytest.approx(fw.artifact.sample_time, rel=1e-12)
    assert read.epk.startswith("smartjoint float ") and fw.artifact.artifact_sha256[:16] in read.epk
    scalars = {n: m for n, m in stated.measurements.items() if m.count == 1}
    assert set(read.measurements) == set(scalars)
    assert set(read.characteristics) == set(stated.characteristics)
    for name, m in read.measurements.items():  # every field as written, limits to their printed digits
        assert dataclasses.replace(m, lower=0.0, upper=0.0) == dataclasses.replace(scalars[name], lower=0.0, upper=0.0)
    for name, c in read.characteristics.items():
        s = stated.characteristics[name]
        assert (c.address, c.datatype, c.unit, c.lower, c.upper) == (s.address, s.datatype, s.unit, s.lower, s.upper)


def test_settings_outside_the_a2l_are_refused_before_any_frame(served_image, capsys):
    _, path = served_image
    channel = "bench-xcp-nobody"  # no slave on it: a frame sent would time out, not be refused
    for setting, words in [
        ("siso.boundary_layer.A1=1", "outside the A2L's limits"),
        ("siso.boundary_layer.A1=nan", "outside the A2L's limits"),
        ("siso.normal_force_min.A1=5", "[10, 400] N"),
        ("no.such.value=1", "not a CHARACTERISTIC"),
        ("siso.boundary_layer.A1", "NAME=VALUE"),
    ]:
        code, out, err = _bench(path, "--channel", channel, "--set", setting, "--artifact", REFERENCE)
        assert code == 2 and words in err and err.count("\n") == 1, (setting, err)
    for options, words in [
        (["--key", "12"], "32 hex digits"),
        (["--measure", "nothing"], "not a MEASUREMENT"),
        (["--duration", "inf"], "--duration"),
        (["--prescaler", "0"], "--prescaler"),
        (["--set-at", "0.5"], "needs --measure"),
        (["-o", "daq.csv", "--measure", "all"], "must name an .mf4 file"),
    ]:
        code, _, err = _bench(path, "--channel", channel, *options)
        assert code == 2 and words in err and err.count("\n") == 1, (options, err)
    code, _, err = _bench(Path(path).with_name("missing.a2l"), "--channel", channel)
    assert code == 2 and "cannot be read" in err
    start = time.monotonic()
    code, _, err = _bench(path, "--channel", channel, "--timeout", "0.3")
    assert code == 2 and "no answer from slave 0x7F1 to CONNECT" in err and time.monotonic() - start < 10


class _Served:
    """The image served on a virtual bus in a thread for ``seconds`` of the study."""

    def __init__(self, image, setup, channel: str, seconds: float):
        self.out: dict = {}
        self.error: BaseException | None = None

        def serve():
            try:
                self.out = xcp_port.serve_study(dataclasses.replace(setup, duration=seconds), image, "virtual",
                                                channel, progress=lambda message: None)  # fmt: skip
            except BaseException as error:  # handed to the test's thread
                self.error = error

        self.thread = threading.Thread(target=serve, daemon=True)

    def __enter__(self):
        self.thread.start()
        time.sleep(0.5)
        return self

    def __exit__(self, *exc):
        self.thread.join(timeout=120)
        assert not self.thread.is_alive() and self.error is None, self.error


def test_bench_xcp_calibrates_mid_measurement_and_records_the_firmware(served_image, three_type_a, tmp_path):
    fw, path = served_image
    fw.reset()
    setup = closed_loop.setup(*three_type_a)
    mf4, plots = tmp_path / "daq.mf4", tmp_path / "plots"
    new = FACTOR * _designed(fw, 0)
    with _Served(fw, setup, "bench-xcp-served", 6.0) as served:
        code, out, err = _bench(path, "--channel", "bench-xcp-served", "--artifact", REFERENCE, "--measure", "all",
                                "--duration", "1.5", "--set", f"siso.boundary_layer.A1={new!r}",
                                "--set-at", "0.5", "-o", mf4, "--plots", plots, "--json")  # fmt: skip
        assert code == 0, err
        report = json.loads(out)
        code, out, err = _bench(path, "--channel", "bench-xcp-served", "--json")  # reads, needs no key
        assert code == 0, err
        after = json.loads(out)["calibration"]
    daq = report["daq"]
    assert report["calibration"]["siso.boundary_layer.A1"] == _designed(fw, 0)
    written = float(np.float32(new))
    assert report["read_back"]["siso.boundary_layer.A1"] == written == after["siso.boundary_layer.A1"]
    assert len(daq["signals"]) >= 20 and daq["lost_samples"] == 0 and daq["stopped"] == "duration"
    assert daq["seconds"] >= 1.5 and daq["set_at_s"] >= 0.5
    assert daq["daq_list"] == {"odts": 2, "entries": 32}  # what the design's bus plan gave the slave
    # Every DAQ value is the firmware's own: the commanded forces against the loop's record, found
    # by the firmware's own step counter (the MF4's time base starts at the first DAQ sample).
    from asammdf import MDF

    loop = served.out["loop"]
    with MDF(mf4) as measured:
        assert measured.get("command.A1").unit == "N" and measured.get("sliding_velocity.A1").unit == "m/s"
        raw, physical = measured.get("sliding_velocity.A1", raw=True), measured.get("sliding_velocity.A1")
        assert raw.samples.dtype.kind == "i" and np.array_equal(
            physical.samples, raw.samples * 1e-9
        )  # the A2L's LINEAR
        stamps = measured.get("command.A1").timestamps
        steps = measured.get("steps").samples.astype(np.int64)
        daq_commands = np.stack([measured.get(f"command.{j}").samples for j in fw.artifact.joint_names], axis=1)
    assert len(stamps) == daq["samples"] and stamps[0] == 0.0
    assert np.array_equal(np.diff(steps), np.ones(len(steps) - 1, dtype=np.int64))  # every sample, in order
    assert np.allclose(np.diff(stamps), fw.artifact.sample_time, rtol=0, atol=1e-9)
    recorded = np.array(loop.record.command, dtype=np.float32)[steps - 1]
    assert np.array_equal(daq_commands.astype(np.float32), recorded)
    assert daq_commands.std(axis=0).min() > 0.0  # the law was acting, not holding a constant
    assert (plots / "xcp_daq.png").stat().st_size > 10_000


def test_a_wrong_a2l_or_key_writes_nothing(served_image, three_type_a, tmp_path):
    fw, path = served_image
    fw.reset()
    setup = closed_loop.setup(*three_type_a)
    other = tmp_path / "other.a2l"
    text = Path(path).read_text()
    epk = a2l_file.read(path).epk
    other.write_text(text.replace(epk, epk.replace("float", "double")))
    with _Served(fw, setup, "bench-xcp-wrong", 4.0):
        setting = f"siso.boundary_layer.A2={FACTOR * _designed(fw, 1)!r}"
        code, _, err = _bench(other, "--channel", "bench-xcp-wrong", "--artifact", REFERENCE, "--set", setting)
        assert code == 2 and "is not the A2L's" in err and "nothing written" in err
        code, _, err = _bench(path, "--channel", "bench-xcp-wrong", "--key", "00" * 16, "--set", setting)
        assert code == 2 and "the slave refused UNLOCK" in err, err
        code, _, err = _bench(path, "--channel", "bench-xcp-wrong", "--set", setting)
        assert code == 2 and "needs UNLOCK" in err
        code, out, err = _bench(path, "--channel", "bench-xcp-wrong", "--json")
        assert code == 0, err
    assert json.loads(out)["calibration"]["siso.boundary_layer.A2"] == _designed(fw, 1)


def _multicast_reaches_this_host(group: str) -> bool:
    import can

    try:
        a = can.Bus(interface="udp_multicast", channel=group, fd=True)
        b = can.Bus(interface="udp_multicast", channel=group, fd=True)
    except (OSError, can.CanError):
        return False
    try:
        a.send(can.Message(arbitration_id=0x7F0, data=bytes(12), is_fd=True, is_extended_id=False))
        return b.recv(2.0) is not None
    finally:
        a.shutdown()
        b.shutdown()


def test_sil_serves_a_master_in_another_process(tmp_path):
    """The user's path: ``sil --xcp-serve`` in one process, ``bench xcp`` in another, over
    python-can's udp_multicast (the host's loopback)."""
    group = f"239.74.{np.random.default_rng().integers(1, 250)}.{np.random.default_rng().integers(1, 250)}"
    if not _multicast_reaches_this_host(group):
        pytest.skip(f"UDP multicast {group} does not loop back on this host")
    a2l = tmp_path / "served.a2l"
    serve = subprocess.Popen(
        [sys.executable, "-m", "smartjoint.cli", "sil", "--law", "siso", "--artifact", str(REFERENCE), "--duration",
         "60", "--xcp-serve", f"udp_multicast:{group}", "--xcp-a2l", str(a2l), "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 240
        while not a2l.exists() and serve.poll() is None and time.monotonic() < deadline:
            time.sleep(0.5)
        assert a2l.exists(), serve.stderr.read() if serve.poll() is not None else "no A2L within 240 s"
        master = subprocess.run(
            [sys.executable, "-m", "smartjoint.cli", "bench", "xcp", str(a2l), "--interface", "udp_multicast",
             "--channel", group, "--artifact", str(REFERENCE), "--measure", "all", "--duration", "0.5", "--json"],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert master.returncode == 0, master.stderr
        daq = json.loads(master.stdout)["daq"]
        assert daq["lost_samples"] == 0 and daq["samples"] >= 500 and len(daq["signals"]) >= 20
        assert "Traceback" not in master.stderr and "Error" not in master.stderr
    finally:
        serve.terminate()
        serve.wait(timeout=60)


def test_the_post_link_a2l_of_an_image_is_codegens_and_refuses_another_image(tmp_path):
    """``bench a2l`` on the PIL image linked here gives codegen's committed A2L (but for the header's
    words on where the addresses come from); an image of another build or prefix is refused."""
    from smartjoint.bench import pil, target

    if target.missing_tools():
        pytest.skip(target.missing_tools())
    elf = pil.build_image(artifact.load(REFERENCE), tmp_path / "image", xcp=Xcp())
    out = tmp_path / "post.a2l"
    assert cli.main(["bench", "a2l", str(elf), "--artifact", str(REFERENCE), "-o", str(out)]) == 0
    committed = (REFERENCE.parent / "smartjoint.a2l").read_text().splitlines()
    written = out.read_text().splitlines()
    differing = [k for k, (a, b) in enumerate(zip(written, committed, strict=True)) if a != b]
    assert [written[k].split()[1] for k in differing] == ["HEADER", "MOD_PAR"]
    for options, words in [
        (["--real", "double"], "is not 'smartjoint double"),
        (["--prefix", "other"], "no symbol other_xcp_epk"),
    ]:
        code, _, err = _run_cli(["bench", "a2l", str(elf), "--artifact", str(REFERENCE), "-o", str(tmp_path / "x.a2l"),
                                 *options])  # fmt: skip
        assert code == 2 and words in err and err.count("\n") == 1, err
        assert not (tmp_path / "x.a2l").exists()


def _run_cli(argv) -> tuple[int, str, str]:
    import contextlib
    import io

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(list(map(str, argv)))
    return code, out.getvalue(), err.getvalue()


def test_codegen_takes_the_designs_xcp_identifiers_and_key(tmp_path):
    """codegen --network DESIGN gives the firmware and its A2L the design's [xcp], not the defaults."""
    from smartjoint.bench import target
    from smartjoint.codegen import xcp_slave
    from smartjoint.design.structure import spec

    base = (spec.REFERENCE_DESIGN.parent / "three_type_a.toml").as_posix()
    key = "00112233445566778899aabbccddeeff"
    design = tmp_path / "d.toml"
    design.write_text(f'base = "{base}"\n[xcp]\nmaster_id = 0x700\nslave_id = 0x701\nkey = "{key}"\n')
    code, _, err = _run_cli(["codegen", REFERENCE, "-o", tmp_path / "out", "--network", design])
    assert code == 0, err
    header = (tmp_path / "out" / "smartjoint_xcp.h").read_text()
    assert "_ID_MASTER 0x700u" in header and "_ID_SLAVE 0x701u" in header
    words = xcp_slave.secret(artifact.load(REFERENCE), Xcp(key=key))
    assert ", ".join(f"0x{w:08X}u" for w in words) in (tmp_path / "out" / "smartjoint_xcp_key.c").read_text()
    if not target.missing_tools():
        described = a2l_file.read(tmp_path / "out" / "smartjoint.a2l")
        assert (described.master_id, described.slave_id) == (0x700, 0x701)
