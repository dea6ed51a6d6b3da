"""The generated C as text against the committed reference firmware (codegen/): rendering is
deterministic and dated nowhere, literals parse back to the rounded value, firmware/generated is
what the generator emits, and the controllers have no dense predictor, heap, recursion or
mutable globals."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from smartjoint.codegen import generate, joint_nodes, rendering
from smartjoint.common import law_registry
from smartjoint.design import load_design
from smartjoint.design.control import artifact
from smartjoint.design.structure import spec

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "firmware" / "generated"


@pytest.fixture(scope="module")
def reference():
    return artifact.load(REFERENCE / "controller.json")


def test_rendering_is_deterministic_and_dated_nowhere(reference):
    first, again = generate.render(reference, "float"), generate.render(reference, "float")
    assert first == again
    double = generate.render(reference, "double")
    assert double != first
    for files in (first, double):
        for name, text in files.items():
            assert not re.search(r"\b20\d\d-\d\d-\d\d\b", text), name
            assert reference.artifact_sha256 in text, name
    assert "typedef float smartjoint_real;" in first["smartjoint_types.h"]
    for name in ("smartjoint_clqg.c", "smartjoint_siso.c", "main.c"):
        code = re.sub(r"/\*.*?\*/", "", first[name], flags=re.S)
        for number, suffix in re.findall(r"(?<![\w.])(\d+\.\d*(?:e[-+]?\d+)?|\d+e[-+]?\d+)(f?)", code):
            assert suffix == "f", (name, number)  # no double constant in the float build


def test_literals_parse_back_to_the_rounded_value():
    rng = np.random.default_rng(0)
    values = np.concatenate([rng.normal(0, 1, 200) * 10.0 ** rng.uniform(-40, 38, 200), [0.0, 1.0, -400.0, 1e-45]])
    for v in values:
        text = rendering.literal(v, "double")
        assert float(text) == float(v) and ("." in text or "e" in text)
        text = rendering.literal(v, "float")
        assert text.endswith("f") and np.float32(text[:-1]) == np.float32(v) and ("." in text or "e" in text)


def test_committed_reference_firmware_is_what_the_generator_emits(reference):
    assert reference.design_sha256 == load_design(spec.REFERENCE_DESIGN.parent / "three_type_a.toml").sha256, (
        "the bundled design changed: regenerate firmware/generated (firmware/README.md)"
    )
    from smartjoint.codegen import can_layer, xcp_slave

    files = generate.firmware_files(reference)  # what `smartjoint codegen` writes
    # …which is the sum of its parts, the example main.c with local mode as the nodes are there.
    parts = {
        **generate.render(reference, "float"),
        **can_layer.render_can(reference, nodes=True),
        **joint_nodes.render_nodes(reference),
        **xcp_slave.render_xcp(reference),
    }
    assert parts == files
    # The A2L's addresses are the linked target image's: they move with the ARM toolchain's
    # version, so it is checked apart (tests/test_xcp.py), not byte for byte.
    committed = {p.name for p in REFERENCE.iterdir()} - {"controller.json", "smartjoint.a2l"}
    assert committed == set(files)
    for name, text in files.items():
        assert (REFERENCE / name).read_bytes() == text.encode("ascii"), name


def test_structure_no_dense_predictor_no_heap_no_recursion(reference):
    files = generate.render(reference, "double")
    text = "".join(files[f"{law.c_name('smartjoint')}.c"] for law in law_registry.LAWS.values())
    n2 = 2 * np.asarray(reference.blocks).shape[0]
    assert f"[{n2}][{n2}]" not in text and "[STATES][STATES]" not in text
    assert not re.search(r"\b(malloc|calloc|realloc|free)\s*\(", text)
    for name in (*(f"{law.c_name('smartjoint')}_step" for law in law_registry.LAWS.values()), "fault"):
        body = text.split(f"{name}(", 1)[1]
        body = body[: body.find("\n}\n")]
        assert f"{name}(" not in body  # no recursion
    # No mutable globals: static data is const; the one object each law exports is its const
    # default parameters.
    assert not re.search(r"^static (?!const )[^(]*;", text, flags=re.M)
    assert "TUNABLE" not in text + files["smartjoint_types.h"]
    exported = re.findall(r"^(?!static\b)\w[\w ]*? (\w+)\s*=", text, flags=re.M)
    assert exported == [f"{law.c_name('smartjoint')}_default_params" for law in law_registry.LAWS.values()]
    assert all(
        f"const {law.c_name('smartjoint')}_params {law.c_name('smartjoint')}_default_params = {{" in text
        for law in law_registry.LAWS.values()
    )
    # Every law's tunables are one struct handed to _init (the FMU's convention): its limits and
    # one field per setting, in the entry's order.
    for law in law_registry.LAWS.values():
        name = law.c_name("smartjoint")
        header = files[f"{name}.h"]
        body = re.search(r"typedef struct \{([^}]*)\} " + name + "_params;", header)
        assert body is not None, law.name
        fields = re.findall(r"_real (\w+)[\[;]", body.group(1))
        # (a law's own F_N^min, Setting.lower_force, is the normal_force_min there)
        settings = (setting.key for setting in law.settings if not setting.lower_force)
        assert fields == ["normal_force_min", "normal_force_range", *settings]
        assert f"void {name}_init({name}_state *state, const {name}_params *params);" in header
