"""3D artists (mplot3d): plane patches, shaded meshes of boxes, spheres and capsules,
point masses, contacts, and the paint order that stands in for depth.

mplot3d paints whole artists in z-order (``computed_zorder`` is off here: its own
ordering lets a large floor patch cover the bodies standing on it), so each frame
bodies are ordered far to near along the line of sight, and contacts hidden behind a
solid body are drawn as separate artists under all bodies.
"""

from __future__ import annotations

import numpy as np

from jaxrb.render.common import _PLANE_EDGE, _PLANE_FACE, _darker, _lighter, _status_colors
from jaxrb.render.geometry import _arrow_segments, _plane_pieces_3d, _spokes, _world

# World-fixed light for the 3D flat shading; brightness = ambient + diffuse·max(0, n·l).
_LIGHT = np.array([-0.35, -0.5, 0.8]) / np.linalg.norm([-0.35, -0.5, 0.8])
_AMBIENT, _DIFFUSE = 0.45, 0.55
# A contact counts as hidden when the line of sight from it to the eye runs through a
# solid body for more than this fraction of the body's smallest half-size (so contacts a
# hair inside the surface, as penetrating contacts are, stay visible).
_HIDDEN_CHORD = 0.1
_HIDDEN_ALPHA = 0.3
_HIDDEN_ZORDER = 1.5  # under every body (2 to 3), over a plane seen from its open side (1)


def _finish_axes_3d(ax, low: np.ndarray, high: np.ndarray):
    """z limits, an aspect that scales every axis alike, sparse ticks, our own z-order."""
    from matplotlib.ticker import MaxNLocator
    ax.set_zlim(low[2], high[2])
    ax.set_zlabel("z")
    ax.set_box_aspect(tuple(high - low))
    # mplot3d's default locator crowds the labels of short axes.
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(nbins=4))
    # Draw order is set per frame from depth (see _depth_order); mplot3d's own
    # ordering lets a large floor patch cover the bodies standing on it.
    ax.computed_zorder = False


def _draw_planes_3d(ax, planes: list, low: np.ndarray, high: np.ndarray) -> list:
    """A translucent patch per plane, cut to the view and to the free side of the other
    planes (see :func:`_plane_pieces_3d`); returns them (each knows its ``jaxrb_normal``)."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    artists = []
    for index, polygon in enumerate(_plane_pieces_3d(planes, low, high)):
        if polygon is None:
            continue
        artist = Poly3DCollection([polygon], facecolors=[_PLANE_FACE], edgecolors=[_PLANE_EDGE],
                                  linewidths=0.8, gid=f"jaxrb.plane{index}")
        artist.jaxrb_normal = planes[index][0]
        artist.jaxrb_faces = polygon[None]
        ax.add_collection3d(artist, autolim=False)
        artists.append(artist)
    return artists


def _face_normals(quads: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Outward unit normals (F, 3) of quads (F, 4, 3) around a convex body's ``centre``.

    The cross product of the diagonals is non-zero even for the quads that
    collapse to a triangle at a sphere's poles.
    """
    normal = np.cross(quads[:, 2] - quads[:, 0], quads[:, 3] - quads[:, 1])
    outward = np.einsum("fi,fi->f", normal, quads.mean(axis=1) - centre)
    normal = np.where(outward[:, None] < 0.0, -normal, normal)
    return normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)


def _make_body_3d(ax, geom, color, gid: str):
    """Create one body's artists (gid ``gid``); return the function that moves them.
    Its ``artists`` attribute, when present, lists the artists :func:`_depth_order` sorts."""
    edge = _darker(color)
    if geom.kind == "mesh":
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection
        base = np.array([color[:3], _lighter(color)[:3]])[geom.stripe]
        mesh_edge = _darker(color, 0.45)[:3] + (0.5,)
        artist = Poly3DCollection(geom.faces, edgecolors=[mesh_edge], linewidths=0.4, zorder=2,
                                  gid=gid)
        ax.add_collection3d(artist, autolim=False)

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
    if geom.kind == "points":
        (spoke_line,) = ax.plot([], [], [], color=edge, lw=0.8, alpha=0.7, zorder=2, gid=gid)
        (dots,) = ax.plot([], [], [], linestyle="none", marker="o", markersize=6, color=color,
                          markeredgecolor=edge, zorder=2, gid=gid)

        def update(origin, rotation, com):
            world = _world(geom.local, origin, rotation)
            dots.set_data_3d(*world.T)
            spoke_line.set_data_3d(*_spokes(world, com))
        update.artists = (spoke_line, dots)
        return update
    # A body without a shape: a cross at its centre of mass.
    (marker,) = ax.plot([], [], [], marker="X", markersize=9, linestyle="none", color=color,
                        markeredgecolor=edge, zorder=2, gid=gid)

    def update(origin, rotation, com):
        marker.set_data_3d([com[0]], [com[1]], [com[2]])
    return update


def _toward_eye(ax) -> np.ndarray:
    """Unit world direction from the scene toward the 3D camera. With the box aspect
    set to the axis spans (as here) the view scales every axis alike, so this is the
    line of sight in world coordinates too (exact at the view centre in perspective)."""
    elev, azim = np.radians(ax.elev), np.radians(ax.azim)
    return np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])


def _depth_order(ax, com: np.ndarray, updaters: list, plane_artists: list):
    """Paint far bodies first, and planes first when seen from their open side."""
    toward_eye = _toward_eye(ax)
    rank = np.argsort(np.argsort(com @ toward_eye))
    for index, update in enumerate(updaters):
        for artist in getattr(update, "artists", ()):
            artist.set_zorder(2.0 + rank[index] / (len(rank) + 1.0))
    for artist in plane_artists:
        above = float(artist.jaxrb_normal @ toward_eye) >= 0.0
        artist.set_zorder(1.0 if above else 4.0)


# --------------------------------------------------------------------------------------
# Contacts, and which of them a body hides


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


def _draw_contacts_3d(ax, point, normal, status, length: float, geometries, origin, rotation,
                      reach: float) -> list:
    """Draw k contacts, point and normal (k, 3), of one frame whose bodies have shape
    frames at ``origin`` (n, 3) turned by ``rotation`` (n, 3, 3). Those whose line of
    sight to the camera crosses a solid body (within ``reach``) go to their own artists,
    faint and under every body, so the body covers them."""
    hidden = _hidden_points(point, _toward_eye(ax), geometries, origin, rotation, reach)
    return (_contact_group_3d(ax, point[~hidden], normal[~hidden], status[~hidden], length,
                              "", 5.0, 1.0)
            + _contact_group_3d(ax, point[hidden], normal[hidden], status[hidden], length,
                                "_hidden", _HIDDEN_ZORDER, _HIDDEN_ALPHA))


def _contact_group_3d(ax, point, normal, status, length, suffix, zorder, alpha) -> list:
    """Dots (gid ``jaxrb.contact_points<suffix>``) and normal arrows (gid
    ``jaxrb.contact_normals<suffix>``) of some contacts, as two artists."""
    from mpl_toolkits.mplot3d.art3d import Line3DCollection
    colors = _status_colors(status, alpha)
    segments = _arrow_segments(point, normal, length)
    dots = ax.scatter(point[:, 0], point[:, 1], point[:, 2], s=14, c=colors or None,
                      depthshade=False, zorder=zorder, gid=f"jaxrb.contact_points{suffix}")
    arrows = Line3DCollection(segments, colors=[c for c in colors for _ in range(3)] or None,
                              linewidths=1.2, zorder=zorder, gid=f"jaxrb.contact_normals{suffix}")
    ax.add_collection3d(arrows, autolim=False)
    arrows.jaxrb_segments = segments
    return [dots, arrows]
