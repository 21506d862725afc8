"""3-vectors as tuples of arrays, with structural zeros: the algebra of :mod:`jaxrb.physics.plane_penalty`.

A vector is a 3-tuple of parts, each an array of any shape (all broadcast
together), or the Python float ``0.0`` where a part is zero by construction
(a component of an axis-aligned plane's normal, and whatever it multiplies):
such a part is never computed, so e.g. the dot product with (0, 0, 1) is the
z part alone. A 3×3 matrix is a tuple of 3 rows of 3 parts.

Written on components because, under ``vmap`` on XLA's CPU backend, math on
``(..., 3)`` arrays runs as narrow loops (DESIGN.md, "Speed"); the array
versions of these functions are in :mod:`jaxrb.math.vector`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxrb.math.vector import safe_div, safe_sqrt, unstack


def is_zero(part) -> bool:
    """Whether ``part`` is a structural zero (the Python float 0.0)."""
    return isinstance(part, float) and part == 0.0


def mul(scale, part):
    """scale · part, a structural zero if either is."""
    return 0.0 if is_zero(part) or is_zero(scale) else scale * part


def dot(a, b):
    """a · b over the non-zero products."""
    terms = [x * y for x, y in zip(a, b) if not (is_zero(x) or is_zero(y))]
    return sum(terms[1:], terms[0]) if terms else 0.0


def cross(a, b):
    """a × b."""
    def term(x, y, z, w):  # x y − z w
        return sub((mul(x, y),), (mul(z, w),))[0]
    return (term(a[1], b[2], a[2], b[1]), term(a[2], b[0], a[0], b[2]), term(a[0], b[1], a[1], b[0]))


def along(scale, vector):
    """scale · vector."""
    return tuple(mul(scale, part) for part in vector)


def add(a, b):
    """a + b."""
    return tuple(y if is_zero(x) else (x if is_zero(y) else x + y) for x, y in zip(a, b))


def sub(a, b):
    """a − b."""
    return tuple((-y if not is_zero(y) else 0.0) if is_zero(x) else (x if is_zero(y) else x - y)
                 for x, y in zip(a, b))


def matvec(matrix, vector):
    """matrix (3 rows of 3 arrays) times vector (3 parts)."""
    return tuple(dot(row, vector) for row in matrix)


def matvec_transposed(matrix, vector):
    """matrixᵀ · vector."""
    return tuple(dot(tuple(row[j] for row in matrix), vector) for j in range(3))


def where(condition, vector):
    """vector where condition, else 0 (zero parts stay zero)."""
    return tuple(part if is_zero(part) else jnp.where(condition, part, 0.0) for part in vector)


def safe_length(vector):
    """|v| with a zero gradient at v = 0 (as :func:`jaxrb.math.vector.safe_norm`)."""
    return safe_sqrt(dot(vector, vector))


def clamp_to_disc(vector, limit):
    """:func:`jaxrb.physics.contact.common.clamp_to_disc` on components: v scaled to length <= limit."""
    length = safe_length(vector)
    return along(jnp.where(length >= limit, safe_div(limit, length), 1.0), vector)


def materialize(vector, params):
    """``vector`` (any tuple of parts) computed once and stored, not recomputed inside each of its consumers.

    XLA's CPU backend fuses an elementwise producer into every consumer and
    recomputes it there: the contact force of each row fed six per-body sums
    (force and torque), and each re-derived the whole contact law. A
    conditional is a fusion boundary XLA keeps, so its operands are computed
    once; ``params.dt > 0`` always holds (Scene.build validates dt) and is
    not batched unless dt itself is swept, where the conditional becomes a
    select and the result is the same. The penalty box drop at batch 1 024
    ran 15 % faster with it (docs/design.md, 'Fusion boundaries'), and the
    hand-written adjoint of :mod:`jaxrb.physics.free_body_adjoint` about 35 % at batch 1.

    Only on the CPU: elsewhere (``jax.lax.platform_dependent``, resolved when
    the step is lowered, so the compiler never sees the choice) the parts
    pass through unchanged, because a conditional on a GPU splits the step
    into more kernels, and there launches, not recomputed arithmetic, set
    the time of a small step (docs/design.md, 'Fusion boundaries').
    """
    present = [i for i, part in enumerate(vector) if not is_zero(part)]

    def stored_by_conditional(parts):
        return jax.lax.cond(params.dt > 0.0, lambda parts: parts,
                            lambda parts: tuple(jnp.zeros_like(part) for part in parts), parts)

    stored = jax.lax.platform_dependent(tuple(vector[i] for i in present),
                                        cpu=stored_by_conditional, default=lambda parts: parts)
    return tuple(stored[present.index(i)] if i in present else 0.0 for i in range(len(vector)))


def matrix_rows(entries):
    """A 3×3 matrix's 9 entries row by row -> 3 rows of 3, as :func:`matrix_parts` lays a matrix out."""
    return tuple(tuple(entries[3 * i:3 * i + 3]) for i in range(3))


def stored_matrix(rows, keep):
    """A 3×3 matrix (3 rows of 3 parts) stored once by ``keep`` (:func:`materialize` with its Params), as rows again."""
    return matrix_rows(keep(tuple(entry for row in rows for entry in row)))


def matrix_parts(matrices):
    """(n, 3, 3) -> rows of (n,) entries."""
    return tuple(unstack(row) for row in unstack(matrices, -2))


class stacked:  # noqa: N801 (used like the module: ``vectors.dot``)
    """This module's vector operations on stacked (..., k) arrays.

    A law written against ``vectors.dot``, ``vectors.along``, … runs in both
    layouts: with this module (vectors as parts of (P, K)) in the component
    step and with ``stacked`` (vectors as (C, k) rows) in the general one, so
    the law is written once (:func:`jaxrb.physics.contact.penalty.contact_law`).
    """

    @staticmethod
    def dot(a, b):
        """a · b over the last axis: (..., k), (..., k) -> (...)."""
        return jnp.sum(a * b, axis=-1)

    @staticmethod
    def along(scale, vector):
        """scale (...) · vector (..., k)."""
        return jnp.asarray(scale)[..., None] * vector

    @staticmethod
    def add(a, b):
        """a + b."""
        return a + b

    @staticmethod
    def sub(a, b):
        """a − b."""
        return a - b

    @staticmethod
    def where(condition, vector):
        """vector (..., k) where condition (...), else 0."""
        return jnp.where(condition[..., None], vector, 0.0)

    @staticmethod
    def safe_length(vector):
        """|v| (...) with a zero gradient at v = 0."""
        return safe_sqrt(jnp.sum(vector * vector, axis=-1))

    @staticmethod
    def clamp_to_disc(vector, limit):
        """v (..., k) scaled to length <= limit (...)."""
        length = stacked.safe_length(vector)
        # >=, not >: with limit 0 the clamp is 0 for every vector, so its derivative
        # at the zero vector is 0, not the identity (an unloaded friction row leaked
        # gradient through a body resting above the plane).
        return stacked.along(jnp.where(length >= limit, safe_div(limit, length), 1.0), vector)
