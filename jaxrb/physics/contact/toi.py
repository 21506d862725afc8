"""Time of impact for impulse contact: fast impacts resolved inside the substep.

The soft-step solver (:mod:`jaxrb.physics.contact.impulse`) lets a speculative contact
close exactly its gap by the end of the substep and bounces it there. The
position is right at the substep's end, but *when* the impact happened is
lost: everything after it is shifted by up to one substep, and the outcome's
derivative with respect to the initial state or velocity misses the
dependence of the impact time on them (a ball that starts 1 mm further away
should leave 1 mm/v later).

With ``scene.build(..., time_of_impact=True)``, each substep first looks at
the contact rows of the pair kinds in :data:`TOI_KINDS` (a point, sphere or
circle against a plane or half-plane, a capsule's end cap against a plane,
two spheres or two circles). Along the row's normal, fixed for the step as
the solver's is, the separation closes at the row's approach speed
v_n < 0, so the time of impact is the closed form

    t = s / (−v_n),  s ≥ 0 the current separation,

exact for these shapes while the normal does not turn within the substep
(planes always; sphere pairs when they approach head-on; otherwise it is
first order in the normal's turn). A row that hits within the substep
(t < h) and approaches faster than ``bounce_threshold`` gets its impact there:
the normal impulse that leaves it at −e times its speed at that time (the
substep's loads taken as acting uniformly over it, before and after) and a Coulomb friction impulse
bounded by μ times that impulse (as at the end of a substep). Each body then
moves with its old velocity for t and its new one for h − t: the position
phase moves it with the new velocity for h, and :func:`shift_pose` adds
(v_old − v_new)·t, and the same for rotation.

Rows are resolved one after the other in table order, each with its own time
(summing their shifts is exact for one impact per body per substep, which is
the case the option is for). The solver's own rows for those contacts are
then separating and push nothing, and the restitution pass sees no impulse on
them, so nothing bounces twice. Slow approaches (resting, settling) and other
pair kinds stay with the solver.
"""

from __future__ import annotations

from functools import partial

import jax.numpy as jnp
import numpy as np

from jaxrb.math import quaternion as quat_ops
from jaxrb.physics.contact.impulse import _row_friction
from jaxrb.physics.contact.rows import Prepared
from jaxrb.physics.contact.sequential import _row_push, _row_speed, _sweep_rows
from jaxrb.physics.dynamics import inverse_inertia
from jaxrb.physics.integrators import angvel_from_momentum, body_angvel_and_momentum
from jaxrb.model.types import Model, Params, State

#: Pair kinds whose time of impact has the closed form above (circles are the
#: 2D ``sphere`` kind and half-planes the 2D ``plane`` kind).
TOI_KINDS = ("sphere_plane", "capsule_plane", "points_plane", "sphere_sphere")


def toi_rows(model: Model) -> np.ndarray:
    """Indices of the contact rows whose pair kind is in :data:`TOI_KINDS`.

    Returns a static (R,) int array in :func:`jaxrb.physics.collision.pairs.detect`'s
    row order; empty when the option is off.
    """
    rows, start = [], 0
    for group in model.pair_groups:
        count = group.capacity * group.slots
        if model.time_of_impact and group.kind in TOI_KINDS:
            rows.extend(range(start, start + count))
        start += count
    return np.asarray(rows, dtype=np.int32)


def owned_rows(prep: Prepared, separation, threshold, rows: np.ndarray):
    """(C,) bool: the rows this substep's impact pass owns.

    Those of ``rows`` that are active, not overlapping (separation (C,) ≥ 0)
    and approach faster than ``threshold`` (``prep.approach`` (C,) is the
    approach speed after the substep's velocity phase). The solver must leave
    them alone this substep: it would stop them speculatively, early.
    """
    in_rows = np.zeros(prep.normal.shape[0], dtype=bool)
    in_rows[rows] = True
    return in_rows & prep.active & (separation >= 0.0) & (prep.approach < -threshold)


def resolve_impacts(model: Model, prep: Prepared, vel, angvel, separation, owned, start_speed, h,
                    rows: np.ndarray):
    """Resolve the impacts of ``owned`` rows that happen within this substep.

    Args:
        model: the Model.
        prep: the step's prepared contacts; ``prep.approach`` (C,) must hold
            the approach speeds after this substep's velocity phase.
        vel: (n + 1, dim) padded velocities; angvel: (n + 1, 3), or (n + 1,) in 2D.
        separation: (C,) current separations.
        owned: (C,) bool from :func:`owned_rows`.
        start_speed: (C,) v_n before the substep's velocity phase. The loads
            change v_n by Δ = approach − start over the substep, taken as
            uniform in time: a contact hit at t is hit at start + Δ·t/h and
            leaves at −e times that plus Δ·(1 − t/h). So a ball dropped from
            higher lands faster and bounces higher, as in the continuous
            motion, instead of keeping the substep's one discrete velocity.
        h: substep length.
        rows: (R,) static row indices from :func:`toi_rows`.

    Returns:
        (vel, angvel, shift, turn): the velocities after the impacts, and the
        position (n + 1, dim) and rotation-vector (n + 1, 3) or angle (n + 1,)
        corrections to add after the position phase.
    """
    hits = owned & (separation < -prep.approach * h)
    arrays = (vel, angvel, jnp.zeros_like(vel), jnp.zeros_like(angvel))
    arrays, _ = _sweep_rows(model, prep.replace(active=hits), partial(_impact, model), arrays, None,
                            (separation, start_speed), h, rows=rows)
    return arrays


def _impact(model, row, bodies, _, row_values, h):
    """One row's impact (a :func:`jaxrb.physics.contact.sequential._sweep_rows` update).

    bodies: (v, ω, shift, turn) of body A, then of body B; row_values: the
    row's (separation, start_speed). Returns (bodies, None).
    """
    gap, start_speed = row_values
    vel_a, angvel_a, shift_a, turn_a, vel_b, angvel_b, shift_b, turn_b = bodies
    velocities = (vel_a, angvel_a, vel_b, angvel_b)
    closing = -row.approach
    # closing > threshold >= 0 wherever the row hits; the guard keeps the rows
    # that are solved and then dropped (under vmap, and in the derivative
    # program) from dividing by zero, whose NaN would reach the gradient.
    time = gap / jnp.where(closing > 0.0, closing, 1.0)
    # Symplectic Euler moves a body through the substep with its
    # end-of-substep velocity, so its positions run half a substep ahead of
    # its velocities: the gap closes at t, but the body is then where the
    # continuous motion is at t + h/2. Hit speed and rebound are taken at that
    # time, with the loads' change of v_n over the substep (Δ) spread
    # uniformly (see ``start_speed`` in :func:`resolve_impacts`).
    load_change = row.approach - start_speed
    fraction = time / h
    impact_speed = start_speed + load_change * (fraction + 0.5)
    rebound = -row.restitution * impact_speed + load_change * (0.5 - fraction)
    normal_impulse = jnp.maximum(row.normal_mass * (rebound - _row_speed(row, 0, velocities)), 0.0)
    new = _row_push(row, 0, velocities, normal_impulse)
    no_friction_yet = [jnp.zeros_like(normal_impulse)] * len(row.tangents)
    new, _ = _row_friction(model, row, new, no_friction_yet, normal_impulse)
    # Each body moved with its old velocity for t and moves with the new one
    # for h − t; the position phase gives it the new one for h, so the pose
    # gets (old − new)·t. And after the hit the positions move with the
    # rebound's mean velocity over the rest of the substep, not with its end
    # value: a normal displacement of Δ·t(h − t)/(2h), given to the bodies as
    # a "position impulse" in proportion to their inverse masses.
    moved = tuple(None if pose is None else pose + (old - changed) * time  # B None: a plane
                  for pose, old, changed in zip((shift_a, turn_a, shift_b, turn_b), velocities, new))
    lag = row.normal_mass * load_change * fraction * (h - time) / 2.0
    shift_a, turn_a, shift_b, turn_b = _row_push(row, 0, moved, lag)
    new_vel_a, new_angvel_a, new_vel_b, new_angvel_b = new
    return (new_vel_a, new_angvel_a, shift_a, turn_a, new_vel_b, new_angvel_b, shift_b, turn_b), None


def shift_pose(model: Model, params: Params, state: State, shift, turn) -> State:
    """Add the impact corrections (padded, from :func:`resolve_impacts`) to the pose.

    In 3D the rotation keeps each body's world angular momentum, as the
    position phase does.
    """
    pos = state.pos + shift[:-1]
    if model.dim == 2:
        return state.replace(pos=pos, angle=state.angle + turn[:-1])
    angvel_body, momentum = body_angvel_and_momentum(params, state)
    quat = quat_ops.integrate_exp_map(state.quat, turn[:-1], 1.0)
    angvel, _ = angvel_from_momentum(quat, momentum, params, inverse_inertia(params, 3), angvel_body)
    return state.replace(pos=pos, quat=quat, angvel=angvel)
