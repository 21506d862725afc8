"""2D narrowphase kernels against closed-form answers, conventions and gradients."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxrb.physics.collision.geometry import polygon_arrays
from jaxrb.physics.collision.planar import points_polygon, polygon_polygon, polygon_sphere
from jaxrb.math.vector import rot2

KERNELS = {"polygon_polygon": polygon_polygon, "polygon_sphere": polygon_sphere,
           "points_polygon": points_polygon}


@pytest.fixture(scope="module")
def jitted():
    return {name: jax.jit(kernel) for name, kernel in KERNELS.items()}


def box(hx, hy):
    return tuple(jnp.asarray(a) for a in polygon_arrays([(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]))


def box_jnp(half):
    """Box geometry built in jnp so gradients can flow into the half extents."""
    hx, hy = half[0], half[1]
    vertices = jnp.stack([jnp.stack([-hx, -hy]), jnp.stack([hx, -hy]),
                          jnp.stack([hx, hy]), jnp.stack([-hx, hy])])
    normals = jnp.asarray([[0.0, -1.0], [1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])
    return vertices, normals


TRIANGLE = tuple(jnp.asarray(a) for a in polygon_arrays([(0.0, -0.5), (0.6, 0.4), (-0.6, 0.4)]))
HEXAGON = tuple(jnp.asarray(a) for a in polygon_arrays(
    [(np.cos(a), np.sin(a)) for a in np.linspace(0.0, 2 * np.pi, 7)[:-1] + 0.1]))


def pose(x, y, angle=0.0):
    return jnp.asarray([x, y], dtype=jnp.float64), rot2(jnp.asarray(angle, dtype=jnp.float64))


def sorted_by_x(contacts):
    order = np.argsort(np.asarray(contacts.point[:, 0]))
    return (np.asarray(contacts.dist)[order], np.asarray(contacts.point)[order],
            np.asarray(contacts.normal)[order], np.asarray(contacts.valid)[order])


# ----------------------------------------------------------------------------- polygon_polygon


@pytest.mark.parametrize("swap", [False, True])
def test_box_resting_on_equal_box(jitted, swap):
    # Top box (half 0.5 x 0.25) sinks 0.01 into a bottom box (half 0.5 x 0.5), aligned edges.
    top, bottom = (box(0.5, 0.25), pose(0.0, 0.74)), (box(0.5, 0.5), pose(0.0, 0.0))
    a, b = (bottom, top) if swap else (top, bottom)
    c = jitted["polygon_polygon"](a[0], b[0], a[1], b[1])
    dist, point, normal, valid = sorted_by_x(c)
    assert valid.all()
    np.testing.assert_allclose(dist, [-0.01, -0.01], atol=1e-12)
    np.testing.assert_allclose(normal, [[0.0, -1.0 if swap else 1.0]] * 2, atol=1e-12)
    # Bottom corners of the top box, moved half the depth: midway between the surfaces.
    np.testing.assert_allclose(point, [[-0.5, 0.495], [0.5, 0.495]], atol=1e-12)


@pytest.mark.parametrize("top, bottom, top_x, bottom_x, point_y", [
    ((0.3, 0.2), (2.0, 0.5), 0.7, 0.0, 0.49),
    # The wide box on top of the narrow one: same contact, B's top face as reference.
    ((2.0, 0.5), (0.3, 0.2), 0.0, 0.7, 0.19),
])
def test_box_on_wider_box_gives_narrow_box_corners(jitted, top, bottom, top_x, bottom_x, point_y):
    c = jitted["polygon_polygon"](box(*top), box(*bottom), pose(top_x, 0.68), pose(bottom_x, 0.0))
    dist, point, normal, valid = sorted_by_x(c)
    assert valid.all()
    np.testing.assert_allclose(dist, [-0.02, -0.02], atol=1e-12)
    np.testing.assert_allclose(point, [[0.4, point_y], [1.0, point_y]], atol=1e-12)
    np.testing.assert_allclose(normal, [[0.0, 1.0]] * 2, atol=1e-12)


@pytest.mark.parametrize("swap", [False, True])
def test_slightly_rotated_box_on_box(jitted, swap):
    # Box (half 1 x 0.5) turned by 0.1 rad; its lowest corner 0.03 below a wide ground's top (y=0).
    theta, depth = 0.1, 0.03
    rotation = np.asarray(rot2(theta))
    corners = np.array([[-1.0, -0.5], [1.0, -0.5]]) @ rotation.T
    centre = np.array([0.2, -depth - corners[:, 1].min()])
    top = (box(1.0, 0.5), pose(*centre, theta))
    ground = (box(5.0, 0.5), pose(0.0, -0.5))
    a, b = (ground, top) if swap else (top, ground)
    dist, point, normal, valid = sorted_by_x(jitted["polygon_polygon"](a[0], b[0], a[1], b[1]))
    world = centre + corners                         # lower-left is lowest for theta > 0
    assert valid.all()
    np.testing.assert_allclose(dist, world[:, 1], atol=1e-12)
    np.testing.assert_allclose(dist[0], -depth, atol=1e-12)
    np.testing.assert_allclose(dist[1], -depth + 2.0 * np.sin(theta), atol=1e-12)
    np.testing.assert_allclose(point, world - 0.5 * np.outer(dist, [0.0, 1.0]), atol=1e-12)
    np.testing.assert_allclose(normal, [[0.0, -1.0 if swap else 1.0]] * 2, atol=1e-12)


def test_box_corner_into_box_face(jitted):
    # Square (half 0.5) turned by 40 degrees, lowest corner 0.05 into the ground's top face.
    theta, depth = np.deg2rad(40.0), 0.05
    local = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    corners = local @ np.asarray(rot2(theta)).T
    low = np.argmin(corners[:, 1])
    centre = np.array([0.3, -depth - corners[low, 1]])
    c = jitted["polygon_polygon"](box(0.5, 0.5), box(3.0, 1.0), pose(*centre, theta), pose(0.0, -1.0))
    assert np.asarray(c.valid).all()
    np.testing.assert_allclose(c.normal, [[0.0, 1.0]] * 2, atol=1e-12)
    deepest = int(np.argmin(c.dist))
    np.testing.assert_allclose(c.dist[deepest], -depth, atol=1e-12)
    np.testing.assert_allclose(c.point[deepest], centre + corners[low] + [0.0, 0.5 * depth], atol=1e-12)
    # The other slot is the far end of the incident edge (a neighbouring corner), above the face.
    other = centre + corners[[(low + 1) % 4, (low - 1) % 4]]
    assert np.min(np.abs(c.dist[1 - deepest] - other[:, 1])) < 1e-12
    assert c.dist[1 - deepest] > 0.0


def test_triangle_tip_into_box_and_hexagon(jitted):
    # Triangle tip (0, -0.5) 0.04 into a box's top face: deepest point is the tip.
    c = jitted["polygon_polygon"](TRIANGLE, box(1.0, 1.0), pose(0.1, 0.46), pose(0.0, -1.0))
    deepest = int(np.argmin(c.dist))
    assert bool(c.valid[deepest])
    np.testing.assert_allclose(c.dist[deepest], -0.04, atol=1e-12)
    np.testing.assert_allclose(c.point[deepest], [0.1, -0.02], atol=1e-12)
    np.testing.assert_allclose(c.normal[deepest], [0.0, 1.0], atol=1e-12)
    # Different vertex counts on both sides run, and the swapped pair mirrors the normal.
    d = jitted["polygon_polygon"](box(1.0, 1.0), TRIANGLE, pose(0.0, -1.0), pose(0.1, 0.46))
    np.testing.assert_allclose(np.min(d.dist), -0.04, atol=1e-12)
    np.testing.assert_allclose(d.normal[0], [0.0, -1.0], atol=1e-12)
    e = jitted["polygon_polygon"](HEXAGON, TRIANGLE, pose(0.0, 0.0), pose(0.3, 1.2, 0.4))
    assert np.all(np.isfinite(np.asarray(e.point))) and np.isfinite(np.asarray(e.dist)).all()


def test_separated_boxes_report_positive_dist(jitted):
    c = jitted["polygon_polygon"](box(0.5, 0.5), box(0.5, 0.5), pose(0.2, 1.3), pose(0.0, 0.0))
    dist, point, normal, valid = sorted_by_x(c)
    assert valid.all()
    np.testing.assert_allclose(dist, [0.3, 0.3], atol=1e-12)
    np.testing.assert_allclose(point, [[-0.3, 0.65], [0.5, 0.65]], atol=1e-12)
    np.testing.assert_allclose(normal, [[0.0, 1.0]] * 2, atol=1e-12)
    # Side by side: the normal is horizontal, from B (right) to A (left).
    c = jitted["polygon_polygon"](box(0.5, 0.5), box(0.5, 0.5), pose(-1.2, 0.0), pose(0.0, 0.0))
    np.testing.assert_allclose(c.dist, [0.2, 0.2], atol=1e-12)
    np.testing.assert_allclose(c.normal, [[-1.0, 0.0]] * 2, atol=1e-12)
    # Apart corner to corner: no clipped point survives, but everything is finite.
    c = jitted["polygon_polygon"](box(0.5, 0.5), box(0.5, 0.5), pose(2.0, 2.0), pose(0.0, 0.0))
    assert not np.asarray(c.valid).any()
    assert np.isfinite(np.asarray(c.dist)).all() and np.isfinite(np.asarray(c.point)).all()


def test_reference_choice_is_stable_for_equal_axes(jitted):
    # Equal boxes stacked, A shifted sideways: both axes separate (almost) equally. A keeps the
    # reference under tiny perturbations, so the incident edge is B's top edge, walked from
    # x = 0.5 to x = -0.5 and clipped at A's left side x = -0.3: the slot order does not flip.
    for noise in (0.0, 1e-12, -1e-12, 1e-9, -1e-9):
        c = jitted["polygon_polygon"](box(0.5, 0.5), box(0.5, 0.5), pose(0.2 + noise, 0.99, noise),
                                      pose(0.0, 0.0))
        np.testing.assert_allclose(c.normal, [[0.0, 1.0]] * 2, atol=1e-8)
        np.testing.assert_allclose(c.dist, [-0.01, -0.01], atol=1e-8)
        np.testing.assert_allclose(c.point[:, 0], [0.5, -0.3], atol=1e-8)


# ----------------------------------------------------------------------------- polygon_sphere


def test_circle_against_box_face_vertex_and_inside(jitted):
    kernel, square, radius = jitted["polygon_sphere"], box(1.0, 0.5), (jnp.asarray(0.3),)
    # Face: centre above the top face of a box turned by 90 degrees (so its "right" face is up).
    c = kernel(square, radius, pose(0.0, 0.0, np.pi / 2), pose(0.2, 1.25))
    np.testing.assert_allclose(c.dist, [1.25 - 1.0 - 0.3], atol=1e-12)
    np.testing.assert_allclose(c.normal, [[0.0, -1.0]], atol=1e-12)
    np.testing.assert_allclose(c.point, [[0.2, 0.5 * (1.0 + 0.95)]], atol=1e-12)
    # Vertex region: centre diagonally off the corner (1, 0.5) of a translated box.
    offset = np.array([0.15, 0.2])
    c = kernel(square, radius, pose(2.0, 1.0), pose(*(np.array([3.0, 1.5]) + offset)))
    np.testing.assert_allclose(c.dist, [0.25 - 0.3], atol=1e-12)
    np.testing.assert_allclose(c.normal, [-offset / 0.25], atol=1e-12)
    np.testing.assert_allclose(c.point, [[3.0, 1.5] + offset * (1.0 - (0.25 + 0.3) / 0.5)],
                               atol=1e-12)
    # Inside, nearest the right face (x = 1): face of least penetration.
    c = kernel(square, radius, pose(0.0, 0.0), pose(0.8, 0.1))
    np.testing.assert_allclose(c.dist, [-0.2 - 0.3], atol=1e-12)
    np.testing.assert_allclose(c.normal, [[-1.0, 0.0]], atol=1e-12)
    # Midway between the face (x = 1) and the circle's far side along -normal (x = 0.8 - 0.3).
    np.testing.assert_allclose(c.point, [[0.5 * (1.0 + 0.5), 0.1]], atol=1e-12)
    assert c.dist.shape == (1,) and bool(c.valid[0])


def test_circle_at_polygon_centroid_is_finite(jitted):
    c = jitted["polygon_sphere"](box(0.5, 0.5), (jnp.asarray(0.1),), pose(0.3, 0.2, 0.7), pose(0.3, 0.2))
    np.testing.assert_allclose(c.dist, [-0.6], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(c.normal), 1.0, atol=1e-12)


# ----------------------------------------------------------------------------- points_polygon


def test_points_against_polygon(jitted):
    points = jnp.asarray([[0.0, 0.0], [0.0, -0.9], [1.0, 1.0], [0.5, 0.0]])
    # Body A at (1.5, 0.5) unrotated; polygon B: box (half 1 x 0.5) at (1.5, 0) turned by 90 deg
    # so in the world it spans x in [1, 2], y in [-1, 1].
    c = jitted["points_polygon"]((points,), box(1.0, 0.5), pose(1.5, 0.5), pose(1.5, 0.0, np.pi / 2))
    world = np.asarray(points) + [1.5, 0.5]
    # (1.5, 0.5): inside, 0.5 from the left/right faces and the top; first face of least penetration.
    # (1.5, -0.4): inside, nearest face left/right (0.5) -> dist -0.5.
    # (2.5, 1.5): outside off the corner (2, 1). (2, 0.5): on the right face.
    np.testing.assert_allclose(c.dist, [-0.5, -0.5, np.hypot(0.5, 0.5), 0.0], atol=1e-12)
    np.testing.assert_allclose(c.normal[2], [np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12)
    np.testing.assert_allclose(c.normal[3], [1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(c.point[2], [2.25, 1.25], atol=1e-12)
    np.testing.assert_allclose(c.point[3], world[3], atol=1e-12)
    # Inside points: halfway to their projection on the chosen face.
    for i in (0, 1):
        projection = world[i] - c.dist[i] * np.asarray(c.normal[i])
        np.testing.assert_allclose(c.point[i], 0.5 * (world[i] + projection), atol=1e-12)
        assert abs(abs(projection[0] - 1.5) - 0.5) < 1e-12 or abs(abs(projection[1]) - 1.0) < 1e-12
    assert np.asarray(c.valid).all() and c.dist.shape == (4,)


def test_points_signed_distance_matches_numpy(jitted):
    # Independent numpy reference: |signed distance| is the distance to the nearest edge
    # segment, negative inside (inside = behind every edge line of the convex polygon).
    rng = np.random.default_rng(3)
    points = rng.uniform(-1.6, 1.6, (64, 2))
    angle, origin = 0.7, np.array([0.1, -0.2])
    c = jitted["points_polygon"]((jnp.asarray(points),), HEXAGON, pose(0.0, 0.0), pose(*origin, angle))
    rotation = np.asarray(rot2(angle))
    vertices = np.asarray(HEXAGON[0]) @ rotation.T + origin
    edges = np.roll(vertices, -1, axis=0) - vertices
    rel = points[:, None, :] - vertices[None]
    t = np.clip(np.sum(rel * edges, -1) / np.sum(edges * edges, -1), 0.0, 1.0)
    gap = np.min(np.linalg.norm(rel - t[..., None] * edges, axis=-1), axis=1)
    inside = np.all(edges[None, :, 0] * rel[..., 1] - edges[None, :, 1] * rel[..., 0] >= 0.0, axis=1)
    assert 5 < inside.sum() < 60
    np.testing.assert_allclose(c.dist, np.where(inside, -gap, gap), atol=1e-12)
    # The normal points from the surface to the point, and ``point`` is halfway along it.
    surface = points - np.asarray(c.dist)[:, None] * np.asarray(c.normal)
    np.testing.assert_allclose(c.point, 0.5 * (points + surface), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(c.normal, axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize("kind", list(KERNELS))
def test_float32_stays_float32(jitted, kind):
    batch = jax.tree_util.tree_map(lambda x: x.astype(jnp.float32), random_pairs(kind, 2, seed=4))
    args = unstack(batch, 0)
    c = jitted[kind](*args)
    assert c.dist.dtype == c.normal.dtype == c.point.dtype == jnp.float32
    grad = jax.jit(jax.grad(lambda origin: jnp.sum(
        KERNELS[kind](args[0], args[1], (origin, args[2][1]), args[3]).dist)))(args[2][0])
    assert grad.dtype == jnp.float32 and np.isfinite(np.asarray(grad)).all()


# ----------------------------------------------------------------------------- conventions


def random_pairs(kind, count, seed):
    """Random geometries and poses of one pair kind, stacked along a leading axis."""
    rng = np.random.default_rng(seed)
    pos_a = rng.uniform(-0.6, 0.6, (count, 2))
    pos_b = rng.uniform(-0.6, 0.6, (count, 2))
    ang_a, ang_b = rng.uniform(-np.pi, np.pi, (2, count))
    half_a, half_b = rng.uniform(0.2, 0.6, (2, count, 2))
    poses_a = (jnp.asarray(pos_a), rot2(jnp.asarray(ang_a)))
    poses_b = (jnp.asarray(pos_b), rot2(jnp.asarray(ang_b)))
    boxes_b = jax.vmap(box_jnp)(jnp.asarray(half_b))
    if kind == "polygon_polygon":
        geoms_a = jax.vmap(box_jnp)(jnp.asarray(half_a))
    elif kind == "polygon_sphere":
        geoms_a, boxes_b = jax.vmap(box_jnp)(jnp.asarray(half_a)), (jnp.asarray(half_b[:, 0]),)
    else:
        geoms_a = (jnp.asarray(rng.uniform(-0.5, 0.5, (count, 3, 2))),)
    return geoms_a, boxes_b, poses_a, poses_b


def unstack(tree, i):
    return jax.tree_util.tree_map(lambda x: x[i], tree)


@pytest.mark.parametrize("kind", list(KERNELS))
def test_vmap_matches_loop(jitted, kind):
    count = 16
    batch = random_pairs(kind, count, seed=1)
    stacked = jax.jit(jax.vmap(KERNELS[kind]))(*batch)
    for i in range(count):
        single = jitted[kind](*unstack(batch, i))
        for got, want in zip(jax.tree_util.tree_leaves(unstack(stacked, i)),
                             jax.tree_util.tree_leaves(single)):
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    leaves = jax.tree_util.tree_leaves(stacked)
    assert all(np.isfinite(np.asarray(x, dtype=float)).all() for x in leaves)


@pytest.mark.parametrize("kind", list(KERNELS))
def test_moving_a_along_normal_increases_dist(jitted, kind):
    count, step = 24, 1e-6
    geoms_a, geoms_b, poses_a, poses_b = random_pairs(kind, count, seed=2)
    kernel = jax.jit(jax.vmap(KERNELS[kind]))
    before = kernel(geoms_a, geoms_b, poses_a, poses_b)
    # Move each A along the normal of its first slot (all slots of a polygon pair share it).
    shift = step * before.normal[:, 0, :]
    after = kernel(geoms_a, geoms_b, (poses_a[0] + shift, poses_a[1]), poses_b)
    aligned = np.abs(np.einsum("nkd,nd->nk", before.normal, before.normal[:, 0, :]) - 1.0) < 1e-12
    checked = np.asarray(before.valid) & aligned
    rate = (np.asarray(after.dist) - np.asarray(before.dist)) / step
    assert checked.sum() >= count // 2
    np.testing.assert_allclose(rate[checked], 1.0, atol=1e-4)


# ----------------------------------------------------------------------------- gradients


def as_outputs(kind):
    """Kernel as a function of (origins, angles, shape parameters) returning float arrays."""
    kernel, make_geoms = KERNELS[kind], GEOMS[kind]

    def fn(pos_a, ang_a, pos_b, ang_b, shape):
        geom_a, geom_b = make_geoms(shape)
        c = kernel(geom_a, geom_b, (pos_a, rot2(ang_a)), (pos_b, rot2(ang_b)))
        return c.dist, c.normal, c.point
    return fn


@functools.lru_cache(maxsize=None)
def compiled(kind):
    """Jitted outputs and their forward/reverse Jacobians, compiled once per kernel."""
    fn = as_outputs(kind)
    argnums = tuple(range(5))
    return (jax.jit(fn), jax.jit(jax.jacfwd(fn, argnums=argnums)),
            jax.jit(jax.jacrev(fn, argnums=argnums)))


GEOMS = {
    "polygon_polygon": lambda s: (box_jnp(s[:2]), box_jnp(s[2:])),
    "polygon_sphere": lambda s: (box_jnp(s[:2]), (s[2],)),
    "points_polygon": lambda s: ((jnp.stack([s[:2], jnp.stack([s[0], -s[1]]), s[2:] - 0.9]),),
                                 box_jnp(jnp.asarray([0.5, 0.4]))),
}

GENERIC = {
    # Rotated box sinking into another box; box sinking corner-first; separated boxes.
    "polygon_polygon": [((0.13, 0.61), 0.21, (0.02, -0.03), -0.05, (0.45, 0.25, 0.7, 0.4)),
                        ((0.3, 1.12), 0.7, (0.0, 0.0), 0.0, (0.5, 0.5, 1.5, 0.5)),
                        ((0.1, 1.4), 0.1, (0.0, 0.2), 0.05, (0.5, 0.3, 1.0, 0.5))],
    # Centre inside; in a vertex region; facing an edge from outside.
    "polygon_sphere": [((0.0, 0.0), 0.3, (0.3, 0.1), 0.0, (0.5, 0.4, 0.2, 0.0)),
                       ((0.0, 0.0), 0.3, (0.7, 0.6), 0.0, (0.5, 0.4, 0.3, 0.0)),
                       ((0.1, -0.2), -0.4, (0.05, 0.55), 0.0, (0.5, 0.4, 0.3, 0.0))],
    "points_polygon": [((0.2, 0.1), 0.3, (0.0, 0.0), 0.4, (0.3, 0.2, 1.1, 1.5)),
                       ((0.9, 0.7), -0.2, (0.1, 0.0), -0.1, (0.1, 0.25, 0.4, 0.5))],
}


def cases(table):
    return [(kind, i) for kind, rows in table.items() for i in range(len(rows))]


def args_of(row):
    pos_a, ang_a, pos_b, ang_b, shape = row
    return tuple(jnp.asarray(x, dtype=jnp.float64) for x in (pos_a, ang_a, pos_b, ang_b, shape))


@pytest.mark.parametrize("kind,index", cases(GENERIC))
def test_check_grads_generic(kind, index):
    check_grads(compiled(kind)[0], args_of(GENERIC[kind][index]), order=1, modes=("fwd", "rev"), eps=1e-6)


DEGENERATE = {
    # Equal boxes exactly aligned: touching, overlapping and coincident; separating axes tie.
    "polygon_polygon": [((0.0, 1.0), 0.0, (0.0, 0.0), 0.0, (0.5, 0.5, 0.5, 0.5)),
                        ((0.0, 0.9), 0.0, (0.0, 0.0), 0.0, (0.5, 0.5, 0.5, 0.5)),
                        ((0.2, 0.3), 0.4, (0.2, 0.3), 0.4, (0.5, 0.5, 0.5, 0.5)),
                        ((1.0, 1.0), 0.0, (0.0, 0.0), 0.0, (0.5, 0.5, 0.5, 0.5))],
    # Circle centre at the centroid, on a vertex, on a face, and exactly touching.
    "polygon_sphere": [((0.1, 0.2), 0.3, (0.1, 0.2), 0.0, (0.5, 0.5, 0.2, 0.0)),
                       ((0.0, 0.0), 0.0, (0.5, 0.4), 0.0, (0.5, 0.4, 0.2, 0.0)),
                       ((0.0, 0.0), 0.0, (0.5, 0.1), 0.0, (0.5, 0.4, 0.2, 0.0)),
                       ((0.0, 0.0), 0.0, (0.0, 0.6), 0.0, (0.5, 0.4, 0.2, 0.0))],
    # Points on the surface (face, vertex) and at the polygon's centre.
    "points_polygon": [((0.0, 0.0), 0.0, (0.0, 0.0), 0.0, (0.5, 0.1, 1.4, 1.3)),
                       ((0.0, 0.0), 0.0, (0.0, 0.0), 0.0, (0.5, 0.4, 0.9, 0.9))],
}


@pytest.mark.parametrize("kind,index", cases(DEGENERATE))
def test_gradients_finite_at_degenerate_configurations(kind, index):
    fn, jacfwd, jacrev = compiled(kind)
    args = args_of(DEGENERATE[kind][index])
    values = fn(*args)
    for jacobian in (jacfwd, jacrev):
        leaves = jax.tree_util.tree_leaves(jacobian(*args))
        assert all(np.isfinite(np.asarray(x)).all() for x in leaves), (kind, index)
    assert all(np.isfinite(np.asarray(x)).all() for x in values)
    np.testing.assert_allclose(np.linalg.norm(values[1], axis=-1), 1.0, atol=1e-12)
