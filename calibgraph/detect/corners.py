"""Target detection: image -> point ids, sub-pixel pixels and a quality record.

One entry point per image, :func:`detect_image`, and one per dataset, :func:`dataset_detector`
(parallel, cached next to the data, with a progress bar, for ``Dataset.to_problem(detector=...)``).

Detectors (chosen by the target's kind; ``method`` picks among checkerboard detectors):

* checkerboard: ``cv2.findChessboardCorners`` + ``cv2.cornerSubPix`` with a window sized to the
  grid pitch ("classic"), or ``cv2.findChessboardCornersSB`` with ``CALIB_CB_ACCURACY`` ("sb").
  The benchmark (scripts/bench_detect.py, rendered truth, 1-5 m, three camera presets) picks per
  case: classic is the more accurate for squares of 8 px and more (RMS 0.029 px at >= 20 px
  squares, 0.044 px at 12-20 px; radial bias < 0.002 px) where SB gives 0.10-0.16 px with an
  outward bias of +0.01 to +0.06 px; below 8 px SB on the up-scaled region is found more often
  (0.98 against 0.80) and is more accurate (0.076 against 0.156 px). ``method="auto"`` (default)
  therefore uses classic and switches to SB below ``SB_BELOW_PITCH_PX``.
  Those figures are OpenCV's corners. Every checkerboard corner is then refined on the original
  image by a photometric fit of the board around it (:mod:`calibgraph.detect.board_fit`), which
  removes the detectors' outward bias on small squares and most of their noise
  (scripts/results/bench_detect.md has the figures before and after); ``refine=False`` skips it.
* ChArUco: ``cv2.aruco.CharucoDetector``; partial views are kept (ids are fixed by the markers).
  Its corners (cornerSubPix) are then refined by the same photometric fit, with the markers in
  the model (:func:`calibgraph.detect.board_fit.refine_charuco`): radial bias -0.034 -> +0.0004
  px and sigma 0.13 -> 0.007 px at 20 px squares (scripts/results/bench_detect_charuco.md).
* circle grids: ``cv2.findCirclesGrid`` (symmetric, asymmetric), also on the image turned by 90
  and 180 degrees, then, when all fail, the grid assembled from the blob centres (hull
  quadrilateral -> homography -> grown by local affine maps, for close, tilted, distorted views);
  the modified circle grid is found as a symmetric grid and oriented by its enlarged origin dot
  (by its ink, which blur keeps, against the local grid cell, which removes perspective).

Ordering: OpenCV numbers grid points from whichever corner it meets first. Every grid detection is
therefore re-ordered to the target's own ids (``targets`` module docstring): the handedness of the
board (printed side towards the camera) removes mirror orderings, and the remaining 180-degree
ambiguity is settled by the square colours (checkerboards with ``rows + cols`` odd), by the layout
(asymmetric grids with odd row count) or by the big dot (modified circle grid). Boards without such
a cue (``Target.is_symmetric``) are refused, unless ``allow_symmetric=True`` accepts an
image-orientation guess (point 0 nearest the image's top-left), which is then stated in ``reason``.

Far cameras (thesis §6.3): when the target is not found, or its grid pitch is below
``min_pitch_px``, the region of interest is up-scaled (bicubic, x2 then x3) and searched again;
corners are mapped back to original pixels (``cv2.resize`` maps destination pixel ``X`` to source
``(X + 0.5) / k - 0.5``). The region comes from the first detection or, when there is none, from
a saddle-point (checkerboard) or blob (circles) response map. Measured gain: with the thesis's
board the classic detector alone loses the D455-like camera beyond 2 m and the 1080p ones beyond
3.5-4.5 m; with up-scaling all three find it in every image up to 5 m (RMS <= 0.14 px). Where
the original image already works, up-scaling does not improve accuracy (x2 always: 0.035 against
0.029 px at >= 20 px squares), so it is used only when needed.

Every detection passes :func:`calibgraph.detect.grid_filter.check_grid` (thesis Algorithm 3 + homography);
a rejection says why.
"""

from __future__ import annotations

import itertools
import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import DetectionError, InputError
from calibgraph.core.targets import Target
from calibgraph.detect.board_fit import refine_charuco, refine_checkerboard
from calibgraph.detect.grid_filter import check_grid, grid_pitch_px
from calibgraph.io.files import atomic_write_text

# Part of the cache key: bump when a change can move detected points.
DETECTOR_VERSION = "3"


@dataclass(frozen=True)
class ImageDetection:
    """The detection of a target in one image.

    Attributes:
        ids: (N,) target point ids (rows of ``Target.points_board_m``).
        uv_px: (N, 2) sub-pixel positions, OpenCV convention (pixel centres at integers).
        ok: True when the detection is usable; False keeps the points (if any) for diagnosis.
        reason: why it was rejected (or a note on an accepted one); empty when clean.
        n_expected: number of points on the target.
        size_px: square root of the image area covered by the detected points' convex hull.
        spread: fraction of the image area covered by that hull.
        pitch_px: median distance between neighbouring grid points, pixels.
        sharpness_px: edge blur at the points as a Gaussian sigma, pixels (lower is sharper).
        upscale: up-scaling factor of the region the points came from (1 = original image).
        method: detector that produced the points ('classic', 'sb', 'charuco', 'circles', ...).
        n_refined: points moved by the photometric board fit (checkerboards and ChArUco; circle grids keep the
            detector's position).
        homography_rms_px: residual of the board-to-image homography.
        time_s: detection time.
        image: source file, when read from disk.
    """

    ids: np.ndarray
    uv_px: np.ndarray
    ok: bool
    reason: str = ""
    n_expected: int = 0
    size_px: float = 0.0
    spread: float = 0.0
    pitch_px: float = 0.0
    sharpness_px: float = float("nan")
    upscale: int = 1
    method: str = ""
    homography_rms_px: float = float("nan")
    n_refined: int = 0
    time_s: float = 0.0
    image: str | None = None

    def __post_init__(self):
        ids = np.asarray(self.ids, int).reshape(-1)
        uv = np.asarray(self.uv_px, float).reshape(-1, 2)
        if ids.shape[0] != uv.shape[0]:
            raise InputError(f"detection: {ids.shape[0]} ids but {uv.shape[0]} points.")
        if self.ok and ids.size == 0:
            raise InputError("detection: ok=True with no points.")
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "uv_px", uv)

    @property
    def n_found(self) -> int:
        return int(self.ids.size)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["ids"] = self.ids.tolist()
        d["uv_px"] = self.uv_px.tolist()
        for k, v in list(d.items()):
            if isinstance(v, float) and not np.isfinite(v):
                d[k] = None
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ImageDetection":
        d = dict(d)
        for k in ("sharpness_px", "homography_rms_px"):
            if d.get(k) is None:
                d[k] = float("nan")
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})


def _failed(reason: str, target: Target, image: str | None = None, t0: float | None = None, **kw) -> ImageDetection:
    return ImageDetection(ids=np.zeros(0, int), uv_px=np.zeros((0, 2)), ok=False, reason=reason,
                          n_expected=target.n_points, image=image,
                          time_s=0.0 if t0 is None else time.perf_counter() - t0, **kw)


# ---------------------------------------------------------------------------------------------
# Image input
# ---------------------------------------------------------------------------------------------
def read_grey(path) -> np.ndarray:
    """Read an image file as 8-bit grey. Raises :class:`DetectionError` naming the file and the
    problem (missing, empty, truncated/unreadable, unsupported bit depth)."""
    import cv2

    p = Path(path)
    if not p.is_file():
        raise DetectionError(f"{p}: image file not found.")
    if p.stat().st_size == 0:
        raise DetectionError(f"{p}: image file is empty (0 bytes); re-capture it or delete the view.")
    data = np.fromfile(str(p), np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DetectionError(f"{p}: cannot decode the image (truncated or not an image file); re-capture it.")
    return to_grey8(img, str(p))


def to_grey8(img: np.ndarray, where: str = "image") -> np.ndarray:
    """Convert an image array to 8-bit grey: colour -> grey, 16-bit scaled by its white point,
    float in [0, 1] scaled to 255. Other depths are refused with a clear message."""
    import cv2

    img = np.asarray(img)
    if img.size == 0 or img.ndim < 2 or min(img.shape[:2]) < 8:
        raise DetectionError(f"{where}: empty image (shape {img.shape}).")
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[:, :, 0]
        elif img.shape[2] in (3, 4):
            img = cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2GRAY)
        else:
            raise DetectionError(f"{where}: {img.shape[2]} channels; expected grey, BGR or BGRA.")
    elif img.ndim != 2:
        raise DetectionError(f"{where}: image must be 2-D (grey) or 3-D (colour), got shape {img.shape}.")
    if img.dtype == np.uint8:
        return np.ascontiguousarray(img)
    if img.dtype == np.uint16:
        # Cameras often write 10/12-bit data in 16-bit containers: scale by the observed white point.
        hi = float(np.percentile(img, 99.9))
        if hi <= 0:
            raise DetectionError(f"{where}: 16-bit image is black.")
        return np.clip(img.astype(np.float32) * (255.0 / hi), 0, 255).astype(np.uint8)
    if img.dtype in (np.float32, np.float64):
        if not np.all(np.isfinite(img)):
            raise DetectionError(f"{where}: float image contains NaN/inf.")
        scale = 255.0 if img.max() <= 1.0 + 1e-6 else 1.0
        return np.clip(img * scale, 0, 255).astype(np.uint8)
    raise DetectionError(f"{where}: unsupported pixel type {img.dtype}; give 8- or 16-bit grey/colour images.")


# ---------------------------------------------------------------------------------------------
# Geometry helpers
# ---------------------------------------------------------------------------------------------
def _page_xy(target: Target) -> np.ndarray:
    """(N, 2) point positions in page coordinates (x right, y down the printed page)."""
    P = target.points_board_m[:, :2].copy()
    if target.kind == "modified_circles":
        P[:, 1] = -P[:, 1]
    return P


def _handedness(grid_uv: np.ndarray, page: np.ndarray) -> float:
    """Sign of the page-to-image homography's Jacobian determinant (> 0: printed side visible)."""
    import cv2

    H, _ = cv2.findHomography(page, grid_uv, 0)
    if H is None:
        return 0.0
    c = page.mean(0)
    x = np.array([c[0], c[1], 1.0])
    w = H[2] @ x
    J = (H[:2, :2] * w - np.outer(H[:2] @ x, H[2, :2])) / w**2
    return float(np.linalg.det(J))


def _grid_candidates(G: np.ndarray, rows: int, cols: int):
    """All re-orderings of a detected (r, c, 2) grid that give shape (rows, cols, 2)."""
    outs = []
    for B in (G, np.transpose(G, (1, 0, 2))):
        if B.shape[:2] != (rows, cols):
            continue
        for fi in (False, True):
            for fj in (False, True):
                X = B[::-1] if fi else B
                X = X[:, ::-1] if fj else X
                outs.append(np.ascontiguousarray(X))
    return outs


def _bilinear(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    import cv2

    m = uv.astype(np.float32).reshape(-1, 1, 2)
    out = cv2.remap(img, m[:, :, 0], m[:, :, 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1).astype(float)


def _colour_score(grey: np.ndarray, G: np.ndarray) -> float:
    """Mean grey of cells expected black minus cells expected white (negative when the ordering
    matches the board's colours: cell (i, j) between corners (i, j) and (i+1, j+1) is black iff
    i + j is even)."""
    import cv2

    cells = 0.25 * (G[:-1, :-1] + G[1:, 1:] + G[:-1, 1:] + G[1:, :-1])
    sm = cv2.blur(grey, (3, 3))
    val = _bilinear(sm, cells.reshape(-1, 2)).reshape(cells.shape[:2])
    ii, jj = np.indices(val.shape)
    black = (ii + jj) % 2 == 0
    if black.all() or (~black).all():
        return 0.0
    return float(val[black].mean() - val[~black].mean())


def _dot_ink(grey: np.ndarray, uv: np.ndarray, pitch_px: float) -> float:
    """Ink of the dot centred near ``uv``, in units of the local grid cell (pitch_px^2): the summed
    darkness below the paper level within half a pitch of the centre, divided by the cell's area.

    Blur spreads a dot's darkness but keeps its sum, and dividing by the local cell removes
    perspective, so the modified grid's origin dot (twice the diameter) has ~4x the ink of a
    corner dot at any blur, tilt or distortion; a thresholded blob area does not (blur and
    Otsu's threshold shrink that ratio to ~2 on small dots).
    """
    r = 0.5 * pitch_px
    x, y = float(uv[0]), float(uv[1])
    h, w = grey.shape
    x0, x1 = int(max(0, np.floor(x - r))), int(min(w, np.ceil(x + r) + 1))
    y0, y1 = int(max(0, np.floor(y - r))), int(min(h, np.ceil(y + r) + 1))
    patch = grey[y0:y1, x0:x1].astype(float)
    if patch.size < 9:
        return 0.0
    yy, xx = np.mgrid[y0:y1, x0:x1]
    disc = (xx - x) ** 2 + (yy - y) ** 2 <= r * r
    paper = float(np.percentile(patch[~disc] if (~disc).sum() >= 8 else patch, 75))
    return float(np.clip(paper - patch[disc], 0.0, None).sum() / max(paper, 1.0) / (pitch_px * pitch_px))


def _orient_grid(G: np.ndarray, target: Target, grey: np.ndarray, allow_symmetric: bool):
    """Re-order a detected grid to the target's ids. Returns (uv (N, 2), note) or raises
    DetectionError with the reason."""
    rows, cols = target.rows, target.cols
    page = _page_xy(target)
    cands = [C for C in _grid_candidates(G, rows, cols) if _handedness(C.reshape(-1, 2), page) > 0]
    if not cands:
        raise DetectionError("the grid is seen mirrored (printed side away from the camera?)")
    # Asymmetric layouts (acircles with an odd row count) fit a homography in one ordering only.
    if target.kind == "acircles":
        import cv2

        best, best_res = None, np.inf
        for C in cands:
            H, _ = cv2.findHomography(target.points_board_m[:, :2], C.reshape(-1, 2), 0)
            if H is None:
                continue
            ph = np.column_stack([target.points_board_m[:, :2], np.ones(rows * cols)]) @ H.T
            res = np.sqrt(np.mean(np.sum((ph[:, :2] / ph[:, 2:3] - C.reshape(-1, 2)) ** 2, axis=1)))
            if res < best_res:
                best, best_res = C, res
        if not target.is_symmetric:
            return best.reshape(-1, 2), ""
    if target.kind == "checkerboard" and not target.is_symmetric:
        scores = [_colour_score(grey, C) for C in cands]
        k = int(np.argmin(scores))
        if scores[k] > -5.0:
            raise DetectionError(f"cannot tell the board's orientation from its square colours (contrast {-scores[k]:.1f})")
        return cands[k].reshape(-1, 2), ""
    if target.kind == "modified_circles":
        # Ink of the dots at the grid corners the origin could be at; the origin dot has twice
        # the diameter (4x the ink). Each is measured against its own local pitch (perspective).
        origin = (rows - 1) * cols
        sizes = []
        for C in cands:
            P = C.reshape(rows, cols, 2)
            r0, c0 = divmod(origin, cols)
            steps = [np.linalg.norm(P[r0, c0] - P[r0 + dr, c0 + dc]) for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1))
                     if 0 <= r0 + dr < rows and 0 <= c0 + dc < cols]
            sizes.append(_dot_ink(grey, P[r0, c0], float(np.mean(steps))))
        k = int(np.argmax(sizes))
        others = sorted(sizes)[:-1]
        if not others or sizes[k] < 2.0 * max(float(np.median(others)), 1e-3):
            raise DetectionError("the modified circle grid's enlarged origin dot was not found at a grid corner")
        return cands[k].reshape(-1, 2), ""
    # Symmetric pattern: no cue in the image.
    if not allow_symmetric:
        raise DetectionError(
            f"the {target.kind} target {target.rows}x{target.cols} looks the same turned by 180 degrees, so its "
            "point ids would flip between views; use a board with rows + cols odd (checkerboard), a ChArUco or a "
            "modified circle grid, or pass allow_symmetric=True to accept an image-orientation guess")
    k = int(np.argmin([C[0, 0].sum() for C in cands]))
    return cands[k].reshape(-1, 2), "symmetric target: orientation guessed from the image (point 0 nearest top-left)"


def _roi_from_points(uv: np.ndarray, shape, pad_frac: float = 0.35, pad_px: int = 12):
    h, w = shape
    lo = uv.min(0)
    hi = uv.max(0)
    pad = pad_frac * float(np.max(hi - lo)) + pad_px
    x0 = int(max(0, np.floor(lo[0] - pad)))
    y0 = int(max(0, np.floor(lo[1] - pad)))
    x1 = int(min(w, np.ceil(hi[0] + pad) + 1))
    y1 = int(min(h, np.ceil(hi[1] + pad) + 1))
    return x0, y0, x1, y1


def _roi_candidates(grey: np.ndarray, target: Target, max_rois: int = 2):
    """Regions likely to hold a small target: clusters of saddle points (boards of squares) or of
    dark blobs (circle grids), found on the original image."""
    import cv2

    g = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), 1.0)
    if target.kind in ("checkerboard", "charuco"):
        gxx = cv2.Sobel(g, cv2.CV_32F, 2, 0, ksize=3)
        gyy = cv2.Sobel(g, cv2.CV_32F, 0, 2, ksize=3)
        gxy = cv2.Sobel(g, cv2.CV_32F, 1, 1, ksize=3)
        resp = np.maximum(-(gxx * gyy - gxy * gxy), 0)  # saddles have a negative Hessian determinant
    else:
        resp = np.maximum(cv2.Laplacian(g, cv2.CV_32F, ksize=5), 0)  # dark blobs: positive Laplacian
    resp = cv2.GaussianBlur(resp, (0, 0), 1.5)
    hi = float(resp.max())
    if hi <= 0:
        return []
    mask = (resp > 0.15 * hi).astype(np.uint8)
    # Merge responses of one target: close with a kernel a few expected pitches wide.
    k = max(5, int(0.02 * max(grey.shape)))
    mask = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return []
    # Rank by total response inside the component.
    sums = np.bincount(lab.ravel(), weights=resp.ravel(), minlength=n)
    order = [i for i in np.argsort(-sums) if i != 0][:max_rois]
    rois = []
    for i in order:
        x, y, w, h = stats[i, :4]
        if w * h > 0.5 * grey.size:
            continue
        pts = np.array([[x, y], [x + w, y + h]], float)
        # Saddles span the inner corners only: pad by most of that span so the outer squares
        # and the white quiet zone around them are inside the region.
        rois.append(_roi_from_points(pts, grey.shape, pad_frac=0.6, pad_px=8))
    return rois


# ---------------------------------------------------------------------------------------------
# Per-kind raw detectors: return (ids, uv, method, note) on the given (possibly up-scaled) image
# ---------------------------------------------------------------------------------------------
def _subpix_window(pitch_px: float) -> int:
    # Half-window about a third of the pitch: large enough to average noise, small enough not to
    # reach the neighbouring corners (which biases cornerSubPix).
    return int(np.clip(np.floor(pitch_px / 3.0), 2, 11))


# Below this square size (pixels of the original image) the SB detector on the up-scaled region
# is more accurate than classic + cornerSubPix, above it classic is (scripts/bench_detect.py,
# rendered truth, 10 random poses per cell): 25 mm squares on the D455 at 2-5 m (3-8 px): SB x2
# 0.05-0.10 px RMS and always found, classic x2 0.09-0.24 px and lost beyond 3 m; 46 mm squares
# at 9-10 px: classic x2 0.06 px, SB x2 0.2 px with +0.18 px outward bias; 10-40 px squares:
# classic 0.02-0.06 px, SB 0.07-0.2 px.
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


def _sb(grey, target, fast):
    import cv2

    # SB costs seconds on a whole 1080p frame; on the saddle-point regions it costs milliseconds
    # and finds the same corners (the whole frame is the fallback).
    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_NORMALIZE_IMAGE
    h, w = grey.shape
    rois = (_roi_candidates(grey, target) if fast else []) or [(0, 0, w, h)]
    for x0, y0, x1, y1 in rois:
        ok, c = cv2.findChessboardCornersSB(grey[y0:y1, x0:x1], (target.cols, target.rows), flags=flags)
        if ok:
            return np.asarray(c, float).reshape(-1, 2) + [x0, y0]
    return None


def _find_checkerboard(grey, target, method, allow_symmetric, scale=1.0, sb_fallback=True, fast=None):
    """Checkerboard corners on ``grey`` (the original image at ``scale`` 1, or an up-scaled
    region). ``method='auto'``: classic, replaced by SB when the squares are smaller than
    ``SB_BELOW_PITCH_PX`` original pixels, and SB when classic finds nothing and
    ``sb_fallback`` (off on the original image when an up-scaled classic search follows: that
    is more accurate than SB at ~10-12 px squares). ``fast`` (default: on at scale 1) is OpenCV's
    quick rejection of frames without a board."""
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
                    x0, y0, x1, y1 = _roi_from_points(c, grey.shape, pad_frac=0.6, pad_px=4)
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
        c = _sb(grey, target, fast)
        if c is not None:
            found = (c, "sb")
    if found is None:
        return None
    c, m = found
    G = np.asarray(c, float).reshape(target.rows, target.cols, 2)
    uv, note = _orient_grid(G, target, grey, allow_symmetric)
    return np.arange(target.n_points), uv, m, note


def _blob_detector(max_area: float):
    import cv2

    p = cv2.SimpleBlobDetector_Params()
    p.filterByArea = True
    p.minArea = 4.0
    p.maxArea = float(max_area)
    p.filterByCircularity = False
    p.filterByConvexity = True
    p.minConvexity = 0.8
    p.filterByInertia = True
    p.minInertiaRatio = 0.05
    p.minDistBetweenBlobs = 2.0
    return cv2.SimpleBlobDetector_create(p)


def _quads(xy: np.ndarray) -> list:
    """Quadrilaterals (4 vertices each, in hull order) that simplify the convex hull of ``xy`` at
    several tolerances: the hull of a circle grid seen in perspective, with lens distortion or with
    the staggered rows of an asymmetric grid has more than 4 vertices, and which 4 survive depends
    on the tolerance."""
    import cv2

    hull = cv2.convexHull(xy.astype(np.float32)).reshape(-1, 1, 2)
    if len(hull) < 4:
        return []
    peri = cv2.arcLength(hull, True)
    out = []
    for frac in (0.005, 0.01, 0.02, 0.03, 0.05, 0.08, 0.12):
        q = cv2.approxPolyDP(hull, frac * peri, True).reshape(-1, 2).astype(float)
        if len(q) == 4 and not any(np.allclose(q, o) for o in out):
            out.append(q)
    return out


def _grid_from_blobs(blobs_uv: np.ndarray, target: Target) -> np.ndarray | None:
    """Circle-grid points (N, 2) in the target's id order, assembled from blob centres when
    OpenCV's grid search fails (strong perspective close up, lens distortion): a quadrilateral of
    the blobs' hull is matched to one of the page layout's (each turn and mirror), the homography
    they define predicts every point, each takes the nearest blob within 0.4 of the local spacing,
    the homography is refitted on the matches (RANSAC) and this repeats; the result must give every
    point its own blob, predicted to a fifth of the spacing. None otherwise."""
    import cv2

    page = _page_xy(target).astype(np.float64)
    n = len(page)
    if len(blobs_uv) < n or len(blobs_uv) > 4 * n:
        return None
    d_bb = np.linalg.norm(blobs_uv[:, None] - blobs_uv[None], axis=-1)
    np.fill_diagonal(d_bb, np.inf)
    spacing = d_bb.min(axis=1)  # each blob's nearest-neighbour distance
    page_h = page.reshape(-1, 1, 2)
    # The page's hull is small and exact (4 vertices, 6 for an asymmetric grid): every 4 of its
    # vertices, in hull order, is a candidate for the image quadrilateral's corners.
    hull_page = cv2.convexHull(page.astype(np.float32)).reshape(-1, 2).astype(float)
    page_quads = [hull_page[list(c)] for c in itertools.combinations(range(len(hull_page)), 4)] if len(hull_page) <= 8 \
        else _quads(page)
    for q_page in page_quads:
        for q_img in _quads(blobs_uv):
            for order in (q_img, q_img[::-1]):
                for k in range(4):
                    H = cv2.getPerspectiveTransform(q_page.astype(np.float32), np.roll(order, k, axis=0).astype(np.float32))
                    nearest, ok = None, None
                    for _ in range(4):
                        pred = cv2.perspectiveTransform(page_h, H).reshape(-1, 2)
                        d = np.linalg.norm(pred[:, None] - blobs_uv[None], axis=-1)
                        nearest = d.argmin(axis=1)
                        ok = d[np.arange(n), nearest] < 0.4 * spacing[nearest]
                        if ok.sum() < 6:
                            break
                        H, _ = cv2.findHomography(page[ok], blobs_uv[nearest[ok]], cv2.RANSAC,
                                                  0.25 * float(np.median(spacing)))
                        if H is None:
                            break
                    if H is None or ok is None or ok.sum() < max(6, n // 2):
                        continue
                    found = _grow_grid(page, blobs_uv, spacing, nearest, ok)
                    if found is not None:
                        return found
    return None


def _grow_grid(page: np.ndarray, blobs_uv: np.ndarray, spacing: np.ndarray, nearest: np.ndarray, ok: np.ndarray):
    """Extend a partial match (page point i -> blob ``nearest[i]`` where ``ok[i]``) to every point,
    predicting each unmatched point by an affine map fitted to its 6 nearest matched page
    neighbours (a lens bends a grid too much for one homography, not locally); then check every
    point the same way against its neighbours (leave-one-out, within 0.2 of the spacing). The blob
    centres in page order, or None."""
    n = len(page)
    nearest, ok = nearest.copy(), ok.copy()
    d_pp = np.linalg.norm(page[:, None] - page[None], axis=-1)

    def predict(i, mask):
        nb = [j for j in np.argsort(d_pp[i]) if j != i and mask[j]][:6]
        if len(nb) < 3:
            return None
        A = np.column_stack([page[nb], np.ones(len(nb))])
        M, *_ = np.linalg.lstsq(A, blobs_uv[nearest[nb]], rcond=None)
        return np.array([page[i, 0], page[i, 1], 1.0]) @ M

    for _ in range(n):
        changed = False
        for i in np.nonzero(~ok)[0]:
            p = predict(i, ok)
            if p is None:
                continue
            d = np.linalg.norm(blobs_uv - p, axis=1)
            j = int(d.argmin())
            if d[j] < 0.4 * spacing[j] and j not in set(nearest[ok].tolist()):
                nearest[i], ok[i], changed = j, True, True
        if ok.all() or not changed:
            break
    if not ok.all() or len(set(nearest.tolist())) != n:
        return None
    for i in range(n):
        p = predict(i, np.arange(n) != i)
        if p is None or np.linalg.norm(p - blobs_uv[nearest[i]]) > 0.2 * spacing[nearest[i]]:
            return None
    return blobs_uv[nearest]


def _find_circles(grey, target, method, allow_symmetric):
    import cv2

    det = _blob_detector(0.25 * grey.size / max(1, target.n_points) + 1e4)
    if target.kind == "acircles":
        flags = cv2.CALIB_CB_ASYMMETRIC_GRID
        patterns = [(target.cols, target.rows)]
    else:
        flags = cv2.CALIB_CB_SYMMETRIC_GRID
        patterns = [(target.cols, target.rows)] + ([(target.rows, target.cols)] if target.rows != target.cols else [])
    # OpenCV's grid search depends on the grid's direction in the image: a close, tilted (and
    # distorted) board it misses is often found in the image turned by 90 or 180 degrees (exact
    # turns, no resampling), so those are tried before giving up.
    H, W = grey.shape[:2]
    turns = ((None, lambda c: c),
             (cv2.ROTATE_90_CLOCKWISE, lambda c: np.column_stack([c[:, 1], H - 1 - c[:, 0]])),
             (cv2.ROTATE_180, lambda c: np.column_stack([W - 1 - c[:, 0], H - 1 - c[:, 1]])),
             (cv2.ROTATE_90_COUNTERCLOCKWISE, lambda c: np.column_stack([W - 1 - c[:, 1], c[:, 0]])))
    for turn, back in turns:
        img = grey if turn is None else cv2.rotate(grey, turn)
        for pat in patterns:
            ok, c = cv2.findCirclesGrid(img, pat, flags=flags, blobDetector=det)
            if not ok or c is None:
                ok, c = cv2.findCirclesGrid(img, pat, flags=flags | cv2.CALIB_CB_CLUSTERING, blobDetector=det)
            if ok and c is not None:
                G = back(np.asarray(c, float).reshape(-1, 2)).reshape(pat[1], pat[0], 2)
                uv, note = _orient_grid(G, target, grey, allow_symmetric)
                return np.arange(target.n_points), uv, "circles", note
    pts = np.array([k.pt for k in det.detect(grey)], float).reshape(-1, 2)
    uv = _grid_from_blobs(pts, target)
    if uv is not None:
        G = uv.reshape(target.rows, target.cols, 2)
        uv, note = _orient_grid(G, target, grey, allow_symmetric)
        return np.arange(target.n_points), uv, "circles", note
    return None


def _find_charuco(grey, target, intr: Intrinsics | None, scale: float = 1.0):
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


# ---------------------------------------------------------------------------------------------
# Quality
# ---------------------------------------------------------------------------------------------
def _edge_sigma_px(grey: np.ndarray, uv: np.ndarray, pitch_px: float) -> float:
    """Median edge blur near the points, as the sigma of a Gaussian-blurred step:
    sigma = contrast / (sqrt(2 pi) * max gradient)."""
    import cv2

    if uv.size == 0:
        return float("nan")
    r = int(np.clip(0.4 * pitch_px, 3, 15))
    # Work on the points' bounding box only (gradients of a whole 1080p frame cost ~20 ms).
    x0, y0 = np.maximum(np.floor(uv.min(0)).astype(int) - r - 2, 0)
    x1, y1 = np.ceil(uv.max(0)).astype(int) + r + 3
    grey = grey[y0:y1, x0:x1]
    uv = uv - [x0, y0]
    h, w = grey.shape
    g = grey.astype(np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    mag = np.hypot(gx, gy)
    out = []
    for u, v in uv[:: max(1, len(uv) // 24)]:
        x, y = int(round(u)), int(round(v))
        if x - r < 0 or y - r < 0 or x + r + 1 > w or y + r + 1 > h:
            continue
        patch = g[y - r : y + r + 1, x - r : x + r + 1]
        c = np.percentile(patch, 95) - np.percentile(patch, 5)
        gm = mag[y - r : y + r + 1, x - r : x + r + 1].max()
        if gm > 1e-3 and c > 10:
            out.append(c / (np.sqrt(2 * np.pi) * gm))
    return float(np.median(out)) if out else float("nan")


def _hull_area(uv: np.ndarray) -> float:
    import cv2

    if len(uv) < 3:
        return 0.0
    return float(cv2.contourArea(cv2.convexHull(uv.astype(np.float32))))


# ---------------------------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------------------------
def detect_image(image, target: Target, intrinsics: Intrinsics | None = None, upscale="auto", method: str = "auto",
                 allow_symmetric: bool = False, filter: bool = True, min_pitch_px: float = 12.0,
                 min_points: int = 4, source: str | None = None, refine: bool = True,
                 region_px: tuple | None = None) -> ImageDetection:
    """Detect ``target`` in one image.

    Args:
        image: a path or an image array (grey/colour, 8/16-bit or float in [0, 1]).
        target: the target spec.
        intrinsics: camera intrinsics; used to undistort points for the filter and to help ChArUco.
        upscale: ``"auto"`` (up-scale the region of interest x2, then x3, when the target is not
            found or its pitch is below ``min_pitch_px``), ``1``/``"off"`` (never), or an int ``k``
            (always detect on the region up-scaled by ``k``).
        method: checkerboard detector, ``"classic"`` (findChessboardCorners + cornerSubPix),
            ``"sb"`` (findChessboardCornersSB, accuracy flag) or ``"auto"`` (default: classic, but SB
            for squares under ``SB_BELOW_PITCH_PX`` original pixels or when classic finds nothing).
        allow_symmetric: accept symmetric targets with an orientation guessed from the image.
        filter: run the grid filter (thesis Algorithm 3 + homography check).
        min_pitch_px: below this grid pitch ``"auto"`` also tries the up-scaled region.
        min_points: fewer points than this is a failed detection (partial ChArUco views).
        source: file name for messages when ``image`` is an array.
        refine: checkerboards and ChArUco: refine every corner by the photometric board fit of
            :mod:`calibgraph.detect.board_fit` on the original image (removes the detectors'
            bias; ``False`` keeps OpenCV's corners).
        region_px: (x0, y0, x1, y1) where the board is expected (guided detection,
            :mod:`calibgraph.detect.guided`): only that region is searched, like a candidate region
            of the blind search (no quick whole-frame rejection), at full resolution and, with
            ``upscale="auto"``, up-scaled when its squares are small.
    Returns:
        :class:`ImageDetection`; never raises for a bad image: ``ok=False`` and ``reason`` say why.
    """
    t0 = time.perf_counter()
    src = str(image) if isinstance(image, (str, Path)) else source
    try:
        grey = read_grey(image) if isinstance(image, (str, Path)) else to_grey8(image, src or "image")
    except DetectionError as e:
        return _failed(str(e), target, src, t0)
    s = _Search(grey=grey, target=target, intrinsics=intrinsics, method=method, upscale=_check_options(method, upscale),
                allow_symmetric=allow_symmetric, filter=filter, min_pitch_px=min_pitch_px, min_points=min_points,
                refine=refine, src=src, t0=t0)
    if region_px is not None:
        best = _search_region(s, tuple(int(v) for v in region_px))
        return best if best is not None else _not_found(s)
    native = _attempt(s, _raw_detect, s, grey, 1.0) if s.upscale in ("auto", 1) else None
    first = _finish(s, native, 1) if native is not None else None
    if s.upscale == 1 or (first is not None and first.ok and first.pitch_px >= min_pitch_px):
        best = first
    else:
        if native is None and s.upscale != "auto":
            native = _attempt(s, _raw_detect, s, grey, 1.0)  # its points give the region to up-scale
        rois, first = _upscale_regions(s, native, first)
        best = _search_upscaled(s, rois, first)
    return best if best is not None else _not_found(s)


@dataclass
class _Search:
    """One :func:`detect_image` call: its image, options and the reasons of failed attempts."""

    grey: np.ndarray
    target: Target
    intrinsics: Intrinsics | None
    method: str
    upscale: object
    allow_symmetric: bool
    filter: bool
    min_pitch_px: float
    min_points: int
    refine: bool
    src: str | None
    t0: float
    attempts: list = field(default_factory=list)


def _check_options(method: str, upscale):
    """Validate ``method`` and ``upscale``; returns ``upscale`` as ``"auto"`` or an int."""
    if method not in ("classic", "sb", "auto"):
        raise InputError(f"detect: method must be 'classic', 'sb' or 'auto', got {method!r}.")
    if upscale in ("off", None, False):
        upscale = 1
    if upscale != "auto" and int(upscale) not in (1, 2, 3, 4):
        raise InputError(f"detect: upscale must be 'auto', 1, 2, 3 or 4, got {upscale!r}.")
    return upscale


def _raw_detect(s: _Search, img: np.ndarray, scale: float, fast=None):
    """Raw detection on ``img`` (the original image or an up-scaled region): (ids, uv, method,
    note) or None; DetectionError for orientation problems. ``fast=True`` is a quick probe:
    OpenCV's fast check, no SB."""
    target = s.target
    if target.kind == "checkerboard":
        return _find_checkerboard(img, target, s.method, s.allow_symmetric, scale=scale,
                                  sb_fallback=(scale > 1 or s.upscale == 1) and not fast, fast=fast)
    if target.kind == "charuco":
        r, _ = _find_charuco(img, target, s.intrinsics, scale)
        return r
    return _find_circles(img, target, s.method, s.allow_symmetric)


def _detect_in_roi(s: _Search, roi, k: int, fast=None):
    """Raw detection in region ``roi`` (x0, y0, x1, y1) up-scaled by ``k``, mapped back to
    original pixels."""
    import cv2

    x0, y0, x1, y1 = roi
    crop = s.grey[y0:y1, x0:x1]
    if crop.shape[0] < 8 or crop.shape[1] < 8:
        return None
    big = crop if k == 1 else cv2.resize(crop, None, fx=k, fy=k, interpolation=cv2.INTER_CUBIC)
    r = _raw_detect(s, big, float(k), fast=(False if k == 1 else None) if fast is None else fast)
    if r is None:
        return None
    ids, uv, m, note = r
    # cv2.resize: destination pixel X samples source (X + 0.5) / k - 0.5.
    uv = (uv + 0.5) / k - 0.5 + np.array([x0, y0], float)
    return ids, uv, m, note


def _attempt(s: _Search, fn, *a):
    """``fn(*a)``, or None with the reason kept for the final message when it raises."""
    try:
        return fn(*a)
    except DetectionError as e:
        s.attempts.append(str(e))
        return None


def _finish(s: _Search, result, k: int) -> ImageDetection:
    """A raw detection (from an image up-scaled by ``k``) refined, filtered and measured."""
    ids, uv, m, note = result
    target, grey = s.target, s.grey
    n_refined = 0
    if s.refine and target.kind == "checkerboard" and ids.size:
        # On the original pixels whatever the search scale: interpolation adds its own shift.
        fit = refine_checkerboard(grey, target, ids, uv)
        uv, n_refined = fit.uv_px, int(fit.refined.sum())
    elif s.refine and target.kind == "charuco" and ids.size >= 4:
        blur_px = _edge_sigma_px(grey, uv, max(_pitch(ids, uv, target), 4.0))
        fit = refine_charuco(grey, target, ids, uv, blur_px=blur_px)
        uv, n_refined = fit.uv_px, int(fit.refined.sum())
    ok, reason = True, note
    if ids.size < s.min_points:
        ok, reason = False, f"only {ids.size} points found (minimum {s.min_points})"
    pitch = _pitch(ids, uv, target) if ids.size >= 2 else 0.0
    h_rms = float("nan")
    if ok and s.filter:
        fr = check_grid(uv, target.line_ij[ids], target.points_board_m[ids], intrinsics=s.intrinsics)
        h_rms = fr.homography_rms_px
        if not fr.ok:
            ok, reason = False, f"rejected by the grid filter{'' if k == 1 else f' (x{k} up-scaled)'}: {fr.reason}"
    area = _hull_area(uv)
    return ImageDetection(
        ids=ids, uv_px=uv, ok=ok, reason=reason, n_expected=target.n_points, size_px=float(np.sqrt(area)),
        spread=area / float(grey.size), pitch_px=pitch, sharpness_px=_edge_sigma_px(grey, uv, max(pitch, 4.0)),
        upscale=k, method=m, homography_rms_px=h_rms, n_refined=n_refined, time_s=time.perf_counter() - s.t0,
        image=s.src)


def _upscale_regions(s: _Search, native, first):
    """Regions to search up-scaled: around the native detection, else saddle/blob clusters of a
    plausible size. Returns (regions, first detection), the latter possibly found here on a
    board touching the arm (see below)."""
    grey, target = s.grey, s.target
    if native is not None and len(native[1]):
        return [_roi_from_points(native[1], grey.shape)], first
    # Up-scaling helps small boards only: skip regions whose size implies squares of more
    # than 2x min_pitch_px (a miss there has another cause, e.g. a wrong target spec, and
    # searching them up-scaled costs seconds). Regions are padded by 60 % + 8 px per side.
    n_steps = max(target.rows, target.cols) + 1
    cands = _roi_candidates(grey, target)
    rois = [r for r in cands if (max(r[2] - r[0], r[3] - r[1]) - 16) / 2.2 / n_steps < 2 * s.min_pitch_px]
    if first is None and target.kind == "checkerboard":
        # A board on the flange touches the arm, whose shading also answers the saddle
        # filter: its region then looks too big for a small board, and OpenCV's fast check
        # on the whole frame rejects boards of ~10-12 px squares. Search such regions
        # up-scaled x2 with the fast check (a miss costs ~0.1 s where a search without it
        # costs seconds), then redo the found board at full resolution in a tight region.
        for roi in (r for r in cands if r not in rois):
            got = _attempt(s, _detect_in_roi, s, roi, 2, True)
            if got is None:
                continue
            tight = _roi_from_points(got[1], grey.shape)
            nat = _attempt(s, _detect_in_roi, s, tight, 1)
            first = _finish(s, nat, 1) if nat is not None else _finish(s, got, 2)
            rois = [] if first.ok and first.pitch_px >= s.min_pitch_px else [tight]
            break
    return rois, first


def _search_upscaled(s: _Search, rois, first):
    """Search ``rois`` up-scaled (x2 then x3 for ``"auto"``); the first accepted detection wins,
    else the best so far (``first``, or the first rejected one for its reason)."""
    factors = (2, 3) if s.upscale == "auto" else (int(s.upscale),)
    best = first
    for k in factors:
        for roi in rois:
            got = _attempt(s, _detect_in_roi, s, roi, k)
            if got is None:
                continue
            det = _finish(s, got, k)
            if det.ok:
                best = det
                break
            if best is None:
                best = det
        if best is not None and best.ok and best.upscale > 1:
            break
    return best


def _search_region(s: _Search, roi) -> ImageDetection | None:
    """Guided search of one region, as the blind search treats a candidate region: full
    resolution, then (``upscale="auto"``) x2 and x3 while the squares are under ``min_pitch_px``;
    the first passing detection, else the best failure. Before the up-scaled full searches, a
    quick probe (OpenCV's fast check at x2 and x3, no SB) must see a board: where the estimate
    expected one but none is (occluded, out of focus), a miss costs ~0.1 s instead of seconds."""
    if s.upscale != "auto":
        got = _attempt(s, _detect_in_roi, s, roi, int(s.upscale), False)
        return _finish(s, got, int(s.upscale)) if got is not None else None
    got = _attempt(s, _detect_in_roi, s, roi, 1, False)
    best = _finish(s, got, 1) if got is not None else None
    if best is not None and best.ok and best.pitch_px >= s.min_pitch_px:
        return best
    if best is None and all(_attempt(s, _detect_in_roi, s, roi, k, True) is None for k in (2, 3)):
        return None
    for k in (2, 3):
        got = _attempt(s, _detect_in_roi, s, roi, k, False)
        if got is None:
            continue
        det = _finish(s, got, k)
        if det.ok:
            return det
        if best is None:
            best = det
    return best


def _not_found(s: _Search) -> ImageDetection:
    """The failed detection, with the reasons met on the way (or advice when there were none)."""
    t = s.target
    why = "; ".join(dict.fromkeys(s.attempts)) if s.attempts else (
        f"no {t.kind} with {t.rows}x{t.cols} points found; check the target spec matches the board "
        "and that the whole board is in view and in focus")
    return _failed(why, t, s.src, s.t0)


def _pitch(ids: np.ndarray, uv: np.ndarray, target: Target) -> float:
    """Median image distance between neighbours one pitch apart along a row/column, pixels."""
    return grid_pitch_px(uv, target.line_ij[ids])


# ---------------------------------------------------------------------------------------------
# Dataset detection (parallel, cached)
# ---------------------------------------------------------------------------------------------
def cache_path(dataset, cache_dir=None, **options) -> Path:
    """Cache file of a dataset's detections for a target spec, detector version and options
    (in ``DATASET/.calibgraph_cache/`` unless ``cache_dir`` is given)."""
    import hashlib

    key = json.dumps({"target": dataset.target.to_dict(), "version": DETECTOR_VERSION, "options": options},
                     sort_keys=True, default=str)
    h = hashlib.sha1(key.encode()).hexdigest()[:12]
    base = Path(cache_dir) if cache_dir is not None else Path(dataset.root) / ".calibgraph_cache"
    return base / f"detections-{h}.json"


@dataclass
class DatasetDetector:
    """Callable ``(view, dataset) -> (ids, uv_px) | None`` for ``Dataset.to_problem(detector=...)``.

    On its first call it detects every view of the dataset that has an image and no stored
    detection (in parallel, with a progress bar), caches the results in
    ``DATASET/.calibgraph_cache/detections-<hash>.json`` (keyed by image path, size and
    modification time) and then answers from memory.

    Attributes:
        views: optional set of (camera, capture) to detect (default: every undetected view).
        detect_view: optional ``(view, path, intrinsics) -> ImageDetection`` used instead of
            :func:`detect_image` (guided detection, :mod:`calibgraph.detect.guided`); its results
            are cached under ``cache_tag`` so they never stand in for an unguided run's.
        results: (camera, capture) -> :class:`ImageDetection`.
        problems: (file, message) for every image that could not be used; the CLI prints them.
    """

    dataset: object
    workers: int = 2
    progress: bool = True
    options: dict = field(default_factory=dict)
    cache: object = True
    views: object = None
    detect_view: object = None
    cache_tag: str = ""
    results: dict = field(default_factory=dict)
    problems: list = field(default_factory=list)
    _done: bool = False

    def run(self) -> dict:
        """Detect all undetected views now (idempotent); returns ``results``."""
        if self._done:
            return self.results
        from concurrent.futures import ThreadPoolExecutor

        ds = self.dataset
        root = Path(ds.root)
        use_cache = self.cache is not False and self.cache is not None
        key_opts = dict(self.options, **({"guided": self.cache_tag} if self.cache_tag else {}))
        cpath = cache_path(ds, None if self.cache is True else self.cache, **key_opts) if use_cache else None
        cache = {}
        if use_cache and cpath.is_file():
            try:
                cache = json.loads(cpath.read_text()).get("entries", {})
            except (OSError, ValueError):
                cache = {}  # a damaged cache is only a lost speed-up
        todo, keys = [], {}
        wanted = None if self.views is None else set(self.views)
        for v in ds.views:
            if v.detected or (wanted is not None and (v.camera, v.capture) not in wanted):
                continue
            if not v.image:
                self.problems.append((f"camera {v.camera}, capture {v.capture}", "no image and no detection; skipped"))
                continue
            p = root / v.image
            try:
                st = p.stat()
                stamp = f"{st.st_size}:{int(st.st_mtime_ns)}"
            except OSError:
                stamp = "missing"
            key = v.image
            keys[(v.camera, v.capture)] = (key, stamp)
            hit = cache.get(key)
            if hit is not None and hit.get("stamp") == stamp and stamp != "missing":
                self.results[(v.camera, v.capture)] = ImageDetection.from_dict(hit["detection"])
            else:
                todo.append(v)

        def work(v):
            import cv2

            cv2.setNumThreads(1)  # parallelism comes from the pool; avoid oversubscription
            intr = ds.cameras.get(v.camera)
            try:
                if self.detect_view is not None:
                    return v, self.detect_view(v, root / v.image, intr)
                return v, detect_image(root / v.image, ds.target, intrinsics=intr, **self.options)
            except (cv2.error, ValueError, MemoryError) as e:
                # One odd image must not stop the run: record it and carry on with the rest.
                return v, _failed(f"detector failed on this image ({type(e).__name__}: {str(e).strip()[:200]})",
                                  ds.target, str(root / v.image))

        if todo:
            bar = None
            if self.progress:
                from tqdm import tqdm

                bar = tqdm(total=len(todo), desc="detect", unit="img", leave=False)
            with ThreadPoolExecutor(max_workers=max(1, int(self.workers))) as ex:
                for v, det in ex.map(work, todo):
                    self.results[(v.camera, v.capture)] = det
                    if bar is not None:
                        bar.update(1)
            if bar is not None:
                bar.close()
        if todo and use_cache:
            entries = dict(cache)
            for (cam, cap), det in self.results.items():
                k, stamp = keys.get((cam, cap), (None, None))
                if k is not None and stamp != "missing":
                    entries[k] = {"stamp": stamp, "detection": det.to_dict()}
            try:
                atomic_write_text(cpath, json.dumps({"version": DETECTOR_VERSION, "target": ds.target.to_dict(),
                                                     "options": {k: str(v) for k, v in key_opts.items()},
                                                     "entries": entries}))
            except InputError as e:
                self.problems.append((str(cpath), f"cannot write the detection cache ({e}); continuing without"))
        for (cam, cap), det in sorted(self.results.items(), key=lambda kv: (kv[0][0], kv[0][1])):
            if not det.ok:
                self.problems.append((det.image or f"camera {cam}, capture {cap}", det.reason))
        # A target that is found nowhere is most likely the wrong spec: say so once.
        if self.results and not any(d.ok for d in self.results.values()) and self.detect_view is None:
            t = ds.target
            self.problems.append((str(root), f"the target ({t.kind}, {t.rows}x{t.cols} points, pitch {t.pitch_m} m) was "
                                  "not found in any image: check the target spec in dataset.yaml"))
        self._done = True
        return self.results

    def __call__(self, view, dataset=None):
        self.run()
        if view.detected:
            return view.ids, view.uv_px
        det = self.results.get((view.camera, view.capture))
        if det is None or not det.ok:
            return None
        return det.ids, det.uv_px


def dataset_detector(dataset, workers: int = 2, progress: bool = True, cache=True, views=None, detect_view=None,
                     cache_tag: str = "", **options) -> DatasetDetector:
    """A detector for ``Dataset.to_problem(detector=...)`` that detects all undetected views of
    ``dataset`` in parallel (``workers`` threads; OpenCV releases the GIL), shows a tqdm progress
    bar, caches results next to the data and collects per-file problems in ``.problems``.
    ``cache``: True (``DATASET/.calibgraph_cache/``), False (no cache) or a folder.
    ``options`` are passed to :func:`detect_image` (e.g. ``upscale=1``, ``method="sb"``); ``views``,
    ``detect_view`` and ``cache_tag`` as in :class:`DatasetDetector`."""
    return DatasetDetector(dataset=dataset, workers=workers, progress=progress, options=dict(options), cache=cache,
                           views=views, detect_view=detect_view, cache_tag=cache_tag)
