"""Plane geometry: ``n . p + d = 0`` with a unit normal ``n`` pointing to the side the sensor saw.

Planes travel as a (4,) array ``[nx, ny, nz, d]`` or as separate ``normals (N, 3)`` and ``offsets (N,)``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "check_normals",
    "transform_plane",
    "transform_planes",
    "plane_angle_deg",
    "plane_errors",
    "orient_toward",
    "plane_from_points_exact",
    "point_plane_distance",
    "weakest_direction_support",
]


def check_normals(normals: np.ndarray, name: str = "normals", tol: float = 1e-6) -> np.ndarray:
    """Validate (N, 3) unit normals and return them as float64."""
    n = np.asarray(normals, dtype=np.float64)
    if n.ndim != 2 or n.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (N, 3), got {n.shape}")
    if not np.all(np.isfinite(n)):
        raise ValueError(f"{name}: expected finite values")
    norms = np.linalg.norm(n, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > tol)
    if bad.size:
        raise ValueError(f"{name}: expected unit vectors, row {bad[0]} has norm {norms[bad[0]]:.6g}")
    return n


def transform_planes(T_a_b: np.ndarray, normals_b: np.ndarray, offsets_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Move planes from frame b to frame a.

    With ``p_a = R p_b + t``: ``n_a = R n_b`` and ``d_a = d_b - n_a . t``. Shapes (N, 3), (N,) in and out.
    """
    T = np.asarray(T_a_b, dtype=np.float64)
    n_b = np.asarray(normals_b, dtype=np.float64).reshape(-1, 3)
    d_b = np.asarray(offsets_b, dtype=np.float64).reshape(-1)
    n_a = n_b @ T[:3, :3].T
    d_a = d_b - n_a @ T[:3, 3]
    return n_a, d_a


def transform_plane(T_a_b: np.ndarray, plane_b: np.ndarray) -> np.ndarray:
    """Move one plane ``[nx, ny, nz, d]`` from frame b to frame a."""
    p = np.asarray(plane_b, dtype=np.float64).reshape(4)
    n_a, d_a = transform_planes(T_a_b, p[None, :3], p[3:4])
    return np.concatenate([n_a[0], d_a])


def plane_angle_deg(n1: np.ndarray, n2: np.ndarray, *, unsigned: bool = False) -> float | np.ndarray:
    """Angle between normals in degrees. ``unsigned=True`` treats ``n`` and ``-n`` as the same direction."""
    a = np.asarray(n1, dtype=np.float64)
    b = np.asarray(n2, dtype=np.float64)
    dot = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    if unsigned:
        dot = np.abs(dot)
    ang = np.degrees(np.arccos(np.clip(dot, -1.0, 1.0)))
    return float(ang) if np.ndim(ang) == 0 else ang


def plane_errors(plane_est: np.ndarray, plane_ref: np.ndarray) -> tuple[float, float]:
    """(angle error in degrees, offset error in m) between two planes ``[n, d]``, sign-agnostic.

    The estimate is flipped to the reference's side first, so a plane fitted with the opposite normal is compared
    fairly; the offset error is ``|d_est - d_ref|`` after that flip (the distance between the planes along the
    normal at the origin).
    """
    e = np.asarray(plane_est, dtype=np.float64).reshape(4).copy()
    r = np.asarray(plane_ref, dtype=np.float64).reshape(4)
    e /= np.linalg.norm(e[:3])
    if np.dot(e[:3], r[:3]) < 0:
        e = -e
    return float(plane_angle_deg(e[:3], r[:3])), float(abs(e[3] - r[3] / np.linalg.norm(r[:3])))


def orient_toward(normals: np.ndarray, offsets: np.ndarray, viewpoint: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Flip planes so their normals point toward ``viewpoint`` (default: the frame origin, i.e. the sensor).

    A plane faces the viewpoint ``v`` when ``n . v + d > 0``. Returns new arrays (N, 3), (N,).
    """
    n = np.array(normals, dtype=np.float64).reshape(-1, 3)
    d = np.array(offsets, dtype=np.float64).reshape(-1)
    v = np.zeros(3) if viewpoint is None else np.asarray(viewpoint, dtype=np.float64).reshape(3)
    flip = (n @ v + d) < 0
    n[flip] *= -1
    d[flip] *= -1
    return n, d


def plane_from_points_exact(p0: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Plane ``[n, d]`` through three non-collinear points."""
    p0, p1, p2 = (np.asarray(p, dtype=np.float64).reshape(3) for p in (p0, p1, p2))
    n = np.cross(p1 - p0, p2 - p0)
    norm = np.linalg.norm(n)
    if norm < 1e-12:
        raise ValueError("p0, p1, p2: expected three non-collinear points")
    n /= norm
    return np.concatenate([n, [-float(n @ p0)]])


def point_plane_distance(points: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """Signed distances (N,) of points (N, 3) to a plane ``[n, d]`` with unit ``n``."""
    p = np.asarray(plane, dtype=np.float64).reshape(4)
    return np.asarray(points, dtype=np.float64) @ p[:3] + p[3]


def angle_window_ok(angle_deg: float, lo_deg: float, hi_deg: float) -> bool:
    """True when ``lo <= angle <= hi`` (helper for the triplet orthogonality window)."""
    return lo_deg <= angle_deg <= hi_deg and math.isfinite(angle_deg)


# Directions whose stiffness (``e^T M e``) is at most this many times the least count as weak. Two perpendicular
# walls of equal area make every direction between them equally stiff: the eigenvector is then an accident of
# rounding, and half-way between the walls both of them support it.
_WEAK_STIFFNESS_RATIO = 2.0


def _half_sphere(m: int) -> np.ndarray:
    """(m, 3) unit vectors spread evenly over the half sphere z >= 0 (a Fibonacci lattice)."""
    i = np.arange(m) + 0.5
    z = i / m
    phi = i * (math.pi * (3.0 - math.sqrt(5.0)))
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


_SPHERE = _half_sphere(2000)
_CIRCLE = np.radians(np.arange(0.0, 180.0, 1.0))


def weakest_direction_support(normals: np.ndarray, areas: np.ndarray) -> tuple[np.ndarray, float]:
    """The direction along which planes (unit ``normals`` (N, 3), ``areas`` (N,) in m^2, N >= 1) pin a translation
    least, and the area that pins it there.

    A plane supports a direction when its normal is within 60 degrees of it. The weak direction is the eigenvector
    of ``M = sum a n n^T`` with the smallest eigenvalue, as in ICP degeneracy analysis. When other eigenvalues are
    at most ``_WEAK_STIFFNESS_RATIO`` times the smallest, the translation is about as weak along their eigenvectors
    (for equal eigenvalues the one first is an accident of rounding): every direction of their span at most that
    many times as stiff as the least (``e^T M e``; sampled every degree in a plane, on 2,000 directions in space)
    is weak, and the one with the least support is returned. A corridor view
    (floor, ceiling, two walls and one door jamb) is pinned along the corridor by the jamb alone; a room corner
    with two walls of equal area is pinned along either wall's normal by that wall alone, not by both, as the
    direction half-way between them would say. Returns ``(direction (3,), area)``.
    """
    normals = np.asarray(normals, dtype=np.float64)
    areas = np.asarray(areas, dtype=np.float64)
    M = (normals * areas[:, None]).T @ normals
    w, V = np.linalg.eigh(M)
    limit = _WEAK_STIFFNESS_RATIO * max(float(w[0]), 0.0) + 1e-12 * max(float(w[-1]), 0.0)
    k = int(np.sum(w <= limit))
    if k <= 1:
        e = V[:, 0]
        return e, float(areas[np.abs(normals @ e) >= 0.5].sum())
    if k == 2:
        D = np.cos(_CIRCLE)[:, None] * V[:, 0] + np.sin(_CIRCLE)[:, None] * V[:, 1]
    else:
        D = np.concatenate([V.T, _SPHERE])
    D = D[((D @ M) * D).sum(axis=1) <= limit]  # the first row, an eigenvector of w[0], always stays
    support = (np.abs(D @ normals.T) >= 0.5) @ areas
    b = int(np.argmin(support))
    return D[b], float(support[b])
