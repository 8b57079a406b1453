"""Numba kernels: robust weighted plane fit of one point set (RANSAC start, then IRLS with per-point sigmas).

Points are relative to the sensor (the sensor at the origin, z its viewing direction); callers shift them.
Per-point sigma of the distance to the plane, from the depth noise law ``sigma_z = coeff * z**power``:
- ``ray_mode`` false: ``sigma_i = sigma_z(z_i)`` (noise along the normal, the paper's synthetic protocol); planes are
  solved by weighted total least squares with ``noise_i = 1 / sigma_i^2``;
- ``ray_mode`` true: depth noise moves the point along its viewing ray, and the distance to the plane moves by
  ``sigma_z(z_i) |n . p| / z`` (bounded below by ``MIN_INCIDENCE`` sigma_z at grazing angles); planes are solved in
  the ray form ``a . p = 1`` with ``noise_i = z_i^2 / sigma_z(z_i)^2`` (see ``_kernels_linalg``).

Weights of one IRLS pass: ``w_i = pos_i * noise_i * tukey(u_i / (c s))`` with ``u_i = r_i / sigma_i`` (the depth
error over sigma_z in ray mode), ``s`` the robust (MAD) scale of the ``u_i`` (1 when the noise law is exact),
``pos_i`` the paper's Eq. 2 position weight; each factor can be switched off.
"""

from __future__ import annotations

import math

import numpy as np

from reloc._numba import njit, register_warmup
from reloc.extraction._kernels_linalg import plane_covariance, plane_covariance_ray, solve_plane
# numba caches a kernel with the kernels it calls compiled in, keyed on this file's stamp only: a change to the
# plane solvers in _kernels_linalg (closed-form eigen, smallest_eig3) goes with an edit here.

MIN_INCIDENCE = 0.05
MIN_DEPTH = 1e-3


@njit(error_model="numpy")
def point_sigma(z, power, coeff):
    """Depth noise sigma (m) at depth ``z`` (m)."""
    z = max(abs(z), MIN_DEPTH)
    if power == 0:
        return coeff
    if power == 1:
        return coeff * z
    return coeff * z * z


@njit(error_model="numpy")
def distance_sigma(qx, qy, qz, nx, ny, nz, sig_z, ray_mode):
    """Sigma of the point-to-plane distance of a point at ``q`` (relative to the sensor) with depth sigma ``sig_z``."""
    if not ray_mode:
        return sig_z
    z = max(abs(qz), MIN_DEPTH)
    f = abs(nx * qx + ny * qy + nz * qz) / z
    return sig_z * max(f, MIN_INCIDENCE)


@njit(error_model="numpy")
def noise_weight(z, sig_z, sig_dist, ray_mode):
    """Inverse-variance weight of a point for the plane solver of the mode (module docstring)."""
    if ray_mode:
        z = max(abs(z), MIN_DEPTH)
        return z * z / (sig_z * sig_z)
    return 1.0 / (sig_dist * sig_dist)


@njit(error_model="numpy")
def position_weight(rho, alpha, beta):
    """Paper Eq. 2 with ``rho = r / r_max``: ``1 - alpha rho^2`` for ``rho <= 1/2``, ``exp(-beta rho^2)`` beyond."""
    if rho <= 0.5:
        return max(1.0 - alpha * rho * rho, 0.0)
    return math.exp(-beta * rho * rho)


@njit(error_model="numpy")
def tukey_weight(u, c):
    """Tukey's biweight of the normalised residual ``u`` with width ``c``."""
    t = u / c
    if abs(t) >= 1.0:
        return 0.0
    t = 1.0 - t * t
    return t * t


@njit(error_model="numpy")
def _hypothesis_cost(pts, sig_z, sub, nx, ny, nz, d, ray_mode, trunc):
    cost = 0.0
    for k in range(sub.shape[0]):
        i = sub[k]
        px = pts[i, 0]
        py = pts[i, 1]
        pz = pts[i, 2]
        r = nx * px + ny * py + nz * pz + d
        sg = distance_sigma(px, py, pz, nx, ny, nz, sig_z[i], ray_mode)
        u = r / sg
        u2 = u * u
        cost += u2 if u2 < trunc * trunc else trunc * trunc
    return cost


@njit(error_model="numpy")
def ransac_start(pts, sig_z, n_hyp, n_sub, trunc, seed, ray_mode):
    """Best of ``n_hyp`` three-point planes by the truncated cost ``sum min(u^2, trunc^2)`` on ``n_sub`` points.

    ``pts`` (N, 3) float64, ``sig_z`` (N,) depth sigmas. Returns ``(nx, ny, nz, d, found)``.
    """
    n = pts.shape[0]
    np.random.seed(seed)
    m = min(n, n_sub)
    sub = np.empty(m, np.int64)
    for k in range(m):
        sub[k] = (k * n) // m
    # Spread of the cloud, for the degeneracy test of a triple.
    ext = 0.0
    for k in range(m):
        i = sub[k]
        for j in range(3):
            ext = max(ext, abs(pts[i, j] - pts[sub[0], j]))
    min_area2 = (1e-6 * ext * ext) ** 2
    best = np.inf
    bx, by, bz, bd = 0.0, 0.0, 1.0, 0.0
    found = False
    for _h in range(n_hyp):
        i = np.random.randint(0, n)
        j = np.random.randint(0, n)
        k = np.random.randint(0, n)
        ax = pts[j, 0] - pts[i, 0]
        ay = pts[j, 1] - pts[i, 1]
        az = pts[j, 2] - pts[i, 2]
        cx = pts[k, 0] - pts[i, 0]
        cy = pts[k, 1] - pts[i, 1]
        cz = pts[k, 2] - pts[i, 2]
        nx = ay * cz - az * cy
        ny = az * cx - ax * cz
        nz = ax * cy - ay * cx
        nn = nx * nx + ny * ny + nz * nz
        if not nn > min_area2:
            continue
        inv = 1.0 / math.sqrt(nn)
        nx *= inv
        ny *= inv
        nz *= inv
        d = -(nx * pts[i, 0] + ny * pts[i, 1] + nz * pts[i, 2])
        cost = _hypothesis_cost(pts, sig_z, sub, nx, ny, nz, d, ray_mode, trunc)
        if cost < best:
            best = cost
            bx, by, bz, bd = nx, ny, nz, d
            found = True
    return bx, by, bz, bd, found


@njit(error_model="numpy")
def _inlier_sphere(pts, u_abs, lim):
    """Centre and largest distance from it of the points with ``u_abs < lim``: the paper's plane centre and r_max."""
    cnt = 0
    sx = 0.0
    sy = 0.0
    sz = 0.0
    for i in range(pts.shape[0]):
        if u_abs[i] < lim:
            cnt += 1
            sx += pts[i, 0]
            sy += pts[i, 1]
            sz += pts[i, 2]
    if cnt == 0:
        return 0.0, 0.0, 0.0, 1.0
    cx = sx / cnt
    cy = sy / cnt
    cz = sz / cnt
    r2max = 0.0
    for i in range(pts.shape[0]):
        if u_abs[i] < lim:
            dx = pts[i, 0] - cx
            dy = pts[i, 1] - cy
            dz = pts[i, 2] - cz
            r2max = max(r2max, dx * dx + dy * dy + dz * dz)
    return cx, cy, cz, max(math.sqrt(r2max), 1e-12)


@njit(error_model="numpy")
def robust_fit_points(pts, power, coeff, ray_mode, use_noise, use_position, alpha, beta, use_robust, kernel_c, n_hyp,
                      seed, max_iter, out_plane, out_cov):
    """Robust weighted plane of ``pts`` (N, 3) float64 (sensor at the origin); writes ``out_plane`` (4,) and
    ``out_cov`` (4, 4).

    Start: the best RANSAC hypothesis (``n_hyp > 0``) or the noise-weighted fit of all points. Then IRLS until the
    plane moves by less than 1e-12 or ``max_iter`` passes. The normal is oriented toward the origin.
    Returns ``(iterations, n_inliers, scale)``; ``n_inliers`` counts points with a non-zero final weight.
    """
    n = pts.shape[0]
    A = np.empty((3, 3))
    w3 = np.empty(3)
    V = np.empty((3, 3))
    s = np.empty(3)
    S = np.empty((3, 3))
    ref = np.zeros(3)
    sig_z = np.empty(n)
    u_abs = np.zeros(n)
    for i in range(n):
        sig_z[i] = point_sigma(pts[i, 2], power, coeff)
        for j in range(3):
            ref[j] += pts[i, j] / n
    found = False
    nx, ny, nz, d = 0.0, 0.0, 1.0, 0.0
    if n_hyp > 0:
        nx, ny, nz, d, found = ransac_start(pts, sig_z, n_hyp, 2000, 3.0, seed, ray_mode)
    if not found:
        W = 0.0
        s[:] = 0.0
        S[:, :] = 0.0
        for i in range(n):
            wi = noise_weight(pts[i, 2], sig_z[i], sig_z[i], ray_mode) if use_noise else 1.0
            qx = pts[i, 0] - ref[0]
            qy = pts[i, 1] - ref[1]
            qz = pts[i, 2] - ref[2]
            W += wi
            s[0] += wi * qx
            s[1] += wi * qy
            s[2] += wi * qz
            S[0, 0] += wi * qx * qx
            S[0, 1] += wi * qx * qy
            S[0, 2] += wi * qx * qz
            S[1, 1] += wi * qy * qy
            S[1, 2] += wi * qy * qz
            S[2, 2] += wi * qz * qz
        S[1, 0] = S[0, 1]
        S[2, 0] = S[0, 2]
        S[2, 1] = S[1, 2]
        nx, ny, nz, d, _l0, _l1, _l2 = solve_plane(W, s, S, ref, ray_mode, A, w3, V)
    # Position weights (Eq. 2): centre and r_max of the current inliers, updated every pass so that the converged
    # plane does not depend on the start.
    cx, cy, cz = ref[0], ref[1], ref[2]
    r_max = 1.0
    iters = 0
    scale = 1.0
    n_in = n
    W = 0.0
    for it in range(max(max_iter, 1)):
        iters = it + 1
        # Noise along the normal: sigmas at the depth of each point's foot on the current plane. A sigma taken at
        # the measured depth grows with the noise draw itself and weights points whose noise pushed them nearer
        # more, biasing the plane toward the sensor. (Along the ray the foot is unstable at grazing incidence,
        # and measured depths did as well there on ray-noise data, so ray mode keeps them.)
        if not ray_mode and (use_noise or use_robust):
            for i in range(n):
                pz = pts[i, 2]
                z_hat = pz - (nx * pts[i, 0] + ny * pts[i, 1] + nz * pz + d) * nz
                sig_z[i] = point_sigma(z_hat if z_hat > 0.0 else pz, power, coeff)
        # Robust scale of the sigma-normalised residuals (MAD).
        if use_robust:
            for i in range(n):
                sg = distance_sigma(pts[i, 0], pts[i, 1], pts[i, 2], nx, ny, nz, sig_z[i], ray_mode)
                u_abs[i] = abs((nx * pts[i, 0] + ny * pts[i, 1] + nz * pts[i, 2] + d) / sg)
            scale = max(1.4826 * np.median(u_abs), 1e-9)
        if use_position:
            cx, cy, cz, r_max = _inlier_sphere(pts, u_abs, kernel_c * scale if use_robust else np.inf)
        W = 0.0
        s[:] = 0.0
        S[:, :] = 0.0
        n_in = 0
        for i in range(n):
            px = pts[i, 0]
            py = pts[i, 1]
            pz = pts[i, 2]
            sg = distance_sigma(px, py, pz, nx, ny, nz, sig_z[i], ray_mode)
            wi = 1.0
            if use_noise:
                wi = noise_weight(pz, sig_z[i], sg, ray_mode)
            if use_robust:
                u = (nx * px + ny * py + nz * pz + d) / sg
                wi *= tukey_weight(u, kernel_c * scale)
            if use_position:
                dx = px - cx
                dy = py - cy
                dz = pz - cz
                wi *= position_weight(math.sqrt(dx * dx + dy * dy + dz * dz) / r_max, alpha, beta)
            if wi <= 0.0:
                continue
            n_in += 1
            qx = px - ref[0]
            qy = py - ref[1]
            qz = pz - ref[2]
            W += wi
            s[0] += wi * qx
            s[1] += wi * qy
            s[2] += wi * qz
            S[0, 0] += wi * qx * qx
            S[0, 1] += wi * qx * qy
            S[0, 2] += wi * qx * qz
            S[1, 1] += wi * qy * qy
            S[1, 2] += wi * qy * qz
            S[2, 2] += wi * qz * qz
        if n_in < 3:
            break
        S[1, 0] = S[0, 1]
        S[2, 0] = S[0, 2]
        S[2, 1] = S[1, 2]
        mx, my, mz, md, _l0, _l1, _l2 = solve_plane(W, s, S, ref, ray_mode, A, w3, V)
        if mx * nx + my * ny + mz * nz < 0.0:
            mx, my, mz, md = -mx, -my, -mz, -md
        change = abs(mx - nx) + abs(my - ny) + abs(mz - nz) + abs(md - d)
        nx, ny, nz, d = mx, my, mz, md
        if not use_robust:
            break  # the weights do not depend on the plane: one pass is the solution
        if change < 1e-12:
            break
    if d < 0.0:
        nx, ny, nz, d = -nx, -ny, -nz, -d
    out_plane[0] = nx
    out_plane[1] = ny
    out_plane[2] = nz
    out_plane[3] = d
    if n_in >= 3:
        if ray_mode:
            plane_covariance_ray(nx, ny, nz, d, W, s, S, ref, float(n_in), out_cov)
        else:
            plane_covariance(nx, ny, nz, d, W, s, S, ref, float(n_in), out_cov)
    else:
        out_cov[:, :] = 0.0
    return iters, n_in, scale


@register_warmup
def _warmup() -> None:
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50), 2.0 + 0.001 * rng.normal(size=50)])
    plane = np.zeros(4)
    cov = np.zeros((4, 4))
    for ray in (True, False):
        robust_fit_points(pts, 2, 1.425e-3, ray, True, True, 0.5, 2.0, True, 3.0, 16, 0, 5, plane, cov)
