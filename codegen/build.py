"""Compile the generated controllers with cffi and wrap them behind the controller interface.

``compile_controllers`` renders the artefact, writes the files to the build cache and compiles
them with the warning set the generated C is held to (any warning is an error). The wrappers
``CompiledSiso`` and ``CompiledClippedLqg`` have the interface of the Python reference
controllers (``reset()``, ``step(measurements) -> normal_forces``, ``sample_time``, ``status``)
so the plant simulation runs either. ``run`` feeds a whole input sequence through C in one call
(a loop inside C), for back-to-back checks and step-time measurements.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from smartjoint.common import native
from smartjoint.design.control.artifact import ControllerArtifact
from smartjoint.common.errors import ModelError
from smartjoint.design.plant.interface import Measurements
from smartjoint.codegen import generate

WARNINGS = ["-Wall", "-Wextra", "-Wpedantic", "-Wconversion", "-Wdouble-promotion", "-Wshadow", "-Werror"]
FLAGS = ["-std=c99", "-O2", "-ffp-contract=off", *WARNINGS]


@dataclass(frozen=True)
class Sizes:
    joints: int
    sensors: int
    coordinates: int


def _declarations(prefix: str, real: str, s: Sizes) -> str:
    l, ny, n2 = s.joints, s.sensors, 2 * s.coordinates
    return f"""
typedef {real} {prefix}_real;
typedef struct {{ {prefix}_real sliding_velocity[{l}]; {prefix}_real friction_force[{l}];
                 {prefix}_real normal_force[{l}]; }} {prefix}_siso_input;
typedef struct {{ {prefix}_real normal_force[{l}]; }} {prefix}_siso_output;
typedef struct {{ {prefix}_real previous_friction[{l}]; {prefix}_real previous_normal_force[{l}]; }} {prefix}_siso_state;
void {prefix}_siso_init({prefix}_siso_state *state);
unsigned int {prefix}_siso_step({prefix}_siso_state *state, const {prefix}_siso_input *input, {prefix}_siso_output *output);
unsigned int {prefix}_siso_run({prefix}_siso_state *state, const {prefix}_siso_input *input, {prefix}_siso_output *output,
                               unsigned int *status, int count);
typedef struct {{ {prefix}_real sensors[{ny}]; {prefix}_real friction_force[{l}]; {prefix}_real normal_force[{l}]; }} {prefix}_clqg_input;
typedef struct {{ {prefix}_real normal_force[{l}]; {prefix}_real desired_force[{l}]; }} {prefix}_clqg_output;
typedef struct {{ {prefix}_real estimate[{n2}]; {prefix}_real previous_force[{l}]; int started; }} {prefix}_clqg_state;
void {prefix}_clqg_init({prefix}_clqg_state *state);
unsigned int {prefix}_clqg_step({prefix}_clqg_state *state, const {prefix}_clqg_input *input, {prefix}_clqg_output *output);
unsigned int {prefix}_clqg_run({prefix}_clqg_state *state, const {prefix}_clqg_input *input, {prefix}_clqg_output *output,
                               unsigned int *status, int count);
"""


def _driver(prefix: str) -> str:
    """Batch loops compiled next to the generated code (not part of the firmware)."""
    out = [f'#include "{prefix}_siso.h"', f'#include "{prefix}_clqg.h"']
    for law in ("siso", "clqg"):
        out.append(f"""
unsigned int {prefix}_{law}_run({prefix}_{law}_state *state, const {prefix}_{law}_input *input,
                                {prefix}_{law}_output *output, unsigned int *status, int count)
{{
    unsigned int all = 0u;
    int k;
    for (k = 0; k < count; ++k) {{
        status[k] = {prefix}_{law}_step(state, &input[k], &output[k]);
        all |= status[k];
    }}
    return all;
}}""")
    return "\n".join(out) + "\n"


class Controllers:
    """The compiled module of one artefact and scalar type."""

    def __init__(self, artifact: ControllerArtifact, real: str = "double", prefix: str = "smartjoint",
                 flags: list[str] | None = None):
        files = generate.render(artifact, real, prefix)
        self.artifact, self.real, self.prefix, self.files = artifact, real, prefix, files
        self.sizes = Sizes(len(artifact.joint_names), len(artifact.sensor_names), int(np.asarray(artifact.blocks).shape[0]))
        digest = hashlib.sha256("\0".join(f"{k}\0{v}" for k, v in sorted(files.items())).encode()).hexdigest()[:16]
        folder = native.cache_dir() / f"generated-{prefix}-{real}-{digest}"
        if not all((folder / name).exists() and (folder / name).read_text() == text for name, text in files.items()):
            generate.write(files, folder)
        driver = folder / "_driver.c"
        if not driver.exists() or driver.read_text() != _driver(prefix):
            generate.write({"_driver.c": _driver(prefix)}, folder)
        self.folder = folder
        # The generated C (and the batch driver) compile alone with the strict flags — any
        # warning fails the build; only cffi's own glue is compiled with the default flags.
        flags = FLAGS if flags is None else flags
        objects = tuple(compile_object(folder / name, flags) for name in
                        (f"{prefix}_siso.c", f"{prefix}_clqg.c", "_driver.c"))
        glue = folder / "_glue.c"
        glue_text = f'#include "{prefix}_siso.h"\n#include "{prefix}_clqg.h"\n' + "".join(
            f"unsigned int {prefix}_{law}_run({prefix}_{law}_state *state, const {prefix}_{law}_input *input, "
            f"{prefix}_{law}_output *output, unsigned int *status, int count);\n" for law in ("siso", "clqg"))
        if not glue.exists() or glue.read_text() != glue_text:
            generate.write({"_glue.c": glue_text}, folder)
        module = native.load(f"controllers_{real}", _declarations(prefix, real, self.sizes), glue,
                             objects=objects, includes=(folder,))
        self.ffi, self.lib = module.ffi, module.lib
        self.dtype = np.float32 if real == "float" else np.float64

    def siso(self) -> "CompiledSiso":
        return CompiledSiso(self)

    def clipped_lqg(self) -> "CompiledClippedLqg":
        return CompiledClippedLqg(self)


def compile_object(source: Path, flags: list[str]) -> Path:
    """``cc -c`` one file with ``flags`` (+ -fPIC) next to it, named by a hash of the flags;
    a compiler message is raised as a ModelError with the compiler's text."""
    tag = hashlib.sha256((" ".join(flags) + source.read_text()).encode()).hexdigest()[:12]
    target = source.with_name(f"{source.stem}-{tag}.o")
    if target.exists():
        return target
    compiler = os.environ.get("CC", "cc")
    temporary = target.with_name(f".{target.name}.{os.getpid()}")
    done = subprocess.run([compiler, *flags, "-fPIC", "-c", str(source), "-o", str(temporary)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        temporary.unlink(missing_ok=True)
        raise ModelError(f"compiling {source.name} with {' '.join(flags)} failed:\n{done.stderr.strip()}")
    os.replace(temporary, target)
    return target


class _Compiled:
    law = ""
    input_fields: tuple[str, ...] = ()
    output_fields: tuple[str, ...] = ()

    def __init__(self, controllers: Controllers):
        self.c = controllers
        p, ffi = controllers.prefix, controllers.ffi
        self.sample_time = float(controllers.artifact.sample_time)
        self._state = ffi.new(f"{p}_{self.law}_state *")
        self._input = ffi.new(f"{p}_{self.law}_input *")
        self._output = ffi.new(f"{p}_{self.law}_output *")
        self._init = getattr(controllers.lib, f"{p}_{self.law}_init")
        self._step = getattr(controllers.lib, f"{p}_{self.law}_step")
        self._run = getattr(controllers.lib, f"{p}_{self.law}_run")
        self.status = 0
        self.reset()

    def reset(self) -> None:
        self._init(self._state)
        self.status = 0

    def _inputs(self, measurements: Measurements) -> list[np.ndarray]:
        raise NotImplementedError

    def step(self, measurements: Measurements) -> np.ndarray:
        for field, values in zip(self.input_fields, self._inputs(measurements)):
            getattr(self._input, field)[0:len(values)] = [float(v) for v in values]
        self.status = int(self._step(self._state, self._input, self._output))
        return np.array(list(self._output.normal_force), dtype=float)

    def run(self, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Feed rows of inputs (fields concatenated in struct order) through C from the current
        state; returns (outputs in struct order, status per row)."""
        dtype = self.c.dtype
        rows = np.ascontiguousarray(inputs, dtype=dtype)
        count = rows.shape[0]
        ffi, p = self.c.ffi, self.c.prefix
        input_array = ffi.new(f"{p}_{self.law}_input[]", count)
        output_array = ffi.new(f"{p}_{self.law}_output[]", count)
        status = np.zeros(count, dtype=np.uintc)
        np.frombuffer(ffi.buffer(input_array), dtype=dtype).reshape(count, -1)[:] = rows
        self._run(self._state, input_array, output_array, ffi.from_buffer("unsigned int[]", status), count)
        outputs = np.frombuffer(ffi.buffer(output_array), dtype=dtype).reshape(count, -1).astype(float)
        return outputs, status


class CompiledSiso(_Compiled):
    """The generated SISO law (Eq. 30–31) behind the controller interface."""

    law = "siso"
    input_fields = ("sliding_velocity", "friction_force", "normal_force")

    def _inputs(self, m: Measurements):
        return [np.asarray(m.sliding_velocity), np.asarray(m.friction_force), np.asarray(m.normal_force)]


class CompiledClippedLqg(_Compiled):
    """The generated clipped-optimal LQG (Eq. 33–34) behind the controller interface."""

    law = "clqg"
    input_fields = ("sensors", "friction_force", "normal_force")

    def _inputs(self, m: Measurements):
        return [np.asarray(m.sensors), np.asarray(m.friction_force), np.asarray(m.normal_force)]

    @property
    def desired_force(self) -> np.ndarray:
        return np.array(list(self._output.desired_force), dtype=float)


def compile_controllers(artifact: ControllerArtifact, real: str = "double", prefix: str = "smartjoint",
                        flags: list[str] | None = None) -> Controllers:
    return Controllers(artifact, real, prefix, flags)


def _first_error(output: str, folder: Path) -> str:
    """The compiler's first diagnostic line, with the temporary folder taken out of it."""
    lines = [line.replace(f"{folder}{os.sep}", "") for line in output.splitlines() if line.strip()]
    for line in lines:
        if "error" in line:
            return line.strip()
    return lines[0].strip() if lines else "no message"


def check_folder(folder: Path, flags: list[str] | None = None) -> dict:
    """Compile everything C in ``folder`` as written: every header alone (each must be
    self-contained), every ``.c`` with ``flags`` (default :data:`FLAGS`, any warning an error),
    then link them into the example program. Build products go to a temporary folder of their
    own; the first diagnostic is raised as a one-line ModelError."""
    folder = Path(folder)
    flags = FLAGS if flags is None else flags
    compiler = os.environ.get("CC", "cc")
    if shutil.which(compiler) is None:
        raise ModelError(f"--check: no C compiler {compiler!r} found (install one or set CC)")
    headers = sorted(p.name for p in folder.glob("*.h"))
    sources = sorted(p.name for p in folder.glob("*.c"))
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
