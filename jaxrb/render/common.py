"""What the drawing modules share: input checks, colours, the poses and contacts of
every frame (computed once), new Axes and a figure's pixels."""

from __future__ import annotations

import functools
import math
from typing import Optional

import jax
import numpy as np

from jaxrb.physics.collision.pairs import detect
from jaxrb.compile import jit
from jaxrb.model.types import COLLIDING, RESTING, SEPARATING, Model, Params, State

STATUS_COLORS = {COLLIDING: "tab:red", RESTING: "tab:green", SEPARATING: "tab:orange"}
STATUS_NAMES = {COLLIDING: "colliding", RESTING: "resting", SEPARATING: "separating"}
# Default body colours, cycled: blues, purples and greys only, so that no body reads as
# a contact status (matplotlib's default cycle starts blue, orange, green, red). In
# CIELAB each is at least 70 away from every status colour; the status colours are
# 40 apart among themselves (red and orange).
BODY_COLORS = ("tab:blue", "tab:purple", "tab:cyan", "tab:gray", "#5254a3", "#9c9ede")
# Planes: translucent grey, darker edges.
_PLANE_FACE = (0.55, 0.55, 0.55, 0.3)
_PLANE_EDGE = (0.3, 0.3, 0.3, 0.9)


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


def _is_positive(value) -> bool:
    return (isinstance(value, (int, float, np.number)) and not isinstance(value, bool)
            and math.isfinite(value) and value > 0)


# --------------------------------------------------------------------------------------
# Colours


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


def _darker(rgba, factor=0.55):
    return (rgba[0] * factor, rgba[1] * factor, rgba[2] * factor, 1.0)


def _lighter(rgba, factor=0.45):
    return tuple(c + (1.0 - c) * factor for c in rgba[:3]) + (1.0,)


def _status_colors(status, alpha: float = 1.0) -> list:
    """One RGBA tuple per contact status code (black for an unknown code)."""
    from matplotlib.colors import to_rgba
    return [to_rgba(STATUS_COLORS.get(int(code), "k"), alpha) for code in status]


# --------------------------------------------------------------------------------------
# Poses and contacts of every frame, computed once


def _rotation_matrices(model: Model, states: State) -> np.ndarray:
    if model.dim == 2:
        angle = np.asarray(states.angle, dtype=np.float64)
        c, s = np.cos(angle), np.sin(angle)
        return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    return _quaternion_matrices(states.quat)


def _quaternion_matrices(quat) -> np.ndarray:
    """(..., 3, 3) float64 rotation matrices of (..., 4) quaternions (w, x, y, z), on the host."""
    quat = np.asarray(quat, dtype=np.float64)
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
        if model.shape_frames:  # shapes placed in their bodies: the shape's own frame
            # On the host in float64 (pairs.shape_frame_arrays makes JAX arrays, and
            # float64 asked of JAX without x64 warns and truncates).
            placed = [(np.zeros(3), (1.0, 0.0, 0.0, 0.0)) if frame is None else frame
                      for frame in model.shape_frames]
            shift = np.array([offset for offset, _ in placed], dtype=np.float64)
            turn = _quaternion_matrices([quat for _, quat in placed])
            self.origin = self.origin + np.einsum("fnij,nj->fni", self.rotation, shift)
            self.rotation = self.rotation @ turn
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
# Figures


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
