"""Fuzzing depth frames into plane extraction: rendered planes (one to three, any pose, noise-free or noisy) and
frames that are all invalid, all one value, NaN and inf, negative, a single valid pixel, extreme ranges (1e-30 to
1e30 m), with holes punched in them, under a few parameter sets (voxel size, pixel stride, depth limits).

Property: ``extract_planes`` returns planes with finite parameters, unit normals toward the sensor, positive counts
and a label image of the frame's shape whose labels are -1 or a plane index; a frame showing one noise-free plane
gives only that plane (normal within 1 degree, offset within 1 cm). Or it raises ``ValueError`` (no frame should).
"""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from reloc.camera import DepthFrame, Intrinsics
from reloc.extraction import ExtractionParams
from reloc.extraction.pipeline import extract_planes
from test_fuzz_common import Target, fuzz_settings, outcome

W, H = 64, 48
K = Intrinsics(fx=50.0, fy=50.0, cx=31.5, cy=23.5, width=W, height=H, depth_scale=1000.0)
PARAMS = [
    ExtractionParams(min_plane_points=20, min_points_per_voxel=5, min_plane_area_m2=0.0),
    ExtractionParams(min_plane_points=20, min_points_per_voxel=5, min_plane_area_m2=0.0, voxel_size_m=0.1,
                     pixel_stride=2),
    ExtractionParams(min_plane_points=10, min_points_per_voxel=3, min_plane_area_m2=0.0, min_depth_m=1e-3,
                     max_depth_m=1e3, voxel_size_m=0.5),
    ExtractionParams(),
]
RAYS = np.stack([*np.meshgrid((np.arange(W) - K.cx) / K.fx, (np.arange(H) - K.cy) / K.fy), np.ones((H, W))], -1)


def render(normals: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Depth (H, W) of the nearest of the planes n.p + d = 0 in front of the camera (NaN where none)."""
    depth = np.full((H, W), np.inf)
    for n, d in zip(normals, offsets):
        with np.errstate(divide="ignore", invalid="ignore"):
            z = -d / (RAYS @ n)
        depth = np.where((z > 0) & (z < depth), z, depth)
    return np.where(np.isfinite(depth), depth, np.nan).astype(np.float32)


unit = st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda v: np.linalg.norm(v) > 0.2).map(
    lambda v: np.array(v) / np.linalg.norm(v))


@st.composite
def frames(draw) -> tuple:
    """(depth (H, W) float32, gravity or None, params index, the one true plane (n, d) or None)."""
    kind = draw(st.integers(0, 9))
    truth = None
    if kind <= 4:  # rendered planes, facing the camera
        k = draw(st.integers(1, 3))
        normals, offsets = [], []
        for _ in range(k):
            n = draw(unit)
            n = n if n[2] < 0 else -n  # toward the sensor: the camera looks along +z
            if n[2] > -0.3:
                n = np.array([n[0], n[1], -0.8]) / np.linalg.norm([n[0], n[1], -0.8])
            normals.append(n)
            offsets.append(draw(st.floats(0.5, 6.0)))
        depth = render(np.array(normals), np.array(offsets))
        if k == 1 and kind <= 1:
            truth = (normals[0], offsets[0])
        elif draw(st.booleans()):
            depth = depth + np.random.default_rng(draw(st.integers(0, 99))).normal(0, 0.003, depth.shape).astype(
                np.float32) * depth ** 2
    elif kind == 5:  # constant
        depth = np.full((H, W), draw(st.sampled_from([0.0, np.nan, np.inf, -1.0, 1e-30, 0.3, 2.0, 7.999, 8.0, 1e30,
                                                      65.535, 3.4e38])), np.float32)
    elif kind == 6:  # one valid pixel
        depth = np.full((H, W), draw(st.sampled_from([0.0, np.nan])), np.float32)
        depth[draw(st.integers(0, H - 1)), draw(st.integers(0, W - 1))] = draw(st.floats(0.01, 20))
    elif kind == 7:  # random values over extreme ranges
        rng = np.random.default_rng(draw(st.integers(0, 999)))
        lo, hi = draw(st.sampled_from([(-5, 5), (1e-30, 1e-20), (0.29, 0.31), (1e3, 1e30), (-1e30, 1e30)]))
        with np.errstate(over="ignore"):
            depth = rng.uniform(lo, hi, (H, W)).astype(np.float32)
    elif kind == 8:  # steps and stripes
        depth = np.full((H, W), 2.0, np.float32)
        depth[:, draw(st.integers(0, W - 1)):] = draw(st.floats(0.1, 10))
        depth[::2] = draw(st.sampled_from([np.nan, 0.0, 1.0]))
    else:  # a plane in a field of special values
        depth = render(np.array([[0.0, 0.0, -1.0]]), np.array([draw(st.floats(0.3, 8))]))
        special = np.array([np.nan, np.inf, -np.inf, 0.0, -2.0, 1e30], np.float32)
        rng = np.random.default_rng(draw(st.integers(0, 999)))
        mask = rng.random((H, W)) < draw(st.floats(0, 1))
        depth[mask] = special[rng.integers(0, len(special), mask.sum())]
    if truth is None and draw(st.integers(0, 3)) == 0:  # holes
        rng = np.random.default_rng(draw(st.integers(0, 999)))
        depth = depth.copy()
        depth[rng.random((H, W)) < draw(st.floats(0, 1))] = np.nan
    gravity = draw(st.one_of(st.none(), unit))
    return depth.astype(np.float32), gravity, draw(st.integers(0, len(PARAMS) - 1)), truth


def check_frame(depth: np.ndarray, gravity, params_index: int, truth) -> None:
    frame = DepthFrame(depth_m=depth, intrinsics=K, stamp_ns=0, gravity_cam=gravity)
    result = extract_planes(frame, PARAMS[params_index])
    p = result.planes
    n = len(p)
    assert np.isfinite(p.normals).all() and np.isfinite(p.offsets).all() and np.isfinite(p.centroids).all()
    assert np.isfinite(p.covariances).all() and np.isfinite(p.areas).all() and np.isfinite(p.sample_points).all()
    if n:
        assert np.allclose(np.linalg.norm(p.normals, axis=1), 1.0, atol=1e-6)
        assert np.all(p.offsets > 0), "normals point toward the sensor at the origin: n.0 + d > 0"
        assert np.all(p.counts > 0)
    assert p.labels is not None and p.labels.shape == (H, W)
    assert p.labels.min() >= -1 and p.labels.max() < n
    if truth is not None:
        normal, offset = truth
        for i in range(n):
            angle = np.degrees(np.arccos(np.clip(p.normals[i] @ normal, -1, 1)))
            assert angle < 1.0 and abs(p.offsets[i] - offset) < 0.01, (p.normals[i], p.offsets[i], truth)


def run(case) -> str:
    return outcome(lambda: check_frame(*case), names=None, timeout_s=120)


TARGET = Target("depth_frame", "depth frame into extraction", frames(), run)


@fuzz_settings(80)
@given(frames())
def test_fuzzed_depth_frames_give_valid_planes(case):
    run(case)


def test_a_frame_of_one_plane_gives_that_plane():
    n = np.array([0.2, -0.3, -0.9])
    n /= np.linalg.norm(n)
    depth = render(n[None], np.array([2.0]))
    result = extract_planes(DepthFrame(depth_m=depth, intrinsics=K, stamp_ns=0), PARAMS[0])
    assert len(result.planes) == 1
    check_frame(depth, None, 0, (n, 2.0))


# Regressions found by the fuzzer (each escaped before its fix).


def test_far_depth_limit_does_not_allocate_the_whole_frustum():
    # max_depth_m 1000 m with 0.5 m voxels: a dense key table of 44 GiB for this 64x48 camera (MemoryError before);
    # the occupied cells are hashed instead and the plane comes out as with the usual limits.
    n = np.array([0.0, 0.0, -1.0])
    depth = render(n[None], np.array([3.0]))
    far = extract_planes(DepthFrame(depth_m=depth, intrinsics=K, stamp_ns=0), PARAMS[2]).planes
    assert len(far) == 1
    np.testing.assert_allclose(far.normals[0], n, atol=1e-6)
    assert abs(far.offsets[0] - 3.0) < 1e-4


def test_depth_images_that_are_not_numbers_and_bad_stamps_are_value_errors():
    # A record array escaped as TypeError; booleans, text, dates and objects became "depths" silently before.
    for arr in (np.zeros((H, W), "i4,f4"), np.ones((H, W), bool), np.full((H, W), "1.5"),
                np.ones((H, W), "M8[s]"), np.full((H, W), None, object), np.ones((H, W), np.complex64)):
        assert outcome(lambda: DepthFrame(depth_m=arr, intrinsics=K, stamp_ns=0), names="depth_m") == "error"
    for stamp in (True, 2**70, 1.5):
        assert outcome(lambda: DepthFrame(depth_m=np.ones((H, W), np.float32), intrinsics=K, stamp_ns=stamp),
                       names="stamp_ns") == "error"
    for arr in (np.ones((H, W), np.uint16), np.ones((H, W), np.float64)):  # numbers of any width are depths
        assert DepthFrame(depth_m=arr, intrinsics=K, stamp_ns=0).depth_m.dtype == np.float32
