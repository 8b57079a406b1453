"""Building the live loop's parts from the config: camera, plane source, map, relocalizer, firmware bridge.

These are the edges where the config object is read; the loop itself takes plain parameters and components.
Heavy or optional parts are imported inside the functions.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from reloc.camera import DepthFrame
from reloc.planeset import PlaneSet

__all__ = ["open_camera", "make_extractor", "load_plane_map", "make_relocalizer", "make_submap_fuser", "make_bridge",
           "TruthPlanes"]


def open_camera(spec: str, cfg, *, rate: "str | float | None" = None, n_frames: int | None = None, **kwargs):
    """A frame source for ``reloc run --camera SPEC``: ``sim[:SCENE]``, ``oak[:ID]``, ``replay:DIR``.

    ``rate`` ("recorded", "fast" or Hz) paces simulated and replayed frames; by default ``live.realtime`` decides.
    A simulated camera runs its trajectory for ``n_frames`` frames (looping the tour when more are asked for
    by ``--duration``). Extra ``kwargs`` go to the source.
    """
    from drivers.source import open_source

    kind = spec.partition(":")[0]
    if kind in ("sim", "replay", "rosbag") and "rate" not in kwargs:
        kwargs["rate"] = rate if rate is not None else ("recorded" if cfg.live.realtime else "fast")
    if kind == "sim":
        kwargs.setdefault("n_frames", int(n_frames) if n_frames else 900)
        kwargs.setdefault("loop", n_frames is None)
    if kind == "oak":
        from drivers.oak import oak_kwargs_from_config

        kwargs = {**oak_kwargs_from_config(cfg), **kwargs}
    return open_source(spec, **kwargs)


@dataclass(frozen=True)
class _Extracted:
    planes: PlaneSet
    timings_ms: dict


class TruthPlanes:
    """The simulator's ground-truth planes of each frame (``sim.ground_truth.visible_planes``) in place of
    extraction: the oracle that separates the loop's behaviour from extraction errors in tests and benchmarks."""

    def __init__(self, scene, noise: str = "stereo"):
        self.scene = scene
        self.noise = noise

    def __call__(self, frame: DepthFrame) -> _Extracted:
        import time

        from sim.ground_truth import visible_planes

        t0 = time.perf_counter()
        planes = visible_planes(frame, self.scene, noise=self.noise)
        return _Extracted(planes, {"truth": (time.perf_counter() - t0) * 1e3})


def make_extractor(cfg, *, planes: str = "extract", scene=None) -> Callable[[DepthFrame], Any]:
    """``frame -> result`` with ``.planes`` and ``.timings_ms``: plane extraction with the config's parameters
    (``planes="extract"``), or the simulator's ground truth (``planes="truth"``, needs the simulated ``scene``)."""
    if planes == "truth":
        if scene is None:
            raise ValueError("planes: 'truth' needs a simulated camera (ground-truth planes come from its scene)")
        return TruthPlanes(scene)
    if planes != "extract":
        raise ValueError(f"planes: expected 'extract' or 'truth', got {planes!r}")
    try:
        from reloc.extraction import ExtractionParams, PlaneExtractor
    except ImportError as exc:  # the extraction pipeline is a separate part of the project
        raise ValueError(f"planes: plane extraction is not available in this build ({exc}); use --planes truth "
                         "with a simulated camera") from None
    return PlaneExtractor(ExtractionParams.from_config(cfg)).extract


def with_camera_noise(cfg, source):
    """``(cfg, note)``: the config with the camera's own depth noise law (``source.noise_law()``: simulated cameras,
    an OAK stereo pair from its calibration, a replayed recording that stored it), see
    :func:`reloc.config.with_noise_law`."""
    from reloc.config import with_noise_law

    return with_noise_law(cfg, source.noise_law(), "the camera")


def load_plane_map(spec: str) -> tuple[PlaneSet, Any]:
    """``(map planes in the map frame, the object to relocalize in)`` for ``--map``.

    ``spec`` is a map file written by ``reloc map`` (:func:`reloc.mapping.load_map`), or ``sim:SCENE`` for the
    exact map of a simulated scene (every scene plane, world frame = map frame).
    """
    if spec.startswith("sim:"):
        from sim.ground_truth import scene_planes
        from sim.scenes import make_scene

        planes, _ = scene_planes(make_scene(spec[4:] or "living_room"))
        return planes, planes
    path = Path(spec)
    if not path.exists():
        raise FileNotFoundError(f"--map: no such file: {path}")
    try:
        from reloc.mapping import load_map
    except ImportError:
        load_map = None
    if load_map is not None:
        plane_map = load_map(path)
        return plane_map.planes, plane_map
    # Until the mapping module is in this build: a bare PlaneSet archive (PlaneSet.to_arrays, optional prefix).
    with np.load(path, allow_pickle=False) as npz:
        keys = list(npz.keys())
        prefix = next((k[: -len("normals")] for k in keys if k.endswith("normals")), None)
        if prefix is None:
            raise ValueError(f"--map: {path} holds no plane map (arrays {keys[:8]}); expected a file from reloc map")
        planes = PlaneSet.from_arrays(npz, prefix=prefix, frame="map")
    return planes, planes


def make_relocalizer(plane_map, cfg):
    """The relocalizer with the config's matching parameters; the map index is built here, once."""
    from reloc.matching import MatchingParams, Relocalizer

    return Relocalizer(plane_map, MatchingParams.from_config(cfg))


class SubmapFuser:
    """``fuse(plane_sets, T_odom_cams)``: :func:`reloc.mapping.build_submap` with fixed mapping parameters; its
    ``stats`` count the window frames the odometry check left out (``frames_left_out``)."""

    def __init__(self, params):
        from reloc.mapping import build_submap, grow_submap

        self.params, self._build, self._grow = params, build_submap, grow_submap
        self.stats: dict = {"frames_left_out": 0}

    def __call__(self, plane_sets, T_odom_cams):
        return self._build(plane_sets, T_odom_cams, self.params, self.stats)

    def grow(self, fetch, first: int, most: int):
        """:func:`reloc.mapping.grow_submap` with these parameters: ``(submap, frames used)``."""
        return self._grow(fetch, first, most, self.params, self.stats)


def make_submap_fuser(cfg):
    """A :class:`SubmapFuser` with the config's mapping parameters, or None (planes of a window stacked unfused)
    when the mapping module is not in this build."""
    try:
        from reloc.mapping import MappingParams
    except ImportError:
        return None
    return SubmapFuser(MappingParams.from_config(cfg))


def make_bridge(url: str, cfg, **overrides):
    """A started :class:`firmware_bridge.HostBridge` on ``url`` with the ``serial`` section of the config."""
    from firmware_bridge import HostBridge

    return HostBridge.from_config(cfg.serial, url=url, **overrides).start()
