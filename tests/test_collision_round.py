"""Round-shape narrowphase kernels against closed forms and an independent reference.

float64 throughout (conftest enables x64). The reference for segment-segment
closest points enumerates the candidates of the box-constrained quadratic in
numpy, so it shares no code with the kernel.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxrb.math import quaternion
from jaxrb.physics.collision.contacts import Contacts
from jaxrb.physics.collision.round import PARALLEL_SIN, capsule_capsule, capsule_sphere, sphere_sphere

EYE3 = np.eye(3)
# Rotation taking shape z to world x (a capsule lying along x), and to world y.
ALONG_X = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
ALONG_Y = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

KERNELS = {"sphere_sphere": sphere_sphere, "capsule_sphere": capsule_sphere,
           "capsule_capsule": capsule_capsule}


def as_arrays(tree):
    """Every leaf as a float64 array (float32 leaves stay float32), so each jitted
    function sees one signature and compiles once for the whole file."""
    def convert(x):
        return x if getattr(x, "dtype", None) == jnp.float32 else jnp.asarray(x, dtype=jnp.float64)
    return jax.tree.map(convert, tree)


COMPILED = {name: jax.jit(kernel) for name, kernel in KERNELS.items()}
JITTED = {name: (lambda compiled: lambda *args: compiled(*as_arrays(args)))(compiled)
          for name, compiled in COMPILED.items()}


def _outputs(compiled):
    def fn(pose_a, pose_b, geom_a, geom_b):
        out = compiled(geom_a, geom_b, pose_a, pose_b)
        return out.dist, out.normal, out.point
    return fn


#: (pose_a, pose_b, geom_a, geom_b) -> (dist, normal, point) through the same
#: compiled kernels, so the gradient tests add only the jvp/vjp compilations.
OUTPUTS = {name: _outputs(compiled) for name, compiled in COMPILED.items()}


def pose(origin, rotation=EYE3):
    return jnp.asarray(origin, dtype=jnp.float64), jnp.asarray(rotation, dtype=jnp.float64)


def rot_about(axis, angle):
    quat = quaternion.from_axis_angle(jnp.asarray(axis, float), angle)
    return np.asarray(quaternion.to_rotation_matrix(quat))


def random_rotation(rng):
    q = rng.normal(size=4)
    return np.asarray(quaternion.to_rotation_matrix(jnp.asarray(q / np.linalg.norm(q))))


def random_pose(rng):
    return pose(rng.normal(size=3), random_rotation(rng))


def rotation_of(rotvec):
    return quaternion.to_rotation_matrix(quaternion.exp(rotvec))


def reference_segments(ca, da, ha, cb, db, hb):
    """Exact closest parameters (s, t) of two segments c + u d, |u| <= h, in numpy."""
    ca, da, cb, db = map(np.asarray, (ca, da, cb, db))
    clip = np.clip
    candidates = []
    for s in (-ha, ha):
        candidates.append((s, clip(db @ (ca + s * da - cb), -hb, hb)))
    for t in (-hb, hb):
        candidates.append((clip(da @ (cb + t * db - ca), -ha, ha), t))
    gram = np.array([[1.0, -(da @ db)], [da @ db, -1.0]])
    if abs(np.linalg.det(gram)) > 1e-12:
        s, t = np.linalg.solve(gram, [-(da @ (ca - cb)), -(db @ (ca - cb))])
        if abs(s) <= ha and abs(t) <= hb:
            candidates.append((s, t))
    gaps = [np.linalg.norm(ca + s * da - cb - t * db) for s, t in candidates]
    s, t = candidates[int(np.argmin(gaps))]
    return ca + s * da, cb + t * db


def assert_contact(contacts, slot, dist, normal, point, atol=1e-12):
    np.testing.assert_allclose(contacts.dist[slot], dist, atol=atol)
    np.testing.assert_allclose(contacts.normal[slot], normal, atol=atol)
    np.testing.assert_allclose(contacts.point[slot], point, atol=atol)


def assert_ball_contact(contacts, slot, core_a, core_b, radius_a, radius_b, atol=1e-9):
    """Slot matches the contact of balls at core_a / core_b (numpy closed form)."""
    delta = np.asarray(core_a) - np.asarray(core_b)
    gap = np.linalg.norm(delta)
    normal = delta / gap
    assert_contact(contacts, slot, gap - radius_a - radius_b, normal,
                   0.5 * ((core_a - radius_a * normal) + (core_b + radius_b * normal)), atol=atol)


def assert_well_formed(contacts, k, dim):
    assert contacts.dist.shape == (k,)
    assert contacts.normal.shape == (k, dim)
    assert contacts.point.shape == (k, dim)
    assert contacts.valid.shape == (k,) and contacts.valid.dtype == jnp.bool_
    for leaf in (contacts.dist, contacts.normal, contacts.point):
        assert np.all(np.isfinite(leaf))
    np.testing.assert_allclose(np.linalg.norm(contacts.normal, axis=-1), 1.0, atol=1e-12)


# ---------------------------------------------------------------- sphere_sphere


@pytest.mark.parametrize("gap", [1.5, 0.0, -0.4])  # separated, touching, penetrating
def test_sphere_sphere_closed_form(gap):
    ra, rb = 1.0, 0.5
    direction = np.array([2.0, -1.0, 2.0]) / 3.0
    cb = np.array([0.3, 0.2, -0.1])
    ca = cb + (ra + rb + gap) * direction
    out = JITTED["sphere_sphere"]((ra,), (rb,), pose(ca), pose(cb, random_rotation(np.random.default_rng(1))))
    assert_well_formed(out, 1, 3)
    assert bool(out.valid[0])
    # A's surface is ca - ra n, B's is cb + rb n; the point is midway.
    assert_contact(out, 0, gap, direction, 0.5 * (ca - ra * direction + cb + rb * direction))


def test_sphere_sphere_2d_circles():
    ra, rb = 0.3, 0.2
    out = JITTED["sphere_sphere"]((ra,), (rb,), pose([0.0, 1.0], np.eye(2)), pose([0.0, 0.0], np.eye(2)))
    assert_well_formed(out, 1, 2)
    assert_contact(out, 0, 0.5, [0.0, 1.0], [0.0, 0.5 * (0.7 + 0.2)])
    out = JITTED["sphere_sphere"]((ra,), (rb,), pose([3.0, 4.0], np.eye(2)), pose([0.0, 0.0], np.eye(2)))
    # A's surface is 0.3 from (3, 4) towards B, B's is (0.12, 0.16).
    assert_contact(out, 0, 4.5, [0.6, 0.8], 0.5 * (np.array([3.0, 4.0]) * (1 - 0.3 / 5) + [0.12, 0.16]))


@pytest.mark.parametrize("dim", [2, 3])
def test_sphere_sphere_coincident_centres_fallback_and_gradients(dim):
    ra, rb = 0.4, 0.1
    centre = jnp.arange(1.0, dim + 1.0)
    out = sphere_sphere((ra,), (rb,), pose(centre, np.eye(dim)), pose(centre, np.eye(dim)))
    assert_well_formed(out, 1, dim)
    up = np.eye(dim)[-1]
    assert_contact(out, 0, -ra - rb, up, centre + 0.5 * (rb - ra) * up)
    assert_finite_grads(sphere_sphere, (ra,), (rb,), pose(centre, np.eye(dim)), pose(centre, np.eye(dim)))


def test_sphere_sphere_swap_symmetry_and_2d_equals_3d_slice():
    rng = np.random.default_rng(2)
    for _ in range(5):
        ca, cb = rng.normal(size=3), rng.normal(size=3)
        ab = JITTED["sphere_sphere"]((0.3,), (0.7,), pose(ca), pose(cb))
        ba = JITTED["sphere_sphere"]((0.7,), (0.3,), pose(cb), pose(ca))
        assert_contact(ba, 0, ab.dist[0], -ab.normal[0], ab.point[0])
        # A 2D pair is the z = 0 slice of the 3D pair.
        flat = JITTED["sphere_sphere"]((0.3,), (0.7,), pose(ca[:2], np.eye(2)), pose(cb[:2], np.eye(2)))
        lifted = JITTED["sphere_sphere"]((0.3,), (0.7,), pose(np.r_[ca[:2], 0.0]), pose(np.r_[cb[:2], 0.0]))
        assert_contact(flat, 0, lifted.dist[0], lifted.normal[0, :2], lifted.point[0, :2])


# --------------------------------------------------------------- capsule_sphere


def test_capsule_sphere_closed_form():
    ra, half, rb = 0.2, 1.0, 0.3
    kernel = JITTED["capsule_sphere"]
    # Beside the segment of a capsule lying along x: closest point (0.5, 0, 0).
    out = kernel((ra, half), (rb,), pose([0.0, 0.0, 0.0], ALONG_X), pose([0.5, 2.0, 0.0]))
    assert_well_formed(out, 1, 3)
    assert_contact(out, 0, 2.0 - ra - rb, [0.0, -1.0, 0.0], [0.5, 0.5 * (0.2 + 1.7), 0.0])
    # Beyond the end: the end cap at (1, 0, 0) is closest.
    out = kernel((ra, half), (rb,), pose([0.0, 0.0, 0.0], ALONG_X), pose([4.0, 4.0, 0.0]))
    assert_ball_contact(out, 0, np.array([1.0, 0.0, 0.0]), np.array([4.0, 4.0, 0.0]), ra, rb)
    np.testing.assert_allclose(out.dist[0], 5.0 - 0.5, atol=1e-12)
    # Penetrating, capsule standing along z, sphere just off its side.
    out = kernel((ra, half), (rb,), pose([1.0, 1.0, 1.0]), pose([1.1, 1.0, 1.7]))
    assert_contact(out, 0, 0.1 - 0.5, [-1.0, 0.0, 0.0], [1.0 + 0.5 * (0.2 + 0.1 - 0.3) , 1.0, 1.7])


def test_capsule_sphere_rotated_matches_reference():
    rng = np.random.default_rng(3)
    for _ in range(8):
        rotation, ca, cb = random_rotation(rng), rng.normal(size=3), 2.0 * rng.normal(size=3)
        ra, half, rb = 0.1 + rng.random(), 0.1 + rng.random(), 0.1 + rng.random()
        out = JITTED["capsule_sphere"]((ra, half), (rb,), pose(ca, rotation), pose(cb, random_rotation(rng)))
        axis = rotation[:, 2]
        core = ca + np.clip(axis @ (cb - ca), -half, half) * axis
        assert_ball_contact(out, 0, core, cb, ra, rb)


def test_capsule_sphere_zero_length_is_sphere_sphere():
    rng = np.random.default_rng(4)
    for _ in range(4):
        pa, pb = random_pose(rng), random_pose(rng)
        capsule = JITTED["capsule_sphere"]((0.3, 0.0), (0.6,), pa, pb)
        sphere = JITTED["sphere_sphere"]((0.3,), (0.6,), pa, pb)
        for leaf_c, leaf_s in zip(jax.tree.leaves(capsule), jax.tree.leaves(sphere)):
            np.testing.assert_allclose(leaf_c, leaf_s, atol=1e-12)


@pytest.mark.parametrize("s", [0.3, 1.0])  # inside the segment, exactly at its end
def test_capsule_sphere_centre_on_axis_fallback_and_gradients(s):
    ra, half, rb = 0.2, 1.0, 0.3
    rotation = rot_about([1.0, 2.0, 0.5], 0.7)
    origin = np.array([0.1, -0.2, 0.3])
    centre = origin + s * rotation[:, 2]
    out = capsule_sphere((ra, half), (rb,), pose(origin, rotation), pose(centre))
    assert_well_formed(out, 1, 3)
    # Documented fallback: the capsule's shape-frame x axis.
    assert_contact(out, 0, -ra - rb, rotation[:, 0], centre + 0.5 * (rb - ra) * rotation[:, 0])
    assert_finite_grads(capsule_sphere, (ra, half), (rb,), pose(origin, rotation), pose(centre))


# -------------------------------------------------------------- capsule_capsule


def test_capsule_capsule_crossing_closed_form():
    ra, rb = 0.2, 0.3
    # A along x at the origin, B along y one unit above: touch at the origin's column.
    out = JITTED["capsule_capsule"]((ra, 1.0), (rb, 1.0), pose([0.0, 0.0, 0.0], ALONG_X),
                                    pose([0.0, 0.0, 1.0], ALONG_Y))
    assert_well_formed(out, 2, 3)
    assert out.valid.tolist() == [True, False]
    assert_contact(out, 0, 1.0 - ra - rb, [0.0, 0.0, -1.0], [0.0, 0.0, 0.5 * (0.2 + 0.7)])
    # B shifted so both segments are clamped: A's end (1, 0, 0) against B's end (2, 0, 1)
    # (B spans y in [0, 1] at x = 2... its closest point is its lower end).
    out = JITTED["capsule_capsule"]((ra, 1.0), (rb, 0.5), pose([0.0, 0.0, 0.0], ALONG_X),
                                    pose([2.0, 0.5, 1.0], ALONG_Y))
    assert_ball_contact(out, 0, np.array([1.0, 0.0, 0.0]), np.array([2.0, 0.0, 1.0]), ra, rb)
    assert out.valid.tolist() == [True, False]
    # Penetrating crossing.
    out = JITTED["capsule_capsule"]((ra, 1.0), (rb, 1.0), pose([0.0, 0.0, 0.3], ALONG_X),
                                    pose([0.0, 0.0, 0.0], ALONG_Y))
    assert_contact(out, 0, 0.3 - 0.5, [0.0, 0.0, 1.0], [0.0, 0.0, 0.5 * (0.1 + 0.3)])


def test_capsule_capsule_rotated_matches_reference():
    rng = np.random.default_rng(5)
    for _ in range(12):
        rot_a, rot_b = random_rotation(rng), random_rotation(rng)
        ca, cb = rng.normal(size=3), rng.normal(size=3)
        ra, ha, rb, hb = 0.1 + 0.5 * rng.random(4)
        out = JITTED["capsule_capsule"]((ra, ha), (rb, hb), pose(ca, rot_a), pose(cb, rot_b))
        assert_well_formed(out, 2, 3)
        core_a, core_b = reference_segments(ca, rot_a[:, 2], ha, cb, rot_b[:, 2], hb)
        assert_ball_contact(out, 0, core_a, core_b, ra, rb)


@pytest.mark.parametrize("flip_b", [False, True])  # parallel and anti-parallel axes
def test_capsule_capsule_parallel_two_contacts_span_overlap(flip_b):
    ra, rb = 0.4, 0.3
    rot_b = ALONG_X @ np.diag([-1.0, 1.0, -1.0]) if flip_b else ALONG_X
    # B (x in [-0.5, 1.5]) lies on A (x in [-1, 1]): overlap x in [-0.5, 1].
    out = JITTED["capsule_capsule"]((ra, 1.0), (rb, 1.0), pose([0.0, 0.0, 0.0], ALONG_X),
                                    pose([0.5, 0.0, 1.0], rot_b))
    assert_well_formed(out, 2, 3)
    assert out.valid.tolist() == [True, True]
    np.testing.assert_allclose(out.dist, [0.3, 0.3], atol=1e-12)
    np.testing.assert_allclose(out.normal, [[0.0, 0.0, -1.0]] * 2, atol=1e-12)
    z_mid = 0.5 * (ra + 1.0 - rb)
    np.testing.assert_allclose(sorted(np.asarray(out.point[:, 0])), [-0.5, 1.0], atol=1e-12)
    np.testing.assert_allclose(out.point[:, 1:], [[0.0, z_mid]] * 2, atol=1e-12)


def test_capsule_capsule_parallel_short_b_inside_and_disjoint():
    kernel = JITTED["capsule_capsule"]
    # Short B over the middle of A: contacts at B's two ends.
    out = kernel((0.1, 2.0), (0.1, 0.5), pose([0.0, 0.0, 0.0], ALONG_Y), pose([0.0, 0.2, -0.5], ALONG_Y))
    assert out.valid.tolist() == [True, True]
    np.testing.assert_allclose(sorted(np.asarray(out.point[:, 1])), [-0.3, 0.7], atol=1e-12)
    np.testing.assert_allclose(out.dist, [0.3, 0.3], atol=1e-12)
    np.testing.assert_allclose(out.normal, [[0.0, 0.0, 1.0]] * 2, atol=1e-12)
    # Collinear, end to end with a gap of 1: one contact between the facing ends.
    out = kernel((0.1, 1.0), (0.2, 1.0), pose([0.0, 0.0, 0.0]), pose([0.0, 0.0, 3.0]))
    assert out.valid.tolist() == [True, False]
    assert_contact(out, 0, 1.0 - 0.3, [0.0, 0.0, -1.0], [0.0, 0.0, 0.5 * (1.1 + 1.8)])


def test_capsule_capsule_nearly_parallel_and_crossing_thresholds():
    kernel = JITTED["capsule_capsule"]
    ra, rb = 0.2, 0.2
    for angle, expect_second in [(1e-3, True), (0.05, True), (0.3, False), (np.pi / 2, False)]:
        # B tilted about the vertical through a point off A's centre, one unit above A.
        rot_b = rot_about([0.0, 0.0, 1.0], angle) @ ALONG_X
        out = kernel((ra, 1.0), (rb, 1.0), pose([0.0, 0.0, 0.0], ALONG_X), pose([0.3, 0.0, 0.5], rot_b))
        assert_well_formed(out, 2, 3)
        assert out.valid.tolist() == [True, expect_second], angle
        core_a, core_b = reference_segments(np.zeros(3), ALONG_X[:, 2], 1.0, np.array([0.3, 0.0, 0.5]),
                                            rot_b[:, 2], 1.0)
        assert_ball_contact(out, 0, core_a, core_b, ra, rb)
        # Slot 1 is a real surface pair, never closer than the closest points.
        assert float(out.dist[1]) >= float(out.dist[0]) - 1e-12
    assert np.sin(0.05) < PARALLEL_SIN < np.sin(0.3)


def test_capsule_capsule_tilted_lying_capsule_spans_overlap():
    # B slightly pitched (about y) above A: skew lines whose closest points are an
    # overlap end; slot 1 is the other end and both are exact surface pairs.
    rot_b = rot_about([0.0, 1.0, 0.0], 0.02) @ ALONG_X
    cb = np.array([0.2, 0.0, 0.45])
    out = JITTED["capsule_capsule"]((0.2, 1.0), (0.2, 1.0), pose(np.zeros(3), ALONG_X), pose(cb, rot_b))
    assert out.valid.tolist() == [True, True]
    ends = sorted(np.asarray(out.point[:, 0]))
    assert ends[0] < -0.5 and ends[1] > 0.9  # spans the overlap [-0.78, 1] roughly
    core_a, core_b = reference_segments(np.zeros(3), ALONG_X[:, 2], 1.0, cb, rot_b[:, 2], 1.0)
    assert_ball_contact(out, 0, core_a, core_b, 0.2, 0.2)
    for slot in range(2):
        # A's core point is half the gap plus A's radius from the point along +normal
        # (on A's axis, the x axis); its closest point on B's segment reproduces dist.
        core = np.asarray(out.point[slot] + (out.dist[slot] / 2 + 0.2) * out.normal[slot])
        assert abs(core[1]) < 1e-12 and abs(core[2]) < 1e-12
        t = np.clip(rot_b[:, 2] @ (core - cb), -1.0, 1.0)
        np.testing.assert_allclose(np.linalg.norm(core - cb - t * rot_b[:, 2]) - 0.4, out.dist[slot],
                                   atol=1e-12)


def test_capsule_capsule_swap_symmetry():
    rng = np.random.default_rng(6)
    for _ in range(8):
        pa, pb = random_pose(rng), random_pose(rng)
        ab = JITTED["capsule_capsule"]((0.3, 0.8), (0.2, 0.5), pa, pb)
        ba = JITTED["capsule_capsule"]((0.2, 0.5), (0.3, 0.8), pb, pa)
        assert_contact(ba, 0, ab.dist[0], -ab.normal[0], ab.point[0], atol=1e-10)
    # Exactly crossing segments: the fallback axis_a x axis_b also flips.
    pa, pb = pose(np.zeros(3), ALONG_X), pose(np.zeros(3), ALONG_Y)
    ab = JITTED["capsule_capsule"]((0.3, 0.8), (0.2, 0.5), pa, pb)
    ba = JITTED["capsule_capsule"]((0.2, 0.5), (0.3, 0.8), pb, pa)
    assert_contact(ba, 0, ab.dist[0], -ab.normal[0], ab.point[0])
    # Parallel: the same two contacts, in some order, with opposite normals.
    pa, pb = pose(np.zeros(3), ALONG_X), pose([0.5, 0.0, 1.0], ALONG_X)
    ab = JITTED["capsule_capsule"]((0.3, 1.0), (0.2, 1.0), pa, pb)
    ba = JITTED["capsule_capsule"]((0.2, 1.0), (0.3, 1.0), pb, pa)
    assert ab.valid.tolist() == ba.valid.tolist() == [True, True]
    order = np.argsort(np.asarray(ab.point[:, 0])), np.argsort(np.asarray(ba.point[:, 0]))
    np.testing.assert_allclose(ab.point[order[0]], ba.point[order[1]], atol=1e-12)
    np.testing.assert_allclose(ab.normal, -ba.normal, atol=1e-12)
    np.testing.assert_allclose(ab.dist, ba.dist, atol=1e-12)


def test_capsule_capsule_zero_length_b_is_capsule_sphere():
    rng = np.random.default_rng(7)
    for _ in range(4):
        pa, pb = random_pose(rng), random_pose(rng)
        pair = JITTED["capsule_capsule"]((0.3, 0.8), (0.4, 0.0), pa, pb)
        ball = JITTED["capsule_sphere"]((0.3, 0.8), (0.4,), pa, pb)
        assert_contact(pair, 0, ball.dist[0], ball.normal[0], ball.point[0], atol=1e-12)


# ------------------------------------------------- conventions shared by kernels


def random_case(name, rng, parallel=False):
    """(geom_a, geom_b, pose_a, pose_b) for a kernel, with random sizes and poses."""
    rot_a = random_rotation(rng)
    rot_b = rot_a if parallel else random_rotation(rng)
    pa = (jnp.asarray(rng.normal(size=3)), jnp.asarray(rot_a))
    pb = (jnp.asarray(rng.normal(size=3)), jnp.asarray(rot_b))
    sizes = jnp.asarray(0.1 + 0.5 * rng.random(4))
    geom = {"sphere_sphere": ((sizes[0],), (sizes[2],)),
            "capsule_sphere": ((sizes[0], sizes[1]), (sizes[2],)),
            "capsule_capsule": ((sizes[0], sizes[1]), (sizes[2], sizes[3]))}[name]
    return geom + (pa, pb)


@pytest.mark.parametrize("name", sorted(KERNELS))
def test_moving_a_along_normal_increases_dist(name):
    kernel, rng, step = JITTED[name], np.random.default_rng(8), 1e-6
    for trial in range(6):
        geom_a, geom_b, (origin_a, rot_a), pose_b = random_case(name, rng, parallel=trial % 2 == 1)
        out = kernel(geom_a, geom_b, (origin_a, rot_a), pose_b)
        for slot in np.flatnonzero(np.asarray(out.valid)):
            normal = out.normal[slot]
            plus = kernel(geom_a, geom_b, (origin_a + step * normal, rot_a), pose_b).dist[slot]
            minus = kernel(geom_a, geom_b, (origin_a - step * normal, rot_a), pose_b).dist[slot]
            rate = float(plus - minus) / (2 * step)
            # The closest-point slot separates at rate 1; slot 1 separates too.
            if slot == 0:
                assert abs(rate - 1.0) < 1e-6, (name, rate)
            else:
                assert rate > 0.5, (name, rate)


@pytest.mark.parametrize("name", sorted(KERNELS))
def test_vmap_over_random_pairs_equals_loop(name):
    rng = np.random.default_rng(9)
    cases = [random_case(name, rng, parallel=i % 3 == 0) for i in range(12)]
    batched = jax.tree.map(lambda *xs: jnp.stack(xs), *cases)
    out = jax.jit(jax.vmap(KERNELS[name]))(*batched)
    k = {"capsule_capsule": 2}.get(name, 1)
    assert out.dist.shape == (12, k) and out.normal.shape == (12, k, 3) and out.valid.shape == (12, k)
    for i, case in enumerate(cases):
        single = JITTED[name](*case)
        for leaf_b, leaf_s in zip(jax.tree.leaves(out), jax.tree.leaves(single)):
            np.testing.assert_allclose(leaf_b[i], leaf_s, rtol=1e-12, atol=1e-12)
    if name == "capsule_capsule":
        parallel = np.arange(12) % 3 == 0
        assert np.asarray(out.valid[parallel, 1]).any()  # some parallel pairs overlap
        assert not np.asarray(out.valid[~parallel, 1]).any()  # random axes are not parallel


GRAD_CASES = {  # (geom_a, geom_b, origin_a, rotvec_a, origin_b, rotvec_b)
    "sphere_sphere": [((0.3,), (0.5,), [0.1, 0.2, 0.3], [0.3, -0.2, 0.1], [1.0, 0.4, -0.3], [0.2, 0.1, 0.5])],
    "capsule_sphere": [
        ((0.3, 0.7), (0.5,), [0.1, 0.2, 0.3], [0.3, -0.2, 0.1], [1.0, 0.4, -0.3], [0.0, 0.0, 0.0]),
        ((0.3, 0.7), (0.5,), [0.1, 0.2, 0.3], [0.3, -0.2, 0.1], [0.9, 1.4, 1.3], [0.0, 0.0, 0.0]),
    ],
    "capsule_capsule": [
        ((0.3, 0.7), (0.2, 0.6), [0.1, 0.2, 0.3], [0.3, -0.2, 0.1], [0.6, 0.4, -0.3], [1.2, 0.1, 0.5]),
        ((0.3, 0.7), (0.2, 0.6), [0.1, 0.2, 0.3], [0.3, -0.2, 0.1], [1.3, 0.9, 1.1], [-0.9, 0.7, 0.2]),
        # nearly parallel, overlapping: both slots valid
        ((0.3, 0.7), (0.2, 0.6), [0.1, 0.2, 0.3], [0.3, -0.2, 0.1], [0.4, 0.9, 0.3], [0.32, -0.19, 0.12]),
    ],
}


@pytest.mark.parametrize("name", sorted(GRAD_CASES))
def test_check_grads_generic(name):
    """AD against finite differences wrt both poses (origins and rotation matrix
    entries) and the sizes, on generic configurations of every kernel."""
    for geom_a, geom_b, origin_a, rotvec_a, origin_b, rotvec_b in GRAD_CASES[name]:
        pose_a = pose(origin_a, rotation_of(jnp.asarray(rotvec_a)))
        pose_b = pose(origin_b, rotation_of(jnp.asarray(rotvec_b)))
        args = as_arrays((pose_a, pose_b, geom_a, geom_b))
        if name == "capsule_capsule" and rotvec_b[0] == 0.32:  # exercises slot 1
            assert JITTED[name](geom_a, geom_b, pose_a, pose_b).valid.tolist() == [True, True]
        check_grads(OUTPUTS[name], args, order=1, modes=["fwd", "rev"], eps=1e-6)


def assert_finite_grads(kernel, geom_a, geom_b, pose_a, pose_b):
    """Gradient of sum(dist + normal + point) wrt both poses and all sizes is finite
    (taken as the vjp of the jitted outputs with a cotangent of ones)."""
    args = as_arrays((pose_a, pose_b, geom_a, geom_b))
    outputs, pullback = jax.vjp(OUTPUTS[kernel.__name__], *args)
    grads = pullback(jax.tree.map(jnp.ones_like, outputs))
    leaves = jax.tree.leaves(grads)
    assert len(leaves) == 4 + len(geom_a) + len(geom_b)
    assert all(np.all(np.isfinite(leaf)) for leaf in leaves)
    # The rotation matrix of A gets a gradient (chain rule to any rotation
    # parametrisation is then a product of finite factors).
    assert np.any(np.asarray(grads[0][1]) != 0.0) or kernel is sphere_sphere
    return grads


@pytest.mark.parametrize("case", ["parallel", "antiparallel", "coincident", "crossing_centres",
                                  "collinear_touching"])
def test_capsule_capsule_degenerate_finite(case):
    geom_a, geom_b = (0.3, 1.0), (0.2, 0.5)
    rot = rot_about([1.0, -0.5, 0.3], 0.9)
    flip = rot @ np.diag([1.0, -1.0, -1.0])
    origin = np.array([0.2, -0.1, 0.4])
    dyadic = np.array([0.25, -0.125, 0.5])  # so the collinear end points coincide exactly
    pose_a, pose_b = {
        "parallel": (pose(origin, rot), pose(origin + rot[:, 0] + 0.3 * rot[:, 2], rot)),
        "antiparallel": (pose(origin, rot), pose(origin + 0.4 * rot[:, 1], flip)),
        "coincident": (pose(origin, rot), pose(origin, rot)),
        "crossing_centres": (pose(origin, rot), pose(origin, rot @ ALONG_Y)),
        "collinear_touching": (pose(dyadic), pose(dyadic + [0.0, 0.0, 1.5])),
    }[case]
    if case == "collinear_touching":
        rot = EYE3
    out = capsule_capsule(geom_a, geom_b, pose_a, pose_b)
    assert_well_formed(out, 2, 3)
    assert_finite_grads(capsule_capsule, geom_a, geom_b, pose_a, pose_b)
    expected_dist = {"parallel": 1.0, "antiparallel": 0.4, "coincident": 0.0, "crossing_centres": 0.0,
                     "collinear_touching": 0.0}[case] - 0.5
    np.testing.assert_allclose(out.dist[0], expected_dist, atol=1e-12)
    if case == "crossing_centres":  # fallback: axis_a x axis_b
        axis_b = (rot @ ALONG_Y)[:, 2]
        np.testing.assert_allclose(out.normal[0], np.cross(rot[:, 2], axis_b), atol=1e-12)
        assert out.valid.tolist() == [True, False]
    elif case == "coincident":  # parallel and intersecting: A's shape x axis
        np.testing.assert_allclose(out.normal, [rot[:, 0]] * 2, atol=1e-12)
        assert out.valid.tolist() == [True, True]  # B's ends at s = -0.5 and 0.5
        np.testing.assert_allclose(sorted(np.asarray(out.point @ rot[:, 2] - origin @ rot[:, 2])),
                                   [-0.5, 0.5], atol=1e-12)
    elif case == "collinear_touching":  # end points coincide, axes parallel: A's shape x
        np.testing.assert_allclose(out.normal[0], rot[:, 0], atol=1e-12)
        assert out.valid.tolist() == [True, False]
    else:
        assert out.valid.tolist() == [True, True]
        np.testing.assert_allclose(out.dist[1], out.dist[0], atol=1e-12)


def test_float32_in_float32_out():
    f32 = lambda x: jnp.asarray(x, dtype=jnp.float32)  # noqa: E731
    pa, pb = (f32([0.0, 0.0, 0.0]), f32(ALONG_X)), (f32([0.5, 0.0, 0.55]), f32(ALONG_X))
    out = JITTED["capsule_capsule"]((f32(0.3), f32(1.0)), (f32(0.2), f32(1.0)), pa, pb)
    assert out.dist.dtype == out.normal.dtype == out.point.dtype == jnp.float32
    np.testing.assert_allclose(out.dist, [0.05, 0.05], atol=1e-6)
    assert out.valid.tolist() == [True, True]
    out = JITTED["sphere_sphere"]((f32(0.3),), (f32(0.2),), pa, pa)
    assert out.dist.dtype == out.normal.dtype == jnp.float32
    assert np.all(np.isfinite(out.normal))


def test_contacts_type():
    out = JITTED["capsule_sphere"]((0.1, 0.2), (0.3,), pose(np.zeros(3)), pose(np.ones(3)))
    assert isinstance(out, Contacts)
