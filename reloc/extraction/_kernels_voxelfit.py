"""Numba kernels: the plane of each voxel (PCA and planarity test), then its weighted refit (paper Eq. 2-3 and more).

Points are relative to the sensor (at the origin, z its viewing direction).

Voxel flags: ``FEW`` (fewer points than the minimum), ``NOT_PLANAR`` (failed a planarity test or the refit),
``PLANAR``.

Planarity of a voxel with PCA eigenvalues ``l0 <= l1 <= l2`` and depth noise ``sigma = sigma_z(z_centroid)``:
- thickness: ``sqrt(l0) <= max(k_thick * sigma, floor)``;
- flatness beyond the noise: ``max(l0 - sigma^2, 0) <= max_ratio * l1`` (the paper's eigenvalue ratio, made
  depth-aware: at 5 m the Kinect noise alone gives ``l0 / l1 ~ 0.25`` in a 0.25 m voxel);
- a well-defined normal: ``sqrt(l0 / (n l1)) <= max_normal_std`` (its angular standard deviation, radians).
"""

from __future__ import annotations

import math

import numpy as np

from reloc._numba import njit, register_warmup
from reloc.extraction._kernels_fit import MIN_INCIDENCE, distance_sigma, noise_weight, point_sigma
from reloc.extraction._kernels_linalg import plane_from_moments
# numba caches a kernel with the kernels it calls compiled in, keyed on this file's stamp only: a change to the
# plane solvers in _kernels_linalg (closed-form eigen, smallest_eig3) goes with an edit here.

FEW = 0
NOT_PLANAR = 1
PLANAR = 2


@njit(error_model="numpy")
def voxel_pca_planes(counts, sums, scatters, nv, min_points, power, coeff, thick_sigmas, thick_floor, max_ratio,
                     max_normal_std, planes, eig, normal_std, flags):
    """PCA plane and planarity flag of each voxel from its moments.

    Writes ``planes[v]`` (4,) ``[n, d]`` with the normal toward the sensor, ``eig[v]`` (3,) ascending eigenvalues of
    the point covariance, ``normal_std[v]`` (radians) and ``flags[v]``. Returns the number of planar voxels.
    """
    A = np.empty((3, 3))
    w = np.empty(3)
    V = np.empty((3, 3))
    zero = np.zeros(3)
    n_planar = 0
    for v in range(nv):
        n = counts[v]
        if n < min_points:
            flags[v] = FEW
            planes[v, :] = 0.0
            eig[v, :] = 0.0
            normal_std[v] = np.inf
            continue
        nx, ny, nz, d, l0, l1, l2 = plane_from_moments(float(n), sums[v], scatters[v], zero, A, w, V)
        if d < 0.0:
            nx, ny, nz, d = -nx, -ny, -nz, -d
        planes[v, 0] = nx
        planes[v, 1] = ny
        planes[v, 2] = nz
        planes[v, 3] = d
        eig[v, 0] = l0
        eig[v, 1] = l1
        eig[v, 2] = l2
        sig = point_sigma(sums[v, 2] / n, power, coeff)
        std = math.sqrt(l0 / (n * l1)) if l1 > 0.0 else np.inf
        normal_std[v] = std
        ok = math.sqrt(l0) <= max(thick_sigmas * sig, thick_floor)
        ok = ok and max(l0 - sig * sig, 0.0) <= max_ratio * l1
        ok = ok and std <= max_normal_std
        if ok:
            flags[v] = PLANAR
            n_planar += 1
        else:
            flags[v] = NOT_PLANAR
    return n_planar


@njit(error_model="numpy")
def _keep(bits, j, step):
    """Whether point ``j`` is in the 1-in-``step`` subsample (``step`` a power of two): a hash of its coordinates'
    bits, so the choice does not depend on the order of the points."""
    # The low mantissa bits of measured coordinates are as good as random, and cheap to mix.
    return ((bits[j, 0] ^ bits[j, 1] ^ bits[j, 2]) >> 1) & (step - 1) == 0


@njit(error_model="numpy")
def _keep_flat(bits, j3, mask):
    """:func:`_keep` on the flat view ``bits`` (3 M,) of the points' bits, ``j3 = 3 j`` (unsigned) and ``mask =
    step - 1``."""
    return ((bits[j3] ^ bits[j3 + np.uint64(1)] ^ bits[j3 + np.uint64(2)]) >> 1) & mask == 0


@njit(error_model="numpy")
def pow2_step(n, max_points):
    """Smallest power of two ``k`` with ``n / k <= max_points``."""
    k = 1
    while n > k * max_points:
        k *= 2
    return k


@njit(fastmath={"reassoc", "contract"}, error_model="numpy")
def _weighted_pass(qx, qy, qz, base, gz, mloc, nx, ny, nz, e0, d, cz, use_robust, ray_mode, inv_lim2):
    """Weighted moments of one IRLS pass over a voxel's local points (branch-free, so it vectorises): returns
    ``(W, s (3), S (6 upper), n_nonzero, sum wr u^2, sum wr)``."""
    W = s0 = s1 = s2 = s00 = s01 = s02 = s11 = s12 = s22 = 0.0
    su2 = sw = 0.0
    ne = 0
    for k in range(mloc):
        x = qx[k]
        y = qy[k]
        z = qz[k]
        wi = base[k]
        if use_robust:
            npq = nx * x + ny * y + nz * z
            if ray_mode:
                zz = z + cz
                zz = zz if zz > 1e-3 else 1e-3
                an = abs(npq + e0)
                lo = MIN_INCIDENCE * zz
                u = (npq + e0 + d) * gz[k] / (an if an > lo else lo)
            else:
                u = (npq + e0 + d) * gz[k]
            t = 1.0 - u * u * inv_lim2
            wr = t * t if t > 0.0 else 0.0
            su2 += wr * u * u
            sw += wr
            wi *= wr
        ne += 1 if wi > 0.0 else 0
        W += wi
        s0 += wi * x
        s1 += wi * y
        s2 += wi * z
        s00 += wi * x * x
        s01 += wi * x * y
        s02 += wi * x * z
        s11 += wi * y * y
        s12 += wi * y * z
        s22 += wi * z * z
    return W, s0, s1, s2, s00, s01, s02, s11, s12, s22, ne, su2, sw


@njit(error_model="numpy")
def voxel_weighted_refit(sorted_pts, point_bits, voxel_start, nv, counts, sums, flags, eig, power, coeff, ray_mode,
                         use_noise, use_position, alpha, beta, irls_iterations, kernel_c, max_points, thick_sigmas,
                         thick_floor, max_ratio, max_normal_std, min_inlier_fraction, planes, wmom, wscat, n_eff,
                         radius):
    """Weighted refit of the voxel planes, and (with the robust weight) the planarity test on its inliers.

    Refit: weights ``pos * noise * robust`` (see ``_kernels_fit``); the robust scale starts at
    ``max(1, sqrt(l0) / sigma_centroid)`` and is the Tukey-weighted RMS of the normalised residuals (at least 1)
    afterwards; ``irls_iterations`` passes with the robust weight, one without. ``ray_mode`` sets the per-point
    sigma and weight; the voxel plane itself is solved by weighted total least squares (the voxel faces cut the
    noisy surface along the depth axis, which biases the ray-form regression more than TLS).

    Which voxels: without the robust weight, the planar ones of :func:`voxel_pca_planes`. With it, every voxel
    with enough points whose PCA spectrum is not a blob (``l0 < l1 / 2``), and the planarity test is made again on
    the robust fit: Tukey-weighted RMS distance, the noise-corrected eigenvalue ratio and the normal's standard
    deviation of the weighted covariance, and Tukey weights summing to at least ``min_inlier_fraction`` of the
    points (about 0.81 of them for a clean plane with Gaussian noise).
    So a voxel that holds a wall and 2 % of another surface (a corner) is a plane of the wall, not rejected.

    A voxel with more than ``max_points`` points is refit from about 1 in k of them (chosen by a hash of their
    coordinates, ``point_bits`` = ``sorted_pts`` viewed as int32, so not by their order) with weights scaled to
    stand for all its points: a voxel near the camera holds thousands of points, far more than its plane (used for
    growth, and refined from all points later) needs.

    Updates ``planes[v]`` and ``flags[v]``; writes the weighted moments about the origin (``wmom[v] = [W, sum w p]``
    (4,), ``wscat[v] = sum w p p^T`` (3, 3)), ``n_eff[v]`` (points with a non-zero weight, times k) and
    ``radius[v]`` (largest distance of a voxel point from the voxel centroid).
    """
    A = np.empty((3, 3))
    w3 = np.empty(3)
    V = np.empty((3, 3))
    s = np.empty(3)
    S = np.empty((3, 3))
    ref = np.empty(3)
    cap = 2 * max_points + 16
    qx = np.empty(cap)
    qy = np.empty(cap)
    qz = np.empty(cap)
    base = np.empty(cap)
    gz = np.empty(cap)
    # Room for every point of the largest voxel: the subsample loop below runs to the voxel's end without a test.
    n_pick = cap + 1
    for v in range(nv):
        n_pick = max(n_pick, voxel_start[v + 1] - voxel_start[v] + 1)
    pick = np.empty(n_pick, np.int32)
    flat = sorted_pts.reshape(-1)  # C-contiguous (M, 3)
    bits = point_bits.reshape(-1)
    use_robust = irls_iterations > 0
    n_pass = max(irls_iterations, 1)
    for v in range(nv):
        if flags[v] == FEW:
            continue
        if use_robust:
            if not eig[v, 0] < 0.5 * eig[v, 1]:
                flags[v] = NOT_PLANAR
                continue
        elif flags[v] != PLANAR:
            continue
        a = voxel_start[v]
        b = voxel_start[v + 1]
        cnt = counts[v]
        step = pow2_step(b - a, max_points)
        cx = sums[v, 0] / cnt
        cy = sums[v, 1] / cnt
        cz = sums[v, 2] / cnt
        ref[0] = cx
        ref[1] = cy
        ref[2] = cz
        # Local copies of the (sub)sampled points about the centroid, and their plane-independent weights.
        mloc = 0
        r2max = 0.0
        if step > 1:
            # The subsample's indices without a branch (one on the hash mispredicts about once in k points, and
            # one leaving the loop at ``cap`` costs a compare per point), then only its first ``cap`` points are read.
            # Flat views and unsigned indices (no stride products, no test for an index from the end).
            n_keep = 0
            mask = step - 1
            for j in range(a, b):
                pick[np.uint64(n_keep)] = j
                n_keep += 1 if _keep_flat(bits, np.uint64(3 * j), mask) else 0
            n_keep = min(n_keep, cap)
        else:
            n_keep = min(b - a, cap)
            for i in range(n_keep):
                pick[i] = a + i
        for i in range(n_keep):
            j3 = np.uint64(3 * pick[np.uint64(i)])
            x = flat[j3] - cx
            y = flat[j3 + np.uint64(1)] - cy
            z = flat[j3 + np.uint64(2)] - cz
            um = np.uint64(mloc)
            qx[um] = x
            qy[um] = y
            qz[um] = z
            r2max = max(r2max, x * x + y * y + z * z)
            mloc += 1
        r_max = math.sqrt(r2max)
        radius[v] = r_max
        inv_r2max = 1.0 / r2max if r2max > 0.0 else 0.0
        for k in range(mloc):
            pz = qz[k] + cz
            sz = point_sigma(pz, power, coeff)
            wb = 1.0
            if use_noise:
                wb = noise_weight(pz, sz, sz, ray_mode) if ray_mode else 1.0 / (sz * sz)
            if use_position:
                rho2 = (qx[k] * qx[k] + qy[k] * qy[k] + qz[k] * qz[k]) * inv_r2max
                if rho2 <= 0.25:
                    wb *= max(1.0 - alpha * rho2, 0.0)
                else:
                    wb *= math.exp(-beta * rho2)
            base[k] = wb
            # u = |r| * gz / f with f = max(|n . p|, MIN_INCIDENCE z) (ray) or f = 1 (normal).
            gz[k] = max(pz, 1e-3) / sz if ray_mode else 1.0 / sz
        nx = planes[v, 0]
        ny = planes[v, 1]
        nz = planes[v, 2]
        d = planes[v, 3]
        sig_c = distance_sigma(cx, cy, cz, nx, ny, nz, point_sigma(cz, power, coeff), ray_mode)
        scale = max(1.0, math.sqrt(eig[v, 0]) / sig_c)
        W = 0.0
        ne = 0
        su2 = 0.0
        sw = 0.0
        l0 = l1 = 0.0
        for _it in range(n_pass):
            inv_lim2 = 1.0 / (kernel_c * scale) ** 2
            e0 = nx * cx + ny * cy + nz * cz
            W, s0, s1, s2, s00, s01, s02, s11, s12, s22, ne, su2, sw = _weighted_pass(
                qx, qy, qz, base, gz, mloc, nx, ny, nz, e0, d, cz, use_robust, ray_mode, inv_lim2)
            s[0] = s0
            s[1] = s1
            s[2] = s2
            S[0, 0] = s00
            S[0, 1] = s01
            S[0, 2] = s02
            S[1, 1] = s11
            S[1, 2] = s12
            S[2, 2] = s22
            if ne < 3:
                break
            S[1, 0] = S[0, 1]
            S[2, 0] = S[0, 2]
            S[2, 1] = S[1, 2]
            mx, my, mz, md, l0, l1, _l2 = plane_from_moments(W, s, S, ref, A, w3, V)
            if mx * nx + my * ny + mz * nz < 0.0:
                mx, my, mz, md = -mx, -my, -mz, -md
            nx, ny, nz, d = mx, my, mz, md
            if sw > 0.0:
                scale = max(1.0, math.sqrt(su2 / sw))
        if ne < 3:
            flags[v] = NOT_PLANAR
            continue
        if use_robust:
            # Planarity of the inliers (moments are about the centroid, so the eigenvalues are centred ones).
            sig = point_sigma(cz, power, coeff)
            thick = max(thick_sigmas * sig, thick_floor)
            std = math.sqrt(l0 / (ne * l1)) if l1 > 0.0 else np.inf
            ok = l0 <= thick * thick and max(l0 - sig * sig, 0.0) <= max_ratio * l1 and std <= max_normal_std
            ok = ok and sw >= min_inlier_fraction * mloc
            flags[v] = PLANAR if ok else NOT_PLANAR
            if not ok:
                continue
        if d < 0.0:
            nx, ny, nz, d = -nx, -ny, -nz, -d
        planes[v, 0] = nx
        planes[v, 1] = ny
        planes[v, 2] = nz
        planes[v, 3] = d
        # Moments about the origin: sum w p = s + W c; sum w p p^T = S + s c^T + c s^T + W c c^T, scaled from the
        # subsample to all points.
        f = (b - a) / mloc
        n_eff[v] = int(round(ne * f))
        W *= f
        for i in range(3):
            s[i] *= f
            for k in range(3):
                S[i, k] *= f
        wmom[v, 0] = W
        for i in range(3):
            wmom[v, 1 + i] = s[i] + W * ref[i]
            for k in range(3):
                wscat[v, i, k] = S[i, k] + s[i] * ref[k] + ref[i] * s[k] + W * ref[i] * ref[k]


@register_warmup
def _warmup() -> None:
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(0, 0.2, 40), rng.uniform(0, 0.2, 40), 2.0 + 0.001 * rng.normal(size=40)])
    pts = pts.astype(np.float32)
    start = np.array([0, 40], np.int64)
    counts = np.array([40], np.int64)
    p64 = pts.astype(np.float64)
    sums = p64.sum(0)[None].copy()
    scat = (p64.T @ p64)[None].copy()
    planes = np.zeros((1, 4))
    eig = np.zeros((1, 3))
    nstd = np.zeros(1)
    flags = np.zeros(1, np.int8)
    voxel_pca_planes(counts, sums, scat, 1, 10, 2, 1.425e-3, 4.0, 0.01, 0.05, 0.1, planes, eig, nstd, flags)
    for ray in (True, False):
        flags[0] = PLANAR
        voxel_weighted_refit(pts, pts.view(np.int32), start, 1, counts, sums, flags, eig, 2, 1.425e-3, ray, True,
                             True, 0.5, 2.0, 2,
                             3.0, 16, 4.0, 0.01, 0.05, 0.1, 0.7, planes, np.zeros((1, 4)), np.zeros((1, 3, 3)),
                             np.zeros(1, np.int64), np.zeros(1))
