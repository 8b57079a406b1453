"""The one place numba is configured; kernel modules take ``njit`` from here.

- Kernels are compiled with ``cache=True``. ``NUMBA_CACHE_DIR`` is honoured when set; otherwise, when the package
  directory is not writable (a system install), the cache goes to the user cache directory
  (``$XDG_CACHE_HOME/voxelplane-reloc/numba`` or ``~/.cache/voxelplane-reloc/numba``).
- Every kernel is registered, so :func:`warm_up` can compile all of them on tiny inputs before anything is timed,
  and print one line when that means compiling on a cold cache. On a cold cache with two usable cores or more, a
  helper process compiles the warm-ups of some packages while this one compiles the rest, and this one then loads
  them from the cache (numba writes its cache files by atomic rename, so two processes may fill one cache).
"""

from __future__ import annotations

import os
import subprocess
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


def _usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _package(module: str) -> str:
    return module.rpartition(".")[0] or module


def _helper_share(warmups: list) -> list:
    """The warm-ups a helper process may compile: those of every package but the one with the most warm-ups (the
    extraction's, in a full warm-up: 42 of its 61 s on a cold cache, measured 2026-11-28); none when they all come
    from one package."""
    counts: dict[str, int] = {}
    for fn in warmups:
        counts[_package(fn.__module__)] = counts.get(_package(fn.__module__), 0) + 1
    if len(counts) < 2:
        return []
    keep = max(counts, key=counts.get)
    return [fn for fn in warmups if _package(fn.__module__) != keep]


def helper_env() -> dict:
    """The environment of a helper process: this one's (``NUMBA_CACHE_DIR`` as this process chose it;
    :func:`configure_cache_dir` sets it when it must), with this package first on the path, as this process imported
    it (a script may have put its checkout on ``sys.path``)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(_PACKAGE_ROOT), env.get("PYTHONPATH", "")) if p)
    return env


def _start_helper(share: list) -> subprocess.Popen | None:
    """A process that imports the modules of ``share`` and runs their warm-ups, filling the cache; None when it
    cannot start (then this process compiles them itself, as without a helper)."""
    mods = sorted({fn.__module__ for fn in share})
    names = sorted({(fn.__module__, fn.__name__) for fn in share})
    code = ("import importlib\n"
            "from reloc import _numba\n"
            f"for m in {mods!r}: importlib.import_module(m)\n"
            f"want = {names!r}\n"
            "for fn in list(_numba._WARMUPS):\n"
            "    if (fn.__module__, fn.__name__) in want: fn()\n")
    try:
        return subprocess.Popen([sys.executable, "-c", code], env=helper_env(), stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError:
        return None


def warm_up(modules: tuple[str, ...] = (), *, quiet: bool = False,
            say: Callable[[str], None] | None = None, parallel: bool | None = None) -> dict:
    """Import ``modules``, run every registered warm-up, and report compilation.

    Returns ``{"kernels": n, "cold": n_without_cache, "seconds": t, "helper": bool}``. When some kernel has no
    cache entry yet, one line goes to stderr before compiling (unless ``quiet``), through ``say`` when given
    (``tqdm.write`` keeps it clear of a progress bar). Then, with ``parallel`` (default: unless the environment
    sets ``RELOC_NUMBA_HELPER=0``) and two usable cores or more, a helper process compiles the warm-ups of
    :func:`_helper_share` (when a kernel of theirs is cold) while this process compiles the others; this process
    waits for it and runs those warm-ups after it, loading what it compiled from the cache (``"helper"`` says
    whether one ran). A helper that fails costs nothing but its time: this process then compiles what it left.
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
    warmups = list(_WARMUPS)
    if parallel is None:
        parallel = os.environ.get("RELOC_NUMBA_HELPER", "1") != "0"
    share = _helper_share(warmups) if cold and parallel and _usable_cores() >= 2 else []
    shared_modules = {fn.__module__ for fn in share}
    if not any(getattr(getattr(d, "py_func", None), "__module__", None) in shared_modules and not _has_cache_index(d)
               for d in _KERNELS):
        share = []  # the helper's part is cached already
    helper = _start_helper(share) if share else None
    try:
        for fn in warmups:
            if fn not in share:
                fn()
        if helper is not None:
            helper.wait()
    finally:
        if helper is not None and helper.poll() is None:
            helper.kill()
            helper.wait()
    for fn in share:
        fn()
    return {"kernels": len(_KERNELS), "cold": cold, "seconds": time.perf_counter() - t0, "helper": helper is not None}
