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

With ``gate`` the probe also stands in front of the search when the spec is settled: a frame in
which it sees no chessboard, or one of fewer than half the declared corners well inside the
frame, is a miss at the cost of the probe (~0.1-0.7 s on 1080p instead of seconds). That is for first looks whose misses are looked at again (the survey of guided
detection, :mod:`calibgraph.solver.build`): the probe misses boards of very small squares, which
the up-scaled search finds.
"""

from __future__ import annotations

from dataclasses import replace

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import DetectionError
from calibgraph.core.targets import Target
from calibgraph.detect.board_size import chessboard_seen, grid_continues
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
    try:
        grey = frame.grey()
    except DetectionError as e:
        return failed_detection(str(e), target, frame.name, t0)
    det = _look(frame, grey, target, intrinsics, check_spec, gate, options)
    return replace(det, time_s=time.perf_counter() - t0)  # the decoding included


def _look(frame, grey, target, intrinsics, check_spec, gate, options) -> ImageDetection:
    if not ((check_spec or gate) and target.kind == "checkerboard"):
        return detect_image(grey, target, intrinsics, source=frame.name, **options)
    declared = tuple(sorted((target.rows, target.cols)))
    k = PROBE_REDUCTION if min(grey.shape) >= PROBE_REDUCE_FROM_PX else 1  # small squares vanish in small frames
    seen = chessboard_seen(frame.reduced(k), k) if k > 1 else None
    if seen is None:
        seen = chessboard_seen(grey)
    if seen is None:
        return failed_detection("no chessboard seen by the quick probe" + ("; searched once the board spec is settled"
                                                                           if check_spec else ""),
                                target, frame.name, deferred=check_spec)
    if gate and not check_spec and not seen.touches_border and 2 * seen.rows * seen.cols < target.n_points:
        # a few squares of something else (the arm's bands, a partial board well inside the frame)
        return failed_detection(f"the quick probe sees only a {seen.rows}x{seen.cols} chessboard", target, frame.name)
    if check_spec and not seen.touches_border and seen.size != declared:
        bigger = "larger" if seen.size[0] >= declared[0] and seen.size[1] >= declared[1] else "other"
        return failed_detection(f"the image shows a chessboard of {seen.rows}x{seen.cols} inner corners, {bigger} "
                                f"than the target's {target.rows}x{target.cols}; searched once the board spec is "
                                "settled", target, frame.name, other_grid=(seen.rows, seen.cols), deferred=True)
    det = detect_image(grey, target, intrinsics, source=frame.name, **options)
    if det.ok and grid_continues(grey, target, det.ids, det.uv_px):
        x0, y0, x1, y1 = roi_from_points(det.uv_px, grey.shape, pad_frac=1.0)
        around = chessboard_seen(grey[y0:y1, x0:x1])
        other = (around.rows, around.cols) if around is not None and around.size != declared else None
        return replace(det, ok=False, other_grid=other,
                       reason=f"the {target.rows}x{target.cols} grid found is part of a larger grid of squares "
                              "(a larger board than the target spec says?)")
    return det
