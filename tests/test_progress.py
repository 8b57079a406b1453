"""Progress bars: redrawn in place on a terminal, whole lines in a log (a file, a pipe, a journal)."""

from __future__ import annotations

import io

from tqdm import tqdm

from reloc.progress import LineProgress, progress_bar


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_log_gets_whole_lines_the_first_and_the_last_state_without_carriage_returns():
    log = io.StringIO()
    with progress_bar(total=1000, desc="map", unit="frame", leave=False, file=log) as bar:
        assert isinstance(bar, LineProgress)
        for _ in range(1000):
            bar.update(1)
    text = log.getvalue()
    assert "\r" not in text and text.endswith("\n")
    lines = text.splitlines()
    # A thousand updates in well under the 10 s interval: the start and the end, nothing between, nothing blank.
    assert len(lines) == 2, lines
    assert lines[0].startswith("map:   0%") and "0/1000" in lines[0]
    assert lines[1].startswith("map: 100%") and "1000/1000" in lines[1]
    assert all(ch.isascii() for ch in text)


def test_a_bar_that_stays_prints_its_last_state_once_and_an_iterable_is_counted():
    log = io.StringIO()
    assert list(progress_bar(range(7), desc="locate", leave=True, file=log)) == list(range(7))
    lines = log.getvalue().splitlines()
    assert [line.split("|")[0].strip() for line in lines] == ["locate:   0%", "locate: 100%"]
    assert "7/7" in lines[-1] and "\r" not in log.getvalue()


def test_a_message_written_beside_a_log_bar_does_not_repeat_its_line():
    log = io.StringIO()
    bar = progress_bar(total=3, desc="eval", file=log, leave=False)
    tqdm.write("a line above", file=log)
    bar.update(3)
    bar.close()
    lines = log.getvalue().splitlines()
    assert lines[0].startswith("eval:   0%") and lines[1] == "a line above" and lines[2].startswith("eval: 100%")
    assert len(lines) == 3


def test_a_quiet_bar_prints_nothing_and_a_terminal_gets_tqdm_redrawing_in_place():
    log = io.StringIO()
    with progress_bar(total=5, desc="map", disable=True, file=log) as bar:
        bar.update(5)
    assert log.getvalue() == ""
    import sys

    saved, sys.stderr = sys.stderr, None  # a detached process: no stream at all
    try:
        assert list(progress_bar(range(3), desc="map")) == [0, 1, 2]
    finally:
        sys.stderr = saved
    term = _Terminal()
    with progress_bar(total=5, desc="map", leave=False, file=term, mininterval=0) as bar:
        assert type(bar) is tqdm
        bar.update(5)
    assert "\r" in term.getvalue()


def test_a_log_gets_a_line_per_stage_and_the_last_state_however_often_its_owner_redraws():
    """``reloc demo``'s bar sets a postfix for every item, ``reloc eval``'s a description for every query (the scene
    and stage): a terminal redraws each time; a log gets a line when the description changes (a new stage), else at
    most one per interval, and the last state when the bar closes."""
    log = io.StringIO()
    bar = progress_bar(total=4, desc="demo", leave=False, file=log, bar_format="{desc}: {n}/{total}{postfix}")
    for step in range(3):
        for k in range(20):
            bar.set_postfix_str(f"step{step} {k}/20")
        bar.update(1)
    for k in range(20):
        bar.set_postfix_str(f"relocalize {k + 1}/20")
    bar.close()
    assert log.getvalue().splitlines() == ["demo: 0/4", "demo: 3/4, relocalize 20/20"]
    log = io.StringIO()
    bar = progress_bar(total=6, desc="eval: ", leave=False, file=log, bar_format="{desc}{n}/{total}")
    for scene in ("office", "corridor"):
        for _ in range(3):
            bar.set_description(f"{scene}: relocalize")
            bar.update(1)
    bar.close()
    assert log.getvalue().splitlines() == ["eval: 0/6", "office: relocalize: 0/6", "corridor: relocalize: 3/6",
                                           "corridor: relocalize: 6/6"]
