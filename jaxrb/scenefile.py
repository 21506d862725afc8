"""Scene files: a versioned JSON format and an importer for a subset of MuJoCo's MJCF.

Both readers treat a file as data: JSON is read with :func:`json.load` into
plain lists, dicts, numbers and strings; MJCF is parsed with
:mod:`xml.etree.ElementTree` (document type declarations and entities are
refused). Nothing in a file is imported, evaluated or executed.

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

MJCF import (:func:`scene_from_mjcf`, or :func:`load_scene` on ``.xml`` /
``.mjcf``) reads the subset of MuJoCo's XML that maps onto jaxrb without
changing its meaning:

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
cameras, sites, ...) are skipped and listed in :attr:`SceneFile.warnings`.
Everything else (hinge or other joints, bodies without a free joint, nested
bodies, several geoms on one body, other geom types, actuators, tendons,
equality constraints, default classes, includes, ...) is a ``ValueError``
naming the element and attribute: nothing is silently misread.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import math
import os
import re
import xml.etree.ElementTree as ElementTree
from typing import Optional

import numpy as np

from jaxrb import options as contact_options
from jaxrb.scene import Scene
from jaxrb.shapes import Box, Capsule, Circle, PointMasses, Polygon, Sphere

FORMAT = "jaxrb-scene"
VERSION = 1
SUPPORTED_VERSIONS = (1,)

SHAPE_KINDS = {"sphere": Sphere, "circle": Circle, "box": Box, "capsule": Capsule,
               "polygon": Polygon, "point_masses": PointMasses}
_KIND_OF_CLASS = {cls: kind for kind, cls in SHAPE_KINDS.items()}
DTYPE_NAMES = ("bfloat16", "float16", "float32", "float64")

_TOP_KEYS = ("format", "version", "dim", "gravity", "bodies", "planes", "build")


# --------------------------------------------------------------------------- #
# SceneFile
# --------------------------------------------------------------------------- #

@dataclasses.dataclass
class SceneFile:
    """A scene read from a file, with the build options the file gave.

    Attributes:
        scene: the :class:`~jaxrb.Scene`, every body and plane already added.
        build_options: keyword arguments for :meth:`jaxrb.Scene.build` (``dtype``
            as a name such as ``"float32"``).
        warnings: what the reader skipped or approximated (MJCF import); empty
            for JSON files.
        source: the file's path (or the ``source`` name given to
            :func:`scene_from_dict` / :func:`scene_from_mjcf`), else ``None``.
    """

    scene: Scene
    build_options: dict = dataclasses.field(default_factory=dict)
    warnings: list = dataclasses.field(default_factory=list)
    source: Optional[str] = None

    def build(self, **overrides):
        """Build the scene with the file's options, ``overrides`` taking precedence.

        Args:
            **overrides: keyword arguments of :meth:`jaxrb.Scene.build`; they
                replace the file's options of the same name.

        Returns:
            ``(model, params, state)`` as :meth:`jaxrb.Scene.build` returns them.

        Raises:
            ValueError: if ``dt`` is neither in the file nor in ``overrides``, an
                override is not a build option, or the scene rejects an option.
        """
        label = self.source or "scene"
        overrides = _read_build(_plain_build_options(overrides), _Context(label, "build overrides"),
                                where="")
        options = dict(self.build_options)
        if "contact" in overrides:  # another model: the file's options of its own model no longer apply
            options = {key: value for key, value in options.items()
                       if contact_options.FLAT_KEYWORDS.get(key, (overrides["contact"],))[0] == overrides["contact"]}
        options.update(overrides)
        if "dt" not in options:
            raise ValueError(f"{label}: no time step: the file's \"build\" section has no 'dt'; "
                             "give one, e.g. SceneFile.build(dt=0.004)")
        try:
            return self.scene.build(**contact_options.grouped(options))
        except ValueError as error:
            raise ValueError(f"{label}: build: {error}") from None


# --------------------------------------------------------------------------- #
# Field checking with paths
# --------------------------------------------------------------------------- #

class _Context:
    """Formats errors as '<source>: <field path>: <message>'."""

    def __init__(self, source: str, root: str = ""):
        self.source = source
        self.root = root

    def fail(self, where: str, message: str):
        path = ".".join(part for part in (self.root, where) if part)
        raise ValueError(f"{self.source}: {path}: {message}" if path else f"{self.source}: {message}")


def _describe(value) -> str:
    if isinstance(value, list):
        return f"a list of {len(value)}"
    if isinstance(value, dict):
        return "an object"
    return f"{type(value).__name__} {value!r}" if not isinstance(value, str) else f"string {value!r}"


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _number(ctx, where, value):
    if not _is_number(value):
        ctx.fail(where, f"expected a number, got {_describe(value)}")
    if not math.isfinite(value):
        ctx.fail(where, f"expected a finite number, got {value!r}")
    return value


def _integer(ctx, where, value):
    if not isinstance(value, int) or isinstance(value, bool):
        ctx.fail(where, f"expected an integer, got {_describe(value)}")
    return value


def _string(ctx, where, value):
    if not isinstance(value, str):
        ctx.fail(where, f"expected a string, got {_describe(value)}")
    return value


def _boolean(ctx, where, value):
    if not isinstance(value, bool):
        ctx.fail(where, f"expected true or false, got {_describe(value)}")
    return value


def _vector(ctx, where, value, length=None):
    """A list of numbers, of ``length`` entries when given."""
    wanted = f"{length} numbers" if length is not None else "numbers"
    if not isinstance(value, list):
        ctx.fail(where, f"expected a list of {wanted}, got {_describe(value)}")
    if length is not None and len(value) != length:
        ctx.fail(where, f"expected {length} numbers, got {len(value)}")
    for index, item in enumerate(value):
        _number(ctx, f"{where}[{index}]", item)
    return value


def _matrix(ctx, where, value, columns, rows=None, min_rows=1):
    """A list of lists of ``columns`` numbers (``rows`` of them, or at least ``min_rows``)."""
    if not isinstance(value, list):
        ctx.fail(where, f"expected a list of rows of {columns} numbers, got {_describe(value)}")
    if rows is not None and len(value) != rows:
        ctx.fail(where, f"expected {rows} rows of {columns} numbers, got {len(value)} rows")
    if len(value) < min_rows:
        ctx.fail(where, f"expected at least {min_rows} rows of {columns} numbers, got {len(value)}")
    for index, row in enumerate(value):
        _vector(ctx, f"{where}[{index}]", row, columns)
    return value


def _check_keys(ctx, where, data, valid, required=()):
    if not isinstance(data, dict):
        ctx.fail(where, f"expected an object, got {_describe(data)}")
    for key in data:
        if key not in valid:
            ctx.fail(f"{where}.{key}" if where else key,
                     f"unknown key {key!r}; valid keys are: {', '.join(valid)}")
    for key in required:
        if key not in data:
            ctx.fail(where, f"missing required key {key!r}")


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


def _build_kinds() -> dict:
    """Build option -> 'number' | 'integer' | 'string' | 'boolean' | 'dtype' (+ '?' if None is allowed).

    Read from Scene.build's signature and the contact groups' fields (stored
    flat, by their keywords in :data:`jaxrb.options.FLAT_KEYWORDS`), so a new
    build option is accepted here without editing this module.
    """
    names = {"float": "number", "int": "integer", "str": "string", "bool": "boolean"}

    def kind(name, annotation, default):
        annotation = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", "")
        optional = annotation.startswith("Optional[") or default is None
        inner = annotation[len("Optional["):-1] if annotation.startswith("Optional[") else annotation
        if name == "contact":  # a file names the model; its options are stored flat beside it
            inner = "str"
        return ("dtype" if name == "dtype" else names.get(inner, "any")) + ("?" if optional else "")

    kinds = {name: kind(name, parameter.annotation, parameter.default)
             for name, parameter in inspect.signature(Scene.build).parameters.items()
             if name != "self" and parameter.kind is not inspect.Parameter.VAR_KEYWORD}
    for group, table in ((contact_options.Impulse, contact_options.IMPULSE_KEYWORDS),
                         (contact_options.Penalty, contact_options.PENALTY_KEYWORDS)):
        for field in dataclasses.fields(group):
            kinds[table[field.name]] = kind(field.name, field.type, field.default)
    return kinds


def _read_build(options, ctx, where="build"):
    """Check a dict of build options; return it with plain Python values."""
    kinds = _build_kinds()
    if not isinstance(options, dict):
        ctx.fail(where, f"expected an object, got {_describe(options)}")
    result = {}
    for key, value in options.items():
        field = f"{where}.{key}" if where else key
        if key not in kinds:
            ctx.fail(field, f"unknown build option {key!r}; valid options are: {', '.join(kinds)}")
        kind = kinds[key]
        if value is None:
            if not kind.endswith("?"):
                ctx.fail(field, "must not be null")
            result[key] = None
            continue
        kind = kind.rstrip("?")
        if kind == "number":
            value = _number(ctx, field, value)
        elif kind == "integer":
            value = _integer(ctx, field, value)
        elif kind == "string":
            value = _string(ctx, field, value)
        elif kind == "boolean":
            value = _boolean(ctx, field, value)
        elif kind == "dtype":
            if value not in DTYPE_NAMES:
                ctx.fail(field, f"expected one of {', '.join(map(repr, DTYPE_NAMES))}, "
                         f"got {_describe(value)}")
        elif not (value is None or isinstance(value, (bool, int, float, str))):
            ctx.fail(field, f"expected a number, string or boolean, got {_describe(value)}")
        result[key] = value
    return result


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


def _plain_build_options(options: dict) -> dict:
    plain = {}
    for key, value in contact_options.flat(options).items():  # a contact group's options stored flat
        if key == "dtype" and value is not None and not isinstance(value, str):
            value = np.dtype(value).name
        elif isinstance(value, np.generic):
            value = value.item()
        elif hasattr(value, "shape") and np.ndim(value) == 0:  # a 0-d jax or numpy array
            value = np.asarray(value).item()
        plain[key] = value
    return plain


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


# --------------------------------------------------------------------------- #
# MJCF
# --------------------------------------------------------------------------- #

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
