"""Building a joint tree on the host: the static :class:`JointTree` and the joints' Params arrays.

:meth:`jaxrb.Scene.build` hands over the bodies' built poses and the
joints, loop closures and actuators as the user gave them (world frames at
the built pose); this module checks how they fit together (one parent a
body, no loop of joints, a free joint only on a root, ...) and writes them in
the child frames the step uses, with MuJoCo's layout of qpos and qvel.
Every message names the joint, closure or actuator and its field.
"""

from __future__ import annotations

import dataclasses
from typing import Optional

import numpy as np

from jaxrb.model.joints import JOINT_WIDTHS, JointTree


@dataclasses.dataclass
class JointSpec:
    """One ``add_joint`` call, checked field by field (world frame at the built pose)."""

    name: str
    kind: str  # "hinge", "slide", "ball", "fixed", "free"
    child: int
    parent: int  # -1: the world
    axis: Optional[np.ndarray]
    anchor: Optional[np.ndarray]
    limited: bool
    range: np.ndarray  # (2,)
    ref: float
    stiffness: float
    springref: float
    damping: float
    armature: float
    frictionloss: float


@dataclasses.dataclass
class EqualitySpec:
    """One ``add_equality`` call."""

    name: str
    kind: str  # "connect", "weld"
    body_a: int
    body_b: int  # -1: the world
    anchor: Optional[np.ndarray]


@dataclasses.dataclass
class ActuatorSpec:
    """One ``add_actuator`` call, as MuJoCo's gain and bias."""

    name: str
    joint: int
    gear: float
    gain: float
    bias: np.ndarray  # (3,)
    ctrl_range: Optional[np.ndarray]
    force_range: Optional[np.ndarray]


def rotation_matrix(quat) -> np.ndarray:
    """(3, 3) rotation matrix of a unit quaternion (w, x, y, z), on the host (NumPy)."""
    w, x, y, z = quat
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _multiply(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _conjugate(q):
    return np.array([q[0], -q[1], -q[2], -q[3]])


def _planar_free(names, body, given):
    """A free body of the plane: slide x, slide y, hinge z, whose coordinates are its frame's x, y and angle."""
    spec = lambda kind, axis, suffix: JointSpec(
        name=f"{names[body]}_{suffix}" if given is None else f"{given.name}_{suffix}", kind=kind, child=body,
        parent=-1, axis=np.asarray(axis, float), anchor=None, limited=False, range=np.zeros(2), ref=0.0,
        stiffness=0.0, springref=0.0, damping=0.0, armature=0.0, frictionloss=0.0)
    return [spec("slide", (1, 0, 0), "x"), spec("slide", (0, 1, 0), "y"), spec("hinge", (0, 0, 1), "angle")]


def build_tree(names, origins, quats, joints: list, equalities: list, actuators: list, joint_friction: str,
               planar: bool = False):
    """Check the joints and lay them out.

    Args:
        names: (n,) body names.
        origins: (n, 3) body frame origins at the built pose (world).
        quats: (n, 4) body frame orientations at the built pose.
        joints, equalities, actuators: lists of :class:`JointSpec`,
            :class:`EqualitySpec`, :class:`ActuatorSpec` in the order added.
        joint_friction: ``"exact"`` or ``"smooth"``.
        planar: a 2D scene (bodies in the x-y plane, hinges about z): a free
            body is a slide along x, a slide along y and a hinge about z.

    Returns:
        (tree, arrays, qpos0, free_roots): the :class:`JointTree`, a dict of
        NumPy arrays for the joints' Params fields, the (nq,) coordinates of
        the built pose, and the set of free bodies (their coordinates take
        their velocities).

    Raises:
        ValueError: naming the joint (or closure, actuator) and the field.
    """
    n = len(names)
    parent = [-1] * n
    has_joint = [False] * n
    by_body: list = [[] for _ in range(n)]
    for index, joint in enumerate(joints):
        label = f"joint {index} ({joint.name!r})"
        if has_joint[joint.child] and parent[joint.child] != joint.parent:
            raise ValueError(f"{label}: field 'parent' is {joint.parent}, but body {joint.child} "
                             f"({names[joint.child]!r}) already has joints to parent {parent[joint.child]}; "
                             "a body's joints all connect it to one parent (close loops with add_equality)")
        if joint.kind in ("free", "fixed") and by_body[joint.child]:
            raise ValueError(f"{label}: field 'kind' is {joint.kind!r}, but body {joint.child} already has "
                             "joints; a free or fixed joint is a body's only joint")
        if by_body[joint.child] and joints[by_body[joint.child][0]].kind in ("free", "fixed"):
            raise ValueError(f"{label}: body {joint.child} already has a "
                             f"{joints[by_body[joint.child][0]].kind} joint, which must be its only joint")
        parent[joint.child] = joint.parent
        has_joint[joint.child] = True
        by_body[joint.child].append(index)
    for body in range(n):  # a loop of joints: walking up from a body comes back to it
        seen, at = set(), body
        while at >= 0:
            if at in seen:
                cycle = [names[b] for b in seen]
                raise ValueError(f"body {body} ({names[body]!r}): its joints form a loop through bodies "
                                 f"{sorted(cycle)}; a joint tree cannot close a loop: join the last pair with "
                                 "scene.add_equality(rb.Connect(...)) instead of a joint")
            seen.add(at)
            at = parent[at]
    order, placed = [], set()
    while len(order) < n:
        for body in range(n):
            if body not in placed and (parent[body] < 0 or parent[body] in placed):
                order.append(body)
                placed.add(body)

    rotations = [rotation_matrix(q) for q in quats]
    kinds, joint_body, joint_names, qpos_adr, dof_adr, limited = [], [], [], [], [], []
    body_joints = []
    arrays = {key: [] for key in ("joint_pos", "joint_axis", "joint_ref", "joint_range", "joint_stiffness",
                                  "joint_springref")}
    dof_arrays = {key: [] for key in ("joint_damping", "joint_armature", "joint_frictionloss")}
    qpos0, nq, nv, joint_of_spec = [], 0, 0, {}
    planar_roots = set()
    for body in range(n):
        specs = [(i, joints[i]) for i in by_body[body] if joints[i].kind != "fixed"]
        free = not has_joint[body] or joints[by_body[body][0]].kind == "free"
        if free and planar:
            planar_roots.add(body)
            given = by_body[body][0] if has_joint[body] else None
            specs = [(given if k == 0 else None, spec) for k, spec in
                     enumerate(_planar_free(names, body, None if given is None else joints[given]))]
        elif not has_joint[body]:  # a root without joints is free, as every body of a scene without joints
            specs = [(None, JointSpec(name=f"{names[body]}_free", kind="free", child=body, parent=-1, axis=None,
                                      anchor=None, limited=False, range=np.zeros(2), ref=0.0, stiffness=0.0,
                                      springref=0.0, damping=0.0, armature=0.0, frictionloss=0.0))]
        mine = []
        for given, spec in specs:
            j = len(kinds)
            if given is not None:
                joint_of_spec[given] = j
            mine.append(j)
            kinds.append(spec.kind)
            joint_body.append(body)
            joint_names.append(spec.name)
            qpos_adr.append(nq)
            dof_adr.append(nv)
            width_q, width_v = JOINT_WIDTHS[spec.kind]
            nq, nv = nq + width_q, nv + width_v
            # Written in the frame the joint turns, at the built pose: the body's own there, as every
            # displacement is zero; a planar root's coordinates are the world's (its frame starts at the origin).
            rotation_t = np.eye(3) if body in planar_roots else rotations[body].T
            anchor = origins[body] if spec.anchor is None or body in planar_roots else spec.anchor
            arrays["joint_pos"].append(rotation_t @ (anchor - origins[body]))
            axis = np.zeros(3) if spec.axis is None else spec.axis / np.linalg.norm(spec.axis)
            arrays["joint_axis"].append(rotation_t @ axis)
            arrays["joint_ref"].append(spec.ref)
            arrays["joint_range"].append(spec.range)
            arrays["joint_stiffness"].append(spec.stiffness)
            arrays["joint_springref"].append(spec.springref)
            limited.append(bool(spec.limited))
            for key, value in (("joint_damping", spec.damping), ("joint_armature", spec.armature),
                               ("joint_frictionloss", spec.frictionloss)):
                dof_arrays[key] += [value] * width_v
            if body in planar_roots:
                qpos0.append(origins[body][0] if spec.axis[0] else origins[body][1] if spec.axis[1]
                             else 2.0 * np.arctan2(quats[body][3], quats[body][0]))
            elif spec.kind == "free":
                qpos0 += list(origins[body]) + list(quats[body])
            elif spec.kind == "ball":
                qpos0 += [1.0, 0.0, 0.0, 0.0]
            else:
                qpos0.append(spec.ref)
        body_joints.append(tuple(mine))

    parent_offset, parent_rotation = [], []
    for body in range(n):
        if body in planar_roots:
            parent_offset.append(np.zeros(3))
            parent_rotation.append(np.array([1.0, 0.0, 0.0, 0.0]))
        elif parent[body] < 0:
            parent_offset.append(origins[body])
            parent_rotation.append(quats[body])
        else:
            p = parent[body]
            parent_offset.append(rotations[p].T @ (origins[body] - origins[p]))
            parent_rotation.append(_multiply(_conjugate(quats[p]), quats[body]))

    equality_kind, equality_bodies = [], []
    eq = {key: [] for key in ("equality_anchor_a", "equality_anchor_b", "equality_rotation")}
    for index, spec in enumerate(equalities):
        a, b = spec.body_a, spec.body_b
        equality_kind.append(spec.kind)
        equality_bodies.append((a, b))
        point = spec.anchor if spec.kind == "connect" else origins[b] if b >= 0 else np.zeros(3)
        eq["equality_anchor_a"].append(rotations[a].T @ (point - origins[a]))
        eq["equality_anchor_b"].append(point if b < 0 else rotations[b].T @ (point - origins[b]))
        quat_b = quats[b] if b >= 0 else np.array([1.0, 0.0, 0.0, 0.0])
        eq["equality_rotation"].append(_multiply(_conjugate(quats[a]), quat_b))

    actuator_joint, act = [], {key: [] for key in ("actuator_gear", "actuator_gain", "actuator_bias",
                                                   "ctrl_range", "force_range")}
    for index, spec in enumerate(actuators):
        label = f"actuator {index} ({spec.name!r})"
        if spec.joint not in joint_of_spec:
            raise ValueError(f"{label}: field 'joint' must be the index of a hinge or slide joint "
                             f"(0..{len(joints) - 1}), got {spec.joint!r}")
        j = joint_of_spec[spec.joint]
        if kinds[j] not in ("hinge", "slide"):
            raise ValueError(f"{label}: field 'joint' names a {kinds[j]} joint ({joint_names[j]!r}); "
                             "actuators drive hinges and slides")
        actuator_joint.append(j)
        act["actuator_gear"].append(spec.gear)
        act["actuator_gain"].append(spec.gain)
        act["actuator_bias"].append(spec.bias)
        act["ctrl_range"].append(spec.ctrl_range if spec.ctrl_range is not None else np.zeros(2))
        act["force_range"].append(spec.force_range if spec.force_range is not None else np.zeros(2))

    frictionloss = np.asarray(dof_arrays["joint_frictionloss"], float)
    tree = JointTree(
        parent=tuple(parent), order=tuple(order), body_joints=tuple(body_joints), joint_kind=tuple(kinds),
        joint_body=tuple(joint_body), joint_names=tuple(joint_names), qpos_adr=tuple(qpos_adr),
        dof_adr=tuple(dof_adr), nq=nq, nv=nv, limited=tuple(limited),
        friction_dofs=tuple(int(d) for d in np.flatnonzero(frictionloss > 0.0)), joint_friction=joint_friction,
        actuator_joint=tuple(actuator_joint), actuator_names=tuple(spec.name for spec in actuators),
        ctrl_limited=tuple(spec.ctrl_range is not None for spec in actuators),
        force_limited=tuple(spec.force_range is not None for spec in actuators),
        equality_kind=tuple(equality_kind), equality_bodies=tuple(equality_bodies))
    shapes = {"joint_pos": (0, 3), "joint_axis": (0, 3), "joint_range": (0, 2), "equality_anchor_a": (0, 3),
              "equality_anchor_b": (0, 3), "equality_rotation": (0, 4), "actuator_bias": (0, 3),
              "ctrl_range": (0, 2), "force_range": (0, 2)}
    out = {}
    for key, values in {**arrays, **dof_arrays, **eq, **act}.items():
        out[key] = np.asarray(values, float).reshape(shapes.get(key, (0,)) if not values else np.shape(values))
    out["parent_offset"] = np.asarray(parent_offset, float)
    out["parent_rotation"] = np.asarray(parent_rotation, float)
    free_roots = {body for body in range(n) if body in planar_roots
                  or (body_joints[body] and kinds[body_joints[body][0]] == "free")}
    return tree, out, np.asarray(qpos0, float), free_roots


def collision_filter(tree: JointTree):
    """Which bodies do not collide, by MuJoCo's rule: ((min, max) body pairs, bodies fixed to the world).

    Bodies welded together (a fixed joint, or both fixed to the world) never
    collide; a body and its parent do not either, unless the parent is fixed
    to the world; bodies fixed to the world do not touch the planes. Weld
    groups stand for their members: w(b) is b for a body with coordinates,
    else its parent's group (the world, -1, at the top).

    Returns:
        (excluded pairs, static bodies), two frozensets.
    """
    n = len(tree.parent)
    group = [0] * n
    for body in tree.order:
        parent = tree.parent[body]
        group[body] = body if tree.body_joints[body] else (group[parent] if parent >= 0 else -1)
    parent_group = [group[tree.parent[g]] if g >= 0 and tree.parent[g] >= 0 else -1 for g in group]
    excluded = set()
    for a in range(n):
        for b in range(a + 1, n):
            wa, wb = group[a], group[b]
            if wa == wb or (wa >= 0 and wb >= 0 and (wa == parent_group[b] or wb == parent_group[a])):
                excluded.add((a, b))
    return frozenset(excluded), frozenset(b for b in range(n) if group[b] < 0)
