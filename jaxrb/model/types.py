"""The three kinds of data: static ``Model``, traced ``Params`` and ``State``.

``Model`` decides which code is compiled (it is hashable and closed over by
``make_step``); ``Params`` holds everything physical a user may fit or sweep;
``State`` is what ``lax.scan`` carries from step to step.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Optional

import jax
import numpy as np

from jaxrb.model.struct import pytree_dataclass
from jaxrb.model.joints import JointTree
from jaxrb.model.shapes import ShapeError, check_inertia

Array = jax.Array

INTEGRATORS = ("euler", "semi_implicit", "implicit_gyro", "rk4", "rk4_body", "midpoint", "implicit")
#: Integrators of scenes with joints only (:data:`jaxrb.physics.joints.step.JOINT_INTEGRATORS`).
JOINT_ONLY_INTEGRATORS = ("midpoint", "implicit")
#: Integrators that integrate the quaternion ODE themselves (no ``orientation`` option).
QUATERNION_ODE_INTEGRATORS = ("rk4", "rk4_body")
ORIENTATIONS = ("first_order", "exp_map")
CONTACT_MODELS = ("none", "penalty", "impulse")
SOLVERS = ("sequential", "jacobi")
PENALTY_FRICTIONS = ("spring", "regularized")
BROADPHASES = ("all_pairs", "spheres")

# Contact status codes (ContactSet.status), from v_rel = n·(v_A − v_B) at the point.
INACTIVE, SEPARATING, RESTING, COLLIDING = 0, 1, 2, 3


def check_option(name: str, value: Any, valid: tuple) -> str:
    """Return ``value`` if it is one of ``valid``, else raise a ValueError listing them.

    Args:
        name: what the option is called, for the message (e.g. ``"integrator"``).
        value: the option given.
        valid: the allowed values.

    Returns:
        ``value`` unchanged.

    Raises:
        ValueError: ``value`` is not in ``valid``; the message names the option
            and lists the valid values.
    """
    if value not in valid:
        raise ValueError(
            f"unknown {name} {value!r}; valid options are: {', '.join(map(repr, valid))}")
    return value


@dataclasses.dataclass(frozen=True)
class Model:
    """Static description of a scene: what gets compiled.

    Attributes:
        dim: 2 or 3.
        num_bodies: number of dynamic bodies ``n``.
        integrator: one of :data:`INTEGRATORS`.
        orientation: one of :data:`ORIENTATIONS` (how the quaternion is advanced;
            in 2D the angle is advanced exactly and this is recorded only).
        contact: one of :data:`CONTACT_MODELS`.
        substeps: integration substeps per call of ``step`` (each ``dt/substeps``).
        damping: whether the linear/angular damping stage is compiled in.
        shapes: per-body shape (hashable, or ``None`` for a body given only mass
            and inertia); used by collision and rendering.
        names: per-body names used in messages and summaries.
        planes: static planes as ``(normal tuple, offset)``; the solid side is
            normal·x < offset.
        pair_groups: the static pair table, one
            :class:`~jaxrb.physics.collision.pairs.PairGroup` per pair kind (and
            geometry size), each run through one vmapped kernel.
        solver: impulse iteration scheme, one of :data:`SOLVERS`.
        iterations: impulse solver iterations per substep (unrolled).
        relax_iterations: iterations without position bias after each substep.
        penalty_smooth: penalty normal force uses the softplus activation.
        penalty_damping_from_restitution: penalty damping is derived per
            contact from restitution instead of ``Params.penalty_damping``.
        penalty_friction: penalty friction law, one of :data:`PENALTY_FRICTIONS`
            (see :mod:`jaxrb.physics.contact.penalty`).
        time_of_impact: impulse contact resolves fast impacts of the pair
            kinds in :data:`jaxrb.physics.contact.toi.TOI_KINDS` at their time inside
            the substep (see :mod:`jaxrb.physics.contact.toi`).
        skipped_pairs: pair kinds present in the scene that no kernel handles.
        joints: the scene's :class:`~jaxrb.model.joints.JointTree`, or None
            for a scene of free bodies (its step has no joint code).
        shape_frames: per body, None where the shape's frame is the body's,
            else the shape's pose in the body frame as ``((x, y, z), (w, x,
            y, z))`` (a MuJoCo geom placed in its body); empty when every
            shape sits at its body's frame.
    """

    dim: int
    num_bodies: int
    integrator: str = "semi_implicit"
    orientation: str = "exp_map"
    contact: str = "none"
    substeps: int = 1
    damping: bool = False
    shapes: tuple = ()
    names: tuple = ()
    planes: tuple = ()
    pair_groups: tuple = ()
    solver: str = "sequential"
    iterations: int = 4
    relax_iterations: int = 1
    penalty_smooth: bool = False
    penalty_damping_from_restitution: bool = True
    penalty_friction: str = "spring"
    time_of_impact: bool = False
    skipped_pairs: tuple = ()
    joints: Optional[JointTree] = None
    shape_frames: tuple = ()

    @property
    def num_actuators(self) -> int:
        """Length of the ``controls`` a step takes (0 without actuators)."""
        return 0 if self.joints is None else self.joints.num_actuators

    @property
    def num_contacts(self) -> int:
        """Fixed contact capacity C of the step (0 when nothing can touch)."""
        return sum(group.capacity * group.slots for group in self.pair_groups)

    def summary(self) -> str:
        """A short human-readable account of what the compiled step contains.

        Returns:
            One line: dimension, body counts per shape kind, substeps and the
            stages of the step in order (collision pair kinds and contact
            slots, integrator, contact model and solver settings).
        """
        kinds: dict[str, int] = {}
        for shape in self.shapes:
            kind = type(shape).__name__ if shape is not None else "MassOnly"
            kinds[kind] = kinds.get(kind, 0) + 1
        body_text = ", ".join(f"{count} {kind}" for kind, count in sorted(kinds.items()))
        stages = ["forces (gravity, constant and applied wrenches)"]
        if self.damping:
            stages.append("damping")
        orientation = self.dim == 3 and self.integrator not in QUATERNION_ODE_INTEGRATORS and self.joints is None
        stages.append(f"integrator {self.integrator}"
                      + (f" + orientation {self.orientation}" if orientation else ""))
        if self.contact != "none":
            # Groups of one kind differ only in geometry size (a kernel each): count them together.
            pairs: dict[str, list] = {}
            for group in self.pair_groups:
                pairs.setdefault(group.kind, []).append(group.capacity)
            kinds = ", ".join(f"{kind} x{sum(sizes)}" + (f" in {len(sizes)} kernels" if len(sizes) > 1 else "")
                              for kind, sizes in pairs.items())
            detail = (f"{self.solver}, {self.iterations} iterations + {self.relax_iterations} relax"
                      + (", time of impact" if self.time_of_impact else "")
                      if self.contact == "impulse" else
                      f"{'smooth' if self.penalty_smooth else 'hard'} activation, "
                      f"{self.penalty_friction} friction")
            stages.insert(0, f"collision ({kinds}; {self.num_contacts} contact slots)")
            stages.append(f"contact {self.contact} ({detail})")
        if self.joints is not None:
            stages.insert(1 if self.contact != "none" else 0, self.joints.summary())
        if self.skipped_pairs:
            stages.append("no kernel for: " + ", ".join(self.skipped_pairs))
        bodies = f"{self.num_bodies} {'body' if self.num_bodies == 1 else 'bodies'}"
        return (f"jaxrb Model: {self.dim}D, {bodies} ({body_text or 'none'}), "
                f"substeps={self.substeps}; step = " + " -> ".join(stages))


@pytree_dataclass
class Params:
    """Physical parameters: differentiable and vmappable.

    The fields from ``parent_offset`` on are the joints' and are None in a
    scene without joints (nj joints, nv dofs, na actuators, ne loop closures;
    the frames are :mod:`jaxrb.model.joints`').

    Attributes:
        mass: (n,) body masses.
        inertia: (n, 3, 3) body-frame inertia tensors about the centre of mass
            in 3D, or (n,) scalar moments in 2D.
        com_offset: (n, dim) centre of mass in the body's own (shape) frame.
        friction: (n,) Coulomb friction coefficients.
        restitution: (n,) coefficients of restitution.
        gravity: (dim,) gravitational acceleration.
        dt: () time step of one call to ``step``.
        linear_damping: (n,) rate c in dv/dt = -c v, 1/s.
        angular_damping: (n,) rate c in dL/dt = -c L, 1/s.
        force: (n, dim) constant world-frame force at each centre of mass.
        torque: (n, 3) constant world-frame torque in 3D, (n,) in 2D.
        plane_friction: (m,) friction of each static plane.
        plane_restitution: (m,) restitution of each static plane.
        contact_margin: () distance (m) below which a contact is kept as
            speculative; fast approaches extend it by dt·|v_n|.
        bounce_threshold: () approach speed (m/s) below which contacts rest
            instead of bouncing; also the band of ``RESTING`` status.
        contact_hertz: () stiffness of the impulse model's soft position
            correction (Hz).
        contact_damping_ratio: () damping ratio of that soft correction.
        max_push_velocity: () cap on the speed (m/s) used to push overlaps apart.
        penalty_stiffness: () penalty spring constant per contact point (N/m).
        penalty_damping: () penalty damper per contact point (N·s/m), used when
            the Model does not derive it from restitution.
        penalty_width: () softplus width (m) of the smooth penalty activation.
        friction_velocity: () regularisation velocity (m/s) of the
            ``"regularized"`` penalty friction: μF_n·v_t/√(|v_t|² + v_reg²).
        impulse_smoothing: () velocity scale σ (m/s) of the impulse model's
            soft complementarity: the accumulated normal impulse is clamped
            with the smooth max ½(λ + √(λ² + (m_n σ)²)) instead of max(λ, 0)
            (m_n: the contact's normal effective mass). 0 (the default) is the
            exact clamp; larger values trade bias (contacts push slightly
            before they touch) for gradients that see contacts coming.
        shape_scale: (n,) length scale of each body's collision shape about
            the shape's own origin (1: as built): radii, half-extents,
            vertices and points are multiplied by it in collision, so a size
            can be fitted (e.g. a tracker's length error). Mass, inertia and
            centre of mass are fields of their own and do not follow it;
            ``jaxrb.render`` draws the shapes as built.
        inv_inertia: derived, not a parameter: None, or ``inertia``'s inverse
            ((n, 3, 3) in 3D, (n,) in 2D) for the stages to use instead of
            inverting ``inertia`` each step. :func:`jaxrb.rollout` fills it
            once per rollout from ``inertia`` (replacing any value given), so
            reverse mode transposes the inverse once, not once per step; a
            step called on its own inverts ``inertia`` itself. Neither fitted
            nor swept (:data:`DERIVED_PARAMS`).
        parent_offset: (n, 3) each body frame's origin in its parent's frame
            at zero joint displacement (MuJoCo's ``body_pos``); a free root's
            is unused.
        parent_rotation: (n, 4) the body frame's orientation in its parent's
            frame, (w, x, y, z) (``body_quat``).
        joint_pos: (nj, 3) joint anchor in the child body's frame (``jnt_pos``).
        joint_axis: (nj, 3) hinge or slide axis in the child body's frame
            (``jnt_axis``; normalised where used).
        joint_ref: (nj,) hinge and slide coordinate at the reference pose (``ref``).
        joint_range: (nj, 2) lower and upper limit of the coordinate, used
            where the Model marks the joint limited.
        joint_stiffness: (nj,) spring (N m/rad or N/m) towards ``joint_springref``.
        joint_springref: (nj,) the spring's rest coordinate.
        joint_damping: (nv,) viscous damping per dof (N m s/rad or N s/m),
            integrated implicitly.
        joint_armature: (nv,) reflected rotor inertia added to the mass
            matrix's diagonal (kg m² or kg).
        joint_frictionloss: (nv,) Coulomb friction torque or force bound.
        joint_friction_velocity: () velocity scale of the smooth Coulomb law
            μ·q̇/√(q̇² + v²) (rad/s or m/s; the ``smooth`` joint friction).
        limit_hertz: () stiffness of the joint limits, an implicit
            spring-damper k = m_jj (2π f)² on the dof's own inertia m_jj.
        limit_damping_ratio: () damping ratio of that spring-damper.
        equality_hertz: () stiffness of the loop closures' soft correction (Hz).
        equality_damping_ratio: () its damping ratio.
        equality_anchor_a: (ne, 3) the closure's point in body A's frame
            (connect), or B's frame origin in A's frame (weld).
        equality_anchor_b: (ne, 3) the same point in body B's frame (world
            frame where B is the world).
        equality_rotation: (ne, 4) weld: B's orientation relative to A's.
        actuator_gear: (na,) transmission: the joint feels gear × force.
        actuator_gain: (na,) force per unit control.
        actuator_bias: (na, 3) force b0 + b1·length + b2·velocity
            (length = gear·q, velocity = gear·q̇).
        ctrl_range: (na, 2) control clamp, where the Model marks it limited.
        force_range: (na, 2) force clamp, where the Model marks it limited.
    """

    mass: Array
    inertia: Array
    com_offset: Array
    friction: Array
    restitution: Array
    gravity: Array
    dt: Array
    linear_damping: Array
    angular_damping: Array
    force: Array
    torque: Array
    plane_friction: Array
    plane_restitution: Array
    contact_margin: Array
    bounce_threshold: Array
    contact_hertz: Array
    contact_damping_ratio: Array
    max_push_velocity: Array
    penalty_stiffness: Array
    penalty_damping: Array
    penalty_width: Array
    friction_velocity: Array
    impulse_smoothing: Array
    shape_scale: Array
    inv_inertia: Optional[Array] = None
    parent_offset: Optional[Array] = None
    parent_rotation: Optional[Array] = None
    joint_pos: Optional[Array] = None
    joint_axis: Optional[Array] = None
    joint_ref: Optional[Array] = None
    joint_range: Optional[Array] = None
    joint_stiffness: Optional[Array] = None
    joint_springref: Optional[Array] = None
    joint_damping: Optional[Array] = None
    joint_armature: Optional[Array] = None
    joint_frictionloss: Optional[Array] = None
    joint_friction_velocity: Optional[Array] = None
    limit_hertz: Optional[Array] = None
    limit_damping_ratio: Optional[Array] = None
    equality_hertz: Optional[Array] = None
    equality_damping_ratio: Optional[Array] = None
    equality_anchor_a: Optional[Array] = None
    equality_anchor_b: Optional[Array] = None
    equality_rotation: Optional[Array] = None
    actuator_gear: Optional[Array] = None
    actuator_gain: Optional[Array] = None
    actuator_bias: Optional[Array] = None
    ctrl_range: Optional[Array] = None
    force_range: Optional[Array] = None

    def replace(self, **changes) -> "Params":
        """A copy with some fields replaced, each checked as ``Scene`` checks it.

        Args:
            **changes: field name -> value, the field's shape or a batch of
                it ((B,) + shape). A number sets the whole field (e.g.
                ``replace(friction=0.3)``: every body's friction). Concrete
                values are cast to the field's dtype and checked; traced ones
                (under ``jit``, ``vmap``, ``grad``) pass unchecked.

        Returns:
            A new Params; ``self`` is unchanged.

        Raises:
            ValueError: an unknown field, a shape that is neither the field's
                nor a batch of it, or values that are not finite or out of
                :data:`PARAM_BOUNDS` (negative mass, restitution above 1, a
                singular inertia), naming the field.
        """
        checked = {}
        for name, value in changes.items():
            if name not in self.__dataclass_fields__:
                raise ValueError(f"Params.replace: unknown field {name!r}; fields are "
                                 f"{', '.join(self.__dataclass_fields__)}")
            old = getattr(self, name)
            physical = hasattr(old, "dtype") and np.issubdtype(old.dtype, np.floating)
            # A Params-shaped tree of masks (bools) or cotangents is not checked; a traced value cannot be.
            if name in DERIVED_PARAMS or not physical or isinstance(value, jax.core.Tracer):
                checked[name] = value
                continue
            try:
                array = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError):
                raise ValueError(f"Params.replace: field {name!r} must be numeric, got {value!r}") from None
            shape = tuple(np.shape(old))
            if array.ndim == 0:
                array = np.broadcast_to(array, shape)
            elif array.shape != shape and array.shape[1:] != shape:
                raise ValueError(f"Params.replace: field {name!r} must have shape {shape} (or a batch of it, "
                                 f"(B,) + {shape}), got {array.shape}")
            check_param_values("Params.replace", name, array, int(np.shape(self.gravity)[-1]))
            checked[name] = jax.numpy.asarray(array, dtype=old.dtype)
        return dataclasses.replace(self, **checked)


#: Params fields computed from the others, never fitted or swept.
DERIVED_PARAMS = ("inv_inertia",)

#: The values each Params field may take, element by element: ``(low, high,
#: low_open)``, None for no bound. ``Scene``, :meth:`Params.replace` and
#: :func:`jaxrb.sweep.batch_params` all check against this one table; fields
#: not named here need only be finite (``inertia`` is checked as a tensor).
PARAM_BOUNDS = {
    "mass": (0.0, None, True), "friction": (0.0, None, False), "restitution": (0.0, 1.0, False),
    "dt": (0.0, None, True), "linear_damping": (0.0, None, False), "angular_damping": (0.0, None, False),
    "plane_friction": (0.0, None, False), "plane_restitution": (0.0, 1.0, False),
    "contact_margin": (0.0, None, False), "bounce_threshold": (0.0, None, False),
    "contact_hertz": (0.0, None, True), "contact_damping_ratio": (0.0, None, False),
    "max_push_velocity": (0.0, None, False), "penalty_stiffness": (0.0, None, True),
    "penalty_damping": (0.0, None, False), "penalty_width": (0.0, None, True),
    "friction_velocity": (0.0, None, True), "impulse_smoothing": (0.0, None, False),
    "shape_scale": (0.0, None, True),
    "joint_stiffness": (0.0, None, False), "joint_damping": (0.0, None, False),
    "joint_armature": (0.0, None, False), "joint_frictionloss": (0.0, None, False),
    "joint_friction_velocity": (0.0, None, True), "limit_hertz": (0.0, None, True),
    "limit_damping_ratio": (0.0, None, False), "equality_hertz": (0.0, None, True),
    "equality_damping_ratio": (0.0, None, False),
}


def param_bounds(name: str) -> dict:
    """``PARAM_BOUNDS[name]`` as keywords ``low``, ``high``, ``low_open`` (None, None, False if unbounded).

    Args:
        name: a Params field.

    Returns:
        A dict for a range check, e.g. ``{"low": 0.0, "high": None, "low_open": True}``.
    """
    low, high, low_open = PARAM_BOUNDS.get(name, (None, None, False))
    return dict(low=low, high=high, low_open=low_open)


def check_param_values(label: str, name: str, value, dim: int, bounds: Optional[dict] = None) -> None:
    """Raise a ValueError naming ``label`` and ``name`` where ``value`` is not a valid value of that field.

    Args:
        label: who checks, e.g. ``"Params.replace"``.
        name: the Params field (or an option named after one).
        value: a concrete array of the field's values (any leading batch axes).
        dim: 2 or 3 (how ``inertia`` is laid out).
        bounds: :func:`param_bounds` of the field; default ``param_bounds(name)``.

    Raises:
        ValueError: non-finite values, values outside :data:`PARAM_BOUNDS`,
            or an inertia that no body has (:func:`jaxrb.model.shapes.check_inertia`).
    """
    array = np.asarray(value, dtype=np.float64)

    def fail(bad, why):
        index = tuple(int(i) for i in np.argwhere(bad)[0])
        where = f" at index {index}" if index else ""
        raise ValueError(f"{label}: field {name!r} must be {why}, got {array[index]}{where}")

    if not np.all(np.isfinite(array)):
        fail(~np.isfinite(array), "finite")
    bounds = param_bounds(name) if bounds is None else bounds
    low, high = bounds["low"], bounds["high"]
    below = None if low is None else (array <= low if bounds["low_open"] else array < low)
    if below is not None and np.any(below):
        fail(below, f"{'>' if bounds['low_open'] else '>='} {low}")
    if high is not None and np.any(array > high):
        fail(array > high, f"<= {high}")
    if name == "inertia":
        for index in np.ndindex(array.shape[:-2] if dim == 3 else array.shape):
            try:
                check_inertia(array[index], dim)
            except ShapeError as error:
                raise ValueError(f"{label}: field 'inertia' at index {index} {error.message}") from None


@pytree_dataclass
class State:
    """Dynamic state of every body.

    Attributes:
        pos: (n, dim) centre of mass, world frame.
        vel: (n, dim) linear velocity of the centre of mass, world frame.
        angvel: (n, 3) world-frame angular velocity in 3D, (n,) in 2D.
        quat: (n, 4) unit quaternions (w, x, y, z) body-to-world in 3D; ``None`` in 2D.
        angle: (n,) body-to-world rotation angle in 2D; ``None`` in 3D.
        time: () simulated time.
        contact_impulse: (C, 1 + dim) per contact slot, the normal impulse then
            the world friction impulse vector: the impulse solver's
            accumulated impulses (its warm start), or, for penalty contact, the
            last substep's normal force and friction spring force times h.
        contact_key: (C,) int32 which pair and slot each row belongs to, so a
            warm start is used only by the same contact.
        overflow: () bool, True if a broadphase had more overlapping pairs than
            its capacity in the last step (contacts were dropped).
        body_momentum: (n, 3) integrator ``rk4_body`` in 3D only (else
            ``None``): body-frame angular momentum M = I Rᵀ ω as the last step
            computed it, which ``angvel`` holds only to rounding. The step
            starts from it while ``angvel`` agrees with it to rounding, so a
            user who replaces ``angvel`` may leave it as it is.
        momentum_residual: (n, 3) with ``body_momentum``: the low part of M,
            the rounding of each step's update carried to the next step
            (compensated summation), of the order of one ulp of M.
        qpos: (nq,) with joints (else ``None``): the joint coordinates in
            MuJoCo's layout (:mod:`jaxrb.model.joints`). In a scene with
            joints these, with ``qvel``, are what the step advances; ``pos``,
            ``quat``, ``vel`` and ``angvel`` are each step's read-outs of
            them (set both with :func:`jaxrb.joints.set_qpos_qvel`).
        qvel: (nv,) with joints: the joint velocities.
    """

    pos: Array
    vel: Array
    angvel: Array
    quat: Optional[Array]
    angle: Optional[Array]
    time: Array
    contact_impulse: Optional[Array] = None
    contact_key: Optional[Array] = None
    overflow: Optional[Array] = None
    body_momentum: Optional[Array] = None
    momentum_residual: Optional[Array] = None
    qpos: Optional[Array] = None
    qvel: Optional[Array] = None


@pytree_dataclass
class Wrench:
    """Forces and torques applied during one step (held constant over it).

    Attributes:
        force: (n, dim) world-frame force at each centre of mass.
        torque: (n, 3) world-frame torque in 3D, (n,) in 2D.
    """

    force: Array
    torque: Array
