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
its own frame, whose origin is ``pos − R·Params.com_offset`` (the body frame's),
then moved and turned by the shape's pose in its body where it has one
(``Model.shape_frames``: a MuJoCo geom's pos/quat). ``extent`` is
``(xmin, xmax, ymin, ymax)`` in 2D and ``(xmin, xmax, ymin, ymax, zmin,
zmax)`` in 3D; without it the limits enclose every body (over all frames of an
animation) and nearby planes, plus a margin. Without ``ax``, :func:`animate`
draws on a plain :class:`matplotlib.figure.Figure` with an Agg canvas (so a
notebook shows only the player, and nothing piles up in pyplot), while
:func:`draw` and the plots make a pyplot figure (so it shows inline and
``plt.show()`` sees it).

The package's modules (internal; use the names above from ``jaxrb.render``):
``common`` (input checks, colours, the frames computed once, figures),
``geometry`` (shape-frame outlines and meshes, axis limits, planes cut to the
view; no matplotlib), ``draw2d`` and ``draw3d`` (the artists of each), ``painter``
(the painter that moves them frame to frame, and :func:`draw`),
``animation`` (:func:`animate`, saving) and ``plots``.
"""

from __future__ import annotations

from jaxrb.render.animation import SAVE_SUFFIXES, animate, save_animation, to_html
from jaxrb.render.common import BODY_COLORS, STATUS_COLORS, STATUS_NAMES, figure_pixels
from jaxrb.render.painter import draw
from jaxrb.render.plots import plot_angular_momentum, plot_energy, plot_series

__all__ = ["BODY_COLORS", "SAVE_SUFFIXES", "STATUS_COLORS", "STATUS_NAMES", "animate", "draw",
           "figure_pixels", "plot_angular_momentum", "plot_energy", "plot_series",
           "save_animation", "to_html"]

# The public functions are documented, and pickled, as jaxrb.render.<name>.
for _function in (animate, draw, figure_pixels, plot_angular_momentum, plot_energy, plot_series,
                  save_animation, to_html):
    _function.__module__ = __name__
del _function
