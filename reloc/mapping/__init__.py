"""Plane maps and submaps: planes of posed frames fused into one plane per physical surface.

One-shot: :func:`build_map` (frames and a plane source to a :class:`PlaneMap`), :func:`build_submap` (a window of
plane sets to one plane set in the latest camera frame), :func:`grow_submap` (a window grown back in time until its
submap can pin a pose). Files: :func:`save_map` / :func:`load_map`
(:class:`MapFileError` names the file and the problem).
"""

from reloc.mapping.builder import (
    MapBuilder,
    MappingParams,
    SubmapBuilder,
    build_map,
    build_submap,
    grow_submap,
    odometry_consistent_frames,
    select_keyframes,
    submap_constrained,
)
from reloc.mapping.fusion import FusionParams, PlaneAccumulator, plane_fit_from_stats
from reloc.mapping.plane_map import MAP_FORMAT, MAP_FORMAT_VERSION, MapFileError, PlaneMap, load_map, save_map
from reloc.mapping.sources import extraction_source, oracle_source

__all__ = [
    "MapBuilder",
    "MappingParams",
    "odometry_consistent_frames",
    "SubmapBuilder",
    "build_map",
    "build_submap",
    "grow_submap",
    "submap_constrained",
    "select_keyframes",
    "FusionParams",
    "PlaneAccumulator",
    "plane_fit_from_stats",
    "MAP_FORMAT",
    "MAP_FORMAT_VERSION",
    "MapFileError",
    "PlaneMap",
    "load_map",
    "save_map",
    "oracle_source",
    "extraction_source",
]
