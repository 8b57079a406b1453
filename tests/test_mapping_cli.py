"""The commands: reloc map build / map info / locate on a short simulated sequence."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

import sim
from reloc.cli import main
from reloc.mapping import load_map
from reloc.transforms import pose_error
from sim.scenes import make_scene
from sim.writer import write_sequence


@pytest.fixture(scope="module")
def office_sequence(tmp_path_factory):
    out = tmp_path_factory.mktemp("seq") / "office"
    scene = make_scene("office")
    frames = sim.simulate_frames(scene, "handheld", 240, noise="kinect", camera="kinect", seed=5, width=160,
                                 height=120)
    write_sequence(frames, scene, out)
    return out


@pytest.mark.parametrize("source", ["oracle", "extraction"])
def test_map_build_and_info(office_sequence, tmp_path, capsys, source):
    out = tmp_path / f"{source}.npz"
    assert main(["map", "build", str(office_sequence), "-o", str(out), "--source", source, "--quiet"]) == 0
    said = capsys.readouterr().out
    assert "planes" in said and "keyframes" in said
    pm = load_map(out)
    c = pm.consistency()
    # Planes fused across two surfaces are reported when the map is built; the simulator's exact planes have none.
    assert ("more than 6 cm off them" in said) == (c["bent_planes"] > 0)
    assert source == "extraction" or c == {"samples_off_plane_fraction": 0.0, "bent_planes": 0, "bent_area_m2": 0.0}
    assert len(pm) >= 8 and pm.meta["plane_source"] == source and pm.meta["frame_count"] == 240
    assert len(pm.free_keys) > 0 and (tmp_path / f"{source}.npz.config.yaml").is_file()
    assert main(["map", "info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["summary"]["planes"] == len(pm) and info["meta"]["format_version"] == 1
    assert {k: info["summary"][k] for k in c} == c


def test_map_info_names_a_bad_file(tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a map")
    assert main(["map", "info", str(bad)]) == 2
    assert str(bad) in capsys.readouterr().err


def test_locate_writes_one_line_per_query(office_sequence, tmp_path):
    map_path = tmp_path / "m.npz"
    assert main(["map", "build", str(office_sequence), "-o", str(map_path), "--quiet"]) == 0
    results = tmp_path / "results.jsonl"
    assert main(["locate", "--map", str(map_path), str(office_sequence), "--frames", "120:240", "--every", "30",
                 "--window", "20", "--stride", "3", "-o", str(results), "--quiet"]) == 0
    lines = [json.loads(x) for x in results.read_text().splitlines()]
    assert [x["frame"] for x in lines] == [120, 150, 180, 210]
    from drivers.readers import open_sequence

    seq = open_sequence(office_sequence)
    for x in lines:
        assert set(x) >= {"frame", "stamp_ns", "status", "reason", "T_map_cam", "score", "matched_planes",
                          "timings_ms"}
        # The sequence's own (exact) poses are the odometry: the check leaves few of a window's frames out.
        assert x["window_frames"] == 20 and 0 <= x["frames_left_out"] <= 2
        assert x["stamp_ns"] == int(seq.stamps_ns[x["frame"]])
        assert x["status"] in ("relocalized", "rejected")
        assert {"extraction", "submap", "select", "verify", "total"} <= set(x["timings_ms"])
        if x["status"] == "relocalized":
            # Same sequence for map and queries: the map frame is the sequence's world frame.
            t_err, r_err = pose_error(np.array(x["T_map_cam"]), seq.T_world_cam[x["frame"]])
            assert t_err < 0.1 and r_err < 1.0
            # With its covariance: symmetric, positive, a translation spread under the 0.1 m the answers keep to.
            cov = np.array(x["covariance"])
            assert cov.shape == (6, 6) and np.allclose(cov, cov.T) and np.linalg.eigvalsh(cov)[0] > 0
            assert np.trace(cov[:3, :3]) < 0.1**2
        else:
            assert x["T_map_cam"] is None and x["covariance"] is None and x["reason"]
    assert sum(x["status"] == "relocalized" for x in lines) >= 2


def test_locate_grows_a_window_that_cannot_pin_a_pose(office_sequence, tmp_path, capsys):
    map_path = tmp_path / "m.npz"
    assert main(["map", "build", str(office_sequence), "-o", str(map_path), "--quiet"]) == 0
    from drivers.readers import open_sequence

    seq = open_sequence(office_sequence)

    def run(*extra):
        results = tmp_path / "results.jsonl"
        assert main(["locate", "--map", str(map_path), str(office_sequence), "--frames", "120:240", "--every", "30",
                     "--window", "1", "--stride", "3", "--out", str(results), "--quiet", *extra]) == 0
        return {x["frame"]: x for x in map(json.loads, results.read_text().splitlines())}

    fixed, grown = run(), run("--max-window", "30")
    # Single frames: at frame 120 no pose matches more than 4 planes (5 needed), frame 210 sees one plane.
    statuses = [fixed[f]["status"] for f in (120, 150, 180, 210)]
    assert statuses == ["rejected", "relocalized", "relocalized", "rejected"]
    assert all(x["window_frames"] == 1 for x in fixed.values())
    # Grown back in time (3 frames apart) where a frame cannot pin a pose (of frame 180's 9 planes 4 have 0.5 m^2),
    # and then relocalized right.
    assert [grown[f]["window_frames"] > 1 for f in (120, 150, 180, 210)] == [True, False, True, True]
    assert all(x["window_frames"] <= 30 for x in grown.values())
    for f, x in grown.items():
        assert x["status"] == "relocalized", x["reason"]
        t_err, r_err = pose_error(np.array(x["T_map_cam"]), seq.T_world_cam[f])
        assert t_err < 0.1 and r_err < 1.0
    assert {f: x["status"] for f, x in run("--max-window", "0").items()} == {f: x["status"] for f, x in fixed.items()}
    capsys.readouterr()
    assert main(["locate", "--map", str(map_path), str(office_sequence), "--window", "4", "--max-window", "2",
                 "--out", str(tmp_path / "r.jsonl"), "--quiet"]) == 2
    assert "expected 0 or at least the window (4 frames), got 2" in capsys.readouterr().err


def test_locate_checks_each_query_at_the_sequences_own_pose(office_sequence, tmp_path, capsys):
    """--check-poses: the answer's error against the sequence's pose, and whether that pose is identifiable (the map
    confirms it as locate would accept it); every answered view here is. --explain writes each query's account,
    its pose error the one in the JSON line."""
    map_path = tmp_path / "m.npz"
    assert main(["map", "build", str(office_sequence), "-o", str(map_path), "--quiet"]) == 0
    capsys.readouterr()
    results, accounts = tmp_path / "results.jsonl", tmp_path / "why.txt"
    assert main(["locate", "--map", str(map_path), str(office_sequence), "--frames", "120:240", "--every", "30",
                 "--window", "20", "--stride", "3", "--out", str(results), "--check-poses", "--quiet",
                 "--explain", str(accounts)]) == 0
    lines = [json.loads(x) for x in results.read_text().splitlines()]
    told = accounts.read_text().split("\n\n== ")
    assert len(told) == len(lines)
    for x, text in zip(lines, told):
        assert text.lstrip("= ").startswith(f"frame {x['frame']} (stamp_ns {x['stamp_ns']})\nresult: {x['status']}")
        if x["status"] == "relocalized":
            assert f"pose error {100 * x['truth']['translation_error_m']:.1f} cm" in text
        want = ("identifiable (the map confirms it as locate would accept it)" if x["truth"]["identifiable"]
                else f"not identifiable ({x['truth']['reason']})")
        assert text.rstrip().splitlines()[-1] == "the true pose: " + want  # the check above, not made again
    from drivers.readers import open_sequence

    seq = open_sequence(office_sequence)
    for x in lines:
        truth = x["truth"]
        assert isinstance(truth["identifiable"], bool) and (truth["identifiable"] or truth["reason"])
        if x["status"] == "relocalized":
            t_err, r_err = pose_error(np.array(x["T_map_cam"]), seq.T_world_cam[x["frame"]])
            assert truth["translation_error_m"] == pytest.approx(t_err, abs=1e-6) and t_err < 0.1
            assert truth["rotation_error_deg"] == pytest.approx(r_err, abs=1e-6)
            assert truth["identifiable"]
        else:
            assert truth["translation_error_m"] is None
    n = sum(x["truth"]["identifiable"] for x in lines)
    assert n >= sum(x["status"] == "relocalized" for x in lines) >= 2
    assert f"{n} identifiable at the sequence's poses" in capsys.readouterr().out


def test_frame_ranges_that_select_nothing_are_errors():
    import click

    from reloc.commands.map_cmd import parse_frames

    assert parse_frames("2:5", 10) == range(2, 5) and parse_frames(":", 10) == range(10)
    assert parse_frames("-3:", 10) == range(7, 10) and parse_frames("8:99", 10) == range(8, 10)
    assert parse_frames("-1", 10) == range(9, 10) and parse_frames(None, 4) == range(4)
    for bad, said in (("5:2", "selects none of the 10 frames"), ("10:20", "selects none"),
                      ("10", "outside the 10 frames"), ("a:b", "expected a:b or an index")):
        with pytest.raises(click.BadParameter, match=said):
            parse_frames(bad, 10)


def test_map_too_small_to_relocalize_in_says_why(office_sequence, tmp_path, capsys):
    out = tmp_path / "tiny.npz"
    # Two frames make at most two keyframes: every plane is seen fewer than min_observations = 3 times.
    assert main(["map", "build", str(office_sequence), "-o", str(out), "--frames", "0:2", "--quiet"]) == 0
    captured = capsys.readouterr()
    assert "0 planes" in captured.out and len(load_map(out)) == 0
    assert "note: 0 planes are too few to relocalize in" in captured.err
    assert "mapping.min_observations = 3" in captured.err
    # A map that can be used says nothing of the kind.
    assert main(["map", "build", str(office_sequence), "-o", str(tmp_path / "ok.npz"), "--quiet"]) == 0
    assert "note:" not in capsys.readouterr().err


def test_a_sequences_stored_noise_law_is_used_unless_the_config_names_one(tmp_path, capsys):
    # `reloc sim` stores the law of its camera in sim.json (stereo, sigma_d / (f b) z^2 for the OAK-D class
    # camera); map build and planes extract with it (locate takes it the same way, sequence_config), and a map
    # records the law it was built with.
    seq = tmp_path / "stereo"
    assert main(["sim", "living_room", "--noise", "stereo", "--camera", "oak-d", "--width", "320", "--height", "200",
                 "--frames", "12", "--out", str(seq)]) == 0
    stored = json.loads((seq / "sim.json").read_text())["noise_law"]
    fx = float(yaml.safe_load((seq / "camera.yaml").read_text())["fx"])
    assert stored["model"] == "stereo" and abs(stored["coeff"] - 0.08 / (fx * 0.075)) < 1e-12
    capsys.readouterr()
    assert main(["map", "build", str(seq), "-o", str(tmp_path / "m.npz")]) == 0
    err = capsys.readouterr().err
    # The stereo law also brings the stereo camera's layer merge (ExtractionParams.layer_share), and says so.
    assert "depth noise: stereo" in err and "layers of its disparity steps are merged" in err
    ex = load_map(tmp_path / "m.npz").meta["config"]["extraction"]
    assert (ex["noise_model"], ex["noise_coeff"]) == ("stereo", stored["coeff"])
    assert main(["map", "info", str(tmp_path / "m.npz")]) == 0
    assert f"depth_noise: stereo {stored['coeff']:.4g}" in capsys.readouterr().out
    assert main(["planes", str(seq), "--frames", "0:2", "--out", str(tmp_path / "p.jsonl"), "--quiet"]) == 0
    assert "noise_model: stereo" in (tmp_path / "p.config.yaml").read_text()
    # A config that names a law keeps it.
    cfg = tmp_path / "kinect.yaml"
    cfg.write_text("extraction:\n  noise_model: kinect\n")
    assert main(["map", "build", str(seq), "-o", str(tmp_path / "k.npz"), "--config", str(cfg), "--quiet"]) == 0
    ex = load_map(tmp_path / "k.npz").meta["config"]["extraction"]
    assert (ex["noise_model"], ex["noise_coeff"]) == ("kinect", 1.425e-3)


def test_map_build_names_planes_fused_across_two_surfaces():
    from reloc.commands.map_cmd import bent_planes_note

    assert bent_planes_note({"bent_planes": 0, "bent_area_m2": 0.0, "samples_off_plane_fraction": 0.0}) is None
    note = bent_planes_note({"bent_planes": 2, "bent_area_m2": 4.9, "samples_off_plane_fraction": 0.0125})
    assert note.startswith("note: 2 planes (4.9 m^2) have more than 25% of their samples more than 6 cm off them")
    assert "1.2% of all samples" in note


def test_locate_and_planes_fail_when_every_frame_fails(office_sequence, tmp_path, capsys):
    """Every depth image unreadable: each frame's error is written, and the command no longer ends with exit 0."""
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(office_sequence, broken)
    for png in (broken / "depth").glob("*.png"):
        png.write_bytes(b"not a png")
    map_path = tmp_path / "m.npz"
    assert main(["map", "build", str(office_sequence), "-o", str(map_path), "--source", "oracle", "--quiet"]) == 0
    results = tmp_path / "results.jsonl"
    assert main(["locate", "--map", str(map_path), str(broken), "--frames", "0:3", "-o", str(results),
                 "--quiet"]) == 1
    lines = [json.loads(x) for x in results.read_text().splitlines()]
    assert len(lines) == 3 and all(x["status"] == "error" and "not a readable PNG" in x["reason"] for x in lines)
    assert "every query failed" in capsys.readouterr().err
    planes = tmp_path / "planes.jsonl"
    assert main(["planes", str(broken), "--frames", "0:3", "-o", str(planes), "--quiet"]) == 1
    assert len(planes.read_text().splitlines()) == 3 and "every frame failed (3)" in capsys.readouterr().err
