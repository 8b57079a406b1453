"""The live loop under injected camera faults (drivers.faults): it survives every one, and what it counts matches
exactly what was injected. Small simulated frames, ground-truth planes, the real relocalizer."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from drivers.faults import FaultySource, SourceDisconnected
from drivers.sim_source import SimSource
from reloc.live.factory import TruthPlanes, load_plane_map
from reloc.live.loop import THREAD_NAMES, LiveLoop
from reloc.live.params import LiveParams
from reloc.matching import Relocalizer


def sim_source(n_frames: int) -> SimSource:
    return SimSource("living_room", n_frames=n_frames, camera="oak-d", width=160, height=100, rate="fast")


@pytest.fixture(scope="module")
def living_room_map():
    planes, plane_map = load_plane_map("sim:living_room")
    reloc = Relocalizer(plane_map)
    # Compile the matcher's kernels now: on a cold numba cache the first query takes seconds, and a pending
    # relocalization is (rightly) replaced by a newer one, which would change which triggers are recorded.
    src = sim_source(1)
    reloc.locate(TruthPlanes(src.scene)(next(iter(src))).planes)
    return planes, reloc


# -- the wrapper alone -------------------------------------------------------------------------------------------


def test_faulty_source_is_seeded_and_counts_what_it_injects():
    def run(seed):
        src = FaultySource(sim_source(60), drop_rate=0.1, invalid_rate=0.1, stall_rate=0.05, stall_s=0.0, seed=seed)
        seqs, invalid = [], []
        for f in src:
            seqs.append(f.seq)
            if not np.any(f.depth_m > 0):
                invalid.append(f.seq)
        return src, seqs, invalid

    a, seqs_a, invalid_a = run(7)
    b, seqs_b, _ = run(7)
    c, seqs_c, _ = run(8)
    assert seqs_a == seqs_b and a.injected == b.injected and seqs_a != seqs_c
    assert a.counts["frames_in"] == 60 and a.counts["frames_out"] == len(seqs_a) == 60 - a.counts["dropped"]
    assert sorted(set(range(60)) - set(seqs_a)) == a.injected["dropped"]
    assert invalid_a == a.injected["invalid"] and a.counts["invalid"] == len(invalid_a) > 0
    assert a.counts["stalls"] == len(a.injected["stalls"]) > 0


def test_faults_at_stated_frames():
    src = FaultySource(sim_source(12), drop_at=[2, 7], invalid_at=[4], stall_at=[5], stall_s=0.0)
    frames = list(src)
    assert [f.seq for f in frames] == [0, 1, 3, 4, 5, 6, 8, 9, 10, 11]
    assert [f.seq for f in frames if not np.any(f.depth_m > 0)] == [4]
    assert src.injected == {"dropped": [2, 7], "stalls": [5], "invalid": [4], "disconnects": []}
    assert src.noise_law() == src.inner.noise_law() and src.noise_law()[0] == "stereo"  # the camera's, passed on


def test_disconnect_then_reconnect_resumes_the_stream():
    src = FaultySource(sim_source(20), disconnect_at=[5, 12], reconnect_failures=1)
    seqs = []
    it = iter(src)
    while True:
        try:
            seqs.extend(f.seq for f in it)
            break
        except SourceDisconnected:
            assert not src.connected
            with pytest.raises(SourceDisconnected):
                next(iter(src))
            assert src.reconnect() is False  # the first attempt fails (device not back yet)
            assert src.reconnect() is True
            it = iter(src)
    assert seqs == [s for s in range(20) if s not in (5, 12)]  # the frame in flight is lost, the rest resumes
    assert src.counts["disconnects"] == src.counts["reconnects"] == 2 and src.counts["reconnect_failures"] == 2
    assert src.injected["disconnects"] == [5, 12]


def test_bad_parameters_are_named():
    with pytest.raises(ValueError, match="drop_rate"):
        FaultySource(sim_source(2), drop_rate=1.5)
    with pytest.raises(ValueError, match="inner"):
        FaultySource([1, 2, 3])
    with pytest.raises(ValueError, match="disconnect_at"):
        FaultySource(sim_source(2), disconnect_at=[-1])
    with pytest.raises(ValueError, match="stall_at"):
        FaultySource(sim_source(2), stall_at=[-3])


# -- the loop under faults ---------------------------------------------------------------------------------------


def test_loop_survives_every_fault_with_matching_counts(living_room_map):
    map_planes, reloc = living_room_map
    src = FaultySource(sim_source(120), drop_rate=0.05, invalid_rate=0.05, stall_rate=0.03, stall_s=0.3,
                       disconnect_at=[20, 45], reconnect_failures=1, seed=3)
    params = LiveParams(queue_frames=1000, stall_s=0.2, reconnect_backoff_s=(0.01,), search_period_s=0.01)
    loop = LiveLoop(src, TruthPlanes(src.inner.scene), reloc, params=params, map_planes=map_planes)
    summary = loop.run()
    src.close()
    assert [t for t in threading.enumerate() if t.name in THREAD_NAMES] == []
    c, f, ev = src.counts, summary.frames, summary.source_events
    assert c["dropped"] > 0 and c["invalid"] > 0 and c["stalls"] > 0 and c["disconnects"] == 2
    # Every frame the source delivered was captured and processed (the queue is large enough to drop none).
    assert f["captured"] == f["processed"] == c["frames_out"] and f["dropped"] == 0
    # Missing sequence numbers are exactly the dropped frames plus the frames lost in the disconnects
    # (except any dropped after the last delivered frame, which no gap can reveal).
    last = max(s for s in range(120) if s not in src.injected["dropped"] + src.injected["disconnects"])
    missing = [s for s in src.injected["dropped"] + src.injected["disconnects"] if s < last]
    assert f["source_gaps"] == len(missing)
    # All-invalid frames are counted by reason and skipped.
    assert f["bad"] == {"no_valid_depth": c["invalid"]} and f["with_planes"] == f["processed"] - c["invalid"]
    assert ev["disconnects"] == ev["reconnects"] == 2 and ev["reconnect_failures"] == 2 and ev["end"] == "end_of_stream"
    # Each injected stall (0.3 s) is seen as a gap over the 0.2 s threshold; no other gap comes near that here.
    assert ev["stalls"] >= c["stalls"]
    assert summary.faults == c
    # And the loop still relocalizes correctly after the faults (single views of this walk relocalize up to about
    # seq 58; later ones are rightly rejected as ambiguous or with too few planes).
    ok = [r for r in summary.relocalizations if r.ok]
    assert [r.seq > 45 for r in summary.relocalizations if "reconnect" in r.trigger] == [False, True]
    assert ok and max(r.seq for r in ok) > 45
    assert all(r.position_error_m < 0.1 and r.rotation_error_deg < 2.0 for r in ok)


def test_a_source_that_cannot_reconnect_ends_the_run_cleanly(living_room_map):
    map_planes, reloc = living_room_map

    class NoReconnect(FaultySource):
        reconnect = None  # a source without reconnect support

    src = NoReconnect(sim_source(40), disconnect_at=[10])
    loop = LiveLoop(src, TruthPlanes(src.inner.scene), reloc, params=LiveParams(queue_frames=100),
                    map_planes=map_planes)
    summary = loop.run()
    assert summary.source_events["end"] == "disconnected" and summary.source_events["disconnects"] == 1
    assert summary.frames["processed"] == 10 and summary.errors == []
    assert [t for t in threading.enumerate() if t.name in THREAD_NAMES] == []
