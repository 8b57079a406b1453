"""Reusable scratch buffers, so that a stream of frames does not allocate (and page-fault) megabytes per frame."""

from __future__ import annotations

import math

import numpy as np


class Workspace:
    """Named buffers that grow on demand; :meth:`get` returns a view valid until the next call with that name."""

    def __init__(self) -> None:
        self._bufs: dict[str, np.ndarray] = {}

    def get(self, name: str, shape, dtype) -> np.ndarray:
        # Called a few dozen times per frame: plain Python arithmetic, not NumPy's, on the shape.
        if isinstance(shape, (int, np.integer)):
            shape = (int(shape),)
            size = shape[0]
        else:
            shape = tuple(int(s) for s in shape)
            size = math.prod(shape)
        buf = self._bufs.get(name)
        if buf is None or buf.dtype != dtype or buf.size < size:
            buf = np.empty(max(size + size // 4, 16), np.dtype(dtype))
            self._bufs[name] = buf
        return buf[:size].reshape(shape)


def fresh(workspace: Workspace | None) -> Workspace:
    return workspace if workspace is not None else Workspace()
