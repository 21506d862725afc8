"""``rb.rollout(..., adjoint=True)`` with penalty contact against planes: the hand-written adjoint against autodiff.

float64 throughout (conftest). The adjoint and autodiff take the same
derivatives in another order, and the adjoint's forward loop is fused by
XLA differently from ``rb.rollout``'s, so the two trajectories differ by
rounding (about 1e-15 relative) and the gradients by about 1e-12 of each
one's size (measured on the benchmark's box drop over 300 steps); the tests
allow 1e-8, room for stiff contact to amplify rounding, while a missed term
or a wrong sign shows up at 1e-3 and above (a first version, one-sided at
the law's kinks, was 4 % off at rest). Both scenes start at a step where
friction is carried, and touch again later in the rollout.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrb as rb
from jaxrb.physics import adjoint
from jaxrb.physics import plane_penalty_adjoint
NUM_STEPS = 60
TOLERANCE = 1e-8
PLANES_ONLY = dict(collision_category=2, collision_mask=1)  # no body-body pair: the plane-penalty path


def box_scene():
    """A tilted, spinning box sliding and rocking on its corners."""
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.6)
    scene.add_body(rb.Box((0.1, 0.15, 0.05)), mass=1.0, pos=(0.0, 0.0, 0.062), vel=(1.0, 0.3, 0.0),
                   angvel=(0.5, 1.0, 2.0), quat=(0.995, 0.05, 0.03, 0.0), restitution=0.2, **PLANES_ONLY)
    return scene


def mixed_scene():
    """Sphere, capsule and point set against a floor and a tilted wall: several groups, per-pair normals."""
    scene = rb.Scene(dim=3, gravity=(0.5, 0.0, -9.81))
    scene.add_plane(friction=0.5)
    scene.add_plane(normal=(-1.0, 0.0, 0.2), offset=-0.3, friction=0.3, restitution=0.4)
    scene.add_body(rb.Sphere(0.1), mass=2.0, pos=(0.2, 0.0, 0.1), vel=(1.5, 0.5, 0.0), angvel=(0.0, 5.0, 0.0),
                   **PLANES_ONLY)
    scene.add_body(rb.Capsule(0.05, 0.2), mass=0.5, pos=(-1.0, 0.0, 0.2), angvel=(1.0, 1.0, 0.0),
                   quat=(0.8, 0.0, 0.6, 0.0), friction=0.9, **PLANES_ONLY)
    scene.add_body(rb.PointMasses(points=[(0.0, 0.0, 0.0), (0.2, 0.0, 0.0), (0.0, 0.1, 0.05)],
                                  masses=[1.0, 2.0, 1.0]), pos=(0.0, 1.0, 0.07), vel=(0.3, 0.0, 0.0),
                   angvel=(0.0, 0.0, 4.0), **PLANES_ONLY)
    return scene


def loss(trajectory):
    """Every State field the rollout writes, so each of their cotangents is exercised."""
    return (jnp.mean(trajectory.pos ** 2) + jnp.mean(trajectory.vel ** 2) + jnp.mean(trajectory.angvel ** 2)
            + jnp.mean(trajectory.quat[..., 1:] ** 2) + jnp.mean(jnp.sin(trajectory.time))
            + jnp.mean(trajectory.contact_impulse ** 2))


def applied_loads(num_bodies):
    steps = jnp.arange(NUM_STEPS, dtype=jnp.float64)[:, None, None]
    return rb.Wrench(force=jnp.sin(0.3 * steps + jnp.arange(3.0)) * jnp.ones((1, num_bodies, 1)),
                     torque=0.05 * jnp.cos(0.2 * steps + jnp.arange(3.0)) * jnp.ones((1, num_bodies, 1)))


CASES = {
    "box": dict(scene=box_scene, build=dict(dt=0.002, contact="penalty"), every=1, applied=False),
    "mixed, 2 substeps, smooth, first_order, every 3, applied loads": dict(
        scene=mixed_scene, build=dict(dt=0.004, substeps=2, contact=rb.Penalty(width=1e-3),
                                      orientation="first_order"),
        every=3, applied=True),
}


@pytest.fixture(scope="module", params=list(CASES))
def case(request):
    setting = CASES[request.param]
    model, params, state = setting["scene"]().build(**setting["build"])
    params = params.replace(force=params.force + 0.4, torque=params.torque + jnp.array([0.02, -0.01, 0.03]))
    step = rb.make_step(model)
    assert adjoint.supports(model)
    # Start at a step in contact, so the initial State carries friction into the rollout.
    warm_up = rb.rollout(step, state, params, 40)
    touching = np.any(np.asarray(warm_up.contact_impulse[:, :, 1:]) != 0.0, axis=(1, 2))
    start = np.flatnonzero(touching[:-2] & touching[1:-1] & touching[2:])[-1]  # and still touching after it
    state = jax.tree_util.tree_map(lambda a: a[start], warm_up)
    applied = applied_loads(model.num_bodies) if setting["applied"] else None

    def objective(use_adjoint):
        def value(params, state, applied):
            return loss(rb.rollout(step, state, params, NUM_STEPS, every=setting["every"], applied=applied,
                                   adjoint=use_adjoint))
        return jax.jit(jax.grad(value, argnums=(0, 1, 2), allow_int=True))

    return dict(step=step, params=params, state=state, applied=applied, every=setting["every"],
                autodiff=objective(False)(params, state, applied), adjoint=objective(True)(params, state, applied))


def along_tangent(g_quat, quat):
    """(n, 4) cotangents without their part along each (n, 4) quaternion."""
    unit = quat / jnp.linalg.norm(quat, axis=-1, keepdims=True)
    return g_quat - jnp.sum(g_quat * unit, axis=-1, keepdims=True) * unit


def assert_same_gradients(expected, got, quat=None):
    """Each float leaf of ``got`` finite and within TOLERANCE of autodiff's largest entry; returns the non-zero ones.

    With ``quat`` (the initial State's), the initial quaternion's cotangent
    is compared along the unit sphere only: the adjoint differs from
    autodiff along q itself, by design (``jaxrb.physics.plane_penalty_adjoint``).
    """
    leaves = [(jax.tree_util.keystr(path), want, have) for (path, want), have
              in zip(jax.tree_util.tree_leaves_with_path(expected), jax.tree_util.tree_leaves(got))
              if jnp.issubdtype(want.dtype, jnp.floating)]  # integer State fields have float0 cotangents
    # A leaf that is zero by symmetry comes out as rounding noise of the others' size (1e-21 against 1).
    noise = 1e-14 * max(float(jnp.max(jnp.abs(want), initial=0.0)) for _, want, _ in leaves)
    nonzero = []
    for name, want, have in leaves:
        if quat is not None and name == "[1].quat":
            want, have = along_tangent(want, quat), along_tangent(have, quat)
        scale = float(jnp.max(jnp.abs(want), initial=0.0))
        assert bool(jnp.all(jnp.isfinite(have))), name
        np.testing.assert_allclose(have, want, rtol=0, atol=TOLERANCE * scale + noise, err_msg=name)
        if scale > 0:
            nonzero.append(name)
    return nonzero


def test_gradients_equal_autodiffs(case):
    nonzero = assert_same_gradients(case["autodiff"], case["adjoint"], quat=case["state"].quat)
    # The contact's own parameters and the carried friction are reached, not only the free-body ones.
    for name in ("[0].penalty_stiffness", "[0].friction", "[0].plane_friction",
                 "[0].mass", "[0].inertia", "[0].dt", "[1].pos", "[1].quat", "[1].contact_impulse"):
        assert name in nonzero, name


def test_states_equal_the_rollouts(case):
    plain = rb.rollout(case["step"], case["state"], case["params"], NUM_STEPS, every=case["every"],
                       applied=case["applied"])
    hand = rb.rollout(case["step"], case["state"], case["params"], NUM_STEPS, every=case["every"],
                      applied=case["applied"], adjoint=True)
    for (path, a), b in zip(jax.tree_util.tree_leaves_with_path(plain), jax.tree_util.tree_leaves(hand)):
        assert a.shape == b.shape, jax.tree_util.keystr(path)
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-12 * max(float(jnp.max(jnp.abs(a))), 1.0),
                                   err_msg=jax.tree_util.keystr(path))


def test_vmapped_gradient_equals_autodiffs():
    model, params, state = box_scene().build(dt=0.002, contact="penalty")
    step = rb.make_step(model)
    states = jax.tree_util.tree_map(lambda a: jnp.stack([a, a, a]), state)
    states = states.replace(vel=states.vel * jnp.array([1.0, 0.5, -1.0])[:, None, None])

    def batch_gradient(use_adjoint):
        def value(params):
            per_world = jax.vmap(lambda s: loss(rb.rollout(step, s, params, NUM_STEPS, adjoint=use_adjoint)))(states)
            return jnp.sum(per_world)
        return jax.jit(jax.grad(value))(params)

    assert len(assert_same_gradients(batch_gradient(False), batch_gradient(True))) >= 8


def test_gradient_is_finite_at_rest_in_exact_contact():
    # The box's corners exactly on the plane, nothing moving: the activation's
    # kink (dist = 0), zero slip in the clamps, zero angular velocity.
    scene = rb.Scene(dim=3)
    scene.add_plane()
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.1))
    model, params, state = scene.build(dt=0.002, contact="penalty")
    step = rb.make_step(model)

    def gradient(use_adjoint):
        return jax.jit(jax.grad(lambda p, s: loss(rb.rollout(step, s, p, 5, adjoint=use_adjoint)),
                                argnums=(0, 1), allow_int=True))(params, state)

    assert len(assert_same_gradients(gradient(False), gradient(True), quat=state.quat)) >= 5


def test_what_it_covers():
    box = box_scene()
    assert plane_penalty_adjoint.supports(box.build(dt=0.002, contact="penalty")[0])
    for settings in (dict(contact=rb.Penalty(friction="regularized")), dict(contact="penalty", integrator="implicit_gyro")):
        model = box.build(dt=0.002, **settings)[0]
        assert not adjoint.supports(model), settings
    damped = rb.Scene(dim=3)
    damped.add_plane()
    damped.add_body(rb.Sphere(0.1), mass=1.0, pos=(0.0, 0.0, 0.1), linear_damping=0.2)
    assert not adjoint.supports(damped.build(dt=0.002, contact="penalty")[0])
