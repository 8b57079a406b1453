"""The flying-pixel filter (``ExtractionParams.flying_pixel_sigmas``): the numba kernel against a NumPy reference,
and what it removes from a frame whose occluding edge has flying pixels."""

from __future__ import annotations

import numpy as np
import pytest

from reloc.camera import DepthFrame, Intrinsics
from reloc.extraction import ExtractionParams, PlaneExtractor
from reloc.extraction.backproject import FLYING_MIN_REL, drop_flying_pixels

K = Intrinsics(fx=262.5, fy=262.5, cx=159.5, cy=119.5, width=320, height=240)


def _reference(depth, power, coeff, k):
    z = depth.astype(np.float64)
    valid = np.isfinite(z) & (z > 0)
    zz = np.where(valid, z, np.nan)
    tau = np.maximum(k * coeff * zz**power, FLYING_MIN_REL * zz)
    bad = np.zeros(z.shape, bool)
    h, w = z.shape
    for dy, dx in ((0, 1), (1, 0), (0, -1), (-1, 0)):
        nb = np.full(z.shape, np.nan)
        nb[max(-dy, 0):h + min(-dy, 0), max(-dx, 0):w + min(-dx, 0)] = zz[max(dy, 0):h + min(dy, 0),
                                                                          max(dx, 0):w + min(dx, 0)]
        with np.errstate(invalid="ignore"):
            bad |= np.abs(zz - nb) > tau
    out = depth.astype(np.float32).copy()
    out[bad & valid] = np.nan
    return out


@pytest.mark.parametrize("model,power", [("kinect", 2), ("tof", 1), ("constant", 0)])
def test_the_kernel_matches_a_numpy_reference(model, power):
    rng = np.random.default_rng(power)
    depth = (2.0 + rng.normal(size=(60, 80)) * 0.01).astype(np.float32)
    depth[20:40, 30:50] = 1.2  # a box in front: an occluding edge all round
    depth[rng.random(depth.shape) < 0.05] = np.nan
    depth[rng.random(depth.shape) < 0.02] = 0.0
    depth[rng.random(depth.shape) < 0.01] = -1.0
    depth[rng.random(depth.shape) < 0.01] = np.inf
    coeff = {"kinect": 1.425e-3, "tof": 3e-3, "constant": 0.01}[model]
    got = drop_flying_pixels(depth, noise_model=model, noise_coeff=coeff, k_sigmas=4.0)
    want = _reference(depth, power, coeff, 4.0)
    assert np.array_equal(np.isnan(got), np.isnan(want))
    assert np.array_equal(got[~np.isnan(got)], want[~np.isnan(want)])


def test_both_sides_of_an_edge_go_and_nothing_else():
    depth = np.full((30, 40), 2.0, np.float32)
    box = np.zeros(depth.shape, bool)
    box[10:20, 15:25] = True
    depth[box] = 1.2
    beside = np.zeros(depth.shape, bool)
    for axis in (0, 1):
        for step in (1, -1):
            beside |= box != np.roll(box, step, axis=axis)
    got = drop_flying_pixels(depth, noise_model="kinect", noise_coeff=1.425e-3, k_sigmas=4.0)
    # The box's outline (36 pixels) and the ring just outside it (40).
    assert np.array_equal(np.isnan(got), beside) and beside.sum() == (4 * 10 - 4) + 4 * 10
    assert np.array_equal(got[~beside], depth[~beside])


def test_bad_arguments_are_refused_by_name():
    with pytest.raises(ValueError, match="depth_m: expected an"):
        drop_flying_pixels(np.zeros(5, np.float32), noise_model="kinect", noise_coeff=1e-3, k_sigmas=4.0)
    with pytest.raises(ValueError, match="k_sigmas"):
        drop_flying_pixels(np.zeros((4, 4), np.float32), noise_model="kinect", noise_coeff=1e-3, k_sigmas=0.0)
    with pytest.raises(ValueError, match="noise_model"):
        drop_flying_pixels(np.zeros((4, 4), np.float32), noise_model="sonar", noise_coeff=1e-3, k_sigmas=4.0)
    with pytest.raises(ValueError, match="flying_pixel_sigmas"):
        ExtractionParams(flying_pixel_sigmas=-1.0)


def test_the_config_switches_it_on():
    from reloc.config import Config

    assert ExtractionParams.from_config(Config()).flying_pixel_sigmas == 0.0
    cfg = Config.model_validate({"extraction": {"flying_pixel_sigmas": 4}})
    assert ExtractionParams.from_config(cfg).flying_pixel_sigmas == 4.0


def _wall_and_board(seed=0):
    """A fronto-parallel wall at 4 m and a 1.2 x 1.0 m board 0.5 m in front of it; on the wall's side of the
    board's vertical edges every pixel is a flying pixel (a depth a fraction 0.1-0.9 of the way from board to
    wall), as real sensors report them. Kinect noise. Returns depth, the flying-pixel mask, the wall's pixels."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:K.height, 0:K.width]
    x = (u - K.cx) / K.fx
    y = (v - K.cy) / K.fy
    z = np.full(u.shape, 4.0)
    board = (np.abs(x * 3.5) < 0.6) & (np.abs(y * 3.5) < 0.5)
    z[board] = 3.5
    edge = ~board & (np.roll(board, 1, axis=1) | np.roll(board, -1, axis=1))
    z[edge] = 3.5 + rng.uniform(0.1, 0.9, edge.sum()) * 0.5
    depth = z + rng.normal(size=z.shape) * 1.425e-3 * z**2
    return depth.astype(np.float32), edge, ~board & ~edge


def test_flying_pixels_at_an_occluding_edge_never_reach_a_plane(monkeypatch):
    depth, flying, wall = _wall_and_board()
    frame = DepthFrame(depth_m=depth, stamp_ns=0, seq=0, intrinsics=K, gravity_cam=np.array([0.0, 1.0, 0.0]))
    off = PlaneExtractor(ExtractionParams()).extract(frame).planes
    on = PlaneExtractor(ExtractionParams(flying_pixel_sigmas=4.0)).extract(frame).planes
    # Without the filter the wall's band (4 sigmas, 9 cm at 4 m) takes in the flying pixels near it.
    assert (off.labels[flying] >= 0).sum() > 20
    assert (on.labels[flying] >= 0).sum() == 0
    # The wall is still found, from nearly all its pixels, as precisely as without the filter.
    for ps in (off, on):
        j = int(np.argmax(ps.areas))
        assert abs(ps.offsets[j] + 4.0 * ps.normals[j][2]) < 0.005 and abs(ps.normals[j][2]) > 0.9999
        assert (ps.labels[wall] == j).mean() > 0.95
    # Switched off, the filter is never run: the depth image goes to extraction as given.
    import reloc.extraction.pipeline as pipeline

    def refuse(*args, **kwargs):
        raise AssertionError("the flying-pixel filter ran while switched off")

    monkeypatch.setattr(pipeline, "drop_flying_pixels", refuse)
    again = PlaneExtractor(ExtractionParams()).extract(frame).planes
    assert np.array_equal(again.labels, off.labels)
