"""Contact kinematics shared by the penalty and impulse models, for 2D and 3D.

Bodies are padded with one static row (index n) of zero inverse mass, so a
contact against a plane uses the same code as one between two bodies.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxrb.math import quaternion as quat_ops
from jaxrb.math.components import stacked
from jaxrb.physics.dynamics import inverse_inertia
from jaxrb.math.vector import cross, cross2, cross_scalar2, matmul, matvec3
from jaxrb.model.types import Model, Params, State


def pad(array):
    """Append one zero row (the static body). array: (n, ...) -> (n + 1, ...)."""
    return jnp.concatenate([array, jnp.zeros_like(array[:1])])


def spin_cross(model: Model, angvel, arm):
    """ω × r. angvel: (..., 3) or (...) in 2D; arm: (..., dim)."""
    return cross(angvel, arm) if model.dim == 3 else cross_scalar2(angvel, arm)


def relative_velocity(model: Model, vel, angvel, body_a, body_b, arm_a, arm_b, take=None):
    """v_A + ω_A × r_A − v_B − ω_B × r_B at contact points.

    Args:
        vel, angvel: padded (n + 1, ...) body velocities (see :func:`pad`), or
            with ``take`` the (n, ...) arrays it reads.
        body_a, body_b: (C,) body rows of each contact.
        arm_a, arm_b: (C, dim) contact point minus each body's centre of mass.
        take: optional ``take(array, side)`` reading side 0 (A) or 1 (B) rows
            (:func:`jaxrb.physics.collision.pairs.row_taker`); default
            ``array[body_a]`` / ``array[body_b]`` of padded arrays.

    Returns:
        (C, dim) relative velocity of A's material point with respect to B's.
    """
    if take is None:
        take = lambda array, side: array[body_b if side else body_a]
    return (take(vel, 0) + spin_cross(model, take(angvel, 0), arm_a)
            - take(vel, 1) - spin_cross(model, take(angvel, 1), arm_b))


def moment(model: Model, arm, force):
    """r × f: (..., 3) in 3D, (...) in 2D."""
    return cross(arm, force) if model.dim == 3 else cross2(arm, force)


def apply_inverse_inertia(model: Model, inv_inertia, torque):
    """I_w⁻¹ τ for world inverse inertia (..., 3, 3) or (...) in 2D."""
    return matvec3(inv_inertia, torque) if model.dim == 3 else inv_inertia * torque


def world_inverse_inertia(model: Model, params: Params, state: State, padded: bool = True):
    """World inverse inertia: (n + 1, 3, 3) R I⁻¹ Rᵀ in 3D, (n + 1,) in 2D; n rows if not ``padded``."""
    body_inverse = inverse_inertia(params, model.dim)
    if model.dim == 3:
        rotation = quat_ops.to_rotation_matrix(state.quat)
        body_inverse = matmul(matmul(rotation, body_inverse), jnp.swapaxes(rotation, -1, -2))
    return pad(body_inverse) if padded else body_inverse


def effective_mass(model, inv_mass_a, inv_mass_b, inv_inertia_a, inv_inertia_b, arm_a, arm_b, direction):
    """1 / (m_a⁻¹ + m_b⁻¹ + Σ (r × d)·I⁻¹(r × d)) along ``direction`` (C, dim)."""
    total = inv_mass_a + inv_mass_b
    for inv_inertia, arm in ((inv_inertia_a, arm_a), (inv_inertia_b, arm_b)):
        arm_cross = moment(model, arm, direction)
        angular = apply_inverse_inertia(model, inv_inertia, arm_cross) * arm_cross
        total = total + (jnp.sum(angular, axis=-1) if model.dim == 3 else angular)
    return 1.0 / total


def tangent_basis(normal):
    """Two unit tangents (C, 3) orthogonal to unit normals (C, 3), smooth away from flips."""
    # Cross with the world axis least aligned with n: never parallel, no branch on values.
    axis_x = jnp.abs(normal[..., 0]) < 0.57735
    helper = jnp.where(axis_x[..., None], jnp.array([1.0, 0.0, 0.0], normal.dtype),
                       jnp.array([0.0, 1.0, 0.0], normal.dtype))
    first = cross(normal, helper)
    first = first / jnp.sqrt(jnp.sum(first * first, axis=-1, keepdims=True))
    return first, cross(normal, first)


def carried_impulses(state: State, contacts):
    """The impulses (C, 1 + dim) in ``state`` of the contacts that persist, 0 for the rest.

    A row carries over when its ``contact_key`` (pair and slot) is the same and
    it is active; its friction part is projected onto the new tangent plane.
    """
    same = (state.contact_key == contacts.key) & contacts.active
    previous = jnp.where(same[:, None], state.contact_impulse, 0.0)
    friction = previous[:, 1:]
    friction = friction - jnp.sum(friction * contacts.normal, axis=-1, keepdims=True) * contacts.normal
    return jnp.concatenate([previous[:, :1], friction], axis=-1)


def clamp_to_disc(vector, limit):
    """Each (..., k) friction vector scaled down to length <= ``limit`` (...): the Coulomb cone.

    Args:
        vector: (..., k) friction vectors.
        limit: (...) their Coulomb bounds.

    Returns:
        (..., k) the clamped vectors (:meth:`jaxrb.math.components.stacked.clamp_to_disc`).
    """
    return stacked.clamp_to_disc(vector, limit)
