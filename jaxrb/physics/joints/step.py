"""The step of a scene with joints: joint coordinates advanced as MuJoCo's integrators do, or better.

One call of ``step(state, params, applied=None, controls=None)``:

1. loads: constant and applied wrenches (gravity enters with the bias forces);
2. ``model.substeps`` substeps of h = dt/substeps. The velocity-first
   integrators (``midpoint``, the default; ``semi_implicit``, MuJoCo's
   ``Euler``; ``implicit``) solve M̃ q̈ = τ in the velocity phase
   (:func:`_velocity_phase`, :mod:`.dynamics`), then run the constraint
   passes (:mod:`.constraints`: loop closures, exact joint friction, impulse
   contacts with warm start, impacts, soft passes, the position update,
   relax passes, restitution) or, with penalty contact, add the contact
   forces computed on the predicted velocities; then qpos advances with the
   new q̇. ``rk4`` is MuJoCo's RK4 on (qpos, qvel), with its correction of
   ball and free rotations, for scenes without contact, loop closures or
   exact friction;
3. the read-outs: ``State.pos`` (centres of mass), ``quat`` (or ``angle``),
   ``vel`` and ``angvel`` from the new qpos and qvel, and ``time += dt``.

Impulse contact detects once a step on the starting pose, as the free-body
solver does, and rebuilds the rows' Jacobians each substep from their
anchors; penalty contact detects every substep. A 2D scene runs on its
Params' 3D view (:mod:`.planar`).
"""

from __future__ import annotations

from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.compile import full_precision
from jaxrb.model.types import Model, Params, State, Wrench
from jaxrb.physics.collision.pairs import detect
from jaxrb.physics.contact.common import carried_impulses
from jaxrb.physics.contact.penalty import penalty_wrench
from jaxrb.physics.joints import constraints, planar
from jaxrb.physics.joints.dynamics import (bias_force, factor, forces, generalized, smooth_force, solve,
                                          world_inertia)
from jaxrb.physics.joints.kinematics import body_velocities, integrate_positions, kinematics

#: Integrators of scenes with joints (``scene.build``'s ``integrator``): the implicit midpoint rule in the
#: Coriolis terms (``midpoint``, the default), MuJoCo's Euler (``semi_implicit``), the linearised implicit
#: Euler in velocity and position (``implicit``) and MuJoCo's RK4 (:func:`_velocity_phase`).
JOINT_INTEGRATORS = ("midpoint", "semi_implicit", "implicit", "rk4")


def read_out(model: Model, params: Params, state: State, qpos, qvel) -> State:
    """``state`` with qpos, qvel and the bodies' poses and velocities they give.

    Args:
        params: the scene's Params (2D ones for a 2D scene).
        qpos: (nq,) coordinates; qvel: (nv,) velocities.

    Returns:
        The State: ``pos`` (n, dim) centres of mass, ``quat`` (n, 4) body
        frames (3D) or ``angle`` (n,) (2D, in [−π, π]), ``vel`` (n, dim) and
        ``angvel`` ((n, 3) world frame, or (n,)).
    """
    space = planar.lift_params(params) if model.dim == 2 else params
    kin = kinematics(model.joints, space, qpos)
    vel, angvel = body_velocities(kin, qvel)
    return _with_bodies(model, state.replace(qpos=qpos, qvel=qvel), kin, vel, angvel)


def _with_bodies(model: Model, state: State, kin, vel, angvel) -> State:
    """``state`` with the bodies' poses of ``kin`` and the velocities given (in the plane for a 2D scene)."""
    if model.dim == 2:
        return state.replace(pos=kin.com[:, :2], angle=planar.angle_of(kin.quat), vel=vel[:, :2],
                             angvel=angvel[:, 2])
    return state.replace(pos=kin.com, quat=kin.quat, vel=vel, angvel=angvel)


def _loads(model: Model, params: Params, applied: Optional[Wrench]):
    """World force and torque (n, 3) on each body from Params and the applied Wrench (not gravity)."""
    force, torque = params.force, params.torque
    if applied is not None:
        force, torque = force + applied.force, torque + applied.torque
    return planar.lift_loads(force, torque) if model.dim == 2 else (force, torque)


def _body_damping(model: Model, params: Params, kin, qvel, force, torque):
    """Loads with the bodies' linear and angular damping added (explicit, as Params document)."""
    if not model.damping:
        return force, torque
    vel, angvel = body_velocities(kin, qvel)
    momentum = jnp.einsum("bij,bj->bi", world_inertia(kin, params), angvel)
    return (force - params.linear_damping[:, None] * params.mass[:, None] * vel,
            torque - params.angular_damping[:, None] * momentum)


def _velocity_phase(model, params, kin, qpos, qvel, h, controls, loads):
    """(q̇ after the velocity phase, the factored M̃).

    Damping, the limits and smooth friction are implicit in every integrator
    (as in MuJoCo's Euler), and the actuators' velocity gains in ``midpoint``
    and ``implicit`` (:func:`.dynamics.forces`). The Coriolis and centrifugal
    terms c(q, q̇) are explicit in ``semi_implicit``; ``midpoint`` evaluates
    them at the step's mid-velocity q̇ + h q̈/2 (one corrector pass with the
    same factor: the implicit midpoint rule in velocity, whose one pass kept
    a double pendulum's energy to 1e-5 of its swing over 10 s, as a
    linearised solve did at a third of its cost); ``implicit`` linearises the
    smooth forces in velocity and position (:func:`.dynamics.smooth_force`)
    and takes them fully implicitly (a non-symmetric solve).
    """
    loads = _body_damping(model, params, kin, qvel, *loads)
    terms = forces(model, params, kin, qpos, qvel, h, controls, loads)
    matrix = terms.mass_matrix + jnp.diag(h * terms.damping + h * h * terms.stiffness)
    rhs = terms.force - h * terms.stiffness * qvel
    tree = model.joints
    coriolis = lambda velocity: -bias_force(tree, params, kin, world_inertia(kin, params), velocity)
    if model.integrator == "implicit":
        smooth = lambda step: smooth_force(model, params, integrate_positions(tree, qpos, step, 1.0), qvel,
                                           controls, loads)[0]
        by_velocity = jax.jacfwd(coriolis)(qvel)
        by_position = jax.jacfwd(smooth)(jnp.zeros_like(qvel))
        found = factor(matrix - h * by_velocity - h * h * by_position, symmetric=False)
        return qvel + h * solve(found, rhs + h * by_position @ qvel), found
    found = factor(matrix, symmetric=True)
    acceleration = solve(found, rhs)
    if model.integrator == "midpoint":
        acceleration = solve(found, rhs + coriolis(qvel + 0.5 * h * acceleration) - coriolis(qvel))
    return qvel + h * acceleration, found


def _zero_impulses(model: Model, qvel, rows=None):
    tree = model.joints
    count = 0 if rows is None else rows.separation.shape[0]
    return (jnp.zeros(tree.equality_rows, qvel.dtype), jnp.zeros(len(tree.friction_dofs), qvel.dtype),
            jnp.zeros((count, 3), qvel.dtype))


def _euler_substep(model, params, qpos, qvel, impulses, h, controls, loads, rows=None):
    """One velocity-first substep with impulse contact (``rows``) or none; returns (qpos, qvel, impulses)."""
    kin = kinematics(model.joints, params, qpos)
    qvel, found = _velocity_phase(model, params, kin, qpos, qvel, h, controls, loads)
    return _constrained_update(model, params, kin, qpos, qvel, found, impulses, h, rows)


def _constrained_update(model, params, kin, qpos, qvel, found, impulses, h, rows=None):
    """The constraint passes around the position update: (qpos, qvel, impulses) at the substep's end.

    Warm start, ``iterations`` soft passes, positions (projected back onto
    the loop closures), ``relax_iterations`` rigid passes, restitution.
    """
    if rows is None and not model.joints.has_rows:
        return integrate_positions(model.joints, qpos, qvel, h), qvel, impulses
    sys = constraints.system(model, params, kin, found, h, qvel, rows)
    qvel = constraints.warm_start(sys, qvel, impulses)
    if rows is not None:
        # Impacts first, contact by contact; restitution later bounces what still approached after them.
        qvel = constraints.collision_pass(params, sys, rows, qvel, h)
        sys = sys.replace(approach=sys.contact_jac[:, 0] @ qvel)

    def passes(qvel, impulses, count, soft):
        one = lambda _, carry: constraints.solve_pass(model, params, sys, rows, *carry, h, soft)
        return jax.lax.fori_loop(0, count, one, (qvel, impulses)) if count else (qvel, impulses)

    qvel, impulses = passes(qvel, impulses, model.iterations, True)
    qpos = integrate_positions(model.joints, qpos, qvel, h)
    if model.joints.equality_kind:
        qpos = constraints.project_closures(model, params, qpos, found)
    qvel, impulses = passes(qvel, impulses, model.relax_iterations, False)
    if rows is not None:
        qvel, impulses = constraints.restitution_pass(params, sys, rows, qvel, impulses)
    return qpos, qvel, impulses


def _penalty_substep(model, params, space, state, qpos, qvel, h, controls, loads):
    """One substep with penalty contact: the contact law on the velocities predicted without it, then the
    contact's generalized force through the same factored M̃; returns (qpos, qvel, state).

    ``params`` are the scene's, ``space`` their 3D view (the same in 3D; :mod:`.planar`).
    """
    kin = kinematics(model.joints, space, qpos)
    current = _with_bodies(model, state, kin, *body_velocities(kin, qvel))
    contacts = detect(model, params, current)
    held = carried_impulses(current, contacts)[:, 1:] / h
    qvel, found = _velocity_phase(model, space, kin, qpos, qvel, h, controls, loads)
    predicted = _with_bodies(model, current, kin, *body_velocities(kin, qvel))
    force, torque, normal_force, held = penalty_wrench(model, params, current, contacts, h, predicted, held)
    if model.dim == 2:
        force, torque = planar.lift_loads(force, torque)
    qvel = qvel + h * solve(found, generalized(kin, force, torque))
    qpos, qvel, _ = _constrained_update(model, space, kin, qpos, qvel, found, _zero_impulses(model, qvel), h)
    carried = jnp.concatenate([normal_force[:, None], held], axis=-1) * h
    return qpos, qvel, state.replace(contact_impulse=carried, contact_key=contacts.key, overflow=contacts.overflow)


def _rk4_step(model, params, qpos, qvel, h, controls, loads):
    """MuJoCo's RK4 (a = ½, ½, 1; b = ⅙, ⅓, ⅓, ⅙) with its correction of ball and free rotations."""
    tree = model.joints

    def acceleration(qpos, qvel):
        kin = kinematics(tree, params, qpos)
        terms = forces(model, params, kin, qpos, qvel, h, controls, _body_damping(model, params, kin, qvel, *loads))
        return solve(factor(terms.mass_matrix, symmetric=True), terms.force)

    rotations = [tree.dof_adr[j] + (3 if kind == "free" else 0)
                 for j, kind in enumerate(tree.joint_kind) if kind in ("ball", "free")]

    def corrected(qvel, turn):
        # MuJoCo 4's RK4 takes a ball's stage tangent as ω + ½ θ×ω + θ×(θ×ω)/12 (θ: the stage's turn).
        for d in rotations:
            omega, theta = qvel[d:d + 3], turn[d:d + 3]
            half = jnp.cross(theta, omega)
            qvel = qvel.at[d:d + 3].set(omega + 0.5 * half + jnp.cross(theta, half) / 12.0)
        return qvel

    a, b = (0.5, 0.5, 1.0), (1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0)
    tangents, rates = [qvel], [acceleration(qpos, qvel)]
    for stage in range(3):
        turn = h * a[stage] * tangents[-1]
        stage_qvel = qvel + h * a[stage] * rates[-1]
        rates.append(acceleration(integrate_positions(tree, qpos, turn, 1.0), stage_qvel))
        tangents.append(corrected(stage_qvel, turn))
    new_qvel = qvel + h * sum(weight * rate for weight, rate in zip(b, rates))
    new_qpos = integrate_positions(tree, qpos, sum(weight * t for weight, t in zip(b, tangents)), h)
    return new_qpos, new_qvel


def make_joint_step(model: Model) -> Callable:
    """``step(state, params, applied=None, controls=None) -> State`` for a Model with joints.

    Args:
        model: a Model whose ``joints`` is a JointTree.

    Returns:
        The pure step (see :func:`jaxrb.make_step`); ``controls`` (na,) in
        the model's actuator order, None for zero.
    """
    tree = model.joints
    substeps = model.substeps

    def run_free(state, params, space, qpos, qvel, h, controls, loads):
        def substep(_, carry):
            qpos, qvel, impulses = carry
            if model.integrator == "rk4":
                return (*_rk4_step(model, space, qpos, qvel, h, controls, loads), impulses)
            return _euler_substep(model, space, qpos, qvel, impulses, h, controls, loads)

        # A loop, not unrolled: a joint substep is large, and ten of them unrolled compiled in 14 s.
        carry = (qpos, qvel, _zero_impulses(model, qvel))
        qpos, qvel, _ = substep(0, carry) if substeps == 1 else jax.lax.fori_loop(0, substeps, substep, carry)
        return state, qpos, qvel

    def run_penalty(state, params, space, qpos, qvel, h, controls, loads):
        overflow = jnp.zeros((), bool)
        for _ in range(substeps):
            qpos, qvel, state = _penalty_substep(model, params, space, state, qpos, qvel, h, controls, loads)
            overflow = overflow | state.overflow
        return state.replace(overflow=overflow), qpos, qvel

    def run_impulse(state, params, space, qpos, qvel, h, controls, loads):
        contacts = detect(model, params, state)
        carried = carried_impulses(state, contacts)
        if model.dim == 2:
            contacts, carried = planar.lift_contacts(contacts), planar.lift_impulses(carried)
        rows = constraints.prepare_contacts(model, space, kinematics(tree, space, qpos), contacts)
        equality, friction, _ = _zero_impulses(model, qvel, rows)
        impulses = (equality, friction, constraints.row_impulses(rows, carried))

        def substep(_, carry):
            return _euler_substep(model, space, *carry, h, controls, loads, rows)

        qpos, qvel, impulses = jax.lax.fori_loop(0, substeps, substep, (qpos, qvel, impulses))
        world = constraints.world_row_impulses(rows, impulses[2])
        return (state.replace(contact_impulse=planar.lower_impulses(world) if model.dim == 2 else world,
                              contact_key=contacts.key, overflow=contacts.overflow), qpos, qvel)

    has_contact = model.contact != "none" and model.num_contacts > 0
    run = run_free if not has_contact else run_penalty if model.contact == "penalty" else run_impulse

    @full_precision  # float32 products in float32 on GPUs too (jaxrb.compile)
    def step(state: State, params: Params, applied: Optional[Wrench] = None, controls=None) -> State:
        if controls is not None and np.shape(controls)[-1:] != (tree.num_actuators,):
            raise ValueError(f"step: 'controls' must have shape ({tree.num_actuators},) (the model's actuators "
                             f"in order), got {np.shape(controls)}")
        h = params.dt / substeps
        space = planar.lift_params(params) if model.dim == 2 else params
        loads = _loads(model, params, applied)
        state, qpos, qvel = run(state, params, space, state.qpos, state.qvel, h, controls, loads)
        state = read_out(model, params, state, qpos, qvel)
        return state.replace(time=state.time + params.dt)

    step.model = model
    return step
