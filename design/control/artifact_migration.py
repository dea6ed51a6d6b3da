"""Older controller artefacts read as the current ``schema_version`` (``artifact_schema``), one
version at a time, where the older file holds everything the newer one needs: version 5 lacked
each law's own F_N^min, version 6 the actuation check's tolerance. Versions 1–4 are refused with
a hint (``artifact_schema.check_version``)."""

from __future__ import annotations

from typing import Any

from smartjoint.common import law_registry
from smartjoint.design.structure.description import Safety

ACTUATION_FRACTION = Safety().actuation_tolerance  # the default, × F_N^max, for a version-6 file


def migrated(data: Any) -> Any:
    """An older artefact as the current version, one version at a time: version 5 gets each law's
    own F_N^min (``Setting.lower_force``: the SISO law's ``laws.siso.normal_force_min``) equal to
    the joints' ``common.normal_force_min`` — what version 5's laws commanded, so every law's
    numbers stay the same; version 6 gets ``safety.actuation_tolerance`` at its default,
    ``ACTUATION_FRACTION`` × F_N^max (the check came with version 7; nothing else changes).
    Anything else is returned as it is (and refused by the checks after).

    Parameters
    ----------
    data : object
        The parsed JSON text.

    Returns
    -------
    object
        ``data``, or a current copy of a version-5 or version-6 artefact.
    """
    if not isinstance(data, dict) or isinstance(data.get("schema_version"), bool):
        return data
    if data.get("schema_version") == 5:
        data = _from_version_5(data)
    if data.get("schema_version") == 6:
        data = _from_version_6(data)
    return data


def _from_version_5(data: dict) -> dict:
    laws, common = data.get("laws"), data.get("common")
    if not isinstance(laws, dict) or not isinstance(common, dict) or "normal_force_min" not in common:
        return data
    laws = dict(laws)
    for law in law_registry.LAWS.values():
        for setting in law.settings:
            section = laws.get(law.name)
            if setting.lower_force and isinstance(section, dict):
                if setting.key in section:  # not what version 5 wrote: refused as version 5
                    return data
                laws[law.name] = {**section, setting.key: common["normal_force_min"]}
    return {**data, "schema_version": 6, "laws": laws}


def _from_version_6(data: dict) -> dict:
    safety, common = data.get("safety"), data.get("common")
    if not isinstance(safety, dict) or not isinstance(common, dict) or "actuation_tolerance" in safety:
        return data
    high = common.get("normal_force_max")
    if not isinstance(high, list) or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in high):
        return data
    return {
        **data,
        "schema_version": 7,
        "safety": {**safety, "actuation_tolerance": [ACTUATION_FRACTION * float(v) for v in high]},
    }


__all__ = ["ACTUATION_FRACTION", "migrated"]
