"""Is tracking lost? Odometry jumps, and whether the current planes agree with the map at the predicted pose."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reloc.planeset import PlaneSet
from reloc.transforms import invert

__all__ = ["OdometryDrift", "odometry_step", "is_jump", "predict_T_map_cam", "explained_fraction",
           "tracked_covariance"]


@dataclass(frozen=True)
class OdometryDrift:
    """How far an odometry may have drifted since a reference pose, one sigma, growing linearly with the motion
    (the systematic errors dominate: a wheel radius or gyro scale a per cent off, a gyro bias), for a robot that moves
    on a level floor: heading ``rad_per_rad`` of the angle turned, ``rad_per_m`` of the path and ``rad_per_s`` of the
    time; position ``m_per_m`` of the path and the heading error over half the path; each added in quadrature."""

    m_per_m: float = 0.025
    rad_per_m: float = 0.0
    rad_per_rad: float = 0.01
    rad_per_s: float = 0.002

    def __post_init__(self) -> None:
        for name in ("m_per_m", "rad_per_m", "rad_per_rad", "rad_per_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise ValueError(f"odometry drift {name}: expected a number >= 0, got {v!r}")

    def sigmas(self, travelled_m: float, turned_rad: float, elapsed_s: float) -> tuple[float, float]:
        """(position sigma in m, heading sigma in rad) after that much motion."""
        heading = float(np.hypot(np.hypot(self.rad_per_rad * turned_rad, self.rad_per_m * travelled_m),
                                 self.rad_per_s * elapsed_s))
        return float(np.hypot(self.m_per_m * travelled_m, 0.5 * heading * travelled_m)), heading


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


def tracked_covariance(cov_ref: np.ndarray, p_now: np.ndarray, up: np.ndarray, travelled_m: float, turned_rad: float,
                       elapsed_s: float, drift: OdometryDrift) -> np.ndarray:
    """(6, 6) covariance of a pose tracked with odometry from a relocalized one whose covariance is ``cov_ref``
    (both over the left perturbation ``(rho, phi)`` of ``T_map_cam`` in the map frame, translation first).

    The reference's uncertainty carries over unchanged: a left perturbation in the map frame is the same for every
    pose chained to it by odometry (a heading error moves a pose far from the reference by the lever arm, which
    ``rho`` and ``phi`` together express). The odometry's drift since then (:class:`OdometryDrift`, after
    ``travelled_m`` of path, ``turned_rad`` of turning and ``elapsed_s``) adds a position error across ``up`` (the
    map's up, unit) and a heading error about ``up`` through the camera's position ``p_now`` (map frame): in the
    left perturbation, ``phi = e up`` and ``rho = p_now x phi``.
    """
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    p = np.asarray(p_now, dtype=np.float64)
    s_pos, s_head = drift.sigmas(travelled_m, turned_rad, elapsed_s)
    Q = np.zeros((6, 6))
    Q[:3, :3] = s_pos**2 * (np.eye(3) - np.outer(u, u))
    J = np.concatenate([np.cross(p, u), u])
    Q += s_head**2 * np.outer(J, J)
    return np.asarray(cov_ref, dtype=np.float64) + Q
