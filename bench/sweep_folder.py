"""The output folder of a sweep: what a sweep writes there, and the output rule on it
(`common.output_path`) — a new or empty folder, or a sweep's own folder continued with
``--resume``; a folder with anything a sweep did not write is refused before any work, so a user's
``report.md``, CSV or Parquet file is never replaced or read as a result.
"""

from __future__ import annotations

import re
from pathlib import Path

from smartjoint.bench.sweep_landscape import LANDSCAPE, LANDSCAPE_PLOT
from smartjoint.common import output_path
from smartjoint.common.errors import OutputError

MANIFEST = "sweep.json"
RESULTS = "results"
# Every name a sweep writes at the top of its folder, and into results/ (hidden: a batch or a
# file being written, renamed whole when done, or left by an interrupted sweep).
OWN_FILES = (MANIFEST, "report.md", "ecdf.png", LANDSCAPE, LANDSCAPE_PLOT)
BATCH = re.compile(r"\.?batch-\d{6}\.parquet(\.\d+\.tmp)?")
STAGING = re.compile(r"\.(" + "|".join(re.escape(name) for name in OWN_FILES) + r")\..+\.partial")


def foreign_entry(folder: Path) -> str | None:
    """The first entry of an existing sweep folder (one with ``sweep.json``) that a sweep did not
    write, as a path relative to ``folder``; None when there is none."""
    for entry in sorted(folder.iterdir()):
        found = output_path.kind(entry)
        if entry.name == RESULTS and found == "folder":
            batches = sorted(
                e for e in entry.iterdir() if not (BATCH.fullmatch(e.name) and output_path.kind(e) == "file")
            )
            if batches:
                return f"{RESULTS}/{batches[0].name}"
        elif not (found == "file" and (entry.name in OWN_FILES or STAGING.fullmatch(entry.name))):
            return entry.name
    return None


def check_output(folder: Path, resume: bool) -> None:
    """Refuse, before any work, an output a sweep must not write (one line, ``OutputError``).

    Parameters
    ----------
    folder : Path
        The output folder.
    resume : bool
        ``--resume``: a sweep's own folder is continued (``bench.sweep.open_output`` compares
        its sweep); without it such a folder is refused.

    Raises
    ------
    OutputError
        Not a folder (a file, link, FIFO, device, below a file), a non-empty folder without
        ``sweep.json``, a sweep's folder without ``resume``, or one holding a file a sweep did not
        write (named).
    """
    output_path.check_folder(folder, "-o", ours=lambda entry: True)
    if not folder.exists() or not any(folder.iterdir()):
        return
    if output_path.kind(folder / MANIFEST) != "file":
        first = sorted(entry.name for entry in folder.iterdir())[0]
        raise OutputError(
            f"-o {folder}: holds {first!r} and no {MANIFEST}: not a sweep's folder — name a new or empty folder"
        )
    if not resume:
        raise OutputError(f"-o {folder}: holds results of a sweep already; --resume continues it, or give another -o")
    foreign = foreign_entry(folder)
    if foreign is not None:
        raise OutputError(
            f"-o {folder}: holds {foreign!r}, which a sweep did not write — move it away; nothing in the folder "
            "is replaced or read as a result"
        )


__all__ = ["BATCH", "MANIFEST", "OWN_FILES", "RESULTS", "check_output", "foreign_entry"]
