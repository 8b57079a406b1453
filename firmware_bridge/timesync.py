"""Mapping the microcontroller's clock to the host's, from the heartbeat exchange.

Each MCU heartbeat echoes the stamp ``t1`` of the last host heartbeat it received and how long it held it
(``hold = t3 - t2`` in its clock); its own header stamp is its send time ``t3`` and the host notes the arrival ``t4``.
As in NTP, with ``offset = host - mcu``::

    offset ~ ((t1 - t2) + (t4 - t3)) / 2        round trip  rtt = (t4 - t1) - hold

The error of one sample is at most ``rtt / 2`` and is only that large when the two directions are delayed unequally,
which is what a delay spike (a busy USB bus, a descheduled reader thread) does. The estimator therefore keeps a
window of recent samples and uses the one with the smallest round trip (a minimum-delay filter): spikes only ever
lengthen the round trip, so they are never chosen. The window is bounded in time so that the estimate follows the
drift of the MCU's crystal (50 ppm is 0.5 ms in 10 s); within the window the offset is extrapolated with the drift
rate fitted to the best samples of successive windows.

Before any two-way sample exists, one-way samples (any MCU frame: ``host_rx - mcu_tx = offset + delay >= offset``)
give an upper bound; their minimum is the estimate until the first heartbeat answer arrives.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass

__all__ = ["ClockSync", "SyncSample"]


@dataclass(frozen=True)
class SyncSample:
    host_ns: int  # host time of the sample (midpoint of the round trip)
    offset_ns: int  # host - mcu
    rtt_ns: int  # round trip (two-way) or -1 (one-way bound)


class ClockSync:
    """Thread-safe estimate of ``host_ns = mcu_ns + offset_ns`` (int64 nanoseconds everywhere).

    Parameters
    ----------
    window_s:
        Samples older than this (host time) are forgotten, so the estimate follows clock drift.
    max_samples:
        At most this many two-way samples are kept.
    min_samples:
        ``synced`` becomes true after this many two-way samples.
    max_rtt_ns:
        Two-way samples with a longer round trip are ignored outright (a stale echo after a reconnect).
    """

    def __init__(self, *, window_s: float = 20.0, max_samples: int = 64, min_samples: int = 3,
                 max_rtt_ns: int = 500_000_000):
        if window_s <= 0:
            raise ValueError(f"window_s: expected > 0, got {window_s}")
        if max_samples < 1 or min_samples < 1:
            raise ValueError(f"max_samples, min_samples: expected >= 1, got {max_samples}, {min_samples}")
        self.window_ns = int(window_s * 1e9)
        self.min_samples = int(min_samples)
        self.max_rtt_ns = int(max_rtt_ns)
        self._lock = threading.Lock()
        self._two_way: deque[SyncSample] = deque(maxlen=int(max_samples))
        self._one_way_best: SyncSample | None = None
        self._anchors: deque[SyncSample] = deque(maxlen=8)  # best sample of past windows, for the drift rate
        self._n_two_way = 0
        self._rejected = 0

    def reset(self) -> None:
        """Forget everything (the MCU rebooted: its clock restarted)."""
        with self._lock:
            self._two_way.clear()
            self._anchors.clear()
            self._one_way_best = None
            self._n_two_way = 0

    def add_two_way(self, t1_host_ns: int, t2_mcu_ns: int, t3_mcu_ns: int, t4_host_ns: int) -> SyncSample | None:
        """One round trip: host sent at t1, MCU received at t2 and replied at t3, host received at t4."""
        rtt = (t4_host_ns - t1_host_ns) - (t3_mcu_ns - t2_mcu_ns)
        if rtt < 0 or rtt > self.max_rtt_ns or t3_mcu_ns < t2_mcu_ns:
            with self._lock:
                self._rejected += 1
            return None
        offset = ((t1_host_ns - t2_mcu_ns) + (t4_host_ns - t3_mcu_ns)) // 2
        sample = SyncSample((t1_host_ns + t4_host_ns) // 2, offset, rtt)
        with self._lock:
            self._prune(t4_host_ns)
            self._two_way.append(sample)
            self._n_two_way += 1
            if not self._anchors or sample.host_ns - self._anchors[-1].host_ns >= self.window_ns // 2:
                self._push_anchor()
        return sample

    def add_one_way(self, mcu_tx_ns: int, host_rx_ns: int) -> None:
        """Any frame from the MCU: its header stamp and the host's arrival time bound the offset from above."""
        offset = host_rx_ns - mcu_tx_ns
        with self._lock:
            best = self._one_way_best
            if best is None or offset < best.offset_ns or best.host_ns < host_rx_ns - self.window_ns:
                self._one_way_best = SyncSample(host_rx_ns, offset, -1)

    def _prune(self, now_host_ns: int) -> None:
        while self._two_way and self._two_way[0].host_ns < now_host_ns - self.window_ns:
            self._two_way.popleft()

    def _push_anchor(self) -> None:
        best = min(self._two_way, key=lambda s: s.rtt_ns)
        if not self._anchors or best.host_ns > self._anchors[-1].host_ns:
            self._anchors.append(best)

    def _best(self) -> SyncSample | None:
        if self._two_way:
            return min(self._two_way, key=lambda s: s.rtt_ns)
        return self._one_way_best

    def _drift(self, best: SyncSample) -> float:
        """d(offset)/d(host time) from the anchors and the current best sample (0 without enough span)."""
        pts = [a for a in self._anchors if a.host_ns < best.host_ns] + [best]
        if len(pts) < 3 or pts[-1].host_ns - pts[0].host_ns < 5e9:
            return 0.0
        n = len(pts)
        mx = sum(p.host_ns for p in pts) / n
        my = sum(p.offset_ns for p in pts) / n
        sxx = sum((p.host_ns - mx) ** 2 for p in pts)
        sxy = sum((p.host_ns - mx) * (p.offset_ns - my) for p in pts)
        rate = sxy / sxx if sxx > 0 else 0.0
        return max(-1e-3, min(1e-3, rate))  # a crystal is never off by more than 1000 ppm

    @property
    def synced(self) -> bool:
        with self._lock:
            return self._n_two_way >= self.min_samples and bool(self._two_way)

    def offset_ns(self, at_host_ns: int | None = None) -> int | None:
        """Estimated ``host - mcu`` (at host time ``at_host_ns`` when drift is known); None without any sample."""
        with self._lock:
            best = self._best()
            if best is None:
                return None
            if best.rtt_ns < 0 or at_host_ns is None:
                return best.offset_ns
            # Integer nanoseconds but for the drift's correction: a host clock of 1.7e18 ns (time.time_ns) has no
            # exact float, and a float sum was off by tens of nanoseconds with no drift at all.
            return best.offset_ns + round(self._drift(best) * (at_host_ns - best.host_ns))

    def uncertainty_ns(self) -> int | None:
        """Half the round trip of the sample in use (bound of its error); None for a one-way bound or no sample."""
        with self._lock:
            best = self._best()
            return None if best is None or best.rtt_ns < 0 else best.rtt_ns // 2

    def mcu_to_host_ns(self, mcu_ns: int) -> int | None:
        """Host time of an MCU stamp, or None before any sample."""
        with self._lock:
            best = self._best()
            if best is None:
                return None
            if best.rtt_ns < 0:
                return int(mcu_ns) + best.offset_ns
            drift = self._drift(best)
            # host = mcu + offset(host); solve to first order around the sample (integer ns but for the correction).
            approx = int(mcu_ns) + best.offset_ns
            return approx + round(drift * (approx - best.host_ns))

    def host_to_mcu_ns(self, host_ns: int) -> int | None:
        """MCU time of a host stamp, or None before any sample."""
        off = self.offset_ns(host_ns)
        return None if off is None else int(host_ns - off)

    def summary(self) -> dict:
        with self._lock:
            best = self._best()
            return {
                "two_way_samples": self._n_two_way,
                "window_samples": len(self._two_way),
                "rejected_samples": self._rejected,
                "offset_ns": None if best is None else best.offset_ns,
                "rtt_ns": None if best is None or best.rtt_ns < 0 else best.rtt_ns,
                "drift_ppm": 0.0 if best is None or best.rtt_ns < 0 else self._drift(best) * 1e6,
            }
