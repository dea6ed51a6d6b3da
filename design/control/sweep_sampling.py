"""The samples of a sweep: points of the unit cube from the sweep's sampler and seed, mapped
through each uncertain input's (truncated) inverse distribution function.

Deterministic: sample i depends only on the seed and i (``random``: the i-th child of the seed's
``numpy.random.SeedSequence``), or on the seed, i and the sample count (``latin-hypercube`` and
``sobol`` of ``scipy.stats.qmc`` with the seed as their generator) — never on how many workers
run the sweep nor in which order.
"""

from __future__ import annotations

import numpy as np
from scipy import stats
from scipy.stats import qmc

from smartjoint.common.errors import ModelError
from smartjoint.design.control.sweep_file import Distribution, Sweep

PER_JOINT = ("friction.", "identification.")  # factors drawn for every joint: <prefix><joint>.<parameter>


def column_distributions(inputs, joint_names) -> list[tuple[str, Distribution]]:
    """Each sampled column and its distribution: the scalar inputs as named, each factor of
    ``friction.<parameter>`` and ``identification.<parameter>`` once per joint
    (``friction.A1.sigma0``), where a joint's own ``friction.<joint>.<parameter>`` replaces the
    common one; in the inputs' order.

    Parameters
    ----------
    inputs : sequence of UncertainInput
    joint_names : sequence of str
        The design's joints, in design order.

    Returns
    -------
    list of (str, Distribution)
    """
    own = {u.name: u.distribution for u in inputs if u.name.startswith("friction.") and u.name.count(".") == 2}
    common = {u.name for u in inputs if u.name.count(".") == 1}
    columns: list[tuple[str, Distribution]] = []
    for uncertain in inputs:
        prefix = next((p for p in PER_JOINT if uncertain.name.startswith(p)), None)
        if prefix is None:
            columns.append((uncertain.name, uncertain.distribution))
        elif uncertain.name in common:
            parameter = uncertain.name.removeprefix(prefix)
            for joint in joint_names:
                column = f"{prefix}{joint}.{parameter}"
                replaced = own.get(column) if prefix == "friction." else None
                columns.append((column, replaced or uncertain.distribution))
        elif f"friction.{uncertain.name.rpartition('.')[2]}" not in common:  # a joint's own, no common one
            columns.append((uncertain.name, uncertain.distribution))
    return columns


def input_columns(sweep: Sweep, joint_names) -> list[str]:
    """The names of the sampled columns (:func:`column_distributions`).

    Parameters
    ----------
    sweep : Sweep
    joint_names : sequence of str
        The design's joints, in design order.

    Returns
    -------
    list of str
    """
    return [column for column, _ in column_distributions(sweep.inputs, joint_names)]


def unit_samples(sampler: str, samples: int, dimensions: int, seed: int) -> np.ndarray:
    """Points of the open unit cube, one row per sample.

    Parameters
    ----------
    sampler : str
        ``random``, ``latin-hypercube`` or ``sobol`` (scrambled; ``samples`` a power of two).
    samples, dimensions : int
    seed : int

    Returns
    -------
    ndarray
        (samples, dimensions), in [0, 1).
    """
    if dimensions == 0:
        return np.zeros((samples, 0))
    if sampler == "random":
        return np.array([np.random.default_rng(child).random(dimensions) for child in _children(seed, samples)])
    if sampler == "latin-hypercube":
        return qmc.LatinHypercube(dimensions, rng=np.random.default_rng(seed)).random(samples)
    return qmc.Sobol(dimensions, rng=np.random.default_rng(seed)).random(samples)


def _children(seed: int, count: int) -> list[np.random.SeedSequence]:
    """The first ``count`` children of the seed's SeedSequence, each made from its index alone
    (``SeedSequence(seed).spawn`` gives the same ones in order)."""
    return [np.random.SeedSequence(seed, spawn_key=(i,)) for i in range(count)]


def inverse(distribution: Distribution, unit: np.ndarray) -> np.ndarray:
    """Values of ``distribution`` truncated to [low, high] at the unit-cube coordinates ``unit``.

    Parameters
    ----------
    distribution : Distribution
    unit : ndarray
        Coordinates in [0, 1).

    Returns
    -------
    ndarray
        Within [low, high].
    """
    d = distribution
    if d.kind == "uniform":
        return d.low + unit * (d.high - d.low)
    frozen = stats.norm(d.mean, d.std) if d.kind == "normal" else stats.lognorm(d.sigma, scale=d.median)
    bottom, top = frozen.cdf(d.low), frozen.cdf(d.high)
    if not top > bottom:  # the whole mass outside [low, high]: numerically a point
        return np.full_like(unit, np.clip(frozen.median(), d.low, d.high))
    return np.clip(frozen.ppf(bottom + unit * (top - bottom)), d.low, d.high)


# The sample table every sweep draws at once, before its first run (issue 37: 10 000 000 samples
# grew to 4.9 GB in 90 s): at most this many bytes.
MAX_INPUT_BYTES = 512 * 1024**2


def sample_inputs(sweep: Sweep, joint_names) -> tuple[list[str], np.ndarray]:
    """Every sample's uncertain inputs.

    Parameters
    ----------
    sweep : Sweep
    joint_names : sequence of str
        The design's joints, in design order.

    Returns
    -------
    tuple
        (the column names of :func:`input_columns`, an array of one row per sample).
    """
    columns = column_distributions(sweep.inputs, joint_names)
    needed = 2 * 8 * sweep.samples * max(len(columns), 1)  # the unit samples and the values, float64
    if needed > MAX_INPUT_BYTES:
        raise ModelError(
            f"samples: {sweep.samples} × {len(columns)} uncertain inputs need {needed / 1024**3:.2f} GiB before the "
            f"first run — at most {MAX_INPUT_BYTES // 1024**2} MiB: {MAX_INPUT_BYTES // (16 * max(len(columns), 1))} "
            "samples; run several sweeps with other seeds"
        )
    unit = unit_samples(sweep.sampler, sweep.samples, len(columns), sweep.seed)
    values = np.empty_like(unit)
    for k, (_, distribution) in enumerate(columns):
        values[:, k] = inverse(distribution, unit[:, k])
    return [column for column, _ in columns], values


__all__ = ["MAX_INPUT_BYTES", "column_distributions", "input_columns", "inverse", "sample_inputs", "unit_samples"]
