"""The generated controllers compiled with cffi behind the controller interface.

``compile_controllers`` renders the artefact (``generate.render``), writes the files to the
build cache and compiles them with the warning set the generated C is held to
(``build.FLAGS``: any warning is an error); the cffi declarations come from the generated
headers (``build.declarations``). ``CompiledLaw`` wraps any law of the registry
(``common.law_registry``) with the interface of the Python reference controllers
(``reset()``, ``step(measurements) -> normal_forces``, ``sample_time``, ``status``) so the plant
simulation runs either; the law's entry names the measurements its input struct holds. ``run``
feeds a whole input sequence through C in one call (a loop inside C), for back-to-back checks
and step-time measurements.
"""

from __future__ import annotations

import numpy as np

from smartjoint.codegen import build, generate
from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control.artifact import ControllerArtifact
from smartjoint.design.plant.interface import Measurements


def _driver_header(prefix: str) -> str:
    """Prototypes of the batch loops (cffi declarations and C alike)."""
    guard = f"{prefix.upper()}_BATCH_DRIVER_H"
    prototypes = "".join(
        f"unsigned int {prefix}_{law}_run({prefix}_{law}_state *state, const {prefix}_{law}_input *input,\n"
        f"                                {prefix}_{law}_output *output, unsigned int *status, int count);\n"
        for law in law_registry.NAMES
    )
    includes = "".join(f'#include "{prefix}_{law}.h"\n' for law in law_registry.NAMES)
    return (
        f"/* Batch loops compiled next to the generated controllers (not part of the firmware). */\n"
        f"#ifndef {guard}\n#define {guard}\n\n{includes}\n{prototypes}\n#endif\n"
    )


def _driver(prefix: str) -> str:
    """Batch loops compiled next to the generated code (not part of the firmware)."""
    out = ['#include "_driver.h"']
    for law in law_registry.NAMES:
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
            (*(f"{prefix}_{law}.c" for law in law_registry.NAMES), "_driver.c"),
            flags,
        )
        self.ffi, self.lib = module.ffi, module.lib
        self.dtype = np.float32 if real == "float" else np.float64

    def law(self, name: str) -> CompiledLaw:
        """A new instance of the compiled law ``name`` (a law of ``common.law_registry``)."""
        return CompiledLaw(self, law_registry.law(name))


class CompiledLaw:
    """One generated law behind the controller interface.

    Parameters
    ----------
    controllers : Controllers
        The compiled module.
    law : law_registry.Law
        The law; its ``inputs`` are the measurements its input struct holds, in order.
    """

    def __init__(self, controllers: Controllers, law: law_registry.Law):
        self.c, self.entry, self.law = controllers, law, law.name
        self.input_fields, self.output_fields = law.inputs, law.outputs
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
        self._init(self._state, self.c.ffi.NULL)
        self.status = 0

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
        for field in self.input_fields:
            values = np.asarray(getattr(measurements, field))
            getattr(self._input, field)[0 : len(values)] = [float(v) for v in values]
        self.status = int(self._step(self._state, self._input, self._output))
        return np.array(list(self._output.normal_force), dtype=float)

    def output(self, field: str) -> np.ndarray:
        """A field of the last step's output struct (one of the law's ``outputs``)."""
        if field not in self.output_fields:
            raise ModelError(
                f"output: {field!r} — the {self.entry.display} law outputs {', '.join(self.output_fields)}"
            )
        return np.array(list(getattr(self._output, field)), dtype=float)

    def __getattr__(self, name: str) -> np.ndarray:
        # The law's further outputs read as the Python reference's attributes (``desired_force``).
        if name in self.__dict__.get("output_fields", ()):
            return self.output(name)
        raise AttributeError(name)

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
        The compiled module; ``.law(name)`` gives a controller.

    Examples
    --------
    >>> law = compile_controllers(artifact, "float").law("siso")  # doctest: +SKIP
    >>> law.step(measurements)  # doctest: +SKIP
    """
    return Controllers(artifact, real, prefix, flags)
