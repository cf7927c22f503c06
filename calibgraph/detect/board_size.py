"""What size of chessboard an image shows: telling a wrong board spec from a board out of view.

A board declared with the wrong number of rows or columns is the commonest set-up mistake, and
the detectors only answer "not found" (or, worse, find the declared grid inside a larger board,
a different part of it in every view). Two signs name the mistake instead:

* :func:`chessboard_seen`: OpenCV's SB detector with ``CALIB_CB_LARGER`` finds a chessboard of at
  least 3 x 3 inner corners and reports the size it found (its ``meta`` output). On the reduced
  frame it costs about what decoding the frame costs, and unlike the classic detector it does not
  spend seconds trying to fit a declared size into a grid of another size.
* :func:`grid_continues`: a detected grid of the declared size is part of a larger board when the
  squares go on past its outer ring of squares: the cells one square further out alternate dark
  and light like the board's (in the opposite phase) instead of showing the white margin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibgraph.core.targets import Target
from calibgraph.detect.image import sample_bilinear


@dataclass(frozen=True)
class ChessboardSeen:
    """A chessboard found by :func:`chessboard_seen`.

    Attributes:
        rows, cols: inner corners along the image's vertical and horizontal grid directions as
            OpenCV orders them (compare as an unordered pair).
        uv_px: (rows * cols, 2) corners in full-resolution pixels.
        touches_border: the grid comes within one square of the image border, so it may be a
            board cut by the border (its size is then a lower bound).
    """

    rows: int
    cols: int
    uv_px: np.ndarray
    touches_border: bool

    @property
    def size(self) -> tuple:
        """(smaller, larger) inner-corner counts: the grid's size whatever its orientation."""
        return tuple(sorted((self.rows, self.cols)))


def chessboard_seen(grey: np.ndarray, scale: int = 1, min_size=(3, 3)) -> ChessboardSeen | None:
    """The largest chessboard of at least ``min_size`` (rows, cols) inner corners in ``grey`` (an
    image reduced by ``scale`` from the full resolution), or None."""
    import cv2

    flags = cv2.CALIB_CB_LARGER | cv2.CALIB_CB_NORMALIZE_IMAGE
    cv2.setRNGSeed(0)  # the SB detector draws from the thread's RNG: one image, one answer
    ok, corners, meta = cv2.findChessboardCornersSBWithMeta(grey, (int(min_size[1]), int(min_size[0])), flags)
    if not ok or corners is None or meta is None or meta.ndim != 2:
        return None
    rows, cols = meta.shape
    if rows * cols != len(corners):
        return None
    uv = np.asarray(corners, float).reshape(-1, 2)
    G = uv.reshape(rows, cols, 2)
    pitch = float(np.median(np.linalg.norm(np.diff(G, axis=1), axis=-1)))
    h, w = grey.shape[:2]
    lo, hi = uv.min(0), uv.max(0)
    touches = bool(lo[0] < 1.5 * pitch or lo[1] < 1.5 * pitch or hi[0] > w - 1 - 1.5 * pitch or hi[1] > h - 1 - 1.5 * pitch)
    # pixel x of the reduced image covers full-resolution pixels scale * x .. scale * x + scale - 1
    return ChessboardSeen(int(rows), int(cols), scale * uv + 0.5 * (scale - 1), touches)


def grid_continues(grey: np.ndarray, target: Target, ids: np.ndarray, uv_px: np.ndarray) -> bool:
    """Whether the checkerboard grid detected at ``uv_px`` (points ``ids`` of ``target``, the whole
    grid) is part of a larger board: on some side of the grid, the cells one square beyond its
    outer ring of squares alternate like board squares (module docstring). Sides whose cells fall
    outside the image, or number fewer than three, are not judged."""
    import cv2

    if target.kind != "checkerboard" or len(ids) != target.n_points:
        return False
    page = target.points_board_m[ids, :2] / target.pitch_m  # (x, y) in squares: corners at 0..cols-1, 0..rows-1
    H, _ = cv2.findHomography(page, np.asarray(uv_px, float), 0)
    if H is None:
        return False
    pitch_px = float(np.median(np.linalg.norm(np.diff(uv_px.reshape(target.rows, target.cols, 2), axis=1), axis=-1)))
    k = int(np.clip(round(pitch_px / 3), 1, 15))
    smooth = cv2.blur(grey, (k, k))
    h, w = grey.shape
    cols, rows = target.cols, target.rows
    # centres of the outer ring of squares (offset -0.5 / +0.5 past the last corner) and of the cells one
    # square further out, along each of the four sides
    sides = []
    along_x = np.arange(-1, cols) + 0.5
    along_y = np.arange(-1, rows) + 0.5
    for fixed, ring, nxt in (("y", -0.5, -1.5), ("y", rows - 0.5, rows + 0.5), ("x", -0.5, -1.5), ("x", cols - 0.5, cols + 0.5)):
        t = along_x if fixed == "y" else along_y
        pts = [np.column_stack([t, np.full_like(t, c)]) if fixed == "y" else np.column_stack([np.full_like(t, c), t])
               for c in (ring, nxt)]
        sides.append(pts)
    for ring_xy, next_xy in sides:
        uv_ring = cv2.perspectiveTransform(ring_xy.reshape(-1, 1, 2), H).reshape(-1, 2)
        uv_next = cv2.perspectiveTransform(next_xy.reshape(-1, 1, 2), H).reshape(-1, 2)
        inside = np.all((uv_next >= 2) & (uv_next <= [w - 3, h - 3]), axis=1) & \
            np.all((uv_ring >= 2) & (uv_ring <= [w - 3, h - 3]), axis=1)
        if inside.sum() < 3:
            continue
        sign = (-1.0) ** np.arange(len(ring_xy))
        v_ring = sample_bilinear(smooth, uv_ring[inside])
        v_next = sample_bilinear(smooth, uv_next[inside])
        s = sign[inside]
        a_ring = float(np.mean(s * (v_ring - v_ring.mean())))
        a_next = float(np.mean(s * (v_next - v_next.mean())))
        # the board's own outer ring alternates with some contrast; a continuing board alternates the
        # other way round one square further out, with a contrast of the same order
        if abs(a_ring) > 10 and a_next * a_ring < 0 and abs(a_next) > 0.5 * abs(a_ring):
            return True
    return False


def board_whole(grey: np.ndarray, seen: ChessboardSeen) -> bool:
    """Whether the chessboard ``seen`` (in ``grey``'s pixels) is a whole board: on each of its four
    sides, a quarter of a square past its outer ring of squares, the image is uniform and the board's
    paper (as light as its white squares, or, printed white on black, as dark as its black ones), as a
    printed margin is. A board partly covered (by a hand, a sheet, an arm) or cut by the image
    border fails on the side where it ends: the cover is neither, or the side is outside the image.
    Inner corners only (``seen.uv_px``, ``seen.rows`` x ``seen.cols``, OpenCV's order)."""
    import cv2

    rows, cols = seen.rows, seen.cols
    if rows < 2 or cols < 2:
        return False
    page = np.array([(j, i) for i in range(rows) for j in range(cols)], float)
    H, _ = cv2.findHomography(page, np.asarray(seen.uv_px, float), 0)
    if H is None:
        return False
    h, w = grey.shape[:2]
    pitch_px = float(np.median(np.linalg.norm(np.diff(seen.uv_px.reshape(rows, cols, 2), axis=1), axis=-1)))
    smooth = cv2.blur(grey, (max(1, int(pitch_px / 6)),) * 2)

    def at(xy):
        uv = cv2.perspectiveTransform(np.asarray(xy, float).reshape(-1, 1, 2), H).reshape(-1, 2)
        if np.any(uv < 1) or np.any(uv > [w - 2, h - 2]):
            return None
        return sample_bilinear(smooth, uv)

    # the outer ring of squares (centres half a square past the last corners) gives the two colours
    ring = np.array([(x, -0.5) for x in np.arange(-0.5, cols)] + [(x, rows - 0.5) for x in np.arange(-0.5, cols)])
    v_ring = at(ring)
    if v_ring is None:
        return False
    dark, light = float(np.percentile(v_ring, 10)), float(np.percentile(v_ring, 90))
    contrast = light - dark
    if contrast < 20:
        return False
    out = 1.25  # past the last inner corner: the outer squares end at 1, the margin begins
    t_x, t_y = np.linspace(-0.5, cols - 0.5, 2 * cols), np.linspace(-0.5, rows - 0.5, 2 * rows)
    sides = ([(x, -out) for x in t_x], [(x, rows - 1 + out) for x in t_x],
             [(-out, y) for y in t_y], [(cols - 1 + out, y) for y in t_y])
    levels = []
    for side in sides:
        v = at(side)
        if v is None or float(np.std(v)) > 0.15 * contrast:
            return False
        levels.append(float(np.median(v)))
    near_light = all(abs(lv - light) < 0.25 * contrast for lv in levels)
    near_dark = all(abs(lv - dark) < 0.25 * contrast for lv in levels)
    return near_light or near_dark
