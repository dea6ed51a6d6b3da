"""The registry of simulation schemes: name → the module that checks a run and builds its kernel.

``loop.simulate`` looks the scheme up here (``scheme=`` by name; by default "fixed", or
"stick_exact" when ``stick_step`` is given). A scheme is a module with ``check(run)``,
``kernel(run)``, ``FRICTION`` and ``COMPACT_DISTURBANCE`` (``kernel.Scheme``); adding one — a
new integrator, an FMU, a processor-in-the-loop target — is one new module and one line below
(docs/simulation.md shows the recipe).
"""

from __future__ import annotations

from smartjoint.common.errors import ModelError
from smartjoint.design.plant import fixed_step, linear, stick_exact
from smartjoint.design.plant.kernel import Scheme

SCHEMES: dict[str, Scheme] = {
    "fixed": fixed_step,  # the default: fixed step, implicit joints, exact modal blocks
    "stick_exact": stick_exact,  # long exact steps while every joint sticks (reduced models)
    "linear": linear,  # frictionless, driven by the controller's joint forces (the active reference)
}


def scheme(name: str) -> Scheme:
    """The scheme registered as ``name``.

    Parameters
    ----------
    name : str
        A key of :data:`SCHEMES`.

    Returns
    -------
    Scheme
        The module providing ``check``, ``kernel``, ``FRICTION`` and ``COMPACT_DISTURBANCE``.

    Examples
    --------
    >>> scheme("fixed").FRICTION
    True
    """
    if name not in SCHEMES:
        raise ModelError(f"scheme: {name!r} — must be one of {', '.join(repr(k) for k in SCHEMES)}")
    return SCHEMES[name]


__all__ = ["SCHEMES", "scheme"]
