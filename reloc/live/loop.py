"""The live loop: frames from a source, planes per frame, submaps over a window, relocalization when needed.

Threads (their names are the tracks of the profiler's Chrome trace):

- ``capture``: pulls frames from the source into a bounded :class:`DropOldestQueue` (the oldest frame is dropped,
  and counted, when processing falls behind); counts gaps in the source's ``seq``, stalls, disconnects, and
  reconnects with backoff when the source has ``reconnect()``.
- ``processing``: per frame, plane extraction, the odometry pose (firmware bridge, else the frame's own odometry,
  else none), the submap window, the tracking check, and the relocalization triggers. A bad frame is counted by
  reason and skipped; nothing in one frame stops the loop.
- ``relocalization``: runs the relocalizer on the newest submap handed to it (a one-slot mailbox: a newer submap
  replaces one still waiting), so relocalization never blocks capture or extraction.
- ``serial`` (with a firmware bridge): relocalization requests and odometry resets in, poses and status out.

Relocalization triggers: start-up, a request (firmware or keypress, :meth:`LiveLoop.request_relocalization`), lost
tracking (an odometry jump, or the current planes disagreeing with the map at the pose predicted from the last
verified one), retries while lost, and a periodic verification.

Stages are timed with one :class:`reloc.profiling.Profiler`; :meth:`LiveLoop.run` returns a :class:`LiveSummary`.
"""

from __future__ import annotations

import math
import queue
import sys
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from reloc.camera import DepthFrame
from reloc.live.frame_queue import DropOldestQueue
from reloc.live.params import LiveParams
from reloc.live.submap import SubmapWindow
from reloc.live.tracking import explained_fraction, is_jump, odometry_step, predict_T_map_cam, tracked_covariance
from reloc.planeset import PlaneSet
from reloc.profiling import Profiler
from reloc.transforms import invert, pose_error

__all__ = ["LiveLoop", "LiveSummary", "RelocRecord", "THREAD_NAMES"]

THREAD_NAMES = ("capture", "processing", "relocalization", "serial", "keyboard")
_TRUTH_SOURCES = ("groundtruth",)


@dataclass(frozen=True)
class RelocRecord:
    """One relocalization: what triggered it, the frame it holds for, and what came out."""

    index: int
    trigger: str
    seq: int
    stamp_ns: int
    status: str
    reason: str
    T_map_cam: np.ndarray | None
    score: float
    submap_frames: int
    submap_planes: int
    reloc_ms: float
    capture_to_pose_ms: float
    request_ids: tuple = ()
    position_error_m: float | None = None  # against the frame's ground truth, when the source has it
    rotation_error_deg: float | None = None

    @property
    def ok(self) -> bool:
        return self.status == "relocalized"

    def to_dict(self) -> dict:
        return {
            "index": self.index, "trigger": self.trigger, "seq": self.seq, "stamp_ns": self.stamp_ns,
            "status": self.status, "reason": self.reason,
            "T_map_cam": None if self.T_map_cam is None else np.round(self.T_map_cam, 9).tolist(),
            "score": _num(self.score), "submap_frames": self.submap_frames, "submap_planes": self.submap_planes,
            "reloc_ms": round(self.reloc_ms, 3), "capture_to_pose_ms": round(self.capture_to_pose_ms, 3),
            "request_ids": list(self.request_ids),
            "position_error_m": _num(self.position_error_m), "rotation_error_deg": _num(self.rotation_error_deg),
        }


def _num(x):
    if x is None:
        return None
    x = float(x)
    return round(x, 6) if math.isfinite(x) else None


@dataclass
class LiveSummary:
    """What a run did (``to_dict()`` is the JSON of ``reloc run --summary``)."""

    source: dict
    duration_s: float
    cpu_s: float
    frames: dict
    source_events: dict
    odometry: dict
    tracking: dict
    relocalizations: list[RelocRecord]  # the latest ``LiveLoop.max_records`` (all of them in any normal run)
    latency_ms: dict
    end_to_end_ms: dict
    bridge: dict | None = None
    faults: dict | None = None
    errors: list[str] = field(default_factory=list)
    relocs_total: int | None = None  # over the whole run (None: as many as listed)
    relocs_ok_total: int | None = None

    @property
    def relocs_ok(self) -> int:
        return self.relocs_ok_total if self.relocs_ok_total is not None else sum(r.ok for r in self.relocalizations)

    @property
    def relocs_count(self) -> int:
        return self.relocs_total if self.relocs_total is not None else len(self.relocalizations)

    def to_dict(self) -> dict:
        return {
            "source": self.source, "duration_s": round(self.duration_s, 3), "cpu_s": round(self.cpu_s, 3),
            "frames": self.frames, "source_events": self.source_events, "odometry": self.odometry,
            "tracking": self.tracking,
            "relocalizations_ok": self.relocs_ok,
            "relocalizations_failed": self.relocs_count - self.relocs_ok,
            "relocalizations_listed": len(self.relocalizations),
            "relocalizations": [r.to_dict() for r in self.relocalizations],
            "latency_ms": self.latency_ms, "end_to_end_ms": self.end_to_end_ms,
            "bridge": self.bridge, "faults": self.faults, "errors": self.errors,
        }


@dataclass
class _Job:
    trigger: str
    submap: PlaneSet
    submap_frames: int
    seq: int
    stamp_ns: int
    t_cap_ns: int
    T_odom_cam: np.ndarray | None
    odometry_kind: str
    odometry_epoch: int
    T_truth: np.ndarray | None
    request_ids: tuple = ()


class _Mailbox:
    """One pending relocalization job; a newer one replaces it (keeping the request ids to answer)."""

    def __init__(self) -> None:
        self._job: _Job | None = None
        self._busy = False
        self._cond = threading.Condition()
        self.superseded = 0

    def submit(self, job: _Job) -> None:
        with self._cond:
            if self._job is not None:
                self.superseded += 1
                job.request_ids = tuple(dict.fromkeys(self._job.request_ids + job.request_ids))
                if self._job.trigger not in job.trigger.split("+"):
                    job.trigger = f"{self._job.trigger}+{job.trigger}"
            self._job = job
            self._cond.notify_all()

    def take(self, timeout_s: float) -> _Job | None:
        with self._cond:
            if self._job is None:
                self._cond.wait(timeout_s)
            job, self._job = self._job, None
            if job is not None:
                self._busy = True
            return job

    def done(self) -> None:
        with self._cond:
            self._busy = False
            self._cond.notify_all()

    @property
    def idle(self) -> bool:
        with self._cond:
            return self._job is None and not self._busy

    def wait_idle(self, timeout_s: float, stop: threading.Event) -> bool:
        end = time.monotonic() + timeout_s
        with self._cond:
            while (self._job is not None or self._busy) and not stop.is_set():
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(min(left, 0.1))
            return True


class LiveLoop:
    """Composes a frame source, plane extraction and a relocalizer into the live loop (module docstring).

    Parameters
    ----------
    source:
        A :class:`drivers.source.FrameSource` (or any iterable of :class:`DepthFrame` with ``info()``); its
        ``reconnect()``, when present, is called with backoff after the stream breaks.
    extract:
        ``extract(frame) -> result`` with ``result.planes`` (PlaneSet, camera frame) and ``result.timings_ms``.
    relocalizer:
        Has ``locate(submap: PlaneSet) -> result`` with ``status`` ("relocalized" or a rejection), ``reason``,
        ``T_map_cam`` (4x4 or None), ``score`` and optionally ``timings_ms``.
    params:
        :class:`LiveParams`.
    map_planes:
        The map as a PlaneSet (map frame), for the tracking check; None disables that check.
    bridge:
        A started :class:`firmware_bridge.HostBridge` (or None): odometry and requests in, poses and status out.
    odometry:
        "auto" (bridge odometry when it has some, else a frame pose whose ``pose_source`` is "odometry"),
        "bridge", "source" (any frame pose, ground truth included: for simulations), or "none".
    profiler:
        Shared :class:`Profiler` (a fresh one when None).
    on_status:
        Called with each status line (at most every ``params.status_period_s``); None prints nothing.
    keyboard:
        Read stdin when it is a terminal: Enter relocalizes, ``q`` Enter stops.
    clock_ns:
        Host clock of capture stamps (the bridge's clock must be the same).
    fuse_submap:
        ``fuse(plane_sets, T_odom_cams) -> PlaneSet`` fusing a window's planes (see :class:`SubmapWindow`); None
        stacks them. With a ``grow`` method as well (:class:`reloc.live.factory.SubmapFuser`), a window that cannot
        pin a pose grows back in time up to ``params.max_window_frames``. The window is fused only when a
        relocalization is asked for (stage ``submap.build``).
    """

    def __init__(self, source, extract: Callable[[DepthFrame], Any], relocalizer, *, params: LiveParams | None = None,
                 map_planes: PlaneSet | None = None, bridge=None, odometry: str = "auto",
                 profiler: Profiler | None = None, on_status: Callable[[str], None] | None = None,
                 keyboard: bool = False, clock_ns: Callable[[], int] = time.monotonic_ns, fuse_submap=None):
        if odometry not in ("auto", "bridge", "source", "none"):
            raise ValueError(f"odometry: expected 'auto', 'bridge', 'source' or 'none', got {odometry!r}")
        if not hasattr(relocalizer, "locate"):
            raise ValueError(f"relocalizer: expected an object with locate(submap), got {type(relocalizer).__name__}")
        if not callable(extract):
            raise ValueError(f"extract: expected a callable frame -> result, got {type(extract).__name__}")
        self.source = source
        self.extract = extract
        self.relocalizer = relocalizer
        self.params = params or LiveParams()
        self.map_planes = map_planes
        self.bridge = bridge
        self.odometry_mode = odometry
        self.profiler = profiler or Profiler()
        self.on_status = on_status
        self.keyboard = keyboard
        self.clock_ns = clock_ns
        self.T_base_cam = self.params.T_base_cam
        self.T_cam_base = invert(self.T_base_cam)

        self._queue = DropOldestQueue(self.params.queue_frames)
        self._mailbox = _Mailbox()
        grow = getattr(fuse_submap, "grow", None)  # a SubmapFuser can grow a window that cannot pin a pose
        self._window = SubmapWindow(self.params.window_frames, fuse=fuse_submap,
                                    max_frames=self.params.max_window_frames if grow is not None else 0, grow=grow)
        self._fuse_stats = getattr(fuse_submap, "stats", None)  # a SubmapFuser counts frames its odometry check left out
        self._outbox: queue.Queue = queue.Queue(maxsize=64)
        self._stop = threading.Event()  # stop everything now (Ctrl-C, duration, stop())
        self._processing_done = threading.Event()
        self._workers_stop = threading.Event()
        self._lock = threading.Lock()
        self._threads: list[threading.Thread] = []
        self.capture_join_s = 5.0  # how long a source blocked in a read may hold up shutdown before it is closed
        self._requests: list[tuple[str, int]] = []  # (trigger, request id or 0) waiting for the next frame

        # Counters (each written by one thread; read under the lock for the status line and summary).
        self.captured = 0
        self.processed = 0
        self.planes_ok = 0
        self.source_gaps = 0
        self.stalls = 0
        self.disconnects = 0
        self.reconnects = 0
        self.reconnect_failures = 0
        self.source_end = "running"
        self.bad: Counter[str] = Counter()  # written by the processing thread only
        self.capture_bad: Counter[str] = Counter()  # written by the capture thread only
        self._last_frame_s: float | None = None
        self.odometry_used: Counter[str] = Counter()
        self.odometry_jumps = 0
        self.odometry_resets = 0
        self.serial_errors = 0
        self.reloc_errors = 0  # failures around a query (the query's own errors are records with status "error")
        self.lost_events: Counter[str] = Counter()
        # The latest records (bounded: a robot lost for hours retries several times a second) and run totals.
        self.max_records = 20_000
        self.relocalizations: deque[RelocRecord] = deque(maxlen=self.max_records)
        self.relocs_total = 0
        self.relocs_ok_total = 0
        self.events: deque[str] = deque(maxlen=200)
        self.status_errors = 0  # status lines whose output (on_status) raised
        self.errors: list[str] = []
        self.state = "starting"  # starting | localized | searching
        self.last_error = ""

        # The last accepted pose: (T_map_cam, T_odom_cam at that frame, seq, odometry kind, its covariance or None,
        # the frame's stamp).
        self._verified: tuple[np.ndarray, np.ndarray | None, int, str, np.ndarray | None, int] | None = None
        # The odometry's motion since that pose, for the tracked poses' covariance: [the _verified tuple it is
        # counted from, the last T_odom_cam, path length (m), angle turned (rad)].
        self._track_motion: list | None = None
        self._prev_odom: tuple[str, np.ndarray, int] | None = None  # (kind, T_odom_cam, seq)
        self._odom_reset_pending = False
        self._odom_epoch = 0  # counts resets of the odometry chain
        self._host_stamps = False  # the source stamps frames with the host clock (see _host_clock)
        self._bad_streak = 0
        self._last_attempt_s: float | None = None
        self._last_ok_s: float | None = None
        self._t_start = 0.0

    # -- control -----------------------------------------------------------------------------------------------
    def stop(self) -> None:
        """Stop as soon as possible (thread-safe; signal handlers call it)."""
        self._stop.set()
        self._queue.close()

    def records(self) -> list[RelocRecord]:
        """The relocalizations so far (a copy; safe to call from any thread while the loop runs)."""
        with self._lock:
            return list(self.relocalizations)

    def _frames_usable(self) -> bool:
        """Whether a frame with planes came in lately (within ``stall_s``, at least 1 s): one that a relocalization
        request can be answered with."""
        last = self._last_frame_s
        return last is not None and time.monotonic() - last <= max(1.0, self.params.stall_s)

    def _take_firmware_requests(self) -> tuple[int, ...]:
        """The ids of the pending requests from the firmware, taken off the pending list (other triggers stay)."""
        with self._lock:
            ids = tuple(i for _, i in self._requests if i)
            if ids:
                self._requests = [(t, i) for t, i in self._requests if not i]
        return ids

    def request_relocalization(self, trigger: str = "manual", request_id: int = 0) -> None:
        """Relocalize with the next frame's submap (thread-safe); ``request_id`` is answered over serial."""
        with self._lock:
            self._requests.append((trigger, int(request_id)))

    def run(self, *, max_frames: int | None = None, duration_s: float | None = None) -> LiveSummary:
        """Run (once) until the source ends, ``max_frames`` frames were captured, ``duration_s`` passed, or
        :meth:`stop`.

        Frames already queued are still processed and a pending relocalization finishes when the source ends or
        ``max_frames`` is reached; after :meth:`stop`, Ctrl-C or ``duration_s`` the loop stops at once. Every
        thread is joined before this returns.
        """
        if max_frames is not None and (not isinstance(max_frames, int) or max_frames < 1):
            raise ValueError(f"max_frames: expected a positive integer, got {max_frames!r}")
        if duration_s is not None and not duration_s > 0:
            raise ValueError(f"duration_s: expected > 0, got {duration_s!r}")
        if self._threads:
            raise RuntimeError("LiveLoop.run: a loop runs once; make a new LiveLoop for another run")
        self._t_start = time.monotonic()
        cpu0 = time.process_time()
        targets = [("capture", lambda: self._capture(max_frames)), ("processing", self._processing),
                   ("relocalization", self._relocalization)]
        if self.bridge is not None:
            targets.append(("serial", self._serial))
        if self.keyboard and _stdin_is_tty():
            targets.append(("keyboard", self._keyboard))
        self._threads = [threading.Thread(target=self._guard(fn, name), name=name, daemon=True) for name, fn in targets]
        try:
            for t in self._threads:
                t.start()
            next_status = time.monotonic() + self.params.status_period_s
            last = (time.monotonic(), 0)
            while not self._workers_stop.is_set():
                now = time.monotonic()
                if duration_s is not None and now - self._t_start >= duration_s:
                    self.stop()
                    break
                wait = next_status - now
                if duration_s is not None:
                    wait = min(wait, self._t_start + duration_s - now)
                self._workers_stop.wait(max(wait, 0.0))
                now = time.monotonic()
                if now >= next_status:
                    fps = (self.processed - last[1]) / max(now - last[0], 1e-9)
                    last = (now, self.processed)
                    if self.on_status is not None:
                        self._report_status(self.status_line(fps))
                    next_status = now + self.params.status_period_s
        except KeyboardInterrupt:
            self.events.append("interrupted")
            self.stop()
        except BaseException:
            self.stop()  # else the shutdown waits for a processing thread that only the source's end stops
            raise
        finally:
            self._shutdown()
        return self.summary(time.monotonic() - self._t_start, time.process_time() - cpu0)

    def _report_status(self, line: str) -> None:
        """A status line to ``on_status``; an output that fails (stderr piped into a reader that went away:
        BrokenPipeError) is counted and noted once, and the loop goes on."""
        try:
            self.on_status(line)
        except Exception as exc:  # noqa: BLE001 - whatever the output raises, the robot keeps its poses
            self.status_errors += 1
            if self.status_errors == 1:
                self.events.append(f"status output failed ({exc!r}); later status lines dropped while it fails")

    # -- threads -----------------------------------------------------------------------------------------------
    def _guard(self, fn, name):
        def run():
            try:
                fn()
            except Exception as exc:  # noqa: BLE001 - a dying thread must stop the loop, not hang it
                self.errors.append(f"{name}: {exc!r}")
                self.last_error = f"{name}: {exc!r}"
                self.stop()
                self._workers_stop.set()
        return run

    def _capture(self, max_frames: int | None) -> None:
        prof = self.profiler
        reconnect = getattr(self.source, "reconnect", None)
        it = iter(self.source)
        last_seq = last_cap = None
        missing: set[int] = set()  # numbers skipped over (a few dozen a gap), in case they come late
        tag = None  # a trigger attached to the next frame
        try:
            while not self._stop.is_set():
                t0 = time.perf_counter_ns()
                try:
                    frame = next(it)
                except StopIteration:
                    self.source_end = "end_of_stream"
                    break
                except Exception as exc:  # noqa: BLE001 - a camera failing mid-stream is an event, not a crash
                    self.disconnects += 1
                    self._event(f"source disconnected: {exc}")
                    if not callable(reconnect) or not self._reconnect(reconnect):
                        self.source_end = "disconnected" if not self._stop.is_set() else "stopped"
                        break
                    it = iter(self.source)
                    last_cap = None
                    tag = "reconnect"  # the robot may have moved while the camera was away
                    continue
                t_cap = self.clock_ns()
                prof.record("capture.wait", t0, time.perf_counter_ns() - t0)
                if not isinstance(frame, DepthFrame):
                    self.capture_bad[f"not_a_frame:{type(frame).__name__}"] += 1
                    continue
                if last_seq is not None and frame.seq > last_seq + 1:
                    self.source_gaps += frame.seq - last_seq - 1
                    if len(missing) < 1024:
                        missing.update(range(last_seq + 1, min(frame.seq, last_seq + 65)))
                elif frame.seq in missing:  # delivered late (5, 3, 4): not missing after all
                    missing.discard(frame.seq)
                    self.source_gaps -= 1
                if last_cap is not None and t_cap - last_cap > self.params.stall_s * 1e9:
                    self.stalls += 1
                    self._event(f"source stalled {(t_cap - last_cap) / 1e9:.2f} s before seq {frame.seq}")
                # The highest number so far: a frame delivered late (5, 3, 4) fills in a gap, it opens none.
                last_seq = frame.seq if last_seq is None else max(last_seq, frame.seq)
                last_cap = t_cap
                self.captured += 1
                self._queue.put((frame, t_cap, tag), carry=_carry_trigger)
                tag = None
                if max_frames is not None and self.captured >= max_frames:
                    self.source_end = "max_frames"
                    break
            else:
                self.source_end = "stopped"
        finally:
            self._queue.close()

    def _reconnect(self, reconnect) -> bool:
        backoff = self.params.reconnect_backoff_s
        k = 0
        while not self._stop.is_set():
            if self._stop.wait(backoff[min(k, len(backoff) - 1)]):
                return False
            try:
                ok = bool(reconnect())
            except Exception as exc:  # noqa: BLE001
                ok = False
                self._event(f"reconnect failed: {exc}")
            if ok:
                self.reconnects += 1
                self._event("source reconnected")
                return True
            self.reconnect_failures += 1
            k += 1
        return False

    def _processing(self) -> None:
        try:
            while not self._stop.is_set():
                item = self._queue.get(timeout_s=0.1)
                if item is None:
                    if self._queue.finished:
                        break
                    continue
                frame, t_cap, tag = item
                if tag == "reconnect":
                    self._reset_odometry()  # frames across the gap share no odometry we can trust
                if tag is not None:
                    self.request_relocalization(tag)
                try:
                    self._process(frame, t_cap)
                except Exception as exc:  # noqa: BLE001 - one bad frame never stops the loop
                    self.bad[f"processing_error:{type(exc).__name__}"] += 1
                    self.last_error = f"seq {frame.seq}: {exc!r}"
            if not self._stop.is_set():
                # The source ended: let a pending relocalization finish so its result is reported.
                self._mailbox.wait_idle(30.0, self._stop)
        finally:
            self._processing_done.set()
            self._workers_stop.set()

    def _process(self, frame: DepthFrame, t_cap: int) -> None:
        prof = self.profiler
        self.processed += 1
        depth = frame.depth_m
        if not np.any(depth > 0):  # NaN compares False: all-NaN and all-zero frames have no measurement
            self.bad["no_valid_depth"] += 1
            return
        t0 = time.perf_counter_ns()
        try:
            result = self.extract(frame)
            planes = result.planes
            if not isinstance(planes, PlaneSet):
                raise TypeError(f"extraction returned {type(planes).__name__}, expected a PlaneSet")
        except Exception as exc:  # noqa: BLE001 - one bad frame never stops the loop
            self.bad[f"extraction_error:{type(exc).__name__}"] += 1
            self.last_error = f"seq {frame.seq}: {exc}"
            return
        t1 = time.perf_counter_ns()
        prof.record("extract", t0, t1 - t0)
        timings = {k: v for k, v in getattr(result, "timings_ms", {}).items() if k != "total"}
        prof.add_timings_ms(timings, prefix="extract.", end_ns=t1)
        self.planes_ok += 1
        self._last_frame_s = time.monotonic()  # a frame that can answer a relocalization request
        cap_to_planes = self.clock_ns() - t_cap
        prof.record("latency.capture_to_planes", t1 - cap_to_planes, cap_to_planes)

        with prof.stage("submap"):
            T_odom_cam, odo_kind = self._odometry_pose(frame, t_cap)
            self.odometry_used[odo_kind] += 1
            lost_trigger = None
            if self._prev_odom is not None and self._prev_odom[0] != odo_kind:
                # Poses of different odometry sources (bridge, camera, none) cannot be chained in one submap.
                self._reset_odometry()
            if self._odom_reset_pending:
                self._odom_reset_pending = False
                self._reset_odometry()
                self._verified = None
                lost_trigger = "odometry_reset"
            if T_odom_cam is not None and self._prev_odom is not None and self._prev_odom[0] == odo_kind:
                # Frames dropped in between allow proportionally more motion.
                k = max(1, frame.seq - self._prev_odom[2])
                if is_jump(self._prev_odom[1], T_odom_cam, k * self.params.lost_jump_m, k * self.params.lost_jump_rad):
                    self.odometry_jumps += 1
                    self._reset_odometry()
                    self._verified = None
                    lost_trigger = "odometry_jump"
            self._prev_odom = None if T_odom_cam is None else (odo_kind, T_odom_cam, frame.seq)
            self._window.push(planes, T_odom_cam, frame.seq)

        T_pred = cov_pred = None
        with prof.stage("track"):
            verified = self._verified
            if verified is not None and T_odom_cam is not None and verified[1] is not None and verified[3] == odo_kind:
                T_pred = predict_T_map_cam(verified[0], verified[1], T_odom_cam)
                if self.bridge is not None:  # only the serial link sends it
                    cov_pred = self._tracked_covariance(verified, T_odom_cam, T_pred, frame.stamp_ns)
                if self.map_planes is not None:
                    frac = explained_fraction(planes, T_pred, self.map_planes,
                                              max_angle_rad=self.params.check_max_angle_rad,
                                              max_offset_m=self.params.check_max_offset_m)
                    if frac < self.params.lost_min_explained:  # NaN (no planes) is no evidence
                        self._bad_streak += 1
                    elif frac == frac:
                        self._bad_streak = 0
                    if self._bad_streak >= self.params.lost_frames:
                        self._bad_streak = 0
                        self._verified = None
                        T_pred = None
                        lost_trigger = lost_trigger or "tracking_lost"
        if lost_trigger is not None:
            self.lost_events[lost_trigger] += 1
            self.state = "searching"
            self._event(f"lost ({lost_trigger}) at seq {frame.seq}")
        if T_pred is not None and self.bridge is not None:
            self._post(("tracked", T_pred, frame.stamp_ns if self._host_clock(frame.stamp_ns, t_cap) else t_cap, 0.0,
                        0, cov_pred))

        trigger, request_ids = self._trigger(lost_trigger)
        if trigger is not None:
            with prof.stage("submap.build"):  # only for a relocalization: a window is fused when it is needed
                submap = self._window.build()
            truth = frame.T_world_cam if frame.pose_source in _TRUTH_SOURCES else None
            self._last_attempt_s = time.monotonic()
            self._mailbox.submit(_Job(trigger, submap, self._window.last_frames, frame.seq, frame.stamp_ns, t_cap,
                                      T_odom_cam, odo_kind, self._odom_epoch, truth, request_ids))

    def _reset_odometry(self) -> None:
        """Forget the odometry chain: the window restarts and poses from before cannot be related to later ones."""
        self._window.reset()
        self._prev_odom = None
        self._odom_epoch += 1

    def _trigger(self, lost_trigger: str | None) -> tuple[str | None, tuple]:
        with self._lock:
            requests, self._requests = self._requests, []
        now = time.monotonic()
        triggers = list(dict.fromkeys(t for t, _ in requests))
        ids = tuple(i for _, i in requests if i)
        if lost_trigger is not None:
            triggers.append(lost_trigger)
        if not triggers:
            if self._last_attempt_s is None:
                triggers.append("startup")
            elif self.state != "localized":
                if now - self._last_attempt_s >= self.params.search_period_s and self._mailbox.idle:
                    triggers.append("search")
            elif now - (self._last_ok_s or 0.0) >= self.params.reloc_period_s and \
                    now - self._last_attempt_s >= self.params.reloc_period_s:
                triggers.append("periodic")
        return ("+".join(triggers) if triggers else None), ids

    def _relocalization(self) -> None:
        prof = self.profiler
        while not self._stop.is_set() and not (self._workers_stop.is_set() and self._mailbox.idle):
            job = self._mailbox.take(0.1)
            if job is None:
                continue
            try:
                self._relocalize(job, prof)
            except Exception as exc:  # noqa: BLE001 - a bad result must not stop relocalizing
                self.reloc_errors += 1
                self.last_error = f"relocalization: {exc!r}"
                self._event(f"relocalization error: {exc!r}")
            finally:
                self._mailbox.done()

    def _tracked_covariance(self, verified, T_odom_cam: np.ndarray, T_pred: np.ndarray, stamp_ns: int):
        """The covariance of the pose tracked from ``verified`` (see ``_verified``) to this frame
        (:func:`reloc.live.tracking.tracked_covariance`: the relocalized pose's, plus the odometry's drift over the
        path driven since, counted frame by frame), or None when the relocalizer gave none."""
        motion = self._track_motion
        if motion is None or motion[0] is not verified:
            # A new reference: the motion from its frame to this one (the relocalization's latency) in one step.
            motion = self._track_motion = [verified, verified[1], 0.0, 0.0]
        step_m, step_rad = odometry_step(motion[1], T_odom_cam)
        motion[1] = T_odom_cam
        motion[2] += step_m
        motion[3] += step_rad
        if verified[4] is None:
            return None
        return tracked_covariance(verified[4], T_pred[:3, 3], self._map_up, motion[2], motion[3],
                                  max(0.0, (stamp_ns - verified[5]) * 1e-9), self.params.odometry_drift)

    @property
    def _map_up(self) -> np.ndarray:
        """The map's up (unit, map frame): against its gravity; z without one (the map frame's convention)."""
        for planes in (getattr(self.relocalizer, "planes", None), self.map_planes):
            g = getattr(planes, "gravity", None)
            if g is not None:
                return -np.asarray(g, dtype=np.float64)
        return np.array([0.0, 0.0, 1.0])

    def _relocalize(self, job: _Job, prof: Profiler) -> None:
        t0 = time.perf_counter_ns()
        try:
            res = self.relocalizer.locate(job.submap)
            status, reason = str(res.status), str(getattr(res, "reason", ""))
            T = None if res.T_map_cam is None else np.asarray(res.T_map_cam, dtype=np.float64)
            cov = getattr(res, "covariance", None)
            score = float(getattr(res, "score", float("nan")))
            timings = {k: v for k, v in (getattr(res, "timings_ms", None) or {}).items() if k != "total"}
        except Exception as exc:  # noqa: BLE001 - a failing query is a rejection with a reason
            status, reason, T, score, timings = "error", f"{type(exc).__name__}: {exc}", None, float("nan"), {}
            cov = None
            self.last_error = f"relocalization: {exc!r}"
        t1 = time.perf_counter_ns()
        prof.record("reloc", t0, t1 - t0)
        prof.add_timings_ms(timings, prefix="reloc.", end_ns=t1)
        ok = status == "relocalized" and T is not None
        cap_to_pose = self.clock_ns() - job.t_cap_ns
        if ok:
            prof.record("latency.capture_to_pose", t1 - cap_to_pose, cap_to_pose)
        err_m = err_deg = None
        if ok and job.T_truth is not None:
            err_m, err_deg = pose_error(T, job.T_truth)
        rec = RelocRecord(
            index=self.relocs_total, trigger=job.trigger, seq=job.seq, stamp_ns=job.stamp_ns, status=status,
            reason=reason, T_map_cam=T if ok else None, score=score, submap_frames=job.submap_frames,
            submap_planes=len(job.submap), reloc_ms=(t1 - t0) / 1e6, capture_to_pose_ms=cap_to_pose / 1e6,
            request_ids=job.request_ids, position_error_m=err_m, rotation_error_deg=err_deg,
        )
        with self._lock:
            self.relocalizations.append(rec)
            self.relocs_total += 1
            self.relocs_ok_total += int(rec.ok)
        now = time.monotonic()
        if ok:
            # A result for a frame from before an odometry reset cannot be propagated with the new odometry.
            T_odom = job.T_odom_cam if job.odometry_epoch == self._odom_epoch else None
            C = None if cov is None else np.asarray(cov, dtype=np.float64)
            if C is not None and C.shape != (6, 6):
                C = None
            self._verified = (T, T_odom, job.seq, job.odometry_kind, C, job.stamp_ns)
            self._bad_streak = 0
            self._last_ok_s = now
            self.state = "localized"
        elif self.state == "localized" and job.trigger.startswith("periodic"):
            pass  # a failed verification alone does not mean lost; the tracking check decides
        else:
            self.state = "searching"
        if self.bridge is not None:
            stamp = job.stamp_ns if self._host_clock(job.stamp_ns, job.t_cap_ns) else job.t_cap_ns
            for rid in job.request_ids or (0,):
                self._post(("reloc", T if ok else None, stamp, score, rid, reason, cov if ok else None))

    # -- serial ------------------------------------------------------------------------------------------------
    def _post(self, item) -> None:
        try:
            self._outbox.put_nowait(item)
        except queue.Full:
            try:
                self._outbox.get_nowait()
            except queue.Empty:
                pass
            self._outbox.put_nowait(item)

    def _serial(self) -> None:
        from firmware_bridge.host import BridgeEvent, OdometryEvent, RelocRequestEvent
        from firmware_bridge.messages import HostState, PoseStatus

        bridge, prof = self.bridge, self.profiler
        states = {"starting": HostState.STARTING, "localized": HostState.LOCALIZED, "searching": HostState.SEARCHING}
        next_status = 0.0
        last_T_map_base = np.eye(4)
        while not self._workers_stop.is_set() or not self._outbox.empty():
            try:
                ev = bridge.get_event(timeout_s=0.02)
                while ev is not None:
                    if isinstance(ev, RelocRequestEvent):
                        self._event(f"relocalization requested by the MCU (id {ev.request_id}, "
                                    f"reason {ev.reason})")
                        if not self._frames_usable():
                            # No usable frames (camera starting, lost, stalled, or only bad frames): say so now, do
                            # not make the firmware wait.
                            self._post(("reloc", None, self.clock_ns(), 0.0, ev.request_id, _NO_FRAMES, None))
                        else:
                            self.request_relocalization("request", ev.request_id)
                    elif isinstance(ev, BridgeEvent):
                        if ev.kind in ("odometry_reset", "mcu_reboot"):
                            self.odometry_resets += 1
                            self._odom_reset_pending = True
                        if ev.kind not in ("mcu_alive",):
                            self._event(f"serial: {ev.kind} {ev.detail}".strip())
                    elif isinstance(ev, OdometryEvent):
                        pass  # odometry is read from the bridge's buffer at each frame's capture time
                    ev = bridge.get_event(timeout_s=0)
                if not self._frames_usable():
                    # Requests taken while frames were usable wait for the next usable frame; none came since.
                    for rid in self._take_firmware_requests():
                        self._post(("reloc", None, self.clock_ns(), 0.0, rid, _NO_FRAMES, None))
                while True:
                    try:
                        item = self._outbox.get_nowait()
                    except queue.Empty:
                        break
                    with prof.stage("serial.send_pose"):
                        if item[0] == "tracked":
                            _, T_map_cam, stamp, score, rid, cov = item
                            T_map_base = T_map_cam @ self.T_cam_base
                            bridge.send_pose(T_map_base, stamp, status=PoseStatus.TRACKED, score=score,
                                             request_id=rid, covariance=cov)
                        else:
                            _, T_map_cam, stamp, score, rid, reason, cov = item
                            if T_map_cam is not None:
                                # The covariance is of the left perturbation in the map frame: the same for the
                                # base as for the camera (T_map_base = T_map_cam T_cam_base).
                                last_T_map_base = T_map_cam @ self.T_cam_base
                                bridge.send_pose(last_T_map_base, stamp, status=PoseStatus.OK,
                                                 score=score if math.isfinite(score) else 0.0, request_id=rid,
                                                 covariance=cov)
                            elif rid:
                                # An answer is owed: a rejection with its reason (the pose field holds the last one).
                                bridge.send_pose(last_T_map_base, stamp, status=_reject_status(reason, PoseStatus),
                                                 score=0.0, request_id=rid)
                now = time.monotonic()
                if now >= next_status:
                    next_status = now + 0.5
                    with self._lock:
                        ok = self.relocs_ok_total
                        failed = self.relocs_total - ok
                    bridge.send_status(states.get(self.state, HostState.SEARCHING), frames_processed=self.processed,
                                       relocs_ok=ok, relocs_failed=failed, last_error=self.last_error[:60])
            except Exception as exc:  # noqa: BLE001 - the link must not take the loop down; count and go on
                self.serial_errors += 1
                self.last_error = f"serial: {exc!r}"
                self._event(f"serial error: {exc!r}")
                self._workers_stop.wait(0.05)

    def _host_clock(self, stamp_ns: int, t_cap_ns: int) -> bool:
        """Whether the source stamps frames with the host clock: true from the first frame stamped within a second
        of its capture on. Kept for the run, so that a frame delivered late (a camera that stalled with a frame in
        its buffer) keeps its own stamp: stamped with its capture time instead, its pose would reach the MCU labelled
        with the wrong moment (off by the robot's motion meanwhile) and its odometry would be looked up there."""
        if not self._host_stamps:
            self._host_stamps = _host_clock_stamp(stamp_ns, t_cap_ns)
        return self._host_stamps

    def _odometry_pose(self, frame: DepthFrame, t_cap: int) -> tuple[np.ndarray | None, str]:
        mode = self.odometry_mode
        if mode in ("auto", "bridge") and self.bridge is not None:
            T_odom_base = self.bridge.T_odom_base_at(frame.stamp_ns if self._host_clock(frame.stamp_ns, t_cap)
                                                     else t_cap)
            if T_odom_base is not None:
                return T_odom_base @ self.T_base_cam, "bridge"
        if frame.T_world_cam is not None and (
                (mode == "auto" and frame.pose_source == "odometry") or mode == "source"):
            return frame.T_world_cam, f"source:{frame.pose_source}"
        return None, "none"

    # -- keyboard ----------------------------------------------------------------------------------------------
    def _keyboard(self) -> None:
        import select

        while not self._workers_stop.is_set():
            ready, _, _ = select.select([sys.stdin], [], [], 0.2)
            if not ready:
                continue
            line = sys.stdin.readline()
            if line == "":  # end of input
                return
            if line.strip().lower() in ("q", "quit"):
                self._event("quit requested from the keyboard")
                self.stop()
                return
            self._event("relocalization requested from the keyboard")
            self.request_relocalization("keypress")

    # -- shutdown and reporting --------------------------------------------------------------------------------
    def _shutdown(self) -> None:
        if self._stop.is_set():
            self._queue.close()
        # Processing ends first (it drains the queue unless stopped), then the workers.
        for t in self._threads:
            if t.name == "processing":
                t.join()
        self._workers_stop.set()
        for t in self._threads:
            if t.name == "capture":
                t.join(self.capture_join_s)
                if t.is_alive():
                    # A source blocked in a read: closing it is the way to wake it.
                    self._event("capture thread blocked; closing the source")
                    close = getattr(self.source, "close", None)
                    if callable(close):
                        close()
        for t in self._threads:
            t.join()

    def _event(self, text: str) -> None:
        self.events.append(f"{time.monotonic() - self._t_start:8.3f} s  {text}")

    def status_line(self, fps: float) -> str:
        """One line: fps, per-stage latency (p50), drops, state, last relocalization and its score."""
        stages = self.profiler.summary()["stages"]

        def p50(name):
            s = stages.get(name)
            return f"{s['p50_ms']:.1f}" if s else "-"

        with self._lock:
            last = self.relocalizations[-1] if self.relocalizations else None
        if last is None:
            rel = "none yet"
        else:
            rel = f"#{last.index} {last.status} ({last.trigger}) score {last.score:.3g}"
            if not last.ok:
                rel += f" [{last.reason}]"
        return (f"{fps:5.1f} fps | extract {p50('extract')} ms, reloc {p50('reloc')} ms, "
                f"cap->planes {p50('latency.capture_to_planes')} ms | frames {self.processed}/{self.captured}, "
                f"dropped {self._queue.dropped}, gaps {self.source_gaps}, bad {sum(self.bad.values())} | "
                f"{self.state} | last reloc {rel}")

    def summary(self, duration_s: float, cpu_s: float) -> LiveSummary:
        prof = self.profiler.summary()["stages"]
        e2e = {}
        for key, stage in (("capture_to_planes", "latency.capture_to_planes"),
                           ("capture_to_pose", "latency.capture_to_pose")):
            s = prof.get(stage)
            e2e[key] = None if s is None else {k: round(s[k], 3) for k in ("count", "p50_ms", "p95_ms", "p99_ms",
                                                                           "max_ms", "mean_ms")}
        # NaN (a wait's share: not part of the work) as null, so that the summary stays strict JSON.
        latency = {name: {k: ((round(v, 4) if math.isfinite(v) else None) if isinstance(v, float) else v)
                          for k, v in s.items()}
                   for name, s in prof.items() if not name.startswith("latency.")}
        info = self.source.info() if hasattr(self.source, "info") else {"name": str(self.source)}
        frames = {
            "captured": self.captured, "processed": self.processed, "with_planes": self.planes_ok,
            "dropped": self._queue.dropped, "source_gaps": self.source_gaps,
            "bad": dict(self.bad + self.capture_bad),
            "queue_capacity": self._queue.maxlen, "queue_max_depth": self._queue.max_depth,
            "fps": round(self.processed / duration_s, 3) if duration_s > 0 else None,
        }
        bridge = None
        if self.bridge is not None:
            try:
                bridge = {**_jsonable(self.bridge.stats()), "loop_serial_errors": self.serial_errors}
            except Exception as exc:  # noqa: BLE001
                bridge = {"error": repr(exc)}
        faults = None
        counts = getattr(self.source, "counts", None)
        if isinstance(counts, dict):
            faults = dict(counts)
        return LiveSummary(
            source=_jsonable(info), duration_s=duration_s, cpu_s=cpu_s, frames=frames,
            source_events={"end": self.source_end, "disconnects": self.disconnects, "reconnects": self.reconnects,
                           "reconnect_failures": self.reconnect_failures, "stalls": self.stalls,
                           "events": list(self.events), "status_errors": self.status_errors},
            odometry={"used": dict(self.odometry_used), "jumps": self.odometry_jumps, "resets": self.odometry_resets,
                      "frames_left_out": int((self._fuse_stats or {}).get("frames_left_out", 0))},
            tracking={"lost": dict(self.lost_events), "superseded_requests": self._mailbox.superseded,
                      "relocalization_thread_errors": self.reloc_errors,
                      "final_state": self.state},
            relocalizations=self.records(), relocs_total=self.relocs_total,
            relocs_ok_total=self.relocs_ok_total, latency_ms=latency, end_to_end_ms=e2e, bridge=bridge,
            faults=faults, errors=list(self.errors),
        )


_NO_FRAMES = "not_ready: no usable camera frames"  # the answer to a request no frame can serve


def _carry_trigger(dropped: tuple, oldest: tuple) -> tuple:
    """The queue's oldest frame takes on the trigger of a frame dropped before it: a reconnect's odometry reset must
    come before any frame from after the gap is processed, and its relocalization must still be asked for."""
    return oldest if dropped[2] is None or oldest[2] is not None else (oldest[0], oldest[1], dropped[2])


def _reject_status(reason: str, PoseStatus) -> int:
    """The status a rejection answers a firmware request with: TOO_FEW_PLANES only for the rejection before any
    search (too few planes to try; most other reasons name planes too: "contradicted by the map: 5 planes matched
    less 3 in conflict" is NO_MATCH)."""
    from reloc.matching.relocalizer import TOO_FEW_PLANES_RE

    r = reason.lower()
    if r.startswith("not_ready"):
        return PoseStatus.NOT_READY
    if r.startswith("ambiguous"):
        return PoseStatus.AMBIGUOUS
    if TOO_FEW_PLANES_RE.match(reason):
        return PoseStatus.TOO_FEW_PLANES
    return PoseStatus.NO_MATCH


def _host_clock_stamp(stamp_ns: int, t_cap_ns: int) -> bool:
    """A source stamp is on the host clock (as the OAK driver's are) when it is within a second of capture time."""
    return abs(int(stamp_ns) - int(t_cap_ns)) < 1_000_000_000


def _stdin_is_tty() -> bool:
    try:
        return sys.stdin is not None and sys.stdin.isatty()
    except (ValueError, OSError):
        return False


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, (str, int, bool)) or x is None:
        return x
    return str(x)
