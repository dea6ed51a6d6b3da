"""The FMUs in a second FMI importer whose master steps every FMU and then passes outputs on:
libcosim (Open Simulation Platform) through libcosimpy. There a command reaches the plant one step
after its measurements, whatever the FMU; the controller FMU's ``held`` variant makes that delay
exact, and the model-in-the-loop study with the same one-sample delay (``DelayedCommand``) is then
the co-simulation number for number in the double build, and within the float bound per command
in the float build (docs/fmu.md)."""

from __future__ import annotations

import dataclasses
import os
import platform

import numpy as np
import pytest

from smartjoint.bench import libcosim_master
from smartjoint.bench.fmu_check import FLOAT_BOUND, LAWS
from smartjoint.codegen import fmu
from smartjoint.design.control import artifact_building, runs
from smartjoint.design.control import study as closed_loop
from smartjoint.design.plant.interface import Measurements

if platform.machine() == "x86_64" and (os.environ.get("CI") or os.environ.get("SMARTJOINT_REQUIRE_FUZZ")):
    import libcosimpy  # noqa: F401  (a test dependency on x86-64: here it must be installed)
else:
    pytest.importorskip("libcosimpy")

# Not joint_force: the study records u_R = F_N·μ after the sample's new F_N is applied, libcosim's
# observer before (it samples outputs after a step, before the transfer); the law reads the latter
# in both, which the equal energies, sensors and forces show.
FIELDS = ("time", "energy", "sensors", "normal_force", "sliding_velocity")


@pytest.fixture(scope="module")
def written(three_type_a, tmp_path_factory):
    """The paper's three joints, a 1-s study, its artefact; the plant FMU and both laws' held
    controller FMUs (FMI 2, double and float)."""
    design, _ = three_type_a
    design = dataclasses.replace(design, control=dataclasses.replace(design.control, study_duration=1.0))
    s = closed_loop.run_study(design, progress=lambda message: None)
    artifact = artifact_building.from_design(design, s.setup.model, s.lqg, s.settings())
    folder = tmp_path_factory.mktemp("libcosim")
    out = {"setup": s.setup, "artifact": artifact, "plant": fmu.plant_fmu(s.setup, design, folder / "truss.fmu", 2)}
    for law in ("siso", "clqg"):
        for real in ("double", "float"):
            out[law, real] = fmu.controller_fmu(artifact, law, folder / f"{law}_{real}.fmu", 2, real,
                                                stop_time=1.0, exchange="held")  # fmt: skip
    return out


def _delayed_mil(written, name: str) -> runs.Run:
    setup, artifact = written["setup"], written["artifact"]
    law = runs.DelayedCommand(LAWS[name][1](artifact), setup.normal_force_max)
    return closed_loop.run_semi_active(setup, name, law)


@pytest.mark.parametrize("name", ["SISO", "cLQG"])
def test_libcosim_with_the_held_controller_is_the_delayed_study_number_for_number(written, name):
    law = LAWS[name][0]
    run = libcosim_master.cosimulate(written["setup"], written["plant"].path, written[law, "double"].path, name)
    mil = _delayed_mil(written, name)
    for field in FIELDS:
        assert np.array_equal(getattr(run, field), getattr(mil, field)), field
    assert run.energy_measure() == mil.energy_measure()
    # The delay is real and small: the study without it (the firmware's timing) is another trajectory.
    plain = closed_loop.run_semi_active(written["setup"], name, LAWS[name][1](written["artifact"]))
    assert not np.array_equal(plain.energy, mil.energy)


@pytest.mark.parametrize("name", ["SISO", "cLQG"])
def test_the_float_build_in_libcosim_commands_within_the_float_bound(written, name):
    """The float FMU's command at every sample after the pulse against the Python reference law fed
    the same measurements (those the FMU read in the co-simulation): within FLOAT_BOUND·(F^max − F^min)."""
    setup, artifact = written["setup"], written["artifact"]
    run = libcosim_master.cosimulate(setup, written["plant"].path, written[LAWS[name][0], "float"].path, name)
    law = LAWS[name][1](artifact)
    law.reset()
    span = float(np.min(np.asarray(artifact.normal_force_max) - np.asarray(artifact.normal_force_min)))
    held = int(round(runs.PULSE_DURATION / setup.sample_time))
    worst, compared = 0.0, 0
    for k in range(len(run.time) - 2):
        applied_before = run.normal_force[k - 1] if k else np.asarray(setup.normal_force_max, dtype=float)
        measured = Measurements(run.time[k], run.sensors[k], run.sliding_velocity[k], run.joint_force[k],
                                applied_before)  # fmt: skip
        command = np.asarray(law.step(measured), dtype=float)
        if k + 1 >= held:  # the command of sample k acts from k + 1 on, once the pulse's hold is off
            worst = max(worst, float(np.max(np.abs(command - run.normal_force[k + 1]))))
            compared += 1
    assert compared > 900 and worst <= FLOAT_BOUND * span, (worst, FLOAT_BOUND * span)
