"""The joint nodes of local mode on their target, QEMU mps2-an386 (issue 33), and the bus they need.

Per joint of the artefact, ``bench.node_target.measure``: the node image (the node firmware of
``smartjoint codegen``, float -O2, with a minimal runtime, startup and board support; flash and
RAM of the linked image), and its step on the target (instructions under ``-icount shift=0``, the
mean over seeded samples with the empty loop subtracted); its commands are checked against the
host float build bit for bit. Then the supervision bus of local mode
(``design.network.joint_node.supervision_database``) for 3, 12 and 30 joints at the artefact's
sample time, on CAN FD 1/5 Mbit/s, beside the central bus of the default plan (``plan.plan``)
for the artefact's joints. Targets: ≤ 4 KiB flash, ≤ 256 B RAM, ≤ 200 instructions a step, the
12-joint bus ≤ 15 %.

    python benchmarks/node_image.py [--artifact firmware/generated/controller.json] [--steps 500]
"""

from __future__ import annotations

import argparse
import platform
import subprocess
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from machine import artifact_header, cpu_model, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.bench import node_target
from smartjoint.bench.joint_node import CompiledNode, compiled_nodes
from smartjoint.design.control import artifact as artifacts
from smartjoint.design.network import busload, joint_node, plan, protocol

ROOT = Path(__file__).resolve().parents[1]
RATES = (1_000_000, 5_000_000)


def _version(command: list[str]) -> str:
    return subprocess.run(command, capture_output=True, text=True).stdout.splitlines()[0]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifact", default=str(ROOT / "firmware" / "generated" / "controller.json"))
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--json", default=str(Path(__file__).with_name("node_image.json")))
    args = parser.parse_args()
    a = artifacts.load(args.artifact)
    host = compiled_nodes(a, "float")
    nodes = []
    for j, name in enumerate(a.joint_names):
        m = node_target.measure(a, j, steps=args.steps)
        twin = CompiledNode(host, a, j)
        twin.receive(joint_node.HEARTBEAT_ID, node_target.heartbeat())
        commands = np.array([twin.step(*map(float, row)) for row in m["inputs"]], dtype=np.float32)
        same = commands.tobytes() == m["commands"].tobytes()
        nodes.append({k: v for k, v in m.items() if k not in ("commands", "inputs")} | {"bit_identical_to_host": same})
        print(
            f"node {name}: flash {m['flash']} B, RAM {m['ram']} B, step {m['instructions_per_step']:.1f} "
            f"instructions (±{m['resolution']:.2f}), commands equal to the host float build: {same}"
        )
    loads = {}
    for count in (3, 12, 30):
        design = SimpleNamespace(
            joint_names=[f"J{k}" for k in range(count)], sample_time=a.sample_time, artifact_sha256=a.artifact_sha256
        )
        db = protocol.load_dbc(protocol.dbc_text(joint_node.supervision_database(design)))
        loads[count] = busload.bus_load(db, *RATES).load
        print(
            f"local mode, {count} joints, supervision every {joint_node.SUPERVISION_CYCLES} samples: {loads[count]:.2%}"
        )
    central = plan.plan(a).buses[0].load.load
    print(f"central bus of this artefact ({len(a.joint_names)} joints, every frame every sample): {central:.2%}")
    facts = {
        "cpu": cpu_model(),
        "platform": platform.platform(),
        "arm_gcc": _version(["arm-none-eabi-gcc", "--version"]),
        "qemu": _version(["qemu-system-arm", "--version"]),
    }
    results = artifact_header("node_image", facts, args.artifact, a) | {
        "nodes": nodes,
        "limits": node_target.LIMITS,
        "supervision_cycles": joint_node.SUPERVISION_CYCLES,
        "bitrates": RATES,
        "local_mode_load": {str(k): v for k, v in loads.items()},
        "central_load": central,
    }
    write_json(args.json, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
