"""The network plan (design.network.plan, issue 33): frames of a controller over one or more CAN
FD buses, every bus within its load limit and its sample, one DBC per bus that cantools reads,
packed setpoints where they lower the load, and a one-line refusal naming the bus and the load."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest
from conftest import cli_error, run_cli, small_truss

from smartjoint.bench import e2e
from smartjoint.common.errors import DesignError, ModelError
from smartjoint.design.control import artifact
from smartjoint.design.network import busload, protocol
from smartjoint.design.network.plan import plan
from smartjoint.design.structure.description import Bus, Network
from smartjoint.design.structure.spec import parse_design

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def reference():
    return artifact.load(ROOT / "firmware" / "generated" / "controller.json")


def _joints(reference, count: int):
    """The bundled artefact's bus description with ``count`` joints (what the plan reads)."""
    return SimpleNamespace(
        joint_names=[f"J{k + 1}" for k in range(count)],
        sensor_names=list(reference.sensor_names),
        sensor_quantities=list(reference.sensor_quantities),
        sample_time=reference.sample_time,
        artifact_sha256=reference.artifact_sha256,
        piezo_force_per_volt=reference.piezo_force_per_volt,
        piezo_preload=reference.piezo_preload,
    )


def _buses(count: int) -> Network:
    return Network(tuple(Bus(f"can{k}") for k in range(count)))


def _check(result, design) -> None:
    """Every joint on one bus, its frames there only; the heartbeat on every bus, the tip sensors
    on the first; each bus within its limit and its sample; each DBC reads back as its bus."""
    placed = [j for p in result.buses for j in p.joints]
    assert placed == list(design.joint_names)
    for k, p in enumerate(result.buses):
        back = protocol.load_dbc(p.dbc)
        names = {m.name for m in back.messages}
        assert "CONTROLLER_STATUS" in names and ("TIP_SENSORS" in names) == (k == 0)
        assert {f"JOINT_{j}" for j in p.joints} | {f"AMP_STATUS_{j}" for j in p.joints} <= names
        assert not any(n.startswith(("JOINT_", "AMP_STATUS_")) and n.split("_")[-1] not in p.joints for n in names)
        load = busload.bus_load(back, p.bus.bitrate, p.bus.data_bitrate).load
        assert load == pytest.approx(p.load.load) and load <= p.bus.limit
        assert p.busy <= design.sample_time


def test_the_bundled_design_fits_one_bus_with_packed_setpoints(reference):
    """Packing the three setpoints into one frame lowers the load below one frame each."""
    single = busload.bus_load(protocol.database(reference), 1_000_000, 5_000_000).load
    result = plan(reference)
    _check(result, reference)
    (only,) = result.buses
    assert only.packed and only.load.load < single
    setpoints = [m for m in protocol.load_dbc(only.dbc).messages if m.name.startswith("SETPOINTS_")]
    (frame,) = setpoints
    values = {s.name: 0.0 for s in frame.signals}
    values.update({"voltage_a1": 12.5, "voltage_a2": 0.0, "voltage_a3": 149.9})
    data = e2e.protect(frame.frame_id, bytearray(frame.encode(values)), 3)
    decoded = frame.decode(bytes(data))
    assert decoded["voltage_a1"] == pytest.approx(12.5, abs=1e-7) and decoded["voltage_a3"] == pytest.approx(149.9)


def test_every_dbc_states_the_artefacts_own_amplifier(reference):
    """The setpoint's F_N = force_per_volt·V + preload is the artefact's in every database: the
    one-bus default (`codegen`, `bench dbc`) and each planned bus, packed setpoints included
    (the plan used the paper's 8 N/V and no preload whatever the design said)."""
    import dataclasses

    own = dataclasses.replace(reference, piezo_force_per_volt=10.0, piezo_preload=5.0)
    words = "F_N = 10*V + 5 N"
    comments = lambda db: [s.comment for m in db.messages for s in m.signals if s.name.startswith("voltage")]  # noqa: E731
    assert all(words in c for c in comments(protocol.database(own)))
    planned = comments(plan(own).buses[0].database) + comments(plan(_joints(own, 12), _buses(3)).buses[2].database)
    assert planned and all(words in c for c in planned)
    assert not any(words in c for c in comments(protocol.database(reference)))  # the reference's own: 8*V + 0 N


def test_twelve_joints_need_three_buses_and_each_stays_within_70_percent(reference):
    design = _joints(reference, 12)
    with pytest.raises(ModelError, match=r"^network: bus can0 would carry 1\d\d\.\d% with joints J\d+ … J12 as well"):
        plan(design, _buses(1))
    result = plan(design, _buses(3))
    _check(result, design)
    assert [len(p.joints) for p in result.buses] == [4, 4, 4]
    assert max(p.load.load for p in result.buses) <= 0.70
    assert "| can2 |" in result.table()


def test_the_buses_share_the_load_rather_than_filling_in_order(reference):
    """Four buses for twelve joints: three each (the fill in order would leave the last with
    none), every bus within the load of the three-bus plan's fullest."""
    design = _joints(reference, 12)
    three = plan(design, _buses(3))
    four = plan(design, _buses(4))
    _check(four, design)
    assert [len(p.joints) for p in four.buses] == [3, 3, 3, 3]
    assert max(p.load.load for p in four.buses) < max(p.load.load for p in three.buses)


def test_local_mode_adds_the_node_status_frames(reference):
    """The central frames stay (the cLQG still runs centrally) and each joint's NODE_STATUS joins."""
    central = plan(reference)
    local = plan(reference, Network(siso="local"))
    names = {m.name for m in local.buses[0].database.messages}
    assert {f"NODE_STATUS_{j}" for j in ("A1", "A2", "A3")} <= names
    assert local.buses[0].load.load > central.buses[0].load.load


@pytest.mark.parametrize(
    "network, words",
    [
        ({"siso": "both"}, r"network\.siso: 'both' — allowed: 'central', 'local'"),
        ({"buses": [{"name": "a"}, {"name": "a"}]}, r"network\.buses\[1\]\.name: 'a' — a name no other bus has"),
        ({"buses": [{"name": "a", "limit": 1.5}]}, r"network\.buses\[0\]\.limit: 1\.5 — must be <= 1\.0"),
        (
            {"buses": [{"name": "a", "bitrate": 1_000_000, "data_bitrate": 500_000}]},
            r"network\.buses\[0\]\.data_bitrate",
        ),
        ({"supervision_cycles": 0}, r"network\.supervision_cycles: 0"),
        ({"speed": 1}, r"speed"),
    ],
)
def test_a_bad_network_table_is_one_line(network, words):
    """The design file's [network] is read with the field, the value and what is allowed."""
    d = small_truss()
    d["network"] = network
    with pytest.raises(DesignError, match=words) as caught:
        parse_design(d)
    assert "\n" not in str(caught.value)


def test_the_network_table_reaches_the_design():
    d = small_truss()
    d["network"] = {"siso": "local", "supervision_cycles": 5, "buses": [{"name": "x", "data_bitrate": 8_000_000}]}
    network = parse_design(d).network
    assert network == Network((Bus("x", 1_000_000, 8_000_000, 0.70),), "local", 5)
    assert parse_design(small_truss()).network == Network()


def test_a_design_whose_frames_do_not_fit_is_refused_before_any_work():
    """[placement] count = 12 on one bus: the one-line refusal from the design alone, no FE model."""
    from smartjoint.design.network.plan import check_design

    d = small_truss()
    joints = d.pop("joints", None)
    assert joints
    d["placement"] = {"modes": [1, 2], "count": 12}
    with pytest.raises(ModelError, match=r"^network: bus can0 would carry .* with joints P\d+ … P12 as well"):
        check_design(parse_design(d))
    d["network"] = {"buses": [{"name": f"can{k}"} for k in range(3)]}
    assert len(check_design(parse_design(d)).buses) == 3


def test_codegen_lays_the_layer_on_the_buses_of_a_designs_network(tmp_path):
    """`smartjoint codegen --network DESIGN`: one DBC per bus of the design's plan, each loading
    as its bus's frames; a design whose joints are not the artefact's is refused in one line."""
    design = tmp_path / "two_buses.toml"
    design.write_text(
        f'base = "{(ROOT / "design" / "data" / "three_type_a.toml").as_posix()}"\n'
        '[[network.buses]]\nname = "can0"\nlimit = 0.5\n[[network.buses]]\nname = "can1"\nlimit = 0.5\n'
    )
    reference = ROOT / "firmware" / "generated" / "controller.json"
    out = tmp_path / "firmware"
    done = run_cli("codegen", reference, "-o", out, "--network", design)
    assert done.returncode == 0, done.stderr
    assert not (out / "bus.dbc").exists()
    expected = plan(artifact.load(reference), Network((Bus("can0", limit=0.5), Bus("can1", limit=0.5))))
    for p in expected.buses:
        back = protocol.load_dbc((out / f"bus_{p.bus.name}.dbc").read_text())
        assert {m.name for m in back.messages} == {m.name for m in p.database.messages}
    other = tmp_path / "other.toml"
    other.write_text(
        f'base = "{(ROOT / "design" / "data" / "three_type_a.toml").as_posix()}"\n'
        '[[joints]]\nname = "B1"\nmember = "L1_0"\nend = "start"\ntype = "A"\n'
    )
    assert "joints B1 — the artefact's are A1, A2, A3" in cli_error(
        "codegen", reference, "-o", tmp_path / "x", "--network", other
    )
    assert not (tmp_path / "x").exists()
