"""A sequence written by the simulator reads back with the same depths (within quantization), labels and poses."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

import sim
from drivers.depth_png import read_depth_png, read_label_png
from reloc.camera import Intrinsics
from reloc.transforms import pose_error, transform_from_tum
from sim.cameras import preset
from sim.cli import sim as sim_command
from sim.scenes import make_scene
from sim.writer import stamp_name, write_sequence


def _read_list(path):
    rows = []
    for line in path.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        rows.append(line.split())
    return rows


def test_written_sequence_reads_back(tmp_path):
    scene = make_scene("office")
    intr = preset("kinect").scaled(160, 120)
    frames = sim.simulate_frames(scene, "handheld", 5, noise="kinect", camera=intr, seed=2)
    summary = write_sequence(frames, scene, tmp_path / "seq", metadata={"seed": 2})
    out = tmp_path / "seq"
    assert summary.n_frames == 5 and summary.n_scene_planes == scene.n_planes

    cam = Intrinsics.from_dict(yaml.safe_load((out / "camera.yaml").read_text()))
    assert cam == intr
    depth_rows = _read_list(out / "depth.txt")
    gt_rows = _read_list(out / "groundtruth.txt")
    label_rows = _read_list(out / "labels.txt")
    grav_rows = _read_list(out / "gravity.txt")
    assert len(depth_rows) == len(gt_rows) == len(label_rows) == len(grav_rows) == 5
    for f, g in zip(frames, grav_rows):
        assert g[0] == stamp_name(f.stamp_ns)
        np.testing.assert_allclose(np.array(g[1:], dtype=np.float64), f.gravity_cam, atol=1e-8)
    for f, (ts, fname), gt, (_, lname) in zip(frames, depth_rows, gt_rows, label_rows):
        assert ts == stamp_name(f.stamp_ns) == gt[0]
        assert abs(float(ts) * 1e9 - f.stamp_ns) < 1e3
        depth = read_depth_png(out / fname, cam.depth_scale)
        ok = f.valid_mask
        assert np.array_equal(np.isfinite(depth), ok)
        assert np.abs(depth[ok] - f.depth_m[ok]).max() <= 0.5 / cam.depth_scale + 1e-6
        np.testing.assert_array_equal(read_label_png(out / lname), f.labels)
        T = transform_from_tum(np.array(gt[1:], dtype=np.float64))
        dt, dr = pose_error(T, f.T_world_cam)
        assert dt < 1e-8 and dr < 1e-6

    planes = json.loads((out / "planes.json").read_text())
    assert planes["scene"] == "office" and len(planes["planes"]) == scene.n_planes
    for p in planes["planes"]:
        row = scene.index_of(p["id"])
        np.testing.assert_allclose(p["normal"], scene.normals[row], atol=1e-12)
        for poly in p["polygons"]:
            v = np.array(poly)
            assert np.abs(v @ np.array(p["normal"]) + p["offset"]).max() < 1e-8
    meta = json.loads((out / "sim.json").read_text())
    assert meta["seed"] == 2 and meta["summary"]["n_frames"] == 5

    # A second write into the same folder must be asked for.
    with pytest.raises(ValueError, match="out_dir"):
        write_sequence(frames, scene, out)
    write_sequence(frames[:2], scene, out, overwrite=True)
    assert len(list((out / "depth").glob("*.png"))) == 2


def test_reader_if_present_agrees(tmp_path):
    readers = pytest.importorskip("drivers.readers", reason="drivers.readers (DRIVERS helper) not available yet")
    scene = make_scene("living_room")
    intr = preset("kinect").scaled(160, 120)
    frames = sim.simulate_frames(scene, "robot", 3, noise="none", camera=intr, seed=1)
    write_sequence(frames, scene, tmp_path / "seq")
    seq = readers.open_sequence(tmp_path / "seq")
    assert len(seq) == 3
    for f, g in zip(frames, seq):
        # One spelling for exact poses, whether they come from the simulator or from disk.
        assert f.pose_source == g.pose_source == "groundtruth"
        ok = f.valid_mask
        assert np.abs(np.nan_to_num(g.depth_m[ok]) - f.depth_m[ok]).max() <= 0.5 / intr.depth_scale + 1e-6
        dt, dr = pose_error(g.T_world_cam, f.T_world_cam)
        assert dt < 1e-6 and dr < 1e-4
        # The written sequence carries gravity (gravity.txt): world -z seen from the camera, as the frame had it.
        np.testing.assert_allclose(g.gravity_cam, f.gravity_cam, atol=1e-8)
        np.testing.assert_allclose(g.gravity_cam, f.T_world_cam[:3, :3].T @ [0.0, 0.0, -1.0], atol=1e-8)
    assert seq.has_gravity.all() and not seq.notes


def test_cli_writes_sequence(tmp_path):
    out = tmp_path / "cli"
    res = CliRunner().invoke(sim_command, [
        "living_room", "--trajectory", "random", "--frames", "3", "--seed", "4", "--noise", "tof",
        "--camera", "wide-tof", "--width", "80", "--height", "60", "--out", str(out),
    ])
    assert res.exit_code == 0, res.output
    assert "wrote 3 frames of living_room" in res.output
    assert len(_read_list(out / "groundtruth.txt")) == 3
    assert len(list((out / "depth").glob("*.png"))) == 3
    cam = yaml.safe_load((out / "camera.yaml").read_text())
    assert (cam["width"], cam["height"]) == (80, 60)
    # The same command twice without --overwrite is refused, with the reason.
    res = CliRunner().invoke(sim_command, ["living_room", "--frames", "2", "--out", str(out)])
    assert res.exit_code != 0


def test_a_sequence_written_over_another_keeps_nothing_of_it(tmp_path):
    """A recording written with overwrite over a simulated sequence reads back as itself: no label images asked of
    its frames (a leftover labels/ did), no scene planes and no simulator noise law (planes.json and sim.json did
    stay). The other way round, the simulator's sequence keeps no odometry.txt or recording.json of the recording."""
    from drivers.readers import noise_law_entry, open_sequence, read_noise_law
    from drivers.recorder import Recorder
    from reloc.camera import DepthFrame

    scene = make_scene("living_room")
    intr = preset("kinect").scaled(160, 120)
    out = tmp_path / "seq"
    write_sequence(sim.simulate_frames(scene, "robot", 3, noise="kinect", camera=intr, seed=1), scene, out,
                   metadata={"noise_law": noise_law_entry(("kinect", 1.425e-3))})  # as `reloc sim` stores it
    assert open_sequence(out).label_files is not None and read_noise_law(out) == ("kinect", 1.425e-3)
    rng = np.random.default_rng(2)
    with Recorder(out, overwrite=True) as rec:
        for i in range(2):
            rec.write(DepthFrame(rng.uniform(0.5, 4.0, intr.shape).astype(np.float32), intr, 10**9 + i * 33_333_333,
                                 seq=i, T_world_cam=np.eye(4), pose_source="odometry"))
    seq = open_sequence(out)
    assert len(seq) == 2 and seq.label_files is None and seq.planes_file is None and seq.pose_source == "odometry"
    assert read_noise_law(out) is None and not (out / "labels").exists() and not (out / "sim.json").exists()
    write_sequence(sim.simulate_frames(scene, "robot", 3, noise="none", camera=intr, seed=1), scene, out,
                   overwrite=True)
    seq = open_sequence(out)
    assert len(seq) == 3 and seq.pose_source == "groundtruth" and seq.label_files is not None
    assert not (out / "odometry.txt").exists() and not (out / "recording.json").exists()
