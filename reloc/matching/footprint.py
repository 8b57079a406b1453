"""The map seen from above: where the mapping runs saw surfaces or empty space, and what lies outside all of it.

A rival pose is credited for its planes that land where the map knows nothing (``optimistic_rivals``): a more
complete map might have matched them. Outside the building that credit is void. No map, however complete, puts a
surface 1.5 m beyond the outer wall, where no mapping ray went; but a noisy sensor's map closes its doorways, so the
occlusion test that would catch a plane behind that wall is off for it. The footprint needs no line of sight: the
cells (perpendicular to gravity) that hold a map sample or a voxel of the map's known free space, grown by a margin.
"""

from __future__ import annotations

import math

import numpy as np

from reloc.mapping.fusion import plane_basis
from reloc.matching import _kernels as K

__all__ = ["FOOTPRINT_CELL_M", "MapFootprint"]

# Edge of a footprint cell (m): the map's free-space voxels are 0.25 m.
FOOTPRINT_CELL_M = 0.25


def free_voxel_centres(keys: np.ndarray, voxel_m: float) -> np.ndarray:
    """(K, 3) centres of the voxels of edge ``voxel_m`` with keys ``keys`` (as :func:`reloc.mapping.fusion.voxel_keys`
    and the map's free space make them)."""
    keys = np.asarray(keys, dtype=np.int64)
    m = K._KEY_MASK
    ijk = np.stack([(keys >> 42) & m, (keys >> 21) & m, keys & m], axis=1) - K._KEY_OFFSET
    return (ijk + 0.5) * voxel_m


class MapFootprint:
    """Cells of ``cell_m`` in the plane perpendicular to ``gravity`` that hold one of ``points`` (the map's samples
    and free-space voxel centres, map frame), grown by ``margin_m`` (a disc of cells)."""

    def __init__(self, points: np.ndarray, gravity: np.ndarray, *, margin_m: float, cell_m: float = FOOTPRINT_CELL_M):
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if not len(points):
            raise ValueError("MapFootprint: expected at least one map point, got none")
        if not (math.isfinite(margin_m) and margin_m >= 0 and math.isfinite(cell_m) and cell_m > 0):
            raise ValueError(f"MapFootprint: expected margin_m >= 0 and cell_m > 0, got {margin_m!r} and {cell_m!r}")
        g = np.asarray(gravity, dtype=np.float64).reshape(3)
        self.axes = np.stack(plane_basis(g / np.linalg.norm(g)), axis=1)  # (3, 2)
        self.cell_m = float(cell_m)
        r = int(math.ceil(margin_m / cell_m))
        cells = np.floor(points @ self.axes / cell_m).astype(np.int64)
        self.origin = cells.min(axis=0) - r
        shape = cells.max(axis=0) - self.origin + r + 1
        seen = np.zeros(tuple(shape), dtype=bool)
        seen[cells[:, 0] - self.origin[0], cells[:, 1] - self.origin[1]] = True
        grown = seen.copy()
        nx, ny = seen.shape
        for dx in range(-r, r + 1):
            for dy in range(-r, r + 1):
                if (dx == 0 and dy == 0) or (dx * dx + dy * dy) * cell_m * cell_m > margin_m * margin_m:
                    continue
                grown[max(dx, 0):nx + min(dx, 0), max(dy, 0):ny + min(dy, 0)] |= \
                    seen[max(-dx, 0):nx + min(-dx, 0), max(-dy, 0):ny + min(-dy, 0)]
        self.inside = grown

    @classmethod
    def of_map(cls, samples: np.ndarray, free_keys: np.ndarray, free_voxel_m: float, gravity: np.ndarray, *,
               margin_m: float) -> "MapFootprint":
        """The footprint of a map's samples and its known free space (``free_keys`` of voxels ``free_voxel_m``)."""
        pts = [np.asarray(samples, dtype=np.float64).reshape(-1, 3)]
        if len(free_keys):
            pts.append(free_voxel_centres(free_keys, free_voxel_m))
        return cls(np.concatenate(pts), gravity, margin_m=margin_m)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(..., ) bool: whether each of ``points`` (..., 3), map frame, lies in the footprint."""
        c = np.floor(np.asarray(points, dtype=np.float64) @ self.axes / self.cell_m).astype(np.int64) - self.origin
        nx, ny = self.inside.shape
        ok = (c[..., 0] >= 0) & (c[..., 1] >= 0) & (c[..., 0] < nx) & (c[..., 1] < ny)
        out = np.zeros(ok.shape, dtype=bool)
        out[ok] = self.inside[c[..., 0][ok], c[..., 1][ok]]
        return out

    def outside_share(self, ptr: np.ndarray, points: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(H, S) share of each plane's samples (CSR ``ptr`` (S + 1,), ``points`` (M, 3), submap frame) that the
        pose ``(R[h], t[h])`` puts outside the footprint (0 for a plane without samples)."""
        ptr = np.asarray(ptr, dtype=np.int64)
        S = len(ptr) - 1
        H = len(R)
        if H == 0 or S <= 0:
            return np.zeros((H, max(S, 0)))
        q = np.einsum("hij,nj->hni", np.asarray(R, dtype=np.float64), np.asarray(points, dtype=np.float64))
        q += np.asarray(t, dtype=np.float64)[:, None, :]
        outside = ~self.contains(q)  # (H, M)
        counts = np.diff(ptr)
        plane = np.repeat(np.arange(S), counts)
        share = np.zeros((H, S))
        for h in range(H):
            share[h] = np.bincount(plane, weights=outside[h], minlength=S)
        return share / np.maximum(counts, 1)[None, :]
