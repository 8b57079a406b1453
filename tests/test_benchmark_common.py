"""benchmarks/_common.py helpers that decide what a benchmark measures: the ``--set KEY=VALUE`` overrides."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from _common import parse_overrides, quick_presets, results_name, write_results  # noqa: E402


def test_overrides_parse_literals_and_keep_other_values_as_strings():
    got = parse_overrides(["bevel_max_width_voxels=3", "merge=False", " noise_model = stereo", "x=None",
                           "mounting_gravity_cam=(0, 1, 0)", "alpha= 0.5", "seed=1e3"])
    assert got == {"bevel_max_width_voxels": 3, "merge": False, "noise_model": "stereo", "x": None,
                   "mounting_gravity_cam": (0, 1, 0), "alpha": 0.5, "seed": 1000.0}
    assert parse_overrides([]) == {}
    assert parse_overrides(["a=1", "a=2"]) == {"a": 2}  # the last one wins
    # The config files' spelling of a switch is a switch too, in any case; other words stay strings.
    assert parse_overrides(["a=true", "b=FALSE", "c= True ", "d=yes"]) == {"a": True, "b": False, "c": True, "d": "yes"}


@pytest.mark.parametrize("item", ["no_equals", "=3", " =3"])
def test_an_override_without_a_key_or_value_is_refused_by_name(item):
    with pytest.raises(ValueError, match="--set: expected KEY=VALUE"):
        parse_overrides([item])


@pytest.mark.parametrize("name", ["", "a/b", "..", "x\\y"])
def test_a_results_name_that_is_not_a_plain_stem_is_refused(name, tmp_path):
    with pytest.raises(ValueError, match="--name: expected a plain file stem"):
        results_name(name)
    with pytest.raises(ValueError, match="--name"):
        write_results(name, params={}, results={}, out_dir=tmp_path)
    assert results_name("reloc_accuracy_stereo_bevel3") == "reloc_accuracy_stereo_bevel3"


def test_the_benchmark_scripts_refuse_a_bad_name_before_measuring():
    import subprocess

    root = Path(__file__).resolve().parents[1]
    for script in ("reloc_accuracy.py", "extraction_accuracy.py", "extraction_speed.py", "sim_speed.py",
                   "map_accuracy.py", "compare_accuracy.py", "decision_latency.py"):
        extra = {"compare_accuracy.py": ["x.json:y.json"], "decision_latency.py": ["--prepared", "x"]}.get(script, [])
        done = subprocess.run([sys.executable, str(root / "benchmarks" / script), "--name", "a/b", *extra],
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 2 and "--name: expected a plain file stem" in done.stderr, (script, done.stderr)
    # The long runs name their results file with --out (a 9,000-frame soak once ran 5 minutes, then refused it).
    for script in ("soak.py", "live_loop.py", "profiling_overhead.py"):
        done = subprocess.run([sys.executable, str(root / "benchmarks" / script), "--out", "/tmp/x.json"],
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 2 and "--out: expected a plain file stem" in done.stderr, (script, done.stderr)


def test_the_latency_benchmarks_two_floor_map_holds_both_floors():
    """reloc_latency.py's maps beyond one floor (1,055 planes) stack a second building 200 m away; its per-set values
    (gravity and its tolerance) are the first floor's, not concatenated (a 0-d array broke the 2,000-plane run)."""
    import numpy as np
    from reloc_latency import _building_map
    from sim.ground_truth import scene_planes
    from sim.scenes import make_scene

    _, one = _building_map(two_floors=False)
    other, _ = scene_planes(make_scene("building", 1))
    _, two = _building_map(two_floors=True)
    assert len(two) == len(one) + len(other) > 2000
    assert np.array_equal(two.normals[: len(one)], one.normals) and np.allclose(two.normals[len(one):], other.normals)
    assert np.allclose(two.centroids[len(one):] - other.centroids, [200.0, 0.0, 0.0], atol=1e-9)
    assert two.gravity_tolerance_rad == one.gravity_tolerance_rad and np.array_equal(two.gravity, one.gravity)
    assert np.allclose(two.samples_of(len(one)) - np.float32([200.0, 0.0, 0.0]), other.samples_of(0), atol=1e-4)


def test_the_map_benchmark_scores_each_plane_against_its_true_surface():
    """map_accuracy.py's measure on a made-up map: a floor on its surface, a second floor 10 cm above it over the same
    place (a duplicate, 6 cm or more off), a wall 2 cm off its surface and a tilted plane no true plane is near."""
    from types import SimpleNamespace

    import numpy as np
    from map_accuracy import map_errors

    g = np.stack(np.meshgrid(np.arange(0.0, 2.0, 0.1), np.arange(0.0, 2.0, 0.1)), -1).reshape(-1, 2)
    floor = np.c_[g, np.zeros(len(g))]
    layer = floor[: len(floor) // 2] + [0.0, 0.0, 0.1]
    wall = np.c_[np.full(len(g), 2.02), g]
    tilted = np.c_[g, g[:, 0]]
    samples = [floor, layer, wall, tilted]
    normals = np.array([[0, 0, 1.0], [0, 0, 1.0], [-1.0, 0, 0], [-np.sqrt(0.5), 0, np.sqrt(0.5)]])
    planes = SimpleNamespace(normals=normals, areas=np.array([4.0, 2.0, 4.0, 1.0]), samples_of=lambda i: samples[i])
    scene = SimpleNamespace(normals=np.array([[0, 0, 1.0], [-1.0, 0, 0]]), offsets=np.array([0.0, 2.0]))
    r = map_errors(SimpleNamespace(planes=planes), scene)
    assert r["planes"] == 4 and r["duplicates"] == 1
    assert r["area_by_offset_m2"] == [4.0, 4.0, 0.0, 2.0] and r["unmatched_area_m2"] == 1.0
    assert r["mean_offset_m"] == pytest.approx((4.0 * 0.02 + 2.0 * 0.1) / 10.0)


def test_a_benchmark_measures_the_code_of_its_own_checkout(tmp_path):
    """Run from a second checkout (an old commit's worktree) with this venv, whose editable install points at the
    first, a script must import that checkout's ``reloc``: otherwise the results name one commit and measure
    another. A stand-in checkout whose ``reloc`` says where it is shows which one was imported."""
    import shutil
    import subprocess

    bench = tmp_path / "benchmarks"
    bench.mkdir()
    shutil.copy(Path(__file__).resolve().parents[1] / "benchmarks" / "_common.py", bench)
    (tmp_path / "reloc").mkdir()
    (tmp_path / "reloc" / "__init__.py").write_text("WHERE = 'stand-in checkout'\n")
    (bench / "probe.py").write_text(
        "import _common\nimport reloc\nprint(reloc.WHERE)\ninfo = _common.git_info()\n"
        "print(info['code_is_checkout'], info['code_root'])\n"
    )
    done = subprocess.run([sys.executable, str(bench / "probe.py")], capture_output=True, text=True, timeout=60,
                          cwd=str(tmp_path.parent))
    assert done.returncode == 0, done.stderr
    where, info = done.stdout.splitlines()
    assert where == "stand-in checkout"
    assert info == f"True {tmp_path.resolve()}"


def test_the_benchmark_scripts_import_common_before_the_project():
    """``_common`` sets the path (above), so it must come before the first import of the project in every script."""
    import ast

    project = ("reloc", "sim", "drivers", "firmware_bridge", "plane_baselines", "reloc_latency")
    folder = Path(__file__).resolve().parents[1] / "benchmarks"
    scripts = [p for p in sorted(folder.glob("*.py")) if p.name not in ("_common.py", "plane_baselines.py")]
    assert len(scripts) >= 10
    for path in scripts:
        first_common, first_project = None, None
        nodes = [n for n in ast.walk(ast.parse(path.read_text())) if isinstance(n, (ast.Import, ast.ImportFrom))]
        for node in sorted(nodes, key=lambda n: n.lineno):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            if "_common" in names and first_common is None:
                first_common = node.lineno
            if any(n.split(".")[0] in project or n.startswith("test_") for n in names) and first_project is None:
                first_project = node.lineno
        assert first_common is not None, f"{path.name} does not import _common"
        assert first_project is None or first_common < first_project, (
            f"{path.name}: line {first_project} imports the project before _common (line {first_common})")


def test_a_matcher_variant_is_parsed_into_matching_params_and_its_changed_outcomes_listed():
    from reloc_accuracy import changed_outcomes, parse_variant

    from reloc.evaluation.metrics import Outcome
    from reloc.matching import MatchingParams

    ours = MatchingParams()
    got = parse_variant("min_counted_area_m2=0.2, match_max_angle_deg=4,probe_twins=False", ours)
    assert got == ours.with_(min_counted_area_m2=0.2, match_max_angle_deg=4, probe_twins=False)
    assert got.min_counted_area_m2 == 0.2 and got.probe_twins is False
    for spec, message in [("", "--variant: expected KEY=VALUE"), ("0.2", "--variant: expected KEY=VALUE"),
                          ("min_score=0.1,bogus=2", "unknown parameter 'bogus'")]:
        with pytest.raises(ValueError, match=message):
            parse_variant(spec, ours)

    def outcome(query, label, err=float("nan")):
        return Outcome("office", query, True, False, "", "", label, translation_error_m=err)

    base = [outcome("office/robot/1", "TP", 0.002), outcome("office/robot/2", "FN"), outcome("office/robot/3", "TN")]
    other = [outcome("office/robot/1", "TP", 0.003), outcome("office/robot/2", "FP", 2.5),
             outcome("office/robot/3", "TN")]
    assert changed_outcomes(base, other) == ["office/robot/2 in the map of office: FN -> FP (250.0 cm)"]
    assert changed_outcomes(base, base) == []


def test_the_accuracy_benchmark_refuses_a_bad_variant_before_measuring():
    import subprocess

    root = Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, str(root / "benchmarks" / "reloc_accuracy.py"), "--variant", "nope=1"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "unknown parameter 'nope'" in done.stderr, done.stderr


def test_the_accuracy_benchmark_refuses_a_bad_mapping_setting_before_measuring():
    import subprocess

    root = Path(__file__).resolve().parents[1]
    for arg, message in [("fuse_max_angle_deg", "--mapping-set: expected KEY=VALUE"),
                         ("nope=1", "MappingParams: unknown parameter 'nope'"),
                         ("min_observations=2.5", "MappingParams: min_observations: expected an integer")]:
        done = subprocess.run([sys.executable, str(root / "benchmarks" / "reloc_accuracy.py"), "--mapping-set", arg],
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 2 and message in done.stderr, (arg, done.stderr)


def test_the_real_clip_benchmark_refuses_a_bad_setting_before_measuring():
    import subprocess

    root = Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, str(root / "benchmarks" / "reloc_real.py"), "--set", "nope=1"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "unknown parameter(s) ['nope']" in done.stderr, done.stderr
    done = subprocess.run([sys.executable, str(root / "benchmarks" / "reloc_real.py"), "--variant",
                           "min_ambiguity_ratio=1.4,nope=1"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "MatchingParams: unknown parameter 'nope'" in done.stderr, done.stderr


def test_the_accuracy_benchmark_refuses_a_missing_prepared_suite_before_measuring(tmp_path):
    import subprocess

    root = Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, str(root / "benchmarks" / "reloc_accuracy.py"), "--noise", "stereo",
                           "--no-oracle", "--prepared", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert f"--prepared: {tmp_path / 'extraction_stereo'} holds no prepared suite" in done.stderr, done.stderr


def test_the_machine_record_names_the_cpu_generation_the_kernels_are_compiled_for():
    # VMs that all call their CPU "AMD EPYC" differ by a generation, and extraction times by about 40 % between
    # them: the record keeps the family and LLVM's name for the microarchitecture.
    import llvmlite.binding as llvm

    from _common import machine_info

    info = machine_info()
    assert info["llvm_host_cpu"] == llvm.get_host_cpu_name()
    assert info["cores"] >= 1 and 1 <= info["cores_usable"] <= info["cores"]
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        first = cpuinfo.read_text(encoding="utf-8").split("\n\n")[0]
        fields = dict((k.strip().lower(), v.strip()) for k, _, v in (ln.partition(":") for ln in first.splitlines()))
        assert info["cpu_model"] == fields.get("model name", info["cpu_model"])
        assert info["cpu_family"] == fields.get("cpu family")


def test_the_machine_record_names_the_blas_kernels_numpy_runs():
    # OpenBLAS picks its kernels by CPU and falls back to older ones for a CPU it does not know; the products differ
    # in their last bits, and the ground-truth plane suite's outcomes with them (docs/BENCHMARKS.md).
    import os
    import subprocess

    from _common import machine_info

    if machine_info()["blas_core"] is None:
        pytest.skip("NumPy's BLAS here is not an OpenBLAS that names its kernels")
    code = "from reloc.profiling import machine_info; print(machine_info()['blas_core'])"
    env = dict(os.environ, OPENBLAS_CORETYPE="Sandybridge")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "Sandybridge"


def test_the_accuracy_benchmark_runs_the_suite_reloc_eval_saves(tmp_path):
    """End to end on a tiny suite: ``reloc eval`` saves it, ``reloc_accuracy.py --prepared`` accepts it as its own
    suite (every spec field and parameter compared), evaluates it beside its baselines and writes its JSON, with the
    same outcomes as ``reloc eval`` printed."""
    import json
    import os
    import subprocess

    from click.testing import CliRunner

    from reloc.cli import cli

    tiny = ["--scenes", "living_room", "--queries", "1", "--negatives", "0", "--map-frames", "60", "--window", "4",
            "--max-window", "0"]
    res = CliRunner().invoke(cli, ["eval", "--quiet", "--json", str(tmp_path / "eval.json"), "--save-prepared",
                                   str(tmp_path / "prep" / "extraction_kinect"), *tiny])
    assert res.exit_code == 0, res.output
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "RELOC_RESULTS_DIR": str(tmp_path / "results")}
    done = subprocess.run([sys.executable, str(root / "benchmarks" / "reloc_accuracy.py"), "--noise", "kinect",
                           "--no-oracle", "--prepared", str(tmp_path / "prep"), "--name", "smoke", *tiny],
                          capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    out = json.loads((tmp_path / "results" / "smoke.json").read_text())
    assert out["params"]["spec"]["extraction/kinect"]["width"] == 320
    ours = out["results"]["sources"]["extraction/kinect/ours"]["outcomes"]
    theirs = json.loads((tmp_path / "eval.json").read_text())["outcomes"]["Ours"]

    def key(o):
        return o["query"], o["label"], o["status"], o["reason"]

    assert len(ours) == 2 and [key(o) for o in ours] == [key(o) for o in theirs]


def test_a_quick_run_keeps_the_options_given_on_the_command_line():
    """``--quick --noise tof --queries 1`` ran Kinect with 3 queries and recorded the command as given; a smoke run's
    presets now fill only the options left unset (given as ``--opt v`` or ``--opt=v``)."""
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--noise", default="kinect,tof,stereo")
    ap.add_argument("--queries", type=int, default=10)
    ap.add_argument("--map-frames", type=int, default=3000)
    ap.add_argument("--quick", action="store_true")
    presets = {"noise": "kinect", "queries": 3, "map_frames": 800}
    for argv, want, kept in ((["--quick"], ("kinect", 3, 800), []),
                             (["--quick", "--noise", "tof", "--queries=1"], ("tof", 1, 800), ["noise", "queries"]),
                             (["--map-frames", "3000", "--quick"], ("kinect", 3, 3000), ["map_frames"])):
        args = ap.parse_args(argv)
        assert quick_presets(ap, args, presets, argv) == kept
        assert (args.noise, args.queries, args.map_frames) == want
    assert ap.parse_args([]).noise == "kinect,tof,stereo"  # the parser's own defaults are left as they were


def test_two_accuracy_records_are_compared_view_by_view_in_their_own_maps(tmp_path, capsys, monkeypatch):
    # A negative is named after its own scene's view, so the same query name comes up in two maps: the comparison
    # keys each outcome by (map, query), or the negative would overwrite the positive.
    import json

    from compare_accuracy import main

    def record(labels, bent):
        outcomes = [{"scene": m, "query": q, "label": lab, "ambiguous": False, "reason": "why " + lab}
                    for (m, q), lab in labels.items()]
        total = {k: sum(lab == k for lab in labels.values()) for k in ("TP", "TN", "FP", "FN")}
        src = {"total": total, "outcomes": outcomes, "prepare_s": 1.0, "map_planes": {"office": 10, "corridor": 5},
               "map_consistency": {"office": {"bent_planes": bent, "bent_area_m2": 1.5 * bent},
                                   "corridor": {"bent_planes": 1, "bent_area_m2": 0.5}}}
        return {"git": {"commit": "c"}, "results": {"sources": {"extraction/kinect/ours": src}}}

    before = {("office", "office/robot/1"): "TP", ("office", "office/robot/2"): "FN",
              ("corridor", "office/robot/2"): "TN"}
    after = dict(before)
    after[("office", "office/robot/2")] = "TP"
    after[("corridor", "office/robot/2")] = "FP"
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps(record(before, 3)))
    b.write_text(json.dumps(record(after, 1)))
    import _common

    monkeypatch.setattr(_common, "RESULTS_DIR", tmp_path)
    assert main(["--name", "cmp", f"{a}:{b}"]) == 0
    res = json.loads((tmp_path / "cmp.json").read_text())["results"]
    c = res["pairs"][0]["sources"]["extraction/kinect/ours"]
    assert c["before"] == {"TP": 1, "TN": 1, "FP": 0, "FN": 1} and c["after"] == {"TP": 2, "TN": 0, "FP": 1, "FN": 0}
    assert sorted((x["map"], x["query"], x["before"], x["after"]) for x in c["changed"]) == [
        ("corridor", "office/robot/2", "TN", "FP"), ("office", "office/robot/2", "FN", "TP")]
    assert c["bent_before"] == {"planes": 4, "area_m2": 5.0, "map_planes": 15} and c["bent_after"]["planes"] == 2
    assert res["totals"]["extraction/kinect/ours"]["bent_planes"] == [4, 2]
    assert "office/robot/2 in the map of corridor: TN -> FP" in capsys.readouterr().out
    # One record holding ours and a variant beside it (reloc_accuracy.py --variant): the same comparison.
    both = record(before, 3)
    both["results"]["sources"]["extraction/kinect/ours with x=1"] = record(after, 1)["results"]["sources"][
        "extraction/kinect/ours"]
    v = tmp_path / "v.json"
    v.write_text(json.dumps(both))
    assert main(["--name", "cmpv", "--variant", "x=1", str(v)]) == 0
    res_v = json.loads((tmp_path / "cmpv.json").read_text())["results"]
    assert res_v["pairs"][0]["sources"] == res["pairs"][0]["sources"] and res_v["totals"] == res["totals"]
    b.write_text(json.dumps(record({("office", "office/robot/1"): "TP"}, 1)))
    with pytest.raises(SystemExit, match="do not hold the same queries"):
        main(["--name", "cmp", f"{a}:{b}"])
    # The same names from another query seed are other views: refused by the field that differs (they were paired).
    spec = {"query_seed": 101, "map_seed": 1, "scenes": ["office", "corridor"], "noise": "kinect"}
    for path, seeds in ((a, {}), (b, {"query_seed": 7, "map_seed": 9})):
        r = record(before if path == a else after, 3)
        r["params"] = {"spec": {"extraction/kinect": {**spec, **seeds}}}
        path.write_text(json.dumps(r))
    with pytest.raises(SystemExit, match="not the same queries for extraction/kinect/ours \\(query_seed: 101 -> 7\\)"):
        main(["--name", "cmp", f"{a}:{b}"])
    r = json.loads(b.read_text())
    r["params"]["spec"]["extraction/kinect"].update(query_seed=101)  # another map seed: the same queries
    b.write_text(json.dumps(r))
    assert main(["--name", "cmp", f"{a}:{b}"]) == 0
    # A variant the record does not hold: nothing to compare is an error, not empty tables.
    with pytest.raises(SystemExit, match="no source to compare .*with y=2; the record holds extraction/kinect/ours"):
        main(["--name", "cmpv", "--variant", "y=2", str(v)])


def test_window_growth_rules_take_the_first_grown_answer_that_clears_the_ratio():
    from window_growth import outcome, summarize

    def grown(frames, label, ratio, ambiguous=False):
        return {"frames": frames, "label": label, "ratio": ratio, "ambiguous": ambiguous}

    twin = {"query": "meeting_rooms/robot/6", "map": "meeting_rooms", "positive": True, "label": "FN",
            "grown": [grown(60, "FP", 2.2), grown(80, "TP", None)]}
    late = {"query": "office/robot/6", "map": "office", "positive": True, "label": "FN",
            "grown": [grown(60, "FN", None), grown(80, "TP", 1.6)]}
    never = {"query": "meeting_rooms/robot/7", "map": "meeting_rooms", "positive": True, "label": "TN",
             "grown": [grown(80, "FN", None, ambiguous=False)]}
    still = {"query": "symmetric_room/robot/0", "map": "symmetric_room", "positive": True, "label": "TN",
             "grown": [grown(80, "TN", None, ambiguous=True)]}
    negative = {"query": "office/robot/1", "map": "meeting_rooms", "positive": False, "label": "TN",
                "grown": [grown(60, "FP", 4.0)]}
    untouched = {"query": "living_room/robot/0", "map": "living_room", "positive": True, "label": "TP", "grown": []}
    # Any answer (the decision's own ratio): the first size decides; a stricter ratio skips the twin at 2.2 for the
    # true pose found 20 frames further back, and the answer at 1.6 for a rejection.
    assert [outcome(r, 1.55) for r in (twin, late, never, still, negative)] == ["FP", "TP", "FN", "TN", "FP"]
    assert [outcome(r, 3.0) for r in (twin, late, never, still, negative)] == ["TP", "FN", "FN", "TN", "FP"]
    assert [outcome(r, math.inf) for r in (twin, late, negative)] == ["TP", "FN", "TN"]
    s = summarize([twin, late, never, still, negative, untouched], 3.0)
    assert (s["TP"], s["TN"], s["FP"], s["FN"]) == (2, 1, 1, 2) and s["recall"] == pytest.approx(0.5)
    assert s["changed"] == ["meeting_rooms/robot/6 FN->TP", "meeting_rooms/robot/7 TN->FN",
                            "office/robot/1 in meeting_rooms TN->FP"]
    ours = summarize([twin, late, never, still, negative, untouched], None)
    assert (ours["TP"], ours["TN"], ours["FP"], ours["FN"], ours["changed"]) == (1, 3, 0, 2, [])


def test_window_growth_repeat_share_tells_a_twin_room_from_a_look_alike_corner():
    from window_growth import outcome, repeat_share

    from reloc.evaluation.synthetic import furnished_room, look_at, scene_planes

    # Two identical meeting rooms 6.5 m apart along x: the move from one to the other lays the first room's walls
    # and furniture onto the second's; a move of 1.3 m and 0.9 m across both walls inside the first room lays next
    # to nothing anywhere. A move along x alone slides the walls facing y along themselves: they count as laid.
    planes = scene_planes(furnished_room("meeting") + furnished_room("meeting", origin=(6.5, 0.0)))
    T = look_at((2.0, 1.0, 1.4), (4.0, 4.0, 0.8))
    twin, moved, slid = T.copy(), T.copy(), T.copy()
    twin[0, 3] += 6.5
    moved[:2, 3] += (1.3, 0.9)
    slid[0, 3] += 1.3
    assert repeat_share(planes, T, twin) > 0.9
    assert repeat_share(planes, T, moved) < 0.1
    assert 0.3 < repeat_share(planes, T, slid) < 0.9
    # The gate: a query grows only when its rivals' share is known and under the limit.
    rec = {"query": "meeting_rooms/robot/1", "map": "meeting_rooms", "positive": True, "label": "FN",
           "grown": [{"frames": 60, "label": "TP", "ratio": None, "ambiguous": False}]}
    assert outcome({**rec, "repeat_share": 0.1}, 1.0, 0.3) == "TP"
    assert outcome({**rec, "repeat_share": 0.9}, 1.0, 0.3) == "FN"
    assert outcome({**rec, "repeat_share": None}, 1.0, 0.3) == "FN"
    assert outcome({**rec, "repeat_share": 0.9}, 1.0) == "TP"
