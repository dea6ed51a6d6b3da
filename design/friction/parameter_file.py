"""The identification result file: a joint type's LuGre parameters (paper Eq. 1–2, Table 1's
columns) as ``smartjoint identify -o joint.toml`` writes them and a design file reads them
(``[friction.X] file = …``, docs/design-file.md).

The identified values stand at the top level, in the format ``smartjoint rig --parameters``
reads; the ``[identification]`` table beside them says how they were found: the records used
with their SHA-256, a provenance hash over those records and the settings, the 95 % intervals
and the NRMSE. A parameter the records do not determine (``identifiability``) has no value at
the top level: ``[identification.not_identified]`` names it with the reason, and a design that
reads the file refuses the joint unless its own table states that value.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import math
from pathlib import Path

from smartjoint.common import friction_registry
from smartjoint.design.friction.identifiability import not_identified
from smartjoint.design.friction.identify import Identification


def provenance(identification: Identification, record_hashes: dict[str, str], output_error: bool) -> str:
    """SHA-256 over what decides the result: the records' bytes (by hash, in name order), the
    joint type, the radius, whether the output-error step ran and the smartjoint version.

    Parameters
    ----------
    identification : Identification
    record_hashes : dict of str to str
        Record name → SHA-256 of its file.
    output_error : bool
        Whether the output-error step was asked for.

    Returns
    -------
    str
        64 hex digits.
    """
    parts = [f"{name}={digest}" for name, digest in sorted(record_hashes.items())]
    parts += [
        f"joint_type={identification.joint_type}",
        f"radius={identification.parameters.radius!r}",
        f"output_error={output_error}",
        f"smartjoint={_version()}",
    ]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def file_hashes(paths) -> dict[str, str]:
    """SHA-256 of each record file by its name (the provenance of a result).

    Parameters
    ----------
    paths : iterable of str or Path

    Returns
    -------
    dict of str to str
    """
    return {Path(f).name: hashlib.sha256(Path(f).read_bytes()).hexdigest() for f in paths}


def result_text(identification: Identification, record_hashes: dict[str, str], output_error: bool = True) -> str:
    """The TOML text of an identification result.

    Parameters
    ----------
    identification : Identification
        The result of ``identify``.
    record_hashes : dict of str to str
        The record files it was identified from: name → SHA-256 (:func:`file_hashes`).
    output_error : bool
        Whether the output-error step was asked for.

    Returns
    -------
    str
        TOML: ``joint_type``, the model's parameters, ``radius`` (type B) and ``[identification]``.
    """
    hashes = record_hashes
    summary = identification.as_dict()
    p = identification.parameters
    model = friction_registry.friction_model(p.model)
    lines = [
        f"# {model.display} parameters of a type {identification.joint_type} joint identified by smartjoint "
        f"{_version()}",
        "# from rig records (paper Eq. 3 and the output-error step; docs/identification.md).",
        f'joint_type = "{identification.joint_type}"',
    ]
    if model.name != friction_registry.DEFAULT:  # a file without ``model`` is the default model's
        lines.append(f'model = "{model.name}"')
    missing = not_identified(identification)
    for parameter, value in zip(model.parameters, p.values().values()):
        if parameter.key in missing:
            continue  # no point value for what the records do not determine
        unit = parameter.unit(identification.joint_type)
        lines.append(f"{parameter.key} = {_number(value)}" + (f"  # [{unit}]" if unit else ""))
    if p.radius is not None:
        lines.append(f"radius = {_number(p.radius)}  # [m]")
    lines += [
        "",
        "[identification]",
        f'provenance = "{provenance(identification, hashes, output_error)}"',
        f"output_error = {'true' if identification.refined is not None else 'false'}",
        "records = [",
        *(f'  {{ file = "{_escaped(name)}", sha256 = "{digest}" }},' for name, digest in hashes.items()),
        "]",
        "",
        "[identification.ci95]  # 95 % confidence intervals of the step that set each value",
    ]
    for name, entry in summary["parameters"].items():
        if entry["ci95"] is not None and name not in missing:
            lines.append(f"{name} = [{_number(entry['ci95'][0])}, {_number(entry['ci95'][1])}]")
    if missing:
        lines += ["", "[identification.not_identified]  # no value: the records do not determine these (why)"]
        lines += [f'{name} = "{_escaped(reason)}"' for name, reason in missing.items()]
    lines += ["", "[identification.nrmse]  # normalised RMS error of the friction force per record"]
    lines += [f'"{_escaped(name)}" = {_number(value)}' for name, value in summary["nrmse"].items()]
    return "\n".join(lines) + "\n"


def _number(value: float) -> str:
    """A TOML float that reads back to the same double (repr is the shortest such text)."""
    value = float(value)
    return repr(value) if math.isfinite(value) else ("nan" if math.isnan(value) else ("inf" if value > 0 else "-inf"))


def _version() -> str:
    try:
        return importlib.metadata.version("smartjoint")
    except importlib.metadata.PackageNotFoundError:  # an uninstalled tree
        return "unknown"


def _escaped(text: str) -> str:
    return text.replace("\\", "\\\\").replace('"', '\\"')


__all__ = ["file_hashes", "provenance", "result_text"]
