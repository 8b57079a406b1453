"""Stage timing cheap enough to leave on in production, with per-stage percentiles and a Chrome trace.

One :class:`Profiler` is shared by every thread of a run. Each timed stage costs two ``perf_counter_ns`` calls, a lock
and a write into preallocated arrays: about 1 us per record, 2 us with the trace on, some 0.1% of a frame
(``benchmarks/profiling_overhead.py`` measures it).
Memory is bounded: each stage keeps its last ``window`` durations for percentiles (exact counts, totals and maxima
over the whole run), and the trace keeps at most ``trace_capacity`` events (the newest).

Numba compilation is recorded apart (:meth:`Profiler.note_compile`) and never mixed into stage times: callers warm
up the JIT before the timed run starts.
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import threading
import time
from typing import Iterator

import numpy as np

from reloc.atomic import atomic_write_text

__all__ = ["Profiler", "StageStats", "NULL_PROFILER", "machine_info"]


class StageStats:
    """Durations of one stage: exact count/total/max, and a ring of the latest ``window`` samples."""

    __slots__ = ("count", "total_ns", "max_ns", "_ring", "_pos")

    def __init__(self, window: int):
        self.count = 0
        self.total_ns = 0
        self.max_ns = 0
        self._ring = np.zeros(window, dtype=np.int64)
        self._pos = 0

    def add(self, duration_ns: int) -> None:
        self.count += 1
        self.total_ns += duration_ns
        if duration_ns > self.max_ns:
            self.max_ns = duration_ns
        self._ring[self._pos] = duration_ns
        self._pos = (self._pos + 1) % self._ring.shape[0]

    def samples_ns(self) -> np.ndarray:
        n = min(self.count, self._ring.shape[0])
        return self._ring[:n].copy()


class Profiler:
    """Collects stage durations from any thread; optionally keeps trace events for Perfetto / chrome://tracing.

    - ``with prof.stage("extract"):`` times a block on the calling thread.
    - ``prof.record(name, start_ns, duration_ns)`` adds a measurement taken elsewhere.
    - ``prof.add_timings_ms(timings, prefix, end_ns)`` ingests a component's own per-stage dict (in ms), laying the
      stages back to back so that they end at ``end_ns`` in the trace.
    """

    def __init__(self, *, enabled: bool = True, window: int = 8192, trace_capacity: int = 0):
        self.enabled = enabled
        self._window = int(window)
        self._stats: dict[str, StageStats] = {}
        self._lock = threading.Lock()
        self._trace_capacity = int(trace_capacity)
        # Trace events in preallocated columns: name id, thread id, start, duration.
        self._ev = np.zeros((max(self._trace_capacity, 1), 4), dtype=np.int64)
        self._ev_count = 0
        self._names: dict[str, int] = {}
        self._threads: dict[str, int] = {}
        self._compile_s = 0.0
        self._t0_ns = time.perf_counter_ns()

    # -- recording -------------------------------------------------------------------------------------------------
    @contextlib.contextmanager
    def stage(self, name: str, thread: str | None = None) -> Iterator[None]:
        if not self.enabled:
            yield
            return
        t0 = time.perf_counter_ns()
        try:
            yield
        finally:
            self.record(name, t0, time.perf_counter_ns() - t0, thread)

    def record(self, name: str, start_ns: int, duration_ns: int, thread: str | None = None) -> None:
        if not self.enabled:
            return
        duration_ns = max(int(duration_ns), 0)
        with self._lock:
            st = self._stats.get(name)
            if st is None:
                st = self._stats[name] = StageStats(self._window)
            st.add(duration_ns)
            if self._trace_capacity:
                tname = thread or threading.current_thread().name
                tid = self._threads.setdefault(tname, len(self._threads) + 1)
                nid = self._names.setdefault(name, len(self._names))
                row = self._ev[self._ev_count % self._trace_capacity]
                row[0], row[1], row[2], row[3] = nid, tid, int(start_ns), duration_ns
                self._ev_count += 1

    def add_timings_ms(
        self, timings_ms: dict[str, float], prefix: str = "", end_ns: int | None = None, thread: str | None = None
    ) -> None:
        """Record a component's stage times (ms), e.g. ``ExtractionResult.timings_ms``, under ``prefix``.

        A key ``"a.b"`` whose parent ``"a"`` is also given is a part of ``a`` (its time is included in a's): in the
        trace it is placed inside a's span, after its earlier siblings, instead of after ``a`` (a part of a part
        likewise, inside its parent's span).
        """
        if not self.enabled or not timings_ms:
            return
        end = time.perf_counter_ns() if end_ns is None else int(end_ns)
        durations = [(k, int(round(float(v) * 1e6))) for k, v in timings_ms.items()]
        parent = {k: k.rpartition(".")[0] for k, _ in durations}
        nested = {k for k, p in parent.items() if p and p in timings_ms}
        start = end - sum(d for k, d in durations if k not in nested)
        starts: dict[str, int] = {}
        for key, dur in durations:
            if key not in nested:
                starts[key] = start
                start += dur
        cursor = dict(starts)  # the next free start inside each stage's span, for its parts
        # Parts placed by depth (a parent before its parts; siblings in the order given), then all recorded.
        for key, dur in sorted((kd for kd in durations if kd[0] in nested), key=lambda kd: kd[0].count(".")):
            starts[key] = cursor[key] = cursor[parent[key]]
            cursor[parent[key]] += dur
        for key, dur in durations:
            self.record(f"{prefix}{key}", starts[key], dur, thread)

    def note_compile(self, seconds: float) -> None:
        """Numba compilation time, reported apart from stage times."""
        with self._lock:
            self._compile_s += float(seconds)

    def reset(self) -> None:
        """Forget all measurements (e.g. after a warm-up); compile time is kept."""
        with self._lock:
            self._stats.clear()
            self._ev_count = 0
            self._t0_ns = time.perf_counter_ns()

    # -- reporting -------------------------------------------------------------------------------------------------
    @property
    def stage_names(self) -> list[str]:
        with self._lock:
            return list(self._stats)

    def snapshot(self) -> dict[str, tuple[int, int, np.ndarray]]:
        """Per stage ``(count, total_ns, samples_ns)``: a consistent copy of every stage (the latest ``window``
        durations, oldest first only until the ring wraps), e.g. for histograms or sums of stages."""
        with self._lock:
            return {k: (v.count, v.total_ns, v.samples_ns()) for k, v in self._stats.items()}

    def summary(self, total_stage: str | None = None) -> dict:
        """Per stage: count, mean/p50/p95/p99/max in ms and share of the total.

        The share is relative to ``total_stage`` when given, else to the sum of the top-level stages (names without
        a dot). Without ``total_stage``, a dotted stage has a share only when its parent (the name before its last
        dot) is a recorded stage: ``extract.refine`` is part of ``extract``, while ``capture.wait`` (time spent waiting)
        and ``latency.capture_to_pose`` (an end-to-end span) are not parts of the work and get NaN, not a share
        above 100 %. Also gives ``compile_s`` (numba compilation, not part of any stage).
        """
        with self._lock:
            items = [(k, v.count, v.total_ns, v.max_ns, v.samples_ns()) for k, v in self._stats.items()]
            compile_s = self._compile_s
        if total_stage is not None:
            denom = next((tot for k, _, tot, _, _ in items if k == total_stage), 0)
        else:
            denom = sum(tot for k, _, tot, _, _ in items if "." not in k)
        recorded = {k for k, count, _, _, _ in items if count}
        stages = {}
        for name, count, total_ns, max_ns, samples in items:
            if count == 0:
                continue
            part_of_work = total_stage is not None or "." not in name or name.rsplit(".", 1)[0] in recorded
            p50, p95, p99 = (np.percentile(samples, [50, 95, 99]) / 1e6) if samples.size else (0.0, 0.0, 0.0)
            stages[name] = {
                "count": int(count),
                "mean_ms": total_ns / count / 1e6,
                "p50_ms": float(p50),
                "p95_ms": float(p95),
                "p99_ms": float(p99),
                "max_ms": max_ns / 1e6,
                "total_ms": total_ns / 1e6,
                "share": (total_ns / denom) if denom and part_of_work else float("nan"),
            }
        return {"stages": stages, "compile_s": compile_s}

    def table(self, total_stage: str | None = None, order: list[str] | None = None) -> str:
        """A fixed-width table of :meth:`summary` (the shape of the paper's Table 8, with percentiles)."""
        s = self.summary(total_stage)["stages"]
        names = [n for n in (order or []) if n in s] + sorted(n for n in s if n not in (order or []))
        width = max([len(n) for n in names] + [5])
        head = f"{'stage':<{width}}  {'count':>7}  {'p50 ms':>8}  {'p95 ms':>8}  {'p99 ms':>8}  {'max ms':>8}  {'share':>6}"
        lines = [head, "-" * len(head)]
        for n in names:
            r = s[n]
            share = "" if r["share"] != r["share"] else f"{100 * r['share']:5.1f}%"
            lines.append(
                f"{n:<{width}}  {r['count']:>7}  {r['p50_ms']:>8.3f}  {r['p95_ms']:>8.3f}  {r['p99_ms']:>8.3f}  "
                f"{r['max_ms']:>8.3f}  {share:>6}"
            )
        return "\n".join(lines)

    def chrome_trace(self) -> dict:
        """Events in the Chrome trace event format (complete events 'X', one track per thread, times in us)."""
        with self._lock:
            n = min(self._ev_count, self._trace_capacity)
            if self._ev_count > self._trace_capacity and self._trace_capacity:
                start = self._ev_count % self._trace_capacity
                ev = np.concatenate([self._ev[start:n], self._ev[:start]])
            else:
                ev = self._ev[:n].copy()
            names = {v: k for k, v in self._names.items()}
            threads = dict(self._threads)
            t0 = self._t0_ns
        pid = os.getpid()
        events: list[dict] = [
            {"name": "process_name", "ph": "M", "pid": pid, "tid": 0, "args": {"name": "voxelplane-reloc"}}
        ]
        for tname, tid in threads.items():
            events.append({"name": "thread_name", "ph": "M", "pid": pid, "tid": tid, "args": {"name": tname}})
        for nid, tid, start, dur in ev.tolist():
            events.append(
                {
                    "name": names[nid], "cat": names[nid].split(".")[0], "ph": "X", "pid": pid, "tid": tid,
                    "ts": (start - t0) / 1e3, "dur": dur / 1e3,
                }
            )
        return {"traceEvents": events, "displayTimeUnit": "ms", "otherData": {"compile_s": self._compile_s}}

    def write_chrome_trace(self, path: str | os.PathLike) -> None:
        atomic_write_text(path, json.dumps(self.chrome_trace()))


NULL_PROFILER = Profiler(enabled=False)


def _cpuinfo() -> dict[str, str]:
    """The first processor's fields of ``/proc/cpuinfo`` (empty where there is none)."""
    fields: dict[str, str] = {}
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if not line.strip():
                    break
                key, _, value = line.partition(":")
                fields[key.strip().lower()] = value.strip()
    except OSError:
        pass
    return fields


def machine_info() -> dict:
    """What a time or a last bit depends on: the CPU (its model name, and its family / model numbers and the
    microarchitecture LLVM compiles the numba kernels for, since VMs of one model name differ by a CPU generation),
    logical cores (total and usable by this process), OS and library versions, and the kernels NumPy's OpenBLAS
    picked (``blas_core``, None when that cannot be told)."""
    cpu = _cpuinfo()
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        usable = os.cpu_count()
    info = {
        "cpu_model": cpu.get("model name") or platform.processor() or platform.machine() or "unknown",
        "cpu_family": cpu.get("cpu family"),
        "cpu_model_number": cpu.get("model"),
        "cores": os.cpu_count(),
        "cores_usable": usable,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
    }
    try:
        import llvmlite.binding as llvm
        import numba

        info["numba"] = numba.__version__
        info["llvm_host_cpu"] = llvm.get_host_cpu_name()
    except ImportError:
        pass
    info["blas_core"] = _openblas_core()
    return info


def _openblas_core() -> str | None:
    """The kernels OpenBLAS (NumPy's, loaded in this process) picked for this CPU, or None when that cannot be
    told: a CPU it does not know gets older kernels, whose sums differ in the last bits."""
    import ctypes

    try:
        with open("/proc/self/maps", encoding="utf-8") as fh:
            paths = {ln.split()[-1] for ln in fh if "/" in ln}
    except OSError:
        return None
    libs = {p for p in paths if "openblas" in os.path.basename(p).lower() and ".so" in os.path.basename(p)}
    for lib in sorted(libs):
        try:
            dll = ctypes.CDLL(lib)
        except OSError:
            continue
        for symbol in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename", "openblas_get_corename64_",
                       "openblas_get_corename"):
            fn = getattr(dll, symbol, None)
            if fn is not None:
                fn.restype = ctypes.c_char_p
                name = fn()
                return name.decode("ascii", "replace") if name else None
    return None
