"""Joints: closed forms, MuJoCo's own integrators side by side, stability, limits, motors, coordinates, errors.

The physics is held to closed forms (a physical pendulum's large-amplitude
period), to conserved quantities (a double pendulum's energy), to MuJoCo
itself (the same model stepped by MuJoCo's Euler and RK4), and to the
constraints' own definitions (a four-bar's loop stays closed, a limit holds
an overload). Float64 throughout (conftest enables x64).
"""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import ellipk

import jaxrb as rb
from jaxrb.physics.joints import dynamics
from jaxrb.physics.joints.kinematics import kinematics

G = 9.81


def _along(axis_from_z):
    """Quaternion turning the body z axis (a capsule's axis) onto ``axis_from_z`` in the x-z plane."""
    x, _, z = axis_from_z
    return rb.quaternion.from_axis_angle(jnp.asarray([0.0, 1.0, 0.0]), math.atan2(x, z))


def link(scene, start, end, mass=1.0, radius=0.02):
    """A capsule from ``start`` to ``end`` (x-z plane), its frame at its centre."""
    start, end = np.asarray(start, float), np.asarray(end, float)
    length = float(np.linalg.norm(end - start))
    return scene.add_body(rb.Capsule(radius=radius, half_length=length / 2), mass=mass, pos=(start + end) / 2,
                          quat=_along(end - start))


def double_pendulum(length=0.5):
    """Two 1 kg capsules hanging along −z from the origin, hinges about y (MuJoCo's DOUBLE_PENDULUM below)."""
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, -G))
    upper = link(scene, (0, 0, 0), (0, 0, -length))
    lower = link(scene, (0, 0, -length), (0, 0, -2 * length))
    scene.add_joint(rb.Hinge(axis=(0, 1, 0), anchor=(0, 0, 0)), upper)
    scene.add_joint(rb.Hinge(axis=(0, 1, 0), anchor=(0, 0, -length)), lower, upper)
    return scene


DOUBLE_PENDULUM_XML = """
<mujoco><option gravity="0 0 -9.81"/><worldbody>
  <body><joint type="hinge" axis="0 1 0"/><geom type="capsule" fromto="0 0 0 0 0 -0.5" size="0.02" mass="1"/>
    <body pos="0 0 -0.5"><joint type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.5" size="0.02" mass="1"/></body></body>
</worldbody></mujoco>"""


def energy(model, params, qpos, qvel):
    """Kinetic plus potential energy (J) from the joint coordinates."""
    kin = kinematics(model.joints, params, qpos)
    matrix = dynamics.mass_matrix(params, kin, dynamics.world_inertia(kin, params))
    return 0.5 * qvel @ matrix @ qvel - jnp.sum(params.mass * (kin.com @ params.gravity))


def test_physical_pendulum_keeps_the_large_amplitude_period():
    """A capsule hinged at one end, released at 170°: T = 4√(I/(m g d))·K(sin²(θ₀/2)) within 0.1 %."""
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, -G))
    rod = link(scene, (0, 0, 0), (0, 0, -1.0), radius=0.05)
    scene.add_joint(rb.Hinge(axis=(0, 1, 0), anchor=(0, 0, 0)), rod)
    h = 1.0 / 240.0
    model, params, state = scene.build(dt=h)
    theta0 = math.radians(170.0)
    state = rb.joints.set_qpos_qvel(model, params, state, jnp.asarray([theta0]), jnp.zeros(1))
    traj = rb.rollout(rb.make_step(model), state, params, 2400)
    rate = np.asarray(traj.qvel[:, 0])
    turning = np.flatnonzero((rate[:-1] > 0) & (rate[1:] <= 0))  # the swing's highest points
    times = (turning + 1 + rate[turning] / (rate[turning] - rate[turning + 1])) * h
    inertia = float(params.inertia[0, 1, 1]) + 1.0 * 0.5 ** 2
    period = 4 * math.sqrt(inertia / (1.0 * G * 0.5)) * ellipk(math.sin(theta0 / 2) ** 2)
    assert len(times) >= 2
    assert abs(np.diff(times).mean() - period) < 1e-3 * period


@pytest.mark.parametrize("integrator", ["semi_implicit", "rk4"])
def test_double_pendulum_steps_as_mujoco_does(integrator):
    """jaxrb's semi_implicit is MuJoCo's Euler and its rk4 MuJoCo's RK4: the same model, 0.2 s, to 1e-9 rad."""
    mujoco = pytest.importorskip("mujoco")
    h, steps = 1e-3, 200
    model, params, state = double_pendulum().build(dt=h, integrator=integrator)
    state = rb.joints.set_qpos_qvel(model, params, state, jnp.asarray([2.0, -1.0]), jnp.asarray([0.5, 0.0]))
    ours = rb.rollout(rb.make_step(model), state, params, steps).qpos[-1]
    mj_model = mujoco.MjModel.from_xml_string(DOUBLE_PENDULUM_XML)
    mj_model.opt.timestep, mj_model.opt.integrator = h, (0 if integrator == "semi_implicit" else 1)
    data = mujoco.MjData(mj_model)
    data.qpos[:], data.qvel[:] = (2.0, -1.0), (0.5, 0.0)
    for _ in range(steps):
        mujoco.mj_step(mj_model, data)
    np.testing.assert_allclose(np.asarray(ours), data.qpos, atol=1e-9)


def test_double_pendulum_default_integrator_keeps_its_energy_and_beats_mujoco_euler():
    """No drift beyond 0.5 % of the energy above rest over 10 s at h = 1/240 (last second against the first),
    where MuJoCo's Euler (``semi_implicit``) drifts by more than 10 %."""
    drifts = {}
    for integrator in ("midpoint", "semi_implicit"):
        model, params, state = double_pendulum().build(dt=1.0 / 240.0, integrator=integrator)
        state = rb.joints.set_qpos_qvel(model, params, state, jnp.asarray([2.0, -1.0]), jnp.zeros(2))
        traj = rb.rollout(rb.make_step(model), state, params, 2400)
        energies = np.asarray(jax.vmap(lambda q, v: energy(model, params, q, v))(traj.qpos, traj.qvel))
        above_rest = float(energy(model, params, state.qpos, state.qvel) - energy(model, params, jnp.zeros(2),
                                                                                   jnp.zeros(2)))
        drifts[integrator] = (energies[-240:].mean() - energies[:240].mean()) / above_rest
    assert abs(drifts["midpoint"]) < 5e-3, drifts
    assert abs(drifts["semi_implicit"]) > 0.1, drifts


def test_four_bar_linkage_keeps_its_loop_closed():
    """Crank, coupler, rocker and a Connect back to the ground: the loop's end stays within 1 mm over 10 s at
    dt = 1/60, the crank turning full circles."""
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, -G))
    a, b, c, d = (0, 0, 0), (0, 0, 0.3), (0.5, 0, 0.45), (0.6, 0, 0.0)
    crank, coupler, rocker = link(scene, a, b), link(scene, b, c), link(scene, c, d)
    scene.add_joint(rb.Hinge(axis=(0, 1, 0), anchor=a), crank)
    scene.add_joint(rb.Hinge(axis=(0, 1, 0), anchor=b), coupler, crank)
    scene.add_joint(rb.Hinge(axis=(0, 1, 0), anchor=c), rocker, coupler)
    scene.add_equality(rb.Connect(anchor=d), rocker)
    model, params, state = scene.build(dt=1.0 / 60.0, contact="none")
    state = rb.joints.set_qpos_qvel(model, params, state, state.qpos, jnp.asarray([3.0, 0.0, 0.0]))
    traj = rb.rollout(rb.make_step(model), state, params, 600)
    rotation = jax.vmap(rb.quaternion.to_rotation_matrix)(traj.quat[:, rocker])
    half = float(np.linalg.norm(np.subtract(d, c))) / 2
    end = np.asarray(traj.pos[:, rocker] + rotation[:, :, 2] * half)
    assert np.linalg.norm(end - np.asarray(d), axis=-1).max() < 1e-3
    assert float(traj.qpos[-1, 0]) > 4 * math.pi  # two full turns: the loop was driven, not stuck


@pytest.mark.parametrize("end_mass", [1.0, 100.0])
def test_twenty_link_chain_at_a_sixtieth_gains_no_energy(end_mass):
    """20 hinged 0.1 m links released horizontal, dt = 1/60, 20 s with ``implicit``: finite, never above its
    starting energy by more than 1 % of the energy it has to lose, with and without a 100:1 weight at its end."""
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, -G))
    previous = None
    for i in range(20):
        body = link(scene, (0.1 * i, 0, 0), (0.1 * (i + 1), 0, 0), mass=end_mass if i == 19 else 1.0, radius=0.01)
        scene.add_joint(rb.Hinge(axis=(0, 1, 0), anchor=(0.1 * i, 0, 0)), body, previous)
        previous = body
    model, params, state = scene.build(dt=1.0 / 60.0, integrator="implicit", contact="none")
    traj = rb.rollout(rb.make_step(model), state, params, 1200)
    energies = np.asarray(jax.vmap(lambda q, v: energy(model, params, q, v))(traj.qpos, traj.qvel))
    start = float(energy(model, params, state.qpos, state.qvel))
    hanging = jnp.zeros(20).at[0].set(math.pi / 2)
    to_lose = start - float(energy(model, params, hanging, jnp.zeros(20)))
    assert np.all(np.isfinite(energies))
    assert energies.max() - start < 0.01 * to_lose


def limited_rod(dt, integrator="midpoint"):
    """A 1 m, 1 kg rod hinged at its top, limited to ±30°, with a motor."""
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, -G))
    rod = link(scene, (0, 0, 0), (0, 0, -1.0))
    joint = scene.add_joint(rb.Hinge(axis=(0, 1, 0), anchor=(0, 0, 0)), rod, range=np.radians([-30.0, 30.0]))
    scene.add_actuator(joint, "motor")
    return scene.build(dt=dt, integrator=integrator)


@pytest.mark.parametrize("dt", [1.0 / 60.0, 1.0 / 240.0])
def test_limit_holds_a_tenfold_overload(dt):
    """A motor torque 10× the rod's largest gravity torque drives it into its limit: passed by < 1° ever."""
    model, params, state = limited_rod(dt)
    steps = int(round(2.0 / dt))
    torque = jnp.full((steps, 1), 10.0 * G * 0.5)
    traj = rb.rollout(rb.make_step(model), state, params, steps, controls=torque)
    past = np.degrees(np.asarray(traj.qpos[:, 0])) - 30.0
    assert past.max() < 1.0 and past[-1] > -1.0  # at the limit, not short of it


def test_velocity_motor_reaches_its_speed_within_its_force_range():
    """kv (u − q̇) clamped to ±0.5 N m against 0.05 N m s of damping: the wheel settles where kv(u − ω) = bω.

    ``midpoint`` takes the gain implicitly (h·kv/I = 10 here: explicit, as rk4 and MuJoCo's Euler take it, the
    wheel would ring against the clamp)."""
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, -G))
    wheel = scene.add_body(rb.Sphere(0.1), mass=2.0)
    joint = scene.add_joint(rb.Hinge(axis=(0, 0, 1)), wheel, damping=0.05)
    scene.add_actuator(joint, "velocity", kv=5.0, forcerange=(-0.5, 0.5))
    model, params, state = scene.build(dt=1.0 / 60.0, integrator="midpoint")
    traj = rb.rollout(rb.make_step(model), state, params, 600, controls=jnp.full((600, 1), 10.0))
    speed = np.asarray(traj.qvel[:, 0])
    inertia = float(params.inertia[0, 2, 2])
    assert abs(speed[-1] - 5.0 * 10.0 / 5.05) < 1e-3 * speed[-1]
    assert np.all(np.diff(speed[:30]) * 60.0 * inertia <= 0.5 + 1e-9)  # never more than the force range


def test_free_bodies_read_and_write_mujocos_coordinates():
    """A scene without joints: qpos is each body frame's origin and quaternion, qvel the origin's world velocity
    and the body-frame angular velocity; set_qpos_qvel inverts qpos_qvel."""
    scene = rb.Scene(dim=3)
    scene.add_body(rb.Box(half_extents=(0.1, 0.2, 0.3)), mass=1.0, pos=(1.0, 2.0, 3.0),
                   quat=(0.9, 0.1, 0.3, 0.2), vel=(0.5, 0.0, 0.0), angvel=(0.0, 0.0, 2.0),
                   com=(0.05, 0.0, 0.0))
    model, params, state = scene.build(dt=0.01)
    qpos, qvel = rb.joints.qpos_qvel(model, params, state)
    rotation = np.asarray(rb.quaternion.to_rotation_matrix(state.quat[0]))
    np.testing.assert_allclose(qpos[:3], [1.0, 2.0, 3.0], atol=1e-12)
    np.testing.assert_allclose(qvel[3:], rotation.T @ [0.0, 0.0, 2.0], atol=1e-12)
    np.testing.assert_allclose(qvel[:3], [0.5, 0.0, 0.0] - np.cross([0.0, 0.0, 2.0], rotation @ [0.05, 0, 0]),
                               atol=1e-12)
    back = rb.joints.set_qpos_qvel(model, params, state, qpos, qvel)
    for name in ("pos", "quat", "vel", "angvel"):
        np.testing.assert_allclose(getattr(back, name), getattr(state, name), atol=1e-12)


def test_controls_and_dt_trace_through_jit_vmap_and_scan():
    """step(state, params.replace(dt=...), None, controls) under jit and vmap, a scan over per-step dt and
    controls, and set_qpos_qvel vmapped: the same numbers as one world stepped alone."""
    model, params, state = limited_rod(0.01)
    step = rb.make_step(model)
    dts, torques = jnp.asarray([0.01, 0.02, 0.005]), jnp.asarray([[1.0], [-2.0], [0.5]])

    def scanned(state, params):
        def one(state, inputs):
            dt, torque = inputs
            return step(state, params.replace(dt=dt), None, torque), None
        return jax.lax.scan(one, state, (dts, torques))[0]

    alone = scanned(state, params)
    starts = jax.vmap(lambda q: rb.joints.set_qpos_qvel(model, params, state, q, jnp.zeros(1)))(
        jnp.asarray([[0.0], [0.1]]))
    batched = jax.jit(jax.vmap(scanned, in_axes=(0, None)))(starts, params)
    np.testing.assert_allclose(batched.qpos[0], alone.qpos, atol=1e-12)
    np.testing.assert_allclose(float(alone.time), 0.035, atol=1e-12)
    assert float(batched.qpos[1, 0]) != float(batched.qpos[0, 0])


def _pendulum_scene():
    scene = rb.Scene(dim=3)
    upper = link(scene, (0, 0, 0), (0, 0, -0.5))
    lower = link(scene, (0, 0, -0.5), (0, 0, -1.0))
    return scene, upper, lower


@pytest.mark.parametrize("call, message", [
    (lambda s, a, b: s.add_joint(rb.Hinge(axis=(0, 0, 0)), a), r"joint 0 \('joint0'\): field 'axis' must be non-zero"),
    (lambda s, a, b: s.add_joint(rb.Hinge(), a, a), r"field 'parent' is the child body 0 itself"),
    (lambda s, a, b: s.add_joint(rb.Hinge(), a, range=(1.0, -1.0)), r"field 'range' must have lower <= upper"),
    (lambda s, a, b: s.add_joint(rb.Free(), b, a), r"field 'parent' must be None \(the world\) for a free joint"),
    (lambda s, a, b: s.add_joint(rb.Ball(), a, range=(0, 1)), r"field 'range' limits hinges and slides only"),
    (lambda s, a, b: s.add_joint("hinge", a), r"field 'kind' must be one of rb.Hinge"),
    (lambda s, a, b: s.add_joint(rb.Hinge(), 5), r"field 'child' must be a body index 0..1"),
    (lambda s, a, b: s.add_equality(rb.Connect(), a, a), r"equality 0 \('equality0'\): field 'body_b' is body_a"),
    (lambda s, a, b: s.add_actuator(0, "servo"), r"unknown actuator kind 'servo'"),
    (lambda s, a, b: (s.add_joint(rb.Hinge(), a), s.add_actuator(0, "motor", kp=3.0)),
     r"actuator 0 \('actuator0'\): field 'kp' does not apply to a 'motor' actuator"),
    (lambda s, a, b: s.add_actuator(0), r"actuator 0 \('actuator0'\): field 'joint' must be a joint index"),
])
def test_joint_mistakes_name_the_joint_and_field(call, message):
    scene, upper, lower = _pendulum_scene()
    with pytest.raises(ValueError, match=message):
        call(scene, upper, lower)


def test_mistakes_found_at_build_name_the_bodies():
    """A loop of joints, two parents, joint velocities given on a jointed body, an actuator on a ball joint."""
    scene, upper, lower = _pendulum_scene()
    scene.add_joint(rb.Hinge(), upper, lower)
    scene.add_joint(rb.Hinge(), lower, upper)
    with pytest.raises(ValueError, match=r"its joints form a loop .* scene.add_equality\(rb.Connect"):
        scene.build(dt=0.01)
    scene, upper, lower = _pendulum_scene()
    scene.add_joint(rb.Hinge(), lower, upper)
    scene.add_joint(rb.Slider(), lower, None)
    with pytest.raises(ValueError, match=r"joint 1 \('joint1'\): field 'parent' is -1, but body 1"):
        scene.build(dt=0.01)
    scene, upper, lower = _pendulum_scene()
    ball = scene.add_joint(rb.Ball(), upper)
    scene.add_actuator(ball)
    with pytest.raises(ValueError, match=r"actuator 0 \('actuator0'\): field 'joint' names a ball joint"):
        scene.build(dt=0.01)
    scene = rb.Scene(dim=3)
    body = scene.add_body(rb.Sphere(0.1), mass=1.0, vel=(1.0, 0.0, 0.0))
    scene.add_joint(rb.Slider(), body)
    with pytest.raises(ValueError, match=r"body 0 \('body0'\): fields 'vel' and 'angvel' must be zero"):
        scene.build(dt=0.01)


def test_controls_of_the_wrong_shape_are_refused():
    model, params, state = limited_rod(0.01)
    with pytest.raises(ValueError, match=r"'controls' must have shape \(1,\)"):
        rb.make_step(model)(state, params, None, jnp.zeros(2))
    scene = rb.Scene(dim=3)
    scene.add_body(rb.Sphere(0.1), mass=1.0)
    free_model, free_params, free_state = scene.build(dt=0.01)
    with pytest.raises(ValueError, match=r"no actuators, so 'controls' must be None"):
        rb.make_step(free_model)(free_state, free_params, None, jnp.zeros(1))


def test_summary_lists_the_joint_kinds_compiled_in():
    model, _, _ = limited_rod(0.01)
    assert "joints (1 hinge; nq=1, nv=1; limits on 1; 1 actuator)" in model.summary()
    scene = rb.Scene(dim=3)
    scene.add_body(rb.Sphere(0.1), mass=1.0)
    assert "joints" not in scene.build(dt=0.01)[0].summary()  # no joint code in a free-body scene


# --- gradients ---------------------------------------------------------------------------------------------------

def _mechanism(joint_friction="smooth", integrator="midpoint"):
    """A slider carrying a hinged, limited, sprung, damped and servoed arm, with a second hinge below it."""
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, -G))
    cart = scene.add_body(rb.Box(half_extents=(0.1, 0.1, 0.05)), mass=2.0)
    arm = link(scene, (0, 0, 0), (0.3, 0, -0.3))
    tip = link(scene, (0.3, 0, -0.3), (0.3, 0, -0.6), mass=0.5)
    slide = scene.add_joint(rb.Slider(axis=(1, 0, 0)), cart, damping=0.5, frictionloss=0.2)
    hinge = scene.add_joint(rb.Hinge(axis=(0, 1, 0), anchor=(0, 0, 0)), arm, cart, range=(-0.6, 0.6),
                            stiffness=3.0, springref=0.2, damping=0.05, armature=0.01, frictionloss=0.05)
    scene.add_joint(rb.Hinge(axis=(0, 1, 0), anchor=(0.3, 0, -0.3)), tip, arm, damping=0.02)
    scene.add_actuator(slide, "motor", gear=2.0)
    scene.add_actuator(hinge, "position", kp=5.0, kv=0.3, forcerange=(-2.0, 2.0))
    model, params, state = scene.build(dt=0.01, integrator=integrator, joint_friction=joint_friction,
                                       contact="none")
    state = rb.joints.set_qpos_qvel(model, params, state, jnp.asarray([0.0, 0.5, -0.4]),
                                    jnp.asarray([0.3, 1.0, -2.0]))
    return model, params, state


JOINT_FIELDS = ("mass", "inertia", "com_offset", "parent_offset", "parent_rotation", "joint_pos", "joint_axis",
                "joint_ref", "joint_range", "joint_stiffness", "joint_springref", "joint_damping", "joint_armature",
                "joint_frictionloss", "joint_friction_velocity", "limit_hertz", "limit_damping_ratio",
                "actuator_gear", "actuator_gain", "actuator_bias", "force_range", "gravity")


@pytest.fixture(scope="module")
def mechanism_gradient():
    """Value and gradient of a 0.2 s rollout's loss of the mechanism, jitted once."""
    model, params, state = _mechanism()
    controls = jnp.stack([jnp.full(20, 1.5), jnp.linspace(-0.5, 0.8, 20)], axis=-1)

    def loss(params):
        traj = rb.rollout(rb.make_step(model), state, params, 20, controls=controls)
        return jnp.sum(traj.qpos[-1] ** 2) + 0.1 * jnp.sum(traj.qvel[-1] ** 2) + jnp.sum(traj.pos[-1] ** 2)

    return params, jax.jit(loss), jax.jit(jax.grad(loss))


@pytest.mark.parametrize("field", JOINT_FIELDS)
def test_joint_params_gradients_match_central_differences(mechanism_gradient, field):
    """d loss / d field along a random direction: autodiff against central differences, relative 1e-4."""
    params, loss, grad = mechanism_gradient
    value = getattr(params, field)
    direction = jnp.asarray(np.random.default_rng(sorted(JOINT_FIELDS).index(field)).normal(size=np.shape(value)))
    if field == "inertia":
        direction = direction + jnp.swapaxes(direction, -1, -2)
    scale = 1e-6 * max(1.0, float(jnp.max(jnp.abs(value))))
    # dataclasses.replace: a zero stiffness or armature nudged by -1e-6 is outside Params' checked range.
    shifted = lambda sign: loss(dataclasses.replace(params, **{field: value + sign * scale * direction}))
    central = float(shifted(1.0) - shifted(-1.0)) / (2 * scale)
    exact = float(jnp.sum(getattr(grad(params), field) * direction))
    assert np.isfinite(exact)
    assert abs(exact - central) <= 1e-4 * max(abs(central), 1e-3), (exact, central)


def test_gradients_are_finite_at_rest_on_a_limit_and_in_stick_slip():
    """The rod pressed into its limit, starting at rest, with exact Coulomb friction sticking and slipping."""
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, -G))
    rod = link(scene, (0, 0, 0), (0, 0, -1.0))
    joint = scene.add_joint(rb.Hinge(axis=(0, 1, 0), anchor=(0, 0, 0)), rod, range=(-0.1, 0.1), frictionloss=0.8)
    scene.add_actuator(joint, "motor")
    model, params, state = scene.build(dt=0.01)
    state = rb.joints.set_qpos_qvel(model, params, state, jnp.asarray([0.1]), jnp.zeros(1))
    torques = jnp.concatenate([jnp.full((10, 1), 30.0), jnp.full((10, 1), 0.5), jnp.full((10, 1), -3.0)])

    def loss(params):
        return jnp.sum(rb.rollout(rb.make_step(model), state, params, 30, controls=torques).qpos ** 2)

    gradient = jax.grad(loss)(params)
    for field in ("mass", "joint_frictionloss", "joint_range", "limit_hertz", "joint_damping", "joint_armature"):
        assert np.all(np.isfinite(np.asarray(getattr(gradient, field)))), field


# --- contact with joints -----------------------------------------------------------------------------------------

def test_newtons_cradle_passes_the_swing_to_the_last_ball():
    """Five hinged balls touching at rest, e = 1: the first, released at 30°, stops; the last rises to within
    2 % of the first's release height and the middle three stay put."""
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, -G))
    radius, length = 0.05, 0.5
    for i in range(5):
        ball = scene.add_body(rb.Sphere(radius), mass=1.0, pos=(2 * radius * i, 0, -length), restitution=1.0,
                              friction=0.0)
        scene.add_joint(rb.Hinge(axis=(0, 1, 0), anchor=(2 * radius * i, 0, 0)), ball)
    model, params, state = scene.build(dt=1.0 / 240.0)
    state = rb.joints.set_qpos_qvel(model, params, state, state.qpos.at[0].set(math.radians(30.0)), state.qvel)
    release = float(state.pos[0, 2]) + length
    assert float(state.pos[0, 0]) < 0.0  # pulled away from the others
    heights = np.asarray(rb.rollout(rb.make_step(model), state, params, 240).pos[:, :, 2]) + length
    assert abs(heights[:, 4].max() - release) < 0.02 * release
    assert heights[:, 1:4].max() < 0.02 * release


@pytest.mark.parametrize("name", ["hopper", "ant"])
def test_gymnasium_models_dropped_on_their_floor_come_to_rest(name):
    """At the files' own timesteps and contact filtering, lifted 0.2 m and dropped: no NaN, at rest after 3 s,
    sinking less than 5 mm into the floor."""
    gymnasium = pytest.importorskip("gymnasium")
    import os
    path = os.path.join(os.path.dirname(gymnasium.__file__), "envs", "mujoco", "assets", f"{name}.xml")
    model, params, state = rb.load_scene(path).build()
    qpos, qvel = rb.joints.qpos_qvel(model, params, state)
    height = 1 if name == "hopper" else 2  # rootz, or the free joint's z
    state = rb.joints.set_qpos_qvel(model, params, state, qpos.at[height].add(0.2), qvel)
    steps = int(round(3.0 / float(params.dt)))
    traj = rb.rollout(rb.make_step(model), state, params, steps, every=steps // 30)
    assert bool(jnp.all(jnp.isfinite(traj.qpos)))
    last = jax.tree_util.tree_map(lambda a: a[-1], traj)
    assert float(jnp.max(jnp.abs(last.vel))) < 0.05
    contacts = rb.detect_contacts(model, params, last)
    assert float(jnp.max(jnp.where(contacts.active, -contacts.dist, 0.0))) < 5e-3


# --- 2D ----------------------------------------------------------------------------------------------------------

def test_a_2d_double_pendulum_moves_as_the_same_one_in_3d():
    """Hinges of the plane (about z) and the 3D scene's hinges about z: the same coordinates and positions;
    each 2D angle is the sum of the hinge angles above it."""
    def build(dim):
        scene = rb.Scene(dim=dim, gravity=(0.0, -G) if dim == 2 else (0.0, -G, 0.0))
        shape = rb.Box(half_extents=(0.02, 0.25)) if dim == 2 else None
        inertia = 0.02 if dim == 2 else (0.02, 0.02, 0.02)
        at = (lambda x, y: (x, y)) if dim == 2 else (lambda x, y: (x, y, 0.0))
        upper = scene.add_body(shape, mass=1.0, inertia=inertia, pos=at(0.0, -0.25))
        lower = scene.add_body(shape, mass=1.0, inertia=inertia, pos=at(0.0, -0.75))
        hinge = (lambda anchor: rb.Hinge(anchor=anchor)) if dim == 2 else \
            (lambda anchor: rb.Hinge(axis=(0, 0, 1), anchor=anchor))
        scene.add_joint(hinge(at(0.0, 0.0)), upper)
        scene.add_joint(hinge(at(0.0, -0.5)), lower, upper)
        model, params, state = scene.build(dt=1.0 / 240.0, contact="none")
        state = rb.joints.set_qpos_qvel(model, params, state, jnp.asarray([2.0, -1.0]), jnp.zeros(2))
        return rb.rollout(rb.make_step(model), state, params, 240)

    plane, space = build(2), build(3)
    np.testing.assert_allclose(plane.qpos, space.qpos, atol=1e-12)
    np.testing.assert_allclose(plane.pos, space.pos[..., :2], atol=1e-12)
    np.testing.assert_allclose(plane.angle[-1], jnp.cumsum(plane.qpos[-1]), atol=1e-12)


def test_a_2d_box_with_a_hinged_arm_lands_and_reads_its_coordinates():
    """A free box (x, y, angle) carrying a limited arm falls on the ground: it lands on it and the coordinates
    read back as the box's frame and the arm's hinge."""
    scene = rb.Scene(dim=2)
    scene.add_plane()
    box = scene.add_body(rb.Box(half_extents=(0.2, 0.1)), mass=1.0, pos=(0.0, 1.0), angle=0.3, vel=(1.0, 0.0),
                         angvel=2.0)
    arm = scene.add_body(rb.Box(half_extents=(0.2, 0.05)), mass=0.5, pos=(0.4, 1.0), angle=0.3)
    scene.add_joint(rb.Hinge(anchor=(0.2, 1.0)), arm, box, range=(-1.0, 1.0))
    model, params, state = scene.build(dt=1.0 / 60.0)
    np.testing.assert_allclose(state.qpos, [0.0, 1.0, 0.3, 0.0], atol=1e-12)
    np.testing.assert_allclose(state.qvel, [1.0, 0.0, 2.0, 0.0], atol=1e-12)
    traj = rb.rollout(rb.make_step(model), state, params, 180)
    last = jax.tree_util.tree_map(lambda a: a[-1], traj)
    qpos, _ = rb.joints.qpos_qvel(model, params, last)
    assert bool(jnp.all(jnp.isfinite(traj.pos))) and float(traj.pos[:, :, 1].min()) > 0.04
    assert abs(float(jnp.max(jnp.abs(last.vel)))) < 0.05
    np.testing.assert_allclose(qpos[:2], last.pos[0], atol=1e-9)  # the box's frame is its centre
    assert abs(float(qpos[3])) <= 1.0 + math.radians(1.0)


def test_2d_free_bodies_read_and_write_their_coordinates():
    scene = rb.Scene(dim=2)
    scene.add_body(rb.Box(half_extents=(0.1, 0.2)), mass=1.0, pos=(1.0, 2.0), angle=0.5, vel=(0.3, -0.1),
                   angvel=1.5, com=(0.05, 0.0))
    model, params, state = scene.build(dt=0.01)
    qpos, qvel = rb.joints.qpos_qvel(model, params, state)
    np.testing.assert_allclose(qpos, [1.0, 2.0, 0.5], atol=1e-12)
    back = rb.joints.set_qpos_qvel(model, params, state, qpos, qvel)
    for name in ("pos", "angle", "vel", "angvel"):
        np.testing.assert_allclose(getattr(back, name), getattr(state, name), atol=1e-12)


def test_penalty_contact_carries_a_hinged_pair_to_rest():
    """Penalty contact with joints: its wrench enters through Jᵀ; a 2D box with a hinged arm dropped on the
    ground comes to rest on it, finite, sinking less than a millimetre."""
    scene = rb.Scene(dim=2)
    scene.add_plane()
    box = scene.add_body(rb.Box(half_extents=(0.2, 0.1)), mass=1.0, pos=(0.0, 0.5))
    arm = scene.add_body(rb.Box(half_extents=(0.2, 0.05)), mass=0.5, pos=(0.4, 0.5))
    scene.add_joint(rb.Hinge(anchor=(0.2, 0.5)), arm, box)
    model, params, state = scene.build(dt=1e-3, contact=rb.Penalty())
    assert "contact penalty" in model.summary() and "joints (" in model.summary()
    traj = rb.rollout(rb.make_step(model), state, params, 2000, every=100)
    last = jax.tree_util.tree_map(lambda a: a[-1], traj)
    contacts = rb.detect_contacts(model, params, last)
    assert bool(jnp.all(jnp.isfinite(traj.pos))) and float(jnp.max(jnp.abs(last.vel))) < 1e-3
    assert float(jnp.max(jnp.where(contacts.active, -contacts.dist, 0.0))) < 1e-3


def test_joint_wrenches_are_newtons_law_for_the_swinging_rod():
    """A hinged rod swinging: the world pushes it with m (a − g), a its centre of mass's acceleration (by
    autodiff of its position twice): the lower link of a double pendulum takes what its own motion needs, the
    upper one the whole chain's, and the upper hinge adds no torque to its force's about the rod's centre."""
    model, params, state = double_pendulum().build(dt=0.01, integrator="semi_implicit")
    qpos, qvel = jnp.asarray([0.7, -0.4]), jnp.asarray([1.5, -2.0])
    state = rb.joints.set_qpos_qvel(model, params, state, qpos, qvel)
    qacc = (rb.make_step(model)(state, params.replace(dt=1e-7)).qvel - qvel) / 1e-7  # forward dynamics
    force, torque = rb.joints.joint_wrenches(model, params, state, qacc)

    def com(q):
        return kinematics(model.joints, params, q).com

    def com_rate(q):
        return jax.jvp(com, (q,), (qvel,))[1]

    accel = jax.jvp(com_rate, (qpos,), (qvel,))[1] + jax.jvp(com, (qpos,), (qacc,))[1]
    needs = params.mass[:, None] * (accel - params.gravity)
    np.testing.assert_allclose(force[1], needs[1], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(force[0], needs[0] + needs[1], rtol=1e-5, atol=1e-6)
    pivot = jnp.asarray([0.0, 0.0, 0.0])  # the upper hinge, 0.25 m above the upper rod's centre (its origin)
    np.testing.assert_allclose(torque[0] - jnp.cross(pivot - state.pos[0], force[0]), jnp.zeros(3), atol=1e-4)
