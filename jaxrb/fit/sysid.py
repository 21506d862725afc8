"""System identification: fit ``Params`` fields to observed trajectories with optax.

This module holds the fit; its pieces live beside it and are re-exported here
(``rb.sysid.Observation``, ``rb.sysid.to_unconstrained``, ...), each usable alone:

* :mod:`jaxrb.fit.observations`: :class:`Observation` (what was measured, at which
  step indices), :func:`observe` and :func:`trajectory_loss` (weighted
  position, orientation and velocity errors).
* :mod:`jaxrb.fit.parameter_transforms`: :func:`to_unconstrained` /
  :func:`from_unconstrained`, the transforms that keep fitted values physical
  whatever the optimiser does (the list and the defaults are in that module).
* :func:`make_objective`: rollout and loss as one differentiable function.
* :func:`fit`: the optax loop. Its update step (rollout, loss, gradient and
  optimiser update) is jitted once per call and reused for every iteration.

Early stopping (off by default): with ``tol`` set, :func:`fit` stops when the
best loss of the last ``patience`` iterations is less than a fraction ``tol``
below the best loss before them, i.e. the fit has stopped improving in
relative terms. A window rather than consecutive steps, because Adam's loss
oscillates from step to step near a minimum. It also stops, with a warning, at
a non-finite loss. In every case the returned parameters are those with the
lowest loss seen.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from typing import Callable, Mapping, Optional, Union

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxrb.physics import adjoint as hand_written
from jaxrb.compile import jit
from jaxrb.fit.observations import (LossWeights, Observation, _loss_weights, observe, quaternion_angle,
                                    trajectory_loss, wrapped_angle)
from jaxrb.fit.parameter_transforms import (DEFAULT_TRANSFORMS, PARAM_FIELDS, TRANSFORMS, Transform, field_masks,
                                            from_unconstrained, to_unconstrained)
from jaxrb.physics.step import rollout
from jaxrb.model.types import Params, State, Wrench

__all__ = [
    # the fit (defined here)
    "FitResult", "fit", "make_objective",
    # observations and losses (jaxrb.fit.observations)
    "LossWeights", "Observation", "observe", "quaternion_angle", "trajectory_loss", "wrapped_angle",
    # parameter transforms (jaxrb.fit.parameter_transforms)
    "DEFAULT_TRANSFORMS", "PARAM_FIELDS", "TRANSFORMS", "Transform", "field_masks", "from_unconstrained",
    "to_unconstrained",
]


@dataclasses.dataclass(frozen=True)
class FitResult:
    """What :func:`fit` returns.

    Attributes:
        params: Params with the lowest loss seen.
        losses: (num_updates + 1,) numpy array; ``losses[k]`` is the loss after k
            optimiser updates (``losses[0]`` at the starting point).
        steps: optimiser updates made (fewer than asked if it stopped early).
        best_step: index into ``losses`` of ``params``.
        stopped_early: True if the ``tol`` criterion (or a non-finite loss) stopped it.
        unconstrained: ``{name: u}`` of ``params``, to resume a fit.
    """

    params: Params
    losses: np.ndarray
    steps: int
    best_step: int
    stopped_early: bool
    unconstrained: dict


def _check_observation(observed: Observation, state: State, batched: bool) -> int:
    """Validate shapes against the initial state; return the largest step index."""
    if not isinstance(observed, Observation):
        raise ValueError(f"sysid: 'observed' must be a sysid.Observation, got {type(observed).__name__}")
    steps = np.asarray(observed.steps)
    lead = state.pos.shape[:1] if batched else ()
    if steps.ndim != len(lead) + 1 or steps.shape[:len(lead)] != lead or steps.shape[-1] < 1:
        raise ValueError(f"sysid: Observation field 'steps' must have shape {lead + ('T',)} with T >= 1, "
                         f"got {steps.shape}")
    if not np.issubdtype(steps.dtype, np.integer) or np.any(steps < 1):
        raise ValueError(f"sysid: Observation field 'steps' must hold integers >= 1 (the state after k "
                         f"steps), got {steps.tolist()}")
    count, num_bodies, dim = steps.shape[-1], state.pos.shape[-2], state.pos.shape[-1]
    expected = {"pos": (num_bodies, dim), "vel": (num_bodies, dim), "mask": (num_bodies,),
                "quat": (num_bodies, 4), "angle": (num_bodies,),
                "angvel": (num_bodies, 3) if dim == 3 else (num_bodies,), "time": ()}
    if dim == 3 and observed.angle is not None:
        raise ValueError("sysid: Observation field 'angle' is 2D only; use 'quat' in 3D")
    if dim == 2 and observed.quat is not None:
        raise ValueError("sysid: Observation field 'quat' is 3D only; use 'angle' in 2D")
    present = [name for name in expected if getattr(observed, name) is not None and name not in ("mask", "time")]
    if not present:
        raise ValueError("sysid: the Observation holds no data (pos, quat/angle, vel or angvel)")
    for name, shape in expected.items():
        value = getattr(observed, name)
        if value is None:
            continue
        want = lead + (count,) + shape
        if np.shape(value) != want:
            raise ValueError(f"sysid: Observation field {name!r} must have shape {want}, got {np.shape(value)}")
        if name != "mask" and not np.all(np.isfinite(np.asarray(value))):
            raise ValueError(f"sysid: Observation field {name!r} must be finite")
    return int(steps.max())


def _check_observation_times(observed: Observation, state: State, params: Params) -> None:
    """Raise where the samples' recorded times are not the initial time plus ``steps``·dt (wrong ``every``)."""
    if observed.time is None:
        return
    dt = float(np.max(np.asarray(params.dt)))
    steps, time = np.asarray(observed.steps), np.asarray(observed.time, dtype=float)
    start = np.asarray(state.time, dtype=float)[..., None]
    expected = start + steps * dt
    wrong = np.abs(time - expected) > 0.25 * dt
    if np.any(wrong):
        first = tuple(int(i) for i in np.argwhere(wrong)[0])
        raise ValueError(
            f"sysid: Observation sample {first} is labelled step {int(steps[first])} (t = {expected[first]:.6g} s "
            f"at dt = {dt:g}) but its state was recorded at t = {time[first]:.6g} s; was observe()'s 'every' "
            f"the rollout's own every? To thin an every-step rollout, pass observe(states, steps=...)")


def _gcd(values) -> int:
    return int(np.gcd.reduce(np.asarray(values).reshape(-1)))


def make_objective(step: Callable, num_steps: int, every: int, *, weights=None, loss: Optional[Callable] = None,
                   checkpoint: Union[bool, int] = False, batched: bool = False,
                   adjoint: bool = False) -> Callable:
    """``objective(params, initial_state, observed, applied) -> ()`` for one or many trajectories.

    Rolls out ``num_steps`` steps (keeping every ``every``-th state), samples
    the rollout at ``observed.steps`` (multiples of ``every``) and scores it with
    ``loss(predicted, observed)`` (default :func:`trajectory_loss` with
    ``weights``). With ``batched``, ``initial_state``, ``observed`` and
    ``applied`` carry a leading axis B and the objective is the mean over B.

    Args:
        step: from :func:`jaxrb.make_step`.
        num_steps: steps to roll out (a multiple of ``every``, at least the
            largest observed step).
        every: rollout save interval.
        weights: :class:`LossWeights` (or dict) for the default loss.
        loss: optional ``loss(predicted, observed) -> ()`` replacing
            :func:`trajectory_loss`.
        checkpoint: passed to :func:`jaxrb.rollout`.
        adjoint: passed to :func:`jaxrb.rollout` (the hand-written reverse
            mode; the objective then has no forward mode).
        batched: average over a leading batch axis B of the trajectories.

    Returns:
        ``objective(params, initial_state, observed, applied) -> ()``, pure and
        differentiable in ``params``.
    """
    score = loss if loss is not None else (lambda predicted, observed: trajectory_loss(predicted, observed, weights))

    def one(params, initial_state, observed, applied):
        states = rollout(step, initial_state, params, num_steps, every=every, checkpoint=checkpoint, adjoint=adjoint,
                         applied=applied)
        index = observed.steps // every - 1
        predicted = jax.tree_util.tree_map(lambda a: a[index], states)
        return score(predicted, observed)

    if not batched:
        return one

    def mean_over_worlds(params, initial_state, observed, applied):
        per_world = jax.vmap(one, in_axes=(None, 0, 0, None if applied is None else 0))(
            params, initial_state, observed, applied)
        return jnp.mean(per_world)

    return mean_over_worlds


def fit(step: Callable, params: Params, initial_state: State, observed: Observation, *, fields,
        optimizer: optax.GradientTransformation, num_steps: int = 500,
        weights: Union[LossWeights, Mapping[str, float], None] = None, loss: Optional[Callable] = None,
        applied: Optional[Wrench] = None, every: Optional[int] = None, checkpoint: Union[bool, int] = False,
        transforms: Optional[Mapping] = None, tol: Optional[float] = None, patience: int = 20,
        log_every: Optional[int] = None, callback: Optional[Callable] = None,
        callback_every: int = 1, print_fn: Callable = print, adjoint: Optional[bool] = None) -> FitResult:
    """Fit the selected Params fields to observed trajectories with an optax optimiser.

    Each iteration rolls the scene out from ``initial_state``, compares it with
    ``observed`` and takes one optimiser step on the unconstrained parameters
    (see :mod:`jaxrb.fit.parameter_transforms`). The update (rollout + loss +
    gradient + optimiser) is one jitted function, compiled once per call.

    Several trajectories sharing one parameter set: give ``initial_state``
    (pos (B, n, dim), ...), ``observed`` (steps (B, T), ...) and ``applied``
    with a leading batch axis B; rollouts are vmapped and the loss is their mean.

    Args:
        step: from :func:`jaxrb.make_step`.
        params: starting Params (fields not fitted keep these values).
        initial_state: State at step 0 (one world, or B worlds as above).
        observed: :class:`Observation` (batched like ``initial_state``).
        fields: what to fit: a name, names, ``{name: mask}`` or a Params of
            bools (see :func:`field_masks`). Unknown names raise ValueError.
        optimizer: any optax GradientTransformation, e.g. ``optax.adam(0.05)``.
        num_steps: maximum number of optimiser updates.
        weights: :class:`LossWeights` (or dict) for :func:`trajectory_loss`.
        loss: optional ``loss(predicted, observed) -> ()`` replacing
            :func:`trajectory_loss`; ``predicted`` is the State sampled at
            ``observed.steps`` (arrays (T, n, ...)).
        applied: optional :class:`Wrench` sequence, arrays (S, n, ...) with S >=
            the largest observed step (B, S, n, ...) when batched.
        every: rollout save interval; default the gcd of the observed steps.
        checkpoint: passed to :func:`jaxrb.rollout` (reverse mode keeps about √T step
            inputs instead of T; pays when observations are sparse, ``every`` > 1).
        transforms: ``{name: name-or-Transform}`` overriding :data:`DEFAULT_TRANSFORMS`.
        tol, patience: early stopping (module docs); ``tol=None`` runs all steps.
        log_every: print the loss every this many updates (and at the end),
            and say when the first update's compile starts and ends.
        callback: ``callback(step, loss, params)`` called every
            ``callback_every`` updates with the update count, the loss (float)
            and the Params at that point.
        callback_every: how often (in updates) ``callback`` is called.
        print_fn: where ``log_every`` lines go (e.g. ``logging.info``).
        adjoint: take gradients with :func:`jaxrb.rollout`'s hand-written
            adjoint (``adjoint=True``); None (default) does where the model
            has one (``jaxrb.physics.adjoint.supports``: 3D semi-implicit models
            without damping, free bodies or penalty contact with spring
            friction against planes) and ``checkpoint`` is off, on every
            backend (on an H200 it took 0.6–0.7 of autodiff's time at one world:
            docs/accelerator.md). A fit only uses reverse mode, and the
            adjoint's gradients equal autodiff's to rounding.

    Returns:
        :class:`FitResult` with the best Params and the loss history.
    """
    if not hasattr(optimizer, "init") or not hasattr(optimizer, "update"):
        raise ValueError(f"sysid: 'optimizer' must be an optax GradientTransformation, got {optimizer!r}")
    for name, value, low in (("num_steps", num_steps, 0), ("patience", patience, 1),
                             ("callback_every", callback_every, 1), ("log_every", log_every, 1),
                             ("every", every, 1)):
        if value is not None and not (isinstance(value, (int, np.integer)) and not isinstance(value, bool)
                                      and value >= low):
            raise ValueError(f"sysid: {name!r} must be an integer >= {low}, got {value!r}")
    if tol is not None and not (isinstance(tol, (int, float)) and tol >= 0):
        raise ValueError(f"sysid: 'tol' must be a number >= 0 or None, got {tol!r}")
    weights = _loss_weights(weights)

    batched = initial_state.pos.ndim == params.mass.ndim + 2
    last_step = _check_observation(observed, initial_state, batched)
    _check_observation_times(observed, initial_state, params)
    if every is None:
        every = _gcd(observed.steps)
    elif np.any(np.asarray(observed.steps) % every):
        raise ValueError(f"sysid: observed 'steps' must all be multiples of every={every}")
    rollout_steps = last_step  # a multiple of every: it is one of the steps
    if applied is not None:
        length = applied.force.shape[int(batched)]
        if length < rollout_steps:
            raise ValueError(f"sysid: 'applied' covers {length} steps, but the observations reach step "
                             f"{rollout_steps}")
        applied = jax.tree_util.tree_map(
            lambda a: a[:, :rollout_steps] if batched else a[:rollout_steps], applied)

    masks = field_masks(params, fields)
    unconstrained = to_unconstrained(params, masks, transforms)
    if adjoint is None:
        model = getattr(step, "model", None)
        adjoint = model is not None and hand_written.supports(model) and not checkpoint
    objective = make_objective(step, rollout_steps, every, weights=weights, loss=loss,
                               checkpoint=checkpoint, batched=batched, adjoint=adjoint)

    def total_loss(u, base, state, obs, wrench):
        return objective(from_unconstrained(u, base, masks, transforms), state, obs, wrench)

    @jit
    def update(u, opt_state, base, state, obs, wrench):
        value, grads = jax.value_and_grad(total_loss)(u, base, state, obs, wrench)
        updates, opt_state = optimizer.update(grads, opt_state, u)
        return optax.apply_updates(u, updates), opt_state, value

    constrain = jit(lambda u, base: from_unconstrained(u, base, masks, transforms))

    opt_state = optimizer.init(unconstrained)
    losses, best_loss, best_u, best_step = [], math.inf, unconstrained, 0
    best_history = []  # best loss after each evaluation, for the tol window
    stopped_early = False
    u = unconstrained
    updates_done = 0
    for k in range(num_steps + 1):
        if k == 0 and log_every is not None:  # the first call compiles: tens of seconds for long rollouts
            print_fn(f"sysid: compiling the loss gradient of a {rollout_steps}-step rollout…")
            clock = time.perf_counter()
        # The last pass only evaluates the loss at the final parameters.
        new_u, new_opt_state, value = update(u, opt_state, params, initial_state, observed, applied)
        value = float(value)
        if k == 0 and log_every is not None:
            print_fn(f"sysid: compiled and took the first step in {time.perf_counter() - clock:.1f} s")
        losses.append(value)
        if not math.isfinite(value):
            warnings.warn(f"sysid.fit: loss became {value} after {k} updates; stopping and returning "
                          f"the best parameters so far", RuntimeWarning, stacklevel=2)
            stopped_early = True
            break
        if value < best_loss:
            best_loss, best_u, best_step = value, u, k
        best_history.append(best_loss)
        if log_every is not None and (k % log_every == 0 or k == num_steps):
            print_fn(f"sysid step {k:5d}  loss {value:.6e}")
        if callback is not None and k % callback_every == 0:
            callback(k, value, constrain(u, params))
        if (tol is not None and k >= patience
                and best_history[k - patience] - best_loss <= tol * best_history[k - patience]):
            stopped_early = k < num_steps
            break
        if k == num_steps:
            break
        u, opt_state = new_u, new_opt_state
        updates_done = k + 1
    return FitResult(params=constrain(best_u, params), losses=np.asarray(losses), steps=updates_done,
                     best_step=best_step, stopped_early=stopped_early, unconstrained=best_u)
