"""Penalty contact: spring-damper normal forces and Coulomb friction.

For each active contact with penetration p = −dist and normal approach speed
v_n (v_rel = n·(v_A − v_B)):

    F_n = max(k·a(p) − c·v_n·g(p), 0)

with a(p) = max(p, 0), g = [p > 0] (hard), or the smooth activation
a(p) = w·softplus(p/w), g = sigmoid(p/w) of width ``penalty_width`` w. The
damper c is ``Params.penalty_damping``, or, by default, derived per contact
from its restitution e so that the clamped spring-damper, stepped as the
engine steps it, bounces with e (:func:`damping_ratio_from_restitution`):
c = 2ζ√(k m) with m the pair's reduced mass.
Either way c is capped at m_c/h, m_c the contact's effective mass along n
(rotation included) shared among the body's contacts: a stronger explicit
damper overshoots (a box's corners have m_c ≈ m/16 and would rock for ever).

Friction (``Model.penalty_friction``) acts on the tangential slip v_t
*predicted* after this substep's other loads:

* ``"spring"`` (default), stick–slip: each contact carries a tangential spring
  whose elastic force F_e (kept in ``State.contact_impulse`` as F_e·h and
  matched by ``contact_key``) grows by −k·h·v_t per substep; the friction force
  is F_e − c·v_t clamped to the Coulomb disc |F| ≤ μF_n, and where the clamp
  bites the anchor slides so |F_e| ≤ μF_n. Under a steady load below the
  friction angle the spring takes the load and the slip vanishes (integral
  action), so a box on a slope does not creep. The spring has the normal
  stiffness k and damper c; the stick displacement before sliding is μF_n/k.
* ``"regularized"``: smooth Coulomb −μF_n·v_t / √(|v_t|² + v_reg²) with
  v_reg = ``friction_velocity``, capped at the force that stops the slip within
  one substep (the tangential effective mass over h, shared among the body's
  contacts; without the cap a small v_reg is too stiff for an explicit force).
  Smooth in every input, which suits gradients, but memoryless: under a steady
  load it creeps (7 mm/s for a box on a 0.25 rad slope at h = 1 ms).

Limits. Forces are explicit, so the default spring (0.03/h Hz on the mean body
mass) must stay slow against every body's contact modes. At h = 1 ms a 10-box
3D stack (its boxes set off sideways by up to 1 mm) and the 55-box 2D pyramid
stand (1.1 mm deepest overlap), but the column's top box rocks by millimetres,
and with a spring twice as stiff it drifted 2–24 mm in 1 s: a box rocking on
its corners is the fastest mode. At h = 0.5 ms that stiffer spring holds the
column to 0.1 mm (benchmarks/scenes.py, ``STACK_PENALTY_STEP``); a 20-box 2D
column does not settle (its long-wave modes are barely damped under the
damper cap, and the top boxes are thrown), and a 100 kg box on a 1 kg box
blows up (the spring sized on the mean mass of 50 kg is far too stiff for the
1 kg box). Use impulse contact for those.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.physics.collision.pairs import row_summer, row_taker
from jaxrb.math.components import materialize, stacked
from jaxrb.physics.contact.common import (effective_mass, moment,
                                          relative_velocity, world_inverse_inertia)
from jaxrb.math.vector import safe_div
from jaxrb.model.types import Model, Params, State


# A spring switched on and off at step boundaries gains ~0.1 % energy per bounce
# (apex 0.903 -> 0.948 m over 50 undamped bounces at h = 1 ms), so e is capped
# below 1: ζ >= 0.0032 removes ~1 % per bounce and nothing can gain energy.
MAX_PENALTY_RESTITUTION = 0.99
# Below e = 0.05 the damper would pass critical by more than 1.6× and, capped by
# the explicit step's m_c/h, made the contact so stiff that gradients blew up
# (a capsule's size gradient over 0.5 s: 3.3e6 at e = 1e-4, 2.9 at 0.05), so
# smaller e (the default 0 included) are taken as 0.05.
MIN_PENALTY_RESTITUTION = 0.05


def restitution_of_damping_ratio(zeta):
    """Coefficient of restitution of the clamped linear spring-damper, in closed form.

    The force max(k·p + c·ṗ, 0) of one contact point of mass m (ω₀² = k/m,
    ζ = c / (2√(k m))) releases the body when the damper's pull would turn
    the force negative, while it still overlaps: earlier, and faster, than
    the unclamped oscillator's half period. Solving p(t) for that instant:

    * ζ < 1: e = exp(−ζ (π − 2 arcsin ζ) / √(1 − ζ²));
    * ζ ≥ 1: e = r^((1 + r) / (1 − r)), r = (ζ − √(ζ² − 1)) / (ζ + √(ζ² − 1))

    (both e⁻² at ζ = 1). Host NumPy, float64: it builds the inverse's table.

    Args:
        zeta: (...) damping ratios ≥ 0.

    Returns:
        (...) coefficients of restitution in (0, 1].
    """
    zeta = np.asarray(zeta, dtype=np.float64)
    under = np.minimum(zeta, 1.0 - 1e-12)
    over = np.maximum(zeta, 1.0 + 1e-12)
    root = np.sqrt(over ** 2 - 1.0)
    ratio = (over - root) / (over + root)
    return np.where(zeta < 1.0,
                    np.exp(-under * (np.pi - 2.0 * np.arcsin(under)) / np.sqrt(1.0 - under ** 2)),
                    ratio ** ((1.0 + ratio) / (1.0 - ratio)))


def _semi_implicit_equivalent_ratio(zeta, omega_h):
    """ζ of the continuous oscillator that the semi-implicit step's contact map matches.

    One substep of the explicit spring-damper followed by the position update
    is the linear map (p, ṗ) → M (p, ṗ) with det M = 1 − 2ζω₀h and
    tr M = 2 − (ω₀h)² − 2ζω₀h. Its eigenvalues λ = exp(μh) give the exponents
    μ of a continuous oscillator whose ratio ζ' this returns: −Re μ/|μ| for a
    complex pair, (1 + r)/(2√r) with r = μ₁/μ₂ for a real one. The step
    damps more than its ζ says (ζ' > ζ), by 7 % at e = 0.2 and the default
    ω₀h = 0.19. Host NumPy, float64.
    """
    det = 1.0 - 2.0 * zeta * omega_h
    half_trace = (1.0 + det - omega_h ** 2) / 2.0
    root = np.sqrt((half_trace ** 2 - det).astype(complex))
    small, large = np.log(half_trace + root), np.log(half_trace - root)  # log λ₁, log λ₂
    ratio = np.clip(small.real / np.minimum(large.real, -1e-300), 1e-300, 1.0)
    return np.where(half_trace ** 2 < det, -small.real / np.abs(small), (1.0 + ratio) / (2.0 * np.sqrt(ratio)))


#: The inverse's grid: log e uniform over [MIN_, MAX_PENALTY_RESTITUTION], ω₀h from 0 to 0.6.
_LOG_E_GRID = (math.log(MIN_PENALTY_RESTITUTION), math.log(MAX_PENALTY_RESTITUTION), 256)
_OMEGA_H_GRID = (0.0, 0.6, 61)


@functools.lru_cache(maxsize=None)
def _inverse_table() -> np.ndarray:
    """(256, 61) ζ to give the step so that it bounces with e, by log e and ω₀h (bisection, float64)."""
    # ζ(e) of the continuous clamped oscillator, from a dense table of the closed form.
    zeta = np.concatenate([np.linspace(0.0, 1.0, 4097)[:-1], np.geomspace(1.0, 60.0, 2048)])
    log_e = np.log(restitution_of_damping_ratio(zeta))
    target = np.interp(np.linspace(*_LOG_E_GRID), log_e[::-1], zeta[::-1])[:, None]
    omega_h = np.maximum(np.linspace(*_OMEGA_H_GRID), 1e-9)[None, :]
    low = np.zeros(np.broadcast_shapes(target.shape, omega_h.shape))
    high = low + np.minimum((1.0 - 1e-9) / (2.0 * omega_h), 100.0)  # det M > 0: the damper cap m/h
    for _ in range(60):
        middle = (low + high) / 2.0
        short = _semi_implicit_equivalent_ratio(middle, omega_h) < target
        low, high = np.where(short, middle, low), np.where(short, high, middle)
    return (low + high) / 2.0


def damping_ratio_from_restitution(restitution, omega_h):
    """ζ that makes a contact point's bounce have coefficient e on average in the step.

    The inverse of :func:`restitution_of_damping_ratio` (the clamp lets go
    early: the unclamped oscillator's ζ = −ln e / √(π² + ln² e) made
    e = 0.6 bounce 12 % high) corrected for the semi-implicit step
    (:func:`_semi_implicit_equivalent_ratio`), interpolated bilinearly in
    (log e, ω₀h). What stays is the phase of the impact within a substep:
    a single bounce's e varies by ±3 % at e = 0.6 and ω₀h = 0.19 (±1 % at
    ω₀h = 0.05) about a mean within 1 % of e (measured on the 1-D map for
    e in {0.2, 0.6, 0.9}).

    Args:
        restitution: (C,) asked coefficients, clipped to [0.05, 0.99]
            (:data:`MIN_PENALTY_RESTITUTION`, :data:`MAX_PENALTY_RESTITUTION`).
        omega_h: (C,) ω₀h = h√(k/m) of each contact; clipped to 0.6.

    Returns:
        (C,) damping ratios ζ; the damper is c = 2ζ√(k m).
    """
    table = jnp.asarray(_inverse_table(), restitution.dtype)
    log_e = jnp.log(jnp.clip(restitution, MIN_PENALTY_RESTITUTION, MAX_PENALTY_RESTITUTION))

    def cell(value, grid):
        start, stop, count = grid
        position = jnp.clip((value - start) / ((stop - start) / (count - 1)), 0.0, count - 1.0)
        index = jnp.minimum(jnp.floor(position), count - 2.0)
        return index.astype(jnp.int32), position - index

    row, across = cell(log_e, _LOG_E_GRID)
    column, up = cell(omega_h, _OMEGA_H_GRID)
    low = table[row, column] * (1.0 - up) + table[row, column + 1] * up
    high = table[row + 1, column] * (1.0 - up) + table[row + 1, column + 1] * up
    return low * (1.0 - across) + high * across


def restitution_dampers(restitution, stiffness, mass, h):
    """The normal damper that bounces with e, and the friction spring's damper.

    The friction spring shares the normal spring's k but its damper is held
    at critical (ζ ≤ 1): an overdamped explicit tangential damper acts on a
    tangential effective mass smaller than the normal one (2m/7 for a ball)
    and overshot, so a ball rolling down a slope slipped twice the step's
    gravity when e → 0 asked ζ ≫ 1 of the normal damper.

    Args:
        restitution: (C,) coefficients; stiffness: k (N/m); mass: (C,) the
            pair's reduced mass (kg); h: substep (s).

    Returns:
        ``(normal, friction)`` dampers (C,) in N·s/m, before the m_c/h cap.
    """
    critical = 2.0 * jnp.sqrt(stiffness * mass)
    normal = critical * damping_ratio_from_restitution(restitution, h * jnp.sqrt(stiffness / mass))
    return normal, jnp.minimum(normal, critical)


def spring_activation(model: Model, params: Params, penetration):
    """The spring's a(p) and the damper's gate g(p) of each contact (see the module docs).

    Args:
        model: Model (``penalty_smooth`` picks the softplus activation).
        params: Params (``penalty_width``).
        penetration: (...) penetration depth p = −dist (m).

    Returns:
        ``(activation, gate)``, each shaped like ``penetration``.
    """
    if model.penalty_smooth:
        width = params.penalty_width
        return width * jax.nn.softplus(penetration / width), jax.nn.sigmoid(penetration / width)
    return jnp.maximum(penetration, 0.0), (penetration > 0.0).astype(penetration.dtype)


def contact_law(vectors, model: Model, params: Params, h, *, activation, gate, vn, active, contact_mass, normal,
                damping, friction_damping, friction, tangential_vel, slip, held, store=None):
    """The penalty law of each contact row (module docs): normal force, friction force, friction spring carried.

    Written once for both layouts: ``vectors`` is :mod:`jaxrb.math.components`
    (a vector is a tuple of parts, in the component step of
    :mod:`jaxrb.physics.plane_penalty`) or :class:`jaxrb.math.components.stacked` (a
    vector is a (C, dim) array, in :func:`penalty_wrench`). Below, (C)
    stands for either layout's per-row shape.

    Args:
        vectors: the vector operations of the layout.
        model: Model (``penalty_friction``).
        params: Params (``penalty_stiffness``, ``friction_velocity``).
        h: substep length (s).
        activation, gate: (C) the spring's a(p) and the damper's gate g(p)
            (:func:`spring_activation`).
        vn: (C) normal approach speed n·v_rel.
        active: (C) bool, rows within the speculative margin.
        contact_mass: function of a direction (vector) -> (C) effective
            mass along it, shared among the body's contacts.
        normal: (vector) contact normal.
        damping, friction_damping: (C) the normal and friction dampers
            before their cap m_c/h.
        friction: (C) the row's friction coefficient.
        tangential_vel: (vector) the tangential relative velocity the
            positions moved with (the spring's stretch rate).
        slip: (vector) the tangential slip predicted after this substep's
            other loads (the damper's and the regularised law's input).
        held: (vector) the elastic friction force carried from the last
            substep, in this tangent plane (zero for new rows).
        store: optional function storing its arguments (vectors) once for
            all their readers (:func:`jaxrb.math.components.materialize`).

    Returns:
        A dict: ``normal_force`` (C), ``friction_force`` and ``held``
        (vectors: the friction force applied and the elastic force to
        carry), and the intermediates the hand-written adjoint of
        :mod:`jaxrb.physics.plane_penalty_adjoint` reads.
    """
    normal_mass = contact_mass(normal)
    damping = jnp.minimum(damping, normal_mass / h)
    friction_damping = jnp.minimum(friction_damping, normal_mass / h)
    stiffness = params.penalty_stiffness
    normal_force = jnp.where(active, jnp.maximum(stiffness * activation - damping * vn * gate, 0.0), 0.0)
    out = dict(normal_mass=normal_mass, damping=damping, friction_damping=friction_damping)
    if model.penalty_friction == "spring":
        # The spring stretches with the slip the positions moved with (so it is
        # the displacement since sticking, and at rest exactly no slip), the
        # damper acts on the predicted slip (so a steady load is met at once).
        elastic = vectors.sub(held, vectors.along(stiffness * h, tangential_vel))
        damper = friction_damping * gate
        if store is not None:  # both clamps below read these
            (normal_force, damper), elastic, slip = store((normal_force, damper), elastic, slip)
        limit = friction * normal_force
        # Only rows that press carry friction. The mask changes no value (the
        # limit is 0 elsewhere) but keeps out clamp_to_disc's derivative at a
        # zero vector under a zero limit, the identity: a body at rest away
        # from the plane got a friction-spring gradient of -k·h per step
        # (d angvel'/d angvel = -42 at h = 1 ms; over 40 steps 1e200).
        pressing = normal_force > 0.0
        friction_force = vectors.where(
            pressing, vectors.clamp_to_disc(vectors.sub(elastic, vectors.along(damper, slip)), limit))
        held = vectors.where(pressing, vectors.clamp_to_disc(elastic, limit))
        out.update(damper=damper, elastic=elastic, pressing=pressing)
    else:
        limit = friction * normal_force
        length = vectors.safe_length(slip)
        stop_force = contact_mass(vectors.along(safe_div(1.0, length), slip)) / h
        coulomb = limit / jnp.sqrt(length ** 2 + params.friction_velocity ** 2)
        friction_force = held = vectors.along(-jnp.minimum(coulomb, stop_force), slip)
    out.update(normal_force=normal_force, friction_force=friction_force, held=held, slip=slip, limit=limit)
    return out


def penalty_wrench(model: Model, params: Params, state: State, contacts, h, predicted: State,
                   held_friction):
    """Contact force and torque on every body, and each contact's friction spring force.

    Args:
        contacts: a ContactSet from :func:`jaxrb.physics.collision.pairs.detect` on ``state``.
        h: substep length (s).
        predicted: ``state`` after this substep's velocity update without
            contact; friction acts on its slip (see the module docs).
        held_friction: (C, dim) elastic friction force each contact carried
            from the last substep, in its tangent plane (zero for new
            contacts); unused by the ``"regularized"`` friction model.

    Returns:
        ``(force, torque, normal_force, held_friction)``: force (n, dim) and
        torque ((n, 3) or (n,)) on every body, the normal force (C,) and the
        elastic friction force (C, dim) to carry to the next substep.
    """
    a, b = contacts.body_a, contacts.body_b
    # Unpadded per-body arrays: ``take`` reads the static row (planes) as zeros.
    take, add = row_taker(model, a, b), row_summer(model, a, b)
    arm_a, arm_b = contacts.point - take(state.pos, 0), contacts.point - take(state.pos, 1)

    def contact_velocity(source):
        return relative_velocity(model, source.vel, source.angvel, a, b, arm_a, arm_b, take)

    def tangential(vector):
        return vector - jnp.sum(vector * normal, axis=-1, keepdims=True) * normal

    rel_vel = contact_velocity(state)
    normal = contacts.normal
    vn = jnp.sum(rel_vel * normal, axis=-1)
    activation, gate = spring_activation(model, params, -contacts.dist)
    inv_mass = 1.0 / params.mass
    inv_inertia = world_inverse_inertia(model, params, state, padded=False)
    active = contacts.active.astype(contacts.dist.dtype)
    sharing = jnp.maximum(add(active, 0) + add(active, 1), 1.0)  # contacts touching each body
    sharing = jnp.maximum(take(sharing, 0), take(sharing, 1))  # the static row reads 0

    def contact_mass(direction):
        """Effective mass along ``direction`` (C, dim), shared among the body's contacts."""
        return effective_mass(model, take(inv_mass, 0), take(inv_mass, 1), take(inv_inertia, 0),
                              take(inv_inertia, 1),
                              arm_a, arm_b, direction) / sharing

    if model.penalty_damping_from_restitution:
        reduced_mass = 1.0 / (take(inv_mass, 0) + take(inv_mass, 1))
        damping, friction_damping = restitution_dampers(contacts.restitution, params.penalty_stiffness,
                                                        reduced_mass, h)
    else:
        damping = friction_damping = params.penalty_damping
    law = contact_law(stacked, model, params, h, activation=activation, gate=gate, vn=vn, active=contacts.active,
                      contact_mass=contact_mass, normal=normal, damping=damping,
                      friction_damping=friction_damping, friction=contacts.friction,
                      tangential_vel=tangential(rel_vel), slip=tangential(contact_velocity(predicted)),
                      held=held_friction)
    normal_force, friction_force, held_friction = law["normal_force"], law["friction_force"], law["held"]
    force = normal_force[:, None] * normal + friction_force
    # Stored once: each of the four per-body sums below would otherwise
    # re-derive the whole contact law (XLA fuses a producer into every consumer).
    force, normal_force, held_friction = materialize((force, normal_force, held_friction), params)
    body_force = add(force, 0) - add(force, 1)
    body_torque = add(moment(model, arm_a, force), 0) - add(moment(model, arm_b, force), 1)
    return body_force, body_torque, normal_force, held_friction

