"""Parameter and initial-condition sweeps: one jitted, vmapped call, optionally sharded over devices.

A sweep evaluates ``fn(state, params)`` (a step, a rollout, or a rollout
reduced to an outcome) for every world in a batch. The batch lives on a
leading axis of ``Params`` and/or ``State``; :func:`batch_params` and
:func:`batch_state` build such batches by replacing fields of a single world.
``shard=True`` splits the batch over every device JAX sees (one CPU, several
CPU devices from ``XLA_FLAGS=--xla_force_host_platform_device_count=N``, or
many GPUs) with no other change to the code. ``chunk=64`` runs the worlds
64 at a time, one chunk after another, which on a CPU keeps each chunk's
values in the cache (faster for small worlds; see :func:`sweep`).

Example: apex height after the first bounce for 1 024 restitutions::

    model, params, state = scene.build(dt=1 / 240, substeps=4)
    step = rb.make_step(model)
    apex = rb.sweep.rollout_outcome(step, 216, lambda traj, params: traj.pos[:, 0, 2].max())
    restitutions = jnp.linspace(0.2, 0.95, 1024)
    heights = rb.sweep.sweep(apex, rb.sweep.batch_params(params, restitution=restitutions),
                             state=state, shard=True)      # (1024,)

(``rollout_outcome`` keeps each world's trajectory inside the compiled call;
the sweep returns only the 1 024 outcomes.)
"""

from __future__ import annotations

import functools
from typing import Any, Callable, Optional, Sequence, Union

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxrb.compile import jit
from jaxrb.physics.step import rollout
from jaxrb.model.types import DERIVED_PARAMS, Params, State, check_param_values

#: Name of the one mesh axis the batch is split over.
BATCH_AXIS = "batch"


# --- building batches -----------------------------------------------------------------------

def _batch_fields(kind: str, world, fields: dict):
    """Broadcast ``world`` to a batch, replacing ``fields``; shared by Params and State."""
    if not fields:
        raise ValueError(f"batch_{kind}: give at least one field to vary, e.g. "
                         f"batch_{kind}({kind}, {'restitution' if kind == 'params' else 'pos'}=values)")
    valid = [name for name in type(world).__dataclass_fields__ if name not in DERIVED_PARAMS]
    sizes = {}
    values = {}
    for name, value in fields.items():
        if name in DERIVED_PARAMS:
            raise ValueError(f"batch_{kind}: field {name!r} is derived from the others (rollout fills "
                             f"it); sweep 'inertia' instead")
        if name not in valid:
            raise ValueError(f"batch_{kind}: unknown field {name!r}; valid fields are: "
                             f"{', '.join(valid)}")
        template = getattr(world, name)
        if template is None:
            raise ValueError(f"batch_{kind}: field {name!r} is None in this {kind} "
                             f"(e.g. 'quat' in 2D, 'angle' in 3D) and cannot be swept")
        template = jnp.asarray(template)
        try:
            array = np.asarray(value) if not isinstance(value, jax.Array) else value
        except (TypeError, ValueError):
            raise ValueError(f"batch_{kind}: field {name!r} must be an array, got {value!r}") from None
        numeric = np.issubdtype(array.dtype, np.number) or np.issubdtype(array.dtype, np.bool_)
        if not numeric:
            raise ValueError(f"batch_{kind}: field {name!r} must be numeric, got dtype {array.dtype}")
        shape = tuple(array.shape)
        tail = shape[1:]
        # The value is (B, *tail) with tail a trailing part of the field's own shape,
        # so (B,) fills every body and (B, n) gives each body its own value.
        if not shape or len(tail) > template.ndim or (tail and template.shape[-len(tail):] != tail):
            raise ValueError(
                f"batch_{kind}: field {name!r} has shape {template.shape} per world, so its values "
                f"must have shape (B,) + a trailing part of {template.shape}, e.g. (B,) or "
                f"(B, {', '.join(map(str, template.shape))}); got {shape}")
        if not isinstance(array, jax.core.Tracer):
            if not bool(jnp.all(jnp.isfinite(array))):
                raise ValueError(f"batch_{kind}: field {name!r} has non-finite values")
        sizes[name] = shape[0]
        values[name] = (array, template)
    if len(set(sizes.values())) > 1:
        raise ValueError(f"batch_{kind}: fields have different batch sizes: "
                         + ", ".join(f"{name!r}: {size}" for name, size in sizes.items()))
    batch = next(iter(sizes.values()))
    if batch < 1:
        raise ValueError(f"batch_{kind}: batch size must be >= 1, got {batch}")

    def broadcast(leaf):
        return jnp.broadcast_to(leaf, (batch,) + jnp.shape(leaf))

    batched = jax.tree_util.tree_map(broadcast, world)
    replaced = {}
    for name, (array, template) in values.items():
        expanded = jnp.reshape(jnp.asarray(array, dtype=template.dtype),
                               (batch,) + (1,) * (template.ndim - (array.ndim - 1)) + tuple(array.shape[1:]))
        replaced[name] = jnp.broadcast_to(expanded, (batch,) + template.shape)
        if kind == "params" and not isinstance(array, jax.core.Tracer):
            # The ranges Scene and Params.replace check: a negative mass, e > 1, a singular inertia.
            check_param_values("batch_params", name, replaced[name], int(np.shape(world.gravity)[-1]))
    return batched.replace(**replaced)


def batch_params(params: Params, **fields) -> Params:
    """A batch of Params: ``params`` in every world, with some fields varied.

    Each value has a leading batch axis B and is broadcast into the field's
    per-world shape from the right, NumPy style: for ``restitution`` (n,), a
    (B,) array gives every body of world b the value ``values[b]`` and a
    (B, n) array gives each body its own; for ``gravity`` (dim,) a (B, dim)
    array; for ``dt`` () a (B,) array. Values are cast to the field's dtype.

    Args:
        params: Params of one world.
        **fields: field name -> (B, ...) values; every field must have the same B.

    Returns:
        Params whose every leaf has a leading axis of length B.

    Raises:
        ValueError: unknown field, shape that does not broadcast, non-finite
            values or different batch sizes; the message names the field.

    Example::

        batch = batch_params(params, restitution=jnp.linspace(0.2, 0.9, 1024))
        batch.restitution.shape   # (1024, n)
    """
    return _batch_fields("params", params, fields)


def batch_state(state: State, **fields) -> State:
    """A batch of States: ``state`` in every world, with some fields varied.

    Broadcasting as in :func:`batch_params`: e.g. ``pos`` (n, dim) takes
    (B, n, dim) values, or (B, dim) to put every body of world b at the same
    point ``values[b]`` (useful for one-body scenes).

    Args:
        state: State of one world.
        **fields: field name -> (B, ...) values; every field must have the same B.

    Returns:
        State whose every leaf has a leading axis of length B.
    """
    return _batch_fields("state", state, fields)


# --- running a sweep ------------------------------------------------------------------------

def _batch_size(name: str, tree) -> int:
    """The common leading-axis length of every array in ``tree``, else a ValueError."""
    leaves = jax.tree_util.tree_flatten_with_path(tree)[0]
    if not leaves:
        raise ValueError(f"sweep: {name!r} holds no arrays")
    sizes = {}
    for path, leaf in leaves:
        shape = jnp.shape(leaf)
        field = jax.tree_util.keystr(path) or "(the array)"
        if not shape:
            raise ValueError(f"sweep: {name!r} field {field!r} has no batch axis (it is a scalar)")
        sizes.setdefault(shape[0], field)
    if len(sizes) > 1:
        raise ValueError(f"sweep: {name!r} fields have different batch sizes: "
                         + ", ".join(f"{field!r}: {size}" for size, field in sizes.items()))
    return next(iter(sizes))


def _pad(tree, padding: int):
    """Repeat each array's last world ``padding`` times: the pad is a valid world, never NaN."""
    if padding == 0:
        return tree
    return jax.tree_util.tree_map(
        lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], padding, axis=0)], axis=0), tree)


def _chunk_size(chunk, batch: int, sharded: bool) -> Optional[int]:
    """Worlds per chunk for ``sweep``'s ``chunk`` argument, or None for one vmap of the whole batch."""
    if chunk is None:
        return None
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"sweep: 'chunk' must be None or a positive integer, got {chunk!r}")
    if sharded:
        raise ValueError("sweep: 'chunk' and 'shard' cannot be combined; a sharded sweep runs each "
                         "device's worlds in one vmap (leave chunk=None)")
    return int(chunk) if chunk < batch else None


def _in_chunks(batched: Callable, state_axis, params_axis, chunk: int) -> Callable:
    """``batched(state, params)`` (a vmap over B worlds) run ``chunk`` worlds at a time.

    A loop over B // chunk chunks, each one vmap of ``chunk`` worlds, then one
    vmap of the B % chunk worlds left over. Same results as one vmap of all B
    (to float rounding: XLA may vectorise a different batch size differently).
    """
    def cut(tree, axis, start, stop):
        return tree if axis is None else jax.tree_util.tree_map(lambda a: a[start:stop], tree)

    def run(state, params):
        size = jax.tree_util.tree_leaves(state if state_axis == 0 else params)[0].shape[0]
        whole = size // chunk * chunk
        as_chunks = lambda tree, axis: None if axis is None else jax.tree_util.tree_map(
            lambda a: a[:whole].reshape((whole // chunk, chunk) + a.shape[1:]), tree)

        def one_chunk(_, worlds):
            states, params_chunk = worlds
            return None, batched(state if state_axis is None else states,
                                 params if params_axis is None else params_chunk)

        _, out = jax.lax.scan(one_chunk, None, (as_chunks(state, state_axis), as_chunks(params, params_axis)))
        out = jax.tree_util.tree_map(lambda a: a.reshape((whole,) + a.shape[2:]), out)
        if whole == size:
            return out
        rest = batched(cut(state, state_axis, whole, size), cut(params, params_axis, whole, size))
        return jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b]), out, rest)

    return run


@functools.lru_cache(maxsize=64)
def _compiled(fn: Callable, state_axis, params_axis, mesh: Optional[Mesh], chunk: Optional[int] = None) -> Callable:
    """``jit(vmap(fn))`` (by chunks of ``chunk`` worlds if given), cached so a repeated sweep does not recompile."""
    batched = jax.vmap(fn, in_axes=(state_axis, params_axis))
    if mesh is None:
        return jit(batched if chunk is None else _in_chunks(batched, state_axis, params_axis, chunk))
    return jit(batched, out_shardings=NamedSharding(mesh, PartitionSpec(BATCH_AXIS)))


def device_mesh(devices: Optional[Sequence] = None) -> Mesh:
    """A one-axis mesh named :data:`BATCH_AXIS` over ``devices`` (default: ``jax.devices()``).

    Args:
        devices: sequence of JAX devices, or None for all of ``jax.devices()``.

    Returns:
        A :class:`jax.sharding.Mesh` with the one axis :data:`BATCH_AXIS`.

    Raises:
        ValueError: ``devices`` is empty.
    """
    devices = list(jax.devices() if devices is None else devices)
    if not devices:
        raise ValueError("sweep: 'shard' names no devices")
    return Mesh(np.array(devices), (BATCH_AXIS,))


def sweep(fn: Callable, params_batch: Optional[Params] = None, states_batch: Optional[State] = None,
          *, params: Optional[Params] = None, state: Optional[State] = None,
          shard: Union[bool, Sequence, Mesh] = False, chunk: Optional[int] = None) -> Any:
    """Evaluate ``fn(state, params)`` for every world of a batch in one jitted, vmapped call.

    The batch is a leading axis B on ``params_batch``, ``states_batch`` or
    both (same B). The side that is not batched is passed once, unbatched,
    as ``params`` or ``state`` and shared by every world.

    Args:
        fn: ``fn(state, params) -> pytree`` for one world: ``rb.make_step(model)``,
            a function from :func:`rollout_outcome`, or any pure function.
            Define it once and reuse it: the compiled sweep is cached per
            ``fn`` object (and per batched side and device set), so a new
            lambda each call recompiles each call.
        params_batch: Params with a leading axis B on every leaf (see
            :func:`batch_params`), or None.
        states_batch: State with a leading axis B on every leaf (see
            :func:`batch_state`), or None.
        params: Params shared by every world; only when ``params_batch`` is None.
        state: State shared by every world; only when ``states_batch`` is None.
        shard: False to run on the default device; True to split the batch
            over all of ``jax.devices()``; or a sequence of devices or a
            one-axis :class:`jax.sharding.Mesh` to split it over. The batch
            is padded (by repeating its last world) to a multiple of the
            device count, each device runs B_pad / D worlds, and the pad is
            dropped from the result. When B is a multiple of D the result
            stays sharded over the devices on its batch axis; otherwise the
            trimmed result is replicated, since JAX cannot shard an axis
            unevenly (choose B as a multiple of D to keep it distributed).
            Single-process only.
        chunk: None to run the whole batch in one vmap; an integer to run it
            that many worlds at a time, one chunk after another (then one
            vmap of the B % chunk left over; not with ``shard``). The
            results are the same, to float rounding. On a CPU, worlds of one
            body ran faster in chunks of 16-128, whose values stay in the
            cache where those of 1 024 worlds go out to memory at every
            stage: at 1 024 worlds the penalty box slide 1.6x as fast at 64,
            impulse contact's box drop 1.3x at 128. A 10-box column over 256
            worlds ran slower in chunks (0.84x at 64): its vmap is already
            large (docs/design.md, 'Layout'). On a GPU the whole
            batch at once fills the device.

    Returns:
        ``fn``'s output with a leading axis B on every leaf.

    Raises:
        ValueError: no batch given, both a batch and a single value given for
            the same side, or leaves with different batch sizes (the message
            names the field).
    """
    if params_batch is None and states_batch is None:
        raise ValueError("sweep: give 'params_batch' and/or 'states_batch' (a leading batch axis); "
                         "for one world call fn directly")
    if isinstance(params_batch, State) or isinstance(params, State):
        raise ValueError("sweep: a State was given as params; pass a batch of states as "
                         "states_batch=... and one state as state=...")
    if isinstance(states_batch, Params) or isinstance(state, Params):
        raise ValueError("sweep: a Params was given as a state; pass a batch of params as "
                         "params_batch=... and one as params=...")
    if params_batch is not None and params is not None:
        raise ValueError("sweep: give 'params_batch' or 'params', not both")
    if states_batch is not None and state is not None:
        raise ValueError("sweep: give 'states_batch' or 'state', not both")
    sizes = {}
    if params_batch is not None:
        sizes["params_batch"] = _batch_size("params_batch", params_batch)
    if states_batch is not None:
        sizes["states_batch"] = _batch_size("states_batch", states_batch)
    if len(set(sizes.values())) > 1:
        raise ValueError("sweep: 'params_batch' and 'states_batch' have different batch sizes: "
                         + ", ".join(f"{name} {size}" for name, size in sizes.items()))
    batch = next(iter(sizes.values()))
    state_axis = None if states_batch is None else 0
    params_axis = None if params_batch is None else 0
    state_in = state if states_batch is None else states_batch
    params_in = params if params_batch is None else params_batch

    sharded = not (shard is False or shard is None)
    chunk = _chunk_size(chunk, batch, sharded)
    if not sharded:
        return _compiled(fn, state_axis, params_axis, None, chunk)(state_in, params_in)

    mesh = shard if isinstance(shard, Mesh) else device_mesh(None if shard is True else shard)
    if mesh.axis_names != (BATCH_AXIS,):
        raise ValueError(f"sweep: 'shard' mesh must have the one axis {BATCH_AXIS!r}, "
                         f"got {mesh.axis_names}")
    num_devices = mesh.devices.size
    padding = -batch % num_devices
    split = NamedSharding(mesh, PartitionSpec(BATCH_AXIS))
    replicated = NamedSharding(mesh, PartitionSpec())

    def place(tree, batched):
        if tree is None:
            return None
        return jax.device_put(_pad(tree, padding) if batched else tree, split if batched else replicated)

    output = _compiled(fn, state_axis, params_axis, mesh)(place(state_in, state_axis == 0),
                                                          place(params_in, params_axis == 0))
    if padding:
        output = jax.tree_util.tree_map(lambda a: a[:batch], output)
    return output


# --- the common case: roll out, then reduce ---------------------------------------------------

def rollout_outcome(step: Callable, num_steps: int, outcome: Optional[Callable] = None, *,
                    every: int = 1, checkpoint: Union[bool, int] = False, adjoint: bool = False) -> Callable:
    """``fn(state, params)`` that rolls ``step`` out and reduces the trajectory to an outcome.

    Build it once and pass it to :func:`sweep` (or ``jax.grad`` it): the
    trajectory of each world exists only inside the compiled call, so a sweep
    returns B outcomes, not B trajectories.

    Args:
        step: a function from :func:`jaxrb.make_step`.
        num_steps: steps per rollout (a multiple of ``every``).
        outcome: ``outcome(trajectory, params) -> pytree`` for one world, where
            ``trajectory`` is a State with a leading time axis of length
            ``num_steps // every`` (the states after steps every, 2·every, ...).
            None returns the trajectory itself.
        every: keep every ``every``-th state (less memory, coarser outcome).
        checkpoint: passed to :func:`jaxrb.rollout` (reverse-mode memory).
        adjoint: passed to :func:`jaxrb.rollout` (hand-written reverse mode;
            no forward mode through ``fn`` then).

    Returns:
        ``fn(state, params) -> outcome(rollout(step, state, params, num_steps), params)``.
    """
    if not isinstance(num_steps, (int, np.integer)) or isinstance(num_steps, bool) or num_steps < 1:
        raise ValueError(f"rollout_outcome: 'num_steps' must be a positive integer, got {num_steps!r}")
    if outcome is not None and not callable(outcome):
        raise ValueError(f"rollout_outcome: 'outcome' must be callable, got {outcome!r}")

    def run(state: State, params: Params):
        trajectory = rollout(step, state, params, int(num_steps), every=every, checkpoint=checkpoint,
                             adjoint=adjoint)
        return trajectory if outcome is None else outcome(trajectory, params)

    return run
