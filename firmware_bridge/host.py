"""The host side of the bridge, as the live loop uses it.

:class:`HostBridge` wraps a :class:`~firmware_bridge.link.SerialLink` and implements the host's half of the protocol
(docs/protocol.md): heartbeats with the clock echo, acknowledgement and de-duplication of relocalization requests,
rate-limited poses, periodic host status, MCU liveness and reboot detection, and the MCU -> host time mapping.

What the live loop sees::

    with HostBridge.from_config(cfg.serial) as bridge:
        ev = bridge.get_event(timeout_s=0.01)          # OdometryEvent | RelocRequestEvent | BridgeEvent | None
        T_odom_base = bridge.T_odom_base_at(frame.stamp_ns)   # odometry matched to a camera frame (host clock)
        bridge.send_pose(T_map_base, frame.stamp_ns, status=PoseStatus.OK, score=s, covariance=C,
                         request_id=ev.request_id)   # answer a request (never rate-limited) or 0 (rate-limited)
        bridge.send_status(HostState.LOCALIZED, frames_processed=n, relocs_ok=k, relocs_failed=f)

All methods are thread-safe; callbacks run in the reader thread and must return quickly.
"""

from __future__ import annotations

import bisect
import math
import queue
import threading
import time
from collections import deque
from dataclasses import dataclass
from enum import Enum
from typing import Callable, Union

import numpy as np

from .link import LinkEvent, SerialLink
from .messages import (
    Ack,
    AckResult,
    Heartbeat,
    HeartbeatFlags,
    HostState,
    HostStatus,
    McuState,
    MsgType,
    Packet,
    PoseFlags,
    PoseStatus,
    RelocPose,
    RelocRequest,
    WheelOdometry,
)
from .timesync import ClockSync

__all__ = ["HostBridge", "OdometryEvent", "RelocRequestEvent", "BridgeEvent", "SendResult", "planar_transform"]


@dataclass(frozen=True)
class OdometryEvent:
    """One wheel odometry sample. ``stamp_host_ns`` is the MCU stamp mapped to the host clock (the arrival time when
    no clock sample exists yet, see ``synced``)."""

    odometry: WheelOdometry
    stamp_host_ns: int
    rx_ns: int
    synced: bool
    seq: int = 0  # header seq of the frame (diagnostics)

    @property
    def T_odom_base(self) -> np.ndarray:
        o = self.odometry
        return planar_transform(o.x_m, o.y_m, o.yaw_rad)


@dataclass(frozen=True)
class RelocRequestEvent:
    """The MCU asks for a relocalization; answer with ``send_pose(..., request_id=request_id)``."""

    request_id: int
    reason: int
    stamp_host_ns: int  # when the MCU sent it, host clock
    rx_ns: int


@dataclass(frozen=True)
class BridgeEvent:
    """Link and peer events: connected, disconnected, open_failed, write_timeout, write_failed, callback_error,
    mcu_timeout (no frame from the MCU for peer_timeout_s), mcu_alive, mcu_reboot, odometry_reset, queue_overflow."""

    kind: str
    detail: str
    stamp_ns: int


Event = Union[OdometryEvent, RelocRequestEvent, BridgeEvent]


class SendResult(Enum):
    SENT = "sent"
    RATE_LIMITED = "rate_limited"
    LINK_DOWN = "link_down"
    WRITE_FAILED = "write_failed"


def planar_transform(x_m: float, y_m: float, yaw_rad: float) -> np.ndarray:
    """(4, 4) float64 transform of a planar pose (z up)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    T = np.eye(4)
    T[0, 0], T[0, 1], T[1, 0], T[1, 1] = c, -s, s, c
    T[0, 3], T[1, 3] = x_m, y_m
    return T


class HostBridge:
    """Host end of the firmware bridge (see the module docstring).

    Parameters
    ----------
    url, baudrate, read_timeout_s, write_timeout_s, reconnect_backoff_s, max_frame_bytes:
        Passed to :class:`SerialLink`.
    pose_rate_hz:
        Poses sent on the host's own initiative (``request_id == 0``) are limited to this rate; answers to requests
        always go out.
    heartbeat_period_s, status_period_s:
        Host heartbeat and host status periods.
    peer_timeout_s:
        The MCU counts as gone after this long without any good frame from it.
    time_sync_window_s:
        Window of the minimum-delay clock filter (see :mod:`firmware_bridge.timesync`).
    odometry_buffer:
        Odometry samples kept for :meth:`T_odom_base_at`.
    queue_size, queue_odometry:
        Size of the event queue (the oldest event is dropped when full, and counted); with ``queue_odometry`` off
        odometry only goes to the buffer and the callback, not the queue.
    on_odometry, on_reloc_request, on_event:
        Optional callbacks, called in the reader thread (keep them short).
    clock_ns:
        The host clock; camera frame stamps given to this class must use the same clock.
    request_dedup_s:
        A request id seen within this time is acknowledged as DUPLICATE and not raised again.
    opener:
        Passed to :class:`SerialLink` (tests).
    """

    def __init__(
        self,
        url: str,
        *,
        baudrate: int = 921600,
        read_timeout_s: float = 0.05,
        write_timeout_s: float = 0.2,
        reconnect_backoff_s=(0.1, 0.2, 0.5, 1.0, 2.0),
        max_frame_bytes: int = 512,
        pose_rate_hz: float = 10.0,
        heartbeat_period_s: float = 0.5,
        status_period_s: float = 1.0,
        peer_timeout_s: float = 1.5,
        time_sync_window_s: float = 20.0,
        odometry_buffer: int = 4096,
        queue_size: int = 1024,
        queue_odometry: bool = True,
        on_odometry: Callable[[OdometryEvent], None] | None = None,
        on_reloc_request: Callable[[RelocRequestEvent], None] | None = None,
        on_event: Callable[[BridgeEvent], None] | None = None,
        clock_ns: Callable[[], int] = time.monotonic_ns,
        request_dedup_s: float = 10.0,
        opener=None,
    ):
        for name, value in (("pose_rate_hz", pose_rate_hz), ("heartbeat_period_s", heartbeat_period_s),
                            ("status_period_s", status_period_s), ("peer_timeout_s", peer_timeout_s)):
            if not value > 0:
                raise ValueError(f"{name}: expected > 0, got {value}")
        self.pose_min_interval_ns = int(1e9 / pose_rate_hz)
        self.heartbeat_period_s = float(heartbeat_period_s)
        self.status_period_s = float(status_period_s)
        self.peer_timeout_ns = int(peer_timeout_s * 1e9)
        self.request_dedup_ns = int(request_dedup_s * 1e9)
        self.queue_odometry = queue_odometry
        self.on_odometry = on_odometry
        self.on_reloc_request = on_reloc_request
        self.on_event = on_event
        self.clock_ns = clock_ns
        self.clock = ClockSync(window_s=time_sync_window_s)
        self.link = SerialLink(
            url, baudrate=baudrate, read_timeout_s=read_timeout_s, write_timeout_s=write_timeout_s,
            reconnect_backoff_s=reconnect_backoff_s, max_frame_bytes=max_frame_bytes, on_packet=self._on_packet,
            on_event=self._on_link_event, on_connect=self._on_connect, clock_ns=clock_ns, opener=opener,
            name="host-bridge-reader",
        )
        self._events: queue.Queue[Event] = queue.Queue(maxsize=int(queue_size))
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._housekeeping, name="host-bridge-timer", daemon=True)
        self._t0_ns = clock_ns()
        # Odometry buffer: host stamps (sorted) and samples.
        self._odo_stamps: deque[int] = deque(maxlen=int(odometry_buffer))
        self._odo: deque[WheelOdometry] = deque(maxlen=int(odometry_buffer))
        self._odo_reset_count: int | None = None
        self._latest_odometry: OdometryEvent | None = None
        # Peer state.
        self._mcu_last_rx_ns: int | None = None
        self._mcu_alive = False
        self._mcu_state: int | None = None
        self._mcu_uptime_ms: tuple[int, int] | None = None  # (uptime_ms of the last MCU heartbeat, our rx time)
        self._mcu_hb: tuple[int, int] | None = None  # (stamp of the last MCU heartbeat, our arrival time)
        self._last_echo_used = 0
        # After a (re)connection the MCU may have rebooted (a USB device usually has): its clock mapping is only
        # trusted again once its first heartbeat on the new connection has been checked for a restart.
        self._clock_verified = False
        self._requests_seen: dict[int, int] = {}
        self._last_pose_ns: int | None = None
        self._pending_pose_acks: dict[int, int] = {}  # seq -> send time
        self._status = HostStatus(HostState.STARTING)
        self.counters = {
            "odometry": 0, "heartbeats_in": 0, "reloc_requests": 0, "reloc_requests_duplicate": 0,
            "poses_sent": 0, "poses_rate_limited": 0, "poses_failed": 0, "pose_acks": 0, "answers_sent": 0,
            "status_sent": 0, "heartbeats_out": 0, "events_dropped": 0, "mcu_timeouts": 0, "mcu_reboots": 0,
            "odometry_resets": 0, "out_of_order_odometry": 0,
        }
        self.pose_ack_latency_ns: deque[int] = deque(maxlen=1000)

    @classmethod
    def from_config(cls, serial_cfg, **overrides) -> "HostBridge":
        """Build from the ``serial`` section of :class:`reloc.config.Config`; keyword overrides win."""
        if not serial_cfg.url and "url" not in overrides:
            raise ValueError("serial.url: empty (no link configured); expected a pyserial URL or device path")
        kwargs = dict(
            url=serial_cfg.url, baudrate=serial_cfg.baudrate, read_timeout_s=serial_cfg.read_timeout_s,
            write_timeout_s=serial_cfg.write_timeout_s, reconnect_backoff_s=serial_cfg.reconnect_backoff_s,
            max_frame_bytes=serial_cfg.max_frame_bytes, pose_rate_hz=serial_cfg.pose_rate_hz,
            heartbeat_period_s=serial_cfg.heartbeat_period_s, status_period_s=serial_cfg.status_period_s,
            peer_timeout_s=serial_cfg.peer_timeout_s, time_sync_window_s=serial_cfg.time_sync_window_s,
        )
        kwargs.update(overrides)
        url = kwargs.pop("url")
        return cls(url, **kwargs)

    # -- lifecycle ---------------------------------------------------------------------------------------------
    def start(self) -> "HostBridge":
        self.link.start()
        if not self._thread.is_alive():
            self._thread.start()
        return self

    def close(self) -> None:
        """Send a last STOPPING status when connected, stop both threads and join them."""
        if self.link.connected:
            self._status = self._replace_status(state=HostState.STOPPING)
            self._send_status_now()
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)
        self.link.close()

    def __enter__(self) -> "HostBridge":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # -- what the live loop reads ------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self.link.connected

    @property
    def mcu_alive(self) -> bool:
        """A good frame from the MCU arrived within peer_timeout_s."""
        with self._lock:
            last = self._mcu_last_rx_ns
        return last is not None and self.clock_ns() - last <= self.peer_timeout_ns

    @property
    def mcu_state(self) -> int | None:
        return self._mcu_state

    def get_event(self, timeout_s: float | None = 0.0) -> Event | None:
        """Next event, waiting up to ``timeout_s`` (None = forever, 0 = do not wait); None when there is none."""
        try:
            if timeout_s == 0:
                return self._events.get_nowait()
            return self._events.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def latest_odometry(self) -> OdometryEvent | None:
        return self._latest_odometry

    def T_odom_base_at(self, stamp_host_ns: int, *, max_extrapolation_s: float = 0.1) -> np.ndarray | None:
        """(4, 4) ``T_odom_base`` at a host time, interpolated between the odometry samples around it.

        Beyond the newest (or before the oldest) sample the pose is extrapolated with the sample's velocity for at
        most ``max_extrapolation_s``; farther out, or without odometry, None.
        """
        max_ns = int(max_extrapolation_s * 1e9)
        with self._lock:
            if not self._odo_stamps:
                return None
            stamps = self._odo_stamps
            i = bisect.bisect_left(stamps, stamp_host_ns)
            if i < len(stamps) and stamps[i] == stamp_host_ns:
                o = self._odo[i]
                return planar_transform(o.x_m, o.y_m, o.yaw_rad)
            if 0 < i < len(stamps):
                t0, t1 = stamps[i - 1], stamps[i]
                a, b = self._odo[i - 1], self._odo[i]
                w = (stamp_host_ns - t0) / (t1 - t0)
                dyaw = math.remainder(b.yaw_rad - a.yaw_rad, 2 * math.pi)
                return planar_transform(a.x_m + w * (b.x_m - a.x_m), a.y_m + w * (b.y_m - a.y_m), a.yaw_rad + w * dyaw)
            j = 0 if i == 0 else len(stamps) - 1
            o, dt_ns = self._odo[j], stamp_host_ns - stamps[j]
        if abs(dt_ns) > max_ns:
            return None
        dt = dt_ns * 1e-9
        T = planar_transform(o.x_m, o.y_m, o.yaw_rad)
        step = planar_transform(o.vx_mps * dt, o.vy_mps * dt, o.omega_radps * dt)
        return T @ step

    @property
    def clock_synced(self) -> bool:
        """The MCU clock mapping is established and verified on the current connection."""
        return self._clock_verified and self.clock.synced

    def mcu_to_host_ns(self, mcu_ns: int) -> int | None:
        """Host time of an MCU stamp; None before any clock sample (or before the MCU's first heartbeat after a
        reconnection, when it may have rebooted)."""
        return self.clock.mcu_to_host_ns(mcu_ns) if self._clock_verified else None

    def host_to_mcu_ns(self, host_ns: int) -> int | None:
        return self.clock.host_to_mcu_ns(host_ns) if self._clock_verified else None

    # -- what the live loop sends ------------------------------------------------------------------------------
    def send_pose(
        self, T_map_base, stamp_ns: int, *, status: int = PoseStatus.OK, score: float = 0.0, covariance=None,
        request_id: int = 0,
    ) -> SendResult:
        """Send ``T_map_base`` (4x4, map frame z up) for the camera frame stamped ``stamp_ns`` (host clock).

        ``covariance`` is (6, 6) over (translation, rotation) in the map frame, or None (zeros: unknown).
        Unsolicited poses (``request_id`` = 0) other than OK (the TRACKED stream propagated with odometry) are
        rate-limited to pose_rate_hz; a fresh relocalization (OK) and an answer to a request are always sent.
        The stamp goes out in the MCU's clock once the clock is synced (flag STAMP_MCU_CLOCK), else as given.
        """
        now = self.clock_ns()
        if request_id == 0 and status != PoseStatus.OK:
            with self._lock:
                if self._last_pose_ns is not None and now - self._last_pose_ns < self.pose_min_interval_ns:
                    self.counters["poses_rate_limited"] += 1
                    return SendResult.RATE_LIMITED
        flags, stamp = 0, int(stamp_ns)
        if self.clock_synced:
            stamp = self.clock.host_to_mcu_ns(stamp)
            flags |= PoseFlags.STAMP_MCU_CLOCK
        msg = RelocPose.from_transform(
            T_map_base, request_id=request_id, status=status, flags=flags, stamp_ns=stamp, score=score,
            covariance=covariance,
        )
        if not self.link.connected:
            self.counters["poses_failed"] += 1
            return SendResult.LINK_DOWN
        seq = self.link.send(msg, now)
        if seq is None:
            self.counters["poses_failed"] += 1
            return SendResult.WRITE_FAILED
        with self._lock:
            self._last_pose_ns = now
            self._pending_pose_acks[seq] = now
            if len(self._pending_pose_acks) > 256:
                self._pending_pose_acks.pop(next(iter(self._pending_pose_acks)))
            self.counters["poses_sent"] += 1
            if request_id:
                self.counters["answers_sent"] += 1
                self._requests_seen[request_id] = now
        return SendResult.SENT

    def send_status(
        self, state: int | None = None, *, error_code: int = 0, last_error: str = "", frames_processed: int = 0,
        relocs_ok: int = 0, relocs_failed: int = 0,
    ) -> SendResult:
        """Update the host status (also carried by heartbeats) and send it now; it is repeated every status period."""
        self._status = HostStatus(
            self._status.state if state is None else state, 0, error_code, frames_processed, relocs_ok,
            relocs_failed, last_error,
        )
        return self._send_status_now()

    def set_state(self, state: int) -> None:
        """Change the live-loop state; a change is sent at once."""
        if state != self._status.state:
            self._status = self._replace_status(state=state)
            self._send_status_now()

    def stats(self) -> dict:
        """All counters: bridge, link, decoder, clock sync."""
        with self._lock:
            out = dict(self.counters)
        out.update(self.link.stats_dict())
        out["mcu_alive"] = self.mcu_alive
        out["mcu_state"] = None if self._mcu_state is None else _enum_name(McuState, self._mcu_state)
        out["clock"] = self.clock.summary()
        out["clock_synced"] = self.clock_synced
        return out

    # -- internals ---------------------------------------------------------------------------------------------
    def _replace_status(self, **changes) -> HostStatus:
        s = self._status
        fields = dict(state=s.state, flags=s.flags, error_code=s.error_code, frames_processed=s.frames_processed,
                      relocs_ok=s.relocs_ok, relocs_failed=s.relocs_failed, last_error=s.last_error)
        fields.update(changes)
        return HostStatus(**fields)

    def _send_status_now(self) -> SendResult:
        if self.link.send(self._status) is None:
            return SendResult.WRITE_FAILED if self.link.connected else SendResult.LINK_DOWN
        self.counters["status_sent"] += 1
        return SendResult.SENT

    def _put(self, event: Event) -> None:
        while True:
            try:
                self._events.put_nowait(event)
                return
            except queue.Full:
                try:
                    self._events.get_nowait()
                    self.counters["events_dropped"] += 1
                except queue.Empty:
                    pass

    def _raise_event(self, kind: str, detail: str) -> None:
        ev = BridgeEvent(kind, detail, self.clock_ns())
        self._put(ev)
        if self.on_event is not None:
            self.on_event(ev)

    def _on_link_event(self, ev: LinkEvent) -> None:
        if ev.kind == "disconnected":
            with self._lock:
                self._mcu_hb = None
        self._raise_event(ev.kind, ev.detail)

    def _on_connect(self) -> None:
        with self._lock:
            self._mcu_hb = None
            self._clock_verified = False
            # Request ids restart when the firmware does; a pending id from before is answered again if repeated.
            self._requests_seen.clear()
        # Tell the MCU at once who we are and how we are.
        self._send_heartbeat()
        self._send_status_now()

    def _on_packet(self, packet: Packet, rx_ns: int) -> None:
        msg = packet.message
        self.clock.add_one_way(packet.stamp_ns, rx_ns)
        with self._lock:
            self._mcu_last_rx_ns = rx_ns
            was_alive = self._mcu_alive
            self._mcu_alive = True
        if not was_alive:
            self._raise_event("mcu_alive", f"first frame after {'start' if self._mcu_state is None else 'a timeout'}")
        t = msg.TYPE
        if t == MsgType.HEARTBEAT:
            self._on_heartbeat(packet, msg, rx_ns)
        elif t == MsgType.WHEEL_ODOMETRY:
            self._on_odometry(msg, rx_ns, packet.seq)
        elif t == MsgType.RELOC_REQUEST:
            self._on_request(packet, msg, rx_ns)
        elif t == MsgType.ACK:
            if msg.acked_type == MsgType.RELOC_POSE:
                with self._lock:
                    sent = self._pending_pose_acks.pop(msg.acked_seq, None)
                    self.counters["pose_acks"] += 1
                if sent is not None:
                    self.pose_ack_latency_ns.append(rx_ns - sent)
        # RELOC_POSE / HOST_STATUS from the MCU make no sense; they are valid frames and simply ignored.

    def _on_heartbeat(self, packet: Packet, hb: Heartbeat, rx_ns: int) -> None:
        self.counters["heartbeats_in"] += 1
        prev = self._mcu_uptime_ms
        restarted = False
        if prev is not None:
            # The MCU's uptime must have advanced as much as our clock did since its last heartbeat (modulo the
            # u32 wrap, within 0.5 s + 1 %); more is a restart of its clock (its uptime went back and wrapped).
            # Less is a restart only if its whole uptime fits in the gap: a heartbeat read late (this reader held
            # up) also advances less than our clock did, but from an uptime longer than the gap.
            prev_uptime, prev_rx = prev
            elapsed_ms = (rx_ns - prev_rx) / 1e6
            advanced_ms = (hb.uptime_ms - prev_uptime) % (1 << 32)
            restarted = advanced_ms > elapsed_ms * 1.01 + 500 or (
                advanced_ms < elapsed_ms - 500 and hb.uptime_ms < elapsed_ms + 500)
        if restarted:
            # The MCU clock restarted: its old stamps and its odometry origin mean nothing now.
            self.clock.reset()
            with self._lock:
                self._odo_stamps.clear()
                self._odo.clear()
                self._odo_reset_count = None
                self._requests_seen.clear()
            self.counters["mcu_reboots"] += 1
            self._raise_event("mcu_reboot", f"uptime {hb.uptime_ms} ms, expected about "
                                            f"{prev_uptime + elapsed_ms:.0f} ms: the MCU restarted")
        self._mcu_uptime_ms = (hb.uptime_ms, rx_ns)
        self._mcu_state = hb.state
        self._clock_verified = True
        with self._lock:
            self._mcu_hb = (packet.stamp_ns, rx_ns)
        if hb.echo_stamp_ns and hb.echo_stamp_ns != self._last_echo_used:
            self._last_echo_used = hb.echo_stamp_ns
            t3 = packet.stamp_ns
            self.clock.add_two_way(hb.echo_stamp_ns, t3 - hb.echo_hold_ns, t3, rx_ns)

    def _on_odometry(self, odo: WheelOdometry, rx_ns: int, seq: int = 0) -> None:
        self.counters["odometry"] += 1
        synced = self._clock_verified and self.clock.synced
        stamp = self.clock.mcu_to_host_ns(odo.stamp_ns) if self._clock_verified else None
        if stamp is None:
            stamp = rx_ns
        ev = OdometryEvent(odo, stamp, rx_ns, synced, seq)
        with self._lock:
            if self._odo_reset_count is not None and odo.reset_count != self._odo_reset_count:
                self._odo_stamps.clear()
                self._odo.clear()
                self.counters["odometry_resets"] += 1
                reset = True
            else:
                reset = False
            self._odo_reset_count = odo.reset_count
            if self._odo_stamps and stamp <= self._odo_stamps[-1]:
                self.counters["out_of_order_odometry"] += 1
            else:
                self._odo_stamps.append(stamp)
                self._odo.append(odo)
            self._latest_odometry = ev
        if reset:
            self._raise_event("odometry_reset", f"reset_count {odo.reset_count}")
        if self.queue_odometry:
            self._put(ev)
        if self.on_odometry is not None:
            self.on_odometry(ev)

    def _on_request(self, packet: Packet, req: RelocRequest, rx_ns: int) -> None:
        with self._lock:
            first = self._requests_seen.get(req.request_id)
            duplicate = first is not None and rx_ns - first < self.request_dedup_ns
            if not duplicate:
                self._requests_seen[req.request_id] = rx_ns
                if len(self._requests_seen) > 512:
                    for k in [k for k, v in self._requests_seen.items() if rx_ns - v > self.request_dedup_ns]:
                        del self._requests_seen[k]
            self.counters["reloc_requests_duplicate" if duplicate else "reloc_requests"] += 1
        result = AckResult.DUPLICATE if duplicate else AckResult.ACCEPTED
        self.link.send(Ack(MsgType.RELOC_REQUEST, result, packet.seq, req.request_id))
        if duplicate:
            return
        stamp = self.clock.mcu_to_host_ns(packet.stamp_ns) if self._clock_verified else None
        ev = RelocRequestEvent(req.request_id, req.reason, rx_ns if stamp is None else stamp, rx_ns)
        self._put(ev)
        if self.on_reloc_request is not None:
            self.on_reloc_request(ev)

    def _send_heartbeat(self) -> None:
        now = self.clock_ns()
        with self._lock:
            hb = self._mcu_hb
        echo_stamp, hold = (0, 0) if hb is None else (hb[0], now - hb[1])
        rx_errors = min(self.link.decoder.stats.frames_bad, 0xFFFF)
        msg = Heartbeat(
            self._status.state, HeartbeatFlags.CLOCK_SYNCED if self.clock_synced else 0, rx_errors,
            ((now - self._t0_ns) // 1_000_000) & 0xFFFFFFFF, echo_stamp, hold,
        )
        if self.link.send(msg, now) is not None:
            self.counters["heartbeats_out"] += 1

    def _housekeeping(self) -> None:
        next_hb = next_status = 0.0
        while not self._stop.is_set():
            try:
                next_hb, next_status = self._tick(next_hb, next_status)
            except Exception as exc:  # noqa: BLE001 - a faulty callback must not stop heartbeats
                self.link.stats.callback_errors += 1
                self.link.last_error = f"housekeeping: {exc!r}"
            self._stop.wait(min(0.05, self.heartbeat_period_s / 4))

    def _tick(self, next_hb: float, next_status: float) -> tuple[float, float]:
        now_s = time.monotonic()
        if self.link.connected:
            if now_s >= next_hb:
                self._send_heartbeat()
                next_hb = now_s + self.heartbeat_period_s
            if now_s >= next_status:
                self._send_status_now()
                next_status = now_s + self.status_period_s
        with self._lock:
            last, alive = self._mcu_last_rx_ns, self._mcu_alive
        if alive and last is not None and self.clock_ns() - last > self.peer_timeout_ns:
            with self._lock:
                self._mcu_alive = False
            self.counters["mcu_timeouts"] += 1
            self._raise_event("mcu_timeout", f"no frame from the MCU for {self.peer_timeout_ns / 1e9:.2f} s")
        return next_hb, next_status


def _enum_name(enum_cls, value: int) -> str:
    try:
        return enum_cls(value).name
    except ValueError:
        return str(value)
