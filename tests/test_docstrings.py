"""Every public symbol of jaxrb has a Google-style docstring that gives array shapes.

What is public (walked by :func:`public_symbols`, pure introspection, no tracing):

* every function and class named in ``jaxrb.__all__`` (wherever it is defined,
  e.g. ``ContactSet`` and ``detect_contacts`` from ``jaxrb.physics.collision.pairs``);
* every function and class without a leading underscore *defined* in one of
  the public modules ``jaxrb.math.quaternion``, ``jaxrb.math.vector``, ``jaxrb.model.shapes``,
  ``jaxrb.physics.dynamics``, ``jaxrb.physics.integrators``, ``jaxrb.physics.step``, ``jaxrb.model.types``,
  ``jaxrb.scene``, ``jaxrb.fit.sysid`` (with ``jaxrb.fit.observations`` and
  ``jaxrb.fit.parameter_transforms``, whose names it re-exports), ``jaxrb.sweep``,
  and ``jaxrb.render``, ``jaxrb.files.scenefile``, ``jaxrb.files.common``,
  ``jaxrb.files.mjcf`` and ``jaxrb.analytic`` when those exist (they are picked up automatically),
  plus any module named in ``jaxrb.__all__``. Names a module merely imports
  (``jax``, ``numpy``, another jaxrb module's function) are checked where they
  are defined; only objects whose ``__module__`` is inside ``jaxrb`` count;
* the public methods and properties of those classes (``Scene.add_body``,
  ``Model.summary``, ``State.replace``, ...), dunder methods excluded.

Internal, unless a name from them is in ``jaxrb.__all__``: ``jaxrb.bench``,
``jaxrb.physics.collision.*``, ``jaxrb.physics.contact.*``, ``jaxrb.cli.main``, ``jaxrb.cli.runner``,
``jaxrb.cli.demo`` and ``jaxrb.model.struct``. They still deserve docstrings, but this
test does not hold them to the rule; nor the repository's ``benchmarks/``
folder, which is not part of the package.

The rule (:func:`docstring_problems`), for each public symbol:

(a) it has a non-empty docstring of its own (a dataclass's generated
    ``Name(field: type)`` text does not count; every public module has one too);
(b) a function or method with parameters (``self``/``cls`` aside) has an
    ``Args:`` section naming every parameter, ``*args``/``**kwargs`` included
    (with or without the stars); one entry may name several, as in
    ``linear_damping, angular_damping: rates in 1/s``. A class documents its
    constructor parameters the same way in an ``Args:`` or ``Attributes:``
    section of the class docstring (or in ``__init__``'s ``Args:``);
(c) array shapes: a parameter that holds an array (its name is in
    :data:`ARRAY_NAMES`, or it is annotated ``Array``/``np.ndarray``) has a
    shape in its entry: a parenthesised tuple such as ``(n, 3)``, ``(dim,)``,
    ``(T, n, 4)``, ``(..., 3)``, ``()`` or ``(...)``, or the word ``scalar``.
    ``(m)`` or ``(kg)`` is a unit, not a shape: a one-axis shape is written
    ``(n,)``. Dataclass fields (``Model``, ``Params``, ``State``, ``Wrench``,
    ``ContactSet``, ``Observation``, shapes, ...) follow the same rule in the
    class's ``Attributes:`` section when annotated as arrays, or when named in
    :data:`ARRAY_NAMES` and not annotated as a Python scalar;
(d) a function or method that returns a value (found in its source: a
    ``return <value>`` or ``yield`` outside nested functions) has a
    ``Returns:`` (or ``Yields:``) section; if its return annotation is an array
    type, that section gives a shape.

Properties are documented like attributes: a non-empty docstring is enough.
The last tests feed the checker deliberately bad docstrings, so the rule
cannot pass by checking nothing.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import importlib.util
import inspect
import re
import textwrap
import types

import pytest

import jaxrb

PUBLIC_MODULES = ("math.quaternion", "math.vector", "model.shapes", "physics.dynamics", "physics.integrators",
                  "physics.step", "model.types", "scene", "fit.sysid", "fit.observations",
                  "fit.parameter_transforms", "sweep")
# Covered as soon as they exist (written alongside this test).
OPTIONAL_MODULES = ("render", "files.scenefile", "files.common", "files.mjcf", "analytic")

# Parameter and field names that hold arrays in this codebase (grepped from the
# public signatures): their entries must give a shape.
ARRAY_NAMES = frozenset({
    # state and observations
    "pos", "quat", "vel", "angvel", "angle", "time", "times", "steps", "mask", "positions",
    # bodies and shapes
    "mass", "masses", "inertia", "inv_inertia", "com", "com_offset", "points", "point",
    "vertices", "half_extents", "body", "body_a", "body_b",
    # forces, motion, geometry
    "force", "torque", "momentum", "angvel_body", "gravity", "normal", "dist", "vector",
    "rotvec", "target", "values", "h", "dt",
    # math kernels' short names
    "a", "b", "q", "v", "w", "r", "x", "m", "num", "den", "fallback",
})

# Annotations (as strings: modules use ``from __future__ import annotations``)
# that mark an array-valued parameter, field or return.
_ARRAY_ANNOTATION = re.compile(r"^(?:Optional\[)?\s*(?:jax\.|jnp\.|np\.|numpy\.)?"
                               r"(?:Array|ArrayLike|ndarray)\s*\]?$")
_SCALAR_ANNOTATION = re.compile(r"^(?:Optional\[)?\s*(?:int|float|bool|str)\s*\]?$")

# One axis of a shape: a name, a number, "..." or a small expression ("n + 1").
_AXIS = r"(?:\.\.\.|[A-Za-z_]\w*|\d+)(?:\s*[-+*/]\s*(?:[A-Za-z_]\w*|\d+))*"
SHAPE = re.compile(
    r"\(\s*\)"                                   # ()      a 0-d array
    r"|\(\s*\.\.\.\s*\)"                         # (...)   any batch shape
    rf"|\(\s*{_AXIS}\s*,\s*\)"                    # (n,)
    rf"|\(\s*{_AXIS}(?:\s*,\s*{_AXIS})+\s*,?\s*\)"  # (n, 3), (T, n, 4), (..., 3)
    r"|\bscalars?\b")

_ARGS_HEADERS = ("Args", "Arguments", "Parameters")
_CLASS_HEADERS = _ARGS_HEADERS + ("Attributes",)
_RETURN_HEADERS = ("Returns", "Return", "Yields")
_ANY_HEADER = re.compile(r"^(\s*)([A-Z][A-Za-z ]*):\s*(.*)$")
_ENTRY = re.compile(r"^(?P<names>\*{0,2}`{0,2}\w+`{0,2}(?:\s*,\s*\*{0,2}`{0,2}\w+`{0,2})*)"
                    r"\s*(?:\([^)]*\))?\s*:(?:\s+(?P<desc>.*)|$)")
_NAMES_WRAP = re.compile(r"^(\*{0,2}`{0,2}\w+`{0,2}(?:\s*,\s*\*{0,2}`{0,2}\w+`{0,2})*)\s*,$")
_KNOWN_HEADERS = set(_CLASS_HEADERS + _RETURN_HEADERS) | {
    "Raises", "Example", "Examples", "Note", "Notes", "Warning", "Warnings", "See Also", "Todo",
    "References"}


# --- parsing ----------------------------------------------------------------------------------

def _sections(doc: str) -> dict:
    """Google-style sections of a cleaned docstring: ``{header: (header_rest, body lines)}``."""
    sections = {}
    current = None
    header_indent = 0
    for line in doc.splitlines():
        match = _ANY_HEADER.match(line)
        # "Example:" deep inside an Args entry's text does not open a section.
        if match and match.group(2) in _KNOWN_HEADERS and (
                current is None or len(match.group(1)) <= header_indent):
            current = match.group(2)
            header_indent = len(match.group(1))
            sections[current] = (match.group(3).strip(), [])
            continue
        if current is None:
            continue
        if line.strip() and len(line) - len(line.lstrip()) <= header_indent:
            current = None  # back to prose at the header's level: the section ended
            continue
        sections[current][1].append(line)
    return sections


def _split_names(text: str) -> list:
    return [name.strip().strip("`").lstrip("*") for name in text.split(",") if name.strip()]


def parse_entries(lines) -> dict:
    """``{name: description}`` of an Args/Attributes section's lines (continuations joined).

    A long list of names may wrap: ``a, b,`` then, indented, ``c, d: shared text``.
    """
    entries = {}
    indent = None
    names: list = []
    pending: list = []  # names of a list that wrapped onto the next line
    for line in lines:
        if not line.strip():
            continue
        depth = len(line) - len(line.lstrip())
        indent = depth if indent is None else indent
        text = line.strip()
        wrapped = _NAMES_WRAP.match(text)
        if (depth <= indent or pending) and wrapped:
            pending = (pending if depth > indent else []) + _split_names(wrapped.group(1))
            names = []
            continue
        match = _ENTRY.match(text) if depth <= indent or pending else None
        if match:
            names = (pending if depth > indent else []) + _split_names(match.group("names"))
            pending = []
            for name in names:
                entries[name] = (match.group("desc") or "").strip()
        else:
            pending = []
            for name in names:
                entries[name] = (entries[name] + " " + text).strip()
    return entries


def _own_doc(obj) -> str:
    """The object's own docstring, cleaned; '' for none or a dataclass's generated one."""
    doc = obj.__doc__ if isinstance(obj, type) else getattr(obj, "__doc__", None)
    if not doc or not doc.strip():
        return ""
    if isinstance(obj, type) and dataclasses.is_dataclass(obj) and doc.startswith(obj.__name__ + "("):
        return ""
    return inspect.cleandoc(doc)


def _annotation_text(annotation) -> str:
    if annotation is inspect.Parameter.empty:
        return ""
    if isinstance(annotation, str):
        return annotation.strip("'\"")
    return getattr(annotation, "__name__", repr(annotation))


def _is_array(name: str, annotation) -> bool:
    text = _annotation_text(annotation).strip()
    if _ARRAY_ANNOTATION.match(text):
        return True
    return name in ARRAY_NAMES and not _SCALAR_ANNOTATION.match(text)


def _returns_value(func) -> bool:
    """Whether ``func``'s own body has ``return <value>`` or ``yield`` (nested defs excluded)."""
    try:
        source = textwrap.dedent(inspect.getsource(func))
        tree = ast.parse(source)
    except (OSError, TypeError, SyntaxError):
        return True  # cannot tell: ask for a Returns section
    definition = next((node for node in ast.walk(tree)
                       if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))), None)
    if definition is None:
        return True
    if isinstance(definition, ast.Lambda):
        return True
    stack = list(definition.body)
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            continue
        if isinstance(node, (ast.Yield, ast.YieldFrom)):
            return True
        if isinstance(node, ast.Return) and node.value is not None and not (
                isinstance(node.value, ast.Constant) and node.value.value is None):
            return True
        stack.extend(ast.iter_child_nodes(node))
    return False


# --- the rule ---------------------------------------------------------------------------------

def _check_entries(what, entries, wanted, problems):
    """``wanted``: [(name, is_array)]; every name documented, arrays with a shape."""
    for name, is_array in wanted:
        if name not in entries:
            problems.append(f"{what} does not document {name!r}")
        elif is_array and not SHAPE.search(entries[name]):
            problems.append(f"{what} entry {name!r} gives no shape, e.g. '(n, 3)', '(n,)', '()' "
                            f"or 'scalar': {entries[name]!r}")


def _function_problems(func, doc, skip_first: bool) -> list:
    problems = []
    try:
        signature = inspect.signature(func)
    except (TypeError, ValueError):
        return problems
    parameters = list(signature.parameters.values())
    if skip_first and parameters and parameters[0].name in ("self", "cls"):
        parameters = parameters[1:]
    parameters = [p for p in parameters if not p.name.startswith("_")]
    sections = _sections(doc)
    if parameters:
        args = next((sections[h] for h in _ARGS_HEADERS if h in sections), None)
        if args is None:
            problems.append("has parameters " + ", ".join(p.name for p in parameters)
                            + " but no 'Args:' section")
        else:
            entries = parse_entries(args[1])
            _check_entries("Args", entries,
                           [(p.name, _is_array(p.name, p.annotation)) for p in parameters], problems)
            stale = sorted(set(entries) - {p.name for p in parameters})
            if stale:
                problems.append("Args documents " + ", ".join(map(repr, stale))
                                + ", which the signature does not have")
    if _returns_value(func):
        returns = next((sections[h] for h in _RETURN_HEADERS if h in sections), None)
        if returns is None or not (returns[0] or any(line.strip() for line in returns[1])):
            problems.append("returns a value but has no 'Returns:' section")
        elif _ARRAY_ANNOTATION.match(_annotation_text(signature.return_annotation).strip()) and \
                not SHAPE.search(" ".join([returns[0]] + returns[1])):
            problems.append("returns an array but its 'Returns:' section gives no shape")
    return problems


def _own_constructor(cls) -> bool:
    """Whether a jaxrb class in ``cls``'s MRO defines ``__init__`` or ``__new__`` (dataclasses
    and NamedTuples do), so that its signature is ours to document."""
    return any(("__init__" in vars(klass) or "__new__" in vars(klass)) and _in_jaxrb(klass)
               for klass in cls.__mro__)


def _class_problems(cls, doc) -> list:
    problems = []
    init = vars(cls).get("__init__")
    init_doc = _own_doc(init) if inspect.isfunction(init) else ""
    entries = {}
    for text in (doc, init_doc):
        sections = _sections(text)
        for header in _CLASS_HEADERS:
            if header in sections:
                entries.update(parse_entries(sections[header][1]))
    fields = {f.name: f.type for f in dataclasses.fields(cls)} if dataclasses.is_dataclass(cls) else {}
    try:
        parameters = [p for p in inspect.signature(cls).parameters.values()
                      if not p.name.startswith("_") and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
    except (TypeError, ValueError):
        parameters = []
    if not _own_constructor(cls):
        parameters = []  # e.g. an exception or enum taking its base class's arguments
    wanted = {p.name: _is_array(p.name, fields.get(p.name, p.annotation)) for p in parameters}
    for name, annotation in fields.items():
        wanted.setdefault(name, _is_array(name, annotation))
    if wanted and not entries:
        problems.append("has constructor parameters/fields " + ", ".join(wanted)
                        + " but no 'Args:' or 'Attributes:' section")
    else:
        _check_entries("Attributes/Args", entries, list(wanted.items()), problems)
    return problems


def docstring_problems(obj, *, method: bool = False) -> list:
    """Everything wrong with ``obj``'s docstring under the rule in the module docstring."""
    if isinstance(obj, types.ModuleType):
        return [] if _own_doc(obj) else ["has no module docstring"]
    if isinstance(obj, property):
        return [] if _own_doc(obj.fget) else ["property has no docstring"]
    if isinstance(obj, (staticmethod, classmethod)):
        return docstring_problems(obj.__func__, method=isinstance(obj, classmethod))
    doc = _own_doc(obj)
    if not doc:
        return ["has no docstring"]
    if isinstance(obj, type):
        return _class_problems(obj, doc)
    return _function_problems(inspect.unwrap(obj), doc, skip_first=method)


# --- walking the public API -------------------------------------------------------------------

def _in_jaxrb(obj) -> bool:
    module = getattr(obj, "__module__", None) or ""
    return module == "jaxrb" or module.startswith("jaxrb.")


def _is_symbol(obj) -> bool:
    return callable(obj) and (inspect.isclass(obj) or inspect.isfunction(inspect.unwrap(obj)))


def _public_modules():
    """(modules, import errors): the public modules, optional ones only if present."""
    modules, errors = [], []
    names = ["jaxrb." + name for name in PUBLIC_MODULES]
    names += ["jaxrb." + name for name in OPTIONAL_MODULES
              if importlib.util.find_spec("jaxrb." + name) is not None]
    names += [value.__name__ for value in (getattr(jaxrb, n) for n in jaxrb.__all__)
              if isinstance(value, types.ModuleType) and value.__name__ not in names]
    for name in names:
        try:
            modules.append(importlib.import_module(name))
        except Exception as error:  # noqa: BLE001  (reported as a failing test below)
            errors.append((name, f"{type(error).__name__}: {error}"))
    return modules, errors


def public_symbols():
    """[(qualified name, object, is_method)] of the public API, in a stable order."""
    modules, _ = _public_modules()
    found = {}

    def add_class_members(cls, prefix):
        for name, member in vars(cls).items():
            if name.startswith("_"):
                continue
            if isinstance(member, property) or isinstance(member, (staticmethod, classmethod)) \
                    or inspect.isfunction(member):
                found.setdefault(f"{prefix}.{name}", (member, True))

    def add(obj, qualified):
        if not _is_symbol(obj) or not _in_jaxrb(obj):
            return
        if qualified in found:
            return
        found[qualified] = (obj, False)
        if inspect.isclass(obj):
            add_class_members(obj, qualified)

    for module in modules:
        found.setdefault(module.__name__, (module, False))
        for name, obj in vars(module).items():
            if not name.startswith("_") and getattr(obj, "__module__", None) == module.__name__:
                add(obj, f"{module.__name__}.{name}")
    for name in jaxrb.__all__:
        obj = getattr(jaxrb, name)
        if _is_symbol(obj) and _in_jaxrb(obj):
            add(obj, f"{obj.__module__}.{getattr(obj, '__qualname__', name)}")
    return [(name, obj, is_method) for name, (obj, is_method) in sorted(found.items())]


SYMBOLS = public_symbols()


@pytest.mark.parametrize("qualified, obj, is_method", SYMBOLS, ids=[name for name, _, _ in SYMBOLS])
def test_public_docstring(qualified, obj, is_method):
    problems = docstring_problems(obj, method=is_method)
    assert not problems, f"{qualified}: " + "; ".join(problems)


def test_public_modules_import():
    _, errors = _public_modules()
    assert not errors, "public modules that exist but fail to import: " + "; ".join(
        f"{name}: {why}" for name, why in errors)


def test_walker_finds_the_api():
    names = {name for name, _, _ in SYMBOLS}
    for expected in ("jaxrb.physics.step.make_step", "jaxrb.physics.step.rollout", "jaxrb.model.types.State",
                     "jaxrb.model.types.Model.summary", "jaxrb.scene.Scene.add_body",
                     "jaxrb.physics.collision.pairs.detect", "jaxrb.physics.collision.pairs.ContactSet",
                     "jaxrb.math.quaternion.multiply", "jaxrb.fit.sysid.fit", "jaxrb.sweep.batch_params"):
        assert expected in names, expected
    # Re-exported third-party names (types.Array is jax.Array) and private names are left out.
    assert all(_in_jaxrb(obj) for _, obj, is_method in SYMBOLS
               if not is_method and not isinstance(obj, types.ModuleType))
    assert not any(name.rsplit(".", 1)[-1].startswith("_") for name in names)
    assert "jaxrb.model.types.Array" not in names and "jaxrb.fit.sysid.rollout" not in names
    for optional in OPTIONAL_MODULES:
        if importlib.util.find_spec("jaxrb." + optional) is not None:
            assert any(name.startswith(f"jaxrb.{optional}.") for name in names), optional
    assert len(SYMBOLS) > 80


# --- the checker can fail ---------------------------------------------------------------------

def _no_doc(pos):
    return pos


def _no_args(pos, vel):
    """Advance positions."""
    return pos + vel


def _missing_one(pos, vel):
    """Advance positions.

    Args:
        pos: (n, 3) positions.

    Returns:
        (n, 3) new positions.
    """
    return pos + vel


def _no_shape(pos, dt):
    """Advance positions.

    Args:
        pos: world positions (m).
        dt: time step (s).

    Returns:
        (n, 3) new positions.
    """
    return pos * dt


def _stale(pos):
    """Advance positions.

    Args:
        pos: (n, 3) positions.
        vel: (n, 3) a parameter that was renamed away.
    """


def _no_returns(pos):
    """Double positions.

    Args:
        pos: (n, 3) positions.
    """
    return 2 * pos


def _good(pos, vel, linear_damping, angular_damping, *args, **kwargs):
    """Advance positions.

    Args:
        pos: (n, 3) world positions (m).
        vel: (n, 3) velocities,
            continued on a second line.
        linear_damping, angular_damping: rates in 1/s.
        *args, **kwargs: ignored.

    Returns:
        (n, 3) new positions.
    """
    return pos + vel


def _returns_nothing(pos):
    """Check positions.

    Args:
        pos: (n,) positions.
    """
    if pos is None:
        return
    return None


@dataclasses.dataclass(frozen=True)
class _BadFields:
    """A record whose array fields have no shape.

    Attributes:
        pos: positions.
        rest_length: spring rest lengths.
        label: a name.
    """

    pos: Array  # noqa: F821  (a string under postponed evaluation, never resolved)
    rest_length: Array  # noqa: F821
    label: str


@dataclasses.dataclass(frozen=True)
class _UndocumentedDataclass:
    pos: Array  # noqa: F821


class _PlainError(ValueError):
    """An error that takes ValueError's arguments: nothing of its own to document."""


class _GoodClass:
    """A thing with documented arguments.

    Args:
        normal: (3,) unit normal.
        friction: Coulomb coefficient.
    """

    def __init__(self, normal, friction):
        self.normal, self.friction = normal, friction

    def scaled(self, factor):
        """Scaled normal.

        Args:
            factor: multiplier.

        Returns:
            (3,) the scaled normal.
        """
        return self.normal * factor


@pytest.mark.parametrize("bad, expected", [
    (_no_doc, "has no docstring"),
    (_no_args, "no 'Args:' section"),
    (_missing_one, "does not document 'vel'"),
    (_no_shape, "entry 'pos' gives no shape"),
    (_no_returns, "no 'Returns:' section"),
    (_stale, "documents 'vel', which the signature does not have"),
    (_BadFields, "entry 'pos' gives no shape"),
    (_UndocumentedDataclass, "has no docstring"),
])
def test_checker_rejects_bad_docstrings(bad, expected):
    problems = docstring_problems(bad)
    assert any(expected in problem for problem in problems), problems


def test_checker_shape_rule_is_specific():
    assert any("'dt' gives no shape" in p for p in docstring_problems(_no_shape))
    # rest_length is no known array name: its ``Array`` annotation asks for the shape.
    assert any("'rest_length' gives no shape" in p for p in docstring_problems(_BadFields))
    # The non-array field of _BadFields is not asked for a shape.
    assert not any("'label'" in p for p in docstring_problems(_BadFields))


def test_sections_ignore_headers_inside_entries():
    def documented(pos, vel):
        """Advance.

        Args:
            pos: (n, 3) positions, e.g.
                Example: pos = zeros((n, 3)).
            vel: (n, 3) velocities.

        Returns:
            (n, 3) new positions.
        """
        return pos + vel

    assert docstring_problems(documented) == []


def test_checker_accepts_good_docstrings():
    assert docstring_problems(_good) == []
    assert docstring_problems(_returns_nothing) == []
    assert docstring_problems(_GoodClass) == []
    assert docstring_problems(_PlainError) == []
    assert docstring_problems(_GoodClass.scaled, method=True) == []


@pytest.mark.parametrize("text, is_shape", [
    ("(n, 3) positions", True), ("(dim,) gravity", True), ("(T, n, 4) quaternions", True),
    ("(..., 3) vectors", True), ("() time step", True), ("(...) angles", True),
    ("(n + 1, dim) padded", True), ("a scalar in 2D", True),
    ("distance (m)", False), ("mass (kg), positive", False), ("positions", False),
])
def test_shape_pattern(text, is_shape):
    assert bool(SHAPE.search(text)) == is_shape


def test_entries_parser():
    entries = parse_entries(textwrap.dedent("""\
        pos: (n, 3) positions
            over two lines.
        linear_damping, angular_damping: rates.
        **fields: name -> values.
        ``every``: keep every k-th.
        contact_margin, bounce_threshold,
            contact_hertz: initial values
            of Params fields.
    """).splitlines())
    assert entries["pos"] == "(n, 3) positions over two lines."
    assert entries["linear_damping"] == entries["angular_damping"] == "rates."
    assert entries["fields"] == "name -> values."
    assert entries["every"] == "keep every k-th."
    assert entries["contact_margin"] == entries["contact_hertz"] == "initial values of Params fields."
    assert set(entries) == {"pos", "linear_damping", "angular_damping", "fields", "every",
                            "contact_margin", "bounce_threshold", "contact_hertz"}
