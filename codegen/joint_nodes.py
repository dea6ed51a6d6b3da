"""The firmware of the joint nodes (``design.network.joint_node``; its executable specification
is ``bench.joint_node``): one node source for every joint and one constants file per joint, so
that the image of joint j is ``<prefix>_node.c`` + ``<prefix>_node_config.c`` (its constants; the
others' fall to ``--gc-sections``) + the E2E runtime; and the supervisor, the central side of
local mode (``<prefix>_supervisor.c``, its executable specification ``bench.supervisor``).
``smartjoint codegen`` writes them beside the central controller's files.
"""

from __future__ import annotations

import numpy as np

from smartjoint.codegen import rendering
from smartjoint.common import law_registry
from smartjoint.design.control import artifact as artifacts
from smartjoint.design.network import joint_node


def render_nodes(
    artifact: artifacts.ControllerArtifact,
    prefix: str = "smartjoint",
    real: str = "float",
    supervision_cycles: int = joint_node.SUPERVISION_CYCLES,
) -> dict[str, str]:
    """The node sources of an artefact, file name → text: ``<prefix>_node.h/.c``,
    ``<prefix>_node_config.c`` with every joint's ``<prefix>_node_<joint>_config``, and the
    supervisor's ``<prefix>_supervisor.h/.c``.

    Parameters
    ----------
    artifact : ControllerArtifact
        Its joints, SISO law (ε per joint, limits), safe state and timeouts.
    prefix : str
        The prefix of every C identifier and file name.
    real : str
        ``"float"`` or ``"double"``.
    supervision_cycles : int
        Samples per heartbeat and per node status frame.

    Returns
    -------
    dict of str to str
    """
    lit = lambda value: rendering.literal(value, real)  # noqa: E731
    name = f"{prefix}_node"
    banner = rendering.banner(artifact.artifact_sha256, real)
    configs = [joint_node.node_config(artifact, j, supervision_cycles) for j in range(len(artifact.joint_names))]
    context = {
        **rendering.naming(banner, prefix, name),
        "zero": lit(0.0),
        "one": lit(1.0),
        "half": lit(0.5),
        "sample_time": lit(artifact.sample_time),
        "supervision_cycles": int(supervision_cycles),
        "heartbeat_id": joint_node.HEARTBEAT_ID,
        "heartbeat_length": joint_node.HEARTBEAT_LENGTH,
        "heartbeat_cycle_byte": joint_node.HEARTBEAT_CYCLE_BYTE,
        "heartbeat_counts": joint_node.HEARTBEAT_COUNTS,
        "status_length": joint_node.NODE_STATUS_LENGTH,
        "mode_init": law_registry.MODE_INIT,
        "mode_law": joint_node.NODE_LAW.mode,
        "mode_safe": law_registry.MODE_SAFE,
        "node_faults": joint_node.NODE_FAULTS,
        "force_scale": joint_node.FORCE_SCALE,
        "force_per_code": lit(1.0 / joint_node.FORCE_SCALE),
        "force_code_max": lit(float(joint_node.FORCE_CODES)),
        "joints": [c.name for c in configs],
        "digest": artifact.artifact_sha256[:12],
    }
    env = rendering.environment()
    files = {
        f"{name}.h": env.get_template("node.h.j2").render(context),
        f"{name}.c": env.get_template("node.c.j2").render(context),
    }
    joints = [
        {
            "name": c.name,
            "status_id": c.status_id,
            "timeout_samples": c.timeout_samples,
            "timeout_cycles": c.timeout_cycles,
            "recovery_cycles": c.recovery_cycles,
            "normal_force_min": lit(c.normal_force_min),
            # F^max − F^min in double, as the SISO law's (control.SisoLaw.normal_force_range)
            "normal_force_range": lit(float(np.float64(c.normal_force_max) - np.float64(c.normal_force_min))),
            "boundary_layer": lit(c.boundary_layer),
            "safe_normal_force": lit(c.safe_normal_force),
            "sliding_velocity_limit": lit(c.sliding_velocity_limit),
            "friction_force_limit": lit(c.friction_force_limit),
            "measured_normal_force_min": lit(c.measured_normal_force_min),
            "measured_normal_force_max": lit(c.measured_normal_force_max),
        }
        for c in configs
    ]
    files[f"{name}_config.c"] = env.get_template("node_config.c.j2").render({**context, "configs": joints})
    files.update(_supervisor(artifact, prefix, banner, configs, supervision_cycles))
    return files


def _supervisor(artifact, prefix: str, banner: str, configs, supervision_cycles: int) -> dict[str, str]:
    """``<prefix>_supervisor.h/.c``: the central side of local mode (``bench.supervisor``)."""
    name = f"{prefix}_supervisor"
    timeouts = {c.timeout_samples for c in configs}
    context = {
        **rendering.naming(banner, prefix, name),
        "joints": [c.name for c in configs],
        "supervision_cycles": int(supervision_cycles),
        "timeout_samples": max(timeouts),  # one artefact-wide timeout_cycles: the same for every node
        "heartbeat_id": joint_node.HEARTBEAT_ID,
        "heartbeat_length": joint_node.HEARTBEAT_LENGTH,
        "heartbeat_cycle_byte": joint_node.HEARTBEAT_CYCLE_BYTE,
        "heartbeat_counts": joint_node.HEARTBEAT_COUNTS,
        "status_base": joint_node.NODE_STATUS_BASE,
        "status_length": joint_node.NODE_STATUS_LENGTH,
        "mode_law": joint_node.NODE_LAW.mode,
        "mode_safe": law_registry.MODE_SAFE,
        "heartbeat_lost_bit": 2 ** joint_node.NODE_FAULTS.index("heartbeat_lost"),
        "health": joint_node.SUPERVISOR_HEALTH,
    }
    env = rendering.environment()
    return {f"{name}.{kind}": env.get_template(f"supervisor.{kind}.j2").render(context) for kind in "hc"}


__all__ = ["render_nodes"]
