"""Kernels of every shape against a static plane (B is always the plane).

They are dimension-agnostic: the same code serves 3D planes and 2D half-planes.
"""

from __future__ import annotations

import itertools

import jax.numpy as jnp

from jaxrb.physics.collision.contacts import Contacts


def _to_world(points, origin, rotation):
    """origin + R p for body-frame points (K, dim), as a broadcast sum (see :func:`_against_plane`)."""
    return origin + jnp.sum(points[:, None, :] * rotation, axis=-1)


def _against_plane(points, radius, plane):
    """Contacts of world points swept by ``radius`` against a plane. points: (K, dim)."""
    normal, offset = plane
    # Sums, not ``@``: under vmap a dot of (K, 3) by (3,) comes out with the
    # batch axis inside (K, batch) and has to be transposed back.
    height = jnp.sum(points * normal, axis=-1) - offset
    dist = height - radius
    # Midway between the shape's surface (height - radius) and the plane (0).
    point = points - (0.5 * (height + radius))[:, None] * normal
    count = points.shape[0]
    return Contacts(dist=dist, normal=jnp.broadcast_to(normal, points.shape), point=point,
                    valid=jnp.ones((count,), dtype=bool))


def sphere_plane(geom_a, geom_b, pose_a, pose_b):
    """Sphere (or circle) against a plane: 1 contact."""
    (radius,), (origin, _) = geom_a, pose_a
    return _against_plane(origin[None, :], radius, geom_b)


def capsule_plane(geom_a, geom_b, pose_a, pose_b):
    """Capsule against a plane: its two segment ends, 2 contacts."""
    radius, half_length = geom_a
    origin, rotation = pose_a
    axis = rotation[:, 2]
    ends = jnp.stack([origin + half_length * axis, origin - half_length * axis])
    return _against_plane(ends, radius, geom_b)


#: The signs of a box's 8 corners, in the order of its contact rows.
BOX_CORNERS = tuple(itertools.product((-1.0, 1.0), repeat=3))


def box_plane(geom_a, geom_b, pose_a, pose_b):
    """Box against a plane: its 8 corners, 8 contacts (those below the margin matter)."""
    (half_extents,), (origin, rotation) = geom_a, pose_a
    signs = jnp.asarray(BOX_CORNERS, dtype=half_extents.dtype)  # scene dtype, never promoted
    return _against_plane(_to_world(signs * half_extents, origin, rotation), 0.0, geom_b)


def points_plane(geom_a, geom_b, pose_a, pose_b):
    """Point-mass body (or any vertex set) against a plane: one contact per point."""
    (points,), (origin, rotation) = geom_a, pose_a
    return _against_plane(_to_world(points, origin, rotation), 0.0, geom_b)


def polygon_plane(geom_a, geom_b, pose_a, pose_b):
    """2D convex polygon against a half-plane: one contact per vertex."""
    vertices, _ = geom_a
    return points_plane((vertices,), geom_b, pose_a, pose_b)
