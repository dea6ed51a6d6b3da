"""Reading a design file safely: a regular file of bounded size, opened without blocking, and
the chain of ``base = …`` files it extends, without cycles and of bounded depth."""

from __future__ import annotations

import os
import stat
import tomllib
from pathlib import Path
from typing import Any

from smartjoint.common.errors import DesignError


def read_file(path: Path, key: str, shown: str, source: str | None, max_bytes: int) -> bytes:
    """The bytes of a regular file of at most ``max_bytes``.

    Opened without blocking and checked on the open descriptor: a FIFO would block the open
    and a device (``/dev/zero``) or a huge file would fill the memory before TOML sees it.

    Parameters
    ----------
    path : Path
        The file.
    key, shown : str
        The key (``"<file>"`` or ``"base"``) and the value shown in an error.
    source : str or None
        The file that named this one (a base), for the message.
    max_bytes : int
        The largest size read.

    Returns
    -------
    bytes
        The content.

    Raises
    ------
    DesignError
        For a file that cannot be read, is no regular file or is too large.
    """
    what = "base design file" if key == "base" else "design file"
    try:
        descriptor = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as error:
        raise DesignError(key, shown, f"cannot read {what} {path} ({error.strerror})", source) from None
    try:
        status = os.fstat(descriptor)
        if not stat.S_ISREG(status.st_mode):
            kind = (
                "a folder"
                if stat.S_ISDIR(status.st_mode)
                else "a FIFO"
                if stat.S_ISFIFO(status.st_mode)
                else "a device"
                if stat.S_ISCHR(status.st_mode) or stat.S_ISBLK(status.st_mode)
                else "a socket"
                if stat.S_ISSOCK(status.st_mode)
                else "not a regular file"
            )
            raise DesignError(key, shown, f"{path} is {kind}; a {what} must be a regular file", source)
        limit = f"a {what} must be a regular file of at most {max_bytes} bytes ({max_bytes / 1024**2:g} MiB)"
        if status.st_size > max_bytes:
            raise DesignError(key, shown, f"{path} has {status.st_size} bytes; {limit}", source)
        chunks, size = [], 0
        while size <= max_bytes:
            chunk = os.read(descriptor, max_bytes + 1 - size)
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        raw = b"".join(chunks)
    except OSError as error:
        raise DesignError(key, shown, f"cannot read {what} {path} ({error.strerror})", source) from None
    finally:
        os.close(descriptor)
    if len(raw) > max_bytes:  # it grew after the size check
        raise DesignError(key, shown, f"{path} has more than {max_bytes} bytes; {limit}", source)
    return raw


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _chain_names(chain: list[Path]) -> str:
    names = [p.name for p in chain]
    if len(set(names)) < len(set(map(str, chain))):  # file names alone are ambiguous
        names = [str(p) for p in chain]
    return " → ".join(names)


def read_toml(
    path: Path,
    source: str,
    raw: bytes,
    chain: list[Path],
    max_bytes: int,
    max_depth: int,
    origins: dict[str, str] | None = None,
) -> tuple[dict[str, Any], bytes]:
    """Parse a design file; ``base = "other.toml"`` (relative to the file) supplies every
    top-level key the file does not set itself. The hash covers the whole chain of bytes.

    Parameters
    ----------
    path : Path
        The file.
    source : str
        How it is shown in errors.
    raw : bytes
        Its content (`read_file`).
    chain : list of Path
        The files read so far, this one last (for cycles and the depth limit).
    max_bytes : int
        The largest base file read.
    max_depth : int
        The most base files behind the first.
    origins : dict, optional
        Filled with the file each top-level key of the merged data was written in.

    Returns
    -------
    tuple
        (the merged TOML data, the bytes of the whole chain joined by NUL).
    """
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise DesignError("<file>", source, f"not valid TOML: {error}") from None
    anchor_paths(data, path.parent)
    origins = {} if origins is None else origins
    if "base" not in data:
        origins.update(dict.fromkeys(data, str(path)))
        return data, raw
    base = data.pop("base")
    if not isinstance(base, str) or not base:
        raise DesignError("base", base, "expected a path (string) to the design file this one extends", source)
    base_path = (path.parent / base) if not Path(base).is_absolute() else Path(base)
    for earlier in chain:
        if _same_file(earlier, base_path):
            cycle = chain[chain.index(earlier) :] + [base_path]
            raise DesignError(
                "base", base, f"{_chain_names(cycle)} is a cycle; a base chain must end in a file without base", source
            )
    if len(chain) > max_depth:
        raise DesignError(
            "base", base, f"{_chain_names(chain + [base_path])}: at most {max_depth} levels of base files", source
        )
    base_raw = read_file(base_path, "base", base, source, max_bytes)
    base_data, base_chain = read_toml(
        base_path, str(base_path), base_raw, chain + [base_path], max_bytes, max_depth, origins
    )
    origins.update(dict.fromkeys(data, str(path)))
    return {**base_data, **data}, base_chain + b"\0" + raw


def anchor_paths(data: dict[str, Any], folder: Path) -> None:
    """Make the file names a design file gives relative to itself absolute, in place: a base
    chain merges tables from files in other folders, so each name is read where it was written
    (``[friction.X] file``, ``[friction] records``, a joint's ``friction`` file).

    Parameters
    ----------
    data : dict
        The file's tables as read; values of the wrong type are left for the parser to report.
    folder : Path
        The folder of the file.
    """

    def anchored(value: Any) -> Any:
        if isinstance(value, str) and value and not Path(value).is_absolute():
            return os.path.abspath(folder / value)  # absolute: the run reports them from another folder
        return value

    friction = data.get("friction")
    if isinstance(friction, dict):
        for table in friction.values():
            if isinstance(table, dict) and "file" in table:
                table["file"] = anchored(table["file"])
        if isinstance(friction.get("records"), list):
            friction["records"] = [anchored(value) for value in friction["records"]]
    joints = data.get("joints")
    for joint in joints if isinstance(joints, list) else ():
        if isinstance(joint, dict) and isinstance(joint.get("friction"), str):
            joint["friction"] = anchored(joint["friction"])
        elif isinstance(joint, dict) and isinstance(joint.get("friction"), dict) and "file" in joint["friction"]:
            joint["friction"]["file"] = anchored(joint["friction"]["file"])


__all__ = ["anchor_paths", "read_file", "read_toml"]
