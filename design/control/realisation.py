"""The realisation the clipped LQG runs in: symmetry-adapted joint and sensor channels, and the
coordinates grouped by the channels they use.

A mirror-symmetric structure (the paper's joints A1/A2 and its two tip sensors) has modes that are
even or odd under the mirror: in an odd mode the paired joints act with opposite signs, in an even
one alike. So the columns of E, M and K and the rows of C come in ±-equal pairs, and a coordinate's
input E_i·u = e·(u_A1 − u_A2) + 0·u_B needs one multiply, not three. In the channels

    ũ_a = u_a + u_b,  ũ_b = u_a − u_b   (a pair a < b; an unpaired channel stays)

the matrices become E' = E·Tᵀ·D⁻¹, M' = M·T_yᵀ·D_y⁻¹, C' = T_y·C and K' = D⁻¹·T·K (D = T·Tᵀ:
2 for a paired channel, 1 alone; the halves are exact in binary), so that E·u = E'·ũ,
M·y = M'·ỹ, C·x = T_y⁻¹·(C'·x) and u_d = −Tᵀ·(K'·x̂) — the same filter, with each coordinate
reading only the channels of its parity. The forward sums and the back transform are additions.

Entries that cancel (|x'| ≤ ``SYMMETRY_TOLERANCE`` × the largest of its row of E or M, its column of
C or K in the design) become structural zeros: the design's symmetry holds to the FE model's and
LAPACK's rounding (1e-12 … 4e-9 relative on the bundled design), so dropping them moves no gain by
more than that tolerance. A row's (column's) scale is at least ``SCALE_FLOOR`` of its matrix's
largest entry: a row far below it, as the Kalman gains of a quasi-static correction coordinate (1e-7
of the matrix), mirrors only to the solver's absolute accuracy. Coordinates that use the same
channels form a group, which the generated C runs as one loop over a table of its own shape; the
reference (``filter._Lqg``) sums in the same order. A design without such pairs, or whose pairs
leave more than ``MAX_GROUPS`` groups, is realised as it is (one group, every channel, the
coordinates in their order): its numbers are the design's own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# An entry whose pair cancels it to this fraction of its row's (column's) largest is a structural zero.
SYMMETRY_TOLERANCE = 1e-6
# A row (column) scale is at least this fraction of its matrix's largest entry: a row far below the
# matrix's scale (a quasi-static coordinate's Kalman gains, 1e-4 against 800) holds its symmetry only
# to the solver's absolute accuracy (1e-9 there), so its own scale would call that an asymmetry.
# Entries then count as cancelled at 1e-6 · 1e-5 = 1e-11 of the matrix's largest at the least.
SCALE_FLOOR = 1e-5
# More groups than this would multiply the generated loops for little gain: realise the design as it is.
MAX_GROUPS = 4


@dataclass(frozen=True)
class Channels:
    """A pairing of l channels: channel k is ``first[k] + sign[k]·second[k]`` of the design's
    channels (``second[k]`` −1: the channel ``first[k]`` alone). A pair (a, b) gives channel a
    the sum and channel b the difference."""

    first: tuple[int, ...]
    second: tuple[int, ...]
    sign: tuple[int, ...]

    @property
    def count(self) -> int:
        return len(self.first)

    @property
    def identity(self) -> bool:
        return all(s < 0 for s in self.second)

    def forward(self, values: np.ndarray) -> np.ndarray:
        """ũ = T·u: a sum or difference per paired channel (one rounding), a copy otherwise."""
        values = np.asarray(values, dtype=float)
        out = values[list(self.first)].copy()
        for k, (b, s) in enumerate(zip(self.second, self.sign)):
            if b >= 0:
                out[k] = out[k] + values[b] if s > 0 else out[k] - values[b]
        return out

    def back(self, values: np.ndarray) -> np.ndarray:
        """u = Tᵀ·g: a paired channel's u_a = g_a + g_b, u_b = g_a − g_b; a copy otherwise."""
        values = np.asarray(values, dtype=float)
        out = values.copy()
        for k, (b, s) in enumerate(zip(self.second, self.sign)):
            if b >= 0:
                a = self.first[k]
                if s > 0:  # channel k (= a) holds the sum, channel b the difference
                    out[a], out[b] = values[a] + values[b], values[a] - values[b]
        return out

    def matrix(self) -> np.ndarray:
        """T (l × l) with entries 0 and ±1."""
        t = np.zeros((self.count, self.count))
        for k, (a, b, s) in enumerate(zip(self.first, self.second, self.sign)):
            t[k, a] = 1.0
            if b >= 0:
                t[k, b] = float(s)
        return t

    def weights(self) -> np.ndarray:
        """diag(D) = diag(T·Tᵀ): 2 for a paired channel, 1 alone."""
        return np.array([2.0 if b >= 0 else 1.0 for b in self.second])

    def terms(self) -> list[tuple[int, int, int]]:
        """(first, second, sign) per channel for the templates (second −1: alone)."""
        return list(zip(self.first, self.second, self.sign))

    def back_terms(self) -> list[tuple[int, int, int]]:
        """Per design channel j the channels of Tᵀ's row j: (k, m, sign) with u_j = g_k + sign·g_m,
        or (k, −1, 1) for a channel alone."""
        rows: list[tuple[int, int, int]] = [(j, -1, 1) for j in range(self.count)]
        for a, b, s in zip(self.first, self.second, self.sign):
            if b >= 0 and s > 0:
                rows[a], rows[b] = (a, b, 1), (a, b, -1)
        return rows


@dataclass(frozen=True)
class Group:
    """Coordinates ``start`` … ``stop − 1`` of the realisation that read the same channels:
    ``joints`` of ũ (their rows of E'), ``feedback_joints`` (their entries of K' − K'M'·C'), ``sensors`` of
    ν (their columns of M'), ``outputs`` of the prediction C'·q with the components each reads
    (0 velocity, 1 displacement)."""

    name: str
    start: int
    stop: int
    joints: tuple[int, ...]
    feedback_joints: tuple[int, ...]
    sensors: tuple[int, ...]
    outputs: tuple[tuple[int, tuple[int, ...]], ...]


@dataclass(frozen=True)
class Realisation:
    """The filter's matrices in the adapted channels, coordinates in group order (``order``:
    the design's coordinate at each position), with the structural zeros exact (0.0)."""

    joints: Channels
    sensors: Channels
    order: tuple[int, ...]
    groups: tuple[Group, ...]
    blocks: np.ndarray  # (n, 2, 2)
    gamma0: np.ndarray  # (n, 2)
    gamma1: np.ndarray  # (n, 2)
    joint_input: np.ndarray  # E' (n, l)
    output: np.ndarray  # C' (ny, 2n)
    estimator_gain: np.ndarray  # M' (2n, ny)
    feedback_gain: np.ndarray  # K' (l, 2n)
    rotation: bool = False  # every Φ_i' = [[α, −β], [β, α]] (``real_jordan``)
    basis: np.ndarray | None = None  # T_i (n, 2, 2): x_i = T_i·z_i; None: z_i = x_i

    def to_design(self, states: np.ndarray) -> np.ndarray:
        """A state vector of the realisation (2n, its order and basis) in the design's: x_i = T_i·z_i,
        at the design's positions."""
        z = np.asarray(states, dtype=float).reshape(-1, 2)
        x = z if self.basis is None else np.einsum("nij,nj->ni", self.basis, z)
        out = np.empty(z.size)
        out[self.state_order()] = x.reshape(-1)
        return out

    def transformation(self) -> np.ndarray:
        """The whole change of basis (2n × 2n) from the realisation's state to the design's order:
        x[state_order()] = blockdiag(T_i)·z."""
        n = self.blocks.shape[0]
        t = np.zeros((2 * n, 2 * n))
        for i in range(n):
            t[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = np.eye(2) if self.basis is None else self.basis[i]
        return t

    @property
    def adapted(self) -> bool:
        return len(self.groups) > 1 or not (self.joints.identity and self.sensors.identity)

    def state_order(self) -> np.ndarray:
        """The design's state index at each position of the realisation's state vector."""
        return np.array([2 * i + c for i in self.order for c in (0, 1)], dtype=int)

    def output_terms(self) -> np.ndarray:
        """The terms of C'·q the step sums (ny × 2n, bool): a group's outputs and their components."""
        used = np.zeros(self.output.shape, dtype=bool)
        for g in self.groups:
            for r, components in g.outputs:
                for c in components:
                    used[r, 2 * g.start + c : 2 * g.stop : 2] = True
        return used

    def estimator_terms(self) -> np.ndarray:
        """The terms of M'·ν (2n × ny, bool): a group's sensors."""
        used = np.zeros(self.estimator_gain.shape, dtype=bool)
        for g in self.groups:
            used[2 * g.start : 2 * g.stop, list(g.sensors)] = True
        return used

    def feedback_terms(self) -> np.ndarray:
        """The terms of K'·q (l × 2n, bool): a group's feedback joints."""
        used = np.zeros(self.feedback_gain.shape, dtype=bool)
        for g in self.groups:
            used[list(g.feedback_joints), 2 * g.start : 2 * g.stop] = True
        return used


def realise(blocks, gamma0, gamma1, joint_input, output, estimator_gain, feedback_gain) -> Realisation:
    """The realisation of a filter (module docstring): its channel pairs, grouped coordinates
    and matrices, or the design as it is when it has no usable symmetry.

    Parameters
    ----------
    blocks : array_like, shape (n, 2, 2)
        Φ_i.
    gamma0, gamma1 : array_like, shape (n, 2)
    joint_input : array_like, shape (n, l)
        E.
    output : array_like, shape (n_y, 2n)
        C.
    estimator_gain : array_like, shape (2n, n_y)
        M.
    feedback_gain : array_like, shape (l, 2n)
        K.

    Returns
    -------
    Realisation
    """
    blocks, gamma0, gamma1 = (np.asarray(v, dtype=float) for v in (blocks, gamma0, gamma1))
    e, c, m, k = (np.asarray(v, dtype=float) for v in (joint_input, output, estimator_gain, feedback_gain))
    n = e.shape[0]
    row_e = np.maximum(np.abs(e).max(axis=1, keepdims=True), SCALE_FLOOR * np.abs(e).max())
    row_m = np.maximum(np.abs(m).max(axis=1, keepdims=True), SCALE_FLOOR * np.abs(m).max())
    column_c = np.maximum(np.abs(c).max(axis=0, keepdims=True), SCALE_FLOOR * np.abs(c).max())
    column_k = np.maximum(np.abs(k).max(axis=0, keepdims=True), SCALE_FLOOR * np.abs(k).max())
    # A joint's signature: its column of E and row of K, each entry against its scale; a sensor's:
    # its row of C and column of M. Paired channels have equal magnitudes entry by entry.
    joints = _pairing(
        np.vstack([e, k.T]), np.vstack([np.broadcast_to(row_e, e.shape), np.broadcast_to(column_k.T, k.T.shape)])
    )
    sensors = _pairing(
        np.vstack([c.T, m]), np.vstack([np.broadcast_to(column_c.T, c.T.shape), np.broadcast_to(row_m, m.shape)])
    )
    plain = real_jordan(_as_designed(blocks, gamma0, gamma1, e, c, m, k))
    if joints.identity and sensors.identity:
        return plain
    wj, ws = joints.weights(), sensors.weights()
    tj, ts = joints.matrix(), sensors.matrix()
    e2 = _cancel(_ordered(e, tj.T) / wj, row_e)
    m2 = _cancel(_ordered(m, ts.T) / ws, row_m)
    c2 = _cancel(_ordered(ts, c), column_c)
    k2 = _cancel(_ordered(tj, k) / wj[:, None], column_k)
    # The update phase forms (K' − K'M'·C')·q, whose zeros are K''s and the product's common ones.
    prior = k2 - _ordered(_ordered(k2, m2), c2)
    signatures = [_signature(i, e2, c2, m2, prior) for i in range(n)]
    kinds = list(dict.fromkeys(signatures))  # in order of first appearance
    if len(kinds) > MAX_GROUPS:
        return plain
    order = tuple(i for kind in kinds for i in range(n) if signatures[i] == kind)
    states = np.array([2 * i + q for i in order for q in (0, 1)], dtype=int)
    groups, start = [], 0
    names = _group_names(kinds, joints)
    for name, kind in zip(names, kinds):
        stop = start + signatures.count(kind)
        joint_set, feedback_set, sensor_set, output_set = kind
        outputs = _outputs(c2, output_set, [i for i in range(n) if signatures[i] == kind])
        groups.append(Group(name, start, stop, joint_set, feedback_set, sensor_set, outputs))
        start = stop
    return real_jordan(
        Realisation(
            joints,
            sensors,
            order,
            tuple(groups),
            blocks[list(order)],
            gamma0[list(order)],
            gamma1[list(order)],
            e2[list(order)],
            c2[:, states],
            m2[states],
            k2[:, states],
        )
    )


def of_artifact(artifact) -> Realisation:
    """The realisation of a controller artefact's filter (:func:`realise` of its matrices)."""
    a = artifact
    return realise(a.blocks, a.gamma0, a.gamma1, a.joint_input, a.output, a.estimator_gain, a.feedback_gain)


def real_jordan(realisation: Realisation) -> Realisation:
    """Each coordinate in the basis z_i = T_i⁻¹·x_i in which its block is a rotation and scaling,
    Φ_i' = [[α, −β], [β, α]] (α ± iβ its eigenvalues), with T_i upper triangular so that a
    sensor that reads only the displacement still reads only z_1; T_i's free scale makes the
    group's first displacement term of C' exactly 1, and the scalar shared by γ ⊗ eᵢᵀ makes
    γ1'[0] exactly 1 (e_i takes the factor). The step then loads 2 numbers of Φ_i' instead of 4
    and adds instead of multiplying by the ones. A design with a block of real eigenvalues (an
    overdamped or rigid coordinate) is left as it is.

    T_i = [[t00, t01], [0, t11]] solves Φ·T = T·Φ': t00 = β·t11/c, t01 = (a − α)·t11/c for
    Φ_i = [[a, b], [c, d]], α = (a + d)/2, β = √(−((a − d)²/4 + b·c)).
    """
    r = realisation
    basis = _jordan_basis(r)
    if basis is None:
        return r
    alpha, beta, t00, t01, t11 = basis
    n = r.blocks.shape[0]
    blocks = np.empty_like(r.blocks)
    blocks[:, 0, 0], blocks[:, 0, 1], blocks[:, 1, 0], blocks[:, 1, 1] = alpha, -beta, beta, alpha

    def inverse(v: np.ndarray) -> np.ndarray:  # T⁻¹·v per coordinate, v (n, 2, …)
        second = v[:, 1] / t11.reshape((n,) + (1,) * (v.ndim - 2))
        first = (v[:, 0] - t01.reshape(second.shape[:1] + (1,) * (v.ndim - 2)) * second) / t00.reshape(
            (n,) + (1,) * (v.ndim - 2)
        )
        return np.stack([first, second], axis=1)

    def times(v: np.ndarray) -> np.ndarray:  # columns 2i, 2i+1 of v (…, 2n) times T_i
        pairs = v.reshape(v.shape[0], n, 2)
        first = pairs[:, :, 0] * t00
        second = pairs[:, :, 0] * t01 + pairs[:, :, 1] * t11
        return np.stack([first, second], axis=2).reshape(v.shape)

    gamma0, gamma1 = inverse(r.gamma0), inverse(r.gamma1)
    estimator = inverse(r.estimator_gain.reshape(n, 2, -1)).reshape(r.estimator_gain.shape)
    output, feedback = times(r.output), times(r.feedback_gain)
    for g in r.groups:  # the normalised entries exactly 1, as their rounding would not be
        terms = [(s, q) for s, components in g.outputs for q in components if q == 1]
        if terms and np.all(t11[g.start : g.stop] != 1.0):
            output[terms[0][0], 2 * g.start + 1 : 2 * g.stop : 2] = 1.0
    joint_input, gamma0, gamma1 = _unit_hold(r.joint_input, gamma0, gamma1)
    groups = tuple(
        Group(
            g.name,
            g.start,
            g.stop,
            g.joints,
            g.feedback_joints,
            g.sensors,
            _outputs(output, tuple(s for s, _ in g.outputs), list(range(g.start, g.stop))),
        )
        for g in r.groups
    )
    basis = np.zeros((n, 2, 2))
    basis[:, 0, 0], basis[:, 0, 1], basis[:, 1, 1] = t00, t01, t11
    return Realisation(
        r.joints,
        r.sensors,
        r.order,
        groups,
        blocks,
        gamma0,
        gamma1,
        joint_input,
        output,
        estimator,
        feedback,
        True,
        basis,
    )


def _jordan_basis(r: Realisation):
    """(α, β, t00, t01, t11) per coordinate (``real_jordan``), or None when a block has real
    eigenvalues; t11 makes the group's first displacement term of C' one where it can."""
    a, b, c, d = r.blocks[:, 0, 0], r.blocks[:, 0, 1], r.blocks[:, 1, 0], r.blocks[:, 1, 1]
    alpha = (a + d) / 2.0
    discriminant = ((a - d) / 2.0) ** 2 + b * c
    if np.any(discriminant >= 0.0) or np.any(c == 0.0):
        return None
    beta = np.sqrt(-discriminant)
    t00, t01, t11 = beta / c, (a - alpha) / c, np.ones(r.blocks.shape[0])
    for g in r.groups:
        terms = [(s, q) for s, components in g.outputs for q in components if q == 1]
        if not terms:
            continue
        sensor = terms[0][0]
        value = np.array(
            [r.output[sensor, 2 * i] * t01[i] + r.output[sensor, 2 * i + 1] for i in range(g.start, g.stop)]
        )
        if np.all(value != 0.0) and np.all(np.isfinite(1.0 / value)):
            t11[g.start : g.stop] = 1.0 / value
    return alpha, beta, t00 * t11, t01 * t11, t11


def _unit_hold(joint_input: np.ndarray, gamma0: np.ndarray, gamma1: np.ndarray):
    """γ ⊗ eᵢᵀ with the shared scalar moved into eᵢ so that γ1[0] is exactly 1 (where it is a
    usable nonzero number)."""
    joint_input = joint_input.copy()
    scale = gamma1[:, 0]
    usable = (scale != 0.0) & np.isfinite(1.0 / np.where(scale != 0.0, scale, 1.0))
    joint_input[usable] = joint_input[usable] * scale[usable, None]
    gamma0[usable] = gamma0[usable] / scale[usable, None]
    gamma1[usable] = gamma1[usable] / scale[usable, None]
    gamma1[usable, 0] = 1.0
    return joint_input, gamma0, gamma1


def _as_designed(blocks, gamma0, gamma1, e, c, m, k) -> Realisation:
    """One group of every channel, the design's matrices and order (C's unread components apart)."""
    n, ny = e.shape[0], c.shape[0]
    outputs = tuple((r, tuple(q for q in (0, 1) if np.any(c[r, q::2] != 0.0))) for r in range(ny))
    everything = tuple(range(e.shape[1]))
    group = Group("coordinate", 0, n, everything, everything, tuple(range(ny)), tuple(o for o in outputs if o[1]))
    same = Channels(everything, (-1,) * len(everything), (1,) * len(everything))
    sensors = Channels(tuple(range(ny)), (-1,) * ny, (1,) * ny)
    return Realisation(same, sensors, tuple(range(n)), (group,), blocks, gamma0, gamma1, e, c, m, k)


def _pairing(signature: np.ndarray, scale: np.ndarray) -> Channels:
    """Pair channels (columns of ``signature``) whose entries have equal magnitudes to the
    tolerance, each with the first later channel that matches; the rest stay alone."""
    count = signature.shape[1]
    first, second, sign = list(range(count)), [-1] * count, [1] * count
    for a in range(count):
        if second[a] >= 0:
            continue
        for b in range(a + 1, count):
            if second[b] >= 0:
                continue
            limit = SYMMETRY_TOLERANCE * scale[:, a]
            x, y = signature[:, a], signature[:, b]
            close = np.abs(np.abs(x) - np.abs(y)) <= limit
            cancels = np.minimum(np.abs(x - y), np.abs(x + y)) <= limit
            if np.all(close & cancels) and np.any(x != 0.0):
                second[a] = second[b] = b  # channel a: u_a + u_b; channel b: u_a − u_b
                first[b], sign[b] = a, -1
                break
    return Channels(tuple(first), tuple(second), tuple(sign))


def _ordered(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """left @ right summed left to right (no BLAS: the result must not depend on the machine's
    kernels; with T's entries 0 and ±1 each entry is one sum or difference, exact to one rounding)."""
    out = np.zeros((left.shape[0], right.shape[1]))
    for j in range(left.shape[1]):
        out = out + left[:, j : j + 1] * right[j : j + 1, :]
    return out


def _cancel(values: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The entries that cancelled to the tolerance of their scale set to exactly 0."""
    return np.where(np.abs(values) <= SYMMETRY_TOLERANCE * scale, 0.0, values)


def _signature(i: int, e: np.ndarray, c: np.ndarray, m: np.ndarray, k: np.ndarray) -> tuple:
    """The channels coordinate i reads: ũ in E', the joints of K' − K'M'C', ν in M', C''s sensors."""
    rows = slice(2 * i, 2 * i + 2)
    return (
        tuple(int(j) for j in np.flatnonzero(e[i] != 0.0)),
        tuple(int(j) for j in np.flatnonzero(np.any(k[:, rows] != 0.0, axis=1))),
        tuple(int(r) for r in np.flatnonzero(np.any(m[rows] != 0.0, axis=0))),
        tuple(int(r) for r in np.flatnonzero(np.any(c[:, rows] != 0.0, axis=1))),
    )


def _outputs(c: np.ndarray, sensors: tuple[int, ...], coordinates: list[int]) -> tuple:
    """The components (0 velocity, 1 displacement) each sensor channel reads over a group's
    coordinates: a zero inside a used component stays a term, so the loop keeps its shape."""
    return tuple((r, tuple(q for q in (0, 1) if any(c[r, 2 * i + q] != 0.0 for i in coordinates))) for r in sensors)


def _group_names(kinds: list, joints: Channels) -> list[str]:
    """ "even" for the coordinates whose joints act alike (sums and unpaired joints only), "odd" for
    those that read differences only, when there are exactly these two; "group<g>" otherwise."""
    differences = {k for k, s in enumerate(joints.sign) if s < 0}
    parity = [
        "odd" if set(kind[0]) <= differences else "even" if not set(kind[0]) & differences else "" for kind in kinds
    ]
    return parity if sorted(parity) == ["even", "odd"] else [f"group{g}" for g in range(len(kinds))]


__all__ = [
    "MAX_GROUPS",
    "SYMMETRY_TOLERANCE",
    "Channels",
    "Group",
    "Realisation",
    "of_artifact",
    "real_jordan",
    "realise",
]
