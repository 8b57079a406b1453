"""`reloc record` end to end: a recording of a replay or of the simulator reads back as the same sequence."""

from __future__ import annotations

import json

import numpy as np

from drivers.readers import open_sequence
from reloc.cli import main


def test_record_a_replay(real_data, tmp_path, capsys):
    src = real_data / "icl_nuim_living_room"
    assert main(["record", "--camera", f"replay:{src}", "--out", str(tmp_path / "rec"), "--frames", "3"]) == 0
    assert "wrote 3 frames" in capsys.readouterr().out
    rec, orig = open_sequence(tmp_path / "rec"), open_sequence(src)
    assert len(rec) == 3 and rec.intrinsics == orig.intrinsics and rec.pose_source == "groundtruth"
    np.testing.assert_allclose(rec.T_world_cam, orig.T_world_cam[:3], atol=1e-8)
    np.testing.assert_array_equal(rec[2].depth_m, orig[2].depth_m)  # same depth scale: lossless
    # A second recording into the same folder needs --overwrite.
    assert main(["record", "--camera", f"replay:{src}", "--out", str(tmp_path / "rec"), "--frames", "1"]) == 2
    assert "already holds a sequence" in capsys.readouterr().err


def test_record_the_simulator_with_options(tmp_path, capsys):
    out = tmp_path / "sim"
    args = ["record", "--camera", "sim:office", "--out", str(out), "--frames", "2", "-o", "camera=kinect",
            "-o", "width=80", "-o", "height=60", "-o", "noise=none"]
    assert main(args) == 0
    seq = open_sequence(out)
    assert len(seq) == 2 and seq.intrinsics.width == 80 and seq.has_gravity.all() and seq.label_files
    frame = seq[1]
    np.testing.assert_allclose(frame.gravity_cam, frame.T_world_cam[:3, :3].T @ [0, 0, -1], atol=1e-8)


def test_a_recording_of_a_simulated_sequence_keeps_its_ground_truth_files(tmp_path):
    src, rec = tmp_path / "sim", tmp_path / "rec"
    assert main(["sim", "office", "--frames", "3", "--width", "80", "--height", "60", "-o", str(src)]) == 0
    assert main(["record", "--camera", f"replay:{src}", "--out", str(rec), "--frames", "2"]) == 0
    for name in ("planes.json", "sim.json"):
        assert (rec / name).read_text() == (src / name).read_text()
    # The simulated camera's noise law (Kinect, reloc sim's default) goes from sim.json to the new recording.
    assert json.loads((rec / "recording.json").read_text())["noise_law"] == {"model": "kinect", "coeff": 1.425e-3}
    assert open_sequence(rec).label_files  # and its label images
    planes = open_sequence(rec).scene_planes()
    assert planes and planes == open_sequence(src).scene_planes()


def test_record_errors(tmp_path, capsys):
    assert main(["record", "--camera", "webcam", "--out", str(tmp_path / "x")]) == 2
    assert "unknown frame source 'webcam'" in capsys.readouterr().err
    assert main(["record", "--camera", "sim", "--out", str(tmp_path / "x"), "-o", "bad"]) == 2
    assert "expected KEY=VALUE, got 'bad'" in capsys.readouterr().err


def test_options_a_source_cannot_take_are_refused_by_name(tmp_path, capsys):
    """Each escaped before: --config was silently ignored for every camera but oak; loop=fasle (any text) looped a
    replay forever; rates of 1e-300 Hz and sizes of 100,000 pixels ended in OverflowError and MemoryError."""
    config = tmp_path / "c.yaml"
    config.write_text("oak:\n  fps: 15.0\n")
    out = str(tmp_path / "r")
    cases = [
        (["--config", str(config)], "--config sets up OAK cameras"),
        (["-o", "loop=fasle"], "loop: expected true or false, got 'fasle'"),
        (["--rate", "1e-300"], "rate: expected 'recorded', 'fast' or a frame rate of 0.001 to 100000 Hz"),
        (["-o", "rate_hz=0.0000001"], "rate_hz: expected a frame rate of 0.001 to 100000 Hz"),
        (["-o", "width=100000", "-o", "height=100000"], "width: expected a whole number of pixels from 8 to 4096"),
    ]
    for extra, message in cases:
        assert main(["record", "--camera", "sim:living_room", "--out", out, "--frames", "2", *extra]) == 2, extra
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err
    assert main(["sim", "office", "--frames", "2", "--rate-hz", "1e-300", "-o", str(tmp_path / "s")]) == 2
    too_wide = ["--width", "100000", "--height", "60"]
    assert main(["sim", "office", "--frames", "2", *too_wide, "-o", str(tmp_path / "s")]) == 2
    assert not (tmp_path / "r").exists() and not (tmp_path / "s").exists()
