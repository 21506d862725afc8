"""``make_step`` builds the pure step function; ``rollout`` scans it over time."""

from __future__ import annotations

import math
from typing import Callable, Optional, Union

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.physics import adjoint as hand_written
from jaxrb.physics.collision.pairs import detect
from jaxrb.compile import full_precision
from jaxrb.physics.contact import impulse, rows, toi
from jaxrb.physics.contact.common import carried_impulses, pad
from jaxrb.physics.contact.penalty import penalty_wrench
from jaxrb.physics.dynamics import net_wrench, with_inverse_inertia
from jaxrb.physics.integrators import INTEGRATORS, PHASES
from jaxrb.physics.joints.step import make_joint_step
from jaxrb.physics.plane_penalty import PlanePenalty, supports as plane_penalty_supports
from jaxrb.model.types import Model, Params, State, Wrench


def make_step(model: Model) -> Callable:
    """Return ``step(state, params, applied=None, controls=None) -> state`` for ``model``.

    The step is pure and written for one world: jit it, vmap it over states
    (``in_axes=(0, None)``) or params (``in_axes=(None, 0)``), scan it and
    differentiate it. ``applied`` is an optional :class:`~jaxrb.model.types.Wrench`
    held constant over the step (see :func:`jaxrb.physics.dynamics.wrench_at_points`
    for forces at points). Only the stages ``model`` needs are traced.

    A 3D penalty scene whose contacts are all against planes (semi-implicit
    integrator) steps in :mod:`jaxrb.physics.plane_penalty`'s component form: the
    State is split into x, y, z parts on entry and joined on exit, and every
    stage between works on (n,) arrays, which XLA's CPU backend vectorises
    (1.8× the batched throughput of :func:`generic_step`'s (n, 3) form). The
    same step serves ``rb.rollout`` and a user's own loop. A scene with
    joints steps its joint coordinates (:mod:`jaxrb.physics.joints.step`);
    ``controls`` (num_actuators,) drive its actuators, in the model's
    actuator order.

    Args:
        model: the static Model from ``Scene.build``; it decides what is compiled.

    Returns:
        The pure function ``step(state, params, applied=None, controls=None) -> State``:
        ``state`` a State (``pos`` (n, dim), ...), ``params`` the Params,
        ``applied`` an optional Wrench (force (n, dim), torque (n, 3) or (n,)),
        ``controls`` an optional (num_actuators,) array (None: zero).
        It advances ``state.time`` by ``params.dt``; ``step.model`` is ``model``.
    """
    if model.joints is not None:
        return make_joint_step(model)
    if not plane_penalty_supports(model):
        return generic_step(model)
    components = PlanePenalty(model)

    @full_precision  # float32 products in float32 on GPUs too (jaxrb.compile)
    def step(state: State, params: Params, applied: Optional[Wrench] = None, controls=None) -> State:
        _no_controls(controls)
        carry = components.step(components.to_carry(state, params), params, applied)
        return components.from_carry(carry, state, params)

    step.model = model
    return step


def generic_step(model: Model) -> Callable:
    """``make_step``'s step on (n, dim) arrays, for every model.

    ``make_step`` returns it for every model but the plane-penalty ones
    (see there), whose component form the tests hold to this one.

    Args:
        model: the static Model from ``Scene.build``.

    Returns:
        ``step(state, params, applied=None) -> State`` as :func:`make_step`'s.
    """
    substeps = model.substeps
    if model.contact == "none" or model.num_contacts == 0:
        # Contact asked for but nothing can touch (no planes, all pairs filtered).
        run_substeps = _free_substeps(model)
    elif model.contact == "penalty":
        run_substeps = _penalty_substeps(model)
    else:
        run_substeps = _impulse_substeps(model)

    @full_precision  # float32 products in float32 on GPUs too (jaxrb.compile)
    def step(state: State, params: Params, applied: Optional[Wrench] = None, controls=None) -> State:
        _no_controls(controls)
        force, torque = net_wrench(model, params, applied)
        state = run_substeps(state, params, force, torque, params.dt / substeps)
        return state.replace(time=state.time + params.dt)

    step.model = model
    return step


def _no_controls(controls) -> None:
    """A scene without actuators takes no controls: say so rather than ignore them."""
    if controls is not None and np.size(controls):
        raise ValueError(f"step: this model has no actuators, so 'controls' must be None, got shape "
                         f"{np.shape(controls)}")


# Free-body substeps are unrolled in Python so XLA fuses across them; the impulse
# solver's substeps and passes are fori_loops, compiled once (unrolling them made
# a one-box gradient take minutes to compile).

def _free_substeps(model: Model):
    advance = INTEGRATORS[model.integrator]

    def run(state, params, force, torque, h):
        for _ in range(model.substeps):
            state = advance(model, params, state, force, torque, h)
        return state

    return run


def _penalty_substeps(model: Model):
    velocity_phase, position_phase = PHASES[model.integrator]

    def run(state, params, force, torque, h):
        overflow = jnp.zeros((), dtype=bool)  # this step's substeps only, as State documents
        for _ in range(model.substeps):
            contacts = detect(model, params, state)
            overflow = overflow | contacts.overflow
            # State keeps impulses (force x h): the friction spring of a contact
            # that persists carries over.
            held = carried_impulses(state, contacts)[:, 1:] / h
            predicted = velocity_phase(model, params, state, force, torque, h)
            contact_force, contact_torque, normal_force, held = penalty_wrench(
                model, params, state, contacts, h, predicted, held)
            state = velocity_phase(model, params, state, force + contact_force, torque + contact_torque, h)
            state = position_phase(model, params, state, h)
            state = state.replace(contact_impulse=jnp.concatenate([normal_force[:, None], held], axis=-1) * h,
                                  contact_key=contacts.key)
        return state.replace(overflow=overflow)

    return run


def _unpad(state: State, vel, angvel) -> State:
    """Put padded (n + 1) solver velocities back into the state, dropping the static row."""
    return state.replace(vel=vel[:-1], angvel=angvel[:-1])


def _impulse_substeps(model: Model):
    velocity_phase, position_phase = PHASES[model.integrator]
    impact_rows = toi.toi_rows(model)

    def run(state, params, force, torque, h):
        contacts = detect(model, params, state)
        prep = rows.prepare(model, params, state, contacts)
        # The warm start, along each row's directions (rows.row_impulses).
        lam = rows.row_impulses(prep, carried_impulses(state, contacts))
        soft = impulse.soft_parameters(params, h)

        def warm_start(state, lam):
            vel, angvel = rows.push_rows(model, prep, pad(state.vel), pad(state.angvel), list(lam))
            return _unpad(state, vel, angvel)

        def solve(state, lam, prep, soft, passes):
            if passes == 0:
                return state, lam
            separation = rows.current_separation(model, prep, state)
            # A fori_loop, not a Python loop: the pass is compiled once, which
            # keeps compile time (and the reverse-mode program) small.
            one_pass = lambda _, carry: impulse.solve_pass(model, prep, *carry, separation, h, soft)
            if model.solver == "jacobi":
                # Reverse mode keeps each Jacobi pass's input and recomputes the
                # pass, not a stack per intermediate written in the forward loop
                # and read back: the bouncing box's gradient took 0.84-0.99x the
                # time (docs/design.md, 'Reverse mode'). The sequential passes
                # are rematerialised row by row instead (contact.sequential._sweep_rows).
                one_pass = jax.checkpoint(one_pass, prevent_cse=False)
            vel, angvel, lam = jax.lax.fori_loop(0, passes, one_pass, (pad(state.vel), pad(state.angvel), lam))
            return _unpad(state, vel, angvel), lam

        def substep(_, carry):
            state, lam = carry
            if len(impact_rows):
                start_speed = rows.normal_velocity(model, prep, state)
            state = velocity_phase(model, params, state, force, torque, h)
            # Restitution uses the approach speed including this substep's loads
            # (gravity): the speed the contact is actually hit with.
            prep_now = prep.replace(approach=rows.normal_velocity(model, prep, state))
            if len(impact_rows):
                # Fast approaches of the time-of-impact rows are theirs alone: the
                # solver would otherwise stop them speculatively a substep early.
                separation = rows.current_separation(model, prep_now, state)
                owned = toi.owned_rows(prep_now, separation, params.bounce_threshold, impact_rows)
                vel, angvel, shift, turn = toi.resolve_impacts(
                    model, prep_now, pad(state.vel), pad(state.angvel), separation, owned, start_speed, h,
                    impact_rows)
                state = _unpad(state, vel, angvel)
                prep_now = prep_now.replace(active=prep_now.active & ~owned)
                lam = tuple(jnp.where(owned, 0.0, part) for part in lam)  # no warm start for a skipped row
            # Warm start: the substep begins with the last substep's (or step's) impulses.
            state = warm_start(state, lam)
            state, lam = solve(state, lam, prep_now, soft, model.iterations)
            state = position_phase(model, params, state, h)
            if len(impact_rows):
                state = toi.shift_pose(model, params, state, shift, turn)
            state, lam = solve(state, lam, prep_now, None, model.relax_iterations)
            # Bouncing in the substep of impact (not at the step's end) keeps a
            # bounce from waiting on the plane for the remaining substeps.
            vel, angvel, lam = impulse.restitution_pass(model, prep_now, pad(state.vel), pad(state.angvel),
                                                        lam, params.bounce_threshold)
            return _unpad(state, vel, angvel), lam

        state, lam = jax.lax.fori_loop(0, model.substeps, substep, (state, lam))
        return state.replace(contact_impulse=rows.world_impulses(prep, lam), contact_key=contacts.key,
                             overflow=contacts.overflow)

    return run


def _segment_length(num_saved: int, checkpoint: Union[bool, int]) -> int:
    """Saved states per checkpointed segment: about sqrt(num_saved), dividing it."""
    if checkpoint is True:
        target = max(1, int(round(math.sqrt(num_saved))))
        divisors = [d for d in range(1, num_saved + 1) if num_saved % d == 0]
        return min(divisors, key=lambda d: (abs(d - target), d))
    length = int(checkpoint)
    if length < 1 or num_saved % length:
        raise ValueError(f"rollout: 'checkpoint' segment length {checkpoint!r} must be a positive "
                         f"divisor of the number of saved states ({num_saved})")
    return length


def _check_adjoint(model: Optional[Model], checkpoint) -> None:
    """Raise a ValueError naming why ``rollout(..., adjoint=True)`` cannot run."""
    if model is None:
        raise ValueError("rollout: adjoint=True needs a step from jaxrb.make_step (it reads step.model)")
    if not hand_written.supports(model):
        raise ValueError(
            f"rollout: adjoint=True is written for 3D semi-implicit models without damping: free bodies, or "
            f"penalty contact with spring friction against planes only; this model has dim={model.dim}, "
            f"integrator={model.integrator!r}, contact={model.contact!r} with {model.num_contacts} contact rows, "
            f"penalty_friction={model.penalty_friction!r}, damping={model.damping} (use adjoint=False)")
    if checkpoint:
        raise ValueError("rollout: adjoint=True keeps every step's input State; checkpoint segments are not "
                         "available with it (pass checkpoint=False)")


def rollout(step: Callable, state: State, params: Params, num_steps: int, *, every: int = 1,
            checkpoint: Union[bool, int] = False, applied: Optional[Wrench] = None,
            adjoint: bool = False, controls=None) -> State:
    """Run ``step`` for ``num_steps`` steps with ``lax.scan`` and stack the states.

    Args:
        step: a function from :func:`make_step`.
        state: initial State (not included in the output).
        params: Params, constant over the rollout.
        num_steps: number of steps; must be a multiple of ``every``.
        every: keep every ``every``-th state (the states after steps
            every, 2·every, ..., num_steps).
        checkpoint: ``False``; ``True`` to rematerialise in segments of about
            √(num_steps/every) saved states, so reverse mode keeps about √T
            step inputs instead of T; or an int segment length in saved
            states. Each step is rematerialised on its own in any case, so
            reverse mode keeps one State a step, not the step's
            intermediates; the trajectory returned is num_steps // every
            States with or without segments, so segments pay when
            ``every`` > 1.
        applied: optional Wrench with a leading time axis (num_steps, ...)
            applied one slice per step.
        controls: optional (num_steps, num_actuators) actuator inputs, one
            row per step (a scene with actuators; None: zero).
        adjoint: reverse mode by :mod:`jaxrb.physics.adjoint`'s hand-written adjoint
            instead of autodiff: for 3D semi-implicit models without damping
            (``jaxrb.physics.adjoint.supports``), free bodies (a gradient 2-4×
            cheaper, docs/design.md, 'Hand-written adjoints') and penalty contact
            with spring friction against planes. The States
            are the same (for penalty contact to float rounding);
            forward mode (``jax.jvp``, ``jax.jacfwd``) is not available
            through such a rollout, and ``checkpoint`` must stay False (it
            keeps every step's input State, as ``checkpoint=False`` does).

    Returns:
        State whose arrays have a leading axis of length num_steps // every.

    The scan runs ``step`` itself, so a rollout and a user's own loop over
    the same step give the same states.
    """
    if num_steps < 1 or every < 1 or num_steps % every:
        raise ValueError(f"rollout: num_steps ({num_steps}) must be a positive multiple of "
                         f"every ({every})")
    num_saved = num_steps // every
    model = getattr(step, "model", None)
    if adjoint:
        _check_adjoint(model, checkpoint)
    if model is not None:
        # Inverted once here, not in every step: reverse mode then sums the
        # inverse's cotangent over the steps and transposes the inverse once.
        params = with_inverse_inertia(params, model.dim)
    if adjoint:
        return hand_written.rollout(step, state, params, num_steps, every, applied)
    inputs = (applied, controls)
    if controls is not None and np.shape(controls)[0] != num_steps:
        raise ValueError(f"rollout: 'controls' must have one row per step ({num_steps}), got shape "
                         f"{np.shape(controls)}")
    inputs = jax.tree_util.tree_map(lambda a: a.reshape((num_saved, every) + a.shape[1:]), inputs)

    def advance_one(current, inputs_now):
        applied_now, controls_now = inputs_now
        if controls_now is None:  # a step from before controls took (state, params, applied) only
            return step(current, params, applied_now)
        return step(current, params, applied_now, controls_now)
    # Reverse mode recomputes each step from its carried state instead of
    # storing the step's intermediates (scalars per body component, a hundred
    # or more a step, each its own buffer written in the forward loop and read
    # in the backward one): that traffic cost more than the step itself. The
    # forward-only program is unchanged (docs/design.md, 'Reverse mode').
    advance_one = jax.checkpoint(advance_one, prevent_cse=False)

    def advance(current, inputs_chunk):
        def one(inner, inputs_now):
            return advance_one(inner, inputs_now), None

        current, _ = jax.lax.scan(one, current, inputs_chunk, length=every)
        return current, current

    if not checkpoint:
        _, states = jax.lax.scan(advance, state, inputs, length=num_saved)
        return states

    segment = _segment_length(num_saved, checkpoint)
    num_segments = num_saved // segment
    inputs = jax.tree_util.tree_map(lambda a: a.reshape((num_segments, segment) + a.shape[1:]), inputs)

    @jax.checkpoint
    def run_segment(current, inputs_segment):
        return jax.lax.scan(advance, current, inputs_segment, length=segment)

    _, states = jax.lax.scan(run_segment, state, inputs, length=num_segments)
    return jax.tree_util.tree_map(lambda a: a.reshape((num_saved,) + a.shape[2:]), states)
