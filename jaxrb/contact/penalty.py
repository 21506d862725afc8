"""Penalty contact: spring-damper normal forces and regularised Coulomb friction.

For each active contact with penetration p = −dist and normal approach speed
v_n (v_rel = n·(v_A − v_B)):

    F_n = max(k·a(p) − c·v_n·g(p), 0)

with a(p) = max(p, 0), g = [p > 0] (hard), or the smooth activation
a(p) = w·softplus(p/w), g = sigmoid(p/w) of width ``penalty_width`` w. The
damper c is ``Params.penalty_damping``, or, by default, derived per contact
from its restitution e so that a linear spring-damper bounces with e:
ζ = −ln e / √(π² + ln² e), c = 2ζ√(k m) with m the pair's reduced mass.

Friction opposes the tangential slip v_t with μF_n·v_t / √(|v_t|² + v_reg²)
(``friction_velocity`` = v_reg, smooth through zero slip), and is capped at
the force that would stop the slip within one substep (the tangential
effective mass over h, shared among the body's contacts). The slip is the one
*predicted* after this substep's other loads, so within the cone the cap
cancels it exactly: static friction without any stored anchor. Without the
cap a small v_reg makes friction too stiff for an explicit force; with it a
box on a slope below the friction angle does not creep.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxrb.contact.common import (contact_counts, effective_mass, moment, pad, relative_velocity,
                                  world_inverse_inertia)
from jaxrb.math import safe_norm, safe_normalize
from jaxrb.types import Model, Params, State


# A spring switched on and off at step boundaries gains ~0.1 % energy per bounce
# (apex 0.903 -> 0.948 m over 50 undamped bounces at h = 1 ms), so e is capped
# below 1: ζ >= 0.0032 removes ~1 % per bounce and nothing can gain energy.
MAX_PENALTY_RESTITUTION = 0.99


def damping_ratio_from_restitution(restitution):
    """ζ of a linear spring-damper whose bounce has coefficient e. restitution: (C,)."""
    log_e = jnp.log(jnp.clip(restitution, 1e-4, MAX_PENALTY_RESTITUTION))
    return -log_e / jnp.sqrt(jnp.pi ** 2 + log_e ** 2)


def penalty_wrench(model: Model, params: Params, state: State, contacts, h, predicted: State):
    """Contact force (n, dim) and torque ((n, 3) or (n,)) on every body.

    Args:
        contacts: a ContactSet from :func:`jaxrb.collision.pairs.detect` on ``state``.
        h: substep length (caps friction, see the module docs).
        predicted: ``state`` after this substep's velocity update without
            contact. Friction acts on its slip, so a steady load (a box on a
            slope) is cancelled exactly instead of leaving an O(g·h) creep.
    """
    num = model.num_bodies
    pos = pad(state.pos)
    a, b = contacts.body_a, contacts.body_b
    arm_a, arm_b = contacts.point - pos[a], contacts.point - pos[b]

    def contact_velocity(source):
        return relative_velocity(model, pad(source.vel), pad(source.angvel), a, b, arm_a, arm_b)

    rel_vel = contact_velocity(state)
    normal = contacts.normal
    vn = jnp.sum(rel_vel * normal, axis=-1)
    penetration = -contacts.dist
    if model.penalty_smooth:
        width = params.penalty_width
        activation = width * jax.nn.softplus(penetration / width)
        gate = jax.nn.sigmoid(penetration / width)
    else:
        activation = jnp.maximum(penetration, 0.0)
        gate = (penetration > 0.0).astype(penetration.dtype)
    inv_mass = pad(1.0 / params.mass)
    if model.penalty_damping_from_restitution:
        reduced_mass = 1.0 / (inv_mass[a] + inv_mass[b])
        damping = (2.0 * damping_ratio_from_restitution(contacts.restitution)
                   * jnp.sqrt(params.penalty_stiffness * reduced_mass))
    else:
        damping = params.penalty_damping
    normal_force = jnp.maximum(params.penalty_stiffness * activation - damping * vn * gate, 0.0)
    normal_force = jnp.where(contacts.active, normal_force, 0.0)

    predicted_vel = contact_velocity(predicted)
    slip = predicted_vel - jnp.sum(predicted_vel * normal, axis=-1, keepdims=True) * normal
    speed = safe_norm(slip)
    inv_inertia = world_inverse_inertia(model, params, state)
    direction = safe_normalize(slip)
    tangent_mass = effective_mass(model, inv_mass[a], inv_mass[b], inv_inertia[a], inv_inertia[b],
                                  arm_a, arm_b, direction)
    sharing = jnp.maximum(contact_counts(model, contacts), 1.0)
    stop_force = tangent_mass / (h * jnp.maximum(sharing[a], jnp.where(b == num, 1.0, sharing[b])))
    coulomb = contacts.friction * normal_force / jnp.sqrt(speed ** 2 + params.friction_velocity ** 2)
    friction_force = -jnp.minimum(coulomb, stop_force)[:, None] * slip

    force = normal_force[:, None] * normal + friction_force
    total = num + 1
    body_force = jax.ops.segment_sum(force, a, total) - jax.ops.segment_sum(force, b, total)
    body_torque = (jax.ops.segment_sum(moment(model, arm_a, force), a, total)
                   - jax.ops.segment_sum(moment(model, arm_b, force), b, total))
    return body_force[:num], body_torque[:num]
