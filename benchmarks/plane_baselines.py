"""Single-plane fitting baselines the paper compares against (its Table 2), for the accuracy benchmarks.

Every baseline takes points (N, 3) in the sensor frame and returns a :class:`BaselineFit`: a unit normal and an
offset with ``n . p + d = 0``, oriented toward the sensor origin (``d >= 0``), plus how many points it kept and how
many hypotheses it tried. Randomised methods take an explicit ``numpy.random.Generator``; nothing reads global RNG
state, so a seed reproduces a run exactly.

- ``pca``: plane through the centroid, normal = smallest eigenvector of the scatter, all points, no weights.
- ``pca_ls`` (PCA-LS, Klasing et al. 2009 [53]): PCA for the frame, then one unweighted ordinary least-squares refit
  of the height along the PCA normal as an affine function of the in-plane coordinates, on the points within
  ``gate_sigmas`` robust standard deviations (1.4826 * median |residual|) of the PCA plane.
- ``ransac``: 3-point hypotheses scored by inlier count at ``threshold_m``, adaptive number of iterations for the
  stated ``confidence`` (capped at ``max_iterations``), final PCA refit on the inliers of the best hypothesis.
- ``lo_ransac`` (Chum et al. 2003 [54]): as ``ransac``, and each time a new best is found, a local optimisation:
  iterative least squares with the threshold shrinking from ``lo_threshold_scale * t`` to ``t``, and an inner
  RANSAC drawing non-minimal samples from the inliers, each followed by the same iterative least squares.
- ``ndt_ransac`` (Li et al. 2017 [29]): the cloud is split into NDT cells; a cell is planar when it has enough
  points and its smallest covariance eigenvalue is small against the middle one; RANSAC runs over the planar cells'
  planes (a hypothesis is one cell's plane; cells agreeing in normal angle and centroid distance are its consensus,
  scored by their point count) and the final plane is a PCA fit of the points of the consensus cells.
- ``open3d`` (optional): ``open3d.geometry.PointCloud.segment_plane``, only when open3d is importable.

Run ``python benchmarks/extraction_accuracy.py`` for the comparison; the numba kernel here (inlier counting) is
checked against a NumPy reference in ``tests/test_baselines.py``.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from reloc._numba import njit, register_warmup

__all__ = [
    "BaselineFit",
    "BASELINES",
    "count_inliers",
    "count_inliers_reference",
    "pca_plane",
    "pca_ls_plane",
    "ransac_plane",
    "lo_ransac_plane",
    "ndt_ransac_plane",
    "open3d_plane",
    "open3d_available",
]


@dataclass(frozen=True)
class BaselineFit:
    """A fitted plane ``n . p + d = 0`` (``normal`` (3,) unit float64, toward the sensor) and diagnostics."""

    normal: np.ndarray
    d: float
    n_inliers: int
    iterations: int = 0
    note: str = ""

    @property
    def plane(self) -> np.ndarray:
        return np.concatenate([self.normal, [self.d]])


# ----------------------------------------------------------------------------------------------------------------
# Input checks and small geometry
# ----------------------------------------------------------------------------------------------------------------


def _check_points(points: np.ndarray, name: str = "points", min_points: int = 3) -> np.ndarray:
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (N, 3), got {p.shape}")
    if p.shape[0] < min_points:
        raise ValueError(f"{name}: expected at least {min_points} points, got {p.shape[0]}")
    p = np.ascontiguousarray(p, dtype=np.float64)
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{name}: expected finite coordinates, got NaN or inf")
    return p


def _check_positive(value: float, name: str) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name}: expected a finite value > 0, got {value!r}")
    return v


def _check_rng(rng) -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng: expected a numpy.random.Generator (np.random.default_rng(seed)), got {type(rng).__name__}")
    return rng


def _oriented(normal: np.ndarray, d: float) -> tuple[np.ndarray, float]:
    """Unit normal and offset, flipped so the sensor origin is on the positive side (``d >= 0``)."""
    n = np.asarray(normal, dtype=np.float64)
    norm = np.linalg.norm(n)
    n = n / norm
    d = float(d) / norm
    if d < 0:
        return -n, -d
    return n, d


def _pca(points: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centroid (3,), eigenvalues ascending (3,), eigenvectors as columns (3, 3)) of the (weighted) scatter."""
    if weights is None:
        c = points.mean(axis=0)
        q = points - c
        s = q.T @ q / points.shape[0]
    else:
        w = weights / weights.sum()
        c = w @ points
        q = points - c
        s = (q * w[:, None]).T @ q
    evals, evecs = np.linalg.eigh(s)
    return c, evals, evecs


def _plane_pca(points: np.ndarray) -> tuple[np.ndarray, float]:
    c, _, evecs = _pca(points)
    n = evecs[:, 0]
    return _oriented(n, -n @ c)


def _distances(points: np.ndarray, n: np.ndarray, d: float) -> np.ndarray:
    return points @ n + d


# ----------------------------------------------------------------------------------------------------------------
# Numba kernel: inlier counting for a batch of hypotheses (the hot loop of every RANSAC variant)
# ----------------------------------------------------------------------------------------------------------------


@njit
def _count_inliers_kernel(points, planes, threshold, out):
    n_pts = points.shape[0]
    for k in range(planes.shape[0]):
        nx = planes[k, 0]
        ny = planes[k, 1]
        nz = planes[k, 2]
        d = planes[k, 3]
        if not (np.isfinite(nx) and np.isfinite(ny) and np.isfinite(nz) and np.isfinite(d)):
            out[k] = -1
            continue
        c = 0
        for i in range(n_pts):
            r = nx * points[i, 0] + ny * points[i, 1] + nz * points[i, 2] + d
            if abs(r) <= threshold:
                c += 1
        out[k] = c


def count_inliers(points: np.ndarray, planes: np.ndarray, threshold_m: float) -> np.ndarray:
    """Number of points within ``threshold_m`` of each plane.

    points (N, 3) float64 C-contiguous, planes (K, 4) ``[n, d]`` with unit ``n``; a non-finite plane counts -1.
    Returns (K,) int64.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    pl = np.ascontiguousarray(planes, dtype=np.float64).reshape(-1, 4)
    out = np.empty(pl.shape[0], dtype=np.int64)
    _count_inliers_kernel(pts, pl, float(threshold_m), out)
    return out


def count_inliers_reference(points: np.ndarray, planes: np.ndarray, threshold_m: float) -> np.ndarray:
    """Slow, obviously-correct NumPy version of :func:`count_inliers` (for the tests)."""
    pl = np.asarray(planes, dtype=np.float64).reshape(-1, 4)
    out = np.empty(pl.shape[0], dtype=np.int64)
    for k, row in enumerate(pl):
        if not np.all(np.isfinite(row)):
            out[k] = -1
            continue
        r = np.asarray(points, dtype=np.float64) @ row[:3] + row[3]
        out[k] = int(np.count_nonzero(np.abs(r) <= threshold_m))
    return out


@register_warmup
def _warm() -> None:
    pts = np.zeros((4, 3))
    count_inliers(pts, np.array([[0.0, 0.0, 1.0, 0.0]]), 0.1)


def _hypotheses(points: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """Planes (K, 4) through the point triples ``samples`` (K, 3); degenerate triples give NaN rows."""
    p0 = points[samples[:, 0]]
    n = np.cross(points[samples[:, 1]] - p0, points[samples[:, 2]] - p0)
    norm = np.linalg.norm(n, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = n / norm[:, None]
    n[norm < 1e-12] = np.nan
    d = -np.einsum("ij,ij->i", n, p0)
    return np.column_stack([n, d])


def _required_iterations(n_inliers: int, n_points: int, confidence: float, sample_size: int = 3) -> float:
    w = n_inliers / n_points
    if w <= 0:
        return math.inf
    p_good = w**sample_size
    if p_good >= 1.0:
        return 0.0
    return math.log(1.0 - confidence) / math.log(1.0 - p_good)


# ----------------------------------------------------------------------------------------------------------------
# The baselines
# ----------------------------------------------------------------------------------------------------------------


def pca_plane(points: np.ndarray) -> BaselineFit:
    """Plain PCA on all points (the paper's 'PCA' [51])."""
    p = _check_points(points)
    n, d = _plane_pca(p)
    return BaselineFit(n, d, p.shape[0])


def pca_ls_plane(points: np.ndarray, *, gate_sigmas: float = 3.0) -> BaselineFit:
    """PCA, then one unweighted least-squares refit of the gated points (the paper's 'PCA-LS' [53]).

    The gate keeps points within ``gate_sigmas`` robust standard deviations (1.4826 * median |r|) of the PCA plane;
    the refit is ordinary least squares of the height ``h = a u + b v + c`` in the PCA frame (u, v in the plane).
    """
    p = _check_points(points)
    gate = _check_positive(gate_sigmas, "gate_sigmas")
    c, _, evecs = _pca(p)
    e1, e2, n0 = evecs[:, 2], evecs[:, 1], evecs[:, 0]
    q = p - c
    h = q @ n0
    s = 1.4826 * np.median(np.abs(h))
    keep = np.abs(h) <= gate * s if s > 0 else np.ones(p.shape[0], dtype=bool)
    if np.count_nonzero(keep) < 3:
        keep[:] = True
    u, v = q[keep] @ e1, q[keep] @ e2
    a_mat = np.column_stack([u, v, np.ones_like(u)])
    (a, b, c0), *_ = np.linalg.lstsq(a_mat, h[keep], rcond=None)
    # h - a u - b v - c0 = 0  <=>  n = n0 - a e1 - b e2 (then normalised), through the point c + c0 n0.
    n = n0 - a * e1 - b * e2
    n_unit = n / np.linalg.norm(n)
    n_out, d_out = _oriented(n_unit, -n_unit @ (c + c0 * n0))
    return BaselineFit(n_out, d_out, int(np.count_nonzero(keep)))


def _ransac_search(
    p: np.ndarray,
    threshold: float,
    rng: np.random.Generator,
    confidence: float,
    max_iterations: int,
    batch: int,
    on_new_best: Callable[[np.ndarray, int], tuple[np.ndarray, int]] | None = None,
) -> tuple[np.ndarray, int, int]:
    """Shared RANSAC loop: (best plane (4,), its inlier count, hypotheses tried)."""
    n_pts = p.shape[0]
    best = np.full(4, np.nan)
    best_count = -1
    tried = 0
    needed = math.inf
    while tried < max_iterations and tried < needed:
        k = min(batch, max_iterations - tried)
        samples = rng.integers(0, n_pts, size=(k, 3))
        planes = _hypotheses(p, samples)
        counts = count_inliers(p, planes, threshold)
        j = int(np.argmax(counts))
        if counts[j] > best_count:
            best, best_count = planes[j], int(counts[j])
            if on_new_best is not None:
                best, best_count = on_new_best(best, best_count)
            needed = _required_iterations(best_count, n_pts, confidence)
        tried += k
    return best, best_count, tried


def ransac_plane(
    points: np.ndarray,
    *,
    threshold_m: float,
    rng: np.random.Generator,
    confidence: float = 0.99,
    max_iterations: int = 1000,
    batch: int = 32,
) -> BaselineFit:
    """RANSAC with 3-point hypotheses, adaptive iteration count, and a final PCA refit on the inliers.

    The number of hypotheses is ``log(1 - confidence) / log(1 - w^3)`` for the best inlier ratio ``w`` found so
    far, capped at ``max_iterations`` (drawn ``batch`` at a time, so up to ``batch - 1`` more may be tried).
    """
    p = _check_points(points)
    t = _check_positive(threshold_m, "threshold_m")
    rng = _check_rng(rng)
    if not 0 < confidence < 1:
        raise ValueError(f"confidence: expected 0 < confidence < 1, got {confidence!r}")
    best, _, tried = _ransac_search(p, t, rng, confidence, int(max_iterations), int(batch))
    inl = np.abs(_distances(p, best[:3], best[3])) <= t
    if np.count_nonzero(inl) < 3:
        n, d = _oriented(best[:3], best[3])
        return BaselineFit(n, d, int(np.count_nonzero(inl)), tried, "no refit (fewer than 3 inliers)")
    n, d = _plane_pca(p[inl])
    return BaselineFit(n, d, int(np.count_nonzero(inl)), tried)


def _iterative_ls(p: np.ndarray, plane: np.ndarray, t: float, scale: float, steps: int) -> np.ndarray:
    """Chum's iterative least squares: PCA refits on inliers at thresholds shrinking from scale*t to t."""
    n, d = plane[:3], plane[3]
    for s in np.linspace(scale, 1.0, max(steps, 1)):
        inl = np.abs(_distances(p, n, d)) <= s * t
        if np.count_nonzero(inl) < 3:
            break
        n, d = _plane_pca(p[inl])
    return np.concatenate([n, [d]])


def lo_ransac_plane(
    points: np.ndarray,
    *,
    threshold_m: float,
    rng: np.random.Generator,
    confidence: float = 0.99,
    max_iterations: int = 1000,
    lo_threshold_scale: float = 3.0,
    lo_steps: int = 4,
    lo_inner_iterations: int = 10,
    lo_sample_size: int = 24,
    batch: int = 32,
) -> BaselineFit:
    """LO-RANSAC (Chum, Matas, Kittler 2003): RANSAC with a local optimisation of every new best model.

    Local optimisation: iterative least squares over ``lo_steps`` thresholds from ``lo_threshold_scale * t`` down
    to ``t``, and ``lo_inner_iterations`` inner hypotheses each fitted (PCA) to ``lo_sample_size`` points drawn from
    the current inliers and then iterated the same way; the model with the most inliers at ``t`` is kept.
    """
    p = _check_points(points)
    t = _check_positive(threshold_m, "threshold_m")
    rng = _check_rng(rng)
    if not 0 < confidence < 1:
        raise ValueError(f"confidence: expected 0 < confidence < 1, got {confidence!r}")

    def local_opt(plane: np.ndarray, count: int) -> tuple[np.ndarray, int]:
        best_plane, best_count = plane, count
        candidates = [_iterative_ls(p, plane, t, lo_threshold_scale, lo_steps)]
        inl_idx = np.flatnonzero(np.abs(_distances(p, plane[:3], plane[3])) <= t)
        if inl_idx.size > lo_sample_size:
            for _ in range(lo_inner_iterations):
                sub = rng.choice(inl_idx, size=lo_sample_size, replace=False)
                n0, d0 = _plane_pca(p[sub])
                candidates.append(_iterative_ls(p, np.concatenate([n0, [d0]]), t, lo_threshold_scale, lo_steps))
        counts = count_inliers(p, np.array(candidates), t)
        j = int(np.argmax(counts))
        if counts[j] >= best_count:
            best_plane, best_count = candidates[j], int(counts[j])
        return best_plane, best_count

    best, count, tried = _ransac_search(p, t, rng, confidence, int(max_iterations), int(batch), local_opt)
    inl = np.abs(_distances(p, best[:3], best[3])) <= t
    n, d = _oriented(best[:3], best[3])
    return BaselineFit(n, d, int(np.count_nonzero(inl)), tried)


def ndt_ransac_plane(
    points: np.ndarray,
    *,
    threshold_m: float,
    rng: np.random.Generator,
    cell_size_m: float = 0.5,
    min_cell_points: int = 10,
    max_eigen_ratio: float = 0.1,
    max_angle_deg: float = 5.0,
    max_hypotheses: int = 200,
) -> BaselineFit:
    """NDT cells + RANSAC over the planar cells (Li et al. 2017, the paper's 'NDT-RANSAC' [29]).

    Cells are ``cell_size_m`` cubes; a cell with at least ``min_cell_points`` points is planar when
    ``lambda_min <= max_eigen_ratio * lambda_mid`` of its covariance. Each hypothesis is a planar cell's plane (all
    of them, or ``max_hypotheses`` drawn without replacement); its consensus is the planar cells whose normal is
    within ``max_angle_deg`` and whose centroid is within ``threshold_m`` of it, scored by their point count. The
    result is a PCA fit of the points of the best consensus. With no planar cell it falls back to
    :func:`ransac_plane` (``note`` says so).
    """
    p = _check_points(points)
    t = _check_positive(threshold_m, "threshold_m")
    cell = _check_positive(cell_size_m, "cell_size_m")
    rng = _check_rng(rng)

    keys = np.floor((p - p.min(axis=0)) / cell).astype(np.int64)
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    n_cells = int(inverse.max()) + 1
    counts = np.bincount(inverse, minlength=n_cells)
    means = np.stack([np.bincount(inverse, p[:, j], n_cells) for j in range(3)], axis=1) / counts[:, None]
    q = p - means[inverse]
    cov = np.empty((n_cells, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            cov[:, a, b] = cov[:, b, a] = np.bincount(inverse, q[:, a] * q[:, b], n_cells) / counts
    evals, evecs = np.linalg.eigh(cov)
    planar = (counts >= min_cell_points) & (evals[:, 0] <= max_eigen_ratio * evals[:, 1])
    cells = np.flatnonzero(planar)
    if cells.size == 0:
        fit = ransac_plane(p, threshold_m=t, rng=rng)
        return BaselineFit(fit.normal, fit.d, fit.n_inliers, fit.iterations, "no planar NDT cell: plain RANSAC")
    normals = evecs[cells, :, 0]
    centroids = means[cells]
    weights = counts[cells]
    hyps = cells.size if cells.size <= max_hypotheses else max_hypotheses
    order = np.arange(cells.size) if hyps == cells.size else rng.choice(cells.size, size=hyps, replace=False)
    cos_max = math.cos(math.radians(max_angle_deg))
    hn = normals[order]
    hd = -np.einsum("ij,ij->i", hn, centroids[order])
    agree = (np.abs(hn @ normals.T) >= cos_max) & (np.abs(hn @ centroids.T + hd[:, None]) <= t)
    score = agree.astype(np.int64) @ weights
    best = int(np.argmax(score))
    members = cells[agree[best]]
    sel = np.isin(inverse, members)
    n, d = _plane_pca(p[sel])
    return BaselineFit(n, d, int(np.count_nonzero(sel)), hyps, f"{members.size} of {cells.size} planar cells")


def open3d_available() -> bool:
    try:
        importlib.import_module("open3d")
    except Exception:  # ImportError, or a broken binary wheel
        return False
    return True


def open3d_plane(
    points: np.ndarray, *, threshold_m: float, seed: int, num_iterations: int = 1000, probability: float = 0.99
) -> BaselineFit:
    """Open3D's ``segment_plane`` (RANSAC; optional dependency, imported here). Raises ImportError without it."""
    import open3d as o3d

    p = _check_points(points)
    t = _check_positive(threshold_m, "threshold_m")
    o3d.utility.random.seed(int(seed))
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
    model, inliers = pcd.segment_plane(
        distance_threshold=t, ransac_n=3, num_iterations=int(num_iterations), probability=float(probability)
    )
    a, b, c, d = (float(x) for x in model)
    n, d = _oriented(np.array([a, b, c]), d)
    return BaselineFit(n, d, len(inliers), int(num_iterations))


# How the benchmark sets the baselines' scale parameters from the sensor noise sigma it gives them (the same
# knowledge of the noise law that ours gets): the RANSAC inlier threshold, and the NDT cell edge, large enough for
# a noisy plane to stay planar in a cell (smallest / middle eigenvalue ~ 12 sigma^2 / cell^2 ~ 0.05 < 0.1).
THRESHOLD_SIGMAS = 2.5
NDT_CELL_SIGMAS = 15.0
NDT_MIN_CELL_M = 0.5


def _ndt(p, sigma_m, rng):
    return ndt_ransac_plane(
        p, threshold_m=THRESHOLD_SIGMAS * sigma_m, rng=rng, cell_size_m=max(NDT_MIN_CELL_M, NDT_CELL_SIGMAS * sigma_m)
    )


# Name -> fit(points, *, sigma_m, rng, seed): every baseline on the same points with the same noise scale.
BASELINES: dict[str, Callable[..., BaselineFit]] = {
    "PCA": lambda p, *, sigma_m, rng, seed: pca_plane(p),
    "PCA-LS": lambda p, *, sigma_m, rng, seed: pca_ls_plane(p),
    "RANSAC": lambda p, *, sigma_m, rng, seed: ransac_plane(p, threshold_m=THRESHOLD_SIGMAS * sigma_m, rng=rng),
    "LO-RANSAC": lambda p, *, sigma_m, rng, seed: lo_ransac_plane(p, threshold_m=THRESHOLD_SIGMAS * sigma_m, rng=rng),
    "NDT-RANSAC": lambda p, *, sigma_m, rng, seed: _ndt(p, sigma_m, rng),
}
if open3d_available():
    BASELINES["Open3D"] = lambda p, *, sigma_m, rng, seed: open3d_plane(
        p, threshold_m=THRESHOLD_SIGMAS * sigma_m, seed=seed
    )
