"""Compiled rollouts of the hard cases, run in chunks and cached per Model.

:func:`simulate` runs a scene in compiled chunks of ``lax.scan``, checks each
chunk for NaN/inf on the host, and keeps a :class:`Trace` of summaries (pose,
velocity, total kinetic energy, deepest penetration) of every ``every``-th
state, or only what a ``reduce`` function keeps of each chunk (for long runs).

Compiled rollouts are cached per Model (:func:`_chunk_runner`): cases with
the same Model share one compile (a 3-box column in the stack search, the
mass-ratio column and the long rest; the 2D pyramids of the same size), and
a compile reported as 0 s was a cache hit.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np

import jaxrb as rb
from jaxrb.compile import jit

_RUNNERS: dict = {}


def _summary(model, params, state):
    """What a case keeps of one saved state: pose, velocity, total KE, deepest penetration."""
    kinetic = jnp.sum(rb.kinetic_energy(model, params, state))
    if model.contact != "none" and model.num_contacts:
        contacts = rb.detect_contacts(model, params, state)
        penetration = jnp.max(jnp.where(contacts.active, -contacts.dist, 0.0))
    else:
        penetration = jnp.zeros((), state.pos.dtype)
    return dict(pos=state.pos, vel=state.vel, kinetic=kinetic, penetration=penetration)


def _chunk_runner(model, state, params, every: int, samples: int, batched: bool = False):
    """Compiled ``chunk(state, params) -> (state, summaries)`` of ``every * samples`` steps.

    Cached on (model, every, samples, batched, dtype and shapes), so cases with
    the same Model share the compile. Returns ``(compiled, compile_s)``;
    ``compile_s`` is 0 on a cache hit.
    """
    shapes = tuple((leaf.shape, str(leaf.dtype)) for leaf in jax.tree_util.tree_leaves((state, params)))
    key = (model, every, samples, batched, shapes)
    if key in _RUNNERS:
        return _RUNNERS[key], 0.0
    step = rb.make_step(model)

    def chunk(current, params_):
        def advance(inner, _):
            inner = jax.lax.scan(lambda s, __: (step(s, params_), None), inner, None, length=every)[0]
            return inner, _summary(model, params_, inner)

        return jax.lax.scan(advance, current, None, length=samples)

    if batched:
        chunk = jax.vmap(chunk, in_axes=(0, None))
    start = time.perf_counter()
    compiled = jit(chunk).lower(state, params).compile()
    _RUNNERS[key] = compiled
    return compiled, time.perf_counter() - start


@dataclasses.dataclass
class Trace:
    """Saved summaries of a simulation (leading axis: saved samples; batch next when batched).

    Attributes:
        times: (T,) simulated seconds of the samples.
        pos: (T, [B,] n, dim) centre-of-mass positions.
        vel: (T, [B,] n, dim) velocities.
        kinetic: (T, [B]) total kinetic energy (J).
        penetration: (T, [B]) deepest contact penetration (m), 0 without contact.
        steps: steps simulated (a multiple of the chunk length).
        finite: False when a chunk produced a non-finite value (simulation stopped there).
        compile_s, run_s: compile seconds (0 on a cache hit) and wall seconds of the runs.
    """

    times: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    kinetic: np.ndarray
    penetration: np.ndarray
    steps: int
    finite: bool
    compile_s: float
    run_s: float


def simulate(model, params, state, num_steps: int, every: int, chunk_steps: int, batched: bool = False,
             reduce: Optional[Callable] = None) -> Trace:
    """Run ``num_steps`` steps (rounded up to whole chunks) and keep every ``every``-th state's summary.

    Args:
        model, params, state: from ``Scene.build`` (state with a leading batch
            axis when ``batched``: pos (B, n, dim), ...).
        num_steps: steps to run, rounded up to a multiple of ``chunk_steps``.
        every: steps between saved summaries; must divide ``chunk_steps``.
        chunk_steps: steps per compiled ``lax.scan`` call; the host checks
            each chunk for NaN/inf and stops at the first bad one.
        batched: vmap the chunk over the leading axis of ``state``.
        reduce: optional ``f(chunk_summaries: dict of np arrays) -> dict`` applied
            to each chunk on the host; only its output is kept (for long runs).

    Returns:
        A :class:`Trace`; with ``reduce``, its array fields hold the stacked
        outputs of ``reduce`` (one entry per chunk) under the same names.
    """
    if every < 1 or chunk_steps % every:
        raise ValueError(f"simulate: 'every' ({every}) must divide 'chunk_steps' ({chunk_steps})")
    compiled, compile_s = _chunk_runner(model, state, params, every, chunk_steps // every, batched)
    chunks = max(1, math.ceil(num_steps / chunk_steps))
    dt = float(params.dt)
    kept, finite, start = [], True, time.perf_counter()
    done = 0
    for _ in range(chunks):
        state, summary = compiled(state, params)
        summary = {k: np.asarray(v) for k, v in jax.block_until_ready(summary).items()}
        if batched:  # vmap put the batch axis first; keep time first like the unbatched trace
            summary = {k: np.swapaxes(v, 0, 1) for k, v in summary.items()}
        done += 1
        kept.append(reduce(summary) if reduce is not None else summary)
        if not all(np.all(np.isfinite(v)) for v in summary.values()):
            finite = False
            break
    run_s = time.perf_counter() - start
    stacked = {k: (np.stack if reduce is not None else np.concatenate)([c[k] for c in kept]) for k in kept[0]}
    if reduce is None:
        times = dt * every * np.arange(1, len(stacked["kinetic"]) + 1)
    else:
        times = dt * chunk_steps * np.arange(1, done + 1)
    return Trace(times=times, pos=stacked.get("pos"), vel=stacked.get("vel"),
                 kinetic=stacked.get("kinetic"), penetration=stacked.get("penetration"),
                 steps=done * chunk_steps, finite=finite, compile_s=compile_s, run_s=run_s)
