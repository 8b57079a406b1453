"""Numba kernels: 3x3 symmetric eigen decomposition and planes (with their covariance) from weighted moments.

``np.linalg.eigh`` inside numba needs scipy's LAPACK, so the symmetric 3x3 case is solved by cyclic Jacobi
rotations here: a handful of sweeps reach machine precision, and the eigenvector of the smallest eigenvalue (the
plane normal) stays accurate even when the two larger eigenvalues are close.

Moments are of points ``q = p - ref`` about a reference point ``ref`` (the caller picks one near the points, which
keeps the centred scatter free of cancellation): ``W = sum w``, ``s = sum w q``, ``S = sum w q q^T``.
"""

from __future__ import annotations

import math

import numpy as np

from reloc._numba import njit, register_warmup


@njit
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


@njit
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
    sym_eig3(A, w, V)
    nx = V[0, 0]
    ny = V[1, 0]
    nz = V[2, 0]
    cx = mx + ref[0]
    cy = my + ref[1]
    cz = mz + ref[2]
    d = -(nx * cx + ny * cy + nz * cz)
    return nx, ny, nz, d, max(w[0], 0.0), w[1], w[2]


@njit
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


@njit
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


@register_warmup
def _warmup() -> None:
    A = np.eye(3)
    w = np.zeros(3)
    V = np.zeros((3, 3))
    sym_eig3(A, w, V)
    s = np.zeros(3)
    S = np.eye(3)
    ref = np.zeros(3)
    plane_from_moments(1.0, s, S, ref, A, w, V)
    cov = np.zeros((4, 4))
    plane_covariance(0.0, 0.0, 1.0, 0.0, 10.0, s, S, ref, 10.0, cov)
