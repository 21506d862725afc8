"""Mass properties of shapes, checked against closed forms and independent integrations.

Everything here is host-side NumPy (plus one small ``world_inertia`` call), so the
module is fast and compiles next to nothing.
"""

import math

import numpy as np
import pytest
from scipy.integrate import quad

import jaxrb as rb
from jaxrb.model.shapes import ShapeError, check_inertia, mass_properties, validate_shape


def cell_centres(num, low, high, dim=3):
    """Cell-centred grid of ``num**dim`` points filling [low, high]^dim, and its spacing."""
    spacing = (high - low) / num
    axis = low + spacing * (np.arange(num) + 0.5)
    mesh = np.meshgrid(*([axis] * dim), indexing="ij")
    return np.stack(mesh, axis=-1).reshape(-1, dim), spacing


def rotation_from_quat(quat):
    """Reference rotation matrix via Rodrigues' formula (independent of the package's)."""
    quat = np.asarray(quat, dtype=np.float64) / np.linalg.norm(quat)
    angle = 2.0 * math.atan2(np.linalg.norm(quat[1:]), quat[0])
    axis = quat[1:] / np.linalg.norm(quat[1:])
    skew = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * skew + (1.0 - math.cos(angle)) * skew @ skew


# --------------------------------------------------------------------------------------
# 3D primitives in closed form


@pytest.mark.parametrize("radius, density", [(1.0, 1.0), (0.25, 1000.0), (3.0, 7.5)])
def test_sphere_closed_form(radius, density):
    mass, com, inertia = mass_properties(rb.Sphere(radius=radius), density, 3)
    expected_mass = density * 4.0 / 3.0 * math.pi * radius ** 3
    assert mass == pytest.approx(expected_mass, rel=1e-14)
    np.testing.assert_array_equal(com, np.zeros(3))
    np.testing.assert_allclose(inertia, 0.4 * expected_mass * radius ** 2 * np.eye(3), rtol=1e-14)


@pytest.mark.parametrize("half_extents, density", [((0.1, 0.2, 0.3), 1000.0), ((1.0, 1.0, 1.0), 1.0),
                                                   ((2.0, 0.5, 0.05), 3.0)])
def test_box_3d_closed_form(half_extents, density):
    hx, hy, hz = half_extents
    mass, com, inertia = mass_properties(rb.Box(half_extents=half_extents), density, 3)
    expected_mass = density * 8.0 * hx * hy * hz
    assert mass == pytest.approx(expected_mass, rel=1e-14)
    np.testing.assert_array_equal(com, np.zeros(3))
    expected = expected_mass / 3.0 * np.diag([hy ** 2 + hz ** 2, hx ** 2 + hz ** 2, hx ** 2 + hy ** 2])
    np.testing.assert_allclose(inertia, expected, rtol=1e-14, atol=0.0)


def capsule_by_slices(radius, half_length):
    """Mass and (transverse, axial) moments of a unit-density capsule along z.

    Integrates thin discs over z with adaptive quadrature: a disc of radius ρ at
    height z contributes π ρ² dz to the mass, π ρ⁴/2 dz to the axial moment and
    (π ρ⁴/4 + π ρ² z²) dz to the transverse moment. This shares nothing with the
    hemisphere-plus-parallel-axis formula in jaxrb.model.shapes.
    """
    def rho_sq(z):
        beyond = max(abs(z) - half_length, 0.0)
        return max(radius ** 2 - beyond ** 2, 0.0)

    end = half_length + radius
    breaks = [-half_length, half_length] if half_length > 0.0 else [0.0]
    opts = dict(points=breaks, epsabs=0.0, epsrel=1e-12, limit=200)
    mass = quad(lambda z: math.pi * rho_sq(z), -end, end, **opts)[0]
    axial = quad(lambda z: 0.5 * math.pi * rho_sq(z) ** 2, -end, end, **opts)[0]
    transverse = quad(lambda z: 0.25 * math.pi * rho_sq(z) ** 2 + math.pi * rho_sq(z) * z * z,
                      -end, end, **opts)[0]
    return mass, transverse, axial


@pytest.mark.parametrize("radius, half_length", [(0.5, 0.75), (0.1, 2.0), (1.0, 0.05), (0.3, 0.0)])
def test_capsule_matches_slice_integration(radius, half_length):
    density = 2.5
    mass, com, inertia = mass_properties(rb.Capsule(radius=radius, half_length=half_length), density, 3)
    ref_mass, ref_transverse, ref_axial = capsule_by_slices(radius, half_length)
    # quad is asked for 1e-12 relative accuracy on smooth piecewise-polynomial integrands.
    assert mass == pytest.approx(density * ref_mass, rel=1e-9)
    np.testing.assert_array_equal(com, np.zeros(3))
    np.testing.assert_allclose(np.diag(inertia), density * np.array([ref_transverse, ref_transverse, ref_axial]),
                               rtol=1e-9)
    np.testing.assert_array_equal(inertia - np.diag(np.diag(inertia)), np.zeros((3, 3)))


def test_capsule_of_zero_length_is_a_sphere():
    radius, density = 0.4, 900.0
    capsule = mass_properties(rb.Capsule(radius=radius, half_length=0.0), density, 3)
    sphere = mass_properties(rb.Sphere(radius=radius), density, 3)
    assert capsule[0] == pytest.approx(sphere[0], rel=1e-14)
    np.testing.assert_allclose(capsule[2], sphere[2], rtol=1e-14)


def test_capsule_transverse_moment_grows_with_length_faster_than_axial():
    short = mass_properties(rb.Capsule(radius=0.2, half_length=0.1), 1.0, 3)[2]
    long = mass_properties(rb.Capsule(radius=0.2, half_length=1.0), 1.0, 3)[2]
    # Axial moment per unit mass is fixed by the radius (between the cylinder's r²/2
    # and the sphere's 2r²/5); the transverse one grows like L²/3.
    assert long[2, 2] / long[0, 0] < 0.2 * short[2, 2] / short[0, 0]


# --------------------------------------------------------------------------------------
# 2D primitives


@pytest.mark.parametrize("radius, density", [(1.0, 1.0), (0.2, 50.0)])
def test_circle_closed_form(radius, density):
    mass, com, inertia = mass_properties(rb.Circle(radius=radius), density, 2)
    expected_mass = density * math.pi * radius ** 2
    assert mass == pytest.approx(expected_mass, rel=1e-14)
    np.testing.assert_array_equal(com, np.zeros(2))
    assert inertia == pytest.approx(0.5 * expected_mass * radius ** 2, rel=1e-14)


@pytest.mark.parametrize("half_extents", [(0.5, 0.25), (1.0, 1.0), (3.0, 0.01)])
def test_box_2d_closed_form(half_extents):
    hx, hy = half_extents
    density = 4.0
    mass, com, inertia = mass_properties(rb.Box(half_extents=half_extents), density, 2)
    expected_mass = density * 4.0 * hx * hy
    assert mass == pytest.approx(expected_mass, rel=1e-14)
    np.testing.assert_array_equal(com, np.zeros(2))
    assert inertia == pytest.approx(expected_mass / 3.0 * (hx ** 2 + hy ** 2), rel=1e-14)


@pytest.mark.parametrize("offset", [(0.0, 0.0), (3.0, -2.0)])
def test_polygon_rectangle_equals_2d_box(offset):
    hx, hy, density = 0.6, 0.2, 7.0
    corners = np.array([(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]) + np.array(offset)
    mass, com, inertia = mass_properties(rb.Polygon(vertices=corners), density, 2)
    box_mass, _, box_inertia = mass_properties(rb.Box(half_extents=(hx, hy)), density, 2)
    assert mass == pytest.approx(box_mass, rel=1e-12)
    # The centre of mass of an off-centre rectangle is its centre, and the inertia
    # about it does not depend on where the rectangle sits (parallel-axis shift undone).
    np.testing.assert_allclose(com, offset, rtol=1e-12, atol=1e-12)
    assert inertia == pytest.approx(box_inertia, rel=1e-10)


def triangle_reference(vertices, density):
    """Mass, centroid and polar moment about the centroid of a triangle: m (a²+b²+c²)/36."""
    vertices = np.asarray(vertices, dtype=np.float64)
    (ax, ay), (bx, by), (cx, cy) = vertices
    area = 0.5 * abs((bx - ax) * (cy - ay) - (cx - ax) * (by - ay))
    mass = density * area
    sides_sq = sum(float(np.sum((vertices[i] - vertices[(i + 1) % 3]) ** 2)) for i in range(3))
    return mass, vertices.mean(axis=0), mass * sides_sq / 36.0


def test_polygon_off_centre_triangle():
    vertices = [(1.0, 1.0), (4.0, 1.0), (1.5, 3.0)]
    density = 2.0
    mass, com, inertia = mass_properties(rb.Polygon(vertices=vertices), density, 2)
    ref_mass, ref_com, ref_inertia = triangle_reference(vertices, density)
    assert mass == pytest.approx(ref_mass, rel=1e-12)
    np.testing.assert_allclose(com, ref_com, rtol=1e-12)
    np.testing.assert_allclose(com, [6.5 / 3.0, 5.0 / 3.0], rtol=1e-12)
    assert inertia == pytest.approx(ref_inertia, rel=1e-10)


def test_polygon_clockwise_equals_counter_clockwise():
    ccw = [(1.0, 1.0), (4.0, 1.0), (3.0, 2.5), (1.5, 3.0)]
    cw = ccw[::-1]
    a, b = rb.Polygon(vertices=ccw), rb.Polygon(vertices=cw)
    props_a, props_b = mass_properties(a, 3.0, 2), mass_properties(b, 3.0, 2)
    assert props_a[0] > 0.0
    assert props_a[0] == pytest.approx(props_b[0], rel=1e-14)
    np.testing.assert_allclose(props_a[1], props_b[1], rtol=1e-14)
    assert props_a[2] == pytest.approx(props_b[2], rel=1e-14)
    # Both are stored counter-clockwise, so they are the same (hashable) shape.
    assert a == b and hash(a) == hash(b)
    vertices = np.asarray(b.vertices)
    x, y = vertices[:, 0], vertices[:, 1]
    assert np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0.0


def test_polygon_regular_polygon_approaches_circle():
    """A regular k-gon inscribed in radius R: I = m R² (2 + cos(2π/k)) / 6 (exact)."""
    radius, density = 0.7, 5.0
    for k in (3, 6, 64):
        angles = 2.0 * math.pi * np.arange(k) / k + 0.3
        vertices = radius * np.stack([np.cos(angles), np.sin(angles)], axis=1) + np.array([2.0, -1.0])
        mass, com, inertia = mass_properties(rb.Polygon(vertices=vertices), density, 2)
        assert mass == pytest.approx(density * 0.5 * k * radius ** 2 * math.sin(2.0 * math.pi / k), rel=1e-12)
        np.testing.assert_allclose(com, [2.0, -1.0], rtol=1e-12)
        assert inertia == pytest.approx(mass * radius ** 2 * (2.0 + math.cos(2.0 * math.pi / k)) / 6.0, rel=1e-10)


# --------------------------------------------------------------------------------------
# Point masses


def test_point_masses_inertia_is_trace_identity_minus_covariance():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(7, 3))
    masses = rng.uniform(0.5, 2.0, size=7)
    total, com, inertia, rel = rb.point_mass_properties(points, masses)
    assert total == pytest.approx(masses.sum(), rel=1e-14)
    np.testing.assert_allclose(com, masses @ points / masses.sum(), rtol=1e-13)
    np.testing.assert_allclose(rel, points - com, rtol=1e-13, atol=1e-15)
    # Reference written out per point: I = Σ m (|r|² Id − r rᵀ).
    reference = sum(m * (np.dot(r, r) * np.eye(3) - np.outer(r, r)) for m, r in zip(masses, points - com))
    np.testing.assert_allclose(inertia, reference, rtol=1e-12, atol=1e-14)
    covariance = (rel * masses[:, None]).T @ rel
    np.testing.assert_allclose(inertia, np.eye(3) * np.trace(covariance) - covariance, rtol=1e-12, atol=1e-14)


def test_point_masses_2d_polar_moment():
    points = np.array([[1.0, 2.0], [-1.0, 0.5], [3.0, -2.0]])
    masses = np.array([1.0, 2.0, 0.5])
    total, com, inertia, _ = rb.point_mass_properties(points, masses)
    com_ref = masses @ points / masses.sum()
    assert total == pytest.approx(3.5)
    np.testing.assert_allclose(com, com_ref, rtol=1e-14)
    assert inertia == pytest.approx(float(np.sum(masses * np.sum((points - com_ref) ** 2, axis=1))), rel=1e-14)
    # Same through the shape API.
    mass, com2, inertia2 = mass_properties(rb.PointMasses(points=points, masses=masses), 123.0, 2)
    assert (mass, inertia2) == pytest.approx((total, inertia), rel=1e-14)
    np.testing.assert_allclose(com2, com, rtol=1e-14)


@pytest.mark.parametrize("num", [2, 5, 10, 20])
def test_point_mass_grid_box_exact_discrete_inertia(num):
    """N³ cell-centred points filling a box: per-axis mean of x² is exactly h²(1 − 1/N²)/3.

    (Midpoint rule: the cell-centred mean of x² over [−h, h] is h²/3 − (2h/N)²/12.)
    So the grid's inertia is exactly the box's times (1 − 1/N²).
    """
    half = np.array([0.3, 0.5, 0.8])
    unit_points, _ = cell_centres(num, -1.0, 1.0)
    points = unit_points * half
    total_mass = 2.0
    masses = np.full(len(points), total_mass / len(points))
    mass, com, inertia, _ = rb.point_mass_properties(points, masses)
    _, _, box_inertia = mass_properties(rb.Box(half_extents=tuple(half)), 1.0, 3)
    box_inertia = box_inertia * total_mass / (8.0 * np.prod(half))
    assert mass == pytest.approx(total_mass, rel=1e-13)
    np.testing.assert_allclose(com, np.zeros(3), atol=1e-14)
    np.testing.assert_allclose(inertia, box_inertia * (1.0 - 1.0 / num ** 2), rtol=1e-12, atol=1e-14)


def test_point_mass_grid_box_converges():
    half = (0.3, 0.5, 0.8)
    _, _, box = mass_properties(rb.Box(half_extents=half), 1.0, 3)
    box = box / (8.0 * np.prod(half))  # unit mass
    errors = []
    for num in (2, 4, 8, 16):
        points, _ = cell_centres(num, -1.0, 1.0)
        points = points * np.array(half)
        _, _, inertia, _ = rb.point_mass_properties(points, np.full(len(points), 1.0 / len(points)))
        errors.append(float(np.max(np.abs(inertia - box) / np.diag(box))))
    assert all(later < earlier for earlier, later in zip(errors, errors[1:]))
    # Relative error is 1/N² exactly: 6.25% at N=4, below 1% from N=11 on; 0.39% at N=16.
    np.testing.assert_allclose(errors, [1.0 / n ** 2 for n in (2, 4, 8, 16)], rtol=1e-10)
    assert errors[-1] < 0.01


def test_point_mass_grid_sphere_approaches_two_fifths():
    """Cell-centred points inside a ball of radius r approach I = 2/5 m r².

    Tolerance: the sampled body (the union of the kept cells) lies between the balls
    of radius r − δ and r + δ with δ = √3 h / 2, half a cell diagonal, so to first
    order I/(m r²) is within 2δ/r = √3 h/r of 2/5 relatively. Cell-centred interior
    sampling adds only O(h²). By grid symmetry the tensor is exactly isotropic.
    """
    radius = 1.0
    errors = []
    for num in (10, 40):
        points, spacing = cell_centres(num, -radius, radius)
        points = points[np.sum(points * points, axis=1) <= radius ** 2]
        mass, com, inertia, _ = rb.point_mass_properties(points, np.ones(len(points)))
        np.testing.assert_allclose(com, np.zeros(3), atol=1e-12)
        np.testing.assert_allclose(inertia, inertia[0, 0] * np.eye(3), rtol=1e-12, atol=1e-9)
        error = abs(inertia[0, 0] / (mass * radius ** 2) / 0.4 - 1.0)
        assert error < math.sqrt(3.0) * spacing / radius
        errors.append(error)
    assert errors[1] < errors[0]
    assert errors[1] < 0.01  # h = r/20: about 0.09% in practice


def test_rotated_point_masses_body_has_rotated_world_inertia():
    rng = np.random.default_rng(1)
    points = rng.normal(size=(6, 3)) + np.array([0.5, -0.2, 0.3])  # centre of mass not at the origin
    masses = rng.uniform(0.5, 2.0, size=6)
    quat = np.array([0.8, 0.3, -0.5, 0.2])
    pos = np.array([1.0, 2.0, -0.5])
    scene = rb.Scene(dim=3)
    scene.add_body(rb.PointMasses(points=points, masses=masses), pos=pos, quat=quat)
    _, params, state = scene.build(dt=0.01, dtype=np.float64)

    rotation = rotation_from_quat(quat)
    world_points = points @ rotation.T
    total, world_com, world_inertia, _ = rb.point_mass_properties(world_points, masses)
    _, body_com, body_inertia, _ = rb.point_mass_properties(points, masses)

    computed = np.asarray(rb.world_inertia(state.quat, params.inertia))[0]
    np.testing.assert_allclose(computed, world_inertia, rtol=1e-12, atol=1e-12)
    # The rotation does something: the body-frame tensor is not the world one.
    assert np.max(np.abs(body_inertia - world_inertia)) > 0.1 * np.max(np.abs(world_inertia))
    np.testing.assert_allclose(np.asarray(params.inertia)[0], body_inertia, rtol=1e-12, atol=1e-12)
    assert float(params.mass[0]) == pytest.approx(total, rel=1e-14)
    # State position is the world centre of mass, pos + R·com.
    np.testing.assert_allclose(np.asarray(state.pos)[0], pos + rotation @ body_com, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(state.pos)[0], pos + world_com, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(params.com_offset)[0], body_com, rtol=1e-12)


def test_offset_polygon_body_2d_state_is_world_centre_of_mass():
    vertices = [(1.0, 1.0), (4.0, 1.0), (1.5, 3.0)]
    angle, origin = 0.7, np.array([-1.0, 0.5])
    scene = rb.Scene(dim=2)
    scene.add_body(rb.Polygon(vertices=vertices), pos=origin, angle=angle, density=2.0)
    _, params, state = scene.build(dt=0.01, dtype=np.float64)
    com = np.mean(vertices, axis=0)
    c, s = math.cos(angle), math.sin(angle)
    np.testing.assert_allclose(np.asarray(state.pos)[0], origin + np.array([[c, -s], [s, c]]) @ com, rtol=1e-12)
    _, _, ref_inertia = triangle_reference(vertices, 2.0)
    assert float(params.inertia[0]) == pytest.approx(ref_inertia, rel=1e-10)


# --------------------------------------------------------------------------------------
# Singular inertia


@pytest.mark.parametrize("points", [
    [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [3.0, 0.0, 0.0]],
    [[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [-2.0, -4.0, -6.0], [0.5, 1.0, 1.5]],  # off-axis line
    [[1.0, 1.0, 1.0], [2.0, 2.0, 2.0]],
], ids=["x-axis", "oblique", "two-points"])
def test_collinear_point_masses_3d_are_singular(points):
    scene = rb.Scene(dim=3)
    with pytest.raises(ValueError, match=r"body 0.*'inertia'.*singular"):
        scene.add_body(rb.PointMasses(points=points, masses=np.ones(len(points))))
    assert scene.num_bodies == 0


def test_single_point_mass_3d_is_singular():
    with pytest.raises(ValueError, match=r"body 0.*'inertia'.*singular"):
        rb.Scene(dim=3).add_body(rb.PointMasses(points=[[0.3, 0.1, 2.0]], masses=[1.0]))


def test_single_point_mass_2d_is_singular():
    with pytest.raises(ValueError, match=r"body 0.*'inertia'.*singular"):
        rb.Scene(dim=2).add_body(rb.PointMasses(points=[[0.3, 0.1]], masses=[1.0]))


def test_collinear_point_masses_2d_are_fine():
    """In 2D the only axis is normal to the plane, so points on a line do have inertia."""
    scene = rb.Scene(dim=2)
    scene.add_body(rb.PointMasses(points=[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]], masses=[1.0, 1.0, 1.0]))
    _, params, _ = scene.build(dt=0.01)
    assert float(params.inertia[0]) == pytest.approx(4.0)  # 2 · 1 · |(1, 1)|²


def test_planar_point_masses_3d_are_fine():
    """Coplanar (non-collinear) masses sit exactly on the triangle-inequality boundary I3 = I1 + I2."""
    points = [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, -2.0, 0.0]]
    scene = rb.Scene(dim=3)
    scene.add_body(rb.PointMasses(points=points, masses=[1.0] * 4))
    _, params, _ = scene.build(dt=0.01)
    np.testing.assert_allclose(np.asarray(params.inertia)[0], np.diag([8.0, 2.0, 10.0]), rtol=1e-14)


def test_check_inertia_directly():
    check_inertia(np.diag([1.0, 2.0, 2.5]), 3)
    check_inertia(0.1, 2)
    with pytest.raises(ShapeError, match="singular") as info:
        check_inertia(np.diag([0.0, 1.0, 1.0]), 3)
    assert info.value.field == "inertia"
    with pytest.raises(ShapeError, match="singular"):
        check_inertia(0.0, 2)
    with pytest.raises(ShapeError, match="triangle"):
        check_inertia(np.diag([1.0, 1.0, 2.5]), 3)
    with pytest.raises(ShapeError, match="symmetric"):
        check_inertia(np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), 3)


# --------------------------------------------------------------------------------------
# Shape validation and hashing


@pytest.mark.parametrize("shape, field", [
    (rb.Sphere(radius=0.0), "radius"),
    (rb.Sphere(radius=-1.0), "radius"),
    (rb.Sphere(radius=(1.0, 2.0)), "radius"),
    (rb.Circle(radius=float("nan")), "radius"),
    (rb.Box(half_extents=(1.0, 0.0, 1.0)), "half_extents"),
    (rb.Box(half_extents=(1.0,)), "half_extents"),
    (rb.Box(half_extents=((1.0, 1.0), (1.0, 1.0))), "half_extents"),
    (rb.Capsule(radius=0.0, half_length=1.0), "radius"),
    (rb.Capsule(radius=1.0, half_length=-0.1), "half_length"),
    (rb.Polygon(vertices=[(0.0, 0.0), (1.0, 0.0)]), "vertices"),
    (rb.Polygon(vertices=[(0.0, 0.0), (1.0, 1.0), (2.0, 2.0)]), "vertices"),
    (rb.PointMasses(points=[[0.0, 0.0, 0.0]], masses=[0.0]), "masses"),
    (rb.PointMasses(points=[0.0, 0.0, 0.0], masses=[1.0]), "points"),
    ("sphere", "shape"),
], ids=lambda value: repr(value) if isinstance(value, str) else type(value).__name__)
def test_validate_shape_rejects(shape, field):
    with pytest.raises(ShapeError) as info:
        validate_shape(shape)
    assert info.value.field == field
    assert isinstance(info.value, ValueError)


def test_pentagram_is_not_convex():
    """A star turns left at every vertex but winds twice: not a convex polygon."""
    angles = math.pi / 2 + 2 * math.pi / 5 * np.array([0, 2, 4, 1, 3])
    star = rb.Polygon(vertices=np.stack([np.cos(angles), np.sin(angles)], axis=1))
    with pytest.raises(ShapeError, match="convex"):
        validate_shape(star)


def test_small_polygon_far_from_origin_is_accepted():
    """Convexity tolerances are relative to the polygon, not to its distance from the origin."""
    side = 1e-3
    square = np.array([(0.0, 0.0), (side, 0.0), (side, side), (0.0, side)]) + 1e4
    for vertices in (square, square[::-1]):
        polygon = rb.Polygon(vertices=vertices)
        assert polygon.vertices == tuple(map(tuple, square.tolist()))  # stored counter-clockwise
        mass, com, inertia = mass_properties(polygon, 1.0, 2)
        # Coordinates carry ~1e4 · 2e-16 absolute error, i.e. ~2e-9 of the side.
        assert mass == pytest.approx(side ** 2, rel=1e-8)
        np.testing.assert_allclose(com, [1e4 + side / 2, 1e4 + side / 2], rtol=0.0, atol=1e-11)
        assert inertia == pytest.approx(side ** 4 / 6.0, rel=1e-8)


def test_shapes_normalise_to_hashable_python_values():
    import jax.numpy as jnp

    sphere = rb.Sphere(radius=jnp.asarray(0.5))
    assert type(sphere.radius) is float and hash(sphere) == hash(rb.Sphere(radius=0.5))
    box = rb.Box(half_extents=np.array([0.1, 0.2, 0.3]))
    assert box.half_extents == (0.1, 0.2, 0.3) and box.dims == (3,)
    assert rb.Box(half_extents=[1, 2]).dims == (2,)
    cloud = rb.PointMasses(points=np.eye(3), masses=np.ones(3))
    assert cloud.points == ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    assert cloud == rb.PointMasses(points=np.eye(3).tolist(), masses=[1, 1, 1])
    assert hash(cloud) == hash(rb.PointMasses(points=np.eye(3).tolist(), masses=[1, 1, 1]))


def test_mass_properties_rejects_wrong_dimension():
    with pytest.raises(ShapeError, match="not a 2D shape"):
        mass_properties(rb.Sphere(radius=1.0), 1.0, 2)
    with pytest.raises(ShapeError, match="not a 3D shape"):
        mass_properties(rb.Box(half_extents=(1.0, 1.0)), 1.0, 3)
