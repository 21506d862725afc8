"""Shape classes and their mass properties.

Every shape is a frozen, hashable dataclass (geometry lives in the static
``Model``). ``mass_properties(shape, density)`` returns the mass, the centre of
mass in the shape's own frame and the inertia about that centre, in closed form
for primitives and as I = Id·tr(C) − C (C = Σ m x xᵀ) for point masses.

Constructors only normalise what they are given (numbers to Python floats,
arrays to nested tuples, polygons to counter-clockwise order) so that shapes
stay hashable; they do not reject bad values. ``validate_shape(shape)`` (run by
``mass_properties`` and by ``Scene.add_body``) checks them and raises
``ShapeError(field, message)``, which the scene builder turns into a
``ValueError`` that also names the body.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np


class ShapeError(ValueError):
    """A bad shape field; ``field`` names it so callers can say which body.

    Args:
        field: name of the offending field (e.g. ``"radius"``, ``"inertia"``).
        message: what is wrong with it.
    """

    def __init__(self, field: str, message: str):
        super().__init__(f"field {field!r}: {message}")
        self.field = field
        self.message = message


def _finite_array(field, value, shape=None):
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ShapeError(field, f"must be numeric, got {value!r}") from error
    if shape is not None and array.shape != shape:
        raise ShapeError(field, f"must have shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ShapeError(field, f"must be finite, got {array.tolist()}")
    return array


def _positive(field, value, shape=None):
    array = _finite_array(field, value, shape)
    if np.any(array <= 0.0):
        raise ShapeError(field, f"must be positive (a zero-size shape has no volume), got {array.tolist()}")
    return array


def _as_tuple(array):
    return tuple(np.asarray(array, dtype=np.float64).ravel().tolist()) if np.ndim(array) <= 1 else \
        tuple(tuple(row) for row in np.asarray(array, dtype=np.float64).tolist())


def _normalised(value, ndim):
    """``value`` as a Python float (ndim 0) or nested tuple (ndim 1, 2) when it is a numeric
    array of that rank; otherwise unchanged, for ``validate_shape`` to reject with a message."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return value
    if array.ndim != ndim:
        return value
    return float(array) if ndim == 0 else _as_tuple(array)


def _set(shape, field, value):
    object.__setattr__(shape, field, value)


@dataclasses.dataclass(frozen=True)
class Sphere:
    """3D sphere of ``radius`` centred on the body origin.

    Attributes:
        radius: radius (m), > 0.
    """

    radius: float
    dims = (3,)

    def __post_init__(self):
        _set(self, "radius", _normalised(self.radius, 0))


@dataclasses.dataclass(frozen=True)
class Circle:
    """2D disc of ``radius`` centred on the body origin.

    Attributes:
        radius: radius (m), > 0.
    """

    radius: float
    dims = (2,)

    def __post_init__(self):
        _set(self, "radius", _normalised(self.radius, 0))


@dataclasses.dataclass(frozen=True)
class Box:
    """Box centred on the body origin: ``half_extents`` has 3 entries in 3D, 2 in 2D.

    Attributes:
        half_extents: (3,) in 3D or (2,) in 2D half side lengths (m) along the
            body axes, each > 0.
    """

    half_extents: tuple

    def __post_init__(self):
        _set(self, "half_extents", _normalised(self.half_extents, 1))

    @property
    def dims(self):
        """Dimensions this box can be used in: ``(3,)`` or ``(2,)`` from ``half_extents``."""
        return (np.shape(self.half_extents)[0],) if np.ndim(self.half_extents) == 1 else ()


@dataclasses.dataclass(frozen=True)
class Capsule:
    """3D capsule: a segment of ``half_length`` along the body z axis, swept by ``radius``.

    Attributes:
        radius: radius of the swept sphere (m), > 0.
        half_length: half the length of the core segment (m), >= 0 (0 is a sphere).
    """

    radius: float
    half_length: float
    dims = (3,)

    def __post_init__(self):
        _set(self, "radius", _normalised(self.radius, 0))
        _set(self, "half_length", _normalised(self.half_length, 0))


@dataclasses.dataclass(frozen=True)
class Polygon:
    """2D convex polygon; ``vertices`` (k, 2) in the body frame, either winding.

    Stored counter-clockwise. Its centre of mass need not be the body origin.

    Attributes:
        vertices: (k, 2) body-frame corners (m), k >= 3, strictly convex.
    """

    vertices: tuple
    dims = (2,)

    def __post_init__(self):
        vertices = _normalised(self.vertices, 2)
        if isinstance(vertices, tuple) and np.shape(vertices)[1:] == (2,) \
                and np.all(np.isfinite(vertices)) and _polygon_signed_area(np.asarray(vertices)) < 0.0:
            vertices = vertices[::-1]
        _set(self, "vertices", vertices)


@dataclasses.dataclass(frozen=True)
class PointMasses:
    """A body made of point masses, as in the classic formulation.

    Mass, centre of mass and inertia are computed from the points.

    Attributes:
        points: (k, dim) body-frame positions (m); dim 3 or 2.
        masses: (k,) positive masses (kg).
    """

    points: tuple
    masses: tuple

    def __post_init__(self):
        _set(self, "points", _normalised(self.points, 2))
        _set(self, "masses", _normalised(self.masses, 1))

    @property
    def dims(self):
        """Dimensions this body can be used in: ``(points.shape[1],)``."""
        return (np.shape(self.points)[1],) if np.ndim(self.points) == 2 else ()


SHAPES = (Sphere, Circle, Box, Capsule, Polygon, PointMasses)


def _polygon_signed_area(vertices):
    vertices = vertices - vertices.mean(axis=0)  # about the vertex mean: no cancellation far out
    x, y = vertices[:, 0], vertices[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _check_convex(vertices):
    """Raise unless ``vertices`` (k, 2), counter-clockwise, bound a strictly convex polygon.

    Every turn must be to the left by a non-negligible angle and the turns must add up
    to one full revolution (a star such as a pentagram turns left everywhere but twice
    round). Tolerances are relative to the polygon's own size, not its distance from
    the origin.
    """
    message = ("must form a strictly convex polygon with non-zero area "
               "(no repeated, collinear or reflex vertices, not self-intersecting)")
    edges = np.roll(vertices, -1, axis=0) - vertices
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    size = float(np.max(np.hypot(*(vertices - vertices.mean(axis=0)).T)))
    if not size > 0.0 or np.any(lengths <= 1e-9 * size):
        raise ShapeError("vertices", message)
    following = np.roll(edges, -1, axis=0)
    turns = edges[:, 0] * following[:, 1] - edges[:, 1] * following[:, 0]
    dots = np.sum(edges * following, axis=1)
    if np.any(turns <= 1e-9 * lengths * np.roll(lengths, -1)):
        raise ShapeError("vertices", message)
    if abs(float(np.sum(np.arctan2(turns, dots))) - 2.0 * math.pi) > 1e-6:
        raise ShapeError("vertices", message)


def point_mass_properties(points, masses):
    """Mass properties of a set of point masses.

    Args:
        points: (k, dim) positions in the body frame.
        masses: (k,) positive masses.

    Returns:
        (total mass, centre of mass (dim,), inertia about it: (3, 3) in 3D or a
        float in 2D, body-frame points relative to the centre of mass (k, dim)).
    """
    points = np.asarray(points, dtype=np.float64)
    masses = np.asarray(masses, dtype=np.float64)
    total = float(np.sum(masses))
    com = masses @ points / total
    rel = points - com
    if points.shape[1] == 2:
        return total, com, float(np.sum(masses * np.sum(rel * rel, axis=1))), rel
    covariance = (rel * masses[:, None]).T @ rel
    return total, com, np.eye(3) * np.trace(covariance) - covariance, rel


def _polygon_properties(vertices, density):
    """Area-density mass, centroid and polar moment about the centroid of a CCW polygon.

    The sums are taken about the vertex mean, not the frame origin, so a small polygon
    far from the origin does not lose its digits to cancellation.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    reference = vertices.mean(axis=0)
    vertices = vertices - reference
    area = centroid_x = centroid_y = second_moment = 0.0
    count = len(vertices)
    for index in range(count):
        (x0, y0), (x1, y1) = vertices[index], vertices[(index + 1) % count]
        cross = x0 * y1 - x1 * y0
        area += 0.5 * cross
        centroid_x += (x0 + x1) * cross / 6.0
        centroid_y += (y0 + y1) * cross / 6.0
        second_moment += cross * (x0 * x0 + x0 * x1 + x1 * x1 + y0 * y0 + y0 * y1 + y1 * y1) / 12.0
    centroid = np.array([centroid_x, centroid_y]) / area
    mass = density * area
    # Second moment is about the reference point; shift to the centroid (parallel axis).
    return mass, reference + centroid, density * second_moment - mass * float(centroid @ centroid)


def validate_shape(shape):
    """Check a shape's own fields; raise ``ShapeError(field, why)`` if any is bad.

    Zero-size shapes (a radius or half-extent <= 0), non-finite numbers, arrays of the
    wrong shape, polygons that are not strictly convex and point-mass sets whose
    ``masses`` do not match their ``points`` are rejected. Whether the inertia that
    results is singular is :func:`check_inertia`'s job.

    Args:
        shape: an instance of one of the shape classes.

    Raises:
        ShapeError: naming the bad field.
    """
    if isinstance(shape, (Sphere, Circle)):
        _positive("radius", shape.radius, ())
    elif isinstance(shape, Box):
        half = _finite_array("half_extents", shape.half_extents)
        if half.shape not in ((2,), (3,)):
            raise ShapeError("half_extents", f"must have shape (2,) in 2D or (3,) in 3D, got {half.shape}")
        _positive("half_extents", half)
    elif isinstance(shape, Capsule):
        _positive("radius", shape.radius, ())
        if float(_finite_array("half_length", shape.half_length, ())) < 0.0:
            raise ShapeError("half_length", f"must be >= 0, got {shape.half_length}")
    elif isinstance(shape, Polygon):
        vertices = _finite_array("vertices", shape.vertices)
        if vertices.ndim != 2 or vertices.shape[1] != 2 or vertices.shape[0] < 3:
            raise ShapeError("vertices", f"must have shape (k, 2) with k >= 3, got {vertices.shape}")
        _check_convex(vertices)
    elif isinstance(shape, PointMasses):
        points = _finite_array("points", shape.points)
        if points.ndim != 2 or points.shape[1] not in (2, 3) or points.shape[0] < 1:
            raise ShapeError("points", f"must have shape (k, 2) or (k, 3) with k >= 1, got {points.shape}")
        masses = _finite_array("masses", shape.masses)
        if masses.shape != (points.shape[0],):
            raise ShapeError("masses", f"must have shape ({points.shape[0]},) to match points, "
                             f"got {masses.shape}")
        if np.any(masses <= 0.0):
            raise ShapeError("masses", f"must all be positive, got {masses.tolist()}")
    else:
        raise ShapeError("shape", f"unknown shape type {type(shape).__name__}; expected one of "
                         + ", ".join(cls.__name__ for cls in SHAPES))


def mass_properties(shape, density: float, dim: int):
    """Mass, centre of mass (dim,) in the shape frame and inertia about it.

    Args:
        shape: one of the shape classes.
        density: mass per volume (3D) or per area (2D); ignored for PointMasses.
        dim: 2 or 3.

    Returns:
        (mass, com (dim,), inertia (3, 3) in 3D or float in 2D).

    Raises:
        ShapeError: if :func:`validate_shape` rejects the shape or it is not a ``dim``-D shape.
    """
    validate_shape(shape)
    if dim not in shape.dims:
        raise ShapeError("shape", f"{type(shape).__name__} is not a {dim}D shape")
    if isinstance(shape, PointMasses):
        mass, com, inertia, _ = point_mass_properties(shape.points, shape.masses)
        return mass, com, inertia
    origin = np.zeros(dim)
    if isinstance(shape, Sphere):
        radius = float(shape.radius)
        mass = density * 4.0 / 3.0 * math.pi * radius ** 3
        return mass, origin, np.eye(3) * 0.4 * mass * radius ** 2
    if isinstance(shape, Circle):
        radius = float(shape.radius)
        mass = density * math.pi * radius ** 2
        return mass, origin, 0.5 * mass * radius ** 2
    if isinstance(shape, Box):
        half = np.asarray(shape.half_extents, dtype=np.float64)
        mass = density * float(np.prod(2.0 * half))
        if dim == 2:
            return mass, origin, mass / 3.0 * float(half @ half)
        sq = half ** 2
        return mass, origin, np.diag([sq[1] + sq[2], sq[0] + sq[2], sq[0] + sq[1]]) * mass / 3.0
    if isinstance(shape, Capsule):
        radius, half_length = float(shape.radius), float(shape.half_length)
        cylinder = density * math.pi * radius ** 2 * 2.0 * half_length
        caps = density * 4.0 / 3.0 * math.pi * radius ** 3
        axial = cylinder * radius ** 2 / 2.0 + caps * 0.4 * radius ** 2
        # Each hemisphere's centre of mass sits 3r/8 beyond the segment end.
        transverse = (cylinder * (radius ** 2 / 4.0 + half_length ** 2 / 3.0)
                      + caps * (0.4 * radius ** 2 + half_length ** 2 + 0.75 * half_length * radius))
        return cylinder + caps, origin, np.diag([transverse, transverse, axial])
    if isinstance(shape, Polygon):
        return _polygon_properties(np.asarray(shape.vertices, dtype=np.float64), density)
    raise ShapeError("shape", f"unknown shape type {type(shape).__name__}")


def check_inertia(inertia, dim: int, tolerance: float = 1e-9):
    """Validate an inertia about the centre of mass; raise ShapeError('inertia', why) if bad.

    3D: symmetric, positive definite (no zero principal moment, e.g. collinear
    point masses or a single point) and obeying the triangle inequality
    I1 + I2 >= I3 on principal moments. 2D: a positive scalar.

    Args:
        inertia: (3, 3) body-frame tensor in 3D, a scalar moment in 2D.
        dim: 2 or 3.
        tolerance: relative tolerance of the symmetry and definiteness tests.

    Raises:
        ShapeError: with field ``"inertia"``, saying why.
    """
    if dim == 2:
        value = float(inertia)
        if not value > 0.0:
            raise ShapeError("inertia", f"is singular: moment {value} must be positive "
                             "(a single point mass has no rotational inertia)")
        return
    inertia = np.asarray(inertia, dtype=np.float64)
    scale = max(float(np.max(np.abs(inertia))), 1e-300)
    if np.max(np.abs(inertia - inertia.T)) > tolerance * scale:
        raise ShapeError("inertia", f"must be symmetric, got {inertia.tolist()}")
    principal = np.linalg.eigvalsh(inertia)
    if principal[0] <= tolerance * scale:
        raise ShapeError("inertia", f"is singular or not positive definite: principal moments "
                         f"{principal.tolist()} (collinear or coincident point masses have a zero "
                         "moment about their line)")
    if principal[0] + principal[1] < principal[2] * (1.0 - 1e-7):
        raise ShapeError("inertia", f"principal moments {principal.tolist()} violate the triangle "
                         "inequality I1 + I2 >= I3 that every real mass distribution obeys")
