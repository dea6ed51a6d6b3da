"""Model reduction of the linear subsystem (paper Section 4).

``selection`` scores the modes by their closed-form Hankel singular values (Eq. 16–18), each
input and output channel scaled by its own reference so that the ranking does not depend on units,
``krylov`` adds the Krylov correction vectors and builds the reduced model (Eq. 24–29),
``metrics`` compares a reduced model with the full one (frequency responses, static compliance,
band-limited H2/H∞), and ``study`` runs the reduction example of Section 4.3 (Fig. 10).
Every function here raises `ModelError` (exported too) for a request the model cannot meet.
"""

from smartjoint.common.errors import ModelError
from smartjoint.design.reduction.krylov import (
    NYQUIST_MULTIPLE,
    QUASI_STATIC_DAMPING,
    Reduction,
    correction_frequency,
    krylov_vectors,
    quasi_static_corrections,
    reduce,
)
from smartjoint.design.reduction.metrics import (
    band_norms,
    error_metrics,
    frequency_grid,
    frequency_response,
    modal_compliance,
    static_compliance,
)
from smartjoint.design.reduction.selection import (
    PATHS,
    ChannelReference,
    channel_references,
    hankel_values,
    modal_gramians,
    select_modes,
)
from smartjoint.design.reduction.study import WINDOWS, load_case, reduction_study, study_summary

__all__ = [
    "ChannelReference",
    "ModelError",
    "PATHS",
    "NYQUIST_MULTIPLE",
    "QUASI_STATIC_DAMPING",
    "Reduction",
    "WINDOWS",
    "band_norms",
    "channel_references",
    "correction_frequency",
    "error_metrics",
    "frequency_grid",
    "frequency_response",
    "hankel_values",
    "krylov_vectors",
    "quasi_static_corrections",
    "modal_gramians",
    "modal_compliance",
    "reduce",
    "load_case",
    "reduction_study",
    "select_modes",
    "static_compliance",
    "study_summary",
]
