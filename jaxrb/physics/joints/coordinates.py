"""MuJoCo's coordinates of any scene: ``qpos``/``qvel`` read out of a State and written into one.

In a scene with joints the State carries them (``State.qpos``, ``State.qvel``)
and the bodies' poses are their read-outs. A 3D scene of free bodies has the
layout MuJoCo gives free bodies, 7 and 6 numbers a body: the body frame's
origin and quaternion; the origin's world velocity, then the angular
velocity in the body frame. A 2D free body has 3 and 3: its frame origin's
x, y and its angle, and their rates (a 2D scene with joints lays its free
bodies out the same way). Both functions work under ``jit``, ``vmap`` and
``scan``.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxrb.math import quaternion as quat_ops
from jaxrb.math.vector import cross
from jaxrb.model.types import Model, Params, State
from jaxrb.physics.joints.step import read_out


def qpos_qvel(model: Model, params: Params, state: State):
    """The State's coordinates in MuJoCo's layout for the same model.

    Args:
        model: the Model.
        params: the Params (``com_offset`` places a free body's frame origin).
        state: a State (any leading batch axes only under ``vmap``).

    Returns:
        (qpos (nq,), qvel (nv,)): free 7/6, ball 4/3, hinge and slide 1/1, in body order.
    """
    if model.joints is not None:
        return state.qpos, state.qvel
    if model.dim == 2:  # a free body of the plane: its frame's x, y and angle, their rates
        arm = _arm2(state.angle, params.com_offset)
        origin_vel = state.vel - state.angvel[:, None] * jnp.stack([-arm[:, 1], arm[:, 0]], axis=-1)
        return (jnp.concatenate([state.pos - arm, state.angle[:, None]], axis=-1).reshape(-1),
                jnp.concatenate([origin_vel, state.angvel[:, None]], axis=-1).reshape(-1))
    arm = quat_ops.rotate(state.quat, params.com_offset)  # frame origin to centre of mass, world
    origin, origin_vel = state.pos - arm, state.vel - cross(state.angvel, arm)
    local_angvel = quat_ops.rotate_inverse(state.quat, state.angvel)
    return (jnp.concatenate([origin, state.quat], axis=-1).reshape(-1),
            jnp.concatenate([origin_vel, local_angvel], axis=-1).reshape(-1))


def set_qpos_qvel(model: Model, params: Params, state: State, qpos, qvel) -> State:
    """``state`` moved to the coordinates ``qpos``, ``qvel`` (MuJoCo's layout), its bodies' poses with it.

    Args:
        model: the Model.
        params: the Params.
        state: the State to change (contact warm starts and time are kept).
        qpos: (nq,) coordinates; quaternions are normalised where used.
        qvel: (nv,) velocities.

    Returns:
        The new State: ``qpos``/``qvel`` and the read-outs ``pos`` (centres
        of mass), ``quat``, ``vel`` and ``angvel``.
    """
    qpos, qvel = jnp.asarray(qpos, state.pos.dtype), jnp.asarray(qvel, state.pos.dtype)
    if model.joints is not None:
        return read_out(model, params, state, qpos, qvel)
    n = model.num_bodies
    if model.dim == 2:
        qpos, qvel = qpos.reshape(n, 3), qvel.reshape(n, 3)
        arm = _arm2(qpos[:, 2], params.com_offset)
        spin = qvel[:, 2:] * jnp.stack([-arm[:, 1], arm[:, 0]], axis=-1)
        return state.replace(pos=qpos[:, :2] + arm, angle=qpos[:, 2], vel=qvel[:, :2] + spin, angvel=qvel[:, 2])
    qpos, qvel = qpos.reshape(n, 7), qvel.reshape(n, 6)
    quat = quat_ops.normalize(qpos[:, 3:])
    arm = quat_ops.rotate(quat, params.com_offset)
    angvel = quat_ops.rotate(quat, qvel[:, 3:])
    return state.replace(pos=qpos[:, :3] + arm, quat=quat, vel=qvel[:, :3] + cross(angvel, arm), angvel=angvel)


def _arm2(angle, com_offset):
    """(n, 2) each 2D body's frame origin to its centre of mass, world."""
    c, s = jnp.cos(angle), jnp.sin(angle)
    return jnp.stack([c * com_offset[:, 0] - s * com_offset[:, 1], s * com_offset[:, 0] + c * com_offset[:, 1]], axis=-1)
