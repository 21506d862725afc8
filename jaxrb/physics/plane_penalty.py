"""The step of bodies against planes with penalty contact, written on components.

``make_step`` returns this module's step for one kind of scene: 3D,
``contact="penalty"``, ``integrator="semi_implicit"``, and every contact
pair a shape (box, sphere, capsule or point set) against a static plane —
boxes, spheres and capsules dropped, thrown or slid on the ground, and
batches of such worlds. It is the same physics, stage for stage
(:mod:`jaxrb.physics.contact.penalty`'s law and friction models,
:mod:`jaxrb.physics.integrators`' semi-implicit phases, the plane kernels of
:mod:`jaxrb.physics.collision.plane` with the speculative margin of
:func:`jaxrb.physics.collision.pairs.detect`), written on component tuples: the
State is split into x, y, z parts on entry (:meth:`PlanePenalty.to_carry`)
and joined on exit (:meth:`PlanePenalty.from_carry`).

Why a second form: on XLA's CPU backend a step written on ``(n, 3)``
arrays ends each stage in a concatenate whose fused loop picks a component
per element, unvectorised, recomputing the chain behind it for each
(docs/design.md, 'Layout'). On components only the final join
remains, and the carry is stored before it: the batched box drop runs 1.8×
the (n, 3) step's speed, in a user's loop over ``vmap(step)`` and in
``rollout`` alike (docs/design.md, 'Fusion boundaries'). Each substep computes each body's rotation
matrix once and stores it (``components.materialize``): XLA duplicates a
producer into every consumer, and the 8 contact rows of a box each re-derived
it from the quaternion. It is not carried from the substep before: as a
loop operand, each of its nine entries was computed before the loop in a
kernel of its own, which the compile paid for (docs/design.md, 'Fusion boundaries').

Agreement with the generic step is tested (``tests/test_plane_penalty.py``):
the same trajectories to float rounding, and the same gradients.
"""

from __future__ import annotations

import dataclasses
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.math import components as vec

from jaxrb.math import quaternion as quat_ops
from jaxrb.physics.collision.geometry import geometry
from jaxrb.physics.collision.plane import BOX_CORNERS
from jaxrb.physics.collision.pairs import mix_friction
from jaxrb.physics.contact.penalty import contact_law, restitution_dampers, spring_activation
from jaxrb.physics.dynamics import inverse_inertia, net_wrench
from jaxrb.math.vector import unstack
from jaxrb.model.types import Model, Params, State

#: Pair kinds this path handles: each is a set of body-frame points swept by a radius.
PLANE_KINDS = ("box_plane", "sphere_plane", "capsule_plane", "points_plane")


def supports(model: Model) -> bool:
    """Whether ``make_step(model)`` returns this module's step (see the module docs).

    Args:
        model: a Model from ``Scene.build``.

    Returns:
        True for 3D penalty contact with the semi-implicit integrator where
        every pair group is one of :data:`PLANE_KINDS`. (Free bodies keep the
        generic step: its batch-1 rollout is 3.6× faster than this form's,
        while batched this form is only 2.2× faster; docs/design.md,
        'Layout'.)
    """
    return (model.dim == 3 and model.contact == "penalty" and model.integrator == "semi_implicit"
            and model.num_contacts > 0 and model.joints is None and not model.shape_frames
            and all(group.b_is_plane and group.kind in PLANE_KINDS for group in model.pair_groups))


# ---------------------------------------------------------------- the static plane groups

class _Normal:
    """A group's plane normals: shared Python floats when every pair has the same plane.

    Shared, the zero components drop out of every dot and cross product, and
    for an axis-aligned plane the tangential part of a vector is the vector
    with one component set to 0 (exactly what v − (v·n)n gives).
    """

    def __init__(self, normals: np.ndarray):
        self.shared = bool(np.all(normals == normals[0]))
        self.axis = None
        if self.shared:
            self.parts = tuple(float(x) for x in normals[0])
            nonzero = [i for i, x in enumerate(self.parts) if x != 0.0]
            if len(nonzero) == 1 and abs(self.parts[nonzero[0]]) == 1.0:
                self.axis = nonzero[0]
        else:
            self.parts = tuple(normals[:, i:i + 1] for i in range(3))

    def vector(self, dtype):
        """The normal as 3 parts: floats (0.0 kept) when shared, else (P, 1) arrays of ``dtype``."""
        if self.shared:
            return tuple(0.0 if x == 0.0 else jnp.asarray(x, dtype) for x in self.parts)
        return tuple(jnp.asarray(part, dtype) for part in self.parts)

    def tangential(self, vector, normal):
        if self.axis is not None:
            return tuple(0.0 if i == self.axis else part for i, part in enumerate(vector))
        return vec.sub(vector, vec.along(vec.dot(vector, normal), normal))


@dataclasses.dataclass(frozen=True)
class _PlaneGroup:
    """One pair group against planes, as static numpy arrays (P pairs, K points each)."""

    bodies: np.ndarray  # (P,) body index of each pair
    planes: np.ndarray  # (P,) plane index
    normal: _Normal
    offset: np.ndarray  # (P, 1)
    points: tuple  # 3 × (P, K) shape-frame points
    radius: np.ndarray  # (P, 1) sweep radius (0 for corners and points)
    rows: slice  # this group's rows of the contact arrays


def _shape_points(kind, arrays):
    """Shape-frame points (K, 3) and sweep radius of one shape: what its plane kernel tests."""
    if kind == "box":
        return np.asarray(BOX_CORNERS) * arrays[0], 0.0
    if kind == "sphere":
        return np.zeros((1, 3)), float(arrays[0])
    if kind == "capsule":
        return np.array([(0.0, 0.0, arrays[1]), (0.0, 0.0, -arrays[1])]), float(arrays[0])
    return np.asarray(arrays[0]), 0.0


def _plane_groups(model: Model):
    groups, start = [], 0
    for group in model.pair_groups:
        kind = group.kind.split("_")[0]
        shapes = [_shape_points(kind, geometry(model.shapes[b], 3)[1]) for b in group.body_a]
        points = np.stack([points for points, _ in shapes])
        count = len(group.body_a) * group.slots
        groups.append(_PlaneGroup(
            bodies=np.asarray(group.body_a), planes=np.asarray(group.body_b),
            normal=_Normal(np.array([model.planes[p][0] for p in group.body_b], dtype=np.float64)),
            offset=np.array([[model.planes[p][1]] for p in group.body_b]),
            points=tuple(points[..., i] for i in range(3)),
            radius=np.array([[radius] for _, radius in shapes]), rows=slice(start, start + count)))
        start += count
    return tuple(groups)


def _rows(values, bodies):
    """(n,) per-body values -> (P, 1) per-pair values; a slice where the bodies are consecutive."""
    first = int(bodies[0])
    if np.array_equal(bodies, np.arange(first, first + len(bodies))):
        return values[first:first + len(bodies), None]
    return values[bodies, None]


def _to_bodies(values, bodies, num_bodies):
    """(P, K) per-row values -> (n,) per-body sums over the group's rows."""
    per_pair = jnp.sum(values, axis=1)
    first = int(bodies[0])
    if np.array_equal(bodies, np.arange(first, first + len(bodies))):
        return jnp.pad(per_pair, (first, num_bodies - first - len(bodies)))
    return jax.ops.segment_sum(per_pair, bodies, num_bodies)


def rotation_stored(quat, params):
    """R(quat) (3 rows of 3 parts of (n,)), its nine entries computed once for all their readers."""
    return vec.stored_matrix(quat_ops.rotation_matrix_parts(quat), lambda parts: vec.materialize(parts, params))


def _stored(params, *vectors):
    """``vectors`` (tuples of (P, K) parts) computed once and stored, through one :func:`jaxrb.math.components.materialize`.

    XLA recomputes an elementwise producer inside every consumer: without
    this, each part of the friction force and of the spring carried (four
    fusions for a horizontal plane) re-derived the row's whole chain, from
    the rotated corner to the clamp's inputs.
    """
    flat = vec.materialize(tuple(part for vector in vectors for part in vector), params)
    out, start = [], 0
    for vector in vectors:
        out.append(flat[start:start + len(vector)])
        start += len(vector)
    return tuple(out)


# ---------------------------------------------------------------- the carry

@jax.tree_util.register_dataclass
@dataclasses.dataclass
class Carry:
    """What the scan carries: the State on components.

    Attributes:
        pos, vel, angvel: 3-tuples of (n,) world-frame components.
        quat: 4-tuple of (n,) quaternion components (w, x, y, z).
        normal_force: per group, (P, K) last substep's normal force.
        friction: per group, 3 parts of the (P, K) elastic friction force
            (world frame; 0.0 for a part an axis-aligned plane makes zero).
        time: () simulated time.
    """

    pos: tuple
    vel: tuple
    angvel: tuple
    quat: tuple
    normal_force: tuple
    friction: tuple
    time: jax.Array


class PlanePenalty:
    """The component form of ``make_step(model)``'s step, and the State ↔ Carry conversions.

    :meth:`step` calls :meth:`prepare` (what
    depends only on Params: mixed friction, dampers, body-frame contact
    points, inverse inertia) inside the loop. Those are a few operations a
    body, on Params that ``vmap`` over worlds leaves unbatched. Computed
    before the loop, they (with the rotation the Carry then held) were at
    least 36 of the batched box drop's 77 kernels outside it, each compiled
    apart: the drop compiled in 1.15–1.3× the time and ran no faster
    (docs/design.md, 'Fusion boundaries').

    Args:
        model: a Model for which :func:`supports` holds.
    """

    def __init__(self, model: Model):
        if not supports(model):
            raise ValueError("plane_penalty: the model is not 3D penalty contact against planes only "
                             "with the semi-implicit integrator")
        self.model = model
        self.groups = _plane_groups(model)
        self.keys = np.concatenate([group.key_offset + np.arange(len(group.body_a) * group.slots)
                                    for group in model.pair_groups]).astype(np.int32)

    def to_carry(self, state: State, params: Params) -> Carry:
        """Components of ``state``; contact rows whose key is not this model's start with no friction.

        Args:
            state: State of one world (``pos`` (n, 3), ``contact_impulse`` (C, 4), ...).
            params: Params (the time step, for the stored impulse → force).

        Returns:
            The Carry.
        """
        h = params.dt / self.model.substeps
        same = state.contact_key == self.keys
        force = jnp.where(same[:, None], state.contact_impulse, 0.0) / h
        friction, rows = [], lambda column, group: column[group.rows].reshape(len(group.bodies), -1)
        for group in self.groups:
            vector = tuple(rows(force[:, 1 + i], group) for i in range(3))
            friction.append(group.normal.tangential(vector, group.normal.vector(force.dtype)))
        return Carry(
            pos=unstack(state.pos), vel=unstack(state.vel), angvel=unstack(state.angvel),
            quat=unstack(state.quat),
            normal_force=tuple(rows(force[:, 0], group) for group in self.groups),
            friction=tuple(friction), time=state.time)

    def from_carry(self, carry: Carry, like: State, params: Params) -> State:
        """The State of ``carry`` (``like`` gives the fields the carry does not hold).

        Args:
            carry: a Carry after at least one step.
            like: a State of the same world (its ``overflow`` and
                ``momentum_residual`` fields).
            params: Params (the time step).

        Returns:
            The State, with ``contact_key`` the model's keys.
        """
        # Stored before the joins below: XLA's CPU backend otherwise fuses the
        # whole step into each stack that interleaves components into (n, 3)
        # arrays, computed one element at a time. The batched box drop as a
        # user's loop over vmap(step) ran 8.5 M body-steps/s with this, 4.6 M without.
        leaves, tree = jax.tree_util.tree_flatten(dataclasses.replace(carry, time=None))
        carry = dataclasses.replace(jax.tree_util.tree_unflatten(tree, list(vec.materialize(tuple(leaves), params))),
                                    time=carry.time)
        state = like.replace(
            pos=jnp.stack(carry.pos, axis=-1), vel=jnp.stack(carry.vel, axis=-1),
            angvel=jnp.stack(carry.angvel, axis=-1), quat=jnp.stack(carry.quat, axis=-1), time=carry.time)
        h = params.dt / self.model.substeps
        dtype = carry.pos[0].dtype
        flat = lambda part, shape: jnp.broadcast_to(jnp.asarray(part, dtype), shape).reshape(-1)
        columns = [jnp.concatenate([flat(force, force.shape) for force in carry.normal_force])]
        for i in range(3):
            columns.append(jnp.concatenate([flat(friction[i], force.shape) for friction, force
                                            in zip(carry.friction, carry.normal_force)]))
        return state.replace(contact_impulse=jnp.stack(columns, axis=-1) * h, contact_key=jnp.asarray(self.keys),
                             overflow=jnp.zeros((), dtype=bool))

    def prepare(self, params: Params) -> dict:
        """What the step needs from ``params`` alone, per body and per group.

        Args:
            params: Params.

        Returns:
            A dict pytree of arrays: per-body inverse mass, inertia and
            inverse inertia entries (n,); per group the body-frame contact
            points, inverse mass and inverse inertia entries of each pair's
            body, mixed friction and the normal and friction dampers before their
            cap (P, 1).
        """
        model, dtype = self.model, params.mass.dtype
        inv_inertia = vec.matrix_parts(inverse_inertia(params, 3))
        com = unstack(params.com_offset)
        groups = []
        for group in self.groups:
            take = lambda values: _rows(values, group.bodies)
            mass = take(params.mass)
            if model.penalty_damping_from_restitution:
                restitution = jnp.maximum(take(params.restitution), params.plane_restitution[group.planes][:, None])
                damping, friction_damping = restitution_dampers(restitution, params.penalty_stiffness, mass,
                                                                params.dt / model.substeps)
            else:
                damping = friction_damping = jnp.broadcast_to(params.penalty_damping, mass.shape)
            groups.append(dict(
                local=tuple(jnp.asarray(points, dtype) * take(params.shape_scale) - take(part)
                            for points, part in zip(group.points, com)),
                inv_mass=1.0 / mass, inv_inertia=tuple(tuple(map(take, row)) for row in inv_inertia),
                friction=mix_friction(take(params.friction), params.plane_friction[group.planes][:, None]),
                damping=damping, friction_damping=friction_damping, offset=jnp.asarray(group.offset, dtype),
                radius=jnp.asarray(group.radius, dtype) * take(params.shape_scale)))
        return dict(inv_mass=1.0 / params.mass, inertia=vec.matrix_parts(params.inertia),
                    inv_inertia=inv_inertia, groups=tuple(groups))

    def step(self, carry: Carry, params: Params, applied=None, prepared: Optional[dict] = None) -> Carry:
        """One step (all substeps) on the carry; ``make_step``'s step in component form.

        Args:
            carry: the Carry of one world.
            params: Params.
            applied: optional Wrench for this step, as for ``make_step``.
            prepared: ``self.prepare(params)``, computed here when None.

        Returns:
            The Carry after the step.
        """
        model = self.model
        prepared = self.prepare(params) if prepared is None else prepared
        force, torque = net_wrench(model, params, applied)
        force, torque = unstack(force), unstack(torque)
        h = params.dt / model.substeps
        for _ in range(model.substeps):
            carry = self._substep(carry, params, prepared, force, torque, h)
        return dataclasses.replace(carry, time=carry.time + params.dt)

    def _damp(self, value, rate, h):
        if not self.model.damping:
            return value
        return vec.along(1.0 / (1.0 + h * rate), value)

    def _velocity_phase(self, params, prepared, carry, rotation, force, torque, h):
        """semi_implicit_velocity: v += h F/m, ω += h R I⁻¹ Rᵀ τ, damped (``rotation`` R(carry.quat))."""
        vel = vec.add(carry.vel, vec.along(h * prepared["inv_mass"], force))
        body_torque = vec.matvec_transposed(rotation, torque)
        spin = vec.matvec(rotation, vec.matvec(prepared["inv_inertia"], body_torque))
        angvel = vec.add(carry.angvel, vec.along(h, spin))
        return (self._damp(vel, params.linear_damping, h), self._damp(angvel, params.angular_damping, h))

    def _substep(self, carry, params, prepared, force, torque, h):
        start = rotation_stored(carry.quat, params)
        contact_force, contact_torque, normal_forces, frictions = self._penalty(
            carry, start, params, prepared, force, torque, h)
        vel, angvel = self._velocity_phase(params, prepared, carry, start, vec.add(force, contact_force),
                                           vec.add(torque, contact_torque), h)
        # Stored once: the new quaternion's 4 parts and the new ω's 3 each
        # re-derived this ω (the contact torque's sums and R I⁻¹ Rᵀ) in their
        # own fusion. The batched box drop runs 0.80-0.86x the time
        # (docs/design.md, 'Fusion boundaries').
        angvel = vec.materialize(angvel, params)
        # semi_implicit_position: x += h v; q by the orientation update; world L kept.
        pos = vec.add(carry.pos, vec.along(h, vel))
        angvel_body = vec.matvec_transposed(start, angvel)
        momentum = vec.matvec(start, vec.matvec(prepared["inertia"], angvel_body))
        quat = quat_ops.ORIENTATION_UPDATES_PARTS[self.model.orientation](carry.quat, angvel, h)
        rotation = quat_ops.rotation_matrix_parts(quat)
        # ω_b + I⁻¹(Rᵀ L − I ω_b) as integrators.angvel_from_momentum, with the new rotation.
        change = vec.sub(vec.matvec_transposed(rotation, momentum), vec.matvec(prepared["inertia"], angvel_body))
        angvel = vec.matvec(rotation, vec.add(angvel_body, vec.matvec(prepared["inv_inertia"], change)))
        return Carry(pos=pos, vel=vel, angvel=angvel, quat=quat,
                     normal_force=normal_forces, friction=frictions, time=carry.time)

    def _penalty(self, carry, rotation, params, prepared, force, torque, h, record: Optional[dict] = None):
        """penalty_wrench on every group: body force and torque sums, and each row's carried forces.

        ``rotation`` is R(carry.quat), 3 rows of 3 parts of (n,).

        ``record``, when given, receives the intermediates the hand-written
        adjoint reads (:mod:`jaxrb.physics.plane_penalty_adjoint`): the predicted
        angular velocity and, under ``"groups"``, one dict per group.

        Returns:
            ``(force, torque, normal_forces, frictions)``: 3 parts of (n,)
            per-body contact force and torque, and per group the (P, K)
            normal force and the 3 parts of the friction force to carry.
        """
        model, num = self.model, self.model.num_bodies
        dtype = carry.pos[0].dtype
        contact_force, contact_torque = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
        normal_forces, frictions = [], []
        predicted_vel, predicted_angvel = self._velocity_phase(params, prepared, carry, rotation, force, torque, h)
        if record is not None:
            record.update(predicted_angvel=predicted_angvel, groups=[])
        rows = [self._contact_rows(params, carry, rotation, group, data)
                for group, data in zip(self.groups, prepared["groups"])]
        # Contacts touching each body, over all its groups (the damper cap shares them).
        sharing_body = jnp.maximum(sum(_to_bodies(row["active"].astype(dtype), group.bodies, num)
                                       for row, group in zip(rows, self.groups)), 1.0)
        for index, (row, group, data) in enumerate(zip(rows, self.groups, prepared["groups"])):
            take = lambda values: _rows(values, group.bodies)
            rotation, arm, normal = row["rotation"], row["arm"], row["normal"]
            active, rel_vel = row["active"], row["rel_vel"]
            sharing = take(sharing_body)

            def contact_mass(direction):
                """Effective mass along ``direction`` (3 parts), shared among the body's contacts."""
                arm_cross = vec.matvec_transposed(rotation, vec.cross(arm, direction))  # body frame
                angular = vec.dot(vec.matvec(data["inv_inertia"], arm_cross), arm_cross)
                return 1.0 / (data["inv_mass"] + angular) / sharing

            activation, gate = spring_activation(model, params, -row["dist"])
            predicted_rel = vec.add(tuple(map(take, predicted_vel)), vec.cross(tuple(map(take, predicted_angvel)), arm))
            held = group.normal.tangential(vec.where(active, carry.friction[index]), normal)
            law = contact_law(vec, model, params, h, activation=activation, gate=gate, vn=row["vn"], active=active,
                              contact_mass=contact_mass, normal=normal, damping=data["damping"],
                              friction_damping=data["friction_damping"], friction=data["friction"],
                              tangential_vel=group.normal.tangential(rel_vel, normal),
                              slip=group.normal.tangential(predicted_rel, normal), held=held,
                              store=lambda *vectors: _stored(params, *vectors))
            normal_force, friction, held = law["normal_force"], law["friction_force"], law["held"]
            total = vec.materialize(vec.add(vec.along(normal_force, normal), friction), params)
            if record is not None:  # the spring friction's intermediates (the adjoint's only law)
                record["groups"].append(dict(row, **law, sharing=sharing, activation=activation, gate=gate,
                                             friction=friction, total=total))
            to_bodies = lambda vector: tuple(part if vec.is_zero(part) else _to_bodies(part, group.bodies, num)
                                             for part in vector)
            contact_force = vec.add(contact_force, to_bodies(total))
            contact_torque = vec.add(contact_torque, to_bodies(vec.cross(arm, total)))
            normal_forces.append(normal_force)
            frictions.append(held)
        return contact_force, contact_torque, tuple(normal_forces), tuple(frictions)

    def _contact_rows(self, params, carry, rotation, group, data):
        """The plane kernel and detect's speculative margin for one group: every row (P, K)."""
        take = lambda values: _rows(values, group.bodies)
        rotation = tuple(tuple(map(take, row)) for row in rotation)
        arm = vec.matvec(rotation, data["local"])  # point minus centre of mass, world frame
        normal = group.normal.vector(carry.pos[0].dtype)
        height = vec.dot(vec.add(tuple(map(take, carry.pos)), arm), normal) - data["offset"]
        # The contact point is midway between the shape's surface and the plane.
        arm = vec.sub(arm, vec.along(0.5 * (height + data["radius"]), normal))
        rel_vel = vec.add(tuple(map(take, carry.vel)), vec.cross(tuple(map(take, carry.angvel)), arm))
        dist = height - data["radius"]
        if self.model.penalty_friction == "spring":
            # Every later stage of the row reads these: computed once (with the
            # friction inputs stored in _penalty, the batched drop runs 1.5-1.7x faster;
            # the regularised law gains nothing from it: docs/design.md, 'Fusion boundaries').
            arm, rel_vel, (dist,) = _stored(params, arm, rel_vel, (dist,))
        vn = vec.dot(rel_vel, normal)
        reach = params.contact_margin + params.dt * jnp.maximum(-vn, 0.0)
        return dict(rotation=rotation, arm=arm, normal=normal, rel_vel=rel_vel, vn=vn, dist=dist,
                    active=dist < reach)
