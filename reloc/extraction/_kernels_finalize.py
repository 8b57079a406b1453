"""Numba kernels: from merged planes to the plane set: supporting points, statistics, radius, area, samples, labels.

In-plane coordinates of a point ``p`` of plane ``(n, d)``: ``(u, v) = (t1 . p, t2 . p)`` with ``t1, t2`` the
tangent basis of ``n`` (``tangent_basis``); the grid cells of the area count and of the samples are
``floor(u / l)``, ``floor(v / l)``, anchored at the foot of the origin on the plane, so they do not depend on the
order of the points. Points are relative to the sensor (at the origin).
"""

from __future__ import annotations

import math

import numpy as np

from reloc._numba import njit, register_warmup
from reloc.extraction._kernels_fit import MIN_DEPTH, MIN_INCIDENCE
from reloc.extraction._kernels_linalg import solve_plane, tangent_basis
# numba caches a kernel with the kernels it calls compiled in, keyed on this file's stamp only: a change to the
# plane solvers in _kernels_linalg (closed-form eigen, smallest_eig3) goes with an edit here.
from reloc.extraction._kernels_voxel import voxel_lookup
from reloc.extraction._kernels_voxelfit import _keep

MAX_CANDIDATES = 8
# Rows of the float64 scratch of assign_points: x, y, z, g, u, nearest candidate, then e_k per candidate.
SCR_E = 6
SCRATCH_ROWS = SCR_E + MAX_CANDIDATES
CORNER_BANDS = 1.5


@njit(error_model="numpy")
def _sigma_z(z, power, coeff):
    if power == 2:
        return coeff * z * z
    if power == 1:
        return coeff * z
    return coeff


@njit(error_model="numpy")
def _candidates(v, voxel_key, box, dense, cellmap, tkeys, tvals, plane_of_voxel, neighbours, cand):
    """Distinct planes of voxel ``v`` and (``neighbours``) of its 26 neighbours into ``cand``; returns how many."""
    nc = 0
    own = plane_of_voxel[v]
    if own >= 0:
        cand[0] = own
        nc = 1
    if not neighbours:
        return nc
    nyz = box[4] * box[5]
    key = voxel_key[v]
    ix = key // nyz
    iy = (key // box[5]) % box[4]
    iz = key % box[5]
    for dx in range(-1, 2):
        for dy in range(-1, 2):
            for dz in range(-1, 2):
                if dx == 0 and dy == 0 and dz == 0:
                    continue
                c = voxel_lookup(ix + dx, iy + dy, iz + dz, box, dense, cellmap, tkeys, tvals)
                if c < 0:
                    continue
                q = plane_of_voxel[c]
                if q < 0:
                    continue
                seen = False
                for k in range(nc):
                    if cand[k] == q:
                        seen = True
                if not seen and nc < cand.shape[0]:
                    cand[nc] = q
                    nc += 1
    return nc


@njit(fastmath={"reassoc", "contract"}, error_model="numpy")
def _subsample_voxel(sorted_pts, point_bits, step, by_order, a, b, q, planes, band, power, coeff, ray_mode,
                     use_noise, refs, acc_w, acc_s, acc_S, acc_n, acc_sum, scratch):
    """The refit sums of :func:`_single_plane_voxel` from about 1 in ``step`` points only (every ``step``-th in
    order with ``by_order``, else by the coordinate hash); assigns nothing. As there, the distances first (into
    ``scratch`` (5, >= b - a): the point's x, y, z, ``u``, ``g``), then branch-free sums over those contiguous rows
    that vectorise."""
    nx = planes[q, 0]
    ny = planes[q, 1]
    nz = planes[q, 2]
    d = planes[q, 3]
    bq = band[q]
    inv_b2 = 1.0 / (bq * bq)
    rx = refs[q, 0]
    ry = refs[q, 1]
    rz = refs[q, 2]
    k = 0
    for j in range(a, b, step if by_order else 1):
        if not by_order and not _keep(point_bits, j, step):
            continue
        px = np.float64(sorted_pts[j, 0])
        py = np.float64(sorted_pts[j, 1])
        pz = np.float64(sorted_pts[j, 2])
        npd = nx * px + ny * py + nz * pz
        zz = pz if pz > MIN_DEPTH else MIN_DEPTH
        g = zz / _sigma_z(zz, power, coeff)
        an = abs(npd)
        lo = MIN_INCIDENCE * zz
        den = (an if an > lo else lo) if ray_mode else zz
        scratch[0, k] = px
        scratch[1, k] = py
        scratch[2, k] = pz
        scratch[3, k] = abs(npd + d) * g / den
        scratch[4, k] = g
        k += 1
    W = s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = 0.0
    c0 = c1 = c2 = cn = 0.0
    for i in range(k):
        px = scratch[0, i]
        py = scratch[1, i]
        pz = scratch[2, i]
        u = scratch[3, i]
        t = 1.0 - u * u * inv_b2
        t = t if t > 0.0 else 0.0
        w = t * t
        if use_noise:
            zz = pz if pz > MIN_DEPTH else MIN_DEPTH
            g = scratch[4, i]
            w *= g * g if ray_mode else g * g / (zz * zz)
        x = px - rx
        y = py - ry
        z = pz - rz
        W += w
        s0 += w * x
        s1 += w * y
        s2 += w * z
        s3 += w * x * x
        s4 += w * x * y
        s5 += w * x * z
        s6 += w * y * y
        s7 += w * y * z
        s8 += w * z * z
        f = 1.0 if t > 0.0 else 0.0
        cn += f
        c0 += f * px
        c1 += f * py
        c2 += f * pz
    acc_w[q] += W
    acc_s[q, 0] += s0
    acc_s[q, 1] += s1
    acc_s[q, 2] += s2
    acc_S[q, 0, 0] += s3
    acc_S[q, 0, 1] += s4
    acc_S[q, 0, 2] += s5
    acc_S[q, 1, 1] += s6
    acc_S[q, 1, 2] += s7
    acc_S[q, 2, 2] += s8
    acc_n[q] += int(cn)
    acc_sum[q, 0] += c0
    acc_sum[q, 1] += c1
    acc_sum[q, 2] += c2


@njit(fastmath={"reassoc", "contract"}, error_model="numpy")
def _single_plane_assign(sorted_pts, a, b, q, planes, band, power, coeff, ray_mode, point_plane, scratch):
    """:func:`_single_plane_voxel` without sums (the plane set's own assignment): the plane of every point, two
    branch-free loops (distances into ``scratch[0]``, then the band test). Returns the number of points assigned."""
    nx = planes[q, 0]
    ny = planes[q, 1]
    nz = planes[q, 2]
    d = planes[q, 3]
    bq = band[q]
    flat = sorted_pts.reshape(-1)  # flat view, unsigned indices: the loops vectorise (as in _single_plane_voxel)
    for j in range(a, b):
        j3 = np.uint64(3 * j)
        px = np.float64(flat[j3])
        py = np.float64(flat[j3 + np.uint64(1)])
        pz = np.float64(flat[j3 + np.uint64(2)])
        npd = nx * px + ny * py + nz * pz
        zz = pz if pz > MIN_DEPTH else MIN_DEPTH
        g = zz / _sigma_z(zz, power, coeff)
        an = abs(npd)
        lo = MIN_INCIDENCE * zz
        den = (an if an > lo else lo) if ray_mode else zz
        scratch[0, np.uint64(j - a)] = abs(npd + d) * g / den
    n_in = 0
    for j in range(a, b):
        inside = scratch[0, np.uint64(j - a)] <= bq
        n_in += 1 if inside else 0
        point_plane[np.uint64(j)] = q if inside else -1
    return n_in


@njit(fastmath={"reassoc", "contract"}, error_model="numpy")
def _weighted_sums_only(sorted_pts, a, b, q, ray_mode, use_noise, rx, ry, rz, acc_w, acc_s, acc_S, scratch):
    """The weighted refit sums of :func:`_single_plane_voxel` alone (``scratch`` rows: u, g, Tukey's t, x, y, z)."""
    W = s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = 0.0
    for j in range(a, b):
        px = scratch[3, j - a]
        py = scratch[4, j - a]
        pz = scratch[5, j - a]
        t = scratch[2, j - a]
        w = t * t
        if use_noise:
            zz = pz if pz > MIN_DEPTH else MIN_DEPTH
            g = scratch[1, j - a]
            w *= g * g if ray_mode else g * g / (zz * zz)
        x = px - rx
        y = py - ry
        z = pz - rz
        W += w
        s0 += w * x
        s1 += w * y
        s2 += w * z
        s3 += w * x * x
        s4 += w * x * y
        s5 += w * x * z
        s6 += w * y * y
        s7 += w * y * z
        s8 += w * z * z
    acc_w[q] += W
    acc_s[q, 0] += s0
    acc_s[q, 1] += s1
    acc_s[q, 2] += s2
    acc_S[q, 0, 0] += s3
    acc_S[q, 0, 1] += s4
    acc_S[q, 0, 2] += s5
    acc_S[q, 1, 1] += s6
    acc_S[q, 1, 2] += s7
    acc_S[q, 2, 2] += s8


@njit(fastmath={"reassoc", "contract"}, error_model="numpy")
def _single_plane_voxel(sorted_pts, v, a, b, q, planes, band, power, coeff, ray_mode, point_plane,
                        accumulate, use_noise, refs, counts, sums, scatters, acc_w, acc_s, acc_S, acc_n, acc_sum, sup,
                        scratch):
    """:func:`assign_points` for a voxel ``v`` whose only candidate is plane ``q`` (most voxels): no corner test,
    and branch-free loops (distances, then weighted sums) that vectorise. ``scratch`` (6, >= b - a) float64 (u, g,
    Tukey's base t, x, y, z per point).
    Returns the number of points assigned.

    When every point of the voxel is inside the band with a non-zero weight (most voxels), the plain sums (points
    of non-zero weight, supporting points) are the voxel's moments ``counts[v]``, ``sums[v]``, ``scatters[v]``
    (about the origin), so only the weighted sums are made point by point: the same figures to rounding."""
    if not accumulate:
        return _single_plane_assign(sorted_pts, a, b, q, planes, band, power, coeff, ray_mode, point_plane, scratch)
    nx = planes[q, 0]
    ny = planes[q, 1]
    nz = planes[q, 2]
    d = planes[q, 3]
    bq = band[q]
    n_in = 0
    # A flat view of the points (C-contiguous) and unsigned indices (no test for an index from the end): this loop
    # and the next then vectorise (the pass over every point 2.15 -> 1.77 ms per 640x480 frame; the same figures
    # bit for bit with ray noise, the default; with noise along the normal the vectorised arithmetic rounds the
    # last bit of a plane differently).
    flat = sorted_pts.reshape(-1)
    for j in range(a, b):
        j3 = np.uint64(3 * j)
        uk = np.uint64(j - a)
        px = np.float64(flat[j3])
        py = np.float64(flat[j3 + np.uint64(1)])
        pz = np.float64(flat[j3 + np.uint64(2)])
        npd = nx * px + ny * py + nz * pz
        zz = pz if pz > MIN_DEPTH else MIN_DEPTH
        g = zz / _sigma_z(zz, power, coeff)  # 1 / sigma_z in depth units per metre of depth
        an = abs(npd)
        lo = MIN_INCIDENCE * zz
        den = (an if an > lo else lo) if ray_mode else zz
        u = abs(npd + d) * g / den
        scratch[0, uk] = u
        scratch[1, uk] = g
        # float64 copies for the sums below (contiguous rows, not strided float32 loads again)
        scratch[3, uk] = px
        scratch[4, uk] = py
        scratch[5, uk] = pz
    inv_b2 = 1.0 / (bq * bq)
    n_pos = 0
    for j in range(a, b):
        uk = np.uint64(j - a)
        u = scratch[0, uk]
        inside = u <= bq
        n_in += 1 if inside else 0
        point_plane[np.uint64(j)] = q if inside else -1
        # Tukey's weight base, stored so that the sums below see the same value that was counted here.
        t = 1.0 - u * u * inv_b2
        t = t if t > 0.0 else 0.0
        n_pos += 1 if t > 0.0 else 0
        scratch[2, uk] = t
    rx = refs[q, 0]
    ry = refs[q, 1]
    rz = refs[q, 2]
    if n_in == b - a and n_pos == b - a:
        _weighted_sums_only(sorted_pts, a, b, q, ray_mode, use_noise, rx, ry, rz, acc_w, acc_s, acc_S, scratch)
        # Plain sums from the voxel's moments: about the origin for acc_sum, about refs[q] for sup.
        n = np.float64(counts[v])
        sx = sums[v, 0]
        sy = sums[v, 1]
        sz = sums[v, 2]
        acc_n[q] += counts[v]
        acc_sum[q, 0] += sx
        acc_sum[q, 1] += sy
        acc_sum[q, 2] += sz
        sup[q, 0] += n
        sup[q, 1] += sx - n * rx
        sup[q, 2] += sy - n * ry
        sup[q, 3] += sz - n * rz
        sup[q, 4] += scatters[v, 0, 0] - 2.0 * rx * sx + n * rx * rx
        sup[q, 5] += scatters[v, 0, 1] - rx * sy - ry * sx + n * rx * ry
        sup[q, 6] += scatters[v, 0, 2] - rx * sz - rz * sx + n * rx * rz
        sup[q, 7] += scatters[v, 1, 1] - 2.0 * ry * sy + n * ry * ry
        sup[q, 8] += scatters[v, 1, 2] - ry * sz - rz * sy + n * ry * rz
        sup[q, 9] += scatters[v, 2, 2] - 2.0 * rz * sz + n * rz * rz
        return n_in
    W = s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = 0.0
    c0 = c1 = c2 = cn = 0.0
    h0 = h1 = h2 = h3 = h4 = h5 = h6 = h7 = h8 = h9 = 0.0
    for j in range(a, b):
        px = scratch[3, j - a]
        py = scratch[4, j - a]
        pz = scratch[5, j - a]
        u = scratch[0, j - a]
        t = scratch[2, j - a]
        w = t * t
        if use_noise:
            zz = pz if pz > MIN_DEPTH else MIN_DEPTH
            g = scratch[1, j - a]
            w *= g * g if ray_mode else g * g / (zz * zz)
        x = px - rx
        y = py - ry
        z = pz - rz
        W += w
        s0 += w * x
        s1 += w * y
        s2 += w * z
        s3 += w * x * x
        s4 += w * x * y
        s5 += w * x * z
        s6 += w * y * y
        s7 += w * y * z
        s8 += w * z * z
        f = 1.0 if t > 0.0 else 0.0
        cn += f
        c0 += f * px
        c1 += f * py
        c2 += f * pz
        # Plain statistics of the supporting points (about the same reference).
        h = 1.0 if u <= bq else 0.0
        h0 += h
        h1 += h * x
        h2 += h * y
        h3 += h * z
        h4 += h * x * x
        h5 += h * x * y
        h6 += h * x * z
        h7 += h * y * y
        h8 += h * y * z
        h9 += h * z * z
    sup[q, 0] += h0
    sup[q, 1] += h1
    sup[q, 2] += h2
    sup[q, 3] += h3
    sup[q, 4] += h4
    sup[q, 5] += h5
    sup[q, 6] += h6
    sup[q, 7] += h7
    sup[q, 8] += h8
    sup[q, 9] += h9
    acc_w[q] += W
    acc_s[q, 0] += s0
    acc_s[q, 1] += s1
    acc_s[q, 2] += s2
    acc_S[q, 0, 0] += s3
    acc_S[q, 0, 1] += s4
    acc_S[q, 0, 2] += s5
    acc_S[q, 1, 1] += s6
    acc_S[q, 1, 2] += s7
    acc_S[q, 2, 2] += s8
    acc_n[q] += int(cn)
    acc_sum[q, 0] += c0
    acc_sum[q, 1] += c1
    acc_sum[q, 2] += c2
    return n_in


@njit(error_model="numpy")
def _gather_points(sorted_pts, point_bits, step, by_order, a, b, scratch):
    """The points of a voxel (``step`` 1), or about 1 in ``step`` of them (as :func:`_subsample_voxel`), as float64
    rows ``scratch[0:3]`` (x, y, z); returns how many."""
    k = 0
    if step == 1:
        flat = sorted_pts.reshape(-1)
        for j in range(a, b):
            j3 = np.uint64(3 * j)
            uk = np.uint64(j - a)
            scratch[0, uk] = flat[j3]
            scratch[1, uk] = flat[j3 + np.uint64(1)]
            scratch[2, uk] = flat[j3 + np.uint64(2)]
        return b - a
    for j in range(a, b, step if by_order else 1):
        if not by_order and not _keep(point_bits, j, step):
            continue
        scratch[0, k] = sorted_pts[j, 0]
        scratch[1, k] = sorted_pts[j, 1]
        scratch[2, k] = sorted_pts[j, 2]
        k += 1
    return k


@njit(error_model="numpy")
def _nearest_candidates(scratch, mloc, cand, nc, planes, band, power, coeff, ray_mode):
    """For the ``mloc`` points in ``scratch[0:3]``: ``g = z / sigma_z`` (row 3), per candidate ``k`` the signed depth
    error over sigma ``e_k`` (row ``SCR_E + k``), and the nearest candidate within its band (row 5, -1 for none)
    with its distance ``u`` in sigmas (row 4, inf for none). Loops over points without a branch (they vectorise);
    ties go to the first candidate, as a scalar scan over the candidates would."""
    for i in range(mloc):
        zz = scratch[2, i]
        zz = zz if zz > MIN_DEPTH else MIN_DEPTH
        scratch[3, i] = zz / _sigma_z(zz, power, coeff)
        scratch[4, i] = np.inf
        scratch[5, i] = -1.0
    for k in range(nc):
        q = cand[k]
        nx = planes[q, 0]
        ny = planes[q, 1]
        nz = planes[q, 2]
        d = planes[q, 3]
        bq = band[q]
        kf = np.float64(k)
        row = SCR_E + k
        for i in range(mloc):
            px = scratch[0, i]
            py = scratch[1, i]
            pz = scratch[2, i]
            zz = pz if pz > MIN_DEPTH else MIN_DEPTH
            g = scratch[3, i]
            npd = nx * px + ny * py + nz * pz
            r = npd + d
            lo = MIN_INCIDENCE * zz
            den = npd if abs(npd) >= lo else (lo if npd >= 0.0 else -lo)
            e = r * g / den
            scratch[row, i] = e
            u = abs(e) if ray_mode else abs(r) * g / zz
            better = u <= bq and u < scratch[4, i]
            scratch[4, i] = u if better else scratch[4, i]
            scratch[5, i] = kf if better else scratch[5, i]


@njit(error_model="numpy")
def _multi_plane_voxel(sorted_pts, point_bits, step, by_order, a, b, cand, nc, planes, band, power, coeff, ray_mode,
                       point_plane, accumulate, use_noise, cos_corner, refs, acc_w, acc_s, acc_S, acc_n, acc_sum,
                       acc_amb, sup, scratch, parallel, n_of):
    """:func:`assign_points` for a voxel with several candidate planes (all its points, or about 1 in ``step`` of
    them for a cheap refit pass, which assigns nothing). In phases over a float64 copy of the points in ``scratch``
    (``SCRATCH_ROWS``, >= b - a): the nearest candidate of every point (:func:`_nearest_candidates`, vectorised),
    whether it is near a corner (from the stored depth errors, candidate pair by pair, vectorised), then per
    candidate the masked sums of its points (:func:`_masked_sums`, vectorised; skipped for a candidate nearest to
    none of them). ``parallel`` (MAX_CANDIDATES, MAX_CANDIDATES) bool and ``n_of`` (MAX_CANDIDATES,) int64 scratch
    (1 where a candidate is some point's nearest).
    Returns the number of points assigned."""
    mloc = _gather_points(sorted_pts, point_bits, step, by_order, a, b, scratch)
    _nearest_candidates(scratch, mloc, cand, nc, planes, band, power, coeff, ray_mode)
    if accumulate:
        # Candidates within the corner angle (``cos_corner``) are pieces of one surface (fragments that merge
        # later), not a corner.
        for k in range(nc):
            for o in range(nc):
                q = cand[k]
                c = cand[o]
                parallel[k, o] = (planes[c, 0] * planes[q, 0] + planes[c, 1] * planes[q, 1]
                                  + planes[c, 2] * planes[q, 2]) > cos_corner
    n_in = 0
    for i in range(mloc):
        n_in += 1 if scratch[5, np.uint64(i)] >= 0.0 else 0
    if step == 1:
        for i in range(mloc):
            c = scratch[5, np.uint64(i)]
            point_plane[np.uint64(a + i)] = cand[np.uint64(max(c, 0.0))] if c >= 0.0 else -1
    if not accumulate:
        return n_in
    # Corner points, candidate pair by candidate pair in loops over the points that vectorise: a point nearest to
    # candidate ``bb`` is at a corner when another, non-parallel candidate meets its pixel ray within
    # CORNER_BANDS bands (of ``bb``) of where ``bb`` does. Its code is then shifted past the candidates.
    for bb in range(nc):
        bf = np.float64(bb)
        shifted = np.float64(bb + MAX_CANDIDATES + 1)
        lim = CORNER_BANDS * band[cand[bb]]
        row_b = np.uint64(SCR_E + bb)
        hits = 0
        n_mine = 0
        for k in range(nc):
            if k == bb or parallel[bb, k]:
                continue
            row_k = np.uint64(SCR_E + k)
            for i in range(mloc):
                ui = np.uint64(i)
                hit = (scratch[5, ui] == bf) & (abs(scratch[row_k, ui] - scratch[row_b, ui]) < lim)
                scratch[5, ui] = shifted if hit else scratch[5, ui]
                hits += 1 if hit else 0
        acc_amb[cand[bb]] += hits
        for i in range(mloc):
            c = scratch[5, np.uint64(i)]
            n_mine += 1 if (c == bf) | (c == shifted) else 0
        n_of[bb] = 1 if n_mine > 0 else 0
    for k in range(nc):
        if n_of[k] == 0:  # no point is nearest to this candidate: nothing to sum
            continue
        q = cand[k]
        bq = band[q]
        inv_b2 = 1.0 / (bq * bq)
        rx = refs[q, 0]
        ry = refs[q, 1]
        rz = refs[q, 2]
        W, s0, s1, s2, s3, s4, s5, s6, s7, s8, c0, c1, c2, cn, h = _masked_sums(
            scratch, mloc, k, inv_b2, rx, ry, rz, ray_mode, use_noise)
        acc_w[q] += W
        acc_s[q, 0] += s0
        acc_s[q, 1] += s1
        acc_s[q, 2] += s2
        acc_S[q, 0, 0] += s3
        acc_S[q, 0, 1] += s4
        acc_S[q, 0, 2] += s5
        acc_S[q, 1, 1] += s6
        acc_S[q, 1, 2] += s7
        acc_S[q, 2, 2] += s8
        acc_n[q] += int(cn)
        acc_sum[q, 0] += c0
        acc_sum[q, 1] += c1
        acc_sum[q, 2] += c2
        if step == 1:
            for i in range(10):
                sup[q, i] += h[i]
    return n_in


@njit(fastmath={"reassoc", "contract"}, error_model="numpy")
def _masked_sums(scratch, mloc, k, inv_b2, rx, ry, rz, ray_mode, use_noise):
    """Refit and support sums of the points whose nearest candidate is ``k`` (see :func:`_multi_plane_voxel`:
    ``scratch`` rows x, y, z, ``g``, ``u``, the candidate (``+ MAX_CANDIDATES + 1`` at a corner)); corner points
    count for the support, not for the refit."""
    W = s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = 0.0
    c0 = c1 = c2 = cn = 0.0
    h0 = h1 = h2 = h3 = h4 = h5 = h6 = h7 = h8 = h9 = 0.0
    kf = np.float64(k)
    kc = np.float64(k + MAX_CANDIDATES + 1)
    for i in range(mloc):
        code = scratch[5, i]
        fit = 1.0 if code == kf else 0.0
        mine = fit + (1.0 if code == kc else 0.0)
        px = scratch[0, i]
        py = scratch[1, i]
        pz = scratch[2, i]
        u = scratch[4, i]
        u = u if mine > 0.0 else 0.0  # u is inf where the point has no plane
        t = 1.0 - u * u * inv_b2
        t = t if t > 0.0 else 0.0
        w = t * t * fit
        if use_noise:
            zz = pz if pz > MIN_DEPTH else MIN_DEPTH
            g = scratch[3, i]
            w *= g * g if ray_mode else g * g / (zz * zz)
        x = px - rx
        y = py - ry
        z = pz - rz
        W += w
        s0 += w * x
        s1 += w * y
        s2 += w * z
        s3 += w * x * x
        s4 += w * x * y
        s5 += w * x * z
        s6 += w * y * y
        s7 += w * y * z
        s8 += w * z * z
        f = fit if t > 0.0 else 0.0
        cn += f
        c0 += f * px
        c1 += f * py
        c2 += f * pz
        h0 += mine
        h1 += mine * x
        h2 += mine * y
        h3 += mine * z
        h4 += mine * x * x
        h5 += mine * x * y
        h6 += mine * x * z
        h7 += mine * y * y
        h8 += mine * y * z
        h9 += mine * z * z
    return W, s0, s1, s2, s3, s4, s5, s6, s7, s8, c0, c1, c2, cn, (h0, h1, h2, h3, h4, h5, h6, h7, h8, h9)


@njit(error_model="numpy")
def _reachable(v, nc, cand, own, counts, sums, scatters, planes, band, power, coeff):
    """Keep in ``cand[:nc]`` the voxel's own plane and the planes that can reach its points (see
    :func:`assign_points`); returns how many are left."""
    n = counts[v]
    cx = sums[v, 0] / n
    cy = sums[v, 1] / n
    cz = sums[v, 2] / n
    sz = _sigma_z(max(cz, MIN_DEPTH), power, coeff)
    k = 0
    for i in range(nc):
        q = cand[i]
        if q != own:
            nx = planes[q, 0]
            ny = planes[q, 1]
            nz = planes[q, 2]
            S = scatters[v]
            var = ((nx * (S[0, 0] * nx + S[0, 1] * ny + S[0, 2] * nz) + ny * (S[1, 0] * nx + S[1, 1] * ny + S[1, 2] * nz)
                    + nz * (S[2, 0] * nx + S[2, 1] * ny + S[2, 2] * nz)) / n
                   - (nx * cx + ny * cy + nz * cz) ** 2)
            dist = abs(nx * cx + ny * cy + nz * cz + planes[q, 3])
            if dist > 3.0 * math.sqrt(max(var, 0.0)) + band[q] * sz + 0.02:
                continue
        cand[k] = q
        k += 1
    return k


@njit(error_model="numpy")
def assign_points(sorted_pts, point_bits, step, by_order, voxel_start, nv, voxel_key, box, dense, cellmap, tkeys,
                  tvals,
                  counts, sums, scatters, plane_of_voxel, planes, band, power, coeff, ray_mode, refine_boundary,
                  point_plane, accumulate, use_noise, cos_corner, refs, acc_w, acc_s, acc_S, acc_n, acc_sum, acc_amb,
                  sup, scratch):
    """Plane of every point (sorted order) into ``point_plane`` (-1 for none); returns the number assigned.

    Per point and candidate plane ``q``: the signed depth error over the depth sigma, ``e_q = z r_q / (n_q . p)
    / sigma_z`` (``r_q`` the distance to the plane; ``z - e_q sigma_z`` is where the point's pixel ray meets the
    plane). The distance in sigmas is ``u_q = |e_q|`` for ray noise and ``|r_q| / sigma_z`` for noise along the
    normal. A point supports the candidate with the smallest ``u`` when within that plane's ``band``. The
    candidates of a voxel are its own plane and, with ``refine_boundary``, the planes of its 26 neighbours (so
    points of corner, edge and sparse voxels, and points pushed across a voxel face by the noise, find their
    plane).

    With ``accumulate``, also sums per plane the moments about ``refs[p]`` (P, 3) of its points weighted by Tukey's
    biweight of width ``band`` (times the inverse-variance weight with ``use_noise``): ``acc_w`` (P,), ``acc_s``
    (P, 3), ``acc_S`` (P, 3, 3), with ``acc_n`` (P,) the points of non-zero weight and ``acc_sum`` (P, 3) their
    plain sum; ``sup`` (P, 10) the plain moments ``[n, s (3), S (6 upper)]`` about ``refs`` of the supporting
    points (those assigned to the plane); all zeroed here. Near the intersection of two planes the noise decides which one a point looks
    closest to, so keeping every point for its nearest plane would cut each plane's noise one-sidedly there and
    tilt it. A point is left out of the refit (and counted in ``acc_amb``) when its pixel ray meets another,
    non-parallel candidate (normals further apart than ``acos(cos_corner)``) within ``CORNER_BANDS`` bands of where
    it meets its own (``|e_q - e_o|`` small): that uses the noise-free ray, not the noisy depth, so it truncates
    nothing.

    A neighbour's plane is a candidate only where it can reach the voxel's points: its distance to the voxel
    centroid at most 3 standard deviations of the points along its normal (from the voxel's moments ``counts``,
    ``sums``, ``scatters``) plus its band (in depth sigmas at the centroid) and 2 cm.

    ``step > 1`` (a power of two, with ``accumulate``) is a cheap refit pass: only about 1 in ``step`` points, every
    ``step``-th of each voxel with ``by_order`` (a depth image's fixed raster order), else chosen by a hash of their
    coordinates (``point_bits`` = ``sorted_pts`` viewed as int32) so that the order of a point cloud does not matter;
    ``point_plane`` is not written. ``scratch`` (``SCRATCH_ROWS``, >= the largest voxel) float64.
    """
    cand = np.empty(MAX_CANDIDATES, np.int64)
    parallel = np.empty((MAX_CANDIDATES, MAX_CANDIDATES), np.bool_)
    n_of = np.empty(MAX_CANDIDATES, np.int64)
    n_planes = planes.shape[0]
    if accumulate:
        for p in range(n_planes):
            acc_w[p] = 0.0
            acc_n[p] = 0
            acc_amb[p] = 0
            for i in range(10):
                sup[p, i] = 0.0
            for i in range(3):
                acc_s[p, i] = 0.0
                acc_sum[p, i] = 0.0
                for k in range(3):
                    acc_S[p, i, k] = 0.0
    n_assigned = 0
    for v in range(nv):
        a = voxel_start[v]
        b = voxel_start[v + 1]
        nc = _candidates(v, voxel_key, box, dense, cellmap, tkeys, tvals, plane_of_voxel, refine_boundary, cand)
        if nc > 1 or (nc == 1 and plane_of_voxel[v] < 0):
            nc = _reachable(v, nc, cand, plane_of_voxel[v], counts, sums, scatters, planes, band, power, coeff)
        if nc == 0:
            for j in range(a, b):
                point_plane[j] = -1
            continue
        if nc == 1:
            if step > 1:
                _subsample_voxel(sorted_pts, point_bits, step, by_order, a, b, cand[0], planes, band, power, coeff,
                                 ray_mode, use_noise, refs, acc_w, acc_s, acc_S, acc_n, acc_sum, scratch)
                continue
            if not accumulate:
                n_assigned += _single_plane_assign(sorted_pts, a, b, cand[0], planes, band, power, coeff, ray_mode,
                                                   point_plane, scratch)
                continue
            n_assigned += _single_plane_voxel(sorted_pts, v, a, b, cand[0], planes, band, power, coeff, ray_mode,
                                              point_plane, accumulate, use_noise, refs, counts, sums, scatters,
                                              acc_w, acc_s, acc_S, acc_n, acc_sum, sup, scratch)
            continue
        n_assigned += _multi_plane_voxel(sorted_pts, point_bits, step, by_order, a, b, cand, nc, planes, band, power,
                                         coeff, ray_mode, point_plane, accumulate, use_noise, cos_corner, refs, acc_w,
                                         acc_s, acc_S, acc_n, acc_sum, acc_amb, sup, scratch, parallel, n_of)
    if accumulate:
        for p in range(n_planes):
            acc_S[p, 1, 0] = acc_S[p, 0, 1]
            acc_S[p, 2, 0] = acc_S[p, 0, 2]
            acc_S[p, 2, 1] = acc_S[p, 1, 2]
    return n_assigned


@njit(error_model="numpy")
def solve_planes(acc_w, acc_s, acc_S, refs, ray_mode, planes, wmom, wscat):
    """Refit every plane with a positive weight from moments about ``refs``: ``planes`` (P, 4) updated (normal
    toward the sensor), moments moved to the origin into ``wmom`` (P, 4) ``[W, sum w p]`` and ``wscat`` (P, 3, 3)."""
    A = np.empty((3, 3))
    w3 = np.empty(3)
    V = np.empty((3, 3))
    for p in range(planes.shape[0]):
        W = acc_w[p]
        if not W > 0.0:
            continue
        nx, ny, nz, d, _l0, _l1, _l2 = solve_plane(W, acc_s[p], acc_S[p], refs[p], ray_mode, A, w3, V)
        if d < 0.0:
            nx, ny, nz, d = -nx, -ny, -nz, -d
        planes[p, 0] = nx
        planes[p, 1] = ny
        planes[p, 2] = nz
        planes[p, 3] = d
        wmom[p, 0] = W
        for i in range(3):
            wmom[p, 1 + i] = acc_s[p, i] + W * refs[p, i]
            for k in range(3):
                wscat[p, i, k] = (acc_S[p, i, k] + acc_s[p, i] * refs[p, k] + refs[p, i] * acc_s[p, k]
                                  + W * refs[p, i] * refs[p, k])


@njit(error_model="numpy")
def refine_keep(acc_w, acc_s, acc_S, refs, ray_mode, planes, wmoments, wscatters, acc_n, acc_amb, acc_sum, counts,
                sums, n_eff, radius_bound, plane_of_voxel, old_to_kept, k_planes, k_wmom, k_wscat, k_counts, k_sums,
                k_neff, k_radius, k_plane_of_voxel):
    """The refinement pass's planes kept: every plane with a positive weight refit (:func:`solve_planes`, ``planes``
    updated in place; the weighted moments ``wmoments`` / ``wscatters`` of the others kept), then the planes that
    are not a bevel (``acc_amb <= acc_n``) copied in order into the ``k_*`` outputs (>= P rows), those that kept
    more than 3 points with the pass's ``acc_n`` as count and effective count and ``acc_sum`` as sum, the others
    with their ``counts``, ``n_eff``, ``sums``; ``radius_bound`` as it was. ``old_to_kept`` (P,) receives each
    plane's kept index (-1 for a bevel) and ``k_plane_of_voxel`` (V,) the voxels' planes renumbered so (-1 stays
    -1). Returns the number of planes kept."""
    n = planes.shape[0]
    wmom = wmoments.copy()
    wscat = wscatters.copy()
    solve_planes(acc_w, acc_s, acc_S, refs, ray_mode, planes, wmom, wscat)
    nk = 0
    for p in range(n):
        if acc_amb[p] > acc_n[p]:
            old_to_kept[p] = -1
            continue
        old_to_kept[p] = nk
        kept = acc_n[p] > 3
        for i in range(4):
            k_planes[nk, i] = planes[p, i]
            k_wmom[nk, i] = wmom[p, i]
        for i in range(3):
            k_sums[nk, i] = acc_sum[p, i] if kept else sums[p, i]
            for j in range(3):
                k_wscat[nk, i, j] = wscat[p, i, j]
        k_counts[nk] = acc_n[p] if kept else counts[p]
        k_neff[nk] = acc_n[p] if kept else n_eff[p]
        k_radius[nk] = radius_bound[p]
        nk += 1
    for v in range(plane_of_voxel.shape[0]):
        g = plane_of_voxel[v]
        k_plane_of_voxel[v] = old_to_kept[g] if g >= 0 else -1
    return nk


@njit(error_model="numpy")
def plane_minor_widths(planes, plane_of_voxel, counts, sums, scatters, widths):
    """Width of each plane across its shorter in-plane axis: ``sqrt(12 l)`` with ``l`` the smaller in-plane
    eigenvalue of the covariance of the points of its voxels (from the voxels' moments ``counts``, ``sums``,
    ``scatters`` about the origin; the width of a uniform strip). A bevel made by voxels holding two surfaces is a
    strip about one voxel wide along their corner; a wall is not. ``widths`` (P,) float64; 0 for a plane without
    voxels."""
    n_planes = planes.shape[0]
    acc = np.zeros((n_planes, 10))
    for v in range(plane_of_voxel.shape[0]):
        p = plane_of_voxel[v]
        if p < 0:
            continue
        acc[p, 0] += counts[v]
        acc[p, 1] += sums[v, 0]
        acc[p, 2] += sums[v, 1]
        acc[p, 3] += sums[v, 2]
        acc[p, 4] += scatters[v, 0, 0]
        acc[p, 5] += scatters[v, 0, 1]
        acc[p, 6] += scatters[v, 0, 2]
        acc[p, 7] += scatters[v, 1, 1]
        acc[p, 8] += scatters[v, 1, 2]
        acc[p, 9] += scatters[v, 2, 2]
    for p in range(n_planes):
        n = acc[p, 0]
        if n <= 0.0:
            widths[p] = 0.0
            continue
        mx = acc[p, 1] / n
        my = acc[p, 2] / n
        mz = acc[p, 3] / n
        cxx = acc[p, 4] / n - mx * mx
        cxy = acc[p, 5] / n - mx * my
        cxz = acc[p, 6] / n - mx * mz
        cyy = acc[p, 7] / n - my * my
        cyz = acc[p, 8] / n - my * mz
        czz = acc[p, 9] / n - mz * mz
        t1x, t1y, t1z, t2x, t2y, t2z = tangent_basis(planes[p, 0], planes[p, 1], planes[p, 2])
        # C t1 and C t2, then the 2 x 2 in-plane covariance [[a, b], [b, c]].
        u0 = cxx * t1x + cxy * t1y + cxz * t1z
        u1 = cxy * t1x + cyy * t1y + cyz * t1z
        u2 = cxz * t1x + cyz * t1y + czz * t1z
        w0 = cxx * t2x + cxy * t2y + cxz * t2z
        w1 = cxy * t2x + cyy * t2y + cyz * t2z
        w2 = cxz * t2x + cyz * t2y + czz * t2z
        a = t1x * u0 + t1y * u1 + t1z * u2
        b = t2x * u0 + t2y * u1 + t2z * u2
        c = t2x * w0 + t2y * w1 + t2z * w2
        lam = 0.5 * (a + c) - math.sqrt(0.25 * (a - c) * (a - c) + b * b)
        widths[p] = math.sqrt(12.0 * max(lam, 0.0))


@njit(error_model="numpy")
def compose_table(old_to_kept, kept_to_final, table):
    """``table[p] = kept_to_final[old_to_kept[p]]`` (-1 where ``old_to_kept`` is -1)."""
    for p in range(old_to_kept.shape[0]):
        k = old_to_kept[p]
        table[p] = kept_to_final[k] if k >= 0 else -1


@njit(error_model="numpy")
def plane_grids(planes, plane_of_voxel, nv, counts, sums, pad, area_cell, sample_cell, tb, area_grid, sample_grid):
    """In-plane grids of every plane, sized from its voxels (no pass over the points).

    ``tb`` (P, 6) receives each plane's tangent basis ``(t1, t2)``. A supporting point lies in one of the plane's
    voxels or in a 26-neighbour of one, so within ``pad`` (3.5 voxel edges) of a voxel centroid: the grids cover
    the voxel centroids' in-plane bounds plus ``pad``. ``area_grid`` / ``sample_grid`` (P, 4) int64 get the first
    cell ``(iu0, iv0)`` and the size ``(nu, nv)`` for cells of ``area_cell`` / ``sample_cell``. Returns the total
    cell counts ``(n_area, n_sample)``.
    """
    n_planes = planes.shape[0]
    box = np.empty((n_planes, 4))
    for p in range(n_planes):
        t1x, t1y, t1z, t2x, t2y, t2z = tangent_basis(planes[p, 0], planes[p, 1], planes[p, 2])
        tb[p, 0] = t1x
        tb[p, 1] = t1y
        tb[p, 2] = t1z
        tb[p, 3] = t2x
        tb[p, 4] = t2y
        tb[p, 5] = t2z
        box[p, 0] = np.inf
        box[p, 1] = -np.inf
        box[p, 2] = np.inf
        box[p, 3] = -np.inf
    for v in range(nv):
        p = plane_of_voxel[v]
        if p < 0:
            continue
        cx = sums[v, 0] / counts[v]
        cy = sums[v, 1] / counts[v]
        cz = sums[v, 2] / counts[v]
        u = tb[p, 0] * cx + tb[p, 1] * cy + tb[p, 2] * cz
        w = tb[p, 3] * cx + tb[p, 4] * cy + tb[p, 5] * cz
        box[p, 0] = min(box[p, 0], u)
        box[p, 1] = max(box[p, 1], u)
        box[p, 2] = min(box[p, 2], w)
        box[p, 3] = max(box[p, 3], w)
    n_area = 0
    n_sample = 0
    for p in range(n_planes):
        if not box[p, 1] >= box[p, 0]:
            for k in range(4):
                area_grid[p, k] = 0
                sample_grid[p, k] = 0
            continue
        for grid, cell in ((area_grid, area_cell), (sample_grid, sample_cell)):
            i0 = int(math.floor((box[p, 0] - pad) / cell))
            j0 = int(math.floor((box[p, 2] - pad) / cell))
            grid[p, 0] = i0
            grid[p, 1] = j0
            grid[p, 2] = int(math.floor((box[p, 1] + pad) / cell)) - i0 + 1
            grid[p, 3] = int(math.floor((box[p, 3] + pad) / cell)) - j0 + 1
        n_area += area_grid[p, 2] * area_grid[p, 3]
        n_sample += sample_grid[p, 2] * sample_grid[p, 3]
    return n_area, n_sample


@njit(error_model="numpy")
def plane_order(counts, sums, min_points, area_grid, sample_grid, centroids, area_off, sample_off, order, remap):
    """Before :func:`plane_extent`: the offsets of each plane's cells (``area_off`` / ``sample_off`` (P + 1,), from
    the grids' sizes), the centroids ``sums / max(counts, 1)``, and the planes with at least ``min_points`` points
    in ``order`` (most points first, ties by index: a stable sort) with ``remap`` (P,) their rank (-1 for the
    others). Returns how many are in ``order``."""
    n = counts.shape[0]
    area_off[0] = 0
    sample_off[0] = 0
    for p in range(n):
        area_off[p + 1] = area_off[p] + area_grid[p, 2] * area_grid[p, 3]
        sample_off[p + 1] = sample_off[p] + sample_grid[p, 2] * sample_grid[p, 3]
        c = max(counts[p], 1)
        for i in range(3):
            centroids[p, i] = sums[p, i] / c
        remap[p] = -1
    k = 0
    for p in range(n):
        if counts[p] >= min_points:
            j = k
            while j > 0 and counts[order[j - 1]] < counts[p]:
                order[j] = order[j - 1]
                j -= 1
            order[j] = p
            k += 1
    for i in range(k):
        remap[order[i]] = i
    return k


@njit(error_model="numpy")
def keep_planes(order, n_order, areas, min_area, remap, keep, final):
    """After :func:`plane_extent`: the planes of ``order[:n_order]`` with an area of at least ``min_area``, in that
    order, into ``keep``; ``final`` (n_order,) maps each rank of ``remap`` to its index among them (-1: dropped).
    Returns how many are kept."""
    nk = 0
    for i in range(n_order):
        final[i] = -1
    for i in range(n_order):
        p = order[i]
        if areas[p] >= min_area:
            keep[nk] = p
            final[remap[p]] = nk
            nk += 1
    return nk


@njit(error_model="numpy")
def gather_planes(keep, nk, planes, centroids, counts, radii, areas, covariances, sums, scatters, normals_out,
                  offsets_out, centroids_out, counts_out, radii_out, areas_out, covariances_out, sums_out,
                  scatters_out):
    """The rows ``keep[:nk]`` of the plane statistics copied into the ``*_out`` arrays (``planes`` split into
    normals and offsets)."""
    for i in range(nk):
        p = keep[i]
        for k in range(3):
            normals_out[i, k] = planes[p, k]
            centroids_out[i, k] = centroids[p, k]
            sums_out[i, k] = sums[p, k]
            for j in range(3):
                scatters_out[i, k, j] = scatters[p, k, j]
        offsets_out[i] = planes[p, 3]
        counts_out[i] = counts[p]
        radii_out[i] = radii[p]
        areas_out[i] = areas[p]
        for k in range(4):
            for j in range(4):
                covariances_out[i, k, j] = covariances[p, k, j]


@njit(error_model="numpy")
def plane_stats(sorted_pts, point_plane, m, counts, sums, scatters):
    """Count, sum and scatter (about the origin) of each plane's supporting points; outputs zeroed here."""
    for p in range(counts.shape[0]):
        counts[p] = 0
        sums[p, :] = 0.0
        scatters[p, :, :] = 0.0
    for j in range(m):
        p = point_plane[j]
        if p < 0:
            continue
        x = np.float64(sorted_pts[j, 0])
        y = np.float64(sorted_pts[j, 1])
        z = np.float64(sorted_pts[j, 2])
        counts[p] += 1
        sums[p, 0] += x
        sums[p, 1] += y
        sums[p, 2] += z
        scatters[p, 0, 0] += x * x
        scatters[p, 0, 1] += x * y
        scatters[p, 0, 2] += x * z
        scatters[p, 1, 1] += y * y
        scatters[p, 1, 2] += y * z
        scatters[p, 2, 2] += z * z
    for p in range(counts.shape[0]):
        scatters[p, 1, 0] = scatters[p, 0, 1]
        scatters[p, 2, 0] = scatters[p, 0, 2]
        scatters[p, 2, 1] = scatters[p, 1, 2]


@njit(fastmath={"contract"}, error_model="numpy", inline="always")
def _extent_point(flat, j3, acc, cx, cy, cz, t0, t1, t2, t3, t4, t5, inv_s, s0, s1, sn, sv, so):
    """One supporting point of :func:`plane_extent`: its sample cell's sums updated; returns its squared distance
    from the plane's centroid and its in-plane coordinates ``(u, v)``."""
    x = np.float64(flat[j3])
    y = np.float64(flat[j3 + np.uint64(1)])
    z = np.float64(flat[j3 + np.uint64(2)])
    dx = x - cx
    dy = y - cy
    dz = z - cz
    u = t0 * x + t1 * y + t2 * z
    v = t3 * x + t4 * y + t5 * z
    # Offsets from the grid corner are >= 0 inside the grid, where int() is floor().
    iu = min(max(int(u * inv_s - s0), 0), sn - 1)
    iv = min(max(int(v * inv_s - s1), 0), sv - 1)
    c4 = np.uint64(4 * (so + iu * sv + iv))
    acc[c4] += 1.0
    acc[c4 + np.uint64(1)] += x
    acc[c4 + np.uint64(2)] += y
    acc[c4 + np.uint64(3)] += z
    return dx * dx + dy * dy + dz * dz, u, v


@njit(fastmath={"contract"}, error_model="numpy")
def plane_extent(sorted_pts, point_plane, table, m, centroids, tb, area_cell, area_grid, area_off, occupied,
                 sample_cell, sample_grid, sample_off, sample_acc, radii, areas, with_labels, sorted_src, src_is_pixel,
                 pix, remap, width, height, stride, labels):
    """One pass over the supporting points (point ``j`` on plane ``table[point_plane[j]]``, none where either is
    -1: the refinement's assignment renumbered here, not in a pass of its own): radius of each plane (largest
    distance from its centroid), its occupied
    ``area_cell`` squares (``areas`` = their number times ``area_cell^2``), per-cell point sums for the samples
    (``sample_acc`` rows ``[n, sx, sy, sz]``) and, ``with_labels``, the label image (H * W,) int32: ``remap[plane]``
    at the pixel of every supporting point (the whole ``stride x stride`` block it stands for), -1 elsewhere.

    Grids from :func:`plane_grids` (``tb`` the tangent bases), ``area_off`` / ``sample_off`` (P + 1,) the offsets of
    each plane's cells into ``occupied`` (uint8) / ``sample_acc``; outputs zeroed here. The pixel of point ``j`` is
    ``sorted_src[j]`` itself with ``src_is_pixel`` (a grid made from the image), else ``pix[sorted_src[j]]``. The grids contain every
    supporting point by construction; a point outside would be clamped to the border cell. Fused multiply-adds
    (``fastmath`` contract: 10 % faster) move the in-plane coordinates by an ulp, not a point across a cell border
    in practice.
    """
    n_planes = tb.shape[0]
    for p in range(n_planes):
        radii[p] = 0.0
    occupied[: area_off[n_planes]] = 0
    sample_acc[: sample_off[n_planes], :] = 0.0
    if with_labels:
        labels[:] = -1
    # With the same cells for the area and the samples (the defaults), a cell is occupied when it has a sample.
    same = area_cell == sample_cell
    for p in range(n_planes):
        for k in range(4):
            same = same and area_grid[p, k] == sample_grid[p, k]
    # A depth image's points at every pixel with the default cells: a loop of its own, with no test of these
    # settings per point (the compiler does not take them out of the loop: 1.7 -> 1.1 ms per 640x480 frame).
    image = with_labels and src_is_pixel and stride == 1 and same
    inv_a = 1.0 / area_cell
    inv_s = 1.0 / sample_cell
    # Flat views (``sorted_pts`` and ``sample_acc`` C-contiguous) and unsigned indices: no stride products and no
    # test for an index from the end in the loop over the points (15 % faster).
    flat = sorted_pts.reshape(-1)
    acc = sample_acc.reshape(-1)
    # The points come voxel by voxel, so a plane's points come in runs of one id in ``point_plane``: the run's
    # plane is looked up once, its constants stay in registers and its largest squared distance in one.
    j = 0
    while j < m:
        raw = point_plane[np.uint64(j)]
        p = table[np.uint64(raw)] if raw >= 0 else -1
        k = j + 1
        if p < 0:
            while k < m and point_plane[np.uint64(k)] == raw:
                k += 1
            j = k
            continue
        cx, cy, cz = centroids[p, 0], centroids[p, 1], centroids[p, 2]
        t0, t1, t2, t3, t4, t5 = tb[p, 0], tb[p, 1], tb[p, 2], tb[p, 3], tb[p, 4], tb[p, 5]
        a0, a1 = np.float64(area_grid[p, 0]), np.float64(area_grid[p, 1])
        an, av, ao = area_grid[p, 2], area_grid[p, 3], area_off[p]
        s0, s1 = np.float64(sample_grid[p, 0]), np.float64(sample_grid[p, 1])
        sn, sv, so = sample_grid[p, 2], sample_grid[p, 3], sample_off[p]
        q = remap[p]
        r2 = 0.0
        k = j
        if image:
            while k < m:
                uk = np.uint64(k)
                if point_plane[uk] != raw:
                    break
                dd, _u, _v = _extent_point(flat, np.uint64(3 * k), acc, cx, cy, cz, t0, t1, t2, t3, t4, t5, inv_s, s0,
                                           s1, sn, sv, so)
                r2 = dd if dd > r2 else r2
                labels[np.uint64(sorted_src[uk])] = q
                k += 1
        else:
            while k < m:
                uk = np.uint64(k)
                if point_plane[uk] != raw:
                    break
                k += 1  # first: the tests below go on to the next point with ``continue``
                dd, u, v = _extent_point(flat, np.uint64(3 * (k - 1)), acc, cx, cy, cz, t0, t1, t2, t3, t4, t5, inv_s,
                                         s0, s1, sn, sv, so)
                r2 = dd if dd > r2 else r2
                if not same:
                    iu = min(max(int(u * inv_a - a0), 0), an - 1)
                    iv = min(max(int(v * inv_a - a1), 0), av - 1)
                    occupied[np.uint64(ao + iu * av + iv)] = 1
                if not with_labels:
                    continue
                px = sorted_src[uk] if src_is_pixel else pix[np.uint64(sorted_src[uk])]
                if stride == 1:
                    labels[np.uint64(px)] = q
                    continue
                if q < 0:
                    continue
                v0 = px // width
                u0 = px % width
                for vv in range(v0, min(v0 + stride, height)):
                    for uu in range(u0, min(u0 + stride, width)):
                        labels[vv * width + uu] = q
        radii[p] = max(radii[p], r2)
        j = k
    for p in range(n_planes):
        radii[p] = math.sqrt(radii[p])
        cnt = 0
        if same:
            for c in range(sample_off[p], sample_off[p + 1]):
                cnt += 1 if sample_acc[c, 0] > 0.0 else 0
        else:
            for c in range(area_off[p], area_off[p + 1]):
                cnt += occupied[c]
        areas[p] = cnt * area_cell * area_cell


@njit(error_model="numpy")
def support_moments(sup, refs, table, n_out, counts, sums, scatters):
    """Plain moments about the origin of each output plane from ``sup`` (P, 10) about ``refs`` (see
    :func:`assign_points`), plane ``p`` going to ``table[p]`` (-1: dropped); outputs (n_out,...) zeroed here."""
    for o in range(n_out):
        counts[o] = 0
        sums[o, :] = 0.0
        scatters[o, :, :] = 0.0
    for p in range(sup.shape[0]):
        o = table[p]
        if o < 0:
            continue
        n = sup[p, 0]
        rx = refs[p, 0]
        ry = refs[p, 1]
        rz = refs[p, 2]
        sx = sup[p, 1]
        sy = sup[p, 2]
        sz = sup[p, 3]
        counts[o] += int(round(n))
        sums[o, 0] += sx + n * rx
        sums[o, 1] += sy + n * ry
        sums[o, 2] += sz + n * rz
        scatters[o, 0, 0] += sup[p, 4] + 2.0 * sx * rx + n * rx * rx
        scatters[o, 0, 1] += sup[p, 5] + sx * ry + rx * sy + n * rx * ry
        scatters[o, 0, 2] += sup[p, 6] + sx * rz + rx * sz + n * rx * rz
        scatters[o, 1, 1] += sup[p, 7] + 2.0 * sy * ry + n * ry * ry
        scatters[o, 1, 2] += sup[p, 8] + sy * rz + ry * sz + n * ry * rz
        scatters[o, 2, 2] += sup[p, 9] + 2.0 * sz * rz + n * rz * rz
    for o in range(n_out):
        scatters[o, 1, 0] = scatters[o, 0, 1]
        scatters[o, 2, 0] = scatters[o, 0, 2]
        scatters[o, 2, 1] = scatters[o, 1, 2]


@njit(error_model="numpy")
def layer_candidates(planes, counts, sums, cos_max, k_sigmas, power, coeff, out):
    """Pairs ``(i, j)`` of planes that may be layers of one surface: both with points, ``j`` not larger (by
    count; ties by index), normals within ``acos(cos_max)``, and ``j``'s centroid within ``k_sigmas`` depth sigmas
    (at its depth) of ``i``'s plane. Rows into ``out`` (cap, 2); returns how many (more than cap: cut)."""
    n = planes.shape[0]
    c = 0
    for i in range(n):
        if counts[i] <= 0:
            continue
        for j in range(n):
            if j == i or counts[j] <= 0 or counts[j] > counts[i] or (counts[j] == counts[i] and j < i):
                continue
            if planes[i, 0] * planes[j, 0] + planes[i, 1] * planes[j, 1] + planes[i, 2] * planes[j, 2] < cos_max:
                continue
            cx = sums[j, 0] / counts[j]
            cy = sums[j, 1] / counts[j]
            cz = sums[j, 2] / counts[j]
            off = abs(planes[i, 0] * cx + planes[i, 1] * cy + planes[i, 2] * cz + planes[i, 3])
            zz = cz if cz > MIN_DEPTH else MIN_DEPTH
            if off > k_sigmas * _sigma_z(zz, power, coeff):
                continue
            if c < out.shape[0]:
                out[c, 0] = i
                out[c, 1] = j
            c += 1
    return c


@njit(error_model="numpy")
def layer_blocks(point_plane, table, m, sorted_src, src_is_pixel, pix, width, block, n_blocks_w, bit_of, masks):
    """Which of the planes with a bit (``bit_of[plane]`` >= 0, at most 64) have a supporting point in each
    ``block x block`` pixel block: ``masks`` (blocks,) uint64, zeroed by the caller, OR-ed here. Point ``j`` is on
    plane ``table[point_plane[j]]`` at pixel ``sorted_src[j]`` (``src_is_pixel``) or ``pix[sorted_src[j]]``.
    The row of pixel ``k`` is ``(k + 0.5) / width`` rounded down, taken with a multiplication: exact, since that
    quotient is at least ``0.5 / width`` from an integer; with an integer division per point a call took 0.59 ms
    instead of 0.45 on stereo frames with layer candidates."""
    inv_width = 1.0 / width
    for j in range(m):
        p = point_plane[j]
        if p < 0:
            continue
        q = table[p]
        if q < 0:
            continue
        b = bit_of[q]
        if b < 0:
            continue
        k = sorted_src[j] if src_is_pixel else pix[sorted_src[j]]
        row = np.int64((k + 0.5) * inv_width)
        blk = row // block * n_blocks_w + (k - row * width) // block
        masks[blk] |= np.uint64(1) << np.uint64(b)


@njit(error_model="numpy")
def remap_points(point_plane, m, table):
    """``point_plane[:m]`` renumbered through ``table`` (-1 stays -1)."""
    for j in range(m):
        p = point_plane[j]
        if p >= 0:
            point_plane[j] = table[p]


@njit(error_model="numpy")
def collect_samples(sample_acc, sample_off, keep, sample_points, sample_ptr):
    """Mean point of every occupied sample cell of the planes ``keep`` (in that order) into ``sample_points``
    (float32) with CSR offsets ``sample_ptr`` (len(keep) + 1,); returns the number of samples."""
    k = 0
    sample_ptr[0] = 0
    for i in range(keep.shape[0]):
        p = keep[i]
        for c in range(sample_off[p], sample_off[p + 1]):
            n = sample_acc[c, 0]
            if n > 0.0:
                sample_points[k, 0] = sample_acc[c, 1] / n
                sample_points[k, 1] = sample_acc[c, 2] / n
                sample_points[k, 2] = sample_acc[c, 3] / n
                k += 1
        sample_ptr[i + 1] = k
    return k


@register_warmup
def _warmup() -> None:
    rng = np.random.default_rng(0)
    m = 30
    pts = np.column_stack([rng.uniform(0, 0.2, m), rng.uniform(0, 0.2, m), np.full(m, 2.0)]).astype(np.float32)
    start = np.array([0, 15, m], np.int64)
    box = np.array([0, 0, 8, 2, 1, 1], np.int64)
    cellmap = np.array([0, 1], np.int32)
    tk = np.full(4, -1, np.int64)
    tv = np.zeros(4, np.int32)
    vkey = np.array([0, 1], np.int64)
    planes = np.array([[0, 0, -1.0, 2.0]])
    pp = np.empty(m, np.int32)
    refs = np.zeros((1, 3))
    aw = np.zeros(1)
    a_s = np.zeros((1, 3))
    aS = np.zeros((1, 3, 3))
    an = np.zeros(1, np.int64)
    amb = np.zeros(1, np.int64)
    asum = np.zeros((1, 3))
    for dense in (True, False):
        for step, by_order in ((1, False), (4, True), (4, False)):
            assign_points(pts, pts.view(np.int32), step, by_order, start, 2, vkey, box, dense, cellmap, tk, tv,
                          np.array([15, 15], np.int64), pts[:2].astype(np.float64) * 15, np.tile(np.eye(3), (2, 1, 1)) * 60,
                          np.array([0, -1], np.int32), planes, np.array([4.0]), 2, 1.425e-3, True, True, pp, True, True,
                          0.985, refs, aw, a_s, aS, an, asum, amb, np.zeros((1, 10)), np.empty((SCRATCH_ROWS, m)))
    for ray in (True, False):
        solve_planes(aw, a_s, aS, refs, ray, planes.copy(), np.zeros((1, 4)), np.zeros((1, 3, 3)))
        refine_keep(aw, a_s, aS, refs, ray, planes.copy(), np.zeros((1, 4)), np.zeros((1, 3, 3)), an, amb, asum,
                    np.ones(1, np.int64), np.zeros((1, 3)), np.ones(1, np.int64), np.zeros(1),
                    np.array([0, -1], np.int32), np.empty(1, np.int32), np.empty((1, 4)), np.empty((1, 4)),
                    np.empty((1, 3, 3)), np.empty(1, np.int64), np.empty((1, 3)), np.empty(1, np.int64), np.empty(1),
                    np.empty(2, np.int32))
    compose_table(np.array([0, -1], np.int32), np.array([0], np.int32), np.empty(2, np.int32))
    plane_minor_widths(planes, np.array([0, -1], np.int32), np.array([15, 15], np.int64),
                       pts[:2].astype(np.float64) * 15, np.tile(np.eye(3), (2, 1, 1)) * 60, np.empty(1))
    counts = np.zeros(1, np.int64)
    sums = np.zeros((1, 3))
    scat = np.zeros((1, 3, 3))
    tb = np.zeros((1, 6))
    ag = np.zeros((1, 4), np.int64)
    sg = np.zeros((1, 4), np.int64)
    na, ns = plane_grids(planes, np.array([0, -1], np.int32), 2, np.array([15, 15], np.int64),
                         pts[:2].astype(np.float64) * 15, 0.8, 0.1, 0.1, tb, ag, sg)
    aoff = np.array([0, na], np.int64)
    soff = np.array([0, ns], np.int64)
    occ = np.zeros(max(na, 1), np.uint8)
    acc = np.zeros((max(ns, 1), 4))
    areas = np.zeros(1)
    plane_stats(pts, pp, m, counts, sums, scat)
    support_moments(np.ones((1, 10)), np.zeros((1, 3)), np.array([0], np.int32), 1, counts, sums, scat)
    remap_points(pp, m, np.array([0], np.int32))
    layer_candidates(np.vstack([planes, planes]), np.array([5, 3], np.int64), np.ones((2, 3)), 0.99, 4.0, 2,
                     1.425e-3, np.empty((4, 2), np.int64))
    for src_is_pixel in (False, True):
        layer_blocks(pp, np.array([0], np.int32), m, np.arange(m).astype(np.int32) % 20, src_is_pixel,
                     np.arange(20).astype(np.int32), 5, 2, 3, np.zeros(1, np.int64), np.zeros(6, np.uint64))
    labels = np.empty(20, np.int32)
    cent = sums / max(counts[0], 1)
    for stride in (1, 2):
        for src_is_pixel in (False, True):
            plane_extent(pts, pp, np.array([0], np.int32), m, cent, tb, 0.1, ag, aoff, occ, 0.1, sg, soff, acc, np.zeros(1), areas, True,
                         np.arange(m).astype(np.int32) % 20, src_is_pixel, np.arange(20).astype(np.int32),
                         np.array([0], np.int32), 5, 4, stride, labels)
    order = np.empty(1, np.int64)
    remap = np.empty(1, np.int32)
    n_order = plane_order(counts, sums, 1, ag, sg, cent, aoff.copy(), soff.copy(), order, remap)
    keep = np.empty(1, np.int64)
    nk = keep_planes(order, n_order, areas, 0.0, remap, keep, np.empty(1, np.int32))
    gather_planes(keep, nk, planes, cent, counts, np.zeros(1), areas, np.zeros((1, 4, 4)), sums, scat,
                  np.empty((1, 3)), np.empty(1), np.empty((1, 3)), np.empty(1, np.int64), np.empty(1), np.empty(1),
                  np.empty((1, 4, 4)), np.empty((1, 3)), np.empty((1, 3, 3)))
    sp = np.zeros((max(ns, 1), 3), np.float32)
    ptr = np.zeros(2, np.int64)
    collect_samples(acc, soff, np.array([0], np.int64), sp, ptr)
