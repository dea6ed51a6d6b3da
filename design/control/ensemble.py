"""One sample of a sweep: the closed-loop study's laws on a perturbed plant, as table rows.

What every sample shares (:class:`EnsembleBase`: the design model, the LQG gains, the nominal
friction laws, the study's set-up) is built once (:func:`build_base`) and handed to the workers;
a sample changes only what it draws — the plant's modal frequencies and damping, each joint's
LuGre parameters, the pulse amplitude — and the design variables of its grid point (ε, F_N^min,
F_N^max). The controllers stay those designed on the nominal model, as on the real structure.

Rows (:func:`run_batch`): one per sample, grid point and law, with the inputs and the metrics of
``study.metrics`` (Eq. 32's E(t_e), e(t_e), RMS and peak tip deflection, settling time, control
power) and the controller samples spent in the safe state. Deterministic: a row depends only on
the base, the grid point and the sample's inputs.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.design.control import tuning
from smartjoint.design.control.artifact import ControllerArtifact
from smartjoint.design.control.artifact_building import from_design
from smartjoint.design.control.best_passive import best_passive
from smartjoint.design.control.interconnection import ClosedLoop, PythonLoop
from smartjoint.design.control.laws import check_limits
from smartjoint.design.control.lqg import LqgDesign
from smartjoint.design.control.runs import (
    PLANT_STEPS_PER_SAMPLE,
    Run,
    StudySetup,
    run_active,
    setup,
)
from smartjoint.design.control.study import design_model, lqg_for, metrics, sensor_quantities
from smartjoint.design.structure.modal import ModalModel

# The metric columns of every row, in order (None in ``study.metrics`` becomes NaN).
METRICS = (
    "energy_end",
    "energy_end_relative",
    "energy_measure",
    "tip_rms_total",
    "tip_peak",
    "settling_time",
    "control_power",
    "safe_state_samples",
    "passive_normal_force",  # the best passive settings' constant F_N [N]; NaN for the other laws
)
# The best passive settings (best_passive.py): law → the figure their constant F_N minimises.
BEST_PASSIVE = {"best passive E": "energy_measure", "best passive e": "energy_end"}
KEYS = ("sample", "point", "law")
FAILED = -1  # safe_state_samples of a run that could not finish (its metrics NaN)


@dataclass(frozen=True)
class EnsembleBase:
    """What every sample shares: the nominal study set-up (its ``model`` the design model the
    controllers are designed on), the LQG, ε of the design, the laws to run and the columns."""

    setup: StudySetup  # of the first grid point
    setups: tuple[StudySetup, ...]  # at each grid point (its placement's design where the grid sets one)
    lqg: LqgDesign  # of the design's own weights
    lqgs: tuple[LqgDesign, ...]  # at each grid point (its control weight where the grid sets one)
    artifacts: tuple[ControllerArtifact, ...]  # the laws at each grid point, as the firmware gets them
    laws: tuple[str, ...]
    seed: int  # the sweep's: a sample's sensor noise is drawn from (seed, sample) alone
    joint_names: tuple[str, ...]
    quantities: tuple[str, ...]
    grid_columns: tuple[str, ...]
    input_columns: tuple[str, ...]

    def columns(self) -> tuple[str, ...]:
        """Every column of a row, in order."""
        return (*KEYS, *self.grid_columns, *self.input_columns, *METRICS)


def build_base(sweep, design, input_columns, progress=print, placements=(), base_model=None) -> EnsembleBase:
    """The design model, LQG and set-up every sample shares (built once, then shared).

    Parameters
    ----------
    sweep : Sweep
        The sweep (its laws and grid).
    design : Design
        The base design (updated, its study duration already the sweep's).
    input_columns : sequence of str
        The sampled inputs' columns (``sweep_sampling.input_columns``).
    progress : callable
        Receives progress lines.
    placements : sequence of Design
        ``grid.placement``'s designs (prepared like ``design``), indexed by the points' value.
    base_model : ModalModel, optional
        The design model of ``design`` where the caller has built it (``study.design_model``).

    Returns
    -------
    EnsembleBase

    Raises
    ------
    ModelError
        When a law is run without a setting it needs (the SISO ε) in the grid or the design's
        [control], or a placement's joints or sensors are not the design's.
    """
    for law in law_registry.LAWS.values():  # a law the sweep runs needs every setting it has no default for
        for setting in law.settings:
            key = setting.design_key(law.name)
            if law.display in sweep.laws and setting.default is None and key not in sweep.grid:
                if setting.key not in tuning.given(design, law):
                    raise ModelError(
                        f"{sweep.source}: the {law.display} law needs {key} — give grid.{key} or the design's "
                        f"control.{key} (`smartjoint design` tunes it)"
                    )
    candidates = [design, *placements]  # the base design, then grid.placement's (point value + 1)
    built: dict[int, tuple] = {}
    setups, lqgs, artifacts = [], [], []
    for point in sweep.points():  # in the driver, before any task: every point checked and built
        k = int(point["placement"]) + 1 if "placement" in point else 0
        if k not in built:
            built[k] = _candidate(sweep, candidates[k], design, input_columns, progress, base_model if k == 0 else None)
        chosen, model, shared, lqg = built[k]
        point_limits(shared, point)
        setups.append(shared)
        lqgs.append(point_lqg(chosen, model, lqg, point))
        artifacts.append(point_artifact(chosen, model, lqgs[-1], point))
    first, model, _, lqg = next(iter(built.values()))
    return EnsembleBase(
        setup=setups[0],
        setups=tuple(setups),
        lqg=lqg,
        lqgs=tuple(lqgs),
        artifacts=tuple(artifacts),
        laws=tuple(sweep.laws),
        seed=int(sweep.seed),
        joint_names=tuple(j.name for j in design.joints),
        quantities=tuple(sensor_quantities(first, model)),
        grid_columns=tuple(sweep.grid),
        input_columns=tuple(input_columns),
    )


def _candidate(sweep, chosen, design, input_columns, progress, model=None):
    """One design of the sweep (the base or a placement): its design model, study set-up and LQG,
    its joints and sensors checked against the base design's."""
    for what in ("joints", "sensors"):
        names, base = [x.name for x in getattr(chosen, what)], [x.name for x in getattr(design, what)]
        if names != base:
            raise ModelError(
                f"{sweep.source}: grid.placement: {chosen.source} has {what} {names} — a placement must keep the "
                f"design's {base} (the rows share their columns)"
            )
    model = model if model is not None else design_model(chosen, progress)
    inputs = model.disturbance_input.shape[1]
    if "pulse_direction" in input_columns and inputs < 2:
        raise ModelError(
            f"{sweep.source}: uncertain.pulse_direction: the design has {inputs} disturbance input — the angle "
            "needs two (the plane of the first two)"
        )
    return chosen, model, setup(chosen, model), lqg_for(chosen, model)


def _point_design(design, point: dict[str, float]):
    """The design with the grid point's design variables in its [control] table."""
    names = ("normal_force_min", "normal_force_max", "control_weight")
    changed = {k: point[k] for k in names if k in point}
    if changed:
        design = dataclasses.replace(design, control=dataclasses.replace(design.control, **changed))
    return tuning.with_settings(design, {k: point[k] for k in tuning.design_keys() if k in point})


def point_lqg(design, model: ModalModel, lqg: LqgDesign, point: dict[str, float]) -> LqgDesign:
    """The LQG at a grid point: ``lqg`` (the design's), or designed anew with the point's control
    weight ρ (Eq. 33) on the same model."""
    return lqg if "control_weight" not in point else lqg_for(_point_design(design, point), model)


def _held_open(design, values: dict, setup, progress) -> tuple[dict, None]:
    """A law's settings with each open one held at 1 (``tuning.tuned``'s ``tune``)."""
    return {key: 1.0 if value is None else value for key, value in values.items()}, None


def point_artifact(design, model: ModalModel, lqg: LqgDesign, point: dict[str, float]) -> ControllerArtifact:
    """The controller artefact at a grid point: the design's with the point's ε and normal-force
    limits (and the plausibility ranges the design derives from them).

    Parameters
    ----------
    design : Design
    model : ModalModel
        The design model the LQG was designed on.
    lqg : LqgDesign
        The point's (``point_lqg``).
    point : dict
        The grid point's design variables.

    Returns
    -------
    ControllerArtifact
    """
    design = _point_design(design, point)
    # A setting left open (the SISO ε, in a sweep without that law or with it in the grid: build_base
    # checks) is held at 1 in the artefact, which nothing runs.
    settings = {law.name: tuning.tuned(law, design, tune=_held_open).settings for law in law_registry.LAWS.values()}
    return from_design(design, model, lqg, settings)


def perturbed_plant(model: ModalModel, inputs: dict[str, float]) -> ModalModel:
    """The design model with the sample's modal frequency scale and damping (itself when the
    sample changes neither). The damping is the structure's: quasi-static Krylov corrections
    (critically damped, `reduction.quasi_static_corrections`) keep theirs, as they stand for
    residual flexibility, not a mode whose damping could be measured."""
    scale = inputs.get("modal_frequency_scale")
    damping = inputs.get("modal_damping")
    if scale is None and damping is None:
        return model
    return dataclasses.replace(
        model,
        omega=model.omega * (1.0 if scale is None else scale),
        damping=model.damping if damping is None else np.where(model.damping >= 1.0, model.damping, damping),
    )


def point_limits(s: StudySetup, point: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """F_N^min and F_N^max per joint at a grid point: the point's where it sets them, else the
    design's; checked (0 <= F_N^min <= F_N^max)."""
    low = np.full_like(s.normal_force_min, point.get("normal_force_min", 0.0))
    high = np.full_like(s.normal_force_max, point.get("normal_force_max", 0.0))
    low = low if "normal_force_min" in point else s.normal_force_min
    high = high if "normal_force_max" in point else s.normal_force_max
    check_limits(low, high)
    return low, high


def sensor_noise(base: EnsembleBase, sample: int, s: StudySetup, deviation: float) -> np.ndarray:
    """The white noise on the tip sensors of sample ``sample``: one row per controller sample,
    standard normal times ``deviation``, from the sweep's seed and the sample's number alone
    (``SeedSequence(seed, spawn_key=(sample, 1))``, apart from the inputs' stream)."""
    rng = np.random.default_rng(np.random.SeedSequence(base.seed, spawn_key=(sample, 1)))
    return deviation * rng.standard_normal((s.samples, s.plant.velocity_output.shape[0]))


def sample_schedule(base: EnsembleBase, sample: int, s: StudySetup, deviation: float) -> np.ndarray:
    """The plant step of each controller sample of sample ``sample`` with the sampling instant
    jittered: k·ratio plus a normal offset of standard deviation ``deviation`` [s], rounded to
    whole plant steps and clipped to ±(ratio − 1)//2 steps so the samples stay in order; the first
    at 0. From the sweep's seed and the sample's number alone (``spawn_key=(sample, 2)``)."""
    ratio, count = PLANT_STEPS_PER_SAMPLE, s.samples
    rng = np.random.default_rng(np.random.SeedSequence(base.seed, spawn_key=(sample, 2)))
    widest = (ratio - 1) // 2
    offsets = np.clip(np.rint(deviation / s.plant_step * rng.standard_normal(count)), -widest, widest)
    offsets[0] = 0.0
    return np.minimum(np.arange(count) * ratio + offsets.astype(np.int64), s.plant_steps - 1)


def sample_setup(
    base: EnsembleBase, point: dict[str, float], inputs: dict[str, float], sample: int = 0, index: int = 0
) -> StudySetup:
    """The study set-up of one sample at grid point ``index``: its placement's plant perturbed, the
    friction, the point's normal-force limits, the sample's pulse amplitude and direction, sensor
    noise, amplifier lag and sampling instants."""
    s = base.setups[index]
    laws = []
    for joint, law in zip(base.joint_names, s.laws):
        factors: dict[str, float] = {}  # the physical factor times the identification's, per parameter
        for name, value in inputs.items():
            if name.startswith((f"friction.{joint}.", f"identification.{joint}.")):
                parameter = name.rpartition(".")[2]
                factors[parameter] = factors.get(parameter, 1.0) * value
        laws.append(dataclasses.replace(law, **{p: getattr(law, p) * f for p, f in factors.items()}))
    low, high = point_limits(s, point)
    out = dataclasses.replace(
        s,
        plant=perturbed_plant(s.model, inputs),
        laws=laws,
        normal_force_min=low,
        normal_force_max=high,
        pulse_amplitude=float(inputs.get("pulse_amplitude", s.pulse_amplitude)),
        pulse_direction=inputs.get("pulse_direction", s.pulse_direction),
        amplifier_lag=inputs.get("amplifier_lag", s.amplifier_lag),
    )
    if "sensor_noise" in inputs:
        out = dataclasses.replace(out, sensor_noise=sensor_noise(base, sample, out, inputs["sensor_noise"]))
    if "sample_jitter" in inputs:
        out = dataclasses.replace(out, sample_steps=sample_schedule(base, sample, out, inputs["sample_jitter"]))
    return out


def drawn_setups(design, s: StudySetup, samples: int, seed: int) -> list[StudySetup]:
    """``samples`` plants drawn from the design's physical spread (its ``[uncertainty]`` and the
    defaults, ``physical_spread``; Latin hypercube of ``seed``) around the study ``s``: what a law
    tuned on an ensemble is tuned on, without a sweep's grid, laws or output.

    Parameters
    ----------
    design : Design
        Its joints and ``uncertainty``.
    s : StudySetup
        The nominal study (its ``model`` the design model).
    samples, seed : int

    Returns
    -------
    list of StudySetup
        One per sample, as a sweep's sample of the same inputs and seed.
    """
    from smartjoint.design.control.physical_spread import physical_spread  # the spread's defaults
    from smartjoint.design.control.sweep_sampling import column_distributions, inverse, unit_samples

    joints = tuple(joint.name for joint in design.joints)
    inputs = [entry.input for entry in physical_spread(design, float(s.pulse_amplitude))]
    columns = column_distributions(inputs, joints)
    unit = unit_samples("latin-hypercube", samples, len(columns), seed)
    values = np.column_stack([inverse(d, unit[:, k]) for k, (_, d) in enumerate(columns)])
    base = EnsembleBase(
        setup=s, setups=(s,), lqg=None, lqgs=(), artifacts=(), laws=(), seed=int(seed),  # type: ignore[arg-type]
        joint_names=joints, quantities=(), grid_columns=(), input_columns=tuple(c for c, _ in columns),
    )  # fmt: skip
    names = [column for column, _ in columns]
    return [sample_setup(base, {}, dict(zip(names, map(float, row))), k) for k, row in enumerate(values)]


def _run_law(
    base: EnsembleBase, s: StudySetup, law: str, index: int, point: dict, compiled, cache: dict
) -> tuple[Run, int, float]:
    """One law's run, its safe-state sample count and its constant F_N (best passive settings):
    the semi-active and passive laws through ``compiled(artifact)`` where given, else the Python
    loop with the reference laws (the same numbers). ``cache``: the sample's constant-force runs."""
    artifact = base.artifacts[index]
    closed: ClosedLoop = compiled(artifact) if compiled is not None else PythonLoop(artifact)
    passive = closed.run_passive
    if law == "passive F_min":
        return passive(s, law, s.normal_force_min), 0, math.nan
    if law == "passive F_max":
        return passive(s, law, s.normal_force_max), 0, math.nan
    if law in BEST_PASSIVE:
        run, force = best_passive(s, law, BEST_PASSIVE[law], passive, cache)
        return run, 0, force
    if law == "active LQG":
        # the point's gains, designed on the nominal model, on the perturbed plant
        return run_active(dataclasses.replace(s, model=s.plant), base.lqgs[index]), 0, math.nan
    for key in tuning.design_keys():  # the point's settings are its artefact's
        if key in point:
            found = tuning.setting_of(key)
            assert found is not None  # a key of design_keys()
            entry, setting = found
            held = getattr(artifact, dict(entry.artifact)[setting.key])
            if not np.all(np.asarray(held) == point[key]):
                raise ModelError(
                    f"grid point {index}: {key} = {point[key]!r}, its artefact's {np.asarray(held).tolist()}"
                )
    return (*closed.run(s, law), math.nan)


def _number(value) -> float:
    return math.nan if value is None else float(value)


def run_sample(
    base: EnsembleBase, sample: int, index: int, point: dict[str, float], inputs: dict[str, float], compiled=None
):
    """The rows of one sample at one grid point, one per law (the base's order).

    Parameters
    ----------
    base : EnsembleBase
    sample, index : int
        The sample's number and the grid point's.
    point : dict
        The grid point's design variables.
    inputs : dict
        The sample's uncertain inputs by column.
    compiled : callable, optional
        ``compiled(artifact)`` gives the compiled closed loop of an artefact
        (``codegen.closed_loop.CompiledLoops``); None runs the Python reference laws. Both give
        the same rows.

    Returns
    -------
    list of dict
        Rows with the columns of ``base.columns()``.
    """
    s = sample_setup(base, point, inputs, sample, index)
    cache: dict = {}
    runs: list = []
    for law in base.laws:
        try:
            runs.append((law, *_run_law(base, s, law, index, point, compiled, cache)))
        except ModelError:  # one plant the law cannot finish (a joint solve): a row of NaN, not the sweep
            runs.append((law, None, FAILED, math.nan))
    reference = next((run for law, run, _, _ in runs if law == "passive F_max"), None)
    rows = []
    for law, run, safe, force in runs:
        if run is None:
            figures = {**dict.fromkeys(METRICS, math.nan), "safe_state_samples": FAILED}
            rows.append({"sample": sample, "point": index, "law": law, **point, **inputs, **figures})
            continue
        m = metrics(run, reference if reference is not None else run, base.quantities)
        figures = {
            "energy_end": m["energy_end"],
            "energy_end_relative": m["energy_end_relative"] if reference is not None else math.nan,
            "energy_measure": m["energy_measure"],
            "tip_rms_total": _number(m["tip_rms_total"]),
            "tip_peak": math.nan if m["tip_peak"] is None else max(m["tip_peak"]),
            "settling_time": _number(m["settling_time"]),
            "control_power": m["control_power"],
            "safe_state_samples": safe,
            "passive_normal_force": force,
        }
        rows.append({"sample": sample, "point": index, "law": law, **point, **inputs, **figures})
    return rows


def run_batch(base: EnsembleBase, points, samples, values, compiled=None) -> list[dict]:
    """The rows of a batch: every sample of ``samples`` at every grid point (the task a worker runs).

    Parameters
    ----------
    base : EnsembleBase
    points : list of dict
        The grid points (``Sweep.points``; one empty point without a grid).
    samples : sequence of int
        The batch's sample numbers.
    values : array_like
        The batch's uncertain inputs, one row per sample in ``base.input_columns`` order.
    compiled : callable, optional
        As in :func:`run_sample`.

    Returns
    -------
    list of dict
        Sample by sample, point by point, law by law.
    """
    rows = []
    for sample, row in zip(samples, np.asarray(values, dtype=float).reshape(len(samples), -1)):
        inputs = {name: float(v) for name, v in zip(base.input_columns, row)}
        for index, point in enumerate(points):
            rows.extend(run_sample(base, int(sample), index, point, inputs, compiled))
    return rows


__all__ = [
    "BEST_PASSIVE",
    "FAILED",
    "KEYS",
    "METRICS",
    "EnsembleBase",
    "build_base",
    "perturbed_plant",
    "point_artifact",
    "point_lqg",
    "point_limits",
    "run_batch",
    "run_sample",
    "sample_schedule",
    "sample_setup",
    "sensor_noise",
]
