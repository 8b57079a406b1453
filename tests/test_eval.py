"""Evaluation: outcome counting, ambiguity labels, a short end-to-end run on the simulator, and the demo."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from reloc.evaluation.ambiguity import is_ambiguous, scene_symmetries
from reloc.evaluation.metrics import Outcome, classify, format_table, summarize
from reloc.evaluation.suite import quick_spec, run_suite


def test_classify_follows_the_paper():
    assert classify(True, False, True, (0.1, 2.0)) == "TP"
    assert classify(True, False, True, (0.3, 2.0)) == "FP"  # wrong pose
    assert classify(True, False, True, (0.1, 6.0)) == "FP"
    assert classify(True, False, False, None) == "FN"
    assert classify(False, False, False, None) == "TN"
    assert classify(False, False, True, None) == "FP"
    # A view that repeats elsewhere has no unique answer: refusing is right, any pose is a guess.
    assert classify(True, True, False, None) == "TN"
    assert classify(True, True, True, (0.0, 0.0)) == "FP"


def test_summary_counts_precision_recall_and_errors():
    def o(label, t=math.nan, r=math.nan, ms=2.0):
        return Outcome("s", "q", label != "TN", False, "x", "", label, t, r, ms, {"verify": 1.0})

    outs = [o("TP", 0.01, 0.1), o("TP", 0.03, 0.3), o("TP", 0.02, 0.2), o("FN"), o("TN"), o("FP")]
    s = summarize("s", outs)
    assert (s.TP, s.TN, s.FP, s.FN) == (3, 1, 1, 1)
    assert s.precision == pytest.approx(0.75) and s.recall == pytest.approx(0.75)
    assert s.median_translation_error_m == pytest.approx(0.02)
    assert s.median_rotation_error_deg == pytest.approx(0.2)
    assert s.mean_ms == pytest.approx(2.0) and s.stage_mean_ms == {"verify": 1.0}
    assert "75.00" in format_table([s])
    assert s.identifiable == 0 and math.isnan(s.recall_identifiable)  # nothing checked at its true pose


def test_recall_over_identifiable_queries_leaves_out_views_the_planes_cannot_pin_down():
    def o(label, identifiable, why=""):
        return Outcome("s", "q", label != "TN", False, "x", "", label, identifiable=identifiable,
                       identifiable_reason=why)

    outs = [o("TP", True), o("TP", True), o("FN", True), o("FN", False, "pose weakly constrained"),
            o("FN", False, "3 submap planes"), o("TN", None)]
    # Whether a symmetric twin of the true pose is confirmed too: for the identifiable ones only.
    outs = [replace(x, twin_confirmed=twin) for x, twin in zip(outs, (False, True, False, None, None, None))]
    s = summarize("s", outs)
    assert s.recall == pytest.approx(2 / 5)
    assert (s.identifiable, s.identified) == (3, 2) and s.recall_identifiable == pytest.approx(2 / 3)
    assert (s.unique, s.identified_unique) == (2, 1) and s.recall_unique == pytest.approx(1 / 2)
    row = format_table([s]).splitlines()[-1].split()
    assert row[8:12] == ["3", "66.67", "2", "50.00"]
    d = json.loads(json.dumps(s.to_dict()))
    assert d["identifiable"] == 3 and d["recall_identifiable"] == pytest.approx(0.666667)
    assert d["unique"] == 2 and d["recall_unique"] == pytest.approx(0.5)
    assert json.loads(json.dumps(outs[1].to_dict()))["twin_confirmed"] is True
    assert json.loads(json.dumps(outs[3].to_dict()))["identifiable_reason"] == "pose weakly constrained"
    # A positive answered with a wrong pose (FP) is in none of the recalls' populations: R_id stays at least R, and
    # the identifiable views are a share of TP + FN (with it counted, 2 identifiable of 1 gave R_id 0.5 < R = 1).
    s = summarize("s", [replace(o("TP", True), twin_confirmed=False), replace(o("FP", True), twin_confirmed=False)])
    assert s.recall == 1.0 and (s.identifiable, s.identified, s.unique) == (1, 1, 1)
    assert s.recall_identifiable == 1.0 and s.recall_unique == 1.0


def test_a_twin_of_the_true_pose_is_confirmed_where_the_map_holds_the_twin_room():
    """A view in one furnished office of a map that holds a second, identical office 7 m along x: the true pose
    moved 7 m (the twin) is confirmed as the truth is; moved the other way, or turned a quarter about the room's
    centre, it is not. In a map of the first office alone, no twin is."""
    from reloc.evaluation.metrics import identifiable, twin_confirmed
    from reloc.evaluation.synthetic import furnished_room, look_at, scene_planes, view_planes
    from reloc.matching import MatchingParams, Relocalizer

    def shifted(dx):
        S = np.eye(4)
        S[0, 3] = dx
        return S

    c, s_ = math.cos(math.pi / 2), math.sin(math.pi / 2)
    quarter = np.array([[c, -s_, 0, 3.0 - 3.0 * c + 2.5 * s_], [s_, c, 0, 2.5 - 3.0 * s_ - 2.5 * c], [0, 0, 1, 0],
                        [0, 0, 0, 1.0]])
    first = furnished_room("office")
    T = look_at((1.0, 1.0, 1.4), (4.5, 3.5, 0.8))
    sub = view_planes(first, T)
    twins = Relocalizer(scene_planes(first + furnished_room("office", origin=(7.0, 0.0))), MatchingParams())
    alone = Relocalizer(scene_planes(first), MatchingParams())
    assert identifiable(twins, sub, T)[0] and identifiable(alone, sub, T)[0]
    assert twin_confirmed(twins, sub, T, [shifted(7.0)])
    assert not twin_confirmed(twins, sub, T, [shifted(-7.0), quarter])
    assert not twin_confirmed(alone, sub, T, [shifted(7.0), shifted(-7.0), quarter])
    # reloc eval --explain says so, given the scene's symmetries.
    from reloc.evaluation.explain import explain_query

    assert "a symmetric twin of it is confirmed too" in explain_query(twins, sub, T, symmetries=[shifted(7.0)])
    assert "no symmetric twin of it is confirmed: unique" in explain_query(alone, sub, T, symmetries=[shifted(7.0)])
    assert "symmetric twin" not in explain_query(twins, sub, T)


def test_ambiguity_labels_come_from_the_scene_geometry():
    from sim.scenes import make_scene
    from sim.trajectories import pose_from

    sym = make_scene("symmetric_room")
    assert len(scene_symmetries(sym)) == 3
    for name in ("symmetric_room", "corridor", "meeting_rooms"):  # by name, as the evaluation asks: the same
        by_scene, by_name = scene_symmetries(make_scene(name)), scene_symmetries(name)
        assert len(by_scene) == len(by_name) > 0
        assert all(np.array_equal(a, b) for a, b in zip(by_scene, by_name))
    # In the middle of the four-fold symmetric room every view has a twin.
    assert is_ambiguous(sym, pose_from(3.0, 1.5, 1.4, 1.2, -0.2))
    living = make_scene("living_room")
    assert scene_symmetries(living) == []
    assert not is_ambiguous(living, pose_from(3.0, 2.0, 1.4, 0.5, -0.2))
    rooms = make_scene("meeting_rooms")
    # Looking at the table of the second meeting room, away from its door: identical to the first room's view.
    assert is_ambiguous(rooms, pose_from(5.12 + 2.5, 4.5, 1.4, math.pi / 2, -0.3))
    corridor = make_scene("corridor")
    # Looking across at a door (the y = 2 side at x = 9) from the corridor's middle: the view of the door at x = 12
    # on the other side, half a turn about (10.5, 1), is the same; so is the door at x = 15 one step of 6 m along.
    S = scene_symmetries(corridor)
    assert len(S) == 8 + 10
    view = pose_from(9.0, 0.6, 1.4, math.pi / 2, -0.1)
    assert is_ambiguous(corridor, view)
    half_turns = [s for s in S if s[0, 0] < 0]
    assert is_ambiguous(corridor, view, symmetries=half_turns)


def test_a_querys_history_starts_with_its_own_window_and_goes_further_back():
    from dataclasses import replace

    from sim.scenes import make_scene

    from reloc.evaluation.suite import extraction_for_sensor, make_plane_source, make_queries, query_history
    from reloc.mapping import MappingParams, build_submap

    # The living room's views have no twin; the meeting rooms' first views (at the first room's table) all do.
    for name, labelled in (("living_room", False), ("meeting_rooms", True)):
        spec = replace(quick_spec(plane_source="extraction"), scenes=(name,), queries_per_kind=2, window_frames=4,
                       query_spacing_frames=40)
        scene = make_scene(name)
        source = make_plane_source("extraction", scene, extraction=extraction_for_sensor(spec))
        queries = make_queries(scene, spec, source)
        assert [q.name for q in queries] == [f"{name}/{k}/{i}" for k in ("robot", "handheld") for i in (0, 1)]
        for q in queries:
            fetch, ambiguous = query_history(spec, q.name)
            sets, poses = fetch(spec.window_frames)
            again = build_submap(sets, poses, MappingParams())
            # The same frames, noise included: the same submap, to the bit.
            assert len(again) == len(q.submap) > 0
            assert np.array_equal(again.normals, q.submap.normals)
            assert np.array_equal(again.offsets, q.submap.offsets)
            assert np.array_equal(poses[-1], q.T_world_cam)
            assert ambiguous(spec.window_frames) == q.ambiguous == labelled
            # Further back: older frames first, the newest still the query's, as far as the trajectory goes (the
            # first query of each kind ends at frame 39, so 14 frames 3 apart; the second at 79, 27 frames).
            more, older = fetch(30)
            assert len(more) == (14, 27)[int(q.name[-1])]
            assert np.array_equal(older[-1], q.T_world_cam) and all(a is b for a, b in zip(more[-4:], sets))
    with pytest.raises(ValueError, match="no query 'office/robot/0'"):
        query_history(spec, "office/robot/0")
    with pytest.raises(ValueError, match="scene/kind/index"):
        query_history(spec, "meeting_rooms/drone/0")


@pytest.fixture(scope="module")
def quick_results():
    return run_suite(quick_spec(plane_source="extraction"))


def test_short_end_to_end_run_has_no_false_positive(quick_results):
    """Two scenes, extraction on every frame, 16 positives and 12 negatives (fixed seeds): P = 1.0, R >= 0.75."""
    outcomes = [o for r in quick_results for o in r.outcomes]
    s = summarize("all", outcomes)
    assert s.TP + s.FN == 16 and s.TN + s.FP == 12
    assert s.FP == 0
    assert s.recall >= 0.75
    # Poses of the true positives are accurate to centimetres.
    assert s.median_translation_error_m < 0.03 and s.median_rotation_error_deg < 0.5
    for o in outcomes:
        if o.label == "TP":
            assert o.translation_error_m < 0.1 and o.rotation_error_deg < 1.0
        if not o.positive:
            assert o.status == "rejected" and o.reason
    # Every positive, unambiguous query is checked at its true pose; a true positive's truth holds (its refined pose
    # is the one found), and a query whose truth does not hold says why.
    checked = [o for o in outcomes if o.positive and not o.ambiguous]
    assert checked and all(o.identifiable is not None for o in checked)
    assert all(o.identifiable is None for o in outcomes if not o.positive)
    assert all(o.identifiable for o in checked if o.label == "TP")
    assert all(o.identifiable_reason for o in checked if not o.identifiable)
    assert s.identifiable == sum(o.identifiable for o in checked) and s.identified == s.TP
    assert s.recall_identifiable == pytest.approx(s.TP / s.identifiable)
    # Twins are looked for where the true pose is identifiable; these scenes have none, so every such view is unique.
    assert {r.scene for r in quick_results} == {"office", "living_room"}
    assert all((o.twin_confirmed is None) == (o.identifiable is not True) for o in outcomes)
    assert (s.unique, s.identified_unique) == (s.identifiable, s.identified)


def test_demo_runs_and_reports(tmp_path, monkeypatch, capsys):
    from reloc import _numba
    from reloc.demo import DemoSpec, format_demo, run_demo

    # Seen as a cold cache, the demo says in one line that it compiles (the kernels themselves are cached by now).
    monkeypatch.setattr(_numba, "_has_cache_index", lambda disp: False)

    spec = DemoSpec(map_trajectories=(("robot", 300), ("handheld", 300)), queries_per_kind=1, negatives=2,
                    window_frames=10, width=160, height=120)
    steps = []
    result = run_demo(spec, progress=lambda step, done, total: steps.append(step))
    c = result["counts"]
    assert c["TP"] + c["FN"] + c["TN"] + c["FP"] == 4
    assert c["FP"] == 0
    assert result["identifiable"] <= result["queries"]["positive"] - result["queries"]["ambiguous"]
    assert all(o["identifiable"] for o in result["outcomes"] if o["label"] == "TP")
    assert {"compile", "map", "queries", "relocalize"} <= set(steps)
    assert capsys.readouterr().err.count("numba: compiling") == 1
    assert result["latency_ms"]["relocalization_total"]["median"] > 0
    text = format_demo(result)
    assert "TP" in text and "R_id[%]" in text and "relocalization_total" in text
    # Each true pose is judged by its own covariance: its normalized squared error and spread are reported.
    tps = [o for o in result["outcomes"] if o["label"] == "TP"]
    assert result["covariance"]["checked"] == len(tps)
    assert all(o["pose_nees"] >= 0 and 0 < o["pose_sigma_m"] < 0.25 for o in tps)
    if tps:
        assert f"of {len(tps)} true poses inside its 95 % ellipsoid" in text
    json.loads(json.dumps(result))  # JSON-ready
    assert np.isfinite(result["phases_s"]["total_s"])


def test_the_demos_negative_queries_made_by_a_helper_process_are_the_same(monkeypatch):
    """With two usable cores the negative queries are made by a helper process while the map and the positive
    queries are made here: the same queries (same code and seeds), so the same outcomes as without it
    (``RELOC_DEMO_HELPER=0``); a helper that fails leaves them to this process."""
    import subprocess
    import sys

    import reloc.demo
    from reloc import _numba
    from reloc.demo import DemoSpec, run_demo

    monkeypatch.setattr(_numba, "_usable_cores", lambda: 2)  # a helper even on a one-core runner
    spec = DemoSpec(map_trajectories=(("robot", 300), ("handheld", 300)), queries_per_kind=1, negatives=3,
                    window_frames=10, width=160, height=120)
    runs = {}
    for name, env in (("helper", "1"), ("alone", "0")):
        monkeypatch.setenv("RELOC_DEMO_HELPER", env)
        runs[name] = run_demo(spec)
    monkeypatch.setenv("RELOC_DEMO_HELPER", "1")
    monkeypatch.setattr(reloc.demo, "_start_negatives_helper", lambda *a: (subprocess.Popen(
        [sys.executable, "-c", "raise SystemExit(3)"]), None))
    runs["failed helper"] = run_demo(spec)
    assert [r["queries"]["negatives_by_helper"] for r in runs.values()] == [True, False, False]

    def key(result):
        return [(o["query"], o["label"], o["reason"], o["translation_error_m"], o["counts"])
                for o in result["outcomes"]]

    assert runs["helper"]["queries"]["negative"] == 3
    assert key(runs["helper"]) == key(runs["alone"]) == key(runs["failed helper"])
    assert sum(o["label"] == "TN" for o in runs["helper"]["outcomes"]) == 3


def test_the_demo_starts_no_helper_where_it_cannot(monkeypatch):
    """No helper with one usable core, with ``RELOC_DEMO_HELPER=0``, without negatives, or when no temporary
    directory can be made (then nothing is left behind and the demo makes the negatives itself)."""
    import tempfile

    from reloc import _numba
    from reloc.config import Config
    from reloc.demo import DemoSpec, _start_negatives_helper

    monkeypatch.setenv("RELOC_DEMO_HELPER", "1")
    monkeypatch.setattr(_numba, "_usable_cores", lambda: 1)
    assert _start_negatives_helper(DemoSpec(), Config()) == (None, None)
    monkeypatch.setattr(_numba, "_usable_cores", lambda: 2)
    assert _start_negatives_helper(DemoSpec(negatives=0), Config()) == (None, None)
    monkeypatch.setenv("RELOC_DEMO_HELPER", "0")
    assert _start_negatives_helper(DemoSpec(), Config()) == (None, None)
    monkeypatch.setenv("RELOC_DEMO_HELPER", "1")

    def no_room(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(tempfile, "mkdtemp", no_room)
    assert _start_negatives_helper(DemoSpec(), Config()) == (None, None)


def test_demo_names_an_unknown_scene_before_any_work():
    from reloc.demo import DemoSpec, run_demo

    steps = []
    for spec, said in ((DemoSpec(scene="kitchen"), "scene: expected one of living_room"),
                       (DemoSpec(negative_scene="garage"), "negative_scene: expected one of .* got 'garage'"),
                       # Negatives of the mapped scene were scored as positives (TP 8 of 4 positives).
                       (DemoSpec(scene="office", negative_scene="office"),
                        "negative_scene: expected a scene other than the mapped one \\('office'\\)")):
        with pytest.raises(ValueError, match=said):
            run_demo(spec, progress=lambda step, done, total: steps.append(step))
    assert steps == []


def test_eval_command_runs_a_replicate_on_other_seeds(tmp_path):
    """``reloc eval --query-seed / --map-seed``: the spec carries the seeds, and the queries are other views (their
    submaps' plane counts and their outcomes differ from the default seeds' ones, which repeat exactly from run to
    run), counted like any run."""
    from click.testing import CliRunner

    from reloc.cli import cli

    def run(*seeds):
        out = tmp_path / f"eval{len(seeds)}.json"
        res = CliRunner().invoke(cli, ["eval", "--quick", "--scenes", "living_room", "--quiet", "--json", str(out),
                                       *seeds])
        assert res.exit_code == 0, res.output
        return json.loads(out.read_text())

    base, rep = run(), run("--query-seed", "7", "--map-seed", "5")
    assert (base["spec"]["query_seed"], base["spec"]["map_seed"]) == (101, 1)
    assert (rep["spec"]["query_seed"], rep["spec"]["map_seed"]) == (7, 5)
    for d in (base, rep):
        outcomes = d["outcomes"]["Ours"]
        assert len(outcomes) == 8 and all(o["positive"] for o in outcomes)  # one scene: no negatives
    # Other views: their submaps and outcomes are not those of the default seeds.
    def views(d):
        return [(o["counts"]["submap_planes"], o["status"], o["reason"], o["translation_error_m"])
                for o in d["outcomes"]["Ours"]]

    assert views(base) != views(rep)


def test_eval_command_saves_a_prepared_suite_and_evaluates_it_again(tmp_path):
    """``reloc eval --save-prepared DIR`` then ``--prepared DIR``: the same outcomes without building anything; a
    config whose matching differs is evaluated on the saved suite, one whose extraction differs is refused with the
    parameter named, ``--ablation`` does not take a prepared suite, and ``--explain QUERY`` gives one query's
    account."""
    from click.testing import CliRunner

    from reloc.cli import cli

    suite = tmp_path / "suite"
    base = ["eval", "--quick", "--scenes", "living_room", "--quiet"]

    def run(*args, code=0):
        res = CliRunner().invoke(cli, [*base, *args])
        assert res.exit_code == code, res.output
        return res

    def outcomes(path):
        return [{k: v for k, v in o.items() if k not in ("total_ms", "timings_ms")}
                for o in json.loads(path.read_text())["outcomes"]["Ours"]]

    saved = run("--json", str(tmp_path / "a.json"), "--save-prepared", str(suite))
    assert f"saved the prepared suite to {suite}" in saved.output
    run("--json", str(tmp_path / "b.json"), "--prepared", str(suite))
    first = outcomes(tmp_path / "a.json")
    assert len(first) == 8 and sum(o["label"] == "TP" for o in first) >= 3
    assert outcomes(tmp_path / "b.json") == first
    # Another matching setting on the same maps and queries: no view matches 40 planes, so every one is rejected.
    strict = tmp_path / "strict.yaml"
    strict.write_text("evaluation:\n  min_matched_planes: 40\n")
    run("--json", str(tmp_path / "c.json"), "--prepared", str(suite), "--config", str(strict))
    assert [o["status"] for o in outcomes(tmp_path / "c.json")] == ["rejected"] * 8
    other = tmp_path / "other.yaml"
    other.write_text("extraction:\n  voxel_size_m: 0.3\n")
    refused = run("--prepared", str(suite), "--config", str(other), code=2)
    assert "extraction.voxel_size_m: saved 0.25, asked 0.3" in refused.output
    assert "holds another suite" in run("--prepared", str(suite), "--query-seed", "7", code=2).output
    assert "no such directory" in run("--prepared", str(tmp_path / "nowhere"), code=2).output
    assert "without --ablation" in run("--ablation", "--prepared", str(suite), code=2).output
    # --explain: the account of one query of the saved suite, its result the table's.
    tp = next(o for o in first if o["label"] == "TP")
    told = run("--prepared", str(suite), "--explain", tp["query"]).output
    assert f"== {tp['query']} in the map of living_room" in told
    assert "result: relocalized" in told and "winner (nearest the truth)" in told
    assert "no query 'nope' in this suite" in run("--prepared", str(suite), "--explain", "nope", code=2).output
    assert "--explain-map goes with --explain" in run("--explain-map", "office", code=2).output
    assert "--json goes without it" in run("--explain", tp["query"], "--json", "x.json", code=2).output


def test_eval_command_runs_the_benchmark_suite_with_each_sensor_camera(tmp_path):
    """``reloc eval`` (without --quick) builds the suite of ``benchmarks/reloc_accuracy.py``, whose figures
    docs/BENCHMARKS.md records: frames of 320 x 240, and for stereo noise the OAK-D class camera at its own 640 x 400,
    whose noise law is several times smaller than the same law on a 160 x 120 image. Checked on a tiny suite (one
    scene, short maps and windows) through the spec and noise law the run reports, and on --quick's spec."""
    from dataclasses import asdict, replace

    from click.testing import CliRunner

    from reloc.cli import cli
    from reloc.evaluation.suite import EvalSpec, extraction_for_sensor, sensor_spec, suite_spec

    tiny = ["--scenes", "living_room", "--queries", "1", "--negatives", "0", "--map-frames", "60", "--window", "4",
            "--max-window", "0"]
    specs = {}
    for noise in ("kinect", "stereo"):
        out = tmp_path / f"{noise}.json"
        res = CliRunner().invoke(cli, ["eval", "--noise", noise, "--quiet", "--json", str(out), *tiny])
        assert res.exit_code == 0, res.output
        specs[noise] = json.loads(out.read_text())["spec"]
        assert len(json.loads(out.read_text())["outcomes"]["Ours"]) == 2  # one robot-like, one hand-held view
    assert (specs["kinect"]["camera"], specs["kinect"]["width"], specs["kinect"]["height"]) == ("kinect", 320, 240)
    assert (specs["stereo"]["camera"], specs["stereo"]["width"], specs["stereo"]["height"]) == ("oak-d", 640, 400)
    want = asdict(suite_spec("stereo", scenes=("living_room",), queries=1, negatives=0, window=4, max_window=0,
                             map_frames=60))
    assert specs["stereo"] == json.loads(json.dumps(want))
    # The stereo law at the OAK's own size: sigma(3 m) = c * 9 about 2.2 cm; rendered at 160 x 120 the same camera
    # would be a 8.7 cm one (and the Kinect-like camera reloc eval used to take, 7.3 cm).
    oak = extraction_for_sensor(suite_spec("stereo"))
    small = extraction_for_sensor(replace(EvalSpec(), noise="stereo", camera="oak-d"))
    assert oak.noise_coeff * 9 == pytest.approx(0.0218, abs=0.001)
    assert small.noise_coeff * 9 == pytest.approx(0.087, abs=0.002)
    quick = sensor_spec(quick_spec(), "stereo")
    assert (quick.camera, quick.width, quick.height, quick.scenes) == ("oak-d", 640, 400, ("living_room", "office"))


def test_the_demo_runs_with_a_stereo_camera_and_decides_at_its_noise(monkeypatch):
    """``reloc demo --noise stereo`` simulates the OAK-D class camera at its 640 x 400 (as ``reloc eval`` does), and
    the demo's matcher takes its decision offsets from that camera's noise law, not from the config's Kinect one."""
    from click.testing import CliRunner

    import reloc.demo
    from reloc.cli import cli
    from reloc.demo import DemoSpec, run_demo
    from reloc.evaluation.suite import EvalSpec, extraction_for_sensor
    from reloc.matching import MatchingParams
    from reloc.matching.params import CONFLICT_SIGMAS, sensor_sigma_m

    seen = []

    def stop(spec, cfg=None, **kw):
        seen.append(spec)
        raise KeyboardInterrupt

    monkeypatch.setattr(reloc.demo, "run_demo", stop)
    CliRunner().invoke(cli, ["demo", "--noise", "stereo", "--quiet"])
    CliRunner().invoke(cli, ["demo", "--quiet"])
    assert [(s.noise, s.camera, s.width, s.height) for s in seen] == [("stereo", "oak-d", 640, 400),
                                                                       ("kinect", "kinect", 320, 240)]
    monkeypatch.undo()
    spec = DemoSpec(noise="stereo", camera="oak-d", width=640, height=400, queries_per_kind=1, negatives=1,
                    map_trajectories=(("robot", 120), ("handheld", 120)), window_frames=5, window_max_frames=0)
    kept: dict = {}
    result = run_demo(spec, keep=kept)
    law = extraction_for_sensor(EvalSpec(noise="stereo", camera="oak-d", width=640, height=400))
    sigma = sensor_sigma_m(law.noise_model, law.noise_coeff)
    assert sigma == pytest.approx(0.0218, abs=0.001)  # 2.2 cm at 3 m
    params = kept["relocalizer"].params
    assert params.decision_conflict_m == pytest.approx(CONFLICT_SIGMAS * sigma)
    assert params.decision_conflict_m > MatchingParams().decision_conflict_m and not params.occlusion
    assert sum(result["counts"].values()) == 3 and result["counts"]["FP"] == 0


def test_the_suites_map_tour_is_named_and_checked():
    """``map_tour`` goes from suite_spec into the spec (and so into a saved suite's record); the suite's maps come
    from runs that enter every room, a record from before the field was a random walk's (and asking for the suite
    of now on it names the difference); another name is refused with the names it takes."""
    from dataclasses import asdict
    from pathlib import Path
    from types import SimpleNamespace

    from reloc.evaluation.prepared_io import _spec_from, mismatch
    from reloc.evaluation.suite import EvalSpec, suite_spec

    assert suite_spec("kinect").map_tour == "rooms"
    assert suite_spec("stereo", map_tour="random").map_tour == "random"
    old = {k: v for k, v in json.loads(json.dumps(asdict(suite_spec("kinect")))).items() if k != "map_tour"}
    saved = _spec_from(old, Path("suite.json"))
    assert saved.map_tour == "random"
    assert mismatch(SimpleNamespace(spec=saved), {"params": {}}, suite_spec("kinect"), {}) == [
        "map_tour: saved 'random', asked 'rooms'"]
    assert mismatch(SimpleNamespace(spec=saved), {"params": {}}, suite_spec("kinect", map_tour="random"), {}) == []
    # reloc eval writes the names and the suite's tour out (it imports no simulator before a command runs).
    from reloc.commands.eval_cmd import eval_cmd
    from reloc.evaluation.suite import SUITE_MAP_TOUR
    from sim.trajectories import TOURS

    option = next(p for p in eval_cmd.params if p.name == "map_tour")
    assert option.default == SUITE_MAP_TOUR and tuple(option.type.choices) == TOURS
    with pytest.raises(ValueError, match="map_tour: expected one of random, rooms, got 'everywhere'"):
        EvalSpec(map_tour="everywhere")


def test_look_at_straight_down_is_a_rotation_that_sees_the_floor():
    """A camera looking down along the world's up (the floor from above): the cross product with up is zero, and
    ``look_at`` returned NaN, so ``view_planes`` refused the gravity. Its x is now a world axis square to the view."""
    from reloc.evaluation.synthetic import furnished_room, look_at, view_planes

    for target in ((3.0, 2.5, 0.0), (3.0, 2.5, 4.0)):
        T = look_at((3.0, 2.5, 2.0), target)
        R = T[:3, :3]
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1.0)
        np.testing.assert_allclose(R[:, 2], np.sign(target[2] - 2.0) * np.array([0.0, 0.0, 1.0]), atol=1e-12)
    down = view_planes(furnished_room("living"), look_at((3.0, 2.5, 2.0), (3.0, 2.5, 0.0)))
    np.testing.assert_allclose(down.gravity, [0.0, 0.0, 1.0], atol=1e-12)  # gravity along the view
    floor = int(np.argmax(down.areas))
    np.testing.assert_allclose(down.normals[floor], [0.0, 0.0, -1.0], atol=1e-9)  # the floor faces the camera
    np.testing.assert_allclose(down.offsets[floor], 2.0, atol=1e-9)
    with pytest.raises(ValueError, match="eye and target are the same point"):
        look_at((1.0, 2.0, 3.0), (1.0, 2.0, 3.0))
