"""Running a sweep on ``dask.distributed`` (issue 20, ``docs/sweep.md``): a LocalCluster of
single-threaded worker processes by default, any running scheduler by its address with the
same code.

The driver reads the sweep and its design, builds what every sample shares once
(``ensemble.build_base``: design model, reduction, LQG gains) and scatters it to the workers,
draws every sample's inputs (``sweep_sampling``), and submits one task per batch of samples.
Each finished batch is written by the driver as one Parquet file, atomically (a temporary file
renamed into place), so an interrupted sweep loses at most the batches in flight and ``resume``
computes only the batches whose file is missing or incomplete.

Output folder: ``sweep.json`` (what the results are of: the sweep file's hash, the sample,
batch and row counts, the columns) and ``results/batch-NNNNNN.parquet``, a Parquet dataset
(``read_results`` reads it as one table sorted by sample, point and law).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import signal
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from smartjoint.bench.interrupts import quiet_on_interrupt
from smartjoint.bench.sweep_folder import MANIFEST, RESULTS, check_output
from smartjoint.bench.sweep_landscape import LANDSCAPE, write_landscape
from smartjoint.codegen.closed_loop import CompiledLoops
from smartjoint.common import output_path
from smartjoint.common.errors import ModelError, SmartjointError
from smartjoint.design.control import ensemble, sweep_sampling
from smartjoint.design.control.sweep_file import Sweep

SCHEDULER_TIMEOUT = 3.0  # s: an unreachable scheduler is reported after this, the command within 10 s


class SweepError(SmartjointError):
    """A sweep that cannot run: its output folder, its scheduler, its results."""


@dataclass
class Prepared:
    """A sweep ready to run: the shared base, the grid points and every sample's inputs."""

    sweep: Sweep
    base: ensemble.EnsembleBase
    points: list[dict[str, float]]
    values: np.ndarray  # (samples, inputs)
    design_sha256: str
    compiled: CompiledLoops | None = None  # the semi-active laws' compiled closed loop; None: Python

    def schema(self) -> pa.Schema:
        """The columns of every batch file."""
        fields = [pa.field("sample", pa.int64()), pa.field("point", pa.int64()), pa.field("law", pa.string())]
        fields += [pa.field(name, pa.float64()) for name in (*self.base.grid_columns, *self.base.input_columns)]
        fields += [
            pa.field(name, pa.int64() if name == "safe_state_samples" else pa.float64()) for name in ensemble.METRICS
        ]
        return pa.schema(fields)

    def batch_rows(self, batch: range) -> int:
        return len(batch) * len(self.points) * len(self.base.laws)


def prepare(sweep: Sweep, progress=print, design=None, model=None) -> Prepared:
    """Load the sweep's design (updated unless ``update = false``, its study duration the
    sweep's), build the shared base and draw the samples.

    Parameters
    ----------
    sweep : Sweep
    progress : callable
        Receives progress lines.
    design : Design, optional
        The design itself, already as the sweep wants it (``smartjoint run``'s, with its placed
        joints and identified friction), instead of loading ``sweep.design``.
    model : ModalModel, optional
        The design model of ``design`` where the caller has it (``smartjoint run``'s control
        stage), instead of building it again.

    Returns
    -------
    Prepared
    """
    if design is None:
        design = _loaded(sweep.design, sweep, progress)
    if sweep.friction_from_identification:
        design, sweep = _identified_friction(sweep, design, progress)
    design = _with_duration(design, sweep)
    if sweep.spread_from_design:
        sweep = _design_spread(sweep, design, progress)
    # grid.placement: the other designs, loaded (and updated) alike; the friction factors apply to each.
    placements = [_with_duration(_loaded(path, sweep, progress), sweep) for path in sweep.placements]
    joints = [j.name for j in design.joints]
    columns, values = sweep_sampling.sample_inputs(sweep, joints)
    progress(f"design model, reduction and gains of {design.name!r} (built once, shared with the workers) …")
    base = ensemble.build_base(sweep, design, columns, progress, placements, model)
    return Prepared(sweep, base, sweep.points(), values, design.sha256, _compiled_loops(base, progress))


def _design_spread(sweep: Sweep, design, progress) -> Sweep:
    """``[uncertain] from = "design"``: the design's physical spread (its ``[uncertainty]`` and the
    defaults, ``physical_spread``) with the file's own entries replacing those of the same name."""
    from smartjoint.design.control.physical_spread import describe, physical_spread

    own = {u.name for u in sweep.inputs}
    entries = [e for e in physical_spread(design, design.control.pulse_amplitude) if e.input.name not in own]
    for line in describe(entries):
        progress(f"  spread: {line}")
    return dataclasses.replace(sweep, inputs=(*(e.input for e in entries), *sweep.inputs))


def _loaded(path, sweep: Sweep, progress):
    """A design file of the sweep, updated to its EMA unless the sweep says ``update = false``."""
    from smartjoint.design import load_design, updated_design

    design = load_design(path)
    if sweep.update and design.updating is not None:
        progress(f"updating {len(design.updating.parameters)} parameters of {design.name!r} to its EMA …")
        design, _ = updated_design(design)
    return design


def _with_duration(design, sweep: Sweep):
    """The design with the sweep's study duration, where it sets one."""
    if sweep.study_duration is None:
        return design
    return dataclasses.replace(design, control=dataclasses.replace(design.control, study_duration=sweep.study_duration))


def _identified_friction(sweep: Sweep, design, progress):
    """``from = "identification"``: the design's friction identified as ``smartjoint run`` does it
    (its rig records, else its parameters checked on simulated records; ``friction_stage``) and
    each LuGre factor the file does not give drawn from the 95 % intervals
    (``friction_uncertainty``); the design with the identified parameters and the sweep with them."""
    import tempfile

    from smartjoint.design.control.friction_uncertainty import friction_inputs, friction_spreads
    from smartjoint.design.friction.stage import friction_stage

    progress(f"friction of {design.name!r} identified for the 95 % intervals of its LuGre parameters …")
    with tempfile.TemporaryDirectory() as scratch:  # the identification's result files are not kept
        design, friction = friction_stage(design, Path(scratch), lambda line: None)
    spreads = friction_spreads(friction)
    progress("  σ of the logarithms: " + ", ".join(f"{name} {sigma:.3g}" for name, sigma in spreads.items()))
    given = {u.name for u in sweep.inputs}
    drawn = tuple(u for u in friction_inputs(spreads) if u.name not in given)
    return design, dataclasses.replace(sweep, inputs=(*sweep.inputs, *drawn))


def _compiled_loops(base: ensemble.EnsembleBase, progress) -> CompiledLoops | None:
    """The compiled closed loop of every grid point's artefact, built here once (the workers load
    it from the build cache); None, said once, where it cannot be built (no C compiler)."""
    if base.laws == ("active LQG",):  # the only law the compiled loop does not run
        return None
    loops = CompiledLoops()
    try:
        for artifact in base.artifacts:
            loops(artifact)
    except ModelError as error:
        progress(f"the semi-active laws run in Python (about 10x slower): {str(error).splitlines()[0]}")
        return None
    return loops


def connect(scheduler: str | None, workers: int | None, scratch: str | None = None):
    """A Dask client: on the scheduler at ``scheduler``, else on a new LocalCluster of
    ``workers`` single-threaded processes (default: one per core) whose spill and work files go
    to ``scratch`` (default: Dask's ``dask-scratch-space`` in the temporary folder, which stays).

    Returns
    -------
    tuple
        (Client, LocalCluster or None).

    Raises
    ------
    SweepError
        When the scheduler cannot be reached within ``SCHEDULER_TIMEOUT``.
    """
    from dask.distributed import Client, LocalCluster

    if scheduler is not None:
        _probe(scheduler)
        return Client(scheduler, timeout=SCHEDULER_TIMEOUT, set_as_default=False), None
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # inherited by the worker processes: one core each
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    # Ctrl-C reaches every process of the terminal's group: the worker processes start with SIGINT
    # ignored (inherited through exec), so only this process answers it and shuts them down.
    main = threading.current_thread() is threading.main_thread()  # signals are the main thread's
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
    try:
        cluster = LocalCluster(
            n_workers=workers or os.cpu_count() or 1,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",
            silence_logs=logging.ERROR,
            local_directory=scratch,
        )
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    return Client(cluster, set_as_default=False), cluster


def _probe(scheduler: str) -> None:
    """Connect to the scheduler once and shake hands, within ``SCHEDULER_TIMEOUT``: an address
    where nothing (or no Dask scheduler) answers fails here with one line, before a Client
    exists whose clean-up would wait for it again."""
    import asyncio

    from distributed.comm import connect as comm_connect

    async def handshake() -> None:
        comm = await comm_connect(scheduler, timeout=SCHEDULER_TIMEOUT)
        await comm.close()

    try:
        asyncio.run(asyncio.wait_for(handshake(), SCHEDULER_TIMEOUT + 1.0))
    except Exception as error:  # refused, timed out, a bad address, a server that is no scheduler
        known = isinstance(error, (OSError, TimeoutError, ValueError)) and str(error)
        reason = str(error).splitlines()[0] if known else "what answers there is no Dask scheduler"
        raise SweepError(
            f"--scheduler {scheduler}: cannot reach a Dask scheduler within {SCHEDULER_TIMEOUT:g} s ({reason})"
        ) from None


def _manifest(prepared: Prepared) -> dict:
    s = prepared.sweep
    return {
        "schema": "smartjoint-sweep-results/1",
        "sweep": s.source,
        "sweep_sha256": s.sha256,
        "design": str(s.design),
        "design_sha256": prepared.design_sha256,
        "samples": s.samples,
        "batch": s.batch,
        "points": len(prepared.points),
        "laws": list(s.laws),
        "rows": s.samples * len(prepared.points) * len(s.laws),
        "columns": list(prepared.base.columns()),
    }


def batch_path(folder: Path, number: int) -> Path:
    return folder / RESULTS / f"batch-{number:06d}.parquet"


def _complete(path: Path, rows: int) -> bool:
    """A batch file that exists and holds its rows (a partial one cannot: files are renamed whole)."""
    try:
        return pq.read_metadata(path).num_rows == rows
    except (OSError, pa.ArrowException):
        return False


def open_output(folder: Path, prepared: Prepared, resume: bool) -> list[int]:
    """Create or check the output folder; the batches still to compute.

    Raises
    ------
    SweepError
        For results of another sweep, or results without ``resume``.
    """
    manifest = _manifest(prepared)
    path = folder / MANIFEST
    check_output(folder, resume)
    if path.exists():
        try:
            found = json.loads(path.read_text())
        except (OSError, ValueError) as error:
            raise SweepError(f"-o {folder}: {MANIFEST} cannot be read ({error})") from None
        where = ("sweep", "design")  # the files' paths may be given otherwise; their hashes decide
        changed = sorted(
            k for k in manifest if k not in where and (found.get(k) if isinstance(found, dict) else None) != manifest[k]
        )
        if changed:
            raise SweepError(
                f"-o {folder}: results of another sweep ({', '.join(changed) or MANIFEST} differ); "
                "--resume continues only the same sweep file and design"
            )
    else:
        output_path.write_file(path, json.dumps(manifest, indent=1) + "\n")
    (folder / RESULTS).mkdir(parents=True, exist_ok=True)
    batches = prepared.sweep.batches()
    return [k for k, b in enumerate(batches) if not _complete(batch_path(folder, k), prepared.batch_rows(b))]


def write_batch(folder: Path, number: int, rows: list[dict], schema: pa.Schema) -> Path:
    """One batch's rows as a Parquet file, written to a temporary name and renamed into place."""
    path = batch_path(folder, number)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")  # hidden: datasets skip it
    pq.write_table(pa.Table.from_pylist(rows, schema=schema), temporary)
    os.replace(temporary, path)
    return path


def read_results(folder: str | Path) -> pa.Table:
    """The results of a sweep as one table, sorted by sample, grid point and law.

    Parameters
    ----------
    folder : str or Path
        The sweep's output folder.

    Returns
    -------
    pyarrow.Table
    """
    import pyarrow.dataset as ds

    table = ds.dataset(Path(folder) / RESULTS, format="parquet").to_table()
    return table.sort_by([("sample", "ascending"), ("point", "ascending"), ("law", "ascending")])


def _eta(done: int, total: int, computed: int, elapsed: float) -> str:
    rate = computed / elapsed if elapsed > 0 else 0.0
    eta = f"{(total - done) / rate:.0f} s" if rate > 0 else "?"
    return f"{done}/{total} samples ({100 * done / total:.0f} %), {rate:.3g} samples/s, ETA {eta}"


def run_sweep(
    sweep: Sweep,
    folder: str | Path,
    scheduler: str | None = None,
    workers: int | None = None,
    resume: bool = False,
    progress=print,
    design=None,
    model=None,
) -> dict:
    """Run a sweep and write its results (``docs/sweep.md``).

    Parameters
    ----------
    sweep : Sweep
    folder : str or Path
        The output folder.
    scheduler : str, optional
        A Dask scheduler's address; a LocalCluster when not given.
    workers : int, optional
        The LocalCluster's worker processes (default: one per core).
    resume : bool
        Continue the results in ``folder``: compute only the batches missing there.
    progress : callable
        Receives the progress lines (samples done, rate, time left).
    design, model : optional
        As in :func:`prepare`.

    Returns
    -------
    dict
        JSON-ready: the folder, counts of samples, rows and batches, the time and the rate.
    """
    import tempfile

    import dask

    folder = Path(folder)
    check_output(folder, resume)  # before the scheduler and the preparation (minutes on a large design)
    # The LocalCluster's work files in a folder of this run, removed with it (nothing left behind).
    with (
        quiet_on_interrupt(),  # the event loop's logs of what an interrupt cuts short
        tempfile.TemporaryDirectory(prefix="smartjoint-dask-") as scratch,
        dask.config.set({"temporary-directory": scratch}),
    ):
        client, cluster = connect(scheduler, workers, scratch)  # first: an unreachable scheduler fails at once
        try:
            progress(
                f"sweep {sweep.source}: {sweep.samples} samples × {len(sweep.points())} grid point(s) × "
                f"{len(sweep.laws)} law(s) → {folder}"
            )
            prepared = prepare(sweep, progress, design, model)
            todo = open_output(folder, prepared, resume)
            out = _compute(client, prepared, folder, todo, progress)
            return {**out, "landscape": LANDSCAPE if write_landscape(prepared, folder, progress) else None}
        finally:
            client.close()
            if cluster is not None:
                cluster.close()


def _warm_up(artifacts) -> None:
    """On a worker: import the closed loop and load the plant's C kernel and the compiled loops
    of ``artifacts`` (compiled once per cache)."""
    from smartjoint.design.control import ensemble  # noqa: F401 - the import is the point
    from smartjoint.design.plant import kernel

    try:
        kernel.native_module()
        loops = CompiledLoops()
        for artifact in artifacts:
            loops(artifact)
    except Exception:  # no compiler here: the runs fall back to the numpy mirror and say so
        pass


def _compute(client, prepared: Prepared, folder: Path, todo: list[int], progress) -> dict:
    """Submit the missing batches, write each as it finishes, report progress."""
    from dask.distributed import get_task_stream

    sweep, batches = prepared.sweep, prepared.sweep.batches()
    workers = len(client.scheduler_info().get("workers", {}))
    progress(f"sweep {Path(sweep.source).name}: {len(todo)} of {len(batches)} batches to run on {workers} worker(s)")
    started, base = time.perf_counter(), None
    if todo:
        base = client.scatter(prepared.base, broadcast=True)
        # The workers import the simulation and load its C kernels before the clock runs.
        client.run(_warm_up, prepared.base.artifacts if prepared.compiled is not None else ())
    start, driver = time.perf_counter(), time.process_time()
    with get_task_stream(client) as stream:  # the workers' compute time, from Dask's own records
        computed = _submit_and_write(client, prepared, folder, todo, base, progress, start)
    elapsed, driver = time.perf_counter() - start, time.process_time() - driver
    compute = sum(
        part["stop"] - part["start"]
        for task in stream.data
        for part in task["startstops"]
        if part["action"] == "compute"
    )
    return {
        "output": str(folder),
        "samples": sweep.samples,
        "rows": sweep.samples * len(prepared.points) * len(sweep.laws),
        "batches": len(batches),
        "batches_computed": len(todo),
        "samples_computed": computed,
        "workers": workers,
        "startup_seconds": start - started,  # scattering the base, the workers' imports
        "seconds": elapsed,
        "samples_per_second": computed / elapsed if elapsed > 0 and computed else None,
        "samples_per_core_second": computed / (workers * elapsed) if elapsed > 0 and computed else None,
        "compute_seconds": compute,
        # Worker time not spent in the batches' simulations: scheduling, serialisation, idle
        # workers, and the driver's Parquet writing, which shares the machine's cores.
        "outside_share": 1.0 - compute / (workers * elapsed) if elapsed > 0 and computed else None,
        # The driver's own CPU time over the same span (this process: the LocalCluster's scheduler,
        # the client, reading the results and writing Parquet), which slows the workers it shares
        # the cores with: counted as outside too, an upper bound.
        "driver_cpu_seconds": driver,
        "outside_share_with_driver": (
            1.0 - (compute - driver) / (workers * elapsed) if elapsed > 0 and computed else None
        ),
    }


def _submit_and_write(client, prepared: Prepared, folder: Path, todo: list[int], base, progress, start) -> int:
    """Submit the missing batches and write each as it finishes; the samples computed."""
    from dask.distributed import as_completed

    sweep, batches = prepared.sweep, prepared.sweep.batches()
    done, computed = sweep.samples - sum(len(batches[k]) for k in todo), 0
    schema = prepared.schema()
    if todo:
        futures = {
            client.submit(
                ensemble.run_batch,
                base,
                prepared.points,
                list(batches[k]),
                prepared.values[batches[k].start : batches[k].stop],
                prepared.compiled,
                key=f"smartjoint-sweep-{sweep.sha256[:12]}-batch-{k}",
                pure=False,
            ): k
            for k in todo
        }
        seen = set(client.scheduler_info().get("workers", {}))
        for future in as_completed(futures, loop=client.loop):
            k = futures[future]
            write_batch(folder, k, future.result(), schema)
            done, computed = done + len(batches[k]), computed + len(batches[k])
            progress("  " + _eta(done, sweep.samples, computed, time.perf_counter() - start))
            seen = _report_lost_workers(client, seen, progress)
    return computed


def _report_lost_workers(client, seen: set, progress) -> set:
    """Say which workers left the cluster since ``seen`` (killed, lost; Dask re-runs their tasks)."""
    now = set(client.scheduler_info().get("workers", {}))
    for address in sorted(seen - now):
        progress(f"  warning: worker {address} left the cluster (killed or lost); Dask re-runs its tasks elsewhere")
    return now


__all__ = ["SCHEDULER_TIMEOUT", "Prepared", "SweepError", "batch_path", "connect", "open_output", "prepare",
           "read_results", "run_sweep", "write_batch"]  # fmt: skip
