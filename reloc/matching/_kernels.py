"""Numba kernels of plane matching: arrays in, arrays out, no config, no classes.

- a Jacobi eigen solver for small symmetric matrices (``np.linalg.eigh`` needs SciPy inside numba);
- the rotation of plane-normal pairs by the quaternion eigen method (Horn; the paper's Eq. 6, 8-9) and the
  translation from plane offsets (Eq. 7), batched over candidate triplets;
- the candidate join (submap triplet -> map triplets through the pair index) and the brute-force reference;
- verification of a transform against the map (projection inliers Eq. 10, overlap Eq. 11, scene uniqueness);
- the kernel density over SE(3) (Eq. 14) and the greedy grouping of poses into modes.

Status codes of a triplet transform (``TRANSFORM_*``) are shared with the Python layer.
"""

from __future__ import annotations

import math

import numpy as np

from reloc._numba import njit, register_warmup

TRANSFORM_OK = 0
TRANSFORM_PARALLEL = 1  # two normals of the triplet nearly parallel
TRANSFORM_ILL_CONDITIONED = 2  # the translation system is ill-conditioned (normals nearly coplanar)
TRANSFORM_INCONSISTENT = 3  # the rotation cannot align the three normal pairs (mirror image, bad angles)

_KEY_OFFSET = 1 << 20
_KEY_MASK = (1 << 21) - 1


# ---------------------------------------------------------------------------------------------------------------------
# Small dense linear algebra


@njit
def jacobi_eigh(A, V, n):
    """Eigen-decompose the symmetric ``A[:n, :n]`` in place by cyclic Jacobi rotations.

    On return the eigenvalues are on the diagonal of ``A`` (unsorted) and the eigenvectors are the columns of
    ``V[:n, :n]``. float64 arrays, no allocation.
    """
    for i in range(n):
        for j in range(n):
            V[i, j] = 1.0 if i == j else 0.0
    scale = 0.0
    for i in range(n):
        for j in range(n):
            scale += A[i, j] * A[i, j]
    if scale == 0.0:
        return
    for _sweep in range(60):
        off = 0.0
        for p in range(n):
            for q in range(p + 1, n):
                off += A[p, q] * A[p, q]
        if off <= 1e-30 * scale:
            return
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = A[p, q]
                if apq == 0.0:
                    continue
                theta = (A[q, q] - A[p, p]) / (2.0 * apq)
                sgn = 1.0 if theta >= 0.0 else -1.0
                t = sgn / (abs(theta) + math.sqrt(theta * theta + 1.0))
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(n):
                    akp = A[k, p]
                    akq = A[k, q]
                    A[k, p] = c * akp - s * akq
                    A[k, q] = s * akp + c * akq
                for k in range(n):
                    apk = A[p, k]
                    aqk = A[q, k]
                    A[p, k] = c * apk - s * aqk
                    A[q, k] = s * apk + c * aqk
                for k in range(n):
                    vkp = V[k, p]
                    vkq = V[k, q]
                    V[k, p] = c * vkp - s * vkq
                    V[k, q] = s * vkp + c * vkq


@njit
def rotation_from_pairs(n_from, n_to, weights, count, R_out, N, V):
    """Rotation ``R`` maximizing ``sum w_k n_to[k] . (R n_from[k])`` (Horn's quaternion eigen method).

    ``n_from``, ``n_to`` (>= count, 3) float64 unit vectors, ``weights`` (>= count,); ``R_out`` (3, 3) receives the
    rotation; ``N`` and ``V`` are (4, 4) scratch arrays. Returns the gap between the two largest eigenvalues of
    Horn's matrix divided by the total weight (0 means the rotation is not determined).
    """
    sxx = sxy = sxz = syx = syy = syz = szx = szy = szz = 0.0
    wsum = 0.0
    for k in range(count):
        w = weights[k]
        a0, a1, a2 = n_from[k, 0], n_from[k, 1], n_from[k, 2]
        b0, b1, b2 = n_to[k, 0], n_to[k, 1], n_to[k, 2]
        sxx += w * a0 * b0
        sxy += w * a0 * b1
        sxz += w * a0 * b2
        syx += w * a1 * b0
        syy += w * a1 * b1
        syz += w * a1 * b2
        szx += w * a2 * b0
        szy += w * a2 * b1
        szz += w * a2 * b2
        wsum += w
    N[0, 0] = sxx + syy + szz
    N[0, 1] = syz - szy
    N[0, 2] = szx - sxz
    N[0, 3] = sxy - syx
    N[1, 1] = sxx - syy - szz
    N[1, 2] = sxy + syx
    N[1, 3] = szx + sxz
    N[2, 2] = -sxx + syy - szz
    N[2, 3] = syz + szy
    N[3, 3] = -sxx - syy + szz
    for i in range(4):
        for j in range(i):
            N[i, j] = N[j, i]
    jacobi_eigh(N, V, 4)
    best = 0
    for i in range(1, 4):
        if N[i, i] > N[best, best]:
            best = i
    second = -1e300
    for i in range(4):
        if i != best and N[i, i] > second:
            second = N[i, i]
    w_ = V[0, best]
    x = V[1, best]
    y = V[2, best]
    z = V[3, best]
    norm = math.sqrt(w_ * w_ + x * x + y * y + z * z)
    w_ /= norm
    x /= norm
    y /= norm
    z /= norm
    R_out[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R_out[0, 1] = 2.0 * (x * y - z * w_)
    R_out[0, 2] = 2.0 * (x * z + y * w_)
    R_out[1, 0] = 2.0 * (x * y + z * w_)
    R_out[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R_out[1, 2] = 2.0 * (y * z - x * w_)
    R_out[2, 0] = 2.0 * (x * z - y * w_)
    R_out[2, 1] = 2.0 * (y * z + x * w_)
    R_out[2, 2] = 1.0 - 2.0 * (x * x + y * y)
    if wsum <= 0.0:
        return 0.0
    return (N[best, best] - second) / wsum


@njit
def _angle(a, b):
    """Angle (radians) between unit rows ``a`` and ``b``."""
    d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    if d > 1.0:
        d = 1.0
    elif d < -1.0:
        d = -1.0
    return math.acos(d)


@njit
def _triple(a, b, c):
    """``a . (b x c)`` of three 3-vectors."""
    return (
        a[0] * (b[1] * c[2] - b[2] * c[1]) + a[1] * (b[2] * c[0] - b[0] * c[2]) + a[2] * (b[0] * c[1] - b[1] * c[0])
    )


@njit
def triplet_transforms(cand, sub_normals, sub_offsets, map_normals, map_offsets, min_angle_rad, max_condition,
                       max_residual_rad, R_out, t_out, status_out):
    """Transform ``T_map_sub`` of each candidate triplet.

    ``cand`` (H, 6) int32 rows ``(j0, j1, j2, i0, i1, i2)``: submap planes j matched to map planes i. Rotation by
    the quaternion eigen method on the three normal pairs, translation by solving ``n_i . t = d_j - d_i`` (Eq. 7).
    ``R_out`` (H, 3, 3), ``t_out`` (H, 3), ``status_out`` (H,) int8 (``TRANSFORM_*``).
    """
    H = cand.shape[0]
    n_from = np.empty((3, 3))
    n_to = np.empty((3, 3))
    w = np.ones(3)
    R = np.empty((3, 3))
    N = np.empty((4, 4))
    V = np.empty((4, 4))
    M = np.empty((3, 3))
    VM = np.empty((3, 3))
    cos_min = math.cos(min_angle_rad)
    cos_res = math.cos(max_residual_rad)
    for h in range(H):
        for k in range(3):
            j = cand[h, k]
            i = cand[h, 3 + k]
            for c in range(3):
                n_from[k, c] = sub_normals[j, c]
                n_to[k, c] = map_normals[i, c]
        status = TRANSFORM_OK
        # Near-parallel normals on either side: the triplet does not fix the pose.
        for a in range(3):
            for b in range(a + 1, 3):
                da = abs(n_from[a, 0] * n_from[b, 0] + n_from[a, 1] * n_from[b, 1] + n_from[a, 2] * n_from[b, 2])
                db = abs(n_to[a, 0] * n_to[b, 0] + n_to[a, 1] * n_to[b, 1] + n_to[a, 2] * n_to[b, 2])
                if da > cos_min or db > cos_min:
                    status = TRANSFORM_PARALLEL
        if status == TRANSFORM_OK:
            rotation_from_pairs(n_from, n_to, w, 3, R, N, V)
            for k in range(3):
                rx = R[0, 0] * n_from[k, 0] + R[0, 1] * n_from[k, 1] + R[0, 2] * n_from[k, 2]
                ry = R[1, 0] * n_from[k, 0] + R[1, 1] * n_from[k, 1] + R[1, 2] * n_from[k, 2]
                rz = R[2, 0] * n_from[k, 0] + R[2, 1] * n_from[k, 1] + R[2, 2] * n_from[k, 2]
                if rx * n_to[k, 0] + ry * n_to[k, 1] + rz * n_to[k, 2] < cos_res:
                    status = TRANSFORM_INCONSISTENT
        if status == TRANSFORM_OK:
            # Condition number of the 3x3 system with the map normals as rows, from the eigenvalues of A^T A.
            for a in range(3):
                for b in range(3):
                    s = 0.0
                    for k in range(3):
                        s += n_to[k, a] * n_to[k, b]
                    M[a, b] = s
            jacobi_eigh(M, VM, 3)
            lo = min(M[0, 0], min(M[1, 1], M[2, 2]))
            hi = max(M[0, 0], max(M[1, 1], M[2, 2]))
            if lo <= 0.0 or math.sqrt(hi / lo) > max_condition:
                status = TRANSFORM_ILL_CONDITIONED
        if status == TRANSFORM_OK:
            # Cramer's rule on A t = b with A rows = map normals.
            b0 = sub_offsets[cand[h, 0]] - map_offsets[cand[h, 3]]
            b1 = sub_offsets[cand[h, 1]] - map_offsets[cand[h, 4]]
            b2 = sub_offsets[cand[h, 2]] - map_offsets[cand[h, 5]]
            a = n_to
            det = _triple(a[0], a[1], a[2])
            c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
            c01 = a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]
            c02 = a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]
            c10 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
            c11 = a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]
            c12 = a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]
            c20 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
            c21 = a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]
            c22 = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
            t_out[h, 0] = (c00 * b0 + c01 * b1 + c02 * b2) / det
            t_out[h, 1] = (c10 * b0 + c11 * b1 + c12 * b2) / det
            t_out[h, 2] = (c20 * b0 + c21 * b1 + c22 * b2) / det
            for a_ in range(3):
                for b_ in range(3):
                    R_out[h, a_, b_] = R[a_, b_]
        else:
            for a_ in range(3):
                t_out[h, a_] = 0.0
                for b_ in range(3):
                    R_out[h, a_, b_] = 1.0 if a_ == b_ else 0.0
        status_out[h] = status


# ---------------------------------------------------------------------------------------------------------------------
# The map index and the candidate join


@njit
def sphere_gap(c0, r0, c1, r1):
    """Distance between the spheres (centroid, radius) of two planes; 0 when they intersect."""
    dx = c0[0] - c1[0]
    dy = c0[1] - c1[1]
    dz = c0[2] - c1[2]
    g = math.sqrt(dx * dx + dy * dy + dz * dz) - r0 - r1
    return g if g > 0.0 else 0.0


@njit
def build_pairs(normals, centroids, radii, lo_rad, hi_rad, check_gap, max_gap):
    """Ordered pairs ``(i, k)``, ``i != k``, with normal angle in ``[lo, hi]`` and (optionally) sphere gap <= max_gap.

    Returns ``(first (P,) int32, second (P,) int32, angle (P,) float64)`` in row order of ``first``.
    """
    n = normals.shape[0]
    count = 0
    for i in range(n):
        for k in range(n):
            if i == k:
                continue
            a = _angle(normals[i], normals[k])
            if a < lo_rad or a > hi_rad:
                continue
            if check_gap and sphere_gap(centroids[i], radii[i], centroids[k], radii[k]) > max_gap:
                continue
            count += 1
    first = np.empty(count, np.int32)
    second = np.empty(count, np.int32)
    ang = np.empty(count, np.float64)
    m = 0
    for i in range(n):
        for k in range(n):
            if i == k:
                continue
            a = _angle(normals[i], normals[k])
            if a < lo_rad or a > hi_rad:
                continue
            if check_gap and sphere_gap(centroids[i], radii[i], centroids[k], radii[k]) > max_gap:
                continue
            first[m] = i
            second[m] = k
            ang[m] = a
            m += 1
    return first, second, ang


@njit
def _lower_bound(arr, lo, hi, value):
    """First index in ``arr[lo:hi]`` (sorted) with ``arr[idx] >= value``."""
    while lo < hi:
        mid = (lo + hi) // 2
        if arr[mid] < value:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit
def signed_range(normals, offsets, ptr, points, a, b):
    """(lo, hi) signed distances of the samples of plane ``a`` to plane ``b``: where ``a`` lies relative to ``b``.

    A rigid-motion invariant of the pair: what a submap saw of ``a`` lies within what the map holds of it.
    """
    lo = math.inf
    hi = -math.inf
    nx, ny, nz, d = normals[b, 0], normals[b, 1], normals[b, 2], offsets[b]
    for s in range(ptr[a], ptr[a + 1]):
        v = nx * points[s, 0] + ny * points[s, 1] + nz * points[s, 2] + d
        if v < lo:
            lo = v
        if v > hi:
            hi = v
    return lo, hi


@njit
def pair_extents(first, second, normals, offsets, ptr, points):
    """(P, 4) ``[lo, hi]`` of first's samples to second's plane, then of second's samples to first's plane: per
    pair what :func:`signed_range` gives, bit for bit.

    Computed plane by plane: each plane's samples are read once, and each sample is measured against all the planes
    it pairs with in an inner loop over them (independent, so the compiler vectorizes it). Pair by pair, a large
    plane's samples (a floor's 100,000) were read again for each of its hundreds of partners, one at a time.
    """
    P = first.shape[0]
    N = normals.shape[0]
    out = np.empty((P, 4))
    # Each pair twice, grouped by the plane whose samples are measured: (pair, column, partner plane).
    deg = np.zeros(N + 1, np.int64)
    for p in range(P):
        deg[first[p] + 1] += 1
        deg[second[p] + 1] += 1
    for a in range(N):
        deg[a + 1] += deg[a]
    fill = deg[:N].copy()
    slot_pair = np.empty(2 * P, np.int64)
    slot_col = np.empty(2 * P, np.int64)
    slot_other = np.empty(2 * P, np.int64)
    for p in range(P):
        for side in range(2):
            a = first[p] if side == 0 else second[p]
            k = fill[a]
            fill[a] += 1
            slot_pair[k] = p
            slot_col[k] = 2 * side
            slot_other[k] = second[p] if side == 0 else first[p]
    most = 0
    for a in range(N):
        most = max(most, deg[a + 1] - deg[a])
    nx = np.empty(most)
    ny = np.empty(most)
    nz = np.empty(most)
    dd = np.empty(most)
    lo = np.empty(most)
    hi = np.empty(most)
    for a in range(N):
        k0 = deg[a]
        m = deg[a + 1] - k0
        if m == 0:
            continue
        for q in range(m):
            b = slot_other[k0 + q]
            nx[q] = normals[b, 0]
            ny[q] = normals[b, 1]
            nz[q] = normals[b, 2]
            dd[q] = offsets[b]
            lo[q] = math.inf
            hi[q] = -math.inf
        for s in range(ptr[a], ptr[a + 1]):
            px = points[s, 0]
            py = points[s, 1]
            pz = points[s, 2]
            for q in range(m):
                v = nx[q] * px + ny[q] * py + nz[q] * pz + dd[q]  # the order of signed_range's sum
                lo[q] = v if v < lo[q] else lo[q]
                hi[q] = v if v > hi[q] else hi[q]
        for q in range(m):
            p = slot_pair[k0 + q]
            c = slot_col[k0 + q]
            out[p, c] = lo[q]
            out[p, c + 1] = hi[q]
    return out


@njit
def dense_extents(normals, offsets, ptr, points):
    """(N, N, 2): ``[a, b]`` the ``(lo, hi)`` of a's samples to b's plane, for every pair (the map's, for the brute
    force): :func:`trimmed_extents` with nothing left out."""
    return trimmed_extents(normals, offsets, ptr, points, 0.0)


@njit
def _keep_smallest(buf, n, cap, v):
    """Insert ``v`` into the ascending ``buf[:n]`` that keeps the ``cap`` smallest values seen; returns the new n."""
    if n == cap:
        if v >= buf[n - 1]:
            return n
        n -= 1
    i = n
    while i > 0 and buf[i - 1] > v:
        buf[i] = buf[i - 1]
        i -= 1
    buf[i] = v
    return n + 1


@njit
def trimmed_extents(normals, offsets, ptr, points, trim):
    """(N, N, 2) as :func:`dense_extents`, but each range leaves out the ``floor(trim * n)`` most extreme of plane
    ``a``'s ``n`` samples on either side: a few stray samples (a wall's corner points on the floor) do not stretch
    what a submap saw of a plane beyond what the map holds of it."""
    n = normals.shape[0]
    out = np.empty((n, n, 2))
    k_max = 0
    for a in range(n):
        k_max = max(k_max, int(trim * (ptr[a + 1] - ptr[a])))
    low = np.empty(k_max + 1)
    high = np.empty(k_max + 1)  # the largest, negated: ascending like ``low``
    for a in range(n):
        k = int(trim * (ptr[a + 1] - ptr[a]))
        for b in range(n):
            if k == 0:
                lo, hi = signed_range(normals, offsets, ptr, points, a, b)
                out[a, b, 0] = lo
                out[a, b, 1] = hi
                continue
            nx, ny, nz, d = normals[b, 0], normals[b, 1], normals[b, 2], offsets[b]
            n_low = 0
            n_high = 0
            for s in range(ptr[a], ptr[a + 1]):
                v = nx * points[s, 0] + ny * points[s, 1] + nz * points[s, 2] + d
                n_low = _keep_smallest(low, n_low, k + 1, v)
                n_high = _keep_smallest(high, n_high, k + 1, -v)
            out[a, b, 0] = low[k]
            out[a, b, 1] = -high[k]
    return out


@njit
def _inside(sub_lo, sub_hi, map_lo, map_hi, tol):
    """The submap interval lies within the map interval, give or take ``tol``."""
    return sub_lo >= map_lo - tol and sub_hi <= map_hi + tol


@njit
def _triplet_ok(j0, j1, j2, i0, i1, i2, sub_normals, sub_areas, map_normals, map_centroids, map_radii, map_areas,
                map_facing, face0, t01, t02, t12, det_s, tol, require_ground, check_gap, g01, g02, g12, check_area,
                min_area_ratio, min_triple):
    """Every per-triplet test of the selection, shared by the indexed join and the brute force.

    ``face0``: +1 / -1 when the submap plane j0 is a horizontal anchor facing up (floor, table) / down (ceiling);
    with ``require_ground`` the map plane i0 must face the same way. ``g01, g02, g12``: upper bounds of the sphere
    gaps between the map planes (what the submap shows of the same planes is at most that far apart).
    """
    if i0 == i1 or i0 == i2 or i1 == i2:
        return False
    if require_ground and map_facing[i0] != face0:
        return False
    if check_area:
        if map_areas[i0] < min_area_ratio * sub_areas[j0]:
            return False
        if map_areas[i1] < min_area_ratio * sub_areas[j1]:
            return False
        if map_areas[i2] < min_area_ratio * sub_areas[j2]:
            return False
    if abs(_angle(map_normals[i1], map_normals[i2]) - t12) > tol:
        return False
    if abs(_angle(map_normals[i0], map_normals[i1]) - t01) > tol:
        return False
    if abs(_angle(map_normals[i0], map_normals[i2]) - t02) > tol:
        return False
    if check_gap:
        if sphere_gap(map_centroids[i1], map_radii[i1], map_centroids[i2], map_radii[i2]) > g12:
            return False
        if sphere_gap(map_centroids[i0], map_radii[i0], map_centroids[i1], map_radii[i1]) > g01:
            return False
        if sphere_gap(map_centroids[i0], map_radii[i0], map_centroids[i2], map_radii[i2]) > g02:
            return False
    det_m = _triple(map_normals[i0], map_normals[i1], map_normals[i2])
    if abs(det_m) < min_triple or det_m * det_s <= 0.0:
        return False
    return True


@njit
def join_candidates(sub_trip, sub_face0, sub_gaps, sub_ext, sub_normals, sub_areas, map_normals, map_centroids,
                    map_radii, map_areas, map_facing, pair_first, pair_second, pair_angle, pair_ext, adj_ptr, adj_ids,
                    adj_angle, adj_ext, tol, require_ground, check_gap, check_area, min_area_ratio, min_triple,
                    check_extent, extent_tol, out):
    """Map triplets agreeing with each submap triplet, found through the pair index.

    ``sub_trip`` (T, 3) int32 ``(j0, j1, j2)`` with ``sub_face0`` (T,) int8 and ``sub_gaps`` (T, 3) the gap bounds
    ``(g01, g02, g12)`` of each; the pairs ``(pair_first, pair_second)`` are sorted by
    ``pair_angle``; ``adj_*`` is the same relation per plane (CSR, each row sorted by angle; with
    ``require_ground`` the caller passes the relation restricted to horizontal planes). ``sub_ext`` (S, S, 2) and
    ``pair_ext``/``adj_ext`` (rows, 4) are the pairs' signed extents (:func:`pair_extents`); with ``check_extent``
    what the submap saw of the pairs (j1, j2) and (j1, j0) must lie within the map's extents. For the pair
    ``(j1, j2)`` the map pairs ``(i1, i2)`` come from a binary search on the pair angle, and ``i0`` from the rows of
    ``i1`` with the angle of ``(j0, j1)``; every candidate then passes :func:`_triplet_ok`.
    Writes rows ``(j0, j1, j2, i0, i1, i2)`` into ``out`` (cap, 6) int32 and returns
    ``(count, generated)`` where ``generated`` counts the pairs looked at; ``count > cap`` means the output was cut.
    """
    cap = out.shape[0]
    count = 0
    generated = 0
    for t in range(sub_trip.shape[0]):
        j0 = sub_trip[t, 0]
        j1 = sub_trip[t, 1]
        j2 = sub_trip[t, 2]
        t01 = _angle(sub_normals[j0], sub_normals[j1])
        t02 = _angle(sub_normals[j0], sub_normals[j2])
        t12 = _angle(sub_normals[j1], sub_normals[j2])
        det_s = _triple(sub_normals[j0], sub_normals[j1], sub_normals[j2])
        face0 = sub_face0[t]
        g01 = sub_gaps[t, 0]
        g02 = sub_gaps[t, 1]
        g12 = sub_gaps[t, 2]
        p_lo = _lower_bound(pair_angle, 0, pair_angle.shape[0], t12 - tol)
        for p in range(p_lo, pair_angle.shape[0]):
            if pair_angle[p] > t12 + tol:
                break
            i1 = pair_first[p]
            i2 = pair_second[p]
            if check_area and (map_areas[i1] < min_area_ratio * sub_areas[j1]
                               or map_areas[i2] < min_area_ratio * sub_areas[j2]):
                continue
            if check_gap and sphere_gap(map_centroids[i1], map_radii[i1], map_centroids[i2], map_radii[i2]) > g12:
                continue
            if check_extent and not (
                _inside(sub_ext[j1, j2, 0], sub_ext[j1, j2, 1], pair_ext[p, 0], pair_ext[p, 1], extent_tol)
                and _inside(sub_ext[j2, j1, 0], sub_ext[j2, j1, 1], pair_ext[p, 2], pair_ext[p, 3], extent_tol)
            ):
                continue
            a_lo = _lower_bound(adj_angle, adj_ptr[i1], adj_ptr[i1 + 1], t01 - tol)
            for q in range(a_lo, adj_ptr[i1 + 1]):
                if adj_angle[q] > t01 + tol:
                    break
                i0 = adj_ids[q]
                generated += 1
                if check_extent and not (
                    _inside(sub_ext[j1, j0, 0], sub_ext[j1, j0, 1], adj_ext[q, 0], adj_ext[q, 1], extent_tol)
                    and _inside(sub_ext[j0, j1, 0], sub_ext[j0, j1, 1], adj_ext[q, 2], adj_ext[q, 3], extent_tol)
                ):
                    continue
                if _triplet_ok(j0, j1, j2, i0, i1, i2, sub_normals, sub_areas, map_normals, map_centroids, map_radii,
                               map_areas, map_facing, face0, t01, t02, t12, det_s, tol, require_ground, check_gap,
                               g01, g02, g12, check_area, min_area_ratio, min_triple):
                    if count < cap:
                        out[count, 0] = j0
                        out[count, 1] = j1
                        out[count, 2] = j2
                        out[count, 3] = i0
                        out[count, 4] = i1
                        out[count, 5] = i2
                    count += 1
    return count, generated


@njit
def brute_force_candidates(sub_trip, sub_face0, sub_gaps, sub_ext, sub_normals, sub_areas, map_normals,
                           map_centroids, map_radii, map_areas, map_facing, map_ext, tol, require_ground, check_gap,
                           check_area, min_area_ratio, min_triple, check_extent, extent_tol, out):
    """The same candidates as :func:`join_candidates` by enumerating every ordered map triplet (O(N^3) per query).

    The baseline of the latency benchmark and the reference of the index in the tests.
    Returns ``(count, generated)`` like :func:`join_candidates`.
    """
    cap = out.shape[0]
    n = map_normals.shape[0]
    count = 0
    generated = 0
    for t in range(sub_trip.shape[0]):
        j0 = sub_trip[t, 0]
        j1 = sub_trip[t, 1]
        j2 = sub_trip[t, 2]
        t01 = _angle(sub_normals[j0], sub_normals[j1])
        t02 = _angle(sub_normals[j0], sub_normals[j2])
        t12 = _angle(sub_normals[j1], sub_normals[j2])
        det_s = _triple(sub_normals[j0], sub_normals[j1], sub_normals[j2])
        face0 = sub_face0[t]
        g01 = sub_gaps[t, 0]
        g02 = sub_gaps[t, 1]
        g12 = sub_gaps[t, 2]
        for i0 in range(n):
            for i1 in range(n):
                for i2 in range(n):
                    generated += 1
                    if check_extent and not (
                        _inside(sub_ext[j1, j2, 0], sub_ext[j1, j2, 1], map_ext[i1, i2, 0], map_ext[i1, i2, 1],
                                extent_tol)
                        and _inside(sub_ext[j2, j1, 0], sub_ext[j2, j1, 1], map_ext[i2, i1, 0], map_ext[i2, i1, 1],
                                    extent_tol)
                        and _inside(sub_ext[j1, j0, 0], sub_ext[j1, j0, 1], map_ext[i1, i0, 0], map_ext[i1, i0, 1],
                                    extent_tol)
                        and _inside(sub_ext[j0, j1, 0], sub_ext[j0, j1, 1], map_ext[i0, i1, 0], map_ext[i0, i1, 1],
                                    extent_tol)
                    ):
                        continue
                    if _triplet_ok(j0, j1, j2, i0, i1, i2, sub_normals, sub_areas, map_normals, map_centroids,
                                   map_radii, map_areas, map_facing, face0, t01, t02, t12, det_s, tol, require_ground,
                                   check_gap, g01, g02, g12, check_area, min_area_ratio, min_triple):
                        if count < cap:
                            out[count, 0] = j0
                            out[count, 1] = j1
                            out[count, 2] = j2
                            out[count, 3] = i0
                            out[count, 4] = i1
                            out[count, 5] = i2
                        count += 1
    return count, generated


# ---------------------------------------------------------------------------------------------------------------------
# Spatial hash of the map samples (which map planes are near a point)


@njit
def cell_keys(points, cell):
    """int64 key of the cell of each point (N, 3) on a grid of edge ``cell``."""
    n = points.shape[0]
    keys = np.empty(n, np.int64)
    for k in range(n):
        ix = int(math.floor(points[k, 0] / cell)) + _KEY_OFFSET
        iy = int(math.floor(points[k, 1] / cell)) + _KEY_OFFSET
        iz = int(math.floor(points[k, 2] / cell)) + _KEY_OFFSET
        keys[k] = (np.int64(ix & _KEY_MASK) << 42) | (np.int64(iy & _KEY_MASK) << 21) | np.int64(iz & _KEY_MASK)
    return keys


@njit
def dilate_keys(keys, ids):
    """Each (key, id) repeated into the 27 cells around it: (27 N,) keys and ids."""
    n = keys.shape[0]
    out_k = np.empty(27 * n, np.int64)
    out_i = np.empty(27 * n, np.int32)
    m = 0
    for k in range(n):
        key = keys[k]
        ix = (key >> 42) & _KEY_MASK
        iy = (key >> 21) & _KEY_MASK
        iz = key & _KEY_MASK
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                for dz in range(-1, 2):
                    out_k[m] = ((ix + dx) << 42) | ((iy + dy) << 21) | (iz + dz)
                    out_i[m] = ids[k]
                    m += 1
    return out_k, out_i


_MIX = -7046029254386353131  # 0x9E3779B97F4A7C15 as int64: Fibonacci hashing spreads the cell keys over the table


@njit
def key_table(keys):
    """An open-addressing hash table of the unique int64 ``keys`` (all >= 0): ``slots`` (a power of two, at least
    twice the keys, -1 where empty; none for no keys) and ``slot_pos`` (the index in ``keys`` of the key in each
    slot). A lookup (:func:`_find_key`, on a non-empty table) costs one or two probes where a binary search over
    the sorted keys of a large map costs twenty, most of them cache misses."""
    n = keys.shape[0]
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int32)
    size = 16
    while size < 2 * n:
        size *= 2
    slots = np.full(size, -1, np.int64)
    slot_pos = np.zeros(size, np.int32)
    shift, mask = _table_shape(slots)
    for k in range(n):
        h = ((keys[k] * _MIX) >> shift) & mask
        while slots[h] != -1:
            h = (h + 1) & mask
        slots[h] = keys[k]
        slot_pos[h] = k
    return slots, slot_pos


@njit
def _table_shape(slots):
    """(shift, mask) of a non-empty table of :func:`key_table`: a key's first slot is its top bits once mixed."""
    bits = 0
    while (1 << bits) < slots.shape[0]:
        bits += 1
    return 64 - bits, slots.shape[0] - 1


@njit(inline="always")
def _find_key(slots, slot_pos, shift, mask, key):
    """The index of ``key`` among the keys of a :func:`key_table`, or -1 when it is not one of them."""
    h = ((key * _MIX) >> shift) & mask
    while True:
        s = slots[h]
        if s == key:
            return slot_pos[h]
        if s == -1:
            return -1
        h = (h + 1) & mask


@njit
def _cell_of(x, y, z, cell):
    ix = int(math.floor(x / cell)) + _KEY_OFFSET
    iy = int(math.floor(y / cell)) + _KEY_OFFSET
    iz = int(math.floor(z / cell)) + _KEY_OFFSET
    return (np.int64(ix & _KEY_MASK) << 42) | (np.int64(iy & _KEY_MASK) << 21) | np.int64(iz & _KEY_MASK)


# ---------------------------------------------------------------------------------------------------------------------
# Verification of transforms


@njit
def verify_transforms(R, t, cand, plane_order, sub_normals, sub_offsets, sub_centroids, sub_areas, vs_ptr, vs_points,
                      map_normals, map_offsets, map_areas, min_area_ratio, hash_slots, hash_slot_pos,
                      hash_ptr, hash_ids, cell, cos_match, max_offset0, inlier0,
                      use_projection, min_projection, use_overlap, min_overlap, min_matched, min_competitor,
                      min_counted_area, free_slots, free_voxel, max_free_fraction, free_far_min, require_triplet,
                      conflict0, offset_scale, out_match, out_proj, out_over, out_state, out_nmatched, out_explained,
                      out_unknown, out_free, out_pass, out_free_frac):
    """Check each transform ``T_map_sub = (R[h], t[h])`` against the map.

    The offsets are per submap plane: ``max_offset``, ``inlier_m`` and ``conflict_offset`` below are ``max_offset0``,
    ``inlier0`` and ``conflict0`` times plane j's factors in ``offset_scale`` (S, 2): match and projection, conflict
    (ones but for a noisy sensor's near planes, ``Relocalizer._offset_scale``).

    For every submap plane j (the three planes of the candidate first, then ``plane_order``: every plane, or the
    planes to judge, the others left as not judged), its verification
    samples are moved into the map; a map plane i is a candidate when its normal is within the match angle and the
    moved centroid lies within ``max_offset`` of it. With ``use_overlap`` candidates come from the spatial hash
    (a sample counts toward overlap when it falls near a sample of i: Eq. 11 with the samples standing for the
    plane's extent), otherwise every map plane is looked at. The projection ratio (Eq. 10) is the fraction of
    samples within ``inlier_m`` of plane i. j matches its best candidate (the highest sum of the enabled ratios; of
    equal ones, the plane its moved centroid lies nearest) that clears the enabled thresholds and whose area is at
    least ``min_area_ratio`` times j's (a map plane holds what any view saw of it).
    A hypothesis passes when its three triplet planes match (unless ``require_triplet`` is False: a refined pose is
    judged on all its planes alike), at least ``min_matched`` distinct map surfaces match (a map plane is not
    another surface when the submap plane matching it had a map plane already matched among its candidates as well:
    a door a few centimetres behind its wall, a fragment of the same wall), no plane lies in the map's known free space,
    and the matched submap planes, with the planes the map knows nothing about, weigh at least ``min_competitor`` of
    the total: it may be the truth. (Whether it explains enough to be accepted is for the caller to judge from
    ``out_nmatched`` and ``out_explained``.) Each plane weighing the square root of its area (its
    extent): large planes count more than clutter, but a floor and a wall cannot hide unexplained furniture. Planes
    smaller than ``min_counted_area`` count only when they match (small planes are mostly facets of curved clutter
    that no map holds). With ``free_slots`` (a :func:`key_table` of the voxel keys of the map's known free space, edge
    ``free_voxel``), an unmatched plane of at least ``min_counted_area`` whose samples fall in free space for more
    than ``max_free_fraction`` contradicts the map: the hypothesis fails (the map saw empty space where the pose puts
    a surface). Free space is carved only up to a margin short of each surface, so in a narrow place (a wall put
    across a 2 m corridor) most samples of such a plane are near a map surface and never free; with ``free_far_min`` >
    0, when at least that fraction of its samples are away from every map surface (no map sample in their cell of the
    spatial hash), the free share of those samples is judged too. ``out_free`` (H,) counts such planes. ``out_state``
    (H, S) int8 says why each plane is unmatched: 0 matched (or not judged), 1 unknown (the map has nothing there: no
    surface facing the same way off its plane, no free space), 2 conflict (map surfaces facing the same way, but more
    than ``conflict_offset`` off its plane, are there), 3 in known free space, 4 too small to count; with a
    ``conflict_offset`` above ``max_offset``, 5 near a surface facing the same way, between the two offsets (neither
    matched nor in conflict, nor unknown to the map); ``out_unknown`` (H,) is the weight of the unknown planes as a
    fraction of the total (what the pose might still explain with a more complete map); ``out_free_frac`` (H, S)
    float32 is the fraction of an unmatched counted plane's samples in known free space (0 otherwise): a plane the map
    knows nothing about but whose place the map saw partly empty is less likely to be there.

    Outputs per hypothesis h and submap plane j: ``out_match`` (H, S) int32 map plane or -1, ``out_proj`` and
    ``out_over`` (H, S) float32 ratios; per hypothesis ``out_nmatched`` int32, ``out_explained`` float64,
    ``out_pass`` bool. Returns the number of (hypothesis, plane) pairs evaluated.
    """
    H = R.shape[0]
    S = sub_normals.shape[0]
    N = map_normals.shape[0]
    MAXC = 32
    cand_id = np.empty(MAXC, np.int32)
    cand_over = np.empty(MAXC, np.int32)
    cand_proj = np.empty(MAXC, np.int32)
    cand_off = np.empty(MAXC, np.float64)
    cand_ok = np.empty(MAXC, np.bool_)  # large enough to match j (the others only tell which surface j is on)
    matched_ids = np.empty(S, np.int32)
    large_area = 0.0
    for j in range(S):
        if sub_areas[j] >= min_counted_area:
            large_area += math.sqrt(sub_areas[j])
    n_slots = hash_slots.shape[0]
    shift, mask = _table_shape(hash_slots) if n_slots > 0 else (0, 0)
    n_free_slots = free_slots.shape[0]
    free_shift, free_mask = _table_shape(free_slots) if n_free_slots > 0 else (0, 0)
    evaluated = 0
    for h in range(H):
        for j in range(S):
            out_match[h, j] = -1
            out_proj[h, j] = 0.0
            out_over[h, j] = 0.0
            out_state[h, j] = 0 if sub_areas[j] >= min_counted_area else 4
            out_free_frac[h, j] = 0.0
        n_matched = 0
        explained = 0.0
        small_matched = 0.0
        unknown = 0.0
        n_free = 0
        ok = True
        processed = 0
        for step in range(plane_order.shape[0] + 3):
            if step < 3:
                j = cand[h, step]
            else:
                j = plane_order[step - 3]
                if j == cand[h, 0] or j == cand[h, 1] or j == cand[h, 2]:
                    continue
            evaluated += 1
            processed += 1
            # This plane's offsets (``offset_scale`` (S, 2): match and projection, conflict).
            max_offset = max_offset0 * offset_scale[j, 0]
            inlier_m = inlier0 * offset_scale[j, 0]
            conflict_offset = conflict0 * offset_scale[j, 1]
            # The plane in the map frame.
            nx = R[h, 0, 0] * sub_normals[j, 0] + R[h, 0, 1] * sub_normals[j, 1] + R[h, 0, 2] * sub_normals[j, 2]
            ny = R[h, 1, 0] * sub_normals[j, 0] + R[h, 1, 1] * sub_normals[j, 1] + R[h, 1, 2] * sub_normals[j, 2]
            nz = R[h, 2, 0] * sub_normals[j, 0] + R[h, 2, 1] * sub_normals[j, 1] + R[h, 2, 2] * sub_normals[j, 2]
            c = sub_centroids[j]
            cx = R[h, 0, 0] * c[0] + R[h, 0, 1] * c[1] + R[h, 0, 2] * c[2] + t[h, 0]
            cy = R[h, 1, 0] * c[0] + R[h, 1, 1] * c[1] + R[h, 1, 2] * c[2] + t[h, 1]
            cz = R[h, 2, 0] * c[0] + R[h, 2, 1] * c[1] + R[h, 2, 2] * c[2] + t[h, 2]
            n_c = 0
            s0 = vs_ptr[j]
            s1 = vs_ptr[j + 1]
            m_j = s1 - s0
            if use_overlap:
                for s in range(s0, s1):
                    p = vs_points[s]
                    px = R[h, 0, 0] * p[0] + R[h, 0, 1] * p[1] + R[h, 0, 2] * p[2] + t[h, 0]
                    py = R[h, 1, 0] * p[0] + R[h, 1, 1] * p[1] + R[h, 1, 2] * p[2] + t[h, 1]
                    pz = R[h, 2, 0] * p[0] + R[h, 2, 1] * p[1] + R[h, 2, 2] * p[2] + t[h, 2]
                    key = _cell_of(px, py, pz, cell)
                    pos = _find_key(hash_slots, hash_slot_pos, shift, mask, key) if n_slots > 0 else -1
                    if pos < 0:
                        continue
                    for e in range(hash_ptr[pos], hash_ptr[pos + 1]):
                        i = hash_ids[e]
                        if nx * map_normals[i, 0] + ny * map_normals[i, 1] + nz * map_normals[i, 2] < cos_match:
                            continue
                        off_c = abs(map_normals[i, 0] * cx + map_normals[i, 1] * cy + map_normals[i, 2] * cz
                                    + map_offsets[i])
                        if off_c > max_offset:
                            continue
                        slot = -1
                        for q in range(n_c):
                            if cand_id[q] == i:
                                slot = q
                                break
                        if slot < 0:
                            if n_c == MAXC:
                                continue
                            slot = n_c
                            cand_id[slot] = i
                            cand_over[slot] = 0
                            cand_proj[slot] = 0
                            cand_off[slot] = off_c
                            cand_ok[slot] = map_areas[i] >= min_area_ratio * sub_areas[j]
                            n_c += 1
                        if not cand_ok[slot]:  # known to be there; its ratios are never read
                            continue
                        cand_over[slot] += 1
                        if abs(map_normals[i, 0] * px + map_normals[i, 1] * py + map_normals[i, 2] * pz
                               + map_offsets[i]) <= inlier_m:
                            cand_proj[slot] += 1
            else:
                for i in range(N):
                    if nx * map_normals[i, 0] + ny * map_normals[i, 1] + nz * map_normals[i, 2] < cos_match:
                        continue
                    off_c = abs(map_normals[i, 0] * cx + map_normals[i, 1] * cy + map_normals[i, 2] * cz
                                + map_offsets[i])
                    if off_c > max_offset:
                        continue
                    if n_c == MAXC:
                        break
                    cand_id[n_c] = i
                    cand_off[n_c] = off_c
                    cand_ok[n_c] = map_areas[i] >= min_area_ratio * sub_areas[j]
                    cand_over[n_c] = m_j
                    cnt = 0
                    if use_projection and cand_ok[n_c]:
                        for s in range(s0, s1):
                            p = vs_points[s]
                            px = R[h, 0, 0] * p[0] + R[h, 0, 1] * p[1] + R[h, 0, 2] * p[2] + t[h, 0]
                            py = R[h, 1, 0] * p[0] + R[h, 1, 1] * p[1] + R[h, 1, 2] * p[2] + t[h, 1]
                            pz = R[h, 2, 0] * p[0] + R[h, 2, 1] * p[1] + R[h, 2, 2] * p[2] + t[h, 2]
                            if abs(map_normals[i, 0] * px + map_normals[i, 1] * py + map_normals[i, 2] * pz
                                   + map_offsets[i]) <= inlier_m:
                                cnt += 1
                    cand_proj[n_c] = cnt
                    n_c += 1
            best = -1
            best_score = -1.0
            best_p = 0.0
            best_o = 0.0
            inv_m = 1.0 / m_j if m_j > 0 else 0.0
            for q in range(n_c):
                if not cand_ok[q]:
                    continue
                rp = cand_proj[q] * inv_m
                ro = cand_over[q] * inv_m
                if use_projection and rp < min_projection:
                    continue
                if use_overlap and ro < min_overlap:
                    continue
                score = (rp if use_projection else 0.0) + (ro if use_overlap else 0.0)
                # Equal scores (a door recessed a few cm behind its wall, both holding every sample): the map plane
                # its centroid lies on, not whichever the hash listed first.
                if score > best_score or (score == best_score and cand_off[q] < cand_off[best]):
                    best_score = score
                    best = q
                    best_p = rp
                    best_o = ro
            # A map surface stored as several coplanar fragments (seen in pieces, never joined): the plane's extent
            # is their union. With none matched and two candidates or more large enough to match j, judge the
            # strongest of those against the union of the map planes coplanar with it.
            top = -1
            n_ok = 0
            if best < 0 and use_overlap:
                for q in range(n_c):
                    if cand_ok[q]:
                        n_ok += 1
                        if top < 0 or cand_over[q] + cand_proj[q] > cand_over[top] + cand_proj[top]:
                            top = q
            if n_ok > 1:
                it = cand_id[top]
                u_over = 0
                u_proj = 0
                for s in range(s0, s1):
                    p = vs_points[s]
                    px = R[h, 0, 0] * p[0] + R[h, 0, 1] * p[1] + R[h, 0, 2] * p[2] + t[h, 0]
                    py = R[h, 1, 0] * p[0] + R[h, 1, 1] * p[1] + R[h, 1, 2] * p[2] + t[h, 1]
                    pz = R[h, 2, 0] * p[0] + R[h, 2, 1] * p[1] + R[h, 2, 2] * p[2] + t[h, 2]
                    key = _cell_of(px, py, pz, cell)
                    pos = _find_key(hash_slots, hash_slot_pos, shift, mask, key) if n_slots > 0 else -1
                    if pos < 0:
                        continue
                    hit = False
                    # Coplanar: normals within the match angle, planes within max_offset of each other here (their
                    # offsets alone would differ with the map's origin wherever the normals differ at all).
                    off_it = (map_normals[it, 0] * px + map_normals[it, 1] * py + map_normals[it, 2] * pz
                              + map_offsets[it])
                    for e in range(hash_ptr[pos], hash_ptr[pos + 1]):
                        i2 = hash_ids[e]
                        if (map_normals[i2, 0] * map_normals[it, 0] + map_normals[i2, 1] * map_normals[it, 1]
                                + map_normals[i2, 2] * map_normals[it, 2] >= cos_match
                                and abs(map_normals[i2, 0] * px + map_normals[i2, 1] * py + map_normals[i2, 2] * pz
                                        + map_offsets[i2] - off_it) <= max_offset):
                            hit = True
                            break
                    if hit:
                        u_over += 1
                        if abs(off_it) <= inlier_m:
                            u_proj += 1
                ro = u_over * inv_m
                rp = u_proj * inv_m
                if ro >= min_overlap and (not use_projection or rp >= min_projection):
                    best = top
                    best_p = rp
                    best_o = ro
            if best >= 0:
                i = cand_id[best]
                out_match[h, j] = i
                out_state[h, j] = 0
                out_proj[h, j] = best_p if use_projection else 1.0
                out_over[h, j] = best_o if use_overlap else 1.0
                # Scene uniqueness counts surfaces: map plane i is not another one when a map plane already matched
                # was among this plane's candidates too (a door recessed in its wall, with the wall around it; a
                # fragment of the same wall).
                seen = False
                for q in range(n_matched):
                    k = matched_ids[q]
                    if k == i:
                        seen = True
                        break
                    for q2 in range(n_c):
                        if cand_id[q2] == k:
                            seen = True
                            break
                    if seen:
                        break
                if not seen:
                    matched_ids[n_matched] = i
                    n_matched += 1
                explained += math.sqrt(sub_areas[j])
                if sub_areas[j] < min_counted_area:
                    small_matched += math.sqrt(sub_areas[j])
            elif step < 3 and require_triplet:
                ok = False
                break
            elif sub_areas[j] >= min_counted_area and m_j > 0:
                # An unmatched plane that counts: in known free space it contradicts the map; near map surfaces
                # facing the same way (within 30 deg) but off its plane it conflicts with them; elsewhere (nothing
                # there, surfaces across it as at a junction, or its own plane mapped only in part) the map does
                # not know.
                inside = 0
                away = 0
                away_free = 0
                near = 0
                close = 0
                for s in range(s0, s1):
                    p = vs_points[s]
                    px = R[h, 0, 0] * p[0] + R[h, 0, 1] * p[1] + R[h, 0, 2] * p[2] + t[h, 0]
                    py = R[h, 1, 0] * p[0] + R[h, 1, 1] * p[1] + R[h, 1, 2] * p[2] + t[h, 1]
                    pz = R[h, 2, 0] * p[0] + R[h, 2, 1] * p[1] + R[h, 2, 2] * p[2] + t[h, 2]
                    is_free = False
                    if n_free_slots > 0:
                        key = _cell_of(px, py, pz, free_voxel)
                        # Membership only: the table's own keys (all >= 0) stand in for the positions.
                        if _find_key(free_slots, free_slots, free_shift, free_mask, key) >= 0:
                            inside += 1
                            is_free = True
                    key = _cell_of(px, py, pz, cell)
                    pos = _find_key(hash_slots, hash_slot_pos, shift, mask, key) if n_slots > 0 else -1
                    if pos < 0:
                        # Away from every map surface: a sample the map can judge (free space is carved up to a
                        # margin short of each surface, so near one a sample is never free, whatever is there).
                        away += 1
                        away_free += 1 if is_free else 0
                    else:
                        far_hit = False
                        close_hit = False
                        on_hit = False
                        for e in range(hash_ptr[pos], hash_ptr[pos + 1]):
                            i = hash_ids[e]
                            if nx * map_normals[i, 0] + ny * map_normals[i, 1] + nz * map_normals[i, 2] >= 0.866:
                                off = abs(map_normals[i, 0] * px + map_normals[i, 1] * py + map_normals[i, 2] * pz
                                          + map_offsets[i])
                                if off > conflict_offset:
                                    far_hit = True
                                elif off > max_offset:
                                    close_hit = True
                                else:
                                    on_hit = True
                        # A sample on a map surface of its own plane (one too small or too sparse to match, e.g. a
                        # door the map saw in part, in front of its wall) is not in conflict with the wall.
                        if on_hit:
                            continue
                        if far_hit:
                            near += 1
                        elif close_hit:
                            close += 1
                frac_free = inside / m_j
                if free_far_min > 0.0 and away >= free_far_min * m_j and away > 0:
                    frac_free = max(frac_free, away_free / away)
                out_free_frac[h, j] = frac_free
                if frac_free > max_free_fraction:
                    n_free += 1
                    out_state[h, j] = 3
                    ok = False
                    break
                if near >= 0.5 * m_j:
                    out_state[h, j] = 2
                elif near + close >= 0.5 * m_j:
                    out_state[h, j] = 5
                else:
                    out_state[h, j] = 1
                    unknown += math.sqrt(sub_areas[j])
            if n_matched + (S - processed) < min_matched:
                ok = False
                break
        out_nmatched[h] = n_matched
        out_free[h] = n_free
        total = large_area + small_matched
        frac = explained / total if total > 0.0 else 0.0
        out_explained[h] = frac
        out_unknown[h] = unknown / total if total > 0.0 else 0.0
        out_pass[h] = ok and n_matched >= min_matched and frac + out_unknown[h] >= min_competitor
    return evaluated


# ---------------------------------------------------------------------------------------------------------------------
# Planes hidden behind map surfaces

HIDDEN_SHRINK = 0.7  # samples keep this share of their distance from their plane's centre (pulled 30 % of the way in)
_HIDDEN_PARALLEL = 0.866  # occluders within 30 degrees of the plane's own orientation are left to the conflict test


@njit
def surface_key(a, b, cell):
    """int64 key of the ``cell`` square holding in-plane coordinates ``(a, b)``."""
    ia = int(math.floor(a / cell)) + _KEY_OFFSET
    ib = int(math.floor(b / cell)) + _KEY_OFFSET
    return (np.int64(ia & _KEY_MASK) << 21) | np.int64(ib & _KEY_MASK)


@njit
def surface_cells(points, owner, bases, cell):
    """(9 N,) keys of the ``cell`` squares around each point's own (and its eight neighbours) in the plane
    ``owner[k]`` (in-plane basis ``bases[owner[k]]``), point by point: the dilated surface of each plane."""
    n = points.shape[0]
    out = np.empty(9 * n, np.int64)
    m = 0
    for k in range(n):
        i = owner[k]
        a = bases[i, 0, 0] * points[k, 0] + bases[i, 0, 1] * points[k, 1] + bases[i, 0, 2] * points[k, 2]
        b = bases[i, 1, 0] * points[k, 0] + bases[i, 1, 1] * points[k, 1] + bases[i, 1, 2] * points[k, 2]
        for da in range(-1, 2):
            for db in range(-1, 2):
                out[m] = surface_key(a + da * cell, b + db * cell, cell)
                m += 1
    return out


@njit
def _on_surface(i, x, y, z, bases, surf_ptr, surf_keys, cell):
    a = bases[i, 0, 0] * x + bases[i, 0, 1] * y + bases[i, 0, 2] * z
    b = bases[i, 1, 0] * x + bases[i, 1, 1] * y + bases[i, 1, 2] * z
    key = surface_key(a, b, cell)
    lo = surf_ptr[i]
    hi = surf_ptr[i + 1]
    pos = _lower_bound(surf_keys, lo, hi, key)
    return pos < hi and surf_keys[pos] == key


@njit
def _crossing(i, ax, ay, az, bx, by, bz, sa, sb, map_centroids, map_radii):
    """Where the segment from ``a`` to ``b`` crosses map plane ``i`` (``sa``, ``sb``: the ends' signed distances to
    it, of opposite signs), and whether that point lies within the plane's radius of its centroid:
    ``(inside, x, y, z)``."""
    f = sa / (sa - sb)
    x = ax + (bx - ax) * f
    y = ay + (by - ay) * f
    z = az + (bz - az) * f
    dx = x - map_centroids[i, 0]
    dy = y - map_centroids[i, 1]
    dz = z - map_centroids[i, 2]
    return dx * dx + dy * dy + dz * dz <= map_radii[i] * map_radii[i], x, y, z


@njit
def _free_between(ax, ay, az, bx, by, bz, free_slots, free_shift, free_mask, free_voxel):
    """Whether a voxel of the map's known free space (:func:`key_table` ``free_slots``, edge ``free_voxel``) lies on
    the segment from ``a`` to ``b``, looked at every half voxel."""
    dx = bx - ax
    dy = by - ay
    dz = bz - az
    n = int(math.ceil(2.0 * math.sqrt(dx * dx + dy * dy + dz * dz) / free_voxel))
    for k in range(1, n):
        f = k / n
        key = _cell_of(ax + f * dx, ay + f * dy, az + f * dz, free_voxel)
        if _find_key(free_slots, free_slots, free_shift, free_mask, key) >= 0:
            return True
    return False


@njit
def _hidden_from(cx, cy, cz, px, py, pz, nx, ny, nz, map_normals, map_offsets, map_centroids, map_radii, bases,
                 surf_ptr, surf_keys, cell, margin, erode, behind, free_slots, free_shift, free_mask, free_voxel,
                 sealed):
    """Whether the line of sight from the camera ``c`` to the point ``p`` (of a plane with normal ``n``) crosses a
    map surface first: a map plane with ``c`` in front of it and ``p`` more than ``margin`` behind it, crossed
    where that plane has surface all around (the crossing and the four points ``erode`` from it along the plane).
    With ``behind``, also a map plane with ``c`` more than ``erode`` behind it and ``p`` more than ``margin`` in
    front: a wall hides from its back too. Nearer than ``erode`` behind it, a camera may be on the far side of a
    plane the map smeared past its edge (flying pixels at a jamb). With ``sealed``, a map surface hides ``p`` only
    where no voxel of the map's known free space (``free_slots`` with its :func:`_table_shape`, edge ``free_voxel``)
    lies between the crossing and ``p``: the map never saw past the surface there (the outside of a building's outer
    wall), where a noisy sensor's map may draw surface across a doorway the cameras saw through."""
    for i in range(map_normals.shape[0]):
        mx = map_normals[i, 0]
        my = map_normals[i, 1]
        mz = map_normals[i, 2]
        if mx * nx + my * ny + mz * nz >= _HIDDEN_PARALLEL:
            continue
        sc = mx * cx + my * cy + mz * cz + map_offsets[i]
        sp = mx * px + my * py + mz * pz + map_offsets[i]
        if sc > 0.05:
            if sp >= -margin:
                continue
        elif not (behind and sc < -erode and sp > margin):
            continue
        inside, x, y, z = _crossing(i, cx, cy, cz, px, py, pz, sc, sp, map_centroids, map_radii)
        if not inside:
            continue
        if not _on_surface(i, x, y, z, bases, surf_ptr, surf_keys, cell):
            continue
        ok = True
        for k in range(2):
            ex = erode * bases[i, k, 0]
            ey = erode * bases[i, k, 1]
            ez = erode * bases[i, k, 2]
            if not (_on_surface(i, x + ex, y + ey, z + ez, bases, surf_ptr, surf_keys, cell)
                    and _on_surface(i, x - ex, y - ey, z - ez, bases, surf_ptr, surf_keys, cell)):
                ok = False
                break
        if ok and not (sealed and _free_between(x, y, z, px, py, pz, free_slots, free_shift, free_mask,
                                                  free_voxel)):
            return True
    return False


@njit
def mark_hidden(R, t, state, sub_normals, vs_ptr, vs_points, views, map_normals, map_offsets, map_centroids,
                map_radii, bases, surf_ptr, surf_keys, cell, margin, erode, min_fraction, exact, out_frac, behind,
                free_slots, free_voxel, sealed):
    """Planes unknown to the map (``state`` 1) under each pose ``(R[h], t[h])`` that the map says the cameras could
    not have seen: at least ``min_fraction`` of their verification samples, moved toward their centre to
    ``HIDDEN_SHRINK`` of their distance from it (off the borders that lines of sight graze), are hidden behind a map
    surface from every camera position of ``views`` (the submap's viewpoints, its frame; with ``behind``, from
    either side of the surface; with ``sealed``, only behind surfaces the map never saw past, :func:`_hidden_from`).
    Their state becomes 6 in place; ``out_frac`` (H, S) float32 gets the hidden fraction of each plane looked at (0
    elsewhere; for a plane not marked, counted only until the samples left could no longer make ``min_fraction``,
    unless ``exact``: then over all its samples). Returns the planes marked.

    A look-alike pose puts what the cameras saw through a doorway, or the side of a door jamb, behind a wall of the
    map, where the map knows nothing (it never saw behind the wall) but where nothing could have been seen either.
    A map surface is known up to ~0.3 m beyond its edges (noise, flying pixels, map samples of 0.1 m cells), so it
    hides a point only where it has surface ``erode`` all around the crossing; a door-sized opening stays open.
    """
    H = R.shape[0]
    S = sub_normals.shape[0]
    V = views.shape[0]
    vx = np.empty(V)
    vy = np.empty(V)
    vz = np.empty(V)
    free_shift, free_mask = _table_shape(free_slots) if sealed else (0, 0)
    marked = 0
    for h in range(H):
        for v in range(V):
            c = views[v]
            vx[v] = R[h, 0, 0] * c[0] + R[h, 0, 1] * c[1] + R[h, 0, 2] * c[2] + t[h, 0]
            vy[v] = R[h, 1, 0] * c[0] + R[h, 1, 1] * c[1] + R[h, 1, 2] * c[2] + t[h, 1]
            vz[v] = R[h, 2, 0] * c[0] + R[h, 2, 1] * c[1] + R[h, 2, 2] * c[2] + t[h, 2]
        for j in range(S):
            out_frac[h, j] = 0.0
            if state[h, j] != 1 or V == 0:
                continue
            s0 = vs_ptr[j]
            s1 = vs_ptr[j + 1]
            m = s1 - s0
            if m == 0:
                continue
            nx = R[h, 0, 0] * sub_normals[j, 0] + R[h, 0, 1] * sub_normals[j, 1] + R[h, 0, 2] * sub_normals[j, 2]
            ny = R[h, 1, 0] * sub_normals[j, 0] + R[h, 1, 1] * sub_normals[j, 1] + R[h, 1, 2] * sub_normals[j, 2]
            nz = R[h, 2, 0] * sub_normals[j, 0] + R[h, 2, 1] * sub_normals[j, 1] + R[h, 2, 2] * sub_normals[j, 2]
            mx = 0.0
            my = 0.0
            mz = 0.0
            for s in range(s0, s1):
                mx += vs_points[s, 0]
                my += vs_points[s, 1]
                mz += vs_points[s, 2]
            mx /= m
            my /= m
            mz /= m
            need = min_fraction * m
            hidden = 0
            for s in range(s0, s1):
                if not exact and hidden + (s1 - s) < need:
                    break
                qx = mx + HIDDEN_SHRINK * (vs_points[s, 0] - mx)
                qy = my + HIDDEN_SHRINK * (vs_points[s, 1] - my)
                qz = mz + HIDDEN_SHRINK * (vs_points[s, 2] - mz)
                px = R[h, 0, 0] * qx + R[h, 0, 1] * qy + R[h, 0, 2] * qz + t[h, 0]
                py = R[h, 1, 0] * qx + R[h, 1, 1] * qy + R[h, 1, 2] * qz + t[h, 1]
                pz = R[h, 2, 0] * qx + R[h, 2, 1] * qy + R[h, 2, 2] * qz + t[h, 2]
                every = True
                for v in range(V):
                    if not _hidden_from(vx[v], vy[v], vz[v], px, py, pz, nx, ny, nz, map_normals, map_offsets,
                                        map_centroids, map_radii, bases, surf_ptr, surf_keys, cell, margin, erode,
                                        behind, free_slots, free_shift, free_mask, free_voxel, sealed):
                        every = False
                        break
                if every:
                    hidden += 1
            frac = hidden / m
            out_frac[h, j] = frac
            if hidden >= need:
                state[h, j] = 6
                marked += 1
    return marked


@njit
def _walks_through(ax, ay, az, bx, by, bz, map_normals, map_offsets, map_centroids, map_radii, bases, surf_ptr,
                   surf_keys, cell, margin, reach, up):
    """Whether the step from ``a`` to ``b`` goes through a wall of the map: a map plane of normal at least 60 degrees
    from ``up`` (the map's unit up), with one end more than ``margin`` in front of it and the other more than
    ``margin`` behind, crossed where the plane has surface, and surface on along its horizontal every ``cell`` up to
    ``reach`` on both sides. A doorway the map saw narrowed by its edges' samples still leaves a gap within
    ``reach`` of any step through it."""
    for i in range(map_normals.shape[0]):
        mx = map_normals[i, 0]
        my = map_normals[i, 1]
        mz = map_normals[i, 2]
        if abs(mx * up[0] + my * up[1] + mz * up[2]) > 0.5:
            continue
        sa = mx * ax + my * ay + mz * az + map_offsets[i]
        sb = mx * bx + my * by + mz * bz + map_offsets[i]
        if not ((sa > margin and sb < -margin) or (sa < -margin and sb > margin)):
            continue
        inside, x, y, z = _crossing(i, ax, ay, az, bx, by, bz, sa, sb, map_centroids, map_radii)
        if not inside:
            continue
        # The plane's horizontal direction: n x up.
        hx = my * up[2] - mz * up[1]
        hy = mz * up[0] - mx * up[2]
        hz = mx * up[1] - my * up[0]
        hn = math.sqrt(hx * hx + hy * hy + hz * hz)
        hx /= hn
        hy /= hn
        hz /= hn
        solid = _on_surface(i, x, y, z, bases, surf_ptr, surf_keys, cell)
        k = 1
        while solid and k * cell <= reach + 1e-9:
            e = k * cell
            solid = (_on_surface(i, x + e * hx, y + e * hy, z + e * hz, bases, surf_ptr, surf_keys, cell)
                     and _on_surface(i, x - e * hx, y - e * hy, z - e * hz, bases, surf_ptr, surf_keys, cell))
            k += 1
        if solid:
            return True
    return False


@njit
def path_blocked(R, t, views, min_step, map_normals, map_offsets, map_centroids, map_radii, bases, surf_ptr,
                 surf_keys, cell, margin, reach, up, out):
    """Whether the camera path of a submap, under each pose ``(R[h], t[h])``, walks through a wall of the map
    (:func:`_walks_through`; walls are planes whose normals are at least 60 degrees from ``up``, the map's unit
    up): ``out[h]``. The path is ``views`` (V, 3), the submap's camera positions in order (its
    frame), taken in steps of at least ``min_step`` (a step of a few centimetres cannot be both in front of a wall
    and behind it); each step is judged, and so is each pair of steps (a point of the path within ``margin`` of a
    wall is on neither side of it)."""
    H = R.shape[0]
    V = views.shape[0]
    px = np.empty(V)
    py = np.empty(V)
    pz = np.empty(V)
    for h in range(H):
        out[h] = False
        if V < 2:
            continue
        n = 0
        for v in range(V):
            x = R[h, 0, 0] * views[v, 0] + R[h, 0, 1] * views[v, 1] + R[h, 0, 2] * views[v, 2] + t[h, 0]
            y = R[h, 1, 0] * views[v, 0] + R[h, 1, 1] * views[v, 1] + R[h, 1, 2] * views[v, 2] + t[h, 1]
            z = R[h, 2, 0] * views[v, 0] + R[h, 2, 1] * views[v, 1] + R[h, 2, 2] * views[v, 2] + t[h, 2]
            if n > 0 and v < V - 1 and (x - px[n - 1]) ** 2 + (y - py[n - 1]) ** 2 + (z - pz[n - 1]) ** 2 < (
                    min_step * min_step):
                continue
            px[n] = x
            py[n] = y
            pz[n] = z
            n += 1
            for back in range(2, 4):
                if n >= back and _walks_through(px[n - back], py[n - back], pz[n - back], x, y, z, map_normals,
                                                map_offsets, map_centroids, map_radii, bases, surf_ptr, surf_keys,
                                                cell, margin, reach, up):
                    out[h] = True
                    break
            if out[h]:
                break


# ---------------------------------------------------------------------------------------------------------------------
# Kernel density over SE(3) and modes


@njit
def _log_se3_into(R, t, out):
    """``out`` (6,) = log of the rigid transform (R, t) as ``[rho, phi]``."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    vx = R[2, 1] - R[1, 2]
    vy = R[0, 2] - R[2, 0]
    vz = R[1, 0] - R[0, 1]
    s = 0.5 * math.sqrt(vx * vx + vy * vy + vz * vz)
    cth = 0.5 * (tr - 1.0)
    theta = math.atan2(s, cth)
    if theta < 1e-6:
        px, py, pz = 0.5 * vx, 0.5 * vy, 0.5 * vz
    elif math.pi - theta < 1e-4:
        # Axis from the symmetric part near pi.
        b00 = 0.5 * (R[0, 0] + 1.0)
        b11 = 0.5 * (R[1, 1] + 1.0)
        b22 = 0.5 * (R[2, 2] + 1.0)
        if b00 >= b11 and b00 >= b22:
            ax, ay, az = b00, 0.5 * (R[0, 1] + R[1, 0]) * 0.5, 0.5 * (R[0, 2] + R[2, 0]) * 0.5
        elif b11 >= b22:
            ax, ay, az = 0.5 * (R[1, 0] + R[0, 1]) * 0.5, b11, 0.5 * (R[1, 2] + R[2, 1]) * 0.5
        else:
            ax, ay, az = 0.5 * (R[2, 0] + R[0, 2]) * 0.5, 0.5 * (R[2, 1] + R[1, 2]) * 0.5, b22
        nrm = math.sqrt(ax * ax + ay * ay + az * az)
        ax /= nrm
        ay /= nrm
        az /= nrm
        if ax * vx + ay * vy + az * vz < 0.0:
            ax, ay, az = -ax, -ay, -az
        px, py, pz = ax * theta, ay * theta, az * theta
    else:
        f = theta / (2.0 * math.sin(theta))
        px, py, pz = vx * f, vy * f, vz * f
    # V^-1 = I - K/2 + coef K^2 with K = hat(phi).
    if theta < 1e-8:
        coef = 1.0 / 12.0
    else:
        half = 0.5 * theta
        coef = (1.0 - half * math.cos(half) / math.sin(half)) / (theta * theta)
    # K t and K K t.
    kx = py * t[2] - pz * t[1]
    ky = pz * t[0] - px * t[2]
    kz = px * t[1] - py * t[0]
    kkx = py * kz - pz * ky
    kky = pz * kx - px * kz
    kkz = px * ky - py * kx
    out[0] = t[0] - 0.5 * kx + coef * kkx
    out[1] = t[1] - 0.5 * ky + coef * kky
    out[2] = t[2] - 0.5 * kz + coef * kkz
    out[3] = px
    out[4] = py
    out[5] = pz


@njit
def relative_log(Ra, ta, Rb, tb, Rrel, trel, out):
    """``out`` = log(T_a^-1 T_b) (6,), using the (3, 3) and (3,) scratch arrays ``Rrel``, ``trel``."""
    for r in range(3):
        for c in range(3):
            s = 0.0
            for k in range(3):
                s += Ra[k, r] * Rb[k, c]
            Rrel[r, c] = s
        s = 0.0
        for k in range(3):
            s += Ra[k, r] * (tb[k] - ta[k])
        trel[r] = s
    _log_se3_into(Rrel, trel, out)


@njit
def kde_density(R, t, weights, info_diag, out):
    """Eq. 14 at every candidate pose: ``out[a] = sum_b w_b exp(-xi^T I xi)``, ``xi = log(T_a^-1 T_b)``.

    ``R`` (H, 3, 3), ``t`` (H, 3), ``weights`` (H,), ``info_diag`` (6,) the diagonal of the information matrix;
    ``out`` (H,) (not normalized).
    """
    H = R.shape[0]
    Rrel = np.empty((3, 3))
    trel = np.empty(3)
    xi = np.empty(6)
    # Pairs farther apart than the kernel reaches (exp(-50)) are skipped before the log map.
    t_info = info_diag[0]
    r_info = info_diag[3]
    for a in range(H):
        acc = 0.0
        for b in range(H):
            if weights[b] == 0.0:
                continue
            dx = t[a, 0] - t[b, 0]
            dy = t[a, 1] - t[b, 1]
            dz = t[a, 2] - t[b, 2]
            if t_info * (dx * dx + dy * dy + dz * dz) > 200.0:
                continue
            tr = 0.0
            for r in range(3):
                for c in range(3):
                    tr += R[a, r, c] * R[b, r, c]
            ca = 0.5 * (tr - 1.0)
            if ca < 1.0:
                ang = math.acos(max(ca, -1.0))
                if r_info * ang * ang > 50.0:
                    continue
            relative_log(R[a], t[a], R[b], t[b], Rrel, trel, xi)
            q = 0.0
            for k in range(6):
                q += info_diag[k] * xi[k] * xi[k]
            if q < 50.0:
                acc += weights[b] * math.exp(-q)
        out[a] = acc


@njit
def group_poses(R, t, order, max_translation, max_rotation_rad, out_group):
    """Greedy modes: poses taken in ``order`` join the first earlier group whose leader lies within both
    thresholds, else start a group. ``out_group`` (H,) int32 receives group ids (0 = the group of ``order[0]``);
    returns the leaders' indices (G,) int32."""
    H = R.shape[0]
    leaders = np.empty(H, np.int32)
    n_groups = 0
    cos_max = math.cos(max_rotation_rad)
    for q in range(H):
        a = order[q]
        group = -1
        for g in range(n_groups):
            b = leaders[g]
            dx = t[a, 0] - t[b, 0]
            dy = t[a, 1] - t[b, 1]
            dz = t[a, 2] - t[b, 2]
            if dx * dx + dy * dy + dz * dz > max_translation * max_translation:
                continue
            tr = 0.0
            for r in range(3):
                for c in range(3):
                    tr += R[a, r, c] * R[b, r, c]
            if 0.5 * (tr - 1.0) < cos_max:
                continue
            group = g
            break
        if group < 0:
            leaders[n_groups] = a
            group = n_groups
            n_groups += 1
        out_group[a] = group
    return leaders[:n_groups].copy()


@register_warmup
def _warmup() -> None:
    """Compile every kernel on a tiny problem: three perpendicular planes matched to themselves."""
    normals = np.eye(3)
    offsets = np.array([-1.0, -2.0, -3.0])
    centroids = -normals * offsets[:, None]
    radii = np.ones(3)
    areas = np.ones(3)
    facing = np.array([0, 0, 1], np.int8)
    first, second, ang = build_pairs(normals, centroids, radii, 0.1, 3.0, True, 10.0)
    order = np.argsort(ang, kind="stable")
    first, second, ang = first[order], second[order], ang[order]
    adj_ptr = np.zeros(4, np.int64)
    for i in first:
        adj_ptr[i + 1] += 1
    adj_ptr = np.cumsum(adj_ptr)
    adj_ids = second.astype(np.int32)
    adj_ang = ang.copy()
    trip = np.array([[2, 0, 1]], np.int32)
    face0 = np.ones(1, np.int8)
    gaps = np.full((1, 3), 10.0)
    out = np.empty((16, 6), np.int32)
    sptr = np.arange(4, dtype=np.int64)
    pext = pair_extents(first, second, normals, offsets, sptr, centroids)
    dext = dense_extents(normals, offsets, sptr, centroids)
    trimmed_extents(normals, offsets, np.array([0, 3, 3, 3], np.int64), centroids, 0.5)
    join_candidates(trip, face0, gaps, dext, normals, areas, normals, centroids, radii, areas, facing, first, second,
                    ang, pext, adj_ptr, adj_ids, adj_ang, pext, 0.1, True, True, True, 0.5, 0.2, True, 0.3, out)
    brute_force_candidates(trip, face0, gaps, dext, normals, areas, normals, centroids, radii, areas, facing, dext, 0.1,
                           True, True, True, 0.5, 0.2, True, 0.3, out)
    cand = np.array([[0, 1, 2, 0, 1, 2]], np.int32)
    Rs = np.empty((1, 3, 3))
    ts = np.empty((1, 3))
    st = np.empty(1, np.int8)
    triplet_transforms(cand, normals, offsets, normals, offsets, 0.2, 50.0, 0.2, Rs, ts, st)
    pts = centroids.copy()
    keys = cell_keys(pts, 0.25)
    dk, di = dilate_keys(keys, np.arange(3, dtype=np.int32))
    o = np.argsort(dk, kind="stable")
    dk, di = dk[o], di[o]
    uk, starts = np.unique(dk, return_index=True)
    hptr = np.append(starts, dk.shape[0]).astype(np.int64)
    slots, slot_pos = key_table(uk)
    vs_ptr = np.arange(4, dtype=np.int64)
    S = 3
    om = np.empty((1, S), np.int32)
    op = np.empty((1, S), np.float32)
    oo = np.empty((1, S), np.float32)
    on = np.empty(1, np.int32)
    oe = np.empty(1)
    ou = np.empty(1)
    ost = np.empty((1, S), np.int8)
    of = np.empty(1, np.int32)
    ok = np.empty(1, np.bool_)
    off = np.empty((1, S), np.float32)
    for use_overlap in (True, False):
        verify_transforms(Rs, ts, cand, np.arange(3, dtype=np.int32), normals, offsets, centroids, areas, vs_ptr, pts,
                          normals, offsets, areas, 0.5, slots, slot_pos, hptr, di, 0.25, 0.99, 0.1, 0.05, True,
                          0.5, use_overlap, 0.3, 3, 0.5, 0.3, slots, 0.25, 0.5, 0.25, True, 0.1, np.ones((S, 2)), om,
                          op, oo, ost, on, oe, ou, of, ok, off)
    bases = np.zeros((3, 2, 3))
    bases[:, 0] = normals[[1, 2, 0]]
    bases[:, 1] = normals[[2, 0, 1]]
    skeys = np.unique(surface_cells(pts, np.zeros(3, np.int64), bases, 0.1))[:1]
    sptr3 = np.array([0, 1, 1, 1], np.int64)
    hid = np.ones((1, S), np.int8)
    mark_hidden(Rs, ts, hid, normals, vs_ptr, pts, np.zeros((1, 3)), normals, offsets, centroids, radii, bases,
                sptr3, skeys, 0.1, 0.04, 0.3, 0.5, True, np.empty((1, S), np.float32), True, slots, 0.25, False)
    mark_hidden(Rs, ts, hid, normals, vs_ptr, pts, np.zeros((1, 3)), normals, offsets, centroids, radii, bases,
                sptr3, skeys, 0.1, 0.04, 0.3, 0.5, True, np.empty((1, S), np.float32), True, slots, 0.25, True)
    path_blocked(Rs, ts, np.array([[0.0, 0.0, 2.0], [0.0, 0.0, -2.0]]), 0.3, normals, offsets, centroids, radii,
                 bases, sptr3, skeys, 0.1, 0.05, 0.5, np.array([0.0, 0.0, 1.0]), np.empty(1, np.bool_))
    dens = np.empty(1)
    kde_density(Rs, ts, np.ones(1), np.ones(6), dens)
    grp = np.empty(1, np.int32)
    group_poses(Rs, ts, np.zeros(1, np.int64), 0.25, 0.1, grp)


@njit
def farthest_point_samples(points, ptr, m, out_ptr, out_points):
    """Up to ``m`` samples per plane by farthest-point sampling (CSR in, CSR out).

    ``points`` (M, 3) float64 with rows ``ptr[j]:ptr[j + 1]`` for plane j; the first pick is the point farthest
    from the plane's mean, so the result does not depend on the order of the points. ``out_ptr`` (S + 1,) and
    ``out_points`` (>= S * m, 3) receive the result; returns the number of points written.
    """
    S = ptr.shape[0] - 1
    written = 0
    out_ptr[0] = 0
    maxlen = 0
    for j in range(S):
        if ptr[j + 1] - ptr[j] > maxlen:
            maxlen = ptr[j + 1] - ptr[j]
    dist = np.empty(maxlen)
    for j in range(S):
        s0 = ptr[j]
        n = ptr[j + 1] - s0
        if n > 0:
            mx = 0.0
            my = 0.0
            mz = 0.0
            for k in range(n):
                mx += points[s0 + k, 0]
                my += points[s0 + k, 1]
                mz += points[s0 + k, 2]
            mx /= n
            my /= n
            mz /= n
            for k in range(n):
                dx = points[s0 + k, 0] - mx
                dy = points[s0 + k, 1] - my
                dz = points[s0 + k, 2] - mz
                dist[k] = dx * dx + dy * dy + dz * dz
            take = m if m < n else n
            for q in range(take):
                best = 0
                for k in range(1, n):
                    if dist[k] > dist[best]:
                        best = k
                px = points[s0 + best, 0]
                py = points[s0 + best, 1]
                pz = points[s0 + best, 2]
                out_points[written, 0] = px
                out_points[written, 1] = py
                out_points[written, 2] = pz
                written += 1
                for k in range(n):
                    dx = points[s0 + k, 0] - px
                    dy = points[s0 + k, 1] - py
                    dz = points[s0 + k, 2] - pz
                    d = dx * dx + dy * dy + dz * dz
                    if q == 0 or d < dist[k]:
                        dist[k] = d
        out_ptr[j + 1] = written
    return written


@register_warmup
def _warmup_fps() -> None:
    pts = np.random.default_rng(0).random((10, 3))
    out_ptr = np.empty(3, np.int64)
    out = np.empty((8, 3))
    farthest_point_samples(pts, np.array([0, 6, 10], np.int64), 4, out_ptr, out)


@njit
def sample_set_distances(ptr, points, out):
    """``out`` (S, S): the smallest distance between the samples of every two planes (CSR ``ptr``, ``points``
    (M, 3) float64), 0 on the diagonal. Every plane must have a sample. The same numbers, bit for bit, as the
    smallest entries of the full (M, M) distance matrix, without building it (squared distances summed in the same
    order; the square root taken of the smallest, which is the smallest root)."""
    S = ptr.shape[0] - 1
    for a in range(S):
        out[a, a] = 0.0
        for b in range(a + 1, S):
            best = np.inf
            for i in range(ptr[a], ptr[a + 1]):
                px, py, pz = points[i, 0], points[i, 1], points[i, 2]
                for k in range(ptr[b], ptr[b + 1]):
                    dx = px - points[k, 0]
                    dy = py - points[k, 1]
                    dz = pz - points[k, 2]
                    d = dx * dx + dy * dy + dz * dz
                    if d < best:
                        best = d
            out[a, b] = math.sqrt(best)
            out[b, a] = out[a, b]


@register_warmup
def _warmup_sample_set_distances() -> None:
    out = np.empty((2, 2))
    sample_set_distances(np.array([0, 2, 3], np.int64), np.random.default_rng(0).random((3, 3)), out)
