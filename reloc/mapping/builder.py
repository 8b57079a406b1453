"""Building a global plane map from a posed sequence, and submaps from a window of frames.

- :func:`select_keyframes`: a frame becomes a keyframe after the camera moved ``keyframe_min_translation_m`` or
  turned ``keyframe_min_rotation_rad`` since the last keyframe (the first frame always is one).
- :class:`MapBuilder`: per keyframe, planes (camera frame) are moved into the map frame with ``T_map_cam`` and
  fused (:class:`~reloc.mapping.fusion.PlaneAccumulator`); when the keyframe's depth image is given, the space its
  rays crossed is carved into a voxel set of known free space (:class:`FreeSpace`), which lets matching tell a
  plane the map contradicts from one the map never saw. :meth:`MapBuilder.finish` merges planes that grew together
  and returns the :class:`~reloc.mapping.plane_map.PlaneMap`.
- :func:`build_map`: the one-shot call over frames with a plane source (extraction, or the simulator's oracle).
- :func:`build_submap` / :class:`SubmapBuilder`: one frame's planes, or a window of K frames fused with their
  relative (odometry) poses, in the frame of the latest camera, with its gravity. Older frames whose planes, moved
  with odometry, disagree with the newest frame's view of the same surfaces are left out first
  (:func:`odometry_consistent_frames`): a wrong odometry pose would otherwise make a rigidly displaced submap.
- :func:`grow_submap`: a window that grows back in time while its submap cannot pin a pose
  (:func:`submap_constrained`: too few large planes, or too little area along its weakest direction).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Callable, Iterable

import numpy as np

from reloc._params import with_changes
from reloc.mapping.fusion import FusionParams, PlaneAccumulator, plane_basis, plane_cells
from reloc.mapping.plane_map import PlaneMap
from reloc.planes import weakest_direction_support
from reloc.planeset import PlaneSet, moved_geometry
from reloc.transforms import check_transform, invert, rotation_angle_rad

__all__ = ["MappingParams", "select_keyframes", "FreeSpace", "MapBuilder", "build_map", "build_submap", "SubmapBuilder",
           "odometry_consistent_frames", "submap_constrained", "grow_submap"]

# A plane of an older frame and one of the newest frame are views of one surface when their normals are within
# this angle, the older plane's centroid within this distance of the newer plane, and at least half of the older
# plane's samples, projected on the newer plane, fall within about a cell of the newer plane's own (a door in its
# niche is not the wall around it).
_PARTNER_MAX_ANGLE_RAD = math.radians(10.0)
_PARTNER_MAX_OFFSET_M = 0.3
_PARTNER_CELL_M = 0.1
_PARTNER_MIN_OVERLAP = 0.5


@dataclass(frozen=True)
class MappingParams:
    keyframe_min_translation_m: float = 0.2
    keyframe_min_rotation_rad: float = math.radians(10.0)
    fuse_max_angle_rad: float = math.radians(8.0)
    fuse_max_offset_m: float = 0.03
    fuse_min_overlap: float = 0.0
    fuse_check_bridged: bool = True
    fuse_max_far_fraction: float = 0.25
    fuse_check_local: bool = False
    map_sample_spacing_m: float = 0.1
    min_observations: int = 3
    submap_window_frames: int = 1
    submap_min_observations: int = 2
    free_space_voxel_m: float = 0.15
    free_space_margin_m: float = 0.3
    free_space_pixel_stride: int = 8
    free_space_max_range_m: float = 5.0
    submap_check_sigmas: float = 4.0
    submap_check_min_angle_rad: float = math.radians(1.0)
    submap_check_min_offset_m: float = 0.02
    submap_check_min_area_m2: float = 0.3
    submap_check_fraction: float = 0.34
    submap_max_window_frames: int = 0
    submap_grow_min_planes: int = 6
    submap_grow_min_support_m2: float = 1.0
    submap_grow_min_area_m2: float = 0.5

    def __post_init__(self) -> None:
        if self.keyframe_min_translation_m < 0 or self.keyframe_min_rotation_rad < 0:
            raise ValueError("MappingParams: keyframe thresholds must be >= 0, got "
                             f"{self.keyframe_min_translation_m} m and {self.keyframe_min_rotation_rad} rad")
        if self.min_observations < 1:
            raise ValueError(f"MappingParams.min_observations: expected >= 1, got {self.min_observations}")
        if self.free_space_voxel_m < 0 or self.free_space_margin_m < 0 or self.free_space_pixel_stride < 1:
            raise ValueError("MappingParams: free_space_voxel_m and free_space_margin_m must be >= 0 and "
                             f"free_space_pixel_stride >= 1, got {self.free_space_voxel_m}, "
                             f"{self.free_space_margin_m}, {self.free_space_pixel_stride}")
        if self.submap_window_frames < 1:
            raise ValueError(f"MappingParams.submap_window_frames: expected >= 1, got {self.submap_window_frames}")
        if self.submap_max_window_frames and self.submap_max_window_frames < self.submap_window_frames:
            raise ValueError("MappingParams.submap_max_window_frames: expected 0 (the window does not grow) or at "
                             f"least submap_window_frames ({self.submap_window_frames}), got "
                             f"{self.submap_max_window_frames}")
        if self.submap_max_window_frames < 0 or self.submap_grow_min_planes < 0:
            raise ValueError("MappingParams: submap_max_window_frames and submap_grow_min_planes must be >= 0, got "
                             f"{self.submap_max_window_frames} and {self.submap_grow_min_planes}")
        for name in ("submap_check_sigmas", "submap_check_min_angle_rad", "submap_check_min_offset_m",
                     "submap_check_min_area_m2", "submap_check_fraction", "submap_grow_min_support_m2",
                     "submap_grow_min_area_m2"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"MappingParams.{name}: expected a finite number >= 0, got {v!r}")
        if self.submap_check_fraction > 1:
            raise ValueError(f"MappingParams.submap_check_fraction: expected a fraction in [0, 1], got "
                             f"{self.submap_check_fraction!r}")
        self.fusion  # validates the fusion thresholds

    def with_(self, **changes) -> "MappingParams":
        """A copy with some fields changed (``NAME_deg`` sets ``NAME_rad`` in degrees); unknown names and values of
        the wrong type raise ValueError naming the parameter."""
        return with_changes(self, changes)

    @property
    def fusion(self) -> FusionParams:
        return FusionParams(self.fuse_max_angle_rad, self.fuse_max_offset_m, self.fuse_min_overlap,
                            self.map_sample_spacing_m, self.fuse_check_bridged, self.fuse_max_far_fraction,
                            self.fuse_check_local)

    @classmethod
    def from_config(cls, cfg) -> "MappingParams":
        m = cfg.mapping
        return cls(
            keyframe_min_translation_m=m.keyframe_min_translation_m,
            keyframe_min_rotation_rad=math.radians(m.keyframe_min_rotation_deg),
            fuse_max_angle_rad=math.radians(m.fuse_max_angle_deg),
            fuse_max_offset_m=m.fuse_max_offset_m,
            fuse_min_overlap=m.fuse_min_overlap,
            fuse_check_bridged=m.fuse_check_bridged,
            fuse_max_far_fraction=m.fuse_max_far_fraction,
            fuse_check_local=m.fuse_check_local,
            map_sample_spacing_m=m.map_sample_spacing_m,
            min_observations=m.min_observations,
            submap_window_frames=m.submap_window_frames,
            submap_min_observations=m.submap_min_observations,
            free_space_voxel_m=m.free_space_voxel_m,
            free_space_margin_m=m.free_space_margin_m,
            free_space_pixel_stride=m.free_space_pixel_stride,
            free_space_max_range_m=m.free_space_max_range_m,
            submap_check_sigmas=m.submap_check_sigmas,
            submap_check_min_angle_rad=math.radians(m.submap_check_min_angle_deg),
            submap_check_min_offset_m=m.submap_check_min_offset_m,
            submap_check_min_area_m2=m.submap_check_min_area_m2,
            submap_check_fraction=m.submap_check_fraction,
            submap_max_window_frames=m.submap_max_window_frames,
            submap_grow_min_planes=m.submap_grow_min_planes,
            submap_grow_min_support_m2=m.submap_grow_min_support_m2,
            submap_grow_min_area_m2=m.submap_grow_min_area_m2,
        )


def select_keyframes(T_world_cams: np.ndarray, min_translation_m: float, min_rotation_rad: float) -> np.ndarray:
    """Indices of the keyframes among (N, 4, 4) poses: the first, then each one far enough from the last kept."""
    poses = np.asarray(T_world_cams, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"T_world_cams: expected shape (N, 4, 4), got {poses.shape}")
    keep = []
    last = None
    for i, T in enumerate(poses):
        if last is None:
            keep.append(i)
            last = T
            continue
        moved = float(np.linalg.norm(T[:3, 3] - last[:3, 3]))
        turned = rotation_angle_rad(last[:3, :3].T @ T[:3, :3])
        if moved >= min_translation_m or turned >= min_rotation_rad:
            keep.append(i)
            last = T
    return np.array(keep, dtype=np.int64)


class FreeSpace:
    """Voxels (edge ``voxel_m``) that depth rays crossed: space known to be empty, as sorted unique int64 keys."""

    def __init__(self, voxel_m: float, margin_m: float, pixel_stride: int, max_range_m: float):
        self.voxel_m = voxel_m
        self.margin_m = margin_m
        self.pixel_stride = pixel_stride
        self.max_range_m = max_range_m
        self._keys = np.zeros(0, np.int64)
        self._pending: list[np.ndarray] = []

    def carve(self, frame, T_map_cam: np.ndarray) -> None:
        """Add the free space seen by ``frame`` (a DepthFrame) from ``T_map_cam``."""
        from reloc.mapping import _kernels as K

        depth = np.ascontiguousarray(frame.depth_m, dtype=np.float32)
        intr = frame.intrinsics
        H, W = depth.shape
        s = self.pixel_stride
        per_ray = int(self.max_range_m / (0.5 * self.voxel_m)) + 2
        out = np.empty(((H + s - 1) // s) * ((W + s - 1) // s) * per_ray, np.int64)
        T = np.asarray(T_map_cam, dtype=np.float64)
        n = K.carve_free_space(depth, float(intr.fx), float(intr.fy), float(intr.cx), float(intr.cy),
                               np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]), s, self.voxel_m,
                               self.margin_m, self.max_range_m, out)
        self._pending.append(np.unique(out[:n]))
        if len(self._pending) >= 32:
            self._flush()

    def _flush(self) -> None:
        if self._pending:
            self._keys = np.unique(np.concatenate([self._keys, *self._pending]))
            self._pending = []

    def keys(self, occupied_points: np.ndarray | None = None) -> np.ndarray:
        """The free voxel keys, minus the voxels holding or touching ``occupied_points`` (N, 3) (surfaces seen
        at a grazing angle must never count as free)."""
        from reloc.mapping.fusion import _neighbours, voxel_keys

        self._flush()
        keys = self._keys
        if occupied_points is not None and len(occupied_points) and len(keys):
            occ = np.unique(_neighbours(np.unique(voxel_keys(occupied_points, self.voxel_m))).ravel())
            keys = keys[~np.isin(keys, occ, assume_unique=True)]
        return keys


class MapBuilder:
    """Fuses keyframe plane sets into a map; gravity in the map frame is averaged from the keyframes' gravity."""

    def __init__(self, params: MappingParams | None = None):
        self.params = params or MappingParams()
        self._acc = PlaneAccumulator(self.params.fusion, frame="map")
        p = self.params
        self._free = (FreeSpace(p.free_space_voxel_m, p.free_space_margin_m, p.free_space_pixel_stride,
                                p.free_space_max_range_m) if p.free_space_voxel_m > 0 else None)
        self._gravity_sum = np.zeros(3)
        self._gravity_tolerance = 0.0  # the largest of the keyframes' (a camera-y gravity keeps its tilt allowance)
        self.keyframes = 0
        self.carved = 0

    def add(self, planes_cam: PlaneSet, T_map_cam: np.ndarray, frame=None) -> np.ndarray:
        """Fuse one keyframe's planes (camera frame) seen from ``T_map_cam``; with ``frame`` (its DepthFrame) also
        carve the free space it saw. Returns the planes' indices in the accumulator (final indices are assigned by
        :meth:`finish`)."""
        if not isinstance(planes_cam, PlaneSet):
            raise ValueError(f"planes_cam: expected a PlaneSet, got {type(planes_cam).__name__}")
        T = check_transform(T_map_cam, "T_map_cam")
        planes_map = planes_cam.transformed(T, "map")
        if planes_map.gravity is not None:
            self._gravity_sum += planes_map.gravity
            self._gravity_tolerance = max(self._gravity_tolerance, planes_map.gravity_tolerance_rad)
        self.keyframes += 1
        if frame is not None and self._free is not None:
            self._free.carve(frame, T)
            self.carved += 1
        return self._acc.add(planes_map)

    def finish(self, meta: dict | None = None) -> PlaneMap:
        """Merge planes that grew together and return the map (gravity -z when no keyframe carried gravity)."""
        self._acc.merge_pass()
        g = self._gravity_sum
        gravity = g / np.linalg.norm(g) if np.linalg.norm(g) > 1e-9 else np.array([0.0, 0.0, -1.0])
        planes, obs = self._acc.to_planeset(gravity=gravity, min_observations=self.params.min_observations,
                                            gravity_tolerance_rad=self._gravity_tolerance)
        info = {"keyframe_count": self.keyframes}
        info.update(meta or {})
        if self._free is not None and self.carved:
            free = self._free.keys(planes.sample_points)
            return PlaneMap(planes, obs, info, free_keys=free, free_voxel_m=self._free.voxel_m)
        return PlaneMap(planes, obs, info)


def build_map(
    frames: Iterable,
    plane_source: Callable,
    params: MappingParams | None = None,
    *,
    meta: dict | None = None,
    progress: Callable[[int], None] | None = None,
) -> PlaneMap:
    """One-shot: the plane map of posed ``frames`` (DepthFrames with ``T_world_cam``; the world frame becomes the
    map frame). ``plane_source(frame) -> PlaneSet`` gives each keyframe's planes in its camera frame;
    ``progress(1)`` is called once per frame read. Frames without a pose are skipped and counted in the metadata.
    """
    params = params or MappingParams()
    builder = MapBuilder(params)
    last = None
    n_frames = n_unposed = n_failed = 0
    for frame in frames:
        n_frames += 1
        if progress is not None:
            progress(1)
        T = getattr(frame, "T_world_cam", None)
        if T is None:
            n_unposed += 1
            continue
        if last is not None:
            moved = float(np.linalg.norm(T[:3, 3] - last[:3, 3]))
            turned = rotation_angle_rad(last[:3, :3].T @ T[:3, :3])
            if moved < params.keyframe_min_translation_m and turned < params.keyframe_min_rotation_rad:
                continue
        try:
            planes = plane_source(frame)
        except ValueError:
            n_failed += 1  # a bad frame is counted, the map goes on
            continue
        builder.add(planes, T, frame if getattr(frame, "depth_m", None) is not None else None)
        last = T
    info = {"frame_count": n_frames, "frames_without_pose": n_unposed, "frames_failed": n_failed}
    info.update(meta or {})
    return builder.finish(info)


def _offset_variance(cov: np.ndarray, point: np.ndarray) -> float:
    """Variance of a plane's signed distance at ``point`` from the (4, 4) covariance of its ``(n, d)``."""
    v = np.array([point[0], point[1], point[2], 1.0])
    return float(v @ cov @ v)


_KEY_STRIDE = 1 << 22  # cell (i, j) -> i * stride + j: distinct while |j| < 2^21 cells (210 km of 0.1 m cells)
_NEIGHBOURS = np.array([a * _KEY_STRIDE + b for a in (-1, 0, 1) for b in (-1, 0, 1)], dtype=np.int64)


def _cell_keys(points: np.ndarray, basis, cell: float) -> np.ndarray:
    """One int64 key per point for the plane cell (:func:`~reloc.mapping.fusion.plane_cells`) it projects into."""
    ij = plane_cells(points, basis, cell)
    return ij[:, 0] * _KEY_STRIDE + ij[:, 1]


class _MovedGeometry:
    """What the odometry check reads of ``plane_sets[k].subset(sel).transformed(T, ...)`` (normals, centroids,
    radii, areas, (n, d) covariances, samples): :func:`~reloc.planeset.moved_geometry` on the selected rows, the
    figures of ``transformed`` to the last bit, without the sufficient statistics and the validation of two new
    PlaneSets (a window of 40 frames: 15 -> 10 ms)."""

    def __init__(self, ps: PlaneSet, sel: np.ndarray, T_a_b: np.ndarray):
        self.radii = ps.radii[sel]
        self.areas = ps.areas[sel]
        pieces = [ps.samples_of(int(i)) for i in sel]
        self.sample_ptr = np.concatenate([[0], np.cumsum([len(p) for p in pieces])]).astype(np.int64)
        pts = np.concatenate(pieces) if pieces else np.zeros((0, 3), np.float32)
        self.normals, self.centroids, self.covariances, self.sample_points = moved_geometry(
            T_a_b, ps.normals[sel], ps.centroids[sel], ps.covariances[sel], pts)

    def samples_of(self, i: int) -> np.ndarray:
        return self.sample_points[self.sample_ptr[i] : self.sample_ptr[i + 1]]


def odometry_consistent_frames(plane_sets: list[PlaneSet], T_odom_cams, params: MappingParams) -> np.ndarray:
    """(K,) bool: the frames of a window whose odometry agrees with the newest frame's (the newest always does).

    Each older frame's planes of at least ``submap_check_min_area_m2`` are moved with odometry into the newest
    camera frame and paired with the newest frame's view of the same surface (normals within 10 degrees, centroid
    within 0.3 m of it, half of its samples over the newer plane's; the nearest such plane). A pair disagrees by
    more than ``submap_check_sigmas`` times the two fits' uncertainty (from their ``(n, d)`` covariances) and at
    least ``submap_check_min_angle_rad`` or ``submap_check_min_offset_m``. The frame is left out when its
    disagreeing pairs weigh (square root of area) at least ``submap_check_fraction`` of its pairs: its odometry pose
    is off, and fused in it would shift or turn the submap rigidly, which no check of the matcher can see. (One
    plane alone does not decide: fits of a surface seen partly, or a neighbour taken for it, differ by a degree or
    two between views far apart.) Frames sharing no surface with the newest are kept (nothing to compare).
    ``submap_check_sigmas`` = 0 turns the check off.
    """
    n = len(plane_sets)
    keep = np.ones(n, dtype=bool)
    p = params
    newest = plane_sets[-1]
    big = np.flatnonzero(newest.areas >= p.submap_check_min_area_m2)
    if p.submap_check_sigmas <= 0 or n < 2 or len(big) == 0:
        return keep
    nb, db, cb, rb = newest.normals[big], newest.offsets[big], newest.centroids[big], newest.radii[big]
    cells: dict[int, tuple] = {}  # a newest plane's basis and sorted occupied cells (dilated), made when first needed
    T_last_odom = invert(check_transform(T_odom_cams[-1], "T_odom_cams[-1]"))
    cos_partner = math.cos(_PARTNER_MAX_ANGLE_RAD)
    for k in range(n - 1):
        sel = np.flatnonzero(plane_sets[k].areas >= p.submap_check_min_area_m2)
        if len(sel) == 0:
            continue
        T = T_last_odom @ check_transform(T_odom_cams[k], f"T_odom_cams[{k}]")
        moved = _MovedGeometry(plane_sets[k], sel, T)
        paired = disagreeing = 0.0
        for a in range(len(sel)):
            ca = moved.centroids[a]
            cos_ab = nb @ moved.normals[a]
            off = nb @ ca + db
            near = np.flatnonzero((cos_ab >= cos_partner) & (np.abs(off) <= _PARTNER_MAX_OFFSET_M)
                                  & (np.linalg.norm(cb - ca, axis=1) <= rb + moved.radii[a]))
            samples = moved.samples_of(a).astype(np.float64)
            i = -1
            for c in near[np.argsort(np.abs(off[near]), kind="stable")]:
                b = int(big[c])
                if b not in cells:
                    basis = plane_basis(newest.normals[b])
                    own = _cell_keys(newest.samples_of(b).astype(np.float64), basis, _PARTNER_CELL_M)
                    cells[b] = (basis, np.unique((own[:, None] + _NEIGHBOURS[None, :]).ravel()))
                basis, occupied = cells[b]
                keys = _cell_keys(samples, basis, _PARTNER_CELL_M)
                at = np.minimum(np.searchsorted(occupied, keys), len(occupied) - 1)
                if len(keys) and len(occupied) and np.mean(occupied[at] == keys) >= _PARTNER_MIN_OVERLAP:
                    i = int(c)
                    break
            if i < 0:
                continue
            b = int(big[i])
            angle = math.acos(min(1.0, float(cos_ab[i])))
            sigma_angle = math.sqrt(max(0.0, float(np.trace(moved.covariances[a][:3, :3])
                                                   + np.trace(newest.covariances[b][:3, :3]))))
            sigma_offset = math.sqrt(max(0.0, _offset_variance(newest.covariances[b], ca)
                                         + _offset_variance(moved.covariances[a], ca)))
            weight = math.sqrt(min(moved.areas[a], newest.areas[b]))
            paired += weight
            if (angle > max(p.submap_check_min_angle_rad, p.submap_check_sigmas * sigma_angle)
                    or abs(off[i]) > max(p.submap_check_min_offset_m, p.submap_check_sigmas * sigma_offset)):
                disagreeing += weight
        if disagreeing > 0 and disagreeing >= p.submap_check_fraction * paired:
            keep[k] = False
    return keep


def build_submap(
    plane_sets: list[PlaneSet],
    T_odom_cams: list[np.ndarray] | np.ndarray | None = None,
    params: MappingParams | None = None,
    stats: dict | None = None,
) -> PlaneSet:
    """The submap of a window of frames in the frame of the LAST camera (frame "cam", its gravity).

    ``plane_sets``: each frame's planes in its own camera frame; ``T_odom_cams``: their poses in any common frame
    (odometry; only relative poses matter), required when more than one frame is given. One frame returns its
    planes unchanged (labels dropped). The submap's ``viewpoints`` are the positions of the window's cameras in the
    latest camera's frame (the origin alone for one frame). Older frames whose odometry disagrees with the newest
    frame's view are left out (:func:`odometry_consistent_frames`); with ``stats`` (a dict) their number is added to
    ``stats["frames_left_out"]``.
    """
    if not plane_sets:
        raise ValueError("plane_sets: expected at least one plane set, got none")
    if len(plane_sets) == 1:
        return replace(plane_sets[0].subset(np.arange(len(plane_sets[0]))), viewpoints=np.zeros((1, 3)))
    if T_odom_cams is None or len(T_odom_cams) != len(plane_sets):
        raise ValueError(f"T_odom_cams: expected {len(plane_sets)} poses (one per plane set), got "
                         f"{None if T_odom_cams is None else len(T_odom_cams)}")
    params = params or MappingParams()
    keep = odometry_consistent_frames(plane_sets, T_odom_cams, params)
    if not keep.all():
        if stats is not None:
            stats["frames_left_out"] = stats.get("frames_left_out", 0) + int((~keep).sum())
        plane_sets = [ps for ps, ok in zip(plane_sets, keep) if ok]
        T_odom_cams = [T for T, ok in zip(T_odom_cams, keep) if ok]
        if len(plane_sets) == 1:
            return replace(plane_sets[0].subset(np.arange(len(plane_sets[0]))), viewpoints=np.zeros((1, 3)))
    T_last_odom = invert(check_transform(T_odom_cams[-1], "T_odom_cams[-1]"))
    acc = PlaneAccumulator(params.fusion, frame="cam")
    views = np.empty((len(plane_sets), 3))
    for k, (ps, T) in enumerate(zip(plane_sets, T_odom_cams)):
        T_last_k = T_last_odom @ check_transform(T, f"T_odom_cams[{k}]")
        views[k] = T_last_k[:3, 3]
        acc.add(ps.transformed(T_last_k, "cam"))
    acc.merge_pass()
    # Planes seen in one frame only are dropped from windows of 3+ frames: mostly facets of clutter.
    min_obs = params.submap_min_observations if len(plane_sets) >= 3 else 1
    gravity, tolerance = plane_sets[-1].gravity, plane_sets[-1].gravity_tolerance_rad
    if gravity is None:
        gs = [T_last_odom[:3, :3] @ np.asarray(T)[:3, :3] @ ps.gravity for ps, T in zip(plane_sets, T_odom_cams)
              if ps.gravity is not None]
        gravity = np.mean(gs, axis=0) if gs else None
        tolerance = max((ps.gravity_tolerance_rad for ps in plane_sets if ps.gravity is not None), default=0.0)
    planes, _ = acc.to_planeset(gravity=gravity, min_observations=min_obs, gravity_tolerance_rad=tolerance)
    return replace(planes, viewpoints=views)


def submap_constrained(submap: PlaneSet, params: MappingParams | None = None) -> tuple[bool, str]:
    """Whether ``submap`` can pin a pose by itself: at least ``submap_grow_min_planes`` planes of at least
    ``submap_grow_min_area_m2``, and of those at least ``submap_grow_min_support_m2`` along the weakest direction of
    the translation they fix (:func:`reloc.planes.weakest_direction_support`). The matcher asks as much of the
    planes it matches (five of them, 0.4 m^2 along the weakest direction), so a submap short of this is likely to be
    rejected or, worse, to slide: a corridor view of floor, ceiling and two walls. Returns ``(ok, why not)``."""
    params = params or MappingParams()
    large = np.flatnonzero(submap.areas >= params.submap_grow_min_area_m2)
    if len(large) < max(params.submap_grow_min_planes, 1):
        return False, (f"{len(large)} planes of at least {params.submap_grow_min_area_m2} m^2 (needs "
                       f"{params.submap_grow_min_planes})")
    _, support = weakest_direction_support(submap.normals[large], submap.areas[large])
    if support < params.submap_grow_min_support_m2:
        return False, (f"{support:.2f} m^2 along its weakest direction (needs {params.submap_grow_min_support_m2})")
    return True, ""


def grow_submap(fetch: Callable[[int], tuple[list[PlaneSet], list[np.ndarray]]], first: int, most: int,
                params: MappingParams | None = None, stats: dict | None = None) -> tuple[PlaneSet, int]:
    """The submap of the newest ``first`` frames of a window, grown back in time while it is not constrained
    (:func:`submap_constrained`), ``first // 2`` frames (at least one) at a time, up to ``most`` frames or as far
    as the history goes.

    ``fetch(k)`` returns the plane sets and odometry poses of the newest ``k`` frames, oldest first (fewer when the
    history is shorter). A view along a corridor, of floor, ceiling and two walls, cannot tell where along the
    corridor it is; the frames before it, which saw the door it passed, can. Returns ``(submap, frames used)``;
    ``stats`` (a dict) gets ``frames_left_out`` of the last build (:func:`build_submap`) and ``window_frames``.
    """
    params = params or MappingParams()
    if first < 1 or most < first:
        raise ValueError(f"first, most: expected 1 <= first <= most, got {first} and {most}")
    k, step = first, max(1, first // 2)
    while True:
        sets, poses = fetch(k)
        if not sets:
            raise ValueError("fetch: returned no frames")
        built: dict = {}
        submap = build_submap(sets, poses, params, built)
        if len(sets) < k or k >= most or submap_constrained(submap, params)[0]:
            break
        k = min(most, k + step)
    if stats is not None:
        stats["frames_left_out"] = stats.get("frames_left_out", 0) + built.get("frames_left_out", 0)
        stats["window_frames"] = len(sets)
    return submap, len(sets)


class SubmapBuilder:
    """A sliding window of the last K frames' planes and odometry poses; :meth:`submap` fuses them."""

    def __init__(self, params: MappingParams | None = None, window_frames: int | None = None):
        self.params = params or MappingParams()
        k = self.params.submap_window_frames if window_frames is None else window_frames
        if not isinstance(k, (int, np.integer)) or k < 1:
            raise ValueError(f"window_frames: expected an integer >= 1, got {k!r}")
        self._planes: deque = deque(maxlen=k)
        self._poses: deque = deque(maxlen=k)
        self._unposed = False  # the newest frame came without odometry

    def push(self, planes_cam: PlaneSet, T_odom_cam: np.ndarray | None) -> None:
        """Add a frame; a frame without odometry, and the frame after it, restart the window (their poses relative
        to the frames before are unknown)."""
        if T_odom_cam is None or self._unposed:
            self._planes.clear()
            self._poses.clear()
        self._unposed = T_odom_cam is None
        self._planes.append(planes_cam)
        self._poses.append(np.eye(4) if T_odom_cam is None else np.asarray(T_odom_cam, dtype=np.float64))

    def __len__(self) -> int:
        return len(self._planes)

    def submap(self) -> PlaneSet:
        return build_submap(list(self._planes), list(self._poses), self.params)
