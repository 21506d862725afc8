"""jaxrb.math.small_linalg against NumPy's LAPACK: the joint dynamics' factorisations."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrb.math import small_linalg


@pytest.mark.parametrize("size", [1, 3, 7, 14])
def test_factorisations_solve_like_lapack(size):
    rng = np.random.default_rng(size)
    general = rng.normal(size=(size, size))
    spd = general @ general.T + size * np.eye(size)
    rhs = rng.normal(size=(size, 2))
    lower = small_linalg.cholesky(jnp.asarray(spd))  # float64: the suite enables x64 (conftest)
    np.testing.assert_allclose(lower, np.linalg.cholesky(spd), atol=1e-12)
    np.testing.assert_allclose(small_linalg.cholesky_solve(lower, jnp.asarray(rhs)), np.linalg.solve(spd, rhs),
                               atol=1e-12)
    packed, permutation = small_linalg.lu_factor(jnp.asarray(general))
    for right in (rhs, rhs[:, 0]):  # (n, k) and (n,)
        np.testing.assert_allclose(small_linalg.lu_solve(packed, permutation, jnp.asarray(right)),
                                   np.linalg.solve(general, right), atol=1e-9)


def test_lu_pivots_past_a_zero_leading_entry_and_differentiates():
    matrix = jnp.array([[0.0, 2.0], [3.0, 1.0]])
    packed, permutation = small_linalg.lu_factor(matrix)
    np.testing.assert_allclose(small_linalg.lu_solve(packed, permutation, jnp.array([2.0, 4.0])), [1.0, 1.0],
                               atol=1e-6)
    # d/dA of A⁻¹b is -A⁻¹ (dA) A⁻¹ b: check one entry's sensitivity against the closed form.
    grad = jax.grad(lambda a: small_linalg.lu_solve(*small_linalg.lu_factor(matrix.at[1, 0].set(a)),
                                                    jnp.array([2.0, 4.0]))[0])(3.0)
    inverse = np.linalg.inv(np.array([[0.0, 2.0], [3.0, 1.0]]))
    np.testing.assert_allclose(grad, -(inverse[:, 1] * 1.0)[0], atol=1e-5)
