"""Shared machinery of the fuzz tests (``tests/test_fuzz_*.py``) and of ``benchmarks/fuzz_report.py``.

Each fuzzed target is a :class:`Target`: a hypothesis strategy of cases and ``run(case)``, which feeds one case to
the code under test and checks what came back. A case ends in one of two ways:

- ``"ok"``: a result, which ``run`` checks is right (for example: a config that loads is usable by every stage, a
  map that loads has finite, unit-normal planes). A wrong result fails an assertion.
- ``"error"``: the target's own clear error (``ValueError`` or the module's subclass of it, ``FileNotFoundError``
  for missing files), whose message names the input (the file, or the argument).

Anything else escapes: another exception type, an assertion about the result, or a hang (a case running longer
than ``timeout_s`` raises :class:`Hang`). The tests let an escape fail the test; the report counts them.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from dataclasses import dataclass
from typing import Any, Callable

from hypothesis import HealthCheck, settings

__all__ = ["Hang", "Target", "outcome", "time_limit", "fuzz_settings"]

# Tests: deterministic examples (the same cases on every run and in CI), no shrinking database, no deadline (the
# first case may include numba compilation).
SUPPRESS = [HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much,
            HealthCheck.function_scoped_fixture]


def fuzz_settings(max_examples: int) -> settings:
    return settings(max_examples=max_examples, deadline=None, derandomize=True, database=None,
                    suppress_health_check=SUPPRESS)


class Hang(BaseException):
    """A case ran longer than its time limit (a BaseException so that no ``except Exception`` swallows it)."""


@contextlib.contextmanager
def time_limit(seconds: float):
    """Raise :class:`Hang` in the main thread after ``seconds`` (a no-op outside the main thread)."""
    if threading.current_thread() is not threading.main_thread() or seconds is None:
        yield
        return

    def on_alarm(signum, frame):
        raise Hang(f"case still running after {seconds} s")

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def outcome(fn: Callable[[], Any], *, names: str | None = None, clear=(ValueError,), timeout_s: float = 20.0) -> str:
    """``"ok"`` when ``fn()`` returns, ``"error"`` when it raises one of ``clear`` whose message contains ``names``;
    anything else propagates."""
    with time_limit(timeout_s):
        try:
            fn()
        except clear as exc:
            if names is not None:
                assert names in str(exc), f"{type(exc).__name__} does not name {names!r}: {exc}"
            return "error"
    return "ok"


@dataclass(frozen=True)
class Target:
    """One fuzzed input: ``cases`` (a hypothesis strategy) and ``run(case) -> "ok" | "error"``."""

    name: str
    input: str
    cases: Any
    run: Callable[[Any], str]
