"""Quaternion algebra and orientation integration, on components.

Quaternions are (w, x, y, z) with w the scalar part, stored on the last axis,
and rotate body-frame vectors into the world frame: v_world = q v_body q*.

The ``*_parts`` functions are the same algebra on component tuples (a
quaternion as a tuple of 4 arrays, a vector as a tuple of 3): the array
functions unpack, call them and stack, and the component-carrying rollout
(:mod:`jaxrb.physics.plane_penalty`) calls them directly.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxrb.math.vector import safe_normalize, unstack


def multiply_parts(a, b):
    """:func:`multiply` on component tuples.

    Args:
        a, b: 4-tuples (w, x, y, z) of arrays, broadcast against each other.

    Returns:
        The 4-tuple of a ⊗ b's components.
    """
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


def multiply(a, b):
    """Hamilton product a ⊗ b (the rotation b followed by a).

    Args:
        a, b: (..., 4) quaternions (w, x, y, z), broadcast against each other.

    Returns:
        (..., 4) the products.
    """
    return jnp.stack(multiply_parts(unstack(a), unstack(b)), axis=-1)


def conjugate(q):
    """Conjugate (the inverse of a unit quaternion).

    Args:
        q: (..., 4) quaternions (w, x, y, z).

    Returns:
        (..., 4) quaternions (w, −x, −y, −z).
    """
    return q * jnp.array([1.0, -1.0, -1.0, -1.0], dtype=q.dtype)


def normalize(q):
    """Unit quaternion along q; the identity where q = 0.

    Args:
        q: (..., 4) quaternions (w, x, y, z), any length.

    Returns:
        (..., 4) unit quaternions; gradient finite at q = 0.
    """
    identity = jnp.array([1.0, 0.0, 0.0, 0.0], dtype=q.dtype)
    return safe_normalize(q, fallback=identity)


def rotate(q, v):
    """Rotate body vectors into the world: R(q) v.

    Exact for any non-zero q, not only unit ones: the rotation part is divided
    by |q|². A renormalised float32 quaternion is 1 ± ~1e-7 long, with a bias,
    and without this the world ↔ body round trip every step scaled ω by that
    bias and drifted |L| by 1e-3 over 4800 steps.

    Args:
        q: (..., 4) non-zero quaternions (w, x, y, z), body to world.
        v: (..., 3) body-frame vectors.

    Returns:
        (..., 3) the world-frame vectors.
    """
    return jnp.stack(rotate_parts(unstack(q), unstack(v)), axis=-1)


def rotate_parts(q, v):
    """:func:`rotate` on component tuples.

    Args:
        q: 4-tuple (w, x, y, z) of arrays, a non-zero quaternion, body to world.
        v: 3-tuple of (...) arrays, a body-frame vector.

    Returns:
        The 3-tuple of R(q) v's components.
    """
    w, x, y, z = q
    vx, vy, vz = v
    inv_norm_sq = 1.0 / (w * w + x * x + y * y + z * z)
    # v' = v + (2w (u x v) + 2 u x (u x v)) / |q|² with u = (x, y, z): no matrix needed.
    tx = 2.0 * inv_norm_sq * (y * vz - z * vy)
    ty = 2.0 * inv_norm_sq * (z * vx - x * vz)
    tz = 2.0 * inv_norm_sq * (x * vy - y * vx)
    return (vx + w * tx + (y * tz - z * ty),
            vy + w * ty + (z * tx - x * tz),
            vz + w * tz + (x * ty - y * tx))


def rotate_inverse(q, v):
    """Rotate world vectors into the body frame: R(q)^T v.

    Args:
        q: (..., 4) unit quaternions (w, x, y, z), body to world.
        v: (..., 3) world-frame vectors.

    Returns:
        (..., 3) the body-frame vectors.
    """
    return rotate(conjugate(q), v)


def to_rotation_matrix(q):
    """Closed-form rotation matrix of a unit quaternion.

    Args:
        q: (..., 4) unit quaternions (w, x, y, z).

    Returns:
        (..., 3, 3) rotation matrices R with R v = q v q*.
    """
    rows = rotation_matrix_parts(unstack(q))
    return jnp.stack([jnp.stack(row, axis=-1) for row in rows], axis=-2)


def rotation_matrix_parts(q, scale=2.0):
    """:func:`to_rotation_matrix` on component tuples.

    Args:
        q: 4-tuple (w, x, y, z) of arrays, a unit quaternion (any non-zero
            one with ``scale`` = 2/|q|²).
        scale: 2 for a unit quaternion; 2/|q|² gives R(q/|q|), what
            :func:`rotate_parts` applies to any non-zero q.

    Returns:
        3 rows of 3 arrays: ``R[i][j]`` is entry (i, j) of R(q).
    """
    w, x, y, z = q
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    return ((1.0 - scale * (yy + zz), scale * (xy - wz), scale * (xz + wy)),
            (scale * (xy + wz), 1.0 - scale * (xx + zz), scale * (yz - wx)),
            (scale * (xz - wy), scale * (yz + wx), 1.0 - scale * (xx + yy)))


def _half_angle_terms(theta_sq):
    """cos(θ/2) and sin(θ/2)/θ from θ², finite with finite derivatives at θ = 0."""
    small = theta_sq < 1e-8
    safe_sq = jnp.where(small, 1.0, theta_sq)
    theta = jnp.sqrt(safe_sq)
    cos_half = jnp.where(small, 1.0 - theta_sq / 8.0 + theta_sq * theta_sq / 384.0,
                         jnp.cos(0.5 * theta))
    sinc_half = jnp.where(small, 0.5 - theta_sq / 48.0 + theta_sq * theta_sq / 3840.0,
                          jnp.sin(0.5 * theta) / theta)
    return cos_half, sinc_half


def exp(rotvec):
    """Quaternion of the rotation by the rotation vector θ·axis.

    Smooth at rotvec = 0, where it returns the identity with the right derivative.

    Args:
        rotvec: (..., 3) rotation vectors (axis times angle in rad).

    Returns:
        (..., 4) unit quaternions (cos θ/2, sin(θ/2)·axis).
    """
    cos_half, sinc_half = _half_angle_terms(jnp.sum(rotvec * rotvec, axis=-1))
    return jnp.concatenate([cos_half[..., None], sinc_half[..., None] * rotvec], axis=-1)


def from_axis_angle(axis, angle):
    """Quaternion rotating by ``angle`` about ``axis``.

    Args:
        axis: (..., 3) rotation axes, any length > 0.
        angle: (...) angles (rad), broadcast against ``axis[..., 0]``.

    Returns:
        (..., 4) unit quaternions (w, x, y, z).
    """
    unit = safe_normalize(axis)
    return exp(unit * jnp.asarray(angle)[..., None])


def integrate_first_order(q, angvel, h):
    """q + h/2 (0, ω) ⊗ q, renormalised.

    Args:
        q: (..., 4) unit quaternions (w, x, y, z), body to world.
        angvel: (..., 3) world-frame angular velocities ω (rad/s).
        h: () time step (s).

    Returns:
        (..., 4) the advanced unit quaternions.
    """
    omega = jnp.concatenate([jnp.zeros_like(angvel[..., :1]), angvel], axis=-1)
    return normalize(q + (0.5 * h) * multiply(omega, q))


def integrate_exp_map(q, angvel, h):
    """exp(h ω) ⊗ q, renormalised against round-off.

    Args:
        q: (..., 4) unit quaternions (w, x, y, z), body to world.
        angvel: (..., 3) world-frame angular velocities ω (rad/s).
        h: () time step (s).

    Returns:
        (..., 4) the advanced unit quaternions.
    """
    return normalize(multiply(exp(h * angvel), q))


ORIENTATION_UPDATES = {"first_order": integrate_first_order, "exp_map": integrate_exp_map}


def normalize_parts(q):
    """:func:`normalize` on component tuples.

    Args:
        q: 4-tuple (w, x, y, z) of arrays, any length.

    Returns:
        The 4-tuple of the unit quaternion; the identity (with a zero
        gradient) where q = 0.
    """
    norm_sq = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]
    nonzero = norm_sq > 0.0
    norm = jnp.sqrt(jnp.where(nonzero, norm_sq, 1.0))
    identity = (1.0, 0.0, 0.0, 0.0)
    return tuple(jnp.where(nonzero, part / norm, fallback) for part, fallback in zip(q, identity))


def integrate_first_order_parts(q, angvel, h):
    """:func:`integrate_first_order` on component tuples.

    Args:
        q: 4-tuple (w, x, y, z) of arrays, unit quaternions, body to world.
        angvel: 3-tuple of (...) arrays, world-frame angular velocity ω (rad/s).
        h: () time step (s).

    Returns:
        The 4-tuple of the advanced unit quaternion.
    """
    change = multiply_parts((jnp.zeros_like(angvel[0]),) + tuple(angvel), q)
    return normalize_parts(tuple(a + (0.5 * h) * b for a, b in zip(q, change)))


def integrate_exp_map_parts(q, angvel, h):
    """:func:`integrate_exp_map` on component tuples.

    Args:
        q: 4-tuple (w, x, y, z) of arrays, unit quaternions, body to world.
        angvel: 3-tuple of (...) arrays, world-frame angular velocity ω (rad/s).
        h: () time step (s).

    Returns:
        The 4-tuple of the advanced unit quaternion.
    """
    rotvec = tuple(h * part for part in angvel)
    cos_half, sinc_half = _half_angle_terms(rotvec[0] * rotvec[0] + rotvec[1] * rotvec[1]
                                            + rotvec[2] * rotvec[2])
    turn = (cos_half,) + tuple(sinc_half * part for part in rotvec)
    return normalize_parts(multiply_parts(turn, q))


ORIENTATION_UPDATES_PARTS = {"first_order": integrate_first_order_parts, "exp_map": integrate_exp_map_parts}
