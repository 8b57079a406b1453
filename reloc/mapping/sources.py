"""Plane sources: what turns a depth frame into its planes (camera frame) for maps and submaps.

- :func:`extraction_source`: plane extraction (:mod:`reloc.extraction`), what runs on real data.
- :func:`oracle_source`: the simulator's ground truth (``sim.ground_truth.visible_planes``), exact planes of the
  labelled pixels; isolates matching errors from extraction errors.
Each source is a callable ``frame -> PlaneSet`` (camera frame, with the frame's gravity) with a ``name``.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

__all__ = ["oracle_source", "extraction_source", "extraction_ablation"]


def oracle_source(scene, **kwargs) -> Callable:
    """Ground-truth planes of simulated frames of ``scene`` (a ``sim.scenes.Scene`` or its name)."""
    from sim.ground_truth import visible_planes
    from sim.scenes import Scene, make_scene

    sc = scene if isinstance(scene, Scene) else make_scene(scene)

    def source(frame):
        return visible_planes(frame, sc, **kwargs)

    source.name = "oracle"
    return source


def _extraction_module():
    try:
        import reloc.extraction as extraction

        extraction.PlaneExtractor  # noqa: B018 (present only once the extraction pipeline is installed)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"plane source 'extraction': reloc.extraction is not usable here ({exc})") from None
    return extraction


def extraction_source(params=None) -> Callable:
    """Planes extracted from each frame with ``params`` (a ``reloc.extraction.ExtractionParams``, None = defaults);
    one :class:`~reloc.extraction.PlaneExtractor` reuses its buffers across frames."""
    extraction = _extraction_module()
    extractor = extraction.PlaneExtractor(params)

    def source(frame):
        return extractor.extract(frame).planes

    source.name = "extraction"
    return source


def extraction_ablation(params, variant: str):
    """Extraction parameters of the paper's extraction ablations: ``VR-NE`` (adaptive weights off) and ``VR-NM``
    (plane merging off)."""
    extraction = _extraction_module()
    params = params if params is not None else extraction.ExtractionParams()
    if variant == "VR-NE":
        return replace(params, adaptive_weights=False)
    if variant == "VR-NM":
        return replace(params, merge=False)
    raise ValueError(f"variant: expected 'VR-NE' or 'VR-NM', got {variant!r}")
