"""Plane extraction: a depth frame (or a point cloud) becomes a :class:`~reloc.planeset.PlaneSet`.

Data flow (one module per stage, numba kernels in the ``_kernels_*`` modules):
``backproject`` (depth to points) -> ``voxelize`` (counting sort into voxels, per-voxel moments) ->
``voxel_planes`` (PCA plane and planarity per voxel, then the robust weighted refit with the paper's Eq. 2 weights)
-> ``merge`` (voxel growth and under-grown fragments from summed moments, then the refinement pass over the points
near each plane) -> ``assemble`` (statistics, radius, area, samples, labels); ``pipeline`` composes and times them,
``cli`` is ``reloc planes``. ``fit`` is the robust weighted fit for one arbitrary point set.
"""

from reloc.extraction.fit import fit_plane
from reloc.extraction.params import ExtractionParams, noise_sigma
from reloc.extraction.pipeline import (
    STAGES,
    ExtractionResult,
    PlaneExtractor,
    extract_planes,
    extract_planes_from_points,
)

__all__ = [
    "ExtractionParams",
    "ExtractionResult",
    "PlaneExtractor",
    "STAGES",
    "extract_planes",
    "extract_planes_from_points",
    "fit_plane",
    "noise_sigma",
]
