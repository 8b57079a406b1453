"""A prepared suite saved to disk and loaded back evaluates exactly as the one in memory; bad directories are named."""

import json

import numpy as np
import pytest

from reloc.evaluation.prepared_io import (
    PreparedSuiteError,
    load_prepared,
    load_queries,
    save_prepared,
    save_queries,
)
from reloc.evaluation.suite import prepare_suite, quick_spec


@pytest.fixture(scope="module")
def prepared():
    spec = quick_spec(queries_per_kind=2, negatives_per_scene=2)  # office and living room
    return prepare_suite(spec)


@pytest.fixture
def saved(prepared, tmp_path):
    save_prepared(tmp_path / "suite", prepared, {"commit": "abc", "mapping": {"fuse_check_bridged": True}})
    return tmp_path / "suite"


def _key(outcome):
    d = outcome.to_dict()
    d.pop("total_ms")
    d.pop("timings_ms")
    return d


def test_a_saved_suite_evaluates_exactly_as_the_one_in_memory(prepared, saved):
    loaded, meta = load_prepared(saved)
    assert meta == {"commit": "abc", "mapping": {"fuse_check_bridged": True}}
    assert loaded.spec == prepared.spec
    for name in prepared.spec.scenes:
        a, b = prepared.queries[name], loaded.queries[name]
        assert [q.name for q in a] == [q.name for q in b]
        for qa, qb in zip(a, b):
            assert qa.ambiguous == qb.ambiguous and qa.frames_left_out == qb.frames_left_out
            np.testing.assert_array_equal(qa.T_world_cam, qb.T_world_cam)
            np.testing.assert_array_equal(qa.submap.normals, qb.submap.normals)
            np.testing.assert_array_equal(qa.submap.sample_points, qb.submap.sample_points)
        assert len(loaded.maps[name]) == len(prepared.maps[name])
    before = [_key(o) for r in prepared.evaluate() for o in r.outcomes]
    after = [_key(o) for r in loaded.evaluate() for o in r.outcomes]
    assert len(before) == 2 * (4 + 2)
    assert after == before
    assert sum(o["label"] == "TP" for o in before) >= 4  # the suite is not trivially all rejected


def test_a_save_that_did_not_finish_does_not_load(saved):
    (saved / "suite.json").unlink()
    with pytest.raises(PreparedSuiteError, match=r"suite\.json: missing"):
        load_prepared(saved)


def test_a_missing_directory_is_named(tmp_path):
    with pytest.raises(PreparedSuiteError, match="no such directory"):
        load_prepared(tmp_path / "nowhere")


def test_another_format_version_is_refused(saved):
    index = json.loads((saved / "suite.json").read_text())
    index["format_version"] = 99
    (saved / "suite.json").write_text(json.dumps(index))
    with pytest.raises(PreparedSuiteError, match="format version 99"):
        load_prepared(saved)


def test_a_truncated_query_file_is_named(saved):
    path = saved / "queries" / "office.npz"
    path.write_bytes(path.read_bytes()[:200])
    with pytest.raises(PreparedSuiteError, match=r"queries/office\.npz"):
        load_prepared(saved)


def test_a_corrupted_map_is_named(saved):
    (saved / "maps" / "living_room.npz").write_bytes(b"not a map")
    with pytest.raises(PreparedSuiteError, match=r"maps/living_room\.npz.*not a map file"):
        load_prepared(saved)


def test_a_spec_field_this_program_does_not_know_is_refused(saved):
    index = json.loads((saved / "suite.json").read_text())
    index["spec"]["lighting"] = "dim"
    (saved / "suite.json").write_text(json.dumps(index))
    with pytest.raises(PreparedSuiteError, match="unknown field.*lighting"):
        load_prepared(saved)


def test_a_query_file_that_is_not_an_archive_is_named(saved):
    (saved / "queries" / "living_room.npz").write_bytes(b"\x80\x04K\x01.")
    with pytest.raises(PreparedSuiteError, match=r"queries/living_room\.npz.*not an \.npz \(zip\) archive"):
        load_prepared(saved)


def test_saving_over_a_suite_removes_its_index_first(prepared, saved, monkeypatch):
    import reloc.evaluation.prepared_io as io

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(io, "save_map", interrupted)
    with pytest.raises(KeyboardInterrupt):
        save_prepared(saved, prepared)
    with pytest.raises(PreparedSuiteError, match=r"suite\.json: missing"):
        load_prepared(saved)


def test_a_loaded_suite_is_checked_against_every_parameter_it_was_built_with(prepared, tmp_path):
    """``built_with`` records every extraction (as tuned to the sensor) and fusion parameter, defaults included;
    ``mismatch`` names each spec field and parameter that differs, and a suite that recorded none."""
    from dataclasses import asdict, replace

    from reloc.evaluation.prepared_io import built_with, mismatch
    from reloc.extraction import ExtractionParams
    from reloc.mapping import MappingParams

    spec = prepared.spec  # ground-truth planes: no extraction to record
    params = built_with(spec)
    assert params["extraction"] is None
    assert params["mapping"] == json.loads(json.dumps(asdict(MappingParams())))
    extracted = replace(spec, plane_source="extraction")
    tuned = built_with(extracted)["extraction"]
    assert (tuned["noise_model"], tuned["noise_coeff"], tuned["voxel_size_m"]) == ("kinect", 1.425e-3, 0.25)
    save_prepared(tmp_path / "s", prepared, {"params": params})
    loaded, meta = load_prepared(tmp_path / "s")
    assert mismatch(loaded, meta, spec, built_with(spec)) == []
    other = replace(spec, query_seed=7, map_seed=5)
    assert mismatch(loaded, meta, other, built_with(other, mapping=MappingParams(fuse_max_offset_m=0.05))) == [
        "map_seed: saved 1, asked 5",
        "query_seed: saved 101, asked 7",
        "mapping.fuse_max_offset_m: saved 0.03, asked 0.05",
    ]
    assert mismatch(loaded, meta, extracted, built_with(extracted)) == [
        "plane_source: saved 'oracle', asked 'extraction'", f"extraction: saved None, asked {tuned!r}"]
    # Between two extracted suites, each parameter that differs is named (a default changed since counts too).
    meta_ext = {"params": built_with(extracted)}
    ext = ExtractionParams(voxel_size_m=0.3, min_points_per_voxel=20)
    assert mismatch(replace(loaded, spec=extracted), meta_ext, extracted, built_with(extracted, ext)) == [
        "extraction.min_points_per_voxel: saved 12, asked 20", "extraction.voxel_size_m: saved 0.25, asked 0.3"]
    assert mismatch(loaded, {}, spec, params) == [
        "no parameters recorded (saved by an older version): prepare it again"]
    # The layer merge is compared as it acts: a suite saved when its default was 0.0 is the one asked for now (null)
    # with every sensor but stereo, where null means 0.5.
    old = json.loads(json.dumps(meta_ext))
    old["params"]["extraction"]["layer_min_shared"] = 0.0
    assert built_with(extracted)["extraction"]["layer_min_shared"] is None
    assert mismatch(replace(loaded, spec=extracted), old, extracted, built_with(extracted)) == []
    stereo = replace(extracted, noise="stereo", camera="oak-d", width=640, height=400)
    old_stereo = {"params": built_with(stereo)}
    old_stereo["params"]["extraction"]["layer_min_shared"] = 0.0
    assert mismatch(replace(loaded, spec=stereo), old_stereo, stereo, built_with(stereo)) == [
        "extraction.layer_min_shared: saved 0.0, asked 0.5"]
    assert mismatch(replace(loaded, spec=stereo), {"params": built_with(stereo)}, stereo, built_with(stereo)) == []


def test_the_decision_latency_benchmark_times_every_query_of_a_saved_suite(saved, monkeypatch, capsys):
    """benchmarks/decision_latency.py relocalizes every query of the suite (positives and negatives in each scene's
    map, as reloc eval does) with ours and each variant, and records per matcher and stage the times of as many
    queries; a bad variant is refused before anything is timed."""
    from pathlib import Path

    bench = Path(__file__).resolve().parents[1] / "benchmarks"
    monkeypatch.syspath_prepend(str(bench))
    import _common
    from decision_latency import STAGES, main

    monkeypatch.setattr(_common, "RESULTS_DIR", saved.parent)
    assert main(["--prepared", str(saved), "--variant", "hidden_rival_credit=True", "--repeats", "2",
                 "--name", "dl"]) == 0
    res = json.loads((saved.parent / "dl.json").read_text())["results"]
    loaded, _ = load_prepared(saved)
    n = sum(len(loaded.queries_in(scene)) for scene in loaded.spec.scenes)
    assert n == sum(len(qs) + loaded.spec.negatives_per_scene for qs in loaded.queries.values())
    assert set(res) == {"ours", "ours with hidden_rival_credit=True"}
    for r in res.values():
        assert r["queries"] == n == 12
        assert set(r["ms"]) == set(STAGES) and r["ms"]["total"]["median"] > 0
    assert "12 queries, fastest of 2 passes each" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["--prepared", str(saved), "--variant", "no_such_setting=1"])
    assert "no_such_setting" in capsys.readouterr().err


def test_queries_saved_into_one_file_load_back_as_they_were(prepared, tmp_path):
    """``save_queries`` / ``load_queries`` (how ``reloc demo``'s helper hands its queries over, without pickle):
    every field and array as it was; a truncated file, a file that is not an archive and another format version
    are named."""
    queries = prepared.queries["office"]
    path = save_queries(tmp_path / "q.npz", queries)
    back = load_queries(path)
    assert len(back) == len(queries) >= 4
    for a, b in zip(queries, back):
        assert (a.scene, a.name, a.ambiguous, a.frames_left_out, a.window_frames, a.timings_ms) == (
            b.scene, b.name, b.ambiguous, b.frames_left_out, b.window_frames, b.timings_ms)
        np.testing.assert_array_equal(a.T_world_cam, b.T_world_cam)
        for key, value in a.submap.to_arrays().items():
            np.testing.assert_array_equal(value, b.submap.to_arrays()[key], err_msg=key)
    assert load_queries(save_queries(tmp_path / "none.npz", [])) == []
    data = path.read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(PreparedSuiteError, match=r"cut\.npz: unreadable queries"):
        load_queries(tmp_path / "cut.npz")
    (tmp_path / "pickle.npz").write_bytes(b"\x80\x04K\x01.")
    with pytest.raises(PreparedSuiteError, match=r"pickle\.npz.*not an \.npz \(zip\) archive"):
        load_queries(tmp_path / "pickle.npz")
    with pytest.raises(PreparedSuiteError, match=r"nowhere\.npz: missing"):
        load_queries(tmp_path / "nowhere.npz")
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    listing = json.loads(str(arrays["listing"]))
    listing["format_version"] = 99
    arrays["listing"] = np.array(json.dumps(listing))
    np.savez(tmp_path / "old.npz", **arrays)
    with pytest.raises(PreparedSuiteError, match="format version 99"):
        load_queries(tmp_path / "old.npz")
