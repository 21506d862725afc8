"""make_step and rollout under jit, vmap, grad; check_grads in float64; float32 end to end."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import jaxrb as rb
from conftest import assert_grad_matches_fd

INTEGRATORS = ["euler", "semi_implicit", "implicit_gyro", "rk4", "rk4_body"]


def mixed_scene(dim=3, integrator="semi_implicit", dtype=None, damping=0.0):
    """A few bodies of different kinds, spinning and moving, with gravity."""
    scene = rb.Scene(dim=dim)
    if dim == 3:
        scene.add_body(rb.Box((0.1, 0.2, 0.3)), mass=1.0, pos=(0, 0, 1), angvel=(1.0, 2.0, -0.5),
                       vel=(0.3, 0, 1), linear_damping=damping, angular_damping=damping)
        scene.add_body(rb.Capsule(0.05, 0.2), pos=(1, 0, 1), quat=(0.9, 0.1, 0.3, 0.2), angvel=(0, 3.0, 0))
        scene.add_body(rb.PointMasses([(0, 0, 0), (0.2, 0, 0), (0, 0.3, 0), (0, 0, 0.1)], [1, 2, 1, 0.5]),
                       pos=(0, 1, 1), angvel=(0.4, -0.3, 0.2))
    else:
        scene.add_body(rb.Box((0.1, 0.2)), mass=1.0, pos=(0, 1), angvel=2.0, vel=(0.3, 1),
                       linear_damping=damping, angular_damping=damping)
        scene.add_body(rb.Polygon([(0, 0), (0.3, 0), (0.1, 0.2)]), density=10.0, angle=0.4, angvel=-1.0)
    return scene.build(dt=0.01, integrator=integrator, dtype=dtype, contact="none")


@pytest.fixture(scope="module")
def scene3():
    model, params, state = mixed_scene()
    return model, params, state, jax.jit(rb.make_step(model))


def test_jit_matches_eager(scene3):
    model, params, state, jitted = scene3
    eager = rb.make_step(model)(state, params)
    for a, b in zip(jax.tree_util.tree_leaves(eager), jax.tree_util.tree_leaves(jitted(state, params))):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-14)


def test_second_call_does_not_recompile(scene3):
    model, params, state, jitted = scene3
    jitted(state, params)
    size = jitted._cache_size()
    jitted(state.replace(pos=state.pos + 1.0), params.replace(mass=params.mass * 2.0))
    assert jitted._cache_size() == size


def test_vmap_over_states_and_params_matches_loop(scene3):
    model, params, state, jitted = scene3
    offsets = jnp.linspace(0.0, 1.0, 4)
    states = jax.vmap(lambda d: state.replace(vel=state.vel + d))(offsets)
    batched = jax.jit(jax.vmap(jitted, in_axes=(0, None)))(states, params)
    masses = jax.vmap(lambda m: params.replace(force=params.force + m))(offsets)
    batched_params = jax.jit(jax.vmap(jitted, in_axes=(None, 0)))(state, masses)
    for i, offset in enumerate(offsets):
        single = jitted(state.replace(vel=state.vel + offset), params)
        np.testing.assert_allclose(batched.pos[i], single.pos, rtol=1e-12)
        np.testing.assert_allclose(batched.quat[i], single.quat, rtol=1e-12)
        single = jitted(state, params.replace(force=params.force + offset))
        np.testing.assert_allclose(batched_params.vel[i], single.vel, rtol=1e-12)


def test_grad_of_final_position(scene3):
    model, params, state, _ = scene3
    step = rb.make_step(model)

    def final_height(mass, params=params):
        final = rb.rollout(step, state, params.replace(mass=mass, force=params.force.at[:, 2].set(1.0)), 20)
        return final.pos[-1, :, 2].sum()

    grad = jax.jit(jax.grad(final_height))(params.mass)
    # z'' = g + 1/m, so d z(T)/dm = -(1/m²) * (semi-implicit sum of h² terms) < 0 for every body.
    assert np.all(np.isfinite(grad)) and np.all(np.asarray(grad) < 0.0)


# --- check_grads in float64 --------------------------------------------------------

@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("dim", [2, 3])
def test_check_grads_one_step(integrator, dim):
    model, params, state = mixed_scene(dim, integrator, damping=0.3)
    step = rb.make_step(model)

    def f(pos, vel, angvel, mass, inertia):
        s = step(state.replace(pos=pos, vel=vel, angvel=angvel), params.replace(mass=mass, inertia=inertia))
        return s.pos, s.vel, s.angvel, (s.quat if dim == 3 else s.angle)

    check_grads(jax.jit(f), (state.pos, state.vel, state.angvel, params.mass, params.inertia),
                order=1, modes=("fwd", "rev"), atol=1e-6, rtol=1e-6, eps=1e-6)


@pytest.mark.parametrize("integrator", ["semi_implicit", "implicit_gyro", "rk4", "rk4_body"])
def test_check_grads_fifty_step_rollout(integrator):
    model, params, state = mixed_scene(3, integrator)
    step = rb.make_step(model)

    def f(pos, quat, vel, angvel, mass, inertia):
        final = rb.rollout(step, state.replace(pos=pos, quat=quat, vel=vel, angvel=angvel),
                           params.replace(mass=mass, inertia=inertia), 50, every=50)
        return final.pos[-1], final.quat[-1], final.angvel[-1]

    check_grads(jax.jit(f), (state.pos, state.quat, state.vel, state.angvel, params.mass, params.inertia),
                order=1, modes=("rev",), atol=1e-5, rtol=1e-5, eps=1e-6)


@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("orientation", ["first_order", "exp_map"])
def test_gradients_finite_at_zero_angular_velocity(integrator, orientation):
    if integrator in ("rk4", "rk4_body"):
        orientation = None
    scene = rb.Scene(dim=3)
    scene.add_body(rb.Box((0.1, 0.1, 0.2)), mass=1.0)
    model, params, state = scene.build(dt=0.01, integrator=integrator, orientation=orientation)
    step = rb.make_step(model)

    def f(angvel, quat):
        final = rb.rollout(step, state.replace(angvel=angvel, quat=quat), params, 5, every=5)
        return jnp.sum(final.quat[-1] * jnp.array([0.3, 0.1, -0.2, 0.5])) + jnp.sum(final.angvel[-1])

    grads = assert_grad_matches_fd(f, (jnp.zeros((1, 3)), state.quat))
    # At ω = 0, perturbing ω rotates the body: the gradient is not identically zero.
    assert float(jnp.abs(grads[0]).sum()) > 0.0


# --- float32 ------------------------------------------------------------------------

@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_float32_end_to_end(dim, integrator):
    model, params, state = mixed_scene(dim, integrator, dtype=jnp.float32, damping=0.1)
    step = rb.make_step(model)
    traj = jax.jit(lambda s, p: rb.rollout(step, s, p, 100))(state, params)
    for leaf in jax.tree_util.tree_leaves(traj):
        assert leaf.dtype == jnp.float32
        assert np.all(np.isfinite(leaf))
    grad = jax.jit(jax.grad(lambda p: rb.rollout(step, state, p, 100).pos[-1].sum()))(params)
    for leaf in jax.tree_util.tree_leaves(grad):
        assert leaf.dtype == jnp.float32 and np.all(np.isfinite(leaf))
    reference = mixed_scene(dim, integrator, damping=0.1)
    traj64 = rb.rollout(rb.make_step(reference[0]), reference[2], reference[1], 100)
    np.testing.assert_allclose(traj.pos, traj64.pos, rtol=1e-4, atol=1e-5)


# --- rollout options ------------------------------------------------------------------

def test_rollout_every_and_checkpoint_agree(scene3):
    model, params, state, _ = scene3
    step = rb.make_step(model)
    run = jax.jit(lambda s, p, every, checkpoint: rb.rollout(step, s, p, 60, every=every, checkpoint=checkpoint),
                  static_argnums=(2, 3))
    plain, thinned, checkpointed = run(state, params, 1, False), run(state, params, 3, False), run(state, params, 3, True)
    np.testing.assert_allclose(thinned.pos, plain.pos[2::3], rtol=1e-12)
    np.testing.assert_allclose(checkpointed.quat, thinned.quat, rtol=1e-12)
    assert thinned.time.shape == (20,)

    def loss(p, checkpoint):
        return rb.rollout(step, state, p, 60, every=3, checkpoint=checkpoint).pos[-1].sum()

    grad_plain = jax.jit(jax.grad(loss), static_argnums=1)(params, False)
    grad_checkpointed = jax.jit(jax.grad(loss), static_argnums=1)(params, 4)
    for a, b in zip(jax.tree_util.tree_leaves(grad_plain), jax.tree_util.tree_leaves(grad_checkpointed)):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("dim", [3, 2])
def test_rollout_inverts_inertia_once_with_the_same_gradient(dim):
    # rollout fills Params.inv_inertia outside its scan; a plain scan of the
    # step inverts inertia in every step. Values and gradients must agree,
    # and a stale inv_inertia handed to rollout must be replaced, not used.
    model, params, state = mixed_scene(dim)
    params = params.replace(torque=jnp.full_like(params.torque, 0.3))  # so 2D angvel depends on inertia
    step = rb.make_step(model)

    def by_scan(p):
        return jax.lax.scan(lambda s, _: (step(s, p),) * 2, state, length=40)[1]

    def loss(trajectory):
        return jnp.sum(trajectory.pos ** 2) + jnp.sum(trajectory.angvel ** 2)

    stale = params.replace(inv_inertia=2.0 * rb.physics.dynamics.inverse_inertia(params, dim))
    traj = rb.rollout(step, state, stale, 40)
    reference = by_scan(params)
    np.testing.assert_allclose(traj.angvel, reference.angvel, rtol=1e-12, atol=1e-14)
    grad = jax.grad(lambda p: loss(rb.rollout(step, state, p, 40)))(params)
    grad_reference = jax.grad(lambda p: loss(by_scan(p)))(params)
    assert grad.inv_inertia is None
    assert float(jnp.max(jnp.abs(grad_reference.inertia))) > 1e-3  # inertia really matters here
    np.testing.assert_allclose(grad.inertia, grad_reference.inertia, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(grad.mass, grad_reference.mass, rtol=1e-10, atol=1e-12)


def test_checkpoint_lowers_memory_of_thinned_rollouts(scene3):
    # Rollout rematerialises every step, so its reverse mode keeps at most a
    # State a step; with every = 10 the saved trajectory is small, and
    # segments of about √(T / every) saved states keep a few times less
    # (measured: 88 against 19 bytes a step; with every = 1, 217 against 148).
    model, params, state, _ = scene3
    step = rb.make_step(model)

    def temp_bytes(checkpoint):
        loss = lambda p: jnp.sum(rb.rollout(step, state, p, 1000, every=10, checkpoint=checkpoint).pos ** 2)
        return jax.jit(jax.grad(loss)).lower(params).compile().memory_analysis().temp_size_in_bytes

    assert temp_bytes(True) < temp_bytes(False) / 3


def test_rollout_applied_wrench_sequence():
    scene = rb.Scene(dim=2, gravity=(0.0, 0.0))
    scene.add_body(rb.Circle(0.1), mass=2.0)
    model, params, state = scene.build(dt=0.1)
    force = jnp.zeros((10, 1, 2)).at[:5, 0, 0].set(4.0)  # 2 m/s² for 0.5 s, then coast
    applied = rb.Wrench(force=force, torque=jnp.zeros((10, 1)))
    traj = rb.rollout(rb.make_step(model), state, params, 10, applied=applied)
    np.testing.assert_allclose(traj.vel[-1, 0], [1.0, 0.0], rtol=1e-12)


def test_rollout_rejects_bad_arguments(scene3):
    model, params, state, _ = scene3
    step = rb.make_step(model)
    with pytest.raises(ValueError, match="multiple"):
        rb.rollout(step, state, params, 10, every=3)
    with pytest.raises(ValueError, match="divisor"):
        rb.rollout(step, state, params, 10, checkpoint=3)


@pytest.mark.parametrize("contact", ["impulse", "penalty"])
def test_user_loop_and_rollout_give_the_same_states(contact):
    """A fori_loop over vmap(step), as the README's loop, against vmap(rollout): one step, one result.

    A box lands on a plane at 4 start heights (the penalty model takes
    make_step's component form); float64, 120 steps of 2 ms. Two compiled
    programs may fuse the same arithmetic differently (contraction, sum
    order), and contact amplifies that rounding: equal to 1e-9, not bit for
    bit (a wrong or missing stage shows at 1e-3 and above).
    """
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.6)
    scene.add_body(rb.Box((0.1, 0.15, 0.05)), mass=1.0, pos=(0.0, 0.0, 0.2), vel=(0.5, 0.0, -1.0),
                   angvel=(2.0, -1.0, 3.0), quat=(0.9, 0.3, 0.1, 0.2), restitution=0.3)
    model, params, state = scene.build(dt=0.002, contact=contact, dtype=jnp.float64)
    step = rb.make_step(model)
    states = jax.vmap(lambda z: state.replace(pos=state.pos.at[0, 2].set(z)))(jnp.linspace(0.15, 0.3, 4))
    loop = jax.jit(lambda s: jax.lax.fori_loop(0, 120, lambda _, x: jax.vmap(step, in_axes=(0, None))(x, params), s))
    scanned = jax.jit(jax.vmap(lambda s: rb.rollout(step, s, params, 120, every=120)))
    by_loop, by_rollout = loop(states), scanned(states)
    assert float(jnp.min(by_loop.pos[:, 0, 2])) < 0.16  # landed
    for field in ("pos", "vel", "angvel", "quat", "contact_impulse"):
        np.testing.assert_allclose(np.asarray(getattr(by_loop, field)), np.asarray(getattr(by_rollout, field)[:, -1]),
                                   atol=1e-9, rtol=0, err_msg=field)
