"""The bounded queue between capture and processing: when full, the oldest item makes room and is counted."""

from __future__ import annotations

import threading
from collections import deque
from typing import Any, Callable

__all__ = ["DropOldestQueue"]


class DropOldestQueue:
    """A thread-safe FIFO of at most ``maxlen`` items; ``put`` never blocks and evicts the oldest when full.

    A live consumer wants the newest frames: when processing falls behind, old frames are dropped (and counted in
    :attr:`dropped`) instead of piling up. ``close()`` tells the consumer that nothing more will come; ``get``
    then drains what is left and returns None.
    """

    def __init__(self, maxlen: int):
        if not isinstance(maxlen, int) or maxlen < 1:
            raise ValueError(f"maxlen: expected a positive integer, got {maxlen!r}")
        self.maxlen = maxlen
        self._items: deque = deque()
        self._cond = threading.Condition()
        self._closed = False
        self.put_count = 0
        self.dropped = 0
        self.max_depth = 0

    def put(self, item: Any, carry: Callable[[Any, Any], Any] | None = None) -> Any | None:
        """Append ``item``; returns the evicted oldest item when the queue was full, else None. With ``carry``, the
        oldest item left becomes ``carry(evicted, oldest)`` (what of a dropped item must not be lost with it)."""
        with self._cond:
            evicted = None
            if len(self._items) >= self.maxlen:
                evicted = self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            if evicted is not None and carry is not None:
                self._items[0] = carry(evicted, self._items[0])
            self.put_count += 1
            self.max_depth = max(self.max_depth, len(self._items))
            self._cond.notify()
            return evicted

    def get(self, timeout_s: float | None = None) -> Any | None:
        """The oldest item, waiting up to ``timeout_s``; None on timeout or when closed and empty."""
        with self._cond:
            if not self._items and not self._closed:
                self._cond.wait(timeout_s)
            return self._items.popleft() if self._items else None

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def finished(self) -> bool:
        """Closed and drained."""
        with self._cond:
            return self._closed and not self._items

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)
