"""Sweeps: batches built from one world, one vmapped call, sharding over devices.

The physics check is the bouncing sphere of tests/test_contact.py (impulse
contact, dt = 1/240 s with 4 substeps): the apex after the first bounce is
e²·h0 for restitution e and drop height h0 (measured at the sphere's bottom).
"""

import dataclasses
import json
import math
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrb as rb
from jaxrb import sweep as rb_sweep

G = 9.81
RADIUS = 0.1
DROP = 1.0  # initial centre height, so the bottom falls h0 = 0.9 m
DT, SUBSTEPS = 1 / 240, 4
# 0.9 s: the first impact is at 0.43 s and the first apex 0.43·e s later, 0.84 s for
# e = 0.95. Later flights are lower (e⁴·h0), so the maximum after the first rebound
# is the first apex whatever else the horizon holds.
NUM_STEPS = 216
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def bounce_world(dtype=None):
    """A sphere above a plane; plane restitution 0, so the mixed max(e_A, e_B) is the body's."""
    scene = rb.Scene(dim=3)
    scene.add_plane(restitution=0.0)
    scene.add_body(rb.Sphere(RADIUS), mass=1.0, pos=(0.0, 0.0, DROP))
    return scene.build(contact="impulse", dt=DT, substeps=SUBSTEPS, dtype=dtype)


def first_apex(trajectory, params):
    """Highest bottom height once the sphere has started moving up (after the first bounce)."""
    height = trajectory.pos[:, 0, 2] - RADIUS
    rebounded = jnp.cumsum(trajectory.vel[:, 0, 2] > 0.0) > 0
    return jnp.max(jnp.where(rebounded, height, -jnp.inf))


@pytest.fixture(scope="module")
def world():
    model, params, state = bounce_world()
    step = rb.make_step(model)
    # One function object for the module, so sweeps of it share compiled code.
    return params, state, rb_sweep.rollout_outcome(step, NUM_STEPS, first_apex)


def impact_tolerance(h0):
    """The impact is resolved in the substep where the sphere reaches the plane, so
    the bounce starts up to one substep's travel at impact speed, √(2 g h0)·dt/substeps,
    away from the plane; the apex inherits that height error (sampling the apex at dt
    adds only g·dt²/8 = 2e-5 m)."""
    return math.sqrt(2 * G * h0) * DT / SUBSTEPS


def test_restitution_sweep_matches_closed_form_in_one_call(world):
    params, state, apex = world
    restitution = np.linspace(0.2, 0.95, 1024)  # rebound speed >= 0.84 m/s, above bounce_threshold
    batch = rb_sweep.batch_params(params, restitution=restitution)
    assert batch.restitution.shape == (1024, 1) and batch.mass.shape == (1024, 1)
    heights = np.asarray(rb_sweep.sweep(apex, batch, state=state))
    assert heights.shape == (1024,)
    h0 = DROP - RADIUS
    np.testing.assert_allclose(heights, h0 * restitution ** 2, rtol=0, atol=impact_tolerance(h0))
    # The documented first-apex accuracy at e = 0.8 (tests/test_contact.py): within 0.5 %.
    at = np.argmin(abs(restitution - 0.8))
    assert abs(heights[at] / (h0 * restitution[at] ** 2) - 1) < 5e-3


def test_sweep_over_states_and_params_together(world):
    params, state, apex = world
    drops = np.linspace(0.5, 1.0, 8)
    restitution = np.linspace(0.5, 0.9, 8)
    states = rb_sweep.batch_state(state, pos=np.stack([np.zeros(8), np.zeros(8), drops], axis=1))
    assert states.pos.shape == (8, 1, 3) and states.quat.shape == (8, 1, 4)
    heights = np.asarray(rb_sweep.sweep(apex, rb_sweep.batch_params(params, restitution=restitution), states))
    h0 = drops - RADIUS
    np.testing.assert_allclose(heights, h0 * restitution ** 2, rtol=0, atol=impact_tolerance(h0.max()))


def test_repeated_sweep_does_not_retrace():
    scene = rb.Scene(dim=3)  # no plane: a cheap free-fall step
    scene.add_body(rb.Sphere(RADIUS), mass=1.0, pos=(0.0, 0.0, DROP))
    model, params, state = scene.build(dt=DT, substeps=SUBSTEPS)
    step = rb.make_step(model)
    traces = []

    def one_step(state, params):
        traces.append(1)  # runs only while tracing
        return step(state, params).pos

    batch = rb_sweep.batch_params(params, mass=np.linspace(1.0, 2.0, 16))
    first = rb_sweep.sweep(one_step, batch, state=state)
    second = rb_sweep.sweep(one_step, batch.replace(dt=batch.dt * 0.5), state=state)
    assert len(traces) == 1
    assert first.shape == (16, 1, 3)
    # Free fall from rest over one step of dt (semi-implicit Euler, 4 substeps of h),
    # independent of mass:
    # z = z0 − g h²·n(n+1)/2, different for the halved dt, so the second call really ran.
    for out, dt in ((first, DT), (second, DT / 2)):
        h = dt / SUBSTEPS
        np.testing.assert_allclose(out[:, 0, 2], DROP - G * h * h * SUBSTEPS * (SUBSTEPS + 1) / 2, rtol=1e-12)


def test_batch_params_broadcasts_into_per_body_fields():
    scene = rb.Scene(dim=3)
    for x in (0.0, 1.0):
        scene.add_body(rb.Sphere(0.1), mass=1.0, pos=(x, 0.0, 1.0))
    _, params, state = scene.build(dt=0.01, dtype=jnp.float32)
    batch = rb_sweep.batch_params(params, restitution=[0.1, 0.2, 0.3],
                                  friction=[[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]],
                                  gravity=np.tile([0.0, 0.0, -1.0], (3, 1)), dt=[0.1, 0.2, 0.3],
                                  inertia=np.broadcast_to(np.eye(3), (3, 3, 3)))
    np.testing.assert_allclose(batch.restitution, [[0.1, 0.1], [0.2, 0.2], [0.3, 0.3]], rtol=1e-6)
    np.testing.assert_allclose(batch.friction, [[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]], rtol=1e-6)
    assert batch.gravity.shape == (3, 3) and batch.dt.shape == (3,)
    assert batch.inertia.shape == (3, 2, 3, 3)
    np.testing.assert_array_equal(batch.mass, np.ones((3, 2)))  # untouched fields are copies
    assert all(leaf.dtype == jnp.float32 for leaf in jax.tree_util.tree_leaves(batch))
    states = rb_sweep.batch_state(state, vel=np.array([[1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]))
    np.testing.assert_array_equal(states.vel[:, :, 0], [[1.0, 1.0], [2.0, 2.0]])
    assert states.time.shape == (2,)


@pytest.mark.parametrize("fields,message", [
    (dict(elasticity=[0.1]), "elasticity"),
    (dict(restitution=0.5), "restitution"),  # no batch axis
    (dict(restitution=np.zeros((4, 3))), "restitution"),  # 3 is not the body count 1
    (dict(gravity=np.zeros((4, 2))), "gravity"),
    (dict(restitution=[0.1, 0.2], friction=[0.1, 0.2, 0.3]), "different batch sizes"),
    (dict(dt=[0.01, np.nan]), "dt"),
    (dict(friction=["low", "high"]), "friction.*numeric"),
    (dict(), "at least one field"),
    (dict(inv_inertia=np.ones((2, 1, 3, 3))), "'inv_inertia' is derived"),
    (dict(mass=-np.ones(4)), r"'mass' must be > 0.0, got -1.0 at index \(0, 0\)"),  # was accepted
    (dict(restitution=[0.5, 1.2]), r"'restitution' must be <= 1.0, got 1.2 at index \(1, 0\)"),
    (dict(inertia=np.ones(3)), "'inertia' at index \\(0, 0\\) is singular"),  # every entry 1: rank one
])
def test_batch_params_rejects_bad_input(world, fields, message):
    params, _, _ = world
    with pytest.raises(ValueError, match=message):
        rb_sweep.batch_params(params, **fields)


@pytest.mark.parametrize("batched", ["states", "params", "both"])
def test_sweep_in_chunks_equals_one_vmap_and_free_fall(batched):
    # 10 worlds in chunks of 4: two chunks and a remainder of 2 run apart.
    scene = rb.Scene(dim=3)  # no plane: a cheap free-fall step
    scene.add_body(rb.Sphere(RADIUS), mass=1.0, pos=(0.0, 0.0, DROP))
    model, params, state = scene.build(dt=DT, substeps=SUBSTEPS)
    step = rb.make_step(model)
    up = np.linspace(-1.0, 1.0, 10)
    states = rb_sweep.batch_state(state, vel=np.stack([np.zeros(10), np.zeros(10), up], axis=1))
    dts = DT * np.linspace(0.5, 1.5, 10)
    steps = rb_sweep.batch_params(params, dt=dts)
    sides = dict(states=dict(states_batch=states, params=params), params=dict(params_batch=steps, state=state),
                 both=dict(states_batch=states, params_batch=steps))[batched]
    one_vmap = rb_sweep.sweep(step, **sides, chunk=None)
    chunked = rb_sweep.sweep(step, **sides, chunk=4)
    assert chunked.pos.shape == one_vmap.pos.shape == (10, 1, 3)
    for name in ("pos", "vel", "quat", "angvel"):
        np.testing.assert_allclose(getattr(chunked, name), getattr(one_vmap, name), rtol=1e-12, atol=0)
    # n semi-implicit substeps of h = dt/n from upward speed v0, each world its own:
    # z = z0 + n h v0 − g h² n(n+1)/2.
    n = SUBSTEPS
    h = (dts if batched != "states" else np.full(10, DT)) / n
    v0 = up if batched != "params" else np.zeros(10)
    np.testing.assert_allclose(chunked.pos[:, 0, 2], DROP + n * h * v0 - G * h * h * n * (n + 1) / 2, rtol=1e-12)


@pytest.mark.parametrize("chunk", [0, -3, 2.5, "fast", True])
def test_sweep_rejects_bad_chunk(world, chunk):
    params, state, apex = world
    batch = rb_sweep.batch_params(params, restitution=np.full(4, 0.5))
    with pytest.raises(ValueError, match="'chunk'"):
        rb_sweep.sweep(apex, batch, state=state, chunk=chunk)


def test_sweep_rejects_chunk_with_shard(world):
    params, state, apex = world
    batch = rb_sweep.batch_params(params, restitution=np.full(4, 0.5))
    with pytest.raises(ValueError, match="'shard'"):
        rb_sweep.sweep(apex, batch, state=state, shard=True, chunk=2)


def test_batch_state_rejects_missing_field(world):
    _, state, _ = world
    with pytest.raises(ValueError, match="'angle'"):
        rb_sweep.batch_state(state, angle=[0.0, 1.0])  # 3D state: no angle


def test_sweep_rejects_bad_batches(world):
    params, state, apex = world
    params_batch = rb_sweep.batch_params(params, restitution=np.full(4, 0.5))
    states_batch = rb_sweep.batch_state(state, pos=np.tile([0.0, 0.0, 1.0], (3, 1)))
    with pytest.raises(ValueError, match="different batch sizes"):
        rb_sweep.sweep(apex, params_batch, states_batch)
    with pytest.raises(ValueError, match="'friction' must have shape"):
        params_batch.replace(friction=jnp.full((5, 1), 0.5))
    # Batches put together by hand (Params.replace refuses these) are checked by sweep too.
    ragged = dataclasses.replace(params_batch, friction=jnp.full((5, 1), 0.5))
    with pytest.raises(ValueError, match="friction"):
        rb_sweep.sweep(apex, ragged, state=state)
    with pytest.raises(ValueError, match="params_batch"):
        rb_sweep.sweep(apex, state=state, params=params)
    with pytest.raises(ValueError, match="not both"):
        rb_sweep.sweep(apex, params_batch, params=params, state=state)
    with pytest.raises(ValueError, match="dt"):
        rb_sweep.sweep(apex, dataclasses.replace(params_batch, dt=params.dt), state=state)
    with pytest.raises(ValueError, match="states_batch="):  # a State in the params slot
        rb_sweep.sweep(apex, states_batch, params=params)
    with pytest.raises(ValueError, match="num_steps"):
        rb_sweep.rollout_outcome(rb.make_step(bounce_world()[0]), 0, first_apex)


def test_rollout_outcome_without_outcome_returns_trajectories():
    scene = rb.Scene(dim=3)
    scene.add_body(rb.Sphere(0.1), mass=1.0, pos=(0.0, 0.0, 0.0))
    model, params, state = scene.build(dt=0.1)
    run = rb_sweep.rollout_outcome(rb.make_step(model), 10, every=5)
    states = rb_sweep.batch_state(state, vel=np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]))
    traj = rb_sweep.sweep(run, states_batch=states, params=params)
    assert traj.pos.shape == (3, 2, 1, 3)
    # Ballistic: semi-implicit Euler from rest height 0: z(t_k) = v0z t − g h² k(k+1)/2.
    k = np.array([5, 10])
    expected_z = 3.0 * 0.1 * k - G * 0.01 * k * (k + 1) / 2
    np.testing.assert_allclose(traj.pos[2, :, 0, 2], expected_z, rtol=1e-12)
    np.testing.assert_allclose(traj.pos[1, :, 0, 1], 2.0 * 0.1 * k, rtol=1e-12)


SHARDED_SCRIPT = textwrap.dedent("""
    import json
    import jax
    jax.config.update("jax_enable_x64", True)
    import numpy as np
    import jaxrb as rb
    from jaxrb import sweep as rb_sweep
    from tests.test_sweep import NUM_STEPS, bounce_world, first_apex

    model, params, state = bounce_world()
    apex = rb_sweep.rollout_outcome(rb.make_step(model), NUM_STEPS, first_apex)
    restitution = np.linspace(0.2, 0.95, 1024)
    plain = rb_sweep.sweep(apex, rb_sweep.batch_params(params, restitution=restitution), state=state)
    report = {"devices": len(jax.devices()), "plain": np.asarray(plain).tolist()}
    # 1021 worlds are padded to 1024, so both sharded calls share one compiled program.
    for size in (1024, 1021):
        batch = rb_sweep.batch_params(params, restitution=restitution[:size])
        sharded = rb_sweep.sweep(apex, batch, state=state, shard=True)
        report[str(size)] = {
            "sharded": np.asarray(sharded).tolist(),
            "devices_used": len(sharded.sharding.device_set),
            "shard_rows": sorted({s.data.shape[0] for s in sharded.addressable_shards}),
        }
    print("RESULT" + json.dumps(report))
""")


@pytest.fixture(scope="module")
def sharded_run():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4", JAX_PLATFORMS="cpu",
               PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    done = subprocess.run([sys.executable, "-c", SHARDED_SCRIPT], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    line = [text for text in done.stdout.splitlines() if text.startswith("RESULT")][-1]
    return json.loads(line[len("RESULT"):])


def test_sharded_sweep_splits_batch_over_devices(sharded_run):
    assert sharded_run["devices"] == 4
    divisible = sharded_run["1024"]
    assert divisible["devices_used"] == 4
    assert divisible["shard_rows"] == [256]  # each device holds a quarter of the batch
    np.testing.assert_allclose(divisible["sharded"], sharded_run["plain"], rtol=1e-12, atol=0)


def test_sharded_sweep_pads_batch_not_divisible_by_device_count(sharded_run):
    uneven = sharded_run["1021"]
    assert len(uneven["sharded"]) == 1021  # padded to 1024 to run, trimmed after
    np.testing.assert_allclose(uneven["sharded"], sharded_run["plain"][:1021], rtol=1e-12, atol=0)
