"""The best passive landscape of a sweep (issue 36): on the sweep's nominal plant, both searches
for the best constant normal force (``best_passive.search_landscape``), every force they ran with
its E(t_e) and e(t_e), written beside the results as ``best_passive_landscape.json``; the sweep
report plots it (``sweep_report``). Only when the sweep runs a best passive law."""

from __future__ import annotations

import json
from pathlib import Path

from smartjoint.common import output_path
from smartjoint.design.control import ensemble
from smartjoint.design.control.best_passive import search_landscape
from smartjoint.design.control.interconnection import PythonLoop

LANDSCAPE = "best_passive_landscape.json"
LANDSCAPE_PLOT = "best_passive_landscape.png"  # drawn by the sweep report


def write_landscape(prepared, folder: Path, progress=print) -> dict | None:
    """Search the nominal plant of ``prepared`` (a ``bench.sweep.Prepared``) and write the
    landscape into ``folder`` (atomically); None when the sweep runs no best passive law."""
    if not any(law in ensemble.BEST_PASSIVE for law in prepared.sweep.laws):
        return None
    base = prepared.base
    loop = prepared.compiled(base.artifacts[0]) if prepared.compiled is not None else PythonLoop(base.artifacts[0])
    progress("  best constant F_N on the nominal plant: the landscape of both searches …")
    landscape = search_landscape(base.setup, loop.run_passive)
    output_path.write_file(Path(folder) / LANDSCAPE, json.dumps(landscape, indent=1) + "\n")
    return landscape


__all__ = ["LANDSCAPE", "LANDSCAPE_PLOT", "write_landscape"]
