"""White-on-black prints: a board printed (or shown) with its ink and paper swapped.

Every detector here looks for the board as printed, dark ink on light paper: black squares (and a
light quiet zone around them), ArUco markers with a black border, dark dots. A board printed white on
black (white squares, markers or dots on a black sheet) is the same board in the inverted image
(``255 - grey``), with the same corners at the same pixels, so :func:`~calibgraph.detect.search.detect_image`
searches that image when the board is not found as printed (``polarity="auto"``, the default):

* as printed first, the inverted image only where that finds nothing, and only when a quick look at
  the inverted image sees what the kind's detector needs (:func:`worth_inverting`): ArUco markers of
  the declared dictionary (ChArUco), at least as many blobs as the grid has dots (circle grids), so a
  frame without a board costs little more than before;
* a checkerboard is the exception: OpenCV's classic detector spends 30-50 s on a 1920x1200 frame of a
  white-on-black board before it gives up (its adaptive threshold tries every dilation on squares it
  cannot link, the black margin joining them), so the polarity is told first
  (:func:`checkerboard_polarity`, milliseconds): OpenCV's quick chessboard check on the half-resolution
  frame, then its detector without the adaptive threshold, which fails in milliseconds on the wrong
  polarity and finds a clean board of the right one. Only a frame whose inverted half-size image shows
  the board, and whose image as printed does not (with the adaptive threshold too), is searched
  inverted, and then not as printed.

A detection in the inverted image says so (``ImageDetection.inverted``); its point ids are those of the
board as printed on the page (for a checkerboard the colour rule of :mod:`calibgraph.detect.orient`
holds in the inverted image). The board fit models the inverted image, where the board is ink on paper.
"""

from __future__ import annotations

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target
from calibgraph.detect.circles import blob_detector, blob_image

POLARITIES = ("auto", "normal", "inverted")
HALF_FROM_PX = 480  # the polarity checks look at frames whose shorter side is at least this at half size
CHECK_PITCH_PX = 10.0  # squares the last polarity check needs (pixels of the image it looks at)


def check_polarity(polarity: str) -> str:
    if polarity not in POLARITIES:
        raise InputError(f"detect: polarity must be one of {', '.join(POLARITIES)}, got {polarity!r}.")
    return polarity


def inverted(grey: np.ndarray) -> np.ndarray:
    """The image with ink and paper swapped."""
    return np.ascontiguousarray(255 - grey)


def _half(grey: np.ndarray) -> np.ndarray:
    import cv2

    if min(grey.shape[:2]) < HALF_FROM_PX:
        return grey
    return cv2.resize(grey, (grey.shape[1] // 2, grey.shape[0] // 2), interpolation=cv2.INTER_AREA)


def checkerboard_polarity(grey: np.ndarray, target: Target) -> str | None:
    """``"inverted"`` when ``grey`` shows ``target`` (a checkerboard) printed white on black, ``"normal"``
    when it shows it as printed, None when the quick look cannot tell (no board seen, or one that
    only the full search may find): module docstring. A few milliseconds on a frame without a board
    or with a board as printed; up to ~2 s on a 1920x1200 frame of a white-on-black board."""
    import cv2

    img = _half(grey)
    size = (target.cols, target.rows)
    if not cv2.checkChessboard(img, size):  # either polarity passes it; no board, no question
        return None
    ok, _ = cv2.findChessboardCorners(img, size, flags=cv2.CALIB_CB_FAST_CHECK)
    if ok:
        return "normal"
    ok, corners = cv2.findChessboardCorners(inverted(img), size, flags=cv2.CALIB_CB_FAST_CHECK)
    if not ok:
        return None
    # The inverted image shows a clean board: unless the image as printed shows it too to the search's
    # own flags (a board as printed without a light margin, on a dark ground, looks so), it is a
    # white-on-black print. That check costs ~2 s at half size on a 1920x1200 frame (the slow
    # failure the module docstring tells of), ~0.1 s at a quarter, where squares of 10 px still
    # find a board.
    G = np.asarray(corners, float).reshape(target.rows, target.cols, 2)
    pitch = float(np.median(np.linalg.norm(np.diff(G, axis=1), axis=-1)))
    if pitch >= 2 * CHECK_PITCH_PX and min(img.shape[:2]) >= 2 * HALF_FROM_PX // 2:
        img = cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
    ok, _ = cv2.findChessboardCorners(img, size, flags=flags)
    return "normal" if ok else "inverted"


def worth_inverting(grey: np.ndarray, target: Target) -> bool:
    """Whether the inverted image of ``grey``, in which the board was not found as printed, shows
    what ``target``'s detector needs (module docstring): a checkerboard its polarity check, a ChArUco
    board a marker of its dictionary, a circle grid as many blobs as it has dots."""
    import cv2

    if target.kind == "checkerboard":
        return checkerboard_polarity(grey, target) == "inverted"
    if target.kind == "charuco":
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, target.dictionary))
        p = cv2.aruco.DetectorParameters()
        p.minMarkerPerimeterRate = 0.01  # far boards' markers, as the ChArUco finder allows
        _, ids, _ = cv2.aruco.ArucoDetector(d, p).detectMarkers(inverted(grey))
        return ids is not None and len(ids) > 0
    img = _half(grey)
    scale = grey.shape[0] / img.shape[0]
    max_area = (0.25 * grey.size / max(1, target.n_points) + 1e4) / scale**2
    n = len(blob_detector(max_area).detect(blob_image(inverted(img))))
    return n >= target.n_points
