"""Shape classes and their mass properties.

Every shape is a frozen, hashable dataclass (geometry lives in the static
``Model``). ``mass_properties(shape, density)`` returns the mass, the centre of
mass in the shape's own frame and the inertia about that centre, in closed form
for primitives and as I = Id·tr(C) − C (C = Σ m x xᵀ) for point masses.

Problems are raised as ``ShapeError(field, message)``; the scene builder turns
them into a ``ValueError`` that also names the body.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np


class ShapeError(ValueError):
    """A bad shape field; ``field`` names it so callers can say which body."""

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


def _positive(field, value):
    array = _finite_array(field, value)
    if np.any(array <= 0.0):
        raise ShapeError(field, f"must be positive (a zero-size shape has no volume), got {array.tolist()}")
    return array


def _as_tuple(array):
    return tuple(np.asarray(array, dtype=np.float64).ravel().tolist()) if np.ndim(array) <= 1 else \
        tuple(tuple(row) for row in np.asarray(array, dtype=np.float64).tolist())


@dataclasses.dataclass(frozen=True)
class Sphere:
    """3D sphere of ``radius`` centred on the body origin."""

    radius: float
    dims = (3,)


@dataclasses.dataclass(frozen=True)
class Circle:
    """2D disc of ``radius`` centred on the body origin."""

    radius: float
    dims = (2,)


@dataclasses.dataclass(frozen=True)
class Box:
    """Box centred on the body origin: ``half_extents`` has 3 entries in 3D, 2 in 2D."""

    half_extents: tuple

    def __post_init__(self):
        object.__setattr__(self, "half_extents", _as_tuple(np.atleast_1d(
            np.asarray(self.half_extents, dtype=np.float64))))

    @property
    def dims(self):
        return (len(self.half_extents),)


@dataclasses.dataclass(frozen=True)
class Capsule:
    """3D capsule: a segment of ``half_length`` along the body z axis, swept by ``radius``."""

    radius: float
    half_length: float
    dims = (3,)


@dataclasses.dataclass(frozen=True)
class Polygon:
    """2D convex polygon; ``vertices`` (k, 2) in the body frame, either winding.

    Stored counter-clockwise. Its centre of mass need not be the body origin.
    """

    vertices: tuple
    dims = (2,)

    def __post_init__(self):
        vertices = _finite_array("vertices", self.vertices)
        if vertices.ndim != 2 or vertices.shape[1] != 2 or vertices.shape[0] < 3:
            raise ShapeError("vertices", f"must have shape (k, 2) with k >= 3, got {vertices.shape}")
        if _polygon_signed_area(vertices) < 0.0:
            vertices = vertices[::-1]
        object.__setattr__(self, "vertices", _as_tuple(vertices))


@dataclasses.dataclass(frozen=True)
class PointMasses:
    """A body made of point masses, as in the classic formulation.

    ``points`` (k, dim) are given in the body frame; ``masses`` (k,). Mass,
    centre of mass and inertia are computed from them.
    """

    points: tuple
    masses: tuple

    def __post_init__(self):
        points = _finite_array("points", self.points)
        if points.ndim != 2 or points.shape[1] not in (2, 3) or points.shape[0] < 1:
            raise ShapeError("points", f"must have shape (k, 2) or (k, 3), got {points.shape}")
        masses = _finite_array("masses", self.masses)
        if masses.shape != (points.shape[0],):
            raise ShapeError("masses", f"must have shape ({points.shape[0]},) to match points, "
                             f"got {masses.shape}")
        if np.any(masses <= 0.0):
            raise ShapeError("masses", f"must all be positive, got {masses.tolist()}")
        object.__setattr__(self, "points", _as_tuple(points))
        object.__setattr__(self, "masses", _as_tuple(masses))

    @property
    def dims(self):
        return (len(self.points[0]),)


SHAPES = (Sphere, Circle, Box, Capsule, Polygon, PointMasses)


def _polygon_signed_area(vertices):
    x, y = vertices[:, 0], vertices[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _check_convex(vertices):
    edges = np.roll(vertices, -1, axis=0) - vertices
    turns = edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
    scale = float(np.max(np.abs(vertices))) ** 2
    if np.any(turns <= 1e-12 * scale):
        raise ShapeError("vertices", "must form a strictly convex polygon with non-zero area "
                         "(no repeated, collinear or reflex vertices)")


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
    """Area-density mass, centroid and polar moment about the centroid of a CCW polygon."""
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
    # Second moment is about the origin; shift to the centroid (parallel axis).
    return mass, centroid, density * second_moment - mass * float(centroid @ centroid)


def mass_properties(shape, density: float, dim: int):
    """Mass, centre of mass (dim,) in the shape frame and inertia about it.

    Args:
        shape: one of the shape classes.
        density: mass per volume (3D) or per area (2D); ignored for PointMasses.
        dim: 2 or 3.

    Returns:
        (mass, com (dim,), inertia (3, 3) in 3D or float in 2D).
    """
    if isinstance(shape, PointMasses):
        mass, com, inertia, _ = point_mass_properties(shape.points, shape.masses)
        return mass, com, inertia
    origin = np.zeros(dim)
    if isinstance(shape, Sphere):
        radius = float(_positive("radius", shape.radius))
        mass = density * 4.0 / 3.0 * math.pi * radius ** 3
        return mass, origin, np.eye(3) * 0.4 * mass * radius ** 2
    if isinstance(shape, Circle):
        radius = float(_positive("radius", shape.radius))
        mass = density * math.pi * radius ** 2
        return mass, origin, 0.5 * mass * radius ** 2
    if isinstance(shape, Box):
        half = _positive("half_extents", shape.half_extents)
        mass = density * float(np.prod(2.0 * half))
        if dim == 2:
            return mass, origin, mass / 3.0 * float(half @ half)
        sq = half ** 2
        return mass, origin, np.diag([sq[1] + sq[2], sq[0] + sq[2], sq[0] + sq[1]]) * mass / 3.0
    if isinstance(shape, Capsule):
        radius = float(_positive("radius", shape.radius))
        half_length = float(_finite_array("half_length", shape.half_length))
        if half_length < 0.0:
            raise ShapeError("half_length", f"must be >= 0, got {half_length}")
        cylinder = density * math.pi * radius ** 2 * 2.0 * half_length
        caps = density * 4.0 / 3.0 * math.pi * radius ** 3
        axial = cylinder * radius ** 2 / 2.0 + caps * 0.4 * radius ** 2
        # Each hemisphere's centre of mass sits 3r/8 beyond the segment end.
        transverse = (cylinder * (radius ** 2 / 4.0 + half_length ** 2 / 3.0)
                      + caps * (0.4 * radius ** 2 + half_length ** 2 + 0.75 * half_length * radius))
        return cylinder + caps, origin, np.diag([transverse, transverse, axial])
    if isinstance(shape, Polygon):
        vertices = np.asarray(shape.vertices)
        _check_convex(vertices)
        return _polygon_properties(vertices, density)
    raise ShapeError("shape", f"unknown shape type {type(shape).__name__}")


def check_inertia(inertia, dim: int, tolerance: float = 1e-9):
    """Validate an inertia about the centre of mass; raise ShapeError('inertia', why) if bad.

    3D: symmetric, positive definite (no zero principal moment, e.g. collinear
    point masses or a single point) and obeying the triangle inequality
    I1 + I2 >= I3 on principal moments. 2D: a positive scalar.
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
