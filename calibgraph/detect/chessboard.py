"""Checkerboard corners: OpenCV's classic detector with ``cornerSubPix``, or its SB detector.

``findChessboardCorners`` + ``cornerSubPix`` with a window sized to the grid pitch ("classic"),
or ``findChessboardCornersSB`` with ``CALIB_CB_ACCURACY`` ("sb"). Classic is the more accurate on
squares of a few pixels and more; below ``SB_BELOW_PITCH_PX`` SB on the up-scaled region is found
more often and is more accurate, so ``method="auto"`` uses classic and switches to SB there
(scripts/bench_detect.py measures both against rendered truth; scripts/results/bench_detect.md).
The corners are then ordered to the target's ids (:mod:`calibgraph.detect.orient`).
"""

from __future__ import annotations

import numpy as np

from calibgraph.detect.grid_filter import check_grid
from calibgraph.detect.orient import orient_grid
from calibgraph.detect.regions import roi_candidates, roi_from_points


def _subpix_window(pitch_px: float) -> int:
    # Half-window about a third of the pitch: large enough to average noise, small enough not to
    # reach the neighbouring corners (which biases cornerSubPix).
    return int(np.clip(np.floor(pitch_px / 3.0), 2, 11))



# Below this square size (pixels of the original image) the SB detector on the up-scaled region
# is more accurate than classic + cornerSubPix; above it classic is (scripts/results/bench_detect.md).
SB_BELOW_PITCH_PX = 8.0


def _classic(grey, target, fast):
    import cv2

    # CALIB_CB_FAST_CHECK keeps a miss on a whole frame fast (without it a frame with a tiny
    # board can take seconds) but it also rejects boards with ~10 px squares: those are found
    # afterwards in the up-scaled region of interest, searched without it.
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    ok, c = cv2.findChessboardCorners(grey, (target.cols, target.rows), flags=flags | (cv2.CALIB_CB_FAST_CHECK if fast else 0))
    if not ok:
        return None
    G = c.reshape(target.rows, target.cols, 2)
    pitch = float(np.median(np.linalg.norm(np.diff(G, axis=1), axis=-1)))
    w = _subpix_window(pitch)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    c = cv2.cornerSubPix(grey, c.reshape(-1, 1, 2).astype(np.float32), (w, w), (-1, -1), crit)
    return np.asarray(c, float).reshape(-1, 2)


def _sb(grey, target, fast, rois=None):
    import cv2

    # SB costs seconds on a whole 1080p frame; on the saddle-point regions it costs milliseconds
    # and finds the same corners (the whole frame is the fallback). ``rois``: those regions, when
    # the caller has them already.
    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_NORMALIZE_IMAGE
    h, w = grey.shape
    if rois is None:
        rois = roi_candidates(grey, target) if fast else []
    rois = rois or [(0, 0, w, h)]
    for x0, y0, x1, y1 in rois:
        ok, c = cv2.findChessboardCornersSB(grey[y0:y1, x0:x1], (target.cols, target.rows), flags=flags)
        if ok:
            return np.asarray(c, float).reshape(-1, 2) + [x0, y0]
    return None


def find_checkerboard(grey, target, method, allow_symmetric, scale=1.0, sb_fallback=True, fast=None, rois=None):
    """Checkerboard corners on ``grey`` (the original image at ``scale`` 1, or an up-scaled
    region). ``method='auto'``: classic, replaced by SB when the squares are smaller than
    ``SB_BELOW_PITCH_PX`` original pixels, and SB when classic finds nothing and
    ``sb_fallback`` (off on the original image when an up-scaled classic search follows: that
    is more accurate than SB at ~10-12 px squares). ``fast`` (default: on at scale 1) is OpenCV's
    quick rejection of frames without a board; ``rois``: the saddle-point regions SB searches
    (computed when not given)."""
    fast = scale == 1.0 if fast is None else fast
    found = None
    if method in ("classic", "auto"):
        c = _classic(grey, target, fast)
        if c is not None:
            found = (c, "classic")
            if method == "auto":
                G = c.reshape(target.rows, target.cols, 2)
                pitch = float(np.median(np.concatenate([np.linalg.norm(np.diff(G, axis=1), axis=-1).ravel(),
                                                        np.linalg.norm(np.diff(G, axis=0), axis=-1).ravel()])))
                if pitch / scale < SB_BELOW_PITCH_PX:
                    # SB in a tight region around classic's corners, kept only if it finds the same
                    # grid (every corner within a third of a square of classic's).
                    x0, y0, x1, y1 = roi_from_points(c, grey.shape, pad_frac=0.6, pad_px=4)
                    c2 = _sb(grey[y0:y1, x0:x1], target, False)
                    if c2 is not None:
                        c2 = c2 + [x0, y0]
                        d = np.linalg.norm(c2[:, None, :] - c[None, :, :], axis=-1).min(axis=1)
                        if d.max() < pitch / 3:
                            found = (c2, "sb")
                        else:
                            # They disagree: keep SB only if its grid passes the filter and
                            # classic's does not (raw OpenCV order is a consistent grid, so the
                            # check needs no orientation yet).
                            ij, P = target.line_ij, target.points_board_m
                            if check_grid(c2, ij, P).ok and not check_grid(c, ij, P).ok:
                                found = (c2, "sb")
    if found is None and (method == "sb" or (method == "auto" and sb_fallback)):
        c = _sb(grey, target, fast, rois)
        if c is not None:
            found = (c, "sb")
    if found is None:
        return None
    c, m = found
    G = np.asarray(c, float).reshape(target.rows, target.cols, 2)
    uv, note = orient_grid(G, target, grey, allow_symmetric)
    return np.arange(target.n_points), uv, m, note
