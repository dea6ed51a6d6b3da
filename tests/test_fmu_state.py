"""FMU states and ranges (codegen/fmu.py, templates/fmu/fmu_state.c.j2, issue 37): a saved state
is this FMU's own or refused (size, format tag, checksum, values), and tunables and inputs outside
their documented ranges are refused and not taken, for the plant and the controller FMUs, FMI 2
and FMI 3."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from conftest import small_control_truss
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException

from smartjoint.bench.cosimulation import FmuInstance
from smartjoint.codegen import fmu
from smartjoint.design import parse_design
from smartjoint.design.control import artifact_building
from smartjoint.design.control import study as closed_loop

VERSIONS = (2, 3)
KINDS = ("truss", "siso", "clqg")
HEADER, CHECKSUM = 64, 8  # bytes of the format tag before the model and of the FNV-1a 64 after it


@pytest.fixture(scope="module")
def small():
    """The small truss with two joints (F_N 5 ... 100 N, margin 0.1), a 0.3-s study."""
    design = parse_design(small_control_truss(0.3, krylov=1, siso_boundary_layer=1e-4))
    s = closed_loop.run_study(design, progress=lambda message: None)
    return design, s, artifact_building.from_design(design, s.setup.model, s.lqg, s.settings())


@pytest.fixture(scope="module")
def fmus(small, tmp_path_factory):
    """Plant, SISO and cLQG (double) in FMI 2 and 3; the held cLQG, the preset and the slip-ratio law in FMI 2."""
    design, s, a = small
    folder = tmp_path_factory.mktemp("state_fmus")
    out = {}
    for version in VERSIONS:
        out[version, "truss"] = fmu.plant_fmu(s.setup, design, folder / f"truss{version}.fmu", version)
        for law in ("siso", "clqg"):
            out[version, law] = fmu.controller_fmu(a, law, folder / f"{law}{version}.fmu", version)
    out[2, "held"] = fmu.controller_fmu(a, "clqg", folder / "held.fmu", 2, exchange="held")
    for law in ("preset", "slipratio"):
        out[2, law] = fmu.controller_fmu(a, law, folder / f"{law}.fmu", 2)
    return out


def fnv1a64(data: bytes) -> int:
    """FNV-1a, 64 bits, as the FMU computes its checksum."""
    value = 0xCBF29CE484222325
    for byte in data:
        value = ((value ^ byte) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return value


def forged(blob: bytes, model: bytes) -> bytes:
    """``blob``'s format tag with another model and a checksum that matches it."""
    body = blob[:HEADER] + model
    return body + struct.pack("=Q", fnv1a64(body))


def replaced(blob: bytes, old: float, new: float) -> bytes:
    """A forged state: the one double ``old`` of the model replaced by ``new``, the checksum made to match."""
    model = blob[HEADER:-CHECKSUM]
    pattern = struct.pack("=d", old)
    assert model.count(pattern) == 1, old
    return forged(blob, model.replace(pattern, struct.pack("=d", new)))


class States:
    """An instance's FMU-state calls, FMI 2 and FMI 3 alike."""

    def __init__(self, instance: FmuInstance):
        f, three = instance.fmu, instance.version == 3
        self.get = f.getFMUState if three else f.getFMUstate
        self.set = f.setFMUState if three else f.setFMUstate
        self.serialize = f.serializeFMUState if three else f.serializeFMUstate
        self.deserialize = f.deserializeFMUState if three else f.deSerializeFMUstate


def refused(instance: FmuInstance, call, *words: str) -> None:
    """``call()`` answers the FMI error status and logs one message with ``words``."""
    before = len(instance.messages)
    with pytest.raises(FMICallException) as raised:
        call()
    assert raised.value.status == 3  # fmi2Error = fmi3Error = 3, never OK and never out of range
    logged = [text for status, text in instance.messages[before:] if status == 3]
    assert len(logged) == 1 and all(w in logged[0] for w in words), (logged, words)


def _outputs(instance: FmuInstance) -> list[int]:
    return [v.valueReference for v in instance.description.modelVariables
            if v.causality == "output" and v.type in ("Real", "Float64")]  # fmt: skip


def _run(instance: FmuInstance, start: int, count: int, step: float) -> bytes:
    """The real outputs and the step status over ``count`` steps from step ``start``, as bytes."""
    rows = []
    status = instance.variables.get("CONTROLLER_STATUS.step_status")
    for k in range(start, start + count):
        rows.append(instance.get_real(_outputs(instance)))
        if status is not None:
            assert 0 <= instance.get_integer([status.valueReference])[0] <= 15
        instance.step(k * step, step)
    return np.array(rows).tobytes()


def _blob(fmus, version: int, kind: str) -> bytes:
    """A state of another instance of an FMU, serialised after ten steps."""
    with FmuInstance(fmus[version, kind].path) as other:
        other.initialize()
        step = float(other.description.defaultExperiment.stepSize)
        _run(other, 0, 10, step)
        return States(other).serialize(States(other).get())


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("version", VERSIONS)
def test_a_state_that_is_not_this_fmus_is_refused_and_the_fmu_goes_on(fmus, version, kind):
    """NaN-filled bytes, random bytes, one flipped byte anywhere, a wrong size, the state of
    another FMU of the same size (the other FMI version's) or of another model: fmi2Error/fmi3Error
    with one log message, never OK with NaN outputs; a valid state then still round-trips bit for
    bit and repeats the numbers."""
    # Other FMUs' states first (FMPy's FMI 2 logger proxy serves the instance made last).
    twin = _blob(fmus, 5 - version, kind)  # the same model in the other FMI version: another FMU
    other = _blob(fmus, version, "clqg" if kind != "clqg" else "siso")
    held = _blob(fmus, 2, "held") if kind == "clqg" and version == 2 else None  # the same struct, another FMU
    with FmuInstance(fmus[version, kind].path) as instance:
        states = States(instance)
        instance.initialize()
        step = float(instance.description.defaultExperiment.stepSize)
        _run(instance, 0, 30, step)
        blob = states.serialize(states.get())
        assert blob[:8] == b"SJFMUST\0" and len(blob) > HEADER + CHECKSUM
        assert states.serialize(states.deserialize(blob)) == blob  # bit for bit
        first = _run(instance, 30, 20, step)
        rng = np.random.default_rng(37)
        nan = struct.pack("=d", math.nan) * (len(blob) // 8) + b"\xff" * (len(blob) % 8)
        refused(instance, lambda: states.deserialize(nan), "DeserializeFMUState" if version == 3 else "DeSerial",
                "no format tag")  # fmt: skip
        noise = rng.integers(0, 256, len(blob), dtype=np.uint8).tobytes()
        refused(instance, lambda: states.deserialize(noise), "no format tag")
        for where in (0, 20, 30, HEADER, HEADER + 3, len(blob) // 2, len(blob) - CHECKSUM - 1, len(blob) - 1):
            flipped = bytearray(blob)
            flipped[where] ^= 1 << int(rng.integers(0, 8))
            refused(instance, lambda: states.deserialize(bytes(flipped)), "state")
        refused(instance, lambda: states.deserialize(blob[:-1]), f"{len(blob) - 1} bytes", f"has {len(blob)} bytes")
        refused(instance, lambda: states.deserialize(blob + b"\0"), f"{len(blob) + 1} bytes")
        assert len(twin) == len(blob) and twin[:24] == blob[:24]
        refused(instance, lambda: states.deserialize(twin), "another FMU")
        refused(instance, lambda: states.deserialize(other), "FMU")
        if held is not None:
            assert len(held) == len(blob)
            refused(instance, lambda: states.deserialize(held), "another FMU")
        states.set(states.deserialize(blob))  # still usable: the valid state restores the numbers
        assert _run(instance, 30, 20, step) == first
        states.set(states.deserialize(blob))
        assert states.serialize(states.get()) == blob


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("version", VERSIONS)
def test_a_forged_state_with_a_valid_checksum_but_values_the_fmu_cannot_hold_is_refused(fmus, version, kind):
    """Tag and checksum right, the model not: NaN time, a NaN-filled model, an input or a tunable
    outside its range (as if set), each refused with the value named; the instance goes on."""
    with FmuInstance(fmus[version, kind].path) as instance:
        states = States(instance)
        marked = 87.625  # a number the model holds once: the input or tunable forged below
        if kind == "truss":
            name, bad = next(n for n in instance.variables if n.startswith("DISTURBANCE.")), -1e30
            instance.initialize()
        else:
            name, bad = next(n for n in instance.variables if n.endswith(".normal_force_max")), 1e12
            instance.initialize(parameters={name: marked})
        if kind == "truss":
            instance.set_real(instance.references([name]), [marked])
        blob = states.serialize(states.get())
        model = blob[HEADER:-CHECKSUM]
        refused(instance, lambda: states.deserialize(forged(blob, struct.pack("=d", math.nan) + model[8:])),
                "time is nan", "finite")  # fmt: skip
        nan = struct.pack("=d", math.nan) * (len(model) // 8)
        refused(instance, lambda: states.deserialize(forged(blob, nan)), "the saved state's")
        refused(instance, lambda: states.deserialize(replaced(blob, marked, bad)), name, f"{bad:.17g}", "allowed")
        refused(instance, lambda: states.deserialize(replaced(blob, marked, math.inf)), name, "inf")
        ours = forged(blob, model)
        assert ours == blob  # the forger's checksum is the FMU's
        states.set(states.deserialize(ours))
        step = float(instance.description.defaultExperiment.stepSize)
        _run(instance, 0, 3, step)


@pytest.mark.parametrize("version", VERSIONS)
def test_a_law_state_the_law_never_holds_is_refused(fmus, version):
    """Inside the law's own state (the model's second field, after the time; its first field the
    pointer to the parameters): a NaN or infinite filter estimate q0 of the cLQG."""
    with FmuInstance(fmus[version, "clqg"].path) as instance:
        states = States(instance)
        instance.initialize()
        _run(instance, 0, 5, float(instance.description.defaultExperiment.stepSize))
        blob = states.serialize(states.get())
        model = blob[HEADER:-CHECKSUM]
        for value in (math.nan, -math.inf):
            bad = model[:16] + struct.pack("=d", value) + model[24:]  # time, params pointer, q0[0]
            refused(instance, lambda b=bad: states.deserialize(forged(blob, b)), "the saved state's state.q0", "finite")
        assert states.serialize(states.deserialize(forged(blob, model))) == blob


def test_tuning_beyond_the_artefacts_limits_or_to_nan_is_refused_and_not_taken(fmus, small):
    """F_N^max up to the artefact's measured_normal_force_max (F_N^max (1 + margin)), F_N^min > 0,
    each setting in its range; 1e12 N, NaN and Inf refused with the range in the message."""
    design, s, a = small
    joint = a.joint_names[0]
    limit = float(a.measured_normal_force_max[0])
    assert limit == 110.0
    for version in VERSIONS:
        with FmuInstance(fmus[version, "clqg"].path) as controller:
            controller.initialize()
            high, low = controller.references([f"JOINT_{joint}.normal_force_max", f"JOINT_{joint}.normal_force_min"])
            before = controller.get_real([high, low]).tolist()
            for value in (1e12, math.nan, math.inf, math.nextafter(limit, math.inf)):
                refused(controller, lambda v=value: controller.set_real([high], [v]), "normal_force_max",
                        "< F_N^max <= 110 N", "measured_normal_force_max")  # fmt: skip
            for value in (0.0, -1.0, math.nan):
                refused(controller, lambda v=value: controller.set_real([low], [v]), "normal_force_min", "0 < F_N^min")
            epsilon = controller.references(["boundary_layer"])
            for value in (0.0, math.nan, -math.inf):
                refused(controller, lambda v=value: controller.set_real(epsilon, [v]), "boundary_layer", "> 0")
            assert controller.get_real([high, low]).tolist() == before  # nothing refused was taken
            controller.set_real([high], [limit])  # the limit itself is allowed
            controller.step(0.0, a.sample_time)
            description = read_model_description(str(fmus[version, "clqg"].path))
            row = next(v for v in description.modelVariables if v.name == f"JOINT_{joint}.normal_force_max")
            assert (float(row.min), float(row.max)) == (0.0, limit)
    with FmuInstance(fmus[2, "preset"].path) as preset:
        force = preset.references([f"JOINT_{joint}.force"])
        refused(preset, lambda: preset.set_real(force, [1e12]), "force", "110 N")
    with FmuInstance(fmus[2, "slipratio"].path) as slip:
        decay = slip.references(["decay"])
        refused(slip, lambda: slip.set_real(decay, [1.0 / a.sample_time]), "decay", f"1/dt = {1 / a.sample_time:g}")
        slip.set_real(decay, [0.5 / a.sample_time])


@pytest.mark.parametrize("version", VERSIONS)
def test_inputs_outside_their_plausible_ranges_are_refused(fmus, small, version):
    """The plant: a disturbance within +-1e6 N (MAX_PULSE_AMPLITUDE), F_N within [0, F_N^max (1 + margin)];
    the controller: a measurement within 1000 times the artefact's plausibility limit. Between the
    limit and that bound a measurement is the law's to judge: the safe state and status bit 8."""
    design, s, a = small
    joint = a.joint_names[0]
    with FmuInstance(fmus[version, "truss"].path) as plant:
        plant.initialize()
        name = next(n for n in plant.variables if n.startswith("DISTURBANCE."))
        disturbance, force = plant.references([name, f"SETPOINT_{joint}.normal_force"])
        for value in (-1e30, 1.0000001e6, math.nan, -math.inf):
            refused(plant, lambda v=value: plant.set_real([disturbance], [v]), name, "|value| <= 1e+06 N")
        for value in (110.00001, -1e-9, 1e30, math.nan):
            refused(plant, lambda v=value: plant.set_real([force], [v]), "normal_force", "0 <= value <= 110 N")
        assert plant.get_real([force]).tolist() == [0.0]
        plant.set_real([disturbance, force], [-1e6, 110.0])  # the bounds themselves are allowed
        plant.set_real([disturbance], [0.0])
        plant.step(0.0, s.setup.sample_time)
        rows = {v.name: v for v in read_model_description(str(fmus[version, "truss"].path)).modelVariables}
        assert (float(rows[name].min), float(rows[name].max)) == (-1e6, 1e6)
    with FmuInstance(fmus[version, "siso"].path) as controller:
        controller.initialize()
        velocity = controller.references([f"JOINT_{joint}.sliding_velocity"])
        bound = 1000.0 * float(a.sliding_velocity_limit[0])
        for value in (1e30, -math.nextafter(bound, math.inf), math.nan):
            refused(controller, lambda v=value: controller.set_real(velocity, [v]), "sliding_velocity",
                    "sliding_velocity_limit")  # fmt: skip
        controller.set_real(velocity, [-bound / 10])  # implausible, not impossible: the law's safe state
        status = controller.references(["CONTROLLER_STATUS.step_status"])
        assert controller.get_integer(status) == [8]
