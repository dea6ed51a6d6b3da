"""Issue 19's limits of the product image, held by the figures the benchmarks measure: the whole
float image (controllers + CAN layer + E2E + runtime, -O2, --gc-sections) within 8 KiB of flash
and 512 B of RAM with no double-precision routine linked (benchmarks/firmware_image.py), and the
stack the firmware really uses on the target (painted, bench/pil.py) within 16 B of the static
bound of its deepest CAN entry point — never above it. The figures are deterministic for one
toolchain; a change that grows the image or the stack past them fails here."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from smartjoint.bench import pil, safety, target
from smartjoint.bench.loop import SilLoop
from smartjoint.design.control import artifact

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))  # the measurement machinery of benchmarks/firmware_size.py

from elf_tools import supports_callgraph_info  # noqa: E402
from firmware_image import LIMITS, PRODUCT_WITHOUT, measure_image  # noqa: E402

REFERENCE = artifact.load(ROOT / "firmware" / "generated" / "controller.json")
REASON = target.missing_tools()
pytestmark = pytest.mark.skipif(REASON is not None, reason=f"{REASON} (CI installs them)")


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """The product image (every law but ``PRODUCT_WITHOUT``)."""
    folder = tmp_path_factory.mktemp("image")
    return measure_image(REFERENCE, folder / "image", callgraph=supports_callgraph_info(folder))


@pytest.fixture(scope="module")
def every(tmp_path_factory):
    """The image with every law, as the PIL target builds it."""
    folder = tmp_path_factory.mktemp("every")
    return measure_image(REFERENCE, folder / "image", callgraph=supports_callgraph_info(folder), without=())


def test_the_whole_image_fits_8_kib_of_flash_and_512_b_of_ram_without_a_double_routine(whole, every):
    assert LIMITS == {"flash": 8 * 1024, "ram": 512} and whole["laws_left_out"] == list(PRODUCT_WITHOUT)
    assert whole["flash"] <= LIMITS["flash"] and whole["ram"] <= LIMITS["ram"], (whole["flash"], whole["ram"])
    assert whole["double_routines"] == [] and every["double_routines"] == []
    # leaving a law out of the build leaves its code out (and only that: every law still links)
    assert every["flash"] > whole["flash"] and every["modules_code"].keys() > whole["modules_code"].keys()


def test_the_painted_stack_on_the_target_is_within_16_bytes_below_the_static_bound(every):
    bound, whole = every["stack_max"], every
    with pil.TargetFirmware(REFERENCE, "clqg") as image:
        loop = SilLoop(image, 0.0, channel="smartjoint-image-limits")
        try:
            loop.reset()
            for measurements in safety.signals(None, REFERENCE, 120):
                loop.step(measurements)
        finally:
            loop.close()
        assert not image.safe  # the law ran: the controller step's chain was on the stack
        painted = image.measurements()["stack_high_water"]
    assert bound - 16 <= painted <= bound, (painted, bound, whole["stack"]["step"]["chain"])
