"""The uncertainty of a relocalized pose, from the plane pairs that fix it.

A submap plane ``(n_s, d_s)`` with centroid ``c_s``, moved into the map by the estimate ``T_map_sub``, should lie on
its map plane ``(n_m, d_m)``. Write the truth as ``T_true = exp(delta) T_map_sub`` with the left perturbation
``delta = (rho, phi)`` in the map frame, translation first (the order of the firmware protocol's ``cov``). Each pair
then gives three residuals, linear in ``delta``:

- the normal, in the two directions ``B = (b1, b2)`` across the moved normal ``n``: ``B^T (n_m - n) = -B^T [n]x phi``;
- the offset at the moved centroid ``c``: ``n_m . c + d_m = -n_m . rho - (c x n_m) . phi``.

Their noise is the plane fits' covariances (submap and map, carried to these residuals). The information
``H = sum J^T N^-1 J`` then gives ``H^-1``, which assumes the fits' covariances are right and the pairs independent.
Neither holds: the fits' covariances are about 1.4x too small in sigma, and map planes carry biases of centimetres (a
wall fused with the door in its niche). So each pair whose squared residual ``r^T N^-1 r`` at the estimate exceeds 4
times the median pair's has its noise scaled up to make it 4 times (a biased plane weighs little more than a typical
one); the covariance is scaled by the a-posteriori variance factor of the pairs so weighed, ``s0^2 = sum r^T N^-1 r /
(3 M - 6)`` (at least 1), and by ``inflation`` (4 by default), set so that the pose errors of the simulated suite
follow the covariance: the normalized squared error ``delta^T cov^-1 delta`` has about the mean of a chi-square of 6
degrees of freedom (6), docs/BENCHMARKS.md, "Pose covariance".
"""

from __future__ import annotations

import math

import numpy as np

from reloc.transforms import check_transform

__all__ = ["OUTLIER_FACTOR", "pose_covariance"]

# Added to the fits' variances so that exact planes (ground truth, zero covariance) still give a solvable system:
# (1 micro-radian)^2 and (1 micrometre)^2, far below any measured plane's.
_TINY_VAR = 1e-12
# A pair whose squared residual exceeds this many times the median pair's weighs as if it were just this many times
# (of pairs with Gaussian noise, 2.3 % exceed it: 4 x 2.37, the median of a chi-square of 3 degrees of freedom, is its
# 97.7th percentile).
OUTLIER_FACTOR = 4.0


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise ``a x b`` of (M, 3) arrays (np.cross took 40 % of a call's time here)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def _tangent_bases(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (M, 3) each, perpendicular to the unit normals ``n`` (M, 3) and to each other, with
    ``b2 = n x b1``."""
    a = np.where((np.abs(n[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    t1 = a - np.sum(a * n, axis=1)[:, None] * n
    t1 /= np.linalg.norm(t1, axis=1)[:, None]
    return t1, _cross(n, t1)


def pose_covariance(
    T_map_sub, sub_normals, sub_centroids, sub_covariances, map_normals, map_offsets, map_covariances,
    inflation: float = 4.0, outlier_factor: float = OUTLIER_FACTOR,
) -> tuple[np.ndarray | None, float]:
    """Covariance (6, 6) of the left perturbation ``(rho, phi)`` of ``T_map_sub`` (4x4) in the map frame, from M
    matched plane pairs: submap planes (``sub_normals`` (M, 3) and ``sub_centroids`` (M, 3) in the submap frame,
    ``sub_covariances`` (M, 4, 4) of their ``(n, d)``) and the map planes they match (``map_normals`` (M, 3),
    ``map_offsets`` (M,), ``map_covariances`` (M, 4, 4)). Returns ``(cov, s0^2)``: ``cov`` is None when the pairs
    do not fix all six degrees of freedom (fewer than three, or parallel normals); ``s0^2`` is the variance factor
    of the pairs' residuals (see the module's docstring) that scaled it. ``outlier_factor``: a pair's squared
    residual counts at most this many times the median pair's (``math.inf``: every pair in full)."""
    T = check_transform(T_map_sub, "T_map_sub")
    ns = np.asarray(sub_normals, dtype=np.float64).reshape(-1, 3)
    M = len(ns)
    cs = np.asarray(sub_centroids, dtype=np.float64).reshape(M, 3)
    Cs = np.asarray(sub_covariances, dtype=np.float64).reshape(M, 4, 4)
    nm = np.asarray(map_normals, dtype=np.float64).reshape(M, 3)
    dm = np.asarray(map_offsets, dtype=np.float64).reshape(M)
    Cm = np.asarray(map_covariances, dtype=np.float64).reshape(M, 4, 4)
    if not inflation > 0:
        raise ValueError(f"inflation: expected > 0, got {inflation!r}")
    if not outlier_factor >= 1:
        raise ValueError(f"outlier_factor: expected >= 1, got {outlier_factor!r}")
    if M < 3:
        return None, float("nan")
    R, t = T[:3, :3], T[:3, 3]
    n = ns @ R.T
    c = cs @ R.T + t
    b1, b2 = _tangent_bases(n)
    # The normal's residuals B^T (n_m - n) depend on phi alone, through -B^T [n]x, whose rows are -(b_k x n)^T:
    # b2 and -b1 (b2 = n x b1); the offset's, n_m . c + d_m, on rho through -n_m and on phi through -(c x n_m).
    Jn = np.stack([b2, -b1], axis=1)  # (M, 2, 3)
    Jd = -np.concatenate([nm, _cross(c, nm)], axis=1)  # (M, 6)
    # Their noise: both fits' normal covariances across n (2 x 2), their offsets' variances at the centroid.
    B = np.stack([b1, b2], axis=2)  # (M, 3, 2)
    Cn = R @ Cs[:, :3, :3] @ R.T + Cm[:, :3, :3]
    Nn = np.swapaxes(B, 1, 2) @ Cn @ B + _TINY_VAR * np.eye(2)
    hs = np.concatenate([cs, np.ones((M, 1))], axis=1)
    hm = np.concatenate([c, np.ones((M, 1))], axis=1)
    vd = np.einsum("mi,mij,mj->m", hs, Cs, hs) + np.einsum("mi,mij,mj->m", hm, Cm, hm) + _TINY_VAR
    Wn = np.linalg.inv(Nn)
    rn = np.einsum("mik,mi->mk", B, nm - n)  # (M, 2)
    rd = np.sum(nm * c, axis=1) + dm
    # Each pair's squared residual in its own noise (3 dof). A pair far worse than the others (a map plane biased
    # by centimetres, with the tiny covariance of a large fit) has its noise scaled up to make it outlier_factor times
    # the median pair's. Otherwise the variance factor would blow up every direction with it (along a corridor's
    # length, to 1.8 m of sigma for a pose 9 mm off, replicate A's corridor/robot/7).
    chi2 = np.einsum("ma,mab,mb->m", rn, Wn, rn) + rd * rd / vd
    if math.isinf(outlier_factor):
        k = np.ones(M)
    else:
        k = np.maximum(1.0, chi2 / max(outlier_factor * float(np.median(chi2)), 1e-300))
    H = (Jd.T * (1.0 / (vd * k))) @ Jd
    H[3:, 3:] += np.einsum("mai,mab,mbj->ij", Jn, Wn / k[:, None, None], Jn)
    dof = 3 * M - 6
    s0sq = max(float(np.sum(chi2 / k)) / dof, 1.0) if dof > 0 else 1.0
    eig = np.linalg.eigvalsh(H)
    if not eig[0] > 1e-12 * eig[-1]:
        return None, s0sq
    cov = inflation * s0sq * np.linalg.inv(H)
    return 0.5 * (cov + cov.T), s0sq
