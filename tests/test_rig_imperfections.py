"""Records as a real rig gives them (issue 30): a shaker with harmonics, a drifting preload
recorded by its load cell, sensors with a resolution and a noise floor — and what the
identification does with them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from smartjoint.design.friction import lugre, rig
from smartjoint.design.friction.fitting import excitation_drive
from smartjoint.design.friction.identify import identify
from smartjoint.design.friction.rig_imperfections import RigImperfections, excitation
from smartjoint.design.friction.sequential_campaign import TARGETED, run_sequential

TRUTH_A = lugre.LuGreParameters(
    sigma0=3e5, sigma1=0.05, sigma2=0.02, coulomb=0.8, stribeck=0.3, stribeck_velocity=0.005
)
# A relaxing preload (−3 % over each record), a shaker with 2nd and 3rd harmonics, 16-bit-like
# resolution and a noise floor on every channel.
REAL = RigImperfections(-0.03, ((2, 0.05), (3, 0.02)), (1e-5, 0.03, 0.1), (2e-5, 0.2, 0.5))


def test_a_real_rig_records_the_drifting_preload_and_its_sensors_resolution():
    test = rig.RigTest(
        "A", 400.0, 1.3 * rig.breakaway(TRUTH_A, 400.0), 10.0, cycles=4, inertia=20.0, imperfections=REAL
    )
    record = rig.simulate(test, TRUTH_A)
    start, end = np.mean(record.normal_force[:200]), np.mean(record.normal_force[-200:])
    assert start == pytest.approx(400.0, abs=0.2) and end == pytest.approx(400.0 * 0.97, abs=0.2)
    for column, step in ((record.sliding_velocity, 1e-5), (record.excitation_force, 0.03), (record.normal_force, 0.1)):
        assert np.allclose(column / step, np.round(column / step), atol=1e-6)  # on the ADC's grid
    ideal = rig.simulate(dataclasses.replace(test, imperfections=RigImperfections()), TRUTH_A)
    assert np.all(ideal.normal_force == 400.0) and "imperfections" not in ideal.metadata


@pytest.mark.parametrize(
    "field, value, says",
    [
        ("normal_force_drift", 0.8, "normal_force_drift: 0.8 — allowed: −0.5 … 0.5"),
        ("harmonics", ((1, 0.1),), "harmonics: order 1 — allowed: an integer 2 … 10"),
        ("harmonics", ((3, float("nan")),), "harmonics: amplitude nan"),
        ("resolution", (1e-5, -1.0, 0.1), "resolution of the excitation force: -1.0 — allowed: a finite number >= 0"),
        ("noise_floor", (0.0, 0.0), "noise_floor: (0.0, 0.0) — allowed: one value per channel"),
    ],
)
def test_bad_imperfections_are_refused_in_one_line(field, value, says):
    test = rig.RigTest("A", 400.0, 100.0, 10.0, imperfections=dataclasses.replace(REAL, **{field: value}))
    with pytest.raises(rig.RigError) as error:
        rig.simulate(test, TRUTH_A)
    assert says in str(error.value) and "\n" not in str(error.value)


@pytest.mark.parametrize("harmonics", [((4, 0.05),), ((7, 0.05),), ()])
def test_the_output_error_drive_keeps_the_shaker_s_harmonics_and_drops_its_noise(harmonics):
    """The drive of the output-error model is the applied force within 0.1 % RMS at 1 % sensor
    noise: a 4th harmonic (which the 5× low-pass would attenuate by 14 %) and a 7th (which it
    would remove) are fitted at their exact frequency and kept."""
    real = RigImperfections(harmonics=harmonics)
    test = rig.RigTest("A", 400.0, 1.3 * rig.breakaway(TRUTH_A, 400.0), 10.0, cycles=8, inertia=20.0, noise=0.01,
                       imperfections=real)  # fmt: skip
    record = rig.simulate(test, TRUTH_A)
    drive, frequency = excitation_drive(record)
    applied = excitation(real, test.amplitude, 2 * np.pi * test.frequency, record.time)
    assert frequency == pytest.approx(10.0, rel=1e-4)
    assert np.sqrt(np.mean((drive - applied) ** 2)) < 1e-3 * np.sqrt(np.mean(applied**2))


@pytest.mark.numerics
def test_the_identification_uses_the_measured_normal_force():
    """With the measured F_N(t) the realistic records identify σ0, F_c, F_d, v_s within 1.5 %
    inside their intervals; read with the nominal F_N instead (the preload's drift ignored),
    F_c and F_d come out biased by more than 1.5 %."""
    result = run_sequential(
        "A", TRUTH_A, lambda test, name: rig.simulate(dataclasses.replace(test, imperfections=REAL), TRUTH_A),
        noise=0.01, replicates=0,
    )  # fmt: skip
    identification = result.identification
    entries = identification.parameter_entries()
    for name in TARGETED:
        true, (lower, upper) = getattr(TRUTH_A, name), entries[name]["ci95"]
        assert abs(entries[name]["value"] / true - 1.0) < 0.015, name
        assert lower <= true <= upper, name

    def nominal(record):
        return dataclasses.replace(
            record, normal_force=np.full(record.time.size, 400.0 if "FN400" in record.name else 200.0)
        )

    micro = [nominal(identification.records[n]) for n in identification.micro.nrmse]
    stick = [nominal(identification.records[n]) for n in identification.stick.nrmse]
    biased = identify(micro, stick).parameters
    assert abs(biased.coulomb / TRUTH_A.coulomb - 1.0) > 0.015
    assert abs(biased.stribeck / TRUTH_A.stribeck - 1.0) > 0.015
