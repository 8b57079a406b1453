"""Fault injection around any frame source, so the live loop's behaviour under faults is tested without hardware.

:class:`FaultySource` wraps a :class:`~drivers.source.FrameSource` and, seeded, injects what real cameras do:

- ``drop_rate`` / ``drop_at``: a frame never arrives (the consumer sees a gap in ``seq``);
- ``stall_rate`` / ``stall_at`` / ``stall_s``: the stream stops for a while before the next frame (a USB hiccup);
- ``invalid_rate`` / ``invalid_at``: a frame arrives with no valid depth at all (every pixel NaN: a covered lens, a
  saturated sensor);
- ``disconnect_at``: at these input frame indices the stream breaks with :class:`SourceDisconnected` (an unplug);
  :meth:`FaultySource.reconnect` brings it back after ``reconnect_s``, the stream resuming where it stopped (stamps
  and ``seq`` keep increasing; the frame that was in flight is lost and counted as dropped by the disconnect).

Rates are per-frame probabilities; ``*_at`` are input frame indices (0-based, counted over the wrapped stream) where
the fault happens for certain. Every injected fault is counted in :attr:`FaultySource.counts` and the affected
``seq`` numbers are kept in :attr:`FaultySource.injected`, so a test can check the consumer's counts against exactly what was injected.
The decisions depend only on the seed and the frame's position in the input, never on timing.
"""

from __future__ import annotations

import threading
from dataclasses import replace
from typing import Iterator

import numpy as np

from reloc.camera import DepthFrame, Intrinsics

from drivers.source import FrameSource

__all__ = ["FaultySource", "SourceDisconnected"]

_FAULT_STREAM = 31


class SourceDisconnected(ConnectionError):
    """The source lost its device or stream; ``reconnect()`` may bring it back (the live loop tries with backoff)."""


class FaultySource(FrameSource):
    """A frame source that injects faults into another one (see the module docstring).

    Parameters
    ----------
    inner:
        The wrapped source; closed when this one is.
    drop_rate, stall_rate, invalid_rate:
        Independent per-frame probabilities (0..1) of dropping the frame, stalling before it, making it all-invalid.
    drop_at, stall_at, invalid_at:
        Input frame indices where that fault happens regardless of the rates.
    stall_s:
        Length of each stall, seconds.
    disconnect_at:
        Input frame indices (0-based, counted over the inner stream) at which the stream breaks.
    reconnect_s:
        How long :meth:`reconnect` takes, seconds.
    reconnect_failures:
        The first this many :meth:`reconnect` calls after each disconnect fail (the device is not back yet).
    seed:
        Seed of the fault decisions.
    """

    def __init__(self, inner: FrameSource, *, drop_rate: float = 0.0, stall_rate: float = 0.0, stall_s: float = 0.2,
                 invalid_rate: float = 0.0, disconnect_at=(), reconnect_s: float = 0.0, reconnect_failures: int = 0,
                 drop_at=(), stall_at=(), invalid_at=(), seed: int = 0) -> None:
        super().__init__()
        if not isinstance(inner, FrameSource):
            raise ValueError(f"inner: expected a FrameSource, got {type(inner).__name__}")
        for name, rate in (("drop_rate", drop_rate), ("stall_rate", stall_rate), ("invalid_rate", invalid_rate)):
            if not (isinstance(rate, (int, float)) and 0.0 <= rate <= 1.0):
                raise ValueError(f"{name}: expected a probability in [0, 1], got {rate!r}")
        if not stall_s >= 0 or not reconnect_s >= 0:
            raise ValueError(f"stall_s, reconnect_s: expected >= 0, got {stall_s}, {reconnect_s}")
        at_sets = {}
        for name, idx in (("disconnect_at", disconnect_at), ("drop_at", drop_at), ("stall_at", stall_at),
                          ("invalid_at", invalid_at)):
            at_sets[name] = sorted({int(i) for i in idx})
            if at_sets[name] and at_sets[name][0] < 0:
                raise ValueError(f"{name}: expected non-negative frame indices, got {list(idx)}")
        at = at_sets["disconnect_at"]
        if not isinstance(reconnect_failures, int) or reconnect_failures < 0:
            raise ValueError(f"reconnect_failures: expected a non-negative integer, got {reconnect_failures!r}")
        self.inner = inner
        self.drop_rate, self.stall_rate, self.invalid_rate = float(drop_rate), float(stall_rate), float(invalid_rate)
        self.stall_s, self.reconnect_s = float(stall_s), float(reconnect_s)
        self.disconnect_at = at
        self.drop_at, self.stall_at, self.invalid_at = (set(at_sets[k]) for k in ("drop_at", "stall_at", "invalid_at"))
        self.reconnect_failures = reconnect_failures
        self.seed = int(seed)
        self.name = f"faulty({inner.name})"
        self.counts = {"frames_in": 0, "frames_out": 0, "dropped": 0, "stalls": 0, "invalid": 0, "disconnects": 0,
                       "reconnects": 0, "reconnect_failures": 0, "lost_in_disconnect": 0}
        self.injected: dict[str, list[int]] = {"dropped": [], "stalls": [], "invalid": [], "disconnects": []}
        self._rng = np.random.default_rng(np.random.SeedSequence([self.seed, _FAULT_STREAM]))
        self._it: Iterator[DepthFrame] | None = None
        self._connected = True
        self._failures_left = 0
        self._lock = threading.Lock()
        self._wake = threading.Event()

    @property
    def intrinsics(self) -> Intrinsics:
        return self.inner.intrinsics

    def noise_law(self) -> tuple[str, float] | None:
        return self.inner.noise_law()  # the faults drop and spoil frames; the camera's noise is its own

    @property
    def rate_hz(self) -> float | None:
        return self.inner.rate_hz

    @property
    def connected(self) -> bool:
        return self._connected

    def reconnect(self) -> bool:
        """Try to bring the stream back; True when it is (the next iteration resumes the stream)."""
        if self.closed:
            return False
        if self._connected:
            return True
        if self._failures_left > 0:
            self._failures_left -= 1
            self.counts["reconnect_failures"] += 1
            return False
        if self.reconnect_s:
            self._wake.wait(self.reconnect_s)
        self._connected = True
        self.counts["reconnects"] += 1
        return True

    def _frames(self) -> Iterator[DepthFrame]:
        if not self._connected:
            raise SourceDisconnected(f"{self.name}: disconnected; call reconnect() first")
        if self._it is None:
            self._it = iter(self.inner)
        for frame in self._it:
            k = self.counts["frames_in"]
            self.counts["frames_in"] += 1
            # One draw per fault kind per frame, in a fixed order, so decisions depend only on seed and index.
            u_drop, u_stall, u_invalid = self._rng.random(3)
            if self.disconnect_at and k == self.disconnect_at[0]:
                self.disconnect_at.pop(0)
                self._connected = False
                self._failures_left = self.reconnect_failures
                self.counts["disconnects"] += 1
                self.counts["lost_in_disconnect"] += 1
                self.injected["disconnects"].append(int(frame.seq))
                raise SourceDisconnected(f"{self.name}: device lost at input frame {k} (seq {frame.seq})")
            if u_drop < self.drop_rate or k in self.drop_at:
                self.counts["dropped"] += 1
                self.injected["dropped"].append(int(frame.seq))
                continue
            if u_stall < self.stall_rate or k in self.stall_at:
                self.counts["stalls"] += 1
                self.injected["stalls"].append(int(frame.seq))
                if self._wake.wait(self.stall_s):
                    return
            if u_invalid < self.invalid_rate or k in self.invalid_at:
                self.counts["invalid"] += 1
                self.injected["invalid"].append(int(frame.seq))
                frame = replace(frame, depth_m=np.full(frame.depth_m.shape, np.nan, dtype=np.float32))
            self.counts["frames_out"] += 1
            yield frame
            if self.closed:
                return

    def _close(self) -> None:
        self._wake.set()  # ends a stall or a reconnect wait at once
        self.inner.close()

    def info(self) -> dict:
        return {**self.inner.info(), "name": self.name,
                "faults": {"drop_rate": self.drop_rate, "stall_rate": self.stall_rate, "stall_s": self.stall_s,
                           "invalid_rate": self.invalid_rate, "seed": self.seed}}
