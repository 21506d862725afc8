"""Hand-written reverse mode of rollouts with penalty contact against planes: ``rb.rollout(..., adjoint=True)``.

The rollout of a plane-penalty scene (:mod:`jaxrb.physics.plane_penalty`) scans a
step made of a contact wrench (``PlanePenalty._penalty``: each body-frame
point's penetration, spring and damper, and the friction spring clamped to
its Coulomb disc) and a free-body semi-implicit substep driven by it.
Autodiff's reverse mode of that step costs 4-5 forward rollouts at one
world; with the contact's gradient stopped it still cost 3.5, so both halves
transpose badly (docs/design.md, 'Hand-written adjoints'). This module writes both
adjoints by hand, as :mod:`jaxrb.physics.free_body_adjoint` does for free bodies:

* the forward loop is the plane-penalty rollout's (its States equal
  ``rb.rollout``'s to float rounding: XLA fuses the two programs
  differently), and it keeps each step's input Carry, which with
  ``every=1`` is the trajectory itself;
* the backward loop recomputes a step from its input, the contact's
  intermediates recorded by ``_penalty`` itself, then applies the chain
  rule on components: the free-body substep by :mod:`jaxrb.physics.free_body_adjoint`'s
  substep adjoint, the contact wrench by :func:`_group_adjoint`, with the
  cotangents many others read stored once (``components.materialize``);
* the cotangents of what ``PlanePenalty.prepare`` derives from the Params
  (inverse masses and inertias, mixed friction, dampers, body-frame points)
  are summed in the loop's carry, per body and per contact row, and
  transposed through ``prepare`` once after the loop; those of the loads
  (``net_wrench``) likewise, or per step with applied loads.

What it covers (:func:`supports`): every model the plane-penalty path takes
(3D, penalty contact, semi-implicit, planes only) with the ``"spring"``
friction law (the default) and no damping; either activation (hard or
``penalty_width``), either damper (from restitution or given), any
substeps, applied loads, ``every`` and ``vmap``. The ``"regularized"``
friction law keeps autodiff.

At the contact law's kinks (the penetration or the normal force exactly
0) the derivative taken is JAX's: half of each side's (:func:`_max_slope`).
One difference from autodiff, by construction: the free-body adjoint treats
the orientation as q/|q|, while the forward's rotation matrices are the
unit-quaternion polynomial (``quaternion.rotation_matrix_parts``). The two
agree on unit quaternions, and so do their derivatives along the unit
sphere; only the cotangent of the *initial* State's quaternion along q
itself (a change of |q|, which the rollout ignores after its first step,
where it normalises) differs from autodiff's.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Optional

import jax
import jax.numpy as jnp

from jaxrb.math import components as vec

from jaxrb.math import quaternion as quat_ops
from jaxrb.physics import free_body_adjoint as free_body
from jaxrb.compile import full_precision
from jaxrb.physics.dynamics import net_wrench
from jaxrb.math.vector import safe_div, unstack
from jaxrb.physics.plane_penalty import (Carry, PlanePenalty, _rows, _stored, _to_bodies, rotation_stored,
                                         supports as plane_penalty_supports)
from jaxrb.model.types import Model, Params, State, Wrench


def supports(model: Model) -> bool:
    """Whether ``model``'s rollouts have this module's adjoint.

    Args:
        model: a Model from ``Scene.build``.

    Returns:
        True where the rollout takes the plane-penalty path, with the spring
        friction law and no damping.
    """
    return plane_penalty_supports(model) and model.penalty_friction == "spring" and not model.damping


# ---------------------------------------------------------------- the contact wrench

def _clamp_adjoint(vector, limit, g_out):
    """Cotangents (g_vector, g_limit) of ``components.clamp_to_disc(vector, limit)``.

    Inside the disc the clamp is the identity; on its rim it is
    limit · v/|v|, whose derivative is (limit/|v|)(I − u uᵀ) in v and u in
    the limit (u = v/|v|, taken as 0 at v = 0, where the forward's safe
    division gives a zero derivative too).
    """
    length = vec.safe_length(vector)
    clamped = length >= limit
    inv_length = safe_div(1.0, length)
    unit = vec.along(inv_length, vector)
    radial = vec.dot(unit, g_out)
    scale = limit * inv_length
    g_vector = tuple(0.0 if vec.is_zero(part) else jnp.where(clamped, scale * (g - radial * u), g)
                     for part, g, u in zip(vector, g_out, unit))
    return g_vector, jnp.where(clamped, radial, 0.0)


def _max_slope(x):
    """d max(x, 0)/dx as JAX takes it: 1 above 0, 0 below, ½ at 0 (where the contact law has its kinks)."""
    return jnp.where(x > 0.0, 1.0, jnp.where(x == 0.0, 0.5, 0.0))


def _live(parts, like):
    """``parts`` with a structural zero wherever ``like`` has one (the cotangent of a part that is never computed)."""
    return tuple(0.0 if vec.is_zero(x) else g for g, x in zip(parts, like))


def _group_adjoint(model, params, group, data, rec, angvel, predicted_angvel, h, g_force, g_torque, g_normal_out,
                   g_held_out):
    """Row cotangents of one plane group's contact forces (spring friction), from those of its outputs.

    The forward is ``PlanePenalty._penalty``'s (see there); ``rec`` holds
    its intermediates for this group. Every array is (P, K) (a row per
    contact point) or (P, 1) (a pair's), vectors 3 parts. Cotangents that
    several others read are stored once (``components.materialize``).

    Args:
        g_force, g_torque: 3 parts each, the cotangents of the group's
            bodies' contact force and torque, taken to its pairs (P, 1).
        g_normal_out, g_held_out: cotangents of the rows' normal force and
            carried friction after the substep.

    Returns:
        (rows, g_held_in): ``rows`` a dict of the row-level factors the
        caller sums over each pair's rows (onto its body: ``vel``,
        ``angvel``, ``predicted_vel``, ``predicted_angvel``, ``pos``,
        ``rotation`` (9 entries row by row); onto the prepared values:
        ``local``, ``inv_mass``, ``inv_inertia`` (9), ``friction``,
        ``damping``; onto scalars: ``stiffness``, ``h``, ``width``); g_held_in
        the cotangent of the friction carried into the substep.
    """
    take = lambda values: _rows(values, group.bodies)
    stiffness, width = params.penalty_stiffness, params.penalty_width
    normal, arm, rotation = rec["normal"], rec["arm"], rec["rotation"]
    pressing, active = rec["pressing"], rec["active"]
    tangential = lambda vector: group.normal.tangential(vector, normal)
    # Force and torque sums: force = Σ total, torque = Σ arm × total.
    g_total = vec.materialize(vec.add(g_force, vec.cross(g_torque, arm)), params)
    g_arm = vec.cross(rec["total"], g_torque)
    g_normal = g_normal_out + vec.dot(g_total, normal)
    # The two clamps (friction applied, friction carried) and their limit μN.
    elastic, slip, damper = rec["elastic"], rec["slip"], rec["damper"]
    g_applied, g_limit_a = _clamp_adjoint(vec.sub(elastic, vec.along(damper, slip)), rec["limit"],
                                          vec.where(pressing, _live(g_total, rec["friction"])))
    g_kept, g_limit_k = _clamp_adjoint(elastic, rec["limit"], vec.where(pressing, _live(g_held_out, rec["held"])))
    g_elastic = vec.add(g_applied, g_kept)
    g_slip = vec.along(-damper, g_applied)
    (g_limit, g_damper), g_elastic, g_slip = _stored(params, (g_limit_a + g_limit_k, -vec.dot(g_applied, slip)),
                                                     g_elastic, g_slip)
    g_normal = g_normal + data["friction"] * g_limit
    g_friction = rec["normal_force"] * g_limit
    # elastic = held − k h T(rel): held is the carried friction, projected.
    g_held_in = vec.where(active, tangential(g_elastic))
    g_rel = vec.along(-stiffness * h, tangential(g_elastic))
    rel_tangential = vec.dot(tangential(rec["rel_vel"]), g_elastic)
    g_stiffness = -h * rel_tangential
    g_h = -stiffness * rel_tangential
    # slip = T(predicted_vel + predicted_angvel × arm)
    g_predicted = tangential(g_slip)
    g_arm = vec.add(g_arm, vec.cross(g_predicted, tuple(map(take, predicted_angvel))))
    # N = max(k a − d vn g, 0) where active; the friction's damper is f g.
    activation, gate, damping, vn = rec["activation"], rec["gate"], rec["damping"], rec["vn"]
    g_raw = jnp.where(active, _max_slope(stiffness * activation - damping * vn * gate) * g_normal, 0.0)
    g_stiffness = g_stiffness + activation * g_raw
    g_activation = stiffness * g_raw
    g_damping = -vn * gate * g_raw
    g_friction_damping = gate * g_damper
    g_gate = rec["friction_damping"] * g_damper - damping * vn * g_raw
    g_vn = -damping * gate * g_raw
    # damping = min(d0, m_n / h), friction_damping = min(f0, m_n / h)
    mass_rate = rec["normal_mass"] / h
    capped, friction_capped = mass_rate < data["damping"], mass_rate < data["friction_damping"]
    g_mass_rate = jnp.where(capped, g_damping, 0.0) + jnp.where(friction_capped, g_friction_damping, 0.0)
    g_d0 = jnp.where(capped, 0.0, g_damping)
    g_f0 = jnp.where(friction_capped, 0.0, g_friction_damping)
    g_normal_mass = g_mass_rate / h
    g_h = g_h - mass_rate / h * g_mass_rate
    # (activation, gate) of the penetration p = −dist
    penetration = -rec["dist"]
    if model.penalty_smooth:
        slope = gate * (1.0 - gate)
        x = penetration / width
        g_penetration = gate * g_activation + slope / width * g_gate
        g_width = (jax.nn.softplus(x) - x * gate) * g_activation - slope * x / width * g_gate
    else:
        g_penetration = _max_slope(penetration) * g_activation
        g_width = None
    (g_dist, g_normal_mass, g_vn, g_stiffness, g_h), = _stored(params, (-g_penetration, g_normal_mass, g_vn,
                                                                        g_stiffness, g_h))
    # m_n = 1 / (1/m + cᵀ I⁻¹ c) / sharing, c = Rᵀ (arm × n)
    arm_cross = vec.cross(arm, normal)
    body_cross = vec.matvec_transposed(rotation, arm_cross)
    g_den = -rec["normal_mass"] ** 2 * rec["sharing"] * g_normal_mass
    inv_inertia = data["inv_inertia"]
    g_body_cross = vec.materialize(vec.along(g_den, vec.add(vec.matvec(inv_inertia, body_cross),
                                                            vec.matvec_transposed(inv_inertia, body_cross))), params)
    g_arm_cross = vec.matvec(rotation, g_body_cross)
    g_arm = vec.add(g_arm, vec.cross(normal, g_arm_cross))
    g_rel = vec.materialize(vec.add(g_rel, vec.along(g_vn, normal)), params)
    # rel = vel + ω × arm
    g_arm = vec.add(g_arm, vec.cross(g_rel, tuple(map(take, angvel))))
    # arm = arm0 − ½ (height + radius) n, dist = height − radius, height = (pos + arm0)·n − offset
    g_shift = 0.5 * vec.dot(g_arm, normal)
    g_height = g_dist - g_shift
    (g_height,), g_arm0 = _stored(params, (g_height,), vec.add(g_arm, vec.along(g_height, normal)))
    local = data["local"]
    rows = dict(
        vel=vec.add(g_rel, g_predicted), angvel=vec.cross(arm, vec.add(g_rel, g_predicted)),
        predicted_vel=g_predicted, predicted_angvel=vec.cross(arm, g_predicted),
        pos=vec.along(g_height, normal),
        rotation=_add_parts(_outer(g_arm0, local), _outer(arm_cross, g_body_cross)),
        local=vec.matvec_transposed(rotation, g_arm0), inv_mass=g_den,
        inv_inertia=tuple(vec.mul(g_den, entry) for entry in _outer(body_cross, body_cross)),
        friction=g_friction, damping=g_d0, friction_damping=g_f0, stiffness=g_stiffness, h=g_h, width=g_width,
        radius=-(g_dist + g_shift))
    return rows, g_held_in


def _outer(a, b):
    """a bᵀ of two component vectors as a 9-tuple of entries row by row (structural zeros kept)."""
    return tuple(vec.mul(x, y) for x in a for y in b)


def _add_parts(a, b):
    """a + b part by part, for tuples of any length (a vector, a quaternion, a matrix's 9 entries)."""
    return tuple(vec.add((x,), (y,))[0] for x, y in zip(a, b))


def _contact_adjoint(fast, params, record, prepared, h, quat, force, torque, g_force, g_torque, g_normals, g_helds):
    """Cotangents of one substep's contact wrench's inputs (``PlanePenalty._penalty``, spring friction).

    Args:
        fast: the model's ``PlanePenalty``.
        params: Params (penalty_stiffness, penalty_width, and dt for the
            stored cotangents' branch).
        record: the intermediates ``_penalty`` recorded for this substep,
            with the stored R(q) (``rotation``, 3 rows of 3 parts) the
            caller added.
        prepared: ``fast.prepare(params)``.
        h: () substep length.
        quat: 4 parts of (n,), the substep's input orientation.
        force, torque: 3 parts of (n,) external loads.
        g_force, g_torque: 3 parts of (n,), cotangents of the contact force
            and torque on each body.
        g_normals, g_helds: per group, cotangents of the rows' normal force
            and carried friction after the substep.

    Returns:
        (g_pos, g_vel, g_quat, g_angvel, g_helds_in, g_force_ext,
        g_torque_ext, body, rows): state and load cotangents (3 or 4 parts
        of (n,); per group the carried friction's 3 parts); ``body`` a dict
        of per-body factors (``inv_mass`` (n,), ``inv_inertia`` 9 entries,
        ``h`` (n,)); ``rows`` per group the row-level dict of
        :func:`_group_adjoint` (summed over steps by the caller).
    """
    model, num = fast.model, fast.model.num_bodies
    zero_vector = (0.0, 0.0, 0.0)
    sums = dict(vel=zero_vector, angvel=zero_vector, predicted_vel=zero_vector, predicted_angvel=zero_vector,
                pos=zero_vector, rotation=(0.0,) * 9)
    rows, helds_in = [], []
    for group, data, rec, g_normal, g_held in zip(fast.groups, prepared["groups"], record["groups"], g_normals,
                                                  g_helds):
        take = lambda values: _rows(values, group.bodies)
        group_rows, g_held_in = _group_adjoint(
            model, params, group, data, rec, record["angvel"], record["predicted_angvel"], h,
            tuple(map(take, g_force)), tuple(map(take, g_torque)), g_normal, g_held)
        for name in sums:
            sums[name] = _add_parts(sums[name], tuple(
                part if vec.is_zero(part) else _to_bodies(part, group.bodies, num) for part in group_rows[name]))
        rows.append({name: value for name, value in group_rows.items() if name not in sums})
        helds_in.append(g_held_in)
    # The predicted velocities: v + h F/m and ω + h R I⁻¹ Rᵀ τ.
    inv_mass, inv_inertia = prepared["inv_mass"], prepared["inv_inertia"]
    rotation = record["rotation"]
    g_predicted_vel, g_predicted_angvel = sums["predicted_vel"], sums["predicted_angvel"]
    body_torque = vec.matvec_transposed(rotation, torque)
    spin_body = vec.matvec(inv_inertia, body_torque)
    spin = vec.matvec(rotation, spin_body)
    g_spin = vec.along(h, g_predicted_angvel)
    g_spin_body = vec.matvec_transposed(rotation, g_spin)
    g_body_torque = vec.matvec_transposed(inv_inertia, g_spin_body)
    g_torque_ext = vec.matvec(rotation, g_body_torque)
    force_dot = vec.dot(force, g_predicted_vel)
    body = dict(inv_mass=h * force_dot, inv_inertia=_outer(g_spin_body, body_torque),
                h=inv_mass * force_dot + vec.dot(spin, g_predicted_angvel))
    g_rotation = _add_parts(_add_parts(sums["rotation"], _outer(g_spin, spin_body)), _outer(torque, g_body_torque))
    # R(q)'s polynomial, as the forward computes it (a few products per body: autodiff's transpose is fine).
    _, rotation_vjp = jax.vjp(quat_ops.rotation_matrix_parts, quat)
    g_quat, = rotation_vjp(vec.matrix_rows(tuple(jnp.broadcast_to(g, quat[0].shape) for g in g_rotation)))
    # (sums' vel and angvel hold the predicted velocities' cotangents already.)
    return (sums["pos"], sums["vel"], g_quat, sums["angvel"], tuple(helds_in), vec.along(h * inv_mass, g_predicted_vel),
            g_torque_ext, body, rows)


def _step_adjoint(fast, params, prepared, carry, force, torque, g_after, keep):
    """Cotangents of one step's input from those of its output.

    Args:
        fast: the model's ``PlanePenalty``.
        params: Params (the step reads dt, penalty_stiffness, penalty_width and contact_margin).
        prepared: ``fast.prepare(params)``.
        carry: the step's input Carry.
        force, torque: 3 parts of (n,) external force and torque.
        g_after: (g_pos, g_vel, g_quat, g_angvel, g_normals, g_helds)
            cotangents of the step's output (3 or 4 parts of (n,); per group
            the rows' normal force and the 3 parts of carried friction).
        keep: stores a tuple of parts once for all its users.

    Returns:
        (g_before, body, rows, g_force, g_torque): g_before like g_after for
        the input (its normal-force cotangents are zero: the step does not
        read them); ``body`` the per-body factors (``inv_mass``, ``inertia``
        and ``inv_inertia`` (9 entries), ``h``) and ``rows`` per group the
        row-level ones (see :func:`_group_adjoint`), both summed over the
        substeps; the external loads' cotangents (3 parts of (n,) each).
    """
    model = fast.model
    orientation = model.orientation
    inertia, inv_inertia, inv_mass = prepared["inertia"], prepared["inv_inertia"], prepared["inv_mass"]
    h = params.dt / model.substeps
    state, held = (carry.pos, carry.vel, carry.quat, carry.angvel), carry.friction
    saved = []
    for _ in range(model.substeps):
        # R(q) stored once: the contact rows, their adjoint and the substep's all read it
        # (docs/design.md, 'Hand-written adjoints').
        rotation = rotation_stored(state[2], params)  # as the forward's substep stores it
        now = dataclasses.replace(carry, pos=state[0], vel=state[1], quat=state[2], angvel=state[3], friction=held)
        record = dict(angvel=state[3], rotation=rotation)
        contact_force, contact_torque, _, held = fast._penalty(now, rotation, params, prepared, force, torque, h,
                                                               record)
        total_force = vec.add(force, contact_force)
        accel = vec.along(inv_mass, total_force)
        quat = state[2]
        state, intermediates = free_body._substep_values(orientation, inertia, inv_inertia, *state, accel,
                                                         vec.add(torque, contact_torque), h, keep, rotation)
        saved.append((record, intermediates, accel, total_force, quat))

    g_pos, g_vel, g_quat, g_angvel, g_normals, g_helds = g_after
    g_state = (g_pos, g_vel, g_quat, g_angvel)
    g_force, g_torque, body, rows = None, None, None, None
    for record, intermediates, accel, total_force, quat in reversed(saved):
        g_state, sums, loads = free_body._substep_adjoint(orientation, inertia, inv_inertia, accel, h,
                                                          intermediates, g_state, keep)
        g_accel, g_total_torque = unstack(loads[:3], 0), unstack(loads[3:], 0)
        g_total_force = keep(vec.along(inv_mass, g_accel))
        (g_cpos, g_cvel, g_cquat, g_cangvel, g_helds, g_cforce, g_ctorque, contact_body,
         contact_rows) = _contact_adjoint(fast, params, record, prepared, h, quat, force, torque, g_total_force,
                                          g_total_torque, g_normals, g_helds)
        g_state = tuple(_add_parts(a, b) for a, b in zip(g_state, (g_cpos, g_cvel, g_cquat, g_cangvel)))
        g_normals = tuple(jnp.zeros_like(g) for g in g_normals)
        step_body = dict(inv_mass=vec.dot(g_accel, total_force) + contact_body["inv_mass"], inertia=sums["inertia"],
                         inv_inertia=tuple(a + b for a, b in zip(sums["inv_inertia"], contact_body["inv_inertia"])),
                         h=sums["h"] + contact_body["h"])
        step_force, step_torque = _add_parts(g_total_force, g_cforce), _add_parts(g_total_torque, g_ctorque)
        if body is None:
            g_force, g_torque, body, rows = step_force, step_torque, step_body, contact_rows
        else:
            g_force, g_torque = _add_parts(g_force, step_force), _add_parts(g_torque, step_torque)
            body = jax.tree_util.tree_map(jnp.add, body, step_body)
            rows = jax.tree_util.tree_map(jnp.add, rows, contact_rows)
    return (*g_state, g_normals, g_helds), body, rows, g_force, g_torque


def _prepared_cotangent(prepared, body, rows):
    """``prepare``'s output's cotangent from the backward loop's sums (rows summed over each pair's points)."""
    pair_sum = lambda values: jnp.sum(values, axis=-1, keepdims=True)
    groups = []
    for data, group_rows in zip(prepared["groups"], rows):
        groups.append(dict(
            data, local=tuple(jnp.broadcast_to(g, x.shape) for g, x in zip(group_rows["local"], data["local"])),
            inv_mass=pair_sum(group_rows["inv_mass"]),
            inv_inertia=vec.matrix_rows(tuple(jnp.broadcast_to(pair_sum(g), data["inv_mass"].shape)
                                       for g in group_rows["inv_inertia"])),
            friction=pair_sum(group_rows["friction"]), damping=pair_sum(group_rows["damping"]),
            friction_damping=pair_sum(group_rows["friction_damping"]),
            offset=jnp.zeros_like(data["offset"]), radius=pair_sum(group_rows["radius"])))
    return dict(inv_mass=body["inv_mass"], inertia=vec.matrix_rows(body["inertia"]),
                inv_inertia=vec.matrix_rows(body["inv_inertia"]), groups=tuple(groups))


def rollout(step: Callable, state: State, params: Params, num_steps: int, every: int,
            applied: Optional[Wrench]) -> State:
    """``rb.rollout(..., adjoint=True)`` for a plane-penalty model: the same States, this module's reverse mode.

    Args and the States returned as for :func:`jaxrb.physics.adjoint.rollout`, which
    calls this for a model :func:`supports` accepts. The States are the
    plane-penalty rollout's to float rounding (XLA fuses the two programs
    differently). Reverse mode keeps every step's input Carry; forward mode
    raises (``jax.custom_vjp``).
    """
    model = step.model
    fast = PlanePenalty(model)
    num_saved = num_steps // every
    per_step = applied is not None

    def forward(params, prepared, carry, applied, keep_inputs):
        # make_step's component step, scanned on its Carry (no State between steps).
        def one(current, applied_now):
            return fast.step(current, params, applied_now, prepared), (current if keep_inputs else None)

        def chunk(current, applied_chunk):
            current, inputs = jax.lax.scan(one, current, applied_chunk, length=every)
            return current, (current, inputs)

        chunks = (jax.tree_util.tree_map(lambda a: a.reshape((num_saved, every) + a.shape[1:]), applied)
                  if per_step else None)
        _, (carries, inputs) = jax.lax.scan(chunk, carry, chunks, length=num_saved)
        return carries, inputs

    @jax.custom_vjp
    def run(params, prepared, carry, applied):
        return forward(params, prepared, carry, applied, False)[0]

    def run_forward(params, prepared, carry, applied):
        carries, inputs = forward(params, prepared, carry, applied, every > 1)
        return carries, (params, prepared, carry, carries if every == 1 else inputs, applied)

    def run_backward(residuals, g_carries):
        params, prepared, first, inputs, applied = residuals
        step_inputs, g_steps = free_body.backward_loop_inputs(first, inputs, g_carries, every)

        def keep(parts):
            return vec.materialize(parts, params)

        def step_adjoint(before, g_after, applied_now):
            force, torque = net_wrench(model, params, applied_now)
            return _step_adjoint(fast, params, prepared, before, unstack(force), unstack(torque), g_after, keep)

        # The carry holds the state's cotangent and the sums of the other
        # inputs' (per body, and per contact row for the per-pair values,
        # summed over each pair's rows after the loop); the loads' leave the
        # loop per step where they change from step to step.
        def back(carry, x):
            g_state, sums, g_loads = carry
            before, g_now, applied_now = x
            g_after = (_add_parts(g_state[0], g_now.pos), _add_parts(g_state[1], g_now.vel),
                       _add_parts(g_state[2], g_now.quat), _add_parts(g_state[3], g_now.angvel),
                       jax.tree_util.tree_map(jnp.add, g_state[4], g_now.normal_force),
                       jax.tree_util.tree_map(jnp.add, g_state[5], g_now.friction))
            g_before, body, rows, g_force, g_torque = step_adjoint(before, g_after, applied_now)
            sums = jax.tree_util.tree_map(jnp.add, sums, (body, rows))
            step_loads = (jnp.stack(g_force, -1), jnp.stack(g_torque, -1))
            if per_step:
                return (g_before, sums, g_loads), step_loads
            return (g_before, sums, jax.tree_util.tree_map(jnp.add, g_loads, step_loads)), None

        zeros = lambda tree: jax.tree_util.tree_map(jnp.zeros_like, tree)
        g_none = (zeros(first.pos), zeros(first.vel), zeros(first.quat), zeros(first.angvel),
                  zeros(first.normal_force), zeros(first.friction))
        first_applied = jax.tree_util.tree_map(lambda a: a[0], applied) if per_step else None
        # The sums have one step's structure: traced once for its shapes.
        _, body_shape, rows_shape, _, _ = jax.eval_shape(lambda: step_adjoint(first, g_none, first_applied))
        init_sums = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), (body_shape, rows_shape))
        no_loads = jax.tree_util.tree_map(zeros, net_wrench(model, params, None))
        (g_first, (body, rows), g_loads), stacked = jax.lax.scan(
            back, (g_none, init_sums, None if per_step else no_loads), (step_inputs, g_steps, applied), reverse=True)
        # Loads: force = m g + F (+ applied), torque = τ (+ applied).
        _, loads_vjp = jax.vjp(lambda p, a: net_wrench(model, p, a), params, applied)
        g_params, g_applied = loads_vjp(stacked if per_step else g_loads)
        steps_done = jnp.arange(1, num_steps + 1, dtype=g_steps.time.dtype)
        g_dt = (jnp.sum(body["h"]) + sum(jnp.sum(group["h"]) for group in rows)) / model.substeps
        g_params = dataclasses.replace(  # cotangents: not physical values, so not Params.replace
            g_params, dt=g_params.dt + g_dt + jnp.sum(g_steps.time * steps_done),
            penalty_stiffness=g_params.penalty_stiffness + sum(jnp.sum(group["stiffness"]) for group in rows))
        if model.penalty_smooth:
            g_params = dataclasses.replace(
                g_params, penalty_width=g_params.penalty_width + sum(jnp.sum(group["width"]) for group in rows))
        g_carry = Carry(pos=g_first[0], vel=g_first[1], quat=g_first[2], angvel=g_first[3],
                        normal_force=g_first[4], friction=g_first[5], time=jnp.sum(g_steps.time))
        return g_params, _prepared_cotangent(prepared, body, rows), g_carry, g_applied

    run.defvjp(run_forward, full_precision(run_backward))
    prepared = fast.prepare(params)
    carries = run(params, prepared, fast.to_carry(state, params), applied)
    return jax.vmap(lambda carry: fast.from_carry(carry, state, params))(carries)
