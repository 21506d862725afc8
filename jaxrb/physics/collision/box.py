"""Narrowphase kernels of 3D boxes: box-box, box-sphere, box-capsule, points-box.

(Past 600 lines on purpose: the four kernels share the box's signed distance,
the clipping and the slot tables; split apart, each would import the others'.)

Every kernel follows :mod:`jaxrb.physics.collision.contacts`: one pair in, ``Contacts``
with a fixed number of slots out, normal from B to A, ``dist`` the signed
separation along the normal, ``point`` midway between the surfaces, finite
values and gradients everywhere. For a slot's two surface points,
``point_A - point_B = dist * normal`` and ``point`` is their midpoint (the one
exception: ``box_box`` edge contacts of separated boxes whose closest points
are clamped to the edges' ends, where ``dist`` stays the separating-axis
distance). A box is ``(half_extents (3,),)``; its pose's rotation columns are
the box axes in the world.

Methods, in short (details in each docstring):

* ``box_box`` (K = 8): separating-axis test over the 15 axes; a face axis gives
  a manifold by clipping the incident face against the reference face's side
  planes (fixed-capacity Sutherland-Hodgman); an edge axis gives one contact at
  the closest points of the two edges.
* ``box_sphere`` (K = 1) and ``points_box`` (K = k): the box's exact signed
  distance at a point (closest surface point outside, nearest face inside).
* ``box_capsule`` (K = 2): exact closest (or deepest) point of the capsule's
  segment to the box by enumerating every breakpoint and stationary point of
  the box's signed distance along the segment, then the segment clipped to the
  side slabs of the contact feature for a second contact.

Tolerances are relative to the shapes' size and, where rounding matters, to the
dtype's machine epsilon, so float32 scenes behave like float64 ones.
"""

from __future__ import annotations

import itertools

import jax.numpy as jnp
import numpy as np

from jaxrb.physics.collision.contacts import Contacts
from jaxrb.math.vector import cross, dot, matmul, safe_norm, safe_normalize

#: Edge-edge axes a_i x b_j with |a_i x b_j| (the sine of the angle between the
#: edges) below this are left out of the separating-axis test: they duplicate a
#: face axis and their direction is ill-conditioned.
EDGE_PARALLEL_SIN = 1e-5

#: B's best face axis replaces A's only when its separation is larger by
#: ``FACE_REL_TOL * |sep| + ABS_TOL * size`` (Box2D's hysteresis): A's face wins
#: ties, so a resting pair keeps the same reference face from step to step.
FACE_REL_TOL = 0.02

#: An edge-edge axis replaces the best face axis only when its separation is
#: larger by ``EDGE_REL_TOL * |sep| + ABS_TOL * size`` (ODE's and Bullet's
#: ``fudge_factor`` of 1.05): face manifolds are preferred, which avoids
#: jitter between one edge contact and a face manifold.
EDGE_REL_TOL = 0.05

#: Absolute part of both preferences, in units of the largest half extent.
ABS_TOL = 1e-5

#: Denominators (components of a unit direction, or differences of them) below
#: this are treated as zero in ``box_capsule``'s candidate parameters.
PARALLEL_EPS = 1e-9

#: Number of slots of ``box_box``.
BOX_BOX_SLOTS = 8


def _sign(x):
    """+1 where x >= 0, else -1 (no zero, so a fallback direction is never null)."""
    return jnp.where(x >= 0.0, 1.0, -1.0).astype(x.dtype)


def _rel_tol(dtype):
    """sqrt(machine epsilon): the relative size of a tolerance band against rounding."""
    return float(jnp.finfo(dtype).eps) ** 0.5


def _onehot(index, size, dtype):
    """(size,) one-hot vector of a traced integer index (selects without gather)."""
    return (jnp.arange(size) == index).astype(dtype)


def _box_point(half_extents, x):
    """Signed distance of points to a box, in the box frame.

    Args:
        half_extents: (3,) half extents.
        x: (..., 3) points in the box frame.

    Returns:
        ``(sdf (...), normal (..., 3), surface (..., 3))``: the signed distance
        (negative inside), the box's outward unit normal at its closest feature
        (pointing from the box towards the point: the distance's gradient), and
        the closest point of the box's surface, so ``x - surface = sdf * normal``.
        Outside, the closest feature is a face, an edge or a corner; inside it is
        the nearest face (ties: lowest axis, + side when the coordinate is 0).
    """
    clamped = jnp.clip(x, -half_extents, half_extents)
    excess = x - clamped
    outside_dist = safe_norm(excess)
    outside = outside_dist > 0.0
    outside_normal = safe_normalize(excess)

    depth = jnp.abs(x) - half_extents          # (..., 3), all <= 0 inside
    face = jnp.argmax(depth, axis=-1)
    pick = (jnp.arange(3) == face[..., None])
    side = _sign(x)
    inside_dist = jnp.max(depth, axis=-1)
    inside_normal = jnp.where(pick, side, 0.0).astype(x.dtype)
    inside_surface = jnp.where(pick, side * half_extents, x)

    sdf = jnp.where(outside, outside_dist, inside_dist)
    normal = jnp.where(outside[..., None], outside_normal, inside_normal)
    surface = jnp.where(outside[..., None], clamped, inside_surface)
    return sdf, normal, surface


# --------------------------------------------------------------------------- #
# box-box
# --------------------------------------------------------------------------- #


def _clip(poly, count, dist, tol):
    """Clip a convex polygon by the half-plane ``dist <= 0`` (Sutherland-Hodgman).

    The polygon has a fixed capacity of S slots, its ``count`` vertices in
    cyclic order in the first slots. A vertex is kept when ``dist <= tol``; an
    edge is cut where it goes from ``dist < -tol`` to ``dist > tol`` or back, so
    a vertex on the line (within ``tol``) gives no duplicate and every cut has
    a denominator larger than ``2 tol``.

    Args:
        poly: (S, d) vertices; all d coordinates are interpolated along edges.
        count: () int, number of vertices.
        dist: (S,) signed distance of each slot to the clipping line.
        tol: () tolerance band.

    Returns:
        ``(poly (S, d), count)`` of the clipped polygon (at most S vertices kept).
    """
    slots = dist.shape[0]
    index = jnp.arange(slots)
    filled = index < count
    last = index == count - 1
    poly_next = jnp.where(last[:, None], poly[0], jnp.roll(poly, -1, axis=0))
    dist_next = jnp.where(last, dist[0], jnp.roll(dist, -1))
    keep = filled & (dist <= tol)
    cut = filled & (((dist < -tol) & (dist_next > tol)) | ((dist > tol) & (dist_next < -tol)))
    frac = jnp.where(cut, dist / jnp.where(cut, dist - dist_next, 1.0), 0.0)

    # Candidates in cyclic order: vertex i, then the cut on edge i -> i+1; the
    # kept ones are packed to the front (slot j takes the candidate of rank j;
    # a gather measured 2.5x faster under vmap than a 0/1 matrix product).
    candidates = jnp.stack([poly, poly + frac[:, None] * (poly_next - poly)], axis=1)
    flags = jnp.stack([keep, cut], axis=1).reshape(-1)
    rank = jnp.cumsum(flags) - 1
    select = flags[None, :] & (rank[None, :] == index[:, None])                  # (S, 2S)
    source = jnp.sum(jnp.where(select, jnp.arange(2 * slots)[None, :], 0), axis=1)
    return candidates.reshape(2 * slots, -1)[source], jnp.minimum(jnp.sum(flags), slots)


# _CYCLES[k] has rows e_k, e_{k+1}, e_{k+2}: it reorders a box's axes so that
# axis k comes first, followed by the two axes spanning face k.
_CYCLES = np.stack([np.roll(np.eye(3), -k, axis=0) for k in range(3)]).reshape(3, 9)
# Corners of a face in cyclic order, as signs of its two spanning half edges.
_FACE_CORNERS = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])


def _cycled(k, dtype):
    """(3, 3) permutation with rows e_k, e_{k+1}, e_{k+2} for a traced index k."""
    return (_onehot(k, 3, dtype) @ _CYCLES.astype(dtype)).reshape(3, 3)


def _face_manifold(half_ref, origin_ref, rot_ref, k, half_inc, origin_inc, rot_inc,
                   normal_ref, tol):
    """Contact manifold of a face axis: the incident face clipped to the reference face.

    Args:
        half_ref, origin_ref, rot_ref: the reference box (owner of the axis).
        k: () int, the reference box's axis.
        half_inc, origin_inc, rot_inc: the incident box.
        normal_ref: (3,) unit outward normal of the reference face (towards the
            incident box), +-rot_ref[:, k].
        tol: () clipping tolerance (length).

    Returns:
        ``(height (8,), point (8, 3), valid (8,))``: for each clipped point of
        the incident face, its height above the reference face (the signed
        separation) and the point midway between it and its projection on the
        reference face.
    """
    dtype = origin_ref.dtype
    cycle_ref = _cycled(k, dtype)
    frame_ref = cycle_ref @ rot_ref.T               # rows: axis k, then u, v spanning the face
    half_k, half_u, half_v = cycle_ref @ half_ref
    center_ref = origin_ref + half_k * normal_ref
    basis = jnp.stack([frame_ref[1], frame_ref[2], normal_ref])      # rows u, v, n

    # Incident face: the incident box's face most anti-parallel to normal_ref.
    # Its |cos| is at least 1/sqrt(3), so the face is never seen edge-on.
    cosines = normal_ref @ rot_inc
    cycle_inc = _cycled(jnp.argmax(jnp.abs(cosines)), dtype)
    frame_inc = cycle_inc @ rot_inc.T
    half_inc = cycle_inc @ half_inc
    normal_inc = -_sign(frame_inc[0] @ normal_ref) * frame_inc[0]
    center_inc = origin_inc + half_inc[0] * normal_inc
    corners = center_inc + _FACE_CORNERS.astype(dtype) @ (half_inc[1:, None] * frame_inc[1:])

    # Corners in the reference face frame (u, v, height), cyclic, padded to 8 slots.
    local = (corners - center_ref) @ basis.T
    poly = jnp.concatenate([local, jnp.zeros((BOX_BOX_SLOTS - 4, 3), dtype=dtype)])
    count = jnp.asarray(4)
    for coord, sign, half in ((0, 1.0, half_u), (0, -1.0, half_u),
                              (1, 1.0, half_v), (1, -1.0, half_v)):
        poly, count = _clip(poly, count, sign * poly[:, coord] - half, tol)

    # Nothing left (faces do not overlap in projection, which happens for
    # separated boxes): report the lowest incident corner, clamped into the
    # reference face, as one speculative contact.
    lowest = _onehot(jnp.argmin(local[:, 2]), 4, dtype) @ local
    limit = jnp.stack([half_u, half_v])
    lowest = jnp.concatenate([jnp.clip(lowest[:2], -limit, limit), lowest[2:]])
    empty = count == 0
    poly = jnp.where(empty & (jnp.arange(BOX_BOX_SLOTS) == 0)[:, None], lowest, poly)
    count = jnp.where(empty, 1, count)

    poly, valid = _canonical_slots(poly, count)
    scaled = jnp.stack([basis[0], basis[1], 0.5 * basis[2]])
    return poly[:, 2], center_ref + matmul(poly, scaled), valid


# Slot directions of the face manifold in the reference face's (u, v) frame, at
# 22.5° + k·45°: a rectangle's corners, and each vertex of the octagon two equal
# squares at 45° make, are extreme in one of them without ties.
_SLOT_ANGLES = np.pi / 8.0 + np.arange(BOX_BOX_SLOTS) * np.pi / 4.0
_SLOT_DIRECTIONS = np.stack([np.cos(_SLOT_ANGLES), np.sin(_SLOT_ANGLES)], axis=1)


def _canonical_slots(poly, count):
    """Put the clipped points in slots that keep their meaning from step to step.

    The clipping pass returns the polygon in cyclic order from wherever the
    first kept vertex happens to be, so a shift of a nanometre can rotate the
    slots by one (a box sitting exactly on an equal box: corners on the side
    planes). Slots are contact keys for the impulse solver's warm start, so
    that moved every accumulated impulse to another corner. Here slot j holds
    the point most extreme along the fixed direction j of the reference face
    (the first slot of a point extreme in several directions owns it); points
    extreme in no direction fill the free slots in cyclic order.

    Args:
        poly: (S, 3) clipped points (u, v, height), the first ``count`` filled.
        count: () int.

    Returns:
        ``(poly (S, 3), valid (S,))`` reordered.
    """
    slots = poly.shape[0]
    dtype = poly.dtype
    index = jnp.arange(slots)
    filled = index < count
    score = _SLOT_DIRECTIONS.astype(dtype) @ poly[:, :2].T                 # (S directions, S points)
    pick = jnp.argmax(jnp.where(filled[None, :], score, -jnp.inf), axis=1)   # (S,)
    earlier = index[None, :] < index[:, None]
    owned = ~jnp.any(earlier & (pick[None, :] == pick[:, None]), axis=1)
    claimed = jnp.any(owned[:, None] & (pick[:, None] == index[None, :]), axis=0)
    left = filled & ~claimed
    free = ~owned
    rank_left = jnp.cumsum(left) - 1
    rank_free = jnp.cumsum(free) - 1
    select = ((owned[:, None] & (pick[:, None] == index[None, :]))
              | (free[:, None] & left[None, :] & (rank_free[:, None] == rank_left[None, :])))
    select = select.astype(dtype)
    return matmul(select, poly), jnp.sum(select, axis=1) > 0.0


def _edge_contact(half_a, origin_a, rot_a, i, half_b, origin_b, rot_b, j, normal):
    """One contact at the closest points of edge i of A and edge j of B.

    The edges are the ones parallel to A's axis i (B's axis j) that lie farthest
    along -normal on A (+normal on B), i.e. the edges facing each other.

    Returns ``(dist (), point (3,))``.
    """
    dtype = origin_a.dtype
    pick_i, pick_j = _onehot(i, 3, dtype), _onehot(j, 3, dtype)
    dir_a, dir_b = rot_a @ pick_i, rot_b @ pick_j
    mid_a = origin_a - rot_a @ (half_a * _sign(normal @ rot_a) * (1.0 - pick_i))
    mid_b = origin_b + rot_b @ (half_b * _sign(normal @ rot_b) * (1.0 - pick_j))

    # Closest points of the lines mid_a + s dir_a and mid_b + t dir_b.
    gap = mid_a - mid_b
    cos_ab = dir_a @ dir_b
    along_a, along_b = dir_a @ gap, dir_b @ gap
    denom = 1.0 - cos_ab * cos_ab
    ok = denom > EDGE_PARALLEL_SIN**2
    denom = jnp.where(ok, denom, 1.0)
    s = jnp.where(ok, (cos_ab * along_b - along_a) / denom, 0.0)
    t = jnp.where(ok, (along_b - cos_ab * along_a) / denom, 0.0)
    reach_a, reach_b = half_a @ pick_i, half_b @ pick_j
    on_a = mid_a + jnp.clip(s, -reach_a, reach_a) * dir_a
    on_b = mid_b + jnp.clip(t, -reach_b, reach_b) * dir_b
    return (on_a - on_b) @ normal, 0.5 * (on_a + on_b)


def box_box(geom_a, geom_b, pose_a, pose_b):
    """Box (A) against box (B): up to 8 contacts.

    Separating-axis test over the 15 axes (A's 3 face normals, B's 3, and the 9
    edge-edge crosses a_i x b_j; crosses of (nearly) parallel edges,
    |a_i x b_j| < ``EDGE_PARALLEL_SIN``, are left out). The separation along a
    unit axis L is ``|L.(o_A - o_B)| - r_A(L) - r_B(L)`` with
    ``r(L) = sum_k h_k |L.axis_k|``. The axis of largest separation (least
    penetration) is chosen with a preference for faces: B's face over A's face
    and an edge axis over the chosen face only when better by a relative
    tolerance (``FACE_REL_TOL``, ``EDGE_REL_TOL`` of |separation|, plus
    ``ABS_TOL`` times the largest half extent). The normal is that axis
    oriented from B to A.

    Face axis: the box owning it gives the reference face (the face facing the
    other box), the other box's face most anti-parallel to it is the incident
    face. The incident face is clipped against the reference face's four side
    planes by a fixed-capacity Sutherland-Hodgman pass (8 slots, in cyclic
    order; a rectangle clipped by four half-planes has at most 8 vertices, so
    nothing is dropped except in degenerate rounding cases, where the last
    candidates are). Each clipped point reports ``dist`` = its height above the
    reference face (negative below it) and the point midway between it and its
    projection on the reference face. Vertices within ``sqrt(eps) * size`` of a
    side plane count as inside (no duplicates at touching corners). When the
    faces do not overlap in projection (separated boxes offset sideways) one
    slot holds the lowest incident corner clamped into the reference face.
    Slots are contact keys for the impulse solver's warm start, so they are
    assigned by position, not by clipping order: slot j holds the point most
    extreme along the direction 22.5° + 45°·j of the reference face's frame
    (``_canonical_slots``); a box resting on an equal box keeps its corners in
    slots 0, 2, 4, 6 whichever way it drifts by a hair.

    Edge axis: one contact at the closest points of the two facing edges
    (slot 0, their midpoint), ``dist`` = their separation along the normal
    (the separating-axis value). The lines' closest points are clamped to the
    edges, which only happens for separated boxes.

    Separated pairs get the same features with ``dist > 0``. The SAT separation
    is a lower bound of the true distance for separated boxes (exact when the
    closest features are face-face, face-vertex or edge-edge).

    Args:
        geom_a: ``(half_extents (3,),)`` of A.
        geom_b: ``(half_extents (3,),)`` of B.
        pose_a: ``(origin (3,), rotation (3, 3))`` of A; rotation columns are A's axes.
        pose_b: same for B.

    Returns:
        Contacts with K = 8; ``valid`` marks the filled slots.
    """
    (half_a,), (half_b,) = geom_a, geom_b
    origin_a, rot_a = pose_a
    origin_b, rot_b = pose_b
    dtype = origin_a.dtype
    delta = origin_a - origin_b
    size = jnp.maximum(jnp.max(half_a), jnp.max(half_b))

    # The 15 candidate axes, as rows.
    axes_a, axes_b = rot_a.T, rot_b.T
    crosses = cross(axes_a[:, None, :], axes_b[None, :, :]).reshape(9, 3)
    cross_sq = dot(crosses, crosses)
    edge_ok = cross_sq > EDGE_PARALLEL_SIN**2
    unit_x = jnp.asarray([1.0, 0.0, 0.0], dtype=dtype)
    crosses = jnp.where(edge_ok[:, None], crosses, unit_x)
    edge_axes = crosses / jnp.sqrt(jnp.where(edge_ok, cross_sq, 1.0))[:, None]
    axes = jnp.concatenate([axes_a, axes_b, edge_axes])

    # matmul, not @: under vmap @ is a library call per pair (see jaxrb.math.vector.matmul).
    reach_a = matmul(jnp.abs(matmul(axes, rot_a)), half_a)
    reach_b = matmul(jnp.abs(matmul(axes, rot_b)), half_b)
    sep = jnp.abs(matmul(axes, delta)) - reach_a - reach_b  # (15,)

    abs_tol = ABS_TOL * size
    best_a, sep_a = jnp.argmax(sep[:3]), jnp.max(sep[:3])
    best_b, sep_b = jnp.argmax(sep[3:6]), jnp.max(sep[3:6])
    use_b = sep_b > sep_a + FACE_REL_TOL * jnp.abs(sep_a) + abs_tol
    sep_face = jnp.where(use_b, sep_b, sep_a)
    edge_sep = jnp.where(edge_ok, sep[6:], -jnp.inf)
    best_edge = jnp.argmax(edge_sep)
    use_edge = jnp.max(edge_sep) > sep_face + EDGE_REL_TOL * jnp.abs(sep_face) + abs_tol

    # Face axis: reference box = owner of the axis.
    k = jnp.where(use_b, best_b, best_a)
    rot_ref = jnp.where(use_b, rot_b, rot_a)
    face_axis = rot_ref @ _onehot(k, 3, dtype)
    face_normal = face_axis * _sign(face_axis @ delta)
    half_ref, half_inc = jnp.where(use_b, half_b, half_a), jnp.where(use_b, half_a, half_b)
    origin_ref = jnp.where(use_b, origin_b, origin_a)
    origin_inc = jnp.where(use_b, origin_a, origin_b)
    rot_inc = jnp.where(use_b, rot_a, rot_b)
    normal_ref = jnp.where(use_b, face_normal, -face_normal)
    face_dist, face_point, face_valid = _face_manifold(
        half_ref, origin_ref, rot_ref, k, half_inc, origin_inc, rot_inc, normal_ref,
        _rel_tol(dtype) * size)

    # Edge axis: one contact in slot 0.
    edge_axis = _onehot(best_edge, 9, dtype) @ edge_axes
    edge_normal = edge_axis * _sign(edge_axis @ delta)
    edge_dist, edge_point = _edge_contact(half_a, origin_a, rot_a, best_edge // 3,
                                          half_b, origin_b, rot_b, best_edge % 3, edge_normal)
    slot0 = jnp.arange(BOX_BOX_SLOTS) == 0

    normal = jnp.where(use_edge, edge_normal, face_normal)
    return Contacts(
        dist=jnp.where(use_edge, jnp.where(slot0, edge_dist, 0.0), face_dist),
        normal=jnp.broadcast_to(normal, (BOX_BOX_SLOTS, 3)),
        point=jnp.where(use_edge, jnp.broadcast_to(edge_point, (BOX_BOX_SLOTS, 3)), face_point),
        valid=jnp.where(use_edge, slot0, face_valid),
    )


# --------------------------------------------------------------------------- #
# box against round shapes and points
# --------------------------------------------------------------------------- #


def _ball_contact(half_extents, origin, rotation, local, radius):
    """Contacts of balls (centres ``local`` (..., 3) in the box frame) against the box (A).

    Returns ``(dist (...), normal (..., 3), point (..., 3))`` in the world, the
    normal from the ball (B) to the box (A).
    """
    sdf, outward, surface = _box_point(half_extents, local)
    midway = 0.5 * (surface + local - radius * outward)
    return sdf - radius, -(outward @ rotation.T), origin + midway @ rotation.T


def box_sphere(geom_a, geom_b, pose_a, pose_b):
    """Box (A) against sphere (B): 1 contact.

    The box's exact signed distance at the sphere's centre, minus the radius:
    outside, from the closest point of the box (face, edge or corner); inside,
    from the nearest face (ties: lowest axis, then the + side; a centre at the
    box's centre is pushed out through the face of the smallest half extent).
    The normal points from the sphere to the box.

    Args:
        geom_a: ``(half_extents (3,),)`` of the box.
        geom_b: ``(radius,)`` of the sphere.
        pose_a: ``(origin (3,), rotation (3, 3))`` of the box.
        pose_b: ``(origin (3,), rotation (3, 3))`` of the sphere; rotation unused.

    Returns:
        Contacts with K = 1.
    """
    (half_extents,), (radius,) = geom_a, geom_b
    origin, rotation = pose_a
    local = (pose_b[0] - origin) @ rotation
    dist, normal, point = _ball_contact(half_extents, origin, rotation, local[None, :], radius)
    return Contacts(dist=dist, normal=normal, point=point, valid=jnp.ones((1,), dtype=bool))


def _candidate_tables():
    """Constant tables of ``_segment_candidates`` (see there)."""
    eye = np.eye(3)
    signs = (-1.0, 1.0)
    # Planes crossed by the line: t = (P h + Q c) / (-Q w). A crossing of
    # s_i x_i - h_i = s_j x_j - h_j is a region boundary only where s_i x_i >= 0
    # and s_j x_j >= 0 (plane_sign), else another sign pattern's plane is.
    plane_h, plane_c, plane_sign = [], [], []
    for k in range(3):                      # x_k = s h_k, s in {-1, 0, 1}
        for s in (-1.0, 0.0, 1.0):
            plane_h.append(s * eye[k])
            plane_c.append(-eye[k])
            plane_sign.append(np.zeros(3))
    for i, j in ((0, 1), (0, 2), (1, 2)):   # s_i x_i - h_i = s_j x_j - h_j
        for si, sj in itertools.product(signs, repeat=2):
            plane_h.append(eye[i] - eye[j])
            plane_c.append(-si * eye[i] + sj * eye[j])
            plane_sign.append(si * eye[i] + sj * eye[j])
    # Edge lines along axis k through (s1 h_k1, s2 h_k2): mask of the two
    # other axes and their signs.
    edge_mask, edge_sign = [], []
    for k in range(3):
        k1, k2 = (k + 1) % 3, (k + 2) % 3
        for s1, s2 in itertools.product(signs, repeat=2):
            edge_mask.append(eye[k1] + eye[k2])
            edge_sign.append(s1 * eye[k1] + s2 * eye[k2])
    corners = np.array(list(itertools.product(signs, repeat=3)))
    return tuple(map(np.array, (plane_h, plane_c, plane_sign, edge_mask, edge_sign, corners)))


_PLANE_H, _PLANE_C, _PLANE_SIGN, _EDGE_MASK, _EDGE_SIGN, _CORNERS = _candidate_tables()


def _segment_candidates(center, direction, half_extents, half_length):
    """Parameters t in [-L, L] of the segment center + t direction (box frame)
    among which lies the minimiser of the box's signed distance along it.

    The signed distance of a convex set is convex; along a line it is linear in
    the face regions outside and the nearest-face regions inside, and the
    distance to an edge line or a corner elsewhere. So its minimum over the
    segment lies at an end (2), where the line crosses a region boundary (the
    planes x_k = +-h_k and x_k = 0: 9; |x_i| - h_i = |x_j| - h_j: 12), or at the
    line's closest approach to one of the 12 edge lines or 8 corners: 43 in
    all. Where a denominator is below ``PARALLEL_EPS`` (the line parallel to
    the plane or edge) the candidate is replaced by 0, and a crossing of
    s_i x_i - h_i = s_j x_j - h_j where the signs of x_i, x_j do not match
    (s_i, s_j) by -L; both are harmless since the caller evaluates every
    candidate, and the second keeps derivatives right for cubes, where
    several sign patterns give the same t but not the same motion with h.

    Args:
        center: (3,) segment centre, box frame.
        direction: (3,) unit direction, box frame.
        half_extents: (3,).
        half_length: () L.

    Returns:
        (43,) parameters.
    """
    dtype = center.dtype
    tables = (_PLANE_H, _PLANE_C, _PLANE_SIGN, _EDGE_MASK, _EDGE_SIGN, _CORNERS)
    plane_h, plane_c, plane_sign, edge_mask, edge_sign, corners = (t.astype(dtype) for t in tables)

    def param(num, den):
        ok = jnp.abs(den) > PARALLEL_EPS
        return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)

    planes = param(plane_h @ half_extents + plane_c @ center, -(plane_c @ direction))
    # Drop the crossings of |x_i| - h_i = |x_j| - h_j with the wrong sign
    # pattern (they coincide with the right one when h_i = h_j, but move the
    # other way with h: keeping them would give a wrong derivative).
    on_plane = center + planes[:, None] * direction
    tol = _rel_tol(dtype) * (jnp.max(half_extents) + half_length)
    right_side = jnp.all(plane_sign * on_plane >= -tol, axis=1)
    planes = jnp.where(right_side, planes, -half_length)
    edges = param((edge_sign * half_extents - edge_mask * center) @ direction,
                  edge_mask @ (direction * direction))
    vertices = (corners * half_extents - center) @ direction
    ends = jnp.stack([-half_length, half_length]).astype(dtype)
    return jnp.clip(jnp.concatenate([ends, planes, edges, vertices]), -half_length, half_length)


def box_capsule(geom_a, geom_b, pose_a, pose_b):
    """Box (A) against capsule (B): 2 contacts.

    Method (in the box frame, segment S(t) = c + t w, |t| <= L):

    1. The parameter t0 minimising the box's signed distance along the segment,
       found exactly by evaluating the 43 candidates of
       ``_segment_candidates`` (every breakpoint and stationary point of that
       convex piecewise function). So slot values are exact up to rounding:
       ``dist`` = the true distance from the segment to the box minus the
       radius when apart, and the true penetration (nearest-face depth of the
       deepest segment point plus the radius) when the segment enters the box.
       Candidates whose denominators are below ``PARALLEL_EPS`` are dropped,
       which costs at most about ``PARALLEL_EPS * L`` in the minimum.
    2. The contact feature at S(t0): the coordinates where S(t0) lies beyond
       the box (by more than ``sqrt(eps) * size``) are its normal directions
       (one: a face, two: an edge, three: a corner; none: inside, the nearest
       face). The segment is clipped to the slabs of the other coordinates (the
       face's side slabs, the edge's slab), giving [lo, hi], which holds t0.
    3. Slots = (lo, hi), each a sphere-box contact of the capsule's ball there.
       If t0 is deeper than both ends (by more than ``sqrt(eps) * size``),
       t0 replaces the shallower end. So a capsule lying on a face gets its two
       clipped ends (equal depths), a tilted one its low end and the other
       clipped end, and one crossing an edge the closest point plus the deeper
       clipped end. Slot 1 is invalid when it coincides with slot 0 (within
       ``sqrt(eps) * size``, e.g. L = 0).

    Args:
        geom_a: ``(half_extents (3,),)`` of the box.
        geom_b: ``(radius, half_length)`` of the capsule; its segment runs along
            the capsule's rotation[:, 2].
        pose_a: ``(origin (3,), rotation (3, 3))`` of the box.
        pose_b: ``(origin (3,), rotation (3, 3))`` of the capsule.

    Returns:
        Contacts with K = 2.
    """
    (half_extents,) = geom_a
    radius, half_length = geom_b
    origin, rotation = pose_a
    center = (pose_b[0] - origin) @ rotation
    direction = pose_b[1][:, 2] @ rotation
    dtype = center.dtype
    size = jnp.max(half_extents) + half_length + radius
    tol = _rel_tol(dtype) * size

    # 1. Deepest / closest point of the segment.
    ts = _segment_candidates(center, direction, half_extents, half_length)
    sdf, _, _ = _box_point(half_extents, center + ts[:, None] * direction)
    t0 = jnp.sum(_onehot(jnp.argmin(sdf), ts.shape[0], dtype) * ts)

    # 2. Clip the segment to the side slabs of the contact feature at S(t0).
    x0 = center + t0 * direction
    beyond = jnp.abs(x0) > half_extents + tol
    nearest = jnp.argmax(jnp.abs(x0) - half_extents)
    tangential = jnp.where(jnp.any(beyond), ~beyond, jnp.arange(3) != nearest)
    ok = tangential & (jnp.abs(direction) > PARALLEL_EPS)
    w = jnp.where(ok, direction, 1.0)
    enter, leave = (-half_extents - center) / w, (half_extents - center) / w
    lo = jnp.max(jnp.where(ok, jnp.minimum(enter, leave), -half_length), initial=-half_length)
    hi = jnp.min(jnp.where(ok, jnp.maximum(enter, leave), half_length), initial=half_length)
    lo, hi = jnp.minimum(lo, t0), jnp.maximum(hi, t0)

    # 3. The two slots.
    ends = jnp.stack(jnp.broadcast_arrays(lo, hi, t0))
    end_sdf, _, _ = _box_point(half_extents, center + ends[:, None] * direction)
    replace = end_sdf[2] < jnp.minimum(end_sdf[0], end_sdf[1]) - tol
    deeper = jnp.where(end_sdf[1] < end_sdf[0], hi, lo)
    slots = jnp.stack([jnp.where(replace, t0, lo), jnp.where(replace, deeper, hi)])
    dist, normal, point = _ball_contact(half_extents, origin, rotation,
                                        center + slots[:, None] * direction, radius)
    valid = jnp.stack([jnp.asarray(True), jnp.abs(slots[1] - slots[0]) > tol])
    return Contacts(dist=dist, normal=normal, point=point, valid=valid)


def points_box(geom_a, geom_b, pose_a, pose_b):
    """Point-mass body (A) against box (B): one contact per point.

    Each point is carried into B's frame and tested against the box (the
    classic "corners in the other body's frame" test): ``dist`` is the exact
    signed distance to the box surface (negative inside, where it is the
    distance to the nearest face), the normal is the box's outward normal at
    its closest feature (from B to A), the point is midway between A's point
    and the closest point of the box's surface.

    Args:
        geom_a: ``(points (k, 3),)`` in A's shape frame.
        geom_b: ``(half_extents (3,),)`` of the box.
        pose_a: ``(origin (3,), rotation (3, 3))`` of A.
        pose_b: ``(origin (3,), rotation (3, 3))`` of the box.

    Returns:
        Contacts with K = k, all valid.
    """
    (points,), (half_extents,) = geom_a, geom_b
    origin_a, rot_a = pose_a
    origin_b, rot_b = pose_b
    world = origin_a + points @ rot_a.T
    local = (world - origin_b) @ rot_b
    sdf, outward, surface = _box_point(half_extents, local)
    point = origin_b + (0.5 * (local + surface)) @ rot_b.T
    return Contacts(dist=sdf, normal=outward @ rot_b.T, point=point,
                    valid=jnp.ones(sdf.shape, dtype=bool))
