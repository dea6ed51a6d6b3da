"""Compile generated C: the warning set it is held to, one object file at a time
(:func:`compile_object`), a whole generated folder as written (:func:`check_folder`), and the cffi
declarations of generated code taken from its own headers (:func:`declarations`), and the two
together: a generated set compiled in the build cache and loaded (:func:`load`).

Any warning is an error (``-Werror``): the generated C compiles clean with :data:`FLAGS` or not
at all. The headers are the one source of truth for the C interface: the benches that load the
generated code with cffi read their declarations from the headers the generator wrote, so a
changed template cannot leave a stale Python copy of a struct behind.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path

from smartjoint.codegen import build_files, output
from smartjoint.common import native
from smartjoint.common.errors import ModelError

WARNINGS = ["-Wall", "-Wextra", "-Wpedantic", "-Wconversion", "-Wdouble-promotion", "-Wshadow", "-Werror"]
FLAGS = ["-std=c99", "-O2", "-ffp-contract=off", *WARNINGS]


def compile_object(source: Path, flags: list[str]) -> Path:
    """``cc -c`` one file with ``flags`` (+ -fPIC) next to it, cached by a hash of flags and text.

    Parameters
    ----------
    source : Path
        The C file.
    flags : list of str
        The compiler flags (usually :data:`FLAGS`).

    Returns
    -------
    Path
        The object file ``<stem>-<hash>.o`` next to ``source``.

    Raises
    ------
    ModelError
        The compiler failed; the message carries the compiler's text.
    """
    tag = hashlib.sha256((" ".join(flags) + source.read_text()).encode()).hexdigest()[:12]
    target = source.with_name(f"{source.stem}-{tag}.o")
    if target.exists():
        return target
    compiler = os.environ.get("CC", "cc")
    temporary = target.with_name(f".{target.name}.{os.getpid()}")
    done = subprocess.run(
        [compiler, *flags, "-fPIC", "-c", str(source), "-o", str(temporary)], capture_output=True, text=True
    )
    if done.returncode != 0:
        temporary.unlink(missing_ok=True)
        raise ModelError(f"compiling {source.name} with {' '.join(flags)} failed:\n{done.stderr.strip()}")
    os.replace(temporary, target)
    return target


def _first_error(output: str, folder: Path) -> str:
    """The compiler's first diagnostic line, with the temporary folder taken out of it."""
    lines = [line.replace(f"{folder}{os.sep}", "") for line in output.splitlines() if line.strip()]
    for line in lines:
        if "error" in line:
            return line.strip()
    return lines[0].strip() if lines else "no message"


def check_folder(folder: Path, flags: list[str] | None = None) -> dict:
    """Compile everything C in ``folder`` as written.

    Every header alone (each must be self-contained), every ``.c`` with ``flags`` (any warning
    an error) but the target image's own (``build_files.TARGET_SOURCES``), then link them into
    the example program. Build products go to a temporary folder
    of their own.

    Parameters
    ----------
    folder : Path
        The folder of generated files.
    flags : list of str, optional
        The compiler flags; default :data:`FLAGS`.

    Returns
    -------
    dict
        ``compiler``, ``flags``, and the ``headers`` and ``sources`` compiled (sorted names).

    Raises
    ------
    ModelError
        No compiler, or the first diagnostic as one line (the temporary folders taken out).
    """
    folder = Path(folder)
    flags = FLAGS if flags is None else flags
    compiler = os.environ.get("CC", "cc")
    if shutil.which(compiler) is None:
        raise ModelError(f"--check: no C compiler {compiler!r} found (install one or set CC)")
    headers = sorted(p.name for p in folder.glob("*.h"))
    sources = sorted(p.name for p in folder.glob("*.c") if p.name not in build_files.TARGET_SOURCES)
    with tempfile.TemporaryDirectory(prefix="smartjoint-check-") as scratch:
        work = Path(scratch)

        def run(arguments: list[str], what: str) -> None:
            done = subprocess.run([compiler, *arguments], capture_output=True, text=True)
            if done.returncode != 0:
                message = _first_error(done.stderr + done.stdout, folder).replace(f"{work}{os.sep}", "")
                raise ModelError(f"--check: {what} fails with {compiler} {' '.join(flags)}: {message}")

        for header in headers:
            unit = work / f"header_{header}.c"
            unit.write_text(f'#include "{header}"\n', encoding="ascii")
            run([*flags, "-I", str(folder), "-fsyntax-only", str(unit)], f"{header} (included alone)")
        objects = []
        for source in sources:
            objects.append(str(work / f"{source}.o"))
            run([*flags, "-I", str(folder), "-c", str(folder / source), "-o", objects[-1]], source)
        if sources:
            run([*flags, *objects, "-o", str(work / "example"), "-lm"], f"linking {', '.join(sources)}")
    return {"compiler": compiler, "flags": list(flags), "headers": headers, "sources": sources}


_COMMENT = re.compile(r"/\*.*?\*/|//[^\n]*", re.S)
_LOCAL_INCLUDE = re.compile(r'^[ \t]*#[ \t]*include[ \t]+"([^"]+)"', re.M)
_SIZE_MACRO = re.compile(r"^[ \t]*#[ \t]*define[ \t]+([A-Za-z_]\w*)[ \t]+(\d+)[ \t]*$", re.M)
_IDENTIFIER = re.compile(r"\b[A-Za-z_]\w*\b")


def declarations(files: Mapping[str, str], headers: Iterable[str]) -> str:
    """The cffi declarations (``ffi.cdef`` text) of C headers, taken from the headers themselves.

    Each header and the local headers it includes (``#include "…"``, from ``files``, each once,
    included before includer) contribute their text without comments and preprocessor lines;
    what a C++ compiler alone sees (``#ifdef __cplusplus`` blocks) is left out, and macros that
    stand for a plain decimal number (the array sizes the generator renders from the artefact,
    e.g. ``SMARTJOINT_SISO_JOINTS``) are replaced by that number. System headers (``<stdint.h>``)
    need nothing: cffi knows their types.

    Parameters
    ----------
    files : mapping of str to str
        File name → text, holding every header named or locally included.
    headers : iterable of str
        The headers to declare, in order.

    Returns
    -------
    str
        Declarations for ``ffi.cdef``.

    Raises
    ------
    ModelError
        A locally included header is not among ``files``.

    Examples
    --------
    >>> header = "#define N 3\\ntypedef struct { double x[N]; } point; /* metres */\\n"
    >>> declarations({"point.h": header}, ["point.h"]).strip()
    'typedef struct { double x[3]; } point;'
    """
    order: list[str] = []

    def visit(name: str, includer: str) -> None:
        if name in order:
            return
        if name not in files:
            raise ModelError(f"{includer}: includes {name!r}, which is not among the generated files")
        for included in _LOCAL_INCLUDE.findall(_COMMENT.sub(" ", files[name])):
            visit(included, name)
        order.append(name)

    for header in headers:
        visit(header, "declarations")
    return "\n".join(_header_declarations(files[name]) for name in order)


def _header_declarations(text: str) -> str:
    """One header's declarations: comments, preprocessor lines and C++-only blocks removed, size
    macros replaced by their numbers."""
    text = _COMMENT.sub(" ", text)
    sizes = dict(_SIZE_MACRO.findall(text))
    kept: list[str] = []
    cplusplus: list[bool] = []  # per open #if: whether its branch is seen by a C++ compiler only
    for line in text.splitlines():
        directive = line.strip()
        if not directive.startswith("#"):
            if not any(cplusplus) and directive:
                kept.append(line.rstrip())
            continue
        words = directive[1:].split()
        keyword = words[0] if words else ""
        if keyword in ("if", "ifdef", "ifndef"):
            cplusplus.append(keyword != "ifndef" and "__cplusplus" in directive)
        elif keyword in ("else", "elif") and cplusplus:
            cplusplus[-1] = False
        elif keyword == "endif" and cplusplus:
            cplusplus.pop()
    return _IDENTIFIER.sub(lambda match: sizes.get(match.group(0), match.group(0)), "\n".join(kept))


def load(
    stem: str,
    files: Mapping[str, str],
    header: str,
    sources: Iterable[str],
    flags: list[str] | None = None,
    source_flags: Mapping[str, list[str]] | None = None,
):
    """Compile a set of generated files in the build cache and load it with cffi.

    The set goes to a cache folder named by its hash (files already there as they are stay
    untouched, so their objects stay cached); each of ``sources`` compiles alone with the
    strict ``flags`` — any warning fails the build — and only cffi's own glue, which includes
    ``header``, is compiled with the default flags. The cffi declarations are those of
    ``header`` and the local headers it includes (:func:`declarations`).

    Parameters
    ----------
    stem : str
        The kind of module (names the cache folder and the cffi module).
    files : mapping of str to str
        File name → text of every source and header.
    header : str
        The header that declares everything Python calls.
    sources : iterable of str
        The ``.c`` files linked into the module.
    flags : list of str, optional
        The compiler flags of the sources; default :data:`FLAGS`.
    source_flags : mapping of str to list of str, optional
        Other flags for some of the sources (a hand-written source not held to the warning set).

    Returns
    -------
    tuple of (Path, module)
        The cache folder and the cffi module (``.ffi``, ``.lib``).
    """
    digest = hashlib.sha256("\0".join(f"{k}\0{v}" for k, v in sorted(files.items())).encode()).hexdigest()[:16]
    folder = native.cache_dir() / f"{stem}-{digest}"
    glue = {"_glue.c": f'#include "{header}"\n'}
    stale = {
        name: text
        for name, text in {**files, **glue}.items()
        if not ((folder / name).exists() and (folder / name).read_text() == text)
    }
    if stale:
        output.write(stale, folder)
    flags = FLAGS if flags is None else flags
    chosen = dict(source_flags or {})
    objects = tuple(compile_object(folder / name, chosen.get(name, flags)) for name in sources)
    module = native.load(stem, declarations(files, [header]), folder / "_glue.c", objects=objects, includes=(folder,))
    return folder, module
