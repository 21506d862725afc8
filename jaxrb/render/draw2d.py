"""2D artists: half-planes, bodies (polygons, discs with a radius line, point masses,
bare masses) and contacts. Each body's maker returns ``update(origin, rotation, com)``,
which moves its artists to one pose."""

from __future__ import annotations

import numpy as np

from jaxrb.render.common import _PLANE_EDGE, _PLANE_FACE, _darker, _status_colors
from jaxrb.render.geometry import _arrow_segments, _plane_pieces_2d, _spokes, _world

_FILL_ALPHA = 0.65  # body faces, so what is behind them shows


def _draw_planes_2d(ax, planes: list, low: np.ndarray, high: np.ndarray) -> list:
    """Each half-plane's solid side, filled across the view [low, high], and the stretch of
    its line that borders free space (see :func:`_plane_pieces_2d`); returns the artists."""
    from matplotlib import patches
    artists = []
    for index, (solid, line) in enumerate(_plane_pieces_2d(planes, low, high)):
        gid = f"jaxrb.plane{index}"
        if len(solid) >= 3:
            artists.append(ax.add_patch(patches.Polygon(solid, closed=True, facecolor=_PLANE_FACE,
                                                        edgecolor="none", zorder=1, gid=gid)))
        if line is not None:
            artists += ax.plot(line[:, 0], line[:, 1], color=_PLANE_EDGE, lw=1.5, zorder=1.1,
                               gid=gid)
    return artists


def _make_body_2d(ax, geom, color, gid: str):
    """Create one body's artists (gid ``gid``); return the function that moves them."""
    from matplotlib import patches
    edge = _darker(color)
    face = color[:3] + (_FILL_ALPHA,)
    if geom.kind == "polygon":
        patch = patches.Polygon(geom.local, closed=True, facecolor=face, edgecolor=edge, lw=1.2,
                                zorder=2, gid=gid)
        ax.add_patch(patch)

        def update(origin, rotation, com):
            patch.set_xy(_world(geom.local, origin, rotation))
        return update
    if geom.kind == "circle":
        disc = patches.Circle((0.0, 0.0), geom.radius, facecolor=face, edgecolor=edge, lw=1.2,
                              zorder=2, gid=gid)
        ax.add_patch(disc)
        (line,) = ax.plot([], [], color=edge, lw=1.2, zorder=2.1, gid=gid)

        def update(origin, rotation, com):
            disc.set_center(tuple(origin))
            rim = origin + geom.radius * rotation[:, 0]
            line.set_data([origin[0], rim[0]], [origin[1], rim[1]])
        return update
    if geom.kind == "points":
        count = len(geom.local)
        sizes = 15.0 + 45.0 * geom.masses / float(np.max(geom.masses))
        (spoke_line,) = ax.plot([], [], color=edge, lw=0.8, alpha=0.7, zorder=2, gid=gid)
        dots = ax.scatter(np.zeros(count), np.zeros(count), s=sizes, color=[color],
                          edgecolors=[edge], linewidths=0.8, zorder=2.1, gid=gid)

        def update(origin, rotation, com):
            world = _world(geom.local, origin, rotation)
            dots.set_offsets(world)
            spoke_line.set_data(*_spokes(world, com))
        return update
    # A body without a shape: a cross at its centre of mass.
    (marker,) = ax.plot([], [], marker="X", markersize=9, linestyle="none", color=color,
                        markeredgecolor=edge, zorder=2, gid=gid)

    def update(origin, rotation, com):
        marker.set_data([com[0]], [com[1]])
    return update


def _draw_contacts_2d(ax, point, normal, status, length: float) -> list:
    """Dots (gid ``jaxrb.contact_points``) and normal arrows (gid
    ``jaxrb.contact_normals``) of k contacts, point and normal (k, 2), over the bodies."""
    from matplotlib.collections import LineCollection
    colors = _status_colors(status)
    segments = _arrow_segments(point, normal, length)
    dots = ax.scatter(point[:, 0], point[:, 1], s=14, c=colors or None, zorder=5,
                      gid="jaxrb.contact_points")
    arrows = LineCollection(segments, colors=[c for c in colors for _ in range(3)] or None,
                            linewidths=1.2, zorder=5, gid="jaxrb.contact_normals")
    ax.add_collection(arrows, autolim=False)
    arrows.jaxrb_segments = segments
    return [dots, arrows]
