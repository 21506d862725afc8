"""Kinematics of joint trees: poses from ``qpos``, Jacobians, velocities and their bias accelerations.

Forward kinematics composes each body's frame from its parent's, its
``parent_offset``/``parent_rotation`` and its joints in order, as MuJoCo's
``mj_kinematics`` does: a hinge turns the frame by q − ref about its axis
through its anchor, a slide shifts it by (q − ref) along its axis, a ball
turns it by its quaternion about its anchor, a free joint sets it.

Everything after the poses is written for all bodies and dofs at once, with
the tree's static masks (:class:`jaxrb.model.joints.JointTree`), so no stage
but the poses walks the tree: dof d moves body b where ``body_dofs[b, d]``,
with the velocity a_d × (c_b − p_d) at b's centre of mass for a rotational
dof (axis a_d through anchor p_d) or a_d for a translational one.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.math import quaternion as quat_ops
from jaxrb.math.vector import cross, safe_normalize
from jaxrb.model.struct import pytree_dataclass
from jaxrb.model.types import Array, Params


@pytree_dataclass
class Kinematics:
    """Where every body and dof of a tree is, for one ``qpos``.

    Attributes:
        origin: (n, 3) body frame origins, world.
        quat: (n, 4) body frame orientations (w, x, y, z).
        com: (n, 3) centres of mass, world.
        axis: (nv, 3) each dof's unit axis, world (a free body's first three: x, y, z).
        anchor: (nv, 3) the point each rotational dof turns about, world.
        jac_lin: (n, nv, 3) velocity of each body's centre of mass per unit qvel of each dof.
        jac_ang: (n, nv, 3) angular velocity of each body per unit qvel of each dof.
    """

    origin: Array
    quat: Array
    com: Array
    axis: Array
    anchor: Array
    jac_lin: Array
    jac_ang: Array


#: Codes of the joint kinds in the forward kinematics' slots (0: an empty slot).
KIND_CODES = {"hinge": 1, "slide": 2, "ball": 3, "free": 4}


def _forward_tables(tree):
    """Static tables of :func:`poses`, in the order the bodies are visited (parents first).

    Returns:
        A dict of NumPy arrays: ``body`` (n,), ``parent`` (n,) (n for the
        world: the carry's identity row), per slot (n, K) ``kind``, ``qpos``
        (first qpos index) and ``joint``; per dof (nv,) ``slot`` (index into
        the visited slots, flattened) and ``column`` (0: the slot's hinge or
        slide axis, 1-3: a column of its rotation, 4-6: a world axis).
    """
    n, order = len(tree.parent), list(tree.order)
    slots = max([1] + [len(joints) for joints in tree.body_joints])
    kind, qpos, joint = (np.zeros((n, slots), int) for _ in range(3))
    slot, column = np.zeros(tree.nv, int), np.zeros(tree.nv, int)
    for visit, body in enumerate(order):
        for k, j in enumerate(tree.body_joints[body]):
            name, d = tree.joint_kind[j], tree.dof_adr[j]
            kind[visit, k], qpos[visit, k], joint[visit, k] = KIND_CODES[name], tree.qpos_adr[j], j
            flat = visit * slots + k
            if name in ("hinge", "slide"):
                slot[d], column[d] = flat, 0
            elif name == "ball":
                slot[d:d + 3], column[d:d + 3] = flat, (1, 2, 3)
            else:
                slot[d:d + 6], column[d:d + 6] = flat, (4, 5, 6, 1, 2, 3)
    parent = np.asarray([tree.parent[b] if tree.parent[b] >= 0 else n for b in order])
    return dict(body=np.asarray(order), parent=parent, kind=kind, qpos=qpos, joint=joint, slot=slot,
                column=column)


def poses(tree, params: Params, qpos):
    """Body frames and dof axes and anchors of ``qpos``.

    One ``lax.scan`` over the bodies, parents first, carrying every body's
    frame: each visit reads its parent's frame and applies its joints' slots
    (every kind computed, the slot's own selected), so the program and its
    compile time do not grow with the tree (unrolled, the chain of poses
    compiled in 3 s for 10 bodies, 33 s where the Params were constants).

    Args:
        tree: the Model's :class:`~jaxrb.model.joints.JointTree`.
        params: Params (``parent_offset``, ``parent_rotation``, ``joint_pos``,
            ``joint_axis``, ``joint_ref``).
        qpos: (nq,) joint coordinates.

    Returns:
        (origin (n, 3), quat (n, 4), axis (nv, 3), anchor (nv, 3)).
    """
    tables = _forward_tables(tree)
    dtype = qpos.dtype
    n = len(tree.parent)
    padded_qpos = jnp.concatenate([qpos, jnp.zeros(7, dtype)])
    local_axis = safe_normalize(params.joint_axis) if tree.num_joints else jnp.zeros((1, 3), dtype)
    joint_pos = params.joint_pos if tree.num_joints else jnp.zeros((1, 3), dtype)
    joint_ref = params.joint_ref if tree.num_joints else jnp.zeros((1,), dtype)
    identity = jnp.asarray([1.0, 0.0, 0.0, 0.0], dtype)
    present = set(tree.joint_kind)

    def visit(carry, row):
        origins, quats = carry
        body, parent, kinds, addresses, joints = row
        x = origins[parent] + quat_ops.rotate(quats[parent], params.parent_offset[body])
        q = quat_ops.multiply(quats[parent], params.parent_rotation[body])
        records = []
        for kind, address, j in zip(kinds, addresses, joints):
            coordinates = jax.lax.dynamic_slice_in_dim(padded_qpos, address, 7)
            anchor = x + quat_ops.rotate(q, joint_pos[j])
            axis = quat_ops.rotate(q, local_axis[j])
            displacement = coordinates[0] - joint_ref[j]
            # Only the kinds the tree has are computed (a chain of hinges turns no quaternion from qpos).
            turns = {"hinge": lambda: quat_ops.multiply(q, quat_ops.from_axis_angle(local_axis[j], displacement)),
                     "ball": lambda: quat_ops.multiply(q, quat_ops.normalize(coordinates[:4])),
                     "free": lambda: quat_ops.normalize(coordinates[3:7])}
            chosen = [(kind == KIND_CODES[name], turn()) for name, turn in turns.items() if name in present]
            new_q = jnp.select(*zip(*chosen), q) if chosen else q
            moves = [((kind == 1) | (kind == 3), lambda: anchor - quat_ops.rotate(new_q, joint_pos[j]),
                      present & {"hinge", "ball"}),
                     (kind == 2, lambda: x + axis * displacement, present & {"slide"}),
                     (kind == 4, lambda: coordinates[:3], present & {"free"})]
            chosen = [(condition, move()) for condition, move, wanted in moves if wanted]
            new_x = jnp.select(*zip(*chosen), x) if chosen else x
            # A ball's qvel is the angular velocity in the frame it turns; a free body's about its origin.
            rotation = quat_ops.to_rotation_matrix(new_q) if present & {"ball", "free"} else jnp.zeros((3, 3), dtype)
            records.append((axis, jnp.where(kind == 4, new_x, anchor), rotation))
            x, q = new_x, new_q
        origins = jax.lax.dynamic_update_index_in_dim(origins, x, body, 0)
        quats = jax.lax.dynamic_update_index_in_dim(quats, q, body, 0)
        return (origins, quats), jax.tree_util.tree_map(lambda *parts: jnp.stack(parts), *records)

    start = (jnp.zeros((n + 1, 3), dtype), jnp.zeros((n + 1, 4), dtype).at[n].set(identity))
    rows = tuple(jnp.asarray(tables[key]) for key in ("body", "parent", "kind", "qpos", "joint"))
    (origins, quats), (axes, anchors, rotations) = jax.lax.scan(visit, start, rows)
    if not tree.nv:
        return origins[:n], quats[:n], jnp.zeros((0, 3), dtype), jnp.zeros((0, 3), dtype)
    flat = lambda array: array.reshape((-1,) + array.shape[2:])
    columns = jnp.concatenate([flat(axes)[:, None, :], jnp.swapaxes(flat(rotations), -1, -2),
                               jnp.broadcast_to(jnp.eye(3, dtype=dtype), (flat(axes).shape[0], 3, 3))], axis=1)
    axis = columns[tables["slot"], tables["column"]]
    return origins[:n], quats[:n], axis, flat(anchors)[tables["slot"]]


def kinematics(tree, params: Params, qpos) -> Kinematics:
    """Poses and Jacobians of every body for ``qpos``.

    Args:
        tree: the Model's JointTree.
        params: Params (the joints' fields and ``com_offset``).
        qpos: (nq,) joint coordinates.

    Returns:
        The :class:`Kinematics`.
    """
    origin, quat, axis, anchor = poses(tree, params, qpos)
    com = origin + quat_ops.rotate(quat, params.com_offset)
    rotational = jnp.asarray(tree.dof_rotational)[None, :, None]
    moves = jnp.asarray(tree.body_dofs, qpos.dtype)[..., None]
    lever = com[:, None, :] - anchor[None, :, :]
    axis_b = jnp.broadcast_to(axis[None], lever.shape)
    jac_lin = moves * jnp.where(rotational, cross(axis_b, lever), axis_b)
    jac_ang = moves * jnp.where(rotational, axis_b, 0.0)
    return Kinematics(origin=origin, quat=quat, com=com, axis=axis, anchor=anchor,
                      jac_lin=jac_lin, jac_ang=jac_ang)


def body_velocities(kin: Kinematics, qvel):
    """Centre-of-mass and angular velocities of every body, world frame.

    Args:
        kin: the Kinematics of the current qpos.
        qvel: (nv,) joint velocities.

    Returns:
        (vel (n, 3), angvel (n, 3)).
    """
    return (jnp.einsum("bdi,d->bi", kin.jac_lin, qvel), jnp.einsum("bdi,d->bi", kin.jac_ang, qvel))


def point_jacobian(kin: Kinematics, body, point):
    """Velocity of a point fixed in ``body`` per unit qvel: J_lin + J_ang × (p − c).

    Args:
        kin: Kinematics.
        body: (k,) body indices (static or traced), or -1 for the world (a zero row).
        point: (k, 3) world points.

    Returns:
        (k, nv, 3).
    """
    body = np.asarray(body)
    safe = np.maximum(body, 0)
    lever = point - kin.com[safe]
    jac = kin.jac_lin[safe] + cross(kin.jac_ang[safe], lever[:, None, :])
    return jnp.where(jnp.asarray(body >= 0)[:, None, None], jac, 0.0)


def bias_accelerations(tree, kin: Kinematics, qvel):
    """Each body's accelerations at zero qacc: J̇ q̇ for the centre of mass and the angular velocity.

    A dof's axis turns with the frame it is fixed in (angular velocity ω_d of
    the dofs in ``dof_frame[d]``) and its anchor moves with them, so
    ȧ_d = ω_d × a_d and the anchor's velocity ṗ_d sums those dofs' motions
    at p_d. Then d/dt (a_d × (c_b − p_d)) = ȧ_d × (c_b − p_d) + a_d × (ċ_b − ṗ_d).

    Args:
        tree: the Model's JointTree.
        kin: the Kinematics of the current qpos.
        qvel: (nv,) joint velocities.

    Returns:
        (linear (n, 3), angular (n, 3), vel (n, 3), angvel (n, 3)): the bias
        accelerations and the velocities they were computed with.
    """
    vel, angvel = body_velocities(kin, qvel)
    rotational = jnp.asarray(tree.dof_rotational)
    frame = jnp.asarray(tree.dof_frame, qvel.dtype)
    spin = jnp.where(rotational[:, None], kin.axis, 0.0) * qvel[:, None]  # (nv, 3) a_e q̇_e of rotations
    frame_spin = frame @ spin
    axis_rate = cross(frame_spin, kin.axis)
    lever = kin.anchor[:, None, :] - kin.anchor[None, :, :]  # p_d − p_e
    axis_e = jnp.broadcast_to(kin.axis[None], lever.shape)
    motion = jnp.where(rotational[None, :, None], cross(axis_e, lever), axis_e)
    anchor_vel = jnp.einsum("de,dei,e->di", frame, motion, qvel)
    moves = jnp.asarray(tree.body_dofs, qvel.dtype)
    to_com = kin.com[:, None, :] - kin.anchor[None, :, :]
    turning = (cross(jnp.broadcast_to(axis_rate[None], to_com.shape), to_com)
               + cross(jnp.broadcast_to(kin.axis[None], to_com.shape), vel[:, None, :] - anchor_vel[None]))
    per_dof = jnp.where(rotational[None, :, None], turning, jnp.broadcast_to(axis_rate[None], to_com.shape))
    linear = jnp.einsum("bd,bdi,d->bi", moves, per_dof, qvel)
    angular = (moves * rotational) @ (axis_rate * qvel[:, None])
    return linear, angular, vel, angvel


def integrate_positions(tree, qpos, qvel, h):
    """qpos advanced by qvel over h, quaternions on the sphere (MuJoCo's ``mj_integratePos``).

    Hinge and slide coordinates add h·q̇; a ball's quaternion becomes
    q ⊗ exp(h ω) with ω its body-frame angular velocity; a free body's origin
    adds h·v and its quaternion turns likewise.

    Args:
        tree: the Model's JointTree.
        qpos: (nq,) coordinates.
        qvel: (nv,) velocities (or any tangent such as a Runge–Kutta stage's).
        h: () step.

    Returns:
        (nq,) the new coordinates.
    """
    parts = []
    for j, kind in enumerate(tree.joint_kind):
        a, d = tree.qpos_adr[j], tree.dof_adr[j]
        if kind in ("hinge", "slide"):
            parts.append(qpos[a:a + 1] + h * qvel[d:d + 1])
            continue
        if kind == "free":
            parts.append(qpos[a:a + 3] + h * qvel[d:d + 3])
            a, d = a + 3, d + 3
        turned = quat_ops.multiply(qpos[a:a + 4], quat_ops.exp(h * qvel[d:d + 3]))
        parts.append(quat_ops.normalize(turned))
    return jnp.concatenate(parts) if parts else qpos
