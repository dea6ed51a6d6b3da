"""Rig model against a Radau reference; friction records round-trip and refuse bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from smartjoint.design import lugre, rig
from smartjoint.design.records import RecordError, read_record, write_record


def test_rig_matches_radau_reference():
    p = lugre.TYPE_A
    test = rig.RigTest("A", 400.0, 1.2 * rig.breakaway(p, 400.0), 10.0, cycles=1.0, inertia=1.0, sample_rate=5000.0)
    record = rig.simulate(test)
    gain = 400.0

    def f(t, s):
        _, v, phi = s
        return [v, (test.amplitude * np.sin(2 * np.pi * 10.0 * t) - gain * lugre.friction_coefficient(p, v, phi)) / 1.0,
                lugre.rhs(p, v, phi)]

    reference = solve_ivp(f, (0, record.time[-1]), [0, 0, 0], method="Radau", t_eval=record.time, rtol=1e-11,
                          atol=[1e-13, 1e-13, 1e-14], max_step=1e-4)
    scale = np.abs(reference.y[1]).max()
    assert np.abs(record.sliding_velocity - reference.y[1]).max() < 1e-3 * scale
    assert record.metadata["regime"] == "stick-slip"


def test_record_round_trip(tmp_path):
    record = rig.simulate(rig.RigTest("B", 300.0, 0.5, 8.0, cycles=1.0, inertia=2e-3, sample_rate=2000.0, noise=0.01))
    path = tmp_path / "r.csv"
    write_record(record, path)
    again = read_record(path)
    assert again.joint_type == "B" and again.inertia == record.inertia
    np.testing.assert_array_equal(again.sliding_velocity, record.sliding_velocity)
    np.testing.assert_allclose(again.friction_force, record.friction_force, rtol=1e-12, atol=1e-12)


GOOD = "# joint_type = A\n# inertia = 1.0 kg\ntime [s],sliding_velocity [m/s],excitation_force [N],normal_force [N]\n"


@pytest.mark.parametrize("text, message", [
    ("time [s],sliding_velocity [m/s],normal_force [N]\n0,0,1\n1,0,1\n2,0,1\n", "needs column 'friction_force'"),
    (GOOD.replace(",normal_force [N]", "") + "0,0,1\n1,0,1\n2,0,1\n", "column 'normal_force' missing"),
    (GOOD + "0,0,1,400\n1,nan,1,400\n2,0,1,400\n", "row 5, column 'sliding_velocity': nan m/s"),
    (GOOD + "0,0,1,400\n1,0,1,400\n1,0,1,400\n", "row 6, column 'time': 1 after 1 — time does not increase"),
    (GOOD + "0,0,1,400\n1,0,1\n2,0,1,400\n", "row 5 has 3 fields"),
    (GOOD.replace("[m/s]", "[furlong/s]") + "0,0,1,400\n1,0,1,400\n2,0,1,400\n", "unit 'furlong/s' unknown"),
    (GOOD.replace("# inertia = 1.0 kg\n", "") + "0,0,1,400\n1,0,1,400\n2,0,1,400\n", "needs the '# inertia"),
])
def test_bad_records_name_file_and_column(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(RecordError) as info:
        read_record(path)
    assert message in str(info.value) and "bad.csv" in str(info.value)
