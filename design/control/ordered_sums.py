"""Sums in the order of the generated C: the Python references sum every dot product and every
accumulation term by term in a fixed order, so that the double build of the C reproduces them bit
for bit (BLAS sums in blocks and with FMA, which differs in the last bits)."""

from __future__ import annotations

import numpy as np


def ordered_matrix_product(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """left @ right column by column with :func:`ordered_product`: these numbers become literals
    of the generated C, which must not depend on the BLAS kernels of the machine that generates it."""
    return np.column_stack([ordered_product(left, right[:, j]) for j in range(right.shape[1])])


def output_terms(output: np.ndarray) -> np.ndarray:
    """The terms of C·x the generated C computes: column 2i + q of sensor row r unless that
    sensor reads component q (velocity q = 0, displacement q = 1) of no coordinate, i.e. unless
    C[r, q::2] is all exact zeros (a displacement sensor reads no velocity). A zero inside a
    partly used component stays a term, so the loops keep their fixed stride.

    Parameters
    ----------
    output : ndarray, shape (n_y, 2n)

    Returns
    -------
    ndarray of bool, shape (n_y, 2n)
    """
    used = np.zeros(output.shape, dtype=bool)
    for component in (0, 1):
        used[:, component::2] = np.any(output[:, component::2] != 0.0, axis=1)[:, None]
    return used


def ordered_product(matrix: np.ndarray, vector: np.ndarray, terms: np.ndarray | None = None) -> np.ndarray:
    """matrix @ vector summed strictly left to right over the columns, starting with the first
    product — the order of the generated C, so the double build reproduces this reference bit
    for bit (BLAS sums in blocks and with FMA, which differs in the last bits).

    Parameters
    ----------
    matrix : ndarray, shape (m, n)
    vector : ndarray, shape (n,)
    terms : ndarray of bool, shape (m, n), optional
        Only these products are summed (structural zeros skipped at generation time, which
        changes x·0 = NaN for x = ±Inf/NaN); a row without a term is 0.

    Returns
    -------
    ndarray, shape (m,)

    Examples
    --------
    >>> ordered_product(np.array([[1.0, 2.0], [3.0, 4.0]]), np.array([1.0, 1.0]))
    array([3., 7.])
    """
    if terms is not None:
        return np.array([_row_sum(row, vector, used) for row, used in zip(matrix, terms)])
    total = matrix[:, 0] * vector[0]
    for k in range(1, matrix.shape[1]):
        total = total + matrix[:, k] * vector[k]
    return total


def multiply_add(
    start: np.ndarray, matrix: np.ndarray, vector: np.ndarray, terms: np.ndarray | None = None
) -> np.ndarray:
    """start + matrix @ vector as a chain of multiply-adds, x ← x + a·b column by column from
    ``start``: the generated C's ``MULTIPLY_ADD`` in its double build (two roundings each, so the
    two agree bit for bit; its float build fuses each into one rounding, ``fmaf``).

    Parameters
    ----------
    start : ndarray, shape (m,)
    matrix : ndarray, shape (m, n)
    vector : ndarray, shape (n,)
    terms : ndarray of bool, shape (m, n), optional
        Only these products are added (structural zeros skipped, as in :func:`ordered_product`).

    Returns
    -------
    ndarray, shape (m,)

    Examples
    --------
    >>> multiply_add(np.array([1.0, 0.0]), np.array([[1.0, 2.0], [3.0, 4.0]]), np.array([1.0, 1.0]))
    array([4., 7.])
    """
    if matrix.shape[1] > matrix.shape[0]:  # a few long rows: one scalar chain each (the same IEEE doubles)
        used = np.ones(matrix.shape, dtype=bool) if terms is None else terms
        return np.array([_chain(float(x), row, vector, keep) for x, row, keep in zip(start, matrix, used)])
    total = np.array(start, dtype=float)
    for k in range(matrix.shape[1]):
        if terms is None:
            total = total + matrix[:, k] * vector[k]
        else:
            total = np.where(terms[:, k], total + matrix[:, k] * vector[k], total)
    return total


def _chain(x: float, row: np.ndarray, vector: np.ndarray, used: np.ndarray) -> float:
    """x + row·vector over the used terms, left to right, in Python floats (IEEE doubles)."""
    for a, b, keep in zip(row.tolist(), vector.tolist(), used.tolist()):
        if keep:
            x = x + a * b
    return x


def _row_sum(row: np.ndarray, vector: np.ndarray, used: np.ndarray) -> float:
    columns = np.flatnonzero(used)
    if columns.size == 0:
        return 0.0
    total = row[columns[0]] * vector[columns[0]]
    for k in columns[1:]:
        total = total + row[k] * vector[k]
    return total


__all__ = ["multiply_add", "ordered_matrix_product", "ordered_product", "output_terms"]
