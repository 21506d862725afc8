"""2D narrowphase kernels: convex polygons, circles and point-mass bodies.

Every kernel follows :mod:`jaxrb.physics.collision.contacts`: one pair in, a fixed
number ``K`` of contact slots out, the normal pointing from B to A, ``dist`` > 0
when apart and < 0 when penetrating, the point midway between the surfaces, and
finite values and gradients for every input. Poses are ``(origin (2,),
rotation (2, 2))``; polygons are ``(vertices (k, 2), normals (k, 2))``, CCW,
``normals[i]`` the outward normal of edge ``i -> i+1``.

Discrete choices (which edge, which polygon is the reference) are made with
``argmax``/``argmin`` (in ``polygon_polygon``, chains of compares over the
vertices) and turned into one-hot weights or selects, so the chosen
feature's coordinates stay differentiable and no traced value decides Python
control flow. Under ``vmap`` everything is small elementwise math on components.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from jaxrb.physics.collision.contacts import Contacts
from jaxrb.math.vector import dot, safe_div, safe_normalize, safe_sqrt, unstack

# Reference-face choice in polygon_polygon (Box2D's k_relativeTol/k_absoluteTol):
# B becomes the reference only if its separation beats A's by more than
# REL_TOL * |sep_A| + ABS_TOL * size (size: the smaller polygon's radius about its
# vertex mean). Favouring A consistently stops the reference flip-flopping between
# (numerically) equal axes, e.g. a box resting on an equal box.
REL_TOL = 0.02
ABS_TOL = 1e-3


# --------------------------------------------------------------------------- helpers


def _rotate(rotation, v):
    """rotation @ v on components. rotation: (2, 2), v: (..., 2)."""
    x, y = v[..., 0], v[..., 1]
    return jnp.stack([rotation[0, 0] * x + rotation[0, 1] * y,
                      rotation[1, 0] * x + rotation[1, 1] * y], axis=-1)


def _unrotate(rotation, v):
    """rotation.T @ v on components. rotation: (2, 2), v: (..., 2)."""
    x, y = v[..., 0], v[..., 1]
    return jnp.stack([rotation[0, 0] * x + rotation[1, 0] * y,
                      rotation[0, 1] * x + rotation[1, 1] * y], axis=-1)


def _to_world(pose, local):
    """Shape-frame points (..., 2) to world points (..., 2)."""
    origin, rotation = pose
    return origin + _rotate(rotation, local)


def _to_local(pose, world):
    """World points (..., 2) to shape-frame points (..., 2)."""
    origin, rotation = pose
    return _unrotate(rotation, world - origin)


def _one_hot(index, count, dtype):
    """(..., count) one-hot weights of integer ``index`` (...); carries no gradient."""
    return (jnp.arange(count) == index[..., None]).astype(dtype)


def _pick(weights, rows):
    """Row of ``rows`` (..., k, 2) selected by one-hot ``weights`` (..., k) -> (..., 2)."""
    return jnp.sum(weights[..., None] * rows, axis=-2)


def _point_polygon(points, vertices, normals):
    """Signed distance of points to a convex polygon, all in the polygon's frame.

    Inside, the distance is the (negative) separation from the face of least
    penetration and the normal is that face's normal. Outside, it is the
    Euclidean distance to the nearest boundary point and the normal points from
    that point to the query point (the face normal where they coincide).

    Args:
        points: (m, 2) query points.
        vertices: (k, 2) CCW polygon vertices.
        normals: (k, 2) outward edge normals.

    Returns:
        signed: (m,) signed distance, > 0 outside.
        normal: (m, 2) unit outward normal of the polygon at the nearest feature;
            the nearest surface point is ``points - signed * normal``.
    """
    count = vertices.shape[0]
    edges = jnp.roll(vertices, -1, axis=0) - vertices                   # (k, 2)
    rel = points[:, None, :] - vertices[None, :, :]                      # (m, k, 2)
    face_sep = dot(rel, normals[None])                                   # (m, k)
    face = jnp.argmax(face_sep, axis=1)
    face_normal = _pick(_one_hot(face, count, vertices.dtype), normals)  # (m, 2)
    inside_sep = jnp.max(face_sep, axis=1)                               # (m,)
    # Closest point on each edge segment; edges of a valid polygon have length > 0.
    t = jnp.clip(safe_div(dot(rel, edges[None]), dot(edges, edges)[None]), 0.0, 1.0)
    offset = rel - t[..., None] * edges[None]                            # point - closest, (m, k, 2)
    nearest = jnp.argmin(dot(offset, offset), axis=1)
    offset = _pick(_one_hot(nearest, count, vertices.dtype), offset)     # (m, 2)
    out_normal = safe_normalize(offset, fallback=face_normal)
    outside_sep = dot(offset, out_normal)                                # |offset|, safe at 0
    outside = inside_sep > 0.0
    signed = jnp.where(outside, outside_sep, inside_sep)
    normal = jnp.where(outside[:, None], out_normal, face_normal)
    return signed, normal


# --------------------------------------------------------------------------- kernels


def polygon_sphere(geom_a, geom_b, pose_a, pose_b):
    """Convex polygon A against circle B: 1 contact.

    With the circle centre outside the polygon the contact is with the nearest
    edge or vertex; inside, with the face of least penetration (the first of
    equals, so the centroid of a regular polygon is handled too).

    Args:
        geom_a: (vertices (k, 2), normals (k, 2)) of the polygon.
        geom_b: (radius,) of the circle.
        pose_a, pose_b: (origin (2,), rotation (2, 2)).

    Returns:
        Contacts with K = 1.
    """
    vertices, normals = geom_a
    (radius,) = geom_b
    centre = _to_local(pose_a, pose_b[0])[None, :]                      # (1, 2) in A's frame
    signed, normal = _point_polygon(centre, vertices, normals)
    # Polygon surface at centre - signed * n, circle surface at centre - radius * n.
    point = _to_world(pose_a, centre - (0.5 * (signed + radius))[:, None] * normal)
    return Contacts(dist=signed - radius, normal=-_rotate(pose_a[1], normal), point=point,
                    valid=jnp.ones((1,), dtype=bool))


def points_polygon(geom_a, geom_b, pose_a, pose_b):
    """Point-mass body A against convex polygon B: one contact per point.

    Args:
        geom_a: (points (k, 2),) in A's shape frame.
        geom_b: (vertices (m, 2), normals (m, 2)) of the polygon.
        pose_a, pose_b: (origin (2,), rotation (2, 2)).

    Returns:
        Contacts with K = k; ``dist`` is each point's signed distance to the
        polygon, ``point`` halfway between the point and its projection on the
        polygon's surface.
    """
    (points,) = geom_a
    vertices, normals = geom_b
    local = _to_local(pose_b, _to_world(pose_a, points))                 # (k, 2) in B's frame
    signed, normal = _point_polygon(local, vertices, normals)
    point = _to_world(pose_b, local - (0.5 * signed)[:, None] * normal)
    return Contacts(dist=signed, normal=_rotate(pose_b[1], normal), point=point,
                    valid=jnp.ones(points.shape[:1], dtype=bool))


# polygon_polygon works on components: each vertex coordinate is its own
# array, so under vmap every operation is a wide elementwise loop over pairs.
# On (k, 2) arrays XLA's CPU backend ran the (pairs, k, k, 2) gap tensor and
# the argmax/argmin over k as loops over tiny minor axes: the 55-box pyramid's
# narrowphase at 256 worlds took 7.3 ms of its 26 ms a step that way.


def _world_directions(rotation, local):
    """Shape-frame directions (k, 2) as k world directions, each a pair (x, y) of scalars."""
    xs, ys = unstack(local)
    return [(rotation[0, 0] * x + rotation[0, 1] * y, rotation[1, 0] * x + rotation[1, 1] * y)
            for x, y in zip(unstack(xs, 0), unstack(ys, 0))]


def _world_points(pose, local):
    """Shape-frame points (k, 2) as k world points, each a pair (x, y) of scalars."""
    ox, oy = unstack(pose[0])
    return [(ox + x, oy + y) for x, y in _world_directions(pose[1], local)]


def _dot2(a, b):
    return a[0] * b[0] + a[1] * b[1]


def _first_best(values, better):
    """(index, value) of the first entry of ``values`` (scalars) that no later one is ``better`` than."""
    index, best = jnp.zeros(jnp.shape(values[0]), jnp.int32), values[0]
    for i, value in enumerate(values[1:], start=1):
        wins = better(value, best)
        index, best = jnp.where(wins, i, index), jnp.where(wins, value, best)
    return index, best


def _select(index, points):
    """The point (x, y) of ``points`` at integer ``index`` (no gradient through the choice)."""
    x, y = points[0]
    for i, (px, py) in enumerate(points[1:], start=1):
        chosen = index == i
        x, y = jnp.where(chosen, px, x), jnp.where(chosen, py, y)
    return x, y


def _max_separation(vertices, normals, other):
    """Box2D's b2FindMaxSeparation on component points (world coordinates).

    Args:
        vertices, normals: k points (x, y) of the polygon whose edges are tried.
        other: m points (x, y) of the other polygon's vertices.

    Returns:
        (edge index, separation): the first edge whose normal separates most
        and the separation along it (< 0 when overlapping).
    """
    separations = []
    for (vx, vy), normal in zip(vertices, normals):
        gaps = [_dot2((ox - vx, oy - vy), normal) for ox, oy in other]
        separations.append(functools.reduce(jnp.minimum, gaps))
    return _first_best(separations, jnp.greater)


def _clip(p0, p1, plane_normal, offset):
    """Keep the part of segment p0-p1 with plane_normal·x <= offset (points as (x, y)).

    Returns the two (possibly moved) endpoints and whether any part survives.
    """
    d0 = _dot2(p0, plane_normal) - offset
    d1 = _dot2(p1, plane_normal) - offset
    in0, in1 = d0 <= 0.0, d1 <= 0.0
    # Used only when exactly one end is inside: then d0 - d1 != 0 and the fraction is in [0, 1].
    crossing = in0 != in1
    fraction = d0 / jnp.where(crossing, d0 - d1, 1.0)
    hit = tuple(a + fraction * (b - a) for a, b in zip(p0, p1))
    return (tuple(jnp.where(in0, a, c) for a, c in zip(p0, hit)),
            tuple(jnp.where(in1, b, c) for b, c in zip(p1, hit)), in0 | in1)


def _clip_against_reference(ref_vertices, ref_edge, inc_vertices, inc_normals):
    """Box2D's clipping of the incident edge against a reference edge (component points).

    Args:
        ref_vertices: k points (x, y) of the reference polygon.
        ref_edge: index of the reference edge.
        inc_vertices, inc_normals: m points (x, y) of the incident polygon.

    Returns:
        separation (2,), point (2, 2) midway, reference normal (2,) pointing out of
        the reference polygon, valid (2,).
    """
    v11 = _select(ref_edge, ref_vertices)
    v12 = _select(ref_edge, ref_vertices[1:] + ref_vertices[:1])
    edge = (v12[0] - v11[0], v12[1] - v11[1])
    length = safe_sqrt(edge[0] * edge[0] + edge[1] * edge[1])
    nonzero = length > 0.0
    tangent = tuple(jnp.where(nonzero, e / jnp.where(nonzero, length, 1.0), 0.0) for e in edge)
    normal = (tangent[1], -tangent[0])                                  # outward for CCW
    # Incident edge: the first one most anti-parallel to the reference normal.
    incident, _ = _first_best([_dot2(n, normal) for n in inc_normals], jnp.less)
    p0 = _select(incident, inc_vertices)
    p1 = _select(incident, inc_vertices[1:] + inc_vertices[:1])
    p0, p1, keep1 = _clip(p0, p1, (-tangent[0], -tangent[1]), -_dot2(tangent, v11))
    p0, p1, keep2 = _clip(p0, p1, tangent, _dot2(tangent, v12))
    separation = jnp.stack([_dot2(p, normal) - _dot2(normal, v11) for p in (p0, p1)])
    clipped = jnp.stack([jnp.stack(p0), jnp.stack(p1)])                 # (2, 2)
    point = clipped - (0.5 * separation)[:, None] * jnp.stack(normal)
    valid = jnp.broadcast_to(keep1 & keep2, (2,))
    return separation, point, jnp.stack(normal), valid


def _size(vertices):
    """Radius of a polygon about its vertex mean (for scale-aware tolerances)."""
    centred = jax.lax.stop_gradient(vertices - jnp.mean(vertices, axis=0))
    return jnp.sqrt(jnp.max(dot(centred, centred)))


def polygon_polygon(geom_a, geom_b, pose_a, pose_b, store=lambda parts: parts):
    """Convex polygon A against convex polygon B: 2 contacts (Box2D's clipping).

    Both polygons' edge normals are tried as separating axes; the polygon with
    the larger maximum separation gives the reference edge, with A preferred
    unless B is better by ``REL_TOL * |sep_A| + ABS_TOL * size``. The incident
    edge is the other polygon's edge most anti-parallel to the reference normal;
    it is clipped to the reference edge's side planes and each clipped point's
    separation from the reference edge is its ``dist``. Separated pairs are
    reported too. Both slots are invalid when the incident edge lies entirely
    beyond a side plane (e.g. polygons apart corner to corner).

    Args:
        geom_a, geom_b: (vertices (k, 2), normals (k, 2)); k may differ.
        pose_a, pose_b: (origin (2,), rotation (2, 2)).
        store: ``parts -> parts``, the same values computed once
            (:func:`jaxrb.physics.collision.pairs.detect` passes
            :func:`jaxrb.math.components.materialize`): the separations and the
            results, each read by many consumers that XLA would otherwise
            fuse the whole chain into.

    Returns:
        Contacts with K = 2, normal from B to A.
    """
    vertices_a = _world_points(pose_a, geom_a[0])
    normals_a = _world_directions(pose_a[1], geom_a[1])
    vertices_b = _world_points(pose_b, geom_b[0])
    normals_b = _world_directions(pose_b[1], geom_b[1])
    edge_a, sep_a = _max_separation(vertices_a, normals_a, vertices_b)
    edge_b, sep_b = _max_separation(vertices_b, normals_b, vertices_a)
    edge_a, sep_a, edge_b, sep_b = store((edge_a, sep_a, edge_b, sep_b))
    size = jnp.minimum(_size(geom_a[0]), _size(geom_b[0]))
    reference_b = sep_b > sep_a + REL_TOL * jnp.abs(sep_a) + ABS_TOL * size

    # Both candidates are computed (the polygons may have different vertex counts)
    # and one is selected; each is finite on its own.
    sep_ra, point_ra, normal_ra, valid_ra = _clip_against_reference(
        vertices_a, edge_a, vertices_b, normals_b)
    sep_rb, point_rb, normal_rb, valid_rb = _clip_against_reference(
        vertices_b, edge_b, vertices_a, normals_a)
    normal = jnp.where(reference_b, normal_rb, -normal_ra)              # B -> A either way
    dist, normal, point, valid = store((jnp.where(reference_b, sep_rb, sep_ra), normal,
                                        jnp.where(reference_b, point_rb, point_ra),
                                        jnp.where(reference_b, valid_rb, valid_ra)))
    return Contacts(dist=dist, normal=jnp.broadcast_to(normal, (2, 2)), point=point, valid=valid)
