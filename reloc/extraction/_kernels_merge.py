"""Numba kernels: plane merging (paper: 'Plane merging'), by voxel growth and then merging of under-grown fragments.

A region (a plane under construction) carries the sums of its voxels' weighted moments (``W``, ``sum w p``,
``sum w p p^T`` about the origin), its point count and point sum (for the centroid), its effective point count and an
upper bound of its radius (``max |c_voxel - c_region| + r_voxel``). Its plane is refit from the weighted moments
only, never from the points (by the solver of the mode, see ``_kernels_linalg``). Points are relative to the
sensor (at the origin).
"""

from __future__ import annotations

import math

import numpy as np

from reloc._numba import njit, register_warmup
from reloc.extraction._kernels_fit import point_sigma
from reloc.extraction._kernels_linalg import plane_covariances, plane_from_moments, solve_plane
# numba caches a kernel with the kernels it calls compiled in, keyed on this file's stamp only: a change to the
# plane solvers in _kernels_linalg (closed-form eigen, smallest_eig3) goes with an edit here.
from reloc.extraction._kernels_voxel import voxel_lookup
from reloc.extraction._kernels_voxelfit import PLANAR


@njit(error_model="numpy")
def _refit(r, rmom, rscat, rplane, ray_mode, A, w3, V, zero):
    nx, ny, nz, d, _l0, _l1, _l2 = solve_plane(rmom[r, 0], rmom[r, 1:4], rscat[r], zero, ray_mode, A, w3, V)
    if d < 0.0:
        nx, ny, nz, d = -nx, -ny, -nz, -d
    rplane[r, 0] = nx
    rplane[r, 1] = ny
    rplane[r, 2] = nz
    rplane[r, 3] = d


@njit(error_model="numpy")
def _add_voxel(r, v, wmom, wscat, counts, sums, n_eff, rmom, rscat, rcount, rsum, rneff):
    for i in range(4):
        rmom[r, i] += wmom[v, i]
    for i in range(3):
        rsum[r, i] += sums[v, i]
        for k in range(3):
            rscat[r, i, k] += wscat[v, i, k]
    rcount[r] += counts[v]
    rneff[r] += n_eff[v]


@njit(error_model="numpy")
def grow_regions(nv, flags, voxel_key, box, dense, cellmap, tkeys, tvals, seed_order, planes, counts, sums, scatters,
                 eig, wmom, wscat, n_eff, radius, ray_mode, power, coeff, max_angle, angle_sigmas, max_offset,
                 offset_sigmas, thick_sigmas, thick_floor, grow, region_of, rmom, rscat, rplane, rcount, rsum, rneff,
                 rrad, queue):
    """Voxel growth over the 26-neighbourhood, seeds taken in ``seed_order`` (planar voxel ids) until none is left.

    A neighbour voxel joins the region when it is planar and not taken yet (criterion 1) and its plane agrees with
    the region's (criterion 2):
    - its normal is within ``max(max_angle, atan(angle_sigmas * sigma_z / sqrt(l1)))`` of the region's. A voxel
      normal is only as good as its noise allows: where the noise is not small against the voxel (Kinect noise at
      4.6 m is 3 cm), the voxel faces cut the noisy surface and tilt the voxel's own plane by many degrees, so the
      tolerance grows with ``sigma_z`` over the voxel's in-plane spread ``sqrt(l1)``;
    - its centroid is within ``max(max_offset, offset_sigmas * sigma_z)`` of the region's plane (not
      ``sigma_z / sqrt(n)``: a voxel face cutting the noisy surface moves the centroid by up to ~sigma_z);
    - its points lie on the region's plane: their RMS distance to it (from the voxel's moments, no points read)
      is within the planarity thickness ``max(thick_sigmas * sigma_z, thick_floor)``.
    The region plane is refit from the summed moments each time the region grows by a quarter. With ``grow``
    false every planar voxel is its own region (VR-NM).
    Writes ``region_of`` (V,) (-1 for none) and the region arrays (sized >= the number of seeds); returns the
    number of regions.
    """
    A = np.empty((3, 3))
    w3 = np.empty(3)
    V = np.empty((3, 3))
    zero = np.zeros(3)
    cos_min = math.cos(max_angle)
    nyz = box[4] * box[5]
    for v in range(nv):
        region_of[v] = -1
    nr = 0
    for k in range(seed_order.shape[0]):
        s = seed_order[k]
        if region_of[s] != -1 or flags[s] != PLANAR:
            continue
        r = nr
        nr += 1
        region_of[s] = r
        rmom[r, :] = 0.0
        rscat[r, :, :] = 0.0
        rsum[r, :] = 0.0
        rcount[r] = 0
        rneff[r] = 0
        _add_voxel(r, s, wmom, wscat, counts, sums, n_eff, rmom, rscat, rcount, rsum, rneff)
        for i in range(4):
            rplane[r, i] = planes[s, i]
        if not grow:
            continue
        head = 0
        tail = 1
        queue[0] = s
        size = 1
        next_refit = 2
        while head < tail:
            u = queue[head]
            head += 1
            key = voxel_key[u]
            ix = key // nyz
            iy = (key // box[5]) % box[4]
            iz = key % box[5]
            nx = rplane[r, 0]
            ny = rplane[r, 1]
            nz = rplane[r, 2]
            d = rplane[r, 3]
            for dx in range(-1, 2):
                for dy in range(-1, 2):
                    for dz in range(-1, 2):
                        if dx == 0 and dy == 0 and dz == 0:
                            continue
                        c = voxel_lookup(ix + dx, iy + dy, iz + dz, box, dense, cellmap, tkeys, tvals)
                        if c < 0 or region_of[c] != -1 or flags[c] != PLANAR:
                            continue
                        n_c = counts[c]
                        cx = sums[c, 0] / n_c
                        cy = sums[c, 1] / n_c
                        cz = sums[c, 2] / n_c
                        sig = point_sigma(cz, power, coeff)
                        cosang = nx * planes[c, 0] + ny * planes[c, 1] + nz * planes[c, 2]
                        if cosang < cos_min:
                            spread = math.sqrt(max(eig[c, 1], 1e-30))
                            if cosang < math.cos(min(math.atan(angle_sigmas * sig / spread), 1.5)):
                                continue
                        off = abs(nx * cx + ny * cy + nz * cz + d)
                        if off > max(max_offset, offset_sigmas * sig):
                            continue
                        # Mean squared distance of the voxel's points to the region plane, from its moments.
                        S = scatters[c]
                        nSn = (nx * (S[0, 0] * nx + S[0, 1] * ny + S[0, 2] * nz)
                               + ny * (S[1, 0] * nx + S[1, 1] * ny + S[1, 2] * nz)
                               + nz * (S[2, 0] * nx + S[2, 1] * ny + S[2, 2] * nz))
                        msd = (nSn + 2.0 * d * (nx * sums[c, 0] + ny * sums[c, 1] + nz * sums[c, 2])) / n_c + d * d
                        thick = max(thick_sigmas * sig, thick_floor)
                        if msd > thick * thick:
                            continue
                        region_of[c] = r
                        _add_voxel(r, c, wmom, wscat, counts, sums, n_eff, rmom, rscat, rcount, rsum, rneff)
                        queue[tail] = c
                        tail += 1
                        size += 1
            if size >= next_refit:
                _refit(r, rmom, rscat, rplane, ray_mode, A, w3, V, zero)
                next_refit = size + max(1, size // 4)
        if size > 1:
            _refit(r, rmom, rscat, rplane, ray_mode, A, w3, V, zero)
    # Radius bound of each region from its voxels.
    for r in range(nr):
        rrad[r] = 0.0
    for v in range(nv):
        r = region_of[v]
        if r < 0:
            continue
        inv = 1.0 / rcount[r]
        dx = sums[v, 0] / counts[v] - rsum[r, 0] * inv
        dy = sums[v, 1] / counts[v] - rsum[r, 1] * inv
        dz = sums[v, 2] / counts[v] - rsum[r, 2] * inv
        rrad[r] = max(rrad[r], math.sqrt(dx * dx + dy * dy + dz * dz) + radius[v])
    return nr


@njit(error_model="numpy")
def _region_spread(r, rmom, rscat, A, w3, V, zero):
    """sqrt of the middle eigenvalue of region ``r``'s weighted point covariance (its smaller in-plane extent)."""
    _nx, _ny, _nz, _d, _l0, l1, _l2 = plane_from_moments(rmom[r, 0], rmom[r, 1:4], rscat[r], zero, A, w3, V)
    return math.sqrt(max(l1, 1e-30))


@njit(error_model="numpy")
def merge_fragments(nr, rplane, rmom, rscat, rcount, rsum, rneff, rrad, ray_mode, power, coeff, max_angle,
                    angle_sigmas, max_depth_angle, max_offset, offset_sigmas, thick_sigmas, thick_floor,
                    radius_scale, parent, max_rounds):
    """Merge under-grown fragments into larger regions; returns the number of merges.

    Regions are visited from the largest; a smaller region ``j`` merges into ``i`` when, with ``sigma`` the depth
    noise at ``j``'s centroid:
    1. their normals are within ``max(max_angle, atan(angle_sigmas * sigma / spread_j))`` (nearly parallel, with
       the tolerance a noisy fragment of small extent needs);
    2. the centroid-to-centroid vector ``v`` is nearly perpendicular to ``i``'s normal (the same depth):
       ``|n_i . v| <= max(|v| sin(max_depth_angle), offset_sigmas * sigma)`` and
       ``|n_i . v| <= max(max_offset, offset_sigmas * sigma)``;
    3. ``|v|`` is at most ``radius_scale`` times the larger radius;
    4. ``j``'s points lie on ``i``'s plane: their weighted RMS distance to it, from ``j``'s moments, is within the
       planarity thickness ``max(thick_sigmas * sigma, thick_floor)``.
    The merged plane is refit from the summed weighted moments. ``parent[j]`` is the region ``j`` went into
    (itself for the survivors). Rounds repeat until nothing merges.
    """
    A = np.empty((3, 3))
    w3 = np.empty(3)
    V = np.empty((3, 3))
    zero = np.zeros(3)
    for r in range(nr):
        parent[r] = r
    cos_min = math.cos(max_angle)
    sin_depth = math.sin(max_depth_angle)
    spread = np.empty(nr)
    for r in range(nr):
        spread[r] = _region_spread(r, rmom, rscat, A, w3, V, zero)
    # Larger regions first; ties by index so the order is a function of the data only.
    keys = np.empty(nr, np.int64)
    for r in range(nr):
        keys[r] = -rcount[r] * (nr + 1) + r
    order = np.argsort(keys)
    merges = 0
    for _round in range(max_rounds):
        changed = False
        for a in range(nr):
            i = order[a]
            if parent[i] != i:
                continue
            for b in range(a + 1, nr):
                j = order[b]
                if parent[j] != j:
                    continue
                ci_x = rsum[i, 0] / rcount[i]
                ci_y = rsum[i, 1] / rcount[i]
                ci_z = rsum[i, 2] / rcount[i]
                cj_x = rsum[j, 0] / rcount[j]
                cj_y = rsum[j, 1] / rcount[j]
                cj_z = rsum[j, 2] / rcount[j]
                vx = cj_x - ci_x
                vy = cj_y - ci_y
                vz = cj_z - ci_z
                dist = math.sqrt(vx * vx + vy * vy + vz * vz)
                if dist > radius_scale * max(rrad[i], rrad[j]):
                    continue
                sig = point_sigma(cj_z, power, coeff)
                nx = rplane[i, 0]
                ny = rplane[i, 1]
                nz = rplane[i, 2]
                d = rplane[i, 3]
                cos_ij = nx * rplane[j, 0] + ny * rplane[j, 1] + nz * rplane[j, 2]
                if cos_ij < cos_min:
                    if cos_ij < math.cos(min(math.atan(angle_sigmas * sig / spread[j]), 1.5)):
                        continue
                off = abs(nx * vx + ny * vy + nz * vz)
                if off > max(dist * sin_depth, offset_sigmas * sig) or off > max(max_offset, offset_sigmas * sig):
                    continue
                W = rmom[j, 0]
                if not W > 0.0:
                    continue
                S = rscat[j]
                nSn = (nx * (S[0, 0] * nx + S[0, 1] * ny + S[0, 2] * nz)
                       + ny * (S[1, 0] * nx + S[1, 1] * ny + S[1, 2] * nz)
                       + nz * (S[2, 0] * nx + S[2, 1] * ny + S[2, 2] * nz))
                msd = (nSn + 2.0 * d * (nx * rmom[j, 1] + ny * rmom[j, 2] + nz * rmom[j, 3])) / W + d * d
                thick = max(thick_sigmas * sig, thick_floor)
                if msd > thick * thick:
                    continue
                # Merge j into i.
                parent[j] = i
                for k in range(4):
                    rmom[i, k] += rmom[j, k]
                for k in range(3):
                    rsum[i, k] += rsum[j, k]
                    for m in range(3):
                        rscat[i, k, m] += rscat[j, k, m]
                rcount[i] += rcount[j]
                rneff[i] += rneff[j]
                # New radius bound around the new centroid.
                inv = 1.0 / rcount[i]
                mx = rsum[i, 0] * inv
                my = rsum[i, 1] * inv
                mz = rsum[i, 2] * inv
                di = math.sqrt((ci_x - mx) ** 2 + (ci_y - my) ** 2 + (ci_z - mz) ** 2)
                dj = math.sqrt((cj_x - mx) ** 2 + (cj_y - my) ** 2 + (cj_z - mz) ** 2)
                rrad[i] = max(rrad[i] + di, rrad[j] + dj)
                _refit(i, rmom, rscat, rplane, ray_mode, A, w3, V, zero)
                spread[i] = _region_spread(i, rmom, rscat, A, w3, V, zero)
                merges += 1
                changed = True
        if not changed:
            break
    return merges


@njit(error_model="numpy")
def pack_regions(parent, plane_of_region, region_to_plane, survivors, plane_of_voxel, n_voxels):
    """Regions after :func:`merge_fragments` numbered as planes: the surviving regions (``parent[r] == r``) in
    increasing order into ``survivors``, every region's plane (that of the survivor its merge chain ends in) into
    ``region_to_plane`` (R,), every voxel's plane (``plane_of_region`` (V,) region or -1) into ``plane_of_voxel``
    and the voxels per plane into ``n_voxels`` (zeroed here). Returns the number of planes. A chain is followed for
    at most R steps."""
    nr = parent.shape[0]
    ns = 0
    for r in range(nr):
        if parent[r] == r:
            region_to_plane[r] = ns
            survivors[ns] = r
            ns += 1
        else:
            region_to_plane[r] = -1
    for r in range(nr):
        if parent[r] == r:
            continue
        root = parent[r]
        steps = 1
        while parent[root] != root and steps < nr:
            root = parent[root]
            steps += 1
        region_to_plane[r] = region_to_plane[root]
    for k in range(ns):
        n_voxels[k] = 0
    for v in range(plane_of_region.shape[0]):
        g = plane_of_region[v]
        o = region_to_plane[g] if g >= 0 else -1
        plane_of_voxel[v] = o
        if o >= 0:
            n_voxels[o] += 1
    return ns


@njit(error_model="numpy")
def pack_planes(parent, plane_of_region, rplane, rmom, rscat, rcount, rsum, rneff, rrad, ray_mode, region_to_plane,
                survivors, plane_of_voxel, n_voxels, planes, wmom, wscat, counts, sums, n_eff, radius_bound, covs,
                s0sq):
    """:func:`pack_regions`, then the surviving regions' rows (``rplane``, ``rmom``, ``rscat``, ``rcount``,
    ``rsum``, ``rneff``, ``rrad``) copied in plane order into ``planes``, ``wmom``, ``wscat``, ``counts``, ``sums``,
    ``n_eff``, ``radius_bound`` and each plane's covariance and variance factor (``plane_covariances`` of the
    mode) into ``covs``, ``s0sq`` (every output (>= R, ...), its first rows written). Returns the number of
    planes."""
    ns = pack_regions(parent, plane_of_region, region_to_plane, survivors, plane_of_voxel, n_voxels)
    for k in range(ns):
        r = survivors[k]
        for i in range(4):
            planes[k, i] = rplane[r, i]
            wmom[k, i] = rmom[r, i]
        for i in range(3):
            sums[k, i] = rsum[r, i]
            for j in range(3):
                wscat[k, i, j] = rscat[r, i, j]
        counts[k] = rcount[r]
        n_eff[k] = rneff[r]
        radius_bound[k] = rrad[r]
    plane_covariances(planes[:ns], wmom[:ns], wscat[:ns], n_eff[:ns], ray_mode, covs[:ns], s0sq[:ns])
    return ns


@register_warmup
def _warmup() -> None:
    nv = 2
    flags = np.full(nv, PLANAR, np.int8)
    box = np.array([0, 0, 8, 2, 1, 1], np.int64)
    cellmap = np.array([0, 1], np.int32)
    tk = np.full(4, -1, np.int64)
    tv = np.zeros(4, np.int32)
    vkey = np.array([0, 1], np.int64)
    planes = np.array([[0, 0, -1.0, 2.0], [0, 0, -1.0, 2.0]])
    counts = np.array([20, 20], np.int64)
    sums = np.array([[2.0, 2.0, 40.0], [7.0, 2.0, 40.0]])
    wmom = np.array([[20.0, 2.0, 2.0, 40.0], [20.0, 7.0, 2.0, 40.0]])
    wscat = np.zeros((nv, 3, 3))
    for v in range(nv):
        wscat[v] = np.diag([0.3, 0.3, 80.0])
    n_eff = counts.copy()
    radius = np.full(nv, 0.1)
    eig = np.tile(np.array([1e-6, 0.01, 0.01]), (nv, 1))
    region_of = np.empty(nv, np.int32)
    rmom = np.zeros((nv, 4))
    rscat = np.zeros((nv, 3, 3))
    rplane = np.zeros((nv, 4))
    rcount = np.zeros(nv, np.int64)
    rsum = np.zeros((nv, 3))
    rneff = np.zeros(nv, np.int64)
    rrad = np.zeros(nv)
    queue = np.empty(nv, np.int32)
    for dense in (True, False):
        nr = grow_regions(nv, flags, vkey, box, dense, cellmap, tk, tv, np.arange(nv), planes, counts, sums, wscat, eig,
                          wmom, wscat, n_eff, radius, dense, 2, 1.425e-3, 0.17, 2.0, 0.04, 3.0, 4.0, 0.01, True,
                          region_of, rmom, rscat, rplane, rcount, rsum, rneff, rrad, queue)
        parent = np.arange(nr).astype(np.int32)
        merge_fragments(nr, rplane, rmom, rscat, rcount, rsum, rneff, rrad, dense, 2, 1.425e-3, 0.14, 2.0, 0.09, 0.05,
                        2.0, 4.0, 0.01, 1.5, parent, 5)
        pack_regions(parent, region_of, np.empty(nr, np.int32), np.empty(nr, np.int64), np.empty(nv, np.int32),
                     np.empty(nr, np.int64))
        for ray in (True, False):
            pack_planes(parent, region_of, rplane, rmom, rscat, rcount, rsum, rneff, rrad, ray, np.empty(nr, np.int32),
                        np.empty(nr, np.int64), np.empty(nv, np.int32), np.empty(nr, np.int64), np.empty((nr, 4)),
                        np.empty((nr, 4)), np.empty((nr, 3, 3)), np.empty(nr, np.int64), np.empty((nr, 3)),
                        np.empty(nr, np.int64), np.empty(nr), np.empty((nr, 4, 4)), np.empty(nr))
