"""Velocity-level impulse contact: a soft-step sequential-impulse solver.

Each step (following the "soft step" of Box2D v3 and Catto's Solver2D notes):

1. collision once, at the start of the step; contact arms, normal and tangent
   directions and effective masses are fixed for the step;
2. per substep: integrate velocities (gravity, loads), warm start with the
   accumulated impulses, ``iterations`` passes with a *soft* position bias,
   integrate positions, then ``relax_iterations`` passes without bias. The
   bias that pushed overlaps apart is removed by the relax passes, so position
   correction does not inject kinetic energy (unlike Baumgarte on velocity);
3. restitution: contacts that approached faster than ``bounce_threshold`` get
   −e times their approach speed, after the relax;
4. the accumulated impulses go into ``State.contact_impulse`` for the next
   step's warm start (matched by ``contact_key``).

The soft constraint is a spring-damper of ``contact_hertz`` (capped at a
quarter of the substep rate) and ``contact_damping_ratio``, written as mass
and impulse scales so it stays stable at any stiffness. Speculative contacts
(positive separation s) only stop the approach beyond s/h, which is what keeps
a 10 m/s body from tunnelling through a plane at h = 1/60 s.

Stiffness and stacks. Per contact point the soft constraint is a spring
k = m_eff ω² on the point's effective mass, so a pair carrying a load F sinks
by F/(Σ m_eff ω²) and resists tilting with k·Σx² (x: the points' lever arms).
A column of n boxes of height L on such springs buckles when that rotational
stiffness is below about m·g·L·n³/12, whatever the solver does. Measured with
0.2 m boxes at dt = 1/60 s: a 10-box 3D stack creeps and falls at 30 Hz and
stands at 60 Hz; a 20-box 2D stack falls at 90 Hz and stands at 120 Hz; a
100 kg box sinks 7 mm into a 1 kg box at 60 Hz, 1.8 mm at 120 Hz. Stiffer than
a quarter of the substep rate the few Gauss–Seidel passes no longer converge
(the 20-box stack falls at 150 Hz with 4 substeps; it stands with 12
iterations), and leaving the steady sink out (no impulse leak, or a stiffness
scaled by the load) made stacks jitter and fall too. So stiffness comes from
substeps: ``scene.build``'s default hertz is that cap, 0.25·substeps/dt.

Coulomb friction uses the circular cone: the accumulated friction impulse
vector is clamped to μ·λ_n (two tangent directions in 3D, one in 2D).

Iteration schemes (``Model.solver``):

* ``sequential``: Gauss–Seidel over contacts, each impulse applied at once;
* ``jacobi``: all contacts at once from the same velocities, with each body's
  mass split among its k contacts (inverse mass and inertia times k, Tonge et
  al. 2012), each contact solving its normal then friction rows on its own
  sub-bodies, then the impulses summed: order-independent and vmap-friendly.
  Impulses are applied to the whole body with its true mass (Tonge's averaging
  step); applying them with the split mass, as an earlier version did, overshot
  k-fold and left a box that slid to a stop rocking at 0.2 rad/s. Known
  limitation: each contact's soft spring acts on a split (k times lighter)
  effective mass, so stacks sink about k times deeper than with
  ``sequential``. Measured on the 10-box 3D stack at dt = 1/60 s: 13.6 mm at
  the bottom joint with 4 substeps, 3.4 mm with 8 (tested: it stands 10 s);
  the 2D 55-box pyramid with 8 substeps 6.1 mm; the 20-box 2D column still
  22 mm with 16. Scaling the impulse leak or the stiffness back by k made
  stacks bounce. ``sequential`` is the default.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb import quaternion as quat_ops
from jaxrb._struct import pytree_dataclass
from jaxrb.collision.pairs import plane_rows, round_sides, row_summer, row_taker
from jaxrb.contact.common import (apply_inverse_inertia, clamp_to_disc,
                                  moment, pad, tangent_basis,
                                  world_inverse_inertia)
from jaxrb.math import rotate2
from jaxrb.types import Array, Model, Params, State


@pytree_dataclass
class Prepared:
    """Per-step contact constraint data (C rows).

    Attributes:
        body_a, body_b: (C,) body rows (n is the static row).
        normal: (C, dim); tangents: tuple of (C, dim) unit tangents (2 in 3D, 1 in 2D).
        anchor_a, anchor_b: (C, dim) body-frame point that carries each side's
            contact: the contact point itself, or, for a sphere or circle, its
            centre (rotating a ball leaves its surface in place, so a rolling
            ball's contact must not turn with it and seem to lift off).
        start_a, start_b: (C, dim) the anchors' world positions at the step start.
        separation: (C,) separation at the step start.
        normal_mass: (C,); tangent_mass: tuple of (C,).
        friction, restitution: (C,).
        approach: (C,) v_rel after the current substep's velocity phase (negative
            when approaching); the restitution pass bounces against it.
        active: (C,) bool.
        smoothing: (C,) width m_n·σ (impulse units) of the smooth normal clamp
            (``Params.impulse_smoothing``; 0: the exact clamp).
        inv_mass: (n + 1,) padded inverse masses (true ones: impulses are
            applied to the whole body).
        maps: the :class:`RowMaps` of every row: how it reads and moves its
            bodies. Under ``jacobi`` each body's mass is split among the k
            contacts touching it (each contact sees k·m⁻¹ and k·I⁻¹), which the
            effective masses and the maps' couplings include.
    """

    body_a: Array
    body_b: Array
    normal: Array
    tangents: tuple
    anchor_a: Array
    anchor_b: Array
    start_a: Array
    start_b: Array
    separation: Array
    normal_mass: Array
    tangent_mass: tuple
    friction: Array
    restitution: Array
    approach: Array
    active: Array
    smoothing: Array
    inv_mass: Array
    maps: "RowMaps"


@pytree_dataclass
class RowMaps:
    """How each row's relative velocity reads and moves its two bodies, fixed for the step.

    Along a row direction d (index k: the normal, then the tangents) the
    relative velocity is d·(v_a − v_b) + turn_a[k]·ω_a − turn_b[k]·ω_b, and an
    impulse p along d changes v_a by p·m_a⁻¹·d, ω_a by p·spin_a[k], and B's
    velocities by minus the same with B's maps. Computing r × d and I⁻¹(r × d)
    once per step (as Box2D does) lets a solver row touch only its own two
    bodies, with no 3×3 products and no scatter over all bodies.

    Attributes:
        turn_a, turn_b: tuple (one per direction) of (C, 3) r × d, (C,) in 2D.
        spin_a, spin_b: tuple of (C, 3) I⁻¹(r × d) with the true world inverse
            inertia, (C,) in 2D.
        inv_mass_a, inv_mass_b: (C,) true inverse masses of each row's bodies.
        coupling: (C,) change of the second tangent's speed per unit impulse
            along the first (t₂·K·t₁, K the row's inverse mass matrix of the
            split sub-bodies: the true one unless ``jacobi``); 0 in 2D.
        normal_coupling: under ``jacobi``, a tuple (one per tangent) of (C,)
            changes of the tangent's speed per unit normal impulse (t·K·n);
            else None. (With the true masses the sequential rows re-read their
            bodies' speeds instead.)
    """

    turn_a: tuple
    turn_b: tuple
    spin_a: tuple
    spin_b: tuple
    inv_mass_a: Array
    inv_mass_b: Array
    coupling: Array
    normal_coupling: tuple = None


def _row_maps(model, take, arm_a, arm_b, directions, inv_mass, inv_inertia, split_a, split_b) -> RowMaps:
    """:class:`RowMaps` of rows with arms (C, dim) and unit ``directions``.

    ``take(array, side)`` reads the rows' bodies from the (n, ...) per-body
    ``inv_mass`` and world ``inv_inertia`` (:func:`jaxrb.collision.pairs.row_taker`);
    ``split_a``, ``split_b`` (C,) are the mass-splitting factors of each row's bodies.
    """
    turn = lambda arm: tuple(moment(model, arm, d) for d in directions)
    spin = lambda row_inertia, turns: tuple(apply_inverse_inertia(model, row_inertia, t) for t in turns)
    turn_a, turn_b = turn(arm_a), turn(arm_b)
    spin_a, spin_b = spin(take(inv_inertia, 0), turn_a), spin(take(inv_inertia, 1), turn_b)
    inv_mass_a, inv_mass_b = take(inv_mass, 0), take(inv_mass, 1)
    # Directions are orthogonal, so between two of them only the angular parts couple.
    couple = lambda k, j: (split_a * _dot(model, turn_a[k], spin_a[j])
                           + split_b * _dot(model, turn_b[k], spin_b[j]))
    coupling = couple(2, 1) if model.dim == 3 else jnp.zeros_like(inv_mass_a)
    normal_coupling = (tuple(couple(k, 0) for k in range(1, len(directions))) if model.solver == "jacobi"
                       else None)
    return RowMaps(turn_a=turn_a, turn_b=turn_b, spin_a=spin_a, spin_b=spin_b,
                   inv_mass_a=inv_mass_a, inv_mass_b=inv_mass_b, coupling=coupling,
                   normal_coupling=normal_coupling)


def _dot(model, x, y):
    """Row-wise x·y of (C, 3) vectors, or the product of (C,) 2D angular scalars."""
    return jnp.sum(x * y, axis=-1) if model.dim == 3 else x * y


def _effective_mass(model, maps: RowMaps, k, split_a, split_b):
    """1 / (k_a(m_a⁻¹ + (r_a × d)·I_a⁻¹(r_a × d)) + k_b(...)) along row direction k, from the row maps.

    split_a, split_b: (C,) mass-splitting factors of each row's bodies (1 unless ``jacobi``).
    """
    side_a = maps.inv_mass_a + _dot(model, maps.turn_a[k], maps.spin_a[k])
    side_b = maps.inv_mass_b + _dot(model, maps.turn_b[k], maps.spin_b[k])
    return 1.0 / (split_a * side_a + split_b * side_b)


def _row_rotations(model, state, take):
    """Each row's A-side and B-side orientation (the static body's is the identity).

    Returns:
        Two (C, 4) quaternions in 3D, two (C,) angles in 2D.
    """
    if model.dim == 3:
        identity = jnp.asarray([1.0, 0.0, 0.0, 0.0], state.quat.dtype)
        return take(state.quat, 0, identity), take(state.quat, 1, identity)
    return take(state.angle, 0), take(state.angle, 1)


def _to_world(model, rotation, vector):
    if model.dim == 3:
        return quat_ops.rotate(rotation, vector)
    return rotate2(rotation, vector)


def _to_body(model, rotation, vector):
    if model.dim == 3:
        return quat_ops.rotate_inverse(rotation, vector)
    return rotate2(-rotation, vector)


def _contact_counts(model, contacts):
    """(n + 1,) number of active contacts touching each body (mass splitting); 0 for the static row.

    Summed with the pair table's static slices where it fixes the bodies: a
    scatter in the solver's loops keeps XLA's CPU backend from compiling them
    as one function (docs/design.md, 'Loops compiled whole').
    """
    active = contacts.active.astype(contacts.dist.dtype)
    add = row_summer(model, contacts.body_a, contacts.body_b)
    return pad(add(active, 0) + add(active, 1))


def prepare(model: Model, params: Params, state: State, contacts) -> Prepared:
    """Fix arms, directions and effective masses for the step."""
    # Rows read body values with static slices where the pair table fixes them:
    # a gather's reverse-mode transpose is a scatter, and a loop holding a
    # scatter is not compiled as one function (docs/design.md, 'Loops compiled whole').
    take = row_taker(model, contacts.body_a, contacts.body_b)
    pos_a, pos_b = take(state.pos, 0), take(state.pos, 1)
    arm_a, arm_b = contacts.point - pos_a, contacts.point - pos_b
    inv_mass = 1.0 / params.mass
    inv_inertia = world_inverse_inertia(model, params, state, padded=False)
    split = (jnp.maximum(_contact_counts(model, contacts), 1.0) if model.solver == "jacobi"
             else jnp.ones(inv_mass.shape[0] + 1, inv_mass.dtype))
    normal = contacts.normal
    tangents = tangent_basis(normal) if model.dim == 3 else (jnp.stack([-normal[:, 1], normal[:, 0]], -1),)
    split_a, split_b = take(split, 0), take(split, 1)
    maps = _row_maps(model, take, arm_a, arm_b, (normal,) + tangents, inv_mass, inv_inertia, split_a, split_b)
    masses = [_effective_mass(model, maps, k, split_a, split_b) for k in range(1 + len(tangents))]
    rotation_a, rotation_b = _row_rotations(model, state, take)
    normal_mass = masses[0]
    round_a, round_b = (jnp.asarray(side)[:, None] for side in round_sides(model))
    centre = -params.com_offset  # shape centre from the centre of mass, body frame
    anchor_a = jnp.where(round_a, take(centre, 0), _to_body(model, rotation_a, arm_a))
    anchor_b = jnp.where(round_b, take(centre, 1), _to_body(model, rotation_b, arm_b))
    return Prepared(
        body_a=contacts.body_a, body_b=contacts.body_b, normal=normal, tangents=tangents,
        anchor_a=anchor_a, anchor_b=anchor_b,
        start_a=pos_a + _to_world(model, rotation_a, anchor_a),
        start_b=pos_b + _to_world(model, rotation_b, anchor_b),
        separation=contacts.dist, normal_mass=normal_mass,
        tangent_mass=tuple(masses[1:]),
        friction=contacts.friction, restitution=contacts.restitution,
        approach=contacts.normal_velocity, active=contacts.active,
        smoothing=normal_mass * params.impulse_smoothing,
        inv_mass=pad(inv_mass), maps=maps)


def current_separation(model: Model, prep: Prepared, state: State):
    """Separation now, from the bodies' motion since the step start (no new collision)."""
    take = row_taker(model, prep.body_a, prep.body_b)
    rotation_a, rotation_b = _row_rotations(model, state, take)
    moved_a = take(state.pos, 0) + _to_world(model, rotation_a, prep.anchor_a) - prep.start_a
    moved_b = take(state.pos, 1) + _to_world(model, rotation_b, prep.anchor_b) - prep.start_b
    return prep.separation + jnp.sum(prep.normal * (moved_a - moved_b), axis=-1)


# Every contact's rows at once (the Jacobi passes, the warm start, the
# approach speeds) read and move the bodies through the RowMaps, as the
# sequential rows do, not through the arms and the 3x3 inverse inertias: the
# arms' cotangent, summed in reverse over every pass, was half the Jacobi
# gradient's time (docs/design.md, 'Loops compiled whole').

def _directions(prep: Prepared) -> tuple:
    """The rows' unit directions: (normal, *tangents), each (C, dim)."""
    return (prep.normal,) + tuple(prep.tangents)


def row_speeds(model: Model, prep: Prepared, vel, angvel, count=None) -> list:
    """Relative speed of every contact along its first ``count`` directions (default all).

    Args:
        vel, angvel: (n, ...) or padded (n + 1, ...) body velocities; the pair
            table's slices never read the padded row.

    Returns:
        A list of (C,) speeds d·(v_A − v_B) + (r_A × d)·ω_A − (r_B × d)·ω_B:
        the normal's first, then the tangents'.
    """
    take = row_taker(model, prep.body_a, prep.body_b)
    linear = take(vel, 0) - take(vel, 1)
    spin_a, spin_b = take(angvel, 0), take(angvel, 1)
    maps = prep.maps
    return [jnp.sum(direction * linear, axis=-1) + _dot(model, turn_a, spin_a) - _dot(model, turn_b, spin_b)
            for direction, turn_a, turn_b in zip(_directions(prep)[:count], maps.turn_a, maps.turn_b)]


def normal_velocity(model: Model, prep: Prepared, state: State):
    """v_rel = n·(v_A − v_B) at every contact for the velocities of ``state``. Returns (C,)."""
    return row_speeds(model, prep, state.vel, state.angvel, count=1)[0]


def push_rows(model: Model, prep: Prepared, vel, angvel, impulses):
    """Apply impulses along every contact's directions to the whole bodies: +P on A, −P on B.

    Args:
        vel, angvel: padded (n + 1, ...) body velocities.
        impulses: a list of (C,) impulses along the first len(impulses)
            directions (normal, then tangents).

    Returns:
        (vel, angvel), padded.
    """
    add = row_summer(model, prep.body_a, prep.body_b)  # static slices where the pair table fixes the bodies
    along = lambda vectors: sum(_scale(p, v) for p, v in zip(impulses, vectors))
    linear = along(_directions(prep))
    maps = prep.maps
    angular = add(along(maps.spin_a), 0) - add(along(maps.spin_b), 1)
    return vel + prep.inv_mass[:, None] * pad(add(linear, 0) - add(linear, 1)), angvel + pad(angular)


def _scale(impulse, vector):
    """(C,) impulses times (C, dim) vectors, or times (C,) 2D angular scalars."""
    return impulse[:, None] * vector if vector.ndim == 2 else impulse * vector


# Within a step the solvers carry each row's accumulated impulses along its
# own directions, a tuple (normal, *tangent components) of (C,) arrays, and
# convert from and to State.contact_impulse's world frame once a step. Sliced
# out of and concatenated into one (C, 1 + dim) array in every pass, their
# cotangent was built in reverse by a fusion of pads whose every column
# evaluated every column's terms; batched, it was the passes' largest kernel
# (docs/design.md, 'Loops compiled whole').

def row_impulses(prep: Prepared, world) -> tuple:
    """(C, 1 + dim) impulses (normal, world friction vector) as (normal, *tangent components), each (C,)."""
    friction = world[:, 1:]
    return (world[:, 0],) + tuple(jnp.sum(friction * tangent, axis=-1) for tangent in prep.tangents)


def world_impulses(prep: Prepared, impulses) -> Array:
    """:func:`row_impulses`' inverse: (C, 1 + dim), the normal impulse then the world friction vector."""
    friction = sum(f[:, None] * tangent for f, tangent in zip(impulses[1:], prep.tangents))
    return jnp.concatenate([impulses[0][:, None], friction], axis=-1)


def _normal_impulse(vn, old, separation, normal_mass, smoothing, active, h, soft):
    """New accumulated normal impulse of rows with normal speed ``vn`` (any shape, all alike).

    ``soft`` is None for the relax passes (rigid, no position bias), else the
    soft-constraint coefficients of :func:`soft_parameters`.
    """
    if soft is None:
        bias, mass_scale, impulse_scale = jnp.zeros_like(vn), 1.0, 0.0
    else:
        bias_rate, mass_scale, impulse_scale, max_push = soft
        bias = jnp.maximum(bias_rate * separation, -max_push)
    # A speculative contact (still apart) only forbids closing more than the gap.
    speculative = separation > 0.0
    bias = jnp.where(speculative, separation / h, bias)
    mass_scale = jnp.where(speculative, 1.0, mass_scale)
    impulse_scale = jnp.where(speculative, 0.0, impulse_scale)
    delta = -normal_mass * mass_scale * (vn + bias) - impulse_scale * old
    return jnp.where(active, smooth_clamp(old + delta, smoothing), 0.0)


def smooth_clamp(impulse, width):
    """max(impulse, 0), or the smooth ½(λ + √(λ² + w²)) where ``width`` w > 0.

    The smooth form is positive everywhere, so a contact that is closing but
    not yet touching already pushes a little (and bounces, see
    :func:`restitution_pass`): that is the bias the ``impulse_smoothing`` knob
    trades for gradients that do not switch. It smooths the contact's onset
    only: friction still sticks sharply and impacts still wait for the
    substep's end (``time_of_impact`` fixes that for the kinds it covers).
    """
    smooth = width > 0.0
    root = jnp.sqrt(jnp.where(smooth, impulse ** 2 + width ** 2, 1.0))
    # For λ < 0 the same value written as w²/(2(√(λ² + w²) − λ)): no cancellation.
    negative = impulse < 0.0
    tail = 0.5 * width ** 2 / jnp.where(negative & smooth, root - impulse, 1.0)
    return jnp.where(smooth, jnp.where(negative, tail, 0.5 * (impulse + root)), jnp.maximum(impulse, 0.0))


def solve_pass(model: Model, prep: Prepared, vel, angvel, impulses, separation, h, soft):
    """One iteration over all contacts; returns (vel, angvel, impulses) with padded bodies.

    impulses: the rows' accumulated impulses (:func:`row_impulses`), a tuple
    (normal, *tangent components) of (C,) arrays.
    The sequential solver takes each contact's normal then its friction.
    (Sweeping all normals before all friction made a 10-box stack creep more.)
    """
    if model.solver == "jacobi":
        # Each contact solves its normal and friction rows in turn on its own
        # split sub-bodies (a block), so splitting mass by contact count is enough.
        # Batched, each value below has its cotangent computed once (_cotangent_once).
        once = lambda values: _cotangent_once(values, h, prep.normal_mass)
        speeds = once(row_speeds(model, prep, vel, angvel))
        old_normal, old_friction = impulses[0], impulses[1:]
        normal = once(_normal_impulse(speeds[0], old_normal, separation, prep.normal_mass, prep.smoothing,
                                      prep.active, h, soft))
        pushed = normal - old_normal
        # The tangents' speeds on the sub-bodies after the normal impulse.
        speeds = once([speed + pushed * c for speed, c in zip(speeds[1:], prep.maps.normal_coupling)])
        friction = once(_friction_impulses(model, prep, speeds, old_friction, normal))
        vel, angvel = push_rows(model, prep, vel, angvel,
                                once([pushed] + [f - old for f, old in zip(friction, old_friction)]))
        return vel, angvel, (normal, *friction)

    def one_contact(row, bodies, old, separation, h_soft):
        h, soft = h_soft
        normal = _normal_impulse(_row_speed(row, 0, bodies), old[0], separation,
                                 row.normal_mass, row.smoothing, row.active, h, soft)
        bodies = _row_push(row, 0, bodies, normal - old[0])
        bodies, friction = _row_friction(model, row, bodies, old[1:], normal)
        return bodies, (normal, *friction)

    (vel, angvel), impulses = _sweep_rows(model, prep, one_contact, (vel, angvel), impulses, separation, (h, soft))
    return vel, angvel, impulses


# Why a cotangent computed once: under vmap, XLA's CPU backend fuses the
# cotangent of a value a Jacobi pass reads in several places (the rows'
# speeds, the new normal impulses and friction, the impulse changes) into each
# fusion that reads it, and 22 fusions of the passes' reverse each re-derived
# the same transposes (36 operations of the friction clamp's, up to 31 of the
# normal's). A conditional is a fusion boundary XLA keeps (as
# :func:`jaxrb.components.materialize` uses in the forward); on those values'
# tangents it makes their cotangents computed once, and the bouncing box's
# gradient over 1 024 worlds went from 13.3–13.5× to 10.2–10.6× its forward.
# At one world the same boundary cost more than it saved (1.05×), so it is put
# in only under vmap: unbatched, its predicate is the constant True, and XLA
# removes the conditional, leaving the one-world program as it was
# (docs/design.md, 'Reverse mode').

@jax.custom_batching.custom_vmap
def _in_batch(h, probe):
    """True, a constant XLA folds; under vmap ``h > 0``, a value it cannot fold (Scene.build validates dt)."""
    return jnp.ones((), bool)


@_in_batch.def_vmap
def _in_batch_rule(axis_size, in_batched, h, probe):
    return h > 0.0, in_batched[0]


@jax.custom_jvp
def _cotangent_once(values, h, probe):
    """``values`` (a pytree of arrays) unchanged, with its cotangent computed once under vmap.

    Args:
        h: the substep, a scalar (> 0).
        probe: an array that is batched with the worlds and constant over the
            passes (``prep.normal_mass``). Derived from a value that changes
            from pass to pass, the predicate would be a residual that reverse
            mode stores per pass, and the conditional would stay at one world.
    """
    return values


@_cotangent_once.defjvp
def _cotangent_once_jvp(primals, tangents):
    values, h, probe = primals
    # No derivative reaches _in_batch (a custom_vmap function has none in
    # reverse mode), so a gradient of this gradient can be taken.
    batched = _in_batch(jax.lax.stop_gradient(h), jax.lax.stop_gradient(probe))
    zeros = lambda tangent: jax.tree_util.tree_map(jnp.zeros_like, tangent)
    return values, jax.lax.cond(batched, lambda tangent: tangent, zeros, tangents[0])


# One sequential row at a time. The row index comes from an unbatched arange
# and the rows' bodies from the static pair table, so under vmap every read and
# write below is a dynamic slice of the batched arrays, not a gather/scatter
# (a culled pair table makes the bodies data, and then they are gathers).

def _take(array, index):
    """array[index] along the first axis as a dynamic slice."""
    return jax.lax.dynamic_index_in_dim(array, index, keepdims=False)


def _row(prep: Prepared, index) -> Prepared:
    """Row ``index`` of every per-row field of ``prep`` (the per-body fields left out)."""
    per_row = prep.replace(inv_mass=None)
    return jax.tree_util.tree_map(lambda field: _take(field, index), per_row)


def _read_bodies(arrays, a, b):
    """Bodies a and b of each padded per-body array: (v_a, ω_a, v_b, ω_b) for (vel, angvel).

    ``b`` None (a row against a plane) gives None for B's values: a row
    then reads, moves and differentiates body A alone.
    """
    return (tuple(_take(array, a) for array in arrays)
            + tuple(None if b is None else _take(array, b) for array in arrays))


def _write_bodies(arrays, a, b, bodies):
    """Put :func:`_read_bodies`' values back (the two bodies of a row are never the same)."""
    put = lambda array, value, body: array if body is None else jax.lax.dynamic_update_index_in_dim(
        array, value, body, 0)
    return tuple(put(put(array, at_a, a), at_b, b)
                 for array, at_a, at_b in zip(arrays, bodies[:len(arrays)], bodies[len(arrays):]))


def _row_speed(row, k, bodies):
    """Relative velocity of a row along its direction k (0: normal, then the tangents)."""
    va, wa, vb, wb = bodies
    direction = (row.normal,) + tuple(row.tangents)
    maps = row.maps
    if vb is None:  # against a plane
        return jnp.sum(direction[k] * va) + jnp.sum(maps.turn_a[k] * wa)
    return jnp.sum(direction[k] * (va - vb)) + jnp.sum(maps.turn_a[k] * wa) - jnp.sum(maps.turn_b[k] * wb)


def _row_push(row, k, bodies, impulse):
    """The row's bodies after an impulse (scalar) along its direction k: +A, −B (B None: a plane)."""
    va, wa, vb, wb = bodies
    direction = ((row.normal,) + tuple(row.tangents))[k]
    maps = row.maps
    va, wa = va + impulse * maps.inv_mass_a * direction, wa + impulse * maps.spin_a[k]
    if vb is None:
        return va, wa, vb, wb
    return va, wa, vb - impulse * maps.inv_mass_b * direction, wb - impulse * maps.spin_b[k]


def _row_friction(model, row, bodies, old_friction, normal):
    """A row's friction after its normal impulse ``normal`` (scalar), and its bodies after the change.

    Solved in the row's tangent coordinates: the second tangent sees the
    first one's update through the coupling (a small block Gauss–Seidel),
    then the pair is clamped to the cone μ·normal.

    Args:
        row: one row of :class:`Prepared` (:func:`_row`); bodies: (v_a, ω_a, v_b, ω_b).
        old_friction: the accumulated friction along each tangent (a sequence of scalars).

    Returns:
        (bodies, friction): friction a list of scalars, one per tangent.
    """
    speeds = [_row_speed(row, 1 + k, bodies) for k in range(len(row.tangents))]
    friction = _friction_impulses(model, row, speeds, old_friction, normal)
    for k in range(len(row.tangents)):
        bodies = _row_push(row, 1 + k, bodies, friction[k] - old_friction[k])
    return bodies, friction


def _friction_impulses(model, prep, speeds, old_friction, normal) -> list:
    """New accumulated friction along each tangent, clamped to the cone μ·normal.

    Solved in tangent coordinates: the second tangent sees the first one's
    update through ``prep.maps.coupling`` (a small block Gauss–Seidel), then the
    pair is clamped to the disc. Works on one row (scalars, the sequential
    solver) or on all rows at once ((C,) arrays, Jacobi) alike.

    Args:
        prep: :class:`Prepared` or one row of it (:func:`_row`).
        speeds, old_friction: lists (one per tangent) of the tangent speeds
            and the accumulated friction before this update.
        normal: the rows' new normal impulses.

    Returns:
        A list (one per tangent) of friction impulses, 0 where inactive.
    """
    friction = [old_friction[0] - prep.tangent_mass[0] * speeds[0]]
    if model.dim == 3:
        speed = speeds[1] + prep.maps.coupling * (friction[0] - old_friction[0])
        friction.append(old_friction[1] - prep.tangent_mass[1] * speed)
    clamped = clamp_to_disc(jnp.stack(friction, axis=-1), prep.friction * normal)
    clamped = jnp.where(prep.active[..., None], clamped, 0.0)
    return [clamped[..., k] for k in range(len(friction))]


def _sweep_rows(model: Model, prep: Prepared, update, arrays, lam, per_row=None, extra=(), rows=None):
    """Run ``update(row, bodies, lam_row, per_row_values, extra) -> (bodies, lam_row)`` on rows in order.

    Args:
        arrays: tuple of padded per-body arrays the rows read and write,
            (vel, angvel) for the solver; ``bodies`` holds the row's two
            bodies' values (:func:`_read_bodies`), and ``update`` returns them
            changed.
        lam: a pytree of (R,) per-row values handed in one row at a time and
            returned updated (the accumulated impulses), or None.
        per_row: a pytree of (C, ...) arrays ``update`` reads one row of
            (``per_row_values``), or None.
        extra: any other arrays ``update`` reads (a pytree, passed whole).
        rows: (R,) static row indices to sweep, default every row in order;
            of these, the rows ``prep.active`` marks are solved and the
            others skipped.

    Returns:
        (arrays, lam) after the sweep.

    ``update`` must close over no traced values: everything it differentiates
    comes in as an argument, because :func:`_guarded_row` gives it a custom JVP.

    The rows are a scan whose carry is the per-body arrays only: each row's
    impulses come in and go out as the scan's slices, so an inactive row can
    be skipped by a branch over the bodies and its own impulses. Unbatched, an
    inactive row then costs the branch and its slices (a 10-box stack has 440
    rows, 40 of them active at rest). Under vmap a row active in no world is
    still skipped, and one active in some world is a select of the per-body
    arrays, O(n) per row, where a branch that also carried the (C, 1 + dim)
    impulses made each row O(C).

    Rows against a plane read and move body A alone (``bodies``' B values
    are None): the static row's velocity is zero and stays so, and carrying
    it, its maps and their cotangents through every row cost the bouncing
    box's forward a fifth of its time and its gradient about a third
    (docs/design.md, 'Loops compiled whole'). The rows are swept in their order, in
    one scan per run of rows that do or do not have a plane.
    """
    def solve_row(against_plane, index, arrays, old, prep, per_row, extra):
        row = _row(prep, index)
        body_b = None if against_plane else row.body_b
        bodies = _read_bodies(arrays, row.body_a, body_b)
        row_values = jax.tree_util.tree_map(lambda field: _take(field, index), per_row)
        bodies, new = update(row, bodies, old, row_values, extra)
        return _write_bodies(arrays, row.body_a, body_b, bodies), new

    # Reverse mode keeps each row's input bodies and recomputes the row, not
    # a stack per intermediate of every row: the sequential bouncing box's
    # gradient compiled in 21 s instead of 33 s and ran in 0.87-1.02x the
    # time, where rematerialising whole passes took 1.16-1.23x
    # (docs/design.md, 'Reverse mode').
    def body(against_plane):
        @partial(jax.checkpoint, prevent_cse=False)
        def one_row(arrays, row_slice):
            index, old, row_active = row_slice
            return _guarded_row(partial(solve_row, against_plane), row_active,
                                (index, arrays, old, prep, per_row, extra))
        return one_row

    if rows is None:
        indices, active = np.arange(prep.normal.shape[0]), prep.active
    else:
        indices, active = np.asarray(rows), prep.active[rows]
    against_plane = plane_rows(model)[indices]
    cuts = [0, *(np.flatnonzero(np.diff(against_plane)) + 1), len(indices)]
    whole = len(cuts) == 2  # one run: the per-row values go in unsliced
    part = lambda values, start, stop: values if whole else jax.tree_util.tree_map(lambda v: v[start:stop], values)
    arrays, swept = tuple(arrays), []
    for start, stop in zip(cuts[:-1], cuts[1:]):
        arrays, new = jax.lax.scan(body(bool(against_plane[start])), arrays,
                                   (jnp.asarray(indices[start:stop]), *part((lam, active), start, stop)))
        swept.append(new)
    return arrays, swept[0] if whole else jax.tree_util.tree_map(lambda *parts: jnp.concatenate(parts), *swept)


# Why a custom JVP: the branch that skips an inactive row is what makes the
# forward solver cheap (a 10-box stack runs 40 of its 440 rows at rest), but
# reverse mode through lax.cond keeps both branches' residuals and transposes
# a cond per row. The derivative program selects instead: every row is solved
# and an inactive one's result dropped. Values and derivatives are the same
# (an inactive row's update is discarded either way). The one-box bounce's
# 1 000-step gradient ran about 9 % faster and compiled about 20 % sooner,
# while the forward program keeps its cond (docs/design.md, 'Loops compiled whole').
#
# Why a custom vmap as well: under vmap a cond on a batched predicate becomes
# a select, and JAX first batches every operand of the cond, the row index and
# the rows' body numbers included, so each row's reads and writes turn into
# gathers and scatters over the worlds. The batching rule below selects
# without batching what is not batched: the reads stay dynamic slices
# (docs/design.md, 'Loops compiled whole').

@partial(jax.custom_jvp, nondiff_argnums=(0,))
def _guarded_row(solve_row, active, operands):
    """``solve_row(*operands)`` if ``active`` else the row's velocities and impulses unchanged.

    operands: (index, arrays, old, prep, per_row, extra) as in
    :func:`_sweep_rows`; returns (arrays, lam_row).
    """
    return _branch_or_select(solve_row)(active, operands)


def _kept(operands):
    """What an inactive row leaves: its bodies' values and its impulses, unchanged."""
    _, arrays, old = operands[:3]
    return arrays, old


def _selected(solve_row, active, operands):
    """The row solved whatever ``active`` says, and its result dropped where it is inactive."""
    solved = solve_row(*operands)
    return jax.tree_util.tree_map(lambda new, kept: jnp.where(active, new, kept), solved, _kept(operands))


def _branch_or_select(solve_row):
    """``(active, operands) -> (arrays, lam_row)``: a branch, and under vmap mostly a select."""
    def branch(active, operands):
        return jax.lax.cond(active, lambda ops: solve_row(*ops), _kept, operands)

    branch_or_select = jax.custom_batching.custom_vmap(branch)

    @branch_or_select.def_vmap
    def batched(axis_size, in_batched, active, operands):
        active_batched, operands_batched = in_batched
        in_axes = (0 if active_batched else None,
                   jax.tree_util.tree_map(lambda batched: 0 if batched else None, operands_batched))
        each_world = lambda per_world: jax.vmap(per_world, in_axes=in_axes, axis_size=axis_size)
        if active_batched:
            # A row active in no world (a stack's pairs that do not touch) is
            # skipped in all of them at once; one active anywhere is solved in
            # every world and kept where it is active.
            out = jax.lax.cond(jnp.any(active), each_world(partial(_selected, solve_row)),
                               each_world(lambda _, operands: _kept(operands)), active, operands)
        else:  # the same rows active in every world: the branch still skips them
            out = each_world(branch)(active, operands)
        return out, jax.tree_util.tree_map(lambda _: True, out)

    return branch_or_select


@_guarded_row.defjvp
def _guarded_row_jvp(solve_row, primals, tangents):
    active, operands = primals
    return jax.jvp(partial(_selected, solve_row, active), (operands,), (tangents[1],))


def soft_parameters(params: Params, h):
    """(bias rate, mass scale, impulse scale, max push) of the soft contact constraint."""
    omega = 2.0 * jnp.pi * jnp.minimum(params.contact_hertz, 0.25 / h)
    zeta = params.contact_damping_ratio
    a1 = 2.0 * zeta + h * omega
    a2 = h * omega * a1
    a3 = 1.0 / (1.0 + a2)
    return omega / a1, a2 * a3, a3, params.max_push_velocity


def restitution_pass(model: Model, prep: Prepared, vel, angvel, impulses, threshold):
    """Give contacts that hit faster than ``threshold`` an outgoing speed of −e·v_approach.

    impulses: as in :func:`solve_pass`; returns (vel, angvel, impulses).
    """
    def new_normal(vn, old, row, threshold):
        # With impulse_smoothing every closing contact pushes a little, so it
        # bounces up to a substep early (apex +2 mm on the bounce bench). Gating
        # on the unsmoothed impulse instead was tried: the apex was right but
        # the gradient jumped (std of dA/dh0 41 against 2e-3), so the knob keeps
        # this bias.
        bounce = row.active & (row.approach < -threshold) & (old > 0.0)
        delta = -row.normal_mass * (vn + row.restitution * row.approach)
        return jnp.where(bounce, jnp.maximum(old + delta, 0.0), old)

    if model.solver == "jacobi":
        normal = new_normal(row_speeds(model, prep, vel, angvel, count=1)[0], impulses[0], prep, threshold)
        vel, angvel = push_rows(model, prep, vel, angvel, [normal - impulses[0]])
        return vel, angvel, (normal, *impulses[1:])

    def one_contact(row, bodies, old, _, threshold):
        normal = new_normal(_row_speed(row, 0, bodies), old[0], row, threshold)
        return _row_push(row, 0, bodies, normal - old[0]), (normal, *old[1:])

    (vel, angvel), impulses = _sweep_rows(model, prep, one_contact, (vel, angvel), impulses, extra=threshold)
    return vel, angvel, impulses
