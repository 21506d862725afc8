"""make_step's component form (jaxrb.physics.plane_penalty) against the step on (n, 3) arrays.

Both are the same physics; make_step returns the component form for every
model :func:`supports` accepts. Each test rolls a scene out both ways (the
generic way with ``jaxrb.physics.step.generic_step``) in float64, where the two differ only by rounding (1e-16 relative), which
stiff contact amplifies over a few hundred steps to about 1e-9; a wrong
sign, a missed term or a dropped row shows up at 1e-3 and above.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrb as rb
from jaxrb.physics import plane_penalty
from jaxrb.physics.step import generic_step

FIELDS = ("pos", "vel", "angvel", "quat", "contact_impulse", "contact_key", "time", "overflow")
STEPS = 210
TOLERANCE = 1e-7  # float64 rounding amplified by a few hundred steps of contact (about 1e-9)


# Bodies touch planes only: a pair between two bodies would take the generic step.
PLANES_ONLY = dict(collision_category=2, collision_mask=1)


def tumbling_scene():
    """A box, a sphere, a capsule and a point-mass body dropped with spin onto a plane."""
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.6, restitution=0.2)
    scene.add_body(rb.Box((0.1, 0.15, 0.05)), mass=1.0, pos=(0.0, 0.0, 0.3), vel=(0.5, 0.0, -1.0),
                   angvel=(2.0, -1.0, 3.0), quat=(0.9, 0.3, 0.1, 0.2), restitution=0.5, **PLANES_ONLY)
    scene.add_body(rb.Sphere(0.1), mass=2.0, pos=(1.0, 0.0, 0.2), vel=(1.0, 0.5, 0.0), angvel=(0.0, 5.0, 0.0),
                   **PLANES_ONLY)
    scene.add_body(rb.Capsule(0.05, 0.2), mass=0.5, pos=(-1.0, 0.0, 0.25), angvel=(1.0, 1.0, 0.0),
                   quat=(0.8, 0.0, 0.6, 0.0), friction=0.9, **PLANES_ONLY)
    # Point masses off their centre of mass: the body-frame points carry a com offset.
    scene.add_body(rb.PointMasses(points=[(0.0, 0.0, 0.0), (0.2, 0.0, 0.0), (0.0, 0.1, 0.05)],
                                  masses=[1.0, 2.0, 1.0]), pos=(0.0, 1.0, 0.15), angvel=(0.0, 0.0, 4.0),
                   **PLANES_ONLY)
    return scene


def two_planes_scene():
    """A box sliding into a wall: two groups' normals differ, one body in both."""
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.5)
    scene.add_plane(normal=(-1.0, 0.0, 0.2), offset=-0.3, friction=0.3, restitution=0.4)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.12), vel=(2.0, 0.3, 0.0),
                   angvel=(0.0, 0.0, 1.0), linear_damping=0.3, angular_damping=0.1, **PLANES_ONLY)
    scene.add_body(rb.Sphere(0.1), mass=1.0, pos=(0.1, 0.5, 0.1), vel=(1.5, 0.0, 0.0), **PLANES_ONLY)
    return scene


def rollouts(scene, applied=False, **build):
    """The rollout both ways, float64: (component form, generic)."""
    model, params, state = scene.build(**{"dt": 0.002, "contact": "penalty", "dtype": jnp.float64, **build})
    step, generic = rb.make_step(model), generic_step(model)
    wrench = None
    if applied:
        n = model.num_bodies
        t = jnp.arange(STEPS, dtype=jnp.float64)[:, None, None]
        wrench = rb.Wrench(force=jnp.sin(0.05 * t) * jnp.ones((STEPS, n, 3)),
                           torque=0.1 * jnp.cos(0.03 * t) * jnp.ones((STEPS, n, 3)))
    run = lambda stepper: jax.jit(lambda s, p: rb.rollout(stepper, s, p, STEPS, every=3, applied=wrench))
    return run(step)(state, params), run(generic)(state, params)


def assert_same(fast, generic):
    for field in FIELDS:
        np.testing.assert_allclose(np.asarray(getattr(fast, field), dtype=np.float64),
                                   np.asarray(getattr(generic, field), dtype=np.float64),
                                   atol=TOLERANCE, rtol=0, err_msg=field)


@pytest.mark.parametrize("build", [
    {},
    {"substeps": 2, "orientation": "first_order"},
    {"contact": rb.Penalty(width=2e-3)},
    {"contact": rb.Penalty(friction="regularized")},
    {"contact": rb.Penalty(damping=30.0)},
], ids=["default", "substeps-first-order", "smooth", "regularized", "fixed-damper"])
def test_component_rollout_equals_the_step(build):
    fast, generic = rollouts(tumbling_scene(), **build)
    # The scene does touch: rows press and friction springs hold a force.
    assert np.max(np.asarray(generic.contact_impulse[..., 0])) > 0.0
    assert np.max(np.abs(np.asarray(generic.contact_impulse[..., 1:]))) > 0.0
    assert_same(fast, generic)


def test_component_rollout_with_two_planes_damping_and_applied_wrenches():
    fast, generic = rollouts(two_planes_scene(), applied=True)
    # Both bodies reach the wall (plane 1, at x ≈ 0.3 - 0.1) and come back off it.
    x = np.asarray(generic.pos[:, :, 0])
    assert np.all(x.max(axis=0) > 0.19) and np.all(x[-1] < x.max(axis=0) - 0.02)
    assert np.max(np.asarray(generic.contact_impulse[..., 0])) > 0.0
    assert_same(fast, generic)


def test_component_rollout_on_a_tilted_plane():
    scene = rb.Scene(dim=3)
    scene.add_plane(normal=(0.0, 0.3, 1.0), friction=0.8)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.11), angvel=(0.0, 1.0, 0.0))
    fast, generic = rollouts(scene)
    assert_same(fast, generic)


def test_saved_state_carries_over_into_the_generic_step():
    """A rollout's last state continues under the plain step as from the generic rollout."""
    model, params, state = tumbling_scene().build(dt=0.002, contact="penalty", dtype=jnp.float64)
    step = rb.make_step(model)
    fast = jax.jit(lambda s, p: rb.rollout(step, s, p, 50, every=50))(state, params)
    last = jax.tree_util.tree_map(lambda a: a[-1], fast)
    after_fast = jax.jit(step)(last, params)
    generic = jax.jit(lambda s, p: rb.rollout(generic_step(model), s, p, 51, every=51))(state, params)
    np.testing.assert_allclose(np.asarray(after_fast.pos), np.asarray(generic.pos[-1]), atol=TOLERANCE, rtol=0)


def test_checkpointed_component_rollout_equals_the_plain_one():
    model, params, state = two_planes_scene().build(dt=0.002, contact="penalty", dtype=jnp.float64)
    step = rb.make_step(model)
    plain, segmented = (jax.jit(lambda s, p, c=c: rb.rollout(step, s, p, 60, every=2, checkpoint=c))(state, params)
                        for c in (False, True))
    for field in FIELDS:
        np.testing.assert_array_equal(np.asarray(getattr(plain, field)), np.asarray(getattr(segmented, field)))


def test_gradients_of_the_component_rollout_equal_the_steps():
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.6)
    # Lands within 30 steps, tumbling and sliding: normal force, friction and torque all act.
    scene.add_body(rb.Box((0.1, 0.15, 0.05)), mass=1.0, pos=(0.0, 0.0, 0.15), vel=(0.5, 0.0, -1.0),
                   angvel=(2.0, -1.0, 3.0), quat=(0.9, 0.3, 0.1, 0.2), restitution=0.5)
    model, params, state = scene.build(dt=0.002, contact="penalty", dtype=jnp.float64)
    step, generic = rb.make_step(model), generic_step(model)

    def loss(stepper):
        def of(friction, restitution, mass):
            p = params.replace(friction=friction, restitution=restitution, mass=mass)
            traj = rb.rollout(stepper, state, p, 60)
            return jnp.sum(traj.pos[:, :, 2] ** 2) + jnp.sum(traj.angvel[-1] ** 2)
        return jax.jit(jax.grad(of, argnums=(0, 1, 2)))

    fast = loss(step)(params.friction, params.restitution, params.mass)
    slow = loss(generic)(params.friction, params.restitution, params.mass)
    for a, b in zip(fast, slow):
        assert np.all(np.isfinite(np.asarray(a)))
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6, atol=1e-9)
    assert np.all(np.abs(np.asarray(slow[0])) > 1e-3)  # friction does act on the loss


def test_only_plane_penalty_semi_implicit_3d_models_take_the_component_form():
    scene = tumbling_scene()
    assert plane_penalty.supports(scene.build(dt=0.002, contact="penalty")[0])
    assert not plane_penalty.supports(scene.build(dt=0.002, contact="impulse")[0])
    assert not plane_penalty.supports(scene.build(dt=0.002, contact="penalty", integrator="implicit_gyro")[0])
    two_boxes = rb.Scene(dim=3)
    two_boxes.add_plane()
    two_boxes.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.1))
    two_boxes.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.3))
    assert not plane_penalty.supports(two_boxes.build(dt=0.002, contact="penalty")[0])  # box-box pair
    with pytest.raises(ValueError, match="plane_penalty"):
        plane_penalty.PlanePenalty(two_boxes.build(dt=0.002, contact="penalty")[0])
