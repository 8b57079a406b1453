"""The plane-fitting baselines of benchmarks/plane_baselines.py against ground truth on easy synthetic planes.

Data: a 4 m x 4 m plane about 4 m from the sensor, 3 mm Gaussian noise along the normal, and (for the robust
methods) 10 % outliers uniform in the padded bounding box. With ~3000 inliers the statistical error of an
inlier-only fit is about 3 mm / sqrt(3000) in offset and a few thousandths of a degree in angle, so the tolerances
below (0.1 deg, 2 mm) leave a wide margin for a correct fit yet fail for a fit that outliers pull off (plain PCA on
the contaminated cloud is off by about a degree).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import plane_baselines as pb  # noqa: E402

from reloc.planes import plane_errors  # noqa: E402

NOISE_M = 0.003
THRESHOLD_M = pb.THRESHOLD_SIGMAS * NOISE_M


def _plane_cloud(seed: int, n_inliers: int = 3000, outlier_fraction: float = 0.0):
    """Points of a tilted plane facing the origin, and its ground truth [n, d] (d > 0)."""
    rng = np.random.default_rng(seed)
    n = rng.normal(size=3)
    n[2] = -abs(n[2]) - 1.0  # facing the sensor at the origin, looking along +z
    n /= np.linalg.norm(n)
    d = 4.0
    e1 = np.cross(n, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    uv = rng.uniform(-2.0, 2.0, size=(n_inliers, 2))
    pts = -d * n + uv[:, :1] * e1 + uv[:, 1:] * e2 + rng.normal(0.0, NOISE_M, size=(n_inliers, 1)) * n
    n_out = int(round(outlier_fraction * n_inliers / (1 - outlier_fraction)))
    if n_out:
        lo, hi = pts.min(axis=0) - 0.3, pts.max(axis=0) + 0.3
        pts = np.vstack([pts, rng.uniform(lo, hi, size=(n_out, 3))])
        pts = pts[rng.permutation(pts.shape[0])]
    return pts, np.concatenate([n, [d]])


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("name", ["PCA", "PCA-LS", "RANSAC", "LO-RANSAC", "NDT-RANSAC"])
def test_baseline_recovers_clean_plane(name, seed):
    pts, truth = _plane_cloud(seed)
    fit = pb.BASELINES[name](pts, sigma_m=NOISE_M, rng=np.random.default_rng(seed), seed=seed)
    angle_deg, offset_m = plane_errors(fit.plane, truth)
    assert angle_deg < 0.1 and offset_m < 0.002, (name, angle_deg, offset_m)
    assert abs(np.linalg.norm(fit.normal) - 1.0) < 1e-12
    assert fit.d > 0  # oriented toward the sensor at the origin


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("name", ["PCA-LS", "RANSAC", "LO-RANSAC", "NDT-RANSAC"])
def test_robust_baselines_reject_outliers(name, seed):
    pts, truth = _plane_cloud(seed, outlier_fraction=0.1)
    fit = pb.BASELINES[name](pts, sigma_m=NOISE_M, rng=np.random.default_rng(seed), seed=seed)
    angle_deg, offset_m = plane_errors(fit.plane, truth)
    assert angle_deg < 0.1 and offset_m < 0.002, (name, angle_deg, offset_m)


def test_plain_pca_is_pulled_by_outliers():
    # The contrast that makes the outlier test meaningful: the same data moves plain PCA by far more.
    errs = [plane_errors(pb.pca_plane(_plane_cloud(s, outlier_fraction=0.1)[0]).plane, _plane_cloud(s)[1]) for s in range(3)]
    assert max(a for a, _ in errs) > 0.3


def test_count_inliers_matches_numpy_reference():
    rng = np.random.default_rng(5)
    pts = rng.normal(size=(500, 3))
    planes = rng.normal(size=(20, 4))
    planes[:, :3] /= np.linalg.norm(planes[:, :3], axis=1, keepdims=True)
    planes[3] = np.nan  # a degenerate hypothesis counts -1
    for t in (0.05, 0.3, 1.0):
        np.testing.assert_array_equal(pb.count_inliers(pts, planes, t), pb.count_inliers_reference(pts, planes, t))


@pytest.mark.parametrize("name", ["RANSAC", "LO-RANSAC", "NDT-RANSAC"])
def test_same_seed_same_plane(name):
    pts, _ = _plane_cloud(7, outlier_fraction=0.2)
    a = pb.BASELINES[name](pts, sigma_m=NOISE_M, rng=np.random.default_rng(3), seed=3)
    b = pb.BASELINES[name](pts, sigma_m=NOISE_M, rng=np.random.default_rng(3), seed=3)
    np.testing.assert_array_equal(a.plane, b.plane)


def test_ransac_iterations_adapt_to_inlier_ratio():
    # 0.99 confidence with w = 1 / (1 + 0.2/0.8) = 0.8 needs about log(0.01)/log(1 - 0.512) = 6.4 hypotheses:
    # the search stops after the first batch instead of running to max_iterations.
    pts, _ = _plane_cloud(4, outlier_fraction=0.2)
    fit = pb.ransac_plane(pts, threshold_m=THRESHOLD_M, rng=np.random.default_rng(0), max_iterations=1000, batch=32)
    assert fit.iterations == 32


def test_ndt_ransac_falls_back_without_planar_cells():
    rng = np.random.default_rng(0)
    blob = rng.normal(size=(400, 3))  # isotropic: no cell is planar
    fit = pb.ndt_ransac_plane(blob, threshold_m=0.05, rng=rng, cell_size_m=10.0)
    assert "plain RANSAC" in fit.note


@pytest.mark.parametrize(
    "bad, match",
    [(np.zeros((5, 2)), r"points: expected shape \(N, 3\)"), (np.zeros((2, 3)), "at least 3 points"),
     (np.full((5, 3), np.nan), "finite")],
)
def test_bad_points_raise(bad, match):
    with pytest.raises(ValueError, match=match):
        pb.pca_plane(bad)


def test_bad_threshold_and_rng_raise():
    pts, _ = _plane_cloud(0, n_inliers=50)
    with pytest.raises(ValueError, match="threshold_m"):
        pb.ransac_plane(pts, threshold_m=-1.0, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="rng"):
        pb.ransac_plane(pts, threshold_m=0.01, rng=0)


# ---- the accuracy benchmark's own machinery: synthetic planes and the pixel matching rule --------------------------

import extraction_accuracy as ea  # noqa: E402


def test_protocol1_plane_follows_its_stated_law():
    setup = ea.Protocol1Setup(n_points=4000)
    law = ea.NOISE_LAWS["kinect"]
    sp = ea.make_synthetic_plane(setup, law, np.random.default_rng(0))
    assert sp.points.shape == (4000, 3)
    assert int(sp.is_outlier.sum()) == 200  # exactly 5 %
    inl = sp.points[~sp.is_outlier]
    r = inl @ sp.plane[:3] + sp.plane[3]
    u = r / sp.sigmas[~sp.is_outlier]  # residuals in units of the stated sigma: standard normal
    assert abs(u.mean()) < 0.1 and abs(u.std() - 1.0) < 0.05
    assert setup.depth_min_m - 0.5 < inl[:, 2].min() and inl[:, 2].max() < setup.depth_max_m + 0.5
    assert sp.plane[3] > 0 and abs(np.linalg.norm(sp.plane[:3]) - 1) < 1e-12


def test_match_planes_counts_by_majority_of_pixels():
    det = np.array([[0, 0, 1, 1, 3],
                    [0, 0, 1, 1, 3],
                    [2, 2, -1, -1, 3]])
    gt = np.array([[5, 5, 5, 7, 0],
                   [5, 5, 7, 7, 0],
                   [0, 0, 7, 7, 9]])
    m = ea.match_planes(det, 4, gt, min_gt_pixels=3)
    np.testing.assert_array_equal(m["owner"], [5, 7, 0, 9])
    np.testing.assert_allclose(m["purity"], [1.0, 0.75, 0.0, 1 / 3])
    np.testing.assert_array_equal(m["tp"], [True, True, False, False])  # 2: unlabelled only, 3: 1/3 < 0.5
    np.testing.assert_array_equal(m["under"], [False, True, False, False])  # 1 holds a quarter of plane 5
    np.testing.assert_array_equal(m["gt_ids"], [5, 7, 9])
    np.testing.assert_array_equal(m["detectable"], [True, True, False])
    np.testing.assert_array_equal(m["fragments"], [1, 1, 0])
    np.testing.assert_allclose(m["coverage"], [4 / 5, 3 / 5, 0.0])


def test_match_planes_sees_over_segmentation():
    det = np.array([[0, 0, 1, 1]])
    gt = np.array([[4, 4, 4, 4]])
    m = ea.match_planes(det, 2, gt, min_gt_pixels=1)
    np.testing.assert_array_equal(m["fragments"], [2])
    np.testing.assert_allclose(m["coverage"], [1.0])


def test_protocol1_ray_noise_moves_points_along_their_rays():
    setup = ea.Protocol1Setup(n_points=4000)
    sp = ea.make_synthetic_plane(setup, ea.NOISE_LAWS["kinect-ray"], np.random.default_rng(1))
    keep = ~sp.is_outlier
    p, z = sp.points[keep], sp.z_true[keep]
    # The point stays on the ray of its true position: p / p_z == true / z, so the true point is p * z / p_z.
    true = p * (z / p[:, 2])[:, None]
    np.testing.assert_allclose(true @ sp.plane[:3] + sp.plane[3], 0.0, atol=1e-9)
    u = (p[:, 2] - z) / sp.sigmas[keep]
    assert abs(u.mean()) < 0.1 and abs(u.std() - 1.0) < 0.05
    # The oracle on this data lands close to the truth (it is the limit the table quotes).
    angle_deg, offset_m = plane_errors(ea._oracle(sp), sp.plane)
    assert angle_deg < 0.2 and offset_m < 0.01


def test_protocol2_reports_the_purity_of_its_true_positives():
    """A wall detection that also took a row of the floor: purity 60 / 70 (its own pixels over all of its pixels),
    a clean floor detection 1.0; the frame's mean and 5th percentile over the true positives."""
    from types import SimpleNamespace

    H, W = 10, 10
    gt = np.full((H, W), 1)
    gt[6:, :] = 2  # rows 6-9: the floor (id 2); rows 0-5: the wall (id 1)
    det = np.where(gt == 1, 0, 1)
    det[6, :] = 0  # the wall detection took the floor's first row: 60 + 10 pixels, 60 its own
    det[9, :] = -1  # unassigned
    frame = SimpleNamespace(depth_m=np.full((H, W), 2.0), labels=gt, T_world_cam=np.eye(4),
                            intrinsics=SimpleNamespace(fx=10.0, fy=10.0, cx=4.5, cy=4.5))

    class Planes:  # the parts of a PlaneSet that protocol 2 reads
        labels = det
        normals = np.array([[0.0, 0.0, -1.0], [0.0, -1.0, 0.0]])
        offsets = np.array([2.0, 1.0])

        def __len__(self):
            return 2

    def extract(_frame, _params):
        return SimpleNamespace(planes=Planes())

    def in_camera(_scene, _T):
        return np.array([[0.0, 0.0, -1.0], [0.0, -1.0, 0.0]]), np.array([2.0, 1.0])

    stats = ea._protocol2_frames([frame], None, {1: 0, 2: 1}, None, extract, in_camera, 0.01)
    assert stats["precision"] == 1.0
    assert stats["purity_mean"] == pytest.approx((60 / 70 + 1.0) / 2)
    assert stats["purity_p05"] == pytest.approx(60 / 70 + 0.05 * (1.0 - 60 / 70))


def test_set_overrides_reach_ours_in_protocol1_even_where_the_law_also_sets_a_value(monkeypatch):
    """``--set seed=1`` or ``--set noise_coeff=2e-3`` gave "multiple values for keyword argument" (the law's and the
    seed's keywords were passed beside the overrides); an override wins over them now."""
    from reloc.extraction import fit_plane

    sp = ea.make_synthetic_plane(ea.Protocol1Setup(n_points=800), ea.NOISE_LAWS["kinect"], np.random.default_rng(1))
    law = ea.NOISE_LAWS["kinect"]
    for override in ({"seed": 1}, {"noise_coeff": 2e-3}, {}):
        monkeypatch.setattr(ea, "OURS_OVERRIDES", dict(override))
        methods, _ = ea.protocol1_methods(law, seed=0)
        got = methods["ours (defaults)"](sp, np.random.default_rng(0))
        kw = {"noise_model": law.model, "noise_coeff": law.coeff, "noise_direction": law.direction, "seed": 0,
              **override}
        n, d, _ = fit_plane(sp.points, **kw)
        np.testing.assert_allclose(got, np.r_[n, d], atol=1e-12)
