"""Guided detection: where a pose estimate says the board is, look there, at the right scale.

Once every camera has a coarse pose (from the first views, or a previous result), the board's
image in any capture is predicted from the robot's flange pose: which pixels it covers and how
large its squares are. Then:

- a view predicted to show the board is searched only in the predicted region (with a margin for
  the estimate's error), with up-scaling only when its predicted squares are small, instead of
  the whole frame and every candidate region the blind search tries;
- a view predicted empty (board outside the image, behind the camera or edge-on) is confirmed
  empty cheaply: OpenCV's quick chessboard check on the half-resolution frame, a few ms. Only if
  that check sees a board after all (the prediction was wrong) does the full detector run;
- a view whose board is predicted far out of view (its centre behind the camera, its face turned
  away, or its image farther outside the frame than its own size) is not even decoded: decoding
  is then most of what a frame costs, and the frame is worth nothing. The dataset driver checks a
  sample of such frames anyway, so a wrong estimate shows (:mod:`calibgraph.detect.guided_dataset`).

On a frame without the board the blind detector spends most of its time in the up-scaled searches
of regions that merely look like a board; the confirmation costs little more than the image decode.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import DetectionError
from calibgraph.core.targets import Target
from calibgraph.detect.detection import ImageDetection, failed_detection
from calibgraph.detect.image import Frame
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
        far: not visible, and far enough from it that the frame need not be read (module docstring).
    """

    visible: bool
    region_px: tuple | None = None
    pitch_px: float = 0.0
    far: bool = False


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
    centre = p_c.mean(axis=0)
    if np.any(p_c[:, 2] < 0.05):
        return ViewHint(False, far=bool(centre[2] < 0))
    # the printed face looks along -z of the board frame (+z for the modified circle grid, whose
    # z comes out of the sheet): the viewing ray must run along +z into a face seen from the front
    normal = T[:3, 2] * (-1.0 if target.kind == "modified_circles" else 1.0)
    cos_view = float(normal @ centre) / float(np.linalg.norm(centre))
    if cos_view < np.cos(np.radians(max_angle_deg)):
        return ViewHint(False, far=cos_view < 0)  # seen from behind or edge-on
    uv = intrinsics.project(p_c)
    w, h = intrinsics.width_px, intrinsics.height_px
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    if hi[0] < 0 or hi[1] < 0 or lo[0] > w - 1 or lo[1] > h - 1:
        # how far outside: the gap between the board's image and the frame, against the board's size
        gap = max(-hi[0], -hi[1], lo[0] - (w - 1), lo[1] - (h - 1))
        return ViewHint(False, far=bool(gap > max(float(np.max(hi - lo)), 0.1 * max(w, h))))
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


def board_maybe_present(frame, target: Target) -> bool:
    """A cheap look for a board the prediction missed: OpenCV's quick chessboard check at half
    resolution (checkerboards and ChArUco; their squares form the same pattern), a few ms.
    Circle grids have no such check: they are looked for with the detector at half resolution
    and without up-scaling. ``frame``: a :class:`~calibgraph.detect.image.Frame` or a grey image."""
    import cv2

    half = (frame if isinstance(frame, Frame) else Frame(frame)).reduced(2)
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
    """Detect ``target`` in ``image`` (a path, an image array or a
    :class:`~calibgraph.detect.image.Frame`) guided by ``hint`` (module docstring); ``hint=None``
    is the blind :func:`detect_image`. ``options`` go to :func:`detect_image`."""
    import time

    t0 = time.perf_counter()
    options = dict(options)
    src = options.pop("source", None)
    frame = image if isinstance(image, Frame) else Frame(image, src)
    src = src or frame.name
    if hint is not None and hint.far:
        return failed_detection("board predicted far out of view; frame not read", target, src, t0)
    try:
        if hint is None:
            det = detect_image(frame.grey(), target, intrinsics, source=src, **options)
        elif not hint.visible:
            if board_maybe_present(frame, target):
                det = detect_image(frame.grey(), target, intrinsics, source=src, **options)
            else:
                det = failed_detection("board predicted out of view, and none seen by the quick check", target, src)
        else:
            if not (0 < hint.pitch_px < GUIDED_MIN_PITCH_PX):
                options["upscale"] = 1  # large squares: no up-scaling ladder
            options.setdefault("bounded", True)  # a quick probe before the up-scaled search of an empty region
            det = detect_image(frame.grey(), target, intrinsics, source=src, region_px=hint.region_px, **options)
            if not det.ok:
                det = replace(det, reason=f"{det.reason} (searched the predicted region)")
    except DetectionError as e:
        det = failed_detection(str(e), target, src, unreadable=True)
    return replace(det, time_s=time.perf_counter() - t0)
