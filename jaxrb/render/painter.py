"""The painter that owns one scene's artists on one Axes and moves them to any frame,
and :func:`draw`, which paints one state with it."""

from __future__ import annotations

from typing import Optional

import numpy as np

from jaxrb.render.common import (STATUS_COLORS, STATUS_NAMES, _apply_view, _body_colors,
                                 _check_axes, _check_extent, _check_params, _check_state,
                                 _Frames, _new_axes, _stack_frames)
from jaxrb.render.draw2d import _draw_contacts_2d, _draw_planes_2d, _make_body_2d
from jaxrb.render.draw3d import (_depth_order, _draw_contacts_3d, _draw_planes_3d,
                                 _finish_axes_3d, _make_body_3d)
from jaxrb.render.geometry import _auto_extent, _geometries, _unit_planes
from jaxrb.model.types import COLLIDING, RESTING, SEPARATING, Model, Params, State


class _Painter:
    """Owns the artists of one scene on one Axes and moves them to any frame.

    Attributes:
        ax: the Axes.
        frames: the :class:`jaxrb.render.common._Frames` it shows.
        updaters: per body, ``update(origin, rotation, com)`` moving its artists.
        plane_artists: the planes' artists.
        contact_artists: the current frame's contact artists.
    """

    def __init__(self, ax, model: Model, frames: _Frames, geometries, colors, low, high, title,
                 show_time, legend: bool):
        self.ax, self.model, self.frames = ax, model, frames
        self.title, self.show_time = title, show_time
        self.dim = model.dim
        self.geometries = geometries
        self.low, self.high = low, high
        self.arrow_length = 0.08 * float(np.max(high - low))
        self.contact_artists = []
        self._set_limits()
        planes = _unit_planes(model)
        draw_planes, make_body = ((_draw_planes_2d, _make_body_2d) if self.dim == 2
                                  else (_draw_planes_3d, _make_body_3d))
        self.plane_artists = draw_planes(ax, planes, low, high)
        self.updaters = [make_body(ax, geom, colors[index], f"jaxrb.body{index}")
                         for index, geom in enumerate(geometries)]
        if legend and frames.contacts is not None:
            self._contact_legend()

    def _set_limits(self):
        ax, low, high = self.ax, self.low, self.high
        ax.set_xlim(low[0], high[0])
        ax.set_ylim(low[1], high[1])
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        if self.dim == 2:
            ax.set_aspect("equal", adjustable="box")
        else:
            _finish_axes_3d(ax, low, high)
        ax.set_autoscale_on(False)

    def _contact_legend(self):
        from matplotlib.lines import Line2D
        handles = [Line2D([], [], linestyle="none", marker="o", markersize=5,
                          color=STATUS_COLORS[code], label=STATUS_NAMES[code])
                   for code in (COLLIDING, RESTING, SEPARATING)]
        # A still picks the emptiest corner; an animation keeps one place so it does not jump.
        place = "upper right" if self.show_time and len(self.frames) > 1 else "best"
        self.ax.legend(handles=handles, loc=place, fontsize="x-small", framealpha=0.7)

    def _draw_contacts(self, frame: int):
        """Replace the contact artists by those of frame ``frame``."""
        for artist in self.contact_artists:
            artist.remove()
        self.contact_artists = []
        if self.frames.contacts is None:
            return
        active, point, normal, status = (part[frame] for part in self.frames.contacts)
        point, normal, status = point[active], normal[active], status[active]
        if self.dim == 2:
            self.contact_artists = _draw_contacts_2d(self.ax, point, normal, status,
                                                     self.arrow_length)
        else:
            self.contact_artists = _draw_contacts_3d(
                self.ax, point, normal, status, self.arrow_length, self.geometries,
                self.frames.origin[frame], self.frames.rotation[frame],
                reach=2.0 * float(np.linalg.norm(self.high - self.low)))

    def set_frame(self, frame: int):
        """Move every artist to frame ``frame``; returns the artists (for FuncAnimation)."""
        frames = self.frames
        for index, update in enumerate(self.updaters):
            update(frames.origin[frame, index], frames.rotation[frame, index],
                   frames.com[frame, index])
        if self.dim == 3:
            _depth_order(self.ax, frames.com[frame], self.updaters, self.plane_artists)
        self._draw_contacts(frame)
        if self.show_time:
            clock = f"t = {frames.time[frame]:.3f} s"
            self.ax.set_title(f"{self.title}   {clock}" if self.title else clock)
        elif self.title is not None:
            self.ax.set_title(self.title)
        return self.ax.get_children()


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
