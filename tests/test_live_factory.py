"""reloc run's camera factory: the config's oak section reaches the OAK driver, and simulated/replayed cameras are
paced as the live section says (checked without a device: the source constructor is replaced)."""

from __future__ import annotations

import drivers.source
from reloc.config import config_from_dict
from reloc.live.factory import open_camera


def _capture(monkeypatch):
    calls = []
    monkeypatch.setattr(drivers.source, "open_source", lambda spec, **kw: calls.append((spec, kw)) or "source")
    return calls


def test_oak_camera_gets_the_oak_section_of_the_config(monkeypatch):
    calls = _capture(monkeypatch)
    cfg = config_from_dict({"oak": {"preset": "ROBOTICS", "width": 1280, "height": 800, "fps": 15.0, "imu": False,
                                    "reconnect": False, "search_timeout_s": 1.5}})
    assert open_camera("oak:1844301011", cfg) == "source"
    spec, kw = calls[-1]
    assert spec == "oak:1844301011"
    assert (kw["preset"], kw["width"], kw["height"], kw["fps"]) == ("ROBOTICS", 1280, 800, 15.0)
    assert kw["imu"] is False and kw["reconnect"] is False and kw["search_timeout_s"] == 1.5
    assert "rate" not in kw  # a real camera runs at its own rate
    # Keywords given by the caller win over the config.
    open_camera("oak", cfg, width=640)
    assert calls[-1][1]["width"] == 640 and calls[-1][1]["height"] == 800


def test_sim_and_replay_are_paced_by_the_live_section(monkeypatch):
    calls = _capture(monkeypatch)
    open_camera("sim:office", config_from_dict({"live": {"realtime": True}}), n_frames=50)
    assert calls[-1][1]["rate"] == "recorded" and calls[-1][1]["n_frames"] == 50 and calls[-1][1]["loop"] is False
    open_camera("replay:/data/x", config_from_dict({"live": {"realtime": False}}))
    assert calls[-1][1]["rate"] == "fast" and "preset" not in calls[-1][1]


def test_the_cameras_noise_law_reaches_extraction_and_matching_unless_the_config_sets_one():
    from drivers.sim_source import SimSource
    from drivers.source import FrameSource
    from reloc.extraction import ExtractionParams
    from reloc.live.factory import with_camera_noise
    from reloc.matching import MatchingParams

    src = SimSource("living_room", n_frames=2, rate="fast")  # the OAK-D class stereo camera, 640x400
    fx = src.intrinsics.fx
    cfg = config_from_dict({})
    resolved, note = with_camera_noise(cfg, src)
    # sigma_z = sigma_disparity / (f b) z^2 with the simulator's 0.08 px and 7.5 cm.
    assert resolved.extraction.noise_model == "stereo"
    assert abs(resolved.extraction.noise_coeff - 0.08 / (fx * 0.075)) < 1e-12
    assert "stereo" in note and "from the camera" in note
    assert ExtractionParams.from_config(resolved).noise_coeff == resolved.extraction.noise_coeff
    # The matcher's decision offset follows: 2.3 sigma at 3 m (5.0 cm for this camera, 3 cm for the default law).
    sigma3 = resolved.extraction.noise_coeff * 9.0
    assert abs(MatchingParams.from_config(resolved).decision_max_offset_m - 2.3 * sigma3) < 1e-9
    assert MatchingParams.from_config(cfg).decision_max_offset_m == 0.03
    # A config that names a law keeps it, whichever of the two fields it sets.
    for section in ({"noise_model": "kinect"}, {"noise_coeff": 2e-3}):
        own = config_from_dict({"extraction": section})
        assert with_camera_noise(own, src) == (own, None)
    # A source that does not know its law leaves the config as it is.

    class Unknown(FrameSource):
        intrinsics = src.intrinsics

        def _frames(self):
            return iter(())

    assert with_camera_noise(cfg, Unknown()) == (cfg, None)
    src.close()


def test_with_the_cameras_noise_law_the_odometry_check_keeps_stereo_frames_it_left_out_with_the_default():
    # Exact poses, a robot turning in the living room, 8-frame windows of the simulated OAK-D: every frame the check
    # leaves out is a loss. With the default (Kinect) law the stereo planes look twice as certain as they are and
    # their differences between views exceed 4 sigma; with the camera's law none does (measured: 22 of the 126 older
    # frames of these 18 windows left out with the default, 0 with the camera's law).
    from dataclasses import replace

    from drivers.sim_source import SimSource
    from reloc.extraction import ExtractionParams, PlaneExtractor
    from reloc.mapping import MappingParams, build_submap

    src = SimSource("living_room", n_frames=80, rate="fast")
    frames = list(src)
    law = src.noise_law()
    cfg = config_from_dict({})
    base = ExtractionParams.from_config(cfg)
    left = {}
    for name, params in (("default", base), ("camera", replace(base, noise_model=law[0], noise_coeff=law[1]))):
        extract = PlaneExtractor(params).extract
        sets = [extract(f).planes for f in frames]
        stats = {}
        for end in range(7, len(frames), 4):
            build_submap(sets[end - 7: end + 1], [f.T_world_cam for f in frames[end - 7: end + 1]],
                         MappingParams.from_config(cfg), stats)
        left[name] = stats.get("frames_left_out", 0)
    assert left["camera"] == 0 and left["default"] >= 3, left
