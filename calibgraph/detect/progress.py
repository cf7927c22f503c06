"""Saying what a long detection pass is searching.

A dataset pass shows a progress bar (``detect: 3/16``), which says how many frames are done but not
what the others are doing; a frame can take seconds (a far board searched up-scaled, a spec in
doubt searched in full), and a pass whose bar stands still says nothing. So every search says what it
is doing: the worker thread that searches a frame registers it (:func:`searching`), the search names
its stage as it goes (:func:`stage`: the board size and kind, the image as printed or inverted, the
whole frame, an up-scaled region, ...), and the pass's :class:`Reporter`, called while the pass
waits for its next answer, prints a line at least every ``PROGRESS_EVERY_S`` seconds of a pass
(``detect: 3/16 images done; searching 7.png for 12 s: acircles 7x11, inverted image: the whole
frame``), through the bar's own writer so that the bar stays whole.
"""

from __future__ import annotations

import threading
import time
from contextlib import contextmanager
from pathlib import Path

PROGRESS_EVERY_S = 20.0  # a pass says what it searches at least this often (the bar alone does not)

_LOCK = threading.Lock()
_ACTIVE: dict = {}  # thread id -> [frame name, stage, start (monotonic s)]


@contextmanager
def searching(name):
    """Register the calling thread as searching frame ``name`` while the block runs."""
    tid = threading.get_ident()
    with _LOCK:
        _ACTIVE[tid] = [str(name), "", time.monotonic()]
    try:
        yield
    finally:
        with _LOCK:
            _ACTIVE.pop(tid, None)


def stage(text: str) -> None:
    """Name what the calling thread's search does now (nothing when it is not registered)."""
    with _LOCK:
        entry = _ACTIVE.get(threading.get_ident())
        if entry is not None:
            entry[1] = text


def in_flight() -> list:
    """(frame name, stage, seconds searched) of every registered search, longest first."""
    now = time.monotonic()
    with _LOCK:
        rows = [(name, st, now - t0) for name, st, t0 in _ACTIVE.values()]
    return sorted(rows, key=lambda r: -r[2])


class Reporter:
    """Prints (with ``say``) a line on the pass at most every ``every_s`` seconds, when :meth:`tick`
    is called (module docstring). ``what``: the pass's name, as its bar shows it."""

    def __init__(self, say, what: str = "detect", every_s: float | None = None):
        self.say = say
        self.what = what
        self.every_s = float(PROGRESS_EVERY_S if every_s is None else every_s)
        self.last = time.monotonic()

    def tick(self, done: int, total: int) -> None:
        now = time.monotonic()
        if now - self.last < self.every_s:
            return
        self.last = now
        self.say(self.line(done, total))

    def line(self, done: int, total: int) -> str:
        busy = in_flight()
        head = f"{self.what}: {done}/{total} images done"
        if not busy:
            return head
        name, st, secs = busy[0]
        more = f" (and {len(busy) - 1} more)" if len(busy) > 1 else ""
        return f"{head}; searching {Path(name).name} for {secs:.0f} s{': ' + st if st else ''}{more}"


def bar_writer(bar):
    """A ``say`` for :class:`Reporter` that prints above a tqdm ``bar`` (on standard error)."""
    import sys

    from tqdm import tqdm

    def say(line: str) -> None:
        if bar is not None:
            tqdm.write(line, file=sys.stderr)
        else:
            print(line, file=sys.stderr, flush=True)
    return say
