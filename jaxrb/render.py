"""Matplotlib drawing and animation of jaxrb scenes, 2D and 3D.

Everything here runs headless: nothing calls ``plt.show`` or changes the
backend. Matplotlib is imported on first use, so ``import jaxrb`` stays fast.

Pictures of a scene (what each returns: :func:`draw` and the plots an Axes,
whose Figure is ``ax.figure``; :func:`animate` a FuncAnimation, whose Figure is
``anim.jaxrb_painter.ax.figure``; :func:`save_animation` the path written):

* :func:`draw` ``(model, params, state, ax=None, *, contacts=False, ...) -> Axes``
  draws one world (``rb.render.draw(...).figure.savefig("a.png")`` saves it).
  2D: boxes and polygons as polygons, circles with a radius line that shows
  their rotation, point masses as dots (size by mass) with spokes to the
  centre of mass, half-planes as their solid side shaded across the view
  under the stretch of their line that borders free space (two tilted planes
  meeting in a V show a V-shaped valley). 3D: boxes, spheres and capsules as
  shaded meshes (spheres and capsules striped so spin shows), point masses as
  dots, planes as translucent patches clipped to the view and to the free side
  of the other planes. ``contacts=True`` adds the active contacts of
  :func:`jaxrb.detect_contacts`: a dot and a short normal arrow each, red when
  colliding, green when resting, orange when separating
  (:data:`STATUS_COLORS`). Bodies take :data:`BODY_COLORS` (blues, purples,
  greys) unless ``colors`` is given, so no body reads as a contact status.
* :func:`animate` ``(model, params, traj, *, initial=None, every=1, speed=1.0,
  max_fps=30, ...) -> FuncAnimation`` animates a trajectory from
  :func:`jaxrb.rollout` (after ``initial``, the state it started from, when
  given) in real time, times ``speed``: frames last the simulated time between
  them, and states are skipped rather than time slowed to stay under
  ``max_fps`` (``fps=`` fixes the frame rate instead). Axis limits stay fixed
  over the whole run and the time is in the title. Poses (and contacts) of all
  frames are computed once up front; each frame only moves existing artists.
* :func:`save_animation` writes ``.gif`` (Pillow), ``.mp4`` (ffmpeg) or
  ``.html``; :func:`to_html` gives the HTML/JS player for notebooks:
  ``IPython.display.HTML(rb.render.to_html(anim))``.
* :func:`figure_pixels` returns the rendered figure as an (H, W, 4) RGBA array.

Plots over time: :func:`plot_energy` (kinetic, potential, total),
:func:`plot_angular_momentum` (components and magnitude about the origin) and
:func:`plot_series` (any array over time).

Artists carry ids (``artist.get_gid()``) so they can be found again:
``"jaxrb.body<i>"`` for body ``i``, ``"jaxrb.plane<j>"`` for plane ``j``,
``"jaxrb.contact_points"`` (one offset per active contact) and
``"jaxrb.contact_normals"`` (three segments per arrow: shaft and two barbs).
In 3D, contacts hidden behind a solid body have their own pair,
``"jaxrb.contact_points_hidden"`` and ``"jaxrb.contact_normals_hidden"``:
mplot3d paints whole artists in z-order, not points by depth, so each frame
the line of sight from every contact to the camera is traced through the
boxes, spheres and capsules, and a contact behind one is drawn faint (alpha
0.3) under all bodies, which then cover its dot; visible contacts are drawn
over the bodies. Planes (translucent) and point masses hide nothing. Turning
the view by hand does not redo this; draw again, or call
``anim.jaxrb_painter.set_frame(i)``.
A 3D mesh keeps the world quads it shows, (F, 4, 3), in ``artist.jaxrb_faces``
(a 3D plane its polygon, (1, k, 3)), and the normals artist its world segments, (3k, 2, dim), in
``artist.jaxrb_segments`` (mplot3d has no public getter for 3D data).

Conventions: ``State.pos`` is each body's centre of mass; a shape is drawn in
its own frame, whose origin is ``pos − R·Params.com_offset``. ``extent`` is
``(xmin, xmax, ymin, ymax)`` in 2D and ``(xmin, xmax, ymin, ymax, zmin,
zmax)`` in 3D; without it the limits enclose every body (over all frames of an
animation) and nearby planes, plus a margin. Without ``ax``, :func:`animate`
draws on a plain :class:`matplotlib.figure.Figure` with an Agg canvas (so a
notebook shows only the player, and nothing piles up in pyplot), while
:func:`draw` and the plots make a pyplot figure (so it shows inline and
``plt.show()`` sees it).
"""

from __future__ import annotations

import functools
import itertools
import math
import pathlib
from typing import Optional, Sequence

import jax
import numpy as np

from jaxrb.collision.pairs import detect
from jaxrb.compile import jit
from jaxrb.dynamics import kinetic_energy, potential_energy, total_angular_momentum
from jaxrb.shapes import Box, Capsule, Circle, PointMasses, Polygon, Sphere
from jaxrb.types import COLLIDING, RESTING, SEPARATING, Model, Params, State

__all__ = ["animate", "draw", "figure_pixels", "plot_angular_momentum", "plot_energy",
           "plot_series", "save_animation", "to_html"]

STATUS_COLORS = {COLLIDING: "tab:red", RESTING: "tab:green", SEPARATING: "tab:orange"}
# Default body colours, cycled: blues, purples and greys only, so that no body reads as
# a contact status (matplotlib's default cycle starts blue, orange, green, red). In
# CIELAB each is at least 70 away from every status colour; the status colours are
# 40 apart among themselves (red and orange).
BODY_COLORS = ("tab:blue", "tab:purple", "tab:cyan", "tab:gray", "#5254a3", "#9c9ede")
STATUS_NAMES = {COLLIDING: "colliding", RESTING: "resting", SEPARATING: "separating"}
SAVE_SUFFIXES = (".gif", ".mp4", ".html")

# Mesh resolution of spheres and capsules: coarse keeps 3D frames fast.
_AROUND, _RINGS = 12, 8
# World-fixed light for the 3D flat shading; brightness = ambient + diffuse·max(0, n·l).
_LIGHT = np.array([-0.35, -0.5, 0.8]) / np.linalg.norm([-0.35, -0.5, 0.8])
_AMBIENT, _DIFFUSE = 0.45, 0.55
_PLANE_FACE = (0.55, 0.55, 0.55, 0.3)
_PLANE_EDGE = (0.3, 0.3, 0.3, 0.9)
_BOX_FACES = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1],
                       [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])


# --------------------------------------------------------------------------------------
# Input checks


def _check_state(model: Model, state: State, caller: str, time_axis: bool) -> None:
    """Raise ValueError unless ``state`` is one world (or one trajectory) of ``model``."""
    name = "traj" if time_axis else "state"
    if not isinstance(model, Model):
        raise ValueError(f"{caller}: 'model' must be a jaxrb Model, got {type(model).__name__}")
    if not isinstance(state, State):
        raise ValueError(f"{caller}: {name!r} must be a jaxrb State, got {type(state).__name__}")
    shape = tuple(np.shape(state.pos))
    body_shape = (model.num_bodies, model.dim)
    if len(shape) < 2 or shape[-2:] != body_shape:
        raise ValueError(f"{caller}: {name}.pos must end in (n, dim) = {body_shape} for this "
                         f"model, got shape {shape}")
    leading = shape[:-2]
    if time_axis and not leading:
        raise ValueError(f"{caller}: traj.pos has shape {shape}, with no leading time axis; "
                         "pass a trajectory from rb.rollout (or use draw for one state)")
    if time_axis and len(leading) > 1:
        raise ValueError(f"{caller}: traj.pos has shape {shape}, more than one leading axis "
                         "(a batch of worlds?); index one world, e.g. "
                         "jax.tree_util.tree_map(lambda x: x[:, 0], traj)")
    if not time_axis and leading:
        raise ValueError(f"{caller}: state.pos has shape {shape}, with a leading batch (or time) "
                         "axis; draw one world: index a world, e.g. "
                         "jax.tree_util.tree_map(lambda x: x[0], state), or use animate for a "
                         "trajectory")
    orientation = "quat" if model.dim == 3 else "angle"
    if getattr(state, orientation) is None:
        raise ValueError(f"{caller}: {name}.{orientation} is None but the model is "
                         f"{model.dim}D")


def _check_params(model: Model, params: Params, caller: str) -> None:
    if not isinstance(params, Params):
        raise ValueError(f"{caller}: 'params' must be jaxrb Params, got {type(params).__name__}")
    shape = tuple(np.shape(params.com_offset))
    if shape != (model.num_bodies, model.dim):
        raise ValueError(f"{caller}: params.com_offset has shape {shape}, expected "
                         f"{(model.num_bodies, model.dim)}; pass the Params of one world "
                         "(index a batch of swept Params first)")


def _check_extent(extent, dim: int, caller: str):
    try:
        values = np.asarray(extent, dtype=np.float64)
    except (TypeError, ValueError):
        values = None
    if values is None or values.shape != (2 * dim,):
        names = ", ".join(f"{axis}min, {axis}max" for axis in "xyz"[:dim])
        raise ValueError(f"{caller}: 'extent' must be {2 * dim} numbers ({names}), "
                         f"got {extent!r}")
    low, high = values[0::2], values[1::2]
    if not (np.all(np.isfinite(values)) and np.all(high > low)):
        raise ValueError(f"{caller}: 'extent' must be finite with each max > min, got {extent!r}")
    return low, high


def _body_colors(colors, count: int, caller: str):
    """One RGBA tuple per body from None (:data:`BODY_COLORS`, cycled), one colour, or a
    sequence (used as given)."""
    from matplotlib import colors as mcolors

    if colors is None:
        return [mcolors.to_rgba(BODY_COLORS[i % len(BODY_COLORS)]) for i in range(count)]
    if mcolors.is_color_like(colors):
        return [mcolors.to_rgba(colors)] * count
    try:
        colors = list(colors)
    except TypeError:
        colors = None
    if colors is None or len(colors) != count or not all(mcolors.is_color_like(c) for c in colors):
        raise ValueError(f"{caller}: 'colors' must be one colour or a sequence of n = {count} "
                         f"colours (one per body), got {colors!r}")
    return [mcolors.to_rgba(c) for c in colors]


# --------------------------------------------------------------------------------------
# Poses and contacts of every frame, computed once


def _rotation_matrices(model: Model, states: State) -> np.ndarray:
    if model.dim == 2:
        angle = np.asarray(states.angle, dtype=np.float64)
        c, s = np.cos(angle), np.sin(angle)
        return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    quat = np.asarray(states.quat, dtype=np.float64)
    quat = quat / np.maximum(np.linalg.norm(quat, axis=-1, keepdims=True), 1e-300)
    w, x, y, z = np.moveaxis(quat, -1, 0)
    rows = [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]
    return np.stack([np.stack(row, -1) for row in rows], -2)


@functools.lru_cache(maxsize=16)
def _contact_detector(model: Model):
    """Jitted detection over a leading frame axis, compiled once per Model."""
    return jit(jax.vmap(lambda params, state: detect(model, params, state), in_axes=(None, 0)))


class _Frames:
    """Host copies of everything the artists need, for F frames.

    Attributes:
        com: (F, n, dim) centres of mass.
        origin: (F, n, dim) shape-frame origins, com − R·com_offset.
        rotation: (F, n, dim, dim) shape-to-world rotations.
        time: (F,) simulated times.
        contacts: None, or (active (F, C), point (F, C, dim), normal (F, C, dim),
            status (F, C)) when contacts were asked for and the model has any.
    """

    def __init__(self, model: Model, params: Params, states: State, contacts: bool):
        self.com = np.asarray(states.pos, dtype=np.float64)
        self.rotation = _rotation_matrices(model, states)
        offset = np.asarray(params.com_offset, dtype=np.float64)
        self.origin = self.com - np.einsum("fnij,nj->fni", self.rotation, offset)
        count = self.com.shape[0]
        self.time = np.broadcast_to(np.asarray(states.time, dtype=np.float64), (count,))
        self.contacts = None
        if contacts and model.num_contacts > 0:
            found = _contact_detector(model)(params, states)
            self.contacts = (np.asarray(found.active), np.asarray(found.point, dtype=np.float64),
                             np.asarray(found.normal, dtype=np.float64), np.asarray(found.status))

    def __len__(self):
        return self.com.shape[0]


def _stack_frames(state: State) -> State:
    return jax.tree_util.tree_map(lambda x: np.asarray(x)[None], state)


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


# --------------------------------------------------------------------------------------
# Axis limits


def _auto_extent(model: Model, frames: _Frames, geometries) -> tuple:
    """(low, high) per axis enclosing every body in every frame, nearby planes and a margin."""
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
# Artists


def _darker(rgba, factor=0.55):
    return (rgba[0] * factor, rgba[1] * factor, rgba[2] * factor, 1.0)


def _lighter(rgba, factor=0.45):
    return tuple(c + (1.0 - c) * factor for c in rgba[:3]) + (1.0,)


def _face_normals(quads: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Outward unit normals (F, 3) of quads (F, 4, 3) around a convex body's ``centre``.

    The cross product of the diagonals is non-zero even for the quads that
    collapse to a triangle at a sphere's poles.
    """
    normal = np.cross(quads[:, 2] - quads[:, 0], quads[:, 3] - quads[:, 1])
    outward = np.einsum("fi,fi->f", normal, quads.mean(axis=1) - centre)
    normal = np.where(outward[:, None] < 0.0, -normal, normal)
    return normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)


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


# A contact counts as hidden when the line of sight from it to the eye runs through a
# solid body for more than this fraction of the body's smallest half-size (so contacts a
# hair inside the surface, as penetrating contacts are, stay visible).
_HIDDEN_CHORD = 0.1
_HIDDEN_ALPHA = 0.3
_HIDDEN_ZORDER = 1.5  # under every body (2 to 3), over a plane seen from its open side (1)


def _box_chord(points: np.ndarray, toward_eye: np.ndarray, origin: np.ndarray,
               rotation: np.ndarray, half: np.ndarray) -> np.ndarray:
    """(k,) length of each ray points + s·toward_eye, s >= 0, inside the box (slab test)."""
    half = half - 1e-6 * float(np.max(half))  # a ray along a face does not enter the box
    local = (points - origin) @ rotation  # Rᵀ(p − origin), row-wise
    direction = toward_eye @ rotation
    enter = np.zeros(len(points))
    leave = np.full(len(points), np.inf)
    for axis in range(3):
        if abs(direction[axis]) < 1e-12:
            outside = np.abs(local[:, axis]) >= half[axis]
            leave = np.where(outside, -np.inf, leave)
            continue
        first = (-half[axis] - local[:, axis]) / direction[axis]
        second = (half[axis] - local[:, axis]) / direction[axis]
        enter = np.maximum(enter, np.minimum(first, second))
        leave = np.minimum(leave, np.maximum(first, second))
    return np.maximum(leave - enter, 0.0)


def _round_chord(points: np.ndarray, toward_eye: np.ndarray, origin: np.ndarray,
                 rotation: np.ndarray, radius: float, half_length: float,
                 reach: float) -> np.ndarray:
    """(k,) length of each ray points + s·toward_eye, 0 <= s <= reach, inside the ball of
    the capsule (a sphere when half_length is 0) around the axis point nearest the ray:
    a lower bound of the length inside the capsule, exact for a sphere."""
    axis = rotation[:, 2] * half_length
    start = origin - axis
    ray, segment = reach * toward_eye, 2.0 * axis
    rel = points - start
    a, b, e = ray @ ray, ray @ segment, segment @ segment
    c, f = rel @ ray, rel @ segment
    # Closest points of the segments points + s·ray and start + t·segment (s, t in [0, 1]).
    if e <= 1e-300:
        t = np.zeros(len(points))
    else:
        denom = a * e - b * b
        s = (np.clip((b * f - c * e) / denom, 0.0, 1.0) if denom > 1e-12 * a * e
             else np.zeros(len(points)))
        t = np.clip((b * s + f) / e, 0.0, 1.0)
    centre = start + t[:, None] * segment
    along = (centre - points) @ toward_eye
    miss = np.einsum("ki,ki->k", centre - points, centre - points) - along ** 2
    radius = radius * (1.0 - 1e-6)
    half_chord = np.sqrt(np.maximum(radius ** 2 - miss, 0.0))
    inside = np.where(miss < radius ** 2, along + half_chord - np.maximum(along - half_chord, 0.0),
                      0.0)
    return np.maximum(inside, 0.0)


def _hidden_points(points: np.ndarray, toward_eye: np.ndarray, geometries, origin: np.ndarray,
                   rotation: np.ndarray, reach: float) -> np.ndarray:
    """(k,) bool: the line of sight from each point (k, 3) toward the eye (a unit direction,
    the view taken as parallel) crosses a solid body (boxes, spheres, capsules) deep enough
    to hide it. Planes are translucent and point masses not solid: they hide nothing."""
    hidden = np.zeros(len(points), dtype=bool)
    for index, geom in enumerate(geometries):
        if geom.solid is None or not len(points):
            continue
        if geom.solid[0] == "box":
            half = geom.solid[1]
            chord = _box_chord(points, toward_eye, origin[index], rotation[index], half)
            size = float(np.min(half))
        else:
            _, radius, half_length = geom.solid
            chord = _round_chord(points, toward_eye, origin[index], rotation[index], radius,
                                 half_length, reach)
            size = radius
        hidden |= chord > _HIDDEN_CHORD * size
    return hidden


def _toward_eye(ax) -> np.ndarray:
    """Unit world direction from the scene toward the 3D camera. With the box aspect
    set to the axis spans (as here) the view scales every axis alike, so this is the
    line of sight in world coordinates too (exact at the view centre in perspective)."""
    elev, azim = np.radians(ax.elev), np.radians(ax.azim)
    return np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])


class _Painter:
    """Owns the artists of one scene on one Axes and moves them to any frame."""

    def __init__(self, ax, model: Model, frames: _Frames, geometries, colors, low, high, title,
                 show_time, legend: bool):
        self.ax, self.model, self.frames = ax, model, frames
        self.title, self.show_time = title, show_time
        self.dim = model.dim
        self.geometries = geometries
        self.colors = colors
        self.low, self.high = low, high
        self.arrow_length = 0.08 * float(np.max(high - low))
        self.contact_artists = []
        self._set_limits()
        self._draw_planes()
        self.updaters = [self._make_body(i, geom) for i, geom in enumerate(self.geometries)]
        if legend and frames.contacts is not None:
            self._contact_legend()

    # -- static parts --------------------------------------------------------------

    def _set_limits(self):
        ax, low, high = self.ax, self.low, self.high
        ax.set_xlim(low[0], high[0])
        ax.set_ylim(low[1], high[1])
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        if self.dim == 2:
            ax.set_aspect("equal", adjustable="box")
        else:
            ax.set_zlim(low[2], high[2])
            ax.set_zlabel("z")
            ax.set_box_aspect(tuple(high - low))
            from matplotlib.ticker import MaxNLocator
            # mplot3d's default locator crowds the labels of short axes.
            for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
                axis.set_major_locator(MaxNLocator(nbins=4))
            # Draw order is set per frame from depth (see _depth_order); mplot3d's own
            # ordering lets a large floor patch cover the bodies standing on it.
            ax.computed_zorder = False
        ax.set_autoscale_on(False)

    def _draw_planes(self):
        from matplotlib import patches
        self.plane_artists = []
        planes = _unit_planes(self.model)
        if self.dim == 2:
            for index, (solid, line) in enumerate(_plane_pieces_2d(planes, self.low, self.high)):
                gid = f"jaxrb.plane{index}"
                if len(solid) >= 3:
                    self.ax.add_patch(patches.Polygon(solid, closed=True, facecolor=_PLANE_FACE,
                                                      edgecolor="none", zorder=1, gid=gid))
                if line is not None:
                    self.ax.plot(line[:, 0], line[:, 1], color=_PLANE_EDGE, lw=1.5, zorder=1.1,
                                 gid=gid)
            return
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection
        for index, polygon in enumerate(_plane_pieces_3d(planes, self.low, self.high)):
            if polygon is None:
                continue
            artist = Poly3DCollection([polygon], facecolors=[_PLANE_FACE], edgecolors=[_PLANE_EDGE],
                                      linewidths=0.8, gid=f"jaxrb.plane{index}")
            artist.jaxrb_normal = planes[index][0]
            artist.jaxrb_faces = polygon[None]
            self.ax.add_collection3d(artist, autolim=False)
            self.plane_artists.append(artist)

    def _contact_legend(self):
        from matplotlib.lines import Line2D
        handles = [Line2D([], [], linestyle="none", marker="o", markersize=5,
                          color=STATUS_COLORS[code], label=STATUS_NAMES[code])
                   for code in (COLLIDING, RESTING, SEPARATING)]
        # A still picks the emptiest corner; an animation keeps one place so it does not jump.
        place = "upper right" if self.show_time and len(self.frames) > 1 else "best"
        self.ax.legend(handles=handles, loc=place, fontsize="x-small", framealpha=0.7)

    # -- bodies --------------------------------------------------------------------

    def _make_body(self, index: int, geom: _Geometry):
        """Create body ``index``'s artists; return a function that moves them to a frame."""
        ax, color, gid = self.ax, self.colors[index], f"jaxrb.body{index}"
        edge = _darker(color)
        if geom.kind == "polygon":
            from matplotlib import patches
            patch = patches.Polygon(geom.local, closed=True, facecolor=color[:3] + (0.65,),
                                    edgecolor=edge, lw=1.2, zorder=2, gid=gid)
            ax.add_patch(patch)

            def update(origin, rotation, com):
                patch.set_xy(_world(geom.local, origin, rotation))
            return update
        if geom.kind == "circle":
            from matplotlib import patches
            disc = patches.Circle((0.0, 0.0), geom.radius, facecolor=color[:3] + (0.65,),
                                  edgecolor=edge, lw=1.2, zorder=2, gid=gid)
            ax.add_patch(disc)
            (line,) = ax.plot([], [], color=edge, lw=1.2, zorder=2.1, gid=gid)

            def update(origin, rotation, com):
                disc.set_center(tuple(origin))
                rim = origin + geom.radius * rotation[:, 0]
                line.set_data([origin[0], rim[0]], [origin[1], rim[1]])
            return update
        if geom.kind == "points":
            return self._make_points(geom, color, edge, gid)
        if geom.kind == "mass":
            if self.dim == 2:
                (marker,) = ax.plot([], [], marker="X", markersize=9, linestyle="none", color=color,
                                    markeredgecolor=edge, zorder=2, gid=gid)
            else:
                (marker,) = ax.plot([], [], [], marker="X", markersize=9, linestyle="none",
                                    color=color, markeredgecolor=edge, zorder=2, gid=gid)

            def update(origin, rotation, com):
                if self.dim == 2:
                    marker.set_data([com[0]], [com[1]])
                else:
                    marker.set_data_3d([com[0]], [com[1]], [com[2]])
            return update
        return self._make_mesh(geom, color, gid)

    def _make_points(self, geom, color, edge, gid):
        ax = self.ax
        masses = geom.masses
        sizes = 15.0 + 45.0 * masses / float(np.max(masses))
        count = len(geom.local)

        def spokes(world, com):
            # One polyline: com -> point, break (nan), com -> next point, ...
            starts = np.broadcast_to(com, world.shape)
            gap = np.full_like(world, np.nan)
            return np.stack([starts, world, gap], axis=1).reshape(-1, world.shape[1]).T

        if self.dim == 2:
            (spoke_line,) = ax.plot([], [], color=edge, lw=0.8, alpha=0.7, zorder=2, gid=gid)
            dots = ax.scatter(np.zeros(count), np.zeros(count), s=sizes, color=[color],
                              edgecolors=[edge], linewidths=0.8, zorder=2.1, gid=gid)

            def update(origin, rotation, com):
                world = _world(geom.local, origin, rotation)
                dots.set_offsets(world)
                spoke_line.set_data(*spokes(world, com))
            return update

        (spoke_line,) = ax.plot([], [], [], color=edge, lw=0.8, alpha=0.7, zorder=2, gid=gid)
        (dots,) = ax.plot([], [], [], linestyle="none", marker="o", markersize=6, color=color,
                          markeredgecolor=edge, zorder=2, gid=gid)

        def update(origin, rotation, com):
            world = _world(geom.local, origin, rotation)
            dots.set_data_3d(*world.T)
            spoke_line.set_data_3d(*spokes(world, com))
        update.artists = (spoke_line, dots)
        return update

    def _make_mesh(self, geom, color, gid):
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection
        base = np.array([color[:3], _lighter(color)[:3]])[geom.stripe]
        edge = _darker(color, 0.45)[:3] + (0.5,)
        artist = Poly3DCollection(geom.faces, edgecolors=[edge], linewidths=0.4, zorder=2, gid=gid)
        self.ax.add_collection3d(artist, autolim=False)

        def update(origin, rotation, com):
            faces = _world(geom.faces, origin, rotation)
            light = _face_normals(faces, origin) @ _LIGHT
            brightness = _AMBIENT + _DIFFUSE * np.clip(light, 0.0, 1.0)
            artist.set_verts(faces)
            artist.jaxrb_faces = faces
            artist.set_facecolor(np.concatenate([base * brightness[:, None],
                                                 np.ones((len(faces), 1))], axis=1))
        update.artists = (artist,)
        return update

    # -- per frame -----------------------------------------------------------------

    def _depth_order(self, com: np.ndarray):
        """3D: paint far bodies first, and planes first when seen from their open side."""
        toward_eye = _toward_eye(self.ax)
        rank = np.argsort(np.argsort(com @ toward_eye))
        for index, update in enumerate(self.updaters):
            for artist in getattr(update, "artists", ()):
                artist.set_zorder(2.0 + rank[index] / (len(rank) + 1.0))
        for artist in self.plane_artists:
            above = float(artist.jaxrb_normal @ toward_eye) >= 0.0
            artist.set_zorder(1.0 if above else 4.0)

    def _draw_contacts(self, frame: int):
        """Draw frame ``frame``'s active contacts. In 3D those whose line of sight to the
        camera crosses a solid body are drawn apart, faint and under every body (mplot3d
        orders whole artists, not points), so the body covers them."""
        for artist in self.contact_artists:
            artist.remove()
        self.contact_artists = []
        if self.frames.contacts is None:
            return
        active, point, normal, status = (part[frame] for part in self.frames.contacts)
        point, normal, status = point[active], normal[active], status[active]
        if self.dim == 2:
            self._contact_group(point, normal, status, "", 5.0, 1.0)
            return
        hidden = _hidden_points(point, _toward_eye(self.ax), self.geometries,
                                self.frames.origin[frame], self.frames.rotation[frame],
                                reach=2.0 * float(np.linalg.norm(self.high - self.low)))
        self._contact_group(point[~hidden], normal[~hidden], status[~hidden], "", 5.0, 1.0)
        self._contact_group(point[hidden], normal[hidden], status[hidden], "_hidden",
                            _HIDDEN_ZORDER, _HIDDEN_ALPHA)

    def _contact_group(self, point, normal, status, suffix, zorder, alpha):
        """Dots (gid ``jaxrb.contact_points<suffix>``) and normal arrows (gid
        ``jaxrb.contact_normals<suffix>``) of some contacts, as two artists."""
        from matplotlib.colors import to_rgba
        colors = [to_rgba(STATUS_COLORS.get(int(code), "k"), alpha) for code in status]
        segments = _arrow_segments(point, normal, self.arrow_length)
        segment_colors = [c for c in colors for _ in range(3)]
        if self.dim == 2:
            from matplotlib.collections import LineCollection
            dots = self.ax.scatter(point[:, 0], point[:, 1], s=14, c=colors or None,
                                   zorder=zorder, gid=f"jaxrb.contact_points{suffix}")
            arrows = LineCollection(segments, colors=segment_colors or None, linewidths=1.2,
                                    zorder=zorder, gid=f"jaxrb.contact_normals{suffix}")
            self.ax.add_collection(arrows, autolim=False)
        else:
            from mpl_toolkits.mplot3d.art3d import Line3DCollection
            dots = self.ax.scatter(point[:, 0], point[:, 1], point[:, 2], s=14, c=colors or None,
                                   depthshade=False, zorder=zorder,
                                   gid=f"jaxrb.contact_points{suffix}")
            arrows = Line3DCollection(segments, colors=segment_colors or None, linewidths=1.2,
                                      zorder=zorder, gid=f"jaxrb.contact_normals{suffix}")
            self.ax.add_collection3d(arrows, autolim=False)
        arrows.jaxrb_segments = segments
        self.contact_artists += [dots, arrows]

    def set_frame(self, frame: int):
        """Move every artist to frame ``frame``; returns the artists (for FuncAnimation)."""
        frames = self.frames
        for index, update in enumerate(self.updaters):
            update(frames.origin[frame, index], frames.rotation[frame, index],
                   frames.com[frame, index])
        if self.dim == 3:
            self._depth_order(frames.com[frame])
        self._draw_contacts(frame)
        if self.show_time:
            clock = f"t = {frames.time[frame]:.3f} s"
            self.ax.set_title(f"{self.title}   {clock}" if self.title else clock)
        elif self.title is not None:
            self.ax.set_title(self.title)
        return self.ax.get_children()


def _new_axes(dim: Optional[int], figsize=None, pyplot: bool = True, dpi=None):
    """A fresh Axes (3D when dim == 3) on a pyplot figure or, pyplot=False, a bare Agg one."""
    projection = "3d" if dim == 3 else None
    if pyplot:
        import matplotlib.pyplot as plt
        fig = plt.figure(figsize=figsize, dpi=dpi)
    else:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        fig = Figure(figsize=figsize, dpi=dpi)
        FigureCanvasAgg(fig)
    return fig.add_subplot(projection=projection)


def _check_axes(ax, dim: int, caller: str):
    is_3d = getattr(ax, "name", None) == "3d"
    if dim == 3 and not is_3d:
        raise ValueError(f"{caller}: 'ax' must be a 3D Axes for a 3D model, e.g. "
                         "fig.add_subplot(projection='3d')")
    if dim == 2 and is_3d:
        raise ValueError(f"{caller}: 'ax' is a 3D Axes but the model is 2D")


def _apply_view(ax, dim, view, caller):
    if dim != 3:
        return
    if view is None:
        view = (22.0, -60.0)
    try:
        elev, azim = (float(v) for v in view)
    except (TypeError, ValueError):
        raise ValueError(f"{caller}: 'view' must be (elevation, azimuth) in degrees, "
                         f"got {view!r}") from None
    ax.view_init(elev=elev, azim=azim)


# --------------------------------------------------------------------------------------
# Public API


def _painter(model: Model, params: Params, states: State, ax, caller: str, *, contacts, colors,
             extent, view, title, show_time) -> "_Painter":
    """The painter of :func:`draw` and :func:`animate`, showing frame 0 of ``states`` (T, ...) in ``ax``."""
    frames = _Frames(model, params, states, contacts)
    colors = _body_colors(colors, model.num_bodies, caller)
    _check_axes(ax, model.dim, caller)
    _apply_view(ax, model.dim, view, caller)
    geometries = _geometries(model)
    low, high = (_check_extent(extent, model.dim, caller) if extent is not None
                 else _auto_extent(model, frames, geometries))
    painter = _Painter(ax, model, frames, geometries, colors, low, high, title, show_time,
                       legend=contacts)
    painter.set_frame(0)
    return painter


def draw(model: Model, params: Params, state: State, ax=None, *, contacts: bool = False,
         colors=None, extent=None, title: Optional[str] = None, show_time: bool = False,
         view=None, figsize=None):
    """Draw one world's state with matplotlib; returns the Axes, not a Figure.

    Example::

        ax = rb.render.draw(model, params, state, contacts=True)
        ax.figure.savefig("state.png")  # the Figure is ax.figure

    Args:
        model: the scene's Model (shapes and planes come from it).
        params: Params of one world (``com_offset`` (n, dim) places each shape
            relative to its centre of mass).
        state: State of one world: ``pos`` (n, dim), ``quat`` (n, 4) or
            ``angle`` (n,). A leading batch or time axis is a ValueError;
            index a world first, or use :func:`animate`.
        ax: Axes to draw into (a 3D Axes for a 3D model); default a new pyplot
            figure.
        contacts: also draw the active contacts of
            :func:`jaxrb.detect_contacts` (dot and normal arrow, coloured by
            status) and a legend of the status colours. A model built with
            ``contact="none"`` has no pair table, so it shows none.
        colors: one matplotlib colour for all bodies or a sequence of n, one
            per body, used as given; default :data:`BODY_COLORS` cycled
            (blues, purples, greys: apart from the red, green and orange of
            the contact statuses). For matplotlib's cycle pass
            ``colors=[f"C{i}" for i in range(model.num_bodies)]``.
        extent: fixed limits (xmin, xmax, ymin, ymax) in 2D or (xmin, xmax,
            ymin, ymax, zmin, zmax) in 3D; default: the bodies and nearby
            planes plus a margin.
        title: axes title.
        show_time: append ``t = state.time`` to the title.
        view: 3D only, (elevation, azimuth) in degrees; default (22, -60).
        figsize: figure size in inches when a new figure is made.

    Returns:
        The :class:`matplotlib.axes.Axes` drawn into (``ax`` when given; a 3D
        Axes for a 3D model), not a Figure: its Figure is ``ax.figure``.

    Raises:
        ValueError: a batched state, mismatched params, a bad ``extent``,
            ``colors`` or ``view``, or an ``ax`` of the wrong dimension.
    """
    caller = "draw"
    _check_state(model, state, caller, time_axis=False)
    _check_params(model, params, caller)
    if ax is None:
        ax = _new_axes(model.dim, figsize)
    painter = _painter(model, params, _stack_frames(state), ax, caller, contacts=contacts,
                       colors=colors, extent=extent, view=view, title=title, show_time=show_time)
    return painter.ax


def _is_positive(value) -> bool:
    return (isinstance(value, (int, float, np.number)) and not isinstance(value, bool)
            and math.isfinite(value) and value > 0)


def _with_initial(model: Model, initial: State, traj: State, caller: str) -> State:
    """``traj`` with the one-world state ``initial`` put in front, as host arrays."""
    _check_state(model, initial, caller, time_axis=False)
    first, start = float(np.asarray(traj.time).reshape(-1)[0]), float(initial.time)
    if not start < first:
        raise ValueError(f"{caller}: 'initial' has time {start:g} s, not before the first state "
                         f"of 'traj' ({first:g} s); pass the state the rollout started from, or "
                         "leave 'initial' out when 'traj' already holds it")
    try:
        return jax.tree_util.tree_map(
            lambda a, b: np.concatenate([np.asarray(a)[None], np.asarray(b)]), initial, traj)
    except ValueError as error:  # fields None in one and set in the other
        raise ValueError(f"{caller}: 'initial' and 'traj' hold different State fields "
                         f"({error})") from None


def _playback(times: np.ndarray, every: int, fps, speed: float, max_fps: float):
    """(indices of the states shown, milliseconds per frame) for :func:`animate`."""
    shown = np.arange(0, len(times), every)
    if fps is not None:
        return shown, 1000.0 / fps
    steps = np.diff(times[shown])
    spacing = float(np.median(steps)) if len(steps) else math.nan
    if not (math.isfinite(spacing) and spacing > 0.0):
        return shown, 1000.0 / max_fps  # one frame, or no usable time stamps
    seconds = spacing / speed  # wall time per shown state in real time (×speed)
    # Drop frames over max_fps; the slack keeps float32 time stamps (1/60 s steps summed)
    # from dropping every second state at exactly max_fps.
    skip = max(1, math.ceil(1.0 / (max_fps * seconds) - 1e-3))
    return shown[::skip], 1000.0 * seconds * skip


def animate(model: Model, params: Params, traj: State, *, initial: Optional[State] = None,
            every: int = 1, speed: float = 1.0, max_fps: float = 30.0, fps: Optional[float] = None,
            contacts: bool = False, figsize=None, extent=None, title: Optional[str] = None,
            colors=None, view=None, dpi=None, ax=None):
    """Animate a trajectory in real time; returns a FuncAnimation, not a Figure or a file.

    The axis limits stay fixed over the whole run.

    Playback runs at the simulated pace: each shown frame lasts the simulated
    time between shown states (the median spacing of their ``time``) divided
    by ``speed``, so a 3 s rollout plays for 3 s whatever ``dt`` is. When that
    would mean more than ``max_fps`` frames per second, states are left out
    evenly (beyond ``every``) rather than time slowed: 60 Hz states play at
    30 frames per second, every second state. ``fps=`` instead fixes the
    frame rate and shows every ``every``-th state whatever the time stamps
    (playback then runs at fps·every·dt of simulated time per second).

    Poses and (if asked) contacts of every shown frame are computed once here;
    each frame of the animation only moves the artists.

    Example::

        traj = rb.rollout(step, state, params, 180)       # 3 s at 60 Hz
        anim = rb.render.animate(model, params, traj, initial=state)
        rb.render.save_animation(anim, "run.gif")         # plays for 3 s
        fig = anim.jaxrb_painter.ax.figure                # its Figure, e.g. for a still

    Args:
        model: the scene's Model.
        params: Params of one world.
        traj: State with a leading time axis, e.g. from :func:`jaxrb.rollout`:
            ``pos`` (T, n, dim), ``time`` (T,).
        initial: State of one world shown as frame 0, before ``traj``:
            :func:`jaxrb.rollout` returns the states after each step, not the
            one it started from, so pass that one here. Its ``time`` must be
            before ``traj.time[0]``. Default: start at ``traj``'s first state.
        every: show at most every ``every``-th state (1: all, subject to
            ``max_fps``); counted from frame 0 (``initial`` when given).
        speed: playback speed relative to simulated time (0.5: half speed).
        max_fps: most frames per second in real-time playback; more states
            are skipped to stay under it. GIFs keep time to 1/100 s and
            browsers slow GIF frames shorter than 0.02 s, so keep it <= 50
            for GIFs.
        fps: a fixed frame rate instead of real time (``speed`` and
            ``max_fps`` are then unused); default None (real time).
        contacts: draw the active contacts of each frame (see :func:`draw`).
        figsize: figure size in inches; default (5, 5) in 3D, (6, 4.5) in 2D.
        extent: fixed limits as in :func:`draw`; default encloses the bodies in
            every frame.
        title: title text; the time ``t = ... s`` is appended per frame.
        colors: body colours as in :func:`draw`.
        view: 3D only, (elevation, azimuth) in degrees.
        dpi: figure resolution; default matplotlib's.
        ax: Axes to animate in (its figure is used); default a new figure
            that is not registered with pyplot, so a notebook shows only the
            animation, not a stray still.

    Returns:
        A :class:`matplotlib.animation.FuncAnimation` (not a Figure and not a
        file: write it with :func:`save_animation`, which returns the path, or
        show it in a notebook with :func:`to_html`). Keep a reference to it
        until it is saved or shown. Its Figure is
        ``anim.jaxrb_painter.ax.figure``; ``anim.jaxrb_fps`` is its frame
        rate and ``anim.jaxrb_painter.set_frame(i)`` moves the figure to shown
        frame ``i`` (e.g. for a still). Long animations exceed matplotlib's
        ``animation.embed_limit`` (20 MB) as HTML; show fewer frames with
        ``every`` or ``max_fps``.

    Raises:
        ValueError: ``traj`` without a time axis or with a batch axis, an
            ``initial`` that is not one world of the model or not before
            ``traj``, ``every`` < 1, ``speed``, ``max_fps`` or ``fps`` not
            positive, ``fps`` with a ``speed`` other than 1, or a bad
            ``extent``/``colors``/``view``.
    """
    from matplotlib.animation import FuncAnimation

    caller = "animate"
    _check_state(model, traj, caller, time_axis=True)
    _check_params(model, params, caller)
    if not (isinstance(every, (int, np.integer)) and not isinstance(every, bool) and every >= 1):
        raise ValueError(f"{caller}: 'every' must be an integer >= 1, got {every!r}")
    for name, value in (("speed", speed), ("max_fps", max_fps)) + ((("fps", fps),) if fps is not None else ()):
        if not _is_positive(value):
            raise ValueError(f"{caller}: {name!r} must be a positive number, got {value!r}")
    if fps is not None and speed != 1.0:
        raise ValueError(f"{caller}: give 'fps' (a fixed frame rate) or 'speed' (real time × "
                         f"speed), not both; got fps={fps!r}, speed={speed!r}")
    if initial is not None:
        traj = _with_initial(model, initial, traj, caller)
    times = np.broadcast_to(np.asarray(traj.time, dtype=np.float64), np.shape(traj.pos)[:1])
    indices, interval = _playback(times, every, fps, float(speed), float(max_fps))
    shown = jax.tree_util.tree_map(lambda x: np.asarray(x)[indices], traj)
    if ax is None:
        if figsize is None:
            figsize = (5.0, 5.0) if model.dim == 3 else (6.0, 4.5)
        ax = _new_axes(model.dim, figsize, pyplot=False, dpi=dpi)
    painter = _painter(model, params, shown, ax, caller, contacts=contacts, colors=colors,
                       extent=extent, view=view, title=title, show_time=True)
    anim = FuncAnimation(ax.figure, painter.set_frame, frames=len(painter.frames),
                         init_func=lambda: painter.set_frame(0), interval=interval,
                         blit=False, cache_frame_data=False)
    anim.jaxrb_fps = 1000.0 / interval
    anim.jaxrb_painter = painter
    return anim


def _animation_fps(anim, fps):
    if fps is not None:
        if not _is_positive(fps):
            raise ValueError(f"save_animation: 'fps' must be a positive number, got {fps!r}")
        return float(fps)
    stored = getattr(anim, "jaxrb_fps", None)
    if stored is not None:
        return stored
    interval = getattr(anim, "_interval", None)  # matplotlib's own animations: from the interval
    return 1000.0 / interval if interval else 30.0


def _gif_writer(fps: float):
    """Pillow's GIF writer with frame durations that keep time: a GIF stores them in
    1/100 s, and one rounded duration (33 ms at 30 fps) would run 10 % fast, so frame k
    ends at (k + 1)/fps rounded to 1/100 s (30, 40, 30, 30, 40, ... ms). Durations stay
    >= 20 ms: browsers play shorter GIF frames at 100 ms."""
    from matplotlib.animation import PillowWriter

    class _TimedPillowWriter(PillowWriter):
        def finish(self):
            frames = getattr(self, "_frames", None)
            if not frames:  # matplotlib changed its writer: fall back to its own timing
                return super().finish()
            ends = np.round(np.arange(1, len(frames) + 1) * 100.0 / self.fps) * 10.0
            durations = np.maximum(np.diff(ends, prepend=0.0), 20.0)
            frames[0].save(self.outfile, save_all=True, append_images=frames[1:],
                           duration=[int(d) for d in durations], loop=0)

    return _TimedPillowWriter(fps=fps)


def save_animation(anim, path, *, fps: Optional[float] = None, dpi=None):
    """Write an animation to a file chosen by the suffix of ``path``.

    ``.gif`` uses Pillow, with frame durations rounded to the GIF's 1/100 s
    so that the total time stays right; ``.mp4`` uses ffmpeg (a ValueError when ffmpeg is not
    installed; ``.gif`` needs nothing extra); ``.html`` writes the
    self-contained HTML/JavaScript player of :func:`to_html`.

    Args:
        anim: a matplotlib animation, e.g. from :func:`animate`.
        path: file name (str or path) ending in ``.gif``, ``.mp4`` or ``.html``.
        fps: frames per second; default the animation's own
            (``anim.jaxrb_fps`` from :func:`animate`: real time unless it was
            given ``fps``).
        dpi: resolution; default the figure's.

    Returns:
        The path written, as a :class:`pathlib.Path`.

    Raises:
        ValueError: an unknown suffix (the message lists the valid ones), a
            ``.mp4`` without ffmpeg, or ``fps`` <= 0.
    """
    from matplotlib import animation

    path = pathlib.Path(path)
    suffix = path.suffix.lower()
    if suffix not in SAVE_SUFFIXES:
        raise ValueError(f"save_animation: unknown file suffix {path.suffix!r} in {str(path)!r}; "
                         f"valid suffixes are: {', '.join(SAVE_SUFFIXES)}")
    fps = _animation_fps(anim, fps)
    if suffix == ".gif":
        anim.save(path, writer=_gif_writer(fps), dpi=dpi)
    elif suffix == ".mp4":
        if not animation.writers.is_available("ffmpeg"):
            raise ValueError("save_animation: writing .mp4 needs ffmpeg, which is missing (not on "
                             "PATH); install ffmpeg or save as .gif (Pillow) or .html instead")
        anim.save(path, writer=animation.FFMpegWriter(fps=fps), dpi=dpi)
    else:
        path.write_text(anim.to_jshtml(fps=fps), encoding="utf-8")
    return path


def to_html(anim) -> str:
    """The animation as a self-contained HTML/JavaScript player, for notebooks.

    Use as ``IPython.display.HTML(rb.render.to_html(anim))``.

    Args:
        anim: a matplotlib animation, e.g. from :func:`animate`.

    Returns:
        HTML text with the frames embedded as PNG images and a ``<script>`` player.
    """
    return anim.to_jshtml(fps=_animation_fps(anim, None))


def figure_pixels(fig) -> np.ndarray:
    """Render a figure and return its pixels.

    Args:
        fig: a matplotlib Figure (or an Axes, whose figure is used).

    Returns:
        (H, W, 4) uint8 RGBA array, row 0 at the top.
    """
    from matplotlib.figure import Figure, SubFigure

    if not isinstance(fig, (Figure, SubFigure)) and hasattr(fig, "figure"):
        fig = fig.figure
    if isinstance(fig, SubFigure):
        fig = fig.figure
    canvas = fig.canvas
    if hasattr(canvas, "buffer_rgba"):
        canvas.draw()
        return np.array(canvas.buffer_rgba(), dtype=np.uint8, copy=True)
    # A canvas without a pixel buffer: let savefig render through Agg.
    import io
    buffer = io.BytesIO()
    fig.savefig(buffer, format="rgba", dpi=fig.dpi)
    width, height = (int(round(v)) for v in fig.bbox.size)
    return np.frombuffer(buffer.getvalue(), dtype=np.uint8).reshape(height, width, 4).copy()


def _time_axes(ax, caller):
    if ax is None:
        return _new_axes(None)
    if getattr(ax, "name", None) == "3d":
        raise ValueError(f"{caller}: 'ax' must be a 2D Axes")
    return ax


def _per_time(model: Model, params: Params, traj: State, function):
    """``function(model, params, state)`` for every state of ``traj``, as a host array."""
    return np.asarray(jax.vmap(lambda state: function(model, params, state))(traj))


def plot_energy(model: Model, params: Params, traj: State, ax=None):
    """Plot kinetic, potential and total energy of the whole scene over time.

    Energies are summed over bodies: kinetic from :func:`jaxrb.kinetic_energy`
    (translational plus rotational), potential from
    :func:`jaxrb.potential_energy` (−m g·x, zero at the origin).

    Args:
        model: the scene's Model.
        params: Params of one world.
        traj: State with a leading time axis: ``pos`` (T, n, dim), ``time`` (T,).
        ax: 2D Axes to plot into; default a new pyplot figure.

    Returns:
        The Axes (its Figure is ``ax.figure``), with lines labelled "kinetic",
        "potential" and "total" (in J).
    """
    caller = "plot_energy"
    _check_state(model, traj, caller, time_axis=True)
    _check_params(model, params, caller)
    ax = _time_axes(ax, caller)
    kinetic = _per_time(model, params, traj, lambda m, p, s: kinetic_energy(m, p, s).sum())
    potential = _per_time(model, params, traj, lambda m, p, s: potential_energy(m, p, s).sum())
    times = np.asarray(traj.time)
    ax.plot(times, kinetic, label="kinetic")
    ax.plot(times, potential, label="potential")
    ax.plot(times, kinetic + potential, label="total", color="k", lw=1.5)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("energy (J)")
    ax.legend()
    return ax


def plot_angular_momentum(model: Model, params: Params, traj: State, ax=None):
    """Plot the total angular momentum about the world origin over time.

    3D: the components L_x, L_y, L_z and the magnitude |L|; 2D: the scalar L_z.
    Values come from :func:`jaxrb.total_angular_momentum` (spin plus orbital).

    Args:
        model: the scene's Model.
        params: Params of one world.
        traj: State with a leading time axis: ``pos`` (T, n, dim), ``time`` (T,).
        ax: 2D Axes to plot into; default a new pyplot figure.

    Returns:
        The Axes (its Figure is ``ax.figure``), lines labelled "L_x", "L_y",
        "L_z", "|L|" (3D) or "L_z" (2D).
    """
    caller = "plot_angular_momentum"
    _check_state(model, traj, caller, time_axis=True)
    _check_params(model, params, caller)
    ax = _time_axes(ax, caller)
    momentum = _per_time(model, params, traj, total_angular_momentum)
    times = np.asarray(traj.time)
    if model.dim == 3:
        for axis, name in enumerate(("L_x", "L_y", "L_z")):
            ax.plot(times, momentum[:, axis], label=name)
        ax.plot(times, np.linalg.norm(momentum, axis=1), label="|L|", color="k", lw=1.5)
    else:
        ax.plot(times, momentum, label="L_z")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("angular momentum (kg m²/s)")
    ax.legend()
    return ax


def plot_series(times, values, *, labels: Optional[Sequence[str]] = None, ax=None,
                ylabel: Optional[str] = None):
    """Plot any quantity over time, one line per component.

    Example: ``plot_series(traj.time, traj.angvel[:, 0], labels=["ωx", "ωy", "ωz"])``.

    Args:
        times: (T,) times.
        values: (T,) or (T, ...) values; trailing axes are flattened into
            one line each.
        labels: one label per line; default none (no legend).
        ax: 2D Axes to plot into; default a new pyplot figure.
        ylabel: y-axis label.

    Returns:
        The Axes (its Figure is ``ax.figure``).

    Raises:
        ValueError: ``times`` not one-dimensional, ``values`` of another
            length, or the wrong number of ``labels``.
    """
    caller = "plot_series"
    times = np.asarray(times)
    values = np.asarray(values)
    if times.ndim != 1:
        raise ValueError(f"{caller}: 'times' must have shape (T,), got {times.shape}")
    if values.ndim == 0 or values.shape[0] != times.shape[0]:
        raise ValueError(f"{caller}: 'values' must have shape (T, ...) with T = {times.shape[0]} "
                         f"as 'times', got {values.shape}")
    values = values.reshape(values.shape[0], -1)
    if labels is not None:
        labels = list(labels)
        if len(labels) != values.shape[1]:
            raise ValueError(f"{caller}: 'labels' has {len(labels)} entries but 'values' has "
                             f"{values.shape[1]} lines")
    ax = _time_axes(ax, caller)
    for column in range(values.shape[1]):
        ax.plot(times, values[:, column], label=None if labels is None else labels[column])
    ax.set_xlabel("time (s)")
    if ylabel is not None:
        ax.set_ylabel(ylabel)
    if labels is not None:
        ax.legend()
    return ax
