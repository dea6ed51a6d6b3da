"""Identification model consistency (Eq. 3) and the rig/identify command line."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from smartjoint.design import lugre, rig
from smartjoint.design.identify import classify, model_friction, nrmse


@pytest.mark.parametrize("joint_type, inertia", [("A", 1.0), ("B", 2e-3)])
def test_true_parameters_reproduce_noise_free_records(joint_type, inertia):
    p = lugre.TABLE_1[joint_type]
    level = rig.breakaway(p, 400.0)
    micro = rig.simulate(rig.RigTest(joint_type, 400.0, 0.5 * level, 10.0, cycles=1.0, inertia=inertia))
    stick = rig.simulate(rig.RigTest(joint_type, 400.0, 1.1 * level, 5.0, cycles=1.0, inertia=inertia))
    assert classify(micro) == "micro-slip" and classify(stick) == "stick-slip"
    # Equation error (measured v as input) in micro-slip, output error (rig from F_exc) in stick-slip.
    assert nrmse(micro.friction_force, model_friction(p, micro, micro.sliding_velocity, False)[0]) < 0.01
    friction, velocity = model_friction(p, stick, stick.sliding_velocity, True)
    # The floor here is the record's own F_exc − m·a (Savitzky–Golay acceleration at slip onsets).
    assert nrmse(stick.friction_force, friction) < 0.02
    assert nrmse(stick.sliding_velocity, velocity) < 0.01
    # A wrong Coulomb level is visible in the error: the measure discriminates.
    wrong = lugre.LuGreParameters(p.sigma0, p.sigma1, p.sigma2, 1.1 * p.coulomb, p.stribeck, p.stribeck_velocity,
                                  p.radius)
    assert nrmse(stick.friction_force, model_friction(wrong, stick, stick.sliding_velocity, True)[0]) > 0.03


def test_rig_command_writes_a_readable_record(tmp_path):
    target = tmp_path / "r.csv"
    done = subprocess.run([sys.executable, "-m", "smartjoint.cli", "rig", "--type", "A", "--normal-force", "400",
                           "--amplitude", "150", "--frequency", "10", "--cycles", "1", "--noise", "0.01",
                           "-o", str(target), "--json"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["records"][0]["regime"] == "micro-slip"
    from smartjoint.design.records import read_record

    record = read_record(target)
    assert record.inertia == 1.0 and np.all(record.normal_force == 400.0)


def test_identify_refuses_missing_regime(tmp_path):
    target = tmp_path / "micro.csv"
    subprocess.run([sys.executable, "-m", "smartjoint.cli", "rig", "--normal-force", "400", "--amplitude", "150",
                    "--frequency", "10", "--cycles", "1", "-o", str(target)], check=True, capture_output=True)
    done = subprocess.run([sys.executable, "-m", "smartjoint.cli", "identify", str(target)], capture_output=True,
                          text=True)
    assert done.returncode == 2 and "no stick-slip records" in done.stderr

