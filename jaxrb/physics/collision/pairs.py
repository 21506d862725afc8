"""The static pair table and the detection pipeline.

At build time every pair of shapes that may touch (after collision filtering,
no self pairs, nothing static against static) is sorted into a
:class:`PairGroup` per pair kind and geometry size. At run time
:func:`detect` runs each group's kernel vmapped over its pairs and flattens
the results into one :class:`ContactSet` of fixed capacity.

A group either runs all its pairs (``all_pairs``) or, with the ``spheres``
broadphase, first tests bounding spheres of all its pairs and runs the kernel
on at most ``capacity`` overlapping ones; more overlaps than that set
``ContactSet.overflow`` (and ``State.overflow``): contacts are never dropped
silently.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.math import quaternion as quat_ops
from jaxrb.model.struct import pytree_dataclass
from jaxrb.physics.collision import box, planar, plane, round as round_kernels
from jaxrb.physics.collision.geometry import geometry, pair_kind
from jaxrb.math.components import materialize
from jaxrb.physics.contact.common import relative_velocity
from jaxrb.math.vector import rot2, safe_sqrt, unstack
from jaxrb.model.types import COLLIDING, INACTIVE, RESTING, SEPARATING, Array, Model, Params, State

KERNELS = {
    "sphere_plane": plane.sphere_plane,
    "capsule_plane": plane.capsule_plane,
    "box_plane": plane.box_plane,
    "points_plane": plane.points_plane,
    "polygon_plane": plane.polygon_plane,
    "sphere_sphere": round_kernels.sphere_sphere,
    "capsule_sphere": round_kernels.capsule_sphere,
    "capsule_capsule": round_kernels.capsule_capsule,
    "box_box": box.box_box,
    "box_sphere": box.box_sphere,
    "box_capsule": box.box_capsule,
    "points_box": box.points_box,
    "polygon_sphere": planar.polygon_sphere,
    "polygon_polygon": planar.polygon_polygon,
    "points_polygon": planar.points_polygon,
}

#: Kernels that take ``store(parts) -> parts``: written on components, they
#: need their intermediate results computed once (see
#: :func:`jaxrb.math.components.materialize`), or XLA recomputes them in every consumer.
STORING_KERNELS = frozenset({"polygon_polygon"})


@dataclasses.dataclass(frozen=True)
class PairGroup:
    """All pairs of one kind (and geometry size), run through one vmapped kernel.

    Attributes:
        kind: pair kind, e.g. ``"box_plane"``; A is the first kind.
        body_a: (P,) body index of each pair's A.
        body_b: (P,) body index of B, or plane index when ``b_is_plane``.
        b_is_plane: whether B is a static plane.
        capacity: pairs run through the kernel per step (P for all pairs).
        slots: contacts per pair the kernel returns (K).
        key_offset: first contact key of this group (keys are global slot ids).
    """

    kind: str
    body_a: tuple
    body_b: tuple
    b_is_plane: bool
    capacity: int
    slots: int
    key_offset: int


@pytree_dataclass
class ContactSet:
    """Every contact slot of one world, flat over all pair groups (C slots).

    Attributes:
        body_a: (C,) int32 body of side A.
        body_b: (C,) int32 body of side B; ``n`` (one past the last body) for planes.
        dist: (C,) signed separation (m), negative when penetrating.
        normal: (C, dim) unit normal from B to A.
        point: (C, dim) world contact point.
        active: (C,) bool, a real contact within the (speculative) margin.
        friction: (C,) mixed friction √(μ_A μ_B).
        restitution: (C,) mixed restitution max(e_A, e_B).
        normal_velocity: (C,) v_rel = n·(v_A − v_B) at the point, before the step.
        status: (C,) int8 INACTIVE, SEPARATING, RESTING or COLLIDING
            (|v_rel| ≤ bounce_threshold counts as resting).
        key: (C,) int32 global id of the pair slot held by each row.
        overflow: () bool, a broadphase dropped overlapping pairs.
    """

    body_a: Array
    body_b: Array
    dist: Array
    normal: Array
    point: Array
    active: Array
    friction: Array
    restitution: Array
    normal_velocity: Array
    status: Array
    key: Array
    overflow: Array


def bounding_radius(kind, arrays):
    """Radius about the shape origin that encloses the shape."""
    if kind == "sphere":
        return float(arrays[0])
    if kind == "capsule":
        return float(arrays[0] + arrays[1])
    if kind == "box":
        return float(np.linalg.norm(arrays[0]))
    return float(np.max(np.linalg.norm(arrays[0], axis=-1)))


def _can_collide(filter_a, filter_b):
    (category_a, mask_a), (category_b, mask_b) = filter_a, filter_b
    return bool(category_a & mask_b) and bool(category_b & mask_a)


def _kernel_slots(kind, geom_a, geom_b, dim):
    """K of a kernel, from its output shape (no computation)."""
    pose = (jax.ShapeDtypeStruct((dim,), jnp.float64), jax.ShapeDtypeStruct((dim, dim), jnp.float64))
    spec = lambda arrays: tuple(jax.ShapeDtypeStruct(np.shape(a), jnp.float64) for a in arrays)
    out = jax.eval_shape(KERNELS[kind], spec(geom_a), spec(geom_b), pose, pose)
    return out.dist.shape[0]


def build_pair_groups(shapes, body_filters, planes, plane_filters, dim, broadphase, capacity=None,
                      excluded=frozenset(), static_bodies=frozenset(), excluded_planes=frozenset()):
    """The static pair table.

    Args:
        shapes: per-body shape or None.
        body_filters: per-body (category bits, mask bits).
        planes: tuple of (normal tuple, offset).
        plane_filters: per-plane (category bits, mask bits).
        dim: 2 or 3.
        broadphase: "all_pairs" or "spheres" (body–body groups only; planes
            always run all their pairs).
        capacity: pairs per body–body group the ``spheres`` broadphase keeps;
            default 4 per body of the scene.
        excluded: (a, b) body pairs (a < b) that never collide (joints: a
            body and its parent, bodies welded together).
        static_bodies: bodies fixed to the world, which planes do not touch.
        excluded_planes: (body, plane) pairs that never collide.

    Returns:
        (tuple of PairGroup, tuple of skipped pair kinds).
    """
    geoms = [geometry(shape, dim) if shape is not None else None for shape in shapes]
    buckets: dict = {}
    skipped = set()

    def add(kind, a, b, b_is_plane, size_key):
        if kind not in KERNELS:
            skipped.add(kind)
            return
        buckets.setdefault((kind, b_is_plane, size_key), []).append((a, b))

    for a, geom in enumerate(geoms):
        if geom is None:
            continue
        for p, (normal, offset) in enumerate(planes):
            if a not in static_bodies and (a, p) not in excluded_planes \
                    and _can_collide(body_filters[a], plane_filters[p]):
                add(f"{geom[0]}_plane", a, p, True, tuple(np.shape(x) for x in geom[1]))
        for b in range(a + 1, len(geoms)):
            if geoms[b] is None or (a, b) in excluded or not _can_collide(body_filters[a], body_filters[b]):
                continue
            kind, swap = pair_kind(geom[0], geoms[b][0])
            first, second = (b, a) if swap else (a, b)
            size_key = (tuple(np.shape(x) for x in geoms[first][1]),
                        tuple(np.shape(x) for x in geoms[second][1]))
            add(kind, first, second, False, size_key)

    groups, key_offset = [], 0
    for (kind, b_is_plane, _), pairs in sorted(buckets.items(), key=lambda item: str(item[0])):
        body_a = tuple(a for a, _ in pairs)
        body_b = tuple(b for _, b in pairs)
        geom_a = geoms[body_a[0]][1]
        geom_b = (np.asarray(planes[body_b[0]][0]), np.float64(planes[body_b[0]][1])) if b_is_plane \
            else geoms[body_b[0]][1]
        slots = _kernel_slots(kind, geom_a, geom_b, dim)
        group_capacity = len(pairs)
        if broadphase == "spheres" and not b_is_plane:
            group_capacity = min(len(pairs), capacity if capacity else 4 * len(shapes))
        groups.append(PairGroup(kind=kind, body_a=body_a, body_b=body_b, b_is_plane=b_is_plane,
                                capacity=group_capacity, slots=slots, key_offset=key_offset))
        key_offset += len(pairs) * slots
    return tuple(groups), tuple(sorted(skipped))


def shape_poses(model: Model, params: Params, state: State):
    """World pose of every body's shape frame: origins (n, dim), rotations (n, dim, dim)."""
    if model.dim == 3:
        rotation = quat_ops.to_rotation_matrix(state.quat)
        origin = state.pos - quat_ops.rotate(state.quat, params.com_offset)
    else:
        rotation = rot2(state.angle)
        origin = state.pos - jnp.einsum("nij,nj->ni", rotation, params.com_offset)
    if model.shape_frames:  # shapes placed in their bodies (3D): body frame, then the shape's pose in it
        offset, turn = shape_frame_arrays(model, origin.dtype)
        origin = origin + jnp.einsum("nij,nj->ni", rotation, offset)
        rotation = rotation @ turn
    return origin, rotation


def shape_frame_arrays(model: Model, dtype):
    """Each shape's pose in its body frame as arrays: offsets (n, 3) and rotations (n, 3, 3) (identity: None)."""
    offsets = np.zeros((model.num_bodies, 3))
    turns = np.tile(np.eye(3), (model.num_bodies, 1, 1))
    for body, frame in enumerate(model.shape_frames):
        if frame is not None:
            offsets[body] = frame[0]
            w, x, y, z = frame[1]
            turns[body] = [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                           [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                           [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]
    return jnp.asarray(offsets, dtype), jnp.asarray(turns, dtype)


def shape_centres(model: Model, params: Params):
    """(n, dim) each shape's origin from its body's centre of mass, body frame (where a ball's centre is)."""
    centre = -params.com_offset
    if model.shape_frames:
        centre = centre + shape_frame_arrays(model, centre.dtype)[0]
    return centre


def round_sides(model: Model):
    """Whether side A and side B of each contact row is a sphere or circle.

    Returns two (C,) numpy bool arrays in :func:`detect`'s row order (static:
    they follow from the pair table).
    """
    sides = ([], [])
    for group in model.pair_groups:
        for side, kind in zip(sides, group.kind.split("_")):
            side.append(np.full(group.capacity * group.slots, kind == "sphere"))
    return tuple(np.concatenate(side) if side else np.zeros(0, dtype=bool) for side in sides)


def plane_rows(model: Model):
    """Whether each contact row's side B is a plane (the static row): a (C,) numpy bool array.

    In :func:`detect`'s row order, static like :func:`round_sides`.
    """
    rows = [np.full(group.capacity * group.slots, group.b_is_plane) for group in model.pair_groups]
    return np.concatenate(rows) if rows else np.zeros(0, dtype=bool)


def _bodies_piece(bodies, repeat, static_row=None):
    """How to read ``bodies`` (static ints), each repeated ``repeat`` times, off a per-body array.

    ``("static", rows)`` when every body is ``static_row`` (the planes: zeros);
    ``("range", first, count, repeat, step)`` when they are consecutive
    (step 1: a slice) or all the same (step 0: one row), read with a
    broadcast and no gather; else ``("index", rows)`` with the numpy rows.
    """
    bodies = np.asarray(bodies, dtype=np.int32)
    if np.all(bodies == static_row):
        return ("static", len(bodies) * int(repeat))
    if np.all(np.diff(bodies) == 1) or np.all(bodies == bodies[0]):
        step = 1 if len(bodies) > 1 and bodies[1] != bodies[0] else 0
        return ("range", int(bodies[0]), len(bodies), int(repeat), step)
    return ("index", np.repeat(bodies, repeat))


@functools.lru_cache(maxsize=None)
def static_rows(model: Model):
    """The body rows of the contacts' side A and side B as pieces, one per pair group.

    Each side is a tuple of pieces (see :func:`_bodies_piece`) in
    :func:`detect`'s row order; :func:`take_rows` reads an (n, ...) body
    array with them. Planes are the static row n. A broadphase group's bodies
    are known only at run time: its piece is ``("picked", capacity, slots)``,
    read off the traced rows one pair at a time (a plane side stays static).
    """
    sides = ([], [])
    for group in model.pair_groups:
        picked = group.capacity < len(group.body_a)
        body_b = (model.num_bodies,) * len(group.body_b) if group.b_is_plane else group.body_b
        for side, bodies in zip(sides, (group.body_a, body_b)):
            piece = _bodies_piece(bodies, group.slots, model.num_bodies)
            if picked:
                piece = (("static", group.capacity * group.slots) if piece[0] == "static"
                         else ("picked", group.capacity, group.slots))
            side.append(piece)
    return tuple(tuple(side) for side in sides)


def _picked_bodies(rows, start, count, repeat):
    """The (count,) bodies of a picked piece's pairs: every ``repeat``-th of its traced ``rows``."""
    if rows is None:
        raise ValueError("take_rows/sum_rows: a broadphase group's rows need the traced body rows")
    return rows[start:start + count * repeat:repeat]


def take_rows(array, pieces, static_row=None, rows=None):
    """The rows ``pieces`` name of a per-body array, with slices and broadcasts where they allow.

    Args:
        array: (n, ...) per-body values.
        pieces: one side of :func:`static_rows`.
        static_row: optional (...) value the static row (planes) reads as;
            zeros by default.
        rows: (C,) int traced body of each row, read for ``"picked"`` pieces.

    Returns:
        (C, ...) the rows' values.
    """
    if static_row is None:
        static_row = jnp.zeros(array.shape[1:], array.dtype)
    parts, start = [], 0
    for piece in pieces:
        if piece[0] == "static":
            parts.append(jnp.broadcast_to(static_row, (piece[1],) + array.shape[1:]))
            start += piece[1]
            continue
        if piece[0] == "index":
            parts.append(array[piece[1]])
            start += len(piece[1])
            continue
        if piece[0] == "picked":
            _, count, repeat = piece
            # One gather per pair, not per row: under vmap each gathered row
            # is a transposed copy of the batched body array.
            block = array[_picked_bodies(rows, start, count, repeat)]
        else:
            _, first, count, repeat, step = piece
            block = array[first:first + count] if step else jnp.broadcast_to(array[first], (count,) + array.shape[1:])
        block = jnp.broadcast_to(block[:, None], (count, repeat) + array.shape[1:])
        parts.append(block.reshape((count * repeat,) + array.shape[1:]))
        start += count * repeat
    return parts[0] if len(parts) == 1 else jnp.concatenate(parts)


def body_rows(bodies, *arrays):
    """Each (n, ...) array's rows for the static ``bodies`` (k,), by slices and broadcasts where they allow."""
    piece = (_bodies_piece(bodies, 1),)
    return tuple(take_rows(array, piece) for array in arrays)


def sum_rows(values, pieces, num_rows, rows=None):
    """Per-body sums of per-row ``values``: the transpose of :func:`take_rows`.

    Args:
        values: (C, ...) per contact row.
        pieces: one side of :func:`static_rows`.
        num_rows: bodies n (rows on the static body are left out).
        rows: (C,) int traced body of each row, read for ``"picked"`` pieces.

    Returns:
        (n, ...) Σ of the values of each body's rows.
    """
    total = jnp.zeros((num_rows,) + values.shape[1:], values.dtype)
    start = 0
    for piece in pieces:
        if piece[0] == "static":
            start += piece[1]
            continue
        if piece[0] == "index":
            count = len(piece[1])
            total = total + jax.ops.segment_sum(values[start:start + count], piece[1], num_rows)
            start += count
            continue
        if piece[0] == "picked":
            _, count, repeat = piece
            # A pair's slots summed first: the scatter (a loop under vmap) adds one row per pair.
            block = values[start:start + count * repeat].reshape((count, repeat) + values.shape[1:])
            total = total + jax.ops.segment_sum(jnp.sum(block, axis=1),
                                                _picked_bodies(rows, start, count, repeat), num_rows)
            start += count * repeat
            continue
        _, first, count, repeat, step = piece
        block = values[start:start + count * repeat].reshape((count, repeat) + values.shape[1:])
        # Under vmap a scatter runs as a loop over worlds and wants the rows
        # axis first (a transposed copy of every operand); these are sums.
        if step:
            total = total.at[first:first + count].add(jnp.sum(block, axis=1))
        else:
            total = total.at[first].add(jnp.sum(block, axis=(0, 1)))
        start += count * repeat
    return total


def row_taker(model: Model, body_a, body_b):
    """``take(array, side, static_row=None)``: the side-A (0) or side-B (1) rows of an (n, ...) body array.

    The static row n (planes) reads as ``static_row`` ((...), zeros by
    default). Reads with static slices and broadcasts where the pair table
    fixes the rows (:func:`static_rows`), and a broadphase group's rows with
    one gather per picked pair from the traced ``body_a``, ``body_b`` (C,).
    Under vmap a gather of the batched (n, 3) arrays comes out as a
    transposed (rows, batch, 3) copy that every consumer re-reads; a
    broadcast fuses into its consumer.
    """
    pieces = static_rows(model)
    return lambda array, side, static_row=None: take_rows(array, pieces[side], static_row,
                                                          body_b if side else body_a)


def row_summer(model: Model, body_a, body_b):
    """``add(values, side)``: (n, ...) per-body sums of side-A (0) or side-B (1) row values.

    The transpose of :func:`row_taker` (rows on the static row n are left
    out): static slices and sums where the pair table fixes the rows, a
    segment sum over the picked pairs of a broadphase group.
    """
    pieces = static_rows(model)
    return lambda values, side: sum_rows(values, pieces[side], model.num_bodies, body_b if side else body_a)


def _stack_geometry(model, bodies, dtype, scale):
    """The bodies' geometry arrays stacked, lengths times ``scale`` (P,) (a polygon's normals kept)."""
    found = [geometry(model.shapes[b], model.dim) for b in bodies]
    kind, arrays = found[0][0], [parts for _, parts in found]
    stacked = [jnp.asarray(np.stack([a[i] for a in arrays]), dtype=dtype) for i in range(len(arrays[0]))]
    lengths = stacked[:1] if kind == "polygon" else stacked
    scaled = [part * scale.reshape(scale.shape + (1,) * (part.ndim - 1)) for part in lengths]
    return tuple(scaled + stacked[len(scaled):])


def mix_friction(mu_a, mu_b):
    """Mixed friction √(μ_A μ_B) of two surfaces, 0 (with a finite gradient) where either is 0."""
    product = mu_a * mu_b
    positive = product > 0.0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, product, 1.0)), 0.0)


def _near_pairs(model: Model, params: Params, state: State, origin, group: PairGroup):
    """(P,) whether each of the group's pairs may touch this step: bounding spheres within reach.

    Tested on the dense (A bodies, B bodies) table and read back at the pairs,
    rather than gathered per pair: under vmap each per-pair gather of a
    batched (n, dim) array is a transposed (P, batch, dim) copy, and the
    55-box pyramid's four of them (1 485 pairs) took ~2.5 ms a step at 256
    worlds; the dense table is elementwise over slices of the body arrays.

    Args:
        origin: (n, dim) shape-frame origins.
        group: a PairGroup with a broadphase.
    """
    dtype = state.pos.dtype
    sides = []
    for bodies in (group.body_a, group.body_b):
        rows = np.unique(bodies)
        radius = (jnp.asarray([bounding_radius(*geometry(model.shapes[b], model.dim)) for b in rows], dtype=dtype)
                  * params.shape_scale[np.asarray(rows)])
        sides.append((rows, *body_rows(rows, origin, state.vel), radius))
    (rows_a, origin_a, vel_a, radius_a), (rows_b, origin_b, vel_b, radius_b) = sides

    def distances(points_a, points_b):
        """(A, B) distances, summed over components: a reduce over a minor axis of 2 or 3 is slow under vmap."""
        return safe_sqrt(sum((x[:, None] - y[None]) ** 2 for x, y in zip(unstack(points_a), unstack(points_b))))

    gap = distances(origin_a, origin_b) - radius_a[:, None] - radius_b[None]
    near = gap < params.contact_margin + params.dt * distances(vel_a, vel_b)
    flat = np.searchsorted(rows_a, group.body_a) * len(rows_b) + np.searchsorted(rows_b, group.body_b)
    return near.reshape(-1)[flat]


def _first_true(flags, capacity: int):
    """The first ``capacity`` indices where ``flags`` (P,) holds, in order, and which of them are real.

    ``jnp.nonzero(size=capacity)`` pads with index 0, and a padded slot is not
    marked: it read as pair 0 again wherever pair 0 was near (its contacts
    counted several times). Here unused slots hold 0 and ``in_use`` is false.

    The running count is two small matrix products (within blocks, then over
    the block totals), exact in float32 for P < 2**24: under vmap
    ``jnp.cumsum`` on XLA's CPU backend is a windowed reduce that took
    0.9-1.5 ms of the 55-box pyramid's step at 256 worlds.

    Args:
        flags: (P,) bool, P >= 1.
        capacity: slots to fill.

    Returns:
        ``(indices, in_use)``: (capacity,) int32 and (capacity,) bool.
    """
    count = flags.shape[0]
    block = math.ceil((2 * count) ** (1 / 3))  # minimises count·block + (count/block)², the products' work
    blocks = -(-count // block)
    ones = np.ones((block, block), np.float32)
    padded = jnp.pad(flags.astype(jnp.float32), (0, blocks * block - count)).reshape(blocks, block)
    within = padded @ jnp.asarray(np.triu(ones))                         # inclusive, per block
    before = within[:, -1] @ jnp.asarray(np.triu(np.ones((blocks, blocks), np.float32), 1))
    running = (within + before[:, None]).reshape(-1)[:count].astype(jnp.int32)
    # Each flagged entry's 0-based rank; the others write to a spare slot cut off after.
    rank = jnp.where(flags, running - 1, capacity)
    indices = jnp.zeros(capacity + 1, jnp.int32).at[rank].set(jnp.arange(count, dtype=jnp.int32))[:capacity]
    return indices, jnp.arange(capacity) < running[-1]


def detect(model: Model, params: Params, state: State) -> ContactSet:
    """Run the pair table on ``state``: every contact slot, classified.

    Args:
        model: the scene's Model (its ``pair_groups`` and ``planes``).
        params: Params (friction, restitution, contact margin, bounce threshold, dt).
        state: State (positions, orientations and velocities of the bodies).

    Returns:
        A :class:`ContactSet` with C = ``model.num_contacts`` rows (normal
        (C, dim), point (C, dim), dist (C,), ...).
    """
    dtype = state.pos.dtype
    origin, rotation = shape_poses(model, params, state)

    def pose_of(bodies, traced):
        """Shape poses of a group's pairs' bodies: the ``traced`` (picked) rows, else static slices.

        A broadphase group reads them once it has picked its pairs: gathering
        all pairs' poses first was a (P, batch, ...) copy under vmap.
        """
        if traced is not None:
            return origin[traced], rotation[traced]
        return body_rows(bodies, origin, rotation)

    num = model.num_bodies
    parts, overflow = [], jnp.zeros((), dtype=bool)
    for group in model.pair_groups:
        body_a = jnp.asarray(group.body_a, dtype=jnp.int32)
        body_b = jnp.asarray(group.body_b, dtype=jnp.int32)
        geom_a = _stack_geometry(model, group.body_a, dtype, params.shape_scale[np.asarray(group.body_a)])
        if group.b_is_plane:
            normals = np.asarray([model.planes[p][0] for p in group.body_b], dtype=np.float64)
            offsets = np.asarray([model.planes[p][1] for p in group.body_b], dtype=np.float64)
            geom_b = (jnp.asarray(normals, dtype=dtype), jnp.asarray(offsets, dtype=dtype))
        else:
            geom_b = _stack_geometry(model, group.body_b, dtype, params.shape_scale[np.asarray(group.body_b)])
        pair_ids = jnp.arange(len(group.body_a), dtype=jnp.int32)
        in_use = jnp.ones((len(group.body_a),), dtype=bool)
        picked = group.capacity < len(group.body_a)
        if picked:
            near = _near_pairs(model, params, state, origin, group)
            overflow = overflow | (jnp.sum(near) > group.capacity)
            pair_ids, in_use = _first_true(near, group.capacity)
            geom_a, geom_b = jax.tree_util.tree_map(lambda x: x[pair_ids], (geom_a, geom_b))
            body_a, body_b = body_a[pair_ids], body_b[pair_ids]
        pose_a = pose_of(group.body_a, body_a if picked else None)
        if group.b_is_plane:
            pose_b = (jnp.zeros((len(pair_ids), model.dim), dtype),
                      jnp.broadcast_to(jnp.eye(model.dim, dtype=dtype), (len(pair_ids), model.dim, model.dim)))
        else:
            pose_b = pose_of(group.body_b, body_b if picked else None)
        kernel = KERNELS[group.kind]
        if group.kind in STORING_KERNELS:
            kernel = functools.partial(kernel, store=lambda parts: materialize(parts, params))
        found = jax.vmap(kernel)(geom_a, geom_b, pose_a, pose_b)
        slots = group.slots
        mu_a, e_a = params.friction[body_a], params.restitution[body_a]
        if group.b_is_plane:
            mu_b, e_b = params.plane_friction[body_b], params.plane_restitution[body_b]
            body_b = jnp.full_like(body_b, num)
        else:
            mu_b, e_b = params.friction[body_b], params.restitution[body_b]
        repeat = lambda x: jnp.repeat(x, slots, axis=0)
        key = (group.key_offset + pair_ids[:, None] * slots + jnp.arange(slots, dtype=jnp.int32)).reshape(-1)
        parts.append(dict(
            body_a=repeat(body_a), body_b=repeat(body_b),
            dist=found.dist.reshape(-1), normal=found.normal.reshape(-1, model.dim),
            point=found.point.reshape(-1, model.dim), valid=(found.valid & in_use[:, None]).reshape(-1),
            friction=repeat(mix_friction(mu_a, mu_b)), restitution=repeat(jnp.maximum(e_a, e_b)),
            key=key))
    merged = {name: jnp.concatenate([part[name] for part in parts]) for name in parts[0]}
    take = row_taker(model, merged["body_a"], merged["body_b"])
    rel_vel = relative_velocity(model, state.vel, state.angvel, merged["body_a"], merged["body_b"],
                                merged["point"] - take(state.pos, 0), merged["point"] - take(state.pos, 1), take)
    normal_velocity = jnp.sum(merged["normal"] * rel_vel, axis=-1)
    # Speculative margin: a contact approaching fast is kept from farther away.
    reach = params.contact_margin + params.dt * jnp.maximum(-normal_velocity, 0.0)
    active = merged.pop("valid") & (merged["dist"] < reach)
    threshold = params.bounce_threshold
    status = jnp.where(normal_velocity < -threshold, COLLIDING,
                       jnp.where(normal_velocity > threshold, SEPARATING, RESTING))
    status = jnp.where(active, status, INACTIVE).astype(jnp.int8)
    return ContactSet(active=active, normal_velocity=normal_velocity, status=status,
                      overflow=overflow, **merged)
