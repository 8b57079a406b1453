"""Stage 6: merged planes become the frame's :class:`PlaneSet` (supporting points, statistics, radius, area,
samples, covariance, label image, gravity). Points are in the sensor frame with the sensor at the origin."""

from __future__ import annotations

import numpy as np

from reloc.extraction import _kernels_finalize as kf
from reloc.extraction._workspace import Workspace, fresh
from reloc.extraction.merge import MergedPlanes
from reloc.extraction.params import noise_law_code
from reloc.extraction.voxelize import VoxelGrid
from reloc.planeset import PlaneSet

__all__ = ["assemble_plane_set"]

# Largest in-plane grids (cells over all planes); finer cells over larger planes are refused.
MAX_DENSE_AREA_CELLS = 1 << 24
MAX_DENSE_SAMPLE_CELLS = 1 << 21


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
    gravity_tolerance_rad: float = 0.0,
    layer_min_shared: float = 0.0,
    layer_max_angle_rad: float = np.radians(8.0),
    layer_offset_sigmas: float = 4.0,
) -> PlaneSet:
    """The plane set of the merged planes.

    Supporting points of a plane: the points of its voxels within ``inlier_sigmas`` (times the plane's robust
    scale, at least 1) noise sigmas of it, plus (``refine_boundary``) points of neighbouring voxels without a plane
    that fall in its band. Planes with fewer than ``min_plane_points`` supporting points or a smaller area than
    ``min_plane_area_m2`` are dropped; the rest are ordered by point count (largest first).
    ``pixels`` (M,) int32 (the flat pixel index of each input point) and ``image_shape`` make the label image;
    a grid made from the image itself (``grid.source_is_pixel``) needs no ``pixels``.
    With a label image and ``layer_min_shared`` > 0, layers of one surface are merged first (:func:`_merge_layers`).
    """
    ws = fresh(workspace)
    n_all = len(merged)
    m = int(grid.start[-1]) if len(grid.start) else 0
    labels = None
    if image_shape is not None:
        labels = np.empty(image_shape, np.int32)  # filled by plane_extent
    if n_all == 0 or m == 0:
        if labels is not None:
            labels.fill(-1)
        return PlaneSet.empty(frame=frame, gravity=gravity, labels=labels, gravity_tolerance_rad=gravity_tolerance_rad)
    planes = np.ascontiguousarray(merged.planes)
    band = float(inlier_sigmas) * np.sqrt(np.maximum(merged.variance_factors, 1.0))
    power = noise_law_code(noise_model)
    ray = noise_direction == "ray"
    counts = np.zeros(n_all, np.int64)
    sums = np.zeros((n_all, 3))
    scatters = np.zeros((n_all, 3, 3))
    if (merged.point_plane is not None and len(merged.point_plane) == m and merged.support is not None
            and merged.point_table is not None):
        # The refinement's last pass already assigned every point (in its numbering: point_table maps it to the
        # merged planes) and summed each plane's support.
        point_plane = merged.point_plane
        table = merged.point_table
        counts, sums, scatters = (np.array(x) for x in merged.support)
    else:
        point_plane = ws.get("as_point_plane", m, np.int32)
        table = np.arange(n_all, dtype=np.int32)
        z3 = np.zeros((1, 3))
        kf.assign_points(
            grid.points, grid.points.view(np.int32), 1, False, grid.start, len(grid), grid.keys, grid.box, grid.dense,
            grid.cellmap, grid.tkeys, grid.tvals, grid.counts, grid.sums, grid.scatters, merged.plane_of_voxel,
            planes, band, power, float(noise_coeff), ray, bool(refine_boundary), point_plane, False, False, 1.0, z3,
            np.zeros(1), z3, np.zeros((1, 3, 3)), np.zeros(1, np.int64), z3, np.zeros(1, np.int64),
            np.zeros((1, 10)), ws.get("rf_scratch", (kf.SCRATCH_ROWS, max(int(grid.counts.max()), 1)), np.float64),
        )
        kf.plane_stats(grid.points, point_plane, m, counts, sums, scatters)
    plane_of_voxel = merged.plane_of_voxel
    covariances = merged.covariances
    h, w = image_shape if image_shape is not None else (1, 1)
    if labels is not None and pixels is None and not grid.source_is_pixel:
        raise ValueError("pixels: needed with image_shape to make the label image")
    src_is_pixel = grid.source_is_pixel and pixels is None
    pix = (np.ascontiguousarray(pixels, dtype=np.int32) if labels is not None and not src_is_pixel
           else np.zeros(1, np.int32))
    if labels is not None and layer_min_shared > 0 and n_all > 1:
        layered = _merge_layers(grid, planes, counts, sums, scatters, covariances, plane_of_voxel, point_plane, table,
                                m, src_is_pixel, pix, w, h, min_shared=float(layer_min_shared),
                                max_angle_rad=float(layer_max_angle_rad), offset_sigmas=float(layer_offset_sigmas),
                                power=power, coeff=float(noise_coeff), pixel_stride=int(pixel_stride))
        if layered is not None:
            planes, table, plane_of_voxel, covariances = layered
    radii = np.zeros(n_all)
    areas = np.zeros(n_all)
    tb = np.zeros((n_all, 6))
    area_grid = np.zeros((n_all, 4), np.int64)
    sample_grid = np.zeros((n_all, 4), np.int64)
    n_area, n_sample = kf.plane_grids(planes, plane_of_voxel, len(grid), grid.counts, grid.sums,
                                      3.5 * grid.voxel_size_m, float(area_patch_m), float(sample_spacing_m), tb,
                                      area_grid, sample_grid)
    if n_area > MAX_DENSE_AREA_CELLS or n_sample > MAX_DENSE_SAMPLE_CELLS:
        raise ValueError(
            f"area_patch_m={area_patch_m}, sample_spacing_m={sample_spacing_m}: the in-plane grids would need "
            f"{n_area} area and {n_sample} sample cells (at most {MAX_DENSE_AREA_CELLS} and {MAX_DENSE_SAMPLE_CELLS}); "
            "use larger cells for planes this large"
        )
    area_off = np.empty(n_all + 1, np.int64)
    sample_off = np.empty(n_all + 1, np.int64)
    centroids = np.empty((n_all, 3))
    # Keep the planes that are large enough (the area comes from the pass below), the most supported first.
    order = np.empty(n_all, np.int64)
    remap = np.empty(n_all, np.int32)
    n_order = kf.plane_order(counts, sums, int(min_plane_points), area_grid, sample_grid, centroids, area_off,
                             sample_off, order, remap)
    occupied = ws.get("as_occupied", max(n_area, 1), np.uint8)
    sample_acc = ws.get("as_sample_acc", (max(n_sample, 1), 4), np.float64)
    with_labels = labels is not None
    lab = labels.reshape(-1) if with_labels else np.zeros(1, np.int32)
    kf.plane_extent(grid.points, point_plane, table, m, centroids, tb, float(area_patch_m), area_grid, area_off,
                    occupied, float(sample_spacing_m), sample_grid, sample_off, sample_acc, radii, areas, with_labels,
                    grid.source, src_is_pixel, pix, remap, w, h, int(pixel_stride), lab)
    keep = np.empty(max(n_order, 1), np.int64)
    final = np.empty(max(n_order, 1), np.int32)
    nk = kf.keep_planes(order, n_order, areas, float(min_plane_area_m2), remap, keep, final)
    keep = keep[:nk]
    if nk < n_order and with_labels:  # planes too small in area: renumber the labels
        kf.remap_points(lab, lab.shape[0], final)
    sample_points = np.empty((max(n_sample, 1), 3), np.float32)
    sample_ptr = np.zeros(nk + 1, np.int64)
    n_samples = kf.collect_samples(sample_acc, sample_off, keep, sample_points, sample_ptr)
    sample_points = sample_points[:n_samples].copy()
    out = (np.empty((nk, 3)), np.empty(nk), np.empty((nk, 3)), np.empty(nk, np.int64), np.empty(nk), np.empty(nk),
           np.empty((nk, 4, 4)), np.empty((nk, 3)), np.empty((nk, 3, 3)))
    kf.gather_planes(keep, nk, planes, centroids, counts, radii, areas, covariances, sums, scatters, *out)
    return PlaneSet(
        normals=out[0], offsets=out[1], centroids=out[2], counts=out[3], radii=out[4], areas=out[5],
        covariances=out[6], sums=out[7], scatters=out[8], sample_points=sample_points, sample_ptr=sample_ptr,
        frame=frame, gravity=gravity, labels=labels, gravity_tolerance_rad=gravity_tolerance_rad,
    )


# Pixel blocks of the layer test: layers interleave pixel by pixel (each pixel's disparity step is its own draw), so
# nearly every 2x2 block of a layered wall holds both; a surface in front of another shares only the blocks along
# its outline.
LAYER_BLOCK = 2
MAX_LAYER_PAIRS = 64


def _merge_layers(grid, planes, counts, sums, scatters, covariances, plane_of_voxel, point_plane, table, m,
                  src_is_pixel, pix, width, height, *, min_shared, max_angle_rad, offset_sigmas, power, coeff,
                  pixel_stride=1):
    """Merge planes that are layers of one surface: normals within ``max_angle_rad``, the smaller one's centroid
    within ``offset_sigmas`` depth sigmas of the larger plane, and the two seen in at least ``min_shared`` of the
    smaller one's blocks of 2x2 pixels used (of 2 ``pixel_stride`` pixels square in the image: with a stride, a
    block of 2x2 image pixels holds one pixel used, and no two planes could share one), as two surfaces cannot
    both be seen through the same rays; stereo's disparity steps cut a far wall facing the camera into such layers,
    13-15 cm apart at 6 m.

    ``counts``, ``sums`` and ``scatters`` (plain statistics of the supporting points, about the origin) are summed
    into the larger plane in place; the merged plane and its covariance are refit from them (least squares of all
    its points: the layers' mean). Returns ``(planes, table, plane_of_voxel, covariances)`` renumbered so that the
    smaller plane's points and voxels go to the larger one (which the plane set then drops for having no points),
    or None when nothing merges.
    """
    pairs = np.empty((MAX_LAYER_PAIRS, 2), np.int64)
    n = kf.layer_candidates(planes, counts, sums, float(np.cos(max_angle_rad)), offset_sigmas, power, coeff, pairs)
    if n == 0:
        return None
    pairs = pairs[: min(n, MAX_LAYER_PAIRS)]
    # One bit per plane of a pair (a uint64 per block): a pair with a plane beyond the first 64 is not merged.
    involved = np.unique(pairs)[:64]
    bit_of = np.full(len(planes), -1, np.int64)
    bit_of[involved] = np.arange(len(involved))
    pairs = pairs[(bit_of[pairs[:, 0]] >= 0) & (bit_of[pairs[:, 1]] >= 0)]
    block = LAYER_BLOCK * int(pixel_stride)
    n_bw = (width + block - 1) // block
    masks = np.zeros(n_bw * ((height + block - 1) // block), np.uint64)
    kf.layer_blocks(point_plane, table, m, grid.source, src_is_pixel, pix, width, block, n_bw, bit_of, masks)
    parent = np.arange(len(planes))

    def root(a):
        while parent[a] != a:
            a = parent[a]
        return a

    merged_any = False
    # Largest first, so a wall takes its layers before a layer could take another.
    for i, j in sorted(pairs.tolist(), key=lambda ij: (-counts[ij[0]], -counts[ij[1]], ij[0], ij[1])):
        hj = (masks >> np.uint64(bit_of[j])) & np.uint64(1)
        nj = int(hj.sum())
        if nj == 0:
            continue
        both = int((hj & (masks >> np.uint64(bit_of[i]))).sum())
        if both < min_shared * nj:
            continue
        ri, rj = root(i), root(j)
        if ri != rj:
            parent[rj] = ri
            merged_any = True
    if not merged_any:
        return None
    from reloc.mapping.fusion import plane_fit_from_stats

    roots = np.array([root(a) for a in range(len(planes))])
    moved = np.flatnonzero(roots != np.arange(len(planes)))
    for j in moved:
        r = roots[j]
        counts[r] += counts[j]
        sums[r] += sums[j]
        scatters[r] += scatters[j]
        counts[j] = 0
        sums[j] = 0.0
        scatters[j] = 0.0
    targets = np.unique(roots[moved])
    normals, offsets, _, covs = plane_fit_from_stats(sums[targets], scatters[targets], counts[targets],
                                                     planes[targets, :3])
    planes = planes.copy()
    planes[targets, :3] = normals
    planes[targets, 3] = offsets
    covariances = covariances.copy()
    covariances[targets] = covs
    table = table.copy()
    ok = table >= 0
    table[ok] = roots[table[ok]]
    pov = plane_of_voxel.copy()
    ok = pov >= 0
    pov[ok] = roots[pov[ok]]
    return planes, table.astype(np.int32), pov.astype(plane_of_voxel.dtype), covariances
