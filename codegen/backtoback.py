"""Back-to-back check (SIL against MIL) of the generated controllers on the closed-loop study.

For the SISO law and the clipped LQG: the Python reference runs the study (paper Section 6) and
every measurement it sees is recorded; the compiled C replays exactly those inputs (double and
float build) and its outputs are compared sample by sample. Then the float build runs in the
loop itself, and its E(t_e) (Eq. 32) is compared with the reference's.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from smartjoint.codegen import controllers
from smartjoint.common import law_registry
from smartjoint.design.control import artifact as artifacts
from smartjoint.design.control import study as closed_loop


class Recorder:
    """Wraps a controller and keeps (measurements, output) of every sample.

    Parameters
    ----------
    inner : controller
        Any controller of the plant interface (``reset``, ``step``, ``sample_time``).
    """

    def __init__(self, inner):
        self.inner, self.sample_time, self.log = inner, inner.sample_time, []

    def reset(self) -> None:
        self.inner.reset()
        self.log = []

    def step(self, measurements):
        """Step the wrapped controller and keep what it saw and answered."""
        out = self.inner.step(measurements)
        self.log.append((measurements, np.array(out, dtype=float)))
        return out


def back_to_back(
    setup: closed_loop.StudySetup,
    artifact: artifacts.ControllerArtifact,
    progress=print,
    study: closed_loop.Study | None = None,
) -> dict:
    """Back-to-back check of the generated controllers on the closed-loop study (SIL vs MIL).

    Parameters
    ----------
    setup : study.StudySetup
        The closed-loop study (paper Section 6).
    artifact : ControllerArtifact
        The controller design artefact.
    progress : callable
        ``progress(message)`` hears what runs.
    study : study.Study, optional
        The study's passive and active runs; with it, also the paper's orderings with the float
        build in the loop.

    Returns
    -------
    dict
        Per law (``"SISO"``, ``"cLQG"``): samples compared, max |ΔF_N| of the double and float
        replays, the number of bit-identical samples, and E(t_e) (Eq. 32) of the float build in
        the loop against the reference's; with ``study``, ``float_orderings``.
    """
    builds = {real: controllers.compile_controllers(artifact, real) for real in ("double", "float")}
    out: dict[str, dict] = {}
    for entry in law_registry.LAWS.values():
        name = entry.display
        progress(f"      {name}: reference run, replay through the double and float builds, float build in the loop")
        recorder = Recorder(entry.python_reference(artifact))
        reference = closed_loop.run_semi_active(setup, name, recorder)
        figures: dict = {"samples": len(recorder.log), "energy_measure_reference": reference.energy_measure()}
        for real in ("double", "float"):
            law = builds[real].law(entry.name)
            law.reset()
            deviations = []
            identical = 0
            for measurements, expected in recorder.log:
                got = law.step(measurements)
                deviations.append(float(np.max(np.abs(got - expected))))
                identical += int(got.tobytes() == expected.tobytes())
            figures[f"{real}_max_deviation"] = max(deviations)
            figures[f"{real}_identical_samples"] = identical
        in_loop = closed_loop.run_semi_active(setup, name, builds["float"].law(entry.name))
        figures["energy_measure_float"] = in_loop.energy_measure()
        figures["energy_measure_float_relative_error"] = in_loop.energy_measure() / reference.energy_measure() - 1.0
        if study is not None:
            in_loop.metrics = closed_loop.metrics(in_loop, study.run("passive F_max"), study.sensor_quantities)
            figures["float_run"] = in_loop
        out[name] = figures
    if study is not None:
        laws = [law.display for law in law_registry.LAWS.values()]
        runs = [study.run(r.name) if r.name not in laws else out[r.name].pop("float_run") for r in study.runs]
        float_study = dataclasses.replace(study, runs=runs)
        out["float_orderings"] = float_study.orderings()
    return out


def markdown(figures: dict, artifact: artifacts.ControllerArtifact) -> str:
    """The report section of a back-to-back check.

    Parameters
    ----------
    figures : dict
        What :func:`back_to_back` returned.
    artifact : ControllerArtifact
        The artefact (its normal-force span scales the float deviations).

    Returns
    -------
    str
        A Markdown section with one table row per law.
    """
    span = float(np.min(artifact.normal_force_max - artifact.normal_force_min))
    lines = [
        "## Generated firmware: back-to-back on the study (SIL vs MIL)",
        "",
        "The C of `firmware/` (`smartjoint codegen`) fed with exactly the measurements the Python reference "
        "controllers saw in the closed-loop study; then the float build in the loop.",
        "",
        "| law | samples | double: bit-identical samples | double max abs(ΔF_N) [N] | float max abs(ΔF_N) [N] "
        "(of the F_N span) | E(t_e) float in the loop vs reference |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name, f in figures.items():
        if name == "float_orderings":
            continue
        lines.append(
            f"| {name} | {f['samples']} | {f['double_identical_samples']} | {f['double_max_deviation']:.3g} | "
            f"{f['float_max_deviation']:.3g} ({f['float_max_deviation'] / span:.1e}) | "
            f"{100 * f['energy_measure_float_relative_error']:+.2f} % |"
        )
    orderings = figures.get("float_orderings")
    if orderings is not None:
        # None: an ordering this design cannot judge (RMS tip deflection without a displacement sensor).
        judged = {k: v for k, v in orderings.items() if not k.startswith("power_ratio_") and v is not None}
        held = all(judged.values())
        unjudged = [k for k, v in orderings.items() if v is None]
        failed = [k for k, v in judged.items() if not v]
        lines += [
            "",
            f"The paper's orderings with the float build in the loop: {'all hold' if held else '**not all hold**'} "
            f"(hold: {', '.join(k for k, v in orderings.items() if v is True) or 'none'}"
            + (f"; fail: {', '.join(failed)}" if failed else "")
            + ")"
            + (f"; not judged without a displacement sensor: {', '.join(unjudged)}." if unjudged else "."),
        ]
    return "\n".join(lines) + "\n"
