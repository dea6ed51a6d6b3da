"""Output paths: the one rule every command that writes follows.

A command names its output as a file (``identify -o joint.toml``) or as a folder (``run -o
report``). Before any work it checks the path (:func:`check_file`, :func:`check_folder`); then it
writes each file whole through a hidden temporary sibling and a rename (:func:`write_file`).

The rule:

- a file output is a regular file or a new name; a folder output is a folder or a new name;
- never a symbolic link, a FIFO, a device or a socket: a rename would replace it by a regular
  file (a device node by a file, a link by a copy), so it is refused, never written through;
- never below a file (``FILE/x.csv``): the first existing ancestor is a folder the process may
  write into;
- a folder the command fills holds only what that command wrote (its own test, ``ours``); any
  other entry is named and the folder left as it is — a command never replaces or deletes a
  user's file;
- nothing half-written: the temporary file is removed on any failure, Ctrl-C included; written
  files get the process's usual permissions (``0666 & ~umask``: 0644 under the common umask 022),
  not mkstemp's 0600.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO

from smartjoint.common.errors import OutputError

# What a rename would replace by a regular file: refused as a file and as a folder output.
_SPECIAL = (
    (stat.S_ISLNK, "symbolic link"),
    (stat.S_ISFIFO, "FIFO"),
    (stat.S_ISCHR, "device"),
    (stat.S_ISBLK, "device"),
    (stat.S_ISSOCK, "socket"),
)


def kind(path: Path) -> str | None:
    """What is at ``path`` without following a link.

    Parameters
    ----------
    path : Path

    Returns
    -------
    str or None
        ``"file"``, ``"folder"``, ``"symbolic link"``, ``"FIFO"``, ``"device"``, ``"socket"``,
        ``"below a file"`` (an ancestor is not a folder), or None when nothing is there.
    """
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return None
    except NotADirectoryError:
        return "below a file"
    for test, name in _SPECIAL:
        if test(mode):
            return name
    return "folder" if stat.S_ISDIR(mode) else "file"


def _check_ancestors(path: Path, option: str) -> None:
    """The nearest existing ancestor is a folder the process may write into."""
    for ancestor in Path(os.path.abspath(path)).parents:
        if not os.path.lexists(ancestor):
            continue
        if not ancestor.is_dir():  # a link to a folder is a folder here: the user's own layout
            raise OutputError(f"{option}: {path} — {ancestor} is a file, not a folder; name a path in a folder")
        if not os.access(ancestor, os.W_OK | os.X_OK):
            raise OutputError(f"{option}: {path} — the folder {ancestor} is not writable")
        return


def check_file(path: str | os.PathLike, option: str = "-o") -> Path:
    """Refuse a file output the command must not write, before any work.

    Parameters
    ----------
    path : str or PathLike
        The output file.
    option : str
        The option that named it, for the message (``"-o"``, ``"--output"``).

    Returns
    -------
    Path
        ``path``, a regular file (replaced whole) or a new name in a writable folder.

    Raises
    ------
    OutputError
        A folder, a link, a FIFO, a device or a socket there, or a path below a file.
    """
    path = Path(path)
    _check_kind(path, option, "file")
    return path


def check_folder(path: str | os.PathLike, option: str = "-o", ours: Callable[[Path], bool] | None = None) -> Path:
    """Refuse a folder output the command must not fill, before any work.

    Parameters
    ----------
    path : str or PathLike
        The output folder.
    option : str
        The option that named it, for the message.
    ours : callable, optional
        Whether an entry of an existing folder is one this command wrote (and may replace);
        None: the folder must be new or empty.

    Returns
    -------
    Path
        ``path``: a new name, an empty folder, or a folder of the command's own entries.

    Raises
    ------
    OutputError
        A file, a link, a FIFO, a device or a socket there, a path below a file, or a folder
        holding an entry the command did not write (the first one is named).
    """
    path = Path(path)
    if _check_kind(path, option, "folder") == "folder":
        foreign = sorted(entry.name for entry in path.iterdir() if ours is None or not ours(entry))
        if foreign:
            raise OutputError(
                f"{option}: {path} holds {foreign[0]!r}, which this command did not write — "
                "name a new or empty folder (nothing in it is replaced)"
            )
    return path


def _check_kind(path: Path, option: str, meant: str) -> str | None:
    """What is at ``path`` (:func:`kind`), refused unless nothing or a ``meant`` ("file" or
    "folder") in a writable folder."""
    found = kind(path)
    other = "folder" if meant == "file" else "file"
    if found == other:
        raise OutputError(f"{option}: {path} is a {other} — name a {meant}")
    if found not in (None, meant):
        _refuse_special(path, found, option)
    _check_ancestors(path, option)
    return found


def _refuse_special(path: Path, found: str, option: str) -> None:
    if found == "below a file":
        _check_ancestors(path, option)  # names the file
    raise OutputError(
        f"{option}: {path} is a {found} — smartjoint writes regular files and folders and never replaces a {found}"
    )


def file_mode() -> int:
    """The permissions of a new file under the process's umask (``0666 & ~umask``)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


@contextlib.contextmanager
def writing(path: str | os.PathLike, option: str = "-o", binary: bool = False) -> Iterator[IO]:
    """A stream onto a hidden temporary sibling of ``path``, renamed onto it when the block ends.

    The target holds its old or its new complete content, never a part; a failure (Ctrl-C
    included) removes the temporary file. The folder is created when missing.

    Parameters
    ----------
    path : str or PathLike
        The file (checked by :func:`check_file`, and again right before the rename).
    option : str
        The option that named the path, for a message.
    binary : bool
        A bytes stream instead of UTF-8 text (newlines as written).

    Yields
    ------
    file object
    """
    path = check_file(path, option)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
    try:
        opened = os.fdopen(handle, "wb") if binary else os.fdopen(handle, "w", encoding="utf-8", newline="")
        with opened as stream:
            yield stream
        os.chmod(temporary, file_mode())
        check_file(path, option)  # nothing became a link or a FIFO meanwhile
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def write_file(path: str | os.PathLike, data: str | bytes, option: str = "-o") -> Path:
    """Write ``data`` (UTF-8 text or bytes) to ``path`` whole (:func:`writing`).

    Parameters
    ----------
    path : str or PathLike
    data : str or bytes
    option : str
        The option that named the path, for a message.

    Returns
    -------
    Path
    """
    with writing(path, option, binary=isinstance(data, bytes)) as stream:
        stream.write(data)
    return Path(path)


__all__ = ["check_file", "check_folder", "file_mode", "kind", "write_file", "writing"]
