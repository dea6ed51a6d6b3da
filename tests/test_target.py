"""The generated firmware on its target, QEMU's mps2-an386 (Cortex-M4F): the self-test image
built from the SIL bench's float sources computes the host float build's outputs bit for bit,
exits 0 through semihosting, and its measured instructions per step and stack depth are positive
and within generous bounds (bench/target.py, firmware/target/mps2_an386)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smartjoint.bench import firmware, target
from smartjoint.codegen import controllers, generate
from smartjoint.design.control import artifact

ROOT = Path(__file__).resolve().parents[1]
REASON = target.missing_tools()
pytestmark = pytest.mark.skipif(REASON is not None, reason=f"{REASON} (CI installs them)")


@pytest.fixture(scope="module")
def reference():
    return artifact.load(ROOT / "firmware" / "generated" / "controller.json")


@pytest.fixture(scope="module")
def selftest(reference):
    return target.run_selftest(reference, steps=200)


def test_the_target_builds_from_the_sources_the_host_float_build_compiles(reference):
    on_target = firmware.sources(reference, "float", target.PREFIX)
    host = generate.render(reference, "float", target.PREFIX)
    for law in ("clqg", "siso"):
        for name in (f"{target.PREFIX}_{law}.c", f"{target.PREFIX}_{law}.h", f"{target.PREFIX}_types.h"):
            assert on_target[name] == host[name], name


@pytest.mark.numerics
def test_target_outputs_equal_the_host_float_build_bit_for_bit(reference, selftest):
    host = controllers.compile_controllers(reference, "float")
    for law, controller in (("clqg", host.law("clqg")), ("siso", host.law("siso"))):
        outputs, status = controller.run(selftest["inputs"][law])
        expected = outputs.astype(np.float32).view(np.uint32)
        got = selftest["outputs"][law].view(np.uint32)
        assert got.shape == expected.shape == (200, expected.shape[1]), law
        mismatch = np.argwhere(got != expected)
        assert mismatch.size == 0, f"{law}: first differing (step, word) {mismatch[0].tolist()}"
        assert np.array_equal(selftest["status"][law], status), law
    # The sequence exercises the law, not only its safe state (a few inputs are implausible).
    assert (selftest["status"]["clqg"] == 0).mean() > 0.9 and (selftest["status"]["siso"] == 0).mean() > 0.9
    for law in ("clqg", "siso"):
        assert len(np.unique(selftest["outputs"][law][:, 0])) > 20, law


def test_the_program_ends_through_semihosting_with_status_0(selftest):
    assert selftest["exit_code"] == 0
    assert "-icount shift=0" in selftest["command"] and "mps2-an386" in selftest["command"]


def test_instructions_per_step_and_stack_are_measured_and_bounded(selftest):
    assert 200 < selftest["instructions"]["clqg"] < 5000, selftest["instructions"]
    assert 20 < selftest["instructions"]["siso"] < 1000, selftest["instructions"]
    assert selftest["instructions"]["siso"] < selftest["instructions"]["clqg"]
    # The cLQG's output phase alone (a repeated output phase against an empty call): part of the step.
    assert 20 < selftest["instructions"]["clqg_output_phase"] < selftest["instructions"]["clqg"] / 2
    stack = selftest["stack"]
    assert all(0 < stack[part] <= 1024 for part in ("clqg", "siso", "can")), stack
    assert max(stack["clqg"], stack["siso"], stack["can"]) < stack["high_water"] <= 4096, stack
    size = selftest["size"]
    assert 0 < size["firmware_flash"] <= 64 * 1024 and 0 < size["image_flash"] <= 64 * 1024, size
    assert 0 < size["image_ram"] <= 4096, size
