"""The generated controllers compiled with cffi behind the controller interface.

``compile_controllers`` renders the artefact (``generate.render``), writes the files to the
build cache and compiles them with the warning set the generated C is held to
(``build.FLAGS``: any warning is an error); the cffi declarations come from the generated
headers (``build.declarations``). The wrappers ``CompiledSiso`` and ``CompiledClippedLqg`` have
the interface of the Python reference controllers (``reset()``, ``step(measurements) ->
normal_forces``, ``sample_time``, ``status``) so the plant simulation runs either. ``run`` feeds
a whole input sequence through C in one call (a loop inside C), for back-to-back checks and
step-time measurements.
"""

from __future__ import annotations

import numpy as np

from smartjoint.codegen import build, generate
from smartjoint.design.control.artifact import ControllerArtifact
from smartjoint.design.plant.interface import Measurements

LAWS = ("siso", "clqg")


def _driver_header(prefix: str) -> str:
    """Prototypes of the batch loops (cffi declarations and C alike)."""
    guard = f"{prefix.upper()}_BATCH_DRIVER_H"
    prototypes = "".join(
        f"unsigned int {prefix}_{law}_run({prefix}_{law}_state *state, const {prefix}_{law}_input *input,\n"
        f"                                {prefix}_{law}_output *output, unsigned int *status, int count);\n"
        for law in LAWS
    )
    return (
        f"/* Batch loops compiled next to the generated controllers (not part of the firmware). */\n"
        f"#ifndef {guard}\n#define {guard}\n\n"
        f'#include "{prefix}_siso.h"\n#include "{prefix}_clqg.h"\n\n{prototypes}\n#endif\n'
    )


def _driver(prefix: str) -> str:
    """Batch loops compiled next to the generated code (not part of the firmware)."""
    out = ['#include "_driver.h"']
    for law in LAWS:
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
    """The compiled module of one artefact and scalar type.

    Parameters
    ----------
    artifact : ControllerArtifact
        The controller design artefact.
    real : str
        The scalar type, ``"float"`` or ``"double"``.
    prefix : str
        The prefix of every C identifier and file name.
    flags : list of str, optional
        The compiler flags of the generated C; default ``build.FLAGS``.
    """

    def __init__(
        self,
        artifact: ControllerArtifact,
        real: str = "double",
        prefix: str = "smartjoint",
        flags: list[str] | None = None,
    ):
        files = generate.render(artifact, real, prefix)
        self.artifact, self.real, self.prefix, self.files = artifact, real, prefix, files
        batch = {**files, "_driver.h": _driver_header(prefix), "_driver.c": _driver(prefix)}
        self.folder, module = build.load(
            f"controllers_{prefix}_{real}",
            batch,
            "_driver.h",
            (f"{prefix}_siso.c", f"{prefix}_clqg.c", "_driver.c"),
            flags,
        )
        self.ffi, self.lib = module.ffi, module.lib
        self.dtype = np.float32 if real == "float" else np.float64

    def siso(self) -> CompiledSiso:
        """A new instance of the compiled SISO law (Eq. 30–31)."""
        return CompiledSiso(self)

    def clipped_lqg(self) -> CompiledClippedLqg:
        """A new instance of the compiled clipped-optimal LQG (Eq. 33–34)."""
        return CompiledClippedLqg(self)


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
        """Back to the initial state (the ``<prefix>_<law>_init`` of the C)."""
        self._init(self._state)
        self.status = 0

    def _inputs(self, measurements: Measurements) -> list[np.ndarray]:
        raise NotImplementedError

    def step(self, measurements: Measurements) -> np.ndarray:
        """One controller sample through the C.

        Parameters
        ----------
        measurements : Measurements
            What the joints and sensors measure at this sample.

        Returns
        -------
        numpy.ndarray
            The commanded normal forces F_N,j [N]; ``status`` holds the step's status bits.
        """
        for field, values in zip(self.input_fields, self._inputs(measurements)):
            getattr(self._input, field)[0 : len(values)] = [float(v) for v in values]
        self.status = int(self._step(self._state, self._input, self._output))
        return np.array(list(self._output.normal_force), dtype=float)

    def run(self, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Feed rows of inputs through the C from the current state, in one call.

        Parameters
        ----------
        inputs : numpy.ndarray
            One row per sample, the input struct's fields concatenated in struct order.

        Returns
        -------
        tuple of numpy.ndarray
            The outputs in struct order, one row per sample, and the status bits per row.
        """
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
        """The LQR forces u_d = -K x_hat of the last step [N] (Eq. 33)."""
        return np.array(list(self._output.desired_force), dtype=float)


def compile_controllers(
    artifact: ControllerArtifact, real: str = "double", prefix: str = "smartjoint", flags: list[str] | None = None
) -> Controllers:
    """Render, compile and load the controllers of an artefact.

    Parameters
    ----------
    artifact, real, prefix, flags
        As for :class:`Controllers`.

    Returns
    -------
    Controllers
        The compiled module; ``.siso()`` and ``.clipped_lqg()`` give controllers.

    Examples
    --------
    >>> law = compile_controllers(artifact, "float").siso()  # doctest: +SKIP
    >>> law.step(measurements)  # doctest: +SKIP
    """
    return Controllers(artifact, real, prefix, flags)
