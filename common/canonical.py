"""Canonical signs of basis vectors, the same on every machine.

An eigenvector is defined up to its sign, and LAPACK, ARPACK and the BLAS kernels under them
pick a sign that can change with the last bits of the input: another CPU, another OpenBLAS kernel,
or an input perturbed by 1e-12. Every matrix derived from the basis then flips rows or columns,
and so does the controller artefact and its firmware. A rule such as "largest entry positive" is
no cure on a mirror-symmetric structure, where the largest entries of an antisymmetric mode are
equal and opposite and their last bits decide.

The rule here is a fixed linear functional, seeded and independent of the machine: each vector's
sign makes w·φ > 0 for a pseudo-random w. Its value is of the order |φ|/√N for any vector of a
structure (w has no symmetry to share with it), so no rounding-level change can flip it.
"""

from __future__ import annotations

import numpy as np

SEED = 20_261_207  # of the functional's weights: fixed forever, or every artefact's signs change


def functional(rows: int) -> np.ndarray:
    """The weights w (``rows``,) of the sign rule: standard normal numbers from a fixed seed."""
    return np.random.default_rng(SEED).standard_normal(rows)


def canonical_signs(vectors: np.ndarray) -> np.ndarray:
    """``vectors`` (N, m), each column multiplied by ±1 so that w·φ > 0 (:func:`functional`).

    Parameters
    ----------
    vectors : ndarray
        Basis vectors as columns.

    Returns
    -------
    ndarray
        The same vectors with canonical signs; a column with w·φ = 0 (exactly) keeps its sign.
    """
    projection = functional(vectors.shape[0]) @ vectors
    return vectors * np.where(projection < 0.0, -1.0, 1.0)


__all__ = ["SEED", "canonical_signs", "functional"]
