"""The live loop on the simulator: relocalization against ground truth, the bounded queue, bad frames, triggers,
clean shutdown. Small images (160x100), ground-truth planes in place of extraction (so a pose error is the loop's,
not the extractor's), the real relocalizer, no wall-clock asserts."""

from __future__ import annotations

import json
import threading
import time
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from drivers.sim_source import SimSource
from drivers.source import FrameSource
from reloc.live.factory import TruthPlanes, load_plane_map
from reloc.live.frame_queue import DropOldestQueue
from reloc.live.loop import THREAD_NAMES, LiveLoop, _carry_trigger
from reloc.live.params import LiveParams
from reloc.live.submap import SubmapWindow
from reloc.live.tracking import OdometryDrift, explained_fraction, tracked_covariance
from reloc.camera import DepthFrame, Intrinsics
from reloc.matching import Relocalizer
from reloc.planeset import PlaneSet
from reloc.transforms import log_se3, pose_error
from sim.ground_truth import planes_in_camera, visible_planes

W, H = 160, 100
POS_TOL_M, ROT_TOL_DEG = 0.1, 2.0


@pytest.fixture(scope="module")
def living_room_map():
    planes, plane_map = load_plane_map("sim:living_room")
    return planes, Relocalizer(plane_map)


def sim_source(n_frames=60, **kw) -> SimSource:
    kw.setdefault("rate", "fast")
    return SimSource("living_room", n_frames=n_frames, camera="oak-d", width=W, height=H, **kw)


def loop_threads_alive() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name in THREAD_NAMES and t.is_alive()]


def assert_poses_within_tolerance(summary, min_ok=1, truth=None):
    """Every accepted pose within tolerance of the truth of the frame it holds for (``truth``: seq -> T_world_cam,
    else the error the loop computed from the frame's own ground truth)."""
    ok = [r for r in summary.relocalizations if r.ok]
    assert len(ok) >= min_ok, [(r.trigger, r.status, r.reason) for r in summary.relocalizations]
    for r in ok:
        if truth is not None:
            dt, dr = pose_error(r.T_map_cam, truth[r.seq])
        else:
            dt, dr = r.position_error_m, r.rotation_error_deg
        assert dt < POS_TOL_M and dr < ROT_TOL_DEG, r.to_dict()
    return ok


class OdometrySource(FrameSource):
    """Frames of a simulated source whose pose is turned into "odometry", optionally corrupted by ``edit(i, T)``;
    :meth:`truth_planes` gives ground-truth planes from the true pose (kept in ``truth``)."""

    def __init__(self, inner: SimSource, edit=None):
        super().__init__()
        self.inner, self.edit, self.name = inner, edit, f"odometry({inner.name})"
        self.truth: dict[int, np.ndarray] = {}

    @property
    def intrinsics(self):
        return self.inner.intrinsics

    def _frames(self):
        for f in self.inner:
            self.truth[f.seq] = f.T_world_cam
            T = f.T_world_cam if self.edit is None else self.edit(f.seq, f.T_world_cam)
            yield replace(f, T_world_cam=T, pose_source="odometry")

    def truth_planes(self):
        planes = TruthPlanes(self.inner.scene)
        return lambda f: planes(replace(f, T_world_cam=self.truth[f.seq]))


# -- pieces ------------------------------------------------------------------------------------------------------


def test_drop_oldest_queue_keeps_the_newest_and_counts_the_rest():
    q = DropOldestQueue(4)
    evicted = [q.put(i) for i in range(10)]
    assert evicted == [None] * 4 + [0, 1, 2, 3, 4, 5]
    assert q.dropped == 6 and q.put_count == 10 and q.max_depth == 4 and len(q) == 4
    assert [q.get(0) for _ in range(4)] == [6, 7, 8, 9]
    assert q.get(0) is None and not q.finished
    q.put(10)
    q.close()
    assert q.get(0) == 10 and q.get(0) is None and q.finished
    with pytest.raises(ValueError, match="maxlen"):
        DropOldestQueue(0)


def test_submap_window_moves_every_frame_into_the_newest_camera():
    src = sim_source(30)
    frames = list(src)[::10]  # frames 0, 10, 20: the robot moved in between
    window = SubmapWindow(3)
    for f in frames:
        window.push(visible_planes(f, src.scene), f.T_world_cam, f.seq)
    submap = window.build()
    sizes = [len(visible_planes(f, src.scene)) for f in frames]
    assert len(submap) == sum(sizes) and window.seqs == [0, 10, 20]
    # Every row is an exact scene plane seen from the newest camera (up to orientation).
    n_true, d_true = planes_in_camera(src.scene, frames[-1].T_world_cam)
    for n, d in zip(submap.normals, submap.offsets):
        err = np.minimum(np.abs(n_true @ n - 1) + np.abs(d_true - d), np.abs(n_true @ n + 1) + np.abs(d_true + d))
        assert err.min() < 1e-9
    # The samples moved too: they lie on their planes.
    for i in range(len(submap)):
        s = submap.samples_of(i).astype(np.float64)
        assert np.abs(s @ submap.normals[i] + submap.offsets[i]).max() < 1e-4
    # A frame without odometry restarts the window.
    window.push(visible_planes(frames[0], src.scene), None, 99)
    assert window.seqs == [99] and len(window.build()) == sizes[0]
    # A fusing function (e.g. reloc.mapping.build_submap) gets the window's plane sets and poses, oldest first.
    calls = []
    fused = SubmapWindow(2, fuse=lambda sets, poses: calls.append((sets, poses)) or sets[-1])
    for f in frames:
        fused.push(visible_planes(f, src.scene), f.T_world_cam, f.seq)
    assert fused.build() is calls[0][0][-1] and len(calls[0][0]) == 2
    assert np.array_equal(calls[0][1][0], frames[1].T_world_cam)
    assert np.array_equal(calls[0][1][1], frames[2].T_world_cam)


def test_explained_fraction_separates_right_and_wrong_poses(living_room_map):
    map_planes, _ = living_room_map
    src = sim_source(1)
    f = next(iter(src))
    planes = visible_planes(f, src.scene)
    assert explained_fraction(planes, f.T_world_cam, map_planes, max_angle_rad=0.09, max_offset_m=0.08) == 1.0
    off = f.T_world_cam.copy()
    off[:3, 3] += [0.4, -0.3, 0.0]
    assert explained_fraction(planes, off, map_planes, max_angle_rad=0.09, max_offset_m=0.08) < 0.5


def test_a_tracked_pose_keeps_its_references_covariance_and_adds_the_odometrys_drift_across_the_floor():
    cov_ref = np.diag([4e-6, 5e-6, 6e-6, 1e-6, 2e-6, 3e-6])
    drift = OdometryDrift(m_per_m=0.02, rad_per_m=0.0, rad_per_rad=0.01, rad_per_s=0.002)
    up = np.array([0.0, 0.0, 1.0])
    # Before any motion the reference's covariance, unchanged.
    np.testing.assert_array_equal(tracked_covariance(cov_ref, [2.0, 0.0, 0.0], up, 0.0, 0.0, 0.0, drift), cov_ref)
    # After 2 m, 1 rad and 10 s: heading sigma hypot(0.01 * 1, 0.002 * 10) = 0.02236 rad; position sigma
    # hypot(0.02 * 2, 0.02236 * 2 / 2) = 0.04583 m, across the floor only.
    heading, position = np.hypot(0.01, 0.02), np.hypot(0.04, np.hypot(0.01, 0.02))
    assert drift.sigmas(2.0, 1.0, 10.0) == pytest.approx((position, heading), rel=1e-12)
    Q = tracked_covariance(cov_ref, [2.0, 0.0, 0.0], up, 2.0, 1.0, 10.0, drift) - cov_ref
    assert Q[0, 0] == pytest.approx(position**2, rel=1e-12)
    assert np.all(Q[2] == 0) and np.all(Q[3:5] == 0)  # no drift up, in roll or in pitch
    assert Q[5, 5] == pytest.approx(heading**2, rel=1e-12)
    # A heading error turns the pose about the camera (2 m along x), not about the map's origin: in the left
    # perturbation, the rotation e about z through p is rho = p x (0, 0, e), phi = (0, 0, e).
    e = 0.01
    T_turn = np.eye(4)
    T_turn[:2, :2] = [[np.cos(e), -np.sin(e)], [np.sin(e), np.cos(e)]]
    T_turn[:3, 3] = np.array([2.0, 0.0, 0.0]) - T_turn[:3, :3] @ [2.0, 0.0, 0.0]
    J = log_se3(T_turn) / e
    np.testing.assert_allclose(J, [0.0, -2.0, 0.0, 0.0, 0.0, 1.0], atol=0.02)
    np.testing.assert_allclose(Q, position**2 * np.diag([1.0, 1.0, 0, 0, 0, 0]) + heading**2 * np.outer(J, J),
                               rtol=0.02, atol=1e-9)
    # The floor is the plane across the map's up, whichever it is.
    Qy = tracked_covariance(cov_ref, [0.0, 2.0, 0.0], [0.0, 1.0, 0.0], 2.0, 1.0, 10.0, drift) - cov_ref
    assert Qy[1, 1] == pytest.approx(0.0, abs=1e-15) and Qy[4, 4] == pytest.approx(heading**2, rel=1e-12)
    with pytest.raises(ValueError, match="rad_per_s"):
        OdometryDrift(rad_per_s=-0.1)


def test_the_odometrys_drift_comes_from_the_config_in_degrees():
    from reloc.config import config_from_dict

    cfg = config_from_dict({"live": {"odometry_drift_m_per_m": 0.05, "odometry_heading_drift_deg_per_s": 1.0,
                                     "odometry_heading_drift_deg_per_m": 2.0}})
    d = LiveParams.from_config(cfg).odometry_drift
    assert (d.m_per_m, d.rad_per_rad) == (0.05, 0.01)
    assert d.rad_per_s == pytest.approx(np.radians(1.0)) and d.rad_per_m == pytest.approx(np.radians(2.0))


# -- the loop ----------------------------------------------------------------------------------------------------


def test_loop_relocalizes_on_the_simulator_with_odometry_submaps(living_room_map):
    map_planes, reloc = living_room_map
    src = OdometrySource(sim_source(60))
    truth = src.truth_planes()

    def extract(frame):  # ask for relocalizations at fixed frames (requests are served with the current frame)
        if frame.seq in (12, 30, 48):
            loop.request_relocalization("manual")
        return truth(frame)

    params = LiveParams(queue_frames=1000, window_frames=3, reloc_period_s=1000.0)
    loop = LiveLoop(src, extract, reloc, params=params, map_planes=map_planes)
    summary = loop.run()
    assert loop_threads_alive() == []
    f = summary.frames
    assert f["captured"] == f["processed"] == f["with_planes"] == 60 and f["dropped"] == 0 and f["bad"] == {}
    assert summary.odometry["used"] == {"source:odometry": 60}
    assert summary.relocalizations[0].trigger == "startup"
    # The pose holds for the newest frame of the submap.
    ok = assert_poses_within_tolerance(summary, min_ok=2, truth=src.truth)
    manual = [r for r in ok if "manual" in r.trigger]
    assert manual and all(r.submap_frames == 3 and r.seq in (12, 30, 48) for r in manual)
    d = summary.to_dict()
    assert d["frames"]["captured"] == 60 and d["relocalizations"][0]["T_map_cam"] is not None
    assert "extract" in d["latency_ms"] and d["end_to_end_ms"]["capture_to_planes"]["count"] == 60
    # Waiting for the camera is timed but is no share of the work; the summary stays strict JSON.
    assert d["latency_ms"]["capture.wait"]["share"] is None and 0 < d["latency_ms"]["extract"]["share"] <= 1
    json.dumps(d, allow_nan=False)


def test_a_window_that_cannot_pin_a_pose_grows_when_a_relocalization_asks_for_it():
    from helpers import corridor_walk
    from reloc.config import config_from_dict
    from reloc.live.factory import SubmapFuser
    from reloc.mapping import MappingParams, build_submap

    Ts, sets = corridor_walk(40)  # the newest frames see floor, ceiling and two walls; the oldest a cabinet too
    fuser = SubmapFuser(MappingParams())
    window = SubmapWindow(10, fuse=fuser, max_frames=40, grow=fuser.grow)
    fixed = SubmapWindow(10, fuse=fuser)
    for k, (planes, T) in enumerate(zip(sets, Ts)):
        window.push(planes, T, k)
        fixed.push(planes, T, k)
    assert len(window) == 40 and len(fixed) == 10
    assert len(fixed.build()) == 4 and fixed.last_frames == 10
    grown = window.build()
    assert window.last_frames == 35 and len(grown) == 6
    np.testing.assert_allclose(grown.offsets, build_submap(sets[-35:], Ts[-35:], MappingParams()).offsets,
                               atol=1e-12)
    with pytest.raises(ValueError, match="grow: expected a callable"):
        SubmapWindow(10, max_frames=40)
    with pytest.raises(ValueError, match="max_frames: expected 0"):
        SubmapWindow(10, max_frames=5, grow=fuser.grow)
    cfg = config_from_dict({"mapping": {"submap_window_frames": 10, "submap_max_window_frames": 40}})
    assert LiveParams.from_config(cfg).max_window_frames == 40


def test_loop_without_odometry_uses_single_frame_submaps(living_room_map):
    map_planes, reloc = living_room_map
    src = sim_source(20)  # ground-truth poses are not odometry: "auto" ignores them
    loop = LiveLoop(src, TruthPlanes(src.scene), reloc, params=LiveParams(queue_frames=100, window_frames=4),
                    map_planes=map_planes)
    summary = loop.run()
    assert summary.odometry["used"] == {"none": 20}
    assert all(r.submap_frames == 1 for r in summary.relocalizations)
    assert_poses_within_tolerance(summary)


def test_bounded_queue_drops_the_oldest_frames_when_processing_falls_behind(living_room_map):
    map_planes, reloc = living_room_map
    src = sim_source(40)
    truth = TruthPlanes(src.scene)
    gate = threading.Event()
    seen = []

    def slow_extract(frame):
        seen.append(frame.seq)
        if len(seen) == 1:
            gate.wait(10.0)  # hold the first frame until the source has delivered everything
        return truth(frame)

    loop = LiveLoop(src, slow_extract, reloc, params=LiveParams(queue_frames=3), map_planes=map_planes)
    watcher = threading.Thread(target=lambda: (_wait(lambda: loop.captured == 40), gate.set()))
    watcher.start()
    summary = loop.run()
    watcher.join()
    f = summary.frames
    assert f["captured"] == 40 and f["processed"] + f["dropped"] == 40
    # Processing held its first frame until capture was done: of the rest only the newest three were kept, in order.
    assert len(seen) == 4 and seen[0] < 37 and seen[1:] == [37, 38, 39]
    assert f["dropped"] == 40 - 4 and f["queue_max_depth"] == 3
    assert loop_threads_alive() == []


def _wait(cond, timeout_s=20.0):
    end = time.monotonic() + timeout_s
    while not cond() and time.monotonic() < end:
        time.sleep(0.005)


def test_a_bad_frame_is_counted_and_skipped(living_room_map):
    map_planes, reloc = living_room_map
    src = sim_source(30)
    truth = TruthPlanes(src.scene)

    def flaky(frame):
        if frame.seq in (5, 17):
            raise ValueError(f"corrupt frame {frame.seq}")
        if frame.seq == 9:
            return "not a result"
        if frame.seq == 13:  # planes, but timings that break the bookkeeping after extraction
            return SimpleNamespace(planes=truth(frame).planes, timings_ms=None)
        return truth(frame)

    loop = LiveLoop(src, flaky, reloc, params=LiveParams(queue_frames=100), map_planes=map_planes)
    summary = loop.run()
    f = summary.frames
    assert f["processed"] == 30 and f["with_planes"] == 26
    assert f["bad"] == {"extraction_error:ValueError": 2, "extraction_error:AttributeError": 1,
                        "processing_error:AttributeError": 1}
    assert_poses_within_tolerance(summary)


def test_a_failing_relocalizer_is_a_rejection_not_a_crash(living_room_map):
    map_planes, reloc = living_room_map

    class Broken:
        def locate(self, submap):
            raise RuntimeError("index corrupted")

    src = sim_source(10)
    loop = LiveLoop(src, TruthPlanes(src.scene), Broken(), params=LiveParams(queue_frames=100, search_period_s=0.001),
                    map_planes=map_planes)
    summary = loop.run()
    assert summary.frames["processed"] == 10 and summary.relocalizations
    assert all(r.status == "error" and "index corrupted" in r.reason for r in summary.relocalizations)
    assert summary.tracking["final_state"] == "searching" and summary.errors == []


def test_odometry_jump_and_disagreement_trigger_relocalization(living_room_map):
    map_planes, reloc = living_room_map

    def kidnap(seq, T):  # odometry jumps by 2 m at frame 25, then freezes from frame 45 on
        T = T.copy()
        if seq >= 25:
            T[0, 3] += 2.0
        return T

    src = OdometrySource(sim_source(90), edit=kidnap)
    params = LiveParams(queue_frames=1000, window_frames=1, reloc_period_s=1000.0, lost_frames=3)
    loop = LiveLoop(src, src.truth_planes(), reloc, params=params, map_planes=map_planes)
    summary = loop.run()
    assert summary.odometry["jumps"] == 1 and summary.tracking["lost"].get("odometry_jump") == 1
    after = [r for r in summary.relocalizations if "odometry_jump" in r.trigger]
    assert after and after[0].seq == 25  # relocalization asked at the frame of the jump...
    assert any(r.ok for r in summary.relocalizations if r.seq >= 25)  # ...and found again (retries while lost)
    assert_poses_within_tolerance(summary, min_ok=2, truth=src.truth)

    frozen = {}

    def freeze(seq, T):  # odometry stops while the robot keeps moving: the planes stop agreeing with the map
        if seq >= 20:
            return frozen.setdefault("T", T)
        return T

    src = OdometrySource(sim_source(150), edit=freeze)
    loop = LiveLoop(src, src.truth_planes(), reloc, params=params, map_planes=map_planes)
    summary = loop.run()
    assert summary.tracking["lost"].get("tracking_lost", 0) >= 1, summary.tracking
    lost = [r for r in summary.relocalizations if "tracking_lost" in r.trigger]
    assert lost and lost[0].seq > 20
    assert_poses_within_tolerance(summary, min_ok=2, truth=src.truth)


def test_requests_are_served_and_stop_joins_every_thread(living_room_map):
    map_planes, reloc = living_room_map
    src = sim_source(200, rate=60.0, loop=True)  # paced and endless: only stop() ends it
    lines: list[str] = []
    loop = LiveLoop(src, TruthPlanes(src.scene), reloc, params=LiveParams(reloc_period_s=1000.0, status_period_s=0.05),
                    map_planes=map_planes, on_status=lines.append)

    def driver():
        _wait(lambda: any(r.ok for r in loop.records()))
        loop.request_relocalization("manual")
        _wait(lambda: any("manual" in r.trigger for r in loop.records()) and len(lines) >= 2)
        loop.stop()

    t = threading.Thread(target=driver)
    t.start()
    summary = loop.run()
    t.join()
    src.close()
    assert loop_threads_alive() == []
    assert summary.source_events["end"] == "stopped"
    manual = [r for r in summary.relocalizations if "manual" in r.trigger]
    assert manual and manual[0].ok
    assert lines and "fps" in lines[0] and "last reloc" in lines[-1]


def test_reloc_run_stops_cleanly_on_sigterm(tmp_path):
    """The command as a process: SIGTERM mid-run stops the loop, joins its threads, writes the summary, exits 0."""
    import json
    import os
    import re
    import signal
    import subprocess
    import sys

    out = tmp_path / "summary.json"
    cfg = tmp_path / "c.yaml"
    cfg.write_text("live:\n  status_period_s: 0.1\n")
    proc = subprocess.Popen(
        [sys.executable, "-m", "reloc.cli", "run", "--camera", "sim", "--map", "sim:living_room", "--planes", "truth",
         "--duration", "120", "--summary", str(out), "--config", str(cfg)],
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        for line in proc.stderr:  # a status line after the first frame: the loop runs, the handlers are in place
            m = re.search(r"\| frames (\d+)/", line)
            if m and int(m.group(1)) > 0:
                break
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    s = json.loads(out.read_text())
    assert s["source_events"]["end"] == "stopped" and s["errors"] == []
    assert s["frames"]["captured"] >= s["frames"]["processed"] > 0
    assert "relocalizations:" in stdout


def test_loop_grows_the_window_of_a_relocalization_that_cannot_pin_a_pose(living_room_map):
    """With a fuser that can grow windows (SubmapFuser) and max_window_frames, a relocalization's window grows back
    in time while its submap cannot pin a pose; here none can (50 planes asked for): each grows as far as it may."""
    from reloc.live.factory import SubmapFuser
    from reloc.mapping import MappingParams

    map_planes, reloc = living_room_map
    src = OdometrySource(sim_source(40))
    truth = src.truth_planes()

    def extract(frame):
        if frame.seq in (12, 30):
            loop.request_relocalization("manual")
        return truth(frame)

    fuse = SubmapFuser(MappingParams(submap_grow_min_planes=50))
    params = LiveParams(queue_frames=1000, window_frames=3, max_window_frames=9, reloc_period_s=1000.0)
    loop = LiveLoop(src, extract, reloc, params=params, map_planes=map_planes, fuse_submap=fuse)
    summary = loop.run()
    manual = [r for r in summary.relocalizations if "manual" in r.trigger]
    assert [(r.seq, r.submap_frames) for r in manual] == [(12, 9), (30, 9)]
    assert summary.relocalizations[0].submap_frames == 1  # the first frame: nothing to grow into
    assert_poses_within_tolerance(summary, min_ok=2, truth=src.truth)


def test_loop_with_plane_extraction_and_fused_submaps(living_room_map):
    """The real pipeline: extraction of every 640x400 frame, submaps of 3 frames fused by reloc.mapping, with the
    camera's own noise law in extraction and matching, as ``reloc run`` takes it."""
    from reloc.config import Config
    from reloc.live.factory import make_extractor, make_relocalizer, make_submap_fuser, with_camera_noise

    map_planes, _ = living_room_map
    src = OdometrySource(SimSource("living_room", n_frames=30, camera="oak-d", rate="fast"))
    cfg, _ = with_camera_noise(Config(), src.inner)  # the wrapper adds odometry, not a noise law
    assert cfg.extraction.noise_model == "stereo"
    reloc = make_relocalizer(map_planes, cfg)
    extract = make_extractor(cfg)

    def extract_and_ask(frame):
        if frame.seq in (10, 20, 29):
            loop.request_relocalization("manual")
        return extract(frame)

    fuse = make_submap_fuser(cfg)
    assert fuse is not None
    loop = LiveLoop(src, extract_and_ask, reloc, params=LiveParams(queue_frames=100, window_frames=3,
                                                                 reloc_period_s=1000.0),
                    map_planes=map_planes, fuse_submap=fuse)
    summary = loop.run()
    f = summary.frames
    assert f["processed"] == f["with_planes"] == 30 and f["bad"] == {}
    assert {"backproject", "merge"} <= {k.split(".", 1)[1] for k in summary.latency_ms if k.startswith("extract.")}
    ok = assert_poses_within_tolerance(summary, truth=src.truth)
    assert ok[0].trigger == "startup"
    assert any(r.submap_frames == 3 for r in summary.relocalizations)


def test_reloc_run_replays_a_recording_against_a_map_file(tmp_path):
    """`reloc run --camera replay:DIR --map FILE`: a written sequence, a map saved by reloc.mapping, extraction."""
    import json

    from click.testing import CliRunner

    from drivers.readers import noise_law_entry
    from reloc.cli import cli
    from reloc.mapping import PlaneMap, save_map
    from sim.ground_truth import scene_planes
    from sim.writer import write_sequence

    src = SimSource("living_room", n_frames=12, camera="oak-d", rate="fast")
    # With the camera's noise law, as `reloc sim` writes it: the run extracts and matches for a stereo camera.
    write_sequence(iter(src), src.scene, tmp_path / "seq", metadata={"noise_law": noise_law_entry(src.noise_law())})
    planes, _ = scene_planes(src.scene)
    save_map(tmp_path / "map.npz", PlaneMap(planes, np.ones(len(planes), dtype=np.int64)))
    out = tmp_path / "run.json"
    trace = tmp_path / "run.trace.json"
    result = CliRunner().invoke(cli, ["run", "--camera", f"replay:{tmp_path / 'seq'}", "--map",
                                      str(tmp_path / "map.npz"), "--rate", "fast", "--summary", str(out),
                                      "--trace", str(trace), "--quiet"])
    assert result.exit_code == 0, result.output
    s = json.loads(out.read_text())
    assert s["frames"]["captured"] == 12 and s["source_events"]["end"] == "end_of_stream"
    assert s["config"]["live"]["queue_frames"] == 4 and s["command"]["rate"] == "fast"
    assert s["relocalizations_ok"] >= 1
    for r in s["relocalizations"]:  # the replayed frames carry their ground truth: errors are measured
        if r["status"] == "relocalized":
            assert r["position_error_m"] < POS_TOL_M and r["rotation_error_deg"] < ROT_TOL_DEG
    # The Chrome trace has one track per thread of the loop, each with its stages.
    events = json.loads(trace.read_text())["traceEvents"]
    tracks = {e["tid"]: e["args"]["name"] for e in events if e["name"] == "thread_name"}
    assert {"capture", "processing", "relocalization"} <= set(tracks.values())
    stages = {(tracks[e["tid"]], e["name"].split(".")[0]) for e in events if e["ph"] == "X"}
    assert {("capture", "capture"), ("processing", "extract"), ("relocalization", "reloc")} <= stages


def test_keyboard_enter_relocalizes_and_q_quits(living_room_map, monkeypatch):
    """On a terminal (a pseudo-terminal here), Enter asks for a relocalization and `q` Enter stops the loop."""
    import os
    import sys

    map_planes, reloc = living_room_map
    master, slave = os.openpty()
    tty = os.fdopen(slave, "r")
    monkeypatch.setattr(sys, "stdin", tty)
    src = sim_source(100, rate=60.0, loop=True)
    loop = LiveLoop(src, TruthPlanes(src.scene), reloc, params=LiveParams(reloc_period_s=1000.0), map_planes=map_planes,
                    keyboard=True)

    def typist():
        _wait(lambda: any(r.ok for r in loop.records()))
        os.write(master, b"\n")
        _wait(lambda: any("keypress" in r.trigger for r in loop.records()))
        os.write(master, b"q\n")

    t = threading.Thread(target=typist)
    t.start()
    try:
        summary = loop.run(duration_s=60.0)
    finally:
        t.join()
        src.close()
        tty.close()
        os.close(master)
    assert [r for r in summary.relocalizations if "keypress" in r.trigger][0].ok
    assert summary.source_events["end"] == "stopped"
    assert any("quit requested from the keyboard" in e for e in summary.source_events["events"])
    assert loop_threads_alive() == []


# -- capture and requests under faults (fakes: constant depth, empty planes) --------------------------------------


def _flat_frame(seq: int, depth: float = 2.0) -> DepthFrame:
    intr = Intrinsics(100.0, 100.0, 16.0, 12.0, 32, 24)
    return DepthFrame(np.full((24, 32), depth, np.float32), intr, time.monotonic_ns(), seq)


class _NoPlanes:
    def __init__(self, sleep_s: float = 0.0):
        self.sleep_s = sleep_s

    def __call__(self, frame):
        time.sleep(self.sleep_s)
        return SimpleNamespace(planes=PlaneSet.empty(frame="cam"), timings_ms={})


class _AlwaysLocated:
    def locate(self, submap):
        return SimpleNamespace(status="relocalized", reason="", T_map_cam=np.eye(4), score=1.0)


def test_the_queue_hands_a_dropped_items_trigger_to_the_oldest_left():
    q = DropOldestQueue(2)
    for item in [("f0", 0, "reconnect"), ("f1", 1, None), ("f2", 2, None), ("f3", 3, None)]:
        q.put(item, carry=_carry_trigger)
    assert q.dropped == 2 and [q.get(0), q.get(0)] == [("f2", 2, "reconnect"), ("f3", 3, None)]
    q1 = DropOldestQueue(1)
    q1.put(("f0", 0, "reconnect"), carry=_carry_trigger)
    q1.put(("f1", 1, None), carry=_carry_trigger)
    assert q1.get(0) == ("f1", 1, "reconnect")
    q1.put(("f2", 2, "reconnect"))
    q1.put(("f3", 3, None))  # no carry: dropped with its frame
    assert q1.get(0) == ("f3", 3, None)


def test_a_reconnect_whose_frame_is_dropped_still_resets_odometry_and_relocalizes():
    """After a reconnect the first frame carries the trigger; processing 0.2 s a frame while frames come every 10 ms
    into a queue of 4, that frame is dropped. Its trigger moves to the oldest frame left: the relocalization after
    the gap is asked for (it was lost with the frame, and the odometry chained across the outage)."""
    class Source:
        def __init__(self):
            self.passes = 0

        def info(self):
            return {"name": "fake"}

        def reconnect(self):
            return True

        def __iter__(self):
            self.passes += 1
            first = self.passes == 1

            def frames():
                for s in range(10) if first else range(10, 40):
                    yield _flat_frame(s)
                    time.sleep(0.01)
                if first:
                    raise RuntimeError("usb gone")
            return frames()

    loop = LiveLoop(Source(), _NoPlanes(0.2), _AlwaysLocated(),
                    params=LiveParams(queue_frames=4, reconnect_backoff_s=(0.0,)))
    summary = loop.run()
    assert summary.source_events["reconnects"] == 1 and summary.frames["dropped"] > 4
    assert [r.trigger for r in summary.relocalizations].count("reconnect") == 1


def test_a_firmware_request_is_answered_while_every_frame_is_bad():
    """A covered lens (every frame all zero): a request from the firmware got no answer at all, since bad frames
    counted as frames flowing and never reached the trigger. It is answered not_ready."""
    from firmware_bridge.host import RelocRequestEvent
    from firmware_bridge.messages import PoseStatus

    class Bridge:
        def __init__(self):
            self.t0, self.sent, self.asked = time.monotonic(), [], False

        def get_event(self, timeout_s=0.0):
            if not self.asked and time.monotonic() - self.t0 > 0.5:
                self.asked = True
                return RelocRequestEvent(request_id=7, reason=0, stamp_host_ns=0, rx_ns=0)
            time.sleep(timeout_s)
            return None

        def send_pose(self, T, stamp, *, status=0, score=0.0, request_id=0):
            self.sent.append((request_id, status))

        def send_status(self, *a, **kw):
            pass

        def T_odom_base_at(self, stamp_ns):
            return None

    class Covered:
        def info(self):
            return {"name": "covered"}

        def __iter__(self):
            for s in range(60):
                yield _flat_frame(s, depth=0.0)
                time.sleep(0.033)

    bridge = Bridge()
    summary = LiveLoop(Covered(), _NoPlanes(), _AlwaysLocated(), bridge=bridge).run()
    assert bridge.asked and summary.frames["bad"] == {"no_valid_depth": 60}
    assert [s for i, s in bridge.sent if i == 7] == [PoseStatus.NOT_READY]


def test_a_frame_delivered_late_is_not_counted_missing():
    """Frames 0, 1, 2, 5, 3, 4, 6: nothing is missing (3 were counted before); with 8 and 9 never sent, two are."""

    class Source:
        def info(self):
            return {"name": "late"}

        def __iter__(self):
            for s in (0, 1, 2, 5, 3, 4, 6, 7, 10):
                yield _flat_frame(s)

    summary = LiveLoop(Source(), _NoPlanes(), _AlwaysLocated()).run()
    assert summary.frames["captured"] == 9 and summary.frames["source_gaps"] == 2


def test_a_status_output_that_fails_is_counted_and_the_run_still_ends_on_time(living_room_map):
    """``reloc run`` prints status lines with click.echo to stderr; once the reader of a pipe goes away that raises
    BrokenPipeError. It escaped the main loop, whose shutdown then waited for a processing thread that only the
    source's end stops: an endless source (a camera) ran on past ``duration_s`` for good. Now the failure is
    counted and noted once, and the run ends on time with every thread joined."""
    map_planes, reloc = living_room_map
    src = sim_source(200, rate=60.0, loop=True)  # paced and endless

    def broken(line):
        raise BrokenPipeError(32, "Broken pipe")

    loop = LiveLoop(src, TruthPlanes(src.scene), reloc, params=LiveParams(status_period_s=0.05),
                    map_planes=map_planes, on_status=broken)
    done = {}
    t = threading.Thread(target=lambda: done.update(summary=loop.run(duration_s=1.0)), daemon=True)
    t.start()
    t.join(30.0)
    ended = not t.is_alive()
    if not ended:
        loop.stop()
        t.join(30.0)
    src.close()
    assert ended, "run() did not return within 30 s of a 1 s run"
    assert loop_threads_alive() == []
    s = done["summary"]
    assert s.source_events["status_errors"] >= 2 and s.frames["processed"] > 10
    assert sum("status output failed (BrokenPipeError" in e for e in s.source_events["events"]) == 1


def test_a_rejection_answers_a_request_with_its_own_status():
    """TOO_FEW_PLANES only for the rejection before any search; the relocalizer's other reasons name planes as well
    ("contradicted by the map: 5 planes matched less 3 in conflict") and went out as TOO_FEW_PLANES."""
    from firmware_bridge.messages import PoseStatus
    from reloc.live.loop import _reject_status
    from reloc.matching.relocalizer import too_few_planes_reason

    cases = {
        too_few_planes_reason(3, 80, 5): PoseStatus.TOO_FEW_PLANES,
        too_few_planes_reason(12, 2, 5): PoseStatus.TOO_FEW_PLANES,
        "ambiguous: 5 poses, best score 0.515 not 1.55x the runner-up 0.342": PoseStatus.AMBIGUOUS,
        "contradicted by the map: 5 planes matched less 3 in conflict with it": PoseStatus.NO_MATCH,
        "pose weakly constrained: 0.34 m^2 of matched planes along its weakest direction": PoseStatus.NO_MATCH,
        "refined pose does not verify: no least-squares pose over its matched planes (few": PoseStatus.NO_MATCH,
        "no hypothesis passed verification": PoseStatus.NO_MATCH,
        "not_ready: no usable frames": PoseStatus.NOT_READY,
    }
    for reason, status in cases.items():
        assert _reject_status(reason, PoseStatus) == status, reason


def test_the_default_drift_covers_the_simulated_firmwares_odometry():
    """The poses tracked with the simulated firmware's odometry (its wheel and gyro scales about 1 % off, a gyro bias,
    drawn anew per seed; seeds not among the 40 the defaults were chosen on) lie inside their covariance's 95 %
    ellipsoid about as often as they should, while the relocalized pose's covariance alone would hold almost none."""
    import sys
    from argparse import Namespace
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from tracked_covariance import run

    d = OdometryDrift()
    args = Namespace(seeds=8, seed_base=100, duration=60.0, every=10.0, reloc_sigma_mm=3.0, reloc_sigma_deg=0.05,
                     m_per_m=d.m_per_m, rad_per_m=d.rad_per_m, rad_per_rad=d.rad_per_rad, rad_per_s=d.rad_per_s)
    rows = {(r["horizon_s"], r["covariance"]): r for r in run(args)["rows"]}
    for h in (2.0, 5.0, 10.0):
        assert 0.85 <= rows[h, "ours"]["within_95"] <= 1.0, (h, rows[h, "ours"])
        assert rows[h, "relocalization only"]["within_95"] < 0.3
