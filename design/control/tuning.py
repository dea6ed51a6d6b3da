"""A law's settings for a design: what the design file gives (``[control] <law>_<key>``), each
other setting's default, and what the law's ``tune`` function settles on a study (the SISO ε of
Eq. 30 is optimised for Eq. 32). One path for every law of the registry (``common.law_registry``),
so the study, ``smartjoint design``, the sweeps and the artefact agree on a law's settings.
"""

from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from smartjoint.common import law_registry
from smartjoint.common.errors import ModelError
from smartjoint.common.law_registry import Law, Setting


@dataclass(frozen=True)
class Tuning:
    """A law's settings and how they were found.

    Attributes
    ----------
    law : str
        The law's name.
    settings : dict
        Setting key → value: a float, or an array with one value per controlled joint.
    given : frozenset of str
        The keys the design file gave.
    record : object or None
        What the law's ``tune`` function found (``boundary_layer.BoundaryLayerOptimum``), None
        when nothing was tuned. Its ``figures()`` go into the study's summary.
    """

    law: str
    settings: dict[str, Any]
    given: frozenset[str]
    record: Any = None

    def figures(self) -> dict:
        """JSON-ready: each setting's value, and the tuning's figures (None when none ran)."""
        values = {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in self.settings.items()}
        return {"settings": values, "tuned": None if self.record is None else self.record.figures()}


def given(design, law: Law) -> dict[str, Any]:
    """What the design file sets of ``law``: setting key → value (``Control.law_settings``)."""
    return dict(design.control.law_settings.get(law.name, {}))


def _default(design, setting: Setting):
    if isinstance(setting.default, str):
        return getattr(design.control, setting.default)
    return setting.default


def untuned(law: Law, design) -> dict[str, Any]:
    """The settings of ``law`` the design file gives or their defaults settle, before any tuning:
    setting key → a float, an array with one value per joint, or None (left to ``tune``)."""
    count = len(design.joints)
    from_file = given(design, law)
    values: dict[str, Any] = {}
    for setting in law.settings:
        value = from_file.get(setting.key)
        value = _default(design, setting) if value is None else value
        if value is not None:
            value = (
                np.array(np.broadcast_to(np.asarray(value, dtype=float), (count,)))
                if setting.per_joint
                else float(value)
            )
        values[setting.key] = value
    return values


def tuned(law: Law, design, setup=None, progress=print, tune=None) -> Tuning:
    """The settings of ``law`` for ``design``.

    Parameters
    ----------
    law : Law
        A registry entry.
    design : Design
        The design read from its file.
    setup : StudySetup, optional
        The study the law's ``tune`` function may run; None: nothing is tuned (a setting the
        design file leaves open without a default is then missing).
    progress : callable
        Receives the tuning's progress lines.
    tune : callable, optional
        The law's ``tune`` function; resolved from its entry when None.

    Returns
    -------
    Tuning

    Raises
    ------
    ModelError
        A setting that is still open, in one line naming its ``[control]`` key.
    """
    from_file = given(design, law)
    values = untuned(law, design)
    record = None
    if tune is None and law.tune:
        module, function = law.tune.split(":")
        tune = getattr(importlib.import_module(module), function)
    if tune is not None:
        values, record = tune(design, values, setup, progress)
    for setting in law.settings:
        if values.get(setting.key) is None:
            key = setting.design_key(law.name)
            tuned_by = " (or let `smartjoint design` tune it)" if law.tune else ""
            raise ModelError(f"{key}: missing — {setting.meaning} [{setting.unit}]; give [control] {key}{tuned_by}")
    return Tuning(law.name, values, frozenset(from_file), record)


def tuned_laws(design, setup=None, progress=print) -> dict[str, Tuning]:
    """Every registry law's :func:`tuned` settings, in registry order."""
    return {law.name: tuned(law, design, setup, progress) for law in law_registry.LAWS.values()}


def from_artifact(artifact) -> dict[str, Tuning]:
    """Every law's settings as a controller artefact holds them (nothing given, nothing tuned)."""
    out = {}
    for law in law_registry.LAWS.values():
        fields = dict(law.artifact)
        out[law.name] = Tuning(law.name, {s.key: getattr(artifact, fields[s.key]) for s in law.settings}, frozenset())
    return out


def setting_of(design_key: str) -> tuple[Law, Setting] | None:
    """The law and setting a ``[control]`` key (``siso_boundary_layer``) sets, None for another key."""
    for law in law_registry.LAWS.values():
        for setting in law.settings:
            if setting.design_key(law.name) == design_key:
                return law, setting
    return None


def design_keys() -> tuple[str, ...]:
    """Every law setting's ``[control]`` key, in registry order."""
    return tuple(s.design_key(law.name) for law in law_registry.LAWS.values() for s in law.settings)


def with_settings(design, changed: dict[str, Any]):
    """``design`` with ``[control]`` law settings replaced, by their keys (a sweep's grid point)."""
    if not changed:
        return design
    laws = {name: dict(values) for name, values in design.control.law_settings.items()}
    for key, value in changed.items():
        found = setting_of(key)
        if found is None:
            raise ModelError(f"{key}: not a law setting — allowed: {', '.join(design_keys())}")
        law, setting = found
        laws.setdefault(law.name, {})[setting.key] = value
    return dataclasses.replace(design, control=dataclasses.replace(design.control, law_settings=laws))


__all__ = [
    "Tuning",
    "design_keys",
    "from_artifact",
    "given",
    "setting_of",
    "tuned",
    "tuned_laws",
    "untuned",
    "with_settings",
]
