"""Stage 8 of ``smartjoint run`` in local mode (``[network]``'s node law set to ``"local"``,
issue 33): the node law on one generated joint node per joint on the SIL bench, beside the
central SIL row of that law and against the same model-in-the-loop run and spread."""

from __future__ import annotations

from smartjoint.bench import rounding_spread
from smartjoint.bench.interconnection import LocalNodesLoop
from smartjoint.common import law_registry


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
        the MIL spread and the samples in a safe state.
    """
    law = law_registry.node_law()
    progress(f"      {law.name}: local mode, one joint node per joint (float build) …")
    run, safe = LocalNodesLoop(artifact, "float").run(setup, law.name)
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
        f"{rounding_spread.band_cell(spread)} | {verdict} | {local['safe_samples']} |\n"
    )


__all__ = ["local_mode_markdown", "local_mode_run"]
