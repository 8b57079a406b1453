"""Plane matching: a submap and a plane map become a verified pose, or a rejection with a reason.

One-shot: :func:`locate`. Reusing one map: ``Relocalizer(plane_map, MatchingParams.from_config(cfg)).locate(submap)``.
The stages are public for tests and profiling: :mod:`~reloc.matching.selection` (incremental order, triplets,
candidates), :mod:`~reloc.matching.transform` (pose from plane pairs), :mod:`~reloc.matching.scoring` (weights,
density, decision) and :mod:`~reloc.matching.index` (the map index).
"""

from reloc.matching.params import ABLATIONS, MatchingParams, ablation_params, scaled_to_sensor
from reloc.matching.relocalizer import STAGES, Relocalizer, RelocResult, locate
from reloc.matching.transform import PlanePairTransform, transform_from_plane_pairs

__all__ = [
    "ABLATIONS",
    "MatchingParams",
    "ablation_params",
    "scaled_to_sensor",
    "Relocalizer",
    "RelocResult",
    "STAGES",
    "locate",
    "PlanePairTransform",
    "transform_from_plane_pairs",
]
