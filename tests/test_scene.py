"""Scene building: bad input is rejected at build time, naming the body and the field;
good input produces arrays of the documented shapes and dtypes.

Host-side only: nothing here is jitted.
"""

import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrb as rb
from jaxrb.model.types import (CONTACT_MODELS, INTEGRATORS, JOINT_ONLY_INTEGRATORS, ORIENTATIONS,
                               PENALTY_FRICTIONS, SOLVERS)

NAN, INF = float("nan"), float("inf")


def scene3():
    """A 3D scene with one valid sphere already in it, so the body under test is body 1."""
    scene = rb.Scene(dim=3)
    scene.add_body(rb.Sphere(radius=0.1), mass=1.0)
    return scene


def scene2():
    scene = rb.Scene(dim=2)
    scene.add_body(rb.Circle(radius=0.1), mass=1.0)
    return scene


def assert_rejected(scene, field, *args, match=None, **kwargs):
    """``scene.add_body(*args, **kwargs)`` raises a ValueError naming the new body and ``field``."""
    index = scene.num_bodies
    with pytest.raises(ValueError) as info:
        scene.add_body(*args, **kwargs)
    message = str(info.value)
    assert f"body {index}" in message, message
    assert f"'{field}'" in message, message
    if match is not None:
        assert re.search(match, message), message
    assert scene.num_bodies == index, "a rejected body must not be added"
    return message


# --------------------------------------------------------------------------------------
# Mass, density, inertia


@pytest.mark.parametrize("mass", [0.0, -1.0])
@pytest.mark.parametrize("shape", [rb.Sphere(radius=0.1), None], ids=["sphere", "mass-only"])
def test_non_positive_mass(shape, mass):
    assert_rejected(scene3(), "mass", shape, mass=mass, inertia=(1.0, 1.0, 1.0), match="must be >")


def test_non_positive_mass_2d():
    assert_rejected(scene2(), "mass", rb.Circle(radius=0.2), mass=-0.5)


@pytest.mark.parametrize("density", [0.0, -1000.0])
def test_non_positive_density(density):
    assert_rejected(scene3(), "density", rb.Box(half_extents=(0.1, 0.1, 0.1)), density=density)


def test_mass_and_density_together():
    assert_rejected(scene3(), "density", rb.Sphere(radius=0.1), mass=1.0, density=10.0)


@pytest.mark.parametrize("keyword", ["mass", "density"])
def test_mass_or_density_with_point_masses(keyword):
    cloud = rb.PointMasses(points=np.eye(3), masses=[1.0, 1.0, 1.0])
    assert_rejected(scene3(), keyword, cloud, **{keyword: 2.0}, match="from the points")


def test_shape_none_needs_mass_and_inertia():
    assert_rejected(scene3(), "shape", None, mass=1.0)


def test_singular_inertia_from_collinear_points():
    cloud = rb.PointMasses(points=[[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 2.5, 0.0]], masses=[1.0, 2.0, 1.0])
    assert_rejected(scene3(), "inertia", cloud, match="singular")


@pytest.mark.parametrize("inertia", [(1.0, 1.0, 0.0), np.diag([0.0, 1.0, 1.0]), (1.0, -1.0, 1.0)],
                         ids=["principal-zero", "matrix-zero", "negative"])
def test_singular_given_inertia(inertia):
    assert_rejected(scene3(), "inertia", None, mass=1.0, inertia=inertia, match="singular")


@pytest.mark.parametrize("inertia", [0.0, -0.1])
def test_singular_given_inertia_2d(inertia):
    assert_rejected(scene2(), "inertia", None, mass=1.0, inertia=inertia, match="singular")


@pytest.mark.parametrize("inertia", [(1.0, 1.0, 2.5), np.diag([0.1, 3.0, 0.2])])
def test_inertia_violating_triangle_inequality(inertia):
    assert_rejected(scene3(), "inertia", rb.Sphere(radius=0.1), inertia=inertia, match="triangle")


def test_non_symmetric_inertia():
    inertia = np.array([[1.0, 0.2, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    assert_rejected(scene3(), "inertia", None, mass=1.0, inertia=inertia, match="symmetric")


@pytest.mark.parametrize("inertia", [(1.0, 1.0), np.eye(2), [[1.0, 0.0], [0.0, 1.0, 0.0]]],
                         ids=["two-moments", "2x2", "ragged"])
def test_inertia_wrong_shape(inertia):
    assert_rejected(scene3(), "inertia", None, mass=1.0, inertia=inertia)


def test_valid_inertia_overrides_shape_and_mass_scales_shape_inertia():
    scene = rb.Scene(dim=3)
    scene.add_body(rb.Box(half_extents=(0.1, 0.2, 0.3)), mass=6.0)
    scene.add_body(rb.Sphere(radius=0.5), mass=2.0, inertia=(0.1, 0.2, 0.25))
    _, params, _ = scene.build(dt=0.01)
    np.testing.assert_allclose(params.inertia[0], 6.0 / 3.0 * np.diag([0.13, 0.10, 0.05]), rtol=1e-12)
    np.testing.assert_allclose(params.inertia[1], np.diag([0.1, 0.2, 0.25]), rtol=1e-15)
    np.testing.assert_allclose(params.mass, [6.0, 2.0])


# --------------------------------------------------------------------------------------
# Non-finite numbers


@pytest.mark.parametrize("bad", [NAN, INF, -INF], ids=["nan", "inf", "-inf"])
@pytest.mark.parametrize("field", ["pos", "vel", "angvel", "quat"])
def test_non_finite_vectors_3d(field, bad):
    value = {"pos": [0.0, bad, 1.0], "vel": [bad, 0.0, 0.0], "angvel": [0.0, 0.0, bad],
             "quat": [1.0, 0.0, bad, 0.0]}[field]
    assert_rejected(scene3(), field, rb.Sphere(radius=0.1), **{field: value}, match="finite")


@pytest.mark.parametrize("bad", [NAN, INF], ids=["nan", "inf"])
@pytest.mark.parametrize("field", ["mass", "density", "friction", "restitution", "linear_damping"])
def test_non_finite_scalars(field, bad):
    assert_rejected(scene3(), field, rb.Sphere(radius=0.1), **{field: bad}, match="finite")


@pytest.mark.parametrize("bad", [NAN, INF], ids=["nan", "inf"])
@pytest.mark.parametrize("field", ["pos", "vel", "angvel", "angle", "inertia"])
def test_non_finite_2d(field, bad):
    value = {"pos": [bad, 0.0], "vel": [0.0, bad], "angvel": bad, "angle": bad, "inertia": bad}[field]
    assert_rejected(scene2(), field, rb.Circle(radius=0.1), **{field: value}, match="finite")


def test_non_finite_inertia_3d():
    assert_rejected(scene3(), "inertia", None, mass=1.0, inertia=(1.0, NAN, 1.0), match="finite")


@pytest.mark.parametrize("shape, field", [
    (rb.PointMasses(points=[[0.0, 0.0, 0.0], [1.0, NAN, 0.0]], masses=[1.0, 1.0]), "points"),
    (rb.PointMasses(points=[[0.0, 0.0, 0.0], [1.0, 1.0, 0.0]], masses=[1.0, INF]), "masses"),
    (rb.Sphere(radius=INF), "radius"),
    (rb.Box(half_extents=(0.1, NAN, 0.1)), "half_extents"),
], ids=["points-nan", "masses-inf", "radius-inf", "half-extents-nan"])
def test_non_finite_shape_fields(shape, field):
    assert_rejected(scene3(), field, shape, match="finite")


def test_non_numeric_value():
    assert_rejected(scene3(), "vel", rb.Sphere(radius=0.1), vel="fast", match="numeric")


# --------------------------------------------------------------------------------------
# Zero-size and degenerate shapes


@pytest.mark.parametrize("shape, field", [
    (rb.Sphere(radius=0.0), "radius"),
    (rb.Sphere(radius=-0.1), "radius"),
    (rb.Box(half_extents=(0.1, 0.0, 0.1)), "half_extents"),
    (rb.Capsule(radius=0.0, half_length=0.5), "radius"),
], ids=["sphere-0", "sphere-negative", "box-0", "capsule-radius-0"])
def test_zero_size_shapes_3d(shape, field):
    assert_rejected(scene3(), field, shape, match="positive")


def test_capsule_negative_length():
    assert_rejected(scene3(), "half_length", rb.Capsule(radius=0.1, half_length=-0.5))


@pytest.mark.parametrize("shape, field", [
    (rb.Circle(radius=0.0), "radius"),
    (rb.Box(half_extents=(0.0, 0.1)), "half_extents"),
], ids=["circle-0", "box-0"])
def test_zero_size_shapes_2d(shape, field):
    assert_rejected(scene2(), field, shape, match="positive")


PENTAGRAM = [(math.cos(a), math.sin(a)) for a in math.pi / 2 + 2 * math.pi / 5 * np.array([0, 2, 4, 1, 3])]


@pytest.mark.parametrize("vertices", [
    [(0.0, 0.0), (1.0, 1.0), (2.0, 2.0)],                            # zero area
    [(0.0, 0.0), (1.0, 0.0), (1.0, 0.0), (0.0, 1.0)],                # repeated vertex
    [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0), (2.0, 1.0), (0.0, 1.0)],    # collinear vertex
    [(0.0, 0.0), (2.0, 0.0), (1.0, 0.5), (2.0, 2.0), (0.0, 2.0)],    # reflex (non-convex)
    [(0.0, 0.0), (1.0, 1.0), (1.0, 0.0), (0.0, 1.0)],                # bow tie
    PENTAGRAM,                                                       # winds twice
    [(0.0, 0.0)] * 3,                                                # a point
], ids=["zero-area", "repeated", "collinear", "reflex", "bow-tie", "pentagram", "point"])
def test_degenerate_or_non_convex_polygon(vertices):
    assert_rejected(scene2(), "vertices", rb.Polygon(vertices=vertices), match="convex")


@pytest.mark.parametrize("vertices", [[(0.0, 0.0), (1.0, 0.0)], [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)],
                                      [0.0, 1.0, 2.0]], ids=["two-vertices", "3d-vertices", "flat"])
def test_polygon_wrong_vertex_array(vertices):
    assert_rejected(scene2(), "vertices", rb.Polygon(vertices=vertices), match="shape")


# --------------------------------------------------------------------------------------
# Wrong array shapes


@pytest.mark.parametrize("field, value", [
    ("pos", (0.0, 1.0)),
    ("pos", (0.0, 0.0, 1.0, 0.0)),
    ("vel", 1.0),
    ("quat", (1.0, 0.0, 0.0)),
    ("quat", np.eye(4)),
    ("angvel", (0.0, 1.0)),
    ("angvel", 1.0),
])
def test_wrong_array_shapes_3d(field, value):
    assert_rejected(scene3(), field, rb.Sphere(radius=0.1), **{field: value}, match="shape")


@pytest.mark.parametrize("field, value", [
    ("pos", (0.0, 1.0, 2.0)),
    ("vel", (1.0,)),
    ("angvel", (0.0, 0.0, 1.0)),
    ("angle", (0.1, 0.2)),
])
def test_wrong_array_shapes_2d(field, value):
    assert_rejected(scene2(), field, rb.Circle(radius=0.1), **{field: value}, match="shape")


@pytest.mark.parametrize("masses", [[1.0, 1.0], [1.0, 1.0, 1.0, 1.0], [[1.0, 1.0, 1.0]]])
def test_point_masses_length_mismatch(masses):
    cloud = rb.PointMasses(points=[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], masses=masses)
    assert_rejected(scene3(), "masses", cloud, match="match points")


@pytest.mark.parametrize("points", [[0.0, 1.0, 2.0], np.zeros((0, 3)), np.zeros((2, 4))],
                         ids=["flat", "empty", "4d"])
def test_point_masses_bad_points(points):
    assert_rejected(scene3(), "points", rb.PointMasses(points=points, masses=[1.0, 1.0]), match="shape")


def test_point_masses_non_positive_mass():
    cloud = rb.PointMasses(points=np.eye(3), masses=[1.0, 0.0, 1.0])
    assert_rejected(scene3(), "masses", cloud, match="positive")


def test_zero_quaternion():
    assert_rejected(scene3(), "quat", rb.Sphere(radius=0.1), quat=(0.0, 0.0, 0.0, 0.0), match="non-zero")


# --------------------------------------------------------------------------------------
# Dimension mismatches


@pytest.mark.parametrize("shape", [rb.Sphere(radius=0.1), rb.Box(half_extents=(0.1, 0.1, 0.1)),
                                   rb.Capsule(radius=0.1, half_length=0.2),
                                   rb.PointMasses(points=np.eye(3), masses=[1.0, 1.0, 1.0])],
                         ids=["sphere", "box", "capsule", "points"])
def test_3d_shape_in_2d_scene(shape):
    assert_rejected(scene2(), "shape", shape, match="not a 2D shape")


@pytest.mark.parametrize("shape", [rb.Circle(radius=0.1), rb.Box(half_extents=(0.1, 0.1)),
                                   rb.Polygon(vertices=[(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)]),
                                   rb.PointMasses(points=[[0.0, 0.0], [1.0, 0.0]], masses=[1.0, 1.0])],
                         ids=["circle", "box", "polygon", "points"])
def test_2d_shape_in_3d_scene(shape):
    assert_rejected(scene3(), "shape", shape, match="not a 3D shape")


def test_unknown_shape_type():
    assert_rejected(scene3(), "shape", "sphere", match="unknown shape")


def test_quat_in_2d():
    assert_rejected(scene2(), "quat", rb.Circle(radius=0.1), quat=(1.0, 0.0, 0.0, 0.0), match="3D only")


def test_angle_in_3d():
    assert_rejected(scene3(), "angle", rb.Sphere(radius=0.1), angle=0.5, match="2D only")


# --------------------------------------------------------------------------------------
# Material and damping coefficients


@pytest.mark.parametrize("restitution", [-0.1, 1.5])
def test_restitution_outside_unit_interval(restitution):
    assert_rejected(scene3(), "restitution", rb.Sphere(radius=0.1), restitution=restitution)


@pytest.mark.parametrize("restitution", [0.0, 1.0])
def test_restitution_at_bounds_is_accepted(restitution):
    scene = scene3()
    scene.add_body(rb.Sphere(radius=0.1), restitution=restitution)
    _, params, _ = scene.build(dt=0.01)
    assert float(params.restitution[1]) == restitution


def test_negative_friction():
    assert_rejected(scene3(), "friction", rb.Sphere(radius=0.1), friction=-0.2, match=">= 0")


@pytest.mark.parametrize("field", ["linear_damping", "angular_damping"])
def test_negative_damping(field):
    assert_rejected(scene3(), field, rb.Sphere(radius=0.1), **{field: -1.0})


def test_messages_use_the_body_name():
    message = assert_rejected(scene3(), "mass", rb.Sphere(radius=0.1), mass=-1.0, name="lid")
    assert "'lid'" in message


# --------------------------------------------------------------------------------------
# Scene-wide options at build time


def test_bad_scene_dim_and_gravity():
    with pytest.raises(ValueError, match="'dim'"):
        rb.Scene(dim=1)
    with pytest.raises(ValueError, match="'gravity'"):
        rb.Scene(dim=3, gravity=(0.0, -9.81))
    with pytest.raises(ValueError, match="'gravity'.*finite"):
        rb.Scene(dim=2, gravity=(0.0, NAN))


@pytest.mark.parametrize("option, valid, make", [
    ("integrator", INTEGRATORS, lambda: scene3().build(dt=0.01, integrator="leapfrog")),
    ("orientation", ORIENTATIONS, lambda: scene3().build(dt=0.01, orientation="leapfrog")),
    ("contact", CONTACT_MODELS, lambda: scene3().build(dt=0.01, contact="leapfrog")),
    ("solver", SOLVERS, lambda: rb.Impulse(solver="leapfrog")),
    ("friction", PENALTY_FRICTIONS, lambda: rb.Penalty(friction="leapfrog"))])
def test_unknown_option_lists_valid_ones(option, valid, make):
    with pytest.raises(ValueError) as info:
        make()
    message = str(info.value)
    assert option in message and "'leapfrog'" in message
    for name in valid:
        assert repr(name) in message, message


def test_documented_options_are_the_valid_ones():
    assert set(INTEGRATORS) == {"euler", "semi_implicit", "implicit_gyro", "rk4", "rk4_body", "midpoint", "implicit"}
    assert set(ORIENTATIONS) == {"first_order", "exp_map"}
    assert set(CONTACT_MODELS) == {"none", "penalty", "impulse"}


@pytest.mark.parametrize("dt", [0.0, -1e-3, NAN, INF])
def test_bad_dt(dt):
    with pytest.raises(ValueError, match="'dt'"):
        scene3().build(dt=dt)


@pytest.mark.parametrize("substeps", [0, -2, 1.5, True, "4"])
def test_bad_substeps(substeps):
    with pytest.raises(ValueError, match="'substeps'"):
        scene3().build(dt=0.01, substeps=substeps)


def test_empty_scene():
    with pytest.raises(ValueError, match="no bodies"):
        rb.Scene(dim=3).build(dt=0.01)


@pytest.mark.parametrize("integrator", ["rk4", "rk4_body"])
@pytest.mark.parametrize("orientation", ["first_order", "exp_map"])
def test_orientation_given_with_rk4(orientation, integrator):
    with pytest.raises(ValueError, match=f"'orientation'.*'{integrator}'"):
        scene3().build(dt=0.01, integrator=integrator, orientation=orientation)


@pytest.mark.parametrize("integrator", ["rk4", "rk4_body"])
def test_rk4_without_orientation_builds(integrator):
    model, _, state = scene3().build(dt=0.01, integrator=integrator)
    assert model.integrator == integrator
    # Only rk4_body carries the compensated-summation residual of body-frame momentum.
    assert (state.momentum_residual is not None) == (integrator == "rk4_body")


def test_non_float_dtype():
    with pytest.raises(ValueError, match="'dtype'"):
        scene3().build(dt=0.01, dtype=jnp.int32)


# --------------------------------------------------------------------------------------
# What a good build returns


def full_scene3():
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, -9.81))
    scene.add_body(rb.Sphere(radius=0.1), mass=1.0, pos=(0.0, 0.0, 1.0), quat=(2.0, 0.0, 0.0, 0.0),
                   vel=(1.0, 0.0, 0.0), angvel=(0.0, 0.0, 3.0), friction=0.3, restitution=0.5)
    scene.add_body(rb.Box(half_extents=(0.1, 0.2, 0.3)), density=500.0, quat=(1.0, 1.0, 1.0, 1.0))
    scene.add_body(rb.Capsule(radius=0.05, half_length=0.2), quat=(0.3, -0.2, 0.9, 0.1), linear_damping=0.1)
    return scene


def full_scene2():
    scene = rb.Scene(dim=2)
    scene.add_body(rb.Circle(radius=0.1), mass=1.0, pos=(0.0, 1.0), angle=0.3, angvel=2.0)
    scene.add_body(rb.Box(half_extents=(0.1, 0.2)), vel=(1.0, 0.0))
    scene.add_body(rb.Polygon(vertices=[(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)]))
    return scene


EXPECTED_3D = dict(mass=(3,), inertia=(3, 3, 3), com_offset=(3, 3), friction=(3,), restitution=(3,),
                   gravity=(3,), dt=(), linear_damping=(3,), angular_damping=(3,), force=(3, 3), torque=(3, 3))
EXPECTED_2D = dict(mass=(3,), inertia=(3,), com_offset=(3, 2), friction=(3,), restitution=(3,),
                   gravity=(2,), dt=(), linear_damping=(3,), angular_damping=(3,), force=(3, 2), torque=(3,))


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64], ids=["float32", "float64"])
@pytest.mark.parametrize("dim", [2, 3])
def test_build_shapes_and_dtypes(dim, dtype):
    scene = full_scene3() if dim == 3 else full_scene2()
    model, params, state = scene.build(dt=1e-3, dtype=dtype)
    expected = EXPECTED_3D if dim == 3 else EXPECTED_2D
    for name, shape in expected.items():
        value = getattr(params, name)
        assert isinstance(value, jax.Array), name
        assert value.shape == shape, (name, value.shape)
    state_shapes = dict(pos=(3, dim), vel=(3, dim), angvel=(3, 3) if dim == 3 else (3,), time=())
    state_shapes.update(quat=(3, 4)) if dim == 3 else state_shapes.update(angle=(3,))
    for name, shape in state_shapes.items():
        assert getattr(state, name).shape == shape, name
    assert (state.angle is None) if dim == 3 else (state.quat is None)
    # Every floating leaf has exactly the requested dtype: nothing promoted to
    # float64 in float32. (Contact keys are int32 and the overflow flag bool.)
    for leaf in jax.tree_util.tree_leaves((params, state)):
        if jnp.issubdtype(leaf.dtype, jnp.floating):
            assert leaf.dtype == jnp.dtype(dtype), leaf.dtype
        else:
            assert leaf.dtype in (jnp.int32, jnp.bool_), leaf.dtype
    assert model.dim == dim and model.num_bodies == 3
    assert float(params.dt) == pytest.approx(1e-3, rel=1e-6)
    assert float(state.time) == 0.0


def test_build_default_dtype_is_float64_with_x64():
    _, params, state = full_scene3().build(dt=1e-3)
    assert params.mass.dtype == jnp.float64 and state.pos.dtype == jnp.float64


def test_build_values_3d():
    model, params, state = full_scene3().build(dt=1e-3)
    np.testing.assert_allclose(params.gravity, [0.0, 0.0, -9.81])
    np.testing.assert_allclose(state.pos[0], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(state.vel[0], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(state.angvel[0], [0.0, 0.0, 3.0])
    np.testing.assert_allclose(params.friction, [0.3, 0.5, 0.5])
    np.testing.assert_allclose(params.restitution, [0.5, 0.0, 0.0])
    assert float(params.mass[1]) == pytest.approx(500.0 * 0.2 * 0.4 * 0.6)
    assert model.damping  # body 2 has linear damping
    assert model.names == ("body0", "body1", "body2")


def test_quat_is_normalised():
    _, _, state = full_scene3().build(dt=1e-3)
    quat = np.asarray(state.quat)
    np.testing.assert_allclose(np.linalg.norm(quat, axis=1), 1.0, rtol=1e-15)
    np.testing.assert_allclose(quat[0], [1.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(quat[1], [0.5, 0.5, 0.5, 0.5])
    raw = np.array([0.3, -0.2, 0.9, 0.1])
    np.testing.assert_allclose(quat[2], raw / np.linalg.norm(raw), rtol=1e-15)


def test_quat_normalised_in_float32():
    _, _, state = full_scene3().build(dt=1e-3, dtype=jnp.float32)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(state.quat, dtype=np.float64), axis=1), 1.0, rtol=1e-6)


def test_model_is_hashable_and_equal_models_hash_equal():
    model_a, _, _ = full_scene3().build(dt=1e-3, integrator="implicit_gyro")
    model_b, _, _ = full_scene3().build(dt=2e-3, integrator="implicit_gyro")  # dt is a Param
    model_c, _, _ = full_scene3().build(dt=1e-3, integrator="implicit_gyro", contact="none")
    assert model_a == model_b and hash(model_a) == hash(model_b)
    assert model_a != model_c
    assert len({model_a, model_b, model_c}) == 2
    model_2d, _, _ = full_scene2().build(dt=1e-3)
    hash(model_2d)


def test_model_hashable_with_array_valued_shape_fields():
    scene = rb.Scene(dim=3)
    scene.add_body(rb.Sphere(radius=np.array(0.1)))
    scene.add_body(rb.Sphere(radius=jnp.asarray(0.2)))
    scene.add_body(rb.Box(half_extents=jnp.array([0.1, 0.2, 0.3])))
    scene.add_body(rb.PointMasses(points=np.eye(3), masses=np.ones(3)))
    model, _, _ = scene.build(dt=1e-3)
    other = rb.Scene(dim=3)
    other.add_body(rb.Sphere(radius=0.1))
    other.add_body(rb.Sphere(radius=0.2))
    other.add_body(rb.Box(half_extents=(0.1, 0.2, 0.3)))
    other.add_body(rb.PointMasses(points=np.eye(3).tolist(), masses=[1.0, 1.0, 1.0]))
    assert hash(model) == hash(other.build(dt=1e-3)[0])
    assert model == other.build(dt=1e-3)[0]


@pytest.mark.parametrize("integrator", [name for name in INTEGRATORS if name not in JOINT_ONLY_INTEGRATORS])
def test_summary_mentions_integrator(integrator):
    contact = None if integrator in ("semi_implicit", "implicit_gyro") else "none"
    model, _, _ = full_scene3().build(dt=1e-3, integrator=integrator, contact=contact)
    summary = model.summary()
    assert integrator in summary
    assert "3D" in summary and "3 bodies" in summary
    for kind in ("Sphere", "Box", "Capsule"):
        assert kind in summary


def test_orientation_recorded_in_model():
    model, _, _ = full_scene3().build(dt=1e-3, orientation="first_order")
    assert model.orientation == "first_order"
    assert "first_order" in model.summary()


def test_substeps_recorded_in_model():
    model, _, _ = full_scene3().build(dt=1e-3, substeps=np.int64(4))
    assert model.substeps == 4 and type(model.substeps) is int


@pytest.mark.parametrize("dt, contact, expected", [(1 / 60, None, 8), (2e-3, None, 1), (1 / 240, None, 2),
                                                   (1 / 60, "penalty", 1), (1 / 60, "none", 1)])
def test_default_substeps_keep_impulse_substeps_at_most_1_480_s(dt, contact, expected):
    scene = scene3()
    scene.add_plane()
    model, _, _ = scene.build(dt=dt, contact=contact)
    assert model.substeps == expected
    assert model.contact != "impulse" or dt / model.substeps <= 1 / 480 + 1e-12


@pytest.mark.parametrize("integrator", ["euler", "rk4", "rk4_body"])
def test_contact_scene_with_an_integrator_that_cannot_take_contact_is_refused(integrator):
    """A box over a floor built with rk4 fell through it (z = -19 m after 2 s) with no word."""
    scene = scene3()
    scene.add_plane()
    with pytest.raises(ValueError, match=f"integrator '{integrator}' cannot take contact.*contact='none'"):
        scene.build(dt=0.01, integrator=integrator)
    with pytest.raises(ValueError, match="needs a velocity-first integrator"):
        scene.build(dt=0.01, integrator=integrator, contact="impulse")
    model, _, _ = scene.build(dt=0.01, integrator=integrator, contact="none")  # said out loud: allowed
    assert model.contact == "none" and model.num_contacts == 0


def test_params_replace_checks_as_the_scene_does():
    """replace(mass=-1) simulated to 1e29 m and replace(friction=0.3) failed deep in collision."""
    _, params, _ = full_scene3().build(dt=1e-3)
    n = params.mass.shape[0]
    for change, message in [(dict(mass=-1.0), r"'mass' must be > 0.0, got -1.0 at index \(0,\)"),
                            (dict(restitution=np.full(n, 1.5)), "'restitution' must be <= 1.0"),
                            (dict(dt=np.nan), "'dt' must be finite"),
                            (dict(inertia=np.zeros((n, 3, 3))), "'inertia' at index \\(0,\\) is singular"),
                            (dict(mass=np.ones(n + 1)), rf"'mass' must have shape \({n},\)"),
                            (dict(masses=np.ones(n)), "unknown field 'masses'")]:
        with pytest.raises(ValueError, match=message):
            params.replace(**change)
    # A number sets the whole field, in the field's dtype; a batch of the field's shape is taken.
    replaced = params.replace(friction=0.3, penalty_stiffness=2e4)
    np.testing.assert_allclose(replaced.friction, np.full(n, 0.3), rtol=1e-6)
    assert replaced.friction.dtype == params.friction.dtype and replaced.penalty_stiffness.shape == ()
    assert params.replace(mass=np.ones((4, n))).mass.shape == (4, n)
    # Traced values pass unchecked (a fit's transforms keep them physical).
    doubled = jax.jit(lambda p: p.replace(mass=2.0 * p.mass))(params)
    np.testing.assert_allclose(doubled.mass, 2.0 * params.mass)


def test_summary_counts_each_pair_kind_once_and_says_body():
    """It said '1 bodies' and listed 'polygon_plane x2, polygon_plane x4' with nothing telling them apart."""
    scene = rb.Scene(dim=2)
    scene.add_plane()
    scene.add_plane(normal=(1.0, 0.0), offset=-2.0)
    scene.add_body(rb.Polygon([(0.0, 0.0), (0.2, 0.0), (0.1, 0.2)]), mass=1.0, pos=(0.0, 0.5))
    for index in range(2):
        scene.add_body(rb.Box((0.1, 0.1)), mass=1.0, pos=(0.0, 0.3 * index + 0.1))
    summary = scene.build(dt=1 / 60)[0].summary()
    assert summary.count("polygon_plane") == 1 and "polygon_plane x6 in 2 kernels" in summary
    assert "3 bodies (2 Box, 1 Polygon)" in summary
    one = rb.Scene(dim=3)
    one.add_body(rb.Sphere(0.1), mass=1.0)
    assert "3D, 1 body (1 Sphere)" in one.build(dt=0.01)[0].summary()
