"""Autodiff against central finite differences, and finite gradients at degenerate points.

Part 1 (float64): for every differentiable input a user fits — the initial
state, mass, inertia, friction, restitution, contact stiffness and damping,
linear/angular damping, gravity — the directional derivative from ``jax.grad``
of a rollout loss is compared with a central difference along a random
direction. Free-body rollouts are smooth, so the two agree to 1e-5. Contact
rollouts are only piecewise smooth (which contacts are active, whether the
friction clamp bites, the step in which an impact happens are all discrete),
so every scene below is chosen so that none of those discrete choices changes
within the difference step, and the agreement asked for is 1e-3.

Part 2 (float32 and float64): gradients of every public function are finite at
the points users hit: zero angular velocity, separation exactly 0, zero
relative velocity, bodies at rest on a plane, coincident sphere centres.

Relative errors per parameter are collected in ``FD_ERRORS`` and printed as a
table when the module finishes (``pytest -s`` shows it).
"""

import math
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrb as rb
from conftest import assert_grad_matches_fd

FREE_TOLERANCE = 1e-5
CONTACT_TOLERANCE = 1e-3
# Step of the central difference along a direction scaled to each parameter's
# size. In float64 its truncation error (∝ eps²) and rounding error (∝ 1e-16/eps)
# are both far below 1e-5 of the derivatives measured here.
EPS = 1e-6
# A derivative smaller than this would make the relative error meaningless (the
# losses are O(1-10), so a difference quotient carries ~1e-8 of rounding): every
# checked parameter must visibly move the loss.
MIN_DERIVATIVE = 1e-5

# (case, parameter) -> (finite difference, autodiff, relative error)
FD_ERRORS = {}


@pytest.fixture(scope="module", autouse=True)
def print_error_table():
    """Print the per-parameter errors after the module's tests (visible with -s)."""
    yield
    if not FD_ERRORS:
        return
    width = max(len(case) for case, _ in FD_ERRORS)
    lines = ["", "FD vs AD relative error per parameter",
             f"{'case':{width}s} {'parameter':28s} {'finite diff':>13s} {'autodiff':>13s} {'rel. error':>10s}"]
    for (case, key), (fd, ad, error) in FD_ERRORS.items():
        lines.append(f"{case:{width}s} {key:28s} {fd:13.6e} {ad:13.6e} {error:10.2e}")
    print("\n".join(lines))


# --------------------------------------------------------------------------- helpers

STATE_FIELDS = ("pos", "vel", "angvel", "quat", "angle")


def rollout_loss(model, params, state, num_steps, seed=0):
    """loss(theta) = fixed random weights · final state, theta a dict 'state.x'/'params.y' -> array.

    Fields not in theta keep the values of ``state`` and ``params``.
    """
    step = rb.make_step(model)
    rng = np.random.default_rng(seed)
    fields = [f for f in STATE_FIELDS if getattr(state, f) is not None]
    weights = {f: jnp.asarray(rng.normal(size=np.shape(getattr(state, f))), dtype=state.pos.dtype)
               for f in fields}

    def loss(theta):
        new_params = params.replace(**{k[7:]: v for k, v in theta.items() if k.startswith("params.")})
        new_state = state.replace(**{k[6:]: v for k, v in theta.items() if k.startswith("state.")})
        final = rb.rollout(step, new_state, new_params, num_steps, every=num_steps)
        return sum(jnp.sum(w * getattr(final, f)[-1]) for f, w in weights.items())

    return loss


def theta_of(params, state, keys):
    return {k: getattr(params if k.startswith("params.") else state, k.split(".", 1)[1]) for k in keys}


def direction(key, value, rng):
    """A random direction for ``key``, scaled to the parameter's size (so EPS is relative).

    Inertia directions are symmetric (a physical tensor); quaternion directions
    are tangent to the unit sphere (a rotation, not a change of |q|, which the
    step would normalise away at the first position update anyway).
    """
    value = np.asarray(value)
    scale = max(float(np.sqrt(np.mean(value * value))), 1.0)
    tangent = rng.normal(size=value.shape) * scale
    if key == "params.inertia" and value.ndim == 3:
        tangent = 0.5 * (tangent + np.swapaxes(tangent, -1, -2))
    if key == "state.quat":
        tangent = tangent - np.sum(tangent * value, axis=-1, keepdims=True) * value
    return jnp.asarray(tangent, dtype=value.dtype)


def check_against_fd(case, loss, theta, tolerance, seed=1):
    """Compare autodiff with a central difference for each key of ``theta`` on its own.

    Value and gradient are compiled once per case and reused for every key,
    which is why this does not call conftest's ``assert_grad_matches_fd`` (it
    compiles per call). Records the errors in FD_ERRORS and asserts them.
    """
    value = jax.jit(loss)
    grad = jax.jit(jax.grad(loss))(theta)
    rng = np.random.default_rng(seed)
    failures = []
    for key in theta:
        tangent = direction(key, theta[key], rng)
        plus = dict(theta, **{key: theta[key] + EPS * tangent})
        minus = dict(theta, **{key: theta[key] - EPS * tangent})
        finite_difference = float(value(plus) - value(minus)) / (2.0 * EPS)
        autodiff = float(jnp.sum(grad[key] * tangent))
        error = abs(autodiff - finite_difference) / max(abs(finite_difference), 1e-300)
        FD_ERRORS[(case, key)] = (finite_difference, autodiff, error)
        if not (np.isfinite(autodiff) and abs(finite_difference) > MIN_DERIVATIVE and error <= tolerance):
            failures.append(f"{key}: fd {finite_difference:.6e} ad {autodiff:.6e} rel {error:.2e}")
    assert not failures, f"{case}: " + "; ".join(failures)


# --------------------------------------------------------------------------- free bodies

FREE_KEYS_3D = ("state.pos", "state.vel", "state.quat", "state.angvel", "params.mass", "params.inertia",
                "params.gravity", "params.force", "params.torque", "params.linear_damping",
                "params.angular_damping", "params.dt")
FREE_KEYS_2D = tuple(k.replace("quat", "angle") for k in FREE_KEYS_3D)


def free_body_case(dim, integrator, orientation):
    """Two tumbling bodies with damping, a constant force and torque, 1 s in 100 steps.

    The force and torque make mass and inertia enter (under gravity alone the
    motion of a centre of mass does not depend on the mass); the asymmetric
    inertia and fast spin make the gyroscopic term matter in 3D.
    """
    scene = rb.Scene(dim=dim, gravity=(0.0, 0.0, -9.81) if dim == 3 else (0.0, -9.81))
    if dim == 3:
        tilt = np.asarray(rb.quaternion.from_axis_angle(jnp.array([1.0, 2.0, 0.5]), 0.7))
        scene.add_body(None, mass=1.5, inertia=(0.3, 0.35, 0.4), pos=(0.1, -0.2, 1.0), quat=tilt,
                       vel=(1.0, 0.5, 2.0), angvel=(0.4, 5.0, 0.3), linear_damping=0.2, angular_damping=0.3)
        scene.add_body(None, mass=0.5, inertia=(0.02, 0.05, 0.06), vel=(-1.0, 0.0, 3.0),
                       angvel=(2.0, -1.0, 0.5), linear_damping=0.1, angular_damping=0.05)
        force, torque = [[1.0, -2.0, 0.5], [0.3, 0.2, 0.0]], [[0.1, 0.0, -0.2], [0.0, 0.05, 0.02]]
    else:
        scene.add_body(None, mass=1.5, inertia=0.3, pos=(0.1, 1.0), angle=0.7, vel=(1.0, 2.0), angvel=5.0,
                       linear_damping=0.2, angular_damping=0.3)
        scene.add_body(None, mass=0.5, inertia=0.05, vel=(-1.0, 3.0), angvel=-2.0,
                       linear_damping=0.1, angular_damping=0.05)
        force, torque = [[1.0, -2.0], [0.3, 0.2]], [0.1, -0.2]
    model, params, state = scene.build(dt=0.01, integrator=integrator, orientation=orientation)
    params = params.replace(force=jnp.asarray(force), torque=jnp.asarray(torque))
    return model, params, state


# Every orientation update and velocity-phase variant once (each case is one compile).
FREE_CASES = [(3, "semi_implicit", "exp_map"), (3, "implicit_gyro", "first_order"), (3, "rk4", None),
              (3, "rk4_body", None), (2, "semi_implicit", None)]


@pytest.mark.parametrize("dim,integrator,orientation", FREE_CASES)
def test_free_body_rollout_gradients_match_finite_differences(dim, integrator, orientation):
    model, params, state = free_body_case(dim, integrator, orientation)
    keys = FREE_KEYS_3D if dim == 3 else FREE_KEYS_2D
    case = f"free {dim}D {integrator}" + (f"/{orientation}" if orientation else "")
    check_against_fd(case, rollout_loss(model, params, state, 100), theta_of(params, state, keys),
                     FREE_TOLERANCE)


# --------------------------------------------------------------------------- contact rollouts

G = 9.81
# Bodies touch the plane only (category 0b10, mask 0b01), so the three
# experiments of a scene are independent and share one compiled step.
BODY_FILTER = dict(collision_category=0b10, collision_mask=0b01)
PLANE_FILTER = dict(collision_category=0b01)
SECONDS = 0.15
# Impulse: contact_hertz below the cap 0.25/h = 60 Hz, since the soft step uses
# min(hertz, cap), which has a kink at the default (the cap itself).
IMPULSE = dict(dt=1 / 60, substeps=4, contact=rb.Impulse(hertz=30.0))
PENALTY_STIFFNESS = 4e4
# Explicit damper (below the effective-mass cap m_c/h ≈ 62 N·s/m of a box corner,
# whose min() would be a kink): penalty_damping_from_restitution is off.
PENALTY = dict(dt=1e-3, contact=rb.Penalty(stiffness=PENALTY_STIFFNESS, damping=20.0))
# Below equilibrium: the impulse model's overdamped soft contact (damping ratio
# 10) lifts the bodies towards their sink of ~3e-4 m without overshooting, so
# every separation stays negative. At separation 0 the solver switches between
# its speculative (rigid) and soft rows, a jump in the output.
IMPULSE_SINK = 5e-4


def ground_scene(dim, contact):
    """Three independent experiments on one plane (friction 0.5, restitution 0.3).

    * a box sliding under a push (and, in 3D, spinning about the vertical):
      every corner keeps slipping for the whole rollout (it stops after 0.34 s),
      so the friction clamp is active throughout and the normal forces stay
      positive — a fixed contact set;
    * a ball launched at 4 m/s without spin: friction spins it up while it
      slides, until rolling at 2 v0/(7 μ g) = 0.23 s (3D; 0.27 s in 2D), after
      the rollout: friction and inertia enter through the spin-up;
    * a ball dropped onto the plane with restitution 0.6: it hits after 0.065 s
      and the output at 0.15 s is taken in flight, before the second impact at
      about 0.26 s. The impact's step index is discrete, so the output is a
      smooth function of the inputs only between changes of that index, far
      from every value used here.

    Resting bodies start at their penalty equilibrium (so no contact is
    exactly at separation 0, where the hard penalty activation has a kink), or
    for impulse contact at IMPULSE_SINK below the surface.
    """
    scene = rb.Scene(dim=dim, gravity=(0.0, 0.0, -G) if dim == 3 else (0.0, -G))
    scene.add_plane(friction=0.5, restitution=0.3, **PLANE_FILTER)
    corners = 4 if dim == 3 else 2
    if contact == "impulse":
        box_z, ball_z = 0.1 - IMPULSE_SINK, 0.1 - IMPULSE_SINK
    else:
        box_z, ball_z = 0.1 - G / (corners * PENALTY_STIFFNESS), 0.1 - G / PENALTY_STIFFNESS
    common = dict(mass=1.0, friction=0.5, linear_damping=0.1, angular_damping=0.2, **BODY_FILTER)
    if dim == 3:
        scene.add_body(rb.Box((0.1, 0.1, 0.1)), pos=(0.0, 0.0, box_z), vel=(1.0, 0.3, 0.0),
                       angvel=(0.0, 0.0, 2.0), **common)
        scene.add_body(rb.Sphere(0.1), pos=(0.0, 2.0, ball_z), vel=(4.0, 0.0, 0.0), **common)
        scene.add_body(rb.Sphere(0.1), pos=(0.0, -2.0, 0.2), vel=(0.5, 0.0, -1.0), angvel=(0.0, 1.0, 0.0),
                       restitution=0.6, **common)
        push = [[2.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    else:
        scene.add_body(rb.Box((0.1, 0.1)), pos=(0.0, box_z), vel=(1.0, 0.0), **common)
        scene.add_body(rb.Circle(0.1), pos=(2.0, ball_z), vel=(4.0, 0.0), **common)
        scene.add_body(rb.Circle(0.1), pos=(-2.0, 0.2), vel=(0.5, -1.0), angvel=1.0, restitution=0.6, **common)
        push = [[2.0, 0.0], [0.0, 0.0], [0.0, 0.0]]
    model, params, state = scene.build(**(IMPULSE if contact == "impulse" else PENALTY))
    return model, params.replace(force=jnp.asarray(push, dtype=params.mass.dtype)), state


CONTACT_KEYS = ("state.pos", "state.vel", "state.quat", "state.angvel", "params.mass", "params.inertia",
                "params.friction", "params.plane_friction", "params.restitution", "params.gravity",
                "params.linear_damping", "params.angular_damping", "params.force")
MODEL_KEYS = {"impulse": ("params.contact_hertz", "params.contact_damping_ratio"),
              # Under penalty contact with an explicit damper restitution does nothing;
              # it is checked in the bounce test below.
              "penalty": ("params.penalty_stiffness", "params.penalty_damping")}


@pytest.mark.slow
@pytest.mark.parametrize("dim", [3, 2])
@pytest.mark.parametrize("contact", ["penalty", "impulse"])
def test_contact_rollout_gradients_match_finite_differences(contact, dim):
    model, params, state = ground_scene(dim, contact)
    keys = [k for k in CONTACT_KEYS if not (contact == "penalty" and k == "params.restitution")]
    keys = [k.replace("quat", "angle") if dim == 2 else k for k in keys] + list(MODEL_KEYS[contact])
    num_steps = int(round(SECONDS / float(params.dt)))
    check_against_fd(f"{contact} {dim}D ground", rollout_loss(model, params, state, num_steps),
                     theta_of(params, state, keys), CONTACT_TOLERANCE)


@pytest.mark.slow
@pytest.mark.parametrize("dim", [3, 2])
def test_penalty_restitution_gradient_matches_finite_differences(dim):
    """Penalty damping derived from restitution (the default): a ball's bounce, read in flight."""
    scene = rb.Scene(dim=dim, gravity=(0.0, 0.0, -G) if dim == 3 else (0.0, -G))
    scene.add_plane(restitution=0.3)
    scene.add_body(rb.Sphere(0.1) if dim == 3 else rb.Circle(0.1), mass=1.0, restitution=0.6,
                   pos=(0.0, 0.0, 0.2) if dim == 3 else (0.0, 0.2), vel=(0.5, 0.0, -1.0) if dim == 3 else (0.5, -1.0))
    model, params, state = scene.build(dt=1e-3, contact=rb.Penalty(stiffness=PENALTY_STIFFNESS))
    assert model.penalty_damping_from_restitution
    keys = ("state.pos", "state.vel", "params.mass", "params.restitution", "params.penalty_stiffness")
    check_against_fd(f"penalty {dim}D bounce", rollout_loss(model, params, state, 150),
                     theta_of(params, state, keys), CONTACT_TOLERANCE)


def test_impulse_solver_derivatives_equal_those_of_its_branching_forward(monkeypatch):
    """The solver skips an inactive row with lax.cond; its derivatives select instead.

    ``sequential._guarded_row`` gives the row update a custom JVP (solve every row,
    drop an inactive one's result). Its gradient must equal that of
    differentiating the cond itself. The scene has rows of both kinds: a 2D
    box falls 5 cm with a spin (speculative rows inactive) and lands at about
    0.1 s, inside the 0.2 s rollout, slower than the bounce threshold, so
    the solver's rows (not the time-of-impact pass) stop it. Float64, the
    same arithmetic in another order: equal to 1e-9. (One relax sweep fewer
    than the default keeps the two compiles short; the sweeps share
    ``_sweep_rows``.)
    """
    from jaxrb.physics.contact import sequential

    scene = rb.Scene(dim=2, gravity=(0.0, -G))
    scene.add_plane(friction=0.5, restitution=0.3)
    scene.add_body(rb.Box((0.1, 0.1)), pos=(0.0, 0.15), vel=(1.0, 0.0), angvel=0.5, mass=1.0,
                   friction=0.5, restitution=0.6)
    model, params, state = scene.build(**dict(IMPULSE, contact=rb.Impulse(hertz=30.0, relax_iterations=0), bounce_threshold=2.0))
    # Rows of both kinds: the box starts beyond the contact margin and is pushed on later.
    assert float(state.pos[0, 1]) - 0.1 > float(params.contact_margin)
    trajectory = rb.rollout(rb.make_step(model), state, params, 12)
    assert float(jnp.max(trajectory.contact_impulse[..., 0])) > 0.0
    keys = ("state.pos", "state.vel", "state.angvel", "params.mass", "params.inertia", "params.friction",
            "params.restitution", "params.contact_hertz")
    theta = theta_of(params, state, keys)
    loss = rollout_loss(model, params, state, 12)
    guarded = jax.jit(jax.grad(loss))(theta)

    def branching(solve_row, active, operands):
        return jax.lax.cond(active, lambda ops: solve_row(*ops), lambda ops: (ops[1], ops[2]), operands)

    monkeypatch.setattr(sequential, "_guarded_row", branching)
    reference = jax.jit(jax.grad(rollout_loss(model, params, state, 12)))(theta)
    for key in keys:
        np.testing.assert_allclose(guarded[key], reference[key], rtol=1e-9, atol=1e-12, err_msg=key)
    assert any(float(jnp.max(jnp.abs(guarded[key]))) > 1e-3 for key in keys)


def test_cotangent_once_is_the_identity_to_every_order():
    """``impulse._cotangent_once`` changes no derivative: first, second (forward and reverse) or batched.

    Its JVP routes the tangent through a conditional whose predicate comes
    from a custom_vmap function, which reverse mode cannot differentiate; a
    gradient of a gradient must still be taken (and equal the plain one's).
    A loop, as in the solver, whose body reads a loop constant as the probe.
    """
    from jaxrb.physics.contact import impulse

    def loss(x, h, once):
        probe = jnp.cos(x)
        body = lambda _, carry: jnp.sin(once(2.0 * carry, h, probe)) * h
        return jnp.sum(jax.lax.fori_loop(0, 4, body, x) ** 2)

    plain = partial(loss, once=lambda values, h, probe: values)
    marked = partial(loss, once=impulse._cotangent_once)
    x, h, xs = jnp.array([0.5, 1.5, 2.5]), jnp.asarray(0.7), jnp.array([[0.5, 1.5, 2.5], [0.1, -0.4, 0.9]])
    second = lambda f: jax.grad(lambda y: jnp.sum(jax.grad(f)(y, h)))
    for transform, arguments in ((jax.grad, (x, h)), (partial(jax.grad, argnums=1), (x, h)), (jax.hessian, (x, h)),
                                 (second, (x,)), (lambda f: jax.vmap(jax.grad(f), (0, None)), (xs, h))):
        expected, actual = transform(plain)(*arguments), jax.jit(transform(marked))(*arguments)
        np.testing.assert_allclose(actual, expected, rtol=1e-12, atol=1e-14)
        assert float(jnp.max(jnp.abs(expected))) > 1e-3


@pytest.mark.slow  # three gradient compiles, about 75 s on 2 cores
def test_vmapped_jacobi_gradients_equal_each_worlds():
    """Batched, the Jacobi pass computes its tangents' cotangents once; the gradients must not change.

    ``impulse._cotangent_once`` puts a conditional (a fusion boundary) on the
    pass's tangents under vmap only; at one world its predicate is a constant
    and XLA removes it. A box lands sliding and spinning in three worlds that
    differ in speed. Float64, the same arithmetic grouped otherwise: the
    batched gradients (grad of the worlds' summed losses, and vmap of grad)
    equal each world's own to 1e-9. The compiled programs must show the
    boundary where it belongs: none in the one-world gradient (a box on a
    plane has no other conditional), some in both batched ones. (No relax
    pass: one pass loop fewer keeps the three compiles shorter.)
    """
    scene = rb.Scene(gravity=(0.0, 0.0, -G))
    scene.add_plane(friction=0.5, restitution=0.3)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), pos=(0.0, 0.0, 0.15), vel=(1.0, 0.3, -0.5), angvel=(0.3, 0.0, 1.0),
                   mass=1.0, friction=0.5, restitution=0.6)
    model, params, state = scene.build(**dict(IMPULSE, contact=rb.Impulse(hertz=30.0, solver="jacobi", relax_iterations=0)))
    states = jax.vmap(lambda speed: state.replace(vel=state.vel.at[0, 0].set(speed)))(jnp.array([0.5, 1.0, 2.0]))
    world = lambda tree, index: jax.tree_util.tree_map(lambda array: array[index], tree)
    step = rb.make_step(model)
    weights = np.random.default_rng(0).normal(size=(3, 3))

    def loss(params, state):
        final = rb.rollout(step, state, params, 12, every=12)
        return sum(jnp.sum(w * v[-1, 0]) for w, v in zip(weights, (final.pos, final.vel, final.angvel)))

    landed = jax.vmap(lambda s: rb.rollout(step, s, params, 12).contact_impulse[..., 0].max())(states)
    assert bool(jnp.all(landed > 0.0))
    one_world = rb.jit(jax.grad(loss)).lower(params, state).compile()
    summed = rb.jit(jax.grad(lambda p, s: jnp.sum(jax.vmap(loss, (None, 0))(p, s)))).lower(params, states).compile()
    each = rb.jit(jax.vmap(jax.grad(loss), (None, 0))).lower(params, states).compile()
    conditionals = lambda compiled: compiled.as_text().count(" conditional(")
    assert conditionals(one_world) == 0
    assert conditionals(summed) > 0 and conditionals(each) > 0

    worlds = [one_world(params, world(states, index)) for index in range(3)]
    pairs = [(jax.tree_util.tree_map(lambda *grads: sum(grads), *worlds), summed(params, states))]
    batched = each(params, states)
    pairs += [(worlds[index], world(batched, index)) for index in range(3)]
    for want, got in pairs:
        for (path, expected), actual in zip(jax.tree_util.tree_leaves_with_path(want), jax.tree_util.tree_leaves(got)):
            np.testing.assert_allclose(actual, expected, rtol=1e-9, atol=1e-12, err_msg=jax.tree_util.keystr(path))
    assert float(jnp.max(jnp.abs(worlds[0].friction))) > 1e-3  # friction acts on the landing box


# --------------------------------------------------------------------------- degenerate points

# Plane-only bodies (category 0b10) and a pair of coincident balls that touch
# each other only (category 0b100): every degenerate configuration in one scene,
# with only the kernels it needs compiled.
ON_PLANE = dict(collision_category=0b10, collision_mask=0b01)
PAIR_ONLY = dict(collision_category=0b100, collision_mask=0b100)
TETRA_3D = ((0.0, 0.0, 0.0), (0.2, 0.0, 0.0), (0.0, 0.2, 0.0), (0.0, 0.0, 0.2))
TRIANGLE_2D = ((0.0, 0.0), (0.2, 0.0), (0.0, 0.2))


def degenerate_scene(dim, contact, dtype):
    """Everything at rest, zero velocity and angular velocity, at exact contact.

    A box, a ball (with zero friction, so the mixed √(μ_A μ_B) is at 0), a
    polygon or capsule and a point-mass body all touch the plane at separation
    exactly 0; two balls share a centre.
    """
    scene = rb.Scene(dim=dim)
    scene.add_plane(**PLANE_FILTER)
    if dim == 3:
        lying = np.asarray([math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0])
        scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.1), **ON_PLANE)
        scene.add_body(rb.Sphere(0.1), mass=1.0, pos=(1.0, 0.0, 0.1), friction=0.0, **ON_PLANE)
        scene.add_body(rb.Capsule(0.05, 0.1), mass=1.0, pos=(2.0, 0.0, 0.05), quat=lying, **ON_PLANE)
        scene.add_body(rb.PointMasses(TETRA_3D, (1.0, 1.0, 1.0, 1.0)), pos=(3.0, 0.0, 0.0), **ON_PLANE)
        for _ in range(2):
            scene.add_body(rb.Sphere(0.1), mass=1.0, pos=(-1.0, 0.0, 1.0), **PAIR_ONLY)
    else:
        scene.add_body(rb.Box((0.1, 0.1)), mass=1.0, pos=(0.0, 0.1), **ON_PLANE)
        scene.add_body(rb.Circle(0.1), mass=1.0, pos=(1.0, 0.1), friction=0.0, **ON_PLANE)
        scene.add_body(rb.Polygon(((-0.1, 0.0), (0.1, 0.0), (0.0, 0.15))), mass=1.0, pos=(2.0, 0.0), **ON_PLANE)
        scene.add_body(rb.PointMasses(TRIANGLE_2D, (1.0, 1.0, 1.0)), pos=(3.0, 0.0), **ON_PLANE)
        for _ in range(2):
            scene.add_body(rb.Circle(0.1), mass=1.0, pos=(-1.0, 1.0), **PAIR_ONLY)
    settings = IMPULSE if contact == "impulse" else dict(dt=1e-3, contact="penalty")
    return scene.build(dtype=dtype, **settings)


FLOAT_STATE = ("pos", "vel", "angvel", "quat", "angle")
FLOAT_PARAMS = tuple(f.name for f in __import__("dataclasses").fields(rb.Params))


def assert_finite_tree(tree, dtype, what):
    for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
        assert leaf.dtype == dtype, f"{what}{jax.tree_util.keystr(path)} is {leaf.dtype}, not {dtype}"
        assert np.all(np.isfinite(np.asarray(leaf))), f"{what}{jax.tree_util.keystr(path)} is not finite"


@pytest.mark.slow
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
@pytest.mark.parametrize("dim", [3, 2])
@pytest.mark.parametrize("contact", ["penalty", "impulse"])
def test_gradients_are_finite_at_degenerate_points(contact, dim, dtype):
    model, params, state = degenerate_scene(dim, contact, dtype)
    assert float(jnp.max(jnp.abs(state.vel))) == 0.0 and float(jnp.max(jnp.abs(state.angvel))) == 0.0
    contacts = rb.detect_contacts(model, params, state)
    on_plane = np.asarray(contacts.active & (contacts.body_b == model.num_bodies))
    assert np.any(np.asarray(contacts.dist)[on_plane] == 0.0)  # exact contact is really exercised
    step = rb.make_step(model)
    theta = dict(state={f: getattr(state, f) for f in FLOAT_STATE if getattr(state, f) is not None},
                 params={f: getattr(params, f) for f in FLOAT_PARAMS})

    def unpack(theta):
        return state.replace(**theta["state"]), params.replace(**theta["params"])

    def rollout_loss(theta):
        # Two steps, so the second starts from the first's warm start / friction springs.
        start, p = unpack(theta)
        final = rb.rollout(step, start, p, 2, every=2)
        fields = [getattr(final, f) for f in FLOAT_STATE if getattr(final, f) is not None]
        return sum(jnp.sum(x) for x in fields) + jnp.sum(final.contact_impulse)

    def detect_loss(theta):
        found = rb.detect_contacts(model, *reversed(unpack(theta)))
        return (jnp.sum(found.dist) + jnp.sum(found.normal) + jnp.sum(found.point)
                + jnp.sum(found.normal_velocity) + jnp.sum(found.friction) + jnp.sum(found.restitution))

    def body_loss(theta):
        start, p = unpack(theta)
        loss = (jnp.sum(rb.kinetic_energy(model, p, start)) + jnp.sum(rb.potential_energy(model, p, start))
                + jnp.sum(rb.angular_momentum(model, p, start))
                + jnp.sum(rb.total_angular_momentum(model, p, start)))
        # A force applied exactly at the centre of mass: zero lever arm.
        wrench = rb.wrench_at_points(model, start, jnp.arange(model.num_bodies), start.vel + 1.0, start.pos)
        loss = loss + jnp.sum(wrench.force) + jnp.sum(wrench.torque)
        if dim == 3:
            loss = loss + jnp.sum(rb.world_inertia(start.quat, p.inertia))
        return loss

    for name, loss in (("rollout", rollout_loss), ("detect_contacts", detect_loss), ("bodies", body_loss)):
        value, grad = jax.jit(jax.value_and_grad(loss))(theta)
        assert value.dtype == dtype and np.isfinite(float(value)), name
        assert_finite_tree(grad, dtype, f"d {name} / d")


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_quaternion_functions_have_finite_gradients_at_zero_rotation(dtype):
    quaternion = rb.quaternion
    identity = jnp.array([1.0, 0.0, 0.0, 0.0], dtype)
    zero = jnp.zeros(3, dtype)
    h = jnp.asarray(0.01, dtype)
    functions = {
        "exp": lambda w: quaternion.exp(w),
        "from_axis_angle(axis, 0)": lambda w: quaternion.from_axis_angle(w + jnp.array([0.0, 0.0, 1.0], dtype),
                                                                         jnp.sum(w)),
        "from_axis_angle(0, angle)": lambda w: quaternion.from_axis_angle(w, 0.3 + jnp.sum(w)),
        "integrate_exp_map": lambda w: quaternion.integrate_exp_map(identity, w, h),
        "integrate_first_order": lambda w: quaternion.integrate_first_order(identity, w, h),
        "normalize(0)": lambda w: quaternion.normalize(jnp.concatenate([w[:1], w])),
        "rotate": lambda w: quaternion.rotate(quaternion.exp(w), w),
        "to_rotation_matrix": lambda w: quaternion.to_rotation_matrix(quaternion.exp(w)),
    }
    for name, function in functions.items():
        jacobian = jax.jit(jax.jacobian(function))(zero)
        assert jacobian.dtype == dtype and np.all(np.isfinite(np.asarray(jacobian))), name


def test_exp_map_gradient_at_zero_angular_velocity_matches_finite_differences():
    """At ω = 0 the exponential map's Taylor branch must have the true derivative, not just a finite one."""
    q = rb.quaternion.from_axis_angle(jnp.array([1.0, -2.0, 0.5]), 0.4)
    weights = jnp.array([0.3, -1.0, 2.0, 0.7])

    def turned(angvel):
        return jnp.sum(weights * rb.quaternion.integrate_exp_map(q, angvel, 0.1))

    grad = assert_grad_matches_fd(turned, (jnp.zeros(3),), rtol=1e-8, eps=1e-6)
    # d(exp(hω) q)/dω at 0 is (h/2)(0, I) q: compare with that closed form too.
    expected = jax.grad(lambda w: jnp.sum(weights * rb.quaternion.multiply(
        jnp.concatenate([jnp.ones(1), 0.05 * w]), q)))(jnp.zeros(3))
    np.testing.assert_allclose(grad[0], expected, rtol=1e-12)


# --------------------------------------------------------------------------- no contact, no contact gradient

@pytest.mark.parametrize("dim", [3, 2])
@pytest.mark.parametrize("contact", ["penalty", pytest.param("impulse", marks=pytest.mark.slow)])
def test_body_off_the_plane_has_the_free_body_jacobian(contact, dim):
    """A box at rest 5 mm above the plane (inside the contact margin) and one 1 m above it.

    Neither touches within the step (it falls 1.7 mm), so d(state')/d(state)
    must be the free body's. Both rows carry zero normal force and zero slip,
    where the friction clamp's derivative used to leak: penalty contact gave
    d angvel'/d angvel = -42 for the far box (an inactive row), 0.77 for the
    near one, impulse contact 0.38 for the near one.
    """
    scene = rb.Scene(dim=dim)
    scene.add_plane()
    for x, gap in ((0.0, 0.005), (1.0, 1.0)):
        position = (x, 0.0, 0.05 + gap) if dim == 3 else (x, 0.05 + gap)
        scene.add_body(rb.Box((0.05,) * dim), mass=1.0, pos=position)
    settings = dict(dt=1 / 60, substeps=4) if contact == "impulse" else dict(dt=1e-3)
    model, params, state = scene.build(contact=contact, **settings)
    free_model, _, _ = scene.build(contact="none", **settings)
    # Only the near box's bottom corners are active contacts: a margin row, zero load.
    assert int(jnp.sum(rb.detect_contacts(model, params, state).active)) == (4 if dim == 3 else 2)

    def jacobian(step_model):
        step = rb.make_step(step_model)
        velocities = lambda vel, angvel: step(state.replace(vel=vel, angvel=angvel), params)
        return jax.jit(jax.jacobian(lambda v, w: (velocities(v, w).vel, velocities(v, w).angvel),
                                    argnums=(0, 1)))(state.vel, state.angvel)

    touching, free = jacobian(model), jacobian(free_model)
    for got, expected in zip(jax.tree_util.tree_leaves(touching), jax.tree_util.tree_leaves(free)):
        np.testing.assert_allclose(got, expected, atol=1e-12)
