"""The report folder of ``smartjoint run``: written whole or not at all, and never over a user's files.

Before any work the output path is checked: a path that does not exist yet or an empty folder
is taken; a folder that an earlier run wrote — its manifest ``smartjoint-manifest.json`` names
every file in it with its SHA-256, and nothing else is there — is replaced; anything else (a
file, a link, a folder with files no run wrote or changed since) is refused with one line.

A run works beside the output, in a staging folder ``.<name>.smartjoint-<run id>.staging``,
next to a claim file ``.<name>.smartjoint-<run id>.run`` that names the process writing it. At
the end the earlier report is moved aside (``….previous``), the staging folder renamed into
place and the earlier one deleted, with SIGINT and SIGTERM held back for those few renames;
every other exit deletes what the run staged. A run that was killed outright (SIGKILL, power
loss) leaves its claim behind; the next run to the same output removes that run's folders —
only when the claim proves its process gone, and never anything the claim does not name — and
puts an earlier report that had been moved aside back if the new one never arrived.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import secrets
import shutil
import signal
import socket
from datetime import UTC, datetime
from pathlib import Path

from smartjoint.common.errors import SmartjointError

MANIFEST = "smartjoint-manifest.json"
MANIFEST_KIND = "smartjoint run report"
_RUN_ID = r"\d{8}T\d{6}Z-[0-9a-f]{8}"


class ReportFolderError(SmartjointError):
    """The output path cannot take a report: it names the path, what is there and what is allowed."""


def new_run_id(now: datetime) -> str:
    """``YYYYMMDDTHHMMSSZ-xxxxxxxx``: sortable by start time (UTC), unique by its random tail."""
    return f"{now:%Y%m%dT%H%M%SZ}-{secrets.token_hex(4)}"


def utc_now() -> datetime:
    return datetime.now(UTC)


def iso(moment: datetime) -> str:
    return moment.isoformat(timespec="milliseconds").replace("+00:00", "Z")


# --------------------------------------------------------------------------- what is at the output


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _entries(folder: Path) -> tuple[dict[str, Path], list[str]]:
    """Files (relative name → path) and other entries (links, devices, …) below ``folder``, no link followed."""
    files, others = {}, []
    for directory, subfolders, names in os.walk(folder, followlinks=False):
        base = Path(directory)
        for name in subfolders:
            if (base / name).is_symlink():
                others.append((base / name).relative_to(folder).as_posix())
        for name in names:
            path = base / name
            relative = path.relative_to(folder).as_posix()
            if path.is_symlink() or not path.is_file():
                others.append(relative)
            else:
                files[relative] = path
    return files, others


def _foreign(folder: Path) -> str | None:
    """``None`` when ``folder`` is a report that a run wrote and nobody changed since, else why not."""
    try:
        manifest = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
        listed = manifest["files"] if manifest.get("kind") == MANIFEST_KIND else None
        if not isinstance(listed, dict):
            raise ValueError
    except FileNotFoundError:
        first = min(entry.name for entry in folder.iterdir())
        return f"holds {first!r} and has no {MANIFEST}: not a report of a smartjoint run"
    except (OSError, ValueError, TypeError, KeyError):
        return f"has a {MANIFEST} that is not a smartjoint run manifest"
    files, others = _entries(folder)
    if others:
        return f"holds {others[0]!r}, which no smartjoint run wrote"
    for name, path in sorted(files.items()):
        if name == MANIFEST:
            continue
        if name not in listed:
            return f"holds {name!r}, which no smartjoint run wrote"
        if _sha256(path) != listed[name]:
            return f"holds {name!r}, changed since run {manifest.get('run_id')} wrote it"
    return None


def inspect(output: Path) -> str:
    """What is at ``output``: ``"missing"``, ``"empty"`` (an empty folder) or ``"report"`` (one
    a run wrote); anything else raises :class:`ReportFolderError`."""
    where = f"-o {output}"
    allowed = "give a new or empty folder, or the report folder of an earlier run"
    if output.is_symlink():
        raise ReportFolderError(f"{where}: is a symbolic link — {allowed}, not a link to one")
    if not output.name or output.name in (".", ".."):
        raise ReportFolderError(f"{where}: names no folder of its own — {allowed}")
    if not output.exists():
        if output.parent.exists() and not output.parent.is_dir():
            raise ReportFolderError(f"{where}: {output.parent} is a file — {allowed}")
        return "missing"
    if not output.is_dir():
        raise ReportFolderError(f"{where}: is a file, not a folder — {allowed}; the file is left as it is")
    try:
        if not any(output.iterdir()):
            return "empty"
        reason = _foreign(output)
    except PermissionError as error:
        raise ReportFolderError(f"{where}: cannot be read ({error.strerror}) — {allowed}") from None
    if reason is not None:
        raise ReportFolderError(f"{where}: {reason} — {allowed}; nothing was changed")
    return "report"


def write_manifest(folder: Path, run_id: str) -> None:
    """Name every file of the finished ``folder`` with its SHA-256 (the mark :func:`inspect` trusts)."""
    files, others = _entries(folder)
    if others:
        raise ReportFolderError(f"{folder}: the report holds {others[0]!r}, which is not a regular file")
    listed = {name: _sha256(path) for name, path in sorted(files.items()) if name != MANIFEST}
    document = {"kind": MANIFEST_KIND, "run_id": run_id, "files": listed}
    (folder / MANIFEST).write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")


# --------------------------------------------------------------------------- signals held back


@contextlib.contextmanager
def signals_held():
    """Defer SIGINT and SIGTERM for a few renames that must not be cut in half; a signal that
    arrived meanwhile is delivered again at the end (its usual handler then runs)."""
    caught: list[int] = []
    try:
        previous = {
            number: signal.signal(number, lambda n, _frame: caught.append(n))
            for number in (signal.SIGINT, signal.SIGTERM)
        }
    except ValueError:  # not the main thread: no handlers to swap, and nothing can interrupt us here
        yield
        return
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        for number in dict.fromkeys(caught):
            signal.raise_signal(number)


# --------------------------------------------------------------------------- the claim of a run


def _boot_id() -> str | None:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return None


def _process_start(pid: int) -> str | None:
    """The start time of ``pid`` in clock ticks since boot (Linux), so a reused pid is told apart."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat[stat.rindex(")") + 2 :].split()[19]  # field 22 of proc(5), counted after "pid (comm)"


def _claim() -> dict:
    return {
        "kind": "smartjoint run claim",
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "boot_id": _boot_id(),
        "process_start": _process_start(os.getpid()),
    }


def _gone(claim: dict) -> bool:
    """True only when the process named by ``claim`` has certainly ended."""
    if claim.get("kind") != "smartjoint run claim" or claim.get("host") != socket.gethostname():
        return False  # another machine's run (a shared file system): nothing to prove it by
    pid = claim.get("pid")
    if not isinstance(pid, int) or pid <= 0:
        return False
    boot = _boot_id()
    if boot is not None and claim.get("boot_id") is not None and boot != claim["boot_id"]:
        return True  # the machine restarted since
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False  # alive, another user's
    start = _process_start(pid)
    return start is not None and claim.get("process_start") is not None and start != claim["process_start"]


def _remove_folder(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)


def clean_stale(output: Path) -> list[str]:
    """Remove what killed runs to ``output`` left beside it (see the module docstring); the names removed."""
    parent = output.parent
    pattern = re.compile(rf"\.{re.escape(output.name)}\.smartjoint-({_RUN_ID})\.run")
    removed: list[str] = []
    try:
        candidates = sorted(parent.iterdir()) if parent.is_dir() else []
    except OSError:
        return removed
    for claim_path in candidates:
        match = pattern.fullmatch(claim_path.name)
        if match is None or claim_path.is_symlink() or not claim_path.is_file():
            continue
        try:
            claim = json.loads(claim_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if not isinstance(claim, dict) or claim.get("run_id") != match.group(1) or not _gone(claim):
            continue
        stem = claim_path.name.removesuffix(".run")
        try:
            with signals_held():
                _remove_folder(parent / f"{stem}.staging")
                previous = parent / f"{stem}.previous"
                if previous.is_dir() and not previous.is_symlink():
                    if not os.path.lexists(output):
                        os.rename(previous, output)  # killed between moving the old report aside and the new in
                    else:
                        shutil.rmtree(previous)
                claim_path.unlink()
        except OSError:
            continue  # not ours to remove after all (permissions): leave it, the run goes on
        removed.append(stem)
    return removed


# --------------------------------------------------------------------------- one run's folder


class ReportFolder:
    """Staging, commit and clean-up of one run's report folder (a context manager).

    The constructor checks ``output`` (:func:`inspect`), raising before anything is written,
    then clears what killed runs left. ``with`` creates the claim and the staging folder
    (``staging``); :meth:`commit` puts the finished report in place; leaving the block without a
    commit deletes the staging folder and the claim.
    """

    def __init__(self, output: Path, run_id: str):
        self.output = Path(output)
        self.run_id = run_id
        inspect(self.output)
        self.stale_removed = clean_stale(self.output)
        stem = f".{self.output.name}.smartjoint-{run_id}"
        self.claim = self.output.parent / f"{stem}.run"
        self.staging = self.output.parent / f"{stem}.staging"
        self.previous = self.output.parent / f"{stem}.previous"
        self.committed = False
        self.created: list[Path] = []  # parent folders this run made (removed again if it fails)

    def __enter__(self) -> ReportFolder:
        try:
            missing = self.output.parent
            while not missing.exists():
                self.created.append(missing)
                missing = missing.parent
            self.output.parent.mkdir(parents=True, exist_ok=True)
            with signals_held():
                with open(self.claim, "x", encoding="utf-8") as handle:
                    json.dump({**_claim(), "run_id": self.run_id, "output": self.output.name}, handle)
                self.staging.mkdir()
        except OSError as error:
            self._discard()
            raise ReportFolderError(
                f"-o {self.output}: cannot write beside it ({error.strerror}) — give a folder in a writable place"
            ) from None
        except BaseException:  # a signal held back above: __exit__ does not run when __enter__ raises
            self._discard()
            raise
        return self

    def commit(self) -> None:
        """Move the finished staging folder into place (after writing its manifest)."""
        write_manifest(self.staging, self.run_id)
        with signals_held():
            kind = inspect(self.output)  # again: the user may have put something there meanwhile
            if kind == "empty":
                try:
                    os.rmdir(self.output)
                except OSError as error:  # filled up in between
                    raise ReportFolderError(
                        f"-o {self.output}: is no longer empty ({error.strerror}) — nothing was changed"
                    ) from None
            elif kind == "report":
                os.rename(self.output, self.previous)
                reason = _foreign(self.previous)
                if reason is not None:  # changed between the check and the move: put it back untouched
                    os.rename(self.previous, self.output)
                    raise ReportFolderError(f"-o {self.output}: {reason} — nothing was changed")
            try:
                os.rename(self.staging, self.output)
            except OSError as error:
                if os.path.isdir(self.previous) and not os.path.lexists(self.output):
                    os.rename(self.previous, self.output)
                raise ReportFolderError(
                    f"-o {self.output}: cannot put the report in place ({error.strerror})"
                ) from None
            self.committed = True
            _remove_folder(self.previous)
            self.claim.unlink(missing_ok=True)

    def __exit__(self, *exc) -> None:
        if not self.committed:
            with signals_held():
                self._discard()

    def _discard(self) -> None:
        _remove_folder(self.staging)
        if os.path.isdir(self.previous) and not os.path.lexists(self.output):
            os.rename(self.previous, self.output)
        _remove_folder(self.previous)
        self.claim.unlink(missing_ok=True)
        for folder in self.created:  # deepest first; only while empty
            try:
                folder.rmdir()
            except OSError:
                break
