"""What the joints transmit: the wrench each body's parent (or the world) exerts on it, for a motion.

For a state and its joint accelerations q̈, each body's Newton–Euler
equations give the force and torque it needs, f = m (a − g) − F and
τ = I α + ω × I ω − T (a, α its accelerations J q̈ + J̇ q̇, F and T the loads
applied to it); what its joints pass in from the parent carries its whole
subtree: the sum of those over the subtree, the torque taken about the
body's frame origin (MuJoCo's ``cfrc_int``, in the world frame and about
another point). The constraint force is its part across the joint's free
directions; along them it is the actuator, spring, damping and friction
forces. Contact forces are not known here: give them in ``applied`` (or the
body's needs include them).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxrb.math.vector import cross, matvec3
from jaxrb.model.types import Model, Params, State, Wrench
from jaxrb.physics.joints import planar
from jaxrb.physics.joints.dynamics import world_inertia
from jaxrb.physics.joints.kinematics import bias_accelerations, kinematics


def _subtrees(tree) -> np.ndarray:
    """(n, n) bool: row b marks b and its descendants."""
    n = len(tree.parent)
    inside = np.eye(n, dtype=bool)
    for body in range(n):
        at = tree.parent[body]
        while at >= 0:
            inside[at, body] = True
            at = tree.parent[at]
    return inside


def joint_wrenches(model: Model, params: Params, state: State, qacc, applied: Wrench = None):
    """The wrench each body's parent (or the world) exerts on it through its joints.

    Args:
        model: a Model with joints.
        params: the Params.
        state: the State (its ``qpos``, ``qvel``).
        qacc: (nv,) joint accelerations, e.g. (q̇ₖ₊₁ − q̇ₖ)/dt of a trajectory.
        applied: an optional Wrench of loads besides gravity and the
            Params' constant ones: force (n, dim), torque (n, 3) or (n,)
            (contact forces belong here).

    Returns:
        (force (n, 3), torque (n, 3)): world frame, the torque about each
        body's frame origin. For a 2D scene the 3D view's (forces in the
        plane, torques about z).
    """
    tree = model.joints
    if tree is None:
        raise ValueError("rb.joints.joint_wrenches: this model has no joints")
    space = planar.lift_params(params) if model.dim == 2 else params
    kin = kinematics(tree, space, state.qpos)
    linear, angular, _, angvel = bias_accelerations(tree, kin, state.qvel)
    qacc = jnp.asarray(qacc, state.qvel.dtype)
    linear = linear + jnp.einsum("bdi,d->bi", kin.jac_lin, qacc)
    angular = angular + jnp.einsum("bdi,d->bi", kin.jac_ang, qacc)
    force, torque = space.force, space.torque
    if applied is not None:
        extra = planar.lift_loads(applied.force, applied.torque) if model.dim == 2 else (applied.force,
                                                                                         applied.torque)
        force, torque = force + extra[0], torque + extra[1]
    inertia = world_inertia(kin, space)
    needs = space.mass[:, None] * (linear - space.gravity) - force
    turns = matvec3(inertia, angular) + cross(angvel, matvec3(inertia, angvel)) - torque
    subtree = jnp.asarray(_subtrees(tree), needs.dtype)  # (n, n): b's subtree
    total_force = subtree @ needs
    lever = kin.com[None, :, :] - kin.origin[:, None, :]  # (b, c, 3): c's centre of mass from b's origin
    moments = turns[None, :, :] + cross(lever, jnp.broadcast_to(needs[None], lever.shape))
    total_torque = jnp.sum(subtree[:, :, None] * moments, axis=1)
    return total_force, total_torque
