"""Serial faults with the simulated firmware over a pseudo-terminal: an unplug in the middle of a frame, and a firmware
that floods or goes silent while the live loop runs. Counts and outcomes only; waits are bounded polls."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from helpers import wait_until

from drivers.sim_source import SimSource
from firmware_bridge import HostBridge
from firmware_bridge.mcu_sim import McuSimulator, PtyEndpoint
from firmware_bridge.messages import WheelOdometry
from reloc.config import Config
from reloc.live.factory import TruthPlanes, load_plane_map
from reloc.live.loop import THREAD_NAMES, LiveLoop
from reloc.live.params import LiveParams
from reloc.matching import Relocalizer

FAST = dict(reconnect_backoff_s=(0.02, 0.05, 0.1), heartbeat_period_s=0.1, status_period_s=0.5)
T_BASE_CAM = np.array(Config().camera.T_base_cam).reshape(4, 4)




def settle(read, period_s: float = 0.2, timeout_s: float = 5.0) -> None:
    """Wait until ``read()`` stops changing (bounded)."""
    prev, end = read(), time.monotonic() + timeout_s
    while time.monotonic() < end:
        time.sleep(period_s)
        cur = read()
        if cur == prev:
            return
        prev = cur


def test_unplug_in_the_middle_of_a_frame_is_reported_counted_and_recovered(tmp_path):
    link = tmp_path / "ttyMCU"
    accepted = []
    events = []
    bridge = HostBridge(str(link), on_odometry=accepted.append, on_event=events.append, **FAST)
    mcu = McuSimulator(PtyEndpoint(link), reloc_period_s=0.0, odom_rate_hz=200.0, record_sent=100_000, seed=1)
    with mcu, bridge:
        assert wait_until(lambda: bridge.stats()["odometry"] >= 50)
        # The cable goes: the first half of a frame is on the line, then the device vanishes.
        mcu.unplug(mid_frame=True, hold_s=0.2)
        assert wait_until(lambda: any(e.kind == "disconnected" for e in events))
        assert wait_until(lambda: bridge.link.stats.open_failures >= 2)  # the host keeps trying with its backoff
        assert not bridge.connected and bridge.link.alive
        before = bridge.stats()
        # The cable comes back under the same name.
        mcu.plug(PtyEndpoint(link))
        assert wait_until(lambda: bridge.stats()["odometry"] >= before["odometry"] + 50)
        after = bridge.stats()
    assert mcu.counters["half_frames_sent"] == 1 and mcu.counters["unplugs"] == 1
    assert after["disconnects"] == 1 and after["connects"] == 2
    # The half frame is counted once as truncated, never joined to the next connection's bytes.
    assert after["truncated"] == 1
    assert after["crc_errors"] == after["framing_errors"] == after["oversize"] == 0
    assert after["frames_bad"] == 1
    # Every odometry message the host accepted, before and after, is exactly one the firmware sent.
    assert len(accepted) >= after["odometry"] >= 100
    for ev in accepted:
        assert mcu.sent_log[ev.seq] == ev.odometry and isinstance(ev.odometry, WheelOdometry)


@pytest.fixture(scope="module")
def living_room():
    planes, plane_map = load_plane_map("sim:living_room")
    reloc = Relocalizer(plane_map)
    src = SimSource("living_room", n_frames=1, camera="oak-d", width=160, height=100, rate="fast")
    reloc.locate(TruthPlanes(src.scene)(next(iter(src))).planes)  # compile the matcher's kernels first
    return src.scene, planes, reloc


def _run_loop_with(mcu: McuSimulator, bridge: HostBridge, living_room, n_frames: int, rate_hz: float):
    scene, map_planes, reloc = living_room
    src = SimSource("living_room", n_frames=n_frames, camera="oak-d", width=160, height=100, rate=rate_hz)
    params = LiveParams(queue_frames=n_frames, T_base_cam=T_BASE_CAM, reconnect_backoff_s=(0.01,))
    loop = LiveLoop(src, TruthPlanes(scene), reloc, params=params, map_planes=map_planes, bridge=bridge)
    with bridge:
        with mcu:
            assert wait_until(lambda: bridge.connected and bridge.mcu_alive)
            summary = loop.run()
        # The firmware has stopped: let the host read what is still on the line before counting.
        settle(lambda: bridge.stats()["bytes_in"])
        stats = bridge.stats()
    src.close()
    assert [t.name for t in threading.enumerate() if t.name in THREAD_NAMES] == []
    return summary, stats


def test_a_flooding_firmware_is_bounded_and_the_loop_keeps_running(tmp_path, living_room):
    link = tmp_path / "ttyMCU"
    # Odometry at 5 kHz (several messages per millisecond) into a small event queue and odometry buffer.
    mcu = McuSimulator(PtyEndpoint(link), reloc_period_s=0.0, flood_hz=5000.0, seed=2, record_sent=200_000)
    accepted = []
    bridge = HostBridge(str(link), queue_size=64, odometry_buffer=256, on_odometry=accepted.append, **FAST)
    summary, stats = _run_loop_with(mcu, bridge, living_room, n_frames=60, rate_hz=20.0)
    f = summary.frames
    # Every frame went through (the loop kept up), no error, relocalizations still correct.
    assert f["captured"] == f["processed"] == 60 and f["dropped"] == 0 and summary.errors == []
    assert summary.bridge["loop_serial_errors"] == 0
    ok = [r for r in summary.relocalizations if r.ok]
    assert ok and all(r.position_error_m < 0.1 and r.rotation_error_deg < 2.0 for r in ok)
    # The flood arrived (far more than the 50 Hz a firmware sends), and the host kept up or dropped and counted.
    sent = mcu.counters["odometry_sent"]
    assert stats["odometry"] > 1000 and stats["odometry"] <= sent and len(accepted) == stats["odometry"]
    # The firmware floods from its start; what it sent before the host's first frame was on the line before the host
    # connected, and the host drops such stale bytes at connect by design (the sequence count starts at its first
    # frame). Those are the only ones it may miss unseen: 0-6 in runs here, where the check against everything sent
    # failed 4 times in 6 (and once in CI, with 6 of 6,495).
    first = min(ev.seq for ev in accepted)
    assert all(mcu.sent_log[ev.seq] == ev.odometry for ev in accepted)  # and each one is what was sent
    before = sum(1 for seq, msg in mcu.sent_log.items() if seq < first and isinstance(msg, WheelOdometry))
    # From then on what did not arrive intact is counted: lost by sequence number, or bad (a write cut short by the
    # full line). The simulator's stop lets the host read what is still on the line before the pty closes, so nothing
    # vanishes unseen at the end either.
    assert stats["odometry"] + stats["frames_lost"] + stats["frames_bad"] >= sent - before
    assert bridge._events.qsize() <= 64 and len(bridge._odo) <= 256  # memory bounded
    assert summary.odometry["used"].get("bridge", 0) > 0


def test_a_silent_firmware_shows_in_the_host_state_and_the_loop_goes_on(tmp_path, living_room):
    link = tmp_path / "ttyMCU"
    # Silent for 1.5 s after 1 s: no heartbeat, no odometry; then it speaks again (the camera runs 4 s).
    mcu = McuSimulator(PtyEndpoint(link), reloc_period_s=0.0, silent_after_s=1.0, silent_for_s=1.5, seed=3)
    events = []
    bridge = HostBridge(str(link), peer_timeout_s=0.4, on_event=events.append, **FAST)
    alive_seen = []
    done = threading.Event()

    def watch():
        while not done.wait(0.02):
            alive_seen.append(bridge.mcu_alive)

    watcher = threading.Thread(target=watch)
    watcher.start()
    try:
        summary, stats = _run_loop_with(mcu, bridge, living_room, n_frames=120, rate_hz=30.0)
    finally:
        done.set()
        watcher.join()
    kinds = [e.kind for e in events]
    assert "mcu_timeout" in kinds and kinds.index("mcu_timeout") < len(kinds) - 1 - kinds[::-1].index("mcu_alive")
    assert stats["mcu_timeouts"] >= 1 and False in alive_seen and stats["mcu_reboots"] == 0
    assert mcu.counters["silent_frames"] > 0
    f = summary.frames
    assert f["captured"] == f["processed"] == 120 and summary.errors == []
    # Without odometry from the firmware the loop falls back to single-frame submaps, then uses it again.
    used = summary.odometry["used"]
    assert used.get("bridge", 0) > 0 and used.get("none", 0) > 0
    ok = [r for r in summary.relocalizations if r.ok]
    assert ok and all(r.position_error_m < 0.1 and r.rotation_error_deg < 2.0 for r in ok)


def test_a_heartbeat_read_late_is_not_a_reboot_and_a_quick_reboot_still_is():
    """The MCU's uptime advances less than the host's clock when the host reads a heartbeat late (its reader held
    up for 0.51 s): that is no restart, and the clock mapping and odometry stay. An uptime that fits in the gap since
    the last heartbeat (a reboot shorter than the u32 wrap would show) is one. Heartbeats every 0.5 s, the MCU clock
    the host's, 2 ms of link delay."""
    from firmware_bridge.messages import Heartbeat, McuState, Packet

    ms = 1_000_000
    bridge = HostBridge("loop://")

    def heartbeat(uptime_ms: int, rx_ms: int) -> None:
        bridge._on_packet(Packet(0, uptime_ms * ms, Heartbeat(McuState.DRIVING, uptime_ms=uptime_ms)), rx_ms * ms)

    for t in range(10_000, 13_000, 500):
        heartbeat(t, t + 2)
        bridge._on_packet(Packet(0, t * ms, WheelOdometry(t * ms, 0.001 * (t - 10_000), 0.0, 0.0)), t * ms + 2 * ms)
    offset = bridge.clock.offset_ns()
    assert bridge.counters["mcu_reboots"] == 0 and len(bridge._odo) == 6 and offset == 2 * ms
    heartbeat(13_000, 13_000 + 2 + 510)
    assert bridge.counters["mcu_reboots"] == 0 and len(bridge._odo) == 6 and bridge.clock.offset_ns() == offset
    assert bridge.T_odom_base_at(12_502 * ms) is not None
    heartbeat(1_200, 16_000)  # up 1.2 s after 13 s: its uptime went back (and wrapped), it restarted
    assert bridge.counters["mcu_reboots"] == 1 and len(bridge._odo) == 0 and bridge.clock.offset_ns() is None
    heartbeat(1_700, 16_502)
    heartbeat(2_500, 20_000)  # up 2.5 s, 3.5 s after its last heartbeat at 1.7 s: it restarted in the gap
    assert bridge.counters["mcu_reboots"] == 2
