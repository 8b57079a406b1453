"""Stage 5: voxel planes merged into planes (paper: 'Plane merging'): 26-neighbour voxel growth from a seed list,
then merging of under-grown fragments; every merged plane is refit from its summed weighted moments. Then the
refinement (beyond the paper): one robust pass over the points near each merged plane refits it and lets
fragments that the voxel noise kept apart merge.

Points are in the sensor frame with the sensor at the origin."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from reloc.extraction import _kernels_finalize as kfin
from reloc.extraction import _kernels_linalg as kl
from reloc.extraction import _kernels_merge as km
from reloc.extraction._workspace import Workspace, fresh
from reloc.extraction.params import noise_law_code
from reloc.extraction.voxel_planes import PLANAR, VoxelPlanes
from reloc.extraction.voxelize import VoxelGrid

__all__ = ["MergedPlanes", "merge_voxel_planes", "refine_merged_planes", "plane_covariances"]


@dataclass(frozen=True)
class MergedPlanes:
    """Planes after merging (P rows, own arrays), and which voxels make them.

    - ``plane_of_voxel`` (V,) int32: plane index of each voxel, -1 for none.
    - ``planes`` (P, 4) ``[n, d]`` toward the sensor, refit from ``wmoments`` (P, 4) ``[W, sum w p]`` and
      ``wscatters`` (P, 3, 3) (about the origin); ``n_eff`` (P,) points with a non-zero weight.
    - ``counts`` (P,), ``sums`` (P, 3): the plane's points (all points of its voxels after growth, the supporting
      points after refinement); ``radius_bound`` (P,) an upper bound of the radius from the voxels' centroids and
      radii; ``n_voxels`` (P,).
    - ``covariances`` (P, 4, 4) of ``(n, d)`` and ``variance_factors`` (P,) (``s0^2``, 1 for an exact noise law).
    - ``n_fragment_merges``: merges made by the under-grown steps.
    - ``point_plane``: after a refinement over all points, the plane of every point (sorted order, -1 for none)
      from that pass, in the pass's numbering: ``point_table`` (int32) maps it to these planes (-1: dropped) (the
      plane set reuses both instead of assigning the points again); and ``support`` = ``(counts (P,), sums (P, 3),
      scatters (P, 3, 3))`` the plain moments about the origin of the points it assigned to each plane.
    """

    plane_of_voxel: np.ndarray
    planes: np.ndarray
    wmoments: np.ndarray
    wscatters: np.ndarray
    n_eff: np.ndarray
    counts: np.ndarray
    sums: np.ndarray
    radius_bound: np.ndarray
    n_voxels: np.ndarray
    covariances: np.ndarray
    variance_factors: np.ndarray
    n_fragment_merges: int
    point_plane: np.ndarray | None = None
    support: tuple | None = None
    point_table: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.planes.shape[0])


def plane_covariances(planes, wmoments, wscatters, n_eff, *, ray_mode: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(P, 4, 4) covariances of ``(n, d)`` and (P,) variance factors from weighted moments about the origin, for
    planes solved in the ray form (``ray_mode``) or by total least squares."""
    n = planes.shape[0]
    covs = np.zeros((n, 4, 4))
    s0 = np.zeros(n)
    if n:
        kl.plane_covariances(np.ascontiguousarray(planes), np.ascontiguousarray(wmoments),
                             np.ascontiguousarray(wscatters), np.ascontiguousarray(n_eff, dtype=np.int64),
                             bool(ray_mode), covs, s0)
    return covs, s0


def _fragment_args(noise_model, noise_coeff, undergrown_max_angle_rad, grow_angle_noise_sigmas,
                   undergrown_max_depth_angle_rad, undergrown_max_offset_m, grow_offset_sigmas, max_thickness_sigmas,
                   max_thickness_floor_m, undergrown_radius_scale) -> tuple:
    return (noise_law_code(noise_model), float(noise_coeff), float(undergrown_max_angle_rad),
            float(grow_angle_noise_sigmas), float(undergrown_max_depth_angle_rad), float(undergrown_max_offset_m),
            float(grow_offset_sigmas), float(max_thickness_sigmas), float(max_thickness_floor_m),
            float(undergrown_radius_scale))


def _merge_and_pack(plane_of_region, rplane, rmom, rscat, rcount, rsum, rneff, rrad, *, merge, ray, fragment_args,
                    n_merges_before=0) -> MergedPlanes:
    """Under-grown fragment merging over regions, then the surviving regions packed as :class:`MergedPlanes`.

    ``plane_of_region`` (V,) maps voxels to region indices (-1 for none). Returns the planes and the (R,) plane
    index of every region."""
    nr = rplane.shape[0]
    parent = np.arange(nr, dtype=np.int32)
    n_merges = 0
    if merge and nr > 1:
        n_merges = km.merge_fragments(nr, rplane, rmom, rscat, rcount, rsum, rneff, rrad, ray, *fragment_args,
                                      parent, 16)
    # Resolve merge chains to their surviving region, number the survivors, the voxels' planes, and copy the
    # survivors' rows with their covariances (one kernel: the NumPy indexing it replaces cost more than it).
    region_to_plane = np.empty(nr, np.int32)
    plane_of_voxel = np.empty(plane_of_region.shape[0], np.int32)
    planes, wmom, sums = np.empty((nr, 4)), np.empty((nr, 4)), np.empty((nr, 3))
    wscat, covs = np.empty((nr, 3, 3)), np.empty((nr, 4, 4))
    counts, n_eff, n_voxels = np.empty(nr, np.int64), np.empty(nr, np.int64), np.empty(nr, np.int64)
    radius_bound, s0 = np.empty(nr), np.empty(nr)
    ns = km.pack_planes(parent, plane_of_region, rplane, rmom, rscat, rcount, rsum, rneff, rrad, ray, region_to_plane,
                        np.empty(nr, np.int64), plane_of_voxel, n_voxels, planes, wmom, wscat, counts, sums, n_eff,
                        radius_bound, covs, s0)
    return MergedPlanes(
        plane_of_voxel=plane_of_voxel, planes=planes[:ns], wmoments=wmom[:ns], wscatters=wscat[:ns],
        n_eff=n_eff[:ns], counts=counts[:ns], sums=sums[:ns], radius_bound=radius_bound[:ns],
        n_voxels=n_voxels[:ns], covariances=covs[:ns], variance_factors=s0[:ns],
        n_fragment_merges=int(n_merges + n_merges_before),
    ), region_to_plane


def merge_voxel_planes(
    grid: VoxelGrid,
    vp: VoxelPlanes,
    *,
    merge: bool = True,
    grow_max_angle_rad: float = np.radians(10.0),
    grow_max_offset_m: float = 0.02,
    grow_offset_sigmas: float = 2.0,
    grow_angle_noise_sigmas: float = 2.0,
    max_thickness_sigmas: float = 4.0,
    max_thickness_floor_m: float = 0.01,
    undergrown_max_angle_rad: float = np.radians(8.0),
    undergrown_max_depth_angle_rad: float = np.radians(5.0),
    undergrown_max_offset_m: float = 0.05,
    undergrown_radius_scale: float = 1.5,
    noise_model: str = "kinect",
    noise_coeff: float = 1.425e-3,
    noise_direction: str = "ray",
    workspace: Workspace | None = None,
) -> MergedPlanes:
    """Merge the planar voxels of ``vp`` (refined, so their weighted moments exist) into planes.

    Seeds are the planar voxels from the most populated (ties by voxel id, so the result does not depend on the
    order of the points). ``merge=False`` keeps every planar voxel as its own plane (the paper's VR-NM).
    ``noise_direction`` picks the plane solver of the refits (as in :func:`refine_voxel_planes`).
    """
    ws = fresh(workspace)
    ray = noise_direction == "ray"
    nv = len(grid)
    planar = np.flatnonzero(vp.flags[:nv] == PLANAR)
    seeds = planar[np.argsort(-grid.counts[planar], kind="stable")].astype(np.int64)
    n_seed = len(seeds)
    region_of = ws.get("mg_region_of", nv, np.int32)
    rmom = np.zeros((n_seed, 4))
    rscat = np.zeros((n_seed, 3, 3))
    rplane = np.zeros((n_seed, 4))
    rcount = np.zeros(n_seed, np.int64)
    rsum = np.zeros((n_seed, 3))
    rneff = np.zeros(n_seed, np.int64)
    rrad = np.zeros(n_seed)
    queue = ws.get("mg_queue", max(nv, 1), np.int32)
    nr = 0
    if nv:
        nr = km.grow_regions(
            nv, vp.flags, grid.keys, grid.box, grid.dense, grid.cellmap, grid.tkeys, grid.tvals, seeds, vp.planes,
            grid.counts, grid.sums, grid.scatters, vp.eigenvalues, vp.wmoments, vp.wscatters, vp.n_eff, vp.radius,
            ray, noise_law_code(noise_model), float(noise_coeff), float(grow_max_angle_rad),
            float(grow_angle_noise_sigmas), float(grow_max_offset_m), float(grow_offset_sigmas),
            float(max_thickness_sigmas), float(max_thickness_floor_m), bool(merge), region_of, rmom, rscat, rplane,
            rcount, rsum, rneff, rrad, queue,
        )
    fragment_args = _fragment_args(noise_model, noise_coeff, undergrown_max_angle_rad, grow_angle_noise_sigmas,
                                   undergrown_max_depth_angle_rad, undergrown_max_offset_m, grow_offset_sigmas,
                                   max_thickness_sigmas, max_thickness_floor_m, undergrown_radius_scale)
    return _merge_and_pack(region_of[:nv].copy(), rplane[:nr], rmom[:nr], rscat[:nr], rcount[:nr], rsum[:nr],
                           rneff[:nr], rrad[:nr], merge=merge, ray=ray, fragment_args=fragment_args)[0]


def refine_merged_planes(
    grid: VoxelGrid,
    merged: MergedPlanes,
    *,
    merge: bool = True,
    inlier_sigmas: float = 4.0,
    refine_boundary: bool = True,
    noise_weights: bool = True,
    grow_offset_sigmas: float = 2.0,
    grow_angle_noise_sigmas: float = 2.0,
    max_thickness_sigmas: float = 4.0,
    max_thickness_floor_m: float = 0.01,
    undergrown_max_angle_rad: float = np.radians(8.0),
    undergrown_max_depth_angle_rad: float = np.radians(5.0),
    undergrown_max_offset_m: float = 0.05,
    undergrown_radius_scale: float = 1.5,
    noise_model: str = "kinect",
    noise_coeff: float = 1.425e-3,
    noise_direction: str = "ray",
    point_step: int = 1,
    ordered: bool = False,
    workspace: Workspace | None = None,
    bevel_max_width_m: float = math.inf,
    corner_min_angle_rad: float = np.radians(20.0),
) -> MergedPlanes:
    """One robust pass over the points near each merged plane: refit, then merge fragments again.

    Every point of a plane's voxels and (``refine_boundary``) of their neighbours goes to the nearest candidate
    plane within ``inlier_sigmas`` (times the plane's robust scale, at least 1) noise sigmas; each plane is refit
    from its points weighted by Tukey's biweight of that width times the inverse noise variance. This removes what
    the voxel faces did to the merged plane (points the noise pushed into a neighbouring voxel were lost to it) and
    puts fragments of one surface on nearly the same plane, so the under-grown step can now merge them.
    ``point_step > 1`` (a power of two) refits from about 1 in ``point_step`` points (a cheap first pass; every
    ``point_step``-th of a voxel when ``ordered``, as the points of a depth image are); with 1 the pass's
    assignment of every point is kept in the result (``point_plane``).
    A plane whose points are mostly corner points (their pixel ray meets another candidate, more than
    ``corner_min_angle_rad`` away in angle, nearly where it meets this plane) is a bevel across that corner and is
    dropped, unless it is wider than ``bevel_max_width_m`` across its shorter in-plane axis
    (:func:`plane_minor_widths`; inf: any width). Corner points are left out of every plane's refit.
    """
    ws = fresh(workspace)
    ray = noise_direction == "ray"
    n = len(merged)
    m = int(grid.start[-1]) if len(grid.start) else 0
    if n == 0 or m == 0:
        return merged
    planes = merged.planes.copy()
    refs = merged.sums / np.maximum(merged.counts, 1)[:, None]
    band = float(inlier_sigmas) * np.sqrt(np.maximum(merged.variance_factors, 1.0))
    point_plane = ws.get("rf_point_plane", m, np.int32)
    acc_w = np.zeros(n)
    acc_s = np.zeros((n, 3))
    acc_S = np.zeros((n, 3, 3))
    acc_n = np.zeros(n, np.int64)
    acc_sum = np.zeros((n, 3))
    acc_amb = np.zeros(n, np.int64)
    sup = np.zeros((n, 10))
    kfin.assign_points(
        grid.points, grid.points.view(np.int32), int(point_step), bool(ordered), grid.start, len(grid), grid.keys, grid.box,
        grid.dense, grid.cellmap, grid.tkeys, grid.tvals, grid.counts, grid.sums, grid.scatters,
        merged.plane_of_voxel, planes, band, noise_law_code(noise_model), float(noise_coeff), ray,
        bool(refine_boundary), point_plane, True, bool(noise_weights), math.cos(corner_min_angle_rad), refs, acc_w,
        acc_s, acc_S, acc_n, acc_sum, acc_amb, sup,
        ws.get("rf_scratch", (kfin.SCRATCH_ROWS, max(int(grid.counts.max()), 1)), np.float64),
    )
    # Refit, drop the bevels and take the pass's statistics (one kernel). A plane whose points are mostly at a
    # corner of two other planes is a bevel across that corner made by voxels holding both surfaces: dropped, its
    # points go to the planes around it. Planes that kept points take their refined statistics; the others keep
    # the merged ones.
    # With a width limit, only a plane as narrow as a bevel can be one: a wall whose points mostly lie where the
    # ray also meets a fragment tilted across it (far stereo walls, whose noise band is wide) is a wall, kept.
    if math.isfinite(bevel_max_width_m):
        widths = np.empty(n)
        kfin.plane_minor_widths(merged.planes, merged.plane_of_voxel, grid.counts, grid.sums, grid.scatters, widths)
        acc_amb[widths > bevel_max_width_m] = 0
    old_to_kept = np.empty(n, np.int32)
    k_planes, k_wmom, k_sums = np.empty((n, 4)), np.empty((n, 4)), np.empty((n, 3))
    k_wscat = np.empty((n, 3, 3))
    k_counts, k_neff, k_radius = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n)
    plane_of_voxel = np.empty(merged.plane_of_voxel.shape[0], np.int32)
    nk = kfin.refine_keep(acc_w, acc_s, acc_S, refs, ray, planes, merged.wmoments, merged.wscatters, acc_n, acc_amb,
                          acc_sum, merged.counts, merged.sums, merged.n_eff, merged.radius_bound,
                          merged.plane_of_voxel, old_to_kept, k_planes, k_wmom, k_wscat, k_counts, k_sums, k_neff,
                          k_radius, plane_of_voxel)
    fragment_args = _fragment_args(noise_model, noise_coeff, undergrown_max_angle_rad, grow_angle_noise_sigmas,
                                   undergrown_max_depth_angle_rad, undergrown_max_offset_m, grow_offset_sigmas,
                                   max_thickness_sigmas, max_thickness_floor_m, undergrown_radius_scale)
    out, kept_to_final = _merge_and_pack(plane_of_voxel, k_planes[:nk], k_wmom[:nk], k_wscat[:nk], k_counts[:nk],
                                         k_sums[:nk], k_neff[:nk], k_radius[:nk], merge=merge, ray=ray,
                                         fragment_args=fragment_args, n_merges_before=merged.n_fragment_merges)
    if point_step != 1 or np.any(old_to_kept[:n] < 0):
        # Not every point seen, or a bevel dropped: its points go to the planes around it, so the plane set assigns
        # every point again (the pass's own assignment would leave them on no plane, and out of their counts).
        return out
    # The pass's planes to the output's (the plane set applies it to the points): merged fragments go to their
    # survivor.
    table = np.empty(n, np.int32)
    kfin.compose_table(old_to_kept, kept_to_final, table)
    n_out = len(out)
    support = (np.zeros(n_out, np.int64), np.zeros((n_out, 3)), np.zeros((n_out, 3, 3)))
    kfin.support_moments(sup, refs, table, n_out, *support)
    return replace(out, point_plane=point_plane[:m], point_table=table, support=support)
