"""Inverse dynamics of joint trees and the linear-in-parameters model robot identification uses.

* :func:`inverse_dynamics` — the joint forces τ = M(q) q̈ + c(q, q̇) + D q̇ +
  μ·s(q̇) + K (q − q_ref) that a trajectory needs: the force the actuators
  and the constraints must supply. It is built from the step's own terms
  (:mod:`.dynamics`), so it is the exact inverse of the equations of motion
  the integrators solve.
* :func:`regressor` — Y(q, q̇, q̈) with ``inverse_dynamics == Y @ theta``,
  theta the *standard parameters* (:func:`standard_parameters`): per moving
  body the 10 inertial parameters about its frame origin, in its frame

      m, m c_x, m c_y, m c_z, I_xx, I_xy, I_xz, I_yy, I_yz, I_zz

  (c the centre of mass; I = I_com + m (|c|² 1 − c cᵀ), the parallel-axis
  inertia about the origin), then per dof armature, damping and Coulomb
  friction, then per hinge or slide stiffness (springref fixed). The
  regressor is the Newton–Euler equations about each body's frame origin,
  written independently of :mod:`.dynamics` (where the inertia sits about
  the centre of mass and the parameters do not enter linearly), and
  differentiated exactly (``jax.jacfwd`` of a function linear in theta).
* :func:`base_parameters` — the identifiable combinations theta_b = K theta
  of a stacked regressor, found in the order of the standard parameters
  (each parameter whose column is a combination of earlier ones is folded
  into them, as Khalil and Gautier regroup a robot's parameters), and named
  by the parameter they lead plus the ones folded in, e.g.
  ``"I_yy[link1] + 0.09 m[link2] + armature[shoulder]"``.
* :func:`fit_base_parameters` — least squares of theta_b from measured
  (q, q̇, q̈, τ), with per-dof weighting and standard errors.

Everything but :func:`base_parameters` and :func:`fit_base_parameters` works
under ``jit`` and ``vmap`` (those two are host-side NumPy on a stacked
regressor). The model must have joints (:mod:`jaxrb.model.joints`); a 2D
scene's run on the 3D view of its Params (:mod:`.planar`), a body then
having the plane's 4 inertial parameters m, m c_x, m c_y and I_zz.

What :func:`inverse_dynamics` leaves out: joint limits (their spring-damper is
a constraint force, part of what it returns once a joint is past its range)
and loop closures and contacts (constraint forces as well). It includes the
constant loads of the Params (``force``/``torque``) and the bodies' linear
and angular damping where the Model compiles them in; those two are not
linear in the standard parameters, so :func:`regressor` refuses Models and
Params that have them.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Callable, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.math import quaternion as quat_ops
from jaxrb.math.vector import cross, matvec3
from jaxrb.model.types import Model, Params
from jaxrb.physics.joints import planar
from jaxrb.physics.joints.dynamics import bias_force, generalized, mass_matrix, spring_force, world_inertia
from jaxrb.physics.joints.kinematics import bias_accelerations, body_velocities, kinematics

#: Coulomb friction laws of :func:`inverse_dynamics` and :func:`regressor`: jaxrb's smooth
#: μ q̇/√(q̇² + v²) (``Params.joint_friction_velocity`` = v, the step's ``"smooth"`` joint friction)
#: and the discontinuous μ sign(q̇) (what a sliding joint feels with ``"exact"`` friction).
FRICTION_LAWS = ("smooth", "sign")
#: The 10 inertial parameters of a body, in the order of the standard parameter vector.
INERTIAL_NAMES = ("m", "mc_x", "mc_y", "mc_z", "I_xx", "I_xy", "I_xz", "I_yy", "I_yz", "I_zz")
#: A body's inertial parameters in a 2D scene (motion in the x-y plane, turning about z): their
#: indices among :data:`INERTIAL_NAMES`.
PLANAR_INERTIAL = (0, 1, 2, 9)
#: (row, column) of the inertia entries I_xx, I_xy, I_xz, I_yy, I_yz, I_zz.
_INERTIA_ENTRIES = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
_DOF_SUFFIXES = {"ball": ("x", "y", "z"), "free": ("x", "y", "z", "rx", "ry", "rz")}


def _space(model: Model, params: Params) -> Params:
    """The 3D view of the Params the joint machinery runs on (:mod:`.planar` for a 2D scene)."""
    return planar.lift_params(params) if model.dim == 2 else params


def _inertial_fields(model: Model) -> tuple:
    return tuple(INERTIAL_NAMES[k] for k in PLANAR_INERTIAL) if model.dim == 2 else INERTIAL_NAMES


def _tree(model: Model, caller: str):
    if getattr(model, "joints", None) is None:
        raise ValueError(f"rb.joints.{caller}: the model has no joints (build a 3D scene with scene.add_joint; "
                         "a body without joint is then a free root)")
    return model.joints


def _check_friction(friction: str, caller: str) -> None:
    if friction not in FRICTION_LAWS:
        raise ValueError(f"rb.joints.{caller}: 'friction' must be one of {FRICTION_LAWS}, got {friction!r}")


def _friction_shape(params: Params, qvel, friction: str):
    """(nv,) s(q̇): sign(q̇) or q̇/√(q̇² + v²)."""
    if friction == "sign":
        return jnp.sign(qvel)
    scale = params.joint_friction_velocity
    return qvel / jnp.sqrt(qvel ** 2 + scale ** 2)


def _spring_joints(tree) -> list:
    return [j for j, kind in enumerate(tree.joint_kind) if kind in ("hinge", "slide")]


def _moving_bodies(tree) -> list:
    return [int(b) for b in np.flatnonzero(np.asarray(tree.body_dofs).any(axis=1))]


def dof_names(model: Model) -> tuple:
    """Names of the dofs in qvel order: a hinge's or slide's joint name; ``"joint.x"`` ... for balls and free joints.

    Args:
        model: a Model with joints.

    Returns:
        (nv,) tuple of str: a ball's three dofs are ``name.x``, ``name.y``,
        ``name.z`` (its body-frame angular velocity), a free joint's six
        ``name.x`` ... ``name.z`` then ``name.rx`` ... ``name.rz``.
    """
    tree = _tree(model, "dof_names")
    names = [""] * tree.nv
    for j, kind in enumerate(tree.joint_kind):
        start = tree.dof_adr[j]
        for k, suffix in enumerate(_DOF_SUFFIXES.get(kind, ("",))):
            names[start + k] = tree.joint_names[j] + (f".{suffix}" if suffix else "")
    return tuple(names)


def parameter_names(model: Model) -> tuple:
    """Names of the standard parameters, in the order of :func:`standard_parameters` and :func:`regressor`.

    Args:
        model: a Model with joints.

    Returns:
        (P,) tuple of str: ``m[body]``, ``mc_x[body]`` ... ``I_zz[body]`` per
        moving body (body order; in a 2D scene only ``m``, ``mc_x``, ``mc_y``,
        ``I_zz``), then ``armature[dof]`` per dof, ``damping[dof]`` per dof,
        ``friction[dof]`` per dof, ``stiffness[joint]`` per hinge or slide.
        P = 10 (4 in 2D) × (moving bodies) + 3 nv + (hinges and slides).
    """
    tree = _tree(model, "parameter_names")
    bodies = model.names if len(model.names) == len(tree.parent) else tuple(f"body{b}" for b in
                                                                             range(len(tree.parent)))
    names = [f"{field}[{bodies[b]}]" for b in _moving_bodies(tree) for field in _inertial_fields(model)]
    dofs = dof_names(model)
    for field in ("armature", "damping", "friction"):
        names += [f"{field}[{dof}]" for dof in dofs]
    names += [f"stiffness[{tree.joint_names[j]}]" for j in _spring_joints(tree)]
    return tuple(names)


def standard_parameters(model: Model, params: Params):
    """The standard parameter vector theta of ``params``, in :func:`parameter_names`' order.

    Per moving body b: m, m·c (c = ``com_offset``, body frame) and the
    entries xx, xy, xz, yy, yz, zz of the inertia about the body frame's
    origin in the body frame, I_com + m (|c|² 1 − c cᵀ); then per dof
    ``joint_armature``, ``joint_damping``, ``joint_frictionloss``; then
    ``joint_stiffness`` per hinge or slide. In a 2D scene a body has m,
    m c_x, m c_y and its moment about the frame origin I_z + m |c|². Works
    under ``jit`` and ``vmap``.

    Args:
        model: a Model with joints.
        params: its Params.

    Returns:
        (P,) theta, so that ``regressor(...)[0] @ theta == inverse_dynamics(...)``.
    """
    _tree(model, "standard_parameters")
    return _standard_program(model)(params)


@functools.lru_cache(maxsize=32)
def _standard_program(model: Model):
    """Jitted :func:`standard_parameters` of a Model (one program, not many small eager ones)."""
    return jax.jit(functools.partial(_standard, model))


def _standard(model: Model, params: Params):
    tree = model.joints
    bodies = np.asarray(_moving_bodies(tree), int)
    space = _space(model, params)
    mass, com, inertia = space.mass[bodies], space.com_offset[bodies], space.inertia[bodies]
    first = mass[:, None] * com
    shift = mass[:, None, None] * (jnp.sum(com * com, -1)[:, None, None] * jnp.eye(3, dtype=com.dtype)
                                   - com[:, :, None] * com[:, None, :])
    about_origin = inertia + shift
    entries = jnp.stack([about_origin[:, r, c] for r, c in _INERTIA_ENTRIES], axis=-1)
    inertial = jnp.concatenate([mass[:, None], first, entries], axis=-1)
    if model.dim == 2:
        inertial = inertial[:, np.asarray(PLANAR_INERTIAL)]
    inertial = inertial.reshape(-1)
    springs = np.asarray(_spring_joints(tree), int)
    return jnp.concatenate([inertial, params.joint_armature, params.joint_damping, params.joint_frictionloss,
                            params.joint_stiffness[springs] if len(springs) else jnp.zeros(0, inertial.dtype)])


def _loads(model: Model, params: Params, kin, qvel):
    """World force and torque (n, 3) the Params and the body damping apply (as the step adds them)."""
    force, torque = params.force, params.torque
    if model.damping:
        vel, angvel = body_velocities(kin, qvel)
        momentum = matvec3(world_inertia(kin, params), angvel)
        force = force - params.linear_damping[:, None] * params.mass[:, None] * vel
        torque = torque - params.angular_damping[:, None] * momentum
    return force, torque


def inverse_dynamics(model: Model, params: Params, qpos, qvel, qacc, *, friction: str = "smooth"):
    """The joint forces a motion needs: τ = M(q) q̈ + c(q, q̇) + D q̇ + μ s(q̇) + K (q − q_ref) − Jᵀ f_ext.

    The force, per dof, that actuators and constraints must supply for the
    joints to move with acceleration ``qacc`` at (``qpos``, ``qvel``): the
    mass matrix with armature (:func:`.dynamics.mass_matrix`), the Coriolis,
    centrifugal and gravity terms (:func:`.dynamics.bias_force`), viscous
    ``joint_damping``, Coulomb ``joint_frictionloss`` (every dof's, the law
    ``friction``), the hinge and slide springs, minus the generalized force
    of the Params' constant ``force``/``torque`` loads and of the bodies'
    linear and angular damping where the Model has them. Joint limits,
    loop closures and contacts are not modelled: their forces are part of
    the answer. For a motion the step produced, this equals the actuators'
    and applied loads' generalized force (to the integrator's treatment of
    the implicit terms: the Euler integrators take damping and the smooth
    friction's slope at the step's end velocity). Works under ``jit``,
    ``vmap`` and ``grad``.

    Args:
        model: a Model with joints.
        params: its Params.
        qpos: (nq,) joint coordinates.
        qvel: (nv,) joint velocities.
        qacc: (nv,) joint accelerations (a ball's or free joint's angular
            ones are the derivative of its qvel: body-frame angular velocity).
        friction: ``"smooth"`` (μ q̇/√(q̇² + v²), v = ``Params.joint_friction_velocity``,
            as the step's ``"smooth"`` joint friction) or ``"sign"`` (μ sign(q̇)).

    Returns:
        (nv,) τ, N m for rotational dofs and N for translational ones.
    """
    tree = _tree(model, "inverse_dynamics")
    _check_friction(friction, "inverse_dynamics")
    params = _space(model, params)
    kin = kinematics(tree, params, qpos)
    inertia = world_inertia(kin, params)
    tau = mass_matrix(params, kin, inertia) @ qacc + bias_force(tree, params, kin, inertia, qvel)
    tau = tau + params.joint_damping * qvel + params.joint_frictionloss * _friction_shape(params, qvel, friction)
    tau = tau - spring_force(tree, params, qpos)
    return tau - generalized(kin, *_loads(model, params, kin, qvel))


def _linear_model(model: Model, params: Params, qpos, qvel, qacc, friction: str):
    """``theta -> τ`` (P,) -> (nv,): the Newton–Euler equations about each body's origin, linear in theta
    (the 3D theta, 10 inertial parameters a body, in a 2D scene too).

    For body b with origin velocity v_o = J_o q̇, angular velocity ω = J_ω q̇,
    accelerations a_o = J_o q̈ + J̇_o q̇ − g and α = J_ω q̈ + J̇_ω q̇, first
    moment h = R (m c) and inertia about the origin I_o = R I Rᵀ:
    f = m a_o + α × h + ω × (ω × h), n_o = I_o α + ω × I_o ω + h × a_o, and
    τ = Σ_b J_oᵀ f + J_ωᵀ n_o, plus the joint terms.
    """
    tree = model.joints
    params = _space(model, params)
    bodies = np.asarray(_moving_bodies(tree), int)
    springs = np.asarray(_spring_joints(tree), int)
    at_origin = dataclasses.replace(params, com_offset=jnp.zeros_like(params.com_offset))
    kin = kinematics(tree, at_origin, qpos)  # com = frame origin: jac_lin is the origin's Jacobian
    linear_bias, angular_bias, _, angvel = bias_accelerations(tree, kin, qvel)
    jac_o, jac_w = kin.jac_lin[bodies], kin.jac_ang[bodies]
    acc = jnp.einsum("bdi,d->bi", jac_o, qacc) + linear_bias[bodies] - params.gravity
    alpha = jnp.einsum("bdi,d->bi", jac_w, qacc) + angular_bias[bodies]
    omega = angvel[bodies]
    rotation = quat_ops.to_rotation_matrix(kin.quat[bodies])
    nv, nb = tree.nv, len(bodies)
    rows = np.asarray([r for r, _ in _INERTIA_ENTRIES])
    cols = np.asarray([c for _, c in _INERTIA_ENTRIES])
    spring_dofs = np.asarray([tree.dof_adr[j] for j in springs], int)
    spring_q = qpos[np.asarray([tree.qpos_adr[j] for j in springs], int)] if len(springs) else None
    shape = _friction_shape(params, qvel, friction)

    def torque(theta):
        inertial = theta[:10 * nb].reshape(nb, 10)
        mass, first = inertial[:, 0], inertial[:, 1:4]
        local = jnp.zeros((nb, 3, 3), theta.dtype).at[:, rows, cols].set(inertial[:, 4:])
        local = local.at[:, cols, rows].set(inertial[:, 4:])
        inertia = rotation @ local @ jnp.swapaxes(rotation, -1, -2)
        h = matvec3(rotation, first)
        force = mass[:, None] * acc + cross(alpha, h) + cross(omega, cross(omega, h))
        moment = matvec3(inertia, alpha) + cross(omega, matvec3(inertia, omega)) + cross(h, acc)
        tau = jnp.einsum("bdi,bi->d", jac_o, force) + jnp.einsum("bdi,bi->d", jac_w, moment)
        armature, damping, mu = (theta[10 * nb + k * nv:10 * nb + (k + 1) * nv] for k in range(3))
        tau = tau + armature * qacc + damping * qvel + mu * shape
        if len(springs):
            stiffness = theta[10 * nb + 3 * nv:]
            rest = params.joint_springref[springs]
            tau = tau.at[spring_dofs].add(stiffness * (spring_q - rest))
        return tau

    return torque, 10 * nb + 3 * nv + len(springs)


def _check_linear(model: Model, params: Params) -> None:
    if model.damping:
        raise ValueError("rb.joints.regressor: the model compiles in the bodies' linear/angular damping, which "
                         "is not linear in the standard parameters; build without it (or model it as joint "
                         "damping)")
    for field in ("force", "torque"):
        value = getattr(params, field)
        if not isinstance(value, jax.core.Tracer) and np.any(np.asarray(value) != 0.0):
            raise ValueError(f"rb.joints.regressor: Params.{field} holds constant loads, whose generalized "
                             "force is not linear in the standard parameters; subtract it from the measured "
                             "torques (inverse_dynamics with zero inertia shows it) and zero the field")


#: Samples per call of the compiled batched regressor: any number of samples runs through one program.
_CHUNK = 256


@functools.lru_cache(maxsize=32)
def _regressor_programs(model: Model, friction: str):
    """Jitted ``(params, q, q̇, q̈) -> Y``: one sample (nv, P), and a chunk of :data:`_CHUNK` (C, nv, P)."""

    columns = None
    if model.dim == 2:  # planar motion: only m, m c_x, m c_y and I_zz act
        tree = model.joints
        nb = len(_moving_bodies(tree))
        inertial = [10 * b + k for b in range(nb) for k in PLANAR_INERTIAL]
        columns = np.asarray(inertial + list(range(10 * nb, 10 * nb + 3 * tree.nv + len(_spring_joints(tree)))))

    def one(params, qpos, qvel, qacc):
        torque, count = _linear_model(model, params, qpos, qvel, qacc, friction)
        dtype = jnp.result_type(qpos, qvel, qacc, params.mass)
        values = jax.jacfwd(torque)(jnp.zeros(count, dtype))
        return values if columns is None else values[:, columns]

    return jax.jit(one), jax.jit(jax.vmap(one, in_axes=(None, 0, 0, 0)))


def _chunked(program, params, qpos, qvel, qacc):
    """``program`` over the samples in chunks of :data:`_CHUNK` (the last padded with its first sample)."""
    count = qpos.shape[0]
    padded = -(-count // _CHUNK) * _CHUNK
    pad = lambda x: jnp.concatenate([x, jnp.broadcast_to(x[:1], (padded - count,) + x.shape[1:])])  # noqa: E731
    qpos, qvel, qacc = pad(qpos), pad(qvel), pad(qacc)
    parts = [program(params, qpos[k:k + _CHUNK], qvel[k:k + _CHUNK], qacc[k:k + _CHUNK])
             for k in range(0, padded, _CHUNK)]
    return jnp.concatenate(parts)[:count]


def regressor(model: Model, params: Params, qpos, qvel, qacc, *, friction: str = "sign"):
    """The identification regressor Y with ``inverse_dynamics(...) == Y @ standard_parameters(...)``.

    Y's columns are the joint forces per unit of each standard parameter
    (:func:`parameter_names`): exact (the derivative of a function linear in
    theta), independent of the Params' masses, inertias, centres of mass
    and joint laws, dependent on the kinematic Params (frames, anchors,
    axes), ``gravity``, ``joint_springref`` and, for the smooth law,
    ``joint_friction_velocity``. Leading batch axes of ``qpos``, ``qvel``
    and ``qacc`` (samples) are mapped over; ``Y`` alone works under ``jit``
    and ``vmap`` (the names are static).

    Args:
        model: a Model with joints (without body damping).
        params: its Params (no constant ``force``/``torque`` loads).
        qpos: (..., nq) joint coordinates.
        qvel: (..., nv) joint velocities.
        qacc: (..., nv) joint accelerations.
        friction: the Coulomb law of the friction columns, ``"sign"`` or ``"smooth"``
            (:data:`FRICTION_LAWS`).

    Returns:
        (Y (..., nv, P), names (P,) tuple of str).
    """
    tree = _tree(model, "regressor")
    _check_friction(friction, "regressor")
    _check_linear(model, params)
    qpos, qvel, qacc = jnp.asarray(qpos), jnp.asarray(qvel), jnp.asarray(qacc)
    batch = qpos.shape[:-1]
    one, chunk = _regressor_programs(model, friction)
    if batch:
        flat = [x.reshape((-1, x.shape[-1])) for x in (qpos, qvel, qacc)]
        leaves = jax.tree_util.tree_leaves((params, qpos, qvel, qacc))
        traced = any(isinstance(leaf, jax.core.Tracer) for leaf in leaves)
        if traced or not flat[0].shape[0]:
            values = jax.vmap(one, in_axes=(None, 0, 0, 0))(params, *flat)
        else:
            values = _chunked(chunk, params, *flat)
        values = values.reshape(batch + values.shape[1:])
    else:
        values = one(params, qpos, qvel, qacc)
    return values, parameter_names(model)


def _format_combination(lead: str, terms) -> str:
    text = lead
    for coefficient, name in terms:
        sign = "-" if coefficient < 0 else "+"
        magnitude = abs(coefficient)
        text += f" {sign} {name}" if abs(magnitude - 1.0) < 1e-9 else f" {sign} {magnitude:.4g} {name}"
    return text


def base_parameters(Y_stack, names: Sequence[str], tol: float = 1e-8):
    """The identifiable combinations theta_b = K theta of a stacked regressor, named.

    The columns are taken in the order given (the standard parameters'
    order: bodies from the root, then armature, damping, friction,
    stiffness): a column that is a linear combination of the columns kept
    before it (to ``tol``, relative, on unit-norm columns) is folded into
    them, else it is kept and leads a combination. This is QR factorisation
    without pivoting (the greedy choice keeps the earliest independent
    columns, as Khalil's and Gautier's regrouping does: a link's mass goes into
    its parent's inertia and first moment, a first joint's armature into
    its link's inertia); the coefficients are the least-squares solution
    Y_folded = Y_kept B, so Y θ = Y_kept (θ_kept + B θ_folded). Columns that
    are zero (parameters without effect, e.g. the mass of a body turning
    about its own origin) belong to no combination. Sample many states, so
    that dependencies of the data are not taken for the model's.

    Args:
        Y_stack: (M, P) regressor rows of many samples (e.g. ``Y.reshape(-1, P)``
            of :func:`regressor` over N states, M = N nv).
        names: (P,) the parameters' names (:func:`parameter_names`).
        tol: relative threshold on a column's part outside the span of the
            kept ones, and for coefficients small enough to drop.

    Returns:
        (K (B, P) numpy array, base_names (B,) tuple of str): row i of K
        holds 1 at its leading parameter and the folded parameters'
        coefficients; its name reads e.g. ``"I_yy[link1] + 0.09 m[link2] + armature[shoulder]"``.
    """
    K, base_names, _ = _combinations(Y_stack, names, tol)
    return K, base_names


def _combinations(Y_stack, names, tol):
    """:func:`base_parameters` and the index of each combination's leading column."""
    matrix = np.asarray(Y_stack, np.float64)
    names = tuple(names)
    if matrix.ndim != 2 or matrix.shape[1] != len(names):
        raise ValueError(f"base_parameters: 'Y_stack' must be (M, {len(names)}) (one column per name), "
                         f"got {matrix.shape}")
    if not np.all(np.isfinite(matrix)):
        raise ValueError("base_parameters: 'Y_stack' holds non-finite values")
    norms = np.linalg.norm(matrix, axis=0)
    scale = norms.max() if norms.size else 0.0
    active = norms > tol * scale if scale > 0 else np.zeros(len(names), bool)
    unit = matrix / np.where(active, norms, 1.0)
    # The columns' Gram matrix is RᵀR for the QR factor R (P, P): every dependency among Y's columns holds
    # among R's, so the greedy pass runs on R, however many rows Y has.
    small = np.linalg.qr(unit, mode="r") if unit.shape[0] > unit.shape[1] else unit
    kept, basis = [], np.zeros((small.shape[0], 0))
    for column in np.flatnonzero(active):
        residual = small[:, column].copy()
        for _ in range(2):  # Gram–Schmidt twice: orthogonal to rounding
            residual -= basis @ (basis.T @ residual)
        size = np.linalg.norm(residual)
        if size > tol:
            kept.append(column)
            basis = np.concatenate([basis, (residual / size)[:, None]], axis=1)
    kept = np.asarray(kept, int)
    folded = np.asarray([c for c in np.flatnonzero(active) if c not in set(kept.tolist())], int)
    K = np.zeros((len(kept), len(names)))
    K[np.arange(len(kept)), kept] = 1.0
    if len(folded):
        coefficients = np.linalg.lstsq(small[:, kept], small[:, folded], rcond=None)[0]
        coefficients[np.abs(coefficients) < tol ** 0.5 * 1e-2] = 0.0
        K[:, folded] = coefficients * norms[folded][None, :] / norms[kept][:, None]
    base_names = tuple(_format_combination(names[lead], [(K[i, c], names[c]) for c in folded if K[i, c] != 0.0])
                       for i, lead in enumerate(kept))
    return K, base_names, kept


@dataclasses.dataclass(frozen=True)
class BaseFit:
    """What :func:`fit_base_parameters` returns.

    Attributes:
        theta: (B,) the fitted base parameters, theta_b = K theta.
        names: (B,) their names (:func:`base_parameters`).
        K: (B, P) the map from the standard parameters (:func:`parameter_names`) to them; the
            columns of the ``known`` parameters are zero.
        standard_errors: (B,) their standard errors, from the weighted residuals with the rows taken
            as independent: after a low-pass ``filter`` rows closer than about 1/(2 f_c) are
            correlated, and these are too small by about the square root of the rows in that span.
        residual_rms: (nv,) root-mean-square torque residual per dof.
        parameter_names: (P,) the standard parameters' names.
        known: names of the parameters held at their Params values.
    """

    theta: np.ndarray
    names: tuple
    K: np.ndarray
    standard_errors: np.ndarray
    residual_rms: np.ndarray
    parameter_names: tuple
    known: tuple

    def true_values(self, model: Model, params: Params) -> np.ndarray:
        """The base parameters of ``params`` (to compare a fit of simulated data with its truth).

        Args:
            model: the Model the fit was made for.
            params: Params holding the true values.

        Returns:
            (B,) K theta of ``params``.
        """
        return self.K @ np.asarray(standard_parameters(model, params), np.float64)


def fit_base_parameters(model: Model, params: Params, qpos, qvel, qacc, tau, *, friction: str = "sign",
                        known: Sequence[str] = (), filter: Optional[Callable] = None, tol: float = 1e-8,
                        weighted: bool = True) -> BaseFit:
    """Least squares of the base parameters from measured joint coordinates, velocities, accelerations and forces.

    Stacks :func:`regressor` over the N samples, moves the ``known``
    parameters' columns (at their ``params`` values) to the torque side,
    finds the identifiable combinations (:func:`base_parameters`) and solves
    τ − Y_known θ_known = Y_kept θ_b. ``filter`` (Gautier's "parallel
    filtering") applies one linear map along the sample axis to the torques
    and to every regressor column alike, e.g. a zero-phase low-pass and
    decimation: since filter(Y θ) = filter(Y) θ for any linear filter, it
    removes the noise of differentiated accelerations and the mismatch of a
    friction step against smoothed accelerations without biasing the fit,
    so ``qacc`` may be a plain difference of lightly smoothed velocities.
    With ``weighted``, a second pass
    weighs each dof's rows by the inverse of its first-pass residual RMS
    (Gautier's weighted least squares: joints of different torque scales and
    noise count alike). The samples should be rich (many states, the joints
    at both low and high speeds in both directions), and the accelerations
    smoothed consistently with the velocities.

    Args:
        model: a Model with joints.
        params: Params with the kinematic values (frames, axes, gravity,
            ``joint_springref``, ``joint_friction_velocity``) and the
            ``known`` parameters' values.
        qpos: (N, nq) measured joint coordinates.
        qvel: (N, nv) joint velocities.
        qacc: (N, nv) joint accelerations.
        tau: (N, nv) measured joint forces (actuators' generalized forces).
        friction: the friction columns' law, ``"sign"`` or ``"smooth"``.
        known: standard parameter names (:func:`parameter_names`) taken as known,
            e.g. the stiffness of joints without springs.
        filter: ``x (N, ...) -> (N', ...)``, linear along axis 0 and the same for
            every column (e.g. ``lambda x: scipy.signal.filtfilt(b, a, x, axis=0)[::5]``),
            or None.
        tol: :func:`base_parameters`' threshold.
        weighted: reweight the dofs by their residuals (one extra solve).

    Returns:
        :class:`BaseFit`.
    """
    Y, names = regressor(model, params, qpos, qvel, qacc, friction=friction)
    Y = np.asarray(Y, np.float64)
    tau = np.asarray(tau, np.float64)
    nv = model.joints.nv
    if Y.ndim != 3 or tau.shape != Y.shape[:2]:
        raise ValueError(f"fit_base_parameters: 'tau' must be (N, {nv}) like 'qvel', got {tau.shape}")
    unknown = [name for name in known if name not in names]
    if unknown:
        raise ValueError(f"fit_base_parameters: 'known' names no standard parameter: {unknown}")
    if filter is not None:
        Y, tau = np.asarray(filter(Y), np.float64), np.asarray(filter(tau), np.float64)
        if Y.shape[1:] != (nv, len(names)) or tau.shape != Y.shape[:2]:
            raise ValueError(f"fit_base_parameters: 'filter' must map (N, ...) arrays to (N', ...) along axis 0 "
                             f"alike, got regressor {Y.shape} and torques {tau.shape}")
    known_set = set(known)
    is_known = np.asarray([name in known_set for name in names], bool)
    theta = np.asarray(standard_parameters(model, params), np.float64)
    target = tau - Y[:, :, is_known] @ theta[is_known]
    free = np.flatnonzero(~is_known)
    K_free, base_names, kept = _combinations(Y[:, :, free].reshape(-1, len(free)), [names[c] for c in free], tol)
    design = Y[:, :, free[kept]]

    def solve(weights):
        rows = (design * weights[None, :, None]).reshape(-1, len(kept))
        solution = np.linalg.lstsq(rows, (target * weights[None, :]).reshape(-1), rcond=None)[0]
        return solution, rows, target - design @ solution

    weights = np.ones(nv)
    solution, rows, residual = solve(weights)
    if weighted:
        rms = np.sqrt(np.mean(residual ** 2, axis=0))
        weights = 1.0 / np.maximum(rms, 1e-12 * max(float(rms.max()), 1e-300))
        solution, rows, residual = solve(weights)
    whitened = (residual * weights[None, :]).reshape(-1)
    variance = float(whitened @ whitened) / max(rows.shape[0] - rows.shape[1], 1)
    covariance = variance * np.linalg.pinv(rows.T @ rows)
    K = np.zeros((len(kept), len(names)))
    K[:, free] = K_free
    return BaseFit(theta=solution, names=base_names, K=K, standard_errors=np.sqrt(np.maximum(np.diag(covariance), 0)),
                   residual_rms=np.sqrt(np.mean(residual ** 2, axis=0)), parameter_names=names, known=tuple(known))
