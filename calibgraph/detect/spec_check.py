"""Stopping early on a wrong board spec: the first frames of every camera decide.

A wrong target spec (rows and columns swapped for another board's, the wrong kind) used to cost
a blind search of every frame before the solver blamed the views. :class:`BoardSpecCheck` watches
the detections of the first frames of each camera as they come in and raises one
:class:`~calibgraph.core.errors.InputError` naming the likely cause as soon as the evidence is in.
The quick probe of :mod:`calibgraph.detect.blind` (OpenCV's SB detector for a chessboard of any
size, on the reduced frame) only decides what is searched first: frames in which it sees no
chessboard, or one of another size, are deferred. It misses boards of small squares, sees a 3x3
corner of a board cut by an occluder, and on boards with markers in their white squares it sees
whatever part its grid growing reaches. So before anything is named wrong, a few deferred frames
are searched in full (:func:`calibgraph.detect.blind.search_in_full`: up-scaled, with the SB
detector, no probe), and a spec is named wrong only when that full search finds the declared board
in none of them (nor did any other frame):

* frames of every camera show a chessboard of one other size of at least ``MIN_GRID`` x
  ``MIN_GRID`` inner corners, found whole in at least ``SIGHTINGS_NEEDED`` frames (by the probe, or
  the declared grid found inside a larger board): "the images show a 6x9 grid: check rows/cols".
  A smaller grid is never such evidence: it is a sub-grid of a small or partly seen board. The
  frames searched in full are ``PATTERN_SAMPLE`` of those where the probe saw a chessboard,
  those of the grid named first;
* the first ``FIRST_FRAMES`` frames of every camera show no board at all: the frames searched in
  full are those where the probe saw a pattern and ``SAMPLE_PER_CAMERA`` a camera of those where
  it saw none.

A board found in any frame settles it: the spec is right, and cameras that do not see the board
are the solver's business (with its own message), not this check's. A frame that cannot be read
says nothing about the board.
"""

from __future__ import annotations

from collections import Counter

from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target

FIRST_FRAMES = 24     # frames per camera after which no board at all means a wrong spec
SIGHTED_FRAMES = 8    # frames per camera after which a consistent other grid means a wrong spec
SIGHTINGS_NEEDED = 3  # frames that must show the same other grid, whole
MIN_GRID = 4          # inner corners along each side of a grid that is evidence of another board
CONFIRMING_FRAMES = 2  # frames showing the declared board that settle the spec (one can be a fluke)
PATTERN_SAMPLE = 4    # frames where the probe saw a chessboard, searched in full before a spec is named wrong
SAMPLE_PER_CAMERA = 2  # frames the probe saw nothing in, searched in full before "no board at all" is said


class BoardSpecCheck:
    """Watches detections of the first frames of each camera (module docstring).

    ``frames_per_camera``: camera -> number of frames that camera has to search, so that a camera
    with fewer than ``FIRST_FRAMES`` frames is judged on all of them. ``where``: the file that
    declares the target, for the message.

    The driver :meth:`add`\\ s every frame's detection, calls :meth:`judge` after each, searches the
    frames it returns with :func:`~calibgraph.detect.blind.search_in_full` (the deferred detection's
    ``pattern`` says where) and adds their detections; :meth:`judge` raises on a wrong spec.
    """

    def __init__(self, target: Target, frames_per_camera: dict, where: str = "dataset.yaml"):
        self.target = target
        self.where = where
        self.total = {c: int(n) for c, n in frames_per_camera.items() if n > 0}
        self.done = Counter()
        self.sightings = Counter()
        self.parts = Counter()  # of the sightings, those of a part of a board (no margin on some side)
        self.spec_notes = Counter()  # what frames that found the board but could not number it said of the spec
        self.found = 0
        self._cleared = False
        self._unseen = {}       # camera -> keys of frames deferred because the probe saw no chessboard
        self._patterns = {}     # key -> (camera, grid size) of frames deferred because the probe saw another grid
        self._sampling = None   # keys of the sample being searched in full (None: no sample taken yet)

    def add(self, camera: str, det, readable: bool = True, key=None) -> None:
        """Count one frame's detection (:class:`~calibgraph.detect.detection.ImageDetection`, ``key``
        naming the frame). A frame that could not be read (``readable=False``, or the detection
        says so) says nothing about the board."""
        if self._sampling and key in self._sampling:  # a sampled frame's full search, counted already
            self._sampling.discard(key)
            self.found += bool(det.ok)
            return
        if self.settled or camera not in self.total:
            return
        if not readable or getattr(det, "unreadable", False):
            self.total[camera] -= 1
            return
        self.done[camera] += 1
        if det.ok:
            self.found += 1
            return
        if getattr(det, "spec_note", ""):
            self.spec_notes[det.spec_note] += 1
        size = None if det.other_grid is None else tuple(sorted(det.other_grid))
        if size is not None and size[0] >= MIN_GRID:
            self.sightings[size] += 1
            self.parts[size] += getattr(det, "other_whole", None) is False
        if det.deferred and size is not None:
            self._patterns[key] = (camera, size)
        elif det.deferred:
            self._unseen.setdefault(camera, []).append(key)

    def first_frames_done(self) -> bool:
        """Every camera has searched its first ``FIRST_FRAMES`` frames (or all it has)."""
        return self._all_cameras_reached(FIRST_FRAMES)

    @property
    def confirmed(self) -> bool:
        """Enough frames show the declared board: the spec is right."""
        return self.found >= CONFIRMING_FRAMES

    def judge(self, final: bool = False) -> list:
        """Once the evidence is in (another grid in every camera's first ``SIGHTED_FRAMES`` frames,
        or every camera's first ``FIRST_FRAMES`` frames done, or the stream ``final``): settles the
        spec when a board was found; else returns, once, the keys of the frames to be searched in
        full and added (module docstring); else (the sample searched, no board) raises
        :class:`InputError`. [] otherwise. At ``final`` a spec still waiting for its sample is
        settled: the frames are then all searched, none is left out."""
        if self.settled:
            return []
        if self._sampling:
            if final:  # nothing more will come in (a sampled frame never came back): search everything
                self._cleared = True
            return []
        other = self._other_grid() is not None and self._all_cameras_reached(SIGHTED_FRAMES)
        if not (final or other or self.first_frames_done()):
            return []
        if self.found or not any(self.done.values()):  # a board seen; or no frame could be read at all
            self._cleared = True
            return []
        if self._sampling is None:
            self._sampling = set(self._sample(unseen_too=not other))
            if self._sampling:
                return sorted(self._sampling, key=str)
        raise InputError(self._message(self._other_grid()))

    @property
    def settled(self) -> bool:
        """The spec is taken as right: confirmed, or cleared by :meth:`judge`."""
        return self.confirmed or self._cleared

    @property
    def searching(self) -> bool:
        """The spec is not yet settled: frames are still worth the probe for another grid (and
        may be deferred, :mod:`calibgraph.detect.blind`)."""
        return not self.settled

    def _all_cameras_reached(self, n: int) -> bool:
        return all(self.done[c] >= min(n, total) for c, total in self.total.items())

    def _other_grid(self):
        """The grid of another size the frames show, when it is evidence (module docstring), else None."""
        if not self.sightings:
            return None
        size, n = self.sightings.most_common(1)[0]
        return size if n >= SIGHTINGS_NEEDED else None

    def _sample(self, unseen_too: bool) -> list:
        """Frames to search in full: ``PATTERN_SAMPLE`` of those where the probe saw a chessboard
        (those of the likely grid first, then the others; taken in turn from every camera), plus, with
        ``unseen_too``, ``SAMPLE_PER_CAMERA`` a camera of those where it saw none."""
        likely = self._other_grid()
        by_camera = {}
        for key, (camera, size) in self._patterns.items():
            by_camera.setdefault(camera, []).append((size != likely, key))
        queues = [[k for _, k in sorted(v, key=lambda x: x[0])] for _, v in sorted(by_camera.items())]
        picked = []
        while len(picked) < PATTERN_SAMPLE and any(queues):
            for q in queues:
                if q and len(picked) < PATTERN_SAMPLE:
                    picked.append(q.pop(0))
        if unseen_too:
            picked += [k for keys in self._unseen.values() for k in _spread(keys, SAMPLE_PER_CAMERA)]
        return picked

    def _message(self, size) -> str:
        t = self.target
        n = max(self.done.values(), default=0)
        frames = f"the first {n} frames" if n > 1 else "the frames"
        which = "any camera" if len(self.total) > 1 else "the camera"
        unit = "inner corners" if t.kind in ("checkerboard", "charuco") else "points"
        head = f"no {t.kind} of {t.rows}x{t.cols} {unit} (as {self.where} declares) in {frames} of {which}"
        if self.spec_notes and size is None:
            # the board was found in the frames, and the spec could not number it: say why
            return f"{head}: {self.spec_notes.most_common(1)[0][0]}"
        if size is None:
            return (f"{head}: check the target spec (kind, rows, cols) in {self.where} against the printed board, "
                    "and that the board is in view (the images were searched as printed and inverted, white on black)")
        a, b = size if t.rows <= t.cols else size[::-1]  # in the declared orientation
        declared = tuple(sorted((t.rows, t.cols)))
        part = size[0] <= declared[0] and size[1] <= declared[1] and size != declared
        if t.kind in ("checkerboard", "charuco") and part and 2 * self.parts[size] > self.sightings[size]:
            # a part of the declared board, ending without a margin on some side: covered or cut off
            return (f"{head}; the images show only a {a}x{b} part of it, the board partly covered or cut off in every "
                    f"frame (the grid found fits inside the declared {t.rows}x{t.cols} and ends short of a margin): show "
                    "the whole board in some of the views")
        if t.kind in ("checkerboard", "charuco"):
            return f"{head}; the images show a {a}x{b} grid: check rows/cols of the target in {self.where}"
        return (f"{head}; the images show a chessboard of {a}x{b} inner corners: check the target's kind, rows and "
                f"cols in {self.where}")


def _spread(keys: list, n: int) -> list:
    """``n`` of ``keys`` evenly spread (all when there are fewer)."""
    if len(keys) <= n:
        return list(keys)
    return [keys[round(i * (len(keys) - 1) / (n - 1))] for i in range(n)] if n > 1 else [keys[len(keys) // 2]]
