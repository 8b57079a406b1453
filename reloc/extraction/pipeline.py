"""Depth frame (or point cloud) to plane set: the stages composed, timed, with buffers kept across frames."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np

from reloc.camera import DepthFrame, gravity_from_camera_y
from reloc.extraction._workspace import Workspace
from reloc.extraction.assemble import assemble_plane_set
from reloc.extraction.backproject import depth_to_key_image, depth_to_points, drop_flying_pixels
from reloc.extraction.fit import check_points
from reloc.extraction.merge import MergedPlanes, merge_voxel_planes, refine_merged_planes
from reloc.extraction.params import ExtractionParams
from reloc.extraction.voxel_planes import VoxelPlanes, fit_voxel_planes, refine_voxel_planes
from reloc.extraction.voxelize import (
    MAX_FRUSTUM_CELLS, VoxelGrid, frustum_box, frustum_cells, voxelize, voxelize_key_image,
)
from reloc.planeset import PlaneSet

__all__ = ["ExtractionResult", "PlaneExtractor", "extract_planes", "extract_planes_from_points", "STAGES"]

STAGES = ("backproject", "voxelize", "fit", "weight", "merge", "refine", "finalize")


@dataclass(frozen=True)
class ExtractionResult:
    """The plane set of one frame, the time each stage took (ms, keys :data:`STAGES` and ``total``) and counts
    (``points``, ``voxels``, ``planar_voxels``, ``merged_planes`` before the size filter, ``fragment_merges``)."""

    planes: PlaneSet
    timings_ms: dict[str, float]
    stats: dict[str, int] = field(default_factory=dict)


class PlaneExtractor:
    """Extraction with fixed parameters and scratch buffers reused from frame to frame (one thread at a time)."""

    def __init__(self, params: ExtractionParams | None = None):
        self.params = params if params is not None else ExtractionParams()
        self.workspace = Workspace()
        self._box = None
        self._box_key = None

    def gravity_of(self, frame: DepthFrame) -> tuple[np.ndarray | None, float]:
        """The frame's gravity, or the fallback of ``params.gravity_fallback`` when it has none, and how far the
        true direction may be from it (radians: 0 when measured or fixed by the mounting)."""
        if frame.gravity_cam is not None:
            return frame.gravity_cam, 0.0
        fallback = self.params.gravity_fallback
        if fallback == "camera_y":
            return gravity_from_camera_y(frame.intrinsics), self.params.camera_tilt_tolerance_rad
        if fallback == "mounting":
            return np.array(self.params.mounting_gravity_cam), 0.0
        return None, 0.0

    def extract(self, frame: DepthFrame) -> ExtractionResult:
        """Planes of a depth frame, in its camera frame, with a label image."""
        if not isinstance(frame, DepthFrame):
            raise ValueError(f"frame: expected a DepthFrame, got {type(frame).__name__}")
        p = self.params
        t0 = time.perf_counter()
        key = (frame.intrinsics, p.min_depth_m, p.max_depth_m, p.voxel_size_m, p.pixel_stride)
        if self._box_key != key:
            self._box = frustum_box(frame.intrinsics, min_depth_m=p.min_depth_m, max_depth_m=p.max_depth_m,
                                    voxel_size_m=p.voxel_size_m)
            self._box_key = key
        depth = frame.depth_m
        if p.flying_pixel_sigmas > 0:
            depth = drop_flying_pixels(depth, noise_model=p.noise_model, noise_coeff=p.noise_coeff,
                                       k_sigmas=p.flying_pixel_sigmas, workspace=self.workspace)
        if frustum_cells(self._box) > MAX_FRUSTUM_CELLS:
            # Depth limits far beyond the voxel size: the frustum's dense key table would not fit in memory, so
            # the points are voxelized on their own (a hash of the occupied cells when their box is large).
            pts, pix = depth_to_points(depth, frame.intrinsics, min_depth_m=p.min_depth_m,
                                       max_depth_m=p.max_depth_m, pixel_stride=p.pixel_stride,
                                       workspace=self.workspace)
            timings = {"backproject": (time.perf_counter() - t0) * 1e3}
            t = time.perf_counter()
            grid = voxelize(pts, voxel_size_m=p.voxel_size_m, workspace=self.workspace)
        else:
            # Image-order voxelization: a pass that keys every pixel to its cell of the frustum, then one that
            # writes each point straight to its voxel's place (no point list in pixel order, no gather).
            depth, pixel_key, cellcount, m, runs = depth_to_key_image(
                depth, frame.intrinsics, self._box, voxel_size_m=p.voxel_size_m, min_depth_m=p.min_depth_m,
                max_depth_m=p.max_depth_m, pixel_stride=p.pixel_stride, workspace=self.workspace,
            )
            timings = {"backproject": (time.perf_counter() - t0) * 1e3}
            t = time.perf_counter()
            grid = voxelize_key_image(depth, frame.intrinsics, pixel_key, cellcount, m, runs, self._box,
                                      voxel_size_m=p.voxel_size_m, pixel_stride=p.pixel_stride,
                                      workspace=self.workspace)
            pts, pix = grid.points, None
        timings["voxelize"] = (time.perf_counter() - t) * 1e3
        gravity, tolerance = self.gravity_of(frame)
        return self._from_grid(grid, pts, pix, frame.intrinsics.shape, gravity, timings, t0, ordered=True,
                               gravity_tolerance_rad=tolerance)

    def extract_points(self, points_cam: np.ndarray, gravity=None, sensor_origin=(0.0, 0.0, 0.0)) -> ExtractionResult:
        """Planes of a point cloud in a frame parallel to the sensor's (z = viewing direction, the depth of the noise
        law) with the sensor at ``sensor_origin``; the planes come back in the cloud's frame."""
        t0 = time.perf_counter()
        pts = check_points(points_cam, "points_cam").astype(np.float32)
        origin = np.asarray(sensor_origin, dtype=np.float64).reshape(-1)
        if origin.shape != (3,) or not np.all(np.isfinite(origin)):
            raise ValueError(f"sensor_origin: expected 3 finite numbers, got {origin.tolist()}")
        if gravity is not None:
            gravity = np.asarray(gravity, dtype=np.float64).reshape(-1)
            if gravity.shape != (3,) or not np.all(np.isfinite(gravity)) or np.linalg.norm(gravity) < 1e-9:
                raise ValueError(f"gravity: expected a non-zero 3-vector, got {gravity.tolist()}")
        shifted = bool(np.any(origin != 0.0))
        if shifted:
            pts = pts - origin.astype(np.float32)  # the stages work with the sensor at the origin
        timings = {"backproject": (time.perf_counter() - t0) * 1e3}
        t = time.perf_counter()
        grid = voxelize(pts, voxel_size_m=self.params.voxel_size_m, workspace=self.workspace)
        timings["voxelize"] = (time.perf_counter() - t) * 1e3
        result = self._from_grid(grid, pts, None, None, gravity, timings, t0)
        if shifted:
            T = np.eye(4)
            T[:3, 3] = origin
            result = ExtractionResult(result.planes.transformed(T, "cam"), result.timings_ms, result.stats)
        return result

    def _from_grid(self, grid: VoxelGrid, pts, pix, image_shape, gravity, timings, t_start,
                   ordered: bool = False, gravity_tolerance_rad: float = 0.0) -> ExtractionResult:
        p = self.params
        ws = self.workspace
        noise = dict(noise_model=p.noise_model, noise_coeff=p.noise_coeff)
        t = time.perf_counter()
        vp: VoxelPlanes = fit_voxel_planes(
            grid, min_points_per_voxel=p.min_points_per_voxel, max_thickness_sigmas=p.max_thickness_sigmas,
            max_thickness_floor_m=p.max_thickness_floor_m, max_eigen_ratio=p.max_eigen_ratio,
            max_normal_std_rad=p.max_normal_std_rad, workspace=ws, **noise,
        )
        timings["fit"] = (time.perf_counter() - t) * 1e3
        t = time.perf_counter()
        refine_voxel_planes(
            grid, vp, noise_direction=p.noise_direction, noise_weights=p.noise_weights,
            adaptive_weights=p.adaptive_weights, alpha=p.alpha, beta=p.beta, irls_iterations=p.irls_iterations,
            irls_kernel_sigmas=p.irls_kernel_sigmas, voxel_fit_max_points=p.voxel_fit_max_points,
            max_thickness_sigmas=p.max_thickness_sigmas, max_thickness_floor_m=p.max_thickness_floor_m,
            max_eigen_ratio=p.max_eigen_ratio, max_normal_std_rad=p.max_normal_std_rad,
            min_inlier_fraction=p.min_inlier_fraction, **noise,
        )
        timings["weight"] = (time.perf_counter() - t) * 1e3
        t = time.perf_counter()
        merged: MergedPlanes = merge_voxel_planes(
            grid, vp, merge=p.merge, grow_max_angle_rad=p.grow_max_angle_rad, grow_max_offset_m=p.grow_max_offset_m,
            grow_offset_sigmas=p.grow_offset_sigmas, grow_angle_noise_sigmas=p.grow_angle_noise_sigmas,
            max_thickness_sigmas=p.max_thickness_sigmas, max_thickness_floor_m=p.max_thickness_floor_m,
            undergrown_max_angle_rad=p.undergrown_max_angle_rad,
            undergrown_max_depth_angle_rad=p.undergrown_max_depth_angle_rad,
            undergrown_max_offset_m=p.undergrown_max_offset_m, undergrown_radius_scale=p.undergrown_radius_scale,
            noise_direction=p.noise_direction, workspace=ws, **noise,
        )
        timings["merge"] = (time.perf_counter() - t) * 1e3
        t = time.perf_counter()
        for it in range(p.refine_iterations):
            # Every pass but the last refits from ~1 point in 4: cheap, and the last one (all points) decides.
            merged = refine_merged_planes(
                grid, merged, merge=p.merge, inlier_sigmas=p.inlier_sigmas, refine_boundary=p.refine_boundary,
                noise_weights=p.noise_weights, grow_offset_sigmas=p.grow_offset_sigmas,
                grow_angle_noise_sigmas=p.grow_angle_noise_sigmas, max_thickness_sigmas=p.max_thickness_sigmas,
                max_thickness_floor_m=p.max_thickness_floor_m, undergrown_max_angle_rad=p.undergrown_max_angle_rad,
                undergrown_max_depth_angle_rad=p.undergrown_max_depth_angle_rad,
                undergrown_max_offset_m=p.undergrown_max_offset_m, undergrown_radius_scale=p.undergrown_radius_scale,
                noise_direction=p.noise_direction, point_step=4 if it < p.refine_iterations - 1 else 1, ordered=ordered,
                workspace=ws, bevel_max_width_m=p.bevel_max_width_m, corner_min_angle_rad=p.corner_min_angle_rad,
                **noise,
            )
        timings["refine"] = (time.perf_counter() - t) * 1e3
        t = time.perf_counter()
        planes = assemble_plane_set(
            grid, merged, pixels=pix, image_shape=image_shape, pixel_stride=p.pixel_stride,
            inlier_sigmas=p.inlier_sigmas, refine_boundary=p.refine_boundary, area_patch_m=p.area_patch_m,
            sample_spacing_m=p.sample_spacing_m, min_plane_points=p.min_plane_points,
            min_plane_area_m2=p.min_plane_area_m2, noise_direction=p.noise_direction, gravity=gravity, frame="cam", workspace=ws,
            gravity_tolerance_rad=gravity_tolerance_rad, layer_min_shared=p.layer_share if p.merge else 0.0,
            layer_max_angle_rad=p.undergrown_max_angle_rad, layer_offset_sigmas=p.max_thickness_sigmas, **noise,
        )
        t_end = time.perf_counter()
        timings["finalize"] = (t_end - t) * 1e3
        timings["total"] = (t_end - t_start) * 1e3
        stats = {
            "points": int(pts.shape[0]), "voxels": len(grid), "planar_voxels": int(len(vp.planar)),
            "merged_planes": len(merged), "fragment_merges": merged.n_fragment_merges,
        }
        return ExtractionResult(planes=planes, timings_ms=timings, stats=stats)


_local = threading.local()


def _extractor(params: ExtractionParams | None) -> PlaneExtractor:
    """A per-thread extractor whose buffers are reused while the parameters stay the same."""
    params = params if params is not None else ExtractionParams()
    ex = getattr(_local, "extractor", None)
    if ex is None or ex.params != params:
        ex = PlaneExtractor(params)
        _local.extractor = ex
    return ex


def extract_planes(frame: DepthFrame, params: ExtractionParams | None = None) -> ExtractionResult:
    """Planes of one depth frame in its camera frame (see :class:`PlaneExtractor`); the one-shot call."""
    return _extractor(params).extract(frame)


def extract_planes_from_points(points_cam: np.ndarray, params: ExtractionParams | None = None,
                               gravity=None, sensor_origin=(0.0, 0.0, 0.0)) -> ExtractionResult:
    """Planes of an (N, 3) point cloud given in a sensor frame (z forward; the noise law uses z as the depth).

    Non-finite points are dropped. The plane set has no label image; ``gravity`` (3,) is passed through as given.
    """
    return _extractor(params).extract_points(points_cam, gravity=gravity, sensor_origin=sensor_origin)
