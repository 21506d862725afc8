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

Where the pieces are: this module holds the impulse laws (the soft normal
impulse, :func:`smooth_clamp`, the friction cone) and the passes
(:func:`solve_pass` with the Jacobi passes' ``_cotangent_once``,
:func:`restitution_pass`); :mod:`jaxrb.physics.contact.rows`
prepares the step's rows (:func:`jaxrb.physics.contact.rows.prepare`) and reads and
moves every row at once; :mod:`jaxrb.physics.contact.sequential` sweeps the rows one
at a time for the sequential solver.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxrb.physics.contact.common import clamp_to_disc
from jaxrb.physics.contact.rows import Prepared, push_rows, row_speeds
from jaxrb.physics.contact.sequential import _row_push, _row_speed, _sweep_rows
from jaxrb.model.types import Model, Params


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

    impulses: the rows' accumulated impulses (:func:`jaxrb.physics.contact.rows.row_impulses`), a tuple
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
# :func:`jaxrb.math.components.materialize` uses in the forward); on those values'
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


def _row_friction(model, row, bodies, old_friction, normal):
    """A row's friction after its normal impulse ``normal`` (scalar), and its bodies after the change.

    Solved in the row's tangent coordinates: the second tangent sees the
    first one's update through the coupling (a small block Gauss–Seidel),
    then the pair is clamped to the cone μ·normal.

    Args:
        row: one row of :class:`Prepared` (:func:`jaxrb.physics.contact.sequential._row`);
            bodies: (v_a, ω_a, v_b, ω_b).
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
        prep: :class:`Prepared` or one row of it (:func:`jaxrb.physics.contact.sequential._row`).
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


def soft_coefficients(hertz, damping_ratio, h, cap=0.25):
    """(bias rate, mass scale, impulse scale) of a soft constraint: a spring-damper taken implicitly.

    The stiffness is capped at a quarter of the step rate, the stiffest the
    few passes resolve (see the module docs). Contacts, the joints' loop
    closures and their limits' solver rows all use it.

    Args:
        hertz: () the spring's frequency (Hz).
        damping_ratio: () its damping ratio.
        h: () the (sub)step.
        cap: the highest frequency taken, as a fraction of the step rate.

    Returns:
        (bias_rate, mass_scale, impulse_scale), each (): an update is
        Δλ = −mass_scale·m_eff·(v + bias_rate·C) − impulse_scale·λ for a
        constraint C with speed v and accumulated impulse λ.
    """
    omega = 2.0 * jnp.pi * jnp.minimum(hertz, cap / h)
    a1 = 2.0 * damping_ratio + h * omega
    a2 = h * omega * a1
    a3 = 1.0 / (1.0 + a2)
    return omega / a1, a2 * a3, a3


def soft_parameters(params: Params, h):
    """(bias rate, mass scale, impulse scale, max push) of the soft contact constraint."""
    return (*soft_coefficients(params.contact_hertz, params.contact_damping_ratio, h), params.max_push_velocity)


def collision_impulse(vn, old, restitution, normal_mass, active, threshold):
    """A contact's normal impulse after it collides now: Newton's j = −(1 + e)·m_n·v_n.

    For a contact closing faster than ``threshold`` at this moment (v_n <
    −threshold), the impulse that leaves it at −e·v_n; elsewhere ``old``.
    Applied contact by contact, in sweeps, before the solver's passes, it
    carries an impact through a row of touching bodies one contact at a time
    (a Newton's cradle), which the passes' simultaneous solve followed by
    :func:`bounce_impulse` cannot: they share the momentum among all the
    bodies first. Any shapes, all alike.

    Args:
        vn: normal speeds now; old: accumulated normal impulses;
            restitution, normal_mass, active: the rows'; threshold: () m/s.

    Returns:
        The new accumulated normal impulses.
    """
    hit = active & (vn < -threshold)
    return jnp.where(hit, jnp.maximum(old - (1.0 + restitution) * normal_mass * vn, 0.0), old)


def bounce_impulse(vn, old, approach, restitution, normal_mass, active, threshold):
    """A contact's normal impulse after its restitution update: outgoing speed −e·v_approach.

    Applies where the contact is active, approached faster than ``threshold``
    and pushes (``old`` > 0); elsewhere ``old`` is returned. Any shapes, all alike.

    Args:
        vn: normal speeds now; old: accumulated normal impulses; approach:
            normal speeds after the velocity phase (negative approaching);
            restitution, normal_mass, active: the rows'; threshold: () m/s.

    Returns:
        The new accumulated normal impulses.
    """
    # With impulse_smoothing every closing contact pushes a little, so it
    # bounces up to a substep early (apex +2 mm on the bounce bench). Gating
    # on the unsmoothed impulse instead was tried: the apex was right but
    # the gradient jumped (std of dA/dh0 41 against 2e-3), so the knob keeps
    # this bias.
    bounce = active & (approach < -threshold) & (old > 0.0)
    delta = -normal_mass * (vn + restitution * approach)
    return jnp.where(bounce, jnp.maximum(old + delta, 0.0), old)


def restitution_pass(model: Model, prep: Prepared, vel, angvel, impulses, threshold):
    """Give contacts that hit faster than ``threshold`` an outgoing speed of −e·v_approach.

    impulses: as in :func:`solve_pass`; returns (vel, angvel, impulses).
    """
    def new_normal(vn, old, row, threshold):
        return bounce_impulse(vn, old, row.approach, row.restitution, row.normal_mass, row.active, threshold)

    if model.solver == "jacobi":
        normal = new_normal(row_speeds(model, prep, vel, angvel, count=1)[0], impulses[0], prep, threshold)
        vel, angvel = push_rows(model, prep, vel, angvel, [normal - impulses[0]])
        return vel, angvel, (normal, *impulses[1:])

    def one_contact(row, bodies, old, _, threshold):
        normal = new_normal(_row_speed(row, 0, bodies), old[0], row, threshold)
        return _row_push(row, 0, bodies, normal - old[0]), (normal, *old[1:])

    (vel, angvel), impulses = _sweep_rows(model, prep, one_contact, (vel, angvel), impulses, extra=threshold)
    return vel, angvel, impulses
