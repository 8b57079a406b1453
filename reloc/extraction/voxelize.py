"""Stage 2: points grouped into an n x n x n m voxel grid, with per-voxel sufficient statistics."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reloc.extraction import _kernels_voxel as kv
from reloc.extraction._workspace import Workspace, fresh

__all__ = ["VoxelGrid", "voxelize", "voxelize_keyed", "voxelize_key_image", "frustum_box", "frustum_cells",
           "MAX_FRUSTUM_CELLS"]

# Largest dense key table of a frame's viewing frustum (int32 cells, 256 MB); beyond it the occupied cells are hashed.
MAX_FRUSTUM_CELLS = 1 << 26

# Largest dense key box, in cells, relative to the number of points (beyond it the hash table is used).
DENSE_CELLS_PER_POINT = 4
DENSE_MIN_CELLS = 1 << 16
MAX_AXIS_CELLS = 1 << 20


@dataclass(frozen=True)
class VoxelGrid:
    """Points grouped by voxel (arrays may be workspace views: valid until the next call with that workspace).

    - ``voxel_size_m``; ``box`` int64 (6,) ``[x0, y0, z0, nx, ny, nz]``: origin and size (in cells) of the key box,
      voxel ``(ix, iy, iz)`` of the grid anchored at the origin has key ``((ix-x0) ny + iy-y0) nz + iz-z0``.
    - ``dense`` and the lookup table (``cellmap`` or the hash ``tkeys``/``tvals``) mapping keys to voxel ids.
    - ``keys`` (V,) increasing; ``start`` (V + 1,) offsets into ``points`` (M, 3) float32 / ``source`` (M,) int32
      (index of each point in the input, or its flat pixel index ``v * W + u`` when ``source_is_pixel``: a grid
      made from a depth image by :func:`voxelize_key_image`), voxel by voxel.
    - ``counts`` (V,) int64, ``sums`` (V, 3), ``scatters`` (V, 3, 3): point count, sum and sum of ``p p^T`` about the
      origin (float64).
    """

    voxel_size_m: float
    box: np.ndarray
    dense: bool
    cellmap: np.ndarray
    tkeys: np.ndarray
    tvals: np.ndarray
    keys: np.ndarray
    start: np.ndarray
    points: np.ndarray
    source: np.ndarray
    counts: np.ndarray
    sums: np.ndarray
    scatters: np.ndarray
    source_is_pixel: bool = False

    def __len__(self) -> int:
        return int(self.keys.shape[0])

    @property
    def coords(self) -> np.ndarray:
        """(V, 3) int64 voxel coordinates ``floor(p / voxel_size_m)``."""
        b = self.box
        ix = self.keys // (b[4] * b[5])
        iy = (self.keys // b[5]) % b[4]
        iz = self.keys % b[5]
        return np.column_stack([ix + b[0], iy + b[1], iz + b[2]])

    def lookup(self, coords: np.ndarray) -> np.ndarray:
        """Voxel id of each (K, 3) voxel coordinate, -1 where there is no voxel."""
        c = np.asarray(coords, dtype=np.int64).reshape(-1, 3)
        out = np.empty(len(c), np.int64)
        b = self.box
        for i, (x, y, z) in enumerate(c):
            out[i] = kv.voxel_lookup(x - b[0], y - b[1], z - b[2], b, self.dense, self.cellmap, self.tkeys,
                                     self.tvals)
        return out


def frustum_box(intrinsics, *, min_depth_m: float, max_depth_m: float, voxel_size_m: float,
                pixel_stride: int = 1) -> np.ndarray:
    """Key box ``[x0, y0, z0, nx, ny, nz]`` (int64) of every voxel a frame's valid points can fall in: the viewing
    frustum between ``min_depth_m`` and ``max_depth_m``, with a one-cell margin against rounding."""
    K = intrinsics
    us = np.array([0.0, K.width - 1.0])
    vs = np.array([0.0, K.height - 1.0])
    zs = np.array([min_depth_m, max_depth_m])
    xs = ((us[:, None] - K.cx) / K.fx * zs[None, :]).ravel()
    ys = ((vs[:, None] - K.cy) / K.fy * zs[None, :]).ravel()
    lo = np.floor(np.array([xs.min(), ys.min(), zs.min()]) / voxel_size_m).astype(np.int64) - 1
    hi = np.floor(np.array([xs.max(), ys.max(), zs.max()]) / voxel_size_m).astype(np.int64) + 1
    return np.concatenate([lo, hi - lo + 1]).astype(np.int64)


def frustum_cells(box: np.ndarray) -> int:
    """Cells of a key box ``[x0, y0, z0, nx, ny, nz]``, in Python integers (the int64 product wraps round for a
    frustum thousands of kilometres deep)."""
    return int(box[3]) * int(box[4]) * int(box[5])


def _grid(ws, m, nv, box, dense, cellmap, tkeys, tvals, voxel_size_m, source_is_pixel=False) -> VoxelGrid:
    return VoxelGrid(
        voxel_size_m=float(voxel_size_m), box=box, dense=bool(dense), cellmap=cellmap, tkeys=tkeys, tvals=tvals,
        keys=ws.get("vx_keys", max(m, 1), np.int64)[:nv], start=ws.get("vx_start", m + 1, np.int64)[: nv + 1],
        points=ws.get("vx_points", (m, 3), np.float32), source=ws.get("vx_source", m, np.int32),
        counts=ws.get("vx_counts", max(m, 1), np.int64)[:nv], sums=ws.get("vx_sums", (max(m, 1), 3), np.float64)[:nv],
        scatters=ws.get("vx_scatters", (max(m, 1), 3, 3), np.float64)[:nv], source_is_pixel=source_is_pixel,
    )


def voxelize_keyed(points: np.ndarray, point_key: np.ndarray, cellcount: np.ndarray, box: np.ndarray, *,
                   voxel_size_m: float, workspace: Workspace | None = None) -> VoxelGrid:
    """The counting sort of :func:`voxelize` for points whose dense keys and per-cell counts are already known
    (from ``count_keys``). ``cellcount`` becomes the cell map."""
    ws = fresh(workspace)
    m = points.shape[0]
    args = (ws.get("vx_keys", max(m, 1), np.int64), ws.get("vx_start", m + 1, np.int64),
            ws.get("vx_points", (m, 3), np.float32), ws.get("vx_source", m, np.int32),
            ws.get("vx_counts", max(m, 1), np.int64), ws.get("vx_sums", (max(m, 1), 3), np.float64),
            ws.get("vx_scatters", (max(m, 1), 3, 3), np.float64))
    nv = kv.scatter_dense(points, m, point_key, cellcount, box, *args[:4])
    if nv:
        kv.voxel_moments(args[2], args[1], nv, *args[4:])
    return _grid(ws, m, nv, box, True, cellcount, ws.get("vx_tkeys", 1, np.int64), ws.get("vx_tvals", 1, np.int32),
                 voxel_size_m)


def voxelize_key_image(depth: np.ndarray, intrinsics, pixel_key: np.ndarray, cellcount: np.ndarray, m: int,
                       runs: np.ndarray, box: np.ndarray, *, voxel_size_m: float, pixel_stride: int = 1,
                       workspace: Workspace | None = None) -> VoxelGrid:
    """The second half of image-order voxelization (after ``backproject.depth_to_key_image``): the ``m`` valid
    pixels' points computed again and written straight to their voxel's place, then each voxel's moments. The
    points are those of ``depth_to_points`` (same values, and in raster order inside a voxel, as
    :func:`voxelize_keyed` leaves them); ``source`` holds their flat pixel indices. ``cellcount`` becomes the cell
    map. ``runs``: where each run of equal keys starts, then the end (from ``depth_to_key_image``)."""
    ws = fresh(workspace)
    g = _grid(ws, m, m, box, True, cellcount, ws.get("vx_tkeys", 1, np.int64), ws.get("vx_tvals", 1, np.int32),
              voxel_size_m, source_is_pixel=True)
    K = intrinsics
    nv = kv.scatter_image(depth, float(K.fx), float(K.fy), float(K.cx), float(K.cy), int(pixel_stride), pixel_key,
                          runs, len(runs) - 1, cellcount, box, g.keys, g.start, g.points, g.source)
    g = _grid(ws, m, nv, box, True, cellcount, g.tkeys, g.tvals, voxel_size_m, source_is_pixel=True)
    if nv:
        kv.voxel_moments(g.points, g.start, nv, g.counts, g.sums, g.scatters)
    return g


def voxelize(
    points: np.ndarray,
    *,
    voxel_size_m: float = 0.25,
    force_hash: bool = False,
    workspace: Workspace | None = None,
) -> VoxelGrid:
    """Group (M, 3) float32 points by voxel with a counting sort, and compute each voxel's moments.

    The key box of the occupied cells indexes a dense table when it has at most ``max(4 M, 65536)`` cells, else a
    hash table (``force_hash`` to always use it). Voxel ids follow the key order, so they do not depend on the order
    of the points. Points farther than 2^20 voxels from the origin along an axis are rejected (ValueError).
    """
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points: expected shape (M, 3), got {pts.shape}")
    pts = np.ascontiguousarray(pts, dtype=np.float32)
    if not (np.isfinite(voxel_size_m) and voxel_size_m > 0):
        raise ValueError(f"voxel_size_m: expected a finite number > 0, got {voxel_size_m!r}")
    if not np.isfinite(pts).all():
        raise ValueError("points: expected finite values (drop NaN/inf rows first)")
    ws = fresh(workspace)
    m = pts.shape[0]
    inv = 1.0 / float(voxel_size_m)
    if m == 0:
        box = np.array([0, 0, 0, 1, 1, 1], np.int64)
    else:
        x0, y0, z0, x1, y1, z1 = kv.voxel_box(pts, m, inv)
        dims = (x1 - x0 + 1, y1 - y0 + 1, z1 - z0 + 1)
        if max(dims) > MAX_AXIS_CELLS or min(x0, y0, z0) < -MAX_AXIS_CELLS or max(x1, y1, z1) > MAX_AXIS_CELLS:
            raise ValueError(
                f"points: voxel coordinates span {dims} cells of {voxel_size_m} m (at most {MAX_AXIS_CELLS} per "
                "axis and from the origin): are the points in metres?"
            )
        box = np.array([x0, y0, z0, *dims], np.int64)
    ncell = int(box[3] * box[4] * box[5])
    dense = (not force_hash) and ncell <= max(DENSE_CELLS_PER_POINT * m, DENSE_MIN_CELLS)
    point_key = ws.get("vx_point_key", m, np.int64)
    if dense:
        cellmap = ws.get("vx_cellmap", ncell, np.int32)
        kv.count_keys(pts, m, inv, box, point_key, cellmap)
        return voxelize_keyed(pts, point_key, cellmap, box, voxel_size_m=voxel_size_m, workspace=ws)
    size = 1 << max(4, int(np.ceil(np.log2(max(2 * m, 2)))))
    cellmap = ws.get("vx_cellmap", 1, np.int32)
    tkeys = ws.get("vx_tkeys", size, np.int64)
    tvals = ws.get("vx_tvals", size, np.int32)
    g = _grid(ws, m, m, box, False, cellmap, tkeys, tvals, voxel_size_m)
    nv = kv.voxelize_hash(pts, m, inv, box, tkeys, tvals, point_key, g.keys, g.start, g.points, g.source)
    g = _grid(ws, m, nv, box, False, cellmap, tkeys, tvals, voxel_size_m)
    if nv:
        kv.voxel_moments(g.points, g.start, nv, g.counts, g.sums, g.scatters)
    return g
