"""Narrowphase kernels of round shapes: sphere (circle) and capsule pairs.

Every kernel follows :mod:`jaxrb.physics.collision.contacts`: one pair in, ``Contacts``
with a fixed number of slots out, normal from B to A, ``dist`` = distance of the
core features (centre or segment) minus both radii, ``point`` midway between the
two surfaces, finite values and gradients everywhere.

A capsule is the set of points within ``radius`` of its core segment
``origin + s * rotation[:, 2]``, ``s`` in ``[-half_length, half_length]``, so
capsules are 3D shapes. ``sphere_sphere`` is dimension-agnostic and also serves
2D circles.

Fallback normals, used where the core features touch and the direction from B
to A is undefined (the contact is still reported, with ``dist = -ra - rb``):

* ``sphere_sphere``, coincident centres: the last world axis (+z in 3D, +y in 2D).
* ``capsule_sphere``, sphere centre on the capsule's segment: the capsule's
  shape-frame x axis, ``rotation_a[:, 0]`` (perpendicular to its axis).
* ``capsule_capsule``, intersecting segments: ``normalize(axis_a x axis_b)``,
  which flips sign when A and B swap; if the segments are also parallel,
  ``rotation_a[:, 0]``.

These fallbacks are not antisymmetric under swapping A and B (except the
capsule-capsule cross product); elsewhere swapping A and B negates the normal and
keeps ``dist`` and ``point``.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxrb.physics.collision.contacts import Contacts
from jaxrb.math.vector import cross, dot, safe_norm, safe_normalize

#: capsule_capsule reports a second contact when sin(angle between the axes) is
#: below this and the segments overlap along A's axis.
PARALLEL_SIN = 0.1

#: The second capsule_capsule contact is dropped (valid=False) when it lies
#: closer than this fraction of ``radius_a + radius_b`` to the first along A's
#: axis, so a barely overlapping pair does not get a duplicated contact.
DUPLICATE_FRACTION = 1e-3


def _core_contact(center_a, center_b, radius_a, radius_b, fallback):
    """Contact between two balls. centers: (dim,), fallback: (dim,) unit normal.

    Returns ``(dist (), normal (dim,), point (dim,))``; where the centres coincide
    the normal is ``fallback`` and every value and gradient stays finite.
    """
    delta = center_a - center_b
    normal = safe_normalize(delta, fallback=fallback)
    dist = safe_norm(delta) - radius_a - radius_b
    # Midway between A's surface (center_a - ra n) and B's (center_b + rb n).
    point = 0.5 * (center_a + center_b) + (0.5 * (radius_b - radius_a)) * normal
    return dist, normal, point


def _stack(contacts, valid):
    """Contacts from a list of (dist, normal, point) slots and a (K,) valid mask."""
    dist, normal, point = (jnp.stack(parts) for parts in zip(*contacts))
    return Contacts(dist=dist, normal=normal, point=point, valid=valid)


def sphere_sphere(geom_a, geom_b, pose_a, pose_b):
    """Sphere against sphere (or circle against circle): 1 contact.

    Args:
        geom_a: ``(radius,)`` of A.
        geom_b: ``(radius,)`` of B.
        pose_a: ``(origin (dim,), rotation (dim, dim))`` of A; rotation unused.
        pose_b: same for B.

    Returns:
        Contacts with K = 1, ``dim`` taken from the origins (2 or 3). Coincident
        centres get the normal +e_last (the last world axis).
    """
    (radius_a,), (radius_b,) = geom_a, geom_b
    center_a, center_b = pose_a[0], pose_b[0]
    fallback = jnp.eye(center_a.shape[-1], dtype=center_a.dtype)[-1]
    contact = _core_contact(center_a, center_b, radius_a, radius_b, fallback)
    return _stack([contact], jnp.ones((1,), dtype=bool))


def capsule_sphere(geom_a, geom_b, pose_a, pose_b):
    """Capsule (A) against sphere (B): 1 contact, 3D.

    Args:
        geom_a: ``(radius, half_length)`` of the capsule; its segment runs along
            the shape-frame z axis.
        geom_b: ``(radius,)`` of the sphere.
        pose_a: ``(origin (3,), rotation (3, 3))`` of the capsule.
        pose_b: ``(origin (3,), rotation (3, 3))`` of the sphere; rotation unused.

    Returns:
        Contacts with K = 1 between the sphere and the point of the capsule's
        segment closest to its centre. A centre on the segment gets the normal
        ``rotation_a[:, 0]``.
    """
    radius_a, half_length = geom_a
    (radius_b,) = geom_b
    origin_a, rotation_a = pose_a
    center_b = pose_b[0]
    axis = rotation_a[:, 2]
    s = jnp.clip(dot(center_b - origin_a, axis), -half_length, half_length)
    contact = _core_contact(origin_a + s * axis, center_b, radius_a, radius_b, rotation_a[:, 0])
    return _stack([contact], jnp.ones((1,), dtype=bool))


def capsule_capsule(geom_a, geom_b, pose_a, pose_b):
    """Capsule (A) against capsule (B): 2 contacts, 3D.

    Slot 0 holds the closest points of the two segments (always valid). Slot 1
    holds the end of the segments' overlap (B's segment projected on A's axis)
    farther from slot 0: the point of A's segment there and its closest point on
    B's segment. It is valid only when the axes are nearly parallel
    (sin(angle) < ``PARALLEL_SIN``), the overlap is not empty, and it is not a
    duplicate of slot 0. So a capsule lying on a capsule gets two contacts
    spanning the overlap, and crossing capsules get one. Slot 1 is a true
    surface-to-surface pair (a ball of A's radius inside A against B), so its
    ``dist`` is never smaller than slot 0's.

    Args:
        geom_a: ``(radius, half_length)`` of A; its segment runs along shape z.
        geom_b: ``(radius, half_length)`` of B.
        pose_a: ``(origin (3,), rotation (3, 3))`` of A.
        pose_b: ``(origin (3,), rotation (3, 3))`` of B.

    Returns:
        Contacts with K = 2.
    """
    radius_a, half_a = geom_a
    radius_b, half_b = geom_b
    origin_a, rotation_a = pose_a
    origin_b, rotation_b = pose_b
    axis_a, axis_b = rotation_a[:, 2], rotation_b[:, 2]
    offset = origin_a - origin_b

    # Closest points of the segments A(s) = origin_a + s axis_a and
    # B(t) = origin_b + t axis_b (unit axes): Ericson, Real-Time Collision
    # Detection 5.1.9, with the line solution's denominator 1 - (a.b)^2
    # computed as |a x b|^2 (accurate at small angles).
    cos_ab = dot(axis_a, axis_b)
    along_a = dot(axis_a, offset)
    along_b = dot(axis_b, offset)
    axes_cross = cross(axis_a, axis_b)
    sin_sq = dot(axes_cross, axes_cross)

    # B's segment projected on A's axis, clipped to A: the overlap [lower, upper].
    reach = half_b * jnp.abs(cos_ab)
    lower = jnp.maximum(-half_a, -along_a - reach)
    upper = jnp.minimum(half_a, -along_a + reach)

    # Parallel axes (any s is a line solution): start from the overlap's lower
    # end; the clamped alternation below then lands on an exact closest pair.
    # The threshold eps keeps the rounding error of either branch at about
    # eps * size^2 in dist^2; the double where keeps the gradient finite.
    skew = sin_sq > jnp.finfo(sin_sq.dtype).eps
    s_line = (cos_ab * along_b - along_a) / jnp.where(skew, sin_sq, 1.0)
    s = jnp.clip(jnp.where(skew, s_line, lower), -half_a, half_a)
    t = jnp.clip(cos_ab * s + along_b, -half_b, half_b)
    s = jnp.clip(cos_ab * t - along_a, -half_a, half_a)

    # Intersecting segments: normal perpendicular to both axes, or to A's axis.
    fallback = safe_normalize(axes_cross, fallback=rotation_a[:, 0])
    first = _core_contact(origin_a + s * axis_a, origin_b + t * axis_b,
                          radius_a, radius_b, fallback)

    # Second slot: the overlap end farther from the first contact, against B.
    s_far = jnp.clip(jnp.where(jnp.abs(s - lower) >= jnp.abs(s - upper), lower, upper),
                     -half_a, half_a)
    t_far = jnp.clip(cos_ab * s_far + along_b, -half_b, half_b)
    second = _core_contact(origin_a + s_far * axis_a, origin_b + t_far * axis_b,
                           radius_a, radius_b, first[1])
    valid_second = ((sin_sq < PARALLEL_SIN**2) & (upper > lower)
                    & (jnp.abs(s_far - s) > DUPLICATE_FRACTION * (radius_a + radius_b)))
    return _stack([first, second], jnp.stack([jnp.ones_like(valid_second), valid_second]))
