"""Compile a C source of this package with cffi on first use and load it (cached per machine).

The compiled module lands in ``$SMARTJOINT_CACHE`` (default ``~/.cache/smartjoint``) under a
name that carries a hash of the source, the declarations, the flags and the Python ABI, so an
edited source recompiles and a stale build is never loaded. Builds go to a private temporary
folder first and are moved into place atomically: two processes compiling at once both win.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import platform
import shutil
import sys
import sysconfig
import tempfile
import warnings
from pathlib import Path

from smartjoint.common.errors import ModelError

# No -ffast-math and no FMA contraction: the kernels must round like their numpy mirrors.
# -march=native: the build is per machine anyway, and the key below names the CPU.
FLAGS = ["-O3", "-march=native", "-std=c99", "-ffp-contract=off"]


def _cpu() -> str:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return platform.processor()
    lines = [line for line in text.splitlines() if line.startswith(("model name", "flags", "Features"))]
    return "\n".join(sorted(set(lines)))


def cache_dir() -> Path:
    """Where compiled modules are kept: ``$SMARTJOINT_CACHE``, else ``~/.cache/smartjoint``.

    Returns
    -------
    Path
    """
    return Path(os.environ.get("SMARTJOINT_CACHE") or Path.home() / ".cache" / "smartjoint")


_LOADED: dict[tuple, object] = {}  # per process: a short simulation should not re-hash the source


def load(
    stem: str, declarations: str, source: Path, *, objects: tuple[Path, ...] = (), includes: tuple[Path, ...] = ()
):
    """The cffi module (``.ffi``, ``.lib``) of ``source`` with the C ``declarations``, compiled on
    first use and cached per machine (the key hashes the source, declarations, flags, Python and CPU).

    Parameters
    ----------
    stem : str
        The module's name stem.
    declarations : str
        The C declarations cffi binds (read from the source's header).
    source : Path
        The C source.
    objects : tuple of Path
        Compiled object files linked into the module.
    includes : tuple of Path
        Header folders.

    Returns
    -------
    module
        With ``ffi`` and ``lib``.

    Raises
    ------
    ModelError
        When the compiler fails (no compiler, headers missing): one line.
    """
    stamp = tuple((str(p), p.stat().st_mtime_ns, p.stat().st_size) for p in (Path(source), *map(Path, objects)))
    key = (stem, declarations, stamp, tuple(map(str, includes)))
    if key not in _LOADED:
        _LOADED[key] = _load(stem, declarations, Path(source), tuple(objects), tuple(includes))
    return _LOADED[key]


def _load(stem: str, declarations: str, source: Path, objects: tuple[Path, ...], includes: tuple[Path, ...]):
    text = source.read_text()
    flags = FLAGS
    extra = [f"{p.name}\0{p.read_bytes().hex()}" for p in objects]
    key = hashlib.sha256(
        "\0".join([declarations, text, " ".join(flags), sys.version, *extra, sysconfig.get_platform(), _cpu()]).encode()
    ).hexdigest()[:16]
    name = f"_sj_{stem}_{key}"
    target_dir = cache_dir()
    suffix = sysconfig.get_config_var("EXT_SUFFIX") or ".so"
    target = target_dir / f"{name}{suffix}"
    if not target.exists():
        import cffi

        ffi = cffi.FFI()
        ffi.cdef(declarations)
        ffi.set_source(
            name,
            text,
            extra_objects=[str(p) for p in objects],
            include_dirs=[str(p) for p in includes],
            extra_compile_args=flags,
            libraries=["m"],
        )
        target_dir.mkdir(parents=True, exist_ok=True)
        build = Path(tempfile.mkdtemp(prefix=f"{name}-", dir=target_dir))
        try:
            built = Path(ffi.compile(tmpdir=str(build), verbose=False))
            os.replace(built, target)
        except Exception as error:  # no compiler, headers missing, …
            raise ModelError(f"compiling {source.name} failed: {error}") from None
        finally:
            shutil.rmtree(build, ignore_errors=True)
    spec = importlib.util.spec_from_file_location(name, target)
    if spec is None or spec.loader is None:  # a path ending in an extension suffix always has one
        raise ModelError(f"{target}: not loadable as an extension module")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def library(module) -> Path:
    """The shared library a module of :func:`load` was loaded from (its symbols: ``nm``)."""
    return Path(module.__spec__.origin)


def choose(backend: str, what: str, compiled, mirror, failures: list[str], stacklevel: int = 3):
    """``compiled()`` or ``mirror()`` for ``backend`` 'c', 'python' or 'auto' (C where it builds).

    Under 'auto' a failed build warns once (``failures`` remembers why, per kernel) and every
    later call goes straight to the Python mirror; under 'c' the build error reaches the caller.

    Parameters
    ----------
    backend : str
        'auto', 'c' or 'python'.
    what : str
        The kernel's name in the warning.
    compiled, mirror : callable
        Return the C kernel and its Python mirror.
    failures : list of str
        The kernel's build failures so far (filled here).
    stacklevel : int
        Of the warning, from this function's caller.

    Returns
    -------
    object
        What ``compiled()`` or ``mirror()`` returned.
    """
    if backend not in ("auto", "c", "python"):
        raise ModelError(f"backend: {backend!r} — must be 'auto', 'c' or 'python'")
    if backend == "python" or (backend == "auto" and failures):
        return mirror()
    try:
        return compiled()
    except ModelError as error:
        if backend == "c":
            raise
        failures.append(str(error))
        warnings.warn(
            f"{what} falls back to Python (about 100x slower): {error}", RuntimeWarning, stacklevel=stacklevel + 1
        )
        return mirror()
