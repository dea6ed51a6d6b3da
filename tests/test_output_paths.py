"""The output rule (common.output_path, issue 37): every command that writes refuses, in one line
and before any work, a path it must not write — a folder where a file is meant or a file where a
folder is, a path below a file, a FIFO, a symbolic link, a device, a folder holding a user's
files — and leaves the target as it was; what it writes is whole and readable by others."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from smartjoint.cli import main
from smartjoint.common import output_path
from smartjoint.common.errors import OutputError

ROOT = Path(__file__).resolve().parents[1]
ARTIFACT = str(ROOT / "firmware" / "generated" / "controller.json")
SWEEP = "[sweep]\nsamples = 2\n"  # never read: the output is refused first


def _snapshot(folder: Path) -> dict:
    """Every entry below ``folder`` by relative path: its kind, link target or bytes."""
    found = {}
    for path in sorted(folder.rglob("*")):
        kind = output_path.kind(path)
        if kind == "symbolic link":
            found[str(path.relative_to(folder))] = (kind, os.readlink(path))
        elif kind == "file":
            found[str(path.relative_to(folder))] = (kind, path.read_bytes())
        else:
            found[str(path.relative_to(folder))] = (kind, stat.S_IFMT(os.lstat(path).st_mode))
    return found


def _cases(tmp_path: Path) -> dict[str, Path]:
    """One target per kind of path the rule refuses (a device only where the process may make one)."""
    (tmp_path / "a-file").write_text("the user's file\n")
    (tmp_path / "a-folder").mkdir()
    (tmp_path / "a-folder" / "notes.txt").write_text("the user's notes\n")
    os.mkfifo(tmp_path / "a-fifo")
    (tmp_path / "a-link").symlink_to("a-file")
    (tmp_path / "a-folder-link").symlink_to("a-folder")
    cases = {
        "below a file": tmp_path / "a-file" / "x.out",
        "fifo": tmp_path / "a-fifo",
        "link to a file": tmp_path / "a-link",
        "link to a folder": tmp_path / "a-folder-link",
    }
    try:
        os.mknod(tmp_path / "a-device", stat.S_IFCHR | 0o666, os.makedev(1, 3))  # like /dev/null
        cases["device"] = tmp_path / "a-device"
    except (PermissionError, OSError):
        pass  # not root: no device can be made here, and none is needed to show the others
    return cases


# Each command with its output options: (argv before the option, option, "file" or "folder").
COMMANDS = {
    "run": (["run"], "-o", "folder"),
    "sweep": (["sweep", "s.toml"], "-o", "folder"),
    "codegen": (["codegen", ARTIFACT], "-o", "folder"),
    "rig --campaign": (["rig", "--campaign"], "-o", "folder"),
    "rig": (["rig", "--normal-force", "300", "--amplitude", "1e-4", "--frequency", "5"], "-o", "file"),
    "identify": (["identify", "missing.csv"], "-o", "file"),
    "identify --plots": (["identify", "missing.csv"], "--plots", "plots"),
    "fmu": (["fmu", ARTIFACT, "--law", "siso"], "-o", "file"),
    "design": (["design"], "-o", "file"),
    "place": (["place"], "-o", "file"),
    "export-model": (["export-model"], "-o", "file"),
    "reduce --plots": (["reduce"], "--plots", "plots"),
    "study --plots": (["study"], "--plots", "plots"),
    "bench dbc": (["bench", "dbc", ARTIFACT], "-o", "file"),
    "bench log": (["bench", "log", "--interface", "virtual", "--duration", "0.1"], "-o", "file"),
    "bench decode": (["bench", "decode", "missing.blf", "--artifact", ARTIFACT], "-o", "file"),
    "bench decode --plots": (["bench", "decode", "missing.blf", "--artifact", ARTIFACT], "--plots", "plots"),
    "sil --log-folder": (["sil", "--artifact", ARTIFACT], "--log-folder", "folder"),
    "sil --xcp-a2l": (["sil", "--artifact", ARTIFACT], "--xcp-a2l", "file"),
    # the experimenter's records folder (positional): its own files are kept, never replaced
    "campaign": (["campaign", "--prior", str(ROOT / "design" / "data" / "paper_table1_type_a.toml")], "", "shared"),
}
SHARED = ("codegen", "campaign")  # folders shared by design: other files are left as they are


def _refused(argv: list[str], capsys) -> str:
    assert main(argv) == 2, argv
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_command_refuses_a_path_it_must_not_write_and_leaves_it_as_it_was(command, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(SWEEP)
    argv, option, meant = COMMANDS[command]
    cases = _cases(tmp_path)
    wrong = tmp_path / ("a-folder" if meant == "file" else "a-file")
    cases["a file where a folder is meant" if meant != "file" else "a folder where a file is meant"] = wrong
    if meant != "file" and command not in SHARED:  # codegen shares its folder (below)
        cases["a folder with a user's file"] = tmp_path / "a-folder"
    before = _snapshot(tmp_path)
    for case, target in cases.items():
        err = _refused([*argv, *([option] if option else []), str(target)], capsys)
        assert str(target) in err and option in err, (case, err)
        assert _snapshot(tmp_path) == before, case  # nothing replaced, made or left behind


def test_codegen_writes_beside_a_users_files_and_leaves_them_as_they_were(tmp_path, capsys):
    """The one command whose folder is shared by design (the artefact lives beside its firmware):
    it replaces only files it generated (docs/codegen.md) and names the others untouched."""
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "notes.txt").write_text("the user's notes\n")
    (tmp_path / "out" / "smartjoint_siso.c").write_text("/* the user's own law */\n")
    before = _snapshot(tmp_path)
    err = _refused(["codegen", ARTIFACT, "-o", str(tmp_path / "out")], capsys)
    assert "smartjoint_siso.c: not written by smartjoint codegen" in err and _snapshot(tmp_path) == before
    (tmp_path / "out" / "smartjoint_siso.c").unlink()
    assert main(["codegen", ARTIFACT, "-o", str(tmp_path / "out"), "--json"]) == 0
    assert (tmp_path / "out" / "notes.txt").read_text() == "the user's notes\n"
    assert str(tmp_path / "out" / "notes.txt") in capsys.readouterr().out


def test_a_written_file_is_whole_readable_by_others_and_leaves_nothing_beside_it(tmp_path):
    previous = os.umask(0o022)
    try:
        path = output_path.write_file(tmp_path / "sub" / "a.txt", "text\n")
        assert path.read_text() == "text\n" and stat.S_IMODE(path.stat().st_mode) == 0o644
        output_path.write_file(path, b"\x00bytes")  # replaced whole
        assert path.read_bytes() == b"\x00bytes" and stat.S_IMODE(path.stat().st_mode) == 0o644
    finally:
        os.umask(previous)
    with pytest.raises(KeyboardInterrupt), output_path.writing(tmp_path / "sub" / "a.txt") as stream:
        stream.write("half")
        raise KeyboardInterrupt  # Ctrl-C while writing: the old file stays, no temporary is left
    assert sorted(p.name for p in (tmp_path / "sub").iterdir()) == ["a.txt"] and path.read_bytes() == b"\x00bytes"


def test_the_rule_names_what_it_found(tmp_path):
    cases = _cases(tmp_path)
    messages = {case: "" for case in cases}
    for case, target in cases.items():
        with pytest.raises(OutputError) as refused:
            output_path.check_file(target, "-o")
        messages[case] = str(refused.value)
    assert "a-file is a file, not a folder" in messages["below a file"]
    assert "is a FIFO" in messages["fifo"] and "is a symbolic link" in messages["link to a file"]
    assert "device" not in cases or "is a device" in messages["device"]
    with pytest.raises(OutputError, match="holds 'notes.txt', which this command did not write"):
        output_path.check_folder(tmp_path / "a-folder", "-o")
    assert output_path.check_folder(tmp_path / "a-folder", "-o", ours=lambda entry: entry.suffix == ".txt")
    assert output_path.check_folder(tmp_path / "new" / "deeper", "-o") == tmp_path / "new" / "deeper"
