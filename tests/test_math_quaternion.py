"""Quaternion algebra and safe math: values against closed forms, gradients by check_grads."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxrb.math import components as vec
from jaxrb.math import vector as rbm
from jaxrb.math import quaternion as Q
RNG = np.random.default_rng(0)


def random_quats(count):
    q = RNG.normal(size=(count, 4))
    return jnp.asarray(q / np.linalg.norm(q, axis=1, keepdims=True))


def test_multiply_matches_rotation_composition():
    a, b = random_quats(5), random_quats(5)
    composed = Q.to_rotation_matrix(Q.multiply(a, b))
    np.testing.assert_allclose(composed, Q.to_rotation_matrix(a) @ Q.to_rotation_matrix(b), atol=1e-12)


def test_rotation_matrix_is_orthonormal_and_matches_rotate():
    q, v = random_quats(7), jnp.asarray(RNG.normal(size=(7, 3)))
    rotation = Q.to_rotation_matrix(q)
    np.testing.assert_allclose(rotation @ jnp.swapaxes(rotation, -1, -2), np.broadcast_to(np.eye(3), (7, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(rotation), 1.0, atol=1e-12)
    np.testing.assert_allclose(Q.rotate(q, v), np.einsum("nij,nj->ni", rotation, v), atol=1e-12)
    np.testing.assert_allclose(Q.rotate_inverse(q, Q.rotate(q, v)), v, atol=1e-12)


def test_conjugate_inverts():
    q = random_quats(4)
    np.testing.assert_allclose(Q.multiply(q, Q.conjugate(q)), np.tile([1.0, 0, 0, 0], (4, 1)), atol=1e-12)


def test_axis_angle_quarter_turn_about_z():
    q = Q.from_axis_angle(jnp.array([0.0, 0.0, 2.0]), jnp.pi / 2)
    np.testing.assert_allclose(Q.rotate(q, jnp.array([1.0, 0.0, 0.0])), [0.0, 1.0, 0.0], atol=1e-12)


def test_exp_map_matches_axis_angle_and_identity_at_zero():
    rotvec = jnp.array([0.3, -0.2, 0.5])
    angle = float(jnp.linalg.norm(rotvec))
    np.testing.assert_allclose(Q.exp(rotvec), Q.from_axis_angle(rotvec, angle), atol=1e-12)
    np.testing.assert_allclose(Q.exp(jnp.zeros(3)), [1.0, 0.0, 0.0, 0.0])
    # Just above and below the Taylor switch the two branches agree.
    for theta in (0.9e-4, 1.1e-4):
        small = jnp.array([theta, 0.0, 0.0])
        np.testing.assert_allclose(Q.exp(small), [np.cos(theta / 2), np.sin(theta / 2), 0, 0], atol=1e-15)


@pytest.mark.parametrize("update", [Q.integrate_first_order, Q.integrate_exp_map])
def test_orientation_updates_rotate_about_constant_axis(update):
    """A constant ω about z for time T rotates by |ω|T; exp_map exactly, first order to O(h)."""
    q = jnp.array([[1.0, 0.0, 0.0, 0.0]])
    angvel, h, steps = jnp.array([[0.0, 0.0, 2.0]]), 1e-3, 500
    for _ in range(steps):
        q = update(q, angvel, h)
    angle = 2.0 * np.arctan2(float(q[0, 3]), float(q[0, 0]))
    tolerance = 1e-12 if update is Q.integrate_exp_map else 1e-3
    assert abs(angle - 1.0) < tolerance
    np.testing.assert_allclose(jnp.linalg.norm(q), 1.0, atol=1e-12)


def test_safe_functions_finite_at_zero():
    zero = jnp.zeros(3)
    assert float(rbm.safe_norm(zero)) == 0.0
    np.testing.assert_array_equal(jax.grad(rbm.safe_norm)(zero), np.zeros(3))
    np.testing.assert_array_equal(rbm.safe_normalize(zero), np.zeros(3))
    assert np.all(np.isfinite(jax.jacobian(rbm.safe_normalize)(zero)))
    assert float(jax.grad(lambda d: rbm.safe_div(1.0, d))(0.0)) == 0.0
    np.testing.assert_allclose(Q.normalize(jnp.zeros(4)), [1.0, 0.0, 0.0, 0.0])
    assert np.all(np.isfinite(jax.jacobian(Q.normalize)(jnp.zeros(4))))


def test_inverse3_and_matvec3():
    matrix = jnp.asarray(RNG.normal(size=(4, 3, 3)) + 3 * np.eye(3))
    np.testing.assert_allclose(rbm.inverse3(matrix), np.linalg.inv(matrix), atol=1e-12)
    vector = jnp.asarray(RNG.normal(size=(4, 3)))
    np.testing.assert_allclose(rbm.matvec3(matrix, vector), np.einsum("nij,nj->ni", matrix, vector), atol=1e-12)
    np.testing.assert_allclose(rbm.cross(vector, vector[::-1]), np.cross(vector, vector[::-1]), atol=1e-12)


@pytest.mark.parametrize("shape_a, shape_b", [((8, 3), (3, 3)), ((4, 8, 3), (4, 3, 2)), ((15, 3), (3,)),
                                              ((4, 8, 3), (3,)), ((9,), (9, 3)), ((2,), (4, 2, 3)), ((3,), (3,))])
def test_matmul_matches_numpy(shape_a, shape_b):
    a, b = RNG.normal(size=shape_a), RNG.normal(size=shape_b)
    product = rbm.matmul(jnp.asarray(a), jnp.asarray(b))
    assert product.shape == (a @ b).shape
    np.testing.assert_allclose(product, a @ b, atol=1e-12)


def test_rotate2_matches_rot2():
    angle, v = jnp.asarray(RNG.normal(size=5)), jnp.asarray(RNG.normal(size=(5, 2)))
    np.testing.assert_allclose(rbm.rotate2(angle, v), np.einsum("nij,nj->ni", rbm.rot2(angle), v), atol=1e-12)


def parts(array):
    return tuple(array[..., i] for i in range(array.shape[-1]))


def test_component_orientation_updates_equal_the_array_ones():
    q, w = random_quats(6), jnp.asarray(RNG.normal(size=(6, 3)) * 3.0)
    w = w.at[0].set(0.0)  # the small-angle branch of the exp map too
    for name, update in Q.ORIENTATION_UPDATES.items():
        expected = update(q, w, 0.05)
        got = jnp.stack(Q.ORIENTATION_UPDATES_PARTS[name](parts(q), parts(w), 0.05), axis=-1)
        np.testing.assert_allclose(got, expected, atol=1e-12, err_msg=name)
    np.testing.assert_allclose(jnp.stack(Q.normalize_parts(parts(jnp.zeros((2, 4)))), axis=-1),
                               np.tile([1.0, 0.0, 0.0, 0.0], (2, 1)))


def test_component_vectors_with_structural_zeros_match_numpy():
    a, b = RNG.normal(size=(2, 5, 3))
    matrix = RNG.normal(size=(5, 3, 3))
    as_parts = lambda x: tuple(jnp.asarray(x[..., i]) for i in range(3))
    stacked = lambda v: np.stack([np.broadcast_to(np.asarray(part), (5,)) for part in v], axis=-1)
    for zero in range(3):  # a with a structural zero in each place, as a plane's normal makes
        a_zero = a.copy()
        a_zero[:, zero] = 0.0
        a_parts = tuple(0.0 if i == zero else jnp.asarray(a[:, i]) for i in range(3))
        np.testing.assert_allclose(vec.dot(a_parts, as_parts(b)), np.sum(a_zero * b, axis=-1), atol=1e-12)
        np.testing.assert_allclose(stacked(vec.cross(a_parts, as_parts(b))), np.cross(a_zero, b), atol=1e-12)
        np.testing.assert_allclose(stacked(vec.cross(as_parts(b), a_parts)), np.cross(b, a_zero), atol=1e-12)
        np.testing.assert_allclose(stacked(vec.sub(a_parts, as_parts(b))), a_zero - b, atol=1e-12)
        np.testing.assert_allclose(stacked(vec.sub(as_parts(b), a_parts)), b - a_zero, atol=1e-12)
        np.testing.assert_allclose(stacked(vec.add(a_parts, as_parts(b))), a_zero + b, atol=1e-12)
        rows = tuple(tuple(jnp.asarray(matrix[:, i, j]) for j in range(3)) for i in range(3))
        np.testing.assert_allclose(stacked(vec.matvec(rows, a_parts)), np.einsum("nij,nj->ni", matrix, a_zero),
                                   atol=1e-12)
        np.testing.assert_allclose(stacked(vec.matvec_transposed(rows, a_parts)),
                                   np.einsum("nji,nj->ni", matrix, a_zero), atol=1e-12)
    assert vec.is_zero(vec.dot((0.0, 0.0, 0.0), as_parts(b)))
    limit = jnp.asarray(np.abs(RNG.normal(size=5)))
    clamped = stacked(vec.clamp_to_disc(as_parts(a), limit))
    expected = a * np.minimum(1.0, np.asarray(limit) / np.linalg.norm(a, axis=-1))[:, None]
    np.testing.assert_allclose(clamped, expected, atol=1e-12)


# --- gradients (float64, both modes, second order) ---

Q1, Q2 = random_quats(1)[0], random_quats(1)[0]
V = jnp.asarray(RNG.normal(size=3))


@pytest.mark.parametrize("name,fn,args", [
    ("multiply", Q.multiply, (Q1, Q2)),
    ("rotate", Q.rotate, (Q1, V)),
    ("rotate_inverse", Q.rotate_inverse, (Q1, V)),
    ("to_rotation_matrix", Q.to_rotation_matrix, (Q1,)),
    ("normalize", Q.normalize, (Q1 * 1.7,)),
    ("exp", Q.exp, (V,)),
    ("exp_at_zero", Q.exp, (jnp.zeros(3),)),
    ("from_axis_angle", Q.from_axis_angle, (V, 0.7)),
    ("first_order", lambda q, w: Q.integrate_first_order(q, w, 0.01), (Q1, V)),
    ("first_order_at_zero_w", lambda q, w: Q.integrate_first_order(q, w, 0.01), (Q1, jnp.zeros(3))),
    ("exp_map", lambda q, w: Q.integrate_exp_map(q, w, 0.01), (Q1, V)),
    ("exp_map_at_zero_w", lambda q, w: Q.integrate_exp_map(q, w, 0.01), (Q1, jnp.zeros(3))),
    ("safe_norm", rbm.safe_norm, (V,)),
    ("safe_normalize", rbm.safe_normalize, (V,)),
    ("inverse3", rbm.inverse3, (jnp.eye(3) * 2.0 + 0.1,)),
    ("rotate2", rbm.rotate2, (0.3, V[:2])),
])
def test_check_grads(name, fn, args):
    check_grads(fn, args, order=2, modes=("fwd", "rev"), atol=1e-6, rtol=1e-6)
