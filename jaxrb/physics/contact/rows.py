"""The impulse solver's contact rows for one step: what is fixed at the step's start, and every row at once.

:func:`prepare` fixes each row's directions (the normal, then the tangents),
arms, effective masses and :class:`RowMaps` (how a row reads and moves its two
bodies) into a :class:`Prepared`, once a step. Every row at once then reads
its relative speeds (:func:`row_speeds`, :func:`normal_velocity`) and applies
impulses (:func:`push_rows`) through the maps: the Jacobi passes, the warm
start and the approach speeds use these, and :func:`current_separation` gives
each row's separation as the bodies move within the step. The rows' impulses
are carried along their own directions within a step and converted from and
to ``State.contact_impulse``'s world frame by :func:`row_impulses` and
:func:`world_impulses`.

The solver that uses the rows is :mod:`jaxrb.physics.contact.impulse`; the sequential
sweep over them one at a time is :mod:`jaxrb.physics.contact.sequential`.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxrb.math import quaternion as quat_ops
from jaxrb.model.struct import pytree_dataclass
from jaxrb.physics.collision.pairs import round_sides, row_summer, row_taker, shape_centres
from jaxrb.physics.contact.common import apply_inverse_inertia, moment, pad, tangent_basis, world_inverse_inertia
from jaxrb.math.vector import rotate2
from jaxrb.model.types import Array, Model, Params, State


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
    ``inv_mass`` and world ``inv_inertia`` (:func:`jaxrb.physics.collision.pairs.row_taker`);
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
    centre = shape_centres(model, params)  # shape centre from the centre of mass, body frame
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
