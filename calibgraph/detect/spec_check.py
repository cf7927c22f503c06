"""Stopping early on a wrong board spec: the first frames of every camera decide.

A wrong target spec (rows and columns swapped for another board's, the wrong kind) used to cost
a blind search of every frame before the solver blamed the views. :class:`BoardSpecCheck` watches
the detections of the first frames of each camera as they come in and raises one
:class:`~calibgraph.core.errors.InputError` naming the likely cause as soon as the evidence is in:

* frames of every camera show a chessboard of one other size (found by
  :func:`calibgraph.detect.board_size.chessboard_seen`, or the declared grid found inside a larger
  board) and none shows the declared board: "the images show a 6x9 grid: check rows/cols";
* the first ``FIRST_FRAMES`` frames of every camera show no board at all (frames in which the
  quick probe saw no chessboard were not searched, :mod:`calibgraph.detect.blind`: a few of them,
  ``SAMPLE_PER_CAMERA`` a camera, are searched in full before this is said).

A board found in a few frames of any camera settles it: the spec is right, and cameras that do not
see the board are the solver's business (with its own message), not this check's.
"""

from __future__ import annotations

from collections import Counter

from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target

FIRST_FRAMES = 24     # frames per camera after which no board at all means a wrong spec
SIGHTED_FRAMES = 8    # frames per camera after which a consistent other grid means a wrong spec
SIGHTINGS_NEEDED = 3  # frames that must show the same other grid
CONFIRMING_FRAMES = 2  # frames showing the declared board that settle the spec (one can be a fluke)
SAMPLE_PER_CAMERA = 2  # frames the probe saw nothing in, searched in full before "no board at all" is said


class BoardSpecCheck:
    """Watches detections of the first frames of each camera (module docstring).

    ``frames_per_camera``: camera -> number of frames that camera has to search, so that a camera
    with fewer than ``FIRST_FRAMES`` frames is judged on all of them.
    """

    def __init__(self, target: Target, frames_per_camera: dict, where: str = "dataset.yaml"):
        self.target = target
        self.where = where
        self.total = {c: int(n) for c, n in frames_per_camera.items() if n > 0}
        self.done = Counter()
        self.sightings = Counter()
        self.found = 0
        self._cleared = False
        self._unseen = {}       # camera -> keys of frames deferred because the probe saw no chessboard
        self._sampling = None   # keys of the sample being searched in full (None: no sample taken yet)

    def add(self, camera: str, det, readable: bool = True, key=None) -> None:
        """Count one frame's detection (:class:`~calibgraph.detect.detection.ImageDetection`, ``key``
        naming the frame); raises :class:`InputError` when a consistent other grid is seen in every
        camera's first frames. A frame that could not be read (``readable=False``) says nothing
        about the board."""
        again = bool(self._sampling) and key in self._sampling  # a sampled frame, counted already
        if again:
            self._sampling.discard(key)
        if self.settled or camera not in self.total:
            return
        if not readable:
            self.total[camera] -= 1
            return
        self.done[camera] += not again
        if det.ok:
            self.found += 1
            return
        if det.other_grid is not None:
            self.sightings[tuple(sorted(det.other_grid))] += 1
        elif det.deferred:
            self._unseen.setdefault(camera, []).append(key)
        size, n = self._likely_grid()
        if n >= SIGHTINGS_NEEDED and self._all_cameras_reached(SIGHTED_FRAMES):
            raise InputError(self._message(size))

    def first_frames_done(self) -> bool:
        """Every camera has searched its first ``FIRST_FRAMES`` frames (or all it has)."""
        return self._all_cameras_reached(FIRST_FRAMES)

    @property
    def confirmed(self) -> bool:
        """Enough frames show the declared board: the spec is right."""
        return self.found >= CONFIRMING_FRAMES

    def judge(self, final: bool = False) -> list:
        """Once the first frames of every camera are in (or the stream is ``final``): settles the
        spec when a board was found; else returns, once, the keys of a sample of the frames the
        probe saw nothing in, to be searched in full and added; else raises :class:`InputError`.
        [] otherwise. At ``final``, a spec neither named wrong nor sampled is settled."""
        if self.settled or self._sampling or not (final or self.first_frames_done()):
            if final:
                self._cleared = True  # nothing more will come in: search everything
            return []
        if self.found or not any(self.done.values()):  # a board found; or not one frame could be read (a FIFO,
            self._cleared = True                        # a truncated file: each named on its own), nothing to judge
            return []
        if self._sampling is None:
            self._sampling = {k for keys in self._unseen.values() for k in _spread(keys, SAMPLE_PER_CAMERA)}
            if self._sampling:
                return sorted(self._sampling, key=str)
        raise InputError(self._message(self._likely_grid()[0]))

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

    def _likely_grid(self):
        if not self.sightings:
            return None, 0
        return self.sightings.most_common(1)[0]

    def _message(self, size) -> str:
        t = self.target
        n = max(self.done.values(), default=0)
        frames = f"the first {n} frames" if n > 1 else "the frames"
        which = "any camera" if len(self.total) > 1 else "the camera"
        unit = "inner corners" if t.kind in ("checkerboard", "charuco") else "points"
        head = f"no {t.kind} of {t.rows}x{t.cols} {unit} (as {self.where} declares) in {frames} of {which}"
        if size is None:
            return (f"{head}: check the target spec (kind, rows, cols) in {self.where} against the printed board, "
                    "and that the board is in view")
        a, b = size if t.rows <= t.cols else size[::-1]  # in the declared orientation
        if t.kind in ("checkerboard", "charuco"):
            return f"{head}; the images show a {a}x{b} grid: check rows/cols of the target in {self.where}"
        return (f"{head}; the images show a chessboard of {a}x{b} inner corners: check the target's kind, rows and "
                f"cols in {self.where}")


def _spread(keys: list, n: int) -> list:
    """``n`` of ``keys`` evenly spread (all when there are fewer)."""
    if len(keys) <= n:
        return list(keys)
    return [keys[round(i * (len(keys) - 1) / (n - 1))] for i in range(n)] if n > 1 else [keys[len(keys) // 2]]
