"""Plane sources: what turns a depth frame into its planes (camera frame) for maps and submaps.

- :func:`oracle_source`: the simulator's ground truth (``sim.ground_truth.visible_planes``), exact planes of the
  labelled pixels; isolates matching errors from extraction errors.
Each source is a callable ``frame -> PlaneSet`` with the frame's gravity.
"""

from __future__ import annotations

from typing import Callable

__all__ = ["oracle_source"]


def oracle_source(scene, **kwargs) -> Callable:
    """Ground-truth planes of simulated frames of ``scene`` (a ``sim.scenes.Scene`` or its name)."""
    from sim.ground_truth import visible_planes
    from sim.scenes import Scene, make_scene

    sc = scene if isinstance(scene, Scene) else make_scene(scene)

    def source(frame):
        return visible_planes(frame, sc, **kwargs)

    source.name = "oracle"
    return source
