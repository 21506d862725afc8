"""The sequential solver's rows one at a time: a scan that reads and writes only each row's two bodies.

:func:`_sweep_rows` runs a row update (a solver pass's, the restitution
pass's in :mod:`jaxrb.physics.contact.impulse`, the time-of-impact pass's in
:mod:`jaxrb.physics.contact.toi`) on the rows in order, reading each row's bodies with
dynamic slices (:func:`_read_bodies`, :func:`_row_speed`, :func:`_row_push`)
and skipping an inactive row with a branch. :func:`_guarded_row` gives that
branch a custom JVP (derivatives select instead of branching) and a custom
vmap (a select that batches only what is batched). The rows themselves come
from :func:`jaxrb.physics.contact.rows.prepare`.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.physics.collision.pairs import plane_rows
from jaxrb.physics.contact.rows import Prepared
from jaxrb.model.types import Model


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
