"""The 3x3 eigen solver, plane moments and covariance, and the robust single-plane fit, against NumPy references."""

from __future__ import annotations

import numpy as np
import pytest

from reloc.extraction import ExtractionParams, fit_plane
from reloc.extraction._kernels_linalg import plane_covariance, plane_from_moments, sym_eig3
from reloc.planes import plane_errors


def _rotation(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q


@pytest.mark.parametrize("seed", range(5))
def test_sym_eig3_matches_numpy(seed):
    rng = np.random.default_rng(seed)
    cases = [rng.normal(size=(3, 3)) for _ in range(50)]
    cases = [m @ m.T for m in cases]
    # Nearly degenerate spectra: a plane (two close large eigenvalues) and a line.
    for diag in ([1e-9, 1.0, 1.0 + 1e-10], [1e-6, 1e-6 + 1e-12, 2.0], [0.0, 0.0, 0.0], [3.0, 3.0, 3.0]):
        r = _rotation(rng)
        cases.append(r @ np.diag(diag) @ r.T)
    for a in cases:
        w = np.zeros(3)
        v = np.zeros((3, 3))
        sym_eig3(a.copy(), w, v)
        w_ref, v_ref = np.linalg.eigh(a)
        scale = max(np.abs(w_ref).max(), 1e-300)
        assert np.abs(w - w_ref).max() <= 1e-13 * scale + 1e-300
        assert np.allclose(v.T @ v, np.eye(3), atol=1e-12)
        assert np.allclose(a @ v, v * w, atol=1e-12 * scale + 1e-300)
        if w_ref[1] - w_ref[0] > 1e-6 * scale:  # a well-separated smallest eigenvector is unique up to sign
            assert abs(abs(v[:, 0] @ v_ref[:, 0]) - 1.0) < 1e-10


def test_plane_from_moments_and_covariance_match_numpy():
    rng = np.random.default_rng(3)
    n_true = np.array([0.3, -0.4, -0.866])
    n_true /= np.linalg.norm(n_true)
    a = np.cross(n_true, [1.0, 0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(n_true, a)
    uv = rng.uniform(-1, 1, size=(500, 2))
    sig = rng.uniform(0.001, 0.01, size=500)
    pts = np.array([1.0, 2.0, 4.0]) + uv[:, :1] * a + uv[:, 1:] * b + (rng.normal(size=500) * sig)[:, None] * n_true
    w = 1.0 / sig**2
    ref = pts[0].copy()
    q = pts - ref
    W, s, S = w.sum(), (w[:, None] * q).sum(0), (w[:, None, None] * q[:, :, None] * q[:, None, :]).sum(0)
    out = plane_from_moments(W, s, S, ref, np.zeros((3, 3)), np.zeros(3), np.zeros((3, 3)))
    n = np.array(out[:3])
    # Reference: weighted PCA with NumPy.
    mu = (w[:, None] * pts).sum(0) / W
    C = ((w[:, None] * (pts - mu)).T @ (pts - mu)) / W
    lam, vec = np.linalg.eigh(C)
    n_ref = vec[:, 0] * np.sign(vec[:, 0] @ n)
    assert np.allclose(n, n_ref, atol=1e-12)
    assert out[3] == pytest.approx(-n_ref @ mu, abs=1e-12)
    assert np.allclose(out[4:], lam, rtol=1e-9, atol=1e-15)
    # Covariance: Gauss-Newton in a tangent parameterisation, computed densely with NumPy.
    cov = np.zeros((4, 4))
    s0sq = plane_covariance(out[0], out[1], out[2], out[3], W, s, S, ref, 500.0, cov)
    r = pts @ n + out[3]
    assert s0sq == pytest.approx((w * r**2).sum() / (500 - 3), rel=1e-9)
    t1 = np.cross(n, [0.0, 1.0, 0.0] if abs(n[0]) >= 0.9 else [1.0, 0.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    B = np.zeros((4, 3))
    B[:3, 0], B[:3, 1], B[3, 2] = t1, t2, 1.0
    J = np.column_stack([pts, np.ones(500)]) @ B
    cov_ref = s0sq * B @ np.linalg.inv(J.T @ (w[:, None] * J)) @ B.T
    assert np.allclose(cov, cov_ref, rtol=1e-7, atol=1e-18)
    # s0^2 near 1 because the weights are the exact inverse variances.
    assert 0.8 < s0sq < 1.2


def _table2_plane(rng, n=20000, outliers=0.05, coeff=1.425e-3):
    """The paper's Table 2 protocol: a plane at a random orientation, depths 1-9 m, noise sigma = c z^2 along the
    normal, a fraction of outliers uniform in the points' bounding box."""
    normal = rng.normal(size=3)
    normal[2] = -abs(normal[2]) - 0.5
    normal /= np.linalg.norm(normal)
    c0 = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), 5.0])
    a = np.cross(normal, [1.0, 0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    uv = rng.uniform(-12, 12, size=(40 * n, 2))
    p = c0 + uv[:, :1] * a + uv[:, 1:] * b
    keep = (p[:, 2] >= 1) & (p[:, 2] <= 9) & (np.abs(p[:, 0]) < 0.6 * p[:, 2]) & (np.abs(p[:, 1]) < 0.5 * p[:, 2])
    p = p[keep][:n]
    assert len(p) == n
    p = p + (rng.normal(size=n) * coeff * p[:, 2] ** 2)[:, None] * normal
    k = int(outliers * n)
    p[:k] = rng.uniform(p.min(0), p.max(0), size=(k, 3))
    return p, np.concatenate([normal, [-normal @ c0]])


@pytest.mark.parametrize("seed", [0, 1])
def test_fit_plane_table2_protocol(seed):
    rng = np.random.default_rng(seed)
    pts, truth = _table2_plane(rng)
    n, d, cov = fit_plane(pts, noise_direction="normal")
    ang, off = plane_errors(np.concatenate([n, [d]]), truth)
    # The goal of the issue is 0.05 deg and 3 mm; the Cramer-Rao level on these data is ~0.015 deg / 0.5 mm.
    assert ang < 0.05 and off < 0.003
    # Oriented toward the sensor at the origin.
    assert d > 0
    # The reported covariance is of the right size: the angle error is within 5 sigma of the predicted spread.
    sd_angle = np.degrees(np.sqrt(np.trace(cov[:3, :3])))
    assert 1e-4 < sd_angle < 0.05 and ang < 5 * sd_angle
    # Plain PCA on the same points is far worse (so the data really are hard).
    c = pts.mean(0)
    n_pca = np.linalg.eigh(np.cov(pts.T))[1][:, 0]
    ang_pca, _ = plane_errors(np.concatenate([n_pca, [-n_pca @ c]]), truth)
    assert ang_pca > 5 * ang


def test_fit_plane_switches_and_determinism():
    rng = np.random.default_rng(5)
    pts, truth = _table2_plane(rng, n=5000)
    a = fit_plane(pts, noise_direction="normal", seed=3)
    b = fit_plane(pts[rng.permutation(len(pts))], noise_direction="normal", seed=3)
    # Shuffling changes the RANSAC draws but not the converged IRLS solution.
    assert plane_errors(np.concatenate([a[0], [a[1]]]), np.concatenate([b[0], [b[1]]]))[0] < 1e-6
    # Robust weights off (irls_iterations=0): outliers pull the fit away.
    n0, d0, _ = fit_plane(pts, noise_direction="normal", irls_iterations=0)
    assert plane_errors(np.concatenate([n0, [d0]]), truth)[0] > 0.1
    # No RANSAC start still converges here (5% outliers) thanks to the IRLS.
    n1, d1, _ = fit_plane(pts, noise_direction="normal", ransac_hypotheses=0)
    assert plane_errors(np.concatenate([n1, [d1]]), truth)[0] < 0.1


def test_fit_plane_rejects_bad_input():
    with pytest.raises(ValueError, match="points: expected shape"):
        fit_plane(np.zeros((10, 2)))
    with pytest.raises(ValueError, match="at least 3 finite points"):
        fit_plane(np.array([[0, 0, 1.0], [np.nan, 0, 1], [1, 0, 1], [np.inf, 1, 1]]))
    with pytest.raises(ValueError, match="unknown parameter"):
        fit_plane(np.eye(3) + 1, not_a_param=1)
    with pytest.raises(ValueError, match="sensor_origin"):
        fit_plane(np.eye(3) + 1, sensor_origin=(0, 0))


def test_fit_plane_ignores_non_finite_rows():
    rng = np.random.default_rng(2)
    xy = rng.uniform(-1, 1, size=(300, 2))
    pts = np.column_stack([xy, 2.0 + 0.001 * rng.normal(size=300)])
    bad = pts.copy()
    bad[::7] = np.nan
    bad[3::11, 2] = np.inf
    n, d, _ = fit_plane(bad)
    assert np.all(np.isfinite(n)) and np.isfinite(d)
    assert plane_errors(np.concatenate([n, [d]]), np.array([0, 0, -1.0, 2.0]))[0] < 0.5


def test_params_from_config_and_validation():
    from reloc.config import Config, config_from_dict

    p = ExtractionParams.from_config(Config())
    assert p == ExtractionParams()  # the defaults of the config and of the parameters are the same
    assert p.grow_max_angle_rad == pytest.approx(np.radians(10.0))
    assert p.voxel_size_m == Config().extraction.voxel_size_m
    cfg = config_from_dict({"merging": {"enabled": False}, "camera": {"gravity_source": "imu"}})
    p2 = ExtractionParams.from_config(cfg)
    assert p2.merge is False and p2.gravity_fallback == "none"
    corner = ExtractionParams.from_config(config_from_dict({"extraction": {"corner_min_angle_deg": 10.0}}))
    assert corner.corner_min_angle_rad == pytest.approx(np.radians(10.0))
    assert (p.corner_min_angle_rad, p.grow_max_offset_m) == (pytest.approx(np.radians(20.0)), 0.02)
    with pytest.raises(ValueError, match="corner_min_angle_rad"):
        ExtractionParams(corner_min_angle_rad=2.0)
    with pytest.raises(ValueError, match="voxel_size_m"):
        ExtractionParams(voxel_size_m=-1.0)
    with pytest.raises(ValueError, match="noise_direction"):
        ExtractionParams(noise_direction="sideways")
