"""The covariance of a relocalized pose (reloc.matching.covariance) against the errors it is meant to describe."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from reloc.evaluation.synthetic import furnished_room, look_at, scene_planes, view_planes
from reloc.matching import MatchingParams, Relocalizer
from reloc.matching.covariance import pose_covariance
from reloc.matching.transform import rotation_from_normal_pairs, translation_from_offsets
from reloc.transforms import (
    exp_se3,
    invert,
    log_se3,
    rotation_from_axis_angle,
    transform_from_rotation_translation,
)

# Chi-square quantiles of 6 degrees of freedom and F(6, 18) ones (scaled by 6): the normalized squared error of a
# 6-dof pose, with a known covariance or with one scaled by the variance factor of 3 x 8 - 6 = 18 residuals.
CHI2_6_999 = 22.46
F_6_18_95_TIMES_6 = 6 * 2.66


def _log_left(T_true, T_est):
    """``delta = (rho, phi)`` with ``T_true = exp(delta) T_est``."""
    return log_se3(T_true @ invert(T_est))


def _room_planes():
    """Eight planes of a room in the map frame: normals (unit), offsets and centroids, all six dof fixed."""
    raw = [((0, 0, 1), (2.0, 2.0, 0.0)), ((1, 0, 0), (0.0, 2.0, 1.2)), ((0, 1, 0), (2.5, 0.0, 1.2)),
           ((-1, 0, 0), (5.0, 2.0, 1.2)), ((0, -1, 0), (2.5, 4.0, 1.2)), ((0, 0, -1), (2.0, 2.0, 2.6)),
           ((0.6, 0.8, 0), (3.6, 1.0, 0.5)), ((0, 0.6, 0.8), (1.0, 3.0, 0.4))]
    n = np.array([np.asarray(a, float) / np.linalg.norm(a) for a, _ in raw])
    c = np.array([c for _, c in raw], dtype=float)
    return n, -np.sum(n * c, axis=1), c


def _tangent(n):
    a = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 1.0, 0])
    t1 = a - (a @ n) * n
    t1 /= np.linalg.norm(t1)
    return np.stack([t1, np.cross(n, t1)], axis=1)


def _plane_cov(n, c, sigma_n, sigma_d, stretch=1.0):
    """Covariance (4, 4) of ``(n, d)`` for a plane whose normal tilts by ``sigma_n`` (rad) toward the first
    direction of :func:`_tangent` and ``stretch`` times that toward the second, and which moves by ``sigma_d`` along
    its normal at its centroid ``c``."""
    B = _tangent(n)
    J = np.zeros((4, 3))
    J[:3, :2] = B
    J[3, :2] = -c @ B
    J[3, 2] = -1.0
    return J @ np.diag([sigma_n**2, (stretch * sigma_n)**2, sigma_d**2]) @ J.T


def _noisy_submap(rng, T_map_sub, n_map, c_map, sigma_n, sigma_d, stretch=1.0):
    """The map planes seen from ``T_map_sub`` (submap frame), each perturbed as :func:`_plane_cov` describes."""
    T_sub_map = invert(T_map_sub)
    R, t = T_sub_map[:3, :3], T_sub_map[:3, 3]
    ns, ds, cs, covs = [], [], [], []
    for n, c in zip(n_map, c_map):
        n_s, c_s = R @ n, R @ c + t
        B = _tangent(n_s)
        e = rng.normal(0, sigma_n, 2) * [1.0, stretch]
        n_noisy = n_s + B @ e
        n_noisy /= np.linalg.norm(n_noisy)
        c_noisy = c_s + rng.normal(0, sigma_d) * n_s
        ns.append(n_noisy)
        ds.append(-n_noisy @ c_noisy)
        cs.append(c_noisy)
        covs.append(_plane_cov(n_noisy, c_noisy, sigma_n, sigma_d, stretch))
    return np.array(ns), np.array(ds), np.array(cs), np.array(covs)


def _least_squares_pose(ns, cs, n_map, d_map, covs=None):
    """The refinement's estimator: rotation from the normals, translation from the offsets at the centroids. With
    ``covs``, then three Gauss-Newton steps weighted by the planes' covariances, on residuals of its own (each
    normal across its map normal, each centroid's distance to its map plane) and numerical derivatives."""
    w = np.ones(len(ns))
    R, _ = rotation_from_normal_pairs(ns, n_map, w)
    d_sub = -np.sum(n_map * (cs @ R.T), axis=1)
    t, _ = translation_from_offsets(n_map, d_sub, d_map, w)
    T = transform_from_rotation_translation(R, t)
    if covs is None:
        return T
    Bs = [_tangent(n) for n in n_map]
    h = np.concatenate([cs, np.ones((len(cs), 1))], axis=1)
    W = []
    for k in range(len(ns)):
        N = np.zeros((3, 3))
        N[:2, :2] = Bs[k].T @ R @ covs[k][:3, :3] @ R.T @ Bs[k]
        N[2, 2] = h[k] @ covs[k] @ h[k]
        W.append(np.linalg.inv(N))

    def residuals(T_):
        n, c = ns @ T_[:3, :3].T, cs @ T_[:3, :3].T + T_[:3, 3]
        return [np.append(Bs[k].T @ (n_map[k] - n[k]), n_map[k] @ c[k] + d_map[k]) for k in range(len(ns))]

    for _ in range(3):
        r0 = residuals(T)
        J = np.zeros((len(ns), 3, 6))
        for i in range(6):
            e = np.zeros(6)
            e[i] = 1e-6
            rp, rm = residuals(exp_se3(e) @ T), residuals(exp_se3(-e) @ T)
            for k in range(len(ns)):
                J[k, :, i] = (rp[k] - rm[k]) / 2e-6
        H = sum(J[k].T @ W[k] @ J[k] for k in range(len(ns)))
        g = sum(J[k].T @ W[k] @ r0[k] for k in range(len(ns)))
        T = exp_se3(-np.linalg.solve(H, g)) @ T
    return T


@pytest.mark.parametrize("sigma_n_deg, sigma_d_m, carried, stretch, weighted", [
    (0.2, 0.002, 1.0, 1.0, False), (1.0, 0.01, 0.3, 1.0, True), (0.2, 0.02, 1.0, 4.0, True)])
def test_pose_errors_follow_the_covariance_over_many_noisy_submaps(sigma_n_deg, sigma_d_m, carried, stretch,
                                                                   weighted):
    # Monte Carlo: 400 submaps of one room, their planes perturbed with known noise; the pose from the refinement's
    # least squares, or with ``weighted`` that refined by the planes' covariances (the estimate the covariance
    # describes: at 1 deg and 1 cm the refinement's own is up to 2x worse in variance). The planes carry covariances
    # of ``carried`` times the noise's sigma (0.3: too small, as plane fits' are; the residuals' variance factor
    # makes up for it); ``stretch``: each normal 4x less certain in one direction across it than in the other, as a
    # long narrow plane's. With no inflation, delta^T cov^-1 delta is then 6 F(6, 18), mean 6.75 and 95 % below
    # 15.96, where the variance factor is not held at its floor of 1; held there about half the time (the planes'
    # covariances right), the mean is about 5.5. Tolerances: the mean within 5.0-8.0, 90-99.5 % below 15.96.
    rng = np.random.default_rng(11)
    n_map, d_map, c_map = _room_planes()
    sn = math.radians(sigma_n_deg)
    zero = np.zeros((len(n_map), 4, 4))
    nees, sq_errors, variances = [], [], []
    for _ in range(400):
        axis = rng.normal(size=3)
        T_true = transform_from_rotation_translation(rotation_from_axis_angle(axis / np.linalg.norm(axis) * 0.7),
                                                     rng.uniform(1, 3, size=3))
        ns, ds, cs, covs = _noisy_submap(rng, T_true, n_map, c_map, sn, sigma_d_m, stretch)
        T_est = _least_squares_pose(ns, cs, n_map, d_map, covs if weighted else None)
        cov, s0sq = pose_covariance(T_est, ns, cs, covs * carried**2, n_map, d_map, zero, inflation=1.0)
        assert cov is not None and s0sq >= 1.0
        assert np.allclose(cov, cov.T) and np.linalg.eigvalsh(cov)[0] > 0
        delta = _log_left(T_true, T_est)
        nees.append(delta @ np.linalg.solve(cov, delta))
        sq_errors.append(delta[:3] @ delta[:3])
        variances.append(np.trace(cov[:3, :3]))
    nees = np.array(nees)
    assert 5.0 < nees.mean() < 8.0, nees.mean()
    assert 0.90 <= np.mean(nees < F_6_18_95_TIMES_6) <= 0.995
    # The translation's predicted spread is the errors' own: root mean squares within 20 % of each other.
    ratio = math.sqrt(np.mean(sq_errors) / np.mean(variances))
    assert 0.8 < ratio < 1.2, ratio


def test_a_corridor_view_is_least_certain_along_the_corridor():
    # Floor, ceiling and two long walls (normals z and y) fix all but x; a door jamb (normal x) holds it. The largest
    # translation variance lies along x (within 10 deg), and is more than 10x that along y.
    rng = np.random.default_rng(3)
    n_map = np.array([[0, 0, 1.0], [0, 0, -1.0], [0, 1.0, 0], [0, -1.0, 0], [1.0, 0, 0], [0, 1.0, 0]])
    c_map = np.array([[3.0, 1.0, 0], [3.0, 1.0, 2.5], [3.0, 0, 1.2], [3.0, 2.0, 1.2], [5.0, 0.15, 1.0],
                      [1.0, 0.0, 0.4]])
    d_map = -np.sum(n_map * c_map, axis=1)
    T_true = look_at((1.0, 1.0, 1.2), (6.0, 1.0, 1.0))
    ns, ds, cs, covs = _noisy_submap(rng, T_true, n_map, c_map, math.radians(0.3), 0.003)
    # The jamb is a narrow strip: its normal and offset are ten times less certain than the walls'.
    ns[4:5], ds[4:5], cs[4:5], covs[4:5] = _noisy_submap(rng, T_true, n_map[4:5], c_map[4:5], math.radians(3.0), 0.03)
    T_est = _least_squares_pose(ns, cs, n_map, d_map)
    cov, _ = pose_covariance(T_est, ns, cs, covs, n_map, d_map, np.zeros((6, 4, 4)))
    w, V = np.linalg.eigh(cov[:3, :3])
    assert abs(V[0, 2]) > math.cos(math.radians(10))
    assert cov[0, 0] > 10 * cov[1, 1]


def test_one_biased_plane_does_not_blow_up_every_direction():
    # The corridor again (two jambs), its floor a large fit with a tiny covariance, then 3 cm off its map plane, as a
    # map plane fused across a step is. Its residual is then hundreds of times the others': weighed as 4 times the
    # median pair's, it leaves the spread along the corridor within 1.5x of the unbiased one (weighed in full, 2.5x:
    # 5.4 -> 13.6 mm; with it, 5.1 -> 5.0 mm). The pose from least squares weighted by the covariances.
    n_map = np.array([[0, 0, 1.0], [0, 0, -1.0], [0, 1.0, 0], [0, -1.0, 0], [1.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]])
    c_map = np.array([[3.0, 1.0, 0], [3.0, 1.0, 2.5], [3.0, 0, 1.2], [3.0, 2.0, 1.2], [5.0, 0.15, 1.0],
                      [5.0, 1.85, 1.0], [1.0, 0.0, 0.4]])
    d_map = -np.sum(n_map * c_map, axis=1)
    T_true = look_at((1.0, 1.0, 1.2), (6.0, 1.0, 1.0))
    sigma_x, sigma_x_full = [], []
    for bias in (0.0, 0.03):
        rng = np.random.default_rng(3)
        ns, ds, cs, covs = _noisy_submap(rng, T_true, n_map, c_map, math.radians(0.3), 0.003)
        # The floor: a fit to 0.01 deg and 0.1 mm, its centroid moved along its normal by the bias.
        ns[:1], ds[:1], cs[:1], covs[:1] = _noisy_submap(rng, T_true, n_map[:1], c_map[:1], math.radians(0.01), 1e-4)
        cs[0] += bias * ns[0]
        T_est = _least_squares_pose(ns, cs, n_map, d_map, covs)
        cov, _ = pose_covariance(T_est, ns, cs, covs, n_map, d_map, np.zeros((len(ns), 4, 4)))
        sigma_x.append(math.sqrt(cov[0, 0]))
        full, _ = pose_covariance(T_est, ns, cs, covs, n_map, d_map, np.zeros((len(ns), 4, 4)),
                                  outlier_factor=math.inf)
        sigma_x_full.append(math.sqrt(full[0, 0]))
    assert sigma_x[1] < 1.5 * sigma_x[0], sigma_x
    assert sigma_x_full[1] > 2 * sigma_x_full[0], sigma_x_full


def test_pairs_that_do_not_fix_the_pose_give_no_covariance():
    n = np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 0, -1.0], [0, 0, 1.0]])
    c = np.array([[0, 0, 0.0], [1, 0, 0.0], [0, 0, 2.5], [2, 1, 0.0]])
    d = -np.sum(n * c, axis=1)
    covs = np.array([_plane_cov(ni, ci, 0.01, 0.01) for ni, ci in zip(n, c)])
    cov, _ = pose_covariance(np.eye(4), n, c, covs, n, d, covs)
    assert cov is None  # parallel planes leave x, y and yaw free
    cov, _ = pose_covariance(np.eye(4), n[:2], c[:2], covs[:2], n[:2], d[:2], covs[:2])
    assert cov is None  # two pairs
    with pytest.raises(ValueError, match="inflation"):
        pose_covariance(np.eye(4), n, c, covs, n, d, covs, inflation=0.0)
    with pytest.raises(ValueError, match="outlier_factor"):
        pose_covariance(np.eye(4), n, c, covs, n, d, covs, outlier_factor=0.5)
    with pytest.raises(ValueError, match="MatchingParams: covariance_inflation"):
        MatchingParams(covariance_inflation=0.0)


def test_a_relocalized_result_carries_its_covariance_and_a_rejected_one_none():
    rects = furnished_room("living")
    reloc = Relocalizer(scene_planes(rects), MatchingParams())
    rng = np.random.default_rng(5)
    T = look_at((5, 4, 1.5), (1, 1, 0.5))
    res = reloc.locate(view_planes(rects, T, point_noise_m=0.005, normal_noise_deg=0.3, offset_noise_m=0.005,
                                   rng=rng))
    assert res.relocalized, res.reason
    cov = res.covariance
    assert cov.shape == (6, 6) and np.allclose(cov, cov.T) and np.linalg.eigvalsh(cov)[0] > 0
    delta = _log_left(T, res.T_map_cam)
    assert delta @ np.linalg.solve(cov, delta) < CHI2_6_999
    back = json.loads(json.dumps(res.to_dict()))
    assert np.allclose(back["covariance"], cov, rtol=1e-5, atol=0)
    other = reloc.locate(view_planes(furnished_room("office"), look_at((1, 1, 1.5), (5, 4, 0.5))))
    assert not other.relocalized and other.covariance is None and other.to_dict()["covariance"] is None


def test_an_answer_is_judged_by_its_own_covariance():
    from reloc.evaluation.metrics import covariance_check

    rng = np.random.default_rng(2)
    T_true = look_at((1.0, 2.0, 1.5), (4.0, 3.0, 0.5))
    delta = np.array([0.01, -0.02, 0.005, 0.001, -0.002, 0.003])
    T_est = invert(exp_se3(delta)) @ T_true  # T_true = exp(delta) T_est
    sig = np.array([0.01, 0.02, 0.01, 0.002, 0.002, 0.003])
    nees, sigma_t = covariance_check(T_est, T_true, np.diag(sig**2))
    assert nees == pytest.approx(np.sum((delta / sig) ** 2), rel=1e-9)
    assert sigma_t == pytest.approx(math.sqrt(np.sum(sig[:3] ** 2)))
    assert all(math.isnan(v) for v in covariance_check(T_est, T_true, None))
    # Any rotation of the map frame with its covariance gives the same normalized error.
    R = rotation_from_axis_angle(rng.normal(size=3))
    G = transform_from_rotation_translation(R, rng.normal(size=3))
    Ad = np.zeros((6, 6))
    Ad[:3, :3] = R
    Ad[3:, 3:] = R
    Ad[:3, 3:] = np.array([[0, -G[2, 3], G[1, 3]], [G[2, 3], 0, -G[0, 3]], [-G[1, 3], G[0, 3], 0]]) @ R
    moved, _ = covariance_check(G @ T_est, G @ T_true, Ad @ np.diag(sig**2) @ Ad.T)
    assert moved == pytest.approx(nees, rel=1e-6)
