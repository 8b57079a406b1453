"""``reloc plot``: each picture is a PNG of the requested size made from small files like the commands write; what
the pictures show is read back from the files (outcome kinds, panels, percentiles); bad files are named."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("matplotlib", reason="pictures need the viz extra (matplotlib)")

import sim  # noqa: E402
from PIL import Image  # noqa: E402
from sim.ground_truth import scene_planes  # noqa: E402
from sim.scenes import make_scene  # noqa: E402
from sim.writer import write_sequence  # noqa: E402

from reloc import transforms as tf  # noqa: E402
from reloc.cli import main  # noqa: E402
from reloc.mapping import PlaneMap, save_map  # noqa: E402
from reloc.viz import eval_panels, latency_data, read_results, result_kinds, stats_from_samples  # noqa: E402


def _png_size(path):
    assert path.is_file() and path.stat().st_size > 1000
    with Image.open(path) as im:
        assert im.format == "PNG"
        return im.size


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A map of the scene's exact planes, a short sequence of it, and locate results with every kind of outcome."""
    root = tmp_path_factory.mktemp("plot")
    scene = make_scene("living_room")
    planes, _ = scene_planes(scene)
    map_path = save_map(root / "map.npz", PlaneMap(planes, np.ones(len(planes), np.int64)))
    frames = sim.simulate_frames(scene, "robot", 8, noise="none", camera="kinect", seed=3, width=160, height=120)
    seq = root / "seq"
    write_sequence(frames, scene, seq)
    T = [f.T_world_cam for f in frames]
    wrong = T[3] @ tf.transform_from_rotation_translation(np.eye(3), np.array([0.6, 0.0, 0.0]))
    records = [
        {"frame": 2, "status": "relocalized", "reason": "", "T_map_cam": T[2].tolist(), "score": 1.0,
         "timings_ms": {"extraction": 3.0, "submap": 9.0, "select": 1.0, "verify": 0.5, "total": 2.0}},
        {"frame": 3, "status": "relocalized", "reason": "", "T_map_cam": wrong.tolist(), "score": 0.5,
         "timings_ms": {"extraction": 3.5, "submap": 8.0, "select": 1.5, "verify": 0.7, "total": 2.5}},
        {"frame": 5, "status": "rejected", "reason": "too few planes", "T_map_cam": None, "score": None,
         "timings_ms": {"extraction": 2.5, "submap": 7.0, "select": 0.5, "verify": 0.2, "total": 0.9}},
        {"frame": 7, "status": "error", "reason": "cannot read", "T_map_cam": None, "score": None},
    ]
    results = root / "results.jsonl"
    results.write_text("".join(json.dumps(r) + "\n" for r in records))
    return {"root": root, "map": map_path, "seq": seq, "results": results, "T": T}


def test_results_are_classified_against_ground_truth(files):
    records = read_results(files["results"])
    truth = {i: files["T"][i] for i in range(8)}
    kinds = [k for k, _ in result_kinds(records, truth)]
    assert kinds == ["right", "wrong", "rejected", "error"]
    assert result_kinds(records, truth)[0][1] == pytest.approx((0.0, 0.0), abs=1e-6)
    assert result_kinds(records, truth)[1][1][0] == pytest.approx(0.6, abs=1e-9)
    assert [k for k, _ in result_kinds(records)][:2] == ["relocalized", "relocalized"]  # nothing to check against


def test_plot_map_alone_with_results_and_with_a_submap(files, tmp_path, capsys):
    out = tmp_path / "map.png"
    assert main(["plot", "map", str(files["map"]), "-o", str(out), "--width", "400", "--height", "300"]) == 0
    assert _png_size(out) == (400, 300)
    out = tmp_path / "results.png"
    assert main(["plot", "map", str(files["map"]), "--results", str(files["results"]), "--truth", str(files["seq"]),
                 "-o", str(out), "--width", "520", "--height", "410"]) == 0
    assert _png_size(out) == (520, 410)
    out = tmp_path / "submap.png"
    assert main(["plot", "map", str(files["map"]), "--submap", str(files["seq"]), "--frame", "5", "--window", "3",
                 "--source", "oracle", "--results", str(files["results"]), "-o", str(out), "--width", "450",
                 "--height", "380"]) == 0
    assert "rejected" in capsys.readouterr().out  # the estimate of frame 5 came from the results file
    assert _png_size(out) == (450, 380)


def test_plot_frame(files, tmp_path, capsys):
    out = tmp_path / "frame.png"
    assert main(["plot", "frame", str(files["seq"]), "--index", "-1", "--source", "oracle", "-o", str(out),
                 "--width", "700", "--height", "260"]) == 0
    assert _png_size(out) == (700, 260)
    # --map: the config the map recorded; a map without one is named.
    from reloc.commands.map_cmd import config_sections
    from reloc.config import Config
    from reloc.mapping import load_map

    plain = load_map(files["map"])
    with_cfg = save_map(tmp_path / "cfg.npz", PlaneMap(plain.planes, plain.observations,
                                                       meta={"config": config_sections(Config())}))
    out2 = tmp_path / "frame2.png"
    assert main(["plot", "frame", str(files["seq"]), "--index", "2", "--map", str(with_cfg), "-o", str(out2),
                 "--width", "600", "--height", "240"]) == 0
    assert _png_size(out2) == (600, 240)
    assert main(["plot", "frame", str(files["seq"]), "--index", "2", "--map", str(files["map"]), "-o",
                 str(out2)]) == 2
    assert f"{files['map']}: the map records no config" in capsys.readouterr().err


def test_plot_frame_and_submap_extract_with_the_sequences_noise_law(tmp_path, capsys):
    """A stereo sequence of ``reloc sim`` stores its noise law; ``reloc plot frame`` (and ``plot map --submap``)
    extracted with the config as loaded (the Kinect law, no layer merge), so the picture showed other planes than
    map build and locate use."""
    from reloc.commands.map_cmd import sequence_config, sequence_plane_source
    from reloc.config import load_config
    from drivers.readers import open_sequence

    seq = tmp_path / "stereo"
    assert main(["sim", "living_room", "--noise", "stereo", "--camera", "oak-d", "--width", "320", "--height", "200",
                 "--frames", "3", "--out", str(seq)]) == 0
    cfg = sequence_config(load_config(None), str(seq), quiet=True)
    assert cfg.extraction.noise_model == "stereo"
    expected = len(sequence_plane_source(str(seq), "extraction", cfg)(open_sequence(seq)[0]))
    plain = len(sequence_plane_source(str(seq), "extraction", load_config(None))(open_sequence(seq)[0]))
    assert plain != expected  # the two laws differ on this frame: the test can tell them apart
    capsys.readouterr()
    out = tmp_path / "frame.png"
    assert main(["plot", "frame", str(seq), "--index", "0", "-o", str(out), "--width", "500", "--height", "200"]) == 0
    assert f"({expected} planes, extraction)" in capsys.readouterr().out


def test_plot_latency_table8_of_a_live_profile(tmp_path):
    """A live profile's "other" and "total" rows have a total but no percentiles (the loop's threads overlap):
    ``reloc plot latency --table8`` failed on them (min of an empty array); they are left out of the picture."""
    from reloc.commands.profile_cmd import EXTRACT_STAGES, _plain, profile_report
    from reloc.profiling import Profiler

    prof = Profiler(window=1000)
    for i in range(20):
        t = i * 33_000_000
        prof.record("capture.wait", t, 30_000_000)
        prof.record("extract", t, 20_000_000)
        prof.add_timings_ms({s: 20 / len(EXTRACT_STAGES) for s in EXTRACT_STAGES}, "extract.", t + 20_000_000)
        prof.record("submap", t, 1_000_000)
        prof.record("latency.capture_to_planes", t, 25_000_000)
        if i % 5 == 0:
            prof.record("reloc", t, 50_000_000)
            prof.add_timings_ms({"prepare": 10.0, "select": 10.0, "verify": 20.0, "decide": 10.0}, "reloc.",
                                t + 50_000_000)
    doc = _plain(profile_report(prof, total_stage=None))
    assert doc["table8"]["total"]["p50_ms"] is None and doc["table8"]["total"]["total_ms"] > 0
    assert doc["stages"]["capture.wait"]["share"] is None  # a wait has no share of the work
    f = tmp_path / "live.json"
    f.write_text(json.dumps(doc, allow_nan=False))
    out = tmp_path / "table8.png"
    assert main(["plot", "latency", str(f), "--table8", "-o", str(out), "--width", "800", "--height", "400"]) == 0
    assert _png_size(out) == (800, 400)


def _summary(name, tp, tn, fp, fn):
    return {"name": name, "TP": tp, "TN": tn, "FP": fp, "FN": fn, "precision": tp / (tp + fp) if tp + fp else None,
            "recall": tp / (tp + fn) if tp + fn else None}


def test_eval_panels_from_each_writer():
    ev = {"spec": {"plane_source": "oracle", "noise": "kinect"},
          "tables": {"Ours": [_summary("office", 8, 10, 0, 2), _summary("all", 8, 10, 0, 2)]}}
    (panel,) = eval_panels(ev)
    assert [r["name"] for r in panel.rows] == ["office", "all"] and panel.rows[0]["recall"] == pytest.approx(0.8)
    ablation = {"tables": {"Ours": [_summary("office", 8, 10, 0, 2)], "VR-NO": [_summary("office", 1, 10, 0, 9)],
                           "by_method": [_summary("Ours", 8, 10, 0, 2), _summary("VR-NO", 1, 10, 0, 9)]}}
    panels = eval_panels(ablation)
    assert [r["name"] for r in panels[0].rows] == ["Ours", "VR-NO"] and panels[0].rows[1]["recall"] == 0.1
    bench = {"results": {"sources": {
        "oracle/kinect/ours": {"per_scene": [_summary("office", 5, 5, 0, 0)], "total": _summary("all", 5, 5, 0, 0)},
        "oracle/kinect/paper settings": {"per_scene": [_summary("office", 5, 2, 3, 0)],
                                         "total": _summary("all", 5, 2, 3, 0)}},
        "ablation": {"Ours": _summary("all", 5, 5, 0, 0)}}}
    panels = eval_panels(bench)
    assert len(panels) == 3 and panels[1].rows[1]["precision"] == pytest.approx(5 / 8)
    demo = {"spec": {"scene": "office"}, "counts": {}, "outcomes": [
        {"query": "office/robot/0", "positive": True, "label": "TP"},
        {"query": "office/handheld/0", "positive": True, "label": "FN"},
        {"query": "living_room/robot/1", "positive": False, "label": "TN"}]}
    rows = {r["name"]: r for r in eval_panels(demo)[0].rows}
    assert rows["robot queries"]["TP"] == 1 and rows["handheld queries"]["recall"] == 0.0
    assert rows["negatives (living_room)"]["TN"] == 1 and rows["all"]["recall"] == 0.5
    with pytest.raises(ValueError, match="expected the JSON of reloc eval"):
        eval_panels({"something": 1})


def test_plot_eval(tmp_path):
    ev = {"tables": {"Ours": [_summary("office", 8, 10, 0, 2), _summary("corridor", 0, 10, 1, 3),
                              _summary("all", 8, 20, 1, 5)]}}
    f = tmp_path / "eval.json"
    f.write_text(json.dumps(ev))
    out = tmp_path / "eval.png"
    assert main(["plot", "eval", str(f), "-o", str(out), "--width", "800", "--height", "300"]) == 0
    assert _png_size(out) == (800, 300)


def test_latency_stats_and_sources():
    rng = np.random.default_rng(0)
    samples = {"extract": rng.gamma(4.0, 5.0, 500), "reloc": rng.gamma(2.0, 2.0, 500)}
    stats = stats_from_samples({k: v.tolist() for k, v in samples.items()})
    np.testing.assert_allclose(stats["extract"]["p95_ms"], np.percentile(samples["extract"], 95))
    total = samples["extract"].sum() + samples["reloc"].sum()
    assert stats["reloc"]["share"] == pytest.approx(samples["reloc"].sum() / total)
    lat = latency_data({"stages": stats, "samples_ms": {k: v.tolist() for k, v in samples.items()}, "compile_s": 2})
    assert lat.compile_s == 2.0 and lat.samples_ms["reloc"].shape == (500,)
    run = latency_data({"latency_ms": {"extract": stats["extract"]},
                        "end_to_end_ms": {"capture_to_planes": stats["reloc"], "capture_to_pose": None}})
    assert set(run.stats) == {"extract", "latency.capture_to_planes"} and not run.samples_ms
    with pytest.raises(ValueError, match=r"stages\['extract'\]: expected p50_ms"):
        latency_data({"stages": {"extract": {"count": 3}}})


def test_plot_latency_from_a_profile_a_run_summary_and_locate_results(files, tmp_path):
    rng = np.random.default_rng(1)
    samples = {"extract": rng.gamma(4.0, 5.0, 300), "reloc": np.r_[np.zeros(20), rng.lognormal(0, 1.5, 280)]}
    prof = {"stages": stats_from_samples({k: v.tolist() for k, v in samples.items()}),
            "samples_ms": {k: v.tolist() for k, v in samples.items()}, "compile_s": 1.5}
    f = tmp_path / "profile.json"
    f.write_text(json.dumps(prof))
    out = tmp_path / "lat.png"
    assert main(["plot", "latency", str(f), "-o", str(out), "--width", "900", "--height", "350"]) == 0
    assert _png_size(out) == (900, 350)
    summary = tmp_path / "run.json"
    summary.write_text(json.dumps({"latency_ms": prof["stages"], "end_to_end_ms": {}}))
    assert main(["plot", "latency", str(summary), "-o", str(out), "--width", "600", "--height", "240"]) == 0
    assert _png_size(out) == (600, 240)
    assert main(["plot", "latency", str(files["results"]), "-o", str(out), "--width", "640", "--height", "480",
                 "--stages", "submap,total"]) == 0
    assert _png_size(out) == (640, 480)


def test_bad_files_are_named(files, tmp_path, capsys):
    bad = tmp_path / "eval.json"
    bad.write_text("{not json")
    assert main(["plot", "eval", str(bad), "-o", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "not JSON" in err
    bad.write_text(json.dumps({"stages": 3}))
    assert main(["plot", "latency", str(bad), "-o", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "stages" in err
    not_map = tmp_path / "map.npz"
    not_map.write_bytes(b"nope")
    assert main(["plot", "map", str(not_map), "-o", str(tmp_path / "x.png")]) == 2
    assert str(not_map) in capsys.readouterr().err
    lines = tmp_path / "results.jsonl"
    lines.write_text('{"frame": 1, "status": "relocalized", "T_map_cam": [[1, 0], [0, 1]]}\n')
    assert main(["plot", "map", str(files["map"]), "--results", str(lines), "-o", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert f"{lines}:1" in err and "T_map_cam" in err
    # A frame out of range names the option it came from (each said --frames, which these commands do not have).
    assert main(["plot", "frame", str(files["seq"]), "--index", "1000", "-o", str(tmp_path / "x.png")]) == 2
    assert "Invalid value for --index: index 1000 outside the" in capsys.readouterr().err
    assert main(["plot", "map", str(files["map"]), "--submap", str(files["seq"]), "--frame", "1000",
                 "-o", str(tmp_path / "x.png")]) == 2
    assert "Invalid value for --frame: index 1000 outside the" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()


def test_missing_matplotlib_names_the_extra(files, tmp_path, capsys, monkeypatch):
    import reloc.viz._mpl as mpl

    def missing():
        raise ImportError("No module named 'matplotlib'")

    monkeypatch.setattr(mpl, "require_matplotlib", missing)
    assert main(["plot", "map", str(files["map"]), "-o", str(tmp_path / "x.png")]) == 1
    assert "pip install -e '.[viz]'" in capsys.readouterr().err


def test_demo_plots_one_of_each(tmp_path):
    from reloc.demo import DemoSpec, run_demo
    from reloc.viz.demo_plots import save_demo_plots

    spec = DemoSpec(map_trajectories=(("robot", 120), ("handheld", 120)), queries_per_kind=1, negatives=1,
                    window_frames=10, width=160, height=120, plane_source="oracle")
    kept = {}
    result = run_demo(spec, keep=kept)
    assert len(kept["queries"]) == len(result["outcomes"]) == 3
    written = save_demo_plots(result, kept, tmp_path / "plots")
    names = sorted(p.name for p in written)
    assert names == ["eval_bars.png", "frame_planes.png", "latency_hist.png", "map_submap.png", "reloc_results.png"]
    sizes = {p.name: _png_size(p) for p in written}
    assert sizes["frame_planes.png"] == (1500, 560) and sizes["map_submap.png"] == (1000, 900)
    assert sizes["reloc_results.png"] == (1100, 900) and sizes["eval_bars.png"][0] == 1300


def test_rerun_recording_of_a_frame_a_map_and_a_query(files, tmp_path):
    pytest.importorskip("rerun", reason="--rerun needs the optional rerun-sdk package")
    from drivers.readers import open_sequence
    from reloc.mapping import load_map
    from reloc.viz.rerun_log import log_frame, log_map, log_query, open_recording
    from sim.ground_truth import visible_planes

    seq = open_sequence(files["seq"])
    frame = seq[4]
    planes = visible_planes(frame, make_scene("living_room"))
    out = tmp_path / "demo.rrd"
    rec = open_recording(out)
    log_map(rec, load_map(files["map"]).planes)
    log_frame(rec, frame, planes)
    log_query(rec, 0, "q0", planes, "relocalized", frame.T_world_cam, frame.T_world_cam)
    log_query(rec, 1, "q1", planes, "rejected", None, frame.T_world_cam)
    rec.flush()
    rec.disconnect()
    assert out.stat().st_size > 10_000  # the map's points alone are ~100 kB
    with pytest.raises(ValueError, match=r"\.rrd"):
        open_recording(tmp_path / "x.png")


def test_missing_rerun_says_how_to_install(monkeypatch, tmp_path):
    import sys

    from reloc.viz.rerun_log import open_recording

    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun -> ImportError, installed or not
    with pytest.raises(ImportError, match="pip install rerun-sdk"):
        open_recording(tmp_path / "x.rrd")
