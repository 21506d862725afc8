"""Box narrowphase kernels against closed forms and independent numpy references.

float64 throughout (conftest enables x64). The numpy references (box signed
distance, ternary search along a segment) share no code with the kernels.
"""

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxrb.math import quaternion
from jaxrb.physics.collision.box import box_box, box_capsule, box_sphere, points_box

EYE3 = np.eye(3)
# Rotation taking shape z to world x (a capsule lying along x).
ALONG_X = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])

KERNELS = {"box_box": box_box, "box_sphere": box_sphere, "box_capsule": box_capsule,
           "points_box": points_box}
JITTED = {name: jax.jit(kernel) for name, kernel in KERNELS.items()}

CUBE = (np.full(3, 0.5),)
POINTS = (np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 0.1], [0.7, 0.1, -0.2], [-0.4, 0.8, 0.9]]),)
POINTS_ON_SURFACE = (np.array([[0.5, 0.0, 0.0], [0.5, 0.5, 0.5], [0.0, 0.0, 0.0], [0.5, 0.2, -0.5]]),)


def pose(origin, rotation=EYE3):
    return jnp.asarray(origin, dtype=jnp.float64), jnp.asarray(rotation, dtype=jnp.float64)


def rot_about(axis, angle):
    return np.asarray(quaternion.to_rotation_matrix(
        quaternion.from_axis_angle(jnp.asarray(axis, float), angle)))


def rotation_of(rotvec):
    return quaternion.to_rotation_matrix(quaternion.exp(rotvec))


def random_rotation(rng):
    q = rng.normal(size=4)
    return np.asarray(quaternion.to_rotation_matrix(jnp.asarray(q / np.linalg.norm(q))))


def ref_sdf(half, x):
    """Exact signed distance of points x (..., 3) to an axis-aligned box, numpy."""
    q = np.abs(x) - half
    return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)


def sorted_rows(rows):
    """Rows sorted lexicographically (rounded), so sets of contacts compare in any order."""
    rows = np.asarray(rows, dtype=float)
    return rows[np.lexsort(np.round(rows, 9).T[::-1])]


def valid_rows(contacts):
    """(n, 4) array of [dist, point] of the valid slots, sorted for set comparison."""
    valid = np.asarray(contacts.valid)
    return sorted_rows(np.concatenate([np.asarray(contacts.dist)[valid, None],
                                       np.asarray(contacts.point)[valid]], axis=1))


def deepest(contacts):
    dist = np.where(np.asarray(contacts.valid), np.asarray(contacts.dist), np.inf)
    return int(np.argmin(dist))


def assert_contract(contacts, slots):
    """Shapes, unit normals and finiteness of every slot."""
    assert contacts.dist.shape == (slots,)
    assert contacts.normal.shape == (slots, 3)
    assert contacts.point.shape == (slots, 3)
    assert contacts.valid.shape == (slots,) and contacts.valid.dtype == bool
    for field in (contacts.dist, contacts.normal, contacts.point):
        assert np.all(np.isfinite(np.asarray(field)))
    np.testing.assert_allclose(np.linalg.norm(np.asarray(contacts.normal), axis=1), 1.0,
                               atol=1e-12)


# --------------------------------------------------------------------------- #
# box-box
# --------------------------------------------------------------------------- #


def test_box_box_equal_cubes_face_to_face():
    contacts = JITTED["box_box"](CUBE, CUBE, pose([0.0, 0.0, 0.9]), pose([0.0, 0.0, 0.0]))
    assert_contract(contacts, 8)
    assert int(contacts.valid.sum()) == 4
    expected = [[-0.1, x, y, 0.45] for x, y in itertools.product((-0.5, 0.5), repeat=2)]
    np.testing.assert_allclose(valid_rows(contacts), sorted_rows(expected), atol=1e-12)
    np.testing.assert_allclose(contacts.normal, np.tile([0.0, 0.0, 1.0], (8, 1)), atol=1e-12)


@pytest.mark.parametrize("small_is_a", [True, False])
def test_box_box_small_box_resting_gives_its_four_corners(small_is_a):
    small_half, big_half = np.array([0.1, 0.2, 0.05]), np.array([1.0, 1.5, 1.0])
    yaw = rot_about([0, 0, 1], 0.5)
    small_origin = np.array([0.3, -0.2, 1.0 + 0.05 - 0.01])     # 0.01 into the big box
    small = ((small_half,), pose(small_origin, yaw))
    big = ((big_half,), pose([0.0, 0.0, 0.0]))
    if small_is_a:
        contacts = JITTED["box_box"](small[0], big[0], small[1], big[1])
        normal = [0.0, 0.0, 1.0]
    else:
        contacts = JITTED["box_box"](big[0], small[0], big[1], small[1])
        normal = [0.0, 0.0, -1.0]
    assert_contract(contacts, 8)
    corners = [small_origin + yaw @ (small_half * [sx, sy, -1.0])
               for sx, sy in itertools.product((-1.0, 1.0), repeat=2)]
    # Midway between the small box's bottom (z = 0.99) and the big box's top (z = 1).
    expected = [[-0.01, c[0], c[1], 0.995] for c in corners]
    np.testing.assert_allclose(valid_rows(contacts), sorted_rows(expected), atol=1e-12)
    np.testing.assert_allclose(contacts.normal[0], normal, atol=1e-12)


def test_box_box_45_degree_octagon():
    contacts = JITTED["box_box"](CUBE, CUBE, pose([0.0, 0.0, 0.95], rot_about([0, 0, 1], np.pi / 4)),
                                 pose([0.0, 0.0, 0.0]))
    assert_contract(contacts, 8)
    assert bool(contacts.valid.all())
    cut = np.sqrt(0.5) - 0.5      # where the rotated square's edges cross x = +-0.5
    expected = ([[-0.05, sx * 0.5, sy * cut, 0.475] for sx, sy in itertools.product((-1, 1), repeat=2)]
                + [[-0.05, sx * cut, sy * 0.5, 0.475] for sx, sy in itertools.product((-1, 1), repeat=2)])
    np.testing.assert_allclose(valid_rows(contacts), sorted_rows(expected), atol=1e-12)


def crossed_edges(depth):
    """Two unit cubes, A's bottom edge along x resting across B's top edge along y."""
    z = np.sqrt(2.0) - depth
    return (CUBE, CUBE, pose([0.1, -0.05, z], rot_about([1, 0, 0], np.pi / 4)),
            pose([0.0, 0.0, 0.0], rot_about([0, 1, 0], np.pi / 4)))


@pytest.mark.parametrize("depth", [0.05, -0.2])
def test_box_box_edge_edge_crossing(depth):
    contacts = JITTED["box_box"](*crossed_edges(depth))
    assert_contract(contacts, 8)
    assert np.asarray(contacts.valid).tolist() == [True] + [False] * 7
    np.testing.assert_allclose(contacts.dist[0], -depth, atol=1e-12)
    np.testing.assert_allclose(contacts.normal[0], [0.0, 0.0, 1.0], atol=1e-12)
    # A's edge runs along x at y = -0.05, B's along y at x = 0: they cross above (0, -0.05).
    top_of_b = np.sqrt(0.5)
    np.testing.assert_allclose(contacts.point[0], [0.0, -0.05, top_of_b - 0.5 * depth], atol=1e-12)


def test_box_box_separated_faces_keep_speculative_contacts():
    contacts = JITTED["box_box"](CUBE, CUBE, pose([0.2, 0.1, 1.2]), pose([0.0, 0.0, 0.0]))
    assert int(contacts.valid.sum()) == 4
    np.testing.assert_allclose(np.asarray(contacts.dist)[np.asarray(contacts.valid)], 0.2, atol=1e-12)
    # Boxes apart sideways (no face overlap in projection): one speculative contact.
    contacts = JITTED["box_box"](CUBE, CUBE, pose([1.6, 1.5, 0.0]), pose([0.0, 0.0, 0.0]))
    assert int(contacts.valid.sum()) == 1
    np.testing.assert_allclose(contacts.dist[0], 0.6, atol=1e-12)


def test_box_box_tilted_box_on_big_box_matches_its_corners():
    small_half = np.array([0.2, 0.15, 0.1])
    rotation = rot_about([0.3, -0.5, 0.2], 0.4)
    corners = np.array([rotation @ (small_half * s) for s in itertools.product((-1, 1), repeat=3)])
    lowest = corners[:, 2].min()
    origin = np.array([0.1, 0.2, 1.0 - lowest - 0.02])           # deepest corner 0.02 in
    contacts = JITTED["box_box"]((small_half,), (np.ones(3),), pose(origin, rotation), pose(np.zeros(3)))
    assert_contract(contacts, 8)
    valid = np.asarray(contacts.valid)
    assert valid.sum() == 4
    np.testing.assert_allclose(contacts.normal[0], [0.0, 0.0, 1.0], atol=1e-12)
    # The 4 contacts are the corners of the bottom face, at their heights above z = 1.
    bottom = corners[np.argsort(corners[:, 2])[:4]] + origin
    expected = [[c[2] - 1.0, c[0], c[1], 0.5 * (c[2] + 1.0)] for c in bottom]
    np.testing.assert_allclose(valid_rows(contacts), sorted_rows(expected), atol=1e-12)
    np.testing.assert_allclose(np.min(np.asarray(contacts.dist)[valid]), -0.02, atol=1e-12)


def test_box_box_face_preference_over_nearly_parallel_edges():
    # A slightly yawed and tilted: the edge axes are nearly face axes; the face
    # manifold (4 points) must win, not a single edge contact.
    rotation = rot_about([0.2, 0.1, 1.0], 1e-3)
    contacts = JITTED["box_box"](CUBE, CUBE, pose([0.0, 0.0, 0.99], rotation), pose([0.0, 0.0, 0.0]))
    assert int(contacts.valid.sum()) >= 4


# --------------------------------------------------------------------------- #
# box-sphere
# --------------------------------------------------------------------------- #


@pytest.mark.parametrize("center, dist, normal", [
    ([0.2, -0.1, 0.75], 0.05, [0.0, 0.0, -1.0]),                     # above the top face
    ([0.8, 0.1, 0.9], 0.5 - 0.2, [-0.6, 0.0, -0.8]),                  # edge region
    ([0.5 + 0.3, 0.5 + 0.4, 0.5 + 1.2], 1.3 - 0.2, None),             # corner region
    ([0.1, 0.2, 0.4], -0.1 - 0.2, [0.0, 0.0, -1.0]),                  # inside, near the top
])
def test_box_sphere_closed_forms(center, dist, normal):
    contacts = JITTED["box_sphere"](CUBE, (0.2,), pose([0.0, 0.0, 0.0]), pose(center))
    assert_contract(contacts, 1)
    np.testing.assert_allclose(contacts.dist[0], dist, atol=1e-12)
    if normal is None:
        normal = -np.array([0.3, 0.4, 1.2]) / 1.3
    np.testing.assert_allclose(contacts.normal[0], normal, atol=1e-12)
    # Box surface point and sphere surface point are dist * normal apart; point is midway.
    surface_b = np.asarray(center) + 0.2 * np.asarray(normal)
    np.testing.assert_allclose(contacts.point[0], surface_b + 0.5 * dist * np.asarray(normal), atol=1e-12)


def test_box_sphere_center_at_box_center_pushes_through_smallest_face():
    half = (np.array([0.5, 0.3, 0.4]),)
    contacts = JITTED["box_sphere"](half, (0.1,), pose([1.0, 2.0, 3.0]), pose([1.0, 2.0, 3.0]))
    assert_contract(contacts, 1)
    np.testing.assert_allclose(contacts.dist[0], -0.4, atol=1e-12)
    np.testing.assert_allclose(np.abs(contacts.normal[0]), [0.0, 1.0, 0.0], atol=1e-12)


def test_box_sphere_matches_reference_sdf_on_rotated_box():
    rng = np.random.default_rng(1)
    half = np.array([0.4, 0.25, 0.6])
    for _ in range(10):
        rotation, origin = random_rotation(rng), rng.normal(size=3)
        center = origin + rng.normal(scale=0.6, size=3)
        contacts = JITTED["box_sphere"]((half,), (0.15,), pose(origin, rotation), pose(center))
        local = rotation.T @ (center - origin)
        np.testing.assert_allclose(contacts.dist[0], ref_sdf(half, local) - 0.15, atol=1e-12)


# --------------------------------------------------------------------------- #
# box-capsule
# --------------------------------------------------------------------------- #


def capsule_pose(center, direction):
    """Capsule pose whose shape z axis is ``direction``."""
    direction = np.asarray(direction, float) / np.linalg.norm(direction)
    axis = np.cross([0.0, 0.0, 1.0], direction)
    angle = np.arctan2(np.linalg.norm(axis), direction[2])
    rotation = rot_about(axis if np.linalg.norm(axis) > 0 else [1.0, 0.0, 0.0], angle)
    return pose(center, rotation)


@pytest.mark.parametrize("center_x, half_length, ends", [
    (0.0, 0.3, (-0.3, 0.3)),       # on the face: the segment ends
    (0.0, 1.0, (-0.5, 0.5)),       # overhanging both sides: clipped at the face edges
    (0.2, 0.6, (-0.4, 0.5)),       # overhanging one side
])
def test_box_capsule_lying_flat_gives_two_clipped_ends(center_x, half_length, ends):
    radius, depth = 0.1, 0.02
    contacts = JITTED["box_capsule"](CUBE, (radius, half_length), pose(np.zeros(3)),
                                     pose([center_x, 0.1, 0.5 + radius - depth], ALONG_X))
    assert_contract(contacts, 2)
    assert bool(contacts.valid.all())
    expected = [[-depth, x, 0.1, 0.5 - 0.5 * depth] for x in ends]
    np.testing.assert_allclose(valid_rows(contacts), sorted_rows(expected), atol=1e-12)
    np.testing.assert_allclose(contacts.normal, [[0.0, 0.0, -1.0]] * 2, atol=1e-12)


def test_box_capsule_tilted_reports_low_end():
    radius, half_length = 0.1, 0.4
    direction = np.array([np.cos(0.3), 0.0, np.sin(0.3)])
    low_end = np.array([0.1, 0.0, 0.5 + radius - 0.03])
    contacts = JITTED["box_capsule"](CUBE, (radius, half_length), pose(np.zeros(3)),
                                     capsule_pose(low_end + half_length * direction, direction))
    assert_contract(contacts, 2)
    i = deepest(contacts)
    np.testing.assert_allclose(contacts.dist[i], -0.03, atol=1e-12)
    np.testing.assert_allclose(contacts.point[i], low_end - [0.0, 0.0, radius - 0.015], atol=1e-12)
    # The other slot: where the segment leaves the top face's column (x = 0.5).
    clipped_end = low_end + (0.5 - low_end[0]) / direction[0] * direction
    other = 1 - i
    assert bool(contacts.valid[other])
    np.testing.assert_allclose(contacts.dist[other], clipped_end[2] - radius - 0.5, atol=1e-12)
    np.testing.assert_allclose(contacts.normal[other], [0.0, 0.0, -1.0], atol=1e-12)


def test_box_capsule_across_an_edge():
    # Box edge along y at x = z = 0.5; the capsule's axis is perpendicular to the
    # edge and to the edge's diagonal, its centre at distance gap from the edge.
    radius, gap = 0.1, 0.07
    diagonal = np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0)
    center = np.array([0.5, 0.2, 0.5]) + gap * diagonal
    contacts = JITTED["box_capsule"](CUBE, (radius, 0.5), pose(np.zeros(3)),
                                     capsule_pose(center, [1.0, 0.0, -1.0]))
    assert_contract(contacts, 2)
    i = deepest(contacts)
    np.testing.assert_allclose(contacts.dist[i], gap - radius, atol=1e-12)
    np.testing.assert_allclose(contacts.normal[i], -diagonal, atol=1e-12)


def reference_segment_box(half, center, direction, half_length, radius):
    """Minimum over the segment of the box's signed distance minus radius (ternary search)."""
    f = lambda t: ref_sdf(half, center + t * direction)  # noqa: E731 (convex in t)
    lo, hi = -half_length, half_length
    for _ in range(200):
        m1, m2 = lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0
        if f(m1) <= f(m2):
            hi = m2
        else:
            lo = m1
    return min(f(0.5 * (lo + hi)), f(-half_length), f(half_length)) - radius


def test_box_capsule_deepest_matches_reference_on_random_poses():
    rng = np.random.default_rng(2)
    half = np.array([0.5, 0.3, 0.2])
    for _ in range(40):
        rotation, origin = random_rotation(rng), rng.normal(size=3)
        cap_rotation = random_rotation(rng)
        cap_center = origin + rng.normal(scale=0.5, size=3)
        radius, half_length = 0.1, 0.4
        contacts = JITTED["box_capsule"]((half,), (radius, half_length), pose(origin, rotation),
                                         pose(cap_center, cap_rotation))
        assert_contract(contacts, 2)
        local_c = rotation.T @ (cap_center - origin)
        local_w = rotation.T @ cap_rotation[:, 2]
        ref = reference_segment_box(half, local_c, local_w, half_length, radius)
        np.testing.assert_allclose(contacts.dist[deepest(contacts)], ref, atol=1e-10)


def test_box_capsule_zero_length_is_a_sphere():
    center = pose([0.3, 0.9, 0.2], rot_about([1, 2, 3], 0.7))
    contacts = JITTED["box_capsule"](CUBE, (0.2, 0.0), pose(np.zeros(3)), center)
    sphere = JITTED["box_sphere"](CUBE, (0.2,), pose(np.zeros(3)), center)
    assert np.asarray(contacts.valid).tolist() == [True, False]
    np.testing.assert_allclose(contacts.dist[0], sphere.dist[0], atol=1e-12)
    np.testing.assert_allclose(contacts.point[0], sphere.point[0], atol=1e-12)


# --------------------------------------------------------------------------- #
# points-box
# --------------------------------------------------------------------------- #


def test_points_box_closed_forms():
    points = (np.array([[0.0, 0.0, 0.6], [0.1, 0.2, 0.3], [0.6, 0.6, 0.6], [0.5, 0.1, -0.2]]),)
    contacts = JITTED["points_box"](points, CUBE, pose(np.zeros(3)), pose(np.zeros(3)))
    assert_contract(contacts, 4)
    assert bool(contacts.valid.all())
    np.testing.assert_allclose(contacts.dist, [0.1, -0.2, np.sqrt(3) * 0.1, 0.0], atol=1e-12)
    np.testing.assert_allclose(contacts.normal[:3], [[0, 0, 1], [0, 0, 1], [1 / np.sqrt(3)] * 3],
                               atol=1e-12)
    np.testing.assert_allclose(contacts.normal[3], [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(contacts.point, [[0, 0, 0.55], [0.1, 0.2, 0.4], [0.55] * 3,
                                                [0.5, 0.1, -0.2]], atol=1e-12)


def test_points_box_matches_reference_in_both_frames():
    rng = np.random.default_rng(3)
    half = np.array([0.4, 0.7, 0.3])
    for _ in range(5):
        rot_a, rot_b = random_rotation(rng), random_rotation(rng)
        origin_a, origin_b = rng.normal(scale=0.3, size=3), rng.normal(scale=0.3, size=3)
        contacts = JITTED["points_box"](POINTS, (half,), pose(origin_a, rot_a), pose(origin_b, rot_b))
        world = origin_a + POINTS[0] @ rot_a.T
        local = (world - origin_b) @ rot_b
        np.testing.assert_allclose(contacts.dist, ref_sdf(half, local), atol=1e-12)
        # A's point is dist * normal away from the box surface, point midway.
        surface = np.asarray(contacts.point) - 0.5 * np.asarray(contacts.dist)[:, None] * contacts.normal
        np.testing.assert_allclose(ref_sdf(half, (surface - origin_b) @ rot_b), 0.0, atol=1e-12)


# --------------------------------------------------------------------------- #
# Conventions shared by all kernels
# --------------------------------------------------------------------------- #


def random_case(name, rng):
    """A random, mostly penetrating configuration of one kernel."""
    rot_a, rot_b = random_rotation(rng), random_rotation(rng)
    origin_a = rng.normal(scale=0.1, size=3)
    origin_b = origin_a + rng.normal(size=3) * 0.45
    geoms = {"box_box": ((np.array([0.5, 0.3, 0.4]),), (np.array([0.3, 0.6, 0.2]),)),
             "box_sphere": (CUBE, (0.3,)),
             "box_capsule": ((np.array([0.4, 0.3, 0.5]),), (0.15, 0.4)),
             "points_box": (POINTS, (np.array([0.5, 0.4, 0.3]),))}
    return (*geoms[name], pose(origin_a, rot_a), pose(origin_b, rot_b))


@pytest.mark.parametrize("name", list(KERNELS))
def test_moving_a_along_normal_increases_dist(name):
    rng = np.random.default_rng(4)
    eps = 1e-6
    for _ in range(10):
        geom_a, geom_b, (origin_a, rot_a), pose_b = random_case(name, rng)
        contacts = JITTED[name](geom_a, geom_b, (origin_a, rot_a), pose_b)
        i = deepest(contacts)
        moved = JITTED[name](geom_a, geom_b, (origin_a + eps * contacts.normal[i], rot_a), pose_b)
        increase = float(moved.dist[i] - contacts.dist[i])
        # eps exactly on a smooth feature; less (never more) at a kink of the
        # signed distance, e.g. a capsule segment deep inside at a face-switch.
        assert 0.5 * eps < increase <= eps * (1.0 + 1e-6), increase


@pytest.mark.parametrize("name", list(KERNELS))
def test_vmap_matches_loop(name):
    rng = np.random.default_rng(5)
    cases = [random_case(name, rng) for _ in range(16)]
    batched = jax.tree_util.tree_map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *cases)
    result = jax.jit(jax.vmap(KERNELS[name]))(*batched)
    for b, case in enumerate(cases):
        single = JITTED[name](*case)
        assert np.array_equal(result.valid[b], single.valid)
        valid = np.asarray(single.valid)
        for field in ("dist", "normal", "point"):
            np.testing.assert_allclose(np.asarray(getattr(result, field)[b])[valid],
                                       np.asarray(getattr(single, field))[valid], atol=1e-12)


# --------------------------------------------------------------------------- #
# Gradients
# --------------------------------------------------------------------------- #


@functools.cache
def posed(name):
    """Kernel ``name`` as a function of (geom_a, geom_b, origin_a, rotvec_a, origin_b,
    rotvec_b), vmapped over a batch of configurations and jitted: one compiled
    forward, jvp and vjp per kernel, shared by the gradient tests below.

    Returns the dist, normal and point of the valid slots (zero elsewhere) and
    the valid mask as floats (a locally constant output, checked to have zero
    derivative).
    """
    kernel = KERNELS[name]

    def fn(geom_a, geom_b, origin_a, rotvec_a, origin_b, rotvec_b):
        c = kernel(geom_a, geom_b, (origin_a, rotation_of(rotvec_a)), (origin_b, rotation_of(rotvec_b)))
        mask = c.valid[:, None]
        return (jnp.where(c.valid, c.dist, 0.0), jnp.where(mask, c.normal, 0.0),
                jnp.where(mask, c.point, 0.0), c.valid.astype(jnp.float64))
    return jax.jit(jax.vmap(fn))


def config(geom_a, geom_b, *vectors):
    """(geom_a, geom_b, origin_a, rotvec_a, origin_b, rotvec_b) with float64 numpy leaves."""
    as_geom = lambda geom: tuple(np.asarray(x, dtype=np.float64) for x in geom)  # noqa: E731
    return (as_geom(geom_a), as_geom(geom_b), *(np.asarray(v, dtype=np.float64) for v in vectors))


BATCH = 3   # configurations per gradient test (padded by repetition), so compiles are shared


def stacked(configs):
    configs = [config(*c) for c in configs]
    configs += [configs[-1]] * (BATCH - len(configs))
    return jax.tree_util.tree_map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *configs)


# Configurations away from feature switches, as
# (geom_a, geom_b, origin_a, rotvec_a, origin_b, rotvec_b), with the number of
# valid slots each must give (so they exercise what they claim to).
GENERIC = {
    "box_box": [
        # A long box tilted across a wider one: the incident face is cut by the
        # reference face's sides (clipping active, 6 points).
        (((0.6, 0.3, 0.2),), ((0.4, 0.5, 0.3),), (0.05, 0.1, 0.48), (0.04, -0.07, 0.5),
         (0.0, 0.0, 0.0), (0.01, 0.02, -0.1)),
        # Crossed edges, perturbed: one edge-edge contact.
        (CUBE, CUBE, (0.1, -0.05, np.sqrt(2.0) - 0.03), (np.pi / 4 + 0.02, 0.01, 0.03),
         (0.0, 0.02, 0.0), (0.0, np.pi / 4 - 0.03, 0.02)),
        # Separated boxes (speculative face manifold).
        (((0.3, 0.4, 0.2),), CUBE, (0.1, 0.05, 0.8), (0.1, 0.05, 0.2), (0.0, 0.0, 0.0), (0.0, 0.0, 0.1)),
    ],
    "box_sphere": [
        (CUBE, (0.2,), (0.1, 0.0, 0.0), (0.1, 0.2, 0.3), (0.7, 0.3, 0.75), (0.0, 0.0, 0.0)),   # edge region
        (CUBE, (0.2,), (0.1, 0.0, 0.0), (0.1, 0.2, 0.3), (0.15, 0.1, 0.35), (0.0, 0.0, 0.0)),  # inside
        (CUBE, (0.2,), (0.1, 0.0, 0.0), (0.1, 0.2, 0.3), (0.9, 0.8, 0.9), (0.0, 0.0, 0.0)),    # corner
    ],
    "box_capsule": [
        # Tilted over a face, overhanging (a clipped end).
        (CUBE, (0.1, 0.6), (0.0, 0.0, 0.0), (0.02, -0.03, 0.1), (0.3, 0.1, 0.57), (0.1, 1.5, 0.2)),
        # Across an edge.
        (CUBE, (0.1, 0.5), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.55, 0.2, 0.56), (0.1, -0.75, 0.2)),
        # Segment partly inside the box.
        (CUBE, (0.1, 0.5), (0.0, 0.0, 0.0), (0.1, 0.2, 0.0), (0.3, 0.1, 0.45), (0.3, 0.9, 0.1)),
    ],
    "points_box": [
        (POINTS, ((0.5, 0.4, 0.35),), (0.05, 0.02, 0.0), (0.1, -0.2, 0.3), (0.0, 0.1, 0.0), (0.2, 0.1, -0.1)),
    ],
}
GENERIC_VALID = {"box_box": [6, 1, 4], "box_sphere": [1, 1, 1], "box_capsule": [2, 2, 2],
                 "points_box": [4, 4, 4]}


@pytest.mark.parametrize("name", list(GENERIC))
def test_check_grads_at_generic_configurations(name):
    args = stacked(GENERIC[name])
    valid = np.asarray(posed(name)(*args)[3])
    assert valid.sum(axis=1).tolist() == GENERIC_VALID[name]
    check_grads(posed(name), args, order=1, modes=("fwd", "rev"), eps=1e-6)


# Degenerate configurations, same layout as GENERIC (rotations as rotation vectors).
DEGENERATE = {
    "box_box": [
        (CUBE, CUBE, (0.0, 0.0, 1.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),    # aligned faces,
        # all corners coincident; then coincident centres; then both yawed alike
        # (rounding puts corners a hair off the side planes).
        (CUBE, CUBE, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
        (CUBE, CUBE, (0.0, 0.0, 0.95), (0.0, 0.0, 0.3), (0.0, 0.0, 0.0), (0.0, 0.0, 0.3)),
    ],
    "box_sphere": [
        (CUBE, (0.2,), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),  # box centre
        (CUBE, (0.2,), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.5, 0.5, 0.5), (0.0, 0.0, 0.0)),  # on a corner
        (CUBE, (0.2,), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.5, 0.1, 0.0), (0.0, 0.0, 0.0)),  # on a face
    ],
    "box_capsule": [
        (CUBE, (0.1, 0.3), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.55), (0.0, np.pi / 2, 0.0)),
        # ^ parallel to a face; then through the box centre along z; then the
        # segment lying on an edge line.
        (CUBE, (0.1, 0.3), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
        (CUBE, (0.1, 0.8), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.5, 0.0, 0.5), (np.pi / 2, 0.0, 0.0)),
    ],
    "points_box": [
        # Points on faces, on a corner, at the centre.
        (POINTS_ON_SURFACE, ((0.5, 0.5, 0.5),), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0),
         (0.0, 0.0, 0.0)),
    ],
}


@pytest.mark.parametrize("name", list(DEGENERATE))
def test_gradients_finite_at_degenerate_configurations(name):
    # The gradient of the sum of dist, normal and point components of the
    # valid slots, with respect to geometry and poses, for each configuration.
    args = stacked(DEGENERATE[name])
    outputs, vjp = jax.vjp(posed(name), *args)
    assert np.asarray(outputs[3]).sum(axis=1).min() >= 1
    grads = vjp(tuple(jnp.ones_like(out) for out in outputs))
    for leaf in jax.tree_util.tree_leaves(grads):
        assert np.all(np.isfinite(np.asarray(leaf)))
    # The gradient with respect to A's origin is informative, not silently zero.
    assert np.all(np.any(np.asarray(grads[2]) != 0.0, axis=1))


def lattice_batches(name, rng, batches=6):
    """Batches of BATCH configurations built to hit feature switches exactly:
    equal cubes (or cube-sized shapes), rotations by multiples of 90 degrees
    (sometimes off by 1e-13), positions on a lattice of half extents."""
    quarter = [np.zeros(3)] + [s * np.pi / 2 * np.eye(3)[k] for k in range(3) for s in (-1.0, 1.0, 2.0)]
    geoms = {"box_box": (CUBE, CUBE), "box_sphere": (CUBE, (0.5,)), "box_capsule": (CUBE, (0.25, 0.5)),
             "points_box": (POINTS_ON_SURFACE, CUBE)}
    for _ in range(batches):
        configs = []
        for _ in range(BATCH):
            rotvecs = [quarter[rng.integers(len(quarter))] + rng.choice([0.0, 1e-13]) * rng.normal(size=3)
                       for _ in range(2)]
            origins = [0.5 * rng.integers(-2, 3, size=3), np.zeros(3)]
            configs.append((*geoms[name], origins[0], rotvecs[0], origins[1], rotvecs[1]))
        yield stacked(configs)


@pytest.mark.parametrize("name", list(KERNELS))
def test_finite_values_and_gradients_on_aligned_lattice(name):
    rng = np.random.default_rng(6)
    for args in lattice_batches(name, rng):
        outputs, vjp = jax.vjp(posed(name), *args)
        assert np.asarray(outputs[3]).sum(axis=1).min() >= 1
        normals = np.asarray(outputs[1])[np.asarray(outputs[3]) > 0]
        np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-12)
        grads = vjp(tuple(jnp.ones_like(out) for out in outputs))
        for leaf in jax.tree_util.tree_leaves((outputs, grads)):
            assert np.all(np.isfinite(np.asarray(leaf)))


@pytest.mark.parametrize("name", list(KERNELS))
def test_float32_in_float32_out(name):
    case = jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype=jnp.float32),
                                  random_case(name, np.random.default_rng(7)))
    shapes = jax.eval_shape(KERNELS[name], *case)
    assert shapes.dist.dtype == shapes.normal.dtype == shapes.point.dtype == jnp.float32
    assert shapes.valid.dtype == jnp.bool_


def segment_sdf(center, direction, half_length, radius, x):
    """Signed distance of points x (..., 3) to a capsule, numpy."""
    t = np.clip((x - center) @ direction, -half_length, half_length)
    return np.linalg.norm(x - center - t[..., None] * direction, axis=-1) - radius


@pytest.mark.parametrize("name", ["box_box", "box_sphere", "box_capsule"])
def test_surface_points_lie_on_both_surfaces(name):
    # point +- dist/2 normal must be a point of A's surface and of B's surface.
    rng = np.random.default_rng(8)
    for _ in range(30):
        geom_a, geom_b, (origin_a, rot_a), (origin_b, rot_b) = random_case(name, rng)
        contacts = JITTED[name](geom_a, geom_b, (origin_a, rot_a), (origin_b, rot_b))
        valid = np.asarray(contacts.valid)
        half = np.asarray(contacts.dist)[valid, None] / 2.0 * np.asarray(contacts.normal)[valid]
        on_a = np.asarray(contacts.point)[valid] + half
        on_b = np.asarray(contacts.point)[valid] - half
        oa, ra, ob, rb = (np.asarray(x) for x in (origin_a, rot_a, origin_b, rot_b))
        np.testing.assert_allclose(ref_sdf(geom_a[0], (on_a - oa) @ ra), 0.0, atol=1e-12)
        if name == "box_box":
            sdf_b = ref_sdf(geom_b[0], (on_b - ob) @ rb)
        elif name == "box_sphere":
            sdf_b = np.linalg.norm(on_b - ob, axis=-1) - geom_b[0]
        else:
            # Each slot is the capsule's ball at one segment point against the
            # box: its point is on that ball, so inside or on the capsule; on
            # its surface for the deepest slot (the closest segment point)
            # unless the segment itself enters the box (the deepest point is
            # then a kink of the box's distance, its normal not normal to the axis).
            sdf_b = segment_sdf(ob, rb[:, 2], geom_b[1], geom_b[0], on_b)
            assert np.all(sdf_b <= 1e-12)
            deepest_dist = np.min(np.asarray(contacts.dist)[valid])
            sdf_b = sdf_b[np.argmin(np.asarray(contacts.dist)[valid])] if deepest_dist > -geom_b[0] else 0.0
        np.testing.assert_allclose(sdf_b, 0.0, atol=1e-12)


def test_box_box_slots_stable_under_tiny_shifts():
    """Warm starts follow slots, so a resting cube nudged by 1 µm keeps each corner in its slot."""
    import jax.numpy as jnp
    import numpy as np

    from jaxrb.physics.collision.box import box_box

    half = (jnp.array([0.1, 0.1, 0.1]),)
    rotation = jnp.eye(3)
    base = box_box(half, half, (jnp.array([0.0, 0.0, 0.2]), rotation), (jnp.zeros(3), rotation))
    for dx, dy in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
        shifted = box_box(half, half, (jnp.array([1e-6 * dx, 1e-6 * dy, 0.2]), rotation), (jnp.zeros(3), rotation))
        np.testing.assert_array_equal(np.asarray(shifted.valid), np.asarray(base.valid))
        valid = np.asarray(base.valid)
        assert valid.sum() == 4
        np.testing.assert_allclose(np.asarray(shifted.point)[valid], np.asarray(base.point)[valid], atol=1e-5)
