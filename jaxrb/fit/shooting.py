"""Short-horizon (multiple-shooting) residuals: gradients that stay useful on chaotic contact.

The exact gradient of a long rollout through tumbling impacts is correct and
useless: a small change of friction moves which corner hits first a second
later, so the slope of the loss along a whole toss swings by orders of
magnitude and changes sign between neighbouring parameter values (measured on
the cube tosses: autodiff 100-1 000× the loss's finite-difference slope).
Prediction over a short horizon is smooth in the parameters: every segment
starts from a *measured* state and predicts only ``horizon`` samples ahead,
so no error has time to grow through a chain of impacts.

A segment is (trajectory k, start sample s): its initial State is the
measured pose and velocity at s (measured velocities if the data has them,
else central differences of the poses; for articulated bodies the measured
joint coordinates, of which the poses are the read-out), its targets the measured poses at
s + 1 … s + horizon. Residuals per predicted sample are the position error in
fractions of the body's size and the rotation error's vector in radians
times :data:`ROTATION_WEIGHT`, which makes 10° count like 10 % of the size,
as the evaluation protocol weighs them (:mod:`jaxrb.fit.evaluate`).
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.fit.initial_state import quat_conjugate, quat_multiply, quat_log
from jaxrb.fit.measured import Trajectories
from jaxrb.physics.step import rollout
from jaxrb.model.types import State

#: Radians of rotation error that weigh like one body size of position error (10° ~ 10 %).
ROTATION_WEIGHT = 0.1 / np.radians(10.0)


@dataclasses.dataclass(frozen=True)
class Segments:
    """Short windows of measured data, each a start State and the samples that follow.

    Attributes:
        start: State with leading axis S (the measured state at each start).
        pos: (S, H, n, 3) measured positions of the next ``horizon`` samples.
        quat: (S, H, n, 4) measured orientations of those samples.
        trajectory: (S,) index of the trajectory each segment comes from.
        sample: (S,) its start sample.
        horizon: H, samples predicted per segment.
    """

    start: State
    pos: jax.Array
    quat: jax.Array
    trajectory: np.ndarray
    sample: np.ndarray
    horizon: int


def measured_velocities(trajectories: Trajectories):
    """(vel, angvel), each (K, T, n, 3) world frame: the data's own, or central differences of the poses."""
    if trajectories.vel is not None and trajectories.angvel is not None:
        return trajectories.vel, trajectories.angvel
    dt = trajectories.sample_dt
    pos, quat = trajectories.pos, trajectories.quat
    vel = np.gradient(pos, dt, axis=1)
    step = quat_log(quat_multiply(quat[:, 1:], quat_conjugate(quat[:, :-1]))) / dt  # (K, T-1, n, 3) between samples
    angvel = np.concatenate([step[:, :1], 0.5 * (step[:, 1:] + step[:, :-1]), step[:, -1:]], axis=1)
    return vel, angvel


def make_segments(template: State, trajectories: Trajectories, horizon: int, stride: int = 1) -> Segments:
    """Every window of ``horizon`` predicted samples starting at a multiple of ``stride``.

    Args:
        template: a one-world State from ``Scene.build`` (its other fields are copied).
        trajectories: K measured trajectories.
        horizon: samples predicted from each start, >= 1.
        stride: samples between starts, >= 1.

    Returns:
        :class:`Segments`; a trajectory shorter than ``horizon + 1`` gives none.
    """
    if horizon < 1 or stride < 1:
        raise ValueError(f"make_segments: horizon ({horizon}) and stride ({stride}) must be >= 1")
    vel, angvel = measured_velocities(trajectories)
    pairs = [(k, s) for k in range(trajectories.num_trajectories)
             for s in range(0, int(trajectories.length[k]) - horizon, stride)]
    if not pairs:
        raise ValueError(f"{trajectories.source}: no trajectory has more than horizon={horizon} samples")
    k, s = np.array(pairs).T
    ahead = s[:, None] + np.arange(1, horizon + 1)[None]
    dtype = template.pos.dtype
    start = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (len(k),) + jnp.shape(a)), template)
    start = start.replace(pos=jnp.asarray(trajectories.pos[k, s], dtype),
                          quat=jnp.asarray(trajectories.quat[k, s], dtype),
                          vel=jnp.asarray(vel[k, s], dtype), angvel=jnp.asarray(angvel[k, s], dtype))
    if trajectories.qpos is not None:  # a scene with joints steps its coordinates; the poses above are their read-out
        start = start.replace(qpos=jnp.asarray(trajectories.qpos[k, s], dtype),
                              qvel=jnp.asarray(trajectories.qvel[k, s], dtype))
    return Segments(start=start, pos=jnp.asarray(trajectories.pos[k[:, None], ahead], dtype),
                    quat=jnp.asarray(trajectories.quat[k[:, None], ahead], dtype),
                    trajectory=k, sample=s, horizon=horizon)


def rotation_vector(quat, target):
    """(..., 3) vector part of target⁻¹ ⊗ quat, sign-aligned and doubled: the rotation vector for small errors."""
    w = jnp.sum(quat * target, axis=-1, keepdims=True)
    tw, tv = target[..., :1], target[..., 1:]
    qw, qv = quat[..., :1], quat[..., 1:]
    vector = tw * qv - qw * tv - jnp.cross(tv, qv)
    return 2.0 * jnp.where(w < 0, -vector, vector)


def residual_function(step: Callable, segments: Segments, sizes, every: int = 1) -> Callable:
    """``residuals(params) -> (S, H, n, 6)``: each segment's prediction errors (module docstring).

    Args:
        step: the step function.
        segments: from :func:`make_segments`.
        sizes: (n,) body sizes.
        every: steps per sample interval.
    """
    sizes = jnp.asarray(sizes, segments.pos.dtype)[:, None]

    def residuals(params):
        def one(start):
            return rollout(step, start, params, segments.horizon * every, every=every)

        predicted = jax.vmap(one)(segments.start)
        position = (predicted.pos - segments.pos) / sizes
        rotation = ROTATION_WEIGHT * rotation_vector(predicted.quat, segments.quat)
        return jnp.concatenate([position, rotation], axis=-1)

    return residuals
