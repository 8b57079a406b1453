"""Each picture is a non-empty PNG of the requested pixel size, made from small simulated inputs."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib", reason="pictures need the viz extra (matplotlib)")

import sim  # noqa: E402
from PIL import Image  # noqa: E402
from sim.ground_truth import scene_planes, visible_planes  # noqa: E402
from sim.scenes import make_scene  # noqa: E402

from reloc.viz import plot_frame_planes, plot_map_topdown, topdown_basis  # noqa: E402


@pytest.fixture(scope="module")
def small():
    scene = make_scene("living_room")
    frames = sim.simulate_frames(scene, n_frames=3, width=160, height=120)
    return scene, frames


def _size(path):
    assert path.stat().st_size > 1000
    with Image.open(path) as im:
        return im.size


def test_frame_picture_has_the_requested_size(small, tmp_path):
    scene, frames = small
    planes = visible_planes(frames[1], scene)
    out = plot_frame_planes(frames[1], planes, tmp_path / "frame.png", width_px=640, height_px=300)
    assert _size(out) == (640, 300)


def test_frame_picture_rejects_labels_of_another_shape(small, tmp_path):
    scene, frames = small
    planes = visible_planes(frames[1], scene)
    from dataclasses import replace

    bad = replace(planes, labels=np.zeros((10, 10), np.int32))
    with pytest.raises(ValueError, match="labels"):
        plot_frame_planes(frames[1], bad, tmp_path / "x.png")


def test_map_picture_with_submap_and_truth(small, tmp_path):
    scene, frames = small
    plane_map, _ = scene_planes(scene)
    sub = visible_planes(frames[2], scene)
    T = frames[2].T_world_cam
    out = plot_map_topdown(plane_map, tmp_path / "map.png", submap=sub, T_map_cam=T, T_map_cam_gt=T,
                           width_px=500, height_px=400)
    assert _size(out) == (500, 400)


def test_topdown_basis_is_map_xy_for_gravity_down_and_orthonormal_otherwise():
    np.testing.assert_allclose(topdown_basis(np.array([0.0, 0.0, -1.0])), [[1, 0, 0], [0, 1, 0]])
    g = np.array([0.3, -0.2, -0.9])
    B = topdown_basis(g)
    np.testing.assert_allclose(B @ B.T, np.eye(2), atol=1e-12)
    np.testing.assert_allclose(B @ (g / np.linalg.norm(g)), 0.0, atol=1e-12)
    # Gravity along map x (it was NaN: x had nothing left across gravity) or near it.
    for g in ([1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.95, 0.1, -0.3]):
        g = np.asarray(g) / np.linalg.norm(g)
        B = topdown_basis(g)
        np.testing.assert_allclose(B @ B.T, np.eye(2), atol=1e-12)
        np.testing.assert_allclose(B @ g, 0.0, atol=1e-12)
    # Gravity +z (a z-down map): the picture's up is -y, and its axis says so (it said "map y").
    import matplotlib.pyplot as plt
    from reloc.viz.maps import finish_map_axes

    B = topdown_basis(np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(B, [[1, 0, 0], [0, -1, 0]])
    fig, ax = plt.subplots()
    finish_map_axes(ax, B)
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("map x [m]", "-map y [m]")
    plt.close(fig)
