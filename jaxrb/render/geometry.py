"""The numbers behind the pictures, without matplotlib: each body's outline or mesh in
its shape frame, the axis limits, what of each plane shows in the view, arrows."""

from __future__ import annotations

import itertools

import numpy as np

from jaxrb.model.shapes import Box, Capsule, Circle, PointMasses, Polygon, Sphere
from jaxrb.model.types import Model

# Mesh resolution of spheres and capsules: coarse keeps 3D frames fast.
_AROUND, _RINGS = 12, 8
_BOX_FACES = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1],
                       [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])


# --------------------------------------------------------------------------------------
# Body geometry in the shape frame


def _revolution_faces(radius: float, half_length: float) -> tuple:
    """Quads (F, 4, 3) of a capsule along z (a sphere when half_length is 0) and a stripe
    index (F,) that alternates around the axis, so spin about any axis shows."""
    half = _RINGS // 2
    bottom = np.linspace(-np.pi / 2, 0.0, half + 1)
    top = np.linspace(0.0, np.pi / 2, half + 1)
    if half_length > 0.0:
        phi = np.concatenate([bottom, top])
        centre = np.concatenate([np.full(half + 1, -half_length), np.full(half + 1, half_length)])
    else:
        phi = np.concatenate([bottom, top[1:]])
        centre = np.zeros_like(phi)
    ring_z = centre + radius * np.sin(phi)
    ring_r = radius * np.cos(phi)
    theta = np.linspace(0.0, 2.0 * np.pi, _AROUND + 1)
    grid = np.stack([ring_r[:, None] * np.cos(theta)[None], ring_r[:, None] * np.sin(theta)[None],
                     np.broadcast_to(ring_z[:, None], (len(phi), _AROUND + 1))], axis=-1)
    quads = np.stack([grid[:-1, :-1], grid[:-1, 1:], grid[1:, 1:], grid[1:, :-1]], axis=2)
    stripe = np.broadcast_to(np.arange(_AROUND) % 2, quads.shape[:2])
    return quads.reshape(-1, 4, 3), stripe.reshape(-1)


def _box_corners(half_extents) -> np.ndarray:
    half = np.asarray(half_extents, dtype=np.float64)
    signs = np.array(list(itertools.product((-1.0, 1.0), repeat=len(half))))
    return signs * half


class _Geometry:
    """How one body looks in its shape frame.

    Attributes:
        kind: "polygon", "circle", "points", "mesh" or "mass".
        local: (k, dim) outline vertices, points or mesh vertices (flattened).
        faces: (F, 4, 3) mesh quads (3D meshes only).
        stripe: (F,) stripe index of each quad (meshes only).
        radius: circle radius (2D) or 0.
        extent_points: (k, dim) points whose hull, grown by ``pad``, holds the body.
        pad: () radius added around ``extent_points`` for round shapes.
        masses: (k,) point masses, for dot sizes.
        solid: what hides a contact behind it in 3D: ("box", (3,) half extents),
            ("round", radius, half_length) for spheres (0) and capsules along
            z, or None (2D, point masses, bare bodies).
    """

    def __init__(self, shape, dim: int):
        self.faces = self.stripe = self.masses = self.solid = None
        self.radius = self.pad = 0.0
        zero = np.zeros((1, dim))
        if shape is None:
            self.kind, self.local, self.extent_points = "mass", zero, zero
        elif isinstance(shape, PointMasses):
            self.kind = "points"
            self.local = self.extent_points = np.asarray(shape.points, dtype=np.float64)
            self.masses = np.asarray(shape.masses, dtype=np.float64)
        elif dim == 2 and isinstance(shape, (Box, Polygon)):
            self.kind = "polygon"
            if isinstance(shape, Box):
                hx, hy = np.asarray(shape.half_extents, dtype=np.float64)
                self.local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
            else:
                self.local = np.asarray(shape.vertices, dtype=np.float64)
            self.extent_points = self.local
        elif dim == 2 and isinstance(shape, Circle):
            self.kind, self.local, self.extent_points = "circle", zero, zero
            self.radius = self.pad = float(shape.radius)
        elif dim == 3 and isinstance(shape, Box):
            self.kind = "mesh"
            corners = _box_corners(shape.half_extents)
            self.faces = corners[_BOX_FACES]
            self.stripe = np.zeros(len(self.faces), dtype=int)
            self.local = self.extent_points = corners
            self.solid = ("box", np.asarray(shape.half_extents, dtype=np.float64))
        elif dim == 3 and isinstance(shape, (Sphere, Capsule)):
            self.kind = "mesh"
            half_length = float(shape.half_length) if isinstance(shape, Capsule) else 0.0
            self.faces, self.stripe = _revolution_faces(float(shape.radius), half_length)
            self.local = self.faces.reshape(-1, 3)
            self.extent_points = np.array([[0.0, 0.0, -half_length], [0.0, 0.0, half_length]])
            self.pad = float(shape.radius)
            self.solid = ("round", float(shape.radius), half_length)
        else:
            raise ValueError(f"render: cannot draw a {type(shape).__name__} in {dim}D")


def _geometries(model: Model) -> list:
    """A :class:`_Geometry` per body (shape-less bodies when the Model lists no shapes)."""
    shapes = model.shapes if len(model.shapes) == model.num_bodies else (None,) * model.num_bodies
    return [_Geometry(shape, model.dim) for shape in shapes]


def _world(points: np.ndarray, origin: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Shape-frame points (..., dim) to world for one pose."""
    return origin + points @ rotation.T


def _spokes(world: np.ndarray, com: np.ndarray) -> np.ndarray:
    """(dim, 3k) one polyline through k points (k, dim): com -> point, break (nan), com -> next."""
    starts = np.broadcast_to(com, world.shape)
    gap = np.full_like(world, np.nan)
    return np.stack([starts, world, gap], axis=1).reshape(-1, world.shape[1]).T


def _arrow_segments(points: np.ndarray, normals: np.ndarray, length: float) -> np.ndarray:
    """(3k, 2, dim) segments: shaft then two barbs for each of k arrows."""
    tips = points + length * normals
    barb = 0.3 * length
    if points.shape[1] == 2:
        side = np.stack([-normals[:, 1], normals[:, 0]], axis=1)
    else:
        axis = np.eye(3)[np.argmin(np.abs(normals), axis=1)]
        side = np.cross(normals, axis)
        side /= np.maximum(np.linalg.norm(side, axis=1, keepdims=True), 1e-300)
    back = tips - barb * 0.9 * normals
    segments = [np.stack([points, tips], 1),
                np.stack([tips, back + 0.45 * barb * side], 1),
                np.stack([tips, back - 0.45 * barb * side], 1)]
    return np.stack(segments, axis=1).reshape(-1, 2, points.shape[1])


# --------------------------------------------------------------------------------------
# Axis limits


def _auto_extent(model: Model, frames, geometries) -> tuple:
    """(low, high) per axis enclosing every body in every frame of ``frames`` (a
    :class:`jaxrb.render.common._Frames`), nearby planes and a margin."""
    dim = model.dim
    low, high = np.full(dim, np.inf), np.full(dim, -np.inf)
    for index, geom in enumerate(geometries):
        world = frames.origin[:, index, None, :] + np.einsum(
            "fij,kj->fki", frames.rotation[:, index], geom.extent_points)
        world = world[np.all(np.isfinite(world), axis=-1)]
        if world.size:
            low = np.minimum(low, world.min(axis=0) - geom.pad)
            high = np.maximum(high, world.max(axis=0) + geom.pad)
    if not np.all(np.isfinite(low)):
        low, high = -np.ones(dim), np.ones(dim)
    span = float(np.max(high - low))
    scale = span if span > 0.0 else 1.0
    centre = 0.5 * (low + high)
    # Bring in the planes that bodies rest on or move near; far walls would shrink the view.
    for normal, offset in model.planes:
        normal = np.asarray(normal, dtype=np.float64)
        distance = float(normal @ centre - offset)
        if abs(distance) <= 2.0 * scale:
            foot = centre - distance * normal
            band = foot - 0.06 * scale * normal if dim == 2 else foot
            for point in (foot, band):
                low, high = np.minimum(low, point), np.maximum(high, point)
    span = float(np.max(high - low))
    scale = span if span > 0.0 else 1.0
    margin = 0.1 * scale
    low, high = low - margin, high + margin
    # Keep thin scenes readable: every axis gets at least 30 % of the widest one.
    width = high - low
    grow = np.maximum(0.3 * float(np.max(width)) - width, 0.0) / 2.0
    return low - grow, high + grow


# --------------------------------------------------------------------------------------
# Planes in the view


def _plane_polygon(normal: np.ndarray, offset: float, low: np.ndarray, high: np.ndarray):
    """The plane normal·x = offset cut to the box [low, high]: (k, 3) ordered vertices, or None."""
    corners = np.array(list(itertools.product(*zip(low, high))))
    side = corners @ normal - offset
    points = []
    for a, b in itertools.combinations(range(8), 2):
        if bin(a ^ b).count("1") != 1:
            continue  # not an edge of the box
        if side[a] == 0.0:
            points.append(corners[a])
        elif side[a] * side[b] < 0.0:
            points.append(corners[a] + side[a] / (side[a] - side[b]) * (corners[b] - corners[a]))
    if len(points) < 3:
        return None
    points = np.unique(np.round(np.asarray(points), 12), axis=0)
    if len(points) < 3:
        return None
    helper = np.eye(3)[np.argmin(np.abs(normal))]
    first = np.cross(normal, helper)
    first /= np.linalg.norm(first)
    second = np.cross(normal, first)
    rel = points - points.mean(axis=0)
    order = np.argsort(np.arctan2(rel @ second, rel @ first))
    return points[order]


def _clip_polygon(points: np.ndarray, normal: np.ndarray, offset: float,
                  tol: float = 0.0) -> np.ndarray:
    """The part of a convex polygon (k, dim), vertices in order, where normal·x − offset <= tol.

    Sutherland–Hodgman against one half-space; (m, dim), m = 0 when nothing is left.
    """
    side = points @ normal - offset
    kept = []
    for i in range(len(points)):
        j = (i + 1) % len(points)
        if side[i] <= tol:
            kept.append(points[i])
        if (side[i] - tol) * (side[j] - tol) < 0.0:
            kept.append(points[i] + (side[i] - tol) / (side[i] - side[j]) * (points[j] - points[i]))
    return np.asarray(kept, dtype=np.float64).reshape(-1, points.shape[1])


def _unit_planes(model: Model) -> list:
    """(normal, offset) of every plane with a unit normal, as float64."""
    planes = []
    for normal, offset in model.planes:
        normal = np.asarray(normal, dtype=np.float64)
        length = float(np.linalg.norm(normal))
        planes.append((normal / length, float(offset) / length))
    return planes


def _plane_pieces_2d(planes: list, low: np.ndarray, high: np.ndarray) -> list:
    """What shows of each half-plane in the view [low, high]: (solid, line) per plane.

    ``solid`` (k, 2) is the view rectangle cut to the plane's solid side
    normal·x <= offset (k = 0 when the view misses it); ``line`` (2, 2) is the
    stretch of normal·x = offset inside the view and on the free side of every
    other plane (the surface a body can touch), or None. So two tilted planes
    that meet in a V show a V-shaped valley, not two crossing lines.
    """
    rectangle = np.array([[low[0], low[1]], [high[0], low[1]], [high[0], high[1]],
                          [low[0], high[1]]])
    tol = 1e-12 * float(np.max(high - low))
    pieces = []
    for index, (normal, offset) in enumerate(planes):
        solid = _clip_polygon(rectangle, normal, offset, tol)
        foot = offset * normal
        tangent = np.array([-normal[1], normal[0]])
        # x(s) = foot + s·tangent; keep the s with each bound a·x(s) <= b.
        bounds = [(np.eye(2)[axis], high[axis]) for axis in range(2)]
        bounds += [(-np.eye(2)[axis], -low[axis]) for axis in range(2)]
        bounds += [(-other, -other_offset) for k, (other, other_offset) in enumerate(planes)
                   if k != index]
        start, stop = -np.inf, np.inf
        for a, b in bounds:
            slope, room = float(a @ tangent), float(b - a @ foot) + tol
            if abs(slope) < 1e-15:
                if room < 0.0:
                    start, stop = np.inf, -np.inf
            elif slope > 0.0:
                stop = min(stop, room / slope)
            else:
                start = max(start, room / slope)
        line = (np.stack([foot + start * tangent, foot + stop * tangent])
                if start < stop else None)
        pieces.append((solid, line))
    return pieces


def _plane_pieces_3d(planes: list, low: np.ndarray, high: np.ndarray) -> list:
    """Each plane cut to the view box and to the free side of every other plane:
    (k, 3) ordered vertices, or None when nothing of it shows."""
    tol = 1e-12 * float(np.max(high - low))
    pieces = []
    for index, (normal, offset) in enumerate(planes):
        polygon = _plane_polygon(normal, offset, low, high)
        for k, (other, other_offset) in enumerate(planes):
            if polygon is None or k == index:
                continue
            polygon = _clip_polygon(polygon, -other, -other_offset, tol)
            polygon = polygon if len(polygon) >= 3 else None
        pieces.append(polygon)
    return pieces
