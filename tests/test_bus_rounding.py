"""The measurements as the bus carries them (bench/bus_rounding.py): the steps and ranges are the
frames' own, every value the controller sees is a whole number of steps within its signal's range
(half to even, as the codec rounds), and a controller sees exactly what the double firmware's
decode gives for the same values."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smartjoint.bench import bus_rounding, firmware
from smartjoint.design.control import artifact
from smartjoint.design.network import plan
from smartjoint.design.plant.interface import Measurements

REFERENCE = Path(__file__).resolve().parents[1] / "firmware" / "generated" / "controller.json"


@pytest.fixture(scope="module")
def reference():
    return artifact.load(REFERENCE)


class Seen:
    sample_time = 1e-3

    def reset(self):
        self.seen = []

    def step(self, m):
        self.seen.append(m)
        return np.zeros(len(m.friction_force))


def test_the_steps_are_the_frames_own(reference):
    steps = bus_rounding.bus_steps([p.database for p in plan.plan(reference).buses], reference)
    assert [s for s, _, _ in steps.sliding_velocity] == [1e-9] * 3
    assert [s for s, _, _ in steps.friction_force] == [1e-5] * 3
    assert [s for s, _, _ in steps.normal_force] == [0.02] * 3 and steps.normal_force[0][1] == 0.0
    assert [s for s, _, _ in steps.sensors] == [1e-8] * 2


def test_every_input_is_a_whole_number_of_steps_within_its_range_as_the_double_decode_gives(reference):
    fw = firmware.Firmware(reference, "siso", "double")
    steps = bus_rounding.bus_steps(fw.databases, reference)
    inner = Seen()
    rounded = bus_rounding.Rounded(inner, steps)
    rounded.reset()
    rng = np.random.default_rng(7)
    frame = fw.db.get_message_by_name("JOINT_A1")
    for _ in range(200):
        v, u, f = rng.uniform(-1e-6, 1e-6), rng.uniform(-600, 600), rng.uniform(-5, 450)
        rounded.step(Measurements(0.0, np.zeros(2), np.array([v, 0, 0]), np.array([u, 0, 0]), np.array([f, 0, 0])))
        seen = inner.seen[-1]
        # the double build packs and decodes the same values: what its law would see
        data = fw.pack("JOINT_A1", {"sliding_velocity": v, "friction_force": u, "normal_force": f})
        decoded = frame.decode(data, decode_choices=False)
        assert seen.sliding_velocity[0] == pytest.approx(decoded["sliding_velocity"], abs=1e-18)
        assert seen.friction_force[0] == pytest.approx(decoded["friction_force"], abs=1e-12)
        assert seen.normal_force[0] == pytest.approx(decoded["normal_force"], abs=1e-12)
        assert seen.normal_force[0] >= 0.0  # held within the signal's range, as the codec clamps
        assert abs(seen.sliding_velocity[0] / 1e-9 - round(seen.sliding_velocity[0] / 1e-9)) < 1e-6
