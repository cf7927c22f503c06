"""Guided detection: where a pose estimate says the board is, look there, at the right scale.

Once every camera has a coarse pose (from the first views, or a previous result), the board's
image in any capture is predicted from the robot's flange pose: which pixels it covers and how
large its squares are. Then:

- a view predicted to show the board is searched only in the predicted region (with a margin for
  the estimate's error), with up-scaling only when its predicted squares are small, instead of
  the whole frame and every candidate region the blind search tries;
- a view predicted empty (board outside the image, behind the camera or edge-on) is confirmed
  empty cheaply: OpenCV's quick chessboard check on the half-resolution frame, a few ms. Only if
  that check sees a board after all (the prediction was wrong) does the full detector run.

On a frame without the board the blind detector spends most of its time in the up-scaled searches
of regions that merely look like a board; the confirmation costs little more than the image decode.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.targets import Target
from calibgraph.detect.detection import ImageDetection
from calibgraph.detect.image import read_grey
from calibgraph.detect.search import detect_image

# Squares predicted smaller than this (pixels; the blind detector's min_pitch_px) are searched with
# up-scaling of the region.
GUIDED_MIN_PITCH_PX = 12.0


@dataclass(frozen=True)
class ViewHint:
    """Where the board should appear in one view.

    Attributes:
        visible: the board (or part of it) is predicted inside the image, facing the camera.
        region_px: (x0, y0, x1, y1) search region, clipped to the image (None when not visible).
        pitch_px: predicted smallest spacing between neighbouring points, pixels.
    """

    visible: bool
    region_px: tuple | None = None
    pitch_px: float = 0.0


def predict_view(target: Target, intrinsics: Intrinsics, T_cam_board: np.ndarray, margin_frac: float = 0.25,
                 margin_px: float = 24.0, max_angle_deg: float = 85.0) -> ViewHint:
    """The :class:`ViewHint` of a board at ``T_cam_board`` seen by a camera with ``intrinsics``.

    The search region is the bounding box of the projected board (its outer border, not only the
    inner points) grown by ``margin_frac`` of its size plus ``margin_px``, for the estimate's error.
    """
    T = np.asarray(T_cam_board, float)
    x0, y0, x1, y1 = target.extent_m
    outline = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], float)
    pts = np.vstack([target.points_board_m, outline])
    p_c = pts @ T[:3, :3].T + T[:3, 3]
    if np.any(p_c[:, 2] < 0.05):
        return ViewHint(False)
    centre = p_c.mean(axis=0)
    # the printed face looks along -z of the board frame (+z for the modified circle grid, whose
    # z comes out of the sheet): the viewing ray must run along +z into a face seen from the front
    normal = T[:3, 2] * (-1.0 if target.kind == "modified_circles" else 1.0)
    cos_view = float(normal @ centre) / float(np.linalg.norm(centre))
    if cos_view < np.cos(np.radians(max_angle_deg)):
        return ViewHint(False)  # seen from behind or edge-on
    uv = intrinsics.project(p_c)
    w, h = intrinsics.width_px, intrinsics.height_px
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    if hi[0] < 0 or hi[1] < 0 or lo[0] > w - 1 or lo[1] > h - 1:
        return ViewHint(False)
    pad = margin_frac * float(np.max(hi - lo)) + margin_px
    region = (int(max(0, np.floor(lo[0] - pad))), int(max(0, np.floor(lo[1] - pad))),
              int(min(w, np.ceil(hi[0] + pad) + 1)), int(min(h, np.ceil(hi[1] + pad) + 1)))
    grid = uv[: target.n_points]
    pitch = _min_neighbour_px(grid, target)
    return ViewHint(True, region, pitch)


def _min_neighbour_px(uv: np.ndarray, target: Target) -> float:
    """Smallest image distance between grid neighbours (rows/columns of ``target.line_ij``)."""
    ij = target.line_ij
    d = []
    for axis in (0, 1):
        other = 1 - axis
        for k in np.unique(ij[:, axis]):
            idx = np.nonzero(ij[:, axis] == k)[0]
            idx = idx[np.argsort(ij[idx, other])]
            if idx.size >= 2:
                step = np.diff(ij[idx, other]).astype(float)
                d.append(np.linalg.norm(np.diff(uv[idx], axis=0), axis=1) / step)
    return float(np.min(np.concatenate(d))) if d else 0.0


def board_maybe_present(grey: np.ndarray, target: Target) -> bool:
    """A cheap look for a board the prediction missed: OpenCV's quick chessboard check at half
    resolution (checkerboards and ChArUco; their squares form the same pattern), a few ms.
    Circle grids have no such check: they are looked for with the detector at half resolution
    and without up-scaling."""
    import cv2

    half = cv2.resize(grey, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    if target.kind == "checkerboard":
        return bool(cv2.checkChessboard(half, (target.cols, target.rows)))
    if target.kind == "charuco":
        # the chessboard of a ChArUco target has (rows + 1) x (cols + 1) squares; markers break
        # OpenCV's square-quad check, so count any marker instead
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, target.dictionary))
        corners, ids, _ = cv2.aruco.ArucoDetector(dictionary).detectMarkers(half)
        return ids is not None and len(ids) > 0
    return detect_image(half, target, upscale=1, filter=False).ok


def detect_with_hint(image, target: Target, intrinsics: Intrinsics | None, hint: ViewHint | None,
                     **options) -> ImageDetection:
    """Detect ``target`` in ``image`` guided by ``hint`` (module docstring); ``hint=None`` is the
    blind :func:`detect_image`. ``options`` go to :func:`detect_image`."""
    import time

    if hint is None:
        return detect_image(image, target, intrinsics, **options)
    t0 = time.perf_counter()
    options = dict(options)
    src = options.pop("source", None) or (None if isinstance(image, np.ndarray) else str(image))
    grey = image if isinstance(image, np.ndarray) else read_grey(image)
    if not hint.visible:
        if board_maybe_present(grey, target):
            return detect_image(grey, target, intrinsics, source=src, **options)
        return ImageDetection(ids=np.zeros(0, int), uv_px=np.zeros((0, 2)), ok=False,
                              reason="board predicted out of view, and none seen by the quick check",
                              n_expected=target.n_points, image=src, time_s=time.perf_counter() - t0)
    opts = dict(options)
    if not (0 < hint.pitch_px < GUIDED_MIN_PITCH_PX):
        opts["upscale"] = 1  # large squares: no up-scaling ladder
    det = detect_image(grey, target, intrinsics, source=src, region_px=hint.region_px, **opts)
    if det.ok:
        return replace(det, time_s=time.perf_counter() - t0)
    return replace(det, reason=f"{det.reason} (searched the predicted region)", time_s=time.perf_counter() - t0)
