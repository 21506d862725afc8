"""Import of a MuJoCo MJCF subset: planes, and free bodies with at most one sphere, box or capsule.

:func:`scene_from_mjcf` (and :func:`jaxrb.load_scene` on a ``.xml`` or
``.mjcf`` file) reads the subset of MuJoCo's XML that maps onto jaxrb without
changing its meaning, and returns a :class:`~jaxrb.files.common.SceneFile`
as the JSON reader (:mod:`jaxrb.files.scenefile`) does. The file is treated as
data: it is parsed with :mod:`xml.etree.ElementTree` (document type
declarations and entities are refused) and nothing in it is imported,
evaluated or executed. What is read:

* ``<option timestep gravity integrator>``: ``timestep`` (default 0.002 s,
  as MuJoCo) becomes the build ``dt``. jaxrb always runs its own
  ``semi_implicit`` integrator with ``impulse`` contact, which is the closest
  match to MuJoCo's default semi-implicit ``Euler`` with soft constraints;
  another ``integrator`` is recorded as a warning. Substeps are chosen so
  that each substep is at most 1 ms (``substeps = ceil(timestep / 1 ms)``,
  so 2 at MuJoCo's default 2 ms): contacts then resolve at
  ``0.25·substeps/dt`` >= 250 Hz, stiff enough that resting bodies sink by
  micrometres (MuJoCo's own soft contacts sink by about 0.1-1 mm), while a
  2 ms MuJoCo model still costs only two substeps per step.
* ``<compiler angle eulerseq inertiafromgeom>``: angles in degrees unless
  ``angle="radian"`` (as MuJoCo); ``eulerseq`` lowercase letters are axes that
  move with the frame, uppercase fixed axes (MuJoCo's rule; default ``xyz``).
* ``<worldbody>``: ``<geom type="plane">`` becomes a static plane whose
  normal is the geom's z axis; each child ``<body>`` with a free joint
  (``<freejoint/>`` or ``<joint type="free"/>``) becomes a dynamic body with
  at most one geom of type ``sphere``, ``box`` or ``capsule`` (MuJoCo sizes:
  sphere radius; box half sizes; capsule radius and half-length, or radius
  and ``fromto``). The geom's pose inside its body is folded into the jaxrb
  body's pose, whose frame is the shape's frame. Mass comes from
  ``<inertial>`` (whose centre of mass must be the geom's centre: jaxrb keeps
  a primitive's centre of mass at its centre), else the geom's ``mass``,
  else its ``density`` (default 1000 kg/m³, as MuJoCo).
* ``friction``: the first (sliding) coefficient, default 1 as in MuJoCo.
  MuJoCo combines two geoms' friction with ``max``, jaxrb with
  ``sqrt(product)``; a warning lists the pairs where the two differ.
* ``contype``/``conaffinity``: mapped to jaxrb's collision category and mask
  when they are equal on every geom (then MuJoCo's "either way" rule and
  jaxrb's "both ways" rule agree); otherwise an error.

Attributes that only tune MuJoCo's constraint solver or its rendering
(``solref``, ``solimp``, ``margin``, ``condim``, ``rgba``, ...) and elements
that do not change the dynamics (``visual``, ``asset``, ``sensor``, lights,
cameras, sites, ...) are skipped and listed in the result's
:attr:`~jaxrb.files.common.SceneFile.warnings`. Everything else (hinge or
other joints, bodies without a free joint, nested bodies, several geoms on
one body, other geom types, actuators, tendons, equality constraints,
default classes, includes, ...) is a ``ValueError`` naming the element and
attribute: nothing is silently misread.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ElementTree
from typing import Optional

import numpy as np

from jaxrb.scene import Scene
from jaxrb.files.common import SceneFile
from jaxrb.model.shapes import Box, Capsule, Sphere

DEFAULT_TIMESTEP = 0.002
DEFAULT_FRICTION = 1.0
MAX_SUBSTEP = 1e-3

# Attributes that only tune MuJoCo's solver or rendering: skipped with a warning.
_GEOM_HARMLESS = ("solref", "solimp", "solmix", "margin", "gap", "priority", "rgba",
                  "material", "group", "user", "fluidshape", "fluidcoef")
_JOINT_HARMLESS = ("group", "pos", "axis", "ref", "springref", "limited", "range", "margin",
                   "solreflimit", "solimplimit", "solreffriction", "solimpfriction", "user",
                   "actuatorfrclimited", "actuatorfrcrange", "actuatorgravcomp")
_OPTION_HARMLESS = ("cone", "impratio", "tolerance", "ls_tolerance", "noslip_iterations",
                    "noslip_tolerance", "ccd_iterations", "ccd_tolerance", "iterations",
                    "ls_iterations", "solver", "jacobian", "o_margin", "o_solref", "o_solimp",
                    "o_friction", "sdf_iterations", "sdf_initpoints", "apirate", "magnetic",
                    "actuatorgroupdisable", "timestep", "gravity", "integrator")
_COMPILER_HARMLESS = ("autolimits", "meshdir", "texturedir", "assetdir", "strippath",
                      "discardvisual", "fitaabb", "usethread", "inertiagrouprange", "alignfree",
                      "saveinertial", "convexhull", "exactmeshinertia", "angle", "eulerseq",
                      "inertiafromgeom")
_IGNORED_ELEMENTS = ("visual", "asset", "statistic", "size", "sensor", "keyframe", "custom")
_IGNORED_IN_BODY = ("site", "camera", "light")
_ORIENTATIONS = ("quat", "axisangle", "euler", "xyaxes", "zaxis")


class _Mjcf:
    """One MJCF document being read; collects warnings and formats errors."""

    def __init__(self, source: str):
        self.source = source
        self.warnings: list[str] = []
        self.angle_scale = math.pi / 180.0
        self.eulerseq = "xyz"
        self.inertia_from_geom = "auto"

    # ---- errors and attributes ----------------------------------------- #

    def fail(self, where: str, message: str):
        raise ValueError(f"{self.source}: {where}: {message}")

    def warn(self, where: str, message: str):
        self.warnings.append(f"{where}: {message}")

    @staticmethod
    def label(element, parent: str = "") -> str:
        name = element.get("name")
        own = f"<{element.tag}{f' name={name!r}' if name else ''}>"
        return f"{parent} {own}".strip() if parent else own

    def check_attributes(self, element, where, supported, harmless=()):
        skipped = []
        for attribute in element.attrib:
            if attribute in supported:
                continue
            if attribute in harmless:
                skipped.append(attribute)
                continue
            self.fail(where, f"attribute {attribute!r} is not supported by the MJCF importer "
                      f"(supported: {', '.join(supported) or 'none'})")
        if skipped:
            self.warn(where, "ignored " + ", ".join(f"{a}={element.get(a)!r}" for a in skipped)
                      + " (MuJoCo solver, rendering or compiler settings jaxrb does not use)")

    def numbers(self, element, where, attribute, count=None, minimum=None, maximum=None, default=None):
        text = element.get(attribute)
        if text is None:
            return default
        try:
            values = [float(item) for item in text.split()]
        except ValueError:
            self.fail(where, f"attribute {attribute!r}: expected numbers, got {text!r}")
        if not all(math.isfinite(value) for value in values):
            self.fail(where, f"attribute {attribute!r}: expected finite numbers, got {text!r}")
        if count is not None and len(values) != count:
            self.fail(where, f"attribute {attribute!r}: expected {count} numbers, got {len(values)} ({text!r})")
        if minimum is not None and len(values) < minimum:
            self.fail(where, f"attribute {attribute!r}: expected at least {minimum} numbers, "
                      f"got {len(values)} ({text!r})")
        if maximum is not None and len(values) > maximum:
            self.fail(where, f"attribute {attribute!r}: expected at most {maximum} numbers, "
                      f"got {len(values)} ({text!r})")
        return values

    def number(self, element, where, attribute, default=None):
        values = self.numbers(element, where, attribute, count=1)
        return default if values is None else values[0]

    def positive(self, where, attribute, value):
        if not value > 0.0:
            self.fail(where, f"attribute {attribute!r}: must be positive, got {value}")
        return value

    def orientation(self, element, where):
        """The quaternion (w, x, y, z) of an element's orientation attributes (identity if none)."""
        given = [name for name in _ORIENTATIONS if name in element.attrib]
        if len(given) > 1:
            self.fail(where, f"attributes {', '.join(map(repr, given))}: give at most one orientation")
        if not given:
            return np.array([1.0, 0.0, 0.0, 0.0])
        kind = given[0]
        if kind == "quat":
            quat = np.array(self.numbers(element, where, "quat", count=4))
            return self.unit(where, "quat", quat)
        if kind == "axisangle":
            values = self.numbers(element, where, "axisangle", count=4)
            axis = self.unit(where, "axisangle", np.array(values[:3]))
            half = 0.5 * values[3] * self.angle_scale
            return np.concatenate([[math.cos(half)], math.sin(half) * axis])
        if kind == "euler":
            angles = np.array(self.numbers(element, where, "euler", count=3)) * self.angle_scale
            quat = np.array([1.0, 0.0, 0.0, 0.0])
            for letter, angle in zip(self.eulerseq, angles):
                axis = np.eye(3)["xyz".index(letter.lower())]
                turn = np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * axis])
                # Lowercase: about the moving (rotated) axis, so it multiplies on the right;
                # uppercase: about the fixed axis, so it multiplies on the left.
                quat = _quat_multiply(quat, turn) if letter.islower() else _quat_multiply(turn, quat)
            return quat
        if kind == "xyaxes":
            values = np.array(self.numbers(element, where, "xyaxes", count=6))
            x_axis = self.unit(where, "xyaxes", values[:3])
            y_axis = values[3:] - (values[3:] @ x_axis) * x_axis
            y_axis = self.unit(where, "xyaxes", y_axis)
            return _matrix_to_quat(np.column_stack([x_axis, y_axis, np.cross(x_axis, y_axis)]))
        z_axis = self.unit(where, "zaxis", np.array(self.numbers(element, where, "zaxis", count=3)))
        return _quat_between_z_and(z_axis)

    def unit(self, where, attribute, vector):
        norm = float(np.linalg.norm(vector))
        if norm < 1e-12:
            self.fail(where, f"attribute {attribute!r}: must be a non-zero vector")
        return vector / norm

    def friction(self, element, where):
        values = self.numbers(element, where, "friction", minimum=1, maximum=3)
        if values is None:
            return DEFAULT_FRICTION
        if values[0] < 0.0:
            self.fail(where, f"attribute 'friction': must be >= 0, got {values[0]}")
        return values[0]

    def condim(self, element, where):
        condim = element.get("condim", "3")
        if condim == "3":
            return
        if condim not in ("1", "4", "6"):
            self.fail(where, f"attribute 'condim': expected 1, 3, 4 or 6, got {condim!r}")
        self.warn(where, f"condim={condim!r} ignored: jaxrb contacts always have sliding friction "
                  "and nothing else (MuJoCo's condim 3)"
                  + ("; MuJoCo's condim 1 is frictionless" if condim == "1" else
                     ", no torsional or rolling friction"))

    def collision_bits(self, element, where):
        contype = element.get("contype", "1")
        conaffinity = element.get("conaffinity", "1")
        try:
            bits = int(contype), int(conaffinity)
        except ValueError:
            self.fail(where, f"attributes 'contype'/'conaffinity': expected integers, got "
                      f"{contype!r}, {conaffinity!r}")
        if bits[0] != bits[1] or not 0 <= bits[0] < 2 ** 32:
            self.fail(where, f"attributes 'contype'={contype!r}, 'conaffinity'={conaffinity!r}: only "
                      "equal values are supported (then MuJoCo's rule, contype_A & conaffinity_B or "
                      "contype_B & conaffinity_A, equals jaxrb's category/mask rule)")
        return bits[0]

    # ---- document -------------------------------------------------------- #

    def read(self, text: str) -> SceneFile:
        if re.search(r"<!(DOCTYPE|ENTITY)", text, re.I):
            self.fail("document", "DOCTYPE and ENTITY declarations are not supported")
        try:
            root = ElementTree.fromstring(text)
        except ElementTree.ParseError as error:
            self.fail("document", f"not well-formed XML: {error}")
        if root.tag != "mujoco":
            self.fail(f"<{root.tag}>", "the root element must be <mujoco>")
        self.check_attributes(root, "<mujoco>", ("model",))

        for element in root:
            if element.tag == "compiler":
                self.compiler(element)
        timestep, gravity = DEFAULT_TIMESTEP, (0.0, 0.0, -9.81)
        for element in root:
            if element.tag == "option":
                timestep, gravity = self.option(element, timestep, gravity)
        scene = Scene(dim=3, gravity=gravity)
        worldbodies = 0
        for element in root:
            tag = element.tag
            if tag in ("compiler", "option"):
                continue
            if tag == "worldbody":
                worldbodies += 1
                self.worldbody(element, scene)
            elif tag in _IGNORED_ELEMENTS:
                self.warn(f"<{tag}>", "element ignored (it does not change the dynamics)")
            elif tag in ("default", "include", "actuator", "tendon", "equality", "contact",
                         "deformable", "extension", "flex"):
                self.fail(f"<{tag}>", f"element <{tag}> is not supported by the MJCF importer")
            else:
                self.fail(f"<{tag}>", f"unknown or unsupported element <{tag}>")
        if not worldbodies:
            self.fail("<mujoco>", "no <worldbody> element")
        self.friction_warnings(scene)
        substeps = max(1, math.ceil(timestep / MAX_SUBSTEP - 1e-9))
        build = {"dt": timestep, "integrator": "semi_implicit", "contact": "impulse",
                 "substeps": substeps}
        return SceneFile(scene=scene, build_options=build, warnings=self.warnings, source=self.source)

    def compiler(self, element):
        where = "<compiler>"
        self.check_attributes(element, where, ("angle", "eulerseq", "inertiafromgeom"),
                              tuple(a for a in _COMPILER_HARMLESS if a not in
                                    ("angle", "eulerseq", "inertiafromgeom")))
        angle = element.get("angle", "degree")
        if angle not in ("degree", "radian"):
            self.fail(where, f"attribute 'angle': expected 'degree' or 'radian', got {angle!r}")
        self.angle_scale = math.pi / 180.0 if angle == "degree" else 1.0
        sequence = element.get("eulerseq", self.eulerseq)
        if len(sequence) != 3 or any(letter not in "xyzXYZ" for letter in sequence):
            self.fail(where, f"attribute 'eulerseq': expected 3 letters from xyzXYZ, got {sequence!r}")
        self.eulerseq = sequence
        inertia = element.get("inertiafromgeom", self.inertia_from_geom)
        if inertia not in ("auto", "true", "false"):
            self.fail(where, f"attribute 'inertiafromgeom': expected 'auto', 'true' or 'false', "
                      f"got {inertia!r}")
        self.inertia_from_geom = inertia

    def option(self, element, timestep, gravity):
        where = "<option>"
        for attribute in ("density", "viscosity", "wind"):
            values = self.numbers(element, where, attribute)
            if values is not None and any(value != 0.0 for value in values):
                self.fail(where, f"attribute {attribute!r}: fluid forces are not supported (must be 0)")
        self.check_attributes(element, where, ("timestep", "gravity", "integrator", "density",
                                               "viscosity", "wind"),
                              tuple(a for a in _OPTION_HARMLESS
                                    if a not in ("timestep", "gravity", "integrator")))
        timestep = self.positive(where, "timestep", self.number(element, where, "timestep", timestep))
        gravity = self.numbers(element, where, "gravity", count=3, default=gravity)
        integrator = element.get("integrator", "Euler")
        if integrator not in ("Euler", "RK4", "implicit", "implicitfast"):
            self.fail(where, f"attribute 'integrator': unknown value {integrator!r}")
        if integrator != "Euler":
            self.warn(where, f"integrator={integrator!r} ignored: jaxrb integrates with its "
                      "semi-implicit Euler ('semi_implicit') and impulse contact")
        for child in element:
            self.fail(f"{where} <{child.tag}>", f"element <{child.tag}> is not supported "
                      "(it changes which forces and constraints MuJoCo applies)")
        return timestep, gravity

    def worldbody(self, element, scene):
        where = "<worldbody>"
        self.check_attributes(element, where, ())
        for child in element:
            if child.tag == "geom":
                self.plane(child, scene, self.label(child, where))
            elif child.tag == "body":
                self.body(child, scene, self.label(child, where))
            elif child.tag in _IGNORED_IN_BODY:
                self.warn(self.label(child, where), "element ignored (it does not change the dynamics)")
            else:
                self.fail(self.label(child, where), f"element <{child.tag}> is not supported in "
                          "<worldbody> (supported: <geom type='plane'>, <body>)")

    def plane(self, element, scene, where):
        kind = element.get("type", "sphere")
        if kind != "plane":
            self.fail(where, f"attribute 'type'={kind!r}: static geoms in <worldbody> must be planes "
                      "(jaxrb has no static bodies); put the geom in a <body> with a <freejoint/>")
        self.check_attributes(element, where, ("name", "type", "size", "pos", "friction", "contype",
                                               "conaffinity", "condim") + _ORIENTATIONS,
                              _GEOM_HARMLESS + ("mass", "density"))
        self.condim(element, where)
        pos = np.array(self.numbers(element, where, "pos", count=3, default=[0.0, 0.0, 0.0]))
        normal = _rotation(self.orientation(element, where))[:, 2]
        bits = self.collision_bits(element, where)
        scene.add_plane(normal=normal, offset=float(normal @ pos), friction=self.friction(element, where),
                        collision_category=bits, collision_mask=bits)

    def body(self, element, scene, where):
        self.check_attributes(element, where, ("name", "pos") + _ORIENTATIONS, ("user",))
        body_pos = np.array(self.numbers(element, where, "pos", count=3, default=[0.0, 0.0, 0.0]))
        body_quat = self.orientation(element, where)
        joints, geoms, inertials = [], [], []
        for child in element:
            label = self.label(child, where)
            if child.tag in ("freejoint", "joint"):
                joints.append((child, label))
            elif child.tag == "geom":
                geoms.append((child, label))
            elif child.tag == "inertial":
                inertials.append((child, label))
            elif child.tag in _IGNORED_IN_BODY:
                self.warn(label, "element ignored (it does not change the dynamics)")
            elif child.tag == "body":
                self.fail(label, "nested bodies are not supported (jaxrb has free bodies only, "
                          "no joints between bodies)")
            else:
                self.fail(label, f"element <{child.tag}> is not supported in a <body>")
        if not joints:
            self.fail(where, "a body without a free joint is welded to its parent; jaxrb supports "
                      "only free bodies: add <freejoint/>")
        if len(joints) > 1:
            self.fail(joints[1][1], "a body may have only one joint, a free joint")
        self.joint(*joints[0])
        if len(geoms) > 1:
            self.fail(geoms[1][1], f"a body may have at most one geom in jaxrb, this one has {len(geoms)}")
        if len(inertials) > 1:
            self.fail(inertials[1][1], "a body may have only one <inertial>")

        name = element.get("name")
        shape, geom_mass, geom_density = None, None, None
        geom_pos, geom_quat = np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])
        friction, bits = DEFAULT_FRICTION, 1
        if geoms:
            geom, label = geoms[0]
            shape, geom_pos, geom_quat = self.geom(geom, label)
            geom_mass = self.number(geom, label, "mass")
            geom_density = self.number(geom, label, "density")
            if geom_mass is not None:
                self.positive(label, "mass", geom_mass)
            if geom_density is not None:
                self.positive(label, "density", geom_density)
            friction, bits = self.friction(geom, label), self.collision_bits(geom, label)
            name = name or geom.get("name")

        use_inertial = bool(inertials) and not (geoms and self.inertia_from_geom == "true")
        if inertials and not use_inertial:
            self.warn(inertials[0][1], "ignored: compiler inertiafromgeom='true' takes mass and "
                      "inertia from the geom")
        if not use_inertial and not geoms:
            self.fail(where, "a body without a geom needs an <inertial> element")
        if not use_inertial and self.inertia_from_geom == "false":
            self.fail(where, "compiler inertiafromgeom='false' needs an <inertial> element in each body")

        mass = density = inertia = None
        frame_pos, frame_quat = geom_pos, geom_quat
        if use_inertial:
            inertial, label = inertials[0]
            mass, inertia_pos, inertia_body = self.inertial(inertial, label)
            if geoms:
                scale = max(1.0, float(np.max(np.abs(geom_pos))))
                if np.max(np.abs(inertia_pos - geom_pos)) > 1e-9 * scale:
                    self.fail(label, f"attribute 'pos' {inertia_pos.tolist()}: the centre of mass must be "
                              f"the geom's centre {geom_pos.tolist()} (jaxrb keeps a primitive's centre "
                              "of mass at its centre)")
                rotation = _rotation(geom_quat)
                inertia = rotation.T @ inertia_body @ rotation
            else:
                frame_pos, frame_quat = inertia_pos, np.array([1.0, 0.0, 0.0, 0.0])
                inertia = inertia_body
            if geom_mass is not None or geom_density is not None:
                self.warn(geoms[0][1], "mass/density ignored: the body's <inertial> gives its mass")
        elif geom_mass is not None:
            mass = geom_mass
            if geom_density is not None:
                self.warn(geoms[0][1], "density ignored: 'mass' is given (as MuJoCo does)")
        else:
            density = 1000.0 if geom_density is None else geom_density

        pos = body_pos + _rotation(body_quat) @ frame_pos
        quat = _quat_multiply(body_quat, frame_quat)
        try:
            scene.add_body(shape, mass=mass, density=density, inertia=inertia, pos=pos, quat=quat,
                           friction=friction, collision_category=bits, collision_mask=bits, name=name)
        except ValueError as error:
            self.fail(where, str(error))

    def joint(self, element, where):
        if element.tag == "freejoint":
            self.check_attributes(element, where, ("name",), ("group", "align"))
            return
        kind = element.get("type", "hinge")
        if kind != "free":
            self.fail(where, f"attribute 'type'={kind!r}: only free joints are supported "
                      "(jaxrb has no joint constraints)")
        for attribute in ("damping", "stiffness", "armature", "frictionloss"):
            value = self.number(element, where, attribute, 0.0)
            if value != 0.0:
                self.fail(where, f"attribute {attribute!r}={value}: joint {attribute} is not supported")
        self.check_attributes(element, where, ("name", "type", "damping", "stiffness", "armature",
                                               "frictionloss"), _JOINT_HARMLESS)

    def geom(self, element, where):
        """Shape, position (3,) and quaternion (4,) of a body's geom in the body frame."""
        kind = element.get("type", "sphere")
        if kind not in ("sphere", "box", "capsule"):
            self.fail(where, f"attribute 'type'={kind!r}: geom type not supported in a body "
                      "(supported: sphere, box, capsule)")
        self.check_attributes(element, where, ("name", "type", "size", "pos", "fromto", "mass",
                                               "density", "friction", "contype", "conaffinity",
                                               "condim") + _ORIENTATIONS, _GEOM_HARMLESS)
        self.condim(element, where)
        size_count = {"sphere": 1, "box": 3, "capsule": 1 if "fromto" in element.attrib else 2}[kind]
        size = self.numbers(element, where, "size", minimum=size_count, maximum=3)
        if size is None:
            self.fail(where, f"attribute 'size' is required for a {kind} geom")
        for index in range(size_count):
            self.positive(where, "size", size[index])
        pos = np.array(self.numbers(element, where, "pos", count=3, default=[0.0, 0.0, 0.0]))
        quat = self.orientation(element, where)
        if "fromto" in element.attrib:
            if kind != "capsule":
                self.fail(where, f"attribute 'fromto': supported for capsules only, not {kind}")
            given = [a for a in ("pos",) + _ORIENTATIONS if a in element.attrib]
            if given:
                self.fail(where, f"attribute 'fromto' together with {', '.join(map(repr, given))}: "
                          "give either fromto or pos/orientation")
            ends = np.array(self.numbers(element, where, "fromto", count=6))
            axis = ends[3:] - ends[:3]
            length = float(np.linalg.norm(axis))
            if length < 1e-12:
                self.fail(where, "attribute 'fromto': the two ends coincide")
            return Capsule(radius=size[0], half_length=0.5 * length), 0.5 * (ends[:3] + ends[3:]), \
                _quat_between_z_and(axis / length)
        if kind == "sphere":
            return Sphere(radius=size[0]), pos, quat
        if kind == "box":
            return Box(half_extents=tuple(size[:3])), pos, quat
        return Capsule(radius=size[0], half_length=size[1]), pos, quat

    def inertial(self, element, where):
        """Mass, centre of mass (3,) and inertia (3, 3) about it in the body frame."""
        self.check_attributes(element, where, ("pos", "mass", "diaginertia", "fullinertia")
                              + _ORIENTATIONS)
        mass = self.number(element, where, "mass")
        if mass is None:
            self.fail(where, "attribute 'mass' is required")
        self.positive(where, "mass", mass)
        pos = np.array(self.numbers(element, where, "pos", count=3, default=[0.0, 0.0, 0.0]))
        diagonal = self.numbers(element, where, "diaginertia", count=3)
        full = self.numbers(element, where, "fullinertia", count=6)
        if (diagonal is None) == (full is None):
            self.fail(where, "give exactly one of attributes 'diaginertia' and 'fullinertia'")
        if full is not None:
            if any(a in element.attrib for a in _ORIENTATIONS):
                self.fail(where, "attribute 'fullinertia' cannot be combined with an orientation")
            xx, yy, zz, xy, xz, yz = full
            return mass, pos, np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
        rotation = _rotation(self.orientation(element, where))
        return mass, pos, rotation @ np.diag(diagonal) @ rotation.T

    def friction_warnings(self, scene):
        bodies = [(repr(body.name), body.friction) for body in scene._bodies]
        planes = [(f"plane {index}", plane.friction) for index, plane in enumerate(scene._planes)]
        pairs = [(a, b) for index, a in enumerate(bodies) for b in bodies[:index]] + \
                [(a, b) for a in bodies for b in planes]
        differ = [f"{a[0]} ({a[1]:g}) with {b[0]} ({b[1]:g}): MuJoCo {max(a[1], b[1]):g}, "
                  f"jaxrb {math.sqrt(a[1] * b[1]):.4g}"
                  for a, b in pairs if abs(max(a[1], b[1]) - math.sqrt(a[1] * b[1])) > 1e-12]
        if differ:
            shown = "; ".join(differ[:5]) + (f"; and {len(differ) - 5} more" if len(differ) > 5 else "")
            self.warn("friction", "MuJoCo combines a pair's friction with max(), jaxrb with "
                      f"sqrt(product), so these pairs differ: {shown}")


def scene_from_mjcf(text: str, source: Optional[str] = None) -> SceneFile:
    """Read MuJoCo MJCF text (the subset described in this module's docstring).

    Args:
        text: the XML document.
        source: name used in messages; default ``"mjcf"``.

    Returns:
        A :class:`SceneFile` with ``build_options`` ``dt`` (MuJoCo's timestep),
        ``integrator="semi_implicit"``, ``contact="impulse"`` and ``substeps``
        (each substep <= 1 ms), and ``warnings`` listing what was ignored.

    Raises:
        ValueError: naming the element and attribute for anything the importer
            cannot represent faithfully.
    """
    return _Mjcf(source or "mjcf").read(text)


# --------------------------------------------------------------------------- #
# Quaternion helpers (w, x, y, z), host-side NumPy
# --------------------------------------------------------------------------- #

def _quat_multiply(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw])


def _rotation(quat):
    w, x, y, z = np.asarray(quat, dtype=np.float64) / np.linalg.norm(quat)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _matrix_to_quat(matrix):
    """Unit quaternion of a rotation matrix (Shepperd: divide by the largest component)."""
    m = matrix
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    candidates = [trace, m[0, 0], m[1, 1], m[2, 2]]
    largest = int(np.argmax(candidates))
    if largest == 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        quat = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif largest == 1:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        quat = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif largest == 2:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        quat = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        quat = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    quat = np.array(quat)
    return quat / np.linalg.norm(quat)


def _quat_between_z_and(direction):
    """The smallest rotation taking +z to the unit vector ``direction`` (3,)."""
    z = np.array([0.0, 0.0, 1.0])
    cosine = float(z @ direction)
    if cosine < -1.0 + 1e-12:
        return np.array([0.0, 1.0, 0.0, 0.0])  # half turn about x
    quat = np.concatenate([[1.0 + cosine], np.cross(z, direction)])
    return quat / np.linalg.norm(quat)
