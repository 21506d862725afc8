"""Contact scenes against closed forms, for the impulse and penalty models.

Settings per model (documented in the closing note and the guide):
impulse at h = 1/60 s with 4 substeps unless a test says otherwise; penalty at
h = 1 ms (its default spring is 0.03/h Hz, stable for symplectic Euler).
"""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxrb as rb

G = 9.81
MODELS = {"impulse": dict(dt=1 / 60, substeps=4), "penalty": dict(dt=1e-3, substeps=1)}


def simulate(model, params, state, seconds, every=1):
    step = rb.make_step(model)
    num_steps = int(round(seconds / float(params.dt)))
    num_steps -= num_steps % every
    return jax.jit(lambda s, p: rb.rollout(step, s, p, num_steps, every=every))(state, params)


def apexes(height, vz):
    """Heights where the vertical velocity turns from up to down."""
    height, vz = np.asarray(height), np.asarray(vz)
    return np.array([height[i] for i in range(1, len(vz)) if vz[i - 1] > 0.0 >= vz[i]])


# --- bouncing sphere ----------------------------------------------------------------

def bounce_scene(contact, restitution=0.8, drop=1.0, **build):
    scene = rb.Scene(dim=3)
    scene.add_plane(restitution=restitution)
    scene.add_body(rb.Sphere(0.1), mass=1.0, pos=(0.0, 0.0, drop), restitution=restitution)
    return scene.build(contact=contact, **build)


@pytest.mark.parametrize("contact,settings,tolerance", [
    # The impact happens inside a substep; the O(h) timing error needs h = 1/960 s
    # (1/240 with 4 substeps) to stay under 2 % on the third bounce.
    ("impulse", dict(dt=1 / 240, substeps=4), 0.02),
    # The default spring (0.03/h Hz) holds a 4 m/s ball for 3.3 ms at h = 0.2 ms
    # (gravity takes 1 % off its rebound; 4 % at 1 ms), and the impact's phase
    # in a substep moves each bounce's e by up to ±2 % at e = 0.8.
    ("penalty", dict(dt=2e-4, substeps=1), 0.05),
])
def test_bounce_apex_heights(contact, settings, tolerance):
    model, params, state = bounce_scene(contact, **settings)
    traj = simulate(model, params, state, 3.5)
    heights = apexes(traj.pos[:, 0, 2] - 0.1, traj.vel[:, 0, 2])
    expected = 0.9 * 0.8 ** (2 * np.arange(1, 4))
    assert len(heights) >= 3
    np.testing.assert_allclose(heights[:3], expected, rtol=tolerance)


@pytest.mark.parametrize("contact", MODELS)
@pytest.mark.parametrize("restitution", [1.0, 0.9])
def test_no_energy_gain_over_fifty_bounces(contact, restitution):
    model, params, state = bounce_scene(contact, restitution, drop=1.0, **MODELS[contact])
    traj = simulate(model, params, state, 45.0, every=2)
    energy = jax.vmap(lambda s: (rb.kinetic_energy(model, params, s) + rb.potential_energy(model, params, s)).sum())(traj)
    initial = float((rb.kinetic_energy(model, params, state) + rb.potential_energy(model, params, state)).sum())
    # Symplectic Euler conserves E + ½ h m g·v, so E itself swings by ½ h m |g| |v|.
    speed = math.sqrt(2 * G * 0.9)
    swing = 0.5 * float(params.dt) / model.substeps * G * speed * model.substeps
    assert float(jnp.max(energy)) <= initial + swing
    bounces = len(apexes(traj.pos[:, 0, 2], traj.vel[:, 0, 2]))
    if restitution == 1.0:
        assert bounces >= 50


@pytest.mark.parametrize("contact", MODELS)
def test_head_on_spheres_conserve_momentum(contact):
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, 0.0))
    scene.add_body(rb.Sphere(0.1), mass=1.0, pos=(-0.5, 0.0, 0.0), vel=(2.0, 0.0, 0.0), restitution=1.0)
    scene.add_body(rb.Sphere(0.1), mass=3.0, pos=(0.5, 0.0, 0.0), vel=(-1.0, 0.0, 0.0), restitution=1.0)
    model, params, state = scene.build(contact=contact, **MODELS[contact])
    traj = simulate(model, params, state, 1.0)
    momentum = jnp.sum(params.mass[None, :, None] * traj.vel, axis=1)
    np.testing.assert_allclose(momentum, np.broadcast_to([-1.0, 0.0, 0.0], momentum.shape), atol=1e-9)
    # Elastic: 1D closed form u1 = -2.5, u2 = 0.5 (within 2 % for the penalty spring).
    np.testing.assert_allclose(traj.vel[-1, :, 0], [-2.5, 0.5], rtol=0.02, atol=0.02)


# --- friction -----------------------------------------------------------------------

@pytest.mark.parametrize("contact", MODELS)
def test_sliding_box_stopping_distance(contact):
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.5)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.1), vel=(2.0, 0.0, 0.0), friction=0.5)
    model, params, state = scene.build(contact=contact, **MODELS[contact])
    traj = simulate(model, params, state, 1.0)
    distance = float(traj.pos[-1, 0, 0] - state.pos[0, 0])
    np.testing.assert_allclose(distance, 2.0 ** 2 / (2 * 0.5 * G), rtol=0.02)
    assert abs(float(traj.vel[-1, 0, 0])) < 1e-3


def incline_plane(scene, angle, friction):
    """A plane through the origin descending towards +x at ``angle``; returns (normal, downhill)."""
    normal = np.array([math.sin(angle), 0.0, math.cos(angle)])
    scene.add_plane(normal=normal, friction=friction)
    return normal, np.array([math.cos(angle), 0.0, -math.sin(angle)])


@pytest.mark.parametrize("contact", MODELS)
def test_sphere_rolls_down_incline(contact):
    angle, radius = math.radians(30.0), 0.1
    scene = rb.Scene(dim=3)
    normal, downhill = incline_plane(scene, angle, friction=1.0)
    scene.add_body(rb.Sphere(radius), mass=1.0, pos=radius * normal, friction=1.0)
    model, params, state = scene.build(contact=contact, **MODELS[contact])
    traj = simulate(model, params, state, 1.0)
    t = np.asarray(traj.time)
    along = np.asarray(traj.pos[:, 0] @ downhill)
    late = t > 0.2  # after the contact has settled
    acceleration = 2.0 * np.polyfit(t[late], along[late], 2)[0]
    np.testing.assert_allclose(acceleration, 5.0 / 7.0 * G * math.sin(angle), rtol=0.02)
    speed = float(np.asarray(traj.vel[-1, 0]) @ downhill)
    spin = float(np.linalg.norm(traj.angvel[-1, 0]))
    # Rolling without slipping: ω ρ = v, with ρ the distance from the centre to
    # the contact point (r less half the penalty overlap), up to what one step
    # of gravity along the slope adds between the velocity and friction
    # updates, g·sin θ·dt (1 % over it for rounding: the penalty spring sits on it).
    final = jax.tree_util.tree_map(lambda a: a[-1], traj)
    contacts = rb.detect_contacts(model, params, final)
    rolling_radius = float(np.linalg.norm(contacts.point[0] - final.pos[0]))
    assert radius - 1e-3 < rolling_radius <= radius
    assert abs(spin * rolling_radius - speed) < 1.01 * G * math.sin(angle) * float(params.dt)
    assert speed > 3.0


RAMP_ANGLE = 0.25
STICKING = (0.387, 0.316, 0.265)
SLIDING = (0.141, 0.0)


def ramp_velocities(contact, frictions):
    """Downhill speed (len(frictions), T) of a box on a 0.25 rad ramp, one vmapped compile."""
    scene = rb.Scene(dim=3)
    normal, downhill = incline_plane(scene, RAMP_ANGLE, friction=0.5)
    tilt = rb.quaternion.from_axis_angle(jnp.array([0.0, 1.0, 0.0]), RAMP_ANGLE)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=0.1 * normal, quat=np.asarray(tilt))
    model, params, state = scene.build(contact=contact, **MODELS[contact])
    # Box and plane share μ, so the mixed √(μ μ) is μ.
    batch = jax.vmap(lambda mu: params.replace(friction=jnp.full((1,), mu), plane_friction=jnp.full((1,), mu)))(
        jnp.asarray(frictions))
    step = rb.make_step(model)
    num_steps = int(round(1.0 / float(params.dt)))
    traj = jax.jit(jax.vmap(lambda p: rb.rollout(step, state, p, num_steps), in_axes=0))(batch)
    return np.asarray(traj.time[0]), np.asarray(traj.vel[:, :, 0]) @ downhill


@pytest.mark.parametrize("contact", MODELS)
def test_friction_ramp_slides_at_closed_form_acceleration(contact):
    t, speed = ramp_velocities(contact, SLIDING)
    late = t > 0.3
    for index, mu in enumerate(SLIDING):
        acceleration = np.polyfit(t[late], speed[index, late], 1)[0]
        expected = G * (math.sin(RAMP_ANGLE) - mu * math.cos(RAMP_ANGLE))
        np.testing.assert_allclose(acceleration, expected, rtol=0.02)


@pytest.mark.parametrize("contact", MODELS)
def test_friction_ramp_sticks_below_friction_angle(contact):
    _, speed = ramp_velocities(contact, STICKING)
    assert np.all(np.abs(speed[:, -1]) < 1e-3), speed[:, -1]


# --- classification, tunnelling, pair table ---------------------------------------------

def test_contact_status_resting_colliding_separating():
    scene = rb.Scene(dim=3)
    scene.add_plane()
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.1))
    model, params, state = scene.build(**MODELS["impulse"])
    resting = rb.detect_contacts(model, params, state)
    assert set(np.asarray(resting.status[resting.active]).tolist()) == {rb.RESTING}
    assert int(jnp.sum(resting.active)) == 4
    falling = rb.detect_contacts(model, params, state.replace(vel=jnp.array([[0.0, 0.0, -2.0]])))
    assert set(np.asarray(falling.status[falling.active]).tolist()) == {rb.COLLIDING}
    rising = rb.detect_contacts(model, params, state.replace(vel=jnp.array([[0.0, 0.0, 2.0]])))
    assert set(np.asarray(rising.status[rising.active]).tolist()) == {rb.SEPARATING}
    settled = simulate(model, params, state, 1.0, every=60)
    final = jax.tree_util.tree_map(lambda x: x[-1], settled)
    contacts = rb.detect_contacts(model, params, final)
    assert set(np.asarray(contacts.status[contacts.active]).tolist()) == {rb.RESTING}
    # Called outside jit, it ran op by op (seconds of compiling per call site): now
    # one compiled program per Model, whatever the state.
    assert rb.detect_contacts._cache_size() >= 1
    before = rb.detect_contacts._cache_size()
    rb.detect_contacts(model, params, state.replace(pos=state.pos + 0.01))
    assert rb.detect_contacts._cache_size() == before


@pytest.mark.parametrize("contact,settings", [
    ("impulse", dict(dt=1 / 60, substeps=1)),
    # The penalty spring needs a substep short enough to stop 10 m/s within the
    # radius: 10 substeps give a 18 Hz spring, stopping distance v/ω = 8.8 cm.
    ("penalty", dict(dt=1 / 60, substeps=10)),
])
def test_fast_body_does_not_tunnel(contact, settings):
    scene = rb.Scene(dim=3)
    scene.add_plane()
    scene.add_body(rb.Sphere(0.1), mass=1.0, pos=(0.0, 0.0, 0.5), vel=(0.0, 0.0, -10.0))
    model, params, state = scene.build(contact=contact, **settings)
    traj = simulate(model, params, state, 1.0)
    assert float(jnp.min(traj.pos[:, 0, 2])) > 0.0  # the centre never crosses the plane
    assert float(traj.pos[-1, 0, 2]) > 0.05


def test_pair_table_holds_only_the_kernels_the_scene_needs():
    scene = rb.Scene(dim=3)
    scene.add_plane()
    for x in range(3):
        scene.add_body(rb.Sphere(0.1), pos=(0.3 * x, 0.0, 0.1))
    model, _, _ = scene.build(dt=1 / 60)
    kinds = {group.kind for group in model.pair_groups}
    assert kinds == {"sphere_plane", "sphere_sphere"}
    assert "box" not in model.summary()
    free = rb.Scene(dim=3)
    free.add_body(rb.Box((0.1, 0.1, 0.1)))
    free_model, _, free_state = free.build(dt=1 / 60)
    assert free_model.contact == "none" and free_model.pair_groups == () and free_state.contact_impulse is None


def test_static_row_reads_and_sums_equal_gather_and_segment_sum():
    """row_taker/row_summer (slices and sums from the pair table) against indexing and segment_sum.

    The scene has every kind of piece: a plane group over consecutive bodies,
    a single-pair group, body–body groups whose rows are not consecutive, and
    a plane on side B (the static row n); with a broadphase the picked pairs'
    bodies are data, read one pair at a time.
    """
    from jaxrb.physics.collision.pairs import detect, plane_rows, row_summer, row_taker, static_rows

    scene = rb.Scene(dim=3)
    scene.add_plane()
    for x in range(3):
        scene.add_body(rb.Box((0.1, 0.1, 0.1)), pos=(0.15 * x, 0.0, 0.1 + 0.05 * x))
    scene.add_body(rb.Sphere(0.1), pos=(0.1, 0.1, 0.3))
    for broadphase in ("all_pairs", "spheres"):
        model, params, state = scene.build(dt=1 / 60, broadphase=broadphase, broadphase_capacity=2)
        picked = any(piece[0] == "picked" for side in static_rows(model) for piece in side)
        assert picked == (broadphase == "spheres")
        contacts = jax.jit(lambda p, s: detect(model, p, s))(params, state)
        a, b = contacts.body_a, contacts.body_b
        take, add = row_taker(model, a, b), row_summer(model, a, b)
        bodies = 1.0 + jnp.arange(4 * 3, dtype=jnp.float32).reshape(4, 3) ** 2  # n rows
        padded = jnp.concatenate([bodies, jnp.zeros((1, 3))])  # the static row (planes) is zeros
        values = jnp.sin(jnp.arange(3 * a.shape[0], dtype=jnp.float32)).reshape(-1, 3)
        for side, rows in ((0, a), (1, b)):
            np.testing.assert_array_equal(take(bodies, side), padded[rows])
            np.testing.assert_allclose(add(values, side), jax.ops.segment_sum(values, rows, 5)[:4],
                                       rtol=1e-6, atol=1e-6)
        # The sequential solver's rows against a plane move body A alone.
        np.testing.assert_array_equal(plane_rows(model), np.asarray(b) == 4)
        assert 0 < plane_rows(model).sum() < len(b)


@pytest.mark.parametrize("contact", MODELS)
def test_contact_model_with_nothing_to_touch_steps_as_free_bodies(contact):
    scene = rb.Scene(dim=3)
    scene.add_body(rb.Sphere(0.1), mass=1.0, vel=(1.0, 0.0, 0.0))
    model, params, state = scene.build(contact=contact, **MODELS[contact])
    assert model.num_contacts == 0
    moved = rb.make_step(model)(state, params)
    # Symplectic Euler over n substeps of h: z = −g h² n(n + 1)/2.
    n = model.substeps
    h = float(params.dt) / n
    np.testing.assert_allclose(moved.pos[0], [n * h, 0.0, -G * h * h * n * (n + 1) / 2], rtol=1e-12)


def test_collision_filter_removes_pairs():
    scene = rb.Scene(dim=3)
    scene.add_plane(collision_category=0b10)
    scene.add_body(rb.Sphere(0.1), collision_mask=0b01)  # ignores the plane
    scene.add_body(rb.Sphere(0.1), pos=(1.0, 0.0, 0.0))
    model, _, _ = scene.build(dt=1 / 60)
    pairs = {(g.kind, a, b) for g in model.pair_groups for a, b in zip(g.body_a, g.body_b)}
    assert pairs == {("sphere_plane", 1, 0), ("sphere_sphere", 0, 1)}


@pytest.mark.parametrize("contact", MODELS)
def test_broadphase_overflow_is_reported(contact):
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, 0.0))
    for x in range(4):
        scene.add_body(rb.Sphere(0.1), pos=(0.15 * x, 0.0, 0.0))
    model, params, state = scene.build(dt=1 / 60, broadphase="spheres", broadphase_capacity=2, contact=contact)
    assert model.pair_groups[0].capacity == 2
    assert bool(rb.detect_contacts(model, params, state).overflow)
    step = rb.make_step(model)
    crowded = step(state, params)
    assert bool(crowded.overflow)
    # The flag reports the last step, it is not sticky: spread out, it clears.
    assert not bool(step(crowded.replace(pos=crowded.pos * 10.0), params).overflow)
    roomy, params, state = scene.build(dt=1 / 60, broadphase="spheres", broadphase_capacity=6)
    assert not bool(rb.detect_contacts(roomy, params, state).overflow)


def test_broadphase_compaction_keeps_the_first_flagged_pairs_in_order():
    """_first_true against numpy's nonzero: sizes around its block sizes, too few and too many flags."""
    from jaxrb.physics.collision.pairs import _first_true

    rng = np.random.default_rng(0)
    for count, capacity, density in ((1, 1, 1.0), (2, 5, 0.5), (7, 3, 0.9), (100, 10, 0.05), (1485, 150, 0.09)):
        flags = rng.random(count) < density
        indices, in_use = jax.jit(_first_true, static_argnums=1)(jnp.asarray(flags), capacity)
        expected = np.flatnonzero(flags)[:capacity]
        assert int(np.sum(in_use)) == len(expected) and bool(np.all(in_use[:len(expected)]))
        np.testing.assert_array_equal(indices[:len(expected)], expected)
        np.testing.assert_array_equal(indices[len(expected):], 0)


@pytest.mark.parametrize("contact", MODELS)
def test_broadphase_with_room_to_spare_counts_each_pair_once(contact):
    """Spare broadphase slots hold no contact: the pair table's rows, each once.

    The two stacked boxes are pair 0; two more stand far apart. Of the six
    pairs the broadphase keeps one and leaves two of its three slots spare,
    which once read as pair 0 again (tripling its penalty force). The
    contacts and the step must match all pairs'.
    """
    scene = rb.Scene(dim=2)
    scene.add_plane()
    scene.add_body(rb.Box((0.1, 0.1)), mass=1.0, pos=(0.0, 0.1))
    scene.add_body(rb.Box((0.1, 0.1)), mass=1.0, pos=(0.0, 0.295))
    scene.add_body(rb.Box((0.1, 0.1)), mass=1.0, pos=(5.0, 0.1))
    scene.add_body(rb.Box((0.1, 0.1)), mass=1.0, pos=(-5.0, 0.1))
    built = {broadphase: scene.build(dt=1e-3, substeps=1, contact=contact, broadphase=broadphase,
                                     broadphase_capacity=3)
             for broadphase in ("all_pairs", "spheres")}
    found = {name: jax.jit(functools.partial(rb.detect_contacts, model))(params, state)
             for name, (model, params, state) in built.items()}
    spheres, every = found["spheres"], found["all_pairs"]
    assert not bool(spheres.overflow)
    rows = lambda found: sorted(zip(*(np.asarray(x)[np.asarray(found.active)].tolist()
                                      for x in (found.body_a, found.body_b, found.dist))))
    assert rows(spheres) == rows(every) and any(b < 4 for _, b, _ in rows(every))  # a box-box row
    stepped = {name: jax.jit(rb.make_step(model))(state, params) for name, (model, params, state) in built.items()}
    np.testing.assert_allclose(stepped["spheres"].vel, stepped["all_pairs"].vel, rtol=1e-12, atol=1e-12)


# --- transformations ----------------------------------------------------------------------

@pytest.mark.parametrize("contact", MODELS)
def test_vmap_over_worlds_matches_single_worlds(contact):
    model, params, state = bounce_scene(contact, **MODELS[contact])
    heights = jnp.array([0.3, 0.6, 1.0])
    states = jax.vmap(lambda z: state.replace(pos=state.pos.at[0, 2].set(z)))(heights)
    step = rb.make_step(model)
    num_steps = 200 if contact == "impulse" else 600
    run = jax.jit(lambda s: rb.rollout(step, s, params, num_steps, every=num_steps))
    batched = jax.jit(jax.vmap(run))(states)
    for index, height in enumerate(heights):
        single = run(state.replace(pos=state.pos.at[0, 2].set(height)))
        np.testing.assert_allclose(batched.pos[index], single.pos, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("shape, time_of_impact", [(rb.Box((0.1, 0.1, 0.1)), False), (rb.Sphere(0.1), True)],
                         ids=["box", "sphere_time_of_impact"])
def test_vmapped_impulse_rows_write_their_bodies_without_scatters(shape, time_of_impact):
    """Each solver row (and time-of-impact row) updates its two bodies in place in every world, not by a scatter.

    A branch on a batched predicate made JAX batch the row index and body
    numbers too, and the compiled step held a dozen scatters (and some 80
    gathers); the row sweep's custom batching rule keeps them slices. The
    time-of-impact pass added its impulses with scatter-adds until it swept
    its rows the same way.
    """
    scene = rb.Scene(dim=3)
    scene.add_plane(restitution=0.5)
    scene.add_body(shape, mass=1.0, pos=(0.0, 0.0, 0.5), restitution=0.5)
    model, params, state = scene.build(contact=rb.Impulse(time_of_impact=time_of_impact), dt=1 / 60, substeps=2)
    states = jax.tree_util.tree_map(lambda a: jnp.stack([a, a]), state)
    text = jax.jit(jax.vmap(rb.make_step(model), in_axes=(0, None))).lower(states, params).compile().as_text()
    assert " dynamic-update-slice(" in text or "dynamic-update-slice_fusion" in text
    assert " scatter(" not in text


@pytest.mark.parametrize("solver", ["sequential", "jacobi"])
def test_impulse_gradient_compiles_without_gathers_or_scatters(solver):
    """Each solver reads its rows' bodies with the pair table's static slices, in both directions.

    The Jacobi passes read each row's masses, inertias and velocities by body
    index and counted contacts with a segment sum: the compiled gradient of a
    box's bounce held 48 gathers and 32 scatters, and took 18x its forward
    where the sequential solver's took 8x (docs/design.md, 'Loops compiled whole').
    """
    scene = rb.Scene(dim=3)
    scene.add_plane(restitution=0.5)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.09), angvel=(1.0, 2.0, 0.5))
    model, params, state = scene.build(contact=rb.Impulse(solver=solver), dt=1 / 60, substeps=1)
    step = rb.make_step(model)
    height = lambda params: step(state, params).pos[0, 2]
    text = jax.jit(jax.grad(height)).lower(params).compile().as_text()
    assert " gather(" not in text and " scatter(" not in text


def test_vmapped_rows_active_in_no_world_are_skipped():
    """Under vmap a solver row still branches on whether any world has it active.

    The vmapped step keeps the one-world step's branches (one per row sweep),
    and worlds whose rows differ (a box resting on the plane, one falling far
    above it) still each match their own single run.
    """
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.5, restitution=0.3)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.1), vel=(0.5, 0.0, 0.0),
                   friction=0.5, restitution=0.3)
    model, params, state = scene.build(contact="impulse", dt=1 / 60, substeps=2)
    step = rb.make_step(model)
    states = jax.tree_util.tree_map(lambda a: jnp.stack([a, a]), state)
    states = states.replace(pos=states.pos.at[1, 0, 2].set(2.0))
    count = lambda compiled: compiled.as_text().count(" conditional(")
    one_world = jax.jit(step).lower(state, params).compile()
    vmapped = jax.jit(jax.vmap(step, in_axes=(0, None))).lower(states, params).compile()
    assert count(vmapped) == count(one_world) > 0

    for _ in range(10):
        singles = [one_world(jax.tree_util.tree_map(lambda a: a[i], states), params) for i in range(2)]
        states = vmapped(states, params)
        for i, single in enumerate(singles):
            np.testing.assert_allclose(states.pos[i], single.pos, atol=1e-6)
            np.testing.assert_allclose(states.vel[i], single.vel, atol=1e-5)
        states = jax.tree_util.tree_map(lambda *worlds: jnp.stack(worlds), *singles)
    assert float(states.pos[0, 0, 0]) > 0.0 and float(states.pos[1, 0, 2]) > 1.5


@pytest.mark.parametrize("contact", MODELS)
def test_gradients_through_contact_are_finite(contact):
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.5, restitution=0.5)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.1), vel=(1.0, 0.0, 0.0),
                   friction=0.5, restitution=0.5)
    model, params, state = scene.build(contact=contact, **MODELS[contact])
    step = rb.make_step(model)
    num_steps = 12 if contact == "impulse" else 200

    def final_x(friction, restitution, vel):
        p = params.replace(friction=friction, restitution=restitution, plane_friction=friction,
                           plane_restitution=restitution)
        return rb.rollout(step, state.replace(vel=vel), p, num_steps, every=num_steps).pos[-1, 0, 0]

    grads = jax.jit(jax.grad(final_x, argnums=(0, 1, 2)))(params.friction, params.restitution, state.vel)
    for grad in grads:
        assert np.all(np.isfinite(np.asarray(grad)))
    # Sliding friction slows the box: more friction, less distance; a faster start goes farther.
    assert float(grads[0][0]) < 0.0
    assert float(grads[2][0, 0]) > 0.0


def test_jacobi_solver_slides_to_a_stop_without_rocking():
    """Parallel (mass-splitting) solver: same stopping distance, and the box comes to rest.

    Applying the summed impulses with the split mass instead of the true one
    overshot k-fold and left the box rocking on an edge at ~0.2 rad/s.
    """
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.5)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.1), vel=(2.0, 0.0, 0.0), friction=0.5)
    model, params, state = scene.build(contact=rb.Impulse(solver="jacobi"), **MODELS["impulse"])
    traj = simulate(model, params, state, 2.0)
    distance = float(traj.pos[-1, 0, 0] - state.pos[0, 0])
    np.testing.assert_allclose(distance, 2.0 ** 2 / (2 * 0.5 * G), rtol=0.02)
    assert float(jnp.max(jnp.abs(traj.angvel[-30:]))) < 1e-4
    assert float(jnp.max(jnp.abs(traj.vel[-30:]))) < 1e-4


@pytest.mark.parametrize("solver", ["sequential", "jacobi"])
def test_sliding_box_stores_world_frame_impulses(solver):
    """State.contact_impulse holds each row's normal impulse and its world friction vector.

    Within a step the solvers carry friction along each row's tangents; the
    step converts it back for the next step's warm start. While the box
    slides along +x, the rows' impulses of a substep (the solver's unit) sum
    to m·g·h up and μ·m·g·h against the motion, closed form with h = dt/substeps.
    """
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.5)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.1), vel=(2.0, 0.0, 0.0), friction=0.5)
    model, params, state = scene.build(contact=rb.Impulse(solver=solver), **MODELS["impulse"])
    traj = simulate(model, params, state, 0.25)  # it stops at 2/(0.5 g) = 0.41 s
    h = float(params.dt) / model.substeps
    sliding = np.asarray(traj.contact_impulse[5:])  # settled onto its four corners
    normal = np.sum(sliding[..., 0], axis=-1)
    friction = np.sum(sliding[..., 1:], axis=-2)
    np.testing.assert_allclose(normal, G * h, rtol=0.02)
    np.testing.assert_allclose(friction[:, 0], -0.5 * G * h, rtol=0.02)
    np.testing.assert_allclose(friction[:, 1:], 0.0, atol=1e-3 * G * h)


def test_jacobi_row_couplings_match_the_split_sub_bodies():
    """The Jacobi rows' couplings are what an impulse does on Tonge's split sub-bodies.

    A Jacobi contact updates its normal, then its friction, on private copies
    of its two bodies with k-fold inverse masses and inertias (k: contacts on
    the body). The solver reads the normal update's effect on each tangent
    speed, and the first tangent's on the second, from couplings computed once
    a step (``RowMaps.normal_coupling``, ``RowMaps.coupling``). Here each is
    checked against the impulse applied to the sub-bodies with the arms and
    the 3x3 world inverse inertias, for a box resting on a plane and a
    tilted box resting on it (rows with a static side and rows with two bodies).
    """
    from jaxrb.physics.contact import common, rows

    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.5)
    scene.add_body(rb.Box((0.2, 0.2, 0.1)), mass=2.0, pos=(0.0, 0.0, 0.1), friction=0.5)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.03, 0.02, 0.299), quat=(0.99, 0.05, 0.08, 0.1),
                   friction=0.5)
    model, params, state = scene.build(dt=1 / 60, contact=rb.Impulse(solver="jacobi"), dtype=jnp.float64)
    contacts = rb.detect_contacts(model, params, state)
    prep = rows.prepare(model, params, state, contacts)
    active = np.asarray(contacts.active)
    body_a, body_b = np.asarray(contacts.body_a), np.asarray(contacts.body_b)
    assert np.any(active & (body_b == 2)) and np.any(active & (body_b == 1))  # both kinds of row

    split = np.asarray(rows._contact_counts(model, contacts))
    inv_mass = np.append(1.0 / np.asarray(params.mass), 0.0)
    inv_inertia = np.concatenate([np.asarray(common.world_inverse_inertia(model, params, state, padded=False)),
                                  np.zeros((1, 3, 3))])
    pos = np.concatenate([np.asarray(state.pos), np.zeros((1, 3))])
    point, normal = np.asarray(contacts.point), np.asarray(contacts.normal)
    tangents = [np.asarray(t) for t in prep.tangents]

    def speed_change(row, direction):
        """Change of the row's relative velocity (3,) per unit impulse along ``direction`` on the sub-bodies."""
        change = np.zeros(3)
        for body in (body_a[row], body_b[row]):
            k, arm = max(split[body], 1.0), point[row] - pos[body]
            spin = k * inv_inertia[body] @ np.cross(arm, direction)
            change += k * inv_mass[body] * direction + np.cross(spin, arm)
        return change

    maps = prep.maps
    for row in np.flatnonzero(active):
        from_normal = speed_change(row, normal[row])
        for tangent, coupling in zip(tangents, maps.normal_coupling):
            np.testing.assert_allclose(float(coupling[row]), from_normal @ tangent[row], atol=1e-12)
        np.testing.assert_allclose(float(maps.coupling[row]), speed_change(row, tangents[0][row]) @ tangents[1][row],
                                   atol=1e-12)


# ------------------------------------------------------------------ penalty restitution

def _clamped_oscillator_restitution(zeta, steps=200_000):
    """Brute force: integrate p'' = −max(p + 2ζp', 0) (ω₀ = 1) from p = 0, p' = 1 until p < 0."""
    h, p, v = 20.0 / steps, 0.0, 1.0
    for _ in range(steps):
        v -= max(p + 2.0 * zeta * v, 0.0) * h
        p += v * h
        if p < 0.0:
            break
    return -v


@pytest.mark.parametrize("zeta", [0.05, 0.3, 0.7, 1.0, 1.5, 3.0])
def test_clamped_spring_damper_restitution_closed_form(zeta):
    """The closed form (both branches and ζ = 1) against a fine integration (h = 1e-4/ω₀: error ~1e-4)."""
    from jaxrb.physics.contact.penalty import restitution_of_damping_ratio
    assert float(restitution_of_damping_ratio(zeta)) == pytest.approx(_clamped_oscillator_restitution(zeta),
                                                                      abs=3e-4)


@pytest.mark.parametrize("restitution", [0.2, 0.6, 0.9])
def test_penalty_ball_bounces_with_the_asked_restitution(restitution):
    """Default stiffness and damper: a ball's rebound over its approach speed, at 16 phases of a substep.

    No gravity, so the contact law alone sets the rebound (under gravity a
    17 ms contact at h = 1 ms would take 7 % off it). The balls start
    0–1 mm apart so that the impact falls at every phase of a substep; the
    mean must be within 1 % of e, each within the ±0.035 that the impact's
    phase leaves (the 1-D map at this ω₀h = 0.19: e = 0.2 spans 0.17–0.23,
    e = 0.6 0.58–0.62, e = 0.9 0.894–0.907).
    """
    h, approach = 1e-3, 2.0
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, 0.0))
    scene.add_plane(restitution=0.0, friction=0.0)
    scene.add_body(rb.Sphere(radius=0.1), mass=2.0, pos=(0.0, 0.0, 0.11), vel=(0.0, 0.0, -approach),
                   restitution=restitution, friction=0.0)
    model, params, state = scene.build(dt=h, contact="penalty", dtype=jnp.float64)
    step = rb.make_step(model)
    heights = 0.11 + jnp.linspace(0.0, approach * h, 16, endpoint=False)
    states = jax.vmap(lambda z: state.replace(pos=state.pos.at[0, 2].set(z)))(heights)
    final = jax.jit(jax.vmap(lambda s: rb.rollout(step, s, params, 100).vel[-1, 0, 2]))(states)
    ratios = np.asarray(final) / approach  # out of contact after 100 steps: its speed is constant
    assert np.mean(ratios) == pytest.approx(restitution, rel=0.01)
    assert np.all(np.abs(ratios - restitution) < 0.035)
