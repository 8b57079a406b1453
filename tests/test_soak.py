"""benchmarks/soak.py's core on a few hundred frames with frequent faults: its counts add up, every fault it injected
shows in what the loop and the link counted, and no relocalization is false."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from soak import SoakFaults, check_counts, run_soak  # noqa: E402


def test_a_short_soak_with_frequent_faults_adds_up():
    faults = SoakFaults(camera_drop_rate=0.03, camera_invalid_rate=0.03, camera_stall_rate=0.01, camera_stall_s=0.2,
                        camera_disconnect_every=100, serial_garbage_rate=0.05, serial_unplug_every_s=2.0,
                        serial_unplug_down_s=0.3)
    res = run_soak(300, rate_hz=60.0, faults=faults, seed=4, rss_period_s=0.2)
    assert check_counts(res) == []
    f, injected = res["frames"], res["camera_faults_injected"]
    assert f["delivered"] == f["captured"] == 300
    # processed + dropped + bad == delivered, with processed split into frames with planes and bad ones.
    assert f["with_planes"] + f["bad_total"] + f["dropped_by_queue"] == f["delivered"]
    assert injected["invalid"] > 0 and f["bad"].get("no_valid_depth", 0) <= injected["invalid"]
    assert injected["disconnects"] >= 2 and res["source_events"]["reconnects"] == injected["disconnects"]
    assert injected["dropped"] > 0 and f["missing_from_source"] >= injected["dropped"] - 3  # (gaps need a later frame)
    rel = res["relocalizations"]
    assert rel["correct"] >= 1 and rel["false"] == 0 and rel["correct"] == rel["relocalized"]
    fw, host = res["firmware"], res["host_bridge"]
    assert fw["unplugs"] >= 1 and fw["serial_faults_injected"]["garbage_bursts"] > 0
    assert host["disconnects"] >= 1 and host["connects"] >= 2 and host["truncated"] <= fw["half_frames_sent"]
    assert res["memory"]["samples"] >= 10 and res["errors"] == [] and res["threads_left_running"] == []
