"""Joints, loop closures and actuators as a user names them, and the static joint tree a Model holds.

The kinds follow MuJoCo's model. A body's joints connect it to its parent
body (or the world); several joints on one body compose in the order they
were added (a hopper's torso: slide x, slide z, hinge y). A body with no
joint and no parent is free (what every body of a scene without joints is).
Closed loops are :class:`Connect` and :class:`Weld` constraints between two
bodies of the trees (MJCF ``<equality>``).

Frames. Joint anchors and axes are given in the world frame *at the pose
the scene is built in*, the reference configuration, where every hinge and
slide reads its ``ref`` (default 0) and every ball its identity quaternion.
:class:`JointTree` keeps them in the child body's frame, as MuJoCo's
``jnt_pos`` and ``jnt_axis``.

Coordinates are laid out as MuJoCo lays them out (``qpos``/``qvel``): in
body order, each body's joints in order; free 7/6 (the body frame's origin
and quaternion; the origin's world velocity, then the body-frame angular
velocity), ball 4/3 (quaternion; body-frame angular velocity), hinge and
slide 1/1.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Optional

import numpy as np

#: Joint kinds of the tree, with (qpos width, qvel width).
JOINT_WIDTHS = {"free": (7, 6), "ball": (4, 3), "hinge": (1, 1), "slide": (1, 1)}
#: Actuator kinds :meth:`jaxrb.Scene.add_actuator` takes.
ACTUATOR_KINDS = ("motor", "position", "velocity", "general")
#: How Coulomb joint friction (``frictionloss``) is solved: as bounded constraint rows, or smoothed.
JOINT_FRICTIONS = ("exact", "smooth")


@dataclasses.dataclass(frozen=True)
class Hinge:
    """A revolute joint: rotation about ``axis`` through ``anchor``.

    Attributes:
        axis: (3,) rotation axis, world frame at the built pose (normalised
            at build); 2D scenes take no axis (the plane's normal).
        anchor: (dim,) world point on the axis at the built pose; default the
            child body's frame origin.
    """

    axis: Optional[tuple] = (0.0, 0.0, 1.0)
    anchor: Optional[tuple] = None


@dataclasses.dataclass(frozen=True)
class Slider:
    """A prismatic joint: translation along ``axis``.

    Attributes:
        axis: (dim,) direction of travel, world frame at the built pose.
    """

    axis: tuple = (1.0, 0.0, 0.0)


@dataclasses.dataclass(frozen=True)
class Ball:
    """A spherical joint: any rotation about ``anchor`` (3D only).

    Attributes:
        anchor: (3,) world point at the built pose; default the child's frame origin.
    """

    anchor: Optional[tuple] = None


@dataclasses.dataclass(frozen=True)
class Fixed:
    """A weld: the child moves rigidly with its parent (no coordinates)."""


@dataclasses.dataclass(frozen=True)
class Free:
    """Six degrees of freedom, as a body without a joint has (only on a body whose parent is the world)."""


@dataclasses.dataclass(frozen=True)
class Connect:
    """A loop closure: a point of body A stays on a point of body B (MJCF ``<equality connect>``).

    Attributes:
        anchor: (dim,) world point at the built pose, fixed in both bodies' frames.
    """

    anchor: tuple = (0.0, 0.0, 0.0)


@dataclasses.dataclass(frozen=True)
class Weld:
    """A loop closure: body B keeps its built pose relative to body A (MJCF ``<equality weld>``)."""


JOINT_KINDS = {Hinge: "hinge", Slider: "slide", Ball: "ball", Fixed: "fixed", Free: "free"}
EQUALITY_KINDS = {Connect: "connect", Weld: "weld"}


def _masks(parent, body_joints, joint_kind, dof_adr, nv):
    """Static (nb, nv) body–dof and (nv, nv) frame masks, (nv,) rotational flags; see :class:`JointTree`."""
    nb = len(parent)
    rot = np.zeros(nv, bool)
    dof_joint = np.zeros(nv, int)
    for j, kind in enumerate(joint_kind):
        width = JOINT_WIDTHS[kind][1]
        dof_joint[dof_adr[j]:dof_adr[j] + width] = j
        if kind in ("hinge", "ball"):
            rot[dof_adr[j]:dof_adr[j] + width] = True
        elif kind == "free":
            rot[dof_adr[j] + 3:dof_adr[j] + 6] = True
    own = np.zeros((nb, nv), bool)
    for b, joints in enumerate(body_joints):
        for j in joints:
            own[b, dof_adr[j]:dof_adr[j] + JOINT_WIDTHS[joint_kind[j]][1]] = True
    body_dofs = np.zeros((nb, nv), bool)
    for b in range(nb):
        at = b
        while at >= 0:
            body_dofs[b] |= own[at]
            at = parent[at]
    frame = np.zeros((nv, nv), bool)
    for b, joints in enumerate(body_joints):
        above = body_dofs[parent[b]] if parent[b] >= 0 else np.zeros(nv, bool)
        earlier = above.copy()
        for j in joints:
            start, width = dof_adr[j], JOINT_WIDTHS[joint_kind[j]][1]
            dofs = range(start, start + width)
            for d in dofs:
                frame[d] = earlier
                # A ball's (or free body's) rotational axes turn with the joint's own rotation, and a
                # free body's turn about its origin, which its translations move.
                if rot[d] and joint_kind[j] in ("ball", "free"):
                    frame[d, list(dofs)] = True
            earlier = earlier.copy()
            earlier[start:start + width] = True
    return body_dofs, frame, rot, dof_joint


@dataclasses.dataclass(frozen=True)
class JointTree:
    """The static part of a scene's joints: what decides the articulated step's program.

    Every body of a scene with joints is in the tree: a body with no joint
    and no parent is a root on a free joint; a :class:`Fixed` body has a
    parent and no coordinates.

    Attributes:
        parent: (n,) parent body of each body, -1 for the world.
        order: bodies with parents before children (forward kinematics runs in this order).
        body_joints: per body, the indices of its joints in the order they compose.
        joint_kind: (nj,) ``"free"``, ``"ball"``, ``"hinge"`` or ``"slide"``.
        joint_body: (nj,) the body each joint moves.
        joint_names: (nj,) names used in messages.
        qpos_adr, dof_adr: (nj,) each joint's first index in qpos and in qvel.
        nq, nv: lengths of qpos and qvel.
        limited: (nj,) whether each joint's ``range`` is enforced.
        friction_dofs: dofs whose Coulomb friction (``frictionloss``) is compiled in.
        joint_friction: one of :data:`JOINT_FRICTIONS`.
        actuator_joint: (na,) the hinge or slide each actuator drives.
        actuator_names: (na,) names used in messages.
        ctrl_limited, force_limited: (na,) whether controls and forces are clamped.
        equality_kind: (ne,) ``"connect"`` or ``"weld"``.
        equality_bodies: (ne,) (body A, body B or -1 for the world).
        equality_rows: total rows of the loop closures (3 per connect, 6 per weld).
    """

    parent: tuple
    order: tuple
    body_joints: tuple
    joint_kind: tuple
    joint_body: tuple
    joint_names: tuple
    qpos_adr: tuple
    dof_adr: tuple
    nq: int
    nv: int
    limited: tuple
    friction_dofs: tuple = ()
    joint_friction: str = "exact"
    actuator_joint: tuple = ()
    actuator_names: tuple = ()
    ctrl_limited: tuple = ()
    force_limited: tuple = ()
    equality_kind: tuple = ()
    equality_bodies: tuple = ()

    @property
    def num_joints(self) -> int:
        """nj, the joints of the tree (free roots included, welds not)."""
        return len(self.joint_kind)

    @property
    def num_actuators(self) -> int:
        """na, the length of ``controls``."""
        return len(self.actuator_joint)

    @property
    def equality_rows(self) -> int:
        """Rows of the loop closures: 3 a connect, 6 a weld."""
        return sum(3 if kind == "connect" else 6 for kind in self.equality_kind)

    @property
    def has_rows(self) -> bool:
        """Whether the step has constraint rows: loop closures or exact Coulomb joint friction (rk4 has none)."""
        return bool(self.equality_kind) or (bool(self.friction_dofs) and self.joint_friction == "exact")

    @functools.cached_property
    def _derived(self):
        return _masks(self.parent, self.body_joints, self.joint_kind, self.dof_adr, self.nv)

    @property
    def body_dofs(self) -> np.ndarray:
        """(n, nv) bool: the dofs that move each body (its own and its ancestors')."""
        return self._derived[0]

    @property
    def dof_frame(self) -> np.ndarray:
        """(nv, nv) bool: row d marks the dofs that move or turn dof d's anchor and axis."""
        return self._derived[1]

    @property
    def dof_rotational(self) -> np.ndarray:
        """(nv,) bool: rotational dofs (hinge, ball, a free body's last three)."""
        return self._derived[2]

    @property
    def dof_joint(self) -> np.ndarray:
        """(nv,) int: the joint of each dof."""
        return self._derived[3]

    def summary(self) -> str:
        """The joint kinds compiled in, e.g. ``"2 hinge, 1 free; 1 motor; frictionloss (exact) on 2 dofs"``.

        Returns:
            One line for :meth:`jaxrb.Model.summary`.
        """
        counts: dict = {}
        for kind in self.joint_kind:
            counts[kind] = counts.get(kind, 0) + 1
        welds = sum(1 for b, joints in enumerate(self.body_joints) if not joints and self.parent[b] >= 0)
        parts = [", ".join(f"{count} {kind}" for kind, count in counts.items())
                 + (f", {welds} weld{'s' if welds > 1 else ''}" if welds else "")]
        parts.append(f"nq={self.nq}, nv={self.nv}")
        if any(self.limited):
            parts.append(f"limits on {sum(self.limited)}")
        if self.friction_dofs:
            parts.append(f"frictionloss ({self.joint_friction}) on {len(self.friction_dofs)} dofs")
        if self.equality_kind:
            parts.append("loop closures: " + ", ".join(self.equality_kind))
        if self.actuator_joint:
            parts.append(f"{self.num_actuators} actuator{'s' if self.num_actuators > 1 else ''}")
        return "joints (" + "; ".join(parts) + ")"
