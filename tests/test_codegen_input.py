"""`smartjoint codegen` refuses what the C cannot hold and checks everything it writes: names
that would become keywords, reserved or clashing identifiers, limits of the C types and CAN
frames, each a one-line error with nothing written; `--check` compiles the whole set (a planted
error in the CAN layer stops the move); an existing folder keeps every file codegen did not write."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import artifact_fields, artifact_text

from smartjoint import cli
from smartjoint.codegen import can_layer, generate, identifiers, output
from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control import artifact
from smartjoint.design.network import protocol

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "firmware" / "generated"
needs_cc = pytest.mark.skipif(shutil.which("cc") is None, reason="needs a C compiler")


@pytest.fixture(scope="module")
def reference():
    return artifact.load(REFERENCE / "controller.json")


def _codegen(capsys, *arguments) -> tuple[int, str]:
    code = cli.main(["codegen", *arguments])
    captured = capsys.readouterr()
    _codegen.out = captured.out
    return code, captured.err


def _artefact(tmp_path, reference, name, **changes) -> Path:
    data = artifact_fields(reference)
    data.update(changes)
    path = tmp_path / f"{name}.json"
    path.write_text(artifact_text(data))
    return path


def _leftovers(folder: Path) -> list[str]:
    """Temporary siblings codegen may have left next to ``folder``."""
    if not folder.parent.exists():
        return []
    return [p.name for p in folder.parent.iterdir() if p.name.startswith(f".{folder.name}.codegen-")]


# Each case: artefact changes, extra options, (field named in the message, value shown in it).
REFUSED = {
    "sensor counter (E2E signal)": ({"sensor_names": ["counter", "tip_z"]}, [], ("sensor_names[0]", "'counter'")),
    "sensor crc (E2E signal)": ({"sensor_names": ["tip_y", "crc"]}, [], ("sensor_names[1]", "'crc'")),
    "sensor double (C keyword)": ({"sensor_names": ["tip_y", "double"]}, [], ("sensor_names[1]", "'double'")),
    "sensor INT (keyword once lower-cased)": ({"sensor_names": ["INT", "tip_z"]}, [], ("sensor_names[0]", "'int'")),
    "sensor errno (library macro)": ({"sensor_names": ["errno", "tip_z"]}, [], ("sensor_names[0]", "'errno'")),
    "sensor class (C++ keyword)": ({"sensor_names": ["class", "tip_z"]}, [], ("sensor_names[0]", "'class'")),
    "sensors equal but for case": ({"sensor_names": ["tip_y", "TIP_Y"]}, [], ("sensor_names[1]", "'TIP_Y'")),
    "joint _A1 (reserved: leading underscore)": ({"joint_names": ["_A1", "A2", "A3"]}, [], ("joint_names[0]", "'_A1'")),
    "joint A1_ (gives __ in A1__ID)": ({"joint_names": ["A1_", "A2", "A3"]}, [], ("joint_names[0]", "'A1_'")),
    "joint A__2 (double underscore)": ({"joint_names": ["A1", "A__2", "A3"]}, [], ("joint_names[1]", "'A__2'")),
    "joints equal but for case": ({"joint_names": ["A1", "a1", "A3"]}, [], ("joint_names[1]", "'a1'")),
    "joint name too long": ({"joint_names": ["A" * 33, "A2", "A3"]}, [], ("joint_names[0]", "at most 32")),
    "prefix with double underscore": ({}, ["--prefix", "fw__x"], ("--prefix", "'fw__x'")),
    "prefix with leading underscore": ({}, ["--prefix", "_fw"], ("--prefix", "'_fw'")),
    "prefix of the E2E runtime": ({}, ["--prefix", "sj_e2e"], ("--prefix", "'sj_e2e'")),
    "prefix a C keyword": ({}, ["--prefix", "double"], ("--prefix", "'double'")),
    "sample time 5000 s": ({"sample_time": 5000.0}, [], ("sample_time", "5000.0")),
    "safe force above F^max": ({"safe_normal_force": [500.0, 400.0, 400.0]}, [], ("safe_normal_force[0]", "500.0")),
    "safe force below F^min": ({"safe_normal_force": [400.0, 5.0, 400.0]}, [], ("safe_normal_force[1]", "5.0")),
    "safe force count": ({"safe_normal_force": [100.0, 100.0]}, [], ("safe_normal_force", "expected (3,)")),
    "sensor limit beyond the frame": ({"sensor_limit": [25.0, 0.5]}, [], ("sensor_limit[0]", "25.0")),
    "velocity limit beyond the frame": (
        {"sliding_velocity_limit": [1.0, 3.0, 1.0]},
        [],
        ("sliding_velocity_limit[1]", "3.0"),
    ),
    "temperature limit at the frame's top": (
        {"amplifier_temperature_limit": 215.0},
        [],
        ("amplifier_temperature_limit", "215.0"),
    ),
    "F^max 1e12 N": ({"normal_force_max": [1e12, 400.0, 400.0]}, [], ("normal_force_max[0]", "1000000000000.0")),
    "F^max beyond the setpoint frame": (
        {"normal_force_max": [400.0, 1250.0, 400.0], "measured_normal_force_max": [440.0, 1300.0, 440.0]},
        [],
        ("normal_force_max[1]", "1200 N"),
    ),
    "preload above F^min": ({"piezo_preload": 20.0}, [], ("piezo_preload", "20.0")),
    "timeout cycles": ({"timeout_cycles": 1}, [], ("timeout_cycles", "1")),
    "timeout cycles beyond the echo": ({"timeout_cycles": 8}, [], ("timeout_cycles", "8")),
    "recovery cycles as a float": ({"recovery_cycles": 3.0}, [], ("recovery_cycles", "3.0")),
}


@pytest.mark.parametrize("case", list(REFUSED))
def test_each_bad_input_is_one_line_naming_the_field_and_writes_nothing(case, reference, tmp_path, capsys):
    changes, options, (field, value) = REFUSED[case]
    source = _artefact(tmp_path, reference, "bad", **changes)
    target = tmp_path / "deep" / "out"
    code, err = _codegen(capsys, str(source), "-o", str(target), *options)
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("smartjoint codegen: error: "), err
    assert field in lines[0] and value in lines[0], lines[0]
    assert not (tmp_path / "deep").exists() and _leftovers(target) == []


def test_forces_and_voltages_the_frames_cannot_carry_are_refused(reference):
    with pytest.raises(ModelError, match=r"^SETPOINT_A1\.voltage: range \[0, 500\] V — its 32-bit field carries"):
        can_layer.render_can(reference, amplifier=protocol.Amplifier(voltage_max=500.0))
    # A stiffer stack reaches 15 kN, but the JOINT frame reports the applied F_N only up to 1310 N.
    strong = dataclasses.replace(
        reference,
        normal_force_max=np.array([400.0, 400.0, 2000.0]),
        measured_normal_force_max=np.array([440.0, 440.0, 2200.0]),
    )
    with pytest.raises(
        ModelError,
        match=r"^normal_force_max\[2\]: 2000.0 N for joint 'A3' — the JOINT_A3 frame "
        r"carries the applied F_N up to 1310 N",
    ):
        can_layer.render_can(strong, amplifier=protocol.Amplifier(force_per_volt=100.0))
    # The amplifier given to the layer is checked as the artefact's own preload is.
    with pytest.raises(ModelError, match=r"^piezo_preload: 20.0 N — above normal_force_min\[0\] = 10.0 N"):
        can_layer.render_can(reference, amplifier=protocol.Amplifier(preload=20.0))


def test_reserved_words_include_the_standards_spellings():
    for word in (
        "double",
        "_Bool",
        "restrict",
        "inline",
        "_Static_assert",
        "bool",
        "typeof",
        "class",
        "errno",
        "stdin",
        "size_t",
        "uint8_t",
        "isnan",
    ):
        assert word in identifiers.RESERVED, word
    for good in ("A1", "tip_y", "Joint_2b", "x"):
        identifiers.check_names([good], ["tip_y"], members=protocol.E2E_SIGNALS)
    assert set(protocol.E2E_SIGNALS) == {"crc", "counter", "sync"}


def test_the_dbc_written_reads_back_as_the_protocol(reference, monkeypatch):
    longest = dataclasses.replace(reference, joint_names=("J" * 32, "K" * 32, "L" * 32), sensor_names=("s" * 32, "t"))
    frames = protocol.load_dbc(can_layer.render_can(longest)["bus.dbc"]).messages
    assert f"AMP_STATUS_{'J' * 32}" in {m.name for m in frames}  # beyond DBC's 32 characters, still read back
    dropped = protocol.dbc_text
    monkeypatch.setattr(protocol, "dbc_text", lambda db: dropped(db).replace(" SG_ tip_z ", " SG_ tip_w "))
    with pytest.raises(ModelError, match=r"^bus\.dbc: the DBC text does not read back as the protocol"):
        can_layer.render_can(reference)


@needs_cc
def test_unusual_but_legal_names_compile_clean(reference, tmp_path):
    # Names that look like the generated ones: the fixed infixes keep them apart.
    odd = dataclasses.replace(reference, joint_names=("S", "ID", "JOINT_A1"), sensor_names=("sensors", "state"))
    placed = generate.generate(odd, tmp_path / "odd", "double", "fw", check=True)
    laws = [f"{law.c_name('fw')}.c" for law in law_registry.LAWS.values()]
    nodes = ["fw_node.c", "fw_node_config.c", "fw_supervisor.c"]
    slave = ["fw_xcp.c", "fw_xcp_key.c"]
    assert placed.compiled["sources"] == sorted(["fw_can.c", *laws, *nodes, *slave, "main.c", "sj_e2e.c"])
    assert "#define FW_CAN_JOINT_JOINT_A1_ID 0x102u" in (tmp_path / "odd" / "fw_can.h").read_text()


def _planted(monkeypatch, name: str, text: str):
    original = can_layer.render_can

    def render_can(*args, **kwargs):
        files = original(*args, **kwargs)
        files[name] = files[name] + text
        return files

    monkeypatch.setattr(can_layer, "render_can", render_can)


@needs_cc
@pytest.mark.parametrize(
    "name, text, reported",
    [
        ("smartjoint_can.c", "\nint planted(void) { return undeclared_in_the_can_layer; }\n", "smartjoint_can.c"),
        ("smartjoint_can.c", "\nstatic int planted_but_unused;\n", "smartjoint_can.c"),  # a warning is an error
        ("sj_e2e.h", "\nvoid planted(int);\nvoid planted(double);\n", "sj_e2e.h"),
        ("main.c", "\nint main(void);\nint planted(void) { return 1; }\nint planted(void) { return 2; }\n", "main.c"),
    ],
)
def test_a_planted_error_anywhere_in_the_can_layer_stops_the_move(
    name, text, reported, reference, tmp_path, monkeypatch
):
    _planted(monkeypatch, name, text)
    target = tmp_path / "new"
    with pytest.raises(ModelError) as error:
        generate.generate(reference, target, check=True)
    message = str(error.value)
    assert "\n" not in message and message.startswith("--check: ") and reported in message, message
    assert str(tmp_path) not in message  # the temporary folder is not shown
    assert not target.exists() and _leftovers(target) == []

    # Into an existing generated folder: the previous files stay exactly as they were.
    monkeypatch.undo()
    old = tmp_path / "old"
    generate.generate(reference, old, "double")
    before = {p.name: p.read_bytes() for p in old.iterdir()}
    _planted(monkeypatch, name, text)
    with pytest.raises(ModelError):
        generate.generate(reference, old, check=True)
    assert {p.name: p.read_bytes() for p in old.iterdir()} == before and _leftovers(old) == []


@needs_cc
def test_check_catches_what_the_name_rules_would_miss(reference, tmp_path, monkeypatch):
    """Before, a sensor named `double` passed `--check` (only the controllers were compiled):
    with the name rules switched off the compile of the CAN layer itself refuses it."""
    monkeypatch.setattr(identifiers, "check_names", lambda *args, **kwargs: None)
    bad = dataclasses.replace(reference, sensor_names=("tip_y", "double"))
    target = tmp_path / "out"
    with pytest.raises(ModelError, match=r"^--check: .*smartjoint_can\.h"):
        generate.generate(bad, target, check=True)
    assert not target.exists()


@needs_cc
def test_the_reference_regenerates_byte_identical_and_compiles(reference, tmp_path, capsys):
    # Into a copy of firmware/generated (the artefact lies beside the generated files).
    copy = tmp_path / "generated"
    shutil.copytree(REFERENCE, copy)
    (copy / "notes.txt").write_text("mine\n")
    code, err = _codegen(capsys, str(copy / "controller.json"), "-o", str(copy), "--check")
    assert code == 0, err
    for path in REFERENCE.iterdir():
        assert (copy / path.name).read_bytes() == path.read_bytes(), path.name
    assert (copy / "notes.txt").read_text() == "mine\n"
    assert sorted(p.name for p in copy.iterdir()) == sorted([*(p.name for p in REFERENCE.iterdir()), "notes.txt"])
    # And into a new folder: the same bytes, the usual permissions.
    placed = generate.generate(reference, tmp_path / "fresh")
    assert [p.name for p in placed.untouched] == []
    for path in placed.written:
        assert path.read_bytes() == (REFERENCE / path.name).read_bytes(), path.name
        assert path.stat().st_mode & 0o777 == 0o666 & ~output.umask()


def test_an_existing_folder_keeps_every_file_codegen_did_not_write(reference, tmp_path, capsys):
    target = tmp_path / "firmware"
    target.mkdir()
    (target / "main.c").write_text("/* my own main */\nint main(void) { return 0; }\n")
    (target / "my_board.c").write_text("/* my board support */\n")
    code, err = _codegen(capsys, str(REFERENCE / "controller.json"), "-o", str(target))
    assert code == 2 and "main.c: not written by smartjoint codegen" in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in target.iterdir()) == ["main.c", "my_board.c"]  # nothing added, nothing changed
    assert (target / "main.c").read_text().startswith("/* my own main */")

    (target / "main.c").unlink()
    code, err = _codegen(capsys, str(REFERENCE / "controller.json"), "-o", str(target), "--json")
    assert code == 0, err
    assert json.loads(_codegen.out)["untouched"] == [str(target / "my_board.c")]
    assert (target / "my_board.c").read_text() == "/* my board support */\n"
    # A second run with another prefix replaces nothing of the first and leaves it untouched.
    placed = generate.generate(reference, target, prefix="other", can=False)
    assert {p.name for p in placed.untouched} >= {"my_board.c", "smartjoint_can.c", "smartjoint_siso.c"}
    assert (target / "main.c").read_text() != (REFERENCE / "main.c").read_text()  # the controllers-only example

    a_file = tmp_path / "file"
    a_file.write_text("x")
    code, err = _codegen(capsys, str(REFERENCE / "controller.json"), "-o", str(a_file))
    assert code == 2 and "is a file — name a folder" in err and a_file.read_text() == "x"


def test_a_symlink_in_place_of_a_generated_file_is_not_followed(reference, tmp_path):
    target = tmp_path / "out"
    target.mkdir()
    elsewhere = tmp_path / "precious.c"
    elsewhere.write_text("/* Generated by smartjoint, but the link is the user's */\n")
    (target / "smartjoint_siso.c").symlink_to(elsewhere)
    with pytest.raises(ModelError, match="smartjoint_siso.c: not written by smartjoint codegen"):
        generate.generate(reference, target)
    assert (target / "smartjoint_siso.c").is_symlink() and elsewhere.read_text().startswith("/* Generated")


def test_written_by_codegen_recognises_each_kind_of_generated_file(reference, tmp_path):
    files = {**generate.render(reference), **can_layer.render_can(reference)}
    other = {
        **generate.render(dataclasses.replace(reference, clqg_boundary_layer=5.0), "double"),
        **can_layer.render_can(dataclasses.replace(reference, clqg_boundary_layer=5.0)),
    }
    for name, text in files.items():
        path = tmp_path / name
        path.write_text(other[name])  # an earlier generation: another artefact
        assert output.written_by_codegen(path, text), name
        path.write_text("hand-written\n")
        assert not output.written_by_codegen(path, text), name
    # The runtime copies of an earlier release (before the freshness byte) are recognised too: a
    # user who upgrades regenerates into the same folder.
    for name, first in (
        ("sj_e2e.c", "/* CRC-8 SAE J1850 and alive counter, see sj_e2e.h. */\n"),
        ("sj_e2e.h", "/* End-to-end protection of CAN frames: CRC-8 SAE J1850 and a 4-bit alive counter.\n"),
    ):
        (tmp_path / name).write_text(first + "int older;\n")
        assert output.written_by_codegen(tmp_path / name, files[name]), name
        (tmp_path / name).write_text("/* CRC-16 of my own */\n")
        assert not output.written_by_codegen(tmp_path / name, files[name]), name


def test_the_current_folder_as_target(reference, tmp_path, monkeypatch):
    (tmp_path / "fw").mkdir()
    monkeypatch.chdir(tmp_path / "fw")
    placed = generate.generate(reference, ".", can=False)
    assert sorted(p.name for p in (tmp_path / "fw").iterdir()) == sorted(p.name for p in placed.written)
    assert [p.name for p in tmp_path.iterdir()] == ["fw"] and placed.written[0] == Path(".") / "smartjoint_types.h"
