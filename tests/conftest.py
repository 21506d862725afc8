"""Shared test setup.

x64 is enabled for the whole session so physics checks can use float64
tolerances; float32 tests ask for it explicitly with ``scene.build(dtype=...)``
and check that nothing promotes to float64.
"""

import jax
import pytest

jax.config.update("jax_enable_x64", True)

import jaxrb as rb  # noqa: E402

# Principal inertia and initial body-frame spin of the torque-free benchmark body.
TUMBLE_INERTIA = (0.3, 0.35, 0.4)
TUMBLE_ANGVEL = (0.1, 15.0, 0.1)


def tumbling_scene(integrator="rk4", dt=1.0 / 240.0, orientation=None, dtype=None):
    """One box-inertia body spinning near its intermediate axis, no gravity."""
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, 0.0))
    scene.add_body(None, mass=1.0, inertia=TUMBLE_INERTIA, angvel=TUMBLE_ANGVEL)
    return scene.build(dt=dt, integrator=integrator, orientation=orientation, dtype=dtype)


@pytest.fixture(scope="session")
def euler_reference():
    """Body-frame ω(t) of the tumbling body from scipy's DOP853 on Euler's equations."""
    import numpy as np
    from scipy.integrate import solve_ivp

    inertia = np.array(TUMBLE_INERTIA)

    def euler_equations(_, omega):
        return (np.roll(inertia, -1) - np.roll(inertia, 1)) * np.roll(omega, -1) * np.roll(omega, 1) / inertia

    def solve(t_end, times=None):
        return solve_ivp(euler_equations, (0.0, t_end), np.array(TUMBLE_ANGVEL), method="DOP853",
                         rtol=1e-12, atol=1e-12, t_eval=times, dense_output=True)

    return solve


def assert_grad_matches_fd(fn, args, rtol=1e-6, eps=1e-6, directions=3, seed=0):
    """Compare autodiff with central finite differences along random directions.

    ``fn`` maps ``args`` (a tuple of arrays) to a scalar. Value and gradient are
    jitted once, so this stays cheap for rollouts (check_grads retraces per call).
    Returns the gradient so callers can assert more about it.
    """
    import jax.numpy as jnp
    import numpy as np

    value = jax.jit(fn)
    grad = jax.jit(jax.grad(fn, argnums=tuple(range(len(args)))))(*args)
    rng = np.random.default_rng(seed)
    for _ in range(directions):
        tangent = [jnp.asarray(rng.normal(size=np.shape(a))) for a in args]
        plus = value(*[a + eps * t for a, t in zip(args, tangent)])
        minus = value(*[a - eps * t for a, t in zip(args, tangent)])
        finite_difference = float(plus - minus) / (2.0 * eps)
        directional = float(sum(jnp.sum(g * t) for g, t in zip(grad, tangent)))
        assert np.isfinite(directional)
        assert abs(directional - finite_difference) <= rtol * max(1.0, abs(finite_difference)), \
            (directional, finite_difference)
    return grad

def assert_same_build(first, second):
    """Two (model, params, state) triples are equal: static Model, every leaf and its dtype."""
    import numpy as np

    (model_a, params_a, state_a), (model_b, params_b, state_b) = first, second
    assert model_a == model_b
    leaves_a = jax.tree_util.tree_leaves_with_path((params_a, state_a))
    leaves_b = jax.tree_util.tree_leaves((params_b, state_b))
    assert len(leaves_a) == len(leaves_b)
    for (path, a), b in zip(leaves_a, leaves_b):
        assert a.dtype == b.dtype, jax.tree_util.keystr(path)
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=jax.tree_util.keystr(path))
