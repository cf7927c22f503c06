"""Drawings over the board: pose axes and text a capture app drew into the image it saved.

ViSP's ``vpDisplay::displayFrame`` and OpenCV's ``drawFrameAxes`` draw the board's pose as thick red,
green and blue lines from its origin, along its first row and column, often with a text of the pose
beside it; an image saved with them holds lines that are neither ink nor paper. The detectors still
find the grid (the lines are thin beside a square), but a corner or a dot under a line is moved: the
board fit's model has no line (a corner fitted through one moves 1-7 px, with a residual ten times
its neighbours'), a dot a line crosses is joined to it (its blob's centre moves by a third of the
line's width, or the blob is no longer round and is lost). Such a point should cost its own view of
the point, never the view, and never a point put in the wrong place:

* :func:`outlying_points`: a point (a corner the fit could not model) that its neighbours place
  elsewhere, by a local homography from the board to the image fitted to the grid points near it,
  robustly (the worst neighbour dropped while it misses, so that neighbours under the same line do not
  carry it), is dropped: by more than ``OUTLIER_PX`` or ``OUTLIER_PITCH`` of the local pitch, whichever
  is larger (a good corner sits within a few hundredths of a pixel of that prediction). The neighbours
  are those not in doubt themselves within 3 pitches, when there are 6 of them, else all within 2.5;
* :func:`disturbed_corners`: the corners worth that test, those whose board-fit residual stands out
  (``SUSPECT_RATIO`` times the median corner's and ``SUSPECT_EXCESS_GREY`` above it): real images
  (ViSP's, industrial_calibration's ChArUco set, MC-HEC's rendered cell) reach 2-8 times the median,
  a corner under a drawn line 10-20 times. Only such corners are tested, so that a lens's bend
  (which a local homography follows less well than these tolerances at the grid's corners) never
  costs a corner.

Checkerboards and ChArUco boards (their corners are fitted) are covered. Circle grids are not: a dot
has no fit residual to single it out, a line along a row moves all its dots alike (so their neighbours
agree with them), and a strong lens bends a grid's edge by as much (0.1 of a pitch at k1 = -0.35) as
a line moves a dot; such a grid is refused by the grid filter when its row bends, and may be kept
with the moved dots when a whole row moves (scripts/results/bench_detect_prints.md measures it).
"""

from __future__ import annotations

import numpy as np

OUTLIER_PX = 0.5
OUTLIER_PITCH = 0.005
NEIGHBOUR_PITCHES = 2.5
CLEAN_NEIGHBOUR_PITCHES = 3.0  # ... of the neighbours not themselves in doubt, when 6 or more are
SUSPECT_RATIO = 3.0
SUSPECT_EXCESS_GREY = 8.0


def disturbed_corners(rms_grey: np.ndarray) -> np.ndarray:
    """(N,) True where a corner's board-fit residual (grey levels) stands out (module docstring)."""
    r = np.asarray(rms_grey, float)
    if r.size < 4 or not np.isfinite(r).any():
        return np.zeros(r.shape, bool)
    med = float(np.nanmedian(r))
    return np.isfinite(r) & (r > SUSPECT_RATIO * med) & (r > med + SUSPECT_EXCESS_GREY)


def outlying_points(uv_px: np.ndarray, board_xy: np.ndarray, pitch_m: float, candidates=None) -> np.ndarray:
    """(N,) True for each point (of ``candidates``, a mask; default all) that its neighbours on the
    board (``board_xy`` (N, 2), metres) place elsewhere (module docstring): the points not among the
    candidates within ``CLEAN_NEIGHBOUR_PITCHES`` when there are 6, else all within
    ``NEIGHBOUR_PITCHES``. A point with fewer than 6 neighbours is not judged."""
    uv = np.asarray(uv_px, float).reshape(-1, 2)
    xy = np.asarray(board_xy, float).reshape(-1, 2)
    n = len(uv)
    out = np.zeros(n, bool)
    cand = np.ones(n, bool) if candidates is None else np.asarray(candidates, bool)
    if n < 7 or not cand.any():
        return out
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    for i in np.nonzero(cand)[0]:
        # the unsuspected neighbours when there are enough (a line disturbs a row of corners together),
        # else all of them
        nb = np.nonzero((d[i] <= CLEAN_NEIGHBOUR_PITCHES * pitch_m) & ~cand)[0]
        if len(nb) < 6:
            nb = np.nonzero((d[i] <= NEIGHBOUR_PITCHES * pitch_m) & (np.arange(n) != i))[0]
        H = _robust_homography(xy[nb], uv[nb], pitch_m)
        if H is None:
            continue
        p = H @ np.array([xy[i, 0], xy[i, 1], 1.0])
        if not abs(p[2]) > 1e-12:
            continue
        pred = p[:2] / p[2]
        # the local pitch in pixels: the homography's scale at the point
        q = H @ np.array([xy[i, 0] + pitch_m, xy[i, 1], 1.0])
        pitch_px = float(np.linalg.norm(q[:2] / q[2] - pred))
        out[i] = float(np.linalg.norm(uv[i] - pred)) > max(OUTLIER_PX, OUTLIER_PITCH * pitch_px)
    return out


def _robust_homography(xy: np.ndarray, uv: np.ndarray, pitch_m: float):
    """The board-to-image homography of a few neighbouring points, robust to those a line moved too:
    least squares, the worst point dropped while it misses by more than ``OUTLIER_PX`` (and more than
    twice the next worst) and 6 are left; deterministic (no random sampling). None under 6 points."""
    import cv2

    keep = np.ones(len(xy), bool)
    while keep.sum() >= 6:
        H, _ = cv2.findHomography(xy[keep], uv[keep], 0)
        if H is None:
            return None
        ph = np.column_stack([xy, np.ones(len(xy))]) @ H.T
        r = np.linalg.norm(ph[:, :2] / ph[:, 2:3] - uv, axis=1)
        r[~keep] = -1.0
        worst = np.argsort(-r)
        if r[worst[0]] <= OUTLIER_PX or keep.sum() == 6:
            return H
        keep[worst[0]] = False
    return None
