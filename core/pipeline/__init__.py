"""The fur pipeline around FurCollide (paper sections 2 and 4), numpy only.

Public API (paper names, see README "The fur pipeline")::

    from core.pipeline import (
        sample_guides,                                   # Fur Sampler
        bind, Binding,                                   # Fur Attach
        wind, jiggle,                                    # wind / secondary motion
        collider_distance, region_of_influence,          # Collider Distance, RoI
        bind_groom, GroomWeights, deform_groom,          # render groom follows guides
        GroomDeformer,                                   #   (its bind-time work, explicit)
        GroomBinding,                                    #   a whole bound groom, per frame
        clearance_pass, ClearanceMargins,                # final clearance (FurCollide)
        Shot, Motion, RootHistory,                       # a shot, frame by frame
    )

Curves use Blender's layout: ``points`` (P, 3) and ``offsets`` (C+1,),
curve ``i`` is ``points[offsets[i]:offsets[i + 1]]``. Meshes are ``V``
(n, 3) and ``F`` (m, 3) triangles. Bad input raises
:class:`~core.errors.InputError` or :class:`~core.errors.ColliderError`.
"""

from ..closest import closest_faces
from .attach import Binding, bind, surface_values
from .distance import (
    collider_distance,
    segment_mesh_distance,
    segment_triangle_distance,
)
from .frame import FrameResult, Motion, RootHistory, Shot
from .groom import (
    ClearanceMargins,
    GroomBinding,
    GroomDeformer,
    GroomWeights,
    bind_groom,
    clearance_pass,
    deform_groom,
    knn,
)
from .influence import region_of_influence
from .motion import jiggle, spring_impulse_response, wind, wind_noise
from .sampler import dart_throwing, neighbor_pairs, sample_guides

__all__ = [
    "surface_values",
    "Binding",
    "ClearanceMargins",
    "GroomBinding",
    "GroomDeformer",
    "GroomWeights",
    "FrameResult",
    "Motion",
    "RootHistory",
    "Shot",
    "bind",
    "bind_groom",
    "clearance_pass",
    "closest_faces",
    "collider_distance",
    "dart_throwing",
    "deform_groom",
    "jiggle",
    "knn",
    "neighbor_pairs",
    "region_of_influence",
    "sample_guides",
    "segment_mesh_distance",
    "segment_triangle_distance",
    "spring_impulse_response",
    "wind",
    "wind_noise",
]
