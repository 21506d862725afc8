"""Small, gradient-safe vector math written on components.

Vectors keep their public trailing axis (``(..., 3)`` or ``(..., 2)``), but the
kernels unpack the components and spell dot, cross and 3x3 products out: under
``vmap`` on XLA's CPU backend this runs as wide elementwise loops instead of many
tiny ones (see DESIGN.md, "Speed").

Every function that can meet a zero (norms, divisions, normalisation) uses the
double-``where`` trick so both the value and its gradient stay finite there.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def unstack(x, axis=-1):
    """The slices of ``x`` along ``axis`` (that axis dropped), as a tuple.

    ``lax.split`` rather than indexing: reverse mode transposes one split
    into one concatenate, where ``x[..., 0]``, ``x[..., 1]``, ... each
    transpose into a pad of the whole array, summed.

    Args:
        x: (..., k, ...) array.
        axis: the axis to take apart.

    Returns:
        k arrays of x's shape without ``axis``.
    """
    return tuple(jnp.squeeze(part, axis) for part in jax.lax.split(x, (1,) * x.shape[axis], axis=axis))


def dot(a, b):
    """Dot product over the last axis.

    Args:
        a, b: (..., k) vectors (broadcast against each other).

    Returns:
        (...) the dot products.
    """
    return sum(x * y for x, y in zip(unstack(a), unstack(b)))


def matmul(a, b):
    """a @ b (numpy's rules) spelt out over the contracted axis, for small operands.

    Under ``vmap`` a ``@`` becomes a batched dot_general: a library call over
    thousands of tiny matrices (four such products in a 10-box stack's box-box
    kernel took about a fifth of its step). Spelt out, it fuses into XLA's
    elementwise loops.

    Args:
        a: (..., m, k) matrices or a (k,) vector.
        b: (..., k, n) matrices or a (k,) vector.

    Returns:
        The product: (..., m, n), (..., m), (..., n) or ().
    """
    if b.ndim == 1:
        return sum(x * y for x, y in zip(unstack(a), unstack(b)))
    if a.ndim == 1:
        return sum(x * row for x, row in zip(unstack(a), unstack(b, -2)))
    return sum(column[..., :, None] * row[..., None, :] for column, row in zip(unstack(a), unstack(b, -2)))


def cross(a, b):
    """3D cross product a × b.

    Args:
        a, b: (..., 3) vectors (broadcast against each other).

    Returns:
        (..., 3) the cross products.
    """
    ax, ay, az = unstack(a)
    bx, by, bz = unstack(b)
    return jnp.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


def cross2(a, b):
    """2D cross product (the z component of a × b).

    Args:
        a, b: (..., 2) vectors (broadcast against each other).

    Returns:
        (...) a_x b_y − a_y b_x.
    """
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def cross_scalar2(w, r):
    """w e_z × r: the velocity of point r of a 2D body spinning at rate w.

    Args:
        w: (...) scalar angular velocities about e_z.
        r: (..., 2) vectors in the plane.

    Returns:
        (..., 2) the vectors (−w r_y, w r_x).
    """
    return jnp.stack([-w * r[..., 1], w * r[..., 0]], axis=-1)


def safe_norm(x, axis=-1, keepdims=False):
    """Euclidean norm whose gradient at x = 0 is 0 instead of NaN.

    Args:
        x: (..., k) vectors.
        axis: the axis to reduce (an int, default the last).
        keepdims: keep the reduced axis with length 1.

    Returns:
        (...) norms, or (..., 1) with ``keepdims``.
    """
    return safe_sqrt(jnp.sum(x * x, axis=axis, keepdims=keepdims))


def safe_sqrt(x):
    """√x for x >= 0 whose gradient at x = 0 is 0 instead of infinite.

    Args:
        x: (...) non-negative values (squared lengths).

    Returns:
        (...) the square roots.
    """
    nonzero = x > 0.0
    return jnp.where(nonzero, jnp.sqrt(jnp.where(nonzero, x, 1.0)), 0.0)


def safe_div(num, den, fallback=0.0):
    """num / den, and ``fallback`` (with zero gradient) where den == 0.

    Args:
        num: (...) numerators.
        den: (...) denominators, broadcast against ``num``.
        fallback: () or (...) value where ``den`` is zero.

    Returns:
        (...) the quotients, broadcast shape of the inputs.
    """
    nonzero = den != 0.0
    return jnp.where(nonzero, num / jnp.where(nonzero, den, 1.0), fallback)


def safe_normalize(x, axis=-1, fallback=None):
    """x / |x| along ``axis``; where |x| = 0 returns ``fallback`` (default: zeros).

    Args:
        x: (..., k) vectors.
        axis: the axis holding the vector components (an int, default the last).
        fallback: optional (k,) or (..., k) vector used where x is zero.

    Returns:
        (..., k) unit vectors (or ``fallback`` where x is zero), dtype of x.
    """
    norm = safe_norm(x, axis=axis, keepdims=True)
    nonzero = norm > 0.0
    unit = x / jnp.where(nonzero, norm, 1.0)
    if fallback is None:
        fallback = jnp.zeros_like(x)
    return jnp.where(nonzero, unit, jnp.broadcast_to(fallback, x.shape).astype(x.dtype))


def matvec3(m, v):
    """m @ v for 3x3 matrices, spelt out on components.

    Args:
        m: (..., 3, 3) matrices.
        v: (..., 3) vectors.

    Returns:
        (..., 3) the products.
    """
    vx, vy, vz = unstack(v)
    return jnp.stack([row[0] * vx + row[1] * vy + row[2] * vz
                      for row in (unstack(r) for r in unstack(m, -2))], axis=-1)


def inverse3(m):
    """Closed-form inverse of 3x3 matrices via the adjugate.

    The caller guarantees invertibility (inertia tensors are validated at build
    time); no pivoting is needed for the well-conditioned matrices we invert.

    Args:
        m: (..., 3, 3) invertible matrices.

    Returns:
        (..., 3, 3) the inverses.
    """
    (a, b, c), (d, e, f), (g, h, i) = (unstack(row) for row in unstack(m, -2))
    co00, co01, co02 = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * co00 + b * co01 + c * co02
    inv_det = 1.0 / det
    rows = [
        [co00, c * h - b * i, b * f - c * e],
        [co01, a * i - c * g, c * d - a * f],
        [co02, b * g - a * h, a * e - b * d],
    ]
    return jnp.stack([jnp.stack(row, axis=-1) for row in rows], axis=-2) * inv_det[..., None, None]


def rot2(angle):
    """2D rotation matrices.

    Args:
        angle: (...) rotation angles (rad), counter-clockwise.

    Returns:
        (..., 2, 2) the matrices [[cos, −sin], [sin, cos]].
    """
    c, s = jnp.cos(angle), jnp.sin(angle)
    return jnp.stack([jnp.stack([c, -s], axis=-1), jnp.stack([s, c], axis=-1)], axis=-2)


def rotate2(angle, v):
    """Rotate 2D vectors by ``angle``.

    Args:
        angle: (...) rotation angles (rad), counter-clockwise.
        v: (..., 2) vectors.

    Returns:
        (..., 2) the rotated vectors.
    """
    c, s = jnp.cos(angle), jnp.sin(angle)
    return jnp.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)
