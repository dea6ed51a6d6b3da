"""Sweeps of the closed-loop study (issue 20, docs/sweep.md): the sweep file and its one-line
errors, deterministic samples, one sample against the study, and the Dask runner — the same
table on 1 and on 2 workers, ``--resume`` recomputing only a missing batch, an unreachable
scheduler refused within 10 s. Small truss, 0.2 s studies, a handful of samples."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import socket
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import tomli_w
from conftest import cli_error, run_cli, small_truss

from smartjoint.bench.sweep import SweepError, batch_path, connect, prepare, read_results, run_sweep
from smartjoint.common.errors import DesignError, ModelError, OutputError
from smartjoint.design.control import ensemble, sweep_sampling, tuning
from smartjoint.design.control import study as closed_loop
from smartjoint.design.control.sweep_file import load_sweep
from smartjoint.design.structure.spec import parse_design

SWEEP = """\
design = "small.toml"
laws = ["passive F_min", "passive F_max", "SISO", "cLQG", "active LQG"]
samples = 5
seed = 20
batch = 2
sampler = "latin-hypercube"
study_duration = 0.2

[uncertain]
modal_frequency_scale = { distribution = "normal", mean = 1.0, std = 0.01, low = 0.97, high = 1.03 }
modal_damping = { distribution = "lognormal", median = 0.001, sigma = 0.3, high = 0.01 }
pulse_amplitude = { distribution = "uniform", low = 180.0, high = 220.0 }
sensor_noise = { distribution = "uniform", low = 1e-6, high = 1e-5 }

[uncertain.friction]
sigma0 = { distribution = "uniform", low = 0.95, high = 1.05 }
coulomb = { distribution = "normal", mean = 1.0, std = 0.03, low = 0.9, high = 1.1 }

[grid]
siso_boundary_layer = [1e-4, 1e-3]
"""


def _small_design() -> dict:
    design = small_truss()
    design["control"] = {"modes": 4, "considered_modes": 10, "study_duration": 0.2}
    return design


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A folder with the small truss's design file and the sweep file."""
    path = tmp_path_factory.mktemp("sweep")
    (path / "small.toml").write_text(tomli_w.dumps(_small_design()))
    (path / "sweep.toml").write_text(SWEEP)
    return path


def _error(folder, text: str) -> str:
    path = folder / "bad.toml"
    path.write_text(text)
    with pytest.raises(DesignError) as caught:
        load_sweep(path)
    message = str(caught.value)
    assert "\n" not in message
    return message


def _replace(key_line: str, new: str) -> str:
    assert key_line in SWEEP
    return SWEEP.replace(key_line, new)


# ---------------------------------------------------------------------------------- the file
@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        ("samples = 5", "samples = 0", "samples: 0 — must be an integer 1"),
        ("seed = 20", "seed = 20\nworkers = 3", "workers: 3 — unknown key"),
        (
            "study_duration = 0.2",
            "study_duration = 0.2\n[uncertain.jitter]",
            "uncertain.jitter: {} — unknown uncertain",
        ),
        ("sigma0 = {", "sigma3 = {", "uncertain.friction.sigma3:"),
        (
            "low = 0.95, high = 1.05",
            "low = -0.05, high = 0.05",
            "uncertain.friction.sigma0.low: -0.05 — outside the support (0, ∞)",
        ),
        ("sigma = 0.3, high = 0.01", "sigma = 0.3", "uncertain.modal_damping.high: missing — required"),
        (
            "sigma = 0.3, high = 0.01",
            "sigma = 0.3, high = 1.5",
            "uncertain.modal_damping.high: 1.5 — outside the support (0, 0.99]",
        ),
        ("std = 0.01,", "std = 0.0,", "uncertain.modal_frequency_scale.std: 0.0 — must be > 0"),
        (
            '"uniform", low = 180.0',
            '"beta", low = 180.0',
            "uncertain.pulse_amplitude.distribution: 'beta' — allowed: 'uniform'",
        ),
        ('"cLQG", ', '"cLQR", ', "laws: 'cLQR' — a non-empty list"),
        ('sampler = "latin-hypercube"', 'sampler = "sobol"', "samples: 5 — the sobol sampler takes a power of two"),
        (
            "[grid]",
            "[grid]\nnormal_force_min = [10.0, 500.0]\nnormal_force_max = [400.0]",
            "grid.normal_force_min: 500.0",
        ),
        ("[grid]", "[grid]\nstiffness = [1]", "grid.stiffness: [1] — unknown design variable"),
        (
            "[grid]",
            "[grid]\nplacement = [1]",
            "grid.placement: [1] — expected a non-empty list of distinct design files",
        ),
        ('design = "small.toml"', 'design = "missing.toml"', "design: 'missing.toml' — no design file"),
    ],
)
def test_sweep_file_errors_name_key_value_and_what_is_allowed(folder, old, new, expected):
    assert expected in _error(folder, _replace(old, new))


def test_sweep_file_reads_inputs_grid_and_laws(folder):
    sweep = load_sweep(folder / "sweep.toml")
    assert [i.name for i in sweep.inputs] == [
        "modal_frequency_scale",
        "modal_damping",
        "pulse_amplitude",
        "sensor_noise",
        "friction.sigma0",
        "friction.coulomb",
    ]
    assert sweep.points() == [{"siso_boundary_layer": 1e-4}, {"siso_boundary_layer": 1e-3}]
    assert [list(b) for b in sweep.batches()] == [[0, 1], [2, 3], [4]]
    assert len(sweep.sha256) == 64


def test_zero_samples_is_one_line_on_the_command_line(folder):
    (folder / "zero.toml").write_text(_replace("samples = 5", "samples = 0"))
    assert "samples: 0 — must be an integer 1" in cli_error("sweep", str(folder / "zero.toml"))


def test_a_sample_table_too_large_for_memory_is_one_line_before_the_design_model(folder, tmp_path):
    """Issue 37: 10 000 000 samples grew to 4.9 GB in 90 s; now refused before any table is drawn."""
    from smartjoint.design.control import sweep_sampling
    from smartjoint.design.control.sweep_file import load_sweep

    (folder / "huge.toml").write_text(_replace("samples = 5", "samples = 10000000"))
    sweep = load_sweep(folder / "huge.toml")
    with pytest.raises(ModelError, match=r"^samples: 10000000 × \d+ uncertain inputs need [\d.]+ GiB") as refused:
        sweep_sampling.sample_inputs(sweep, ["JA", "JB"])
    assert "at most 512 MiB" in str(refused.value) and "\n" not in str(refused.value)
    done = run_cli("sweep", str(folder / "huge.toml"), "-o", str(tmp_path / "out"))
    line = done.stderr.strip().splitlines()[-1]
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert line.startswith("smartjoint sweep: error: samples: 10000000") and not (tmp_path / "out").exists()


def test_the_example_sweep_reads():
    sweep = load_sweep(Path(__file__).resolve().parents[1] / "examples" / "three_type_a_sweep.toml")
    assert sweep.design.is_file() and sweep.samples == 16 and "active LQG" not in sweep.laws


# ------------------------------------------------------------------------------- the samples
def test_random_samples_depend_only_on_seed_and_index():
    few, many = (sweep_sampling.unit_samples("random", n, 3, 7) for n in (3, 10))
    np.testing.assert_array_equal(few, many[:3])
    children = np.random.SeedSequence(7).spawn(10)
    np.testing.assert_array_equal(many[9], np.random.default_rng(children[9]).random(3))
    for sampler in ("latin-hypercube", "sobol"):
        a, b = (sweep_sampling.unit_samples(sampler, 8, 2, 5) for _ in range(2))
        np.testing.assert_array_equal(a, b)
        assert np.all((a >= 0) & (a < 1))


def test_samples_lie_within_their_truncation(folder):
    sweep = dataclasses.replace(load_sweep(folder / "sweep.toml"), samples=200, sampler="random")
    columns, values = sweep_sampling.sample_inputs(sweep, ["JA", "JB"])
    assert columns[4:] == ["friction.JA.sigma0", "friction.JB.sigma0", "friction.JA.coulomb", "friction.JB.coulomb"]
    bounds = [(0.97, 1.03), (0.0, 0.01), (180, 220), (1e-6, 1e-5), *[(0.9, 1.1)] * 4]
    for column, (low, high) in zip(columns, bounds, strict=True):
        values_of = values[:, columns.index(column)]
        assert np.all((values_of >= low) & (values_of <= high)), column
    assert 0.0008 < np.median(values[:, 1]) < 0.00125  # lognormal of median 1e-3


@pytest.fixture(scope="module")
def prepared(folder):
    """The sweep prepared once: design model, reduction, gains and the samples' inputs."""
    return prepare(load_sweep(folder / "sweep.toml"), progress=lambda line: None)


def test_a_nominal_sample_is_the_study(prepared):
    """No uncertain input, the design's own limits: the rows carry the study's metrics."""
    design = parse_design(_small_design())
    design = tuning.with_settings(design, {"siso_boundary_layer": (3e-4,)})
    point = {"siso_boundary_layer": 3e-4}
    model, lqg = prepared.base.setup.model, prepared.base.lqg
    artifact = ensemble.point_artifact(design, model, lqg, point)
    base = dataclasses.replace(prepared.base, input_columns=(), artifacts=(artifact,))
    rows = ensemble.run_batch(base, [point], [0], np.zeros((1, 0)), prepared.compiled)
    study = closed_loop.run_study(design, base.setup.model, progress=lambda line: None)
    assert [row["law"] for row in rows] == [run.name for run in study.runs if run.name in base.laws]
    for row in rows:
        m = study.run(row["law"]).metrics
        assert row["energy_measure"] == m["energy_measure"] and row["energy_end"] == m["energy_end"]
        assert row["tip_peak"] == max(m["tip_peak"]) and row["control_power"] == m["control_power"]
        assert row["energy_end_relative"] == m["energy_end_relative"]


def test_a_sample_perturbs_plant_friction_and_pulse(prepared):
    base = prepared.base
    inputs = dict(zip(base.input_columns, prepared.values[0]))
    s = ensemble.sample_setup(base, {"siso_boundary_layer": 1e-4}, inputs)
    np.testing.assert_array_equal(s.plant.omega, base.setup.model.omega * inputs["modal_frequency_scale"])
    # the structure's modes take the sampled damping; the quasi-static corrections keep ξ = 1
    corrections = np.array([label.startswith("krylov") for label in base.setup.model.labels])
    assert corrections.any() and np.all(s.plant.damping[corrections] == 1.0)
    assert np.all(s.plant.damping[~corrections] == inputs["modal_damping"])
    assert s.pulse_amplitude == inputs["pulse_amplitude"]
    assert s.laws[1].sigma0 == base.setup.laws[1].sigma0 * inputs["friction.JB.sigma0"]
    assert s.laws[0].sigma1 == base.setup.laws[0].sigma1  # not sampled: nominal
    assert s.model is base.setup.model  # the controllers keep the nominal design model


def test_the_sensor_noise_depends_on_the_seed_and_the_sample_only(prepared):
    base = prepared.base
    s = base.setup
    one, again = ensemble.sensor_noise(base, 3, s, 1e-5), ensemble.sensor_noise(base, 3, s, 1e-5)
    assert one.shape == (200, 2) and np.array_equal(one, again)  # 0.2 s at 1 ms, two tip sensors
    assert not np.array_equal(one, ensemble.sensor_noise(base, 4, s, 1e-5))
    assert 0.8e-5 < float(np.std(one)) < 1.2e-5
    noisy = ensemble.sample_setup(base, {"siso_boundary_layer": 1e-4}, {"sensor_noise": 1e-5}, 3)
    assert np.array_equal(noisy.sensor_noise, one)


def test_the_sample_instants_jitter_on_the_plant_step_grid_in_order(prepared):
    base, s = prepared.base, prepared.base.setup
    k = ensemble.sample_schedule(base, 3, s, 2e-4)  # 4 plant steps of 50 µs
    assert k.size == 200 and k[0] == 0 and np.all(np.diff(k) > 0)
    offsets = k - np.arange(200) * 20
    assert np.all(np.abs(offsets) <= 9) and 2.0 < float(np.std(offsets)) < 6.0
    assert np.array_equal(k, ensemble.sample_schedule(base, 3, s, 2e-4))
    assert not np.array_equal(k, ensemble.sample_schedule(base, 4, s, 2e-4))


def test_a_pulse_angle_on_a_design_with_one_disturbance_input_is_one_line(folder):
    text = _replace(
        "[uncertain.friction]",
        'pulse_direction = { distribution = "uniform", low = 0.0, high = 90.0 }\n\n[uncertain.friction]',
    )
    (folder / "angle.toml").write_text(text)
    with pytest.raises(
        ModelError, match=r"uncertain.pulse_direction: the design has 1 disturbance input — the angle needs two"
    ):
        prepare(load_sweep(folder / "angle.toml"), progress=lambda line: None)


def test_a_control_weight_on_the_grid_designs_the_lqg_of_its_point(folder, prepared):
    """ρ of Eq. 33 as a design variable: the point's LQG is designed anew (heavier weight, smaller
    gains), its artefact carries it, and the compiled and the Python loop still agree row by row."""
    design = parse_design(_small_design())
    base = prepared.base
    rho = design.control.control_weight
    points = [{"siso_boundary_layer": 1e-4}, {"siso_boundary_layer": 1e-4, "control_weight": 100.0 * rho}]
    lqgs = [ensemble.point_lqg(design, base.setup.model, base.lqg, point) for point in points]
    assert lqgs[0] is base.lqg
    assert np.linalg.norm(lqgs[1].feedback_gain) < 0.5 * np.linalg.norm(base.lqg.feedback_gain)
    artifacts = tuple(ensemble.point_artifact(design, base.setup.model, q, p) for q, p in zip(lqgs, points))
    np.testing.assert_array_equal(artifacts[1].feedback_gain, lqgs[1].feedback_gain)
    base = dataclasses.replace(base, lqgs=tuple(lqgs), artifacts=artifacts, input_columns=())
    compiled = ensemble.run_batch(base, points, [0], np.zeros((1, 0)), prepared.compiled)
    python = ensemble.run_batch(base, points, [0], np.zeros((1, 0)))
    assert [row["energy_measure"] for row in compiled] == [row["energy_measure"] for row in python]
    clqg = [row["energy_measure"] for row in compiled if row["law"] == "cLQG"]
    assert clqg[0] != clqg[1]
    message = _error(folder, _replace("siso_boundary_layer = [1e-4, 1e-3]", "control_weight = [0.0]"))
    assert "grid.control_weight: [0.0]" in message and "must be > 0" in message


def test_a_run_that_cannot_finish_is_a_row_of_nan_not_the_end_of_the_sweep(prepared):
    class Failing:
        def __call__(self, artifact):
            return self

        def run(self, s, law):
            raise ModelError("joint solve did not converge at step 0.001 s (residual 1); reduce the step")

        def run_passive(self, s, name, forces):
            return prepared.compiled(prepared.base.artifacts[0]).run_passive(s, name, forces)

    rows = ensemble.run_batch(prepared.base, prepared.points[:1], [0], prepared.values[:1], Failing())
    by_law = {row["law"]: row for row in rows}
    assert by_law["SISO"]["safe_state_samples"] == by_law["cLQG"]["safe_state_samples"] == ensemble.FAILED
    assert np.isnan(by_law["cLQG"]["energy_measure"]) and np.isfinite(by_law["passive F_max"]["energy_measure"])


def test_friction_from_the_identification_draws_each_factor_within_its_interval(folder):
    """``from = "identification"``: the design's friction identified as ``smartjoint run`` does (here
    its parameters checked on simulated rig records); every factor the file does not give is a
    lognormal of median 1 within the 95 % interval (well identified: σ0 within a few per cent;
    weakly identified: at most a factor 2), the one it gives stays as given."""
    from smartjoint.design.control.friction_uncertainty import MAX_LOG_SIGMA, Z95

    text = _replace("[uncertain.friction]\n", '[uncertain.friction]\nfrom = "identification"\n')
    text = text.replace('sigma0 = { distribution = "uniform", low = 0.95, high = 1.05 }\n', "")
    (folder / "identified.toml").write_text(text)
    ready = prepare(load_sweep(folder / "identified.toml"), progress=lambda line: None)
    drawn = {u.name: u.distribution for u in ready.sweep.inputs if u.name.startswith("friction.")}
    assert drawn["friction.coulomb"].kind == "normal"  # given in the file
    assert {"friction.sigma0", "friction.sigma1", "friction.stribeck"} <= set(drawn)
    for name, d in drawn.items():
        if name != "friction.coulomb" and d.kind == "lognormal":
            assert d.median == 1.0 and 0.0 < d.sigma <= MAX_LOG_SIGMA
            assert d.high == pytest.approx(np.exp(Z95 * d.sigma)) and d.low == pytest.approx(np.exp(-Z95 * d.sigma))
    assert drawn["friction.sigma0"].kind == "lognormal" and drawn["friction.sigma0"].sigma < 0.05
    columns = ready.base.input_columns
    for j, column in enumerate(columns):
        if column.startswith("friction.") and not column.endswith("coulomb"):
            d = drawn[column.replace(".JA.", ".").replace(".JB.", ".")]
            assert np.all((ready.values[:, j] >= d.low) & (ready.values[:, j] <= d.high)), column
    message = _error(folder, text.replace('from = "identification"', 'from = "guess"'))
    assert "uncertain.friction.from: 'guess'" in message and "only 'identification'" in message


def test_placement_candidates_on_the_grid_each_get_their_model_gains_and_rows(folder, prepared):
    """grid.placement: the same joints placed elsewhere (JA moved from L2_0's end to L1_0's start):
    each candidate its own design model, set-up, LQG and artefact; the rows say which; the compiled
    and the Python loop agree; a candidate with other joints is one line."""
    moved = _small_design()
    moved["joints"][0] = {"name": "JA", "member": "L1_0", "end": "start", "type": "A"}
    (folder / "moved.toml").write_text(tomli_w.dumps(moved))
    text = _replace(
        "siso_boundary_layer = [1e-4, 1e-3]", 'siso_boundary_layer = [1e-4]\nplacement = ["small.toml", "moved.toml"]'
    )
    (folder / "placed.toml").write_text(text.replace("samples = 5", "samples = 2"))
    ready = prepare(load_sweep(folder / "placed.toml"), progress=lambda line: None)
    base = ready.base
    assert [p["placement"] for p in ready.points] == [0.0, 1.0]
    assert not np.allclose(base.setups[0].model.joint_input, base.setups[1].model.joint_input)
    assert not np.array_equal(base.artifacts[0].feedback_gain, base.artifacts[1].feedback_gain)
    compiled = ensemble.run_batch(base, ready.points, [0], ready.values[:1], ready.compiled)
    python = ensemble.run_batch(base, ready.points, [0], ready.values[:1])
    assert [r["energy_measure"] for r in compiled] == [r["energy_measure"] for r in python]
    clqg = {r["placement"]: r["energy_measure"] for r in compiled if r["law"] == "cLQG"}
    assert clqg[0.0] != clqg[1.0]
    other = _small_design()
    other["joints"][0]["name"] = "JC"
    (folder / "other.toml").write_text(tomli_w.dumps(other))
    (folder / "bad_place.toml").write_text(text.replace('"moved.toml"', '"other.toml"'))
    with pytest.raises(ModelError, match=r"grid.placement: .*other.toml has joints \['JC', 'JB'\] — a placement must"):
        prepare(load_sweep(folder / "bad_place.toml"), progress=lambda line: None)
    missing = _error(folder, text.replace('"moved.toml"', '"nowhere.toml"'))
    assert "grid.placement: 'nowhere.toml' — no design file" in missing


def test_a_grid_point_against_the_design_limits_is_refused(prepared):
    with pytest.raises(ModelError, match=r"normal_force_min \[500.0, 500.0\] / normal_force_max \[400.0, 400.0\]"):
        ensemble.point_limits(prepared.base.setup, {"normal_force_min": 500.0})
    low, high = ensemble.point_limits(prepared.base.setup, {"normal_force_max": 300.0})
    assert low.tolist() == prepared.base.setup.normal_force_min.tolist() and high.tolist() == [300.0, 300.0]


# -------------------------------------------------------------------------------- the runner
def _bytes(table) -> bytes:
    """The table as Parquet bytes (``Table.equals`` holds NaN unequal to itself)."""
    buffer = io.BytesIO()
    pq.write_table(table, buffer)
    return buffer.getvalue()


@contextlib.contextmanager
def _cluster(scratch):
    """Two single-threaded worker processes whose work files (and Dask's locks) stay in the test's
    folder, as ``run_sweep`` keeps its own."""
    import dask
    from dask.distributed import LocalCluster

    with dask.config.set({"temporary-directory": str(scratch)}):
        with LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0", local_directory=str(scratch)
        ) as cluster:
            yield cluster


@pytest.fixture(scope="module")
def two_workers(tmp_path_factory):
    with _cluster(tmp_path_factory.mktemp("dask")) as cluster:
        yield cluster.scheduler_address


def test_one_and_two_workers_give_identical_tables_and_resume_fills_a_gap(folder, two_workers):
    sweep = load_sweep(folder / "sweep.toml")
    quiet = []
    one = run_sweep(sweep, folder / "one", workers=1, progress=quiet.append)
    two = run_sweep(sweep, folder / "two", scheduler=two_workers, progress=quiet.append)
    assert (one["workers"], two["workers"], one["rows"]) == (1, 2, 5 * 2 * 5)
    assert any("5/5 samples (100 %)" in line and "ETA" in line for line in quiet)
    for k in range(3):  # byte for byte, file by file
        assert batch_path(folder / "one", k).read_bytes() == batch_path(folder / "two", k).read_bytes()
    table = read_results(folder / "one")
    assert _bytes(table) == _bytes(read_results(folder / "two")) and table.num_rows == 50
    assert table.column("sample").to_pylist()[:10] == [0] * 10

    kept = {k: batch_path(folder / "two", k).stat().st_mtime_ns for k in (0, 2)}
    batch_path(folder / "two", 1).unlink()
    again = run_sweep(sweep, folder / "two", scheduler=two_workers, resume=True, progress=quiet.append)
    assert (again["batches_computed"], again["samples_computed"]) == (1, 2)
    assert {k: batch_path(folder / "two", k).stat().st_mtime_ns for k in (0, 2)} == kept
    assert batch_path(folder / "two", 1).read_bytes() == batch_path(folder / "one", 1).read_bytes()

    # Refused before any work: the scheduler it names is never asked (none listens there).
    with pytest.raises(OutputError, match="--resume continues it"):
        run_sweep(sweep, folder / "two", scheduler=f"tcp://127.0.0.1:{_free_port()}", progress=quiet.append)
    (folder / "a-file").write_text("mine")
    with pytest.raises(OutputError, match="is a file — name a folder"):
        run_sweep(sweep, folder / "a-file", scheduler=f"tcp://127.0.0.1:{_free_port()}", progress=quiet.append)
    assert (folder / "a-file").read_text() == "mine"
    other = dataclasses.replace(sweep, seed=21, sha256="0" * 64)
    with pytest.raises(SweepError, match="results of another sweep"):
        run_sweep(other, folder / "two", scheduler=two_workers, resume=True, progress=quiet.append)


def _free_port() -> int:
    with socket.socket() as probe:  # a port nothing listens on once closed
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_an_unreachable_scheduler_fails_within_ten_seconds(folder):
    """Timed in this process (a loaded machine may take seconds just to start an interpreter);
    the command line then refuses with the one line."""
    address = f"tcp://127.0.0.1:{_free_port()}"
    start = time.monotonic()
    with pytest.raises(SweepError, match="cannot reach a Dask scheduler within 3 s"):
        connect(address, None)
    assert time.monotonic() - start < 10.0
    line = cli_error("sweep", str(folder / "sweep.toml"), "--scheduler", address, "-o", str(folder / "x"))
    assert f"smartjoint sweep: error: --scheduler {address}: cannot reach a Dask scheduler within 3 s" in line
    assert not (folder / "x").exists()


def test_the_compiled_loop_gives_the_rows_of_the_python_reference(prepared):
    """Every row of two perturbed samples at both grid points: the compiled closed loop (the
    default where a compiler builds) and the Python reference laws give the same numbers."""
    assert prepared.compiled is not None
    points, values = prepared.points, prepared.values[:2]
    compiled = ensemble.run_batch(prepared.base, points, [0, 1], values, prepared.compiled)
    python = ensemble.run_batch(prepared.base, points, [0, 1], values)
    assert len(compiled) == len(python) == 2 * len(points) * len(prepared.base.laws)
    for c, p in zip(compiled, python):
        assert c.keys() == p.keys()
        assert all(c[k] == p[k] or (c[k] != c[k] and p[k] != p[k]) for k in c), (c, p)


def test_killing_a_worker_mid_sweep_loses_no_sample(folder):
    """One worker process killed (SIGKILL) as soon as the first batch is written: Dask re-runs
    its tasks on the other worker (and the nanny's restarted one); every batch is written and the
    table is the undisturbed run's byte for byte."""
    import os
    import signal

    from dask.distributed import Client

    text = _replace("samples = 5", "samples = 12").replace("batch = 2", "batch = 1")
    (folder / "long.toml").write_text(text)
    sweep = load_sweep(folder / "long.toml")
    killed = []
    with _cluster(folder / "dask") as cluster:
        with Client(cluster) as client:
            victim = next(iter(client.run(os.getpid).values()))

            said = []

            def kill_once(line: str) -> None:
                said.append(line)
                if "samples (" in line and not killed:
                    os.kill(victim, signal.SIGKILL)
                    killed.append(line)

            out = run_sweep(sweep, folder / "killed", scheduler=cluster.scheduler_address, progress=kill_once)
    assert killed and killed[0].lstrip().startswith("1/12 samples")
    assert any("left the cluster (killed or lost)" in line for line in said), said
    assert (out["samples_computed"], out["batches_computed"]) == (12, 12)
    calm = run_sweep(sweep, folder / "calm", workers=1, progress=lambda line: None)
    assert calm["rows"] == out["rows"] == 12 * 2 * 5
    assert _bytes(read_results(folder / "killed")) == _bytes(read_results(folder / "calm"))
