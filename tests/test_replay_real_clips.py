"""Replay of every real clip in ../shared/data/real/, whole: the frame count, intrinsics, poses and gravity the
reader gives, through the frame-source interface the live loop uses (and the counts the datasets have)."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.readers import open_sequence
from drivers.source import check_frame_contract, open_source

# clip -> (frames, frames with a pose, frames with gravity): what the clips hold (see their README).
CLIPS = {
    "tum_fr1_xyz": (37, 37, 37),
    "tum_fr2_desk": (50, 50, 0),
    "icl_nuim_living_room": (5, 5, 0),
    "cape_single_frame": (1, 0, 0),
}


@pytest.mark.parametrize("clip", sorted(CLIPS))
def test_replay_of_a_whole_real_clip(real_data, clip):
    n, n_pose, n_gravity = CLIPS[clip]
    seq = open_sequence(real_data / clip)
    with open_source(f"replay:{real_data / clip}", rate="fast") as src:
        assert src.intrinsics == seq.intrinsics
        frames = list(src)
    assert len(frames) == len(seq) == n
    check_frame_contract(frames, seq.intrinsics)
    assert sum(f.T_world_cam is not None for f in frames) == n_pose
    assert sum(f.gravity_cam is not None for f in frames) == n_gravity
    for i, f in enumerate(frames):
        if f.T_world_cam is not None:
            np.testing.assert_array_equal(f.T_world_cam, seq.T_world_cam[i])
            assert f.pose_source == "groundtruth"
        np.testing.assert_array_equal(np.isfinite(f.depth_m), np.isfinite(seq[i].depth_m))
