"""Frame sources: the interface contract for replay and the simulator, pacing (with a fake clock), the factory,
and recordings that replay with the same stamps, poses, gravity and depths."""

from __future__ import annotations

import json

import numpy as np
import pytest

from drivers.readers import open_sequence
from drivers.recorder import Recorder, record, stamp_text
from drivers.replay import ReplaySource
from drivers.source import FrameSource, Pacer, check_frame_contract, open_source, parse_rate
from reloc.camera import DepthFrame, Intrinsics
from reloc.transforms import exp_se3

K = Intrinsics(fx=20.0, fy=20.0, cx=7.5, cy=5.5, width=16, height=12, depth_scale=1000.0)


class FakeClock:
    """Monotonic time that only moves when slept on (or advanced by hand)."""

    def __init__(self):
        self.t = 100.0
        self.sleeps = []

    def __call__(self):
        return self.t

    def sleep(self, dt):
        self.sleeps.append(dt)
        self.t += dt


def _frames(n, *, pose_source="odometry", gravity=True, labels=False, start_ns=1_000_000_123):
    rng = np.random.default_rng(1)
    out = []
    for i in range(n):
        d = rng.uniform(0.5, 4.0, size=K.shape).astype(np.float32)
        d[0, :3] = np.nan
        out.append(DepthFrame(
            depth_m=d, intrinsics=K, stamp_ns=start_ns + i * 33_333_333, seq=i,
            T_world_cam=exp_se3(rng.normal(size=6)) if pose_source else None,
            gravity_cam=rng.normal(size=3) if gravity else None, pose_source=pose_source or "none",
            labels=np.full(K.shape, i % 3, dtype=np.int32) if labels else None,
        ))
    return out


class ListSource(FrameSource):
    name = "list"

    def __init__(self, frames):
        super().__init__()
        self.frames = frames
        self.closed_calls = 0

    @property
    def intrinsics(self):
        return K

    def _frames(self):
        yield from self.frames

    def _close(self):
        self.closed_calls += 1


# --------------------------------------------------------------------------------------------------- pacing


def test_parse_rate():
    assert parse_rate("fast") == "fast" and parse_rate(None) == "recorded" and parse_rate("15") == 15.0
    for bad in ("slow", 0, -2.0, float("nan")):
        with pytest.raises(ValueError, match=r"rate: expected 'recorded', 'fast'"):
            parse_rate(bad)


def test_pacer_recorded_fixed_fast():
    stamps = [0, 50_000_000, 100_000_000, 400_000_000]
    clock = FakeClock()
    pacer = Pacer("recorded", clock=clock, sleep=clock.sleep)
    for s in stamps:
        pacer.wait(s)
    np.testing.assert_allclose(clock.sleeps, [0.05, 0.05, 0.3])
    # Twice as fast.
    clock = FakeClock()
    pacer = Pacer("recorded", speed=2.0, clock=clock, sleep=clock.sleep)
    for s in stamps:
        pacer.wait(s)
    np.testing.assert_allclose(clock.sleeps, [0.025, 0.025, 0.15])
    # A fixed rate ignores the stamps.
    clock = FakeClock()
    pacer = Pacer(10.0, clock=clock, sleep=clock.sleep)
    for s in stamps:
        pacer.wait(s)
    np.testing.assert_allclose(clock.sleeps, [0.1, 0.1, 0.1])
    clock = FakeClock()
    pacer = Pacer("fast", clock=clock, sleep=clock.sleep)
    for s in stamps:
        pacer.wait(s)
    assert clock.sleeps == []


def test_pacer_late_consumer_gets_no_burst():
    clock = FakeClock()
    pacer = Pacer("recorded", clock=clock, sleep=clock.sleep)
    pacer.wait(0)
    clock.t += 0.5  # the consumer took 0.5 s over a frame due after 0.1 s
    pacer.wait(100_000_000)
    assert clock.sleeps == []
    pacer.wait(200_000_000)  # the next one is due 0.1 s after the late one, not immediately
    np.testing.assert_allclose(clock.sleeps, [0.1])


# --------------------------------------------------------------------------------------------------- interface


def test_interface_close_and_context():
    src = ListSource(_frames(3))
    with src as s:
        assert len(list(s)) == 3
    assert src.closed and src.closed_calls == 1
    src.close()
    assert src.closed_calls == 1  # idempotent
    with pytest.raises(RuntimeError, match=r"list: the source is closed"):
        iter(src)


def test_check_frame_contract_catches_order():
    frames = _frames(3)
    check_frame_contract(frames, K)
    with pytest.raises(AssertionError, match=r"frame 2: stamp_ns .* not after"):
        check_frame_contract([frames[0], frames[2], frames[1]], K)
    other = Intrinsics(fx=21.0, fy=20.0, cx=7.5, cy=5.5, width=16, height=12)
    with pytest.raises(AssertionError, match=r"frame 0: intrinsics"):
        check_frame_contract(frames, other)


def test_replay_real_clip(real_data):
    seq = open_sequence(real_data / "tum_fr1_xyz")
    with open_source(f"replay:{real_data / 'tum_fr1_xyz'}", rate="fast", stop=10) as src:
        assert isinstance(src, ReplaySource) and src.intrinsics == seq.intrinsics
        assert src.rate_hz == pytest.approx(30, abs=1)
        frames = list(src)
    assert len(frames) == 10
    check_frame_contract(frames, seq.intrinsics)
    for f, T in zip(frames, seq.T_world_cam[:10]):
        np.testing.assert_array_equal(f.T_world_cam, T)
    assert all(f.gravity_cam is not None for f in frames)


def test_replay_loop_keeps_stamps_increasing(real_data):
    src = ReplaySource(real_data / "icl_nuim_living_room", rate="fast", loop=True)
    frames = []
    for f in src:
        frames.append(f)
        if len(frames) == 12:
            src.close()
    assert len(frames) == 12 and src.closed
    check_frame_contract(frames, src.intrinsics)
    assert [f.seq for f in frames] == list(range(12))
    np.testing.assert_array_equal(frames[5].depth_m, frames[0].depth_m)
    assert frames[5].stamp_ns - frames[4].stamp_ns == frames[1].stamp_ns - frames[0].stamp_ns
    # With a step the next pass goes on by the step too (frames 0, 2, 4, then 6, 8, 10; it went on by 1: 5, 7, 9).
    src = ReplaySource(real_data / "icl_nuim_living_room", rate="fast", loop=True, start=0, stop=5, step=2)
    seqs = []
    for f in src:
        seqs.append(f.seq)
        if len(seqs) == 7:
            src.close()
    assert seqs == [0, 2, 4, 6, 8, 10, 12]


def test_replay_paces_at_recorded_rate(real_data, monkeypatch):
    clock = FakeClock()
    monkeypatch.setattr("drivers.source._monotonic", clock)
    monkeypatch.setattr("drivers.source._sleep", clock.sleep)
    with ReplaySource(real_data / "tum_fr2_desk", stop=6) as src:
        frames = list(src)
    expected = np.diff([f.stamp_ns for f in frames]) / 1e9
    np.testing.assert_allclose(clock.sleeps, expected, atol=1e-9)
    clock.sleeps.clear()
    with ReplaySource(real_data / "tum_fr2_desk", stop=4, rate=5.0) as src:
        list(src)
    np.testing.assert_allclose(clock.sleeps, [0.2, 0.2, 0.2])


def test_open_source_errors(tmp_path):
    with pytest.raises(ValueError, match=r"spec: unknown frame source 'webcam'; expected sim\[:SCENE\]"):
        open_source("webcam")
    with pytest.raises(ValueError, match=r"spec: 'replay' needs a path"):
        open_source("replay:")
    with pytest.raises(FileNotFoundError, match=r"nowhere: sequence not found"):
        open_source(f"replay:{tmp_path / 'nowhere'}")
    with pytest.raises(ValueError, match=r"unexpected keyword argument 'colour'"):
        open_source(f"replay:{tmp_path}", colour="red")


# --------------------------------------------------------------------------------------------------- simulator


def test_sim_source_contract_and_loop():
    with open_source("sim:living_room", n_frames=3, rate="fast", loop=True, camera="kinect", width=64, height=48,
                     noise="kinect") as src:
        assert src.intrinsics.width == 64 and src.rate_hz == 30.0
        frames = []
        for f in src:
            frames.append(f)
            if len(frames) == 5:
                break
    check_frame_contract(frames, src.intrinsics)
    assert [f.seq for f in frames] == [0, 1, 2, 3, 4]
    assert all(f.T_world_cam is not None and f.gravity_cam is not None and f.labels is not None for f in frames)
    np.testing.assert_allclose(frames[3].T_world_cam, frames[0].T_world_cam)
    # Gravity from the simulator is the world's -z seen from the camera.
    np.testing.assert_allclose(frames[1].gravity_cam, frames[1].T_world_cam[:3, :3].T @ [0, 0, -1], atol=1e-12)


# --------------------------------------------------------------------------------------------------- recording


def test_stamp_text_exact():
    assert stamp_text(1305031102160407000) == "1305031102.160407000"
    assert stamp_text(5) == "0.000000005"
    with pytest.raises(ValueError, match=r"stamp_ns: expected a non-negative timestamp, got -1"):
        stamp_text(-1)


@pytest.mark.parametrize("pose_source,pose_file", [("odometry", "odometry.txt"), ("groundtruth", "groundtruth.txt")])
def test_record_then_replay_round_trip(tmp_path, pose_source, pose_file):
    frames = _frames(5, pose_source=pose_source, labels=True)
    with ListSource(frames) as src:
        summary = record(src, tmp_path / "rec")
    assert summary.frames_written == 5 and summary.with_pose == {pose_file[:-4]: 5} and summary.with_gravity == 5
    assert (tmp_path / "rec" / pose_file).is_file() and (tmp_path / "rec" / "gravity.txt").is_file()
    meta = json.loads((tmp_path / "rec" / "recording.json").read_text())
    assert meta["source"]["name"] == "list" and meta["summary"]["frames_written"] == 5
    seq = open_sequence(tmp_path / "rec")
    assert len(seq) == 5 and seq.intrinsics == K and seq.pose_source == pose_source
    for f, g in zip(frames, seq):
        assert g.stamp_ns == f.stamp_ns  # 9-decimal stamps: exact
        np.testing.assert_allclose(g.T_world_cam, f.T_world_cam, atol=1e-8)
        np.testing.assert_allclose(g.gravity_cam, f.gravity_cam, atol=1e-8)
        np.testing.assert_array_equal(g.labels, f.labels)
        np.testing.assert_allclose(g.depth_m, f.depth_m, atol=0.5 / K.depth_scale)  # millimetre quantization
        assert np.isnan(g.depth_m[0, :3]).all()


def test_a_recording_keeps_the_cameras_noise_law_and_its_replay_reports_it(tmp_path):
    from drivers.readers import read_noise_law
    from drivers.sim_source import SimSource

    with SimSource("office", n_frames=3, rate="fast") as src:  # the OAK-D class stereo camera
        law = src.noise_law()
        summary = record(src, tmp_path / "rec")
    assert law[0] == "stereo" and law[1] > 0
    assert summary.noise_law == law and f"depth noise (stereo, {law[1]:.3g}) goes with it" in summary.text()
    meta = json.loads((tmp_path / "rec" / "recording.json").read_text())
    assert meta["noise_law"] == {"model": "stereo", "coeff": law[1]}
    assert read_noise_law(tmp_path / "rec") == law
    assert ReplaySource(tmp_path / "rec").noise_law() == law
    # A source that does not know its law records none, and its replay knows none either.
    with ListSource(_frames(2)) as src:
        assert "depth noise" not in record(src, tmp_path / "plain").text()
    assert json.loads((tmp_path / "plain" / "recording.json").read_text())["noise_law"] is None
    assert ReplaySource(tmp_path / "plain").noise_law() is None
    # A damaged entry is an error that names the file and what was expected.
    meta["noise_law"] = {"model": "sonar", "coeff": 0.01}
    (tmp_path / "rec" / "recording.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"recording\.json: noise_law .*sonar.*expected"):
        read_noise_law(tmp_path / "rec")
    meta["noise_law"] = {"model": "tof", "coeff": -1.0}
    (tmp_path / "rec" / "recording.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="a positive number"):
        read_noise_law(tmp_path / "rec")


def test_a_replay_plays_forward_only(tmp_path):
    """A negative or zero step would play the sequence backwards (stamps decreasing, which every consumer refuses
    frame by frame) or not at all: refused when the source is made, naming ``step``."""
    with ListSource(_frames(3)) as src:
        record(src, tmp_path / "rec")
    for step in (-1, 0, 1.5, True):
        with pytest.raises(ValueError, match=rf"step: expected a positive integer .*got {step!r}"):
            ReplaySource(tmp_path / "rec", step=step)
    with ReplaySource(tmp_path / "rec", rate="fast", step=2) as src:
        assert [f.seq for f in src] == [0, 2]


def test_record_stops_and_skips(tmp_path):
    frames = _frames(6)
    bad = frames[:3] + [frames[1]] + frames[3:]  # a frame out of order is skipped and counted
    with ListSource(bad) as src:
        summary = record(src, tmp_path / "a", n_frames=4)
    assert summary.frames_written == 4 and summary.frames_skipped == 1
    assert "does not increase" in summary.skip_reasons[0] and "skipped 1 frames" in summary.text()
    assert len(open_sequence(tmp_path / "a")) == 4
    with pytest.raises(ValueError, match=r"already holds a sequence \(depth.txt\); use overwrite"):
        Recorder(tmp_path / "a")
    with ListSource(frames[:2]) as src:
        record(src, tmp_path / "a", overwrite=True)
    seq = open_sequence(tmp_path / "a")
    assert len(seq) == 2 and len(list((tmp_path / "a" / "depth").glob("*.png"))) == 2


def test_recorder_flushes_a_valid_prefix(tmp_path):
    frames = _frames(5)
    rec = Recorder(tmp_path / "r", flush_every=2)
    for f in frames[:3]:
        rec.write(f)
    # Not closed yet (as after a crash): the first 2 frames already form a valid sequence.
    seq = open_sequence(tmp_path / "r")
    assert len(seq) == 2 and seq.pose_source == "odometry"
    rec.close()
    assert len(open_sequence(tmp_path / "r")) == 3
    with pytest.raises(RuntimeError, match=r"the recorder is closed"):
        rec.write(frames[4])


def test_recorder_rejects_intrinsics_change_and_counts_clipping(tmp_path):
    frames = _frames(2, pose_source=None, gravity=False)
    rec = Recorder(tmp_path / "r", depth_scale=20000.0)  # 3.27 m is the largest storable depth
    rec.write(frames[0])
    other = DepthFrame(depth_m=np.ones((12, 16), np.float32), stamp_ns=frames[1].stamp_ns, seq=1,
                       intrinsics=Intrinsics(fx=30.0, fy=20.0, cx=7.5, cy=5.5, width=16, height=12))
    with pytest.raises(ValueError, match=r"frame 1: intrinsics .* differ from the first frame's"):
        rec.write(other)
    summary = rec.close()
    assert summary.unrepresentable_pixels == int(np.sum(np.nan_to_num(frames[0].depth_m) > 65535.5 / 20000.0))
    assert summary.unrepresentable_pixels > 0
    seq = open_sequence(tmp_path / "r")
    assert seq.intrinsics.depth_scale == 20000.0 and seq.pose_source == "none"
    d = seq[0].depth_m
    assert np.isnan(d[frames[0].depth_m > 3.3]).all()
