"""The friction's uncertainty from its identification: each LuGre parameter's factor drawn from
the 95 % interval the identification states (``design.friction.identify``: exp(θ ± 1.96σ_θ)),
for the ensemble stage of ``smartjoint run`` and for sweeps whose ``[uncertain.friction]`` says
``from = "identification"``."""

from __future__ import annotations

import math

from smartjoint.common import friction_registry
from smartjoint.design.control.sweep_file import Distribution, UncertainInput

FRICTION_SPREAD = 0.05  # ± of the uniform factor of a parameter the identification gives no interval for
Z95 = 1.959963984540054  # the 97.5 % point of the normal distribution: a 95 % interval is exp(θ ± Z95·σ_θ)
# A weakly identifiable parameter's interval spans decades (σ1, σ2 in the paper): drawn at most
# within a factor 2 at 95 % — the identification does not bound it, and factors of 10^±3 leave
# the friction law's physical range.
MAX_LOG_SIGMA = math.log(2.0) / Z95


def friction_spreads(friction) -> dict[str, float]:
    """σ_θ of each LuGre parameter's logarithm from the identification's 95 % intervals
    (``identify``: exp(θ ± 1.96σ_θ)), the widest over the design's joint types.

    Parameters
    ----------
    friction : list of JointTypeFriction
        The friction stage's results (``design.friction.stage.friction_stage``).

    Returns
    -------
    dict
        Parameter → σ_θ (at most ``MAX_LOG_SIGMA``), for the parameters with a finite positive
        interval.
    """
    spreads: dict[str, float] = {}
    for result in friction:
        keys = friction_registry.friction_model(result.identification.parameters.model).keys
        for name, entry in result.identification.as_dict()["parameters"].items():
            interval = entry.get("ci95")
            if name in keys and interval and 0.0 < interval[0] < interval[1] < math.inf:
                sigma = (math.log(interval[1]) - math.log(interval[0])) / (2.0 * Z95)
                spreads[name] = min(max(spreads.get(name, 0.0), sigma), MAX_LOG_SIGMA)
    return spreads


def friction_inputs(spreads: dict[str, float], model: str = friction_registry.DEFAULT) -> tuple[UncertainInput, ...]:
    """Each parameter's factor (of the friction model ``model``, drawn per joint): lognormal of
    median 1 and σ_θ truncated to the 95 % interval where the identification gives one (however
    wide: a weakly identifiable parameter is that uncertain), else uniform ±FRICTION_SPREAD."""
    inputs = []
    for name in friction_registry.friction_model(model).keys:
        sigma = spreads.get(name)
        if sigma is None or not sigma > 0.0:
            low, high = 1.0 - FRICTION_SPREAD, 1.0 + FRICTION_SPREAD
            inputs.append(UncertainInput(f"friction.{name}", Distribution("uniform", low, high)))
        else:
            low, high = math.exp(-Z95 * sigma), math.exp(Z95 * sigma)
            inputs.append(
                UncertainInput(f"friction.{name}", Distribution("lognormal", low, high, median=1.0, sigma=sigma))
            )
    return tuple(inputs)


__all__ = ["FRICTION_SPREAD", "MAX_LOG_SIGMA", "Z95", "friction_inputs", "friction_spreads"]
