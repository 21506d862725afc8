"""Hand-written reverse mode of free-body rollouts (``rb.rollout(..., adjoint=True)``, :mod:`jaxrb.physics.adjoint`).

Autodiff's reverse mode of a rollout recomputes each step in the backward
loop and transposes it (``rb.rollout`` rematerialises every step). On XLA's
CPU backend that transpose fuses badly: each of the state's 13 cotangent
components is computed in its own kernel, and every kernel re-derives the
intermediates it shares with the others, so a batched gradient costs 7-10
forward rollouts (docs/design.md, 'Hand-written adjoints'). This module writes the
adjoint of the 3D semi-implicit free-body step by hand:

* the forward loop is ``make_step``'s own (the trajectory is bit for bit
  ``rb.rollout``'s), and with ``every=1`` it stores nothing more: each step's
  input State is the previous output;
* the backward loop recomputes one step's intermediates from its input
  State, then applies the chain rule on components; the values many
  cotangents share are computed once (``components.materialize``), and
  the recompute and the adjoint rotate vectors by stored rotation
  matrices rather than by quaternions (:func:`_rotation`);
* the parameters' cotangents are summed in the loop's carry (25 numbers
  a body), except applied loads', which leave the loop stacked (6 a body a
  step) because applied loads change from step to step.

What it covers (:func:`supports`): 3D bodies, integrator ``semi_implicit``
(either orientation update), no contact and no damping; any number of
substeps; gravity, constant and applied loads; ``every`` and ``vmap``.
Bodies against planes with penalty contact have their own adjoint, built
on this one's substep (:mod:`jaxrb.physics.plane_penalty_adjoint`);
:mod:`jaxrb.physics.adjoint` picks between the two.

The price is forward mode: a ``jax.custom_vjp`` function cannot be
differentiated by ``jax.jvp``/``jax.jacfwd``, so ``adjoint=True`` is for
reverse mode (``jax.grad``, ``jax.vjp``, fits). Forward-mode users keep the
default.

Components: a vector is a tuple of (n,) arrays (x, y, z), a quaternion
(w, x, y, z), a 3×3 matrix a tuple of rows (:mod:`jaxrb.math.components`).
``g_<name>`` is the cotangent of ``<name>``.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Optional

import jax
import jax.numpy as jnp

from jaxrb.math import components as vec

from jaxrb.math import quaternion as quat_ops
from jaxrb.compile import full_precision
from jaxrb.physics.dynamics import net_wrench
from jaxrb.math.vector import unstack
from jaxrb.model.types import Model, Params, State, Wrench


def supports(model: Model) -> bool:
    """Whether ``model`` is a free-body model this module's adjoint covers.

    Args:
        model: a Model from ``Scene.build``.

    Returns:
        True for 3D semi-implicit models without damping and without contact rows.
    """
    return (model.dim == 3 and model.integrator == "semi_implicit" and not model.damping
            and (model.contact == "none" or model.num_contacts == 0))


# ---------------------------------------------------------------- primitive adjoints

def _conjugate(q):
    return (q[0], -q[1], -q[2], -q[3])


def _rotation(q, keep: Callable):
    """R(q/|q|) as 3 rows of 3 parts, stored once; what ``quaternion.rotate_parts(q, ·)`` applies.

    The backward loop rotates by these stored entries (each rotated
    component three products) instead of by the quaternion formula, whose
    three components share t = 2 u × v: XLA's CPU fusion recomputed t (and,
    in the penalty adjoint, R(q)'s entries) in every kernel that read a
    rotated vector. With this and the factors :func:`_rotate` and
    :func:`_normalize_adjoint` store, the free-body backward loop compiled
    to 0.58× its arithmetic and the penalty drop's to 0.63×, and their
    gradients took 0.83–0.93× the time (docs/design.md, 'Hand-written adjoints').
    """
    return vec.stored_matrix(quat_ops.rotation_matrix_parts(q, 2.0 / vec.dot(q, q)), keep)


def _rotate(q, rotation, out, g_out, keep: Callable, inverse: bool = False):
    """Cotangents (g_q, g_v) of out = R(q) v (or R(q)ᵀ v with ``inverse``), from the value ``out``.

    R(q) v depends on q only through q/|q|: a change δq turns ``out`` by
    δθ = 2 vec(δq ⊗ q̄)/|q|², so g·δout = δθ·(out × g) and
    g_q = (2/|q|²) (0, out × g) ⊗ q; g_v = R(q)ᵀ g. For R(q)ᵀ v = R(q̄) v
    the same holds with q̄ (and the conjugate taken back), g_v = R(q) g.
    ``rotation`` is :func:`_rotation` of q. ``keep`` stores
    a = (2/|q|²) (out × g), which every part of g_q reads, and both results
    once for all their users (``components.materialize``).
    """
    turned = _conjugate(q) if inverse else q
    w, u = turned[0], turned[1:]
    a = keep(vec.along(2.0 / vec.dot(q, q), vec.cross(out, g_out)))
    g_q = (-vec.dot(a, u),) + vec.add(vec.along(w, a), vec.cross(a, u))
    if inverse:
        g_q, g_v = _conjugate(g_q), vec.matvec(rotation, g_out)
    else:
        g_v = vec.matvec_transposed(rotation, g_out)
    stored = keep(g_q + g_v)
    return stored[:4], stored[4:]


def _multiply_adjoint(a, b, g_out):
    """Cotangents (g_a, g_b) of the quaternion product a ⊗ b (bilinear: L(a)ᵀ = L(ā), R(b)ᵀ = R(b̄))."""
    return (quat_ops.multiply_parts(g_out, _conjugate(b)),
            quat_ops.multiply_parts(_conjugate(a), g_out))


def _normalize_adjoint(y, g_out, keep):
    """Cotangent of y in ``quaternion.normalize_parts(y)`` (zero where y = 0, like the fallback).

    Each of the four results reads every part of y/|y| and g·y/|y|, and
    each is read by the eight parts of a quaternion product's adjoint:
    both are stored once (``keep``), or XLA recomputes them in each.
    """
    norm_sq = vec.dot(y, y)
    nonzero = norm_sq > 0.0
    inv_norm = 1.0 / jnp.sqrt(jnp.where(nonzero, norm_sq, 1.0))
    unit = vec.along(inv_norm, y)
    stored = keep(unit + (vec.dot(unit, g_out), inv_norm))
    unit, radial, inv_norm = stored[:4], stored[4], stored[5]
    return keep(tuple(jnp.where(nonzero, inv_norm * (g - radial * e), 0.0) for g, e in zip(g_out, unit)))


def _exp_adjoint(rotvec, theta_sq, cos_half, sinc_half, g_turn):
    """Cotangent of the rotation vector from that of (cos θ/2, sinc·rotvec), as ``_half_angle_terms`` computes them.

    d cos(θ/2)/dθ² = −sinc/4 and d(sin(θ/2)/θ)/dθ² = (cos(θ/2) − 2 sinc)/(4θ²),
    with the derivatives of the forward's series below θ² = 1e-8.
    """
    small = theta_sq < 1e-8
    safe_sq = jnp.where(small, 1.0, theta_sq)
    d_cos = jnp.where(small, -1.0 / 8.0 + theta_sq / 192.0, -0.25 * sinc_half)
    d_sinc = jnp.where(small, -1.0 / 48.0 + theta_sq / 1920.0, (cos_half - 2.0 * sinc_half) / (4.0 * safe_sq))
    g_vector = g_turn[1:]
    g_theta_sq = g_turn[0] * d_cos + vec.dot(g_vector, rotvec) * d_sinc
    return vec.add(vec.along(sinc_half, g_vector), vec.along(2.0 * g_theta_sq, rotvec))


def _first_order_adjoint(q, angvel, h, g_out, keep):
    """Cotangents (g_q, g_angvel, g_h) of ``quaternion.integrate_first_order_parts``."""
    omega = (jnp.zeros_like(angvel[0]),) + tuple(angvel)
    change = quat_ops.multiply_parts(omega, q)
    y = tuple(a + (0.5 * h) * b for a, b in zip(q, change))
    g_y = _normalize_adjoint(y, g_out, keep)
    g_omega, g_q_change = _multiply_adjoint(omega, q, vec.along(0.5 * h, g_y))
    return tuple(a + b for a, b in zip(g_y, g_q_change)), g_omega[1:], 0.5 * vec.dot(g_y, change)


def _exp_map_adjoint(q, angvel, h, g_out, keep):
    """Cotangents (g_q, g_angvel, g_h) of ``quaternion.integrate_exp_map_parts``."""
    rotvec = vec.along(h, angvel)
    theta_sq = vec.dot(rotvec, rotvec)
    cos_half, sinc_half = quat_ops._half_angle_terms(theta_sq)
    turn = (cos_half,) + vec.along(sinc_half, rotvec)
    g_y = _normalize_adjoint(quat_ops.multiply_parts(turn, q), g_out, keep)
    g_turn, g_q = _multiply_adjoint(turn, q, g_y)
    g_rotvec = _exp_adjoint(rotvec, theta_sq, cos_half, sinc_half, g_turn)
    return g_q, vec.along(h, g_rotvec), vec.dot(g_rotvec, angvel)


_ORIENTATION_ADJOINTS = {"first_order": _first_order_adjoint, "exp_map": _exp_map_adjoint}


# ---------------------------------------------------------------- one substep

def _substep_values(orientation, inertia, inv_inertia, pos, vel, quat, angvel, accel, torque, h, keep,
                    rotation=None):
    """One semi-implicit substep on components, and the intermediates its adjoint reads.

    The arithmetic of ``integrators.semi_implicit`` (velocity phase, then the
    position phase, which keeps world L and re-expresses ω in the new frame),
    its rotations by stored matrices (:func:`_rotation`), so the recomputed
    values equal the forward's to rounding, not bit for bit.

    Args:
        keep: stores a tuple of parts once for all its users.
        rotation: R(quat) as 3 rows of 3 parts, if the caller has it stored
            (else computed here).

    Returns:
        ((pos, vel, quat, angvel) after the substep, dict of intermediates).
    """
    rotation = _rotation(quat, keep) if rotation is None else rotation
    torque_body = vec.matvec_transposed(rotation, torque)
    spin_body = vec.matvec(inv_inertia, torque_body)
    spin = vec.matvec(rotation, spin_body)
    vel1 = vec.add(vel, vec.along(h, accel))
    angvel1 = vec.add(angvel, vec.along(h, spin))
    pos1 = vec.add(pos, vec.along(h, vel1))
    body = vec.matvec_transposed(rotation, angvel1)
    body_momentum = vec.matvec(inertia, body)
    momentum = vec.matvec(rotation, body_momentum)
    quat1 = quat_ops.ORIENTATION_UPDATES_PARTS[orientation](quat, angvel1, h)
    rotation1 = _rotation(quat1, keep)
    momentum_new_frame = vec.matvec_transposed(rotation1, momentum)
    change = vec.sub(momentum_new_frame, body_momentum)
    body1 = vec.add(body, vec.matvec(inv_inertia, change))
    angvel2 = vec.matvec(rotation1, body1)
    saved = dict(quat=quat, rotation=rotation, torque_body=torque_body, spin=spin, vel1=vel1, angvel1=angvel1,
                 body=body, momentum=momentum, quat1=quat1, rotation1=rotation1,
                 momentum_new_frame=momentum_new_frame, change=change, angvel2=angvel2)
    return (pos1, vel1, quat1, angvel2), saved


def _substep_adjoint(orientation, inertia, inv_inertia, accel, h, saved, g_out, keep):
    """Cotangents of one substep's state inputs, and the factors of its parameters' cotangents.

    Args:
        orientation: the Model's orientation update.
        inertia, inv_inertia: 3×3 component matrices.
        accel: the substep's linear acceleration (components).
        h: () substep length.
        saved: the intermediates from :func:`_substep_values`.
        g_out: cotangents of (pos, vel, quat, angvel) after the substep.
        keep: stores a tuple of parts once for all its users.

    Returns:
        (g_state, sums, loads): g_state the cotangents of (pos, vel, quat,
        angvel) before the substep; sums a dict of this substep's terms of
        the parameters' cotangents, which the backward loop accumulates in
        its carry: ``inv_inertia`` and ``inertia`` (9-tuples, the (i, j)
        entries row by row, each (n,)) and ``h`` (n,); loads (6, n): the
        cotangents of the acceleration (times h) and of the torque, kept per
        step because applied loads change from step to step.
    """
    g_pos1, g_vel1, g_quat1, g_angvel2 = g_out
    s = saved
    quat, rotation, quat1, rotation1 = s["quat"], s["rotation"], s["quat1"], s["rotation1"]
    g_quat1_a, g_body1 = _rotate(quat1, rotation1, s["angvel2"], g_angvel2, keep)
    g_change = keep(vec.matvec_transposed(inv_inertia, g_body1))
    g_quat1_b, g_momentum = _rotate(quat1, rotation1, s["momentum_new_frame"], g_change, keep, inverse=True)
    g_quat1 = keep(tuple(a + b + c for a, b, c in zip(g_quat1, g_quat1_a, g_quat1_b)))
    g_quat, g_angvel1, g_h = _ORIENTATION_ADJOINTS[orientation](quat, s["angvel1"], h, g_quat1, keep)
    g_angvel1 = keep(g_angvel1)
    g_quat_m, g_body_momentum = _rotate(quat, rotation, s["momentum"], g_momentum, keep)
    g_body_momentum = vec.sub(g_body_momentum, g_change)
    g_body = keep(vec.add(g_body1, vec.matvec_transposed(inertia, g_body_momentum)))
    g_quat_b, g_angvel1_b = _rotate(quat, rotation, s["body"], g_body, keep, inverse=True)
    g_angvel1 = vec.add(g_angvel1, g_angvel1_b)
    g_vel1 = vec.add(g_vel1, vec.along(h, g_pos1))
    g_h = g_h + vec.dot(g_pos1, s["vel1"]) + vec.dot(g_angvel1, s["spin"]) + vec.dot(g_vel1, accel)
    g_quat_s, g_spin_body = _rotate(quat, rotation, s["spin"], vec.along(h, g_angvel1), keep)
    g_quat_t, g_torque = _rotate(quat, rotation, s["torque_body"], vec.matvec_transposed(inv_inertia, g_spin_body),
                                 keep, inverse=True)
    g_quat = tuple(sum(parts) for parts in zip(g_quat, g_quat_m, g_quat_b, g_quat_s, g_quat_t))
    sums = dict(inv_inertia=tuple(a + b for a, b in zip(_outer(g_body1, s["change"]),
                                                        _outer(g_spin_body, s["torque_body"]))),
                inertia=_outer(g_body_momentum, s["body"]), h=g_h)
    return (g_pos1, g_vel1, g_quat, g_angvel1), sums, jnp.stack(vec.along(h, g_vel1) + g_torque)


def _outer(a, b):
    """The outer product a bᵀ of two component vectors, as a 9-tuple of its entries row by row."""
    return tuple(x * y for x in a for y in b)


# ---------------------------------------------------------------- one step

def _step_adjoint(model: Model, params: Params, state: State, applied: Optional[Wrench], g_after, keep):
    """Cotangents of one ``make_step`` step's input State from those of its output State.

    Args:
        model: a Model that :func:`supports` accepts.
        params: Params with ``inv_inertia`` filled.
        state: the step's input State.
        applied: this step's Wrench, or None.
        g_after: cotangents of the output's (pos, vel, quat, angvel) as components.
        keep: as for :func:`_substep_adjoint`.

    Returns:
        (g_before, sums, loads): g_before like g_after for the input State;
        sums and loads the :func:`_substep_adjoint` ones summed over the
        step's substeps.
    """
    force, torque = net_wrench(model, params, applied)
    accel, torque = unstack(force / params.mass[:, None]), unstack(torque)
    inertia, inv_inertia = vec.matrix_parts(params.inertia), vec.matrix_parts(params.inv_inertia)
    h = params.dt / model.substeps
    values = tuple(unstack(getattr(state, name)) for name in _STATE_VECTORS)
    saved = []
    for _ in range(model.substeps):
        values, intermediates = _substep_values(model.orientation, inertia, inv_inertia, *values, accel,
                                                torque, h, keep)
        saved.append(intermediates)
    g_state, sums, loads = g_after, None, None
    for intermediates in reversed(saved):
        g_state, substep_sums, substep_loads = _substep_adjoint(model.orientation, inertia, inv_inertia, accel,
                                                                h, intermediates, g_state, keep)
        sums, loads = ((substep_sums, substep_loads) if sums is None else
                       (jax.tree_util.tree_map(jnp.add, sums, substep_sums), loads + substep_loads))
    return g_state, sums, loads


def _parameter_cotangents(model: Model, params: Params, applied: Optional[Wrench], sums, loads, g_times):
    """The Params' (and applied loads') cotangents from the backward loop's sums and per-step loads.

    Args:
        model, params: as for :func:`_step_adjoint`.
        applied: None or the Wrench of every step, leading axis T.
        sums: :func:`_step_adjoint`'s sums, accumulated over every step.
        loads: (T, 6, n) :func:`_step_adjoint`'s loads of every step, or
            (1, 6, n) their sum when ``applied`` is None (the loads are then
            the same at every step, and each cotangent is linear in them).
        g_times: (T,) cotangent of each step's output time.

    Returns:
        (g_params, g_applied): Params of cotangents (zero where the step does
        not read the field) and the Wrench of cotangents, leading axis T (or None).
    """
    def matrices(entries):
        # 9-tuple of (n,), row by row -> (n, 3, 3)
        return jnp.stack(entries, -1).reshape(entries[0].shape + (3, 3))

    g_accel = jnp.moveaxis(loads[:, :3], 1, 2)              # (T, n, 3)
    g_torque = jnp.moveaxis(loads[:, 3:], 1, 2)
    force, _ = net_wrench(model, params, applied)           # (n, 3), or (T, n, 3) with applied loads
    g_force = g_accel / params.mass[:, None]
    g_mass = (jnp.sum(g_force * params.gravity, axis=(0, 2))
              - jnp.sum(g_accel * force, axis=(0, 2)) / params.mass ** 2)
    # Step t's output time is t + 1 steps of dt after the start.
    steps_done = jnp.arange(1, g_times.shape[0] + 1, dtype=g_times.dtype)
    g_dt = jnp.sum(sums["h"]) / model.substeps + jnp.sum(g_times * steps_done)
    g_params = dataclasses.replace(  # cotangents: not physical values, so not Params.replace
        jax.tree_util.tree_map(jnp.zeros_like, params),
        mass=g_mass, force=jnp.sum(g_force, axis=0), torque=jnp.sum(g_torque, axis=0),
        gravity=jnp.sum(g_force * params.mass[:, None], axis=(0, 1)), dt=g_dt,
        inertia=matrices(sums["inertia"]), inv_inertia=matrices(sums["inv_inertia"]))
    return g_params, None if applied is None else Wrench(force=g_force, torque=g_torque)


# ---------------------------------------------------------------- the rollout

_STATE_VECTORS = ("pos", "vel", "quat", "angvel")


def _split_leading(tree, outer: int, inner: int):
    """(outer·inner, ...) -> (outer, inner, ...) for every leaf."""
    return jax.tree_util.tree_map(lambda a: a.reshape((outer, inner) + a.shape[1:]), tree)


def _merge_leading(tree):
    """(outer, inner, ...) -> (outer·inner, ...) for every leaf."""
    return jax.tree_util.tree_map(lambda a: a.reshape((-1,) + a.shape[2:]), tree)


def backward_loop_inputs(first, inputs, g_outputs, every: int):
    """What a backward loop over the steps scans: each step's input state and output cotangent.

    Args:
        first: the rollout's initial state (any pytree).
        inputs: with ``every`` = 1 the trajectory (T, ...) itself, else the
            step inputs the forward loop kept, (T/every, every, ...).
        g_outputs: cotangents of the saved states, (T/every, ...).
        every: the rollout's ``every``.

    Returns:
        ``(step_inputs, g_steps)``, both (T, ...): step t's input state and
        the cotangent of its output (zero between saved states).
    """
    if every == 1:
        # Step t's input is step t − 1's output: the trajectory shifted by one
        # step, copied. Read by index inside the loop instead, a vmapped
        # trajectory is (worlds, T, ...) and every step's read strided across
        # it: the tumbler's gradient at 1 024 worlds took 1.19-1.20x as long
        # (docs/design.md, 'Hand-written adjoints').
        def shifted(trajectory, start):
            start = jnp.broadcast_to(jnp.asarray(start, trajectory.dtype), trajectory.shape[1:])
            return jnp.concatenate([start[None], trajectory[:-1]])

        return jax.tree_util.tree_map(shifted, inputs, first), g_outputs
    num_saved = jax.tree_util.tree_leaves(g_outputs)[0].shape[0]
    g_steps = _merge_leading(jax.tree_util.tree_map(
        lambda g: jnp.zeros((num_saved, every) + g.shape[1:], g.dtype).at[:, -1].set(g), g_outputs))
    return _merge_leading(inputs), g_steps


def rollout(step: Callable, state: State, params: Params, num_steps: int, every: int,
            applied: Optional[Wrench]) -> State:
    """``rb.rollout(..., adjoint=True)`` for a free-body model: the same States, this module's reverse mode.

    Args and the States returned as for :func:`jaxrb.physics.adjoint.rollout`, which
    calls this for a model :func:`supports` accepts; the States are bit for
    bit ``rb.rollout``'s. Reverse mode keeps every step's input State (T
    States, as ``rb.rollout`` without segments; with ``every=1`` these are
    the trajectory itself, which the backward pass copies shifted by a step:
    :func:`backward_loop_inputs`).
    """
    model = step.model
    num_saved = num_steps // every

    def forward(params, state, applied, keep_inputs):
        def one(current, applied_now):
            return step(current, params, applied_now), (current if keep_inputs else None)

        def chunk(current, applied_chunk):
            current, inputs = jax.lax.scan(one, current, applied_chunk, length=every)
            return current, (current, inputs)

        chunks = None if applied is None else _split_leading(applied, num_saved, every)
        _, (states, inputs) = jax.lax.scan(chunk, state, chunks, length=num_saved)
        return states, inputs

    @jax.custom_vjp
    def run(params, state, applied):
        return forward(params, state, applied, False)[0]

    def run_forward(params, state, applied):
        # Each step's input is the previous step's output: with every == 1 the
        # trajectory holds them all and the forward loop stores nothing more.
        states, inputs = forward(params, state, applied, every > 1)
        return states, (params, state, states if every == 1 else inputs, applied)

    def run_backward(residuals, g_states):
        params, first, inputs, applied = residuals
        step_inputs, g_steps = backward_loop_inputs(first, inputs, g_states, every)

        def keep(parts):
            return vec.materialize(parts, params)

        # The loop carries the state's cotangent and the sums of the parameters'
        # (25 per body): at 1 024 worlds, stacking the sums' factors per step
        # and contracting them after the loop cost more than the loop itself.
        # Constant loads' cotangents are summed there too; applied loads'
        # leave the loop per step, as the Wrench of each step needs its own.
        def back(carry, x):
            g_state, sums = carry
            before, g_now, applied_now = x
            g_after = tuple(vec.add(g, unstack(getattr(g_now, name))) for g, name in zip(g_state, _STATE_VECTORS))
            g_before, step_sums, loads = _step_adjoint(model, params, before, applied_now, g_after, keep)
            if applied is None:
                step_sums, loads = dict(step_sums, loads=loads), None
            return (g_before, jax.tree_util.tree_map(jnp.add, sums, step_sums)), loads

        init = tuple(unstack(jnp.zeros_like(getattr(first, name))) for name in _STATE_VECTORS)
        zero = jnp.zeros_like(params.mass)
        no_sums = dict(inv_inertia=(zero,) * 9, inertia=(zero,) * 9, h=zero)
        if applied is None:
            no_sums["loads"] = jnp.zeros((6,) + zero.shape, zero.dtype)
        xs = (step_inputs, g_steps, applied)
        (g_first, sums), loads = jax.lax.scan(back, (init, no_sums), xs, reverse=True)
        loads = sums["loads"][None] if applied is None else loads
        g_params, g_applied = _parameter_cotangents(model, params, applied, sums, loads, g_steps.time)
        # The State's other fields (contact, momentum carry) are None for every model supports() accepts.
        g_state = first.replace(time=jnp.sum(g_steps.time),
                                **{name: jnp.stack(parts, -1) for name, parts in zip(_STATE_VECTORS, g_first)})
        return g_params, g_state, g_applied

    # The backward pass's products at full precision, as make_step's (no TF32 on GPUs).
    run.defvjp(run_forward, full_precision(run_backward))
    return run(params, state, applied)
