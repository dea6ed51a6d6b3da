"""Friction joint placement by modal strain energy in the end connectors (paper Section 6, ref. 21).

A type A joint releases the axial slip of a member end against its node, so it can only
dissipate where the modes to be damped strain that end connector axially. For every end
connector c and mode i the fraction of the modal strain energy stored there is

    s_ci = (EA_c / L_c)·Δ_ci² / ω_i²,   Δ_ci = a_cᵀ(u_b − u_a) of the mass-normalised shape ψ_i

(½ψᵀKψ = ½ω² for a mass-normalised mode). A candidate's score is Σ_i s_ci over the target
modes; the joints go to the best-scoring connectors, one per member.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smartjoint.common.errors import ModelError


@dataclass(frozen=True)
class Candidate:
    member: str
    end: str  # "start" | "end"
    fractions: tuple[float, ...]  # s_ci per target mode

    @property
    def score(self) -> float:
        return float(sum(self.fractions))


def connector_energy(fe, modes, targets) -> list[Candidate]:
    """Axial strain-energy fraction of every end connector of the locked truss ``fe`` for the
    target mode indices (0-based) of ``modes`` (from ``modal.solve_modes(fe, …)``).

    Parameters
    ----------
    fe : FEModel
        The locked truss.
    modes : Modes
        Its modes.
    targets : list of int
        The modes to damp (0-based).

    Returns
    -------
    list of Candidate
        One per connector end, with its score (the sum over the targets) and per-mode fractions.
    """
    targets = [int(i) for i in targets]
    if not targets or min(targets) < 0 or max(targets) >= len(modes):
        raise ModelError(f"target modes: {[i + 1 for i in targets]} — must be between 1 and {len(modes)}")
    connectors = [e for e, kind in enumerate(fe.element_kind) if kind == "connector"]
    if not connectors:
        raise ModelError(f"design {fe.design.name!r}: no member has end connectors — nowhere to place a joint")
    shapes = fe.S @ modes.shapes[:, targets]  # (6·points, n_targets) in unconstrained DOFs
    first_of_member: dict[str, int] = {}
    candidates = []
    for e in connectors:
        member = fe.element_member[e]
        end = "start" if first_of_member.setdefault(member, e) == e else "end"
        a, b = fe.element_points[e]
        axis = fe.element_rotation[e, 0]
        length = float(np.linalg.norm(fe.points[b] - fe.points[a]))
        elongation = axis @ (shapes[6 * b : 6 * b + 3] - shapes[6 * a : 6 * a + 3])
        fractions = fe.element_properties[e, 0] / length * elongation**2 / modes.omega[targets] ** 2
        candidates.append(Candidate(member, end, tuple(float(f) for f in fractions)))
    return candidates


TIE_TOLERANCE = 1e-8
"""Relative score difference below which two connectors are tied. Symmetric positions (the two
longerons of one bending plane) score equal up to rounding, and rounding differs per machine:
the eigen solution leaves ~1e-11 relative between mirror images (up to 2e-11 measured over
OpenBLAS kernels), with one sign on one CPU and the opposite sign on another. Distinct positions of the bundled
truss differ by 3.6e-5 relative or more, so 1e-8 separates the two by three orders either side."""


def tied(first: float, second: float) -> bool:
    """Whether two scores are equal within :data:`TIE_TOLERANCE` (relative to the larger).

    Parameters
    ----------
    first, second : float
        The scores.

    Returns
    -------
    bool
    """
    return abs(first - second) <= TIE_TOLERANCE * max(abs(first), abs(second))


def rank(candidates: list[Candidate]) -> list[Candidate]:
    """Best first, with a tie rule that makes the choice the same on every machine.

    The candidates are sorted by score; consecutive scores that are :func:`tied` form one group
    (a chain, so a group can be wider than the tolerance only if the scores are that dense);
    the groups stay in score order and inside a group the candidates go in (member, end)
    order — never by the last bits of their scores.

    Parameters
    ----------
    candidates : list of Candidate
        From `connector_energy`.

    Returns
    -------
    list of Candidate
        Ranked.
    """
    by_score = sorted(candidates, key=lambda c: (-c.score, c.member, c.end))
    groups: list[list[Candidate]] = []
    for candidate in by_score:
        if groups and tied(groups[-1][-1].score, candidate.score):
            groups[-1].append(candidate)
        else:
            groups.append([candidate])
    return [c for group in groups for c in sorted(group, key=lambda c: (c.member, c.end))]


def choose(candidates: list[Candidate], count: int) -> list[Candidate]:
    """The ``count`` best connectors, at most one joint per member.

    Parameters
    ----------
    candidates : list of Candidate
        From `connector_energy`.
    count : int
        Joints to place.

    Returns
    -------
    list of Candidate
        In rank order.
    """
    chosen, members = [], set()
    for candidate in rank(candidates):
        if candidate.member in members:
            continue
        chosen.append(candidate)
        members.add(candidate.member)
        if len(chosen) == count:
            return chosen
    raise ModelError(f"joints: {count} requested, only {len(chosen)} members with end connectors")


def design_text(
    base: str,
    name: str,
    chosen: list[Candidate],
    targets: list[int],
    prefix: str = "A",
    writer: str = "smartjoint place",
) -> str:
    """A design file that extends ``base`` (path relative to the new file) by type A joints at
    the ``chosen`` connectors, named ``A1, A2, …`` in rank order, with the scores as comments.

    Parameters
    ----------
    base : str
        The design extended (``base = …``).
    name : str
        The new design's name.
    chosen : list of Candidate
        From `choose`.
    targets : list of int
        The modes damped (0-based), for the comment.
    prefix : str
        The joint names' prefix.
    writer : str
        The command named in the header comment.

    Returns
    -------
    str
        TOML text.
    """
    lines = [
        f"# Joint placement by modal strain energy (paper Section 6): modes "
        f"{', '.join(str(i + 1) for i in targets)}; written by `{writer}`.",
        f"base = {_quote(base)}",
        f"name = {_quote(name)}",
        "description = "
        + _quote(f"{len(chosen)} type A joints placed for modes " + ", ".join(str(i + 1) for i in targets)),
    ]
    for k, c in enumerate(chosen, start=1):
        lines += [
            "",
            f"# score {c.score:.4g} (strain-energy fraction per mode: "
            + ", ".join(f"{f:.3g}" for f in c.fractions)
            + ")",
            "[[joints]]",
            f"name = {_quote(f'{prefix}{k}')}",
            f"member = {_quote(c.member)}",
            f"end = {_quote(c.end)}",
            'type = "A"',
        ]
    return "\n".join(lines) + "\n"


def _quote(text: str) -> str:
    """A TOML basic string."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


__all__ = ["Candidate", "choose", "connector_energy", "design_text", "rank", "TIE_TOLERANCE", "tied"]
