"""The blind look at one frame of a dataset: nothing predicts where the board is.

It is :func:`calibgraph.detect.search.detect_image` on the whole frame, decoded once, with one
addition while the board spec is still in doubt (``check_spec``; see
:mod:`calibgraph.detect.spec_check`) and the target is a checkerboard: the frame is first looked at
for a chessboard of any size (:func:`~calibgraph.detect.board_size.chessboard_seen`, on the
half-resolution image of a large frame, then on the full one if that shows none). Only a frame
whose chessboard has the declared size (or is cut by the image border) is searched at once. A
frame that shows no chessboard, or one of another size, is *deferred* (not searched): OpenCV's
classic detector spends seconds on such a frame trying to fit the declared size into whatever
grid of squares it sees, and while the spec is in doubt that time is better spent looking at the
next frames. The dataset driver searches deferred frames in full once the spec is settled, so a
right spec loses no view. The size seen goes into the detection's ``other_grid``; a declared grid
found that continues past its border is refused as part of a larger board.

Before the spec check names a spec wrong it has a few of the deferred frames searched in full
(:func:`search_in_full`): the detector's whole ladder, up-scaled and with the SB detector, without
the quick probe, in the region where a declared board containing the pattern the probe saw would
lie (the whole frame when the probe saw none). The probe only decides what is searched first; it
never decides alone that the declared board is absent.

With ``gate`` the probe also stands in front of the search when the spec is settled: a frame in
which it sees no chessboard, or one of fewer than half the declared corners well inside the
frame, is a miss at the cost of the probe (~0.1-0.7 s on 1080p instead of seconds). That is for first looks whose misses are looked at again (the survey of guided
detection, :mod:`calibgraph.detect.guided_dataset`): the probe misses boards of very small squares, which
the up-scaled search finds.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import replace

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import DetectionError
from calibgraph.core.targets import Target
from calibgraph.detect import progress
from calibgraph.detect.board_size import board_whole, chessboard_seen, grid_continues
from calibgraph.detect.detection import ImageDetection, failed_detection
from calibgraph.detect.image import Frame
from calibgraph.detect.regions import roi_from_points
from calibgraph.detect.search import detect_image

PROBE_REDUCTION = 2          # the probe for another grid looks at frames this much reduced ...
PROBE_REDUCE_FROM_PX = 720   # ... when their shorter side has at least this many pixels


def look_blind(frame: Frame, target: Target, intrinsics: Intrinsics | None = None, check_spec: bool = False,
               gate: bool = False, **options) -> ImageDetection:
    """Detect ``target`` in the whole of ``frame`` (module docstring); ``options`` go to
    :func:`detect_image`. ``gate``: a checkerboard frame in which the probe sees no chessboard is
    a miss without a search (for a first look whose misses get a second one anyway: the survey of
    guided detection). Never raises for a bad image: ``ok=False`` and ``reason`` say why."""
    import time

    t0 = time.perf_counter()
    key = None
    if (check_spec or gate) and target.kind == "checkerboard":
        try:
            digest = frame.digest()
        except DetectionError as e:
            return failed_detection(str(e), target, frame.name, t0, unreadable=True)
        key = None if digest is None else (digest, PROBE_REDUCTION, PROBE_REDUCE_FROM_PX)
        known, seen = _recall(key) if key is not None else (False, None)
        if known and seen is None:
            # looked at before (a frame deferred while the spec was in doubt, now settled): the
            # probe saw no chessboard in these very bytes, and would not now; nothing to decode
            return replace(_unseen(frame, target, check_spec), time_s=time.perf_counter() - t0)
    try:
        grey = frame.grey()
    except DetectionError as e:
        return failed_detection(str(e), target, frame.name, t0, unreadable=True)
    det = _look(frame, grey, target, intrinsics, check_spec, gate, options, key)
    return replace(det, time_s=time.perf_counter() - t0)  # the decoding included


def search_in_full(frame: Frame, target: Target, intrinsics: Intrinsics | None = None,
                   pattern: tuple | None = None, seen_size: tuple | None = None) -> ImageDetection:
    """The full search the spec check asks for before it says a spec is wrong
    (:mod:`calibgraph.detect.spec_check`): :func:`detect_image` with its defaults (up-scaled x2 and
    x3 where the squares are small, the SB detector where the classic one finds nothing), no quick
    probe in front of it. ``pattern`` is the deferred frame's (x0, y0, x1, y1, pitch_px)
    (:attr:`ImageDetection.pattern`), ``seen_size`` its inner corners (``other_grid``): then only
    the region is searched in which a declared board containing that pattern could lie
    (:func:`pattern_region`; on a 1080p frame showing a board of another size the whole frame costs
    OpenCV's classic detector up to 20 s, that region 2-4 s), at full resolution with classic then
    SB, and up-scaled as well when its squares are under twice ``min_pitch_px`` (as the blind search
    up-scales only such regions). A declared grid found that continues past its border is refused as
    part of a larger board, as the spec check's blind look does. Never raises for a bad image."""
    import time

    t0 = time.perf_counter()
    try:
        grey = frame.grey()
    except DetectionError as e:
        return failed_detection(str(e), target, frame.name, t0, unreadable=True)
    if pattern is None:
        det = detect_image(grey, target, intrinsics, source=frame.name)
    else:
        pitch_px = float(pattern[4])
        region = pattern_region(pattern, target, grey.shape, seen_size)
        det = detect_image(grey, target, intrinsics, source=frame.name, region_px=region,
                           upscale="auto" if pitch_px < 2 * FULL_SEARCH_MIN_PITCH_PX else 1)
    det = _part_of_larger(grey, target, det)
    return replace(det, time_s=time.perf_counter() - t0)


FULL_SEARCH_MIN_PITCH_PX = 12.0  # detect_image's min_pitch_px: regions of squares under twice this are up-scaled


def pattern_region(pattern: tuple, target: Target, shape: tuple, seen_size: tuple | None = None) -> tuple:
    """(x0, y0, x1, y1) around a chessboard pattern (x0, y0, x1, y1, pitch_px) of ``seen_size``
    inner corners seen in an image of ``shape``, padded so that a declared board containing the
    pattern lies inside: on every side by as many squares as the declared board can reach past it
    (its larger number of inner corners less the pattern's smaller one), plus its outer square, its
    white margin and one square for perspective (the pattern's pitch is a median); clipped to the
    image."""
    x0, y0, x1, y1, pitch_px = (float(v) for v in pattern)
    reach = max(target.rows, target.cols) - (min(seen_size) if seen_size else 2)
    pad = (max(reach, 0) + 3) * pitch_px
    h, w = shape[:2]
    return (int(max(0, x0 - pad)), int(max(0, y0 - pad)), int(min(w, np.ceil(x1 + pad) + 1)),
            int(min(h, np.ceil(y1 + pad) + 1)))


def _look(frame, grey, target, intrinsics, check_spec, gate, options, key=None) -> ImageDetection:
    if not ((check_spec or gate) and target.kind == "checkerboard"):
        return detect_image(grey, target, intrinsics, source=frame.name, **options)
    declared = tuple(sorted((target.rows, target.cols)))
    known, seen = _recall(key) if key is not None else (False, None)
    if not known:
        progress.stage("a quick look for a chessboard of any size (the board spec is not yet settled)")
        k = PROBE_REDUCTION if min(grey.shape) >= PROBE_REDUCE_FROM_PX else 1  # small squares vanish in small frames
        seen = chessboard_seen(frame.reduced(k), k) if k > 1 else None
        if seen is None:
            seen = chessboard_seen(grey)
        if key is not None:
            _remember(key, seen)
    if seen is None:
        return _unseen(frame, target, check_spec)
    if gate and not check_spec and not seen.touches_border and 2 * seen.rows * seen.cols < target.n_points:
        # a few squares of something else (the arm's bands, a partial board well inside the frame)
        return failed_detection(f"the quick probe sees only a {seen.rows}x{seen.cols} chessboard", target, frame.name)
    if check_spec and not seen.touches_border and seen.size != declared:
        bigger = "larger" if seen.size[0] >= declared[0] and seen.size[1] >= declared[1] else "other"
        return failed_detection(f"the image shows a chessboard of {seen.rows}x{seen.cols} inner corners, {bigger} "
                                f"than the target's {target.rows}x{target.cols}; searched once the board spec is "
                                "settled", target, frame.name, other_grid=(seen.rows, seen.cols), deferred=True,
                                pattern=_pattern(seen), other_whole=board_whole(grey, seen))
    det = detect_image(grey, target, intrinsics, source=frame.name, **options)
    return _part_of_larger(grey, target, det)


def _unseen(frame, target, check_spec) -> ImageDetection:
    """The look at a frame in which the probe saw no chessboard."""
    return failed_detection("no chessboard seen by the quick probe" + ("; searched once the board spec is settled"
                                                                       if check_spec else ""),
                            target, frame.name, deferred=check_spec)


# What the probe saw in a frame, by a hash of the frame file's bytes (and the probe's reduction
# settings): the probe is seeded, so a file looked at again (a frame deferred while the spec was in
# doubt, searched once it is settled) gets the same answer without probing or, when the answer was
# "none", decoding it again (the dataset drivers' open_frame decodes every frame it hands over
# first, though). A bounded, thread-safe memo of this process; tests/test_detect_fast_paths.py
# checks it against probing afresh.
_SEEN: OrderedDict = OrderedDict()
_SEEN_LOCK = threading.Lock()
_SEEN_MAX = 4096


def _recall(key) -> tuple:
    """(whether the frame ``key`` was probed, what the probe saw in it: None when nothing)."""
    with _SEEN_LOCK:
        return (key in _SEEN), _SEEN.get(key)


def _remember(key, seen) -> None:
    with _SEEN_LOCK:
        _SEEN[key] = seen
        while len(_SEEN) > _SEEN_MAX:
            _SEEN.popitem(last=False)


def _pattern(seen) -> tuple:
    """(x0, y0, x1, y1, pitch_px) of a :class:`~calibgraph.detect.board_size.ChessboardSeen`."""
    G = seen.uv_px.reshape(seen.rows, seen.cols, 2)
    steps = np.concatenate([np.linalg.norm(np.diff(G, axis=1), axis=-1).ravel(),
                            np.linalg.norm(np.diff(G, axis=0), axis=-1).ravel()])
    (x0, y0), (x1, y1) = seen.uv_px.min(0), seen.uv_px.max(0)
    return (float(x0), float(y0), float(x1), float(y1), float(np.median(steps)))


def _covers(seen, declared: tuple, uv_px) -> bool:
    """Whether the chessboard ``seen`` has at least the ``declared`` (sorted) inner corners each way,
    more one way, and its board holds most of the points ``uv_px`` (same pixel frame): at least half
    of them within its inner corners' hull grown by its outer ring of squares (1.5 of its squares,
    perspective included); a board of its own beside it holds none."""
    import cv2

    if not (seen.size[0] >= declared[0] and seen.size[1] >= declared[1] and seen.size != declared):
        return False
    hull = cv2.convexHull(np.asarray(seen.uv_px, np.float32))
    pitch = float(np.median(np.linalg.norm(np.diff(seen.uv_px.reshape(seen.rows, seen.cols, 2), axis=1), axis=-1)))
    inside = [cv2.pointPolygonTest(hull, (float(u), float(v)), True) > -1.5 * pitch for u, v in uv_px]
    return float(np.mean(inside)) >= 0.5  # a sheared grid of wrong saddles reaches past the board's edge


def _part_of_larger(grey, target, det) -> ImageDetection:
    """``det`` refused when the declared grid it found continues past its border (part of a larger
    board: :func:`~calibgraph.detect.board_size.grid_continues`), naming the grid seen around it."""
    if not det.ok or target.kind != "checkerboard":
        return det
    declared = tuple(sorted((target.rows, target.cols)))
    x0, y0, x1, y1 = roi_from_points(det.uv_px, grey.shape, pad_frac=1.0)
    around = chessboard_seen(grey[y0:y1, x0:x1])
    other = (around.rows, around.cols) if around is not None and around.size != declared else None
    # a whole chessboard of more squares seen around the grid and covering it: the grid found is a part
    # of it, however its own border looks (a sheared sub-grid of wrong saddles is not caught by that)
    larger = other is not None and _covers(around, declared, det.uv_px - [x0, y0])
    if not (larger or grid_continues(grey, target, det.ids, det.uv_px)):
        return det
    return replace(det, ok=False, other_grid=other,
                   reason=f"the {target.rows}x{target.cols} grid found is part of a larger grid of squares "
                          "(a larger board than the target spec says?)")
