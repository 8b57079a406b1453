"""Triplet selection: which submap planes come first, which submap triplets are tried, and their map candidates.

- :func:`order_submap_planes`: the incremental input order, representative planes first (the ground, then large
  planes well separated in angle from those already chosen), then the rest by area; a noisy sensor's far planes
  laid over larger ones (:func:`far_overlays`) are left out. Nearer, a sparse plane so laid (:func:`sparse_overlays`)
  stays, its conflicts with the map forgiven when a pose's explained fraction is judged.
- :func:`submap_triplets`: triplets of submap planes inside the orthogonality window with the ground constraint
  (structural mode), or any non-degenerate triplet (the paper's VR-NG).
- :func:`candidate_triplets`: for each submap triplet, the map triplets agreeing with it (pairwise angles within the
  tolerance, same handedness, spheres close, areas compatible, ground matched to ground), found through the
  :class:`~reloc.matching.index.MapIndex`, or by brute force over all map triplets (the baseline).
"""

from __future__ import annotations

import functools
import itertools
import math

import numpy as np

from reloc.matching import _kernels as K
from reloc.matching.index import MapIndex, horizontal_facing
from reloc.matching.params import MatchingParams
from reloc.planeset import PlaneSet

__all__ = ["order_submap_planes", "far_overlays", "sparse_overlays", "view_distances", "submap_triplets", "gap_bounds",
           "sample_distances", "candidate_triplets"]


# A far plane over a larger one: normals 3-25 deg apart (closer ones are the fusion's to join, or a door in its
# niche), its samples at a median of 0.25 m from the larger plane, and half of them in or next to a 0.2 m cell
# holding a sample of it.
OVERLAY_MIN_ANGLE_RAD = math.radians(3.0)
OVERLAY_MAX_ANGLE_RAD = math.radians(25.0)
OVERLAY_MAX_OFFSET_M = 0.25
OVERLAY_CELL_M = 0.2
OVERLAY_MIN_FRACTION = 0.5


def view_distances(planes: PlaneSet) -> np.ndarray:
    """(N,) distance of each plane's centroid from the nearest camera of its window (``planes.viewpoints``; the
    frame's origin when there are none)."""
    views = planes.viewpoints if planes.viewpoints is not None else np.zeros((1, 3))
    return np.min(np.linalg.norm(planes.centroids[:, None, :] - views[None, :, :], axis=2), axis=1)


def far_overlays(planes: PlaneSet, params: MatchingParams) -> np.ndarray:
    """(N,) bool: the planes a submap is better without. A plane at least ``params.far_overlay_min_depth_m`` from
    every camera of its window (where the sensor's noise reaches ``far_overlay_sigma_m``; 0 = none) that lies over a
    larger plane of the submap, turned 3-25 deg from it (``OVERLAY_*``). At that noise, a third of a 25 cm voxel,
    the voxels' normals are barely defined and the growth joins surfaces: a stereo camera's far wall came out beside
    a plane of 4.5 m^2 made of the wall, a side wall and two door jambs, 8.7 deg off (docs/BENCHMARKS.md, "Stereo's
    lost views, traced"). Such a plane is in conflict with the map at the true pose, or unknown to it where a rival
    is credited for it; the larger plane it lies over holds the surface's evidence. Each plane is judged against
    every larger plane of the submap, left out or not, so the answer does not depend on the planes' order."""
    if params.far_overlay_sigma_m <= 0 or params.far_overlay_min_depth_m <= 0:
        return np.zeros(len(planes), dtype=bool)
    return _laid_over(planes, view_distances(planes) >= params.far_overlay_min_depth_m)


def sparse_overlays(planes: PlaneSet, params: MatchingParams, depths: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: the planes whose conflicts with the map should not keep a pose from explaining enough. A plane at
    least ``params.sparse_overlay_min_depth_m`` from every camera of its window (where the sensor's noise reaches
    ``sparse_overlay_sigma_m``; 0 = none) that lies over a larger plane of the submap as :func:`far_overlays` says,
    with at most ``sparse_overlay_max_density`` of that plane's points per m^2. The two lie at about the same
    distance, so the share is about that of the window's frames that saw the plane on its own; in the others its
    points went to the larger plane. A stereo camera's apartment wall at 3-4.2 m came out beside planes of 0.6-4.1
    m^2 turned 8-16 deg off it, with 1.6-7.3 % of its points per m^2, in conflict with the map at the true pose.
    Left out of the submap they would no longer tell a rival apart either (docs/BENCHMARKS.md, "A sparse plane laid
    over a larger one"), so they stay, as facets of curved clutter do
    (:func:`reloc.matching.scoring.explains_enough`). ``depths``: the planes' :func:`view_distances`, worked out
    here when not given."""
    if params.sparse_overlay_sigma_m <= 0 or params.sparse_overlay_min_depth_m <= 0 or \
            params.sparse_overlay_max_density <= 0:
        return np.zeros(len(planes), dtype=bool)
    depths = view_distances(planes) if depths is None else depths
    return _laid_over(planes, depths >= params.sparse_overlay_min_depth_m,
                      params.sparse_overlay_max_density)


def _laid_over(planes: PlaneSet, candidates: np.ndarray, max_density: float = 0.0) -> np.ndarray:
    """(N,) bool: which ``candidates`` (N,) lie over a larger plane of ``planes`` (``OVERLAY_*``), with at most
    ``max_density`` of its points per m^2 when that is above 0."""
    n = len(planes)
    out = np.zeros(n, dtype=bool)
    if n < 2 or not np.any(candidates):
        return out
    from reloc.mapping.fusion import fraction_touching, voxel_keys

    cos_lo, cos_hi = math.cos(OVERLAY_MAX_ANGLE_RAD), math.cos(OVERLAY_MIN_ANGLE_RAD)
    areas = planes.areas
    density = planes.counts / np.maximum(areas, 1e-12)
    keys: dict[int, np.ndarray] = {}
    for j in np.flatnonzero(candidates):
        pts_j = planes.samples_of(int(j))
        if len(pts_j) == 0:
            continue
        for i in np.flatnonzero(areas > areas[j]):
            c = float(planes.normals[i] @ planes.normals[j])
            if not cos_lo <= c <= cos_hi:
                continue
            if max_density > 0 and density[j] > max_density * density[i]:
                continue
            if np.median(np.abs(pts_j @ planes.normals[i] + planes.offsets[i])) > OVERLAY_MAX_OFFSET_M:
                continue
            if i not in keys:
                keys[i] = np.unique(voxel_keys(planes.samples_of(int(i)), OVERLAY_CELL_M))
            if fraction_touching(pts_j, keys[i], OVERLAY_CELL_M) >= OVERLAY_MIN_FRACTION:
                out[j] = True
                break
    return out


def order_submap_planes(planes: PlaneSet, params: MatchingParams) -> np.ndarray:
    """Indices of ``planes`` in incremental input order, at most ``params.max_submap_planes`` of them, without the
    far planes laid over larger ones (:func:`far_overlays`).

    The ground (the largest plane facing up, else the largest horizontal plane) first; then, while fewer than
    ``initial_planes`` are chosen, the largest plane whose normal is at least 30 degrees from every chosen one (or,
    when none is left, the plane most separated in angle); then the others by decreasing area. Ties are broken by
    the plane's geometry, not its index, so the order does not depend on the order of the input.
    """
    n = len(planes)
    if n == 0:
        return np.zeros(0, np.int64)
    areas = planes.areas
    # Deterministic tie-break independent of input order: area, then the centroid coordinates.
    by_area = np.lexsort((planes.centroids[:, 2], planes.centroids[:, 1], planes.centroids[:, 0], -areas))
    by_area = by_area[~far_overlays(planes, params)[by_area]]
    n = len(by_area)
    chosen: list[int] = []
    facing = horizontal_facing(planes, params.ground_tolerance_rad)
    if (facing[by_area] != 0).any():
        first = next((i for i in by_area if facing[i] == 1), None)
        chosen.append(int(first if first is not None else next(i for i in by_area if facing[i] != 0)))
    sep = math.cos(math.radians(30.0))
    while len(chosen) < min(params.initial_planes, n):
        rest = [int(i) for i in by_area if i not in chosen]
        cosines = np.abs(planes.normals[rest] @ planes.normals[chosen].T).max(axis=1) if chosen else np.zeros(len(rest))
        ok = [i for i, c in zip(rest, cosines) if c <= sep]
        chosen.append(ok[0] if ok else rest[int(np.argmin(cosines))])
    rest = [int(i) for i in by_area if i not in chosen]
    order = np.array(chosen + rest, dtype=np.int64)
    return order[: params.max_submap_planes]


@functools.lru_cache(maxsize=128)
def _combinations3(k: int) -> np.ndarray:
    """(C(k, 3), 3) the index triples ``a < b < c`` below ``k``, in the order of ``itertools.combinations``
    (read-only: shared between calls)."""
    out = np.array(list(itertools.combinations(range(k), 3)), dtype=np.int64).reshape(-1, 3)
    out.flags.writeable = False
    return out


def submap_triplets(
    normals: np.ndarray, facing: np.ndarray, positions: np.ndarray, new_from: int, params: MatchingParams
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Submap triplets among ``positions`` (plane indices) having at least one plane at a position ``>= new_from``
    (the planes added in this round of the incremental input).

    Returns ``(triplets (T, 3) int32, face0 (T,) int8, ground)``. With ``ground`` (structural constraints and a
    horizontal plane among the positions) each row holds exactly one horizontal plane, first, facing ``face0``
    (+1 up, -1 down), and the map side must match it with a horizontal plane facing the same way: the paper's
    ground constraint (Eq. 4-5), extended to ceilings. Rows pass the angle window (all three pairs) and the
    triple-product test (the normals span 3-D space).
    """
    k = len(positions)
    structural = params.structural_constraints
    is_ground = facing != 0
    use_ground = structural and bool(np.any(is_ground[positions]))
    if structural:
        lo, hi = params.triplet_min_angle_rad, params.triplet_max_angle_rad
    else:
        lo, hi = params.degenerate_min_angle_rad, math.pi - params.degenerate_min_angle_rad
    abc = _combinations3(k)
    tri = np.asarray(positions, dtype=np.int64)[abc[abc[:, 2] >= new_from]]
    if use_ground:
        # Exactly one horizontal plane per row, put first; the other two in increasing order.
        g = is_ground[tri]
        one = g.sum(axis=1) == 1
        tri, g = tri[one], g[one]
        others = np.sort(tri[~g].reshape(-1, 2), axis=1)
        tri = np.column_stack([tri[g], others])
    if not len(tri):
        return np.zeros((0, 3), np.int32), np.zeros(0, np.int8), use_ground
    tri = tri.astype(np.int32)
    n0, n1, n2 = normals[tri[:, 0]], normals[tri[:, 1]], normals[tri[:, 2]]

    def ang(u, v):
        return np.arccos(np.clip(np.sum(u * v, axis=1), -1.0, 1.0))

    keep = np.ones(len(tri), dtype=bool)
    for u, v in ((n0, n1), (n0, n2), (n1, n2)):
        a = ang(u, v)
        keep &= (a >= lo) & (a <= hi)
    keep &= np.abs(np.sum(n0 * np.cross(n1, n2), axis=1)) >= params.min_triple_product
    tri = np.ascontiguousarray(tri[keep])
    face0 = np.ascontiguousarray(facing[tri[:, 0]].astype(np.int8)) if use_ground else np.zeros(len(tri), np.int8)
    return tri, face0, use_ground


def sample_distances(ptr: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(S, S) smallest distance between the sample sets of every two planes (CSR ``ptr``, ``points``).

    Computed on the few verification samples of each plane, so it over-estimates the true smallest distance
    between the planes' points by at most the sample spacing.
    """
    S = len(ptr) - 1
    if S == 0 or len(points) == 0:
        return np.zeros((S, S))
    if np.all(np.diff(ptr) > 0):
        out = np.empty((S, S))
        K.sample_set_distances(np.ascontiguousarray(ptr, dtype=np.int64),
                               np.ascontiguousarray(points, dtype=np.float64), out)
        return out
    # A plane without samples: the full matrix, as before the kernel (reduceat gives such a plane the distances of
    # the sample at its start).
    d = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=2)
    starts = np.asarray(ptr[:-1])
    rows = np.minimum.reduceat(d, starts, axis=0)
    return np.minimum.reduceat(rows, starts, axis=1)


def gap_bounds(triplets: np.ndarray, distances: np.ndarray, params: MatchingParams) -> np.ndarray:
    """(T, 3) upper bounds of the sphere gaps ``(g01, g02, g12)`` of the map planes of each triplet.

    A map plane's sphere holds every point of the plane, so the gap between two map spheres is at most the
    distance between what the submap saw of the two planes (plus a tolerance for noise), and at most the index's
    ``max_sphere_gap_m``.
    """
    t = triplets
    g = np.stack([distances[t[:, 0], t[:, 1]], distances[t[:, 0], t[:, 2]], distances[t[:, 1], t[:, 2]]], axis=1)
    return np.ascontiguousarray(np.minimum(g + params.gap_tolerance_m, params.max_sphere_gap_m))


def candidate_triplets(
    index: MapIndex,
    sub_normals: np.ndarray,
    sub_areas: np.ndarray,
    triplets: np.ndarray,
    face0: np.ndarray,
    gaps: np.ndarray,
    sub_ext: np.ndarray,
    require_ground: bool,
    params: MatchingParams,
    *,
    brute_force: bool = False,
) -> tuple[np.ndarray, int, bool]:
    """Candidate correspondences ``(j0, j1, j2, i0, i1, i2)`` (H, 6) int32 for the submap ``triplets``.

    ``face0`` (T,) and ``gaps`` (T, 3) come from :func:`submap_triplets` and :func:`gap_bounds`; ``sub_ext``
    (S, S, 2) from ``_kernels.dense_extents`` on the submap. Returns ``(candidates, generated, truncated)``:
    ``generated`` counts the map triplets looked at (the cost of the search), ``truncated`` is True when more than
    ``params.max_candidates`` agreed (only that many are kept). ``brute_force`` enumerates every ordered map
    triplet instead of the index (the index needs :func:`~reloc.matching.index.with_dense_extents`); it must give
    the same rows.
    """
    if index.structural != params.structural_constraints:
        raise ValueError(
            f"index: built with structural_constraints={index.structural}, but params have "
            f"{params.structural_constraints}; rebuild the index with these params"
        )
    cap = int(params.max_candidates)
    out = np.empty((cap, 6), np.int32)
    if len(triplets) == 0 or len(index) < 3:
        return out[:0], 0, False
    structural = params.structural_constraints
    sub_normals = np.ascontiguousarray(sub_normals, dtype=np.float64)
    sub_areas = np.ascontiguousarray(sub_areas, dtype=np.float64)
    triplets = np.ascontiguousarray(triplets, dtype=np.int32)
    face0 = np.ascontiguousarray(face0, dtype=np.int8)
    gaps = np.ascontiguousarray(gaps, dtype=np.float64)
    sub_ext = np.ascontiguousarray(sub_ext, dtype=np.float64)
    flags = (params.pair_angle_tolerance_rad, bool(require_ground), structural, structural, params.min_area_ratio,
             params.min_triple_product, structural, params.extent_tolerance_m)
    if brute_force:
        if index.dense_ext is None:
            raise ValueError("index: the brute force needs the dense pair extents (index.with_dense_extents)")
        count, generated = K.brute_force_candidates(
            triplets, face0, gaps, sub_ext, sub_normals, sub_areas, index.normals, index.centroids, index.radii,
            index.areas, index.facing, index.dense_ext, *flags, out,
        )
    else:
        adj = ((index.hadj_ptr, index.hadj_ids, index.hadj_angle, index.hadj_ext) if require_ground
               else (index.adj_ptr, index.adj_ids, index.adj_angle, index.adj_ext))
        count, generated = K.join_candidates(
            triplets, face0, gaps, sub_ext, sub_normals, sub_areas, index.normals, index.centroids, index.radii,
            index.areas, index.facing, index.pair_first, index.pair_second, index.pair_angle, index.pair_ext, *adj,
            *flags, out,
        )
    return out[: min(count, cap)], int(generated), count > cap
