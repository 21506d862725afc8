"""Constraint rows of a joint tree's step: loop closures, Coulomb joint friction and contacts, in joint space.

Each row has a Jacobian row J (nv,): its speed is J·q̇, and an impulse λ
along it changes q̇ by M̃⁻¹Jᵀλ, where M̃ = M + hD + h²K is the step's
matrix (:mod:`jaxrb.physics.joints.dynamics`). For a free body J holds
today's d and r × d and M̃⁻¹Jᵀ its m⁻¹d and I⁻¹(r × d); in a tree a row moves
every dof between its bodies and the world.

A pass (Gauss–Seidel over blocks) solves, in turn:

* the loop closures (:class:`~jaxrb.model.joints.Connect`,
  :class:`~jaxrb.model.joints.Weld`) as one block, exactly: their rows are
  coupled through M̃ and few, so the block's (J M̃⁻¹ Jᵀ) is factored once a
  substep; soft (``equality_hertz``) like Box2D's joints;
* Coulomb joint friction (``frictionloss``, the ``exact`` law), one dof at a
  time, |λ| ≤ μ·h;
* contacts, one at a time: the normal row with the impulse model's soft law
  (:func:`jaxrb.physics.contact.impulse._normal_impulse`), then both friction
  rows as a 2×2 block clamped to the Coulomb cone, as the free-body solver
  does; restitution by :func:`jaxrb.physics.contact.impulse.bounce_impulse`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.math import quaternion as quat_ops
from jaxrb.model.struct import pytree_dataclass
from jaxrb.model.types import Array, Params
from jaxrb.physics.collision.pairs import round_sides, row_taker, shape_centres
from jaxrb.physics.contact.common import clamp_to_disc, tangent_basis
from jaxrb.physics.contact.impulse import _normal_impulse, bounce_impulse, collision_impulse, soft_coefficients
from jaxrb.physics.joints.dynamics import Factor, factor, solve
from jaxrb.physics.joints.kinematics import Kinematics, integrate_positions, kinematics, point_jacobian

#: Relative regularisation of the loop closures' block: a closure whose rows are dependent (a planar
#: four-bar's out-of-plane row) stays solvable.
EQUALITY_REGULARIZATION = 1e-6
EQUALITY_CAP = 0.25


def equality_rows(tree, params: Params, kin: Kinematics):
    """Jacobian (E, nv) and error (E,) of the loop closures; ė = J q̇.

    connect: e = x_A(anchor_a) − x_B(anchor_b), three rows; weld: those three
    at B's origin and the rotation vector from q_A ⊗ rotation to q_B (world).
    """
    jacobians, errors = [], []
    rotations = quat_ops.to_rotation_matrix(kin.quat)
    for k, (kind, (body_a, body_b)) in enumerate(zip(tree.equality_kind, tree.equality_bodies)):
        point_a = kin.origin[body_a] + rotations[body_a] @ params.equality_anchor_a[k]
        point_b = (params.equality_anchor_b[k] if body_b < 0
                   else kin.origin[body_b] + rotations[body_b] @ params.equality_anchor_b[k])
        jac_a = point_jacobian(kin, [body_a], point_a[None])[0]
        jac_b = point_jacobian(kin, [body_b], point_b[None])[0]
        jacobians.append((jac_a - jac_b).T)
        errors.append(point_a - point_b)
        if kind == "weld":
            target = quat_ops.multiply(kin.quat[body_a], params.equality_rotation[k])
            actual = kin.quat[body_b] if body_b >= 0 else jnp.asarray([1.0, 0.0, 0.0, 0.0], kin.quat.dtype)
            error = quat_ops.multiply(target, quat_ops.conjugate(actual))  # A's target to B's actual, world
            error = jnp.where(error[0] < 0.0, -error, error)
            angular_b = kin.jac_ang[body_b] if body_b >= 0 else jnp.zeros_like(kin.jac_ang[0])
            jacobians.append((kin.jac_ang[body_a] - angular_b).T)
            errors.append(2.0 * error[1:])
    return jnp.concatenate(jacobians), jnp.concatenate(errors)


def project_closures(model, params: Params, qpos, matrix: Factor):
    """``qpos`` moved back onto its loop closures: one Newton step, q ⊕ −M̃⁻¹Jᵀ(J M̃⁻¹ Jᵀ)⁻¹ e.

    The velocity passes keep a closure's speed at zero, but each step's
    position update still leaves its error at O((h·v)²/r) (a four-bar's
    loop opened 17 mm at dt = 1/60); projecting after the update, with the
    step's own metric M̃, brings it to the square of that.

    Args:
        qpos: (nq,) coordinates after the position update.
        matrix: the substep's factored M̃.

    Returns:
        (nq,) the projected coordinates.
    """
    tree = model.joints
    jac, error = equality_rows(tree, params, kinematics(tree, params, qpos))
    push = solve(matrix, jac.T)
    inverse = jac @ push
    scale = EQUALITY_REGULARIZATION * jnp.mean(jnp.diagonal(inverse)) + jnp.finfo(inverse.dtype).tiny
    step = -push @ solve(factor(inverse + scale * jnp.eye(len(error)), matrix.cholesky is not None), error)
    return integrate_positions(tree, qpos, step, 1.0)


@pytree_dataclass
class ContactRows:
    """One step's contacts as joint-space rows: what is fixed at the step's start.

    Attributes:
        body_a, body_b: (C,) bodies (n: the static row of a plane).
        directions: (C, k, 3) the normal then the tangents (k = 3), world.
        arm_a, arm_b: (C, 3) the contact point from each body's centre of mass at the step's start.
        anchor_a, anchor_b: (C, 3) the body-frame points whose motion tracks the separation.
        start_a, start_b: (C, 3) those points' world positions at the step's start.
        separation: (C,) at the step's start.
        friction, restitution, active: (C,) the contacts'.
        smoothing: () ``impulse_smoothing`` (m/s); times a row's normal mass it is the clamp's width.
    """

    body_a: Array
    body_b: Array
    directions: Array
    arm_a: Array
    arm_b: Array
    anchor_a: Array
    anchor_b: Array
    start_a: Array
    start_b: Array
    separation: Array
    friction: Array
    restitution: Array
    active: Array
    smoothing: Array


def prepare_contacts(model, params: Params, kin: Kinematics, contacts) -> ContactRows:
    """Fix the step's contact rows from ``contacts`` (detected on the step's starting pose)."""
    take = row_taker(model, contacts.body_a, contacts.body_b)
    com_a, com_b = take(kin.com, 0), take(kin.com, 1)
    identity = jnp.asarray([1.0, 0.0, 0.0, 0.0], kin.quat.dtype)
    quat_a, quat_b = take(kin.quat, 0, identity), take(kin.quat, 1, identity)
    arm_a, arm_b = contacts.point - com_a, contacts.point - com_b
    round_a, round_b = (jnp.asarray(side)[:, None] for side in round_sides(model))
    centre = shape_centres(model, params)
    anchor_a = jnp.where(round_a, take(centre, 0), quat_ops.rotate_inverse(quat_a, arm_a))
    anchor_b = jnp.where(round_b, take(centre, 1), quat_ops.rotate_inverse(quat_b, arm_b))
    normal = contacts.normal
    directions = jnp.stack((normal, *tangent_basis(normal)), axis=1)
    return ContactRows(
        body_a=contacts.body_a, body_b=contacts.body_b, directions=directions, arm_a=arm_a, arm_b=arm_b,
        anchor_a=anchor_a, anchor_b=anchor_b, start_a=com_a + quat_ops.rotate(quat_a, anchor_a),
        start_b=com_b + quat_ops.rotate(quat_b, anchor_b), separation=contacts.dist,
        friction=contacts.friction, restitution=contacts.restitution, active=contacts.active,
        smoothing=params.impulse_smoothing)


def contact_jacobians(model, rows: ContactRows, kin: Kinematics):
    """(C, 3, nv) each contact's rows: d·J_lin,A + (r_A × d)·J_ang,A − the same for B."""
    take = row_taker(model, rows.body_a, rows.body_b)

    def side(index, arm):
        linear, angular = take(kin.jac_lin, index), take(kin.jac_ang, index)  # (C, nv, 3)
        at_point = linear + jnp.cross(angular, arm[:, None, :])
        return jnp.einsum("ckj,cdj->ckd", rows.directions, at_point)

    return side(0, rows.arm_a) - side(1, rows.arm_b)


def current_separation(model, rows: ContactRows, kin: Kinematics):
    """(C,) each contact's separation now, from its anchors' motion since the step's start."""
    take = row_taker(model, rows.body_a, rows.body_b)
    identity = jnp.asarray([1.0, 0.0, 0.0, 0.0], kin.quat.dtype)
    moved_a = take(kin.com, 0) + quat_ops.rotate(take(kin.quat, 0, identity), rows.anchor_a) - rows.start_a
    moved_b = take(kin.com, 1) + quat_ops.rotate(take(kin.quat, 1, identity), rows.anchor_b) - rows.start_b
    return rows.separation + jnp.sum(rows.directions[:, 0] * (moved_a - moved_b), axis=-1)


def row_impulses(rows: ContactRows, world):
    """(C, 3) impulses along each row's directions from (C, 4) normal and world friction impulses."""
    tangential = jnp.einsum("cj,ckj->ck", world[:, 1:], rows.directions[:, 1:])
    return jnp.concatenate([world[:, :1], tangential], axis=-1)


def world_row_impulses(rows: ContactRows, impulses):
    """(C, 4): the normal impulse then the world friction vector, for ``State.contact_impulse``."""
    friction = jnp.einsum("ck,ckj->cj", impulses[:, 1:], rows.directions[:, 1:])
    return jnp.concatenate([impulses[:, :1], friction], axis=-1)


@pytree_dataclass
class System:
    """The rows of one substep and how they move q̇, for the passes.

    Attributes:
        equality_jac: (E, nv) or None; equality_push: (nv, E) M̃⁻¹Jᵀ; equality_factor:
            the factor of J M̃⁻¹ Jᵀ; equality_error: (E,).
        friction_push: (nv, F) M̃⁻¹ columns of the friction dofs, friction_mass: (F,) 1/(M̃⁻¹)_jj,
            friction_bound: (F,) μ·h.
        contact_jac: (C, 3, nv) or None; contact_push: (C, nv, 3) M̃⁻¹Jᵀ; contact_inverse:
            (C, 3, 3) J M̃⁻¹ Jᵀ per contact; separation: (C,); approach: (C,) normal speeds
            after the velocity phase.
    """

    equality_jac: Array = None
    equality_push: Array = None
    equality_factor: Factor = None
    equality_error: Array = None
    friction_push: Array = None
    friction_mass: Array = None
    friction_bound: Array = None
    contact_jac: Array = None
    contact_push: Array = None
    contact_inverse: Array = None
    separation: Array = None
    approach: Array = None


def system(model, params: Params, kin: Kinematics, matrix: Factor, h, qvel, rows=None) -> System:
    """The substep's rows and their pushes (M̃⁻¹Jᵀ), ``matrix`` the factored M̃.

    Args:
        qvel: (nv,) the velocities after the velocity phase (the contacts' approach speeds).
        rows: the step's :class:`ContactRows`, or None.
    """
    tree = model.joints
    solve_matrix = lambda rhs: solve(matrix, rhs)
    found = {}
    if tree.equality_kind:
        jac, error = equality_rows(tree, params, kin)
        push = solve_matrix(jac.T)
        inverse = jac @ push
        scale = EQUALITY_REGULARIZATION * jnp.mean(jnp.diagonal(inverse)) + jnp.finfo(inverse.dtype).tiny
        found.update(equality_jac=jac, equality_push=push, equality_error=error,
                     equality_factor=factor(inverse + scale * jnp.eye(len(error)), matrix.cholesky is not None))
    if tree.friction_dofs and tree.joint_friction == "exact":
        dofs = np.asarray(tree.friction_dofs)
        push = solve_matrix(jnp.eye(tree.nv, dtype=qvel.dtype)[:, dofs])
        found.update(friction_push=push, friction_mass=1.0 / push[dofs, np.arange(len(dofs))],
                     friction_bound=params.joint_frictionloss[dofs] * h)
    if rows is not None:
        jac = contact_jacobians(model, rows, kin)
        count = jac.shape[0]
        push = solve_matrix(jac.reshape(count * 3, -1).T).T.reshape(count, 3, -1).transpose(0, 2, 1)
        found.update(contact_jac=jac, contact_push=push, contact_inverse=jnp.einsum("ckd,cdj->ckj", jac, push),
                     separation=current_separation(model, rows, kin), approach=jac[:, 0] @ qvel)
    return System(**found)


def warm_start(sys: System, qvel, impulses):
    """q̇ with the carried impulses applied: (equality (E,), friction (F,), contacts (C, 3))."""
    equality, friction, contact = impulses
    if sys.equality_push is not None:
        qvel = qvel + sys.equality_push @ equality
    if sys.friction_push is not None:
        qvel = qvel + sys.friction_push @ friction
    if sys.contact_push is not None:
        qvel = qvel + jnp.einsum("cdk,ck->d", sys.contact_push, contact)
    return qvel


def solve_pass(model, params: Params, sys: System, rows, qvel, impulses, h, soft: bool):
    """One Gauss–Seidel pass over the blocks; ``soft`` False for the relax passes (no position bias).

    Returns:
        (qvel (nv,), impulses) after the pass.
    """
    equality, friction, contact = impulses
    if sys.equality_jac is not None:
        bias_rate, mass_scale, impulse_scale = (
            soft_coefficients(params.equality_hertz, params.equality_damping_ratio, h, EQUALITY_CAP) if soft
            else (0.0, 1.0, 0.0))
        speed = sys.equality_jac @ qvel + bias_rate * sys.equality_error
        change = -mass_scale * solve(sys.equality_factor, speed) - impulse_scale * equality
        qvel, equality = qvel + sys.equality_push @ change, equality + change
    if sys.friction_push is not None:
        dofs = np.asarray(model.joints.friction_dofs)

        def one_dof(qvel, row):
            k, push, mass, bound, old = row
            new = jnp.clip(old - mass * qvel[dofs][k], -bound, bound)
            return qvel + push * (new - old), new

        qvel, friction = jax.lax.scan(one_dof, qvel, (jnp.arange(len(dofs)), sys.friction_push.T,
                                                      sys.friction_mass, sys.friction_bound, friction))
    if sys.contact_jac is not None:
        qvel, contact = _contact_pass(params, sys, rows, qvel, contact, h, soft)
    return qvel, (equality, friction, contact)


def _contact_pass(params, sys: System, rows: ContactRows, qvel, impulses, h, soft):
    """Each contact in turn: its normal row, then its friction block clamped to the cone."""
    coefficients = None
    if soft:
        bias_rate, mass_scale, impulse_scale = soft_coefficients(params.contact_hertz,
                                                                 params.contact_damping_ratio, h)
        coefficients = (bias_rate, mass_scale, impulse_scale, params.max_push_velocity)

    def one_contact(qvel, row):
        jac, push, inverse, old, separation, active, mu = row
        normal_mass = _inverse_mass(inverse[0, 0])
        normal = _normal_impulse(jac[0] @ qvel, old[0], separation, normal_mass, rows.smoothing * normal_mass,
                                 active, h, coefficients)
        qvel = qvel + push[:, 0] * (normal - old[0])
        trial = old[1:] - _solve_tangents(inverse[1:, 1:], jac[1:] @ qvel)
        friction = jnp.where(active, clamp_to_disc(trial, mu * normal), 0.0)
        qvel = qvel + push[:, 1:] @ (friction - old[1:])
        return qvel, jnp.concatenate([normal[None], friction])

    return jax.lax.scan(one_contact, qvel, (sys.contact_jac, sys.contact_push, sys.contact_inverse, impulses,
                                            sys.separation, rows.active, rows.friction))


def _inverse_mass(inverse):
    """1/w of a row's inverse effective mass w, 0 where the row moves nothing (w = 0: a planar
    mechanism's contact along the plane's normal)."""
    moves = inverse > jnp.finfo(inverse.dtype).tiny
    return jnp.where(moves, 1.0 / jnp.where(moves, inverse, 1.0), 0.0)


def _solve_tangents(block, speed):
    """(2,) impulses that stop ``speed`` (2,) on the tangents, for their (2, 2) inverse mass block.

    Closed form, regularised: a planar mechanism cannot move across its plane,
    so one tangent's row can be zero and the block singular; that tangent then
    takes no impulse (its speed is zero too).
    """
    scale = 1e-6 * (block[0, 0] + block[1, 1]) + jnp.finfo(block.dtype).tiny
    a, b, c, d = block[0, 0] + scale, block[0, 1], block[1, 0], block[1, 1] + scale
    determinant = a * d - b * c
    return jnp.stack([d * speed[0] - b * speed[1], a * speed[1] - c * speed[0]]) / determinant


def collision_pass(params: Params, sys: System, rows: ContactRows, qvel, h):
    """Impacts carried contact by contact (:func:`~jaxrb.physics.contact.impulse.collision_impulse`).

    A contact collides in the substep its gap closes (separation + h·v_n ≤ 0),
    not while a speculative contact is still coming. Two sweeps, in the rows'
    order and back, so an impact crosses a row of touching bodies from either
    end within one substep. The impacts' impulses are not accumulated into the
    rows' (warm-started) impulses: they act once, and the passes then see the
    bodies leaving each other.

    Returns:
        (nv,) q̇ after the sweeps.
    """
    def one_contact(qvel, row):
        jac, push, inverse, restitution, active, separation = row
        speed = jac[0] @ qvel
        impulse = collision_impulse(speed, 0.0, restitution, _inverse_mass(inverse[0, 0]),
                                    active & (separation + h * speed <= 0.0), params.bounce_threshold)
        return qvel + push[:, 0] * impulse, None

    rows_in_order = (sys.contact_jac, sys.contact_push, sys.contact_inverse, rows.restitution, rows.active,
                     sys.separation)
    qvel, _ = jax.lax.scan(one_contact, qvel, rows_in_order)
    return jax.lax.scan(one_contact, qvel, rows_in_order, reverse=True)[0]


def restitution_pass(params: Params, sys: System, rows: ContactRows, qvel, impulses):
    """Contacts that hit faster than ``bounce_threshold`` leave at −e times their approach speed."""
    equality, friction, contact = impulses

    def one_contact(qvel, row):
        jac, push, inverse, old, approach, restitution, active = row
        normal = bounce_impulse(jac[0] @ qvel, old[0], approach, restitution, _inverse_mass(inverse[0, 0]), active,
                                params.bounce_threshold)
        return qvel + push[:, 0] * (normal - old[0]), old.at[0].set(normal)

    qvel, contact = jax.lax.scan(one_contact, qvel, (sys.contact_jac, sys.contact_push, sys.contact_inverse,
                                                     contact, sys.approach, rows.restitution, rows.active))
    return qvel, (equality, friction, contact)
