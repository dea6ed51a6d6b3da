"""The portability leg's input perturbation (``pytest --perturb-inputs=RELATIVE``).

Other machines compute the same model with other last bits (OpenBLAS kernels, libm, FMA), so a
result that holds only for one machine's rounding is not a result. Multiplying every physical
input of the model by ``1 + RELATIVE·r`` with ``r`` in [−1, 1] has the same effect portably,
without touching the machine's BLAS settings: every design that ``parse_design`` (hence
``load_design``) returns gets its material constants, tube sections, connector properties, node
type and point masses and node coordinates perturbed, and so do the joints' LuGre parameters
(the design's ``[friction]``, a joint's own, and Table 1 where the rig command uses it).
Mirror-symmetric positions stop being bit-for-bit mirrors, as they are not on other machines.

``r`` is a hash of the value's place (e.g. ``nodes/N3_1/position/2``), so every run, process and
machine perturbs the same inputs by the same amount. Sample times, durations, counts and the
controller settings stay as written: they are the same bits on every machine.

This file is named ``sitecustomize`` so that Python subprocesses of the tests (the command line)
install the same perturbation: the test option puts this folder on ``PYTHONPATH`` and sets
``SMARTJOINT_PERTURB_INPUTS``. Without that variable, importing it does nothing.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os

VARIABLE = "SMARTJOINT_PERTURB_INPUTS"


def factor(relative: float, *place) -> float:
    """1 + relative·r, r ∈ [−1, 1] a hash of ``place`` (deterministic everywhere)."""
    digest = hashlib.sha256("/".join(str(p) for p in place).encode()).digest()
    r = int.from_bytes(digest[:8], "little") / 2.0**63 - 1.0
    return 1.0 + relative * r


def _scaled(item, relative: float, *place):
    """``item`` (a frozen dataclass) with every float field, and every float of a tuple field,
    multiplied by its own factor."""
    changes = {}
    for f in dataclasses.fields(item):
        value = getattr(item, f.name)
        if isinstance(value, float):
            changes[f.name] = value * factor(relative, *place, f.name)
        elif f.name == "position":
            changes[f.name] = tuple(v * factor(relative, *place, f.name, k) for k, v in enumerate(value))
    return dataclasses.replace(item, **changes)


def perturb_design(design, relative: float):
    """The design with its physical inputs perturbed (the tables named in the module text)."""
    tables = {
        table: {name: _scaled(value, relative, table, name) for name, value in getattr(design, table).items()}
        for table in ("materials", "sections", "connectors", "node_types", "nodes")
    }
    masses = tuple(_scaled(m, relative, "point_masses", k, m.node) for k, m in enumerate(design.point_masses))
    friction = {kind: _scaled(f, relative, "friction", kind) for kind, f in design.friction.items()}
    joints = tuple(
        j if j.friction is None else dataclasses.replace(j, friction=_scaled(j.friction, relative, "joints", j.name))
        for j in design.joints
    )
    return dataclasses.replace(design, point_masses=masses, friction=friction, joints=joints, **tables)


def install(relative: float) -> None:
    """Perturb every design parsed from now on and Table 1, by about ``relative``. Idempotent."""
    import smartjoint.design as package
    import smartjoint.design.structure as structure
    from smartjoint.design.friction import lugre
    from smartjoint.design.structure import spec

    if getattr(spec.parse_design, "perturbation", None) is not None:
        return
    original = spec.parse_design

    def parse_design(data, source="<memory>", origins=None):
        return perturb_design(original(data, source, origins), relative)

    parse_design.__doc__ = original.__doc__
    parse_design.perturbation = relative
    spec.parse_design = package.parse_design = structure.parse_design = parse_design
    for joint_type, parameters in list(lugre.TABLE_1.items()):
        lugre.TABLE_1[joint_type] = _scaled(parameters, relative, "lugre", joint_type)
    lugre.TYPE_A, lugre.TYPE_B = lugre.TABLE_1["A"], lugre.TABLE_1["B"]


if os.environ.get(VARIABLE):
    install(float(os.environ[VARIABLE]))
