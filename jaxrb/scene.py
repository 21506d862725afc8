"""Host-side scene builder: validates input and produces (Model, Params, State).

Everything a user types passes through here once, in NumPy, so mistakes are
caught at build time with a ``ValueError`` that names the body and the field,
and nothing malformed ever reaches the compiled step.

Conventions:
    * ``pos`` given to :meth:`Scene.add_body` is the world position of the
      body's own frame (the frame its shape or points are written in). The
      state stores the centre of mass, ``pos + R·com``; for the symmetric
      primitives the two coincide.
    * ``angvel`` is in the world frame.
    * Mass comes from ``mass`` (inertia scaled to match), else from ``density``
      (default 1000 kg/m³, or kg/m² in 2D), else from the points of a
      ``PointMasses`` body. ``inertia`` overrides the shape's inertia.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np

from jaxrb.model.shapes import PointMasses, ShapeError, check_inertia, mass_properties, validate_shape
from jaxrb.physics.collision.pairs import build_pair_groups
from jaxrb.physics.integrators import body_frame_momentum
from jaxrb.model.joints import ACTUATOR_KINDS, EQUALITY_KINDS, JOINT_FRICTIONS, JOINT_KINDS
from jaxrb.model.options import Contact, flat_options
from jaxrb.physics.joints.tree import ActuatorSpec, EqualitySpec, JointSpec, build_tree, collision_filter
from jaxrb.physics.joints.step import JOINT_INTEGRATORS, read_out
from jaxrb.physics.joints.dynamics import LIMIT_HERTZ_CAP
from jaxrb.model.types import (BROADPHASES, CONTACT_MODELS, INTEGRATORS, JOINT_ONLY_INTEGRATORS, ORIENTATIONS,
                               PENALTY_FRICTIONS, QUATERNION_ODE_INTEGRATORS, SOLVERS, Model, Params, State,
                               check_option, param_bounds)

DEFAULT_DENSITY = 1000.0
EQUALITY_KINDS_BY_NAME = {name: cls for cls, name in EQUALITY_KINDS.items()}
ALL_BITS = 0xFFFFFFFF
# Above this many body–body pairs the default broadphase is "spheres".
ALL_PAIRS_LIMIT = 64
#: Longest default substep (s) of impulse contact (see ``Scene.build``'s ``substeps``).
IMPULSE_SUBSTEP = 1.0 / 480.0


def default_substeps(dt: float, contact: str) -> int:
    """Substeps ``Scene.build`` takes when none are given: see its ``substeps`` argument.

    Args:
        dt: the step (s).
        contact: the scene's contact model, ``"none"``, ``"penalty"`` or ``"impulse"``.

    Returns:
        The fewest substeps of at most :data:`IMPULSE_SUBSTEP` for impulse
        contact, else 1.
    """
    if contact != "impulse":
        return 1
    return max(1, math.ceil(dt / IMPULSE_SUBSTEP - 1e-9))


@dataclasses.dataclass
class _Body:
    name: str
    shape: object
    mass: float
    inertia: np.ndarray  # (3, 3) or ()
    com: np.ndarray  # (dim,)
    pos: np.ndarray  # (dim,) centre of mass, world
    quat: Optional[np.ndarray]
    angle: Optional[float]
    vel: np.ndarray
    angvel: np.ndarray
    friction: float
    restitution: float
    linear_damping: float
    angular_damping: float
    collision_filter: tuple = (1, ALL_BITS)
    shape_frame: Optional[tuple] = None  # the shape's ((x, y, z), (w, x, y, z)) in the body frame


@dataclasses.dataclass
class _Plane:
    normal: np.ndarray
    offset: float
    friction: float
    restitution: float
    collision_filter: tuple


def _check_integer(field, value, low):
    """Reject anything but an integer >= low (bools too) for a build option."""
    if not (isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= low):
        raise ValueError(f"scene.build: {field!r} must be an integer >= {low}, got {value!r}")


def _check_filter(check, category, mask):
    for field, value in (("collision_category", category), ("collision_mask", mask)):
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or not 0 <= value <= ALL_BITS:
            check.fail(field, f"must be an integer bit mask in [0, 2**32), got {value!r}")
    return int(category), int(mask)


class _Fields:
    """Validation helpers that prefix every message with 'body i (name)'."""

    def __init__(self, label: str):
        self.label = label

    def fail(self, field: str, message: str):
        raise ValueError(f"{self.label}: field {field!r} {message}")

    def array(self, field, value, shape):
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            self.fail(field, f"must be numeric, got {value!r}")
        if array.shape != shape:
            self.fail(field, f"must have shape {shape}, got {array.shape}")
        if not np.all(np.isfinite(array)):
            self.fail(field, f"must be finite, got {array.tolist()}")
        return array.copy()  # the scene keeps it: a caller changing its own array later changes nothing

    def scalar(self, field, value, low=None, high=None, low_open=False):
        number = float(self.array(field, value, ()))
        if low is not None and (number < low or (low_open and number == low)):
            self.fail(field, f"must be {'>' if low_open else '>='} {low}, got {number}")
        if high is not None and number > high:
            self.fail(field, f"must be <= {high}, got {number}")
        return number


def _labelled(what: str, index: int, name: Optional[str]):
    """(index, name, field checker) of the ``what`` being added: its messages start 'joint 2 ('elbow')'."""
    name = name if name is not None else f"{what}{index}"
    return index, name, _Fields(f"{what} {index} ({name!r})")


def _given_arguments(arguments: dict, method) -> dict:
    """The keyword arguments of one add_body/add_plane call that differ from the defaults.

    Kept so a scene can be written to a file and replayed through the same
    method (:mod:`jaxrb.files.scenefile`). Arrays are copied, so a caller mutating
    its own array afterwards does not change the record.
    """
    defaults = {name: parameter.default for name, parameter in
                inspect.signature(method).parameters.items()}
    given = {}
    for name, value in arguments.items():
        if name == "self" or value is None:
            continue
        default = defaults.get(name)
        if default is not None and np.ndim(value) == 0 and not isinstance(value, str) \
                and type(value) is type(default) and value == default:
            continue
        if name != "shape" and not isinstance(value, (str, int, float)):
            value = np.array(value)
        given[name] = value
    return given


def _rotation_matrix(quat):
    w, x, y, z = quat
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


class Scene:
    """Collects bodies on the host, then builds the arrays the step runs on.

    The arguments of every accepted ``add_body``/``add_plane`` call are kept
    (those that differ from the defaults), so :mod:`jaxrb.files.scenefile` can save
    the scene and replay it through the same methods.

    Args:
        dim: 2 or 3.
        gravity: (dim,) gravitational acceleration; default (0, -9.81) in 2D and
            (0, 0, -9.81) in 3D.
    """

    def __init__(self, dim: int = 3, gravity=None):
        if dim not in (2, 3):
            raise ValueError(f"scene: 'dim' must be 2 or 3, got {dim!r}")
        self.dim = dim
        if gravity is None:
            gravity = (0.0, -9.81) if dim == 2 else (0.0, 0.0, -9.81)
        self.gravity = _Fields("scene").array("gravity", gravity, (dim,))
        self._bodies: list[_Body] = []
        self._planes: list[_Plane] = []
        # The arguments of each accepted add_body/add_plane call, for jaxrb.files.scenefile.
        self._body_args: list[dict] = []
        self._plane_args: list[dict] = []
        self._joints: list[JointSpec] = []
        self._equalities: list[EqualitySpec] = []
        self._actuators: list[ActuatorSpec] = []
        self._excluded_pairs: set = set()  # (body, body) pairs that never collide (exclude_collision)
        self._excluded_planes: set = set()  # (body, plane) pairs that never collide
        self._joint_args: list[dict] = []
        self._equality_args: list[dict] = []
        self._actuator_args: list[dict] = []

    @property
    def num_bodies(self) -> int:
        """Number of bodies added so far."""
        return len(self._bodies)

    def add_body(self, shape=None, *, mass=None, density=None, inertia=None, pos=None,
                 quat=None, angle=None, vel=None, angvel=None, friction=0.5, restitution=0.0,
                 linear_damping=0.0, angular_damping=0.0, collision_category=1,
                 collision_mask=ALL_BITS, name: Optional[str] = None, com=None, shape_pos=None,
                 shape_quat=None) -> int:
        """Add a dynamic body and return its index.

        Args:
            shape: a shape from :mod:`jaxrb.model.shapes`, or ``None`` for a body given
                only ``mass`` and ``inertia``.
            mass: scalar total mass (kg). Scales the shape's inertia to match.
            density: kg/m³ (3D) or kg/m² (2D); used when ``mass`` is not given.
            inertia: body-frame inertia about the centre of mass: (3,) principal
                moments or (3, 3) in 3D, a scalar in 2D. Overrides the shape's.
            pos: (dim,) world position of the body frame origin.
            quat: (4,) orientation (w, x, y, z), 3D only; normalised here.
            angle: scalar orientation angle (rad), 2D only.
            vel: (dim,) linear velocity of the centre of mass.
            angvel: (3,) world-frame angular velocity in 3D, a scalar in 2D.
            friction: Coulomb coefficient >= 0.
            restitution: in [0, 1].
            linear_damping, angular_damping: rates >= 0 in 1/s.
            collision_category, collision_mask: bit masks; two shapes can touch
                when each one's category meets the other's mask (Box2D's rule).
            name: used in messages; default ``"body<i>"``.
            com: (dim,) centre of mass in the body frame, instead of the
                shape's (``inertia`` is then about it: give it too, or the
                shape's inertia about its own centre is kept).
            shape_pos: (3,) where the shape sits in the body frame (3D; a
                MuJoCo geom placed in its body); default the frame's origin.
            shape_quat: (4,) the shape's orientation in the body frame.

        Returns:
            The body's index i (its row in every (n, ...) array).
        """
        arguments = dict(locals())
        dim, index = self.dim, len(self._bodies)
        name = name if name is not None else f"body{index}"
        check = _Fields(f"body {index} ({name!r})")

        if shape is not None:
            try:
                validate_shape(shape)
            except ShapeError as error:
                check.fail(error.field, error.message)
            if dim not in shape.dims:
                check.fail("shape", f"{type(shape).__name__} is not a {dim}D shape")
        if shape is None and (mass is None or inertia is None):
            check.fail("shape", "is None, so both 'mass' and 'inertia' must be given")
        if isinstance(shape, PointMasses) and (mass is not None or density is not None):
            check.fail("mass" if mass is not None else "density",
                       "must not be given for PointMasses: mass comes from the points")
        if mass is not None and density is not None:
            check.fail("density", "must not be given together with 'mass'")

        if shape is not None:
            shape_density = DEFAULT_DENSITY if density is None else check.scalar(
                "density", density, low=0.0, low_open=True)
            try:
                shape_mass, com, shape_inertia = mass_properties(shape, shape_density, dim)
            except ShapeError as error:
                check.fail(error.field, error.message)
            if mass is not None:
                body_mass = check.scalar("mass", mass, **param_bounds("mass"))
                shape_inertia = np.asarray(shape_inertia) * (body_mass / shape_mass)
            else:
                body_mass = shape_mass
        else:
            body_mass = check.scalar("mass", mass, **param_bounds("mass"))
            com, shape_inertia = np.zeros(dim), None

        shape_frame = None
        if shape_pos is not None or shape_quat is not None:
            if dim != 3:
                check.fail("shape_pos" if shape_pos is not None else "shape_quat", "is 3D only")
            offset = check.array("shape_pos", np.zeros(3) if shape_pos is None else shape_pos, (3,))
            turn = check.array("shape_quat", (1.0, 0.0, 0.0, 0.0) if shape_quat is None else shape_quat, (4,))
            if np.linalg.norm(turn) < 1e-12:
                check.fail("shape_quat", "must be non-zero")
            turn = turn / np.linalg.norm(turn)
            rotation = _rotation_matrix(turn)
            com = offset + rotation @ com
            if shape_inertia is not None:
                shape_inertia = rotation @ np.asarray(shape_inertia) @ rotation.T
            shape_frame = (tuple(offset.tolist()), tuple(turn.tolist()))
        if arguments["com"] is not None:  # the argument: ``com`` now holds the shape's
            com = check.array("com", arguments["com"], (dim,))
        if inertia is not None:
            if dim == 2:
                shape_inertia = check.scalar("inertia", inertia)
            else:
                try:
                    principal = np.shape(inertia) == (3,)
                except ValueError:  # ragged nesting; check.array below reports it
                    principal = False
                shape_inertia = np.diag(check.array("inertia", inertia, (3,))) if principal \
                    else check.array("inertia", inertia, (3, 3))
        try:
            check_inertia(shape_inertia, dim)
        except ShapeError as error:
            check.fail(error.field, error.message)

        origin = check.array("pos", np.zeros(dim) if pos is None else pos, (dim,))
        if dim == 3:
            if angle is not None:
                check.fail("angle", "is 2D only; use 'quat' in 3D")
            quat = check.array("quat", (1.0, 0.0, 0.0, 0.0) if quat is None else quat, (4,))
            norm = float(np.linalg.norm(quat))
            if norm < 1e-12:
                check.fail("quat", "must be non-zero")
            quat = quat / norm
            world_com = origin + _rotation_matrix(quat) @ com
            angvel = check.array("angvel", np.zeros(3) if angvel is None else angvel, (3,))
        else:
            if quat is not None:
                check.fail("quat", "is 3D only; use 'angle' in 2D")
            angle = check.scalar("angle", 0.0 if angle is None else angle)
            c, s = np.cos(angle), np.sin(angle)
            world_com = origin + np.array([[c, -s], [s, c]]) @ com
            angvel = check.array("angvel", 0.0 if angvel is None else angvel, ())
        vel = check.array("vel", np.zeros(dim) if vel is None else vel, (dim,))

        self._bodies.append(_Body(
            name=name, shape=shape, mass=body_mass, inertia=np.asarray(shape_inertia),
            com=np.asarray(com), pos=world_com, quat=quat if dim == 3 else None,
            angle=angle if dim == 2 else None, vel=vel, angvel=angvel,
            **{name: check.scalar(name, value, **param_bounds(name)) for name, value in dict(
                friction=friction, restitution=restitution, linear_damping=linear_damping,
                angular_damping=angular_damping).items()},
            collision_filter=_check_filter(check, collision_category, collision_mask), shape_frame=shape_frame))
        self._body_args.append(_given_arguments(arguments, Scene.add_body))
        return index

    def add_plane(self, normal=None, offset=0.0, *, friction=0.5, restitution=0.0,
                  collision_category=1, collision_mask=ALL_BITS) -> int:
        """Add a static plane (a half-plane in 2D) and return its index.

        The solid is ``normal·x < offset``; bodies rest on its ``+normal`` side.

        Args:
            normal: (dim,) non-zero normal, normalised here; default +z (3D), +y (2D).
            offset: the plane is ``normal·x = offset`` (after normalising).
            friction: Coulomb coefficient >= 0 (mixed with a body's as √(μ_A μ_B)).
            restitution: in [0, 1] (mixed as max(e_A, e_B)).
            collision_category, collision_mask: as in :meth:`add_body`.

        Returns:
            The plane's index (planes are numbered separately from bodies).
        """
        arguments = dict(locals())
        check = _Fields(f"plane {len(self._planes)}")
        default = np.eye(self.dim)[-1]
        normal = check.array("normal", default if normal is None else normal, (self.dim,))
        length = float(np.linalg.norm(normal))
        if length < 1e-12:
            check.fail("normal", "must be non-zero")
        self._planes.append(_Plane(
            normal=normal / length, offset=check.scalar("offset", offset) / length,
            friction=check.scalar("friction", friction, **param_bounds("friction")),
            restitution=check.scalar("restitution", restitution, **param_bounds("restitution")),
            collision_filter=_check_filter(check, collision_category, collision_mask)))
        self._plane_args.append(_given_arguments(arguments, Scene.add_plane))
        return len(self._planes) - 1

    def exclude_collision(self, body_a: int, body_b: Optional[int] = None, *, plane: Optional[int] = None):
        """Never let ``body_a`` touch ``body_b`` (or the static plane ``plane``): MJCF's ``<exclude>``.

        Args:
            body_a: a body index.
            body_b: another body index, or None when ``plane`` is given.
            plane: a plane index (from :meth:`add_plane`), or None.
        """
        check = _Fields("exclude_collision")
        body_a = self._body_index(check, "body_a", body_a, allow_world=False)
        if (body_b is None) == (plane is None):
            check.fail("body_b", "give exactly one of body_b and plane")
        if plane is not None:
            if not isinstance(plane, (int, np.integer)) or not 0 <= plane < len(self._planes):
                check.fail("plane", f"must be a plane index 0..{len(self._planes) - 1}, got {plane!r}")
            self._excluded_planes.add((body_a, int(plane)))
            return
        body_b = self._body_index(check, "body_b", body_b, allow_world=False)
        if body_a == body_b:
            check.fail("body_b", f"is body_a ({body_a}) itself")
        self._excluded_pairs.add((min(body_a, body_b), max(body_a, body_b)))

    def _body_index(self, check, field, value, allow_world):
        """A body index from a user (or None for the world where ``allow_world``), as an int; -1 the world."""
        if value is None and allow_world:
            return -1
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) \
                or not 0 <= value < len(self._bodies):
            world = " or None (the world)" if allow_world else ""
            check.fail(field, f"must be a body index 0..{len(self._bodies) - 1}{world}, got {value!r}")
        return int(value)

    def add_joint(self, kind, child, parent=None, *, range=None, ref=0.0, stiffness=0.0, springref=0.0,
                  damping=0.0, armature=0.0, frictionloss=0.0, name: Optional[str] = None) -> int:
        """Connect ``child`` to ``parent`` (or the world) by a joint and return the joint's index.

        Joints follow MuJoCo's model (:mod:`jaxrb.model.joints`): anchors and
        axes are world-frame values at the pose the scene is built in, where
        each hinge and slide reads ``ref``. Several joints on one body compose
        in the order added (all to the same parent). A body without joints
        and without parent is free. Collisions between a body and its parent
        are off, as in MuJoCo. In 2D, hinges turn about the plane's normal
        (give no axis), sliders take a (2,) axis, anchors are (2,), and a free
        body's coordinates are its frame's x, y and angle.

        Args:
            kind: ``rb.Hinge(axis, anchor)``, ``rb.Slider(axis)``, ``rb.Ball(anchor)``
                (3D), ``rb.Fixed()`` or ``rb.Free()``.
            child: index of the body the joint moves.
            parent: index of the body it is attached to, or None for the world.
            range: (2,) lower and upper limit of a hinge (rad) or slide (m);
                None for no limit.
            ref: () the coordinate at the built pose (MuJoCo's ``ref``).
            stiffness: () spring towards ``springref`` (N m/rad or N/m), hinges and slides.
            springref: () the spring's rest coordinate.
            damping: () viscous damping per dof (N m s/rad or N s/m).
            armature: () reflected rotor inertia per dof (kg m² or kg).
            frictionloss: () Coulomb friction bound per dof (N m or N); see
                ``scene.build``'s ``joint_friction``.
            name: used in messages; default ``"joint<i>"``.

        Returns:
            The joint's index (for :meth:`add_actuator`).
        """
        arguments = dict(locals())
        index, name, check = _labelled("joint", len(self._joints), name)
        if type(kind) not in JOINT_KINDS:
            check.fail("kind", f"must be one of rb.{', rb.'.join(cls.__name__ for cls in JOINT_KINDS)}, "
                               f"got {kind!r}")
        kind_name = JOINT_KINDS[type(kind)]
        child = self._body_index(check, "child", child, allow_world=False)
        parent = self._body_index(check, "parent", parent, allow_world=True)
        if child == parent:
            check.fail("parent", f"is the child body {child} itself; a joint connects two bodies (or a body and "
                                 "the world, parent=None)")
        if kind_name == "free" and parent != -1:
            check.fail("parent", "must be None (the world) for a free joint, as in MuJoCo")
        axis = anchor = None
        if self.dim == 2 and kind_name == "ball":
            check.fail("kind", "a ball joint is 3D only; a 2D scene's hinges turn about the plane's normal")
        if self.dim == 2 and kind_name == "hinge" and tuple(kind.axis) != (0.0, 0.0, 1.0):
            check.fail("axis", "leave it out in 2D: a hinge of the plane turns about its normal, z")
        if kind_name == "hinge":
            axis = check.array("axis", kind.axis, (3,))
        elif kind_name == "slide":
            axis = np.append(check.array("axis", kind.axis, (2,)), 0.0) if self.dim == 2 else \
                check.array("axis", kind.axis, (3,))
        if axis is not None and np.linalg.norm(axis) < 1e-12:
            check.fail("axis", "must be non-zero")
        if kind_name in ("hinge", "ball") and kind.anchor is not None:
            anchor = check.array("anchor", kind.anchor, (self.dim,))
            anchor = np.append(anchor, 0.0) if self.dim == 2 else anchor
        limited = range is not None
        if limited:
            if kind_name not in ("hinge", "slide"):
                check.fail("range", f"limits hinges and slides only, not a {kind_name} joint")
            range = check.array("range", range, (2,))
            if range[0] > range[1]:
                check.fail("range", f"must have lower <= upper, got {range.tolist()}")
        numbers = {field: check.scalar(field, value, **param_bounds("joint_" + field))
                   for field, value in dict(stiffness=stiffness, damping=damping, armature=armature,
                                            frictionloss=frictionloss).items()}
        if numbers["stiffness"] > 0 and kind_name not in ("hinge", "slide"):
            check.fail("stiffness", f"springs act on hinges and slides only, not a {kind_name} joint")
        if kind_name == "fixed" and any(numbers.values()):
            check.fail("kind", "a fixed joint has no coordinate to damp, drive or spring")
        self._joints.append(JointSpec(
            name=name, kind=kind_name, child=child, parent=parent, axis=axis, anchor=anchor, limited=limited,
            range=range if limited else np.zeros(2), ref=check.scalar("ref", ref),
            springref=check.scalar("springref", springref), **numbers))
        self._joint_args.append(_given_arguments(arguments, Scene.add_joint))
        return index

    def add_equality(self, kind, body_a, body_b=None, *, name: Optional[str] = None) -> int:
        """Close a loop: constrain ``body_a`` to ``body_b`` (or the world) and return the closure's index.

        Args:
            kind: ``rb.Connect(anchor)`` (a world point at the built pose that
                stays common to both bodies, a ball joint's constraint) or
                ``rb.Weld()`` (``body_b`` keeps its built pose relative to ``body_a``).
            body_a: () index of a body.
            body_b: () index of another body, or None for the world.
            name: used in messages; default ``"equality<i>"``.

        Returns:
            The closure's index.
        """
        arguments = dict(locals())
        index, name, check = _labelled("equality", len(self._equalities), name)
        if type(kind) not in EQUALITY_KINDS:
            check.fail("kind", f"must be rb.Connect(anchor) or rb.Weld(), got {kind!r}")
        body_a = self._body_index(check, "body_a", body_a, allow_world=False)
        body_b = self._body_index(check, "body_b", body_b, allow_world=True)
        if body_a == body_b:
            check.fail("body_b", f"is body_a ({body_a}) itself; a closure joins two bodies")
        anchor = None
        if isinstance(kind, EQUALITY_KINDS_BY_NAME["connect"]):
            anchor = check.array("anchor", kind.anchor if self.dim == 3 else tuple(kind.anchor)[:2], (self.dim,))
            anchor = np.append(anchor, 0.0) if self.dim == 2 else anchor
        self._equalities.append(EqualitySpec(name=name, kind=EQUALITY_KINDS[type(kind)], body_a=body_a,
                                             body_b=body_b, anchor=anchor))
        self._equality_args.append(_given_arguments(arguments, Scene.add_equality))
        return index

    def add_actuator(self, joint: int, kind: str = "motor", *, gear=1.0, kp=None, kv=None, gain=None, bias=None,
                     ctrlrange=None, forcerange=None, name: Optional[str] = None) -> int:
        """Drive a hinge or slide with an actuator and return its index (its place in ``controls``).

        MuJoCo's actuators with a joint transmission: the actuator's force
        p = gain·u + b0 + b1·l + b2·l̇ (l = gear·q, l̇ = gear·q̇, u the control
        clamped to ``ctrlrange``), clamped to ``forcerange``, acts on the
        joint as gear·p.

        Args:
            joint: index of a hinge or slide joint (from :meth:`add_joint`).
            kind: ``"motor"`` (gain 1, no bias: u is a force or torque),
                ``"position"`` (a servo: p = kp (u − l) − kv l̇), ``"velocity"``
                (p = kv (u − l̇)) or ``"general"`` (``gain`` and ``bias`` given).
            gear: () the transmission ratio.
            kp: () the position servo's gain.
            kv: () the velocity gain (a velocity actuator's, or a position servo's damping).
            gain: () a general actuator's gain.
            bias: (3,) a general actuator's bias terms (b0, b1, b2).
            ctrlrange: (2,) control clamp, or None.
            forcerange: (2,) force clamp, or None.
            name: used in messages; default ``"actuator<i>"``.

        Returns:
            The actuator's index.
        """
        arguments = dict(locals())
        index, name, check = _labelled("actuator", len(self._actuators), name)
        check_option("actuator kind", kind, ACTUATOR_KINDS)
        if not isinstance(joint, (int, np.integer)) or isinstance(joint, bool) or not 0 <= joint < len(self._joints):
            check.fail("joint", f"must be a joint index 0..{len(self._joints) - 1}, got {joint!r}")
        given = {"kp": kp, "kv": kv, "gain": gain, "bias": bias}
        allowed = {"motor": (), "position": ("kp", "kv"), "velocity": ("kv",), "general": ("gain", "bias")}[kind]
        for field, value in given.items():
            if value is not None and field not in allowed:
                check.fail(field, f"does not apply to a {kind!r} actuator (it takes {', '.join(allowed) or 'none'})")
        kp = check.scalar("kp", 0.0 if kp is None else kp, low=0.0)
        kv = check.scalar("kv", 0.0 if kv is None else kv, low=0.0)
        if kind == "position":
            gain, bias = kp, np.array([0.0, -kp, -kv])
        elif kind == "velocity":
            gain, bias = kv, np.array([0.0, 0.0, -kv])
        elif kind == "motor":
            gain, bias = 1.0, np.zeros(3)
        else:
            gain = check.scalar("gain", 1.0 if gain is None else gain)
            bias = check.array("bias", np.zeros(3) if bias is None else bias, (3,))
        ranges = {}
        for field, value in (("ctrlrange", ctrlrange), ("forcerange", forcerange)):
            if value is not None:
                value = check.array(field, value, (2,))
                if value[0] > value[1]:
                    check.fail(field, f"must have lower <= upper, got {value.tolist()}")
            ranges[field] = value
        self._actuators.append(ActuatorSpec(name=name, joint=int(joint), gear=check.scalar("gear", gear),
                                            gain=float(gain), bias=np.asarray(bias, float),
                                            ctrl_range=ranges["ctrlrange"], force_range=ranges["forcerange"]))
        self._actuator_args.append(_given_arguments(arguments, Scene.add_actuator))
        return index

    def build(self, dt: float, integrator: Optional[str] = None, orientation: Optional[str] = None,
              contact: Contact = None, substeps: Optional[int] = None, dtype=None, *,
              broadphase: Optional[str] = None, broadphase_capacity: Optional[int] = None,
              contact_margin: float = 0.01, bounce_threshold: float = 0.5, joint_friction: str = "exact",
              **deprecated):
        """Validate the options and return ``(model, params, state)``.

        Args:
            dt: time step of one ``step`` call (s), > 0.
            integrator: one of ``"euler"``, ``"semi_implicit"`` (the default without
                joints), ``"implicit_gyro"``, ``"rk4"``, ``"rk4_body"`` (see
                :mod:`jaxrb.physics.integrators`). A scene with joints takes
                ``"rk4"`` (MuJoCo's RK4: the default where nothing can touch and
                there are no limits, loop closures or exact joint friction; it
                takes no closures or exact friction), ``"midpoint"`` (the default otherwise: the
                Coriolis terms at the mid-velocity), ``"semi_implicit"``
                (MuJoCo's Euler) or ``"implicit"`` (velocity and position terms
                implicit: stable for stiff chains at large steps, and
                dissipative); see :mod:`jaxrb.physics.joints.step`.
            orientation: ``"first_order"`` or ``"exp_map"`` (default). The RK4s integrate
                the quaternion ODE themselves, so they take no orientation option.
            contact: the contact model and its options: ``rb.Impulse(...)``,
                ``rb.Penalty(...)`` (each option documented there, defaults in
                its ``repr``), or ``"impulse"``, ``"penalty"`` (their
                defaults) or ``"none"``. Contact needs a velocity-first
                integrator (``semi_implicit`` or ``implicit_gyro``); the
                default is impulse contact when any pair can touch, else none.
                A scene whose pairs can touch, built with ``euler``, ``rk4``
                or ``rk4_body``, must say ``contact="none"`` (a ValueError says
                so), rather than silently lose its contact.
            substeps: integration substeps per ``step`` call, >= 1. Default:
                for impulse contact the fewest that keep the substep at or
                below :data:`IMPULSE_SUBSTEP` (1/480 s): 8 at dt = 1/60 s, 1 at
                dt = 2 ms; otherwise 1. Why 1/480 s: a soft contact's spring
                (``hertz``, a quarter of the substep rate) sets how far
                a stack sinks. Measured at dt = 1/60 s over 10 s (0.2 m boxes,
                μ = 0.5, each set off sideways by up to 1 mm), with 4 substeps
                a 10-box column sinks 6.9 mm and a 50 kg box on a 1 kg box
                7.0 mm; with 8 they sink 1.7 and 1.8 mm, drift 0.11 and
                0.17 mm, and the 55-box 2D pyramid's top sinks 0.6 mm.
            dtype: floating dtype of Params and State; default JAX's default float
                (float64 when x64 is enabled, else float32).
            broadphase: ``"all_pairs"`` or ``"spheres"`` (bounding-sphere test,
                then at most ``broadphase_capacity`` pairs per pair kind); default
                all pairs up to 64 body–body pairs.
            broadphase_capacity: pairs kept per pair kind by the ``"spheres"``
                broadphase (default: all of them).
            contact_margin: distance (m) below which a contact is kept as
                speculative (``Params.contact_margin``).
            bounce_threshold: approach speed (m/s) below which a contact rests
                rather than bounces, and the band of ``RESTING`` status
                (``Params.bounce_threshold``).
            joint_friction: how joints' Coulomb friction (``frictionloss``) is
                solved: ``"exact"`` (bounded rows in the constraint passes, as
                MuJoCo's) or ``"smooth"`` (μ·q̇/√(q̇² + v²), v =
                ``Params.joint_friction_velocity``, for gradients through
                stick–slip).
            **deprecated: the contact models' options as flat keywords
                (``iterations=8``, ``penalty_stiffness=2e4``, ...): still
                taken for one release, with a DeprecationWarning
                (:data:`jaxrb.model.options.FLAT_KEYWORDS` maps them).

        Returns:
            ``(model, params, state)``: the static :class:`~jaxrb.model.types.Model`,
            the differentiable :class:`~jaxrb.model.types.Params` and the initial
            :class:`~jaxrb.model.types.State`.
        """
        contact, model_options = flat_options(contact, deprecated)
        return self._build(dt, integrator, orientation, contact, substeps, dtype, broadphase=broadphase,
                           broadphase_capacity=broadphase_capacity, contact_margin=contact_margin,
                           bounce_threshold=bounce_threshold, joint_friction=joint_friction, **model_options)

    def _collision_filter(self, tree) -> dict:
        """``build_pair_groups``' exclusions: the user's, and by MuJoCo's rule those of the joint tree."""
        excluded, static = collision_filter(tree) if tree is not None else (frozenset(), frozenset())
        return dict(excluded=excluded | frozenset(self._excluded_pairs), static_bodies=static,
                    excluded_planes=frozenset(self._excluded_planes))

    def _joint_tree(self, integrator, joint_friction):
        """(tree, arrays, qpos0) of the scene's joints, or Nones without joints (see ``build``)."""
        if not (self._joints or self._equalities or self._actuators):
            return None, None, None, None
        check_option("joint_friction", joint_friction, JOINT_FRICTIONS)
        if integrator not in JOINT_INTEGRATORS:
            raise ValueError(f"scene.build: a scene with joints steps with integrator "
                             f"{', '.join(map(repr, JOINT_INTEGRATORS))}, got {integrator!r}")
        bodies = self._bodies
        frames = [self._frame(b) for b in bodies]
        tree, arrays, qpos0, free_roots = build_tree(
            [b.name for b in bodies], [origin for origin, _ in frames], [quat for _, quat in frames], self._joints,
            self._equalities, self._actuators, joint_friction, planar=self.dim == 2)
        for index, body in enumerate(bodies):
            if index not in free_roots and (np.any(body.vel != 0.0) or np.any(body.angvel != 0.0)):
                raise ValueError(f"body {index} ({body.name!r}): fields 'vel' and 'angvel' must be zero on a "
                                 "body with joints; set joint velocities with rb.joints.set_qpos_qvel")
        return tree, arrays, qpos0, free_roots

    def _frame(self, body):
        """A body's frame at the built pose, in 3D: (origin (3,), quat (4,)); a 2D body's lies in the x-y plane."""
        if self.dim == 3:
            return body.pos - _rotation_matrix(body.quat) @ body.com, body.quat
        c, s = np.cos(body.angle), np.sin(body.angle)
        origin = body.pos - np.array([[c, -s], [s, c]]) @ body.com
        return np.append(origin, 0.0), np.array([np.cos(body.angle / 2), 0.0, 0.0, np.sin(body.angle / 2)])

    def _build(self, dt, integrator, orientation, contact, substeps, dtype, *, solver, iterations,
               relax_iterations, broadphase, broadphase_capacity, contact_margin, bounce_threshold, joint_friction,
               contact_hertz, contact_damping_ratio, max_push_velocity, penalty_stiffness, penalty_damping,
               penalty_frequency, penalty_damping_ratio, penalty_width, penalty_friction, friction_velocity,
               impulse_smoothing, time_of_impact):
        """:meth:`build` with every option as a flat keyword (:func:`jaxrb.model.options.flat_options`)."""
        check = _Fields("scene.build")
        if not self._bodies:
            raise ValueError("scene.build: the scene has no bodies; add one with add_body")
        dt = check.scalar("dt", dt, **param_bounds("dt"))
        jointed = bool(self._joints or self._equalities or self._actuators)
        chosen = integrator
        if integrator is None:  # with joints: rk4 where the scene lets it, decided once its pairs are known
            integrator = "midpoint" if jointed else "semi_implicit"
        check_option("integrator", integrator, INTEGRATORS)
        if integrator in JOINT_ONLY_INTEGRATORS and not jointed:
            raise ValueError(f"scene.build: integrator {integrator!r} is for scenes with joints; free bodies step "
                             "with 'semi_implicit' (the default), 'implicit_gyro', 'euler', 'rk4' or 'rk4_body'")
        tree, joint_arrays, qpos0, free_roots = self._joint_tree(integrator, joint_friction)
        if orientation is not None and integrator in QUATERNION_ODE_INTEGRATORS:
            raise ValueError(f"scene.build: 'orientation' does not apply to integrator {integrator!r}, "
                             "which integrates the quaternion ODE itself; leave it unset")
        orientation = check_option("orientation", "exp_map" if orientation is None else orientation,
                                   ORIENTATIONS)
        check_option("solver", solver, SOLVERS)
        check_option("penalty_friction", penalty_friction, PENALTY_FRICTIONS)
        for field, value, low in (("substeps", 1 if substeps is None else substeps, 1),
                                   ("iterations", iterations, 1),
                                   ("relax_iterations", relax_iterations, 0),
                                   ("broadphase_capacity", broadphase_capacity, 1)):
            if field != "broadphase_capacity" or value is not None:
                _check_integer(field, value, low)
        pair_count = sum(1 for a in range(len(self._bodies)) for b in range(a))
        if broadphase is None:
            broadphase = "all_pairs" if pair_count <= ALL_PAIRS_LIMIT else "spheres"
        check_option("broadphase", broadphase, BROADPHASES)
        pair_groups, skipped = build_pair_groups(
            [b.shape for b in self._bodies], [b.collision_filter for b in self._bodies],
            tuple((tuple(p.normal.tolist()), p.offset) for p in self._planes),
            [p.collision_filter for p in self._planes], self.dim, broadphase, broadphase_capacity,
            **self._collision_filter(tree))
        velocity_first = integrator in ("semi_implicit", "implicit_gyro", "midpoint", "implicit")
        if contact is None and pair_groups and not velocity_first:
            # Defaulting to "none" here let a box fall through the floor (z = -19 m
            # after 2 s) with no word: say so, and let the user choose.
            rows = sum(len(group.body_a) for group in pair_groups)
            raise ValueError(f"scene.build: integrator {integrator!r} cannot take contact (it needs a "
                             f"velocity-first integrator, 'semi_implicit' or 'implicit_gyro'), but this "
                             f"scene has {rows} pair{'s' if rows != 1 else ''} that can touch (planes or bodies); pass "
                             f"contact='none' to simulate it without contact, or choose one of those "
                             f"integrators")
        if contact is None:
            contact = "impulse" if pair_groups else "none"
        check_option("contact", contact, CONTACT_MODELS)
        smooth = jointed and (contact == "none" or not pair_groups) and not tree.has_rows and not any(tree.limited)
        if chosen is None and smooth:
            integrator = "rk4"  # MuJoCo's RK4: a double pendulum's energy to 1e-7 over 10 s (design.md, Joints)
        if jointed and integrator == "rk4" and tree.has_rows:
            raise ValueError("scene.build: integrator 'rk4' takes no loop closures and no exact joint friction "
                             "(use joint_friction='smooth', or the 'midpoint' integrator)")
        if contact == "none":
            pair_groups = ()
        elif not velocity_first:
            raise ValueError(f"scene.build: contact {contact!r} needs a velocity-first integrator "
                             f"('semi_implicit' or 'implicit_gyro'), got {integrator!r}")
        if substeps is None:
            substeps = default_substeps(dt, contact)
        if time_of_impact and contact != "impulse":
            raise ValueError(f"scene.build: 'time_of_impact' needs contact 'impulse', got {contact!r}")
        dtype = jax.dtypes.canonicalize_dtype(jnp.float64 if dtype is None else dtype)
        if not jnp.issubdtype(dtype, jnp.floating):
            raise ValueError(f"scene.build: 'dtype' must be a floating dtype, got {dtype}")

        bodies, dim = self._bodies, self.dim
        model = Model(
            dim=dim, num_bodies=len(bodies), integrator=integrator, orientation=orientation,
            contact=contact, substeps=int(substeps),
            damping=any(b.linear_damping > 0.0 or b.angular_damping > 0.0 for b in bodies),
            shapes=tuple(b.shape for b in bodies), names=tuple(b.name for b in bodies),
            planes=tuple((tuple(p.normal.tolist()), p.offset) for p in self._planes),
            pair_groups=pair_groups, solver=solver, iterations=int(iterations),
            relax_iterations=int(relax_iterations), penalty_smooth=penalty_width is not None,
            penalty_damping_from_restitution=penalty_damping is None and penalty_damping_ratio is None,
            penalty_friction=penalty_friction, time_of_impact=bool(time_of_impact),
            skipped_pairs=skipped, joints=tree,
            shape_frames=tuple(b.shape_frame for b in bodies) if any(b.shape_frame for b in bodies) else ())
        substep = dt / int(substeps)
        mean_mass = float(np.mean([b.mass for b in bodies]))
        if penalty_frequency is None:
            penalty_frequency = 0.03 / substep
        omega = 2.0 * np.pi * check.scalar("penalty_frequency", penalty_frequency, low=0.0, low_open=True)
        if penalty_stiffness is None:
            penalty_stiffness = mean_mass * omega ** 2
        if penalty_damping is None:
            ratio = 0.0 if penalty_damping_ratio is None else check.scalar(
                "penalty_damping_ratio", penalty_damping_ratio, low=0.0)
            penalty_damping = 2.0 * ratio * mean_mass * omega
        given = dict(contact_margin=contact_margin, bounce_threshold=bounce_threshold,
                     contact_hertz=0.25 / substep if contact_hertz is None else contact_hertz,
                     contact_damping_ratio=contact_damping_ratio, max_push_velocity=max_push_velocity,
                     penalty_stiffness=penalty_stiffness, penalty_damping=penalty_damping,
                     penalty_width=1e-3 if penalty_width is None else penalty_width,
                     friction_velocity=friction_velocity, impulse_smoothing=impulse_smoothing)
        scalars = {name: check.scalar(name, value, **param_bounds(name)) for name, value in given.items()}

        def stack(values):
            return jnp.asarray(np.stack([np.asarray(v, dtype=np.float64) for v in values]), dtype=dtype)

        num = len(bodies)
        params = Params(
            mass=stack([b.mass for b in bodies]),
            inertia=stack([b.inertia for b in bodies]),
            com_offset=stack([b.com for b in bodies]),
            friction=stack([b.friction for b in bodies]),
            restitution=stack([b.restitution for b in bodies]),
            gravity=jnp.asarray(self.gravity, dtype=dtype),
            dt=jnp.asarray(dt, dtype=dtype),
            linear_damping=stack([b.linear_damping for b in bodies]),
            angular_damping=stack([b.angular_damping for b in bodies]),
            force=jnp.zeros((num, dim), dtype=dtype),
            torque=jnp.zeros((num, 3) if dim == 3 else (num,), dtype=dtype),
            plane_friction=jnp.asarray([p.friction for p in self._planes], dtype=dtype),
            plane_restitution=jnp.asarray([p.restitution for p in self._planes], dtype=dtype),
            shape_scale=jnp.ones((num,), dtype=dtype),
            **{name: jnp.asarray(value, dtype=dtype) for name, value in scalars.items()})
        slots = model.num_contacts
        state = State(
            pos=stack([b.pos for b in bodies]),
            vel=stack([b.vel for b in bodies]),
            angvel=stack([b.angvel for b in bodies]),
            quat=stack([b.quat for b in bodies]) if dim == 3 else None,
            angle=stack([b.angle for b in bodies]) if dim == 2 else None,
            time=jnp.zeros((), dtype=dtype),
            contact_impulse=jnp.zeros((slots, 1 + dim), dtype=dtype) if slots else None,
            contact_key=jnp.full((slots,), -1, dtype=jnp.int32) if slots else None,
            overflow=jnp.zeros((), dtype=bool) if slots else None)
        if dim == 3 and integrator == "rk4_body":
            state = state.replace(body_momentum=body_frame_momentum(params, state.quat, state.angvel),
                                  momentum_residual=jnp.zeros((num, 3), dtype=dtype))
        if tree is not None:
            params, state = self._joint_params_state(model, params, state, joint_arrays, qpos0, free_roots, substep,
                                                     dtype)
        return model, params, state

    def _joint_params_state(self, model, params, state, arrays, qpos0, free_roots, substep, dtype):
        """Params and State of a scene with joints: its joints' fields, and qpos/qvel with their read-outs."""
        tree = model.joints
        cap = LIMIT_HERTZ_CAP["rk4" if model.integrator == "rk4" else "euler"]
        as_array = lambda value: jnp.asarray(value, dtype=dtype)
        params = params.replace(**{name: as_array(value) for name, value in arrays.items()},
                                joint_friction_velocity=as_array(0.01), limit_hertz=as_array(cap / substep),
                                limit_damping_ratio=as_array(1.0), equality_hertz=as_array(0.25 / substep),
                                equality_damping_ratio=as_array(1.0))
        qvel, moving = np.zeros(tree.nv), set()
        for index in free_roots:  # free bodies keep their velocities, in MuJoCo's layout
            body, start = self._bodies[index], tree.dof_adr[tree.body_joints[index][0]]
            if self.dim == 3:
                rotation = _rotation_matrix(body.quat)
                velocities = np.concatenate([body.vel - np.cross(body.angvel, rotation @ body.com),
                                             rotation.T @ body.angvel])
            else:  # the frame origin's velocity in the plane, then the angular rate
                c, s = np.cos(body.angle), np.sin(body.angle)
                arm = np.array([[c, -s], [s, c]]) @ body.com
                velocities = np.array([body.vel[0] + body.angvel * arm[1], body.vel[1] - body.angvel * arm[0],
                                       body.angvel])
            qvel[start:start + len(velocities)] = velocities
            if np.any(velocities):
                moving.add(index)
        state = state.replace(qpos=as_array(qpos0), qvel=as_array(qvel))
        # The bodies' poses and velocities are the read-outs of qpos0 and qvel already (the built pose),
        # unless a moving free root carries children: their velocities follow it.
        if any(tree.parent[body] in moving for body in range(len(self._bodies))):
            state = jax.jit(read_out, static_argnums=0)(model, params, state, state.qpos, state.qvel)
        return params, state
