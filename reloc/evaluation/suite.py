"""The evaluation suite of the paper, on the simulator: maps, positive and negative queries, outcomes.

For each scene: a map from mapping trajectories (a robot tour and a hand-held walk, seed ``map_seed``); positive
queries from other trajectories of the same scene (robot-like and hand-held, seed ``query_seed``), each a submap
of ``window_frames`` frames ``window_stride`` apart fused with their relative poses (the ground-truth poses stand
for odometry), grown back in time up to ``window_max_frames`` frames while it cannot pin a pose
(:func:`reloc.mapping.grow_submap`); negative queries: ``negatives_per_scene`` queries of the other scenes (the
paper adds 20 per scene). Every query carries its ground truth and an ambiguity label
(:mod:`reloc.evaluation.ambiguity`); :mod:`reloc.evaluation.metrics` turns results into TP / TN / FP / FN.

The steps are public (:func:`build_scene_map`, :func:`make_queries`, :func:`evaluate_queries`); :func:`run_suite`
and :func:`run_ablation` compose them.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from reloc.evaluation.ambiguity import is_ambiguous, scene_symmetries
from reloc.evaluation.metrics import (
    Outcome,
    Summary,
    classify,
    covariance_check,
    identifiable,
    summarize,
    twin_confirmed,
)
from reloc.mapping import MappingParams, PlaneMap, build_map, grow_submap
from reloc.matching import MatchingParams, Relocalizer, ablation_params, scaled_to_sensor
from reloc.planeset import PlaneSet
from reloc.transforms import pose_error

__all__ = ["SCENES", "SENSOR_CAMERAS", "EvalSpec", "Query", "SceneResult", "Prepared", "make_plane_source",
           "extraction_for_sensor", "build_scene_map", "make_queries", "query_history", "evaluate_queries",
           "prepare_suite", "run_suite", "run_ablation", "quick_spec", "sensor_spec", "suite_spec"]

SCENES = ("living_room", "office", "apartment", "corridor", "meeting_rooms", "symmetric_room")
# A noise model that belongs to a camera of its own: (camera preset, width, height) it is simulated with.
SENSOR_CAMERAS = {"stereo": ("oak-d", 640, 400)}


@dataclass(frozen=True)
class EvalSpec:
    """What the suite simulates. Frames are rendered at ``width x height`` (the camera preset resampled)."""

    scenes: tuple[str, ...] = SCENES
    noise: str = "kinect"
    camera: str = "kinect"
    width: int = 160
    height: int = 120
    map_trajectories: tuple[tuple[str, int], ...] = (("robot", 3000), ("handheld", 3000))
    # Where the mapping trajectories go (sim.trajectories.TOURS). "random" is the default of a record that has no
    # such field (suites saved before 2026-11-29); the suite's own is SUITE_MAP_TOUR.
    map_tour: str = "random"
    map_seed: int = 1
    query_kinds: tuple[str, ...] = ("robot", "handheld")
    queries_per_kind: int = 10
    query_seed: int = 101
    query_spacing_frames: int = 150
    window_frames: int = 40
    window_stride: int = 3
    window_max_frames: int = 0  # 0: every window has window_frames frames; else it may grow to this many
    negatives_per_scene: int = 20
    plane_source: str = "oracle"

    def __post_init__(self) -> None:
        if self.plane_source not in ("oracle", "extraction"):
            raise ValueError(f"plane_source: expected 'oracle' or 'extraction', got {self.plane_source!r}")
        from sim.trajectories import TOURS

        if self.map_tour not in TOURS:
            raise ValueError(f"map_tour: expected one of {', '.join(TOURS)}, got {self.map_tour!r}")
        if self.window_frames < 1 or self.window_stride < 1:
            raise ValueError(f"window_frames, window_stride: expected >= 1, got {self.window_frames}, "
                             f"{self.window_stride}")
        if self.window_max_frames and self.window_max_frames < self.window_frames:
            raise ValueError(f"window_max_frames: expected 0 or at least window_frames ({self.window_frames}), got "
                             f"{self.window_max_frames}")
        if self.query_spacing_frames < self.window_stride * (self.window_frames - 1) + 1:
            raise ValueError("query_spacing_frames: expected at least the window span "
                             f"({self.window_stride * (self.window_frames - 1) + 1}), got {self.query_spacing_frames}")


@dataclass(frozen=True)
class Query:
    scene: str
    name: str
    T_world_cam: np.ndarray  # ground truth of the latest camera (the scene's world frame is the map frame)
    submap: PlaneSet
    ambiguous: bool
    timings_ms: dict = field(default_factory=dict)  # extraction (mean per frame) and submap building
    frames_left_out: int = 0  # window frames the odometry check left out of the submap
    window_frames: int = 0  # frames of its window (0: not recorded, the spec's window_frames)


@dataclass
class SceneResult:
    scene: str
    map_planes: int
    map_seconds: float
    outcomes: list[Outcome] = field(default_factory=list)

    def summary(self) -> Summary:
        return summarize(self.scene, self.outcomes)


def extraction_for_sensor(spec: EvalSpec, extraction=None):
    """``extraction`` (ExtractionParams, None = defaults) with its noise law set to the simulated sensor's: kinect
    ``1.425e-3 z^2``; stereo ``sigma_disparity / (f b) z^2`` at the spec's resolution; ToF ``~ b z`` (its constant
    term folded in at 2 m). Extraction's planarity tests and weights depend on it, so a mismatch ruins the planes."""
    from dataclasses import replace as _replace

    from sim.cameras import resolve_intrinsics
    from sim.noise import make_noise

    from reloc.extraction import ExtractionParams

    params = extraction if extraction is not None else ExtractionParams()
    law = make_noise(spec.noise).extraction_law(resolve_intrinsics(spec.camera, spec.width, spec.height).fx)
    if law is None:
        return params
    return _replace(params, noise_model=law[0], noise_coeff=law[1])


def make_plane_source(kind: str, scene, *, extraction=None) -> Callable:
    """``frame -> PlaneSet``: the simulator's ground truth ("oracle") or the extraction ("extraction", with
    ``extraction`` its parameters or None for the defaults)."""
    from reloc.mapping import oracle_source

    if kind == "oracle":
        return oracle_source(scene)
    if kind == "extraction":
        from reloc.mapping.sources import extraction_source

        return extraction_source(extraction)
    raise ValueError(f"kind: expected 'oracle' or 'extraction', got {kind!r}")


def _max_range(noise: str) -> float:
    from sim.noise import make_noise

    return float(min(make_noise(noise).max_range_m, 100.0))


def _frames(scene, poses: np.ndarray, spec: EvalSpec, seed: int) -> list:
    import sim

    return sim.simulate_frames(scene, poses, noise=spec.noise, camera=spec.camera, seed=seed, width=spec.width,
                               height=spec.height)


def build_scene_map(scene, spec: EvalSpec, source: Callable, mapping: MappingParams | None = None) -> PlaneMap:
    """The map of ``scene`` from its mapping trajectories (world frame = map frame).

    Keyframes are chosen from the trajectory's poses first (:func:`reloc.mapping.select_keyframes`), so only they
    are rendered and their planes extracted.
    """
    from sim.trajectories import make_trajectory

    from reloc.mapping import select_keyframes

    mapping = mapping or MappingParams()
    frames = []
    n_frames = 0
    for k, (kind, n) in enumerate(spec.map_trajectories):
        tour = {"tour": spec.map_tour} if kind in ("robot", "handheld") else {}
        poses = make_trajectory(kind, scene, n, spec.map_seed + k, **tour)
        keep = select_keyframes(poses, mapping.keyframe_min_translation_m, mapping.keyframe_min_rotation_rad)
        frames += _frames(scene, poses[keep], spec, spec.map_seed * 7919 + k)
        n_frames += n
    meta = {"source": f"sim:{scene.name}", "plane_source": spec.plane_source,
            "trajectories": [list(t) for t in spec.map_trajectories], "tour": spec.map_tour, "seed": spec.map_seed,
            "trajectory_frames": n_frames}
    return build_map(frames, source, mapping, meta=meta)


class _QueryWindow:
    """The frames of one query's window, newest last, rendered and their planes extracted only when asked for:
    the first ``window_frames`` with the query's seed (as before windows grew), each older chunk with its own."""

    def __init__(self, scene, spec: EvalSpec, source: Callable, poses: np.ndarray, end: int, seed: int):
        self.scene, self.spec, self.source, self.poses, self.seed = scene, spec, source, poses, seed
        self.end = end  # the query's own frame, the newest of its window
        self.idx = np.arange(end - spec.window_stride * (spec.window_frames - 1), end + 1, spec.window_stride)
        self.frames: list = []
        self.sets: list = []
        self.chunks = 0
        self.extract_ms = 0.0
        self.render_ms = 0.0

    def _add(self, idx: np.ndarray, seed: int) -> None:
        t0 = time.perf_counter()
        frames = _frames(self.scene, self.poses[idx], self.spec, seed)
        self.render_ms += (time.perf_counter() - t0) * 1e3
        t0 = time.perf_counter()
        sets = [self.source(f) for f in frames]
        self.extract_ms += (time.perf_counter() - t0) * 1e3
        self.frames, self.sets = frames + self.frames, sets + self.sets

    def fetch(self, k: int) -> tuple[list, list]:
        if not self.frames:
            self._add(self.idx, self.seed)
        stride = self.spec.window_stride
        while len(self.sets) < k and self.idx[0] - stride >= 0:
            more = np.arange(self.idx[0] - min(k - len(self.sets), self.idx[0] // stride) * stride, self.idx[0],
                             stride)
            self.chunks += 1
            self._add(more, self.seed + 50_000 * self.chunks)
            self.idx = np.concatenate([more, self.idx])
        k = min(k, len(self.sets))
        return self.sets[-k:], [f.T_world_cam for f in self.frames[-k:]]


def _query_window(scene, spec: EvalSpec, source: Callable, poses: np.ndarray, kind: int, q: int) -> _QueryWindow:
    """The window of query ``q`` along the trajectory of the ``kind``-th query kind (``poses``)."""
    return _QueryWindow(scene, spec, source, poses, (q + 1) * spec.query_spacing_frames - 1,
                        spec.query_seed * 7919 + 100 * kind + q)


def make_queries(scene, spec: EvalSpec, source: Callable, mapping: MappingParams | None = None) -> list[Query]:
    """Positive queries of ``scene``: windows along query trajectories (not the mapping ones), each grown back in
    time while its submap cannot pin a pose when ``spec.window_max_frames`` allows (its ambiguity label is that of
    the frames it ended with)."""
    from sim.trajectories import make_trajectory

    mapping = mapping or MappingParams()
    out = []
    most = max(spec.window_frames, spec.window_max_frames)
    for k, kind in enumerate(spec.query_kinds):
        n = spec.queries_per_kind * spec.query_spacing_frames
        poses = make_trajectory(kind, scene, n, spec.query_seed + k)
        for q in range(spec.queries_per_kind):
            window = _query_window(scene, spec, source, poses, k, q)
            stats: dict = {}
            t0 = time.perf_counter()
            submap, used = grow_submap(window.fetch, spec.window_frames, most, mapping, stats)
            t_all = (time.perf_counter() - t0) * 1e3
            idx = window.idx[-used:]
            amb = is_ambiguous(scene, poses[idx], max_range_m=_max_range(spec.noise))
            times = {"planes_per_frame": window.extract_ms / len(window.sets),
                     "submap": t_all - window.extract_ms - window.render_ms}
            out.append(Query(scene.name, f"{scene.name}/{kind}/{q}", poses[window.end], submap, amb, times,
                             stats.get("frames_left_out", 0), used))
    return out


def query_history(spec: EvalSpec, name: str, source: Callable | None = None) -> tuple[Callable, Callable]:
    """The history of positive query ``name`` (``scene/kind/index``) of the suite ``spec``, for growing its window
    further back than the suite did: ``(fetch, ambiguous)``. ``fetch(k)`` returns the plane sets and poses of its
    newest ``k`` frames as :func:`make_queries` fetches them (fewer where the trajectory begins); its first
    ``window_frames`` frames are the query's own (same poses and noise), older ones are rendered with seeds of their
    own. ``ambiguous(k)`` is the ambiguity label of those ``k`` frames (:func:`is_ambiguous`). ``source``: the plane
    source (default: the suite's, for the scene)."""
    from sim.scenes import make_scene
    from sim.trajectories import make_trajectory

    try:
        scene_name, kind, index = name.split("/")
        k, q = spec.query_kinds.index(kind), int(index)
    except ValueError:
        raise ValueError(f"name: expected scene/kind/index with a kind of {spec.query_kinds}, got {name!r}") from None
    if scene_name not in spec.scenes or not 0 <= q < spec.queries_per_kind:
        raise ValueError(f"name: no query {name!r} in this suite (scenes {spec.scenes}, indices 0 to "
                         f"{spec.queries_per_kind - 1})")
    scene = make_scene(scene_name)
    if source is None:
        ext = extraction_for_sensor(spec) if spec.plane_source == "extraction" else None
        source = make_plane_source(spec.plane_source, scene, extraction=ext)
    poses = make_trajectory(kind, scene, spec.queries_per_kind * spec.query_spacing_frames, spec.query_seed + k)
    window = _query_window(scene, spec, source, poses, k, q)

    def ambiguous(n: int) -> bool:
        window.fetch(n)
        return bool(is_ambiguous(scene, poses[window.idx[-n:]], max_range_m=_max_range(spec.noise)))

    return window.fetch, ambiguous


def evaluate_queries(relocalizer: Relocalizer, queries: list[Query], scene_name: str,
                     progress: Callable[[int], None] | None = None) -> list[Outcome]:
    """Relocalize each query in the map of ``scene_name``; queries of other scenes are negatives. A positive,
    unambiguous query is also checked at its true pose (:meth:`Relocalizer.confirm`): whether it is identifiable,
    and if so whether a symmetric twin of that pose is confirmed too (:mod:`reloc.evaluation.metrics`)."""
    symmetries = scene_symmetries(scene_name)
    out = []
    for q in queries:
        res = relocalizer.locate(q.submap)
        positive = q.scene == scene_name
        errors = pose_error(res.T_map_cam, q.T_world_cam) if (positive and res.relocalized) else None
        label = classify(positive, q.ambiguous and positive, res.relocalized, errors)
        ident, why, twin = None, "", None
        if positive and not q.ambiguous:
            ident, why = identifiable(relocalizer, q.submap, q.T_world_cam)
            if ident:
                twin = twin_confirmed(relocalizer, q.submap, q.T_world_cam, symmetries)
        nees, sigma = (covariance_check(res.T_map_cam, q.T_world_cam, res.covariance) if errors
                       else (math.nan, math.nan))
        out.append(Outcome(
            scene=scene_name, query=q.name, positive=positive, ambiguous=q.ambiguous and positive,
            status=res.status, reason=res.reason, label=label,
            translation_error_m=errors[0] if errors else math.nan, rotation_error_deg=errors[1] if errors else math.nan,
            total_ms=res.timings_ms.get("total", math.nan),
            timings_ms={**{k: v for k, v in res.timings_ms.items() if k != "total"}, **q.timings_ms},
            counts=res.counts, identifiable=ident, identifiable_reason=why, twin_confirmed=twin,
            pose_nees=nees, pose_sigma_m=sigma,
        ))
        if progress is not None:
            progress(1)
    return out


def _negatives(queries_by_scene: dict[str, list[Query]], scene_name: str, n: int) -> list[Query]:
    """``n`` queries of the other scenes, spread evenly over them (deterministic)."""
    pool = [q for s, qs in queries_by_scene.items() if s != scene_name for q in qs]
    if not pool or n <= 0:
        return []
    idx = np.unique(np.linspace(0, len(pool) - 1, min(n, len(pool))).round().astype(int))
    return [pool[i] for i in idx]


@dataclass
class Prepared:
    """Maps and queries of every scene of a suite, ready to be evaluated with any matching parameters."""

    spec: EvalSpec
    maps: dict
    map_seconds: dict
    queries: dict

    def evaluate(self, matching: MatchingParams | None = None, progress: Callable | None = None,
                 label: str = "") -> list[SceneResult]:
        """Relocalize every scene's positives and negatives with ``matching`` (its decision offsets scaled to the
        spec's sensor, as :meth:`MatchingParams.from_config` does for a live camera)."""
        results = []
        for name in self.spec.scenes:
            reloc = self.relocalizer(name, matching)
            qs = self.queries_in(name)
            desc = f"{label} {name}".strip() if label else f"{name}: relocalize"
            step = None if progress is None else (lambda n, _d=desc: progress(n, _d))
            results.append(SceneResult(name, len(self.maps[name]), self.map_seconds[name],
                                       evaluate_queries(reloc, qs, name, step)))
        return results

    def queries_in(self, scene: str) -> list[Query]:
        """The queries :meth:`evaluate` relocalizes in the map of ``scene``: its positives, then its negatives (from
        the other scenes)."""
        return self.queries[scene] + _negatives(self.queries, scene, self.spec.negatives_per_scene)

    def relocalizer(self, scene: str, matching: MatchingParams | None = None) -> Relocalizer:
        """A relocalizer in the map of ``scene`` with ``matching`` (its decision offsets scaled to the spec's
        sensor), as :meth:`evaluate` uses."""
        sensor = extraction_for_sensor(self.spec)
        matching = scaled_to_sensor(matching or MatchingParams(), sensor.noise_model, sensor.noise_coeff)
        return Relocalizer(self.maps[scene], matching)

    def find_query(self, name: str) -> Query:
        """The query called ``name`` (``scene/kind/index``, as the outcomes name them); ValueError naming a few
        others when there is none."""
        for qs in self.queries.values():
            for q in qs:
                if q.name == name:
                    return q
        names = [q.name for qs in self.queries.values() for q in qs]
        raise ValueError(f"no query {name!r} in this suite; its {len(names)} queries are named like "
                         + ", ".join(names[:3]))


def prepare_suite(spec: EvalSpec, mapping: MappingParams | None = None, *, extraction=None,
                  progress: Callable | None = None) -> Prepared:
    """Build every scene's map and queries (the slow part: rendering, extraction, fusion)."""
    from sim.scenes import make_scene

    mapping = mapping or MappingParams()
    maps, seconds, queries = {}, {}, {}
    for name in spec.scenes:
        scene = make_scene(name)
        ext = extraction_for_sensor(spec, extraction) if spec.plane_source == "extraction" else None
        source = make_plane_source(spec.plane_source, scene, extraction=ext)
        if progress is not None:
            progress(0, f"{name}: map")
        t0 = time.perf_counter()
        maps[name] = build_scene_map(scene, spec, source, mapping)
        seconds[name] = time.perf_counter() - t0
        if progress is not None:
            progress(1, f"{name}: queries")
        queries[name] = make_queries(scene, spec, source, mapping)
        if progress is not None:
            progress(1, None)
    return Prepared(spec, maps, seconds, queries)


def run_suite(spec: EvalSpec, matching: MatchingParams | None = None, mapping: MappingParams | None = None, *,
              extraction=None, progress: Callable | None = None) -> list[SceneResult]:
    """Every scene of ``spec``: its map, its positives and negatives, their outcomes.

    ``progress(n, description)`` is called as work is done (2 steps per scene to prepare, then one per query).
    """
    return prepare_suite(spec, mapping, extraction=extraction, progress=progress).evaluate(matching, progress)


def run_ablation(spec: EvalSpec, variants: tuple[str, ...], matching: MatchingParams | None = None,
                 mapping: MappingParams | None = None, *, extraction=None,
                 progress: Callable | None = None) -> dict[str, list[SceneResult]]:
    """The suite once per ablation variant (Table 3): matching switches change the relocalizer; VR-NE and VR-NM
    switch extraction features off, so with the extraction source their maps and queries are rebuilt (with the
    oracle source they equal Ours)."""
    matching = matching or MatchingParams()
    prepared: dict[str, Prepared] = {}
    out = {}
    for variant in variants:
        ext_key = variant if (spec.plane_source == "extraction" and variant in ("VR-NE", "VR-NM")) else "base"
        if ext_key not in prepared:
            ext = extraction
            if ext_key != "base":
                from reloc.mapping.sources import extraction_ablation

                ext = extraction_ablation(extraction, variant)
            prepared[ext_key] = prepare_suite(spec, mapping, extraction=ext, progress=progress)
        out[variant] = prepared[ext_key].evaluate(ablation_params(matching, variant), progress, label=variant)
    return out


def sensor_spec(spec, noise: str):
    """``spec`` (an :class:`EvalSpec`, a :class:`reloc.demo.DemoSpec`: a dataclass with ``noise``, ``camera``,
    ``width`` and ``height``) with the noise model ``noise`` and the camera that goes with it: the stereo model is the
    OAK-D class camera's, at its own resolution of 640 x 400 (its noise grows as z^2 / (f b), f in pixels, so the same
    camera rendered smaller would be a much noisier one than any OAK); the other models keep the spec's camera and
    size."""
    spec = replace(spec, noise=noise)
    if noise in SENSOR_CAMERAS:
        camera, width, height = SENSOR_CAMERAS[noise]
        spec = replace(spec, camera=camera, width=width, height=height)
    return spec


# The suite's mapping runs enter every room (since 2026-11-29; random walks before, which left whole rooms out of
# the maps: docs/BENCHMARKS.md, "Maps from runs that enter every room").
SUITE_MAP_TOUR = "rooms"


def suite_spec(noise: str = "kinect", *, plane_source: str = "extraction", scenes: tuple[str, ...] = SCENES,
               queries: int = 10, negatives: int = 20, window: int = 40, max_window: int | None = None,
               map_frames: int = 3000, query_seed: int = EvalSpec.query_seed,
               map_seed: int = EvalSpec.map_seed, map_tour: str = SUITE_MAP_TOUR) -> EvalSpec:
    """The suite of ``reloc eval`` and ``benchmarks/reloc_accuracy.py`` (the figures of docs/BENCHMARKS.md), one
    function so that both run the same one: frames of 320 x 240 (for stereo noise the OAK-D's own 640 x 400, see
    :func:`sensor_spec`), ``queries`` positives per trajectory kind and scene, ``negatives`` per scene, windows of
    ``window`` frames grown up to ``max_window`` (default 3 x ``window``; 0: they do not grow), queries at least
    three windows apart, two mapping trajectories of ``map_frames`` frames going where ``map_tour`` says."""
    spec = EvalSpec(scenes=tuple(scenes), plane_source=plane_source, width=320, height=240, queries_per_kind=queries,
                    negatives_per_scene=negatives, window_frames=window,
                    window_max_frames=3 * window if max_window is None else max_window,
                    query_spacing_frames=max(60, 3 * window + 30),
                    map_trajectories=(("robot", map_frames), ("handheld", map_frames)), map_tour=map_tour,
                    query_seed=query_seed, map_seed=map_seed)
    return sensor_spec(spec, noise)


def quick_spec(**changes) -> EvalSpec:
    """A small suite (two scenes, few queries, short maps, frames of 160 x 120) for tests and the demo."""
    base = EvalSpec(scenes=("living_room", "office"), map_trajectories=(("robot", 500), ("handheld", 500)),
                    queries_per_kind=4, negatives_per_scene=6)
    return replace(base, **changes)
