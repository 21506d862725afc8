"""``make_step`` builds the pure step function; ``rollout`` scans it over time."""

from __future__ import annotations

import math
from typing import Callable, Optional, Union

import jax
import jax.numpy as jnp

from jaxrb.dynamics import net_wrench
from jaxrb.integrators import INTEGRATORS
from jaxrb.types import Model, Params, State, Wrench


def make_step(model: Model) -> Callable:
    """Return ``step(state, params, applied=None) -> state`` for ``model``.

    The step is pure and written for one world: jit it, vmap it over states
    (``in_axes=(0, None)``) or params (``in_axes=(None, 0)``), scan it and
    differentiate it. ``applied`` is an optional :class:`~jaxrb.types.Wrench`
    held constant over the step (see :func:`jaxrb.dynamics.wrench_at_points`
    for forces at points). Only the stages ``model`` needs are traced.
    """
    advance = INTEGRATORS[model.integrator]
    substeps = model.substeps

    def step(state: State, params: Params, applied: Optional[Wrench] = None) -> State:
        h = params.dt / substeps
        force, torque = net_wrench(model, params, applied)
        # Substeps are few and fixed: unrolled in Python so XLA fuses across them.
        for _ in range(substeps):
            state = advance(model, params, state, force, torque, h)
        return state.replace(time=state.time + params.dt)

    step.model = model
    return step


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


def rollout(step: Callable, state: State, params: Params, num_steps: int, *, every: int = 1,
            checkpoint: Union[bool, int] = False, applied: Optional[Wrench] = None) -> State:
    """Run ``step`` for ``num_steps`` steps with ``lax.scan`` and stack the states.

    Args:
        step: a function from :func:`make_step`.
        state: initial State (not included in the output).
        params: Params, constant over the rollout.
        num_steps: number of steps; must be a multiple of ``every``.
        every: keep every ``every``-th state (the states after steps
            every, 2·every, ..., num_steps).
        checkpoint: ``False``; ``True`` to rematerialise in segments of about
            √(num_steps/every) saved states, so reverse-mode memory grows as
            about √T instead of T; or an int segment length in saved states.
        applied: optional Wrench with a leading time axis (num_steps, ...)
            applied one slice per step.

    Returns:
        State whose arrays have a leading axis of length num_steps // every.
    """
    if num_steps < 1 or every < 1 or num_steps % every:
        raise ValueError(f"rollout: num_steps ({num_steps}) must be a positive multiple of "
                         f"every ({every})")
    num_saved = num_steps // every
    if applied is not None:
        applied = jax.tree_util.tree_map(
            lambda a: a.reshape((num_saved, every) + a.shape[1:]), applied)

    def advance(current, applied_chunk):
        def one(inner, applied_now):
            return step(inner, params, applied_now), None

        current, _ = jax.lax.scan(one, current, applied_chunk, length=every)
        return current, current

    if not checkpoint:
        _, states = jax.lax.scan(advance, state, applied, length=num_saved)
        return states

    segment = _segment_length(num_saved, checkpoint)
    num_segments = num_saved // segment
    if applied is not None:
        applied = jax.tree_util.tree_map(
            lambda a: a.reshape((num_segments, segment) + a.shape[1:]), applied)

    @jax.checkpoint
    def run_segment(current, applied_segment):
        return jax.lax.scan(advance, current, applied_segment, length=segment)

    _, states = jax.lax.scan(run_segment, state, applied, length=num_segments)
    return jax.tree_util.tree_map(lambda a: a.reshape((num_saved,) + a.shape[2:]), states)
