"""The sweep file: a TOML description of a robustness ensemble or design sweep over the closed-loop
study (issue 20, ``docs/sweep.md``), read with the design file's one-line errors.

A sweep names the base design, the laws to run, the uncertain inputs with their distributions,
the design variables on grids, the sample count, the seed and the sampler. Every check fails with
a :class:`~smartjoint.common.errors.DesignError` naming the key path, the value found and what is
allowed; a key no reader asks for is refused (``unknown key``).
"""

from __future__ import annotations

import hashlib
import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from smartjoint.common import law_registry
from smartjoint.common.errors import DesignError
from smartjoint.design.structure.files import read_file, read_toml
from smartjoint.design.structure.table import DesignTable
from smartjoint.design.structure.uncertainty import (
    DISTRIBUTIONS,
    FACTOR,
    SCALAR_INPUTS,
    Distribution,
    Support,
    UncertainInput,
    distribution_of,
    friction_parameters,
)

SCHEMA = "smartjoint-sweep/1"
# Every law a sweep can run, in the order of the rows; the two best passive settings search the
# constant F_N that minimises E(t_e) or e(t_e) per sample (ensemble.best_passive), so they are
# asked for by name only.
DEFAULT_LAWS = ("passive F_min", "passive F_max", *law_registry.DISPLAY, "active LQG")  # the study's runs
LAWS = (*DEFAULT_LAWS, "best passive E", "best passive e")
SAMPLERS = ("random", "latin-hypercube", "sobol")
# Each law's settings (its registry entry's, by their [control] keys), then those every law shares.
LAW_SETTINGS = {s.design_key(law.name): s for law in law_registry.LAWS.values() for s in law.settings}
GRID_VARIABLES = (
    *LAW_SETTINGS,
    "normal_force_min",
    "normal_force_max",
    "control_weight",
    "placement",
)
MAX_FILE_BYTES = 1024 * 1024
MAX_SAMPLES = 10_000_000
MAX_BATCH = 100_000
MAX_GRID_POINTS = 100_000
MAX_SEED = 2**63 - 1
MAX_NORMAL_FORCE = 1e5  # [N], as [control] (design.structure.control_section)


@dataclass(frozen=True)
class Sweep:
    """A validated sweep file. ``grid``: each design variable's values (the sweep runs their
    Cartesian product, every sample at every point); ``design`` the base design file."""

    source: str
    sha256: str
    design: Path
    update: bool
    laws: tuple[str, ...]
    inputs: tuple[UncertainInput, ...]
    grid: dict[str, tuple[float, ...]]
    samples: int
    seed: int
    sampler: str
    batch: int
    study_duration: float | None
    friction_from_identification: bool = False  # [uncertain.friction] from = "identification"
    spread_from_design: bool = False  # [uncertain] from = "design": the design's physical spread beneath the file's
    placements: tuple[Path, ...] = ()  # grid.placement's design files; the grid holds their indices

    def points(self) -> list[dict[str, float]]:
        """The grid points: every combination of the grid's values, first variable slowest."""
        names = list(self.grid)
        return [dict(zip(names, values)) for values in itertools.product(*(self.grid[n] for n in names))]

    def batches(self) -> list[range]:
        """The samples of each batch (one task, one result file), in order."""
        return [range(start, min(start + self.batch, self.samples)) for start in range(0, self.samples, self.batch)]


def load_sweep(path: str | Path) -> Sweep:
    """Read and validate a sweep file (``docs/sweep.md``).

    Parameters
    ----------
    path : str or Path
        The sweep file (TOML); ``design`` inside is relative to it.

    Returns
    -------
    Sweep
        ``sha256`` over the file's bytes.

    Raises
    ------
    DesignError
        Naming the key path, the value and what is allowed.
    """
    path = Path(path)
    source = str(path)
    raw = read_file(path, "<file>", source, None, MAX_FILE_BYTES)
    data, _ = read_toml(path, source, raw, [path], MAX_FILE_BYTES, 0)
    return parse_sweep(data, path.parent, source, hashlib.sha256(raw).hexdigest())


def parse_sweep(data: dict[str, Any], folder: Path, source: str = "<memory>", sha256: str = "") -> Sweep:
    """Validate a sweep given as a (TOML-like) dictionary; ``design`` is relative to ``folder``."""
    root = DesignTable(data, "", source)
    schema = root.string("schema", SCHEMA)
    if schema != SCHEMA:
        raise root.error("schema", schema, f"this version reads {SCHEMA!r}")
    design = folder / root.string("design")
    if not design.is_file():
        raise root.error("design", str(root.data["design"]), f"no design file {design} (relative to the sweep file)")
    laws = _laws(root)
    samples = root.integer("samples", maximum=MAX_SAMPLES)
    sampler = root.string("sampler", "random", SAMPLERS)
    if sampler == "sobol" and samples & (samples - 1):
        raise root.error("samples", samples, "the sobol sampler takes a power of two (its balance needs 2^m points)")
    inputs, identified, from_design = (
        _inputs(root.table("uncertain", {})) if "uncertain" in root.data else ((), False, False)
    )
    grid, placements = _grid(root.table("grid", {}), folder) if "grid" in root.data else ({}, ())
    duration = root.get("study_duration", None)
    if duration is not None:
        duration = root.number("study_duration", positive=True, maximum=3600.0)
    sweep = Sweep(
        source=source,
        sha256=sha256,
        design=design,
        update=root.boolean("update", True),
        laws=laws,
        inputs=inputs,
        grid=grid,
        samples=samples,
        seed=root.integer("seed", minimum=0, maximum=MAX_SEED),
        sampler=sampler,
        batch=root.integer("batch", 8, maximum=MAX_BATCH),
        study_duration=duration,
        friction_from_identification=identified,
        spread_from_design=from_design,
        placements=placements,
    )
    if len(sweep.points()) > MAX_GRID_POINTS:
        raise root.error("grid", len(sweep.points()), f"at most {MAX_GRID_POINTS} grid points")
    _check_limits(root, sweep.grid)
    root.finish()
    return sweep


def _laws(root: DesignTable) -> tuple[str, ...]:
    value = root.get("laws", list(DEFAULT_LAWS))
    allowed = "a non-empty list of distinct laws: " + ", ".join(repr(law) for law in LAWS)
    if not isinstance(value, list) or not value or len(set(map(str, value))) != len(value):
        raise root.error("laws", value, allowed)
    for law in value:
        if law not in LAWS:
            raise root.error("laws", law, allowed)
    return tuple(law for law in LAWS if law in value)  # the study's order, whatever the file's


def _inputs(table: DesignTable) -> tuple[tuple[UncertainInput, ...], bool, bool]:
    """The [uncertain] table: scalar inputs and the [uncertain.friction] factors, whether the
    factors not given come from the identification (``[uncertain.friction] from =
    "identification"``) and whether the design's physical spread lies beneath them (``from =
    "design"``: its ``[uncertainty]`` and the defaults, ``design.control.physical_spread``)."""
    found = []
    identified = False
    from_design = table.string("from", "") == "design" if "from" in table.data else False
    if "from" in table.data and not from_design:
        raise table.error("from", table.data["from"], "only 'design' (the design's [uncertainty] and its defaults)")
    for name in table.data:
        if name == "from":
            continue
        if name == "friction":
            friction = table.table("friction")
            for parameter in friction.data:
                if parameter == "from":
                    if friction.get("from") != "identification":
                        raise friction.error(
                            "from", friction.data["from"], "only 'identification' (its 95 % intervals)"
                        )
                    identified = True
                    continue
                keys = friction_parameters()
                if parameter not in keys:
                    allowed = "unknown friction parameter; allowed: " + ", ".join(keys)
                    raise friction.error(parameter, friction.data[parameter], allowed)
                distribution = distribution_of(friction.table(parameter), FACTOR)
                found.append(UncertainInput(f"friction.{parameter}", distribution))
            friction.finish()
        elif name in SCALAR_INPUTS:
            found.append(UncertainInput(name, distribution_of(table.table(name), SCALAR_INPUTS[name])))
        else:
            allowed = "unknown uncertain input; allowed: " + ", ".join([*SCALAR_INPUTS, "friction"])
            raise table.error(name, table.data[name], allowed)
    table.finish()
    return tuple(found), identified, from_design


def _placements(table: DesignTable, folder: Path) -> tuple[Path, ...]:
    """grid.placement: design files (relative to the sweep file), each the same joints and sensors
    placed elsewhere."""
    value = table.get("placement")
    if not (
        isinstance(value, list) and value and all(isinstance(v, str) for v in value) and len(set(value)) == len(value)
    ):
        raise table.error("placement", value, "expected a non-empty list of distinct design files")
    paths = tuple(folder / v for v in value)
    for text, path in zip(value, paths):
        if not path.is_file():
            raise table.error("placement", text, f"no design file {path} (relative to the sweep file)")
    return paths


def _grid(table: DesignTable, folder: Path) -> tuple[dict[str, tuple[float, ...]], tuple[Path, ...]]:
    """The [grid] table: each design variable's values, one for every joint; a placement's value
    is its index in the returned design files."""
    grid: dict[str, tuple[float, ...]] = {}
    placements: tuple[Path, ...] = ()
    for name in table.data:
        if name not in GRID_VARIABLES:
            raise table.error(name, table.data[name], "unknown design variable; allowed: " + ", ".join(GRID_VARIABLES))
        if name == "placement":
            placements = _placements(table, folder)
            grid[name] = tuple(float(k) for k in range(len(placements)))
            continue
        value = table.get(name)
        if not (
            isinstance(value, list)
            and value
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            and all(math.isfinite(v) and 0.0 <= v <= MAX_NORMAL_FORCE for v in value)
            and len(set(value)) == len(value)
        ):
            raise table.error(
                name, value, f"expected a non-empty list of distinct numbers in [0, {MAX_NORMAL_FORCE:g}]"
            )
        if name in LAW_SETTINGS and min(value) <= 0.0:
            raise table.error(name, value, f"{LAW_SETTINGS[name].meaning} must be > 0 [{LAW_SETTINGS[name].unit}]")
        if name == "control_weight" and min(value) <= 0.0:
            raise table.error(name, value, "the LQR's control weight ρ (Eq. 33, R = ρI) must be > 0")
        grid[name] = tuple(float(v) for v in value)
    table.finish()
    return grid, placements


def _check_limits(root: DesignTable, grid: dict[str, tuple[float, ...]]) -> None:
    """Every grid point keeps F_N^min < F_N^max where the grid sets both."""
    lows, highs = grid.get("normal_force_min", ()), grid.get("normal_force_max", ())
    for low, high in itertools.product(lows, highs):
        if not low < high:
            raise DesignError(
                "grid.normal_force_min",
                low,
                f"every point needs F_N^min < F_N^max (normal_force_max {high:g})",
                root.source,
            )


__all__ = [
    "DISTRIBUTIONS",
    "FACTOR",
    "GRID_VARIABLES",
    "DEFAULT_LAWS",
    "LAWS",
    "SAMPLERS",
    "SCALAR_INPUTS",
    "SCHEMA",
    "Distribution",
    "Support",
    "Sweep",
    "UncertainInput",
    "distribution_of",
    "load_sweep",
    "parse_sweep",
]
