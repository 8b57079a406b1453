"""Numba kernels: 3x3 symmetric eigen decomposition and planes (with their covariance) from weighted moments.

``np.linalg.eigh`` inside numba needs scipy's LAPACK, so the symmetric 3x3 case is solved here: the planes use
:func:`smallest_eig3` (closed form for the smallest eigenvalue and its eigenvector, polished by Newton steps, 2-3x
faster), which falls back to cyclic Jacobi rotations (:func:`sym_eig3`: a handful of sweeps reach machine precision,
and the eigenvector of the smallest eigenvalue stays accurate even when the two larger eigenvalues are close) when the
two smaller eigenvalues are not well separated.

Moments are of points ``q = p - ref`` about a reference point ``ref`` (the caller picks one near the points, which
keeps the centred scatter free of cancellation): ``W = sum w``, ``s = sum w q``, ``S = sum w q q^T``.

Two plane solvers:
- orthogonal (total least squares, PCA): minimises ``sum w (n . p + d)^2``; right when the noise is along the normal.
- ray (``plane_from_moments_ray``): for depth noise along the viewing rays of a sensor at the origin. A point
  ``p = z r`` (``r`` the exact pixel ray with ``r_z = 1``) of the plane ``a . p = 1`` (``a = -n / d``) gives the
  linear residual ``e = a . p - 1 = dz / z_plane``, so weighted linear least squares ``a = (sum w p p^T)^-1 sum w p``
  with ``w = z^2 / sigma_z^2`` is the maximum-likelihood plane to first order. Total least squares is biased here:
  the noise covariance ``sigma_z^2 r r^T`` is not isotropic and tilts the PCA normal toward the viewing ray by
  about ``sigma_z^2 / l1`` (several degrees for a 0.25 m voxel at 4 m with Kinect noise).
"""

from __future__ import annotations

import math

import numpy as np

from reloc._numba import njit, register_warmup


@njit(error_model="numpy")
def sym_eig3(A, w, V):
    """Eigen decomposition of the symmetric 3x3 ``A`` (float64, destroyed) into ascending ``w`` (3,) and the unit
    eigenvectors as the columns of ``V`` (3, 3)."""
    for i in range(3):
        for j in range(3):
            V[i, j] = 1.0 if i == j else 0.0
    for _sweep in range(50):
        off = A[0, 1] * A[0, 1] + A[0, 2] * A[0, 2] + A[1, 2] * A[1, 2]
        diag = A[0, 0] * A[0, 0] + A[1, 1] * A[1, 1] + A[2, 2] * A[2, 2]
        if off <= 1e-36 * diag or off == 0.0:
            break
        for pq in range(3):
            p = 0 if pq < 2 else 1
            q = 1 if pq == 0 else 2
            apq = A[p, q]
            if apq == 0.0:
                continue
            theta = (A[q, q] - A[p, p]) / (2.0 * apq)
            t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
            if theta < 0.0:
                t = -t
            c = 1.0 / math.sqrt(t * t + 1.0)
            s = t * c
            for k in range(3):
                akp = A[k, p]
                akq = A[k, q]
                A[k, p] = c * akp - s * akq
                A[k, q] = s * akp + c * akq
            for k in range(3):
                apk = A[p, k]
                aqk = A[q, k]
                A[p, k] = c * apk - s * aqk
                A[q, k] = s * apk + c * aqk
            for k in range(3):
                vkp = V[k, p]
                vkq = V[k, q]
                V[k, p] = c * vkp - s * vkq
                V[k, q] = s * vkp + c * vkq
    for i in range(3):
        w[i] = A[i, i]
    # Sort ascending (three elements: a tiny insertion sort), eigenvectors along.
    for i in range(1, 3):
        j = i
        while j > 0 and w[j - 1] > w[j]:
            tmp = w[j - 1]
            w[j - 1] = w[j]
            w[j] = tmp
            for k in range(3):
                tmp = V[k, j - 1]
                V[k, j - 1] = V[k, j]
                V[k, j] = tmp
            j -= 1


@njit(error_model="numpy")
def _charpoly(a00, a01, a02, a11, a12, a22, lam):
    """``det(A - lam I)`` of the symmetric 3x3 ``A`` and its derivative in ``lam``."""
    b00 = a00 - lam
    b11 = a11 - lam
    b22 = a22 - lam
    m0 = b11 * b22 - a12 * a12
    m1 = b00 * b22 - a02 * a02
    m2 = b00 * b11 - a01 * a01
    f = b00 * m0 - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)
    return f, -(m0 + m1 + m2)


@njit(error_model="numpy")
def smallest_eig3(A, w, V):
    """Ascending eigenvalues ``w`` (3,) of the symmetric 3x3 ``A`` (float64, destroyed) and the unit eigenvector of
    the smallest one in ``V[:, 0]`` (the other columns are not set), in closed form: the trigonometric solution of
    the characteristic cubic for the smallest root, polished by two Newton steps on ``det(A - lam I)`` (the
    trigonometric root alone loses half the digits when the two larger eigenvalues are close, the usual case of a
    plane patch); the eigenvector as the largest cross product of two rows of ``A - lam0 I``; the two larger
    eigenvalues from the 2x2 restriction of ``A`` to the plane of that eigenvector (stable formula). Agrees with
    :func:`sym_eig3` to ~1e-13 relative on plane-like scatters (eigenvector error ``~eps |A| / (lam1 - lam0)``,
    as Jacobi's); falls back to :func:`sym_eig3` when the two smaller eigenvalues are not well separated
    (``lam1 - lam0 < 1e-6 |A|``), where the closed form would lose digits. 3-4x faster than the Jacobi sweeps.
    """
    a00 = A[0, 0]
    a01 = A[0, 1]
    a02 = A[0, 2]
    a11 = A[1, 1]
    a12 = A[1, 2]
    a22 = A[2, 2]
    q = (a00 + a11 + a22) / 3.0
    d0 = a00 - q
    d1 = a11 - q
    d2 = a22 - q
    off = a01 * a01 + a02 * a02 + a12 * a12
    p2 = (d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * off) / 6.0
    if not p2 > 0.0:
        sym_eig3(A, w, V)
        return
    p = math.sqrt(p2)
    inv = 1.0 / p
    e0 = d0 * inv
    e1 = d1 * inv
    e2 = d2 * inv
    f01 = a01 * inv
    f02 = a02 * inv
    f12 = a12 * inv
    r = 0.5 * (e0 * (e1 * e2 - f12 * f12) - f01 * (f01 * e2 - f12 * f02) + f02 * (f01 * f12 - e1 * f02))
    r = min(max(r, -1.0), 1.0)
    phi = math.acos(r) / 3.0
    lam = q + 2.0 * p * math.cos(phi + 2.0943951023931953)  # the smallest root
    for _ in range(2):
        f, df = _charpoly(a00, a01, a02, a11, a12, a22, lam)
        if df < 0.0:  # between roots the Newton step is only safe on the decreasing branch below lam1
            lam = lam - f / df
    # Rows of A - lam I; their largest cross product is along the eigenvector.
    b00 = a00 - lam
    b11 = a11 - lam
    b22 = a22 - lam
    x0 = a01 * a12 - a02 * b11
    y0 = a02 * a01 - b00 * a12
    z0 = b00 * b11 - a01 * a01
    n0 = x0 * x0 + y0 * y0 + z0 * z0
    x1 = a01 * b22 - a02 * a12
    y1 = a02 * a02 - b00 * b22
    z1 = b00 * a12 - a01 * a02
    n1 = x1 * x1 + y1 * y1 + z1 * z1
    x2 = b11 * b22 - a12 * a12
    y2 = a12 * a02 - a01 * b22
    z2 = a01 * a12 - b11 * a02
    n2 = x2 * x2 + y2 * y2 + z2 * z2
    if n1 > n0:
        x0, y0, z0, n0 = x1, y1, z1, n1
    if n2 > n0:
        x0, y0, z0, n0 = x2, y2, z2, n2
    # |cross| ~ (lam1 - lam0) (lam2 - lam0): a small one means two close small eigenvalues (or none resolved).
    scale = max(abs(a00), abs(a11), abs(a22), math.sqrt(off))
    if not n0 > (1e-12 * scale * scale) ** 2:
        sym_eig3(A, w, V)
        return
    inv_n = 1.0 / math.sqrt(n0)
    nx = x0 * inv_n
    ny = y0 * inv_n
    nz = z0 * inv_n
    t1x, t1y, t1z, t2x, t2y, t2z = tangent_basis(nx, ny, nz)
    # A restricted to the tangent plane, and A along the normal (the Rayleigh quotient).
    ux = a00 * t1x + a01 * t1y + a02 * t1z
    uy = a01 * t1x + a11 * t1y + a12 * t1z
    uz = a02 * t1x + a12 * t1y + a22 * t1z
    c11 = ux * t1x + uy * t1y + uz * t1z
    c12 = ux * t2x + uy * t2y + uz * t2z
    vx = a00 * t2x + a01 * t2y + a02 * t2z
    vy = a01 * t2x + a11 * t2y + a12 * t2z
    vz = a02 * t2x + a12 * t2y + a22 * t2z
    c22 = vx * t2x + vy * t2y + vz * t2z
    l0 = ((a00 * nx + a01 * ny + a02 * nz) * nx + (a01 * nx + a11 * ny + a12 * nz) * ny
          + (a02 * nx + a12 * ny + a22 * nz) * nz)
    h = 0.5 * (c11 + c22)
    g = math.sqrt(0.25 * (c11 - c22) * (c11 - c22) + c12 * c12)
    l1 = h - g
    l2 = h + g
    if not l1 - l0 > 1e-6 * scale:
        sym_eig3(A, w, V)
        return
    w[0] = l0
    w[1] = l1
    w[2] = l2
    V[0, 0] = nx
    V[1, 0] = ny
    V[2, 0] = nz


@njit(error_model="numpy")
def plane_from_moments(W, s, S, ref, A, w, V):
    """Least-squares plane of weighted moments about ``ref`` (see module docstring).

    Returns ``(nx, ny, nz, d, lam0, lam1, lam2)``: the unit normal (smallest eigenvector of the weighted covariance),
    the offset with ``n . p + d = 0`` in the frame of ``ref``, and the ascending eigenvalues of the weighted
    covariance (``lam0`` is the mean squared weighted distance to the plane). ``A``, ``w``, ``V`` are scratch arrays
    (3, 3), (3,), (3, 3). ``W <= 0`` gives a zero normal.
    """
    if not W > 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    mx = s[0] / W
    my = s[1] / W
    mz = s[2] / W
    A[0, 0] = S[0, 0] / W - mx * mx
    A[0, 1] = S[0, 1] / W - mx * my
    A[0, 2] = S[0, 2] / W - mx * mz
    A[1, 1] = S[1, 1] / W - my * my
    A[1, 2] = S[1, 2] / W - my * mz
    A[2, 2] = S[2, 2] / W - mz * mz
    A[1, 0] = A[0, 1]
    A[2, 0] = A[0, 2]
    A[2, 1] = A[1, 2]
    smallest_eig3(A, w, V)
    nx = V[0, 0]
    ny = V[1, 0]
    nz = V[2, 0]
    cx = mx + ref[0]
    cy = my + ref[1]
    cz = mz + ref[2]
    d = -(nx * cx + ny * cy + nz * cz)
    return nx, ny, nz, d, max(w[0], 0.0), w[1], w[2]


@njit(error_model="numpy")
def solve_sym3(S00, S01, S02, S11, S12, S22, b0, b1, b2):
    """Solve the symmetric 3x3 system ``S x = b`` by cofactors; returns ``(x0, x1, x2, ok)``."""
    c00 = S11 * S22 - S12 * S12
    c01 = S02 * S12 - S01 * S22
    c02 = S01 * S12 - S02 * S11
    c11 = S00 * S22 - S02 * S02
    c12 = S01 * S02 - S00 * S12
    c22 = S00 * S11 - S01 * S01
    det = S00 * c00 + S01 * c01 + S02 * c02
    scale = abs(S00 * S11 * S22) + abs(S01 * S12 * S02) + 1e-300
    if not abs(det) > 1e-15 * scale:
        return 0.0, 0.0, 0.0, False
    inv = 1.0 / det
    x0 = (c00 * b0 + c01 * b1 + c02 * b2) * inv
    x1 = (c01 * b0 + c11 * b1 + c12 * b2) * inv
    x2 = (c02 * b0 + c12 * b1 + c22 * b2) * inv
    return x0, x1, x2, True


@njit(error_model="numpy")
def plane_from_moments_ray(W, s, S, ref, A, w, V):
    """Plane from weighted moments about ``ref`` for depth noise along rays from the origin (module docstring).

    Same return as :func:`plane_from_moments`: ``(nx, ny, nz, d, l0, 0, 0)`` with the normal toward the origin
    (``d > 0``) and ``l0`` the weighted mean squared orthogonal distance. Falls back to the orthogonal solver when
    the system is singular (a plane through the origin).
    """
    if not W > 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    # Moments about the origin.
    so0 = s[0] + W * ref[0]
    so1 = s[1] + W * ref[1]
    so2 = s[2] + W * ref[2]
    S00 = S[0, 0] + 2.0 * s[0] * ref[0] + W * ref[0] * ref[0]
    S01 = S[0, 1] + s[0] * ref[1] + ref[0] * s[1] + W * ref[0] * ref[1]
    S02 = S[0, 2] + s[0] * ref[2] + ref[0] * s[2] + W * ref[0] * ref[2]
    S11 = S[1, 1] + 2.0 * s[1] * ref[1] + W * ref[1] * ref[1]
    S12 = S[1, 2] + s[1] * ref[2] + ref[1] * s[2] + W * ref[1] * ref[2]
    S22 = S[2, 2] + 2.0 * s[2] * ref[2] + W * ref[2] * ref[2]
    a0, a1, a2, ok = solve_sym3(S00, S01, S02, S11, S12, S22, so0, so1, so2)
    na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    if not ok or not na > 0.0:
        return plane_from_moments(W, s, S, ref, A, w, V)
    nx = -a0 / na
    ny = -a1 / na
    nz = -a2 / na
    d = 1.0 / na
    # Mean squared orthogonal distance from the centred moments.
    mx = s[0] / W
    my = s[1] / W
    mz = s[2] / W
    cxx = S[0, 0] / W - mx * mx
    cxy = S[0, 1] / W - mx * my
    cxz = S[0, 2] / W - mx * mz
    cyy = S[1, 1] / W - my * my
    cyz = S[1, 2] / W - my * mz
    czz = S[2, 2] / W - mz * mz
    l0 = (nx * nx * cxx + ny * ny * cyy + nz * nz * czz
          + 2.0 * (nx * ny * cxy + nx * nz * cxz + ny * nz * cyz))
    return nx, ny, nz, d, max(l0, 0.0), 0.0, 0.0


@njit(error_model="numpy")
def solve_plane(W, s, S, ref, ray_mode, A, w, V):
    """:func:`plane_from_moments_ray` when ``ray_mode`` else :func:`plane_from_moments`."""
    if ray_mode:
        return plane_from_moments_ray(W, s, S, ref, A, w, V)
    return plane_from_moments(W, s, S, ref, A, w, V)


@njit(error_model="numpy")
def plane_covariance_ray(nx, ny, nz, d, W, s, S, ref, n_eff, cov):
    """Covariance (4, 4) of ``(n, d)`` of the ray-mode plane (see :func:`plane_from_moments_ray`) into ``cov``.

    ``cov(a) = s0^2 (sum w p p^T)^-1`` with ``s0^2 = sum w (a . p - 1)^2 / (n_eff - 3)``, carried to ``(n, d)`` by
    the Jacobian of ``n = -a / |a|``, ``d = 1 / |a|``: ``[[-(I - n n^T) d], [n^T d^2]]``. Returns ``s0^2`` (-1 and
    zeros when degenerate).
    """
    for i in range(4):
        for j in range(4):
            cov[i, j] = 0.0
    if not W > 0.0 or n_eff <= 3.0 or not d > 0.0:
        return -1.0
    so0 = s[0] + W * ref[0]
    so1 = s[1] + W * ref[1]
    so2 = s[2] + W * ref[2]
    S00 = S[0, 0] + 2.0 * s[0] * ref[0] + W * ref[0] * ref[0]
    S01 = S[0, 1] + s[0] * ref[1] + ref[0] * s[1] + W * ref[0] * ref[1]
    S02 = S[0, 2] + s[0] * ref[2] + ref[0] * s[2] + W * ref[0] * ref[2]
    S11 = S[1, 1] + 2.0 * s[1] * ref[1] + W * ref[1] * ref[1]
    S12 = S[1, 2] + s[1] * ref[2] + ref[1] * s[2] + W * ref[1] * ref[2]
    S22 = S[2, 2] + 2.0 * s[2] * ref[2] + W * ref[2] * ref[2]
    a0 = -nx / d
    a1 = -ny / d
    a2 = -nz / d
    aSa = (a0 * (S00 * a0 + S01 * a1 + S02 * a2) + a1 * (S01 * a0 + S11 * a1 + S12 * a2)
           + a2 * (S02 * a0 + S12 * a1 + S22 * a2))
    rss = max(aSa - 2.0 * (a0 * so0 + a1 * so1 + a2 * so2) + W, 0.0)
    s0sq = rss / (n_eff - 3.0)
    # Columns of S^-1.
    i0x, i0y, i0z, ok0 = solve_sym3(S00, S01, S02, S11, S12, S22, 1.0, 0.0, 0.0)
    i1x, i1y, i1z, ok1 = solve_sym3(S00, S01, S02, S11, S12, S22, 0.0, 1.0, 0.0)
    i2x, i2y, i2z, ok2 = solve_sym3(S00, S01, S02, S11, S12, S22, 0.0, 0.0, 1.0)
    if not (ok0 and ok1 and ok2):
        return -1.0
    Ca = ((i0x, i1x, i2x), (i0y, i1y, i2y), (i0z, i1z, i2z))
    n = (nx, ny, nz)
    # J (4 x 3): rows 0..2 = -(I - n n^T) d, row 3 = n^T d^2.
    J = np.empty((4, 3))
    for i in range(3):
        for j in range(3):
            J[i, j] = -((1.0 if i == j else 0.0) - n[i] * n[j]) * d
        J[3, i] = n[i] * d * d
    for i in range(4):
        for j in range(4):
            acc = 0.0
            for k in range(3):
                for m in range(3):
                    acc += J[i, k] * Ca[k][m] * J[j, m]
            cov[i, j] = s0sq * acc
    return s0sq


@njit(error_model="numpy")
def tangent_basis(nx, ny, nz):
    """Two unit vectors ``(t1, t2)`` perpendicular to the unit ``n`` and to each other, as six scalars."""
    if abs(nx) < 0.9:
        ax, ay, az = 1.0, 0.0, 0.0
    else:
        ax, ay, az = 0.0, 1.0, 0.0
    # t1 = normalise(a - (a . n) n), t2 = n x t1
    dot = ax * nx + ay * ny + az * nz
    t1x = ax - dot * nx
    t1y = ay - dot * ny
    t1z = az - dot * nz
    norm = math.sqrt(t1x * t1x + t1y * t1y + t1z * t1z)
    t1x /= norm
    t1y /= norm
    t1z /= norm
    t2x = ny * t1z - nz * t1y
    t2y = nz * t1x - nx * t1z
    t2z = nx * t1y - ny * t1x
    return t1x, t1y, t1z, t2x, t2y, t2z


@njit(error_model="numpy")
def plane_covariance(nx, ny, nz, d, W, s, S, ref, n_eff, cov):
    """Covariance (4, 4) of ``(nx, ny, nz, d)`` of the weighted least-squares plane, written into ``cov``.

    The information of the fit is ``H = sum w [p; 1][p; 1]^T`` (from the moments, moved to the origin), restricted
    to the 3-dimensional tangent space of the constraint ``|n| = 1``: ``cov = s0^2 B (B^T H B)^-1 B^T`` with ``B`` a
    basis of that space and ``s0^2 = sum w r^2 / (n_eff - 3)`` the a-posteriori variance factor (1 when the weights
    are exact inverse variances). Returns ``s0^2``; a degenerate system gives a covariance of zeros and -1.
    """
    for i in range(4):
        for j in range(4):
            cov[i, j] = 0.0
    if not W > 0.0 or n_eff <= 3.0:
        return -1.0
    # Moments about the origin: S_o = S + s r^T + r s^T + W r r^T, s_o = s + W r.
    so0 = s[0] + W * ref[0]
    so1 = s[1] + W * ref[1]
    so2 = s[2] + W * ref[2]
    H00 = S[0, 0] + 2.0 * s[0] * ref[0] + W * ref[0] * ref[0]
    H01 = S[0, 1] + s[0] * ref[1] + ref[0] * s[1] + W * ref[0] * ref[1]
    H02 = S[0, 2] + s[0] * ref[2] + ref[0] * s[2] + W * ref[0] * ref[2]
    H11 = S[1, 1] + 2.0 * s[1] * ref[1] + W * ref[1] * ref[1]
    H12 = S[1, 2] + s[1] * ref[2] + ref[1] * s[2] + W * ref[1] * ref[2]
    H22 = S[2, 2] + 2.0 * s[2] * ref[2] + W * ref[2] * ref[2]
    # Weighted residual sum about the plane, from the same moments: sum w (n . q + (n . ref + d))^2.
    e = nx * ref[0] + ny * ref[1] + nz * ref[2] + d
    nSn = (nx * (S[0, 0] * nx + S[0, 1] * ny + S[0, 2] * nz)
           + ny * (S[1, 0] * nx + S[1, 1] * ny + S[1, 2] * nz)
           + nz * (S[2, 0] * nx + S[2, 1] * ny + S[2, 2] * nz))
    ns = nx * s[0] + ny * s[1] + nz * s[2]
    rss = max(nSn + 2.0 * e * ns + e * e * W, 0.0)
    s0sq = rss / (n_eff - 3.0)
    t1x, t1y, t1z, t2x, t2y, t2z = tangent_basis(nx, ny, nz)
    # B columns: b0 = [t1, 0], b1 = [t2, 0], b2 = [0, 0, 0, 1]; M = B^T H B.
    Ht1x = H00 * t1x + H01 * t1y + H02 * t1z
    Ht1y = H01 * t1x + H11 * t1y + H12 * t1z
    Ht1z = H02 * t1x + H12 * t1y + H22 * t1z
    Ht2x = H00 * t2x + H01 * t2y + H02 * t2z
    Ht2y = H01 * t2x + H11 * t2y + H12 * t2z
    Ht2z = H02 * t2x + H12 * t2y + H22 * t2z
    m00 = t1x * Ht1x + t1y * Ht1y + t1z * Ht1z
    m01 = t1x * Ht2x + t1y * Ht2y + t1z * Ht2z
    m11 = t2x * Ht2x + t2y * Ht2y + t2z * Ht2z
    m02 = t1x * so0 + t1y * so1 + t1z * so2
    m12 = t2x * so0 + t2y * so1 + t2z * so2
    m22 = W
    # Inverse of the symmetric 3x3 M by cofactors.
    c00 = m11 * m22 - m12 * m12
    c01 = m02 * m12 - m01 * m22
    c02 = m01 * m12 - m02 * m11
    c11 = m00 * m22 - m02 * m02
    c12 = m01 * m02 - m00 * m12
    c22 = m00 * m11 - m01 * m01
    det = m00 * c00 + m01 * c01 + m02 * c02
    scale = abs(m00 * m11 * m22) + 1e-300
    if not abs(det) > 1e-14 * scale:
        return -1.0
    inv = s0sq / det
    i00 = c00 * inv
    i01 = c01 * inv
    i02 = c02 * inv
    i11 = c11 * inv
    i12 = c12 * inv
    i22 = c22 * inv
    # cov = B Minv B^T, with B = [[t1x, t2x, 0], [t1y, t2y, 0], [t1z, t2z, 0], [0, 0, 1]].
    bx0 = (t1x, t1y, t1z)
    bx1 = (t2x, t2y, t2z)
    for i in range(3):
        for j in range(3):
            cov[i, j] = (bx0[i] * (i00 * bx0[j] + i01 * bx1[j]) + bx1[i] * (i01 * bx0[j] + i11 * bx1[j]))
        cov[i, 3] = bx0[i] * i02 + bx1[i] * i12
        cov[3, i] = cov[i, 3]
    cov[3, 3] = i22
    return s0sq


@njit(error_model="numpy")
def plane_covariances(planes, wmoments, wscatters, n_eff, ray_mode, covs, s0sq):
    """Covariance of every plane from weighted moments about the origin (``wmoments`` (P, 4) ``[W, sum w p]``,
    ``wscatters`` (P, 3, 3)): :func:`plane_covariance_ray` when ``ray_mode`` else :func:`plane_covariance`; writes
    ``covs`` (P, 4, 4) and ``s0sq`` (P,)."""
    zero = np.zeros(3)
    for i in range(planes.shape[0]):
        if ray_mode:
            s0sq[i] = plane_covariance_ray(planes[i, 0], planes[i, 1], planes[i, 2], planes[i, 3], wmoments[i, 0],
                                           wmoments[i, 1:4], wscatters[i], zero, float(n_eff[i]), covs[i])
        else:
            s0sq[i] = plane_covariance(planes[i, 0], planes[i, 1], planes[i, 2], planes[i, 3], wmoments[i, 0],
                                       wmoments[i, 1:4], wscatters[i], zero, float(n_eff[i]), covs[i])


@register_warmup
def _warmup() -> None:
    A = np.eye(3)
    w = np.zeros(3)
    V = np.zeros((3, 3))
    sym_eig3(A, w, V)
    smallest_eig3(np.eye(3), w, V)
    s = np.zeros(3)
    S = np.eye(3)
    ref = np.zeros(3)
    plane_from_moments(1.0, s, S, ref, A, w, V)
    cov = np.zeros((4, 4))
    plane_covariance(0.0, 0.0, 1.0, 0.0, 10.0, s, S, ref, 10.0, cov)
    for ray in (True, False):
        solve_plane(1.0, s, S, ref, ray, A, w, V)
        plane_covariances(np.array([[0.0, 0.0, -1.0, 2.0]]), np.array([[10.0, 0.0, 0.0, 20.0]]),
                          np.array([[[1.0, 0, 0], [0, 1.0, 0], [0, 0, 40.0]]]), np.array([10], np.int64), ray,
                          np.zeros((1, 4, 4)), np.zeros(1))
