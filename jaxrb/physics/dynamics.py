"""Forces, torques and Newton–Euler quantities for single bodies.

Angular momentum about a body's centre of mass is L = R I0 Rᵀ ω and its
inverse map ω = R I0⁻¹ Rᵀ L; both are applied by rotating into the body frame,
multiplying by the body-frame tensor and rotating back, which never forms the
world tensor on the hot path.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxrb.math import quaternion as quat_ops
from jaxrb.math.vector import cross, cross2, inverse3, matvec3
from jaxrb.model.types import Model, Params, State, Wrench


def apply_world_inertia(quat, inertia, vector):
    """R I Rᵀ v: a body-frame tensor applied to a world vector, without forming R I Rᵀ.

    Args:
        quat: (n, 4) unit quaternions (w, x, y, z), body to world.
        inertia: (n, 3, 3) body-frame tensors (inertia or inverse inertia).
        vector: (n, 3) world-frame vectors (e.g. angular velocity).

    Returns:
        (n, 3) world-frame products (e.g. angular momentum).
    """
    return quat_ops.rotate(quat, matvec3(inertia, quat_ops.rotate_inverse(quat, vector)))


def world_inertia(quat, inertia):
    """World-frame inertia tensors R I Rᵀ.

    Args:
        quat: (n, 4) unit quaternions (w, x, y, z), body to world.
        inertia: (n, 3, 3) body-frame inertia tensors about the centres of mass.

    Returns:
        (n, 3, 3) world-frame inertia tensors.
    """
    rotation = quat_ops.to_rotation_matrix(quat)
    return rotation @ inertia @ jnp.swapaxes(rotation, -1, -2)


def inverse_inertia(params: Params, dim: int):
    """Body-frame inverse inertia: ``params.inv_inertia`` where filled, else computed.

    Args:
        params: Params (uses ``inv_inertia`` or ``inertia``: (n, 3, 3) in 3D,
            (n,) in 2D).
        dim: 2 or 3.

    Returns:
        (n, 3, 3) inverse tensors in 3D (closed-form), (n,) inverse moments in 2D.
    """
    if params.inv_inertia is not None:
        return params.inv_inertia
    return _inverted(params.inertia, dim)


def _inverted(inertia, dim: int):
    return inverse3(inertia) if dim == 3 else 1.0 / inertia


def with_inverse_inertia(params: Params, dim: int) -> Params:
    """``params`` with ``inv_inertia`` (re)computed from ``inertia``.

    Args:
        params: Params (``inertia``: (n, 3, 3) in 3D, (n,) in 2D).
        dim: 2 or 3.

    Returns:
        Params whose ``inv_inertia`` is ``inertia``'s inverse, whatever it held.
    """
    return params.replace(inv_inertia=_inverted(params.inertia, dim))


def net_wrench(model: Model, params: Params, applied: Wrench | None):
    """Total force and torque on each body from gravity, constant and applied loads.

    Args:
        model: the scene's Model.
        params: Params (``mass``, ``gravity``, ``force``, ``torque``).
        applied: optional Wrench for this step (force (n, dim), torque (n, 3)
            or (n,)), or None.

    Returns:
        (force, torque): (n, dim) world-frame forces at the centres of mass and
        (n, 3) world-frame torques in 3D, (n,) in 2D.
    """
    force = params.mass[:, None] * params.gravity + params.force
    torque = params.torque
    if applied is not None:
        force = force + applied.force
        torque = torque + applied.torque
    return force, torque


def wrench_at_points(model: Model, state: State, body, force, point) -> Wrench:
    """Wrench of forces applied at world points: torque q = Σ (p − x_com) × f.

    Args:
        model: the scene's Model.
        state: the current State (gives each body's centre of mass).
        body: (k,) integer body index of each force.
        force: (k, dim) world-frame forces.
        point: (k, dim) world-frame points of application.

    Returns:
        A :class:`Wrench` with force (n, dim) and torque (n, 3) or (n,), summed per body.
    """
    body = jnp.asarray(body)
    force = jnp.asarray(force, dtype=state.pos.dtype)
    arm = jnp.asarray(point, dtype=state.pos.dtype) - state.pos[body]
    moment = cross(arm, force) if model.dim == 3 else cross2(arm, force)
    total_force = jnp.zeros_like(state.pos).at[body].add(force)
    total_torque = jnp.zeros_like(state.angvel).at[body].add(moment)
    return Wrench(force=total_force, torque=total_torque)


def angular_momentum(model: Model, params: Params, state: State):
    """Per-body angular momentum about each centre of mass.

    Args:
        model: the scene's Model.
        params: Params (body-frame ``inertia``).
        state: State (``quat`` and ``angvel``).

    Returns:
        (n, 3) world-frame angular momenta in 3D, (n,) in 2D.
    """
    if model.dim == 2:
        return params.inertia * state.angvel
    return apply_world_inertia(state.quat, params.inertia, state.angvel)


def total_angular_momentum(model: Model, params: Params, state: State):
    """Angular momentum of the whole scene about the world origin (spin plus orbital).

    Args:
        model: the scene's Model.
        params: Params (``mass``, ``inertia``).
        state: State (positions, velocities, orientations).

    Returns:
        (3,) world-frame total angular momentum in 3D, () in 2D.
    """
    orbital_fn = cross if model.dim == 3 else cross2
    orbital = orbital_fn(state.pos, params.mass[:, None] * state.vel)
    return jnp.sum(angular_momentum(model, params, state) + orbital, axis=0)


def kinetic_energy(model: Model, params: Params, state: State):
    """Per-body kinetic energy, translational plus rotational.

    Args:
        model: the scene's Model.
        params: Params (``mass``, ``inertia``).
        state: State (``vel``, ``angvel``, orientation).

    Returns:
        (n,) kinetic energies (J).
    """
    translational = 0.5 * params.mass * jnp.sum(state.vel * state.vel, axis=-1)
    momentum = angular_momentum(model, params, state)
    rotational = 0.5 * (momentum * state.angvel if model.dim == 2
                        else jnp.sum(momentum * state.angvel, axis=-1))
    return translational + rotational


def potential_energy(model: Model, params: Params, state: State):
    """Per-body gravitational potential energy −m g·x (zero at the world origin).

    Args:
        model: the scene's Model.
        params: Params (``mass``, ``gravity``).
        state: State (``pos``).

    Returns:
        (n,) potential energies (J).
    """
    return -params.mass * jnp.sum(state.pos * params.gravity, axis=-1)
