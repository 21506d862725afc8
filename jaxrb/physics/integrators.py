"""Time integrators for free rigid bodies (one substep of length h).

All five advance position, orientation, linear velocity and angular
momentum; they differ in which values feed which update:

* ``euler``: explicit Euler on (x, q, v, L); every update uses old values.
* ``semi_implicit``: symplectic Euler. v and L are updated first (L += h·τ,
  the lecture's scheme), then x and q move with the new velocities. World
  angular momentum is integrated directly, so it is conserved exactly when no
  torque acts.
* ``implicit_gyro``: semi-implicit, but the gyroscopic term ω × Iω is taken
  implicitly in the body frame (backward Euler, solved by Newton). Stable at
  high spin; the exact backward-Euler solution never gains kinetic energy.
* ``rk4``: classic 4th-order Runge–Kutta on (x, q, v, L), quaternion
  renormalised at the end of the step.
* ``rk4_body``: classic RK4 on (x, q, v, M) with M = Rᵀ L the *body-frame*
  angular momentum, Ṁ = M × I⁻¹M + Rᵀτ (Euler's equations). Torque-free, Ṁ
  does not depend on q, so the body-frame motion (the tumbling that decides
  when a body flips) is integrated at the slow rate of Euler's equations, not
  at the spin rate the quaternion turns at; that is why its flip times are
  orders of magnitude closer than ``rk4``'s at the same h (MuJoCo integrates
  body-frame ω the same way). The price: |L| is conserved but the direction
  of world L drifts with the quaternion's error, where ``rk4`` keeps world L
  exact.

Damping, when compiled in, is dv/dt = −c v and dL/dt = −c L; the semi-implicit
schemes take it implicitly (divide by 1 + h c) so it can never overshoot.

In 2D the angle is advanced by h·ω and the angular momentum iω is a scalar;
there is no gyroscopic term, so ``implicit_gyro`` equals ``semi_implicit``
and ``rk4_body`` equals ``rk4``.
After each step the stored world ω is recomputed from L with the new
orientation, so state.angvel is always consistent with state.quat.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxrb.math import quaternion as quat_ops
from jaxrb.physics.dynamics import inverse_inertia
from jaxrb.math.vector import cross, inverse3, matvec3
from jaxrb.model.types import Model, Params, State

GYRO_NEWTON_ITERATIONS = 2


def angvel_from_momentum(quat, momentum, params, inv_inertia, angvel_body):
    """World ω = R I⁻¹ Rᵀ L, computed as an update of a nearby body-frame ω.

    ω_b' = ω_b + I⁻¹ (Rᵀ L − I ω_b). In exact arithmetic this is I⁻¹ Rᵀ L; in
    floating point the inverse only multiplies the small change, so the fixed
    rounding error of I⁻¹·I ≠ Id (about 1e-7 in float32) does not compound
    step after step (it drifted |L| by 1e-3 over 4800 float32 steps before).

    Args:
        quat: (n, 4) orientation to evaluate at.
        momentum: (n, 3) world angular momentum L.
        params: Params (for the body-frame inertia).
        inv_inertia: (n, 3, 3) body-frame inverse inertia.
        angvel_body: (n, 3) body-frame ω near the answer (e.g. the step's start).

    Returns:
        ((n, 3) world ω, (n, 3) body-frame ω).
    """
    change = quat_ops.rotate_inverse(quat, momentum) - matvec3(params.inertia, angvel_body)
    angvel_body = angvel_body + matvec3(inv_inertia, change)
    return quat_ops.rotate(quat, angvel_body), angvel_body


def body_angvel_and_momentum(params: Params, state: State):
    """Body-frame ω and world angular momentum L = R I ω_b of a 3D state.

    Args:
        params: Params (body-frame ``inertia`` (n, 3, 3)).
        state: 3D State (``quat``, ``angvel``).

    Returns:
        ((n, 3) body-frame ω, (n, 3) world angular momentum L).
    """
    angvel_body = quat_ops.rotate_inverse(state.quat, state.angvel)
    return angvel_body, quat_ops.rotate(state.quat, matvec3(params.inertia, angvel_body))


def body_frame_momentum(params: Params, quat, angvel):
    """Body-frame angular momentum M = I Rᵀ ω.

    Args:
        params: Params (body-frame ``inertia`` (n, 3, 3)).
        quat: (n, 4) orientations.
        angvel: (n, 3) world-frame ω.

    Returns:
        (n, 3) M.
    """
    return matvec3(params.inertia, quat_ops.rotate_inverse(quat, angvel))


def _linear_accel(params, force):
    return force / params.mass[:, None]


def _damp(model, value, rate, h):
    """Implicit damping factor 1/(1 + h c) applied to value ((n, k) or (n,))."""
    if not model.damping:
        return value
    factor = 1.0 / (1.0 + h * rate)
    return value * (factor[:, None] if value.ndim == 2 else factor)


def euler(model: Model, params: Params, state: State, force, torque, h) -> State:
    """Explicit Euler substep: every update uses the values at the start of the substep.

    Args:
        model: the scene's Model (dimension, orientation update, damping).
        params: Params (mass, inertia, damping rates).
        state: State at the start of the substep.
        force: (n, dim) world-frame force on each centre of mass, held constant.
        torque: (n, 3) world-frame torque in 3D, (n,) in 2D, held constant.
        h: () substep length (s).

    Returns:
        State after the substep (``time`` is left to the caller).
    """
    accel = _linear_accel(params, force)
    if model.damping:
        accel = accel - params.linear_damping[:, None] * state.vel
    pos, vel = state.pos + h * state.vel, state.vel + h * accel
    if model.dim == 2:
        alpha = torque / params.inertia
        if model.damping:
            alpha = alpha - params.angular_damping * state.angvel
        return state.replace(pos=pos, vel=vel, angle=state.angle + h * state.angvel,
                             angvel=state.angvel + h * alpha)
    angvel_body, momentum = body_angvel_and_momentum(params, state)
    torque_total = torque - params.angular_damping[:, None] * momentum if model.damping else torque
    quat = quat_ops.ORIENTATION_UPDATES[model.orientation](state.quat, state.angvel, h)
    angvel, _ = angvel_from_momentum(quat, momentum + h * torque_total, params,
                                     inverse_inertia(params, 3), angvel_body)
    return state.replace(pos=pos, vel=vel, quat=quat, angvel=angvel)


def semi_implicit_velocity(model: Model, params: Params, state: State, force, torque, h) -> State:
    """Velocity phase of symplectic Euler: v += h a, L += h τ at the current orientation.

    state.angvel becomes I_w⁻¹ L at the *current* orientation; the position
    phase moves the orientation and re-expresses ω for the new one. The
    contact solver runs between the two phases.

    Args:
        model: the scene's Model (dimension, damping).
        params: Params (mass, inertia, damping rates).
        state: State at the start of the substep.
        force: (n, dim) world-frame force on each centre of mass, held constant.
        torque: (n, 3) world-frame torque in 3D, (n,) in 2D, held constant.
        h: () substep length (s).

    Returns:
        State with ``vel`` and ``angvel`` updated; positions and orientation unchanged.
    """
    vel = _damp(model, state.vel + h * _linear_accel(params, force), params.linear_damping, h)
    if model.dim == 2:
        angvel = state.angvel + h * torque / params.inertia
    else:
        # I_w⁻¹(L + hτ) = ω + h I_w⁻¹ τ: no round trip through L needed.
        angvel = state.angvel + h * quat_ops.rotate(
            state.quat, matvec3(inverse_inertia(params, 3), quat_ops.rotate_inverse(state.quat, torque)))
    return state.replace(vel=vel, angvel=_damp(model, angvel, params.angular_damping, h))


def semi_implicit_position(model: Model, params: Params, state: State, h) -> State:
    """Position phase of symplectic Euler: move x and q with the new velocities, keep world L.

    Args:
        model: the scene's Model (dimension, orientation update).
        params: Params (inertia).
        state: State after the velocity phase.
        h: () substep length (s).

    Returns:
        State with ``pos`` and the orientation advanced (``time`` is left to the caller).
    """
    pos = state.pos + h * state.vel
    if model.dim == 2:
        return state.replace(pos=pos, angle=state.angle + h * state.angvel)
    angvel_body, momentum = body_angvel_and_momentum(params, state)
    quat = quat_ops.ORIENTATION_UPDATES[model.orientation](state.quat, state.angvel, h)
    angvel, _ = angvel_from_momentum(quat, momentum, params, inverse_inertia(params, 3), angvel_body)
    return state.replace(pos=pos, quat=quat, angvel=angvel)


def semi_implicit(model: Model, params: Params, state: State, force, torque, h) -> State:
    """Symplectic Euler substep that integrates world angular momentum.

    Args:
        model: the scene's Model (dimension, orientation update, damping).
        params: Params (mass, inertia, damping rates).
        state: State at the start of the substep.
        force: (n, dim) world-frame force on each centre of mass, held constant.
        torque: (n, 3) world-frame torque in 3D, (n,) in 2D, held constant.
        h: () substep length (s).

    Returns:
        State after the substep (``time`` is left to the caller).
    """
    state = semi_implicit_velocity(model, params, state, force, torque, h)
    return semi_implicit_position(model, params, state, h)


def _skew_times(vector, matrix):
    """[v]x M, column by column. vector: (n, 3), matrix: (n, 3, 3)."""
    columns = [cross(vector, matrix[..., :, j]) for j in range(3)]
    return jnp.stack(columns, axis=-1)


def solve_gyroscopic(inertia, angvel_body, h, iterations=GYRO_NEWTON_ITERATIONS):
    """Backward-Euler step of Euler's equations I ω̇ + ω × Iω = 0 in the body frame.

    Solves f(ω) = I(ω − ω0) + h ω × Iω = 0 with Newton's method from ω0; the
    Jacobian is I + h([ω]x I − [Iω]x).

    Args:
        inertia: (n, 3, 3) body-frame inertia.
        angvel_body: (n, 3) body-frame ω0.
        h: () step length (s).
        iterations: Newton iterations (unrolled; two reach round-off for the
            spin rates a step can resolve).

    Returns:
        (n, 3) body-frame ω after the step.
    """
    angvel = angvel_body
    for _ in range(iterations):
        momentum = matvec3(inertia, angvel)
        residual = matvec3(inertia, angvel - angvel_body) + h * cross(angvel, momentum)
        lx, ly, lz = momentum[..., 0], momentum[..., 1], momentum[..., 2]
        zero = jnp.zeros_like(lx)
        skew_momentum = jnp.stack([jnp.stack([zero, -lz, ly], -1),
                                   jnp.stack([lz, zero, -lx], -1),
                                   jnp.stack([-ly, lx, zero], -1)], -2)
        jacobian = inertia + h * (_skew_times(angvel, inertia) - skew_momentum)
        angvel = angvel - matvec3(inverse3(jacobian), residual)
    return angvel


def implicit_gyro_velocity(model: Model, params: Params, state: State, force, torque, h) -> State:
    """Velocity phase with the gyroscopic term implicit: ω_b solves I(ω_b − ω_b0) + h ω_b × Iω_b = hτ_b.

    In 2D there is no gyroscopic term and this is :func:`semi_implicit_velocity`.

    Args:
        model: the scene's Model (dimension, damping).
        params: Params (mass, inertia, damping rates).
        state: State at the start of the substep.
        force: (n, dim) world-frame force on each centre of mass, held constant.
        torque: (n, 3) world-frame torque in 3D, (n,) in 2D, held constant.
        h: () substep length (s).

    Returns:
        State with ``vel`` and ``angvel`` updated; positions and orientation unchanged.
    """
    if model.dim == 2:
        return semi_implicit_velocity(model, params, state, force, torque, h)
    vel = _damp(model, state.vel + h * _linear_accel(params, force), params.linear_damping, h)
    angvel_body = quat_ops.rotate_inverse(state.quat, state.angvel)
    angvel_body = angvel_body + h * matvec3(inverse_inertia(params, 3),
                                            quat_ops.rotate_inverse(state.quat, torque))
    angvel_body = _damp(model, angvel_body, params.angular_damping, h)
    angvel_body = solve_gyroscopic(params.inertia, angvel_body, h)
    return state.replace(vel=vel, angvel=quat_ops.rotate(state.quat, angvel_body))


def implicit_gyro_position(model: Model, params: Params, state: State, h) -> State:
    """Position phase that carries the body-frame ω (the implicit solve's unknown) along.

    Args:
        model: the scene's Model (dimension, orientation update).
        params: Params (inertia).
        state: State after the velocity phase.
        h: () substep length (s).

    Returns:
        State with ``pos`` and the orientation advanced (``time`` is left to the caller).
    """
    pos = state.pos + h * state.vel
    if model.dim == 2:
        return state.replace(pos=pos, angle=state.angle + h * state.angvel)
    angvel_body = quat_ops.rotate_inverse(state.quat, state.angvel)
    quat = quat_ops.ORIENTATION_UPDATES[model.orientation](state.quat, state.angvel, h)
    return state.replace(pos=pos, quat=quat, angvel=quat_ops.rotate(quat, angvel_body))


def implicit_gyro(model: Model, params: Params, state: State, force, torque, h) -> State:
    """Semi-implicit substep with the gyroscopic term implicit in the body frame.

    Args:
        model: the scene's Model (dimension, orientation update, damping).
        params: Params (mass, inertia, damping rates).
        state: State at the start of the substep.
        force: (n, dim) world-frame force on each centre of mass, held constant.
        torque: (n, 3) world-frame torque in 3D, (n,) in 2D, held constant.
        h: () substep length (s).

    Returns:
        State after the substep (``time`` is left to the caller).
    """
    state = implicit_gyro_velocity(model, params, state, force, torque, h)
    return implicit_gyro_position(model, params, state, h)


def rk4(model: Model, params: Params, state: State, force, torque, h) -> State:
    """Classic RK4 substep on (x, orientation, v, L) with the wrench held constant.

    Args:
        model: the scene's Model (dimension, orientation update, damping).
        params: Params (mass, inertia, damping rates).
        state: State at the start of the substep.
        force: (n, dim) world-frame force on each centre of mass, held constant.
        torque: (n, 3) world-frame torque in 3D, (n,) in 2D, held constant.
        h: () substep length (s).

    Returns:
        State after the substep (``time`` is left to the caller).
    """
    accel = _linear_accel(params, force)

    if model.dim == 2:
        def derivative(y):
            pos, angle, vel, angvel = y
            dvel, dangvel = accel, torque / params.inertia
            if model.damping:
                dvel = dvel - params.linear_damping[:, None] * vel
                dangvel = dangvel - params.angular_damping * angvel
            return vel, angvel, dvel, dangvel

        y = (state.pos, state.angle, state.vel, state.angvel)
        pos, angle, vel, angvel = _rk4_combine(derivative, y, h)
        return state.replace(pos=pos, angle=angle, vel=vel, angvel=angvel)

    inv_inertia = inverse_inertia(params, 3)
    angvel_body, momentum = body_angvel_and_momentum(params, state)

    def derivative(y):
        pos, quat, vel, momentum = y
        angvel, _ = angvel_from_momentum(quat_ops.normalize(quat), momentum, params, inv_inertia,
                                         angvel_body)
        omega = jnp.concatenate([jnp.zeros_like(angvel[..., :1]), angvel], axis=-1)
        dvel, dmomentum = accel, torque
        if model.damping:
            dvel = dvel - params.linear_damping[:, None] * vel
            dmomentum = dmomentum - params.angular_damping[:, None] * momentum
        return vel, 0.5 * quat_ops.multiply(omega, quat), dvel, dmomentum

    pos, quat, vel, momentum = _rk4_combine(derivative, (state.pos, state.quat, state.vel, momentum), h)
    quat = quat_ops.normalize(quat)
    angvel, _ = angvel_from_momentum(quat, momentum, params, inv_inertia, angvel_body)
    return state.replace(pos=pos, quat=quat, vel=vel, angvel=angvel)


def rk4_body(model: Model, params: Params, state: State, force, torque, h) -> State:
    """Classic RK4 substep on (x, q, v, M), M the body-frame angular momentum.

    The wrench is held constant in the world frame (Rᵀτ follows q within the
    step). M is carried in two parts, ``state.body_momentum`` (high) and
    ``state.momentum_residual`` (low), and summed with Fast2Sum (compensated
    summation): in float32 the rounding of adding each step's small update to
    M, and of storing M as world ω, otherwise piles up into flip-time errors of
    0.1–0.4 s over 20 s of tumbling (measured). The step reads M from the
    state rather than back from ω: a read-back I Rᵀ ω rounds differently
    wherever XLA contracts its products into fused multiply-adds differently,
    and an ulp per step lost that way cost 0.03–0.2 s of flip time
    (docs/design.md, 'XLA and LLVM options'). The stored M is used only while ω still
    agrees with it to :data:`MOMENTUM_AGREEMENT` ulps, so a user who replaces
    ``angvel`` gets the M of the new ω; derivatives always flow through the
    read-back, which equals M in exact arithmetic. In 2D this is :func:`rk4`.

    Args:
        model: the scene's Model (dimension, damping).
        params: Params (mass, inertia, damping rates).
        state: State at the start of the substep; ``state.body_momentum`` and
            ``state.momentum_residual`` (n, 3) carry M between substeps.
        force: (n, dim) world-frame force on each centre of mass, held constant.
        torque: (n, 3) world-frame torque in 3D, (n,) in 2D, held constant.
        h: () substep length (s).

    Returns:
        State after the substep with its new ``body_momentum`` and
        ``momentum_residual`` (``time`` is left to the caller).
    """
    if model.dim == 2:
        return rk4(model, params, state, force, torque, h)
    accel = _linear_accel(params, force)
    inv_inertia = inverse_inertia(params, 3)

    def body_angvel(momentum):
        return matvec3(inv_inertia, momentum)

    momentum0, residual = carried_momentum(state, body_frame_momentum(params, state.quat, state.angvel))

    def derivative(y):
        pos, quat, vel, momentum = y
        angvel_body = body_angvel(momentum)
        omega = jnp.concatenate([jnp.zeros_like(angvel_body[..., :1]), angvel_body], axis=-1)
        dvel = accel
        dmomentum = cross(momentum, angvel_body) + quat_ops.rotate_inverse(quat_ops.normalize(quat), torque)
        if model.damping:
            dvel = dvel - params.linear_damping[:, None] * vel
            dmomentum = dmomentum - params.angular_damping[:, None] * momentum
        return vel, 0.5 * quat_ops.multiply(quat, omega), dvel, dmomentum

    y0 = (state.pos, state.quat, state.vel, momentum0)
    pos, quat, vel, momentum_change = _rk4_combine(derivative, y0, h, increments=True)
    pos, quat, vel = state.pos + pos, quat_ops.normalize(state.quat + quat), state.vel + vel
    # Fast2Sum (exact as |update| ≤ |momentum0|, a step's change being small):
    # momentum + low is momentum0 + residual + change to twice the precision.
    update = momentum_change + residual
    momentum = momentum0 + update
    low = update - (momentum - momentum0)
    angvel = quat_ops.rotate(quat, body_angvel(momentum))
    return state.replace(pos=pos, quat=quat, vel=vel, angvel=angvel, body_momentum=momentum,
                         momentum_residual=low)


#: ulps of |M| by which ω's read-back may differ from the carried body-frame
#: momentum and still be taken for the same M (a round trip through R and I⁻¹
#: rounds by a few ulps times I's condition number).
MOMENTUM_AGREEMENT = 256


def carried_momentum(state: State, readback):
    """Body-frame momentum (high, low) to start an ``rk4_body`` substep from.

    Args:
        state: 3D State with ``body_momentum`` and ``momentum_residual`` (n, 3).
        readback: (n, 3) I Rᵀ ω of the state's ω.

    Returns:
        ((n, 3) high part, (n, 3) low part): the carried pair where ω agrees
        with it (see :data:`MOMENTUM_AGREEMENT`), else ``readback`` and 0.
        The high part has the carried value but the read-back's derivatives
        (the two are equal in exact arithmetic).
    """
    difference = state.body_momentum - readback
    tolerance = MOMENTUM_AGREEMENT * jnp.finfo(readback.dtype).eps * jnp.max(jnp.abs(readback), axis=-1)
    agrees = (jnp.max(jnp.abs(difference), axis=-1) <= tolerance)[:, None]
    high = readback + jax.lax.stop_gradient(jnp.where(agrees, difference, 0.0))
    return high, jnp.where(agrees, state.momentum_residual, 0.0)


def _rk4_combine(derivative, y, h, increments=False):
    """One classic RK4 step of y' = derivative(y) (pytrees); the change of y if ``increments``."""
    def shifted(k, scale):
        return jax.tree_util.tree_map(lambda a, b: a + scale * b, y, k)

    k1 = derivative(y)
    k2 = derivative(shifted(k1, 0.5 * h))
    k3 = derivative(shifted(k2, 0.5 * h))
    k4 = derivative(shifted(k3, h))
    change = jax.tree_util.tree_map(lambda b1, b2, b3, b4: (h / 6.0) * (b1 + 2.0 * b2 + 2.0 * b3 + b4),
                                    k1, k2, k3, k4)
    if increments:
        return change
    return jax.tree_util.tree_map(lambda a, b: a + b, y, change)


INTEGRATORS = {"euler": euler, "semi_implicit": semi_implicit,
               "implicit_gyro": implicit_gyro, "rk4": rk4, "rk4_body": rk4_body}

# Integrators that split into a velocity and a position phase, so contact can
# act on the velocities in between.
PHASES = {"semi_implicit": (semi_implicit_velocity, semi_implicit_position),
          "implicit_gyro": (implicit_gyro_velocity, implicit_gyro_position)}
