"""Controller design artefact: exact round trip, canonical text, provenance hashes, validation."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path

import numpy as np
import pytest
from conftest import SLIP_RATIO_LAW, SLIP_RATIO_SETTINGS

from smartjoint.common import law_registry, output_path
from smartjoint.common.errors import ModelError
from smartjoint.design import control, plant
from smartjoint.design.control import artifact, artifact_building, artifact_layout, tuning
from smartjoint.design.control.filter import active_lqg, clipped_lqg
from smartjoint.design.control.laws import siso_law
from smartjoint.design.structure import modal
from smartjoint.design.structure.fem import build_model
from smartjoint.design.structure.spec import load_design, parse_design

DOCS = Path(__file__).resolve().parents[1] / "docs" / "controller-artifact.md"


@pytest.fixture(scope="module")
def setup():
    from conftest import small_truss

    design = parse_design(small_truss())
    fe = build_model(design, joints="released")
    model = modal.modal_model(fe, modal.solve_modes(fe, 8))
    lqg = control.design_lqg(model, design.control.sample_time)
    return (
        design,
        model,
        lqg,
        artifact_building.from_design(
            design, model, lqg, {"siso": {"boundary_layer": [1e-3, 2e-3]}, "slipratio": SLIP_RATIO_LAW}
        ),
    )


def _mutated(built, change) -> str:
    """The artefact's text with ``change`` made to its fields by their Python names (then laid
    out in sections again; a field it removes is missing there, one it adds stands at the top)."""
    flat = artifact_layout.flatten(json.loads(artifact.dumps(built)))
    change(flat)
    nested: dict = {"schema_version": flat.pop("schema_version")} if "schema_version" in flat else {}
    for section, keys in artifact_layout.LAYOUT.items():
        target = nested
        for part in section.split("."):
            target = target.setdefault(part, {})
        target.update({key: flat.pop(field) for key, field in keys if field in flat})
    return json.dumps({**nested, **flat})


def test_round_trip_is_exact_and_the_text_canonical(setup, tmp_path):
    _, model, lqg, built = setup
    path = artifact.save(built, tmp_path / "controller.json")
    loaded = artifact.load(path)
    assert loaded == built and loaded is not built
    assert artifact.dumps(loaded) == artifact.dumps(built) == path.read_text()
    assert hashlib.sha256(path.read_bytes()).hexdigest() == built.artifact_sha256 == loaded.artifact_sha256
    assert np.array_equal(loaded.feedback_gain, lqg.feedback_gain) and not loaded.feedback_gain.flags.writeable
    assert loaded.joint_names == ("JA", "JB") and loaded.sensor_names == ("tip_y", "tip_vz")
    assert np.array_equal(loaded.modal_frequencies, model.omega / (2 * np.pi))
    assert loaded.schema_version == artifact.SCHEMA_VERSION and loaded.package_version
    assert artifact.dumps(built).endswith("}\n")
    assert loaded != dataclasses.replace(built, clqg_boundary_layer=6.0)


@pytest.mark.numerics
def test_rebuilt_controllers_match_the_originals_bit_for_bit(setup, tmp_path):
    design, _, lqg, built = setup
    loaded = artifact.load(artifact.save(built, tmp_path / "c.json"))
    low, high = np.full(2, design.control.normal_force_min), np.full(2, design.control.normal_force_max)
    pairs = [
        (control.SisoLaw(lqg.sample_time, low, high, [1e-3, 2e-3]), siso_law(loaded)),
        (
            control.ClippedLqg(
                lqg, low, high, tuning.tuned(law_registry.LAWS["clqg"], design).settings["boundary_layer"]
            ),
            clipped_lqg(loaded),
        ),
        (control.ActiveLqg(lqg), active_lqg(loaded)),
    ]
    rng = np.random.default_rng(7)
    steps = [
        plant.Measurements(
            k * 1e-3,
            1e-3 * rng.standard_normal(2),
            1e-2 * rng.standard_normal(2),
            50.0 * rng.standard_normal(2),
            rng.uniform(40.0, 400.0, 2),
        )
        for k in range(200)
    ]
    for original, rebuilt in pairs:
        original.reset(), rebuilt.reset()
        for m in steps:
            assert original.step(m).tobytes() == rebuilt.step(m).tobytes()
    assert np.all(np.isnan(artifact.lqg_design(loaded).riccati_control))  # not stored, never read
    assert np.array_equal(artifact.lqg_design(loaded).closed_loop_poles(), lqg.closed_loop_poles())


def test_design_file_changes_reach_both_hashes(setup, tmp_path):
    import tomli_w
    from conftest import small_truss

    _, model, lqg, _ = setup
    path = tmp_path / "small.toml"

    def build(data):
        path.write_text(tomli_w.dumps(data))
        return artifact_building.from_design(
            load_design(path), model, lqg, {"siso": {"boundary_layer": 1e-3}, "slipratio": SLIP_RATIO_LAW}
        )

    data = small_truss()
    first, again = build(data), build(data)
    assert artifact.dumps(first) == artifact.dumps(again) and first.design_source == path.name
    data["point_masses"][0]["mass"] = 0.51
    changed = build(data)
    assert changed.design_sha256 != first.design_sha256 and len(changed.design_sha256) == 64
    assert changed.artifact_sha256 != first.artifact_sha256


def test_controlled_joints_set_the_order_and_limits_broadcast(setup):
    from conftest import small_truss

    design, model, lqg, _ = setup
    data = small_truss()
    data["control"] = {
        "joints": ["JB", "JA"],
        "normal_force_min": [10.0, 20.0],
        "normal_force_max": 300.0,
        "siso_boundary_layer": 4e-3,
        **SLIP_RATIO_SETTINGS,
    }
    swapped = parse_design(data)
    with pytest.raises(ModelError, match="model: joints.*'JB', 'JA'"):
        artifact_building.from_design(swapped, model, lqg)
    order = [1, 0]
    reordered = dataclasses.replace(model, joint_input=model.joint_input[:, order], joint_names=["JB", "JA"])
    built = artifact_building.from_design(swapped, reordered, control.design_lqg(reordered, 1e-3))
    assert built.joint_names == ("JB", "JA")
    assert built.normal_force_min.tolist() == [10.0, 20.0] and built.normal_force_max.tolist() == [300.0, 300.0]
    assert built.siso_boundary_layer.tolist() == [4e-3, 4e-3]
    with pytest.raises(ModelError, match="siso_boundary_layer: missing"):
        artifact_building.from_design(design, model, lqg)
    with pytest.raises(ModelError, match="siso_boundary_layer.*one per joint"):
        artifact_building.from_design(
            design, model, lqg, {"siso": {"boundary_layer": [1e-3, 1e-3, 1e-3]}, "slipratio": SLIP_RATIO_LAW}
        )
    with pytest.raises(ModelError, match="lqg.sample_time"):
        artifact_building.from_design(
            design,
            model,
            control.design_lqg(model, 5e-4),
            {"siso": {"boundary_layer": 1e-3}, "slipratio": SLIP_RATIO_LAW},
        )
    with pytest.raises(ModelError, match="lqg.output.*one per sensor"):
        artifact_building.from_design(
            dataclasses.replace(design, sensors=design.sensors[:1]),
            model,
            lqg,
            {"siso": {"boundary_layer": 1e-3}, "slipratio": SLIP_RATIO_LAW},
        )


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d.update(schema_version=8), r"schema_version: 8 — unknown; this version reads schema_version 7"),
        (
            lambda d: d.update(schema_version=3),
            r"schema_version: 3 — .* flat, without the sections of version 4: re-run `smartjoint design` to write "
            r"version 7",
        ),
        (lambda d: d.update(schema_version=1), r"schema_version: 1 — .* re-run `smartjoint design`"),
        (
            lambda d: d.update(schema_version=2),
            r"schema_version: 2 — .* without the joints' friction: re-run `smartjoint design`",
        ),
        (lambda d: d.update(joint_types=["A", "C"]), r"joint_types\[1\]: 'C' — joint 'JB': allowed: A, B"),
        (
            lambda d: d["friction_parameters"][0].__setitem__(0, 0.0),
            r"friction_parameters\[0\].*σ0, F_c, v_s must be > 0",
        ),
        (
            lambda d: d.update(friction_radius=[0.0, 0.0]),
            r"friction_radius\[1\]: 0.0 — joint 'JB': > 0 \[m\] for type B",
        ),
        (lambda d: d.update(friction_sources=["x"]), r"friction_sources: 1 entries — expected one per joint \(l = 2\)"),
        (
            lambda d: d.update(safe_normal_force=[5.0, 400.0]),
            r"safe_normal_force\[0\]: 5.0 N for joint 'JA' — must lie "
            r"within \[normal_force_min, normal_force_max\]",
        ),
        (lambda d: d.update(sensor_quantities=["displacement", "speed"]), r"sensor_quantities\[1\]: 'speed' — allowed"),
        (
            lambda d: d.update(sensor_quantities=["displacement"]),
            r"sensor_quantities: 1 entries — expected one per sensor",
        ),
        (lambda d: d.update(measured_normal_force_max=[100.0, 500.0]), r"measured_normal_force_max\[0\]: 100.0 N"),
        (lambda d: d.update(sliding_velocity_limit=[0.0, 1.0]), r"sliding_velocity_limit\[0\]: 0.0 for joint 'JA'"),
        (lambda d: d.pop("schema_version"), r"schema_version: missing"),
        (lambda d: d.pop("feedback_gain"), r"laws.clqg.feedback_gain: missing — required field"),
        (lambda d: d.pop("siso_boundary_layer"), r"laws.siso.boundary_layer: missing — required field"),
        (
            lambda d: d.update(feedback_gain=[row[:-1] for row in d["feedback_gain"]]),
            r"feedback_gain: shape \(2, 15\) — expected \(2, 16\) = \(l, 2n\)",
        ),
        (lambda d: d["estimator_gain"][3].__setitem__(1, float("nan")), r"estimator_gain: nan at index \(3, 1\)"),
        (
            lambda d: d.update(normal_force_min=[500.0, 40.0]),
            r"normal_force_min/normal_force_max: 500.0/400.0 N .*'JA'",
        ),
        (lambda d: d.update(joint_names=["JA", "JA"]), r"joint_names\[1\]: 'JA' — duplicate"),
        (lambda d: d.update(sensor_names=["tip_y", ""]), r"sensor_names\[1\]: '' — expected a non-empty string"),
        (lambda d: d.update(sample_time=0.0), r"sample_time: 0.0 — must be > 0 \[s\]"),
        (lambda d: d.update(sample_time="1e-3"), r"sample_time: '1e-3' — expected a number"),
        (lambda d: d.update(siso_boundary_layer=[1e-3, -1.0]), r"siso_boundary_layer: -1.0 for joint 'JB'"),
        (lambda d: d.update(gamma0=[[1.0, 2.0], [3.0]]), r"gamma0: .* rectangular"),
        (lambda d: d["blocks"][0][0].__setitem__(0, True), r"blocks: True — expected a \(nested\) list of numbers"),
        (lambda d: d.update(extra=1), r"extra: 1 — unknown section in schema_version 7"),
        (lambda d: d.update(design_sha256="abc"), r"design_sha256: 'abc'"),
    ],
)
def test_invalid_artefacts_are_named(setup, change, message):
    with pytest.raises(ModelError, match=message):
        artifact.loads(_mutated(setup[3], change))


def test_bad_text_and_files_raise_model_errors(setup, tmp_path, monkeypatch):
    built = setup[3]
    for text, message in (
        ('{"schema_version": 1,', "not valid JSON"),
        ("[1, 2]", "expected a JSON object"),
        ('{"schema_version": 2, "schema_version": 2}', "schema_version: 2 — duplicate key"),
    ):
        with pytest.raises(ModelError, match=message):
            artifact.loads(text)
    with pytest.raises(ModelError, match="missing.json: cannot read"):
        artifact.load(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text(_mutated(built, lambda d: d.update(piezo_preload=-1.0)))
    with pytest.raises(ModelError, match=r"bad.json: piezo_preload: -1.0 — must be >= 0"):
        artifact.load(bad)

    folder = tmp_path / "out"
    folder.mkdir()
    path = artifact.save(built, folder / "controller.json")

    def failing_replace(*args):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(output_path.os, "replace", failing_replace)  # the output rule's one rename
    with pytest.raises(ModelError, match="controller.json: cannot write controller artefact"):
        artifact.save(dataclasses.replace(built, clqg_boundary_layer=9.0), path)
    monkeypatch.undo()
    assert os.listdir(folder) == ["controller.json"] and path.read_text() == artifact.dumps(built)
    with pytest.raises(ModelError, match="cannot write"):
        artifact.save(built, tmp_path / "absent" / "controller.json")
    assert not (tmp_path / "absent").exists()


def test_the_documentation_lists_every_field():
    text = DOCS.read_text(encoding="utf-8")
    for spec in artifact.SCHEMA:
        key = spec.name if spec.name == "schema_version" else artifact_layout.path_of(spec.name)
        assert f"| `{key}` |" in text, key


def _sections(built) -> dict:
    return json.loads(artifact.dumps(built))


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d["safety"].update(extra=1), r"safety.extra: 1 — unknown key in section safety"),
        (lambda d: d["laws"]["siso"].update(blocks=[]), r"laws.siso.blocks: \[\] — unknown key in section laws.siso"),
        (lambda d: d["laws"].update(lqr={}), r"laws.lqr: \{\} — unknown law; allowed: siso, clqg, preset, slipratio"),
        (lambda d: d.pop("network"), r"network: missing — required section"),
        (lambda d: d["laws"].pop("clqg"), r"laws.clqg: missing — required section"),
        (lambda d: d.update(common=[1]), r"common: \[1\] — expected a JSON object"),
        (lambda d: d.update(laws=[]), r"laws: \[\] — expected a JSON object \(a section\)"),
    ],
)
def test_the_sections_are_checked_by_their_paths(setup, change, message):
    data = _sections(setup[3])
    change(data)
    with pytest.raises(ModelError, match=message):
        artifact.loads(json.dumps(data))


def test_every_law_of_the_registry_has_its_section_and_every_field_one_place(setup):
    from smartjoint.common import law_registry

    data = _sections(setup[3])
    assert set(data) == {"schema_version", "common", "safety", "friction", "network", "laws"}
    assert list(data["laws"]) == sorted(law_registry.NAMES)  # canonical text: sorted keys
    for law in law_registry.LAWS.values():
        assert sorted(data["laws"][law.name]) == sorted(key for key, _ in law.artifact)
    placed = [field for keys in artifact_layout.LAYOUT.values() for _, field in keys]
    assert sorted(placed) == sorted(spec.name for spec in artifact.SCHEMA if spec.name != "schema_version")
    assert artifact_layout.path_of("siso_boundary_layer") == "laws.siso.boundary_layer"


def test_the_shipped_json_schema_is_the_layout_and_accepts_the_artefacts(setup):
    """The JSON Schema in the package is what the layout gives, and a standard validator accepts
    the bundled firmware's artefact and a built one, and refuses a key out of place."""
    import jsonschema

    from smartjoint.common import package_data

    shipped = json.loads(package_data.path("smartjoint.design.control", "controller-artifact.schema.json").read_text())
    assert shipped == artifact_layout.json_schema()
    jsonschema.Draft202012Validator.check_schema(shipped)
    reference = Path(__file__).resolve().parents[1] / "firmware" / "generated" / "controller.json"
    for data in (json.loads(reference.read_text()), _sections(setup[3])):
        jsonschema.validate(data, shipped)
    wrong = _sections(setup[3])
    wrong["common"]["boundary_layer"] = 1.0
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(wrong, shipped)
