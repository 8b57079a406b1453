"""Progress bars that suit where they are written: a terminal gets tqdm's bar, redrawn in place; a log file, a pipe or
a service's journal gets whole lines, at most one every ``LOG_INTERVAL_S`` seconds.

tqdm redraws its bar with carriage returns ten times a second. On a terminal that is one line; in a log it is one
endless line of every state the bar went through, in block characters. The bar a command makes with
:func:`progress_bar` checks its stream once: not a terminal, it prints ``desc: 37%|###  | 37/100 [00:01<00:02,
30.5frame/s]`` lines in plain ASCII instead, the first at the start, then as the interval allows, and the last as the
work ends (a log line is never taken back, so also for a bar that leaves no trace on a terminal).
"""

from __future__ import annotations

import sys

from tqdm import tqdm

__all__ = ["LOG_INTERVAL_S", "LineProgress", "progress_bar"]

LOG_INTERVAL_S = 10.0


class LineProgress(tqdm):
    """tqdm printing whole lines (a log's progress): each state it shows on a line of its own (:meth:`refresh` and
    :meth:`close` print none that shows what the last one did)."""

    @staticmethod
    def status_printer(file):
        def print_status(s: str) -> None:
            s = s.strip()
            if s:  # clearing (tqdm.write, close) prints nothing
                file.write(s + "\n")
                getattr(file, "flush", lambda: None)()

        return print_status

    _line_at: tuple | None = None  # (count, description, postfix, time) of the last line printed

    def display(self, msg=None, pos=None):
        if msg is None:
            self._line_at = (self.n, self.desc, self.postfix, self._time())
        return super().display(msg, pos)

    def _shown(self) -> bool:
        """Whether the last line printed shows the count, description and postfix of now."""
        return self._line_at is not None and self._line_at[:3] == (self.n, self.desc, self.postfix)

    def refresh(self, nolock=False, lock_args=None):
        # A terminal's bar is redrawn whenever its owner sets a description or postfix (often once an item); a log
        # gets a line when the description changes (a new stage of the work), else once the interval has passed.
        last = self._line_at
        if last is not None and last[1] == self.desc and (
                self._shown() or self._time() - last[3] < self.mininterval):
            return False
        return super().refresh(nolock, lock_args)

    def close(self) -> None:
        # The last state goes to the log (tqdm, leaving no trace, would only clear the line); with leave=True tqdm
        # prints it itself.
        if not self.disable and not self.leave and not self._shown():
            self.display()
        super().close()


class _LogStream:
    """A stream for :class:`LineProgress`: the carriage returns and bare newlines tqdm writes around a bar (to
    clear it, or to step past it) are for terminals and are dropped; lines pass."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, s: str) -> int:
        if s.strip():
            self._stream.write(s)
        return len(s)

    def flush(self) -> None:
        getattr(self._stream, "flush", lambda: None)()


def _is_terminal(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


def progress_bar(*args, file=None, **kwargs) -> tqdm:
    """``tqdm(*args, file=file, **kwargs)`` on a terminal (``file`` None: stderr); elsewhere a :class:`LineProgress`
    printing a plain-ASCII line at most every ``LOG_INTERVAL_S`` seconds (or ``mininterval``, if larger)."""
    stream = sys.stderr if file is None else file
    if stream is None:  # no stderr at all (a detached process): nothing to show it on
        return tqdm(*args, disable=True, **{k: v for k, v in kwargs.items() if k != "disable"})
    if _is_terminal(stream):
        return tqdm(*args, file=stream, **kwargs)
    kwargs["mininterval"] = max(float(kwargs.get("mininterval", 0.0)), LOG_INTERVAL_S)
    kwargs.setdefault("ascii", True)
    kwargs.setdefault("dynamic_ncols", False)
    kwargs.setdefault("ncols", 100)
    return LineProgress(*args, file=_LogStream(stream), **kwargs)
