"""The index of a plane map, built once per map so that queries never enumerate all map triplets.

- **Pairs**: every ordered pair of map planes ``(i, k)`` whose normal angle can occur inside a triplet (the
  orthogonality window widened by the pair tolerance, or the non-degenerate range without structural constraints)
  and, with structural constraints, whose spheres (centroid, radius) are at most ``max_sphere_gap_m`` apart. Sorted
  by angle, so the pairs agreeing with a submap pair are one binary search away; the same relation is also kept per
  plane (CSR rows sorted by angle) to find the third plane. With the sphere constraint the number of pairs grows
  linearly with the map (each plane has a bounded number of neighbours); without it, quadratically.
- **Horizontal anchors**: map planes whose normal is within ``ground_tolerance`` of the map's up direction (floor,
  table tops: facing +1) or of down (ceilings: facing -1); the paper's ground constraint, extended to ceilings.
- **Spatial hash** of the map planes' samples on a grid of ``extent_cell_m`` dilated by one cell: which map planes
  have samples near a point, in one lookup (verification, Eq. 10-11).
- **Surface cells**: per map plane, the squares of ``SURFACE_CELL_M`` in its own plane (basis
  :func:`reloc.mapping.fusion.plane_basis`) near its samples, dilated by one square: where the plane is a surface
  that hides what lies behind it (:func:`reloc.matching._kernels.mark_hidden`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from reloc.matching import _kernels as K
from reloc.matching.params import MatchingParams
from reloc.planeset import PlaneSet

__all__ = ["MapIndex", "SURFACE_CELL_M", "build_index", "horizontal_facing", "with_dense_extents"]

SURFACE_CELL_M = 0.1  # the map samples' own spacing (``MappingConfig.map_sample_spacing_m``)
_MAX_PLANES = 1 << 21  # a plane's number is packed above the 42 bits of its surface cells' keys (_surface_cells)


def horizontal_facing(planes: PlaneSet, tolerance_rad: float) -> np.ndarray:
    """(N,) int8: +1 for planes facing up (normal within ``tolerance_rad`` of ``-gravity``, widened by the plane
    set's ``gravity_tolerance_rad``, at most 89 degrees), -1 facing down, 0 otherwise (and everywhere without
    gravity)."""
    out = np.zeros(len(planes), dtype=np.int8)
    if planes.gravity is None or len(planes) == 0:
        return out
    c = planes.normals @ -planes.gravity
    cos_tol = math.cos(min(tolerance_rad + planes.gravity_tolerance_rad, math.radians(89.0)))
    out[c >= cos_tol] = 1
    out[c <= -cos_tol] = -1
    return out


@dataclass(frozen=True)
class MapIndex:
    normals: np.ndarray  # (N, 3) float64
    offsets: np.ndarray  # (N,)
    centroids: np.ndarray  # (N, 3)
    radii: np.ndarray  # (N,)
    areas: np.ndarray  # (N,)
    facing: np.ndarray  # (N,) int8: +1 up, -1 down, 0 not horizontal
    pair_first: np.ndarray  # (P,) int32, sorted by pair_angle
    pair_second: np.ndarray  # (P,) int32
    pair_angle: np.ndarray  # (P,) float64 radians
    adj_ptr: np.ndarray  # (N + 1,) int64
    adj_ids: np.ndarray  # (P,) int32, rows sorted by angle
    adj_angle: np.ndarray  # (P,) float64
    hadj_ptr: np.ndarray  # (N + 1,) int64: the same rows restricted to horizontal planes (the anchors)
    hadj_ids: np.ndarray
    hadj_angle: np.ndarray
    pair_ext: np.ndarray  # (P, 4) signed extents of each pair (pair order), see _kernels.pair_extents
    adj_ext: np.ndarray  # (P, 4) the same in adjacency order
    hadj_ext: np.ndarray  # (H, 4) the same for the horizontal rows
    hash_slots: np.ndarray  # the C cell keys of the spatial hash in a hash table (_kernels.key_table), and each
    hash_slot_pos: np.ndarray  # key's cell number c: its map planes are hash_ids[hash_ptr[c]:hash_ptr[c + 1]]
    hash_ptr: np.ndarray  # (C + 1,) int64
    hash_ids: np.ndarray  # (E,) int32 map plane ids per cell
    cell_m: float
    structural: bool
    build_ms: float
    free_keys: np.ndarray = None  # (F,) sorted int64 voxel keys of the map's known free space (may be empty)
    free_slots: np.ndarray = None  # the same keys in a hash table (_kernels.key_table)
    free_voxel_m: float = 1.0
    dense_ext: np.ndarray | None = None  # (N, N, 2) every pair's extents: only for the brute-force baseline
    bases: np.ndarray | None = None  # (N, 2, 3) in-plane unit vectors of each plane (u, v)
    surf_ptr: np.ndarray | None = None  # (N + 1,) int64: plane i's surface cells are surf_keys[surf_ptr[i]:...]
    surf_keys: np.ndarray | None = None  # sorted int64 keys (``_kernels.surface_key``) per plane

    def __len__(self) -> int:
        return int(self.normals.shape[0])

    @property
    def n_pairs(self) -> int:
        return int(self.pair_first.shape[0])


def _spatial_hash(planes: PlaneSet, cell_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pts = planes.sample_points.astype(np.float64)
    ids = np.repeat(np.arange(len(planes), dtype=np.int32), np.diff(planes.sample_ptr))
    # Planes without samples stand for themselves with their centroid.
    empty = np.flatnonzero(np.diff(planes.sample_ptr) == 0)
    if empty.size:
        pts = np.concatenate([pts, planes.centroids[empty]])
        ids = np.concatenate([ids, empty.astype(np.int32)])
    if pts.shape[0] == 0:
        return np.zeros(0, np.int64), np.zeros(1, np.int64), np.zeros(0, np.int32)
    keys = K.cell_keys(np.ascontiguousarray(pts), cell_m)
    cells = _dilated_cells_packed(keys, ids.astype(np.int64), len(planes))
    dk, di = cells if cells is not None else _dilated_cells_lexsorted(keys, ids.astype(np.int32))
    starts = np.flatnonzero(np.r_[True, dk[1:] != dk[:-1]])  # each cell's run of plane ids starts
    keys_u = dk[starts]
    ptr = np.append(starts, dk.shape[0]).astype(np.int64)
    return keys_u.astype(np.int64), ptr, np.ascontiguousarray(di, dtype=np.int32)


def _dilated_cells_lexsorted(keys: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The unique (cell key, plane id) pairs of the 27 cells around each of ``keys`` (:func:`K.cell_keys`) with
    its ``ids``, sorted by key, then id. Any keys; :func:`_dilated_cells_packed` gives the same, faster, where the
    cells fit in one int64."""
    keys, ids = _unique_pairs(keys, ids)  # unique (cell, plane) first, so the 27-fold dilation works on few entries
    dk, di = K.dilate_keys(keys, ids)
    return _unique_pairs(dk, di)


def _dilated_cells_packed(keys: np.ndarray, ids: np.ndarray, n_ids: int) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`_dilated_cells_lexsorted` with each (cell, id) packed into one int64 (the cell's place in the keys'
    bounding box, grown by a cell each way, then the id), so that plain sorts replace two lexsorts (3.6 million
    pairs at 2,000 planes: 0.3 s). None for no keys, or when the box times ``n_ids`` does not fit in 63 bits (a map
    tens of kilometres across)."""
    if len(keys) == 0:
        return None
    comp = np.stack([keys >> 42, (keys >> 21) & K._KEY_MASK, keys & K._KEY_MASK])
    lo = comp.min(axis=1) - 1
    span = [int(v) for v in comp.max(axis=1) - lo + 2]
    if span[0] * span[1] * span[2] * max(n_ids, 1) >= 1 << 63:
        return None
    rel = comp - lo[:, None]
    packed = np.sort(((rel[0] * span[1] + rel[1]) * span[2] + rel[2]) * n_ids + ids)
    packed = packed[np.r_[True, packed[1:] != packed[:-1]]]  # np.unique, at a fraction of its time here
    steps = np.array([((dx * span[1] + dy) * span[2] + dz) * n_ids
                      for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)], dtype=np.int64)
    dil = np.sort((packed[:, None] + steps[None, :]).ravel())
    dil = dil[np.r_[True, dil[1:] != dil[:-1]]]
    cell, di = np.divmod(dil, n_ids)
    x, rest = np.divmod(cell, span[1] * span[2])
    y, z = np.divmod(rest, span[2])
    dk = ((x + lo[0]) << 42) | ((y + lo[1]) << 21) | (z + lo[2])
    return dk, di.astype(np.int32)


def _surface_cells(planes: PlaneSet, cell_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each plane's in-plane basis (N, 2, 3) and the ``cell_m`` squares of its plane within one square of a sample
    (CSR: ``ptr`` (N + 1,), ``keys`` sorted per plane)."""
    from reloc.mapping.fusion import plane_basis

    N = len(planes)
    bases = np.zeros((N, 2, 3))
    for i in range(N):
        bases[i] = plane_basis(planes.normals[i])
    owner = np.repeat(np.arange(N, dtype=np.int64), np.diff(planes.sample_ptr))
    keys = K.surface_cells(np.ascontiguousarray(planes.sample_points, dtype=np.float64), owner, bases, cell_m)
    # A surface key has 42 bits: with the plane's number above them (N < 2^21, see build_index), one sort of one
    # array puts the keys in order per plane (a lexsort of the two took four times as long, np.unique six times:
    # 9.5 million keys at 2,000 planes).
    packed = np.sort(np.repeat(owner, 9) << 42 | keys)
    if len(packed):  # a map without samples has no surface cells
        packed = packed[np.r_[True, packed[1:] != packed[:-1]]]
    keys, ids = np.ascontiguousarray(packed & ((1 << 42) - 1)), packed >> 42
    ptr = np.searchsorted(ids, np.arange(N + 1)).astype(np.int64)
    return bases, ptr, keys


def _unique_pairs(keys: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique (key, id) pairs sorted by key then id (a lexsort: much faster than ``np.unique(axis=0)``)."""
    order = np.lexsort((ids, keys))
    k, i = keys[order], ids[order]
    keep = np.ones(len(k), dtype=bool)
    keep[1:] = (k[1:] != k[:-1]) | (i[1:] != i[:-1])
    return np.ascontiguousarray(k[keep]), np.ascontiguousarray(i[keep])


def build_index(planes: PlaneSet, params: MatchingParams, *, free_keys: np.ndarray | None = None,
                free_voxel_m: float = 0.0) -> MapIndex:
    """Index the map ``planes`` (frame "map", gravity set for the ground constraint) for :mod:`reloc.matching`;
    ``free_keys`` / ``free_voxel_m``: the map's known free space (:class:`reloc.mapping.PlaneMap`), if any."""
    if not isinstance(planes, PlaneSet):
        raise ValueError(f"planes: expected a PlaneSet, got {type(planes).__name__}")
    if len(planes) >= _MAX_PLANES:
        raise ValueError(f"planes: expected fewer than {_MAX_PLANES:,} planes (a plane's number takes 21 bits of a "
                         f"surface cell's key), got {len(planes):,}")
    free_keys = np.ascontiguousarray(free_keys if free_keys is not None else np.zeros(0), dtype=np.int64)
    if len(free_keys) and free_keys.min() < 0:
        raise ValueError(f"free_keys: expected voxel keys >= 0 (the hash table keeps -1 for an empty slot), got "
                         f"{free_keys.min()}")
    t0 = time.perf_counter()
    structural = params.structural_constraints
    tol = params.pair_angle_tolerance_rad
    if structural:
        lo, hi = params.triplet_min_angle_rad - tol, params.triplet_max_angle_rad + tol
    else:
        lo, hi = params.degenerate_min_angle_rad - tol, math.pi - params.degenerate_min_angle_rad + tol
    normals = np.ascontiguousarray(planes.normals)
    centroids = np.ascontiguousarray(planes.centroids)
    radii = np.ascontiguousarray(planes.radii)
    first, second, ang = K.build_pairs(normals, centroids, radii, max(lo, 0.0), min(hi, math.pi), structural,
                                       params.max_sphere_gap_m)
    # Rows (by first) sorted by angle: the adjacency; all pairs sorted by angle: the pair list.
    row_order = np.lexsort((ang, first))
    adj_ids = np.ascontiguousarray(second[row_order])
    adj_angle = np.ascontiguousarray(ang[row_order])
    adj_ptr = np.zeros(len(planes) + 1, np.int64)
    np.add.at(adj_ptr, first.astype(np.int64) + 1, 1)
    adj_ptr = np.cumsum(adj_ptr)
    order = np.argsort(ang, kind="stable")
    facing = horizontal_facing(planes, params.ground_tolerance_rad)
    # Rows restricted to horizontal second planes: the third plane of a ground-anchored triplet.
    hsel = facing[adj_ids] != 0
    hadj_ids = np.ascontiguousarray(adj_ids[hsel])
    hadj_angle = np.ascontiguousarray(adj_angle[hsel])
    row_of = np.repeat(np.arange(len(planes)), np.diff(adj_ptr))
    hadj_ptr = np.zeros(len(planes) + 1, np.int64)
    np.add.at(hadj_ptr, row_of[hsel] + 1, 1)
    hadj_ptr = np.cumsum(hadj_ptr)
    pts = np.ascontiguousarray(planes.sample_points, dtype=np.float64)
    sptr = planes.sample_ptr
    ext = K.pair_extents(first, second, normals, planes.offsets, sptr, pts)  # in build_pairs order
    adj_ext = np.ascontiguousarray(ext[row_order])
    pair_ext = np.ascontiguousarray(ext[order])
    keys, ptr, ids = _spatial_hash(planes, params.extent_cell_m)
    bases, surf_ptr, surf_keys = _surface_cells(planes, SURFACE_CELL_M)
    hash_slots, hash_slot_pos = K.key_table(keys)
    return MapIndex(
        normals=normals,
        offsets=np.ascontiguousarray(planes.offsets),
        centroids=centroids,
        radii=radii,
        areas=np.ascontiguousarray(planes.areas),
        facing=facing,
        pair_first=np.ascontiguousarray(first[order]),
        pair_second=np.ascontiguousarray(second[order]),
        pair_angle=np.ascontiguousarray(ang[order]),
        adj_ptr=adj_ptr,
        adj_ids=adj_ids,
        adj_angle=adj_angle,
        hadj_ptr=hadj_ptr,
        hadj_ids=hadj_ids,
        hadj_angle=hadj_angle,
        pair_ext=pair_ext,
        adj_ext=adj_ext,
        hadj_ext=np.ascontiguousarray(adj_ext[hsel]),
        hash_slots=hash_slots,
        hash_slot_pos=hash_slot_pos,
        hash_ptr=ptr,
        hash_ids=ids,
        cell_m=float(params.extent_cell_m),
        structural=structural,
        build_ms=(time.perf_counter() - t0) * 1e3,
        free_keys=free_keys,
        free_slots=K.key_table(free_keys)[0],
        free_voxel_m=float(free_voxel_m) if free_voxel_m > 0 else 1.0,
        bases=bases,
        surf_ptr=surf_ptr,
        surf_keys=surf_keys,
    )


def with_dense_extents(index: MapIndex, planes: PlaneSet) -> MapIndex:
    """``index`` with the (N, N, 2) extents of every pair of ``planes`` (its map), which the brute force needs."""
    from dataclasses import replace

    dense = K.dense_extents(index.normals, index.offsets, planes.sample_ptr,
                            np.ascontiguousarray(planes.sample_points, dtype=np.float64))
    return replace(index, dense_ext=dense)
