"""Cholesky and LU factorisations of small dense matrices, written in ``jax.numpy``.

Why not ``jax.scipy.linalg``: on CPU its factorisations and triangular solves
are LAPACK custom calls, and jaxlib 0.10 spreads a vmapped batch of them over
XLA's CPU thread pool (``ParallelBatchMap``) and waits for the pieces from a
thread of that same pool. With a large enough batch every thread of the pool
waits and the program hangs, idle, for ever: measured on 2 cores with the
forward-mode Jacobian of the elbow's short-horizon residuals (1 140 segments
× 4 parameters through ``lapack_strsm``). The matrices of a joint tree are
nv × nv with nv from 1 to a few tens, so here each factorisation and solve
is a loop over columns unrolled when traced: ordinary XLA fusions that vmap,
differentiate and run on every backend like the rest of the step.

Every function takes one matrix (nv, nv); ``vmap`` adds batches.
"""

from __future__ import annotations

import jax.numpy as jnp


def cholesky(matrix):
    """Lower-triangular L with L Lᵀ = ``matrix`` (symmetric positive definite, (n, n))."""
    matrix = jnp.asarray(matrix)
    size = matrix.shape[-1]
    lower = jnp.zeros_like(matrix)
    for column in range(size):
        remainder = matrix[column:, column] - lower[column:, :column] @ lower[column, :column]
        lower = lower.at[column:, column].set(remainder / jnp.sqrt(remainder[0]))
    return lower


def _forward(lower, rhs, unit_diagonal=False):
    """Solve L y = rhs for lower-triangular L (n, n); rhs (n,) or (n, k)."""
    out = jnp.zeros_like(rhs)
    for row in range(lower.shape[-1]):
        value = rhs[row] - lower[row, :row] @ out[:row]
        out = out.at[row].set(value if unit_diagonal else value / lower[row, row])
    return out


def _backward(upper, rhs):
    """Solve U x = rhs for upper-triangular U (n, n); rhs (n,) or (n, k)."""
    size = upper.shape[-1]
    out = jnp.zeros_like(rhs)
    for row in reversed(range(size)):
        out = out.at[row].set((rhs[row] - upper[row, row + 1:] @ out[row + 1:]) / upper[row, row])
    return out


def cholesky_solve(lower, rhs):
    """A⁻¹ rhs from A's Cholesky factor ``lower`` (n, n); rhs (n,) or (n, k)."""
    return _backward(lower.T, _forward(lower, rhs))


def lu_factor(matrix):
    """LU with partial pivoting of ``matrix`` (n, n).

    Returns:
        (packed (n, n): U on and above the diagonal, L's multipliers below it
        (L's diagonal is 1), permutation (n,) int: row i of P A is row
        ``permutation[i]`` of A).
    """
    size = matrix.shape[-1]
    packed, permutation = jnp.asarray(matrix), jnp.arange(size)
    rows = jnp.arange(size)
    for column in range(size):
        pivot = column + jnp.argmax(jnp.abs(packed[column:, column]))
        swap = jnp.where(rows == column, pivot, jnp.where(rows == pivot, column, rows))
        packed, permutation = packed[swap], permutation[swap]
        multipliers = packed[column + 1:, column] / packed[column, column]
        packed = packed.at[column + 1:, column].set(multipliers)
        packed = packed.at[column + 1:, column + 1:].add(-multipliers[:, None] * packed[column, column + 1:][None, :])
    return packed, permutation


def lu_solve(packed, permutation, rhs):
    """A⁻¹ rhs from :func:`lu_factor`'s result; rhs (n,) or (n, k)."""
    return _backward(jnp.triu(packed), _forward(packed, rhs[permutation], unit_diagonal=True))
