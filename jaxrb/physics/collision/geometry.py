"""Shape geometry as the arrays kernels consume, and the kind names of pairs.

``geometry(shape, dim)`` returns ``(kind, arrays)``:

=========== ======================================= =========================
kind        arrays                                  shapes
=========== ======================================= =========================
"sphere"    (radius,)                               Sphere (3D), Circle (2D)
"capsule"   (radius, half_length)                   Capsule, axis = shape z
"box"       (half_extents (3,),)                    Box (3D)
"polygon"   (vertices (k, 2), normals (k, 2))       Polygon, Box (2D); CCW,
                                                    normals[i] is the outward
                                                    normal of edge i -> i+1
"points"    (points (k, dim),)                      PointMasses, shape frame
"plane"     (normal (dim,), offset)                 Scene.add_plane: the solid
                                                    is normal·x < offset
=========== ======================================= =========================

A pair kind is ``"<kindA>_<kindB>"`` with A the kind of lower ``KIND_ORDER``
rank, so every pair of kinds has one canonical kernel.
"""

from __future__ import annotations

import numpy as np

from jaxrb.model.shapes import Box, Capsule, Circle, PointMasses, Polygon, Sphere

KIND_ORDER = ("points", "box", "polygon", "capsule", "sphere", "plane")


def polygon_arrays(vertices):
    """CCW vertices (k, 2) -> (vertices, outward edge normals (k, 2))."""
    vertices = np.asarray(vertices, dtype=np.float64)
    edges = np.roll(vertices, -1, axis=0) - vertices
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
    return vertices, normals / np.linalg.norm(normals, axis=1, keepdims=True)


def geometry(shape, dim):
    """(kind, tuple of numpy arrays) for a shape; see the module table."""
    if isinstance(shape, (Sphere, Circle)):
        return "sphere", (np.float64(shape.radius),)
    if isinstance(shape, Capsule):
        return "capsule", (np.float64(shape.radius), np.float64(shape.half_length))
    if isinstance(shape, Box) and dim == 3:
        return "box", (np.asarray(shape.half_extents, dtype=np.float64),)
    if isinstance(shape, Box):
        hx, hy = shape.half_extents
        return "polygon", polygon_arrays([(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)])
    if isinstance(shape, Polygon):
        return "polygon", polygon_arrays(shape.vertices)
    if isinstance(shape, PointMasses):
        return "points", (np.asarray(shape.points, dtype=np.float64),)
    raise ValueError(f"no collision geometry for {type(shape).__name__}")


def pair_kind(kind_a: str, kind_b: str):
    """Canonical pair kind and whether A and B must be swapped to reach it."""
    if KIND_ORDER.index(kind_a) <= KIND_ORDER.index(kind_b):
        return f"{kind_a}_{kind_b}", False
    return f"{kind_b}_{kind_a}", True
