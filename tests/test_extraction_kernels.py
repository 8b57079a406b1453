"""Extraction kernels against slow, obviously-correct NumPy references (small inputs)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from reloc.camera import Intrinsics
from reloc.extraction import _kernels_merge as km
from reloc.extraction import _kernels_voxel as kv
from reloc.extraction.assemble import assemble_plane_set
from reloc.extraction.backproject import depth_to_points
from reloc.extraction.merge import merge_voxel_planes
from reloc.extraction.voxel_planes import PLANAR, fit_voxel_planes, refine_voxel_planes
from reloc.extraction.voxelize import frustum_box, voxelize, voxelize_keyed

K_SMALL = Intrinsics(fx=40.0, fy=-42.0, cx=15.5, cy=11.5, width=32, height=24)  # negative fy, as ICL-NUIM


def _bad_depth(rng):
    depth = rng.uniform(0.5, 6.0, size=(24, 32)).astype(np.float32)
    depth[0, :5] = [np.nan, np.inf, -1.0, 0.0, -np.inf]
    depth[5, 5] = 9.0  # beyond range
    depth[6, 6] = 0.1  # nearer than the minimum
    return depth


@pytest.mark.parametrize("stride", [1, 2, 3])
def test_backproject_matches_numpy_and_drops_invalid(stride):
    rng = np.random.default_rng(stride)
    depth = _bad_depth(rng)
    pts, pix = depth_to_points(depth, K_SMALL, min_depth_m=0.3, max_depth_m=8.0, pixel_stride=stride)
    v, u = np.mgrid[0:24:stride, 0:32:stride]
    z = depth[v, u].astype(np.float64)
    ok = np.isfinite(z) & (z > 0) & (z >= 0.3) & (z <= 8.0)
    ref = np.stack([(u - K_SMALL.cx) / K_SMALL.fx * z, (v - K_SMALL.cy) / K_SMALL.fy * z, z], -1)[ok]
    assert np.array_equal(pix, (v * 32 + u)[ok])
    assert np.allclose(pts, ref, rtol=1e-6, atol=1e-6)
    assert np.all(np.isfinite(pts)) and np.all(pts[:, 2] >= 0.3)
    # Keyed into the frustum box, every point lands inside it.
    box = frustum_box(K_SMALL, min_depth_m=0.3, max_depth_m=8.0, voxel_size_m=0.25)
    key = np.empty(len(pts), np.int64)
    cellcount = np.empty(int(np.prod(box[3:])), np.int32)
    kv.count_keys(pts, len(pts), 4.0, box, key, cellcount)
    ijk = np.floor(pts.astype(np.float64) / 0.25).astype(np.int64) - box[:3]
    assert np.all(ijk >= 0) and np.all(ijk < box[3:])
    assert np.array_equal(key, (ijk[:, 0] * box[4] + ijk[:, 1]) * box[5] + ijk[:, 2])
    assert np.array_equal(cellcount, np.bincount(key, minlength=len(cellcount)))


def _voxel_reference(pts, size):
    """Voxel of each point, the voxels in key order, their members, counts and moments, with NumPy."""
    ijk = np.floor(pts.astype(np.float64) / size).astype(np.int64)
    uniq, inverse = np.unique(ijk, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    p = pts.astype(np.float64)
    counts = np.bincount(inverse)
    sums = np.stack([np.bincount(inverse, weights=p[:, k]) for k in range(3)], 1)
    scat = np.stack([np.stack([np.bincount(inverse, weights=p[:, i] * p[:, j]) for j in range(3)], 1)
                     for i in range(3)], 1)
    return uniq, inverse, counts, sums, scat


@pytest.mark.parametrize("force_hash", [False, True])
def test_voxelize_matches_numpy_grouping(force_hash):
    rng = np.random.default_rng(7)
    pts = np.concatenate([rng.uniform(-2, 2, size=(3000, 3)), rng.normal(0.1, 0.05, size=(500, 3))]).astype(np.float32)
    g = voxelize(pts, voxel_size_m=0.3, force_hash=force_hash)
    uniq, inverse, counts, sums, scat = _voxel_reference(pts, 0.3)
    # Voxel ids follow the key order, which is the lexicographic order of (ix, iy, iz).
    assert np.array_equal(g.coords, uniq)
    assert g.dense is (not force_hash)
    assert np.array_equal(g.counts, counts)
    assert np.allclose(g.sums, sums, rtol=1e-9, atol=1e-9)
    assert np.allclose(g.scatters, scat, rtol=1e-9, atol=1e-9)
    # Every point sits in its voxel's segment, in input order inside the voxel (a stable counting sort).
    for v in range(len(g)):
        src = g.source[g.start[v]:g.start[v + 1]]
        assert np.array_equal(src, np.flatnonzero(inverse == v))
        assert np.array_equal(g.points[g.start[v]:g.start[v + 1]], pts[src])
    # Lookup of occupied and empty cells.
    assert np.array_equal(g.lookup(uniq), np.arange(len(uniq)))
    assert g.lookup(np.array([[1000, 1000, 1000]]))[0] == -1


def test_voxelize_keyed_equals_voxelize():
    rng = np.random.default_rng(3)
    depth = rng.uniform(0.5, 7.0, size=(24, 32)).astype(np.float32)
    box = frustum_box(K_SMALL, min_depth_m=0.3, max_depth_m=8.0, voxel_size_m=0.25)
    pts, _pix = depth_to_points(depth, K_SMALL)
    key = np.empty(len(pts), np.int64)
    cellcount = np.empty(int(np.prod(box[3:])), np.int32)
    kv.count_keys(pts, len(pts), 4.0, box, key, cellcount)
    a = voxelize_keyed(pts, key, cellcount, box, voxel_size_m=0.25)
    b = voxelize(pts, voxel_size_m=0.25)
    assert np.array_equal(a.coords, b.coords) and np.array_equal(a.counts, b.counts)
    assert np.array_equal(a.source[: len(pts)], b.source[: len(pts)])
    assert np.allclose(a.scatters, b.scatters, rtol=1e-9)


def _plane_points(rng, n, normal, d, sigma, extent=0.2, centre=None):
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    a = np.cross(normal, [1.0, 0, 0] if abs(normal[0]) < 0.9 else [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    c0 = -d * normal if centre is None else centre - (normal @ centre + d) * normal
    uv = rng.uniform(-extent, extent, size=(n, 2))
    return c0 + uv[:, :1] * a + uv[:, 1:] * b + rng.normal(0, sigma, size=(n, 1)) * normal


def test_voxel_planes_match_numpy_weighted_fit():
    rng = np.random.default_rng(11)
    # Points of one tilted plane inside a single voxel [2.0, 2.25)^3-ish region around (0.1, 0.1, 2.1).
    n_true = np.array([0.2, -0.1, -1.0])
    n_true /= np.linalg.norm(n_true)
    pts = _plane_points(rng, 400, n_true, -n_true @ np.array([0.12, 0.12, 2.12]), 0.002, extent=0.08,
                        centre=np.array([0.12, 0.12, 2.12])).astype(np.float32)
    g = voxelize(pts, voxel_size_m=0.25)
    assert len(g) == 1
    vp = fit_voxel_planes(g, min_points_per_voxel=12, noise_model="kinect", noise_coeff=1.425e-3)
    assert vp.flags[0] == PLANAR
    p = pts.astype(np.float64)
    c = p.mean(0)
    lam, vec = np.linalg.eigh(np.cov((p - c).T, bias=True))
    assert np.allclose(vp.eigenvalues[0], lam, rtol=1e-6, atol=1e-12)
    n_pca = vec[:, 0] * np.sign(-(vec[:, 0] @ c))  # toward the sensor at the origin
    assert np.allclose(vp.planes[0, :3], n_pca, atol=1e-9)
    # Weighted refit without robust or position weights: weighted TLS with w = z^2 / sigma_z^2 (ray mode).
    refine_voxel_planes(g, vp, noise_direction="ray", noise_weights=True, adaptive_weights=False,
                        irls_iterations=0, voxel_fit_max_points=1000)
    w = p[:, 2] ** 2 / (1.425e-3 * p[:, 2] ** 2) ** 2
    mu = (w[:, None] * p).sum(0) / w.sum()
    C = (w[:, None] * (p - mu)).T @ (p - mu) / w.sum()
    n_ref = np.linalg.eigh(C)[1][:, 0]
    n_ref *= np.sign(-(n_ref @ mu))
    assert np.allclose(vp.planes[0, :3], n_ref, atol=1e-9)
    assert vp.planes[0, 3] == pytest.approx(-n_ref @ mu, abs=1e-9)
    assert vp.wmoments[0, 0] == pytest.approx(w.sum(), rel=1e-9)
    assert np.allclose(vp.wmoments[0, 1:], (w[:, None] * p).sum(0), rtol=1e-9)
    assert np.allclose(vp.wscatters[0], (w[:, None] * p).T @ p, rtol=1e-9)
    assert vp.radius[0] == pytest.approx(np.linalg.norm(p - c, axis=1).max(), rel=1e-6)
    # A voxel of more than voxel_fit_max_points points is refit from the points whose coordinate bits hash into
    # 1 in k (k = 4 for 400 points and at most 100), its moments scaled from them to all points.
    vp = fit_voxel_planes(g, min_points_per_voxel=12, noise_model="kinect", noise_coeff=1.425e-3)
    refine_voxel_planes(g, vp, noise_direction="ray", noise_weights=True, adaptive_weights=False,
                        irls_iterations=0, voxel_fit_max_points=100)
    bits = g.points.view(np.int32)
    picked = ((bits[:, 0] ^ bits[:, 1] ^ bits[:, 2]) >> 1) & 3 == 0
    assert 60 < picked.sum() < 140
    ps = g.points[picked].astype(np.float64)
    ws = ps[:, 2] ** 2 / (1.425e-3 * ps[:, 2] ** 2) ** 2
    f = len(p) / len(ps)
    mu = (ws[:, None] * ps).sum(0) / ws.sum()
    n_ref = np.linalg.eigh((ws[:, None] * (ps - mu)).T @ (ps - mu))[1][:, 0]
    n_ref *= np.sign(-(n_ref @ mu))
    assert np.allclose(vp.planes[0, :3], n_ref, atol=1e-9)
    assert vp.wmoments[0, 0] == pytest.approx(f * ws.sum(), rel=1e-9)
    assert np.allclose(vp.wscatters[0], f * (ws[:, None] * ps).T @ ps, rtol=1e-9)
    assert vp.radius[0] == pytest.approx(np.linalg.norm(ps - c, axis=1).max(), rel=1e-6)


def test_voxel_refit_rejects_outliers_and_a_blob_is_not_planar():
    rng = np.random.default_rng(12)
    centre = np.array([0.12, 0.12, 2.12])
    n_true = np.array([0.0, 0.0, -1.0])
    good = _plane_points(rng, 380, n_true, -n_true @ centre, 0.002, extent=0.1, centre=centre)
    outl = centre + rng.uniform(-0.1, 0.1, size=(20, 3))  # 5 % of the voxel from another surface
    blob = np.array([1.12, 0.12, 2.12]) + rng.uniform(-0.1, 0.1, size=(400, 3))
    pts = np.concatenate([good, outl, blob]).astype(np.float32)
    g = voxelize(pts, voxel_size_m=0.25)
    vp = fit_voxel_planes(g)
    refine_voxel_planes(g, vp, irls_iterations=3)
    v_plane = g.lookup(np.floor(centre / 0.25)[None])[0]
    v_blob = g.lookup(np.floor(np.array([1.12, 0.12, 2.12]) / 0.25)[None])[0]
    assert vp.flags[v_plane] == PLANAR and vp.flags[v_blob] != PLANAR
    assert np.degrees(np.arccos(abs(vp.planes[v_plane, :3] @ n_true))) < 0.5


def _grid_of_plane(rng, n_true, d, sigma, extent, n):
    pts = _plane_points(rng, n, n_true, d, sigma, extent=extent).astype(np.float32)
    g = voxelize(pts, voxel_size_m=0.25)
    vp = fit_voxel_planes(g)
    refine_voxel_planes(g, vp, noise_direction="normal", adaptive_weights=False, irls_iterations=0)
    return pts, g, vp


def test_merging_tiny_case_matches_numpy():
    """A wall across several voxels plus a parallel plane 0.5 m behind: growth makes exactly two planes, each refit
    from the summed moments equal to the weighted fit of all its voxels' points."""
    rng = np.random.default_rng(5)
    n_true = np.array([0.0, 0.0, -1.0])
    a = _plane_points(rng, 3000, n_true, 2.0, 0.002, extent=0.6)
    b = _plane_points(rng, 3000, n_true, 2.5, 0.002, extent=0.6) + np.array([2.0, 0, 0])
    pts = np.concatenate([a, b]).astype(np.float32)
    g = voxelize(pts, voxel_size_m=0.25)
    vp = fit_voxel_planes(g)
    refine_voxel_planes(g, vp, noise_direction="normal", adaptive_weights=False, irls_iterations=0)
    mp = merge_voxel_planes(g, vp, noise_direction="normal")
    assert len(mp) == 2
    for k, part in enumerate((a, b)):
        # Which plane holds this part: the one with the same offset.
        q = int(np.argmin(np.abs(mp.planes[:, 3] - (2.0, 2.5)[k])))
        vox = np.flatnonzero(mp.plane_of_voxel == q)
        assert np.isin(vox, vp.planar).all() and len(vox) > 4
        idx = np.concatenate([g.source[g.start[v]:g.start[v + 1]] for v in vox])
        p = pts[idx].astype(np.float64)
        w = 1.0 / (1.425e-3 * p[:, 2] ** 2) ** 2
        mu = (w[:, None] * p).sum(0) / w.sum()
        n_ref = np.linalg.eigh((w[:, None] * (p - mu)).T @ (p - mu))[1][:, 0]
        n_ref *= np.sign(-(n_ref @ mu))
        assert np.allclose(mp.planes[q, :3], n_ref, atol=1e-9)
        assert mp.planes[q, 3] == pytest.approx(-n_ref @ mu, abs=1e-9)
        assert mp.counts[q] == len(idx)
    # Without merging every planar voxel stays a plane of its own.
    mp0 = merge_voxel_planes(g, vp, merge=False, noise_direction="normal")
    assert len(mp0) == len(vp.planar)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pack_regions_matches_numpy(seed):
    """Merge chains resolved to their survivor, survivors numbered in order, voxels' planes and voxel counts, against
    NumPy (pointer jumping to the fixed point, as the pipeline did before the kernel)."""
    rng = np.random.default_rng(seed)
    nr, nv = 40, 300
    # A forest: each region merges into an earlier one (chains of any length) or survives.
    parent = np.arange(nr, dtype=np.int32)
    for r in range(1, nr):
        if rng.random() < 0.6:
            parent[r] = rng.integers(0, r)
    parent = parent.copy()
    plane_of_region = np.where(rng.random(nv) < 0.2, -1, rng.integers(0, nr, nv)).astype(np.int32)
    root = parent.copy()
    for _ in range(nr):
        root = root[root]
    survivors = np.flatnonzero(root == np.arange(nr))
    final = np.full(nr, -1, np.int32)
    final[survivors] = np.arange(len(survivors))
    ref_pov = np.where(plane_of_region >= 0, final[root[np.maximum(plane_of_region, 0)]], -1)
    ref_nvox = np.bincount(ref_pov[ref_pov >= 0], minlength=len(survivors))
    r2p = np.full(nr, -9, np.int32)
    surv = np.full(nr, -9, np.int64)
    pov = np.full(nv, -9, np.int32)
    nvox = np.full(nr, -9, np.int64)
    ns = km.pack_regions(parent, plane_of_region, r2p, surv, pov, nvox)
    assert ns == len(survivors) and 5 < ns < nr - 5  # chains merged and survivors left
    assert np.array_equal(surv[:ns], survivors) and np.array_equal(r2p, final[root])
    assert np.array_equal(pov, ref_pov) and np.array_equal(nvox[:ns], ref_nvox)



def _random_regions(rng, nr):
    """Region rows as merging leaves them: planes (unit normal, d > 0), weighted moments of a few points about the
    origin, counts, sums, effective counts, radius bounds."""
    rplane = np.zeros((nr, 4))
    rmom = np.zeros((nr, 4))
    rscat = np.zeros((nr, 3, 3))
    for r in range(nr):
        p = rng.normal([0.0, 0.0, 2.0], 0.4, size=(30, 3))
        w = rng.uniform(0.5, 2.0, 30)
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        rplane[r] = [*n, abs(rng.normal(2.0, 0.5))]
        rmom[r] = [w.sum(), *(w @ p)]
        rscat[r] = (p * w[:, None]).T @ p
    rcount = rng.integers(20, 500, nr).astype(np.int64)
    rsum = rng.normal(size=(nr, 3)) * rcount[:, None]
    rneff = rng.integers(0, 500, nr).astype(np.int64)
    rrad = rng.uniform(0.1, 2.0, nr)
    return rplane, rmom, rscat, rcount, rsum, rneff, rrad


@pytest.mark.parametrize("ray_mode", [True, False])
def test_pack_planes_matches_numpy(ray_mode):
    """The surviving regions' rows in plane order with their covariances, against NumPy indexing of the rows and
    the covariance kernel on them (what the pipeline did before the kernel)."""
    from reloc.extraction._kernels_linalg import plane_covariances

    rng = np.random.default_rng(4)
    nr, nv = 30, 200
    parent = np.arange(nr, dtype=np.int32)
    for r in range(1, nr):
        if rng.random() < 0.5:
            parent[r] = rng.integers(0, r)
    plane_of_region = np.where(rng.random(nv) < 0.2, -1, rng.integers(0, nr, nv)).astype(np.int32)
    rows = _random_regions(rng, nr)
    r2p_ref = np.empty(nr, np.int32)
    surv = np.empty(nr, np.int64)
    pov_ref = np.empty(nv, np.int32)
    nvox_ref = np.empty(nr, np.int64)
    ns_ref = km.pack_regions(parent, plane_of_region, r2p_ref, surv, pov_ref, nvox_ref)
    surv = surv[:ns_ref]
    ref = [x[surv] for x in rows]
    covs_ref = np.zeros((ns_ref, 4, 4))
    s0_ref = np.zeros(ns_ref)
    plane_covariances(ref[0], ref[1], ref[2], ref[5], ray_mode, covs_ref, s0_ref)
    out = [np.full((nr, 4), np.nan), np.full((nr, 4), np.nan), np.full((nr, 3, 3), np.nan), np.full(nr, -9),
           np.full((nr, 3), np.nan), np.full(nr, -9), np.full(nr, np.nan)]
    covs = np.full((nr, 4, 4), np.nan)
    s0 = np.full(nr, np.nan)
    r2p = np.full(nr, -9, np.int32)
    pov = np.full(nv, -9, np.int32)
    nvox = np.full(nr, -9, np.int64)
    ns = km.pack_planes(parent, plane_of_region, *rows, ray_mode, r2p, np.empty(nr, np.int64), pov, nvox,
                        *out, covs, s0)
    assert ns == ns_ref and 5 < ns < nr - 5
    assert np.array_equal(r2p, r2p_ref) and np.array_equal(pov, pov_ref) and np.array_equal(nvox[:ns], nvox_ref[:ns])
    for got, want in zip(out, ref):
        assert np.array_equal(got[:ns], want)
    assert np.array_equal(covs[:ns], covs_ref) and np.array_equal(s0[:ns], s0_ref)


@pytest.mark.parametrize("ray_mode", [True, False])
def test_refine_keep_matches_numpy(ray_mode):
    """The refinement's refit, bevels dropped and statistics taken, against NumPy (solve_planes on copies, then
    boolean indexing and np.where, as the pipeline did before the kernel)."""
    from reloc.extraction import _kernels_finalize as kfin

    rng = np.random.default_rng(5)
    n, nv = 25, 120
    planes, wmom, wscat, counts, sums, n_eff, rad = _random_regions(rng, n)
    acc_w = np.where(rng.random(n) < 0.2, 0.0, rng.uniform(1.0, 5.0, n))
    acc_s = rng.normal(0.0, 0.05, size=(n, 3)) * acc_w[:, None]
    acc_S = np.zeros((n, 3, 3))
    for p in range(n):
        q = rng.normal(0.0, [0.5, 0.5, 0.01], size=(20, 3))
        acc_S[p] = q.T @ q * acc_w[p] / 20
    refs = rng.normal([0.0, 0.0, 2.0], 0.5, size=(n, 3))
    acc_n = rng.integers(0, 10, n).astype(np.int64)
    acc_amb = np.where(rng.random(n) < 0.25, acc_n + 1, 0).astype(np.int64)
    acc_sum = rng.normal(size=(n, 3))
    pov = np.where(rng.random(nv) < 0.2, -1, rng.integers(0, n, nv)).astype(np.int32)
    # NumPy reference.
    planes_ref, wmom_ref, wscat_ref = planes.copy(), wmom.copy(), wscat.copy()
    kfin.solve_planes(acc_w, acc_s, acc_S, refs, ray_mode, planes_ref, wmom_ref, wscat_ref)
    keep = ~(acc_amb > acc_n)
    kept = acc_n > 3
    remap = np.full(n, -1, np.int32)
    remap[keep] = np.arange(int(keep.sum()))
    ref = (planes_ref[keep], wmom_ref[keep], wscat_ref[keep], np.where(kept, acc_n, counts)[keep],
           np.where(kept[:, None], acc_sum, sums)[keep], np.where(kept, acc_n, n_eff)[keep], rad[keep])
    pov_ref = np.where(pov >= 0, remap[np.maximum(pov, 0)], -1)
    # Kernel.
    wmom_in, wscat_in = wmom.copy(), wscat.copy()
    old_to_kept = np.full(n, -9, np.int32)
    out = [np.full((n, 4), np.nan), np.full((n, 4), np.nan), np.full((n, 3, 3), np.nan), np.full(n, -9),
           np.full((n, 3), np.nan), np.full(n, -9), np.full(n, np.nan)]
    k_pov = np.full(nv, -9, np.int32)
    planes_in = planes.copy()
    nk = kfin.refine_keep(acc_w, acc_s, acc_S, refs, ray_mode, planes_in, wmom_in, wscat_in, acc_n, acc_amb, acc_sum,
                          counts, sums, n_eff, rad, pov, old_to_kept, out[0], out[1], out[2], out[3], out[4], out[5],
                          out[6], k_pov)
    assert nk == int(keep.sum()) and 3 < nk < n
    assert np.array_equal(old_to_kept, remap) and np.array_equal(k_pov, pov_ref)
    assert np.array_equal(planes_in, planes_ref)  # refit in place
    assert np.array_equal(wmom_in, wmom) and np.array_equal(wscat_in, wscat)  # inputs untouched
    for got, want in zip(out, ref):
        assert np.array_equal(got[:nk], want)
    table = np.full(n, -9, np.int32)
    kept_to_final = rng.integers(-1, 5, nk).astype(np.int32)
    kfin.compose_table(old_to_kept, kept_to_final, table)
    assert np.array_equal(table, np.where(remap >= 0, kept_to_final[np.maximum(remap, 0)], -1))


def test_plane_minor_widths_match_numpy_and_strip_widths():
    """Width across the shorter in-plane axis, from the voxels' moments, against NumPy on the points themselves
    (eigenvalues of the in-plane covariance); uniform strips of known width come out at that width."""
    from reloc.extraction import _kernels_finalize as kfin

    rng = np.random.default_rng(11)
    # Planes 0-2 of random orientation, each a uniform strip (width w, length 3 m) with 1 mm noise along the normal,
    # cut into voxels of 40 points; plane 3 owns no voxel.
    widths_true = np.array([0.25, 0.9, 2.0, 1.0])
    planes = np.zeros((4, 4))
    pts_of, pov, counts, sums, scatters = [], [], [], [], []
    for p, w in enumerate(widths_true):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        t1 = np.cross(n, [0.3, 0.5, 0.8])
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        c = rng.normal([0.0, 0.0, 3.0], 0.5)
        planes[p] = [*n, -n @ c]
        if p == 3:
            continue
        q = (c + rng.uniform(-w / 2, w / 2, (800, 1)) * t1 + rng.uniform(-1.5, 1.5, (800, 1)) * t2
             + rng.normal(0.0, 1e-3, (800, 1)) * n)
        pts_of.append(q)
        for v in range(20):
            block = q[40 * v: 40 * (v + 1)]
            pov.append(p)
            counts.append(len(block))
            sums.append(block.sum(axis=0))
            scatters.append(block.T @ block)
    # A voxel of no plane, which must not count.
    junk = rng.normal(size=(40, 3))
    pov.append(-1)
    counts.append(40)
    sums.append(junk.sum(axis=0))
    scatters.append(junk.T @ junk)
    got = np.full(4, np.nan)
    kfin.plane_minor_widths(planes, np.array(pov, np.int32), np.array(counts, np.int64), np.array(sums),
                            np.array(scatters), got)
    for p, q in enumerate(pts_of):
        n = planes[p, :3]
        basis = np.linalg.svd(np.eye(3) - np.outer(n, n))[0][:, :2]  # any orthonormal basis of the plane
        lam = np.linalg.eigvalsh(basis.T @ np.cov(q.T, bias=True) @ basis)[0]
        assert got[p] == pytest.approx(np.sqrt(12.0 * lam), rel=1e-9)
        # a uniform strip of width w: variance w^2 / 12 across it (800 points: within a few per cent)
        assert got[p] == pytest.approx(widths_true[p], rel=0.06)
    assert got[3] == 0.0


def test_fragment_merge_kernel_on_two_coplanar_regions():
    """Two coplanar fragments side by side merge; a parallel one 0.3 m behind does not."""
    rng = np.random.default_rng(9)
    regions = []
    for shift, d in (((0.0, 0, 0), 2.0), ((1.0, 0, 0), 2.0), ((0.0, 1.0, 0), 2.3)):
        p = _plane_points(rng, 500, [0, 0, -1.0], d, 0.002, extent=0.4) + np.array(shift)
        regions.append(p)
    nr = 3
    rmom = np.array([[len(p), *p.sum(0)] for p in regions])
    rscat = np.array([p.T @ p for p in regions])
    rcount = np.array([len(p) for p in regions], np.int64)
    rsum = np.array([p.sum(0) for p in regions])
    rneff = rcount.copy()
    rrad = np.array([np.linalg.norm(p - p.mean(0), axis=1).max() for p in regions])
    rplane = np.zeros((3, 4))
    for r, p in enumerate(regions):
        c = p.mean(0)
        n = np.linalg.eigh(np.cov(p.T))[1][:, 0]
        n *= np.sign(-(n @ c))
        rplane[r] = [*n, -n @ c]
    parent = np.empty(nr, np.int32)
    merges = km.merge_fragments(nr, rplane, rmom, rscat, rcount, rsum, rneff, rrad, False, 2, 1.425e-3,
                                np.radians(8.0), 2.0, np.radians(5.0), 0.05, 2.0, 4.0, 0.01, 2.0, parent, 8)
    assert merges == 1
    assert parent[1] == 0 or parent[0] == 1
    assert parent[2] == 2
    both = np.concatenate(regions[:2])
    root = 0 if parent[1] == 0 else 1
    assert rcount[root] == len(both)
    c = both.mean(0)
    n_ref = np.linalg.eigh(np.cov(both.T))[1][:, 0]
    n_ref *= np.sign(-(n_ref @ c))
    assert np.allclose(rplane[root, :3], n_ref, atol=1e-9)


@pytest.mark.parametrize("sample_m", [0.2, 0.1])
def test_assemble_statistics_match_numpy(sample_m):
    """Supporting points, statistics, radius, area and samples of a merged plane, against NumPy (sample cells
    other than the area cells, and the same: then the area comes from the sample cells)."""
    rng = np.random.default_rng(21)
    n_true = np.array([0.0, 0.0, -1.0])
    pts = _plane_points(rng, 4000, n_true, 2.0, 0.001, extent=0.5).astype(np.float32)
    g = voxelize(pts, voxel_size_m=0.25)
    vp = fit_voxel_planes(g)
    refine_voxel_planes(g, vp)
    mp = merge_voxel_planes(g, vp)
    ps = assemble_plane_set(g, mp, min_plane_points=10, min_plane_area_m2=0.0, area_patch_m=0.1,
                            sample_spacing_m=sample_m)
    assert len(ps) == 1
    p = pts.astype(np.float64)
    assert ps.counts[0] == len(p)  # all points are within 4 sigma of the plane
    assert np.allclose(ps.sums[0], p.sum(0), rtol=1e-9)
    assert np.allclose(ps.scatters[0], p.T @ p, rtol=1e-9)
    assert np.allclose(ps.centroids[0], p.mean(0), atol=1e-9)
    assert ps.radii[0] == pytest.approx(np.linalg.norm(p - p.mean(0), axis=1).max(), rel=1e-6)
    # Area: occupied 0.1 m cells of the in-plane coordinates (tangent basis of the normal, cells anchored at 0).
    from reloc.extraction._kernels_linalg import tangent_basis

    t = np.array(tangent_basis(*ps.normals[0])).reshape(2, 3)
    cells = np.unique(np.floor(p @ t.T / 0.1).astype(np.int64), axis=0)
    assert ps.areas[0] == pytest.approx(len(cells) * 0.01, rel=1e-9)
    scells, inv = np.unique(np.floor(p @ t.T / sample_m).astype(np.int64), axis=0, return_inverse=True)
    means = np.stack([np.bincount(inv.reshape(-1), weights=p[:, k]) for k in range(3)], 1)
    means /= np.bincount(inv.reshape(-1))[:, None]
    got = ps.samples_of(0).astype(np.float64)
    assert len(got) == len(scells)
    assert np.allclose(np.sort(got, axis=0), np.sort(means, axis=0), atol=1e-5)
    assert ps.labels is None


def test_plane_extent_of_a_depth_image_matches_its_general_loop(monkeypatch):
    """``plane_extent`` has a loop of its own for a depth image's points with the default cells (labels, pixel
    sources, every pixel); given the same points as a cloud with a pixel table (the general loop), it makes the
    same radii, areas, samples and label image, bit for bit."""
    import sim
    from reloc.extraction import PlaneExtractor
    from reloc.extraction import _kernels_finalize as kf

    frame = sim.simulate_frames(scene="office", trajectory="robot", n_frames=2, noise="kinect", camera="kinect",
                                width=160, height=120, seed=4)[1]
    calls = []
    real = kf.plane_extent

    def capture(*args):
        calls.append([a.copy() if isinstance(a, np.ndarray) else a for a in args])
        return real(*args)

    monkeypatch.setattr(kf, "plane_extent", capture)
    PlaneExtractor().extract(frame)
    (args,) = calls
    with_labels, src_is_pixel, stride = args[16], args[18], args[23]
    assert with_labels and src_is_pixel and stride == 1 and args[6] == args[10]  # the image loop's case
    outs = []
    for general in (False, True):
        a = [x.copy() if isinstance(x, np.ndarray) else x for x in args]
        if general:  # the same pixels through a table: sources are indices into it
            a[18] = False
            a[19] = np.arange(frame.depth_m.size, dtype=np.int32)
        real(*a)
        outs.append(a)
    for i, name in ((13, "samples"), (14, "radii"), (15, "areas"), (24, "labels")):
        assert np.array_equal(outs[0][i], outs[1][i]), name
    assert (outs[0][24] >= 0).sum() > 0.5 * frame.depth_m.size and outs[0][15].max() > 1.0


def test_plane_set_renumbers_the_refinement_assignment_like_numpy():
    """The refinement's last pass leaves its point assignment in its own numbering with a table to the merged
    planes (fragments merged, bevels dropped); the plane set applies the table point by point. Same plane set and
    label image as from the assignment renumbered by NumPy first (identity table), for a table that merges and
    drops planes."""
    from dataclasses import replace

    from reloc.extraction.merge import refine_merged_planes

    rng = np.random.default_rng(8)
    walls = [(np.array([0.3, 0.0, -1.0]), 2.5, [0.0, 0.0, 2.4]), (np.array([-1.0, 0.1, -0.2]), 1.2, [-1.0, 0.0, 2.4]),
             (np.array([0.3, 0.0, -1.0]), 2.5, [0.9, 0.0, 2.7])]  # the third: more of the first wall
    pts = np.concatenate([_plane_points(rng, 3000, n, d, 0.003, extent=0.5, centre=np.array(c)) for n, d, c in walls]
                         + [rng.uniform([-1.5, -0.7, 1.5], [1.5, 0.7, 3.2], size=(200, 3))]).astype(np.float32)
    g = voxelize(pts, voxel_size_m=0.2)
    vp = fit_voxel_planes(g)
    refine_voxel_planes(g, vp)
    mp = refine_merged_planes(g, merge_voxel_planes(g, vp), point_step=1)
    assert mp.point_table is not None and len(mp) >= 2
    m = len(pts)
    renumbered = np.where(mp.point_plane >= 0, mp.point_table[np.maximum(mp.point_plane, 0)], -1).astype(np.int32)
    numpy_first = replace(mp, point_plane=renumbered, point_table=np.arange(len(mp), dtype=np.int32))
    # The same assignment in a numbering of a pass whose planes merged and dropped: reversed, every plane twice,
    # and one dropped plane that takes half of the points without a plane.
    n = len(mp)
    table = np.r_[np.arange(n)[::-1], np.arange(n), -1].astype(np.int32)
    ids = {o: np.flatnonzero(table == o) for o in range(-1, n)}
    pick = rng.integers(0, 2, size=m)
    raw = np.array([ids[o][k % len(ids[o])] for o, k in zip(renumbered, pick)], np.int32)
    raw[(renumbered < 0) & (pick == 0)] = -1
    mp = replace(mp, point_plane=raw, point_table=table)
    kw = dict(pixels=np.arange(m, dtype=np.int32), image_shape=(1, m), min_plane_points=50, min_plane_area_m2=0.0)
    got = assemble_plane_set(g, mp, **kw)
    ref = assemble_plane_set(g, numpy_first, **kw)
    assert len(got) == len(ref) >= 2
    for name in ("normals", "offsets", "centroids", "counts", "radii", "areas", "sums", "scatters", "sample_points",
                 "labels"):
        assert np.array_equal(getattr(got, name), getattr(ref, name)), name
    assert (got.labels >= 0).sum() == got.counts.sum()


def _refit_sums_numpy(pts, start, plane_of_voxel, planes, band, refs, coeff, step):
    """The refinement pass of ``assign_points`` for voxels whose only candidate is their own plane (no neighbours),
    Kinect law, depth noise along the rays: plane of every point, Tukey x inverse-variance weighted moments about
    ``refs``, and the plain moments of the supporting points. ``step`` > 1: every ``step``-th point of a voxel."""
    n_planes = len(planes)
    out = {"point_plane": np.full(len(pts), -1), "w": np.zeros(n_planes), "s": np.zeros((n_planes, 3)),
           "S": np.zeros((n_planes, 3, 3)), "n": np.zeros(n_planes, int), "sum": np.zeros((n_planes, 3)),
           "sup": np.zeros((n_planes, 10))}
    for v in range(len(start) - 1):
        q = plane_of_voxel[v]
        if q < 0:
            continue
        idx = np.arange(start[v], start[v + 1])[::step]
        p = pts[idx].astype(np.float64)
        z = np.maximum(p[:, 2], 1e-3)
        g = z / (coeff * z * z)
        npd = p @ planes[q, :3]
        u = np.abs(npd + planes[q, 3]) * g / np.maximum(np.abs(npd), 0.05 * z)
        t = np.clip(1.0 - (u / band[q]) ** 2, 0.0, None)
        w = t * t * g * g
        x = p - refs[q]
        out["w"][q] += w.sum()
        out["s"][q] += w @ x
        out["S"][q] += (x * w[:, None]).T @ x
        out["n"][q] += int((t > 0).sum())
        out["sum"][q] += p[t > 0].sum(0)
        if step == 1:
            h = u <= band[q]
            out["point_plane"][idx[h]] = q
            xh = x[h]
            up = np.triu_indices(3)
            out["sup"][q] += np.concatenate([[h.sum()], xh.sum(0), (xh.T @ xh)[up]])
    return out


@pytest.mark.parametrize("outliers", [300, 0])
@pytest.mark.parametrize("step", [1, 4])
def test_refinement_pass_sums_match_numpy(step, outliers):
    """The refit sums of the refinement pass (all points, and the cheap 1-in-4 pass), against NumPy; without
    outliers every point of a voxel with a plane is inside its band, where the plain sums come from the voxel's
    moments instead of point by point."""
    from reloc.extraction import _kernels_finalize as kfin

    rng = np.random.default_rng(5)
    coeff = 1.425e-3
    walls = [(n / np.linalg.norm(n), d) for n, d in ((np.array([0.3, 0.0, -1.0]), 2.5),
                                                        (np.array([-1.0, 0.1, -0.2]), 1.2))]
    pts = np.concatenate([
        _plane_points(rng, 3000, n, d, 0.004, extent=0.6, centre=c)
        for (n, d), c in zip(walls, ([0.0, 0.0, 2.4], [-1.0, 0.0, 2.4]))
    ] + [rng.uniform([-1.5, -0.7, 1.5], [0.7, 0.7, 3.2], size=(outliers, 3))]).astype(np.float32)
    g = voxelize(pts, voxel_size_m=0.25)
    planes = np.array([np.r_[n, d] for n, d in walls])  # offsets > 0: normals toward the sensor
    # Each voxel takes the plane nearer its centroid when within 3 cm; some voxels have none.
    cent = g.sums / g.counts[:, None]
    dist = np.abs(cent @ planes[:, :3].T + planes[:, 3])
    plane_of_voxel = np.where(dist.min(1) < 0.03, dist.argmin(1), -1).astype(np.int32)
    band = np.array([4.0, 5.0])
    refs = np.array([[0.0, 0.0, 2.4], [-1.0, 0.0, 2.4]])
    n_planes, m = len(planes), len(pts)
    acc = dict(w=np.zeros(n_planes), s=np.zeros((n_planes, 3)), S=np.zeros((n_planes, 3, 3)),
               n=np.zeros(n_planes, np.int64), sum=np.zeros((n_planes, 3)), amb=np.zeros(n_planes, np.int64),
               sup=np.zeros((n_planes, 10)))
    point_plane = np.full(m, -7, np.int32)
    kfin.assign_points(
        g.points, g.points.view(np.int32), step, True, g.start, len(g), g.keys, g.box, g.dense, g.cellmap, g.tkeys,
        g.tvals, g.counts, g.sums, g.scatters, plane_of_voxel, planes, band, 2, coeff, True, False, point_plane,
        True, True, np.cos(np.radians(20.0)), refs, acc["w"], acc["s"], acc["S"], acc["n"], acc["sum"], acc["amb"],
        acc["sup"],
        np.zeros((kfin.SCRATCH_ROWS, int(g.counts.max()))),
    )
    ref = _refit_sums_numpy(g.points, g.start, plane_of_voxel, planes, band, refs, coeff, step)
    assert ref["n"].min() > 100  # both planes hold points of the pass
    if step == 1:  # both paths taken: voxels with every point inside the band and voxels with some outside
        voxel_of = np.repeat(np.arange(len(g)), g.counts)
        outside = np.bincount(voxel_of, weights=ref["point_plane"] < 0, minlength=len(g))
        with_plane = plane_of_voxel >= 0
        assert np.any(outside[with_plane] == 0) and np.any(outside[with_plane] > 0)
    assert np.allclose(acc["w"], ref["w"], rtol=1e-9)
    assert np.allclose(acc["s"], ref["s"], rtol=1e-9, atol=1e-9 * ref["w"].max())
    assert np.allclose(acc["S"], ref["S"], rtol=1e-9, atol=1e-9 * ref["w"].max())
    assert np.array_equal(acc["n"], ref["n"]) and np.allclose(acc["sum"], ref["sum"], rtol=1e-9)
    assert not acc["amb"].any()  # one candidate per voxel: no corner points
    if step == 1:
        assert np.array_equal(point_plane, ref["point_plane"])
        assert np.allclose(acc["sup"], ref["sup"], rtol=1e-9, atol=1e-9)
    else:
        assert np.all(point_plane < 0)  # the cheap pass assigns no point to a plane


@pytest.mark.parametrize("stride", [1, 2, 3])
def test_image_order_voxelization_matches_points_then_voxelize(stride):
    """``depth_to_key_image`` + ``voxelize_key_image`` (no point list in pixel order) give the points of
    ``depth_to_points`` grouped as ``voxelize`` groups them, with each point's pixel as its source."""
    from reloc.extraction.backproject import depth_to_key_image
    from reloc.extraction.voxelize import voxelize_key_image

    rng = np.random.default_rng(10 + stride)
    depth = _bad_depth(rng)
    depth[10:14, 8:20] = 2.0  # a run of pixels in one cell
    box = frustum_box(K_SMALL, min_depth_m=0.3, max_depth_m=8.0, voxel_size_m=0.25)
    pts, pix = depth_to_points(depth, K_SMALL, min_depth_m=0.3, max_depth_m=8.0, pixel_stride=stride)
    d32, pixel_key, cellcount, m, runs = depth_to_key_image(depth, K_SMALL, box, voxel_size_m=0.25, min_depth_m=0.3,
                                                            max_depth_m=8.0, pixel_stride=stride)
    assert m == len(pts)
    # Keys: -1 at invalid pixels, the dense key of floor(p / size) at the others; counts per cell.
    v, u = np.mgrid[0:24:stride, 0:32:stride]
    flat = (v * 32 + u).reshape(-1)
    key_ref = np.full(flat.shape, -1, np.int64)
    ijk = np.floor(pts.astype(np.float64) / 0.25).astype(np.int64) - box[:3]
    key_ref[np.searchsorted(flat, pix)] = (ijk[:, 0] * box[4] + ijk[:, 1]) * box[5] + ijk[:, 2]
    assert np.array_equal(pixel_key, key_ref)
    assert np.array_equal(cellcount, np.bincount(key_ref[key_ref >= 0], minlength=len(cellcount)))
    # Runs: a new one wherever the key changes and at the start of every row of keys.
    row_len = len(range(0, 32, stride))
    starts = np.flatnonzero((np.diff(key_ref, prepend=-2) != 0) | (np.arange(len(key_ref)) % row_len == 0))
    assert np.array_equal(runs, np.append(starts, len(key_ref)))
    g = voxelize_key_image(d32, K_SMALL, pixel_key, cellcount, m, runs, box, voxel_size_m=0.25, pixel_stride=stride)
    ref = voxelize(pts, voxel_size_m=0.25)
    assert g.source_is_pixel and not ref.source_is_pixel
    assert np.array_equal(g.coords, ref.coords) and np.array_equal(g.start, ref.start)
    assert np.array_equal(g.points, ref.points)  # bit for bit, in raster order inside each voxel
    assert np.array_equal(g.source, pix[ref.source])
    assert np.array_equal(g.counts, ref.counts)
    assert np.allclose(g.sums, ref.sums, rtol=1e-12) and np.allclose(g.scatters, ref.scatters, rtol=1e-12)
    assert np.array_equal(g.lookup(ref.coords), np.arange(len(ref)))


def _multi_candidate_numpy(p, cand, planes, band, refs, coeff, ray_mode, cos_corner):
    """Nearest candidate within its band of every point (first of equals), corner points (another candidate at
    least ``acos(cos_corner)`` off in angle whose ray crossing is within 1.5 bands), and the refit / support sums
    per plane, with NumPy."""
    from reloc.extraction._kernels_finalize import CORNER_BANDS

    z = np.maximum(p[:, 2], 1e-3)
    g = z / (coeff * z * z)
    npd = p @ planes[cand, :3].T  # (M, nc)
    r = npd + planes[cand, 3]
    lo = 0.05 * z[:, None]
    den = np.where(np.abs(npd) >= lo, npd, np.where(npd >= 0, lo, -lo))
    e = r * g[:, None] / den
    u = np.abs(e) if ray_mode else np.abs(r) * (g / z)[:, None]
    ok = u <= band[cand][None, :]
    best = np.full(len(p), -1)
    best_u = np.full(len(p), np.inf)
    for k in range(len(cand)):
        better = ok[:, k] & (u[:, k] < best_u)
        best[better] = k
        best_u[better] = u[better, k]
    n = len(planes)
    out = {"point_plane": np.where(best >= 0, np.asarray(cand)[np.maximum(best, 0)], -1), "w": np.zeros(n),
           "s": np.zeros((n, 3)), "S": np.zeros((n, 3, 3)), "n": np.zeros(n, int), "sum": np.zeros((n, 3)),
           "amb": np.zeros(n, int), "sup": np.zeros((n, 10))}
    up = np.triu_indices(3)
    for i in np.flatnonzero(best >= 0):
        k = best[i]
        q = cand[k]
        corner = any(o != k and planes[cand[o], :3] @ planes[q, :3] <= cos_corner
                     and abs(e[i, o] - e[i, k]) < CORNER_BANDS * band[q] for o in range(len(cand)))
        x = p[i] - refs[q]
        out["sup"][q] += np.concatenate([[1.0], x, np.outer(x, x)[up]])
        if corner:
            out["amb"][q] += 1
            continue
        t = max(1.0 - (best_u[i] / band[q]) ** 2, 0.0)
        w = t * t * (g[i] ** 2 if ray_mode else (g[i] / z[i]) ** 2)
        out["w"][q] += w
        out["s"][q] += w * x
        out["S"][q] += w * np.outer(x, x)
        if t > 0:
            out["n"][q] += 1
            out["sum"][q] += p[i]
    return out


@pytest.mark.parametrize("corner_deg", [20.0, 2.0])
@pytest.mark.parametrize("ray_mode", [True, False])
@pytest.mark.parametrize("step", [1, 4])
def test_multi_candidate_voxel_matches_numpy(ray_mode, step, corner_deg):
    """The voxel of ``assign_points`` with several candidate planes (a corner of two walls and a third plane
    nearly parallel to one of them, 2.9 deg: a corner only when the corner angle is below that), against NumPy:
    nearest candidate, corner points, refit and support sums."""
    from reloc.extraction import _kernels_finalize as kfin

    rng = np.random.default_rng(21)
    coeff = 1.425e-3
    n1 = np.array([0.0, 0.0, -1.0])
    n2 = np.array([-1.0, 0.0, -0.3]) / np.linalg.norm([-1.0, 0.0, -0.3])
    n3 = np.array([0.05, 0.0, -1.0]) / np.linalg.norm([0.05, 0.0, -1.0])
    c = np.array([0.1, 0.0, 2.0])
    planes = np.array([np.r_[n, -n @ c] for n in (n1, n2, n3)] + [[0.0, -1.0, 0.0, 1.5]])
    pts = np.concatenate([_plane_points(rng, 300, n, -n @ c, 0.006, extent=0.12, centre=c) for n in (n1, n2)]
                         + [c + rng.uniform(-0.12, 0.12, size=(40, 3))]).astype(np.float32)
    m = len(pts)
    cand = np.array([0, 1, 2, 3], np.int64)
    band = np.array([4.0, 5.0, 4.0, 4.0])
    refs = np.array([[0.0, 0.0, 2.0], [0.1, 0.0, 2.0], [0.0, 0.1, 2.0], [0.0, 0.0, 0.0]])
    n_planes = len(planes)
    acc = dict(w=np.zeros(n_planes), s=np.zeros((n_planes, 3)), S=np.zeros((n_planes, 3, 3)),
               n=np.zeros(n_planes, np.int64), sum=np.zeros((n_planes, 3)), amb=np.zeros(n_planes, np.int64),
               sup=np.zeros((n_planes, 10)))
    point_plane = np.full(m, -7, np.int32)
    n_in = kfin._multi_plane_voxel(
        pts, pts.view(np.int32), step, True, 0, m, cand, len(cand), planes, band, 2, coeff, ray_mode, point_plane, True,
        True, np.cos(np.radians(corner_deg)), refs, acc["w"], acc["s"], acc["S"], acc["n"], acc["sum"], acc["amb"],
        acc["sup"],
        np.zeros((kfin.SCRATCH_ROWS, m)), np.zeros((kfin.MAX_CANDIDATES, kfin.MAX_CANDIDATES), np.bool_),
        np.full(kfin.MAX_CANDIDATES, 99, np.int64))
    ref = _multi_candidate_numpy(pts[::step].astype(np.float64), cand, planes, band, refs, coeff, ray_mode,
                                 np.cos(np.radians(corner_deg)))
    assert n_in == int((ref["point_plane"] >= 0).sum())
    # The fourth candidate (y = 1.5) is nearest to no point: its sums are skipped and must stay zero.
    assert not np.any(ref["point_plane"] == 3) and not acc["w"][3] and not acc["sup"][3].any()
    if corner_deg == 20.0:
        assert ref["n"][0] > 20 and ref["n"][1] > 20 and ref["amb"].sum() > 5  # both walls fit, corner points seen
    else:  # the 2.9 deg plane counts as a corner: every point of the first wall and of it is a corner point
        assert ref["n"][0] == 0 and ref["n"][2] == 0 and ref["n"][1] > 20 and ref["amb"][0] > 40
    wmax = ref["w"].max()
    assert np.allclose(acc["w"], ref["w"], rtol=1e-9)
    assert np.allclose(acc["s"][:, :], ref["s"], rtol=1e-9, atol=1e-9 * wmax)
    assert np.allclose(np.triu(acc["S"][0]), np.triu(ref["S"][0]), rtol=1e-9, atol=1e-9 * wmax)
    assert np.allclose(np.triu(acc["S"][1]), np.triu(ref["S"][1]), rtol=1e-9, atol=1e-9 * wmax)
    assert np.array_equal(acc["n"], ref["n"]) and np.array_equal(acc["amb"], ref["amb"])
    assert np.allclose(acc["sum"], ref["sum"], rtol=1e-9)
    if step == 1:
        assert np.array_equal(point_plane, ref["point_plane"])
        assert np.allclose(acc["sup"], ref["sup"], rtol=1e-9, atol=1e-9)
    else:
        assert np.all(point_plane == -7)  # the cheap pass assigns nothing


def test_plane_order_keep_and_gather_match_numpy():
    """The plane set's bookkeeping kernels against the NumPy they replace: cell offsets, centroids, planes ordered
    by support (stable), the area filter with the labels' renumbering, and the kept rows."""
    from reloc.extraction import _kernels_finalize as kfin

    rng = np.random.default_rng(9)
    n = 40
    counts = rng.integers(0, 400, n).astype(np.int64)
    counts[[3, 7, 11]] = 250  # ties keep their index order
    counts[5] = 0
    sums = rng.normal(size=(n, 3)) * np.maximum(counts, 1)[:, None]
    area_grid = rng.integers(1, 9, size=(n, 4)).astype(np.int64)
    sample_grid = rng.integers(1, 9, size=(n, 4)).astype(np.int64)
    min_points = 200
    area_off_ref = np.concatenate([[0], np.cumsum(area_grid[:, 2] * area_grid[:, 3])])
    sample_off_ref = np.concatenate([[0], np.cumsum(sample_grid[:, 2] * sample_grid[:, 3])])
    centroids_ref = sums / np.maximum(counts, 1)[:, None]
    order_ref = np.flatnonzero(counts >= min_points)
    order_ref = order_ref[np.argsort(-counts[order_ref], kind="stable")]
    remap_ref = np.full(n, -1, np.int32)
    remap_ref[order_ref] = np.arange(len(order_ref))
    area_off = np.full(n + 1, -9, np.int64)
    sample_off = np.full(n + 1, -9, np.int64)
    centroids = np.full((n, 3), np.nan)
    order = np.full(n, -9, np.int64)
    remap = np.full(n, -9, np.int32)
    k = kfin.plane_order(counts, sums, min_points, area_grid, sample_grid, centroids, area_off, sample_off, order,
                         remap)
    assert k == len(order_ref) and 5 < k < n - 5
    assert np.array_equal(area_off, area_off_ref) and np.array_equal(sample_off, sample_off_ref)
    assert np.array_equal(centroids, centroids_ref)
    assert np.array_equal(order[:k], order_ref) and np.array_equal(remap, remap_ref)
    areas = rng.uniform(0.0, 0.1, n)
    keep_ref = order_ref[areas[order_ref] >= 0.04]
    final_ref = np.full(len(order_ref), -1, np.int32)
    final_ref[remap_ref[keep_ref]] = np.arange(len(keep_ref))
    keep = np.full(k, -9, np.int64)
    final = np.full(k, -9, np.int32)
    nk = kfin.keep_planes(order, k, areas, 0.04, remap, keep, final)
    assert 0 < nk < k
    assert np.array_equal(keep[:nk], keep_ref) and np.array_equal(final, final_ref)
    planes = rng.normal(size=(n, 4))
    radii = rng.uniform(size=n)
    covs = rng.normal(size=(n, 4, 4))
    scat = rng.normal(size=(n, 3, 3))
    out = (np.empty((nk, 3)), np.empty(nk), np.empty((nk, 3)), np.empty(nk, np.int64), np.empty(nk), np.empty(nk),
           np.empty((nk, 4, 4)), np.empty((nk, 3)), np.empty((nk, 3, 3)))
    kfin.gather_planes(keep, nk, planes, centroids, counts, radii, areas, covs, sums, scat, *out)
    want = (planes[keep_ref, :3], planes[keep_ref, 3], centroids_ref[keep_ref], counts[keep_ref], radii[keep_ref],
            areas[keep_ref], covs[keep_ref], sums[keep_ref], scat[keep_ref])
    for got, ref in zip(out, want):
        assert np.array_equal(got, ref)


@pytest.mark.parametrize("stride, same_cells", [(1, True), (1, False), (2, True)])
def test_plane_extent_matches_numpy(stride, same_cells):
    """The plane set's pass over the supporting points (radius, occupied area cells, per-cell sample sums, label
    image through the refinement's table) against NumPy, point by point."""
    from reloc.extraction import _kernels_finalize as kfin
    from reloc.extraction._kernels_linalg import tangent_basis

    rng = np.random.default_rng(12)
    n_planes, m, width, height = 5, 3000, 40, 30
    pts = rng.uniform([-1.0, -1.0, 1.0], [1.0, 1.0, 3.0], size=(m, 3)).astype(np.float32)
    # Runs of points of one plane (as voxel by voxel), some without a plane.
    point_plane = np.repeat(rng.integers(-1, 7, m // 20), 20).astype(np.int32)
    table = np.array([0, 1, -1, 2, 3, 4, 1], np.int32)  # pass's planes to the output's (-1: dropped)
    src = rng.integers(0, width * height, m).astype(np.int32)  # pixels (repeated: the last point wins)
    if stride > 1:  # the top-left pixel of each stride x stride block
        src = ((src // width) // stride * stride * width + (src % width) // stride * stride).astype(np.int32)
    normals = rng.normal(size=(n_planes, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    tb = np.array([tangent_basis(*n) for n in normals])
    centroids = rng.normal(size=(n_planes, 3))
    area_cell, sample_cell = (0.1, 0.1) if same_cells else (0.1, 0.25)
    p64 = pts.astype(np.float64)
    uv = np.stack([p64 @ tb[:, :3].T, p64 @ tb[:, 3:].T], axis=2)  # (m, P, 2)
    grids = []
    for cell in (area_cell, sample_cell):
        g = np.zeros((n_planes, 4), np.int64)
        g[:, 0] = np.floor(uv[:, :, 0].min(0) / cell) - 1
        g[:, 1] = np.floor(uv[:, :, 1].min(0) / cell) - 1
        g[:, 2] = np.floor(uv[:, :, 0].max(0) / cell) - g[:, 0] + 2
        g[:, 3] = np.floor(uv[:, :, 1].max(0) / cell) - g[:, 1] + 2
        grids.append(g)
    area_grid, sample_grid = grids
    area_off = np.concatenate([[0], np.cumsum(area_grid[:, 2] * area_grid[:, 3])]).astype(np.int64)
    sample_off = np.concatenate([[0], np.cumsum(sample_grid[:, 2] * sample_grid[:, 3])]).astype(np.int64)
    remap = np.array([2, -1, 0, 1, 3], np.int32)
    occupied = np.full(area_off[-1], 7, np.uint8)
    sample_acc = np.full((sample_off[-1], 4), np.nan)
    radii = np.full(n_planes, np.nan)
    areas = np.full(n_planes, np.nan)
    labels = np.full(width * height, 99, np.int32)
    kfin.plane_extent(pts, point_plane, table, m, centroids, tb, area_cell, area_grid, area_off, occupied, sample_cell,
                      sample_grid, sample_off, sample_acc, radii, areas, True, src, True, np.zeros(1, np.int32), remap,
                      width, height, stride, labels)
    # NumPy reference.
    plane = np.where(point_plane >= 0, table[np.maximum(point_plane, 0)], -1)
    ref_radii = np.zeros(n_planes)
    ref_acc = np.zeros((sample_off[-1], 4))
    ref_occ = np.zeros(area_off[-1], bool)
    ref_labels = np.full((height, width), -1, np.int32)
    for j in np.flatnonzero(plane >= 0):
        p = plane[j]
        ref_radii[p] = max(ref_radii[p], np.linalg.norm(p64[j] - centroids[p]))
        u, v = uv[j, p]
        for grid, off, cell, out in ((area_grid, area_off, area_cell, "a"), (sample_grid, sample_off, sample_cell, "s")):
            iu = min(max(int(np.floor(u / cell)) - grid[p, 0], 0), grid[p, 2] - 1)
            iv = min(max(int(np.floor(v / cell)) - grid[p, 1], 0), grid[p, 3] - 1)
            c = off[p] + iu * grid[p, 3] + iv
            if out == "a":
                ref_occ[c] = True
            else:
                ref_acc[c] += [1.0, *p64[j]]
        if remap[p] >= 0 or stride == 1:
            v0, u0 = divmod(int(src[j]), width)
            ref_labels[v0:v0 + stride, u0:u0 + stride] = remap[p]
    assert np.allclose(radii, ref_radii, rtol=1e-12)
    assert np.array_equal(sample_acc[:, 0], ref_acc[:, 0])
    assert np.allclose(sample_acc, ref_acc, rtol=1e-12, atol=1e-12)
    if same_cells:
        ref_areas = np.array([np.count_nonzero(ref_acc[sample_off[p]:sample_off[p + 1], 0]) for p in range(n_planes)])
    else:
        ref_areas = np.array([np.count_nonzero(ref_occ[area_off[p]:area_off[p + 1]]) for p in range(n_planes)])
    assert np.array_equal(areas, ref_areas * area_cell * area_cell)
    assert np.array_equal(labels.reshape(height, width), ref_labels)


def _random_sym3(rng, kind):
    """A symmetric 3x3 with a random rotation and eigenvalues of the given kind, scaled by 1e-6 .. 1e2."""
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if kind == "plane":  # a thin patch: one small eigenvalue, the two larger ones anywhere
        lam = np.array([rng.uniform(1e-9, 1e-2), rng.uniform(0.05, 1.0), 1.0])
    elif kind == "square":  # a thin square patch: the two larger eigenvalues equal to ~1e-9
        lam = np.array([rng.uniform(1e-9, 1e-2), 1.0, 1.0 + rng.uniform(0.0, 1e-9)])
    elif kind == "generic":
        lam = np.sort(rng.uniform(0.0, 1.0, 3))
    elif kind == "line":  # the two smaller equal: the eigenvector is not defined, only the eigenvalues
        lam = np.array([1e-4, 1e-4 * (1.0 + 1e-10), 1.0])
    elif kind == "sphere":
        lam = np.ones(3)
    else:  # "rank1"
        lam = np.array([0.0, 0.0, 1.0])
    return (Q * lam) @ Q.T * 10.0 ** rng.uniform(-6.0, 2.0)


@pytest.mark.parametrize("kind", ["plane", "square", "generic", "line", "sphere", "rank1"])
def test_smallest_eig3_matches_numpy_eigh(kind):
    from reloc.extraction._kernels_linalg import smallest_eig3, sym_eig3

    rng = np.random.default_rng(len(kind))
    w = np.zeros(3)
    V = np.zeros((3, 3))
    w_j = np.zeros(3)
    V_j = np.zeros((3, 3))
    for _ in range(500):
        M = _random_sym3(rng, kind)
        lam, vec = np.linalg.eigh(M)
        scale = np.abs(lam).max()
        smallest_eig3(M.copy(), w, V)
        sym_eig3(M.copy(), w_j, V_j)
        assert np.allclose(w, lam, rtol=0.0, atol=1e-14 * scale)
        assert np.allclose(w, w_j, rtol=0.0, atol=1e-14 * scale)
        assert abs(np.linalg.norm(V[:, 0]) - 1.0) < 1e-14
        # The eigenvector is defined (up to sign) where the smallest eigenvalue is simple; its error is about
        # eps |A| / (lam1 - lam0), as the Jacobi sweeps'.
        gap = (lam[1] - lam[0]) / scale
        if gap > 1e-3:
            tol = 1e-15 / gap + 1e-15
            assert 1.0 - abs(V[:, 0] @ vec[:, 0]) < tol
            assert 1.0 - abs(V[:, 0] @ V_j[:, 0]) < tol
        else:
            assert np.linalg.norm(M @ V[:, 0] - w[0] * V[:, 0]) < 1e-14 * scale


def test_weight_and_noise_helpers_match_their_formulas():
    """The per-point helpers every fit uses, against the formulas written out in NumPy: the noise laws, the
    point-to-plane sigma along the ray, the inverse-variance weights, the paper's Eq. 2 position weight (square
    model inside sigma = r_max / 2, exponential outside) and Tukey's biweight."""
    from reloc.extraction import _kernels_fit as kfit

    rng = np.random.default_rng(21)
    z = rng.uniform(0.3, 9.0, 50)
    for power, law in ((0, lambda z: np.full_like(z, 2e-3)), (1, lambda z: 2e-3 * z), (2, lambda z: 2e-3 * z**2)):
        got = np.array([kfit.point_sigma(v, power, 2e-3) for v in z])
        np.testing.assert_allclose(got, law(z), rtol=1e-15)
    assert kfit.point_sigma(0.0, 2, 1.0) == kfit.MIN_DEPTH**2  # never zero
    q = rng.normal([0.0, 0.0, 3.0], [1.0, 1.0, 0.5], (50, 3))
    n = rng.normal(size=(50, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    sig_z = 0.01
    incidence = np.maximum(np.abs(np.sum(n * q, axis=1)) / q[:, 2], kfit.MIN_INCIDENCE)  # |n . ray| / ray_z
    for i in range(50):
        ray = kfit.distance_sigma(*q[i], *n[i], sig_z, True)
        assert ray == pytest.approx(sig_z * incidence[i], rel=1e-12)
        assert kfit.distance_sigma(*q[i], *n[i], sig_z, False) == sig_z
        assert kfit.noise_weight(q[i, 2], sig_z, ray, True) == pytest.approx(q[i, 2] ** 2 / sig_z**2, rel=1e-12)
        assert kfit.noise_weight(q[i, 2], sig_z, ray, False) == pytest.approx(1.0 / ray**2, rel=1e-12)
    rho = np.linspace(0.0, 1.0, 101)
    alpha, beta = 0.5, 2.0
    want = np.where(rho <= 0.5, np.maximum(1.0 - alpha * rho**2, 0.0), np.exp(-beta * rho**2))
    np.testing.assert_allclose([kfit.position_weight(r, alpha, beta) for r in rho], want, rtol=1e-14)
    assert kfit.position_weight(0.4, 10.0, 2.0) == 0.0  # the square model is clipped at zero
    u = np.linspace(-5.0, 5.0, 201)
    c = 3.0
    want = np.where(np.abs(u) < c, (1.0 - (u / c) ** 2) ** 2, 0.0)
    np.testing.assert_allclose([kfit.tukey_weight(v, c) for v in u], want, rtol=1e-14, atol=1e-300)


def test_symmetric_solve_and_subsample_step_match_numpy():
    from reloc.extraction import _kernels_linalg as kl
    from reloc.extraction import _kernels_voxelfit as kvf

    rng = np.random.default_rng(22)
    for _ in range(50):
        a = rng.normal(size=(3, 3))
        S = a @ a.T + 0.1 * np.eye(3)
        b = rng.normal(size=3)
        *x, ok = kl.solve_sym3(S[0, 0], S[0, 1], S[0, 2], S[1, 1], S[1, 2], S[2, 2], *b)
        assert ok
        np.testing.assert_allclose(x, np.linalg.solve(S, b), rtol=1e-8, atol=1e-10)
    singular = np.outer([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    assert kl.solve_sym3(*singular[0], singular[1, 1], singular[1, 2], singular[2, 2], 1.0, 1.0, 1.0)[3] is False
    for n in (0, 1, 255, 256, 257, 512, 513, 10_000):
        k = kvf.pow2_step(n, 256)
        assert k & (k - 1) == 0 and n / k <= 256 and (k == 1 or n / (k // 2) > 256), (n, k)


def test_layer_candidates_and_blocks_match_numpy():
    from reloc.extraction import _kernels_finalize as kf

    rng = np.random.default_rng(7)
    n = 12
    normals = rng.normal(size=(n, 3))
    normals[:6] = [0.0, 0.0, -1.0] + 0.02 * rng.normal(size=(6, 3))  # a few nearly parallel planes
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    planes = np.column_stack([normals, rng.uniform(1.0, 6.0, n)])
    counts = rng.integers(0, 500, n).astype(np.int64)
    counts[3] = counts[4]  # a tie, broken by index
    counts[7] = 0  # a plane without points
    sums = rng.uniform(-1, 1, (n, 3)) * counts[:, None]
    sums[:, 2] = rng.uniform(1.0, 6.0, n) * counts
    cos_max, k, coeff = np.cos(np.radians(8.0)), 4.0, 0.01
    out = np.empty((200, 2), np.int64)
    got = kf.layer_candidates(planes, counts, sums, cos_max, k, 2, coeff, out)
    want = []
    for i in range(n):
        for j in range(n):
            if i == j or counts[i] <= 0 or counts[j] <= 0 or (counts[j], -j) > (counts[i], -i):
                continue
            c = sums[j] / counts[j]
            if planes[i, :3] @ planes[j, :3] >= cos_max and abs(planes[i, :3] @ c + planes[i, 3]) <= k * coeff * max(
                    c[2], 0.1) ** 2:
                want.append((i, j))
    assert got == len(want) > 0 and [tuple(r) for r in out[:got]] == want

    m, block = 400, 2
    table = np.array([2, -1, 0, 3, 1], np.int32)
    bit_of = np.array([0, -1, 1, 2], np.int64)
    # Odd sizes too: the kernel takes a pixel's row by a multiplication, the test by an integer division.
    for (width, height), src_is_pixel in itertools.product(((20, 12), (21, 13), (640, 5)), (True, False)):
        point_plane = rng.integers(-1, 5, m).astype(np.int32)
        pix = rng.permutation(width * height).astype(np.int32)
        src = rng.integers(0, width * height, m).astype(np.int32)
        n_bw = -(-width // block)
        masks = np.zeros(n_bw * -(-height // block), np.uint64)
        kf.layer_blocks(point_plane, table, m, src, src_is_pixel, pix, width, block, n_bw, bit_of, masks)
        want = np.zeros_like(masks)
        for j in range(m):
            if point_plane[j] < 0 or table[point_plane[j]] < 0 or bit_of[table[point_plane[j]]] < 0:
                continue
            k = src[j] if src_is_pixel else pix[src[j]]
            want[(k // width) // block * n_bw + (k % width) // block] |= np.uint64(1) << np.uint64(
                bit_of[table[point_plane[j]]])
        np.testing.assert_array_equal(masks, want)
