"""Transform between a submap and the map from matched plane pairs (the paper's Eq. 6-9 and Eq. 7).

With ``p_map = R p_sub + t``, a submap plane ``(n_s, d_s)`` matched to a map plane ``(n_m, d_m)`` gives
``R n_s = n_m`` and ``n_m . t = d_s - d_m``. The rotation maximizes ``sum w n_m . (R n_s)``, solved by the
quaternion eigen method (the eigenvector of Horn's 4x4 matrix with the largest eigenvalue, as Eq. 8-9 with the
Lagrange multiplier); the translation is the weighted least-squares solution of the offset equations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from reloc.planes import check_normals
from reloc.transforms import transform_from_rotation_translation

__all__ = [
    "PlanePairTransform",
    "rotation_from_normal_pairs",
    "translation_from_offsets",
    "transform_from_plane_pairs",
]


@dataclass(frozen=True)
class PlanePairTransform:
    """Result of :func:`transform_from_plane_pairs`.

    ``ok`` is False for a degenerate set of pairs, with ``reason`` saying why; ``T_map_sub`` is then None.
    ``condition`` is the condition number of the translation system and ``max_residual_deg`` the largest angle
    between a rotated submap normal and its map normal.
    """

    ok: bool
    reason: str
    T_map_sub: np.ndarray | None
    condition: float
    max_residual_deg: float


def _horn_matrix(n_from: np.ndarray, n_to: np.ndarray, w: np.ndarray) -> np.ndarray:
    S = (n_from * w[:, None]).T @ n_to  # S[a, b] = sum w n_from[a] n_to[b]
    sxx, sxy, sxz = S[0]
    syx, syy, syz = S[1]
    szx, szy, szz = S[2]
    return np.array(
        [
            [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
            [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
            [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
            [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
        ]
    )


def rotation_from_normal_pairs(
    normals_sub: np.ndarray, normals_map: np.ndarray, weights: np.ndarray | None = None
) -> tuple[np.ndarray, float]:
    """Rotation ``R_map_sub`` (3, 3) best aligning ``R @ normals_sub[k]`` with ``normals_map[k]``.

    ``normals_sub``, ``normals_map``: (K, 3) unit normals, K >= 2; ``weights`` (K,) >= 0 (default ones).
    Returns ``(R, eigengap)``: the gap between the two largest eigenvalues of Horn's matrix over the total weight;
    near 0 the rotation is not determined (all normals parallel).
    """
    a = check_normals(normals_sub, "normals_sub", tol=1e-3)
    b = check_normals(normals_map, "normals_map", tol=1e-3)
    if a.shape != b.shape or a.shape[0] < 2:
        raise ValueError(
            f"normals_sub, normals_map: expected two (K, 3) arrays of the same shape with K >= 2, got {a.shape} "
            f"and {b.shape}"
        )
    w = np.ones(a.shape[0]) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.shape != (a.shape[0],) or np.any(~np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
        raise ValueError(f"weights: expected {a.shape[0]} finite non-negative numbers with a positive sum")
    vals, vecs = np.linalg.eigh(_horn_matrix(a, b, w))
    qw, qx, qy, qz = vecs[:, -1]
    R = np.array(
        [
            [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
            [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
            [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
        ]
    )
    # Re-orthonormalize against rounding (the quaternion is unit up to ~1e-16 already).
    u, _, vt = np.linalg.svd(R)
    R = u @ vt
    return R, float((vals[-1] - vals[-2]) / w.sum())


def translation_from_offsets(
    normals_map: np.ndarray, offsets_sub: np.ndarray, offsets_map: np.ndarray, weights: np.ndarray | None = None
) -> tuple[np.ndarray, float]:
    """Translation ``t`` (3,) solving ``normals_map[k] . t = offsets_sub[k] - offsets_map[k]`` in least squares.

    Returns ``(t, condition)``, the condition number of the (weighted) system; ``inf`` when the normals do not span
    3-D space (then ``t`` is the minimum-norm solution).
    """
    A = np.asarray(normals_map, dtype=np.float64).reshape(-1, 3)
    ds = np.asarray(offsets_sub, dtype=np.float64).reshape(-1)
    dm = np.asarray(offsets_map, dtype=np.float64).reshape(-1)
    if ds.shape[0] != A.shape[0] or dm.shape[0] != A.shape[0]:
        raise ValueError(
            f"offsets_sub, offsets_map: expected {A.shape[0]} values each, got {ds.shape[0]} and {dm.shape[0]}"
        )
    w = np.ones(A.shape[0]) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    sw = np.sqrt(w)
    Aw = A * sw[:, None]
    bw = (ds - dm) * sw
    t, _, rank, sv = np.linalg.lstsq(Aw, bw, rcond=None)
    cond = float(sv[0] / sv[-1]) if rank == 3 and sv[-1] > 0 else math.inf
    return t, cond


def transform_from_plane_pairs(
    planes_sub: np.ndarray,
    planes_map: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    min_angle_deg: float = 15.0,
    max_condition: float = 50.0,
    max_residual_deg: float = 10.0,
) -> PlanePairTransform:
    """``T_map_sub`` from K >= 3 matched planes ``[nx, ny, nz, d]`` (submap rows matched to map rows).

    Degenerate inputs are rejected with a reason, not solved: two normals nearly parallel when K == 3 (closer than
    ``min_angle_deg`` on either side), a translation system worse conditioned than ``max_condition`` (normals
    nearly coplanar), or a rotation that cannot bring every normal within ``max_residual_deg`` of its match
    (a mirrored or inconsistent set).
    """
    ps = np.asarray(planes_sub, dtype=np.float64)
    pm = np.asarray(planes_map, dtype=np.float64)
    if ps.ndim != 2 or ps.shape[1] != 4 or ps.shape != pm.shape:
        raise ValueError(
            f"planes_sub, planes_map: expected two (K, 4) arrays [nx, ny, nz, d] of the same shape, got {ps.shape} "
            f"and {pm.shape}"
        )
    if ps.shape[0] < 3:
        return PlanePairTransform(False, f"{ps.shape[0]} plane pairs, at least 3 needed", None, math.inf, math.nan)
    ns, nm = ps[:, :3], pm[:, :3]
    if ps.shape[0] == 3:
        cos_min = math.cos(math.radians(min_angle_deg))
        for a in range(3):
            for b in range(a + 1, 3):
                if abs(ns[a] @ ns[b]) > cos_min or abs(nm[a] @ nm[b]) > cos_min:
                    return PlanePairTransform(
                        False, f"planes {a} and {b} are nearly parallel (closer than {min_angle_deg} deg)", None,
                        math.inf, math.nan,
                    )
    R, _ = rotation_from_normal_pairs(ns, nm, weights)
    residual = float(np.degrees(np.arccos(np.clip(np.sum((ns @ R.T) * nm, axis=1), -1, 1))).max())
    t, cond = translation_from_offsets(nm, ps[:, 3], pm[:, 3], weights)
    if not cond <= max_condition:
        return PlanePairTransform(
            False, f"translation ill-conditioned (condition {cond:.3g} > {max_condition})", None, cond, residual
        )
    if residual > max_residual_deg:
        return PlanePairTransform(
            False, f"normals cannot be aligned (residual {residual:.2f} deg > {max_residual_deg})", None, cond,
            residual,
        )
    return PlanePairTransform(True, "", transform_from_rotation_translation(R, t), cond, residual)
