"""2D scenes with joints: the plane's quantities lifted into the 3D joint machinery, and the results brought back.

A 2D mechanism is a 3D one whose hinges turn about z and whose sliders and
loads lie in the x-y plane, so the joint step runs the 3D kinematics and
dynamics on a lifted view of the Params (a body's moment of inertia about z
on the diagonal of its tensor, vectors padded with a zero z) and reads the
State's 2D fields back out (position x, y; the angle about z; velocities in
the plane). A free body of the plane is a slide along x, a slide along y and
a hinge about z (qpos: its frame origin's x, y and its angle). Collision runs
the 2D kernels on the 2D State, and its contacts are lifted the same way.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from jaxrb.model.types import Params


def _pad(vectors):
    """(..., 2) -> (..., 3) with a zero z."""
    return jnp.concatenate([vectors, jnp.zeros_like(vectors[..., :1])], axis=-1)


def lift_params(params: Params) -> Params:
    """The 3D view of a 2D scene's Params: inertia (n,) -> (n, 3, 3), com_offset, gravity, force (.., 2) -> (.., 3),
    torque (n,) -> (n, 3) about z. The joints' fields are 3D already."""
    moment = params.inertia
    inertia = moment[:, None, None] * jnp.eye(3, dtype=moment.dtype)
    force, torque = lift_loads(params.force, params.torque)
    # dataclasses.replace, not Params.replace: the view's shapes are not the scene's, on purpose.
    return dataclasses.replace(params, inertia=inertia, com_offset=_pad(params.com_offset),
                               gravity=_pad(params.gravity), force=force, torque=torque, inv_inertia=None)


def lift_loads(force, torque):
    """2D loads (force (n, 2), torque (n,)) as 3D ones ((n, 3), (n, 3))."""
    return _pad(force), _pad(jnp.zeros_like(force)).at[:, 2].set(torque)


def lower_loads(force, torque):
    """3D loads ((n, 3), (n, 3)) back in the plane: (n, 2) and (n,)."""
    return force[:, :2], torque[:, 2]


def lift_contacts(contacts):
    """A 2D ContactSet with its normals and points given a zero z."""
    return contacts.replace(normal=_pad(contacts.normal), point=_pad(contacts.point))


def lift_impulses(impulses):
    """(C, 3) normal and 2D friction impulses -> (C, 4)."""
    return _pad(impulses)


def lower_impulses(impulses):
    """(C, 4) normal and 3D friction impulses -> (C, 3)."""
    return impulses[:, :3]


def angle_of(quat):
    """(n,) the angles about z, in [−π, π], of (n, 4) quaternions that turn about z only."""
    sign = jnp.where(quat[:, 0] < 0.0, -1.0, 1.0)  # q and −q are one rotation: take w >= 0
    return 2.0 * jnp.arctan2(sign * quat[:, 3], sign * quat[:, 0])
