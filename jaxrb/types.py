"""The three kinds of data: static ``Model``, traced ``Params`` and ``State``.

``Model`` decides which code is compiled (it is hashable and closed over by
``make_step``); ``Params`` holds everything physical a user may fit or sweep;
``State`` is what ``lax.scan`` carries from step to step.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Optional

import jax

from jaxrb._struct import pytree_dataclass

Array = jax.Array

INTEGRATORS = ("euler", "semi_implicit", "implicit_gyro", "rk4", "rk4_body")
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
            :class:`~jaxrb.collision.pairs.PairGroup` per pair kind (and
            geometry size), each run through one vmapped kernel.
        solver: impulse iteration scheme, one of :data:`SOLVERS`.
        iterations: impulse solver iterations per substep (unrolled).
        relax_iterations: iterations without position bias after each substep.
        penalty_smooth: penalty normal force uses the softplus activation.
        penalty_damping_from_restitution: penalty damping is derived per
            contact from restitution instead of ``Params.penalty_damping``.
        penalty_friction: penalty friction law, one of :data:`PENALTY_FRICTIONS`
            (see :mod:`jaxrb.contact.penalty`).
        time_of_impact: impulse contact resolves fast impacts of the pair
            kinds in :data:`jaxrb.contact.toi.TOI_KINDS` at their time inside
            the substep (see :mod:`jaxrb.contact.toi`).
        skipped_pairs: pair kinds present in the scene that no kernel handles.
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
        orientation = self.dim == 3 and self.integrator not in QUATERNION_ODE_INTEGRATORS
        stages.append(f"integrator {self.integrator}"
                      + (f" + orientation {self.orientation}" if orientation else ""))
        if self.contact != "none":
            kinds = ", ".join(f"{g.kind} x{g.capacity}" for g in self.pair_groups)
            detail = (f"{self.solver}, {self.iterations} iterations + {self.relax_iterations} relax"
                      + (", time of impact" if self.time_of_impact else "")
                      if self.contact == "impulse" else
                      f"{'smooth' if self.penalty_smooth else 'hard'} activation, "
                      f"{self.penalty_friction} friction")
            stages.insert(0, f"collision ({kinds}; {self.num_contacts} contact slots)")
            stages.append(f"contact {self.contact} ({detail})")
        if self.skipped_pairs:
            stages.append("no kernel for: " + ", ".join(self.skipped_pairs))
        return (f"jaxrb Model: {self.dim}D, {self.num_bodies} bodies ({body_text or 'none'}), "
                f"substeps={self.substeps}; step = " + " -> ".join(stages))


@pytree_dataclass
class Params:
    """Physical parameters: differentiable and vmappable.

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


#: Params fields computed from the others, never fitted or swept.
DERIVED_PARAMS = ("inv_inertia",)


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


@pytree_dataclass
class Wrench:
    """Forces and torques applied during one step (held constant over it).

    Attributes:
        force: (n, dim) world-frame force at each centre of mass.
        torque: (n, 3) world-frame torque in 3D, (n,) in 2D.
    """

    force: Array
    torque: Array
