"""The soak's one false relocalization (0.141 m, 2.54 deg off, a 3-frame submap of 5 planes, score 0.62), rebuilt.

The camera pose of that record lies on the soak's figure-eight at 23.105 s of its 30 s period (the only point of the
path 0.141 m and 2.54 deg from the reported pose). There the simulator's exact planes of three frames, fused with
odometry a few millimetres and half a degree off, made a submap whose least-squares pose (2 cm off) no longer matched
its smallest plane; the relocalizer then fell back to the winning hypothesis's own three-plane pose, 0.14 m and
2.4 deg off, which matched all five planes within the loose tolerances and was accepted.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from firmware_bridge.host import planar_transform
from firmware_bridge.mcu_sim import PlanarPath
from reloc.camera import DepthFrame
from reloc.config import Config
from reloc.live.factory import SubmapFuser, load_plane_map, make_relocalizer, make_submap_fuser
from reloc.mapping import MappingParams
from reloc.transforms import pose_error
from sim.cameras import resolve_intrinsics
from sim.ground_truth import visible_planes
from sim.noise import make_noise
from sim.render import render
from sim.scenes import make_scene
from sim.trajectories import gravity_in_camera

FALSE_M, FALSE_DEG = 0.1, 2.0  # benchmarks/soak.py: a relocalized pose farther off than this is false
T_TRUTH_S = 23.105  # the soak record's camera pose on the path (seq 11442, firmware request 76)


@pytest.fixture(scope="module")
def soak_query():
    cfg = Config()
    T_base_cam = np.asarray(cfg.camera.T_base_cam, dtype=np.float64).reshape(4, 4)
    scene = make_scene("living_room")
    _, plane_map = load_plane_map("sim:living_room")
    path = PlanarPath(center_m=(3.0, 1.8), amplitude_m=(1.5, 1.0), period_s=30.0)  # as in benchmarks/soak.py
    intr = resolve_intrinsics("oak-d", 160, 100)
    noise = make_noise("stereo")
    times = [T_TRUTH_S - 2 / 30, T_TRUTH_S - 1 / 30, T_TRUTH_S]
    planes, poses = [], []
    for k, t in enumerate(times):
        T = path.T_map_base(t) @ T_base_cam
        depth, labels = render(scene, intr, T)
        depth, labels = noise.apply(depth, labels, intr, np.random.default_rng([0, k]))
        frame = DepthFrame(depth, intr, int(t * 1e9), k, T_world_cam=T, gravity_cam=gravity_in_camera(T),
                           pose_source="groundtruth", labels=labels)
        planes.append(visible_planes(frame, scene, noise="stereo"))
        poses.append(T)
    return make_relocalizer(plane_map, cfg), make_submap_fuser(cfg), planes, poses


def _locate(soak_query, poses, fuse=None):
    relocalizer, default_fuse, planes, true_poses = soak_query
    submap = (fuse or default_fuse)(planes, poses)
    res = relocalizer.locate(submap)
    if res.status != "relocalized":
        return res, len(submap), None
    return res, len(submap), pose_error(res.T_map_cam, true_poses[-1])  # (m, deg)


def test_exact_odometry_relocalizes_the_soak_submap_exactly(soak_query):
    res, n, err = _locate(soak_query, soak_query[3])
    assert n == 5 and res.status == "relocalized", res.reason
    assert err[0] < 1e-6 and err[1] < 1e-4


def _without_odometry_check():
    return SubmapFuser(replace(MappingParams.from_config(Config()), submap_check_sigmas=0.0))


def test_the_soak_false_relocalization_is_refused(soak_query):
    # The newest frame's odometry 8 mm and 0.45 deg off: the old code answered 0.141 m and 2.38 deg off.
    poses = list(soak_query[3])
    poses[-1] = planar_transform(-0.0082, -0.0086, math.radians(-0.45)) @ poses[-1]
    # The odometry check leaves older frames out (0.45 deg moves their planes' centroids, about 3 m away, by more
    # than 2 cm): what remains (4 planes) is refused, never answered 0.14 m off.
    fuse = SubmapFuser(MappingParams.from_config(Config()))
    res, n, err = _locate(soak_query, poses, fuse)
    assert fuse.stats["frames_left_out"] >= 1 and res.status != "relocalized", (fuse.stats, res.reason)
    assert err is None or (err[0] <= FALSE_M and err[1] <= FALSE_DEG), f"false relocalization {err}"
    # Without the check the three frames fuse into a displaced 5-plane submap; the matcher must refuse it.
    res, n, err = _locate(soak_query, poses, _without_odometry_check())
    assert n == 5
    assert err is None or (err[0] <= FALSE_M and err[1] <= FALSE_DEG), f"false relocalization {err}"
    # Refused because the least-squares pose over its planes keeps only 4 of 5: found after the decision (refined
    # pose does not verify) or, deciding over refined poses (tight_decision), before it (not enough explained).
    assert res.status != "relocalized", res.reason
    assert res.reason.startswith(("refined pose does not verify", "no pose explains enough: best 4 planes")), res.reason


def test_small_odometry_errors_give_no_false_relocalization(soak_query):
    # Odometry between the frames off by millimetres and tenths of a degree (of the size the soak's wheel odometry
    # and its interpolation can reach over 66 ms, and more): before the fix 12 of 150 such draws were false.
    rng = np.random.default_rng(2)
    true_poses = soak_query[3]
    accepted = 0
    for trial in range(24):
        dx, dy = rng.normal(0, 0.005, 2)
        P = planar_transform(dx, dy, rng.normal(0, math.radians(0.3)))
        poses = list(true_poses)
        if trial % 3 == 0:
            poses[-1] = P @ poses[-1]
        elif trial % 3 == 1:
            poses[0], poses[1] = P @ poses[0], P @ poses[1]
        else:
            poses[0] = P @ poses[0]
        res, _, err = _locate(soak_query, poses)
        if err is not None:
            accepted += 1
            assert err[0] <= FALSE_M and err[1] <= FALSE_DEG, f"trial {trial}: false relocalization {err}"
    assert accepted >= 8  # most of these submaps still relocalize (correctly)


def test_odometry_off_by_centimetres_and_degrees_gives_no_false_relocalization():
    """Windows of three frames at random places of the soak's path whose odometry is off by N(0, 2 cm) and
    N(0, 1.5 deg) (the newest frame's, the two older ones', or the oldest's): fused as they are, such a submap is a
    rigidly displaced copy of the truth that matches the map (about one in five was false over 150 draws); the
    odometry check leaves the disagreeing frames out, and none is false."""
    cfg = Config()
    T_base_cam = np.asarray(cfg.camera.T_base_cam, dtype=np.float64).reshape(4, 4)
    scene = make_scene("living_room")
    _, plane_map = load_plane_map("sim:living_room")
    path = PlanarPath(center_m=(3.0, 1.8), amplitude_m=(1.5, 1.0), period_s=30.0)
    intr = resolve_intrinsics("oak-d", 160, 100)
    noise = make_noise("stereo")
    relocalizer = make_relocalizer(plane_map, cfg)
    checked, unchecked = make_submap_fuser(cfg), _without_odometry_check()
    rng = np.random.default_rng(5)
    false = {"checked": 0, "unchecked": 0}
    correct = {"checked": 0, "unchecked": 0}
    for trial in range(30):
        t_end = rng.uniform(0.0, 30.0)
        planes, poses = [], []
        for k, t in enumerate((t_end - 2 / 30, t_end - 1 / 30, t_end)):
            T = path.T_map_base(t) @ T_base_cam
            depth, labels = render(scene, intr, T)
            depth, labels = noise.apply(depth, labels, intr, np.random.default_rng([trial, k]))
            frame = DepthFrame(depth, intr, int(t * 1e9), k, T_world_cam=T, gravity_cam=gravity_in_camera(T),
                               pose_source="groundtruth", labels=labels)
            planes.append(visible_planes(frame, scene, noise="stereo"))
            poses.append(T)
        P = planar_transform(*rng.normal(0.0, 0.02, 2), rng.normal(0.0, math.radians(1.5)))
        odometry = list(poses)
        for k in ((2,), (0, 1), (0,))[trial % 3]:
            odometry[k] = P @ odometry[k]
        for name, fuse in (("checked", checked), ("unchecked", unchecked)):
            res = relocalizer.locate(fuse(planes, odometry))
            if res.status == "relocalized":
                m, deg = pose_error(res.T_map_cam, poses[-1])
                ok = m <= FALSE_M and deg <= FALSE_DEG
                correct[name] += ok
                false[name] += not ok
    assert false["checked"] == 0, (false, correct)
    assert false["unchecked"] >= 2, (false, correct)  # the draws are hard: without the check some are false
    assert correct["checked"] >= 20, (false, correct)
