"""Plane extraction: a depth frame (or a point cloud) becomes a :class:`~reloc.planeset.PlaneSet`.

Public API: :class:`ExtractionParams` and the robust single-plane fit :func:`fit_plane`.
"""

from reloc.extraction.fit import fit_plane
from reloc.extraction.params import ExtractionParams, noise_sigma

__all__ = ["ExtractionParams", "fit_plane", "noise_sigma"]
