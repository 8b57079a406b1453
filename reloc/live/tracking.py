"""Is tracking lost? Odometry jumps, and whether the current planes agree with the map at the predicted pose."""

from __future__ import annotations

import numpy as np

from reloc.planeset import PlaneSet
from reloc.transforms import invert

__all__ = ["odometry_step", "is_jump", "predict_T_map_cam", "explained_fraction"]


def odometry_step(T_odom_prev: np.ndarray, T_odom_now: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation (rad) of the motion between two poses of the same frame."""
    D = invert(T_odom_prev) @ T_odom_now
    cos = np.clip((np.trace(D[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(D[:3, 3])), float(np.arccos(cos))


def is_jump(T_odom_prev: np.ndarray, T_odom_now: np.ndarray, max_m: float, max_rad: float) -> bool:
    """The step between consecutive frames is larger than any real motion at frame rate."""
    dt, dr = odometry_step(T_odom_prev, T_odom_now)
    return dt > max_m or dr > max_rad


def predict_T_map_cam(T_map_cam_ref: np.ndarray, T_odom_cam_ref: np.ndarray, T_odom_cam_now: np.ndarray) -> np.ndarray:
    """The pose now from the last verified one and odometry:
    ``T_map_cam_ref @ inv(T_odom_cam_ref) @ T_odom_cam_now``."""
    return T_map_cam_ref @ invert(T_odom_cam_ref) @ T_odom_cam_now


def explained_fraction(planes_cam: PlaneSet, T_map_cam: np.ndarray, map_planes: PlaneSet, *,
                       max_angle_rad: float, max_offset_m: float) -> float:
    """Area fraction of ``planes_cam`` that a map plane explains when moved into the map by ``T_map_cam``.

    A frame plane is explained when some map plane has a normal within ``max_angle_rad``, the moved centroid lies
    within ``max_offset_m`` of that map plane, and the two planes' spheres (centroid, radius) overlap. Returns NaN
    for a frame without planes (no evidence either way).
    """
    if len(planes_cam) == 0 or len(map_planes) == 0:
        return float("nan")
    R, t = T_map_cam[:3, :3], T_map_cam[:3, 3]
    n = planes_cam.normals @ R.T  # (S, 3)
    c = planes_cam.centroids @ R.T + t
    cos = n @ map_planes.normals.T  # (S, M)
    dist = np.abs(c @ map_planes.normals.T + map_planes.offsets[None, :])
    gap = np.linalg.norm(c[:, None, :] - map_planes.centroids[None, :, :], axis=2)
    near = gap <= map_planes.radii[None, :] + planes_cam.radii[:, None]
    ok = np.any((cos >= np.cos(max_angle_rad)) & (dist <= max_offset_m) & near, axis=1)
    area = np.maximum(planes_cam.areas, 0.0)
    total = float(area.sum())
    if total <= 0:
        return float(np.mean(ok))
    return float(area[ok].sum() / total)
