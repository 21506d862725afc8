"""Scene files: jaxrb's versioned JSON format, and :func:`load_scene` for JSON or MJCF.

A file is treated as data: JSON is read with :func:`json.load` into plain
lists, dicts, numbers and strings. Nothing in a file is imported, evaluated
or executed.

JSON format (version 2)::

    {"format": "jaxrb-scene", "version": 2, "dim": 3, "gravity": [0, 0, -9.81],
     "bodies": [{"shape": {"kind": "box", "half_extents": [0.1, 0.1, 0.1]},
                 "mass": 1.0, "pos": [0, 0, 0.5], "friction": 0.8},
                {"shape": {"kind": "capsule", "radius": 0.05, "half_length": 0.2},
                 "pos": [0, 0, 1], "com": [0, 0, -0.1], "shape_pos": [0, 0, -0.2]}],
     "planes": [{"normal": [0, 0, 1], "offset": 0.0, "friction": 0.8}],
     "joints": [{"kind": "hinge", "axis": [0, 1, 0], "anchor": [0, 0, 1], "child": 1,
                 "parent": 0, "range": [-1.5, 1.5], "damping": 0.1, "name": "elbow"}],
     "equalities": [{"kind": "connect", "anchor": [0, 0, 0.5], "body_a": 0}],
     "actuators": [{"joint": 0, "kind": "position", "kp": 20.0, "ctrlrange": [-1, 1]}],
     "exclusions": [{"body_a": 0, "body_b": 1}, {"body_a": 1, "plane": 0}],
     "build": {"dt": 0.004, "substeps": 4, "contact": "impulse", "dtype": "float32",
               "joint_friction": "exact"}}

Each list replays one method of :class:`jaxrb.Scene`, in this order, with
the entry's keys as its arguments:

* ``bodies``: :meth:`~jaxrb.Scene.add_body` (its ``shape`` is
  ``{"kind": ..., <constructor fields>}`` with kind one of ``sphere``,
  ``circle``, ``box``, ``capsule``, ``polygon``, ``point_masses``, or absent
  for a body given only mass and inertia);
* ``planes``: :meth:`~jaxrb.Scene.add_plane`;
* ``joints``: :meth:`~jaxrb.Scene.add_joint`; ``kind`` is one of ``hinge``
  (``axis``, ``anchor``), ``slide`` (``axis``), ``ball`` (``anchor``),
  ``fixed``, ``free``, the fields of :class:`~jaxrb.Hinge`,
  :class:`~jaxrb.Slider`, :class:`~jaxrb.Ball` written beside it; ``child``
  and ``parent`` are body indices (``parent`` absent or null: the world);
* ``equalities``: :meth:`~jaxrb.Scene.add_equality`; ``kind`` ``connect``
  (with ``anchor``) or ``weld``; ``body_a``, ``body_b`` body indices;
* ``actuators``: :meth:`~jaxrb.Scene.add_actuator`; ``joint`` a joint index;
* ``exclusions``: :meth:`~jaxrb.Scene.exclude_collision`; ``body_a`` with
  ``body_b`` or ``plane`` (a plane index);

and ``build`` holds keyword arguments of :meth:`jaxrb.Scene.build`
(``dtype`` as a name such as ``"float32"``, a contact model's options flat
beside ``contact``, e.g. ``"penalty_stiffness": 8000.0``). A scene remembers
the arguments of every ``add_*`` call that differ from the defaults, so
saving writes exactly what the user gave and loading replays it through the
same methods: every validation runs again and the built ``Model``,
``Params`` and ``State`` are the same as the original's. An MJCF scene saves
the same way, with its :attr:`SceneFile.build_options` (``dt``,
``integrator``, ``substeps``, ``contact``) as the ``build`` section.

Version 1 (jaxrb before joints) is the same without ``joints``,
``equalities``, ``actuators``, ``exclusions`` and the bodies' ``com``,
``shape_pos`` and ``shape_quat``; it is still read. Files are written as
version 2.

Errors are ``ValueError`` s that start with the file and the path of the
offending field, e.g. ``scene.json: bodies[2].shape.half_extents: expected 3
numbers, got 2`` or ``scene.json: joints[1].kind: unknown joint kind
'hinges'; valid kinds are: hinge, slide, ball, fixed, free``. Unknown keys
(typos) are errors that list the valid keys.

MJCF and URDF import (through MuJoCo's compiler) lives in :mod:`jaxrb.files.mjcf`;
:func:`load_scene` hands it ``.xml``, ``.mjcf`` and ``.urdf`` files, and
:func:`scene_from_mjcf` is importable from here as well. Both readers return
a :class:`SceneFile`, which lives with the field checks they share in
:mod:`jaxrb.files.common`.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import os
import re
from typing import Optional

import numpy as np

from jaxrb.files.common import (DTYPE_NAMES, SceneFile, _check_keys, _Context, _describe,
                                _integer, _is_number, _matrix, _number, _plain_build_options,
                                _read_build, _string, _vector)
from jaxrb.files.mjcf import DEFAULT_FRICTION, DEFAULT_TIMESTEP, MAX_SUBSTEP, scene_from_mjcf, scene_from_path
from jaxrb.model.joints import ACTUATOR_KINDS, EQUALITY_KINDS, JOINT_KINDS
from jaxrb.model.shapes import Box, Capsule, Circle, PointMasses, Polygon, Sphere
from jaxrb.scene import Scene

# The public names; SceneFile, DTYPE_NAMES, scene_from_mjcf and the MJCF defaults
# are defined in jaxrb.files.common and jaxrb.files.mjcf and stay importable from here.
__all__ = ["DEFAULT_FRICTION", "DEFAULT_TIMESTEP", "DTYPE_NAMES", "EQUALITY_KIND_NAMES", "FORMAT",
           "JOINT_KIND_NAMES", "MAX_SUBSTEP", "SHAPE_KINDS", "SUPPORTED_VERSIONS", "SceneFile", "VERSION",
           "load_scene", "save_scene", "scene_from_dict", "scene_from_mjcf", "scene_to_dict"]

FORMAT = "jaxrb-scene"
#: The version :func:`save_scene` writes.
VERSION = 2
#: The versions :func:`load_scene` reads.
SUPPORTED_VERSIONS = (1, 2)

SHAPE_KINDS = {"sphere": Sphere, "circle": Circle, "box": Box, "capsule": Capsule,
               "polygon": Polygon, "point_masses": PointMasses}
_KIND_OF_CLASS = {cls: kind for kind, cls in SHAPE_KINDS.items()}
#: A joint entry's ``kind`` -> its class (``rb.Hinge``, ``rb.Slider``, ...).
JOINT_KIND_NAMES = {name: cls for cls, name in JOINT_KINDS.items()}
#: An equality entry's ``kind`` -> its class (``rb.Connect``, ``rb.Weld``).
EQUALITY_KIND_NAMES = {name: cls for cls, name in EQUALITY_KINDS.items()}

_TOP_KEYS = ("format", "version", "dim", "gravity", "bodies", "planes", "joints", "equalities", "actuators",
             "exclusions", "build")
# What version 2 added: top-level lists, and add_body keywords.
_NEW_IN_2 = {"": ("joints", "equalities", "actuators", "exclusions"), "body": ("com", "shape_pos", "shape_quat")}
# Where a Scene method's message names a field: "joint 1 ('elbow'): field 'axis' must be non-zero".
_SCENE_ERROR = re.compile(r"^(?:(?:body|plane|joint|equality|actuator) \d+(?: \(.*?\))?|exclude_collision): "
                          r"field '(\w+)' (.*)$", re.S)


# --------------------------------------------------------------------------- #
# What each key holds
# --------------------------------------------------------------------------- #

def _vec(length):
    return lambda ctx, where, value: _vector(ctx, where, value, length)


def _body_field_checkers(dim):
    """Per add_body keyword: a checker (ctx, where, value) for its JSON value."""
    def rotation_rate(ctx, where, value):
        return _number(ctx, where, value) if dim == 2 else _vector(ctx, where, value, 3)

    def inertia(ctx, where, value):
        if dim == 2:
            return _number(ctx, where, value)
        if isinstance(value, list) and value and all(isinstance(row, list) for row in value):
            return _matrix(ctx, where, value, 3, rows=3)
        return _vector(ctx, where, value, 3)

    number, integer, string = _number, _integer, _string
    return {"mass": number, "density": number, "inertia": inertia, "pos": _vec(dim),
            "quat": _vec(4), "angle": number, "vel": _vec(dim), "angvel": rotation_rate,
            "friction": number, "restitution": number, "linear_damping": number,
            "angular_damping": number, "collision_category": integer,
            "collision_mask": integer, "name": string, "com": _vec(dim), "shape_pos": _vec(3),
            "shape_quat": _vec(4)}


def _plane_field_checkers(dim):
    return {"normal": lambda ctx, where, value: _vector(ctx, where, value, dim),
            "offset": _number, "friction": _number, "restitution": _number,
            "collision_category": _integer, "collision_mask": _integer}


def _joint_field_checkers():
    """Per add_joint keyword but ``kind``: a checker for its JSON value."""
    return {"child": _integer, "parent": _integer, "range": _vec(2), "ref": _number, "stiffness": _number,
            "springref": _number, "damping": _number, "armature": _number, "frictionloss": _number,
            "name": _string}


def _equality_field_checkers():
    """Per add_equality keyword but ``kind``."""
    return {"body_a": _integer, "body_b": _integer, "name": _string}


def _actuator_field_checkers():
    """Per add_actuator keyword."""
    return {"joint": _integer, "kind": _string, "gear": _number, "kp": _number, "kv": _number,
            "gain": _number, "bias": _vec(3), "ctrlrange": _vec(2), "forcerange": _vec(2), "name": _string}


def _exclusion_field_checkers():
    """Per exclude_collision keyword."""
    return {"body_a": _integer, "body_b": _integer, "plane": _integer}


def _kind_field_checkers(cls, dim):
    """The fields of a joint or equality kind: a hinge's ``axis`` 3 numbers, anchors and a slider's axis ``dim``."""
    return {field.name: _vec(3 if (field.name == "axis" and cls is JOINT_KIND_NAMES["hinge"]) else dim)
            for field in dataclasses.fields(cls)}


def _shape_field_checkers(kind, dim):
    def points(ctx, where, value):
        return _matrix(ctx, where, value, dim)

    def vertices(ctx, where, value):
        return _matrix(ctx, where, value, 2, min_rows=3)

    return {
        "sphere": {"radius": _number},
        "circle": {"radius": _number},
        "box": {"half_extents": lambda ctx, where, value: _vector(ctx, where, value, dim)},
        "capsule": {"radius": _number, "half_length": _number},
        "polygon": {"vertices": vertices},
        "point_masses": {"points": points, "masses": lambda ctx, where, value: _vector(ctx, where, value)},
    }[kind]


def _parameters(method):
    return [name for name in inspect.signature(method).parameters if name != "self"]


# --------------------------------------------------------------------------- #
# Scene -> dict
# --------------------------------------------------------------------------- #

def _plain(value):
    """A recorded argument as JSON data: numbers, strings, nested lists."""
    if isinstance(value, str):
        return value
    if isinstance(value, bool):
        return float(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    array = np.asarray(value)
    if array.dtype.kind in "iu":
        return array.tolist()
    return np.asarray(array, dtype=np.float64).tolist()


def _shape_to_dict(shape) -> dict:
    kind = _KIND_OF_CLASS.get(type(shape))
    if kind is None:
        raise ValueError(f"cannot save shape of type {type(shape).__name__}; "
                         f"known shapes: {', '.join(cls.__name__ for cls in SHAPE_KINDS.values())}")
    data = {"kind": kind}
    for field in dataclasses.fields(shape):
        value = getattr(shape, field.name)
        data[field.name] = np.asarray(value, dtype=np.float64).tolist()
    return data


def _entries(section, records, kinds=None):
    """The JSON entries of recorded add_* calls; a joint's or equality's kind object written flat:
    ``{"kind": "hinge", "axis": [...], "anchor": [...], <the other arguments>}``."""
    entries = []
    for index, arguments in enumerate(records):
        if not isinstance(arguments.get("name", ""), str):
            raise ValueError(f"save_scene: {section}[{index}].name: only string names can be saved, "
                             f"got {arguments['name']!r}")
        entry = {}
        for key, value in arguments.items():
            if key == "shape":
                entry[key] = _shape_to_dict(value)
            elif key == "kind" and kinds is not None:
                # Scene records a kind object as a 0-d object array (it copies what is not a number).
                kind = value.item() if isinstance(value, np.ndarray) and value.dtype == object else value
                entry["kind"] = kinds[type(kind)]
                for field in dataclasses.fields(kind):
                    if getattr(kind, field.name) is not None:
                        entry[field.name] = _plain(getattr(kind, field.name))
            else:
                entry[key] = _plain(value)
        entries.append(entry)
    return entries


def scene_to_dict(scene: Scene, **build_options) -> dict:
    """The JSON-ready description of ``scene`` (format ``jaxrb-scene``, version 2).

    Args:
        scene: a :class:`~jaxrb.Scene`; its bodies, planes, joints, loop
            closures, actuators and collision exclusions are written with the
            arguments they were added with.
        **build_options: keyword arguments of :meth:`jaxrb.Scene.build` to store in
            the ``"build"`` section (``dtype`` may be a dtype or its name).

    Returns:
        A dict of plain lists, numbers and strings that :func:`scene_from_dict`
        turns back into the same scene. ``joints``, ``equalities``,
        ``actuators`` and ``exclusions`` appear where the scene has any.

    Raises:
        ValueError: for an unknown build option, a name that is not a string,
            or a value JSON cannot hold.
    """
    build = _read_build(_plain_build_options(build_options), _Context("save_scene"))
    data = {"format": FORMAT, "version": VERSION, "dim": scene.dim,
            "gravity": np.asarray(scene.gravity, dtype=np.float64).tolist(),
            "bodies": _entries("bodies", scene._body_args),
            "planes": _entries("planes", scene._plane_args)}
    for section, records, kinds in (("joints", scene._joint_args, JOINT_KINDS),
                                    ("equalities", scene._equality_args, EQUALITY_KINDS),
                                    ("actuators", scene._actuator_args, None)):
        if records:
            data[section] = _entries(section, records, kinds)
    exclusions = [{"body_a": int(a), "body_b": int(b)} for a, b in sorted(scene._excluded_pairs)]
    exclusions += [{"body_a": int(a), "plane": int(plane)} for a, plane in sorted(scene._excluded_planes)]
    if exclusions:
        data["exclusions"] = exclusions
    if build:
        data["build"] = build
    return data


def save_scene(path, scene: Scene, **build_options) -> None:
    """Write ``scene`` (and build options) as a JSON scene file (version 2).

    Args:
        path: file to write; its suffix should be ``.json``.
        scene: the :class:`~jaxrb.Scene` to save.
        **build_options: keyword arguments of :meth:`jaxrb.Scene.build` to store,
            e.g. ``dt=0.004, substeps=4, dtype="float32"``; for a scene read
            from MJCF, its ``SceneFile.build_options``.

    Returns:
        None.

    Raises:
        ValueError: for an unknown build option or a path without a ``.json`` suffix.
    """
    if os.path.splitext(os.fspath(path))[1].lower() != ".json":
        raise ValueError(f"save_scene: {os.fspath(path)!r}: scene files are written as JSON; "
                         "use a '.json' suffix")
    data = scene_to_dict(scene, **build_options)
    with open(path, "w", encoding="utf-8") as handle:
        json.dump(data, handle, indent=1, allow_nan=False)
        handle.write("\n")


# --------------------------------------------------------------------------- #
# dict -> Scene
# --------------------------------------------------------------------------- #

def _replay(ctx, where, add, arguments, shape_fields=()):
    """Call ``add(**arguments)``; turn the Scene's message into one with the file path."""
    try:
        add(**arguments)
    except ValueError as error:
        match = _SCENE_ERROR.match(str(error))
        if not match:
            ctx.fail(where, str(error))
        field, message = match.groups()
        if field not in arguments and (field in shape_fields or field in ("shape", "inertia")) \
                and "shape" in arguments:
            field = "shape" if field == "shape" else f"shape.{field}"
        ctx.fail(f"{where}.{field}", message)


def _read_shape(ctx, where, data, dim):
    if data is None:
        return None, ()
    if not isinstance(data, dict):
        ctx.fail(where, f"expected an object such as {{\"kind\": \"sphere\", \"radius\": 0.1}}, "
                 f"got {_describe(data)}")
    if "kind" not in data:
        ctx.fail(where, "missing required key 'kind'; valid kinds are: " + ", ".join(SHAPE_KINDS))
    kind = data["kind"]
    if not isinstance(kind, str) or kind not in SHAPE_KINDS:
        ctx.fail(f"{where}.kind", f"unknown shape kind {_describe(kind)}; valid kinds are: "
                 + ", ".join(SHAPE_KINDS))
    checkers = _shape_field_checkers(kind, dim)
    _check_keys(ctx, where, data, ("kind",) + tuple(checkers), ("kind",) + tuple(checkers))
    for field, check in checkers.items():
        check(ctx, f"{where}.{field}", data[field])
    shape = SHAPE_KINDS[kind](**{field: data[field] for field in checkers})
    return shape, tuple(checkers)


def _list(ctx, data, section, required=False):
    """The top-level list ``section`` (an empty one where absent and not required)."""
    entries = data[section] if required else data.get(section, [])
    if not isinstance(entries, list):
        ctx.fail(section, f"expected a list of objects, got {_describe(entries)}")
    return entries


def _check_fields(ctx, where, entry, checkers):
    """Type-check the entry's non-null values; return them as keyword arguments."""
    for key, value in entry.items():
        if value is not None and key in checkers:
            checkers[key](ctx, f"{where}.{key}", value)
    return dict(entry)


def _read_kind(ctx, where, entry, kinds, what, method, checkers, dim):
    """Arguments of add_joint/add_equality from a flat entry: ``kind`` and its fields become the kind object."""
    if not isinstance(entry, dict):
        ctx.fail(where, f"expected an object, got {_describe(entry)}")
    if "kind" not in entry:
        ctx.fail(where, f"missing required key 'kind'; valid kinds are: {', '.join(kinds)}")
    kind = entry["kind"]
    if not isinstance(kind, str) or kind not in kinds:
        ctx.fail(f"{where}.kind", f"unknown {what} kind {_describe(kind)}; valid kinds are: {', '.join(kinds)}")
    kind_checkers = _kind_field_checkers(kinds[kind], dim)
    others = [name for name in _parameters(method) if name != "kind"]
    valid = ["kind"] + list(kind_checkers) + others
    required = [name for name, parameter in inspect.signature(method).parameters.items()
                if parameter.default is inspect.Parameter.empty and name != "self"]
    try:
        _check_keys(ctx, where, entry, valid, required)
    except ValueError as error:  # name the kind: 'anchor' is valid for a hinge, not for a slide
        message = str(error).replace("; valid keys are:", f"; valid keys of a {kind} {what} are:")
        raise ValueError(message) from None
    arguments = _check_fields(ctx, where, {key: value for key, value in entry.items() if key in others},
                              checkers)
    fields = _check_fields(ctx, where, {key: value for key, value in entry.items() if key in kind_checkers},
                           kind_checkers)
    arguments["kind"] = kinds[kind](**fields)
    return arguments


def _check_version(ctx, data, version):
    """Version 1 files hold none of what version 2 added."""
    if version >= 2:
        return
    for key in _NEW_IN_2[""]:
        if key in data:
            ctx.fail(key, f"needs version 2 of the format (this file says version {version})")
    bodies = data["bodies"]
    for index, body in enumerate(bodies if isinstance(bodies, list) else []):
        for key in _NEW_IN_2["body"]:
            if isinstance(body, dict) and key in body:
                ctx.fail(f"bodies[{index}].{key}", f"needs version 2 of the format (this file says version "
                                                   f"{version})")


def scene_from_dict(data: dict, source: Optional[str] = None) -> SceneFile:
    """Build a :class:`SceneFile` from the parsed JSON of a scene file (version 1 or 2).

    Args:
        data: the dict :func:`scene_to_dict` returns (or :func:`json.load` of a file).
        source: name used in error messages; default ``"scene"``.

    Returns:
        A :class:`SceneFile` whose scene has every body, plane, joint, loop
        closure, actuator and collision exclusion added.

    Raises:
        ValueError: naming the field path for a wrong format or version, an
            unknown key, a missing or ill-typed field, or a value the scene rejects.
    """
    ctx = _Context(source or "scene")
    _check_keys(ctx, "", data, _TOP_KEYS, ("format", "version", "dim", "bodies"))
    if data["format"] != FORMAT:
        ctx.fail("format", f"expected {FORMAT!r}, got {_describe(data['format'])}")
    version = data["version"]
    if not _is_number(version) or version not in SUPPORTED_VERSIONS:
        ctx.fail("version", f"unsupported version {version!r}; this jaxrb reads version(s) "
                 + ", ".join(map(str, SUPPORTED_VERSIONS)))
    _check_version(ctx, data, version)
    dim = data["dim"]
    if not isinstance(dim, int) or isinstance(dim, bool) or dim not in (2, 3):
        ctx.fail("dim", f"expected 2 or 3, got {_describe(dim)}")
    gravity = data.get("gravity")
    if gravity is not None:
        _vector(ctx, "gravity", gravity, dim)
    scene = Scene(dim=dim, gravity=gravity)

    checkers = _body_field_checkers(dim)
    valid = _parameters(Scene.add_body)
    for index, body in enumerate(_list(ctx, data, "bodies", required=True)):
        where = f"bodies[{index}]"
        _check_keys(ctx, where, body, valid)
        arguments = {}
        shape_fields = ()
        for key, value in body.items():
            if key == "shape":
                arguments["shape"], shape_fields = _read_shape(ctx, f"{where}.shape", value, dim)
                continue
            check = checkers.get(key)
            if value is not None and check is not None:
                check(ctx, f"{where}.{key}", value)
            arguments[key] = value
        _replay(ctx, where, scene.add_body, arguments, shape_fields)

    checkers = _plane_field_checkers(dim)
    valid = _parameters(Scene.add_plane)
    for index, plane in enumerate(_list(ctx, data, "planes")):
        where = f"planes[{index}]"
        _check_keys(ctx, where, plane, valid)
        _replay(ctx, where, scene.add_plane, _check_fields(ctx, where, plane, checkers))

    for section, kinds, what, method, checkers in (
            ("joints", JOINT_KIND_NAMES, "joint", Scene.add_joint, _joint_field_checkers()),
            ("equalities", EQUALITY_KIND_NAMES, "equality", Scene.add_equality, _equality_field_checkers())):
        for index, entry in enumerate(_list(ctx, data, section)):
            where = f"{section}[{index}]"
            arguments = _read_kind(ctx, where, entry, kinds, what, method, checkers, dim)
            _replay(ctx, where, getattr(scene, method.__name__), arguments)

    checkers = _actuator_field_checkers()
    for index, entry in enumerate(_list(ctx, data, "actuators")):
        where = f"actuators[{index}]"
        _check_keys(ctx, where, entry, _parameters(Scene.add_actuator), ("joint",))
        arguments = _check_fields(ctx, where, entry, checkers)
        if arguments.get("kind", "motor") not in ACTUATOR_KINDS:
            ctx.fail(f"{where}.kind", f"unknown actuator kind {_describe(arguments['kind'])}; valid kinds are: "
                     + ", ".join(ACTUATOR_KINDS))
        _replay(ctx, where, scene.add_actuator, arguments)

    checkers = _exclusion_field_checkers()
    for index, entry in enumerate(_list(ctx, data, "exclusions")):
        where = f"exclusions[{index}]"
        _check_keys(ctx, where, entry, _parameters(Scene.exclude_collision), ("body_a",))
        _replay(ctx, where, scene.exclude_collision, _check_fields(ctx, where, entry, checkers))

    build = _read_build(data.get("build", {}), ctx)
    return SceneFile(scene=scene, build_options=build, warnings=[], source=source)


def _reject_constant(name):
    raise ValueError(f"{name} is not a number JSON allows")


def _unique_keys(pairs):
    result = {}
    for key, value in pairs:
        if key in result:
            raise ValueError(f"duplicate key {key!r}")
        result[key] = value
    return result


def _read_json(path) -> SceneFile:
    label = os.fspath(path)
    with open(path, "r", encoding="utf-8") as handle:
        text = handle.read()
    try:
        data = json.loads(text, object_pairs_hook=_unique_keys, parse_constant=_reject_constant)
    except json.JSONDecodeError as error:
        raise ValueError(f"{label}: not valid JSON: {error.msg} (line {error.lineno}, "
                         f"column {error.colno})") from None
    except ValueError as error:
        raise ValueError(f"{label}: not valid JSON: {error}") from None
    return scene_from_dict(data, source=label)


def load_scene(path, *, floating_base: bool = False) -> SceneFile:
    """Read a scene file: JSON (``.json``), MuJoCo MJCF (``.xml``, ``.mjcf``) or URDF (``.urdf``).

    MJCF and URDF files are compiled by MuJoCo (:mod:`jaxrb.files.mjcf`, the
    ``mujoco`` package).

    Args:
        path: the file to read.
        floating_base: MJCF/URDF only: give the world's direct children
            without joints a free joint (MuJoCo fixes a URDF's root link to
            the world); its 7 and 6 numbers then lead qpos and qvel.

    Returns:
        A :class:`SceneFile`; ``.build(**overrides)`` returns ``(model, params, state)``.

    Raises:
        ValueError: for an unknown suffix or anything wrong in the file, naming
            the field (JSON) or element and attribute (MJCF).
    """
    suffix = os.path.splitext(os.fspath(path))[1].lower()
    if suffix == ".json":
        return _read_json(path)
    if suffix in (".xml", ".mjcf", ".urdf"):
        return scene_from_path(path, floating_base=floating_base)
    raise ValueError(f"load_scene: {os.fspath(path)!r}: unknown suffix {suffix!r}; "
                     "expected '.json' (jaxrb scene), '.xml'/'.mjcf' (MuJoCo MJCF) or '.urdf'")
