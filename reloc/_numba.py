"""The one place numba is configured; kernel modules take ``njit`` from here.

- Kernels are compiled with ``cache=True``. ``NUMBA_CACHE_DIR`` is honoured when set; otherwise, when the package
  directory is not writable (a system install), the cache goes to the user cache directory
  (``$XDG_CACHE_HOME/voxelplane-reloc/numba`` or ``~/.cache/voxelplane-reloc/numba``).
- Every kernel is registered, so :func:`warm_up` can compile all of them on tiny inputs before anything is timed,
  and print one line when that means compiling on a cold cache.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Callable

_PACKAGE_ROOT = Path(__file__).resolve().parent.parent


def user_cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "voxelplane-reloc" / "numba"


def configure_cache_dir() -> str | None:
    """Choose the numba cache directory (must run before numba is imported); return it, or None for the default."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return os.environ["NUMBA_CACHE_DIR"]
    if os.access(_PACKAGE_ROOT / "reloc", os.W_OK):
        return None  # numba's default: __pycache__ beside each module
    path = user_cache_dir()
    path.mkdir(parents=True, exist_ok=True)
    os.environ["NUMBA_CACHE_DIR"] = str(path)
    return str(path)


configure_cache_dir()

import numba  # noqa: E402  (must come after the cache directory is chosen)

_KERNELS: list = []
_WARMUPS: list[Callable[[], None]] = []


def njit(fn=None, **kwargs):
    """``numba.njit`` with ``cache=True`` by default; the kernel is registered for warm-up and cache reporting.

    Use as ``@njit`` or ``@njit(parallel=True)``; lazy compilation only (no explicit signatures). A helper with
    ``inline="always"`` is not registered: it is compiled into its callers (and cached with them), never on its own,
    so it would count as a cold cache on every start.
    """
    kwargs.setdefault("cache", True)

    def wrap(f):
        disp = numba.njit(**kwargs)(f)
        if kwargs.get("inline") != "always":
            _KERNELS.append(disp)
        return disp

    return wrap(fn) if fn is not None else wrap


def register_warmup(fn: Callable[[], None]) -> Callable[[], None]:
    """Register a function that calls a module's kernels on tiny inputs (decorator)."""
    _WARMUPS.append(fn)
    return fn


def _has_cache_index(disp) -> bool:
    try:
        return os.path.exists(disp._cache._cache_file._index_path)
    except AttributeError:  # a numba version with other internals: assume warm, print nothing
        return True


def cache_location() -> str:
    return os.environ.get("NUMBA_CACHE_DIR") or "__pycache__ beside each module"


def warm_up(modules: tuple[str, ...] = (), *, quiet: bool = False,
            say: Callable[[str], None] | None = None) -> dict:
    """Import ``modules``, run every registered warm-up, and report compilation.

    Returns ``{"kernels": n, "cold": n_without_cache, "seconds": t}``. When some kernel has no cache entry yet, one
    line goes to stderr before compiling (unless ``quiet``), through ``say`` when given (``tqdm.write`` keeps it
    clear of a progress bar).
    """
    import importlib

    for name in modules:
        importlib.import_module(name)
    cold = sum(1 for d in _KERNELS if not _has_cache_index(d))
    if cold and not quiet:
        line = f"numba: compiling {cold} kernels on a cold cache ({cache_location()}); later starts load them from it"
        if say is not None:
            say(line)
        else:
            print(line, file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    for fn in list(_WARMUPS):
        fn()
    return {"kernels": len(_KERNELS), "cold": cold, "seconds": time.perf_counter() - t0}
