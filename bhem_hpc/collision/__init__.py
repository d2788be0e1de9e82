"""Collision and intersection on bicubic patches, numpy only (no dolfinx, PETSc or MPI).

The same Bezier patches that the solver's Hermite surfaces convert to exactly serve intersection
(paper §5): :mod:`.bezier` (nets, de Casteljau splitting, bounds), :mod:`.ray` (static ray-patch
intersection with a BVH broad phase), :mod:`.ccd` (point-patch continuous collision detection).
"""

from bhem_hpc.collision.bezier import aabb, control_nets, evaluate, split_u, split_v, subpatch
from bhem_hpc.collision.ccd import point_patch_toi
from bhem_hpc.collision.colliders import (
    Capsule,
    ColliderError,
    Cylinder,
    PatchModel,
    Plane,
    Sphere,
    TriangleMesh,
)
from bhem_hpc.collision.ray import (
    BoundReached,
    Hit,
    PatchBVH,
    RayHits,
    intersect_patch,
    intersect_rays,
    ray_aabb,
    trace_rays,
)

__all__ = [
    "BoundReached",
    "Capsule",
    "ColliderError",
    "Cylinder",
    "PatchModel",
    "Plane",
    "Sphere",
    "TriangleMesh",
    "Hit",
    "PatchBVH",
    "RayHits",
    "aabb",
    "control_nets",
    "evaluate",
    "intersect_patch",
    "intersect_rays",
    "point_patch_toi",
    "ray_aabb",
    "split_u",
    "split_v",
    "subpatch",
    "trace_rays",
]
