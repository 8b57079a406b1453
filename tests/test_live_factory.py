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
