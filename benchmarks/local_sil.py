"""Local mode against the central SISO law on the bundled study, SIL and MIL side by side (issue 33).

The SISO law four ways on the study of ``firmware/generated/controller.json``'s design: the model in
the loop (``PythonLoop``), the generated joint nodes on the SIL bench in local mode
(``LocalNodesLoop``, double and float builds), and the central firmware through the CAN loop
(``CanLoop``, float); and local mode with joint 0's node as its image on the emulated Cortex-M4F
(``bench.node_target.TargetNode``, processor in the loop), which must equal the local float run
bit for bit. The band is the model in the loop's spread under ``--runs`` perturbations of
its commands at 6e-8 relative (float rounding, ``bench.rounding_spread.perturbed``). Written to
``benchmarks/local_sil.json``.

    python benchmarks/local_sil.py [--runs 8]
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

from machine import artifact_header, cpu_model, write_json  # benchmarks/machine.py (the script's folder is on sys.path)

from smartjoint.bench.interconnection import CanLoop, LocalNodesLoop
from smartjoint.bench.rounding_spread import perturbed
from smartjoint.common import law_registry
from smartjoint.design.control import artifact as artifacts
from smartjoint.design.control.interconnection import PythonLoop
from smartjoint.design.control.runs import run_semi_active, setup
from smartjoint.design.control.study import design_model
from smartjoint.design.structure.spec import load_design

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifact", default=str(ROOT / "firmware" / "generated" / "controller.json"))
    parser.add_argument("--design", default=str(ROOT / "design" / "data" / "three_type_a.toml"))
    parser.add_argument("--runs", type=int, default=8)
    parser.add_argument("--json", default=str(Path(__file__).with_name("local_sil.json")))
    args = parser.parse_args()
    a = artifacts.load(args.artifact)
    design = load_design(args.design)
    s = setup(design, design_model(design, lambda line: None))
    law = law_registry.node_law()
    mil, _ = PythonLoop(a).run(s, law.name)
    runs = {"mil": {"energy_measure": mil.energy_measure(), "seconds": None}}
    print(f"MIL {law.display}: E(t_e) = {mil.energy_measure():.6f} J·s")
    loops = (("local double", LocalNodesLoop(a, "double")), ("local float", LocalNodesLoop(a, "float")))
    target = f"local float, {a.joint_names[0]} on the target"
    for name, loop in (
        *loops,
        (target, LocalNodesLoop(a, "float", target_joints=(0,))),
        ("central float", CanLoop(a, "float")),
    ):
        start = time.perf_counter()
        run, safe = loop.run(s, law.name)
        seconds = time.perf_counter() - start
        deviation = run.energy_measure() / mil.energy_measure() - 1.0
        runs[name] = {"energy_measure": run.energy_measure(), "against_mil": deviation, "safe_samples": safe}
        runs[name]["seconds"] = seconds
        print(f"{name}: E(t_e) = {run.energy_measure():.6f} J·s, {deviation:+.2%} against MIL, {safe} safe samples")
    same = runs[target]["energy_measure"] == runs["local float"]["energy_measure"]
    runs[target]["equal_to_local_float"] = same
    print(f"{target}: the local float run's E(t_e) bit for bit: {same}")
    spread = [
        run_semi_active(s, law.display, perturbed(law.python_reference(a), 6e-8, k)).energy_measure()
        / mil.energy_measure()
        - 1.0
        for k in range(args.runs)
    ]
    print(f"MIL under 6e-8 command perturbations ({args.runs} runs): {min(spread):+.2%} … {max(spread):+.2%}")
    facts = {"cpu": cpu_model(), "platform": platform.platform(), "python": platform.python_version()}
    results = artifact_header("local_sil", facts, args.artifact, a) | {
        "design": args.design,
        "law": law.name,
        "runs": runs,
        "mil_spread_under_float_rounding": spread,
    }
    write_json(args.json, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
