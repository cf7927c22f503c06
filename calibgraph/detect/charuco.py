"""ChArUco corners: OpenCV's ``CharucoDetector``; partial views are kept (the markers fix the ids)."""

from __future__ import annotations

import numpy as np

from calibgraph.core.camera import Intrinsics


def find_charuco(grey, target, intr: Intrinsics | None, scale: float = 1.0):
    import cv2

    board = target.cv_charuco_board()
    cp = cv2.aruco.CharucoParameters()
    if intr is not None and scale == 1.0:
        cp.cameraMatrix = intr.K.astype(np.float64)
        cp.distCoeffs = intr.dist8.astype(np.float64)
    dp = cv2.aruco.DetectorParameters()
    dp.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    # OpenCV's default drops markers with a perimeter under 3 % of the image size (14 px sides on
    # a 1080p frame); far boards have smaller markers that still decode.
    dp.minMarkerPerimeterRate = 0.01
    det = cv2.aruco.CharucoDetector(board, cp, dp)
    cc, cid, mc, mid = det.detectBoard(grey)
    if cid is None or len(cid) == 0:
        n_markers = 0 if mid is None else len(mid)
        return None, n_markers
    return (np.asarray(cid).reshape(-1).astype(int), np.asarray(cc, float).reshape(-1, 2), "charuco", ""), len(mid)
