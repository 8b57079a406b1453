"""The profiler's statistics against known durations, and its trace in the Chrome trace event format."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest

from reloc.profiling import Profiler


def test_percentiles_and_shares_from_recorded_durations():
    prof = Profiler()
    for i in range(1, 101):  # 1..100 ms
        prof.record("extract", 0, i * 1_000_000)
    prof.record("match", 0, 5050 * 1_000_000)  # same total as extract
    s = prof.summary()["stages"]
    assert s["extract"]["count"] == 100
    assert s["extract"]["p50_ms"] == pytest.approx(np.percentile(np.arange(1, 101), 50))
    assert s["extract"]["p99_ms"] == pytest.approx(np.percentile(np.arange(1, 101), 99))
    assert s["extract"]["max_ms"] == pytest.approx(100.0)
    assert s["extract"]["share"] == pytest.approx(0.5)
    assert s["match"]["share"] == pytest.approx(0.5)


def test_waits_and_end_to_end_spans_get_no_share_of_the_work():
    """``capture.wait`` and ``latency.*`` are not parts of a recorded stage: their share is NaN (``reloc run`` printed
    292 % for the capture wait); a part of a recorded stage keeps its share of the top-level total."""
    prof = Profiler()
    prof.record("extract", 0, 8_000_000)
    prof.record("extract.refine", 0, 2_000_000)
    prof.record("reloc", 0, 2_000_000)
    prof.record("capture.wait", 0, 30_000_000)
    prof.record("latency.capture_to_planes", 0, 12_000_000)
    s = prof.summary()["stages"]
    assert s["extract"]["share"] == pytest.approx(0.8)
    assert s["extract.refine"]["share"] == pytest.approx(0.2)
    assert np.isnan(s["capture.wait"]["share"]) and np.isnan(s["latency.capture_to_planes"]["share"])
    assert s["capture.wait"]["p50_ms"] == pytest.approx(30.0)  # still timed
    table = prof.table().splitlines()
    assert "%" not in next(line for line in table if line.startswith("capture.wait"))
    # Against a named total every stage is a share of it.
    assert prof.summary("extract")["stages"]["capture.wait"]["share"] == pytest.approx(30 / 8)


def test_window_bounds_memory_but_counts_stay_exact():
    prof = Profiler(window=10)
    for i in range(1000):
        prof.record("s", 0, i)
    st = prof.summary()["stages"]["s"]
    assert st["count"] == 1000
    assert st["max_ms"] == pytest.approx(999 / 1e6)
    assert st["p50_ms"] == pytest.approx(np.percentile(np.arange(990, 1000), 50) / 1e6)


def test_add_timings_lays_stages_back_to_back():
    prof = Profiler(trace_capacity=16)
    prof.add_timings_ms({"backproject": 1.0, "voxelize": 2.0}, prefix="extract.", end_ns=10_000_000)
    ev = [e for e in prof.chrome_trace()["traceEvents"] if e["ph"] == "X"]
    assert [e["name"] for e in ev] == ["extract.backproject", "extract.voxelize"]
    assert ev[0]["dur"] == pytest.approx(1000.0) and ev[1]["dur"] == pytest.approx(2000.0)
    assert ev[0]["ts"] + ev[0]["dur"] == pytest.approx(ev[1]["ts"])
    # Sub-stages (with a dot) do not count toward the top-level total.
    assert np.isnan(prof.summary()["stages"]["extract.voxelize"]["share"])


def test_trace_has_one_track_per_thread_and_is_valid_json(tmp_path):
    prof = Profiler(trace_capacity=100)

    def work(name):
        with prof.stage(f"{name}.step"):
            pass

    threads = [threading.Thread(target=work, args=(n,), name=n) for n in ("capture", "processing")]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    path = tmp_path / "trace.json"
    prof.write_chrome_trace(path)
    data = json.loads(path.read_text())
    tracks = {e["args"]["name"]: e["tid"] for e in data["traceEvents"] if e["name"] == "thread_name"}
    assert set(tracks) == {"capture", "processing"}
    by_name = {e["name"]: e for e in data["traceEvents"] if e["ph"] == "X"}
    assert by_name["capture.step"]["tid"] == tracks["capture"]
    assert by_name["processing.step"]["tid"] == tracks["processing"]


def test_trace_keeps_the_newest_events():
    prof = Profiler(trace_capacity=3)
    for i in range(5):
        prof.record(f"s{i}", i * 1000, 10)
    names = [e["name"] for e in prof.chrome_trace()["traceEvents"] if e["ph"] == "X"]
    assert names == ["s2", "s3", "s4"]


def test_disabled_profiler_records_nothing_and_compile_time_is_apart():
    prof = Profiler(enabled=False)
    with prof.stage("x"):
        pass
    assert prof.summary()["stages"] == {}
    on = Profiler()
    on.note_compile(2.5)
    with on.stage("x"):
        pass
    s = on.summary()
    assert s["compile_s"] == 2.5 and s["stages"]["x"]["max_ms"] < 2500


def test_add_timings_places_parts_inside_their_parent():
    """``"decide.density"`` with ``"decide"`` given is part of it: inside its span, not after it."""
    prof = Profiler(trace_capacity=16)
    prof.add_timings_ms({"decide.density": 0.5, "verify": 1.0, "decide": 2.0, "decide.weights": 0.25},
                        prefix="reloc.", end_ns=10_000_000)
    ev = {e["name"]: e for e in prof.chrome_trace()["traceEvents"] if e["ph"] == "X"}
    assert ev["reloc.verify"]["ts"] + ev["reloc.verify"]["dur"] == pytest.approx(ev["reloc.decide"]["ts"])
    end_us = ev["reloc.verify"]["ts"] + 3000.0  # top-level stages only: 1 + 2 ms, ending at end_ns
    assert ev["reloc.decide"]["ts"] + ev["reloc.decide"]["dur"] == pytest.approx(end_us)
    assert ev["reloc.decide.density"]["ts"] == pytest.approx(ev["reloc.decide"]["ts"])
    assert ev["reloc.decide.weights"]["ts"] == pytest.approx(ev["reloc.decide"]["ts"] + 500.0)
    assert ev["reloc.decide.weights"]["dur"] == pytest.approx(250.0)
    # A part of a part goes inside its parent's span (it raised KeyError, with the stages before it recorded).
    deep = Profiler(trace_capacity=16)
    deep.add_timings_ms({"decide.density.kde": 0.4, "decide": 2.0, "decide.weights": 0.25, "decide.density": 1.0},
                        end_ns=10_000_000)
    ev = {e["name"]: e for e in deep.chrome_trace()["traceEvents"] if e["ph"] == "X"}
    assert ev["decide.weights"]["ts"] == pytest.approx(ev["decide"]["ts"])
    assert ev["decide.density"]["ts"] == pytest.approx(ev["decide"]["ts"] + 250.0)
    assert ev["decide.density.kde"]["ts"] == pytest.approx(ev["decide.density"]["ts"])
    assert ev["decide.density.kde"]["dur"] == pytest.approx(400.0)
    assert deep.summary()["stages"]["decide.density.kde"]["count"] == 1


def test_snapshot_gives_counts_totals_and_the_windowed_samples():
    prof = Profiler(window=4)
    for i in range(1, 7):
        prof.record("a", 0, i)
    count, total_ns, samples = prof.snapshot()["a"]
    assert count == 6 and total_ns == 21
    assert sorted(samples.tolist()) == [3, 4, 5, 6]  # the latest 4
