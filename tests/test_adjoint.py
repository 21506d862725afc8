"""``rb.rollout(..., adjoint=True)``: the hand-written adjoint against autodiff (float64).

The adjoint and autodiff compute the same derivatives in a different order,
so in float64 they agree to rounding: over these 40-step rollouts they
differ by about 1e-13 of each gradient's size (measured); the tests allow
1e-9. The States are not recomputed, so they must be identical.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrb as rb

NUM_STEPS = 40


def free_scene(bodies=2):
    """Tumbling bodies with full (non-diagonal) inertia, gravity and constant loads."""
    scene = rb.Scene(dim=3, gravity=(0.3, -0.2, -9.81))
    inertia = np.array([[0.30, 0.02, -0.01], [0.02, 0.35, 0.015], [-0.01, 0.015, 0.40]])
    for i in range(bodies):
        scene.add_body(None, mass=1.0 + 0.3 * i, inertia=inertia * (1.0 + 0.2 * i), pos=(0.1 * i, 0.0, 1.0),
                       quat=(1.0, 0.2 * i, 0.1, -0.3), vel=(0.5, -0.2 * i, 1.0), angvel=(0.1 + i, 15.0, 0.3))
    return scene


def loss(trajectory):
    """Every State field the step writes, so each of their cotangents is exercised."""
    return (jnp.mean(trajectory.pos ** 2) + jnp.mean(trajectory.vel ** 2) + jnp.mean(trajectory.angvel ** 2)
            + jnp.mean(trajectory.quat[..., 1:] ** 2) + jnp.mean(jnp.sin(trajectory.time)))


CASES = {
    "exp_map": dict(build=dict(dt=1 / 120), every=1, applied=False),
    "first_order, 2 substeps, every 4, applied loads": dict(
        build=dict(dt=1 / 60, orientation="first_order", substeps=2), every=4, applied=True),
}


def applied_loads(num_bodies):
    steps = jnp.arange(NUM_STEPS, dtype=jnp.float64)[:, None, None]
    return rb.Wrench(force=jnp.sin(0.3 * steps + jnp.arange(3.0)) * jnp.ones((1, num_bodies, 1)),
                     torque=0.05 * jnp.cos(0.2 * steps + jnp.arange(3.0)) * jnp.ones((1, num_bodies, 1)))


@pytest.fixture(scope="module", params=list(CASES))
def case(request):
    setting = CASES[request.param]
    model, params, state = free_scene().build(**setting["build"])
    params = params.replace(force=params.force + 0.4, torque=params.torque + jnp.array([0.02, -0.01, 0.03]))
    step = rb.make_step(model)
    applied = applied_loads(model.num_bodies) if setting["applied"] else None

    def objective(adjoint):
        def value(params, state, applied):
            return loss(rb.rollout(step, state, params, NUM_STEPS, every=setting["every"], applied=applied,
                                   adjoint=adjoint))
        return jax.jit(jax.grad(value, argnums=(0, 1, 2)))

    return dict(step=step, params=params, state=state, applied=applied, every=setting["every"],
                autodiff=objective(False)(params, state, applied), adjoint=objective(True)(params, state, applied))


def assert_same_gradients(expected, got):
    """Each leaf of ``got`` finite and within 1e-9 of autodiff's largest entry; returns the non-zero leaves."""
    nonzero = 0
    for (path, want), have in zip(jax.tree_util.tree_leaves_with_path(expected), jax.tree_util.tree_leaves(got)):
        scale = float(jnp.max(jnp.abs(want), initial=0.0))
        assert bool(jnp.all(jnp.isfinite(have))), jax.tree_util.keystr(path)
        np.testing.assert_allclose(have, want, rtol=0, atol=1e-9 * max(scale, 1e-300),
                                   err_msg=jax.tree_util.keystr(path))
        nonzero += scale > 0
    return nonzero


def test_gradients_equal_autodiffs(case):
    # mass, inertia, gravity, dt, force, torque; pos, vel, angvel, quat, time; the applied loads.
    assert assert_same_gradients(case["autodiff"], case["adjoint"]) >= 11


def test_states_are_bit_for_bit_the_rollouts(case):
    plain = rb.rollout(case["step"], case["state"], case["params"], NUM_STEPS, every=case["every"],
                       applied=case["applied"])
    adjoint = rb.rollout(case["step"], case["state"], case["params"], NUM_STEPS, every=case["every"],
                         applied=case["applied"], adjoint=True)
    for a, b in zip(jax.tree_util.tree_leaves(plain), jax.tree_util.tree_leaves(adjoint)):
        assert a.shape == b.shape and bool(jnp.array_equal(a, b))


def test_vmapped_gradient_equals_autodiffs():
    model, params, state = free_scene(bodies=1).build(dt=1 / 120)
    step = rb.make_step(model)
    states = state.replace(angvel=state.angvel * jnp.array([1.0, 0.5, -2.0])[:, None, None],
                           pos=jnp.broadcast_to(state.pos, (3,) + state.pos.shape),
                           vel=jnp.broadcast_to(state.vel, (3,) + state.vel.shape),
                           quat=jnp.broadcast_to(state.quat, (3,) + state.quat.shape),
                           time=jnp.zeros(3))

    def batch_loss(adjoint):
        def value(params):
            per_world = jax.vmap(lambda s: loss(rb.rollout(step, s, params, NUM_STEPS, adjoint=adjoint)))(states)
            return jnp.sum(per_world)
        return jax.jit(jax.grad(value))(params)

    assert assert_same_gradients(batch_loss(False), batch_loss(True)) >= 5


def test_gradient_is_finite_at_rest():
    # Zero angular velocity takes the exponential map's series branch, and
    # zero velocities make every cross product in the adjoint vanish.
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, 0.0))
    scene.add_body(None, mass=1.0, inertia=(0.3, 0.35, 0.4))
    model, params, state = scene.build(dt=1 / 60)
    step = rb.make_step(model)
    def gradient(adjoint):
        return jax.jit(jax.grad(lambda p: loss(rb.rollout(step, state, p, NUM_STEPS, adjoint=adjoint))))(params)

    assert_same_gradients(gradient(False), gradient(True))


def test_forward_mode_is_refused():
    model, params, state = free_scene(bodies=1).build(dt=1 / 120)
    step = rb.make_step(model)
    with pytest.raises(TypeError, match="custom_vjp"):
        jax.jvp(lambda dt: rb.rollout(step, state, params.replace(dt=dt), 5, adjoint=True).pos,
                (params.dt,), (jnp.ones_like(params.dt),))


def scenes_without_an_adjoint():
    box = rb.Scene(dim=3)
    box.add_plane()
    box.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.5))
    damped = rb.Scene(dim=3)
    damped.add_body(None, mass=1.0, inertia=(1.0, 1.0, 1.0), angular_damping=0.1)
    flat = rb.Scene(dim=2)
    flat.add_body(None, mass=1.0, inertia=1.0)
    return {"impulse contact": (box, dict(dt=1 / 60, contact="impulse")),
            "damping": (damped, dict(dt=1 / 60)),
            "rk4": (free_scene(1), dict(dt=1 / 60, integrator="rk4")),
            "2D": (flat, dict(dt=1 / 60))}


@pytest.mark.parametrize("name", list(scenes_without_an_adjoint()))
def test_models_without_an_adjoint_are_value_errors(name):
    scene, settings = scenes_without_an_adjoint()[name]
    model, params, state = scene.build(**settings)
    with pytest.raises(ValueError, match="adjoint=True is written for 3D semi-implicit models without damping"):
        rb.rollout(rb.make_step(model), state, params, 3, adjoint=True)


def test_checkpoint_and_foreign_steps_are_value_errors():
    model, params, state = free_scene(bodies=1).build(dt=1 / 60)
    with pytest.raises(ValueError, match="checkpoint"):
        rb.rollout(rb.make_step(model), state, params, 4, checkpoint=True, adjoint=True)
    with pytest.raises(ValueError, match="make_step"):
        rb.rollout(lambda s, p, a=None: s, state, params, 4, adjoint=True)
