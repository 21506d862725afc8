"""Equations of motion of joint trees: M(q) q̈ + c(q, q̇) = τ, with MuJoCo's joint and actuator laws.

* Mass matrix M = Σ_b m_b J_lin,bᵀ J_lin,b + J_ang,bᵀ I_b J_ang,b + diag(armature),
  from the Jacobians of :mod:`jaxrb.physics.joints.kinematics` (no tree walk).
* Bias c = Σ_b J_lin,bᵀ m_b (J̇q̇ − g) + J_ang,bᵀ (I_b (J̇q̇)_ang + ω_b × I_b ω_b):
  each body's Newton–Euler equations at zero q̈, projected on the dofs.
* Joint forces (MuJoCo's passive and actuator forces): springs −k (q − springref),
  damping −b q̇ (implicit, as MuJoCo's Euler integrator takes it), smooth
  Coulomb friction, actuators gain·ctrl + b0 + b1·gear·q + b2·gear·q̇ through
  their gear, with control and force clamps.
* Limits: an implicit spring-damper on each limited hinge or slide while it
  is past its range, of stiffness m_jj (2πf)² and damping 2ζ m_jj (2πf) on the
  dof's own inertia m_jj (M's diagonal), f = ``limit_hertz`` capped at a
  fraction of the step rate. MuJoCo's limits are soft constraints solved with
  the contacts (``solreflimit``: a 0.02 s time constant by default); these
  are stiffer (f = 0.5/h by default: a 10× overload passes a limit by
  F/(m_jj ω²)) and take no solver pass.

The step solves (M + h D + h² K) q̈ = τ − D q̇ − K (δ + h q̇) for q̈, where D
holds the damping (the dof's, the limits', the smooth friction's slope) and
K the limits' stiffness with δ the coordinate past the limit: implicit Euler
in those terms, explicit in the rest.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxrb.math import quaternion as quat_ops
from jaxrb.math import small_linalg
from jaxrb.math.vector import cross, matvec3
from jaxrb.model.struct import pytree_dataclass
from jaxrb.model.types import Array, Params
from jaxrb.physics.joints.kinematics import Kinematics, bias_accelerations, kinematics

#: Limit stiffness cap, as a fraction of the step rate 1/h, for implicit Euler and for RK4
#: (explicit: a critically damped spring at ω h = 2π·0.3 ≈ 1.9 stays inside RK4's stability region).
LIMIT_HERTZ_CAP = {"euler": 0.5, "rk4": 0.3}


@pytree_dataclass
class Forces:
    """The terms of one step's equations of motion.

    Attributes:
        mass_matrix: (nv, nv) M(q) with armature.
        force: (nv,) everything explicit: actuators, springs, applied loads, gravity and bias, −D q̇.
        damping: (nv,) the diagonal D taken implicitly.
        stiffness: (nv,) the diagonal K taken implicitly (the limits past their range).
        offset: (nv,) δ, how far each dof is past its limit (0 elsewhere).
    """

    mass_matrix: Array
    force: Array
    damping: Array
    stiffness: Array
    offset: Array


def world_inertia(kin: Kinematics, params: Params):
    """(n, 3, 3) R I Rᵀ of every body."""
    rotation = quat_ops.to_rotation_matrix(kin.quat)
    return rotation @ params.inertia @ jnp.swapaxes(rotation, -1, -2)


def mass_matrix(params: Params, kin: Kinematics, inertia):
    """(nv, nv) joint-space mass matrix with armature; ``inertia`` (n, 3, 3) world inertias."""
    linear = jnp.einsum("bdi,b,bei->de", kin.jac_lin, params.mass, kin.jac_lin)
    angular = jnp.einsum("bdi,bij,bej->de", kin.jac_ang, inertia, kin.jac_ang)
    return linear + angular + jnp.diag(params.joint_armature)


def generalized(kin: Kinematics, force, torque):
    """(nv,) Jᵀ of world forces (n, 3) at the centres of mass and torques (n, 3)."""
    return jnp.einsum("bdi,bi->d", kin.jac_lin, force) + jnp.einsum("bdi,bi->d", kin.jac_ang, torque)


def bias_force(tree, params: Params, kin: Kinematics, inertia, qvel):
    """(nv,) c(q, q̇): Coriolis, centrifugal and gravity terms (move to the right-hand side with a minus)."""
    linear, angular, _, angvel = bias_accelerations(tree, kin, qvel)
    momentum = matvec3(inertia, angvel)
    force = params.mass[:, None] * (linear - params.gravity)
    torque = matvec3(inertia, angular) + cross(angvel, momentum)
    return generalized(kin, force, torque)


def _dof_values(tree, per_joint, qpos):
    """Per-dof values of hinge and slide joints: (nv,) from (nj,) (0 on other dofs); also q per dof."""
    scalar = [j for j, kind in enumerate(tree.joint_kind) if kind in ("hinge", "slide")]
    index = np.zeros(tree.nv, int)
    mask = np.zeros(tree.nv, bool)
    qindex = np.zeros(tree.nv, int)
    for j in scalar:
        index[tree.dof_adr[j]] = j
        mask[tree.dof_adr[j]] = True
        qindex[tree.dof_adr[j]] = tree.qpos_adr[j]
    values = jnp.where(mask, per_joint[index], 0.0)
    return values, jnp.where(mask, qpos[qindex], 0.0), mask


def spring_force(tree, params: Params, qpos):
    """(nv,) −k (q − springref) on hinges and slides."""
    stiffness, q, _ = _dof_values(tree, params.joint_stiffness, qpos)
    rest, _, _ = _dof_values(tree, params.joint_springref, qpos)
    return -stiffness * (q - rest)


def limit_terms(tree, params: Params, qpos, qvel, diagonal, h, integrator):
    """Stiffness, damping and offset (each (nv,)) of the limits that act this step.

    A limit acts once its joint is past it, or, taken implicitly (Euler),
    would pass it within the step at the current speed: then its spring
    aims the step's end at the limit rather than letting it through first
    (as a speculative contact does), and its offset δ is the signed
    distance past the limit (negative while short of it).

    Args:
        qpos: (nq,) coordinates; qvel: (nv,) velocities.
        diagonal: (nv,) M's diagonal, the inertia each limit acts on.
        h: () the step.
        integrator: ``"euler"`` or ``"rk4"`` (the stiffness cap, :data:`LIMIT_HERTZ_CAP`).
    """
    limited = [j for j in range(tree.num_joints) if tree.limited[j]]
    zeros = jnp.zeros_like(diagonal)
    if not limited:
        return zeros, zeros, zeros
    joint = np.zeros(tree.nv, int)
    mask = np.zeros(tree.nv, bool)
    qindex = np.zeros(tree.nv, int)
    for j in limited:
        joint[tree.dof_adr[j]], mask[tree.dof_adr[j]], qindex[tree.dof_adr[j]] = j, True, tree.qpos_adr[j]
    q = qpos[qindex]
    low, high = params.joint_range[joint, 0], params.joint_range[joint, 1]
    reach = h * qvel if integrator == "euler" else 0.0
    below, above = mask & (q + jnp.minimum(reach, 0.0) < low), mask & (q + jnp.maximum(reach, 0.0) > high)
    offset = jnp.where(below, q - low, 0.0) + jnp.where(above, q - high, 0.0)
    active = below | above
    omega = 2.0 * jnp.pi * jnp.minimum(params.limit_hertz, LIMIT_HERTZ_CAP[integrator] / h)
    stiffness = jnp.where(active, diagonal * omega ** 2, 0.0)
    damping = jnp.where(active, 2.0 * params.limit_damping_ratio * diagonal * omega, 0.0)
    return stiffness, damping, offset


def smooth_friction(tree, params: Params, qvel):
    """Smooth Coulomb friction on the friction dofs: force −μ q̇/√(q̇² + v²) and its slope μ v²/(q̇² + v²)^{3/2}.

    Returns:
        (force (nv,), slope (nv,)), zero off the friction dofs.
    """
    mask = np.zeros(tree.nv, bool)
    mask[list(tree.friction_dofs)] = True
    mu = jnp.where(mask, params.joint_frictionloss, 0.0)
    scale = params.joint_friction_velocity
    squared = qvel ** 2 + scale ** 2
    root = jnp.sqrt(squared)
    return -mu * qvel / root, mu * scale ** 2 / (squared * root)


def actuator_force(tree, params: Params, qpos, qvel, controls):
    """The actuators' joint forces for ``controls`` (na,), MuJoCo's gain/bias law with clamps.

    Returns:
        (force (nv,), slope (nv,)): the forces, and each dof's ∂force/∂q̇ from
        the velocity bias b2·gear² where the force is inside its clamp (0 elsewhere).
    """
    if not tree.num_actuators:
        return jnp.zeros_like(qvel), jnp.zeros_like(qvel)
    joints = np.asarray(tree.actuator_joint)
    dof = np.asarray(tree.dof_adr)[joints]
    q = qpos[np.asarray(tree.qpos_adr)[joints]]
    gear = params.actuator_gear
    ctrl = jnp.asarray(controls, qvel.dtype)
    ctrl_limited = np.asarray(tree.ctrl_limited)
    if ctrl_limited.any():
        ctrl = jnp.where(ctrl_limited, jnp.clip(ctrl, params.ctrl_range[:, 0], params.ctrl_range[:, 1]), ctrl)
    bias = params.actuator_bias
    force = params.actuator_gain * ctrl + bias[:, 0] + bias[:, 1] * gear * q + bias[:, 2] * gear * qvel[dof]
    slope = bias[:, 2] * gear * gear
    force_limited = np.asarray(tree.force_limited)
    if force_limited.any():
        low, high = params.force_range[:, 0], params.force_range[:, 1]
        slope = jnp.where(force_limited & ((force < low) | (force > high)), 0.0, slope)
        force = jnp.where(force_limited, jnp.clip(force, low, high), force)
    spread = lambda values: jnp.zeros_like(qvel).at[dof].add(values)
    return spread(gear * force), spread(slope)


def smooth_force(model, params: Params, qpos, qvel, controls=None, applied=None, kin=None):
    """(nv,) everything but the implicit terms: −c(q, q̇) (with gravity), springs, applied loads, actuators.

    Args:
        model: the Model (``joints`` the tree).
        params: Params.
        qpos: (nq,) coordinates; qvel: (nv,) velocities.
        controls: (na,) actuator inputs, or None (zero).
        applied: (force (n, 3), torque (n, 3)) world loads at the centres of
            mass (constant ones and the step's Wrench), or None.
        kin: the Kinematics of ``qpos`` if already computed.

    Returns:
        (force (nv,), actuator slope (nv,)): the generalized force and
        :func:`actuator_force`'s slope.
    """
    tree = model.joints
    kin = kinematics(tree, params, qpos) if kin is None else kin
    force = -bias_force(tree, params, kin, world_inertia(kin, params), qvel) + spring_force(tree, params, qpos)
    if applied is not None:
        force = force + generalized(kin, *applied)
    slope = jnp.zeros_like(qvel)
    if controls is not None:
        actuated, slope = actuator_force(tree, params, qpos, qvel, controls)
        force = force + actuated
    return force, slope


def forces(model, params: Params, kin: Kinematics, qpos, qvel, h, controls=None, applied=None) -> Forces:
    """Every term of the equations of motion at (qpos, qvel), split as ``model.integrator`` takes them.

    Joint damping, the limits and smooth friction are implicit (in ``damping``
    and ``stiffness``) for the velocity-first integrators; ``midpoint`` and
    ``implicit`` take the actuators' velocity gains implicitly too (MuJoCo's
    Euler, ``semi_implicit``, keeps them explicit); ``rk4`` takes everything
    explicitly (``damping`` and ``stiffness`` are then zero, folded into ``force``).

    Args:
        model: the Model (``joints`` the tree, ``integrator``).
        params: Params.
        kin: the Kinematics of ``qpos``.
        qpos: (nq,) coordinates; qvel: (nv,) velocities.
        h: () the step the implicit terms are taken over.
        controls: (na,) actuator inputs, or None (zero).
        applied: (force (n, 3), torque (n, 3)) world loads at the centres of
            mass (constant ones and the step's Wrench), or None.

    Returns:
        :class:`Forces`.
    """
    tree = model.joints
    explicit = model.integrator == "rk4"
    matrix = mass_matrix(params, kin, world_inertia(kin, params))
    force, actuator_slope = smooth_force(model, params, qpos, qvel, controls, applied, kin)
    damping = params.joint_damping
    if model.integrator in ("midpoint", "implicit"):
        damping = damping - actuator_slope  # force already holds the explicit b2 q̇ term, as it holds −D q̇
    if tree.friction_dofs and tree.joint_friction == "smooth":
        friction, slope = smooth_friction(tree, params, qvel)
        force, damping = force + friction, damping + slope
    stiffness, limit_damping, offset = limit_terms(tree, params, qpos, qvel, jnp.diagonal(matrix), h,
                                                   "rk4" if explicit else "euler")
    force = force - params.joint_damping * qvel - limit_damping * qvel - stiffness * offset
    damping = damping + limit_damping
    if explicit:
        return Forces(mass_matrix=matrix, force=force, damping=jnp.zeros_like(damping),
                      stiffness=jnp.zeros_like(stiffness), offset=offset)
    return Forces(mass_matrix=matrix, force=force, damping=damping, stiffness=stiffness, offset=offset)


@pytree_dataclass
class Factor:
    """A factored step matrix M̃: Cholesky where it is symmetric, LU where the implicit integrators
    made it not (their Coriolis and actuator terms); :mod:`jaxrb.math.small_linalg` factors it.

    Attributes:
        cholesky: (nv, nv) lower Cholesky factor, or None.
        lu: (nv, nv) packed LU factors, or None.
        pivots: (nv,) LU's row permutation, or None.
    """

    cholesky: Array = None
    lu: Array = None
    pivots: Array = None


def factor(matrix, symmetric: bool) -> Factor:
    """Factor the (nv, nv) ``matrix`` (Cholesky if ``symmetric``, else LU)."""
    if symmetric:
        return Factor(cholesky=small_linalg.cholesky(matrix))
    lu, pivots = small_linalg.lu_factor(matrix)
    return Factor(lu=lu, pivots=pivots)


def solve(found: Factor, rhs):
    """M̃⁻¹ rhs for rhs (nv,) or (nv, k)."""
    if found.cholesky is not None:
        return small_linalg.cholesky_solve(found.cholesky, rhs)
    return small_linalg.lu_solve(found.lu, found.pivots, rhs)
