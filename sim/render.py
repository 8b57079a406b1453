"""Noise-free depth and plane labels of a scene seen from a pose (the thin, validated layer over the kernels)."""

from __future__ import annotations

import numpy as np

from reloc.camera import Intrinsics
from reloc.transforms import check_transform
from sim import _render_kernels as _k
from sim.scenes import Scene

__all__ = ["render"]


def render(
    scene: Scene,
    intrinsics: Intrinsics,
    T_world_cam: np.ndarray,
    *,
    near_m: float = 0.05,
    far_m: float = 100.0,
    extra_cylinders: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Render ``scene`` from the camera pose ``T_world_cam`` (4x4, camera optical frame to world).

    Returns ``(depth_m, labels)``: (H, W) float32 optical-axis depth in metres (NaN where no surface lies within
    ``(near_m, far_m)``) and (H, W) int32 labels (the plane id, 0 for clutter or nothing). ``extra_cylinders``
    (K, 5) ``[x, y, z_bottom, z_top, radius]`` are added as clutter (moving people).
    """
    if not isinstance(intrinsics, Intrinsics):
        raise ValueError(f"intrinsics: expected an Intrinsics, got {type(intrinsics).__name__}")
    T = check_transform(T_world_cam, "T_world_cam")
    if not (0 < near_m < far_m):
        raise ValueError(f"near_m, far_m: expected 0 < near_m < far_m, got {near_m}, {far_m}")
    R_cam_world = np.ascontiguousarray(T[:3, :3].T)
    t_cam_world = np.ascontiguousarray(-R_cam_world @ T[:3, 3])
    depth = np.full(intrinsics.shape, np.inf, dtype=np.float32)
    labels = np.zeros(intrinsics.shape, dtype=np.int32)
    fx, fy, cx, cy = float(intrinsics.fx), float(intrinsics.fy), float(intrinsics.cx), float(intrinsics.cy)
    _k.rasterize_polygons(
        R_cam_world, t_cam_world, fx, fy, cx, cy, float(near_m), float(far_m),
        scene.poly_vertices, scene.poly_ptr, scene.poly_normals, scene.poly_offsets, scene.poly_labels,
        depth, labels,
    )
    cyl = scene.cylinders
    if extra_cylinders is not None and len(extra_cylinders):
        extra = np.asarray(extra_cylinders, dtype=np.float64)
        if extra.ndim != 2 or extra.shape[1] != 5:
            raise ValueError(f"extra_cylinders: expected shape (K, 5), got {extra.shape}")
        cyl = np.concatenate([cyl, extra])
    if cyl.shape[0] or scene.spheres.shape[0]:
        _k.raycast_clutter(
            R_cam_world, t_cam_world, fx, fy, cx, cy, float(near_m), float(far_m),
            np.ascontiguousarray(cyl), scene.spheres, np.int32(0), depth, labels,
        )
    _k.finish_depth(depth, labels)
    return depth, labels
