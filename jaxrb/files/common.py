"""What the scene-file readers share: :class:`SceneFile` and checks that name the field.

:mod:`jaxrb.files.scenefile` (jaxrb's versioned JSON) and :mod:`jaxrb.files.mjcf` (MuJoCo
MJCF import) both return a :class:`SceneFile`: a :class:`~jaxrb.Scene` with
the build options the file gave. Its :meth:`SceneFile.build` checks the
overrides it is given as the JSON reader checks a file's ``"build"``
section, so the checks live here too:

* typed fields whose errors start with the file and the path of the field,
  e.g. ``scene.json: bodies[2].shape.half_extents: expected 3 numbers, got 2``
  (``_Context``, ``_number``, ``_vector``, ``_matrix``, ``_check_keys``, ...);
* build options, whose names and types are read from
  :meth:`jaxrb.Scene.build`'s signature (``_build_kinds``, ``_read_build``).

This module imports neither reader, so both import it without a cycle.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from typing import Optional

import numpy as np

from jaxrb.model import options as contact_options
from jaxrb.scene import Scene

DTYPE_NAMES = ("bfloat16", "float16", "float32", "float64")


# --------------------------------------------------------------------------- #
# SceneFile
# --------------------------------------------------------------------------- #

@dataclasses.dataclass
class SceneFile:
    """A scene read from a file, with the build options the file gave.

    Attributes:
        scene: the :class:`~jaxrb.Scene`, every body, plane, joint, loop
            closure, actuator and collision exclusion already added.
        build_options: keyword arguments for :meth:`jaxrb.Scene.build` (``dtype``
            as a name such as ``"float32"``).
        warnings: what the reader skipped or approximated (MJCF import); empty
            for JSON files.
        source: the file's path (or the ``source`` name given to
            :func:`jaxrb.files.scenefile.scene_from_dict` /
            :func:`jaxrb.files.mjcf.scene_from_mjcf`), else ``None``.
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
# Build options
# --------------------------------------------------------------------------- #

def _build_kinds() -> dict:
    """Build option -> 'number' | 'integer' | 'string' | 'boolean' | 'dtype' (+ '?' if None is allowed).

    Read from Scene.build's signature and the contact groups' fields (stored
    flat, by their keywords in :data:`jaxrb.model.options.FLAT_KEYWORDS`), so a new
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


def _plain_build_options(options: dict) -> dict:
    plain = {}
    for key, value in contact_options.flattened(options).items():  # a contact group's options stored flat
        if key == "dtype" and value is not None and not isinstance(value, str):
            value = np.dtype(value).name
        elif isinstance(value, np.generic):
            value = value.item()
        elif hasattr(value, "shape") and np.ndim(value) == 0:  # a 0-d jax or numpy array
            value = np.asarray(value).item()
        plain[key] = value
    return plain
