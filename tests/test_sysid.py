"""System identification: transforms, losses, the fit loop, and recovery from noisy data.

The recovery tests (marked slow: each compiles a gradient through a rollout)
fit synthetic observations made by the engine itself at the true parameters,
with Gaussian position noise of 1 % of the trajectory's position scale (the
largest per-axis range of the centre of mass over the rollout), seeded, and
start 50 % off the truth. Each must recover the truth within 2 % in at most
500 Adam steps. Contact fits use penalty contact: its forces are smooth in
friction and restitution, while the impulse model's event timing (a contact
that starts one substep earlier) and bounce threshold make the loss of a
bounce jump, with gradient spikes of 100x that stall Adam (measured on the
bouncing ball: d loss/d e = −9.4 at e = 0.58 against −0.1 around it). The
bouncing ball also needs the penalty spring's smooth activation: with the
hard one, the step each bounce lands on is discrete in e as well (see the test).
"""

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

import jaxrb as rb
from jaxrb.fit import sysid
RECOVERY_TOLERANCE = 0.02  # the requirement
MAX_FIT_STEPS = 500


def noisy(observed, traj, seed):
    """Observation with Gaussian position noise of 1 % of the position scale (per trajectory)."""
    pos = np.asarray(traj.pos)  # (T, n, dim), or (B, T, n, dim) for several trajectories
    ranges = np.ptp(pos, axis=pos.ndim - 3)  # per body and axis
    scale = ranges.reshape(ranges.shape[:-2] + (-1,)).max(axis=-1)[..., None, None, None]
    noise = np.random.default_rng(seed).normal(size=observed.pos.shape)
    return observed.replace(pos=observed.pos + 0.01 * scale * noise)


def penalty_observations(scene, num_steps, seed, every=20, contact=rb.Penalty(), **build):
    """Build ``scene`` with penalty contact (1 ms), roll it out and observe it noisily.

    ``build``: further ``Scene.build`` options. Returns (step, true params,
    initial state, noisy observation every ``every`` steps).
    """
    model, truth, state = scene.build(contact=contact, dt=1e-3, **build)
    step = rb.make_step(model)
    traj = jax.jit(lambda s, p: rb.rollout(step, s, p, num_steps, every=every))(state, truth)
    return step, truth, state, noisy(sysid.observe(traj, every=every), traj, seed=seed)


def assert_recovered(fitted, truth, name):
    error = np.max(np.abs(np.asarray(fitted) / np.asarray(truth) - 1.0))
    assert error < RECOVERY_TOLERANCE, (name, np.asarray(fitted), np.asarray(truth))


# --- a cheap scene for the unit tests: 2D free bodies pushed by a known force --------

PUSH_STEPS = 40


def free_2d_scene(num_bodies=1):
    scene = rb.Scene(dim=2, gravity=(0.0, 0.0))
    for index in range(num_bodies):
        scene.add_body(rb.Box((0.2, 0.1)), mass=1.0 + index, pos=(0.0, index), angvel=0.5)
    return scene.build(dt=1 / 60, contact="none")


def push_2d(num_bodies=1):
    """A known force (2, −1) N at 5 cm from the centre along the box, every step: pushes and spins it."""
    force = np.tile([[2.0, -1.0]], (PUSH_STEPS, num_bodies, 1))
    arm = np.array([0.05, 0.0])  # turns it by < 1 rad: no 2π ambiguity in the angle loss
    torque = arm[0] * force[..., 1] - arm[1] * force[..., 0]
    return rb.Wrench(force=jnp.asarray(force), torque=jnp.asarray(torque))


@pytest.fixture(scope="module")
def free_2d():
    model, truth, state = free_2d_scene()
    step = rb.make_step(model)
    applied = push_2d()
    traj = jax.jit(lambda s, p: rb.rollout(step, s, p, PUSH_STEPS, applied=applied))(state, truth)
    return step, truth, state, applied, traj


# --- transforms --------------------------------------------------------------------

def rotated_inertia():
    """A full (non-diagonal) body-frame inertia: principal (0.05, 0.08, 0.11) in rotated axes."""
    rotation = np.asarray(rb.quaternion.to_rotation_matrix(
        rb.quaternion.from_axis_angle(jnp.array([1.0, 2.0, 3.0]), 0.7)))
    return rotation @ np.diag([0.05, 0.08, 0.11]) @ rotation.T


def test_transforms_round_trip_3d():
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.8, restitution=0.3)
    scene.add_body(rb.Sphere(0.1), mass=2.0, friction=0.4, restitution=0.6)
    scene.add_body(None, mass=3.0, inertia=rotated_inertia(), pos=(1, 0, 0), friction=0.7, restitution=0.2)
    _, params, _ = scene.build(dt=1 / 60)
    fields = ("mass", "inertia", "friction", "restitution", "plane_friction", "gravity")
    unconstrained = sysid.to_unconstrained(params, fields)
    assert unconstrained["inertia"].shape == (2, 6)
    back = sysid.from_unconstrained(unconstrained, params)
    for name in fields:
        np.testing.assert_allclose(getattr(back, name), getattr(params, name), rtol=1e-12, atol=1e-15)
    principal = sysid.to_unconstrained(dataclasses.replace(params, inertia=params.inertia[:1]), "inertia",
                                       transforms={"inertia": "principal"})
    np.testing.assert_allclose(
        sysid.from_unconstrained(principal, dataclasses.replace(params, inertia=params.inertia[:1]),
                                 transforms={"inertia": "principal"}).inertia, params.inertia[:1], rtol=1e-12)


def test_transforms_round_trip_2d(free_2d):
    truth = free_2d[1].replace(restitution=jnp.array([0.3]))
    unconstrained = sysid.to_unconstrained(truth, ("mass", "inertia", "restitution"),
                                           transforms={"restitution": "softplus"})
    np.testing.assert_allclose(unconstrained["inertia"], np.log(truth.inertia))  # 2D default "log"
    back = sysid.from_unconstrained(unconstrained, free_2d[1], transforms={"restitution": "softplus"})
    np.testing.assert_allclose(back.inertia, truth.inertia, rtol=1e-12)
    np.testing.assert_allclose(back.restitution, truth.restitution, atol=1e-12)


@pytest.mark.parametrize("transform,size", [("second_moment", 6), ("principal", 3)])
def test_any_unconstrained_inertia_is_physical(transform, size):
    """Positive definite and the triangle inequality I_i + I_j >= I_k, for wild u."""
    _, params, _ = _two_body_params()
    u = np.random.default_rng(1).normal(scale=3.0, size=(500, size))
    inertia = np.asarray(sysid.from_unconstrained(
        {"inertia": jnp.asarray(u)}, dataclasses.replace(params, inertia=jnp.zeros((500, 3, 3))),
        transforms={"inertia": transform}).inertia)
    np.testing.assert_allclose(inertia, np.swapaxes(inertia, -1, -2), atol=1e-12 * np.abs(inertia).max())
    moments = np.linalg.eigvalsh(inertia)
    assert np.all(moments > 0.0)
    # Sorted ascending, the only inequality that can fail is I_1 + I_2 >= I_3;
    # its slack is 2·min eig(C) >= 0, so allow round-off only.
    assert np.all(moments[:, 0] + moments[:, 1] - moments[:, 2] >= -1e-12 * moments[:, 2])


def _two_body_params():
    scene = rb.Scene(dim=3)
    scene.add_body(rb.Sphere(0.1), mass=2.0)
    scene.add_body(rb.Box((0.1, 0.2, 0.3)), mass=1.0, pos=(1, 0, 0))
    return scene.build(dt=1 / 60, contact="none")


def test_bounded_transforms_stay_in_range():
    _, params, _ = _two_body_params()
    u = {"mass": jnp.array([-40.0, 40.0]), "restitution": jnp.array([-40.0, 40.0]),
         "friction": jnp.array([-30.0, 5.0])}
    fitted = sysid.from_unconstrained(u, params)
    assert np.all(np.asarray(fitted.mass) > 0.0)
    assert np.all((np.asarray(fitted.restitution) >= 0.0) & (np.asarray(fitted.restitution) <= 1.0))
    assert np.all(np.asarray(fitted.friction) >= 0.0)


def test_bad_fields_raise_value_error_naming_the_field():
    _, params, _ = _two_body_params()
    with pytest.raises(ValueError, match="'frction'"):
        sysid.to_unconstrained(params, ("mass", "frction"))
    with pytest.raises(ValueError, match="'mass'.*shape"):
        sysid.field_masks(params, {"mass": np.array([True, False, True])})
    with pytest.raises(ValueError, match="selects no"):
        sysid.field_masks(params, {"mass": False})
    with pytest.raises(ValueError, match="'restitution'.*sigmoid"):
        sysid.to_unconstrained(params.replace(restitution=jnp.array([0.5, 1.0])), "restitution")
    with pytest.raises(ValueError, match="'inertia'.*triangle"):
        sysid.to_unconstrained(dataclasses.replace(params, inertia=jnp.stack([jnp.diag(jnp.array([1.0, 1.0, 3.0]))] * 2)),
                               "inertia")
    with pytest.raises(ValueError, match="'inv_inertia' is derived"):
        sysid.to_unconstrained(params, "inv_inertia")
    with pytest.raises(ValueError, match="unknown transform 'exp' for field 'mass'"):
        sysid.to_unconstrained(params, "mass", transforms={"mass": "exp"})


def test_fields_as_params_of_bools_and_body_masks():
    _, params, _ = _two_body_params()
    selection = jax.tree_util.tree_map(lambda _: False, params).replace(mass=np.array([False, True]),
                                                                        friction=True)
    masks = sysid.field_masks(params, selection)
    assert set(masks) == {"mass", "friction"}
    u = sysid.to_unconstrained(params, selection)
    moved = sysid.from_unconstrained({name: value + 1.0 for name, value in u.items()}, params, selection)
    assert float(moved.mass[0]) == float(params.mass[0])  # masked out: untouched
    np.testing.assert_allclose(moved.mass[1], params.mass[1] * math.e)


# --- losses ------------------------------------------------------------------------

def test_quaternion_angle_is_the_rotation_angle_and_ignores_sign():
    q = rb.quaternion.from_axis_angle(jnp.array([0.3, -1.0, 0.5]), 0.4)
    turn = rb.quaternion.from_axis_angle(jnp.array([1.0, 1.0, 0.0]), 0.25)
    np.testing.assert_allclose(sysid.quaternion_angle(rb.quaternion.multiply(turn, q), q), 0.25, rtol=1e-12)
    np.testing.assert_allclose(sysid.quaternion_angle(-q, q), 0.0, atol=1e-12)
    np.testing.assert_allclose(sysid.wrapped_angle(jnp.array(3.0), jnp.array(-3.0)), 6.0 - 2 * math.pi,
                               rtol=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_loss_is_zero_at_truth_with_finite_gradient(dim, free_2d):
    if dim == 2:
        traj = free_2d[4]
    else:
        model, params, state = _two_body_params()
        state = state.replace(angvel=jnp.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]]))
        traj = rb.rollout(rb.make_step(model), state, params, 10)
    observed = sysid.observe(traj, velocities=True)
    predicted = jax.tree_util.tree_map(lambda a: a[observed.steps - 1], traj)
    value, grad = jax.value_and_grad(sysid.trajectory_loss)(predicted, observed)
    assert float(value) == 0.0
    for leaf in jax.tree_util.tree_leaves(grad):
        assert np.all(np.isfinite(np.asarray(leaf)))
    # A nonzero error shows up in each weighted term.
    moved = predicted.replace(pos=predicted.pos + 0.1)
    assert float(sysid.trajectory_loss(moved, observed, {"position": 2.0})) == pytest.approx(
        2.0 * dim * 0.01, rel=1e-9)


# --- the fit loop ------------------------------------------------------------------

def test_fit_recovers_mass_and_inertia_2d_calls_back_and_compiles_once(free_2d):
    step, truth, state, applied, traj = free_2d
    observed = sysid.observe(traj, steps=np.arange(4, PUSH_STEPS + 1, 4))
    start = truth.replace(mass=truth.mass * 1.5, inertia=truth.inertia * 0.5)
    calls, traces, lines = [], [], []

    def loss(predicted, observed):
        traces.append(1)  # runs only while tracing
        return sysid.trajectory_loss(predicted, observed)

    result = sysid.fit(step, start, state, observed, fields=("mass", "inertia"), optimizer=optax.adam(0.05),
                       num_steps=300, applied=applied, loss=loss, log_every=100, print_fn=lines.append,
                       callback=lambda k, value, params: calls.append((k, value, params)), callback_every=25)
    assert len(traces) == 1  # one jitted update for the whole fit
    assert [k for k, _, _ in calls] == list(range(0, 301, 25))
    assert all(isinstance(p, rb.Params) for _, _, p in calls)
    assert calls[0][1] == result.losses[0] and calls[-1][1] == result.losses[300]
    # The compile is announced (a long rollout's takes tens of seconds), then a loss line every 100.
    assert lines[0] == "sysid: compiling the loss gradient of a 40-step rollout…"
    assert lines[1].startswith("sysid: compiled and took the first step in ")
    assert len(lines) == 6 and all("loss" in line for line in lines[2:])
    assert result.losses.shape == (301,) and result.steps == 300
    assert result.losses[result.best_step] == result.losses.min()
    # Noise-free data: both recovered to 1e-4.
    np.testing.assert_allclose(result.params.mass, truth.mass, rtol=1e-4)
    np.testing.assert_allclose(result.params.inertia, truth.inertia, rtol=1e-4)


def _tumbler_fit_inputs(monkeypatch):
    """``(calls, fit)``: a list that grows each time the adjoint is traced, and a 3D free body's inertia fit."""
    calls = []
    hand_written = rb.physics.adjoint.rollout
    monkeypatch.setattr(rb.physics.adjoint, "rollout", lambda *args: calls.append(1) or hand_written(*args))
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, -9.81))
    scene.add_body(None, mass=2.0, inertia=(0.05, 0.08, 0.11), angvel=(0.5, 3.0, -0.2), vel=(1.0, 0.0, 2.0))
    model, truth, state = scene.build(dt=1 / 60)
    step = rb.make_step(model)
    observed = sysid.observe(jax.jit(lambda s, p: rb.rollout(step, s, p, 30))(state, truth))
    start = truth.replace(inertia=truth.inertia * 1.3)
    return calls, functools.partial(sysid.fit, step, start, state, observed, fields="inertia",
                                    optimizer=optax.adam(0.05), num_steps=5)


def test_fit_takes_the_same_steps_with_the_hand_written_adjoint(monkeypatch):
    """A 3D free body: fit's default (the adjoint) and autodiff take the same optimiser steps."""
    calls, fit = _tumbler_fit_inputs(monkeypatch)
    fits = [fit(adjoint=adjoint) for adjoint in (False, None)]
    assert len(calls) == 1  # traced once, by the default (adjoint=None) fit
    np.testing.assert_allclose(fits[1].losses, fits[0].losses, rtol=1e-9)
    np.testing.assert_allclose(fits[1].params.inertia, fits[0].params.inertia, rtol=1e-9)
    assert not np.allclose(fits[0].losses[1:], fits[0].losses[0])  # the steps changed the loss


def test_fit_takes_the_adjoint_on_any_backend(monkeypatch):
    """On an H200 the adjoint was the faster at one world too (docs/accelerator.md): the default takes it there."""
    calls, fit = _tumbler_fit_inputs(monkeypatch)
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    result = fit()
    assert len(calls) == 1 and np.all(np.isfinite(result.losses))
    fit(adjoint=False)
    assert len(calls) == 1  # turned off, it is not taken


def test_fit_stops_early_and_many_trajectories_share_params():
    """Two worlds (vmapped) from different starts share one mass; tol stops the fit."""
    model, truth, state = free_2d_scene(num_bodies=2)
    step = rb.make_step(model)
    applied = push_2d(num_bodies=2)
    starts = jax.tree_util.tree_map(lambda a: jnp.stack([a, a]), state)
    starts = starts.replace(vel=starts.vel.at[1].set(jnp.array([[1.0, 0.0], [0.0, -1.0]])))
    applied_batch = jax.tree_util.tree_map(lambda a: jnp.stack([a, 2.0 * a]), applied)
    traj = jax.jit(jax.vmap(lambda s, w: rb.rollout(step, s, truth, PUSH_STEPS, every=4, applied=w)))(
        starts, applied_batch)
    observed = jax.vmap(lambda t: sysid.observe(t, every=4))(traj)
    start = truth.replace(mass=truth.mass * 0.5)
    # The batched objective is the mean of the single-world objectives.
    objective = sysid.make_objective(step, PUSH_STEPS, 4, batched=True)
    single = sysid.make_objective(step, PUSH_STEPS, 4)
    worlds = [single(start, *jax.tree_util.tree_map(lambda a: a[i], (starts, observed, applied_batch)))
              for i in range(2)]
    np.testing.assert_allclose(objective(start, starts, observed, applied_batch), np.mean(worlds), rtol=1e-12)

    result = sysid.fit(step, start, starts, observed, fields={"mass": np.array([True, False])},
                       optimizer=optax.adam(0.05), num_steps=500, applied=applied_batch, tol=1e-3, patience=10)
    assert result.stopped_early and result.steps < 500 and result.losses.shape == (result.steps + 1,)
    np.testing.assert_allclose(result.params.mass[0], truth.mass[0], rtol=1e-3)
    assert float(result.params.mass[1]) == float(start.mass[1])  # masked out


def test_fit_rejects_bad_observations(free_2d):
    step, truth, state, applied, traj = free_2d
    observed = sysid.observe(traj)
    with pytest.raises(ValueError, match="'steps'"):
        sysid.fit(step, truth, state, observed.replace(steps=observed.steps - 1), fields="mass",
                  optimizer=optax.adam(0.1), num_steps=1)
    with pytest.raises(ValueError, match="'pos' must have shape"):
        sysid.fit(step, truth, state, observed.replace(pos=observed.pos[:, :, :1]), fields="mass",
                  optimizer=optax.adam(0.1), num_steps=1)
    with pytest.raises(ValueError, match="'applied' covers 10 steps"):
        sysid.fit(step, truth, state, observed, fields="mass", optimizer=optax.adam(0.1), num_steps=1,
                  applied=jax.tree_util.tree_map(lambda a: a[:10], applied))


def test_fit_rejects_samples_labelled_with_the_wrong_every(free_2d):
    """observe(every=k) on an every-step rollout labels sample i as step k(i+1): the states' times say otherwise."""
    step, truth, state, applied, traj = free_2d
    mislabelled = sysid.observe(jax.tree_util.tree_map(lambda a: a[:10], traj), every=4)
    with pytest.raises(ValueError, match=r"labelled step 4 .* recorded at t = 0.0166667 s; was observe\(\)'s 'every'"):
        sysid.fit(step, truth, state, mislabelled, fields="mass", optimizer=optax.adam(0.1), num_steps=1,
                  applied=applied)
    thinned = sysid.observe(traj, steps=range(4, PUSH_STEPS + 1, 4))  # what was meant
    np.testing.assert_allclose(thinned.time, np.arange(4, PUSH_STEPS + 1, 4) / 60, rtol=1e-5)


# --- recovery from noisy data (issue 4 item 5) --------------------------------------

@pytest.mark.slow
def test_recover_mass_and_inertia_of_pushed_tumbling_body():
    """A body in free fall-free space, pushed three times by 4 N at an arm of 0.2 m.

    Each push is along a different axis at a different arm, so the linear
    impulse gives the mass and the three angular impulses (then the
    torque-free tumbling) the principal moments, fitted with the
    ``principal`` transform (body axes known, 3 numbers per body).
    """
    mass, moments = 2.0, np.array([0.05, 0.08, 0.11])
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, 0.0))
    scene.add_body(None, mass=mass, inertia=moments, angvel=(0.5, 0.3, -0.2))
    model, truth, state = scene.build(dt=1 / 60)
    step = rb.make_step(model)
    num_steps = 120  # three 1/6 s pushes, then 1.5 s of torque-free tumbling
    force, torque = np.zeros((num_steps, 1, 3)), np.zeros((num_steps, 1, 3))
    for index, (push, arm) in enumerate([((4.0, 0, 0), (0, 0.2, 0)), ((0, 4.0, 0), (0, 0, 0.2)),
                                         ((0, 0, 4.0), (0.2, 0, 0))]):
        pushed = slice(10 * index, 10 * index + 10)
        force[pushed, 0], torque[pushed, 0] = push, np.cross(arm, push)
    applied = rb.Wrench(force=jnp.asarray(force), torque=jnp.asarray(torque))
    traj = jax.jit(lambda s, p: rb.rollout(step, s, p, num_steps, applied=applied))(state, truth)
    observed = noisy(sysid.observe(traj), traj, seed=0)
    # Orientation noise too: a random rotation of 0.005 rad rms per axis.
    jitter = rb.quaternion.exp(jnp.asarray(np.random.default_rng(1).normal(scale=0.005, size=observed.pos.shape)))
    observed = observed.replace(quat=rb.quaternion.multiply(jitter, observed.quat))

    start = truth.replace(mass=truth.mass * 1.5, inertia=truth.inertia * 1.5)
    result = sysid.fit(step, start, state, observed, fields=("mass", "inertia"), optimizer=optax.adam(0.05),
                       num_steps=MAX_FIT_STEPS, applied=applied, weights={"orientation": 0.01},
                       transforms={"inertia": "principal"}, tol=1e-4, patience=20)
    assert result.steps <= MAX_FIT_STEPS
    assert_recovered(result.params.mass, truth.mass, "mass")
    assert_recovered(np.diag(result.params.inertia[0]), moments, "principal inertia")


@pytest.mark.slow
def test_recover_friction_of_sliding_box():
    """A box sliding at 2 m/s on a plane of μ = 0.5; the body's μ = 0.4 is fitted (mixed √(μ_A μ_B))."""
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.5)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.1), vel=(2.0, 0.0, 0.0), friction=0.4)
    step, truth, state, observed = penalty_observations(scene, 1000, seed=2)
    start = truth.replace(friction=truth.friction * 1.5)
    result = sysid.fit(step, start, state, observed, fields="friction", optimizer=optax.adam(0.05),
                       num_steps=MAX_FIT_STEPS, tol=1e-5, patience=30)
    assert_recovered(result.params.friction, truth.friction, "friction")


@pytest.mark.slow
def test_recover_restitution_of_bouncing_ball():
    """A ball dropped from 0.5 m (bounces twice in 1.2 s) on a plane of restitution 0 (mixed max(e_A, e_B))."""
    scene = rb.Scene(dim=3)
    scene.add_plane(restitution=0.0)
    scene.add_body(rb.Sphere(0.1), mass=1.0, pos=(0.0, 0.0, 0.6), vel=(0.3, 0.0, 0.0), restitution=0.7)
    # The smooth (softplus) spring: with the hard one the step a bounce lands on
    # is discrete in e, and near the truth d loss/d e had the wrong sign (+0.09 at
    # e = 0.68, where the loss falls about 0.1 per unit of e), so Adam wandered and
    # where it stopped hung on float rounding. With a 1 mm width the gradient
    # follows the loss's finite differences and crosses zero at e = 0.700.
    step, truth, state, observed = penalty_observations(scene, 1200, seed=3, contact=rb.Penalty(width=1e-3))
    start = truth.replace(restitution=truth.restitution * 0.5)
    # No early stopping: the loss sits on a plateau (0.020 -> 0.018) for ~150
    # steps before it falls to the noise floor, which fooled tol=1e-3, patience=100.
    result = sysid.fit(step, start, state, observed, fields="restitution", optimizer=optax.adam(0.05),
                       num_steps=MAX_FIT_STEPS)
    assert_recovered(result.params.restitution, truth.restitution, "restitution")


@pytest.mark.slow
def test_recover_friction_and_restitution_of_2d_box_tumbling_onto_ground():
    """Three throws of a 2D box (one parameter set, vmapped): a drop, a low slide, a tumble.

    The drop shows restitution, the slide friction; fitted together from 50 %
    below the truth. (From 50 % above, the tumbling throw's sequence of corner
    impacts changes with the parameters and the loss has local minima: a
    single 0.3 rad, 2 rad/s throw at e = 0.9 gives losses that jump by 10x
    between e = 0.78 and 0.84.)
    """
    throws = [dict(pos=(0.0, 0.8), angle=0.05, vel=(0.5, 0.0), angvel=0.0),
              dict(pos=(0.0, 0.15), angle=0.05, vel=(3.0, 0.0), angvel=0.0),
              dict(pos=(0.0, 0.4), angle=0.3, vel=(1.5, 0.0), angvel=2.0)]
    states = []
    for throw in throws:
        scene = rb.Scene(dim=2)
        scene.add_plane(friction=1.0, restitution=0.0)
        scene.add_body(rb.Box((0.2, 0.1)), mass=1.0, friction=0.3, restitution=0.5, **throw)
        model, truth, state = scene.build(contact="penalty", dt=1e-3)
        states.append(state)
    starts = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *states)
    step = rb.make_step(model)
    traj = jax.jit(jax.vmap(lambda s: rb.rollout(step, s, truth, 800, every=10)))(starts)
    observed = noisy(jax.vmap(lambda t: sysid.observe(t, every=10))(traj), traj, seed=4)
    start = truth.replace(friction=truth.friction * 0.5, restitution=truth.restitution * 0.5)
    result = sysid.fit(step, start, starts, observed, fields=("friction", "restitution"),
                       optimizer=optax.adam(0.05), num_steps=MAX_FIT_STEPS, tol=1e-4, patience=50)
    assert_recovered(result.params.friction, truth.friction, "friction")
    assert_recovered(result.params.restitution, truth.restitution, "restitution")


def test_a_masked_field_checks_only_the_elements_it_fits():
    """Fitting one body's restitution failed on the other bodies' default 0 (outside the sigmoid's domain)."""
    scene = rb.Scene(dim=3)
    scene.add_plane()
    scene.add_body(rb.Sphere(0.1), mass=1.0, pos=(0.0, 0.0, 0.5))
    scene.add_body(rb.Sphere(0.1), mass=1.0, pos=(1.0, 0.0, 0.5), restitution=0.7)
    _, params, _ = scene.build(dt=0.01)
    only_second = {"restitution": np.array([False, True])}
    unconstrained = sysid.to_unconstrained(params, only_second)
    back = sysid.from_unconstrained(unconstrained, params, only_second)
    np.testing.assert_allclose(back.restitution, [0.0, 0.7], rtol=1e-6)
    with pytest.raises(ValueError, match=r"outside the open interval.*transforms=\{'restitution': 'clip'\}"):
        sysid.to_unconstrained(params, "restitution")  # the whole field: body 0's 0 is outside (0, 1)
