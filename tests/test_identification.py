"""Inverse dynamics and the linear-in-parameters identification model (jaxrb.physics.joints.identification).

(a) ``inverse_dynamics`` inverts the step: the accelerations of a
semi-implicit step give back the actuators' torques (to the implicit
damping and friction slope the step takes at its end velocity). (b) the
regressor times the standard parameters is the inverse dynamics, under jit
and vmap. (c) a double pendulum's identifiable combinations are the
classical ones (J1 + m2 L1², J2, m2 a2, m1 a1 + m2 L1, ...). (d) they are
recovered within 2 % from a noisy simulated experiment.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.signal import butter, filtfilt, savgol_filter

import jaxrb as rb
from jaxrb.physics.joints import dynamics
from jaxrb.physics.joints import identification as ident

L1 = 0.3


def arm_scene():
    """A fixed-base hinge – slide – hinge arm with springs, damping, armature, smooth friction and motors."""
    scene = rb.Scene(dim=3)
    base = scene.add_body(rb.Box(half_extents=(0.05, 0.05, 0.2)), mass=1.2, pos=(0.0, 0.0, -0.2),
                          quat=(0.96, 0.2, 0.1, 0.15), com=(0.01, 0.02, -0.03), name="base")
    carriage = scene.add_body(rb.Box(half_extents=(0.04, 0.04, 0.04)), mass=0.5, pos=(0.1, 0.0, -0.4),
                              name="carriage")
    tip = scene.add_body(rb.Capsule(radius=0.02, half_length=0.1), mass=0.3, pos=(0.1, 0.1, -0.5),
                         quat=(0.9, 0.0, 0.3, 0.3), com=(0.0, 0.01, 0.02), name="tip")
    shoulder = scene.add_joint(rb.Hinge(axis=(0.2, 1.0, 0.1), anchor=(0.0, 0.0, 0.0)), base, damping=0.1,
                               armature=0.02, frictionloss=0.3, stiffness=2.0, springref=0.2, name="shoulder")
    slide = scene.add_joint(rb.Slider(axis=(0.3, 0.0, -1.0)), carriage, base, damping=0.5, armature=0.1,
                            frictionloss=0.4, stiffness=20.0, springref=-0.05, name="slide")
    wrist = scene.add_joint(rb.Hinge(axis=(1.0, 0.0, 0.2), anchor=(0.1, 0.05, -0.45)), tip, carriage,
                            damping=0.02, armature=0.003, frictionloss=0.05, name="wrist")
    for joint, gear in ((shoulder, 2.0), (slide, 1.0), (wrist, 0.5)):
        scene.add_actuator(joint, "motor", gear=gear)
    return scene


def floating_scene():
    """A free root carrying a hinged link and a ball-jointed tip."""
    scene = rb.Scene(dim=3)
    root = scene.add_body(rb.Box(half_extents=(0.1, 0.08, 0.05)), mass=2.0, pos=(0.0, 0.0, 1.0),
                          com=(0.01, 0.0, 0.02), name="trunk")
    arm = scene.add_body(rb.Capsule(radius=0.02, half_length=0.12), mass=0.4, pos=(0.15, 0.0, 1.0),
                         quat=(0.7071, 0.0, 0.7071, 0.0), name="arm")
    tip = scene.add_body(rb.Sphere(radius=0.04), mass=0.2, pos=(0.3, 0.0, 1.0), com=(0.02, 0.0, 0.0), name="tip")
    elbow = scene.add_joint(rb.Hinge(axis=(0.0, 1.0, 0.0), anchor=(0.1, 0.0, 1.0)), arm, root, damping=0.05,
                            armature=0.01, name="elbow")  # no friction: the step check holds for either law
    scene.add_joint(rb.Ball(anchor=(0.27, 0.0, 1.0)), tip, arm, damping=0.01, armature=0.002, name="ball")
    scene.add_actuator(elbow, "motor", gear=3.0)
    return scene


def planar_scene():
    """A 2D mechanism: a free box of the plane (slide x, slide y, hinge z), a hinged arm, a sliding tip."""
    scene = rb.Scene(dim=2)
    root = scene.add_body(rb.Box(half_extents=(0.2, 0.1)), mass=1.0, pos=(0.0, 1.0), angle=0.3,
                          com=(0.02, -0.01), name="box")
    arm = scene.add_body(rb.Box(half_extents=(0.2, 0.05)), mass=0.5, pos=(0.4, 1.0), angle=0.3,
                         com=(0.03, 0.0), name="arm")
    tip = scene.add_body(rb.Box(half_extents=(0.05, 0.05)), mass=0.2, pos=(0.65, 1.0), name="tip")
    hinge = scene.add_joint(rb.Hinge(anchor=(0.2, 1.0)), arm, root, damping=0.05, armature=0.01,
                            frictionloss=0.1, stiffness=1.5, springref=0.1, name="hinge")
    slide = scene.add_joint(rb.Slider(axis=(1.0, 0.2)), tip, arm, damping=0.2, armature=0.05, frictionloss=0.2,
                            name="slide")
    scene.add_actuator(hinge, "motor", gear=2.0)
    scene.add_actuator(slide, "motor")
    return scene


def random_states(model, params, state, rng, count):
    """``count`` random (qpos, qvel) pairs of the model (quaternions normalised)."""
    tree = model.joints
    qpos = np.tile(np.asarray(state.qpos), (count, 1))
    for j, kind in enumerate(tree.joint_kind):
        a = tree.qpos_adr[j]
        if kind in ("hinge", "slide"):
            qpos[:, a] += rng.uniform(-1.0, 1.0, count) * (1.0 if kind == "hinge" else 0.1)
        else:
            a += 3 if kind == "free" else 0
            quat = rng.normal(size=(count, 4))
            qpos[:, a:a + 4] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    return jnp.asarray(qpos), jnp.asarray(rng.normal(0.0, 2.0, (count, tree.nv)))


@pytest.mark.parametrize("scene_fn, friction", [(arm_scene, "smooth"), (floating_scene, "sign"),
                                                (planar_scene, "smooth")])
def test_inverse_dynamics_inverts_the_step_and_is_the_regressor_times_the_parameters(scene_fn, friction):
    """(a) q̈ = (q̇' − q̇)/h of a semi-implicit step: ID(q, q̇, q̈) + h (D + friction slope) q̈ is the motors'
    torques, with constant loads on the bodies. (b) Y θ = ID to 1e-10 for random states (Y batched: vmap
    of the jitted regressor; ID: jit of vmap); Y does not see the inertial and joint-law values."""
    model, params, state = scene_fn().build(dt=1e-3, integrator="semi_implicit", joint_friction="smooth",
                                            contact="none")
    tree, h = model.joints, float(params.dt)
    step = rb.make_step(model)
    dofs = np.asarray([tree.dof_adr[j] for j in tree.actuator_joint])
    inverse = jax.jit(jax.vmap(lambda p, q, v, a: rb.joints.inverse_dynamics(model, p, q, v, a, friction=friction),
                               in_axes=(None, 0, 0, 0)))

    @jax.jit
    @jax.vmap
    def advance(qpos, qvel, controls):  # (q̇' − q̇)/h of one step, and the implicit terms' slope
        start = rb.joints.set_qpos_qvel(model, loaded, state, qpos, qvel)
        qacc = (step(start, loaded, controls=controls).qvel - qvel) / h
        return qacc, loaded.joint_damping + dynamics.smooth_friction(tree, loaded, qvel)[1]

    # (a) Constant loads count as applied forces: the inverse dynamics takes them off what the motors supply.
    loads = ([0.3, -0.2, 0.5], [0.05, 0.1, -0.02]) if model.dim == 3 else ([0.3, -0.2], 0.05)
    loaded = params.replace(force=params.force.at[-1].set(jnp.array(loads[0])),
                            torque=params.torque.at[0].set(jnp.array(loads[1])))
    rng = np.random.default_rng(0)
    qpos, qvel = random_states(model, params, state, rng, 4)
    controls = jnp.asarray(rng.normal(0.0, 1.0, (4, tree.num_actuators)))
    qacc, implicit = advance(qpos, qvel, controls)
    tau = inverse(loaded, qpos, qvel, qacc) + h * implicit * qacc
    motors = jnp.zeros((4, tree.nv)).at[:, dofs].add(loaded.actuator_gear * controls)
    np.testing.assert_allclose(np.asarray(tau), np.asarray(motors), rtol=0, atol=1e-9 * float(jnp.abs(motors).max()))

    # (b)
    qpos, qvel = random_states(model, params, state, rng, 16)
    qacc = jnp.asarray(rng.normal(0.0, 5.0, qvel.shape))
    Y, names = rb.joints.regressor(model, params, qpos, qvel, qacc, friction=friction)
    theta = rb.joints.standard_parameters(model, params)
    assert Y.shape == (16, tree.nv, len(names)) and theta.shape == (len(names),)
    assert names == rb.joints.parameter_names(model) and len(set(names)) == len(names)
    per_body = 10 if model.dim == 3 else 4  # 2D: m, mc_x, mc_y, I_zz
    springs = sum(kind in ("hinge", "slide") for kind in tree.joint_kind)
    assert len(names) == per_body * model.num_bodies + 3 * tree.nv + springs
    tau = inverse(params, qpos, qvel, qacc)
    assert float(jnp.max(jnp.abs(Y @ theta - tau))) < 1e-10 * max(1.0, float(jnp.max(jnp.abs(tau))))
    heavier = params.replace(mass=params.mass * 1.7, com_offset=params.com_offset + 0.01,
                             joint_damping=params.joint_damping + 1.0)
    np.testing.assert_allclose(np.asarray(rb.joints.regressor(model, heavier, qpos, qvel, qacc,
                                                              friction=friction)[0]), np.asarray(Y), atol=1e-12)


def test_regressor_refuses_loads_that_are_not_linear_in_the_parameters():
    model, params, _ = arm_scene().build(dt=1e-3, contact="none")
    qpos, qvel = jnp.zeros(model.joints.nq), jnp.zeros(model.joints.nv)
    with pytest.raises(ValueError, match="Params.force"):
        rb.joints.regressor(model, params.replace(force=params.force + 1.0), qpos, qvel, qvel)
    with pytest.raises(ValueError, match="friction"):
        rb.joints.inverse_dynamics(model, params, qpos, qvel, qvel, friction="viscous")


def double_pendulum(dt=1e-3, integrator="rk4"):
    """Two hinges about y, each body's frame origin on its joint axis; centres of mass off the links' lines."""
    scene = rb.Scene(dim=3)
    link1 = scene.add_body(rb.Capsule(radius=0.02, half_length=L1 / 2), mass=1.0, pos=(0.0, 0.0, 0.0),
                           com=(0.03, 0.0, -0.15), shape_pos=(0.0, 0.0, -L1 / 2), name="link1")
    link2 = scene.add_body(rb.Capsule(radius=0.02, half_length=0.1), mass=0.6, pos=(0.0, 0.0, -L1),
                           com=(-0.02, 0.0, -0.12), shape_pos=(0.0, 0.0, -0.1), name="link2")
    shoulder = scene.add_joint(rb.Hinge(axis=(0.0, 1.0, 0.0), anchor=(0.0, 0.0, 0.0)), link1, damping=0.05,
                               armature=0.01, frictionloss=0.2, name="shoulder")
    elbow = scene.add_joint(rb.Hinge(axis=(0.0, 1.0, 0.0), anchor=(0.0, 0.0, -L1)), link2, link1, damping=0.03,
                            armature=0.005, frictionloss=0.1, name="elbow")
    scene.add_actuator(shoulder, "motor")
    scene.add_actuator(elbow, "motor")
    return scene.build(dt=dt, integrator=integrator, joint_friction="smooth", contact="none")


def direct_combinations(params):
    """The double pendulum's base parameters computed by hand from its physical values."""
    m1, m2 = (float(m) for m in params.mass)
    (x1, _, z1), (x2, _, z2) = np.asarray(params.com_offset)
    j1 = float(params.inertia[0, 1, 1]) + m1 * (x1 ** 2 + z1 ** 2)  # link 1 about the shoulder
    j2 = float(params.inertia[1, 1, 1]) + m2 * (x2 ** 2 + z2 ** 2)  # link 2 about the elbow
    arm1, arm2 = (float(a) for a in params.joint_armature)
    b1, b2 = (float(b) for b in params.joint_damping)
    mu1, mu2 = (float(f) for f in params.joint_frictionloss)
    return {
        "mc_x[link1]": m1 * x1,
        "mc_z[link1] - 0.3 m[link2]": -(m1 * -z1 + m2 * L1),       # −(m1 a1 + m2 L1)
        "I_yy[link1] + 0.09 m[link2] + armature[shoulder]": j1 + m2 * L1 ** 2 + arm1,
        "mc_x[link2]": m2 * x2,
        "mc_z[link2]": m2 * z2,                                       # −m2 a2
        "I_yy[link2]": j2,
        "armature[elbow]": arm2,
        "damping[shoulder]": b1, "damping[elbow]": b2,
        "friction[shoulder]": mu1, "friction[elbow]": mu2,
    }


def test_double_pendulum_base_parameters_are_the_classical_combinations():
    """(c) 11 combinations: J1 + m2 L1² + armature1, m1 a1 + m2 L1, J2, m2 a2, the x moments, armature2, b, μ."""
    model, params, state = double_pendulum()
    rng = np.random.default_rng(2)
    count = 64
    qpos = jnp.asarray(rng.uniform(-np.pi, np.pi, (count, 2)))
    qvel, qacc = jnp.asarray(rng.normal(0, 3, (count, 2))), jnp.asarray(rng.normal(0, 20, (count, 2)))
    Y, names = rb.joints.regressor(model, params, qpos, qvel, qacc, friction="smooth")  # (d)'s compiled program
    assert len(names) == 2 * 10 + 3 * 2 + 2
    Y_stack = np.asarray(Y).reshape(-1, len(names))
    springs = [k for k, name in enumerate(names) if name.startswith("stiffness")]  # no springs: drop their columns
    keep = [k for k in range(len(names)) if k not in springs]
    K, base_names = rb.joints.base_parameters(Y_stack[:, keep], [names[k] for k in keep])
    expected = direct_combinations(params)
    assert base_names == tuple(expected), base_names
    theta = np.asarray(rb.joints.standard_parameters(model, params))[keep]
    np.testing.assert_allclose(K @ theta, list(expected.values()), rtol=1e-10, atol=1e-14)
    # The combinations carry the whole torque: Y θ = Y_lead (K θ).
    leads = [names[keep[k]] for k in np.argmax(K == 1.0, axis=1)]
    lead_columns = [names.index(name) for name in leads]
    np.testing.assert_allclose(Y_stack[:, lead_columns] @ (K @ theta), Y_stack[:, keep] @ theta, atol=1e-12)
    # With the springs' columns kept, their stiffnesses are identifiable too (13 combinations).
    assert len(rb.joints.base_parameters(Y_stack, names)[1]) == 13


def test_sysid_recovers_the_double_pendulum_from_one_percent_noise():
    """(d) 20 s of an RK4 simulation under a multisine torque, 1 % noise on q, q̇ and τ: every base
    parameter, damping and friction within 2 % by inverse dynamics with parallel filtering.

    Method (Gautier's IDIM with parallel filtering): q and q̇ lightly smoothed (Savitzky–Golay, 11 ms),
    q̈ their central difference, then the regressor and the measured torque through the same zero-phase
    4th-order Butterworth low-pass at 5 Hz and decimated 5×, weighted least squares. The filter is linear,
    so filter(Y θ) = filter(Y) θ: it removes the differentiated noise and the friction steps' mismatch with
    smoothed accelerations without biasing θ (noise-free, the same pipeline recovers every combination to
    0.012 %). Largest error with this noise seed 0.37 % (12 noise seeds: 0.37-1.08 %, the elbow's damping and
    friction the worst). RK4, because the Euler-type integrators are first order: their noise-free data give
    the damping 1.3 % (midpoint) and 2.9 % (semi_implicit) off at 1 kHz.
    """
    dt, duration = 1e-3, 20.0
    model, params, state = double_pendulum(dt=dt)
    steps = int(round(duration / dt))
    rng = np.random.default_rng(1)
    t = np.arange(steps) * dt

    def multisine(amplitude, frequencies):
        phases = rng.uniform(0.0, 2 * np.pi, len(frequencies))
        waves = sum(np.sin(2 * np.pi * f * t + p) for f, p in zip(frequencies, phases))
        return amplitude * waves / np.sqrt(len(frequencies) / 2)

    controls = np.stack([multisine(1.5, [0.15, 0.35, 0.6, 0.9, 1.3, 1.9, 2.7]),
                         multisine(0.4, [0.2, 0.45, 0.75, 1.1, 1.6, 2.3, 3.1])], axis=-1)
    traj = rb.rollout(rb.make_step(model), state, params, steps, controls=jnp.asarray(controls))
    # State k is at time (k + 1) dt, where the piecewise-constant torque steps from u_k to u_{k+1}:
    # the torque sampled there is their mean (the staircase's value centred on the sample).
    qpos, qvel = np.asarray(traj.qpos)[:-1], np.asarray(traj.qvel)[:-1]
    tau = 0.5 * (controls[1:] + controls[:-1])
    assert np.all(np.ptp(qpos, axis=0) > 3.0) and np.all(np.abs(qvel).max(axis=0) > 5.0)  # a rich motion
    noise = np.random.default_rng(7)
    noisy = lambda x: x + 0.01 * x.std(axis=0) * noise.standard_normal(x.shape)  # noqa: E731
    qpos, qvel, tau = noisy(qpos), noisy(qvel), noisy(tau)

    qpos, qvel = savgol_filter(qpos, 11, 2, axis=0), savgol_filter(qvel, 11, 2, axis=0)
    qacc = np.gradient(qvel, dt, axis=0)
    b, a = butter(4, 5.0 * 2 * dt)
    edge = 500  # the filter's start-up at both ends
    fit = rb.joints.fit_base_parameters(model, params, qpos, qvel, qacc, tau, friction="smooth",
                                        known=("stiffness[shoulder]", "stiffness[elbow]"),
                                        filter=lambda x: filtfilt(b, a, x, axis=0)[edge:-edge:5])
    expected = direct_combinations(params)
    assert fit.names == tuple(expected)
    truth = np.asarray(list(expected.values()))
    np.testing.assert_allclose(fit.true_values(model, params), truth, rtol=1e-10)
    errors = np.abs(fit.theta - truth) / np.abs(truth)
    assert np.all(errors < 0.02), dict(zip(fit.names, np.round(100 * errors, 2)))
    assert np.all(fit.standard_errors > 0) and np.all(fit.standard_errors < 0.01 * np.abs(truth))
