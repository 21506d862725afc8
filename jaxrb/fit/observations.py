"""Observed trajectories and the losses that score a rollout against them.

* :class:`Observation`: what was measured, at which step indices (sparse and
  noisy is fine), with an optional per-sample mask; :func:`observe` takes one
  from a rollout (synthetic data).
* :func:`trajectory_loss`: weighted (:class:`LossWeights`) position,
  orientation and velocity errors between a rollout and an Observation; its
  angle errors are :func:`quaternion_angle` (3D) and :func:`wrapped_angle` (2D).

:func:`jaxrb.fit.sysid.fit` minimises this loss (or one of the user's);
``rb.sysid`` re-exports every public name here.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Mapping, Optional, Sequence, Union

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.model.struct import pytree_dataclass
from jaxrb.math.vector import safe_norm
from jaxrb.model.types import State

Array = jax.Array


@pytree_dataclass
class Observation:
    """An observed trajectory of one world (or, with a leading batch axis B, of several).

    Attributes:
        steps: (T,) int step indices k >= 1: sample t is the state after
            ``steps[t]`` calls of ``step`` from the initial state. Need not be
            evenly spaced.
        pos: (T, n, dim) centre-of-mass positions, or None.
        quat: (T, n, 4) unit quaternions (w, x, y, z), 3D only, or None.
        angle: (T, n) angles, 2D only, or None.
        vel: (T, n, dim) linear velocities, or None.
        angvel: (T, n, 3) world angular velocities in 3D, (T, n) in 2D, or None.
        mask: (T, n) weights (1 observed, 0 missing), or None for all observed.
        time: (T,) the simulated time (s) of each sample as the rollout
            recorded it (``State.time``), or None (measured data). :func:`fit`
            checks it against the initial time plus ``steps``·dt, so samples
            labelled with the wrong steps (``observe``'s ``every`` taken as
            "keep every k-th sample") are an error, not a silently wrong fit.
    """

    steps: Array
    pos: Optional[Array] = None
    quat: Optional[Array] = None
    angle: Optional[Array] = None
    vel: Optional[Array] = None
    angvel: Optional[Array] = None
    mask: Optional[Array] = None
    time: Optional[Array] = None


def observe(states: State, steps: Optional[Sequence[int]] = None, *, every: int = 1,
            velocities: bool = False) -> Observation:
    """An :class:`Observation` taken from a stacked rollout (e.g. to make synthetic data).

    Args:
        states: State with a leading time axis, from ``rollout(..., every=every)``
            (its sample i is the state after ``every·(i + 1)`` steps).
        steps: (T,) step indices to keep, multiples of ``every``; default all.
            To keep every 10th state of an every-step rollout, pass
            ``steps=range(10, T + 1, 10)``.
        every: the ``every`` the rollout was run with (not a thinning:
            :func:`fit` raises if the states' times disagree with it).
        velocities: also record ``vel`` and ``angvel``.

    Returns:
        The Observation (positions and orientations, velocities if asked).
    """
    num_saved = states.pos.shape[0]
    if steps is None:
        steps = every * np.arange(1, num_saved + 1)
    steps = np.asarray(steps)
    if steps.ndim != 1 or np.any(steps < every) or np.any(steps % every) or np.any(steps > every * num_saved):
        raise ValueError(f"observe: 'steps' must be multiples of every={every} in "
                         f"[{every}, {every * num_saved}], got {steps.tolist()}")
    index = steps // every - 1
    take = lambda a: None if a is None else jnp.asarray(a)[index]  # noqa: E731
    return Observation(steps=jnp.asarray(steps, dtype=jnp.int32), pos=take(states.pos),
                       quat=take(states.quat), angle=take(states.angle),
                       vel=take(states.vel) if velocities else None,
                       angvel=take(states.angvel) if velocities else None, time=take(states.time))


@dataclasses.dataclass(frozen=True)
class LossWeights:
    """Weights of the terms of :func:`trajectory_loss` (a term without data counts 0).

    Units: position and velocity terms are squared lengths (m², (m/s)²),
    orientation and angular velocity squared angles (rad², (rad/s)²). For a
    body of size ℓ, an orientation weight near ℓ² makes a rotation count like
    the distance its surface moves.

    Attributes:
        position: weight of the mean squared position error.
        orientation: weight of the mean squared orientation angle.
        velocity: weight of the mean squared velocity error.
        angvel: weight of the mean squared angular velocity error.
    """

    position: float = 1.0
    orientation: float = 1.0
    velocity: float = 1.0
    angvel: float = 1.0


def quaternion_angle(quat, target):
    """Rotation angle (rad) between two orientations, in [0, π].

    θ = 2·atan2(|v|, |w|) with (w, v) = q̂* ⊗ q, so q and −q count as the same
    orientation. ``safe_norm`` keeps the gradient finite (zero) at θ = 0, where
    arccos(|q·q̂|) would divide by zero.

    Args:
        quat: (..., 4) unit quaternions (w, x, y, z).
        target: (..., 4) unit quaternions q̂ to compare with.

    Returns:
        (...) angles in [0, π].
    """
    w = jnp.sum(quat * target, axis=-1)  # scalar part of conj(target) ⊗ quat
    tw, tv = target[..., :1], target[..., 1:]
    qw, qv = quat[..., :1], quat[..., 1:]
    cross = jnp.stack([tv[..., 1] * qv[..., 2] - tv[..., 2] * qv[..., 1],
                       tv[..., 2] * qv[..., 0] - tv[..., 0] * qv[..., 2],
                       tv[..., 0] * qv[..., 1] - tv[..., 1] * qv[..., 0]], axis=-1)
    vector = tw * qv - qw * tv - cross
    return 2.0 * jnp.arctan2(safe_norm(vector), jnp.abs(w))


def wrapped_angle(angle, target):
    """angle − target wrapped into (−π, π]. Smooth except at ±π.

    Args:
        angle: (...) angles (rad).
        target: (...) angles (rad) to compare with.

    Returns:
        (...) the wrapped differences.
    """
    difference = angle - target
    return jnp.arctan2(jnp.sin(difference), jnp.cos(difference))


def _masked_mean(error, mask):
    """Mean of ``error`` (T, n) over the samples with mask weight."""
    if mask is None:
        return jnp.mean(error)
    mask = jnp.asarray(mask, dtype=error.dtype)
    return jnp.sum(error * mask) / jnp.maximum(jnp.sum(mask), 1.0)


def trajectory_loss(predicted: State, observed: Observation,
                    weights: Union[LossWeights, Mapping[str, float], None] = None):
    """Weighted mean squared error of a rollout at the observed samples.

    ``loss = w_p·mean|Δpos|² + w_o·mean θ² + w_v·mean|Δvel|² + w_ω·mean|Δangvel|²``
    with means over the observed (sample, body) pairs and θ the 3D geodesic
    angle (:func:`quaternion_angle`) or the wrapped 2D angle difference.
    A term is left out when ``observed`` lacks its data. Zero at the truth,
    with a finite gradient there.

    Args:
        predicted: State sampled at the observation times: arrays (T, n, ...),
            e.g. ``rollout(...)`` indexed at ``observed.steps``.
        observed: the Observation (one world, no batch axis).
        weights: :class:`LossWeights` or a dict of its fields.

    Returns:
        () the scalar loss.
    """
    weights = _loss_weights(weights)
    mask = observed.mask
    total = 0.0
    if observed.pos is not None and weights.position:
        total = total + weights.position * _masked_mean(
            jnp.sum((predicted.pos - observed.pos) ** 2, axis=-1), mask)
    if weights.orientation:
        if observed.quat is not None:
            total = total + weights.orientation * _masked_mean(
                quaternion_angle(predicted.quat, observed.quat) ** 2, mask)
        elif observed.angle is not None:
            total = total + weights.orientation * _masked_mean(
                wrapped_angle(predicted.angle, observed.angle) ** 2, mask)
    if observed.vel is not None and weights.velocity:
        total = total + weights.velocity * _masked_mean(
            jnp.sum((predicted.vel - observed.vel) ** 2, axis=-1), mask)
    if observed.angvel is not None and weights.angvel:
        error = (predicted.angvel - observed.angvel) ** 2
        total = total + weights.angvel * _masked_mean(
            jnp.sum(error, axis=-1) if error.ndim == 3 else error, mask)
    return jnp.asarray(total)


def _loss_weights(weights) -> LossWeights:
    if weights is None:
        return LossWeights()
    if isinstance(weights, LossWeights):
        return weights
    valid = {f.name for f in dataclasses.fields(LossWeights)}
    for name, value in dict(weights).items():
        if name not in valid:
            raise ValueError(f"sysid: unknown loss weight {name!r}; valid: {', '.join(sorted(valid))}")
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise ValueError(f"sysid: loss weight {name!r} must be a finite number >= 0, got {value!r}")
    return LossWeights(**dict(weights))
