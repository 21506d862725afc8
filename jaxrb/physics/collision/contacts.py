"""What a narrowphase kernel returns, and the conventions every kernel follows.

A kernel handles one pair of shape kinds for ONE pair of shapes (the pipeline
vmaps it over all pairs of that kind):

    kernel(geom_a, geom_b, pose_a, pose_b) -> Contacts with K slots

* ``geom_x`` is the shape's geometry as a tuple of arrays (see
  :mod:`jaxrb.physics.collision.geometry`), ``pose_x = (origin (dim,), rotation
  (dim, dim))`` places the shape frame in the world (rotation maps shape-frame
  vectors to world vectors). Planes are world-fixed: their pose is identity.
* The normal points from B to A: moving A along +normal separates the pair.
  This matches the lecture's v_rel = n·(v_A − v_B) < 0 for colliding contacts.
* ``dist`` is the signed separation along the normal: > 0 apart, < 0
  penetrating. Kernels report the closest features even when apart, so the
  pipeline can keep speculative contacts within a margin.
* ``point`` is midway between the two surfaces.
* ``valid`` marks slots that hold a real candidate (clipping can yield fewer
  points than K). Invalid slots still hold finite numbers.
* Everything is finite in value and gradient for every input, including
  coincident centres and parallel edges (use the ``safe_*`` helpers).
"""

from __future__ import annotations

from jaxrb.model.struct import pytree_dataclass
from jaxrb.model.types import Array


@pytree_dataclass
class Contacts:
    """Candidate contact points of one pair (or, stacked, of many).

    Attributes:
        dist: (..., K) signed separation, negative when penetrating.
        normal: (..., K, dim) unit normal from B to A.
        point: (..., K, dim) world point midway between the surfaces.
        valid: (..., K) bool, whether the slot holds a real candidate.
    """

    dist: Array
    normal: Array
    point: Array
    valid: Array
