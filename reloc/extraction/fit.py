"""Robust weighted plane fit of one arbitrary point set (the per-voxel refit applied to a whole set)."""

from __future__ import annotations

import numpy as np

from reloc.extraction import _kernels_fit as kf
from reloc.extraction.params import ExtractionParams

__all__ = ["fit_plane", "check_points", "MAX_COORDINATE_M"]

MAX_COORDINATE_M = 1e9


def check_points(points: np.ndarray, name: str = "points", min_points: int = 0) -> np.ndarray:
    """Validate an (N, 3) point array; return it as contiguous float64 with the non-finite rows dropped."""
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (N, 3), got {pts.shape}")
    if not np.issubdtype(pts.dtype, np.number):
        raise ValueError(f"{name}: expected a numeric array, got dtype {pts.dtype}")
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    finite = np.isfinite(pts).all(axis=1)
    if not finite.all():
        pts = np.ascontiguousarray(pts[finite])
    # Sums of squares of farther points overflow (a NaN plane) or lose all precision; those of nearer-than-tiny
    # coordinates underflow to subnormals, which turn the eigen-solver's rotations into NaN.
    if pts.size and np.abs(pts).max() > MAX_COORDINATE_M:
        raise ValueError(f"{name}: coordinates up to {np.abs(pts).max():.3g} m, expected within +-{MAX_COORDINATE_M:g} m "
                         "(are the points in metres?)")
    tiny = np.abs(pts) < 1e-100
    if tiny.any():
        pts = np.where(tiny, 0.0, pts)
    if pts.shape[0] < min_points:
        raise ValueError(f"{name}: expected at least {min_points} finite points, got {pts.shape[0]}")
    return pts


def fit_plane(
    points: np.ndarray,
    params: ExtractionParams | None = None,
    *,
    sensor_origin=(0.0, 0.0, 0.0),
    max_iterations: int = 50,
    **overrides,
) -> tuple[np.ndarray, float, np.ndarray]:
    """Robust weighted plane through ``points``.

    Args:
        points: (N, 3) points (any float dtype), N >= 3, in a frame whose z axis is the sensor's viewing direction
            (the camera frame): the noise law uses ``z - sensor_origin_z`` as the depth. Non-finite rows are ignored.
        params: :class:`ExtractionParams` (defaults when None); any of its fields can also be given as keyword
            overrides, e.g. ``fit_plane(p, noise_direction="normal", noise_model="tof", noise_coeff=0.01)``. Used:
            ``noise_model``, ``noise_coeff``, ``noise_direction``, ``noise_weights``, ``adaptive_weights``
            (``alpha``, ``beta``), ``irls_iterations`` (0 switches the robust weights off; otherwise the IRLS runs
            to convergence, at most ``max_iterations`` passes), ``irls_kernel_sigmas``, ``ransac_hypotheses``,
            ``seed``.
        sensor_origin: (3,) where the sensor is: the normal is oriented toward it, and with
            ``noise_direction="ray"`` the viewing rays start there.

    Returns:
        ``(normal (3,), d, cov (4, 4))``: unit normal and offset with ``normal . p + d = 0``, the normal pointing to
        the sensor's side, and the covariance of ``(nx, ny, nz, d)`` (scaled by the a-posteriori variance factor).
    """
    p = params if params is not None else ExtractionParams()
    if overrides:
        p = p.with_(**overrides)
    pts = check_points(points, "points", min_points=3)
    origin = np.asarray(sensor_origin, dtype=np.float64).reshape(-1)
    if origin.shape != (3,) or not np.all(np.isfinite(origin)):
        raise ValueError(f"sensor_origin: expected 3 finite numbers, got {origin.tolist()}")
    if not isinstance(max_iterations, int) or max_iterations < 1:
        raise ValueError(f"max_iterations: expected an integer >= 1, got {max_iterations!r}")
    plane = np.zeros(4)
    cov = np.zeros((4, 4))
    # The kernels work with the sensor at the origin.
    kf.robust_fit_points(
        np.ascontiguousarray(pts - origin), p.noise_power, float(p.noise_coeff), p.noise_direction == "ray",
        bool(p.noise_weights), bool(p.adaptive_weights), float(p.alpha), float(p.beta), p.irls_iterations > 0,
        float(p.irls_kernel_sigmas), int(p.ransac_hypotheses), int(p.seed), int(max_iterations), plane, cov,
    )
    if not (np.all(np.isfinite(plane)) and np.all(np.isfinite(cov))):
        raise ValueError(f"points: no finite plane fits these {len(pts)} points (degenerate or badly scaled)")
    normal = plane[:3].copy()
    # Back to the input frame: n . (p - o) + d_o = 0  ->  d = d_o - n . o; (n, d) = J (n, d_o), J = [[I, 0], [-o^T, 1]].
    d = float(plane[3] - normal @ origin)
    if np.any(origin != 0.0):
        J = np.eye(4)
        J[3, :3] = -origin
        cov = J @ cov @ J.T
    return normal, d, cov
