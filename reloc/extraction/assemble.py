"""Stage 6: merged planes become the frame's :class:`PlaneSet` (supporting points, statistics, radius, area,
samples, covariance, label image, gravity). Points are in the sensor frame with the sensor at the origin."""

from __future__ import annotations

import numpy as np

from reloc.extraction import _kernels_finalize as kf
from reloc.extraction._kernels_linalg import tangent_basis
from reloc.extraction._workspace import Workspace, fresh
from reloc.extraction.merge import MergedPlanes
from reloc.extraction.params import noise_law_code
from reloc.extraction.voxelize import VoxelGrid
from reloc.planeset import PlaneSet

__all__ = ["assemble_plane_set"]

# Largest in-plane grids (cells over all planes) handled densely; beyond, a slower sort-based path is used.
MAX_DENSE_AREA_CELLS = 1 << 24
MAX_DENSE_SAMPLE_CELLS = 1 << 21


def _grids_by_sort(pts, point_plane, planes, cell, n_planes):
    """Sort-based fallback of the in-plane grid: per plane the occupied cells' point counts and sums, cell order."""
    out = []
    for p in range(n_planes):
        sel = point_plane == p
        x = pts[sel].astype(np.float64)
        t = np.array(tangent_basis(*planes[p, :3])).reshape(2, 3)
        iu = np.floor(x @ t[0] / cell).astype(np.int64)
        iv = np.floor(x @ t[1] / cell).astype(np.int64)
        _, inv, cnt = np.unique(np.column_stack([iu, iv]), axis=0, return_inverse=True, return_counts=True)
        inv = inv.reshape(-1)
        sums = np.column_stack([np.bincount(inv, weights=x[:, k], minlength=len(cnt)) for k in range(3)])
        out.append((cnt.astype(np.float64), sums))
    return out


def assemble_plane_set(
    grid: VoxelGrid,
    merged: MergedPlanes,
    *,
    pixels: np.ndarray | None = None,
    image_shape: tuple[int, int] | None = None,
    pixel_stride: int = 1,
    inlier_sigmas: float = 4.0,
    refine_boundary: bool = True,
    area_patch_m: float = 0.1,
    sample_spacing_m: float = 0.1,
    min_plane_points: int = 200,
    min_plane_area_m2: float = 0.04,
    noise_model: str = "kinect",
    noise_coeff: float = 1.425e-3,
    noise_direction: str = "ray",
    gravity: np.ndarray | None = None,
    frame: str = "cam",
    workspace: Workspace | None = None,
) -> PlaneSet:
    """The plane set of the merged planes.

    Supporting points of a plane: the points of its voxels within ``inlier_sigmas`` (times the plane's robust
    scale, at least 1) noise sigmas of it, plus (``refine_boundary``) points of neighbouring voxels without a plane
    that fall in its band. Planes with fewer than ``min_plane_points`` supporting points or a smaller area than
    ``min_plane_area_m2`` are dropped; the rest are ordered by point count (largest first).
    ``pixels`` (M,) int32 (the flat pixel index of each input point) and ``image_shape`` make the label image.
    """
    ws = fresh(workspace)
    n_all = len(merged)
    m = int(grid.start[-1]) if len(grid.start) else 0
    labels = None
    if image_shape is not None:
        labels = np.full(image_shape, -1, np.int32)
    if n_all == 0 or m == 0:
        return PlaneSet.empty(frame=frame, gravity=gravity, labels=labels)
    planes = np.ascontiguousarray(merged.planes)
    band = float(inlier_sigmas) * np.sqrt(np.maximum(merged.variance_factors, 1.0))
    power = noise_law_code(noise_model)
    ray = noise_direction == "ray"
    if merged.point_plane is not None and len(merged.point_plane) == m:
        point_plane = merged.point_plane  # the refinement's last pass already assigned every point
    else:
        point_plane = ws.get("as_point_plane", m, np.int32)
        z3 = np.zeros((1, 3))
        kf.assign_points(
            grid.points, grid.points.view(np.int32), 1, grid.start, len(grid), grid.keys, grid.box, grid.dense,
            grid.cellmap, grid.tkeys, grid.tvals, merged.plane_of_voxel, planes, band, power, float(noise_coeff), ray,
            bool(refine_boundary), point_plane, False, False, z3, np.zeros(1), z3, np.zeros((1, 3, 3)),
            np.zeros(1, np.int64), z3, np.zeros(1, np.int64),
        )
    counts = np.zeros(n_all, np.int64)
    sums = np.zeros((n_all, 3))
    scatters = np.zeros((n_all, 3, 3))
    uvbox = np.zeros((n_all, 4))
    kf.plane_point_stats(grid.points, point_plane, m, planes, counts, sums, scatters, uvbox)
    centroids = sums / np.maximum(counts, 1)[:, None]
    # Radius, area and samples over in-plane grids.
    area_grid = np.zeros((n_all, 4), np.int64)
    sample_grid = np.zeros((n_all, 4), np.int64)
    kf.grid_shape(uvbox, float(area_patch_m), area_grid)
    kf.grid_shape(uvbox, float(sample_spacing_m), sample_grid)
    area_sizes = area_grid[:, 2] * area_grid[:, 3]
    sample_sizes = sample_grid[:, 2] * sample_grid[:, 3]
    radii = np.zeros(n_all)
    areas = np.zeros(n_all)
    dense = area_sizes.sum() <= MAX_DENSE_AREA_CELLS and sample_sizes.sum() <= MAX_DENSE_SAMPLE_CELLS
    if dense:
        area_off = np.concatenate([[0], np.cumsum(area_sizes)]).astype(np.int64)
        sample_off = np.concatenate([[0], np.cumsum(sample_sizes)]).astype(np.int64)
        occupied = ws.get("as_occupied", max(int(area_off[-1]), 1), np.uint8)
        sample_acc = ws.get("as_sample_acc", (max(int(sample_off[-1]), 1), 4), np.float64)
        kf.plane_extent(grid.points, point_plane, m, planes, centroids, float(area_patch_m), area_grid, area_off,
                        occupied, float(sample_spacing_m), sample_grid, sample_off, sample_acc, radii, areas)
    else:
        sel_pts = grid.points[:m]
        pp = point_plane[:m]
        for p in range(n_all):
            x = sel_pts[pp == p].astype(np.float64)
            radii[p] = np.sqrt(((x - centroids[p]) ** 2).sum(1).max()) if len(x) else 0.0
        area_cells = _grids_by_sort(sel_pts, pp, planes, float(area_patch_m), n_all)
        areas = np.array([len(c) * area_patch_m**2 for c, _ in area_cells])
        sample_cells = _grids_by_sort(sel_pts, pp, planes, float(sample_spacing_m), n_all)
    # Keep the planes that are large enough, the most supported first.
    keep = np.flatnonzero((counts >= min_plane_points) & (areas >= min_plane_area_m2))
    keep = keep[np.argsort(-counts[keep], kind="stable")].astype(np.int64)
    remap = np.full(n_all, -1, np.int32)
    remap[keep] = np.arange(len(keep), dtype=np.int32)
    if dense:
        n_cells = int(sample_off[-1])
        sample_points = np.empty((max(n_cells, 1), 3), np.float32)
        sample_ptr = np.zeros(len(keep) + 1, np.int64)
        n_samples = kf.collect_samples(sample_acc, sample_off, keep, sample_points, sample_ptr)
        sample_points = sample_points[:n_samples].copy()
    else:
        pieces = [(sample_cells[p][1] / sample_cells[p][0][:, None]).astype(np.float32) for p in keep]
        sizes = np.array([len(x) for x in pieces], np.int64)
        sample_ptr = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        sample_points = np.concatenate(pieces) if pieces else np.zeros((0, 3), np.float32)
    if labels is not None:
        if pixels is None:
            raise ValueError("pixels: needed with image_shape to make the label image")
        h, w = image_shape
        kf.write_labels(point_plane, grid.source, np.ascontiguousarray(pixels, dtype=np.int32), m, remap, w, h,
                        int(pixel_stride), labels.reshape(-1))
    return PlaneSet(
        normals=planes[keep, :3].copy(), offsets=planes[keep, 3].copy(), centroids=centroids[keep],
        counts=counts[keep], radii=radii[keep], areas=areas[keep], covariances=merged.covariances[keep],
        sums=sums[keep], scatters=scatters[keep], sample_points=sample_points, sample_ptr=sample_ptr,
        frame=frame, gravity=gravity, labels=labels,
    )
