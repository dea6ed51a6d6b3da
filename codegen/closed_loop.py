"""The study's closed loop compiled: the plant kernel stepped from C with a generated law.

An ensemble sample runs the study's semi-active laws thousands of times; the Python loop
(``design.plant.loop.simulate``) crosses into Python at every controller sample — measure, the
law, the command — which costs several times the plant itself. Here one C call runs a whole
run: ``closed_loop.c.j2`` renders ``<prefix>_siso_closed_loop`` and ``<prefix>_clqg_closed_loop``,
which step the fixed-step plant kernel (``plant_kernel.c``, compiled with the flags of its
Python use) and call the generated law (double build, the firmware's source) every sample, in
the statements and order of the Python loop. The Python loop with the Python reference laws
stays the specification: both give the same trajectory bit for bit (``tests/test_closed_loop.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from smartjoint.codegen import build, generate, rendering
from smartjoint.common import law_registry, native, package_data
from smartjoint.common.errors import ModelError
from smartjoint.design.control import artifact as artifacts
from smartjoint.design.control.runs import (
    PLANT_STEPS_PER_SAMPLE,
    PULSE_DURATION,
    LaggingAmplifiers,
    Run,
    StudySetup,
    semi_active_run,
)
from smartjoint.design.plant import loop, schemes
from smartjoint.design.plant.interface import Controller
from smartjoint.design.plant.kernel import PlantRun

LAWS = {law.display: law.name for law in law_registry.LAWS.values()}  # the study's run names → the generated laws


@dataclass(frozen=True)
class _Schedule:
    """What the loop's checks ask of a controller: its sample time (the law itself runs in C)."""

    sample_time: float


def render(artifact: artifacts.ControllerArtifact, prefix: str = "smartjoint") -> dict[str, str]:
    """The files of the compiled closed loop: the laws (double), the plant kernel and the loop.

    Parameters
    ----------
    artifact : ControllerArtifact
    prefix : str
        The prefix of the generated identifiers.

    Returns
    -------
    dict of str to str
        File name → text.
    """
    laws = generate.render(artifact, "double", prefix)
    names = (f"{prefix}_types.h", *(f"{prefix}_{law}.{kind}" for law in LAWS.values() for kind in "hc"))
    files = {name: laws[name] for name in names}
    for name in ("plant_kernel.h", "plant_kernel.c"):
        files[name] = package_data.path("smartjoint.design.plant", name).read_text()
    context = {
        "prefix": prefix,
        "PREFIX": prefix.upper(),
        "laws": list(LAWS.values()),
        "inputs": {law.name: law.inputs for law in law_registry.LAWS.values()},
        "banner": rendering.banner(artifact.artifact_sha256, "double"),
    }
    env = rendering.environment()
    for kind in "hc":
        files[f"{prefix}_closed_loop.{kind}"] = env.get_template(f"closed_loop.{kind}.j2").render(context)
    return files


class CompiledLoop:
    """The compiled closed loop of one artefact (built on first use, cached per machine); a
    ``design.control.interconnection.ClosedLoop``.

    Parameters
    ----------
    artifact : ControllerArtifact
        The laws; its normal-force limits and ε are those of the runs.
    prefix : str
        The prefix of the generated identifiers.
    """

    def __init__(self, artifact: artifacts.ControllerArtifact, prefix: str = "smartjoint"):
        self.artifact, self.prefix = artifact, prefix
        files = render(artifact, prefix)
        sources = (*(f"{prefix}_{law}.c" for law in LAWS.values()), f"{prefix}_closed_loop.c", "plant_kernel.c")
        _, module = build.load(
            "closed_loop",
            files,
            f"{prefix}_closed_loop.h",
            sources,
            source_flags={"plant_kernel.c": native.FLAGS},  # as the Python loop's plant kernel
        )
        self.ffi, self.lib = module.ffi, module.lib

    def _pointer(self, kind: str, cdata, owner):
        """``cdata`` of the plant kernel's cffi module as a pointer of this module."""
        return self.ffi.cast(kind, owner.cast("uintptr_t", cdata))

    def run(self, s: StudySetup, law: str) -> tuple[Run, int]:
        """One semi-active run of the study, as ``runs.run_semi_active`` with the artefact's law.

        Parameters
        ----------
        s : StudySetup
            The study; its sample time, limits and joints those of the artefact.
        law : str
            A law of the registry, by its name or its display name (the study's run).

        Returns
        -------
        tuple of (Run, int)
            The run and the number of controller samples in the safe state.

        Raises
        ------
        ModelError
            An unknown law, a set-up the artefact does not fit, a command the plant cannot take or
            a joint solve that fails, each in one line as the Python loop says it.
        """
        entry = law_registry.law(law)
        self._check_fits(s)
        r, result = self._execute(s, f"{entry.c_name(self.prefix)}_closed_loop")
        return semi_active_run(s, entry.display, r), int(result.safe_state_samples)

    def run_passive(self, s: StudySetup, name: str, normal_forces) -> Run:
        """A passive run of the study, as ``runs.run_passive``: F_N^max during the pulse, then
        ``normal_forces`` (one for all joints or one per joint).

        Parameters
        ----------
        s : StudySetup
        name : str
            The run's name.
        normal_forces : float or array_like
            F_N [N] after the pulse.

        Returns
        -------
        Run
        """
        forces = np.ascontiguousarray(np.broadcast_to(np.asarray(normal_forces, dtype=float), (len(s.laws),)))
        r, _ = self._execute(
            s, f"{self.prefix}_passive_closed_loop", self.ffi.cast("double *", self.ffi.from_buffer(forces))
        )
        return semi_active_run(s, name, r)

    def _execute(self, s: StudySetup, function: str, *extra):
        """Run the C loop ``function`` on the study's fixed-step plant; the simulation and the
        loop's result struct."""
        prepared = loop.prepare(
            schemes.scheme("fixed"),
            PlantRun(
                s.plant,
                s.laws,
                cast(Controller, _Schedule(s.sample_time)),
                s.duration,
                s.plant_step,
                None,
                PLANT_STEPS_PER_SAMPLE,
                "c",
                False,
                None,
                s.sample_steps,
            ),
            s.pulse(),
        )
        kernel: Any = prepared.kernel  # the fixed-step scheme's C kernel (backend "c"): its structs
        hold = np.ascontiguousarray(s.normal_force_max, dtype=float)
        w = np.ascontiguousarray(prepared.w, dtype=float)
        ffi = self.ffi
        noise, schedule, samples, kept = self._sample_inputs(s)
        settings = ffi.new(
            f"{self.prefix}_loop *",
            {
                "steps": prepared.run.steps,
                "ratio": prepared.ratio,
                "record_every": PLANT_STEPS_PER_SAMPLE,
                "step": s.plant_step,
                "hold_until": PULSE_DURATION,
                "hold_normal_force": ffi.cast("double *", ffi.from_buffer(hold)),
                "disturbance": ffi.cast("double *", ffi.from_buffer(w)),
                "sensor_noise": noise,
                "sample_steps": schedule,
                "samples": samples,
                "lagging": int(s.amplifier_lag is not None),
                "amplifier_gain": 0.0
                if s.amplifier_lag is None
                else LaggingAmplifiers.gain_of(s.sample_time, s.amplifier_lag),
            },
        )
        result = ffi.new(f"{self.prefix}_loop_result *")
        plant, state, record, owner = kernel.structs()
        getattr(self.lib, function)(
            self._pointer("sj_plant *", plant, owner),
            self._pointer("sj_state *", state, owner),
            self._pointer("sj_record *", record, owner),
            settings,
            *extra,
            result,
        )
        self._raise_failure(result, kernel, s)
        return loop.result(kernel.recorder, s.plant, s.plant_step, PLANT_STEPS_PER_SAMPLE), result

    def _sample_inputs(self, s: StudySetup):
        """The per-sample inputs as C pointers: the sensor noise, the jittered schedule and its
        length (NULL, NULL, 0 without them) and the arrays they point into (kept by the caller)."""
        ffi = self.ffi
        noise, schedule, samples, kept = ffi.NULL, ffi.NULL, 0, []
        rows = s.samples
        if s.sample_steps is not None:  # checked by loop.prepare: from 0, increasing, within the run
            steps = np.ascontiguousarray(s.sample_steps, dtype=np.dtype("l"))  # C long
            schedule, samples, rows = ffi.cast("long *", ffi.from_buffer(steps)), steps.size, steps.size
            kept.append(steps)
        if s.sensor_noise is not None:
            values = np.ascontiguousarray(s.sensor_noise, dtype=float)
            if values.shape[0] < rows or values.shape[1:] != (s.plant.velocity_output.shape[0],):
                raise ModelError(
                    f"sensor_noise: {values.shape} values — need {rows} rows (samples) of "
                    f"{s.plant.velocity_output.shape[0]} (sensors)"
                )
            noise = ffi.cast("double *", ffi.from_buffer(values))
            kept.append(values)
        return noise, schedule, samples, kept

    def _check_fits(self, s: StudySetup) -> None:
        """The set-up and the artefact agree on the sample time, joints, sensors and limits."""
        a = self.artifact
        if s.sample_time != a.sample_time:
            raise ModelError(f"sample_time: {s.sample_time!r} s — the artefact's law runs at {a.sample_time!r} s")
        shapes = {
            "joints": (len(s.laws), len(a.joint_names)),
            "sensors": (s.plant.velocity_output.shape[0], len(a.sensor_names)),
        }
        for field, (got, want) in shapes.items():
            if got != want:
                raise ModelError(f"{field}: the study has {got}, the artefact {want}")
        for field in ("normal_force_min", "normal_force_max"):
            if not np.array_equal(getattr(s, field), np.asarray(getattr(a, field), dtype=float)):
                raise ModelError(f"{field}: the study's {getattr(s, field).tolist()} are not the artefact's")

    @staticmethod
    def _raise_failure(result, kernel, s: StudySetup) -> None:
        """The Python loop's errors for a failed run."""
        if result.failed_sample >= 0:
            t = result.failed_sample * s.sample_time
            raise ModelError(f"controller returned normal forces that are not all finite and >= 0 at t = {t:.6g} s")
        if result.failed_step >= 0:
            step, residual = kernel.failure()
            raise ModelError(
                f"joint solve did not converge at step {step:.3g} s (residual {residual:.3g}); reduce the step"
            )


_BUILT: dict[str, CompiledLoop] = {}  # per process: one module per artefact


class CompiledLoops:
    """``loops(artifact)``: the :class:`CompiledLoop` of an artefact, built once per process (an
    ensemble's workers each load it from the machine's build cache). Picklable: it holds nothing."""

    def __call__(self, artifact: artifacts.ControllerArtifact) -> CompiledLoop:
        key = artifact.artifact_sha256
        if key not in _BUILT:
            _BUILT[key] = CompiledLoop(artifact)
        return _BUILT[key]


__all__ = ["LAWS", "CompiledLoop", "CompiledLoops", "render"]
