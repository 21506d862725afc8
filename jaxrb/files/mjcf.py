"""MJCF and URDF through MuJoCo's own compiler: a compiled ``mujoco.MjModel`` turned into a Scene.

MuJoCo (the ``mujoco`` package, the ``mjcf`` extra: ``pip install jaxrb[mjcf]``)
reads the file with everything its format allows (``<default>`` classes,
``childclass``, ``<include>``, ``fromto``, frames, compiler options, URDF)
and applies its own defaults; :func:`scene_from_mjmodel` then maps the
compiled arrays onto jaxrb, so jaxrb reads what MuJoCo reads, the way Brax
and MJX do:

* bodies: every moving body (a joint on it or on an ancestor) is a jaxrb
  body with MuJoCo's mass, centre of mass (``body_ipos``) and inertia
  (``body_inertia`` turned by ``body_iquat``); its frame is MuJoCo's body
  frame (``State.quat`` = ``xquat``, ``State.pos`` = ``xipos``), its one
  colliding geom (sphere, capsule or box) placed in it at the geom's pose
  (``shape_pos``/``shape_quat``, given where the geom is off the body's frame).
  Geoms that cannot collide (``contype`` and ``conaffinity`` 0) add mass only.
  Bodies fixed to the world are not bodies: their planes become static
  planes, and a non-plane static geom that can touch a moving one is an
  error (static shapes other than planes are not in jaxrb yet).
* joints: hinge, slide and ball with their anchors, axes, ``ref``,
  ``range`` (where limited), ``stiffness``/``springref``, ``damping``,
  ``armature`` and ``frictionloss``; a moving body without joints is welded
  to its parent (:class:`~jaxrb.model.joints.Fixed`); a free joint is a body
  without parent. ``qpos``/``qvel`` then have MuJoCo's layout.
* actuators with a joint transmission and no activation dynamics
  (``motor``, ``position``, ``velocity``, ``general`` with fixed gain and
  affine bias), their gear, ``ctrlrange`` and ``forcerange``; an actuator's
  ``damping`` and ``armature`` join the joint's (times gear²), as MuJoCo does;
  a joint's ``actuatorfrcrange`` (URDF's effort limit) joins its one
  actuator's ``forcerange`` (divided by the gear), and is moot without one.
* a URDF's root link is fixed to the world, as MuJoCo fixes it;
  ``floating_base=True`` gives the world's jointless children a free joint
  before MuJoCo compiles the file.
* ``<equality>`` ``connect`` and ``weld`` between bodies (active ones).
* contact filtering as MuJoCo's: ``contype``/``conaffinity`` and
  ``<exclude>`` are applied pair by pair with
  :meth:`~jaxrb.Scene.exclude_collision`, a body and its parent by the
  joint tree's own rule. Friction is the geom's sliding coefficient; jaxrb
  mixes a pair's as √(μ_A μ_B) where MuJoCo takes the max (a warning lists
  pairs where they differ).
* ``<option>``: ``timestep`` is the build's ``dt``, ``gravity``, the
  ``integrator`` (``Euler`` -> ``semi_implicit``, ``RK4`` -> ``rk4`` where the
  scene has no contact, loop closure or exact friction, else ``midpoint``;
  the implicit ones -> ``semi_implicit``; each with a warning), and the disable flags for contact,
  gravity, limits, equality, frictionloss, springs and dampers.

What changes the dynamics and has no jaxrb meaning (tendons, activation
dynamics, muscles, other transmissions, mocap bodies, gravity compensation,
fluid forces, cylinders, ellipsoids, meshes, height fields, several
colliding geoms on one body, joint equalities) is a ``ValueError`` naming
the element. What only tunes MuJoCo's own solver (``solref``, ``solimp``,
``margin``, ``condim`` beyond 3, ...) is listed in the SceneFile's warnings,
with how jaxrb differs; lights, cameras, textures, sites and sensors are
skipped quietly.
"""

from __future__ import annotations

import math
import os
from typing import Optional

import numpy as np

from jaxrb.files.common import SceneFile
from jaxrb.model.joints import Ball, Connect, Fixed, Hinge, Slider, Weld
from jaxrb.model.shapes import Box, Capsule, Sphere
from jaxrb.physics.joints.tree import rotation_matrix
from jaxrb.scene import Scene

DEFAULT_TIMESTEP = 0.002
DEFAULT_FRICTION = 1.0
#: Longest substep (s) of an imported scene with impulse contact.
MAX_SUBSTEP = 1e-3

# mjtGeom, mjtJoint, mjtIntegrator, mjtDisableBit, mjtEq, mjtTrn values (stable in MuJoCo's API).
_PLANE, _SPHERE, _CAPSULE, _BOX = 0, 2, 3, 6
_GEOM_NAMES = {0: "plane", 1: "hfield", 2: "sphere", 3: "capsule", 4: "ellipsoid", 5: "cylinder", 6: "box",
               7: "mesh", 8: "sdf"}
_FREE, _BALL, _SLIDE, _HINGE = 0, 1, 2, 3
_DISABLE = {"equality": 1 << 1, "frictionloss": 1 << 2, "limit": 1 << 3, "contact": 1 << 4, "spring": 1 << 5,
            "damper": 1 << 6, "gravity": 1 << 7}


def _mujoco():
    try:
        import mujoco  # noqa: PLC0415  (optional: only model files need it)
    except ImportError:  # pragma: no cover - the dev extra installs it
        raise ValueError("reading MJCF or URDF needs MuJoCo's compiler: pip install 'jaxrb[mjcf]' "
                         "(the mujoco package)") from None
    return mujoco


def _name(mujoco, model, kind, index):
    found = mujoco.mj_id2name(model, kind, index)
    return found if found else f"#{index}"


class _Converter:
    """One compiled model on its way to a Scene (see the module docs)."""

    def __init__(self, mujoco, model, source, floating_base):
        self.mujoco, self.m, self.source = mujoco, model, source
        self.floating_base = floating_base
        self.warnings: list = []
        self.data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, self.data)  # the built pose: qpos0

    def fail(self, element, message):
        raise ValueError(f"{self.source}: {element}: {message}")

    def warn(self, element, message):
        warning = f"{element}: {message}"
        if warning not in self.warnings:  # a geom's margin is met once per pair it is in
            self.warnings.append(warning)

    def element(self, kind, index):
        objects = self.mujoco.mjtObj
        label = {"body": objects.mjOBJ_BODY, "joint": objects.mjOBJ_JOINT, "geom": objects.mjOBJ_GEOM,
                 "actuator": objects.mjOBJ_ACTUATOR, "equality": objects.mjOBJ_EQUALITY}[kind]
        return f"{kind} {_name(self.mujoco, self.m, label, index)!r}"

    def disabled(self, flag):
        return bool(self.m.opt.disableflags & _DISABLE[flag])

    # -- what is refused outright --------------------------------------------------------------
    def check_unsupported(self):
        m = self.m
        if m.ntendon:
            self.fail("tendon", f"the model has {m.ntendon} tendon{'s' if m.ntendon > 1 else ''}; jaxrb has none")
        if m.nmocap:
            self.fail("body", f"{m.nmocap} mocap bodies; jaxrb has no kinematic bodies yet")
        for b in range(m.nbody):
            if m.body_gravcomp[b] != 0:
                self.fail(self.element("body", b), "gravcomp (gravity compensation) is not in jaxrb")
        if m.opt.density or m.opt.viscosity:
            self.fail("option", "density/viscosity (fluid forces) are not in jaxrb")
        for j in np.flatnonzero(m.jnt_actfrclimited):
            driving = [a for a in range(m.nu) if m.actuator_trntype[a] == 0 and m.actuator_trnid[a, 0] == j]
            if len(driving) > 1:
                self.fail(self.element("joint", int(j)), "actuatorfrcrange (a clamp on the joint's summed actuator "
                          f"force) with {len(driving)} actuators on the joint is not in jaxrb; clamp each "
                          "actuator's forcerange")
            # One actuator: the clamp joins its forcerange (add_actuators); none: nothing to clamp.

    # -- bodies ----------------------------------------------------------------------------------
    def moving_bodies(self):
        """MuJoCo body ids that move (a dof on them or an ancestor), in body order; with a floating
        base, the world's direct children without dofs too (they become free bodies)."""
        m = self.m
        moving, floating = [], set()
        for b in range(1, m.nbody):
            at, moves = b, False
            while at > 0:
                if m.body_jntnum[at]:
                    moves = True
                    break
                if self.floating_base and m.body_parentid[at] == 0:
                    moves = True
                    floating.add(at)
                    break
                at = m.body_parentid[at]
            if moves:
                moving.append(b)
        return moving, floating

    def body_shape(self, b):
        """(shape, geom id) of body b's one colliding geom, or (None, None)."""
        m = self.m
        geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == b and self.collides(g)]
        if len(geoms) > 1:
            self.fail(self.element("body", b), f"has {len(geoms)} geoms that can collide "
                      f"({', '.join(self.element('geom', g) for g in geoms)}); a jaxrb body carries one shape")
        if not geoms:
            return None, None
        g = geoms[0]
        kind, size = int(m.geom_type[g]), m.geom_size[g]
        if kind == _SPHERE:
            return Sphere(radius=float(size[0])), g
        if kind == _CAPSULE:
            return Capsule(radius=float(size[0]), half_length=float(size[1])), g
        if kind == _BOX:
            return Box(half_extents=tuple(float(s) for s in size[:3])), g
        self.fail(self.element("geom", g), f"type {_GEOM_NAMES.get(kind, kind)!r} is not a jaxrb shape "
                                           "(sphere, capsule and box are; planes on the world)")

    def collides(self, g):
        """Whether geom g can touch any other geom by the bitmasks (MuJoCo's either-way rule)."""
        m = self.m
        return any(self.bitmask(g, other) for other in range(m.ngeom) if other != g)

    def bitmask(self, g1, g2):
        m = self.m
        return bool((m.geom_contype[g1] & m.geom_conaffinity[g2]) or (m.geom_contype[g2] & m.geom_conaffinity[g1]))

    # -- the conversion --------------------------------------------------------------------------
    def convert(self) -> SceneFile:
        m, d, mujoco = self.m, self.data, self.mujoco
        self.check_unsupported()
        gravity = np.zeros(3) if self.disabled("gravity") else np.array(m.opt.gravity, float)
        scene = Scene(dim=3, gravity=gravity)
        moving, floating = self.moving_bodies()
        if not moving:
            self.fail("worldbody", "no body moves (none has a joint, nor an ancestor with one); a jaxrb scene "
                                   "needs a moving body")
        index = {b: i for i, b in enumerate(moving)}
        shapes = {}
        for b in moving:
            shape, geom = self.body_shape(b)
            shapes[b] = (shape, geom)
            mass = float(m.body_mass[b])
            if mass <= 0.0:
                self.fail(self.element("body", b), "has no mass; a moving jaxrb body needs mass and inertia "
                                                   "(give it an <inertial> or a geom)")
            rotation = rotation_matrix(m.body_iquat[b])
            inertia = rotation @ np.diag(m.body_inertia[b]) @ rotation.T
            options = {}
            if geom is not None:
                options = dict(friction=float(m.geom_friction[geom][0]))
                if np.any(m.geom_pos[geom] != 0.0) or np.any(m.geom_quat[geom] != (1.0, 0.0, 0.0, 0.0)):
                    # a geom away from its body's frame (a geom at the frame, the usual free body, needs none)
                    options.update(shape_pos=np.array(m.geom_pos[geom], float),
                                   shape_quat=np.array(m.geom_quat[geom], float))
            scene.add_body(shape, mass=mass, inertia=inertia, com=np.array(m.body_ipos[b], float),
                           pos=np.array(d.xpos[b], float), quat=np.array(d.xquat[b], float),
                           name=_name(mujoco, m, mujoco.mjtObj.mjOBJ_BODY, b), **options)
        self.add_planes(scene, moving, index)
        joints = self.add_joints(scene, moving, index, floating)
        self.add_actuators(scene, joints)
        self.add_equalities(scene, index)
        self.filter_contacts(scene, moving, index, shapes)
        return SceneFile(scene=scene, build_options=self.build_options(scene), warnings=self.warnings,
                         source=self.source)

    def add_planes(self, scene, moving, index):
        m, d = self.m, self.data
        moving_set = set(moving)
        self.planes = {}
        for g in range(m.ngeom):
            if m.geom_bodyid[g] in moving_set:
                continue
            kind = int(m.geom_type[g])
            touching = [o for o in range(m.ngeom) if m.geom_bodyid[o] in moving_set and self.bitmask(g, o)]
            if not touching:
                continue  # a static geom nothing moving can touch: drawn by MuJoCo only
            if kind != _PLANE:
                self.fail(self.element("geom", g), f"a static {_GEOM_NAMES.get(kind, kind)!r} that moving geoms "
                                                   "can touch; jaxrb's static shapes are planes only for now")
            normal = np.array(d.geom_xmat[g], float).reshape(3, 3)[:, 2]
            offset = float(normal @ d.geom_xpos[g])
            self.planes[g] = scene.add_plane(normal=normal, offset=offset, friction=float(m.geom_friction[g][0]))

    def add_joints(self, scene, moving, index, floating):
        """Joints of every moving body; returns {MuJoCo joint id: jaxrb joint index}."""
        m, d = self.m, self.data
        found = {}
        no_limits, no_spring, no_damper, no_friction = (self.disabled(flag) for flag in
                                                        ("limit", "spring", "damper", "frictionloss"))
        extra_damping, extra_armature = self.actuator_joint_terms()
        for b in moving:
            parent = int(m.body_parentid[b])
            parent_index = index.get(parent)  # None: the world or a body fixed to it
            if m.body_jntnum[b] == 0:
                if b not in floating:
                    body_name = _name(self.mujoco, m, self.mujoco.mjtObj.mjOBJ_BODY, b)
                    scene.add_joint(Fixed(), index[b], parent_index, name=f"{body_name}_weld")
                continue
            for j in range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b]):
                kind = int(m.jnt_type[j])
                label = self.element("joint", j)
                if kind == _FREE:
                    if parent_index is not None or m.body_jntnum[b] > 1:
                        self.fail(label, "a free joint must be its body's only joint, on a body of the world")
                    continue  # a jaxrb body without joints and parent is free
                dof = int(m.jnt_dofadr[j])
                anchor, axis = np.array(d.xanchor[j], float), np.array(d.xaxis[j], float)
                joint_kind = {_HINGE: Hinge(axis=axis, anchor=anchor), _SLIDE: Slider(axis=axis),
                              _BALL: Ball(anchor=anchor)}[kind]
                scalar = kind in (_HINGE, _SLIDE)
                limited = bool(m.jnt_limited[j]) and not no_limits
                if limited and kind == _BALL:
                    self.fail(label, "a ball joint's range (a cone) is not in jaxrb")
                stiffness = 0.0 if no_spring else float(m.jnt_stiffness[j])
                if stiffness and not scalar:
                    self.fail(label, "stiffness on a ball joint is not in jaxrb")
                qpos = int(m.jnt_qposadr[j])
                found[j] = scene.add_joint(
                    joint_kind, index[b], parent_index,
                    range=np.array(m.jnt_range[j], float) if limited else None,
                    ref=float(m.qpos0[qpos]) if scalar else 0.0, stiffness=stiffness,
                    springref=float(m.qpos_spring[qpos]) if scalar else 0.0,
                    damping=0.0 if no_damper else float(m.dof_damping[dof]) + extra_damping.get(dof, 0.0),
                    armature=float(m.dof_armature[dof]) + extra_armature.get(dof, 0.0),
                    frictionloss=0.0 if no_friction else float(m.dof_frictionloss[dof]),
                    name=_name(self.mujoco, m, self.mujoco.mjtObj.mjOBJ_JOINT, j))
                if m.jnt_margin[j]:
                    self.warn(label, "margin (limits acting before they are reached) is not in jaxrb")
        return found

    def actuator_joint_terms(self):
        """{dof: extra damping} and {dof: extra armature} from actuators' damping and armature (× gear²)."""
        m = self.m
        damping, armature = {}, {}
        for a in range(m.nu):
            for name, table in (("actuator_damping", damping), ("actuator_armature", armature)):
                values = getattr(m, name, None)
                if values is not None and values[a] and m.actuator_trntype[a] == 0:
                    dof = int(m.jnt_dofadr[m.actuator_trnid[a, 0]])
                    table[dof] = table.get(dof, 0.0) + float(values[a]) * float(m.actuator_gear[a, 0]) ** 2
        return damping, armature

    def add_actuators(self, scene, joints):
        m = self.m
        for a in range(m.nu):
            label = self.element("actuator", a)
            if m.actuator_trntype[a] != 0:
                self.fail(label, "only joint transmissions are in jaxrb (not tendons, sites, sliders-cranks)")
            if m.actuator_gaintype[a] != 0 or m.actuator_biastype[a] not in (0, 1):
                self.fail(label, "only fixed gains and affine biases are in jaxrb (no muscles, no user types)")
            if m.actuator_dyntype[a] != 0:
                self.fail(label, "activation dynamics (dyntype, e.g. a filtered or integrating actuator) "
                                 "are not in jaxrb")
            if np.any(m.actuator_gainprm[a, 1:3]):
                self.fail(label, "gainprm beyond the first term (an affine gain) is not in jaxrb")
            joint = int(m.actuator_trnid[a, 0])
            if joint not in joints:
                self.fail(label, f"drives {self.element('joint', joint)}, which is not a hinge or slide here")
            if np.any(m.actuator_gear[a, 1:]):
                self.fail(label, "gear beyond its first component")
            bias = np.array(m.actuator_biasprm[a, :3], float) if m.actuator_biastype[a] == 1 else np.zeros(3)
            scene.add_actuator(
                joints[joint], "general", gear=float(m.actuator_gear[a, 0]), gain=float(m.actuator_gainprm[a, 0]),
                bias=bias, ctrlrange=np.array(m.actuator_ctrlrange[a], float) if m.actuator_ctrllimited[a] else None,
                forcerange=self.force_range(a, joint, label),
                name=_name(self.mujoco, m, self.mujoco.mjtObj.mjOBJ_ACTUATOR, a))

    def force_range(self, a, joint, label):
        """Actuator a's force clamp: its forcerange, and its joint's actuatorfrcrange divided by the gear
        (the joint's only actuator, check_unsupported), as MuJoCo clamps gear·force; None without either."""
        m = self.m
        low, high = (m.actuator_forcerange[a] if m.actuator_forcelimited[a] else (-np.inf, np.inf))
        gear = float(m.actuator_gear[a, 0])
        if m.jnt_actfrclimited[joint] and gear != 0.0:
            bounds = sorted(float(limit) / gear for limit in m.jnt_actfrcrange[joint])
            low, high = max(low, bounds[0]), min(high, bounds[1])
            if low > high:
                self.fail(label, "its forcerange and its joint's actuatorfrcrange leave no force")
        return None if np.isinf(low) and np.isinf(high) else np.array([low, high], float)

    def add_equalities(self, scene, index):
        m, d = self.m, self.data
        if self.disabled("equality"):
            return
        for e in range(m.neq):
            label = self.element("equality", e)
            if not m.eq_active0[e]:
                self.warn(label, "inactive at the start (eq_active0): left out")
                continue
            kind = int(m.eq_type[e])
            if kind not in (0, 1):
                self.fail(label, "only connect and weld equalities are in jaxrb (not joint or tendon couplings)")
            if int(m.eq_objtype[e]) != int(self.mujoco.mjtObj.mjOBJ_BODY):
                self.fail(label, "site-based equalities are not read yet; name the bodies (body1, body2)")
            b1, b2 = int(m.eq_obj1id[e]), int(m.eq_obj2id[e])
            if b1 not in index:
                b1, b2 = b2, b1
            if b1 not in index:
                self.fail(label, "joins two bodies fixed to the world")
            data = m.eq_data[e]
            other = index.get(b2)
            name = _name(self.mujoco, m, self.mujoco.mjtObj.mjOBJ_EQUALITY, e)
            if kind == 0:
                anchor = d.xpos[int(m.eq_obj1id[e])] + rotation_matrix(d.xquat[int(m.eq_obj1id[e])]) @ data[0:3]
                scene.add_equality(Connect(anchor=np.array(anchor, float)), index[b1], other, name=name)
            else:
                relative = self.relative_quat(int(m.eq_obj1id[e]), int(m.eq_obj2id[e]))
                if min(np.abs(relative - data[6:10]).max(), np.abs(relative + data[6:10]).max()) > 1e-6:
                    self.fail(label, "relpose differs from the bodies' pose at qpos0; jaxrb's weld keeps the "
                                     "built relative pose")
                if data[10] != 1.0:
                    self.warn(label, "torquescale is not in jaxrb (the weld's rotation is as stiff as its position)")
                scene.add_equality(Weld(), index[b1], other, name=name)
            if np.any(m.eq_solref[e] != m.eq_solref[0]) or np.any(m.eq_solimp[e] != m.eq_solimp[0]):
                self.warn(label, "solref/solimp: jaxrb's loop closures share Params.equality_hertz")

    def relative_quat(self, b1, b2):
        d = self.data
        w1, v1 = d.xquat[b1][0], -d.xquat[b1][1:]
        w2, v2 = d.xquat[b2][0], d.xquat[b2][1:]
        return np.concatenate([[w1 * w2 - v1 @ v2], w1 * v2 + w2 * v1 + np.cross(v1, v2)])

    def filter_contacts(self, scene, moving, index, shapes):
        """MuJoCo's bitmask rule and <exclude>, pair by pair (the parent rule is the joint tree's own)."""
        m = self.m
        excluded = {(int(s) >> 16, int(s) & 0xFFFF) for s in m.exclude_signature}
        warned_friction = []
        for i, a in enumerate(moving):
            geom_a = shapes[a][1]
            if geom_a is None:
                continue
            for g, plane in self.planes.items():
                if not self.bitmask(geom_a, g) or (min(a, int(m.geom_bodyid[g])), max(a, int(m.geom_bodyid[g]))) \
                        in excluded:
                    scene.exclude_collision(index[a], plane=plane)
                else:
                    self.contact_options(geom_a, g, warned_friction)
            for b in moving[i + 1:]:
                geom_b = shapes[b][1]
                if geom_b is None:
                    continue
                if not self.bitmask(geom_a, geom_b) or (min(a, b), max(a, b)) in excluded:
                    scene.exclude_collision(index[a], index[b])
                else:
                    self.contact_options(geom_a, geom_b, warned_friction)
        if warned_friction:
            shown = "; ".join(warned_friction[:5]) + (f"; and {len(warned_friction) - 5} more"
                                                      if len(warned_friction) > 5 else "")
            self.warn("friction", f"MuJoCo mixes a pair's friction with max(), jaxrb with sqrt(product): {shown}")

    def contact_options(self, g1, g2, warned_friction):
        m = self.m
        mu1, mu2 = float(m.geom_friction[g1][0]), float(m.geom_friction[g2][0])
        if abs(max(mu1, mu2) - math.sqrt(mu1 * mu2)) > 1e-12:
            warned_friction.append(f"{self.element('geom', g1)}–{self.element('geom', g2)} "
                                   f"{max(mu1, mu2):g} against {math.sqrt(mu1 * mu2):g}")
        for g in (g1, g2):
            if m.geom_margin[g] or m.geom_gap[g]:
                self.warn(self.element("geom", g), "margin/gap: jaxrb's contact margin is the build's "
                                                   "contact_margin, one for the scene")
            if m.geom_condim[g] not in (1, 3):
                self.warn(self.element("geom", g), f"condim {m.geom_condim[g]}: jaxrb has no torsional or "
                                                   "rolling friction")

    def build_options(self, scene) -> dict:
        m = self.m
        dt = float(m.opt.timestep)
        options = {"dt": dt}
        integrator = int(m.opt.integrator)
        if integrator == 1:
            options["integrator"] = "rk4"
        elif integrator != 0:
            self.warn("option", f"integrator {['Euler', 'RK4', 'implicit', 'implicitfast'][integrator]}: jaxrb "
                                "steps it with its semi-implicit Euler (MuJoCo's Euler, implicit joint damping)")
        if self.disabled("contact"):
            options["contact"] = "none"
        default_solref = np.array([0.02, 1.0])
        if np.any(np.abs(m.geom_solref - default_solref) > 1e-12) or np.any(m.opt.o_solref != default_solref):
            self.warn("solref", "MuJoCo's contact softness is not mapped: jaxrb's soft contacts take "
                                "rb.Impulse(hertz=...) (default a quarter of the substep rate)")
        return options


def _finish(found: SceneFile) -> SceneFile:
    """Substeps and integrator once the scene knows whether it can touch anything."""
    options = found.build_options
    model, _, _ = found.scene.build(dt=options["dt"], contact=options.get("contact"))
    can_touch = model.num_contacts > 0
    tree = model.joints
    if options.get("integrator") == "rk4" and (can_touch or (tree is not None and (
            tree.equality_kind or tree.friction_dofs))):
        options["integrator"] = "midpoint"
        found.warnings.append("option: integrator RK4: this scene has contact, loop closures or joint friction, "
                              "which jaxrb's rk4 does not take; it steps with jaxrb's 'midpoint' (second order in "
                              "the Coriolis terms; closer to RK4 than MuJoCo's Euler)")
    if can_touch:
        options["substeps"] = max(1, math.ceil(options["dt"] / MAX_SUBSTEP - 1e-9))
    return found


def scene_from_mjmodel(model, source: str = "mjcf", *, floating_base: bool = False) -> SceneFile:
    """Turn a compiled ``mujoco.MjModel`` into a :class:`~jaxrb.files.common.SceneFile`.

    Args:
        model: the compiled MuJoCo model.
        source: name used in messages.
        floating_base: make the world's direct children without joints free
            bodies; their 7 and 6 numbers then lead qpos and qvel. (A URDF
            compiled by MuJoCo has its root link fused into the world already:
            read the file with :func:`scene_from_path` or
            :func:`scene_from_mjcf`, which free it before compiling.)

    Returns:
        A SceneFile whose ``build_options`` hold ``dt`` (MuJoCo's timestep),
        the integrator, ``contact`` where disabled and ``substeps`` (each at
        most :data:`MAX_SUBSTEP` where anything can touch), and whose
        ``warnings`` list what was approximated or skipped.

    Raises:
        ValueError: naming the element for anything jaxrb cannot represent.
    """
    converter = _Converter(_mujoco(), model, source, floating_base)
    return _finish(converter.convert())


def _compile(mujoco, load, floating_base):
    """The compiled model from ``load(mujoco.MjSpec)`` (``from_string`` or ``from_file``); with
    ``floating_base``, the world's direct children without joints get a free joint first, so MuJoCo's
    compiler neither fuses them into the world (a URDF's ``fusestatic``) nor fixes them."""
    spec = load(mujoco.MjSpec)
    if floating_base:
        for body in spec.worldbody.bodies:
            if not body.joints:
                body.add_freejoint()
    return spec.compile()


def scene_from_mjcf(text: str, source: Optional[str] = None, *, floating_base: bool = False) -> SceneFile:
    """Read MJCF (or URDF) text through MuJoCo's compiler (see the module docs).

    Args:
        text: the XML document.
        source: name used in messages; default ``"mjcf"``.
        floating_base: give the world's direct children without joints a
            free joint before MuJoCo compiles the model (a URDF's root link is
            otherwise fixed to the world, and fused into it); their 7 and 6
            numbers then lead qpos and qvel.

    Returns:
        A :class:`SceneFile`.

    Raises:
        ValueError: MuJoCo's own compile error, or an element jaxrb cannot represent.
    """
    mujoco = _mujoco()
    source = source or "mjcf"
    try:
        model = _compile(mujoco, lambda spec: spec.from_string(text), floating_base)
    except ValueError as error:
        raise ValueError(f"{source}: MuJoCo cannot compile it: {error}") from None
    return scene_from_mjmodel(model, source)


def scene_from_path(path, *, floating_base: bool = False) -> SceneFile:
    """Read an MJCF or URDF file through MuJoCo's compiler (includes and meshes relative to it).

    Args:
        path: the file.
        floating_base: see :func:`scene_from_mjcf`.

    Returns:
        A :class:`SceneFile`.

    Raises:
        ValueError: MuJoCo's own compile error, or an element jaxrb cannot represent.
    """
    mujoco = _mujoco()
    try:
        model = _compile(mujoco, lambda spec: spec.from_file(os.fspath(path)), floating_base)
    except ValueError as error:
        raise ValueError(f"{os.fspath(path)}: MuJoCo cannot compile it: {error}") from None
    return scene_from_mjmodel(model, os.fspath(path))
