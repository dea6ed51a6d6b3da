"""Stage 8 of ``smartjoint run`` in local mode (``[network]``'s node law set to ``"local"``,
issue 33): the node law on one generated joint node per joint on the SIL bench, beside the
central SIL row of that law and against the same model-in-the-loop run and spread."""

from __future__ import annotations

from smartjoint.bench import rounding_spread
from smartjoint.bench.interconnection import LocalNodesLoop
from smartjoint.common import law_registry
from smartjoint.design.network.joint_node import SUPERVISOR_HEALTH


def local_mode_run(artifact, setup, sil_check: dict, progress) -> dict:
    """The node law in local mode: one generated joint node per joint (float build, as on the
    nodes), each driving its own amplifier model.

    Parameters
    ----------
    artifact : ControllerArtifact
        The run's controller artefact.
    setup : StudySetup
        The study's plant, pulse and duration.
    sil_check : dict
        What ``bench.sil.sil_study`` returned: the central row of the node law gives the MIL
        figure and its spread.
    progress : callable
        Hears one line.

    Returns
    -------
    dict
        E(t_e) and e(t_e) of the local run, its difference from MIL beside the central SIL row's,
        the MIL spread, the samples in a safe state and, per health bit of the generated
        supervisor (``bench.supervisor``), the node-samples it was raised in.
    """
    law = law_registry.node_law()
    progress(f"      {law.name}: local mode, one joint node per joint (float build) …")
    loop = LocalNodesLoop(artifact, "float")
    run, safe = loop.run(setup, law.name)
    record = loop.record
    assert record is not None  # run() keeps the loop's record
    health = [word for words in record.health for word in words]
    central = sil_check["laws"].get(law.name)
    mil = None if central is None else central["energy_measure_mil"]
    return {
        "law": law.name,
        "energy_measure_local": run.energy_measure(),
        "energy_end_local": float(run.energy[-1]),
        "energy_measure_mil": mil,
        "difference": None if mil is None else run.energy_measure() / mil - 1.0,
        "mil_spread_under_float_rounding": None if central is None else central["mil_spread_under_float_rounding"],
        "central_difference": None if central is None else central["energy_measure_difference"],
        "safe_samples": safe,
        "supervisor_health": {bit: sum(1 for w in health if w & (1 << k)) for k, bit in enumerate(SUPERVISOR_HEALTH)},
        "node_samples": len(health),
    }


def local_mode_markdown(sil_check: dict) -> str:
    """The local-mode rows of stage 8 (:func:`local_mode_run`), or nothing without them."""
    local = sil_check.get("local")
    if local is None:
        return ""
    spread = local["mil_spread_under_float_rounding"]
    verdict = rounding_spread.verdict_cell(rounding_spread.within_band(local["difference"], spread), spread)
    difference = "—" if local["difference"] is None else f"{100 * local['difference']:+.2f} %"
    central = "—" if local["central_difference"] is None else f"{100 * local['central_difference']:+.2f} %"
    mil = "—" if local["energy_measure_mil"] is None else f"{local['energy_measure_mil']:.4g}"
    return (
        f"\nLocal mode (`[network]`, docs/safety.md): the {local['law']} law on one generated joint node per "
        "joint, each driving its own amplifier, float build:\n\n"
        "| law | E(t_e) MIL | E(t_e) local | difference | central SIL's difference | MIL spread under 6e-8 "
        "perturbations | within the band? | safe samples |\n|---|---:|---:|---:|---:|---:|---|---:|\n"
        f"| {local['law']} (local) | {mil} | {local['energy_measure_local']:.4g} | {difference} | {central} | "
        f"{rounding_spread.band_cell(spread)} | {verdict} | {local['safe_samples']} |\n" + _supervisor_line(local)
    )


def _supervisor_line(local: dict) -> str:
    """What the generated supervisor saw of the nodes over the run."""
    raised = {bit: count for bit, count in local.get("supervisor_health", {}).items() if count}
    if "supervisor_health" not in local:
        return ""
    seen = (
        "every node healthy at every sample"
        if not raised
        else ", ".join(f"{bit} in {count} of {local['node_samples']} node-samples" for bit, count in raised.items())
    )
    return f"\nThe generated supervisor (`<prefix>_supervisor.c`, docs/safety.md) saw {seen}.\n"


__all__ = ["local_mode_markdown", "local_mode_run"]
