"""Scene files: jaxrb's versioned JSON format, and :func:`load_scene` for JSON or MJCF.

A file is treated as data: JSON is read with :func:`json.load` into plain
lists, dicts, numbers and strings. Nothing in a file is imported, evaluated
or executed.

JSON format (version 1)::

    {"format": "jaxrb-scene", "version": 1, "dim": 3, "gravity": [0, 0, -9.81],
     "bodies": [{"shape": {"kind": "box", "half_extents": [0.1, 0.1, 0.1]},
                 "mass": 1.0, "pos": [0, 0, 0.5], "friction": 0.8}],
     "planes": [{"normal": [0, 0, 1], "offset": 0.0, "friction": 0.8}],
     "build": {"dt": 0.004, "substeps": 4, "contact": "impulse", "dtype": "float32"}}

A body's keys are the keyword arguments of :meth:`jaxrb.Scene.add_body` (its
``shape`` is ``{"kind": ..., <constructor fields>}`` with kind one of
``sphere``, ``circle``, ``box``, ``capsule``, ``polygon``, ``point_masses``,
or absent for a body given only mass and inertia); a plane's keys are those
of :meth:`jaxrb.Scene.add_plane`; ``build`` holds keyword arguments of
:meth:`jaxrb.Scene.build` (``dtype`` as a name such as ``"float32"``). A
scene remembers the arguments of every ``add_body``/``add_plane`` call, so
saving writes exactly what the user gave and loading replays it through the
same methods: every validation runs again and the built ``Model``,
``Params`` and ``State`` are the same as the original's.

Errors are ``ValueError`` s that start with the file and the path of the
offending field, e.g. ``scene.json: bodies[2].shape.half_extents: expected 3
numbers, got 2``. Unknown keys (typos) are errors that list the valid keys.

MJCF import (a subset of MuJoCo's XML) lives in :mod:`jaxrb.files.mjcf`;
:func:`load_scene` hands it ``.xml`` and ``.mjcf`` files, and
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

from jaxrb.files.mjcf import DEFAULT_FRICTION, DEFAULT_TIMESTEP, MAX_SUBSTEP, scene_from_mjcf
from jaxrb.scene import Scene
from jaxrb.files.common import (DTYPE_NAMES, SceneFile, _check_keys, _Context, _describe,
                                _integer, _is_number, _matrix, _number, _plain_build_options,
                                _read_build, _string, _vector)
from jaxrb.model.shapes import Box, Capsule, Circle, PointMasses, Polygon, Sphere

# The public names; SceneFile, DTYPE_NAMES, scene_from_mjcf and the MJCF defaults
# are defined in jaxrb.files.common and jaxrb.files.mjcf and stay importable from here.
__all__ = ["DEFAULT_FRICTION", "DEFAULT_TIMESTEP", "DTYPE_NAMES", "FORMAT", "MAX_SUBSTEP",
           "SHAPE_KINDS", "SUPPORTED_VERSIONS", "SceneFile", "VERSION", "load_scene",
           "save_scene", "scene_from_dict", "scene_from_mjcf", "scene_to_dict"]

FORMAT = "jaxrb-scene"
VERSION = 1
SUPPORTED_VERSIONS = (1,)

SHAPE_KINDS = {"sphere": Sphere, "circle": Circle, "box": Box, "capsule": Capsule,
               "polygon": Polygon, "point_masses": PointMasses}
_KIND_OF_CLASS = {cls: kind for kind, cls in SHAPE_KINDS.items()}

_TOP_KEYS = ("format", "version", "dim", "gravity", "bodies", "planes", "build")


# --------------------------------------------------------------------------- #
# What each key holds
# --------------------------------------------------------------------------- #

def _body_field_checkers(dim):
    """Per add_body keyword: a checker (ctx, where, value) for its JSON value."""
    def vec(length):
        return lambda ctx, where, value: _vector(ctx, where, value, length)

    def rotation_rate(ctx, where, value):
        return _number(ctx, where, value) if dim == 2 else _vector(ctx, where, value, 3)

    def inertia(ctx, where, value):
        if dim == 2:
            return _number(ctx, where, value)
        if isinstance(value, list) and value and all(isinstance(row, list) for row in value):
            return _matrix(ctx, where, value, 3, rows=3)
        return _vector(ctx, where, value, 3)

    number, integer, string = _number, _integer, _string
    return {"mass": number, "density": number, "inertia": inertia, "pos": vec(dim),
            "quat": vec(4), "angle": number, "vel": vec(dim), "angvel": rotation_rate,
            "friction": number, "restitution": number, "linear_damping": number,
            "angular_damping": number, "collision_category": integer,
            "collision_mask": integer, "name": string}


def _plane_field_checkers(dim):
    return {"normal": lambda ctx, where, value: _vector(ctx, where, value, dim),
            "offset": _number, "friction": _number, "restitution": _number,
            "collision_category": _integer, "collision_mask": _integer}


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



def scene_to_dict(scene: Scene, **build_options) -> dict:
    """The JSON-ready description of ``scene`` (format ``jaxrb-scene``, version 1).

    Args:
        scene: a :class:`~jaxrb.Scene`; its bodies and planes are written with the
            arguments they were added with.
        **build_options: keyword arguments of :meth:`jaxrb.Scene.build` to store in
            the ``"build"`` section (``dtype`` may be a dtype or its name).

    Returns:
        A dict of plain lists, numbers and strings that :func:`scene_from_dict`
        turns back into the same scene.

    Raises:
        ValueError: for an unknown build option or a value JSON cannot hold.
    """
    build = _read_build(_plain_build_options(build_options), _Context("save_scene"))
    bodies = []
    for index, arguments in enumerate(scene._body_args):
        if not isinstance(arguments.get("name", ""), str):
            raise ValueError(f"save_scene: bodies[{index}].name: only string names can be saved, "
                             f"got {arguments['name']!r}")
        body = {}
        for key, value in arguments.items():
            body[key] = _shape_to_dict(value) if key == "shape" else _plain(value)
        bodies.append(body)
    planes = [{key: _plain(value) for key, value in arguments.items()} for arguments in scene._plane_args]
    data = {"format": FORMAT, "version": VERSION, "dim": scene.dim,
            "gravity": np.asarray(scene.gravity, dtype=np.float64).tolist(),
            "bodies": bodies, "planes": planes}
    if build:
        data["build"] = build
    return data


def save_scene(path, scene: Scene, **build_options) -> None:
    """Write ``scene`` (and build options) as a JSON scene file.

    Args:
        path: file to write; its suffix should be ``.json``.
        scene: the :class:`~jaxrb.Scene` to save.
        **build_options: keyword arguments of :meth:`jaxrb.Scene.build` to store,
            e.g. ``dt=0.004, substeps=4, dtype="float32"``.

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

_SCENE_ERROR = re.compile(r"^(?:body|plane) \d+(?: \(.*?\))?: field '(\w+)' (.*)$", re.S)


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


def scene_from_dict(data: dict, source: Optional[str] = None) -> SceneFile:
    """Build a :class:`SceneFile` from the parsed JSON of a scene file.

    Args:
        data: the dict :func:`scene_to_dict` returns (or :func:`json.load` of a file).
        source: name used in error messages; default ``"scene"``.

    Returns:
        A :class:`SceneFile` whose scene has every body and plane added.

    Raises:
        ValueError: naming the field path for a wrong format or version, an
            unknown key, a missing or ill-typed field, or a value the scene rejects.
    """
    ctx = _Context(source or "scene")
    _check_keys(ctx, "", data, _TOP_KEYS, ("format", "version", "dim", "bodies"))
    if data["format"] != FORMAT:
        ctx.fail("format", f"expected {FORMAT!r}, got {_describe(data['format'])}")
    version = data["version"]
    if version not in SUPPORTED_VERSIONS or not _is_number(version):
        ctx.fail("version", f"unsupported version {version!r}; this jaxrb reads version(s) "
                 + ", ".join(map(str, SUPPORTED_VERSIONS)))
    dim = data["dim"]
    if not isinstance(dim, int) or isinstance(dim, bool) or dim not in (2, 3):
        ctx.fail("dim", f"expected 2 or 3, got {_describe(dim)}")
    gravity = data.get("gravity")
    if gravity is not None:
        _vector(ctx, "gravity", gravity, dim)
    scene = Scene(dim=dim, gravity=gravity)

    bodies = data["bodies"]
    if not isinstance(bodies, list):
        ctx.fail("bodies", f"expected a list of objects, got {_describe(bodies)}")
    checkers = _body_field_checkers(dim)
    valid = _parameters(Scene.add_body)
    for index, body in enumerate(bodies):
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

    planes = data.get("planes", [])
    if not isinstance(planes, list):
        ctx.fail("planes", f"expected a list of objects, got {_describe(planes)}")
    checkers = _plane_field_checkers(dim)
    valid = _parameters(Scene.add_plane)
    for index, plane in enumerate(planes):
        where = f"planes[{index}]"
        _check_keys(ctx, where, plane, valid)
        for key, value in plane.items():
            if value is not None and key in checkers:
                checkers[key](ctx, f"{where}.{key}", value)
        _replay(ctx, where, scene.add_plane, dict(plane))

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


def load_scene(path) -> SceneFile:
    """Read a scene file: JSON (``.json``) or MuJoCo MJCF (``.xml``, ``.mjcf``).

    MJCF files are read by :func:`jaxrb.files.mjcf.scene_from_mjcf`.

    Args:
        path: the file to read.

    Returns:
        A :class:`SceneFile`; ``.build(**overrides)`` returns ``(model, params, state)``.

    Raises:
        ValueError: for an unknown suffix or anything wrong in the file, naming
            the field (JSON) or element and attribute (MJCF).
    """
    suffix = os.path.splitext(os.fspath(path))[1].lower()
    if suffix == ".json":
        return _read_json(path)
    if suffix in (".xml", ".mjcf"):
        with open(path, "r", encoding="utf-8") as handle:
            text = handle.read()
        return scene_from_mjcf(text, source=os.fspath(path))
    raise ValueError(f"load_scene: {os.fspath(path)!r}: unknown suffix {suffix!r}; "
                     "expected '.json' (jaxrb scene) or '.xml'/'.mjcf' (MuJoCo MJCF)")
