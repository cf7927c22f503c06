"""Circle grids (symmetric, asymmetric, modified): OpenCV's grid search, then a grid assembled
from blob centres when it fails; with a permissive blob detector, then OpenCV's default one, until
a grid passes the caller's check (the grid filter).

``cv2.findCirclesGrid`` is tried on the image and on the image turned by 90 and 180 degrees; when
all fail, the grid is assembled from the blob centres (hull quadrilateral -> homography -> grown by
local affine maps, for close, tilted, distorted views). The modified circle grid is found as a
symmetric grid and oriented by its enlarged origin dot (:mod:`calibgraph.detect.orient`).
"""

from __future__ import annotations

import itertools

import numpy as np

from calibgraph.core.errors import DetectionError
from calibgraph.core.targets import Target
from calibgraph.detect.orient import orient_grid, page_xy


def blob_detector(max_area: float):
    """The permissive blob detector (small, tilted, blurred dots) with an area ceiling."""
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

    page = page_xy(target).astype(np.float64)
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


def _default_blob_detector(max_area: float):
    """OpenCV's default blob detector (``findCirclesGrid``'s own when none is given), with the
    same area ceiling: rounder, larger blobs only, so the letters and marks printed beside a
    grid do not enter it (the permissive detector's small blobs can pull a grid point off its
    dot or give two points one blob)."""
    import cv2

    p = cv2.SimpleBlobDetector_Params()
    p.maxArea = max(float(max_area), p.maxArea)
    return cv2.SimpleBlobDetector_create(p)


# Image noise (grey levels, one sigma) above which the blob detectors look at the image smoothed by
# SMOOTH_SIGMA_PX: on a noisy frame the permissive detector's 4-pixel blobs are mostly noise (2195 of
# them on a rendered 1920x1200 frame at noise 6, where the grid has 77 dots), each costs its contour
# at every threshold, and OpenCV's grid search on thousands of points runs for minutes. A Gaussian
# blur of a pixel keeps a dot's centre (it is symmetric) and removes the noise blobs.
NOISY_SIGMA = 3.0
SMOOTH_SIGMA_PX = 1.0
# At most this many blobs per grid point go to the grid searches (the largest): more are flecks and
# texture, and OpenCV's grid search slows with their number (the assembled grid refuses more anyway).
MAX_BLOBS_PER_POINT = 4


def noise_sigma(grey: np.ndarray) -> float:
    """Robust estimate of the image noise, grey levels: the median absolute response of the
    Laplacian-of-differences mask [[1, -2, 1], [-2, 4, -2], [1, -2, 1]] (which cancels planar shading)
    over every other row, scaled to a Gaussian's sigma; edges are too few to move the median."""
    import cv2

    k = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    r = cv2.filter2D(grey[::2].astype(np.float32), -1, k, borderType=cv2.BORDER_REPLICATE)[1:-1, 1:-1]
    return float(np.median(np.abs(r))) / (0.6745 * 6.0) if r.size else 0.0


def blob_image(grey: np.ndarray) -> np.ndarray:
    """The image the blob detectors look at: ``grey``, smoothed when it is noisy (``NOISY_SIGMA``)."""
    import cv2

    return cv2.GaussianBlur(grey, (0, 0), SMOOTH_SIGMA_PX) if noise_sigma(grey) > NOISY_SIGMA else grey


def _blobs(img: np.ndarray, det, n_points: int) -> tuple:
    """(centres (N, 2) of the blobs ``det`` finds in ``img`` in the detector's order, whether they
    were capped): only the ``MAX_BLOBS_PER_POINT * n_points`` largest when there are more (in the
    same order)."""
    kp = det.detect(img)
    pts = np.array([k.pt for k in kp], float).reshape(-1, 2)
    cap = MAX_BLOBS_PER_POINT * n_points
    if len(pts) <= cap:
        return pts, False
    size = np.array([k.size for k in kp], float)
    return pts[np.sort(np.argsort(-size, kind="stable")[:cap])], True


def _point_detector():
    """The blob detector of :func:`_grid_of_points`'s drawn discs: one threshold, no filters."""
    import cv2

    p = cv2.SimpleBlobDetector_Params()
    p.minThreshold, p.maxThreshold, p.thresholdStep = 127.0, 128.0, 10.0
    p.minRepeatability = 1
    p.minDistBetweenBlobs = 0.5
    p.filterByColor, p.blobColor = True, 0
    p.filterByArea, p.minArea, p.maxArea = True, 1.0, 1e9
    p.filterByCircularity = p.filterByConvexity = p.filterByInertia = False
    return cv2.SimpleBlobDetector_create(p)


def _grid_of_points(pts: np.ndarray, pattern: tuple, flags: int):
    """OpenCV's grid search (``findCirclesGrid``) on a set of points instead of an image: it reads
    only the blob centres of the image it is given, so the points are drawn as small discs on a
    blank canvas (each narrower than its distance to the nearest other point), found again by a
    one-threshold detector, and the grid found is snapped back to the exact points. The blobs of the
    image are then detected once, not at every call (each turn of the image, each pattern, with and
    without clustering: up to 16 detections). (rows, cols, 2) in OpenCV's order, or None."""
    import cv2

    if len(pts) < pattern[0] * pattern[1]:
        return None
    lo = np.floor(pts.min(axis=0)) - 8
    q = pts - lo
    d = np.linalg.norm(q[:, None] - q[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    rad = np.clip(0.3 * d.min(axis=1), 0.8, 6.0)
    w, h = (np.ceil(q.max(axis=0)) + 9).astype(int)
    canvas = np.full((h, w), 255, np.uint8)
    shift = 4
    for (x, y), r in zip(q, rad):
        cv2.circle(canvas, (int(round(x * 2**shift)), int(round(y * 2**shift))), int(round(r * 2**shift)), 0, -1,
                   cv2.LINE_AA, shift)
    ok, c = cv2.findCirclesGrid(canvas, pattern, flags=flags, blobDetector=_point_detector())
    if not ok or c is None:
        return None
    c = np.asarray(c, float).reshape(-1, 2)
    dist = np.linalg.norm(c[:, None] - q[None], axis=-1)
    near = dist.argmin(axis=1)
    if np.any(dist[np.arange(len(c)), near] > 0.5) or len(set(near.tolist())) != len(c):
        return None
    return pts[near].reshape(pattern[1], pattern[0], 2)


def _grids(grey, target, det):
    """Candidate grids (rows*cols, 2), OpenCV's order, from one blob detector: OpenCV's grid
    search on the image turned by 0, 90, 180 and 270 degrees, then the grid assembled from the
    blob centres. The blobs are detected once first: fewer than the grid's dots end the search. On a
    noisy or cluttered image (smoothed by :func:`blob_image`, or more than ``MAX_BLOBS_PER_POINT``
    blobs a dot) OpenCV's search runs on the blobs kept (:func:`_grid_of_points`), not on the image."""
    import cv2

    if target.kind == "acircles":
        flags = cv2.CALIB_CB_ASYMMETRIC_GRID
        patterns = [(target.cols, target.rows)]
    else:
        flags = cv2.CALIB_CB_SYMMETRIC_GRID
        patterns = [(target.cols, target.rows)] + ([(target.rows, target.cols)] if target.rows != target.cols else [])
    img = blob_image(grey)
    pts, capped = _blobs(img, det, target.n_points)
    if len(pts) < target.n_points:
        return
    on_points = capped or img is not grey
    # OpenCV's grid search depends on the grid's direction in the image: a close, tilted (and
    # distorted) board it misses is often found in the image turned by 90 or 180 degrees (exact
    # turns, no resampling; the points turned alike), so those are tried before giving up.
    H, W = grey.shape[:2]
    turns = ((None, lambda c: c, lambda c: c),
             (cv2.ROTATE_90_CLOCKWISE, lambda c: np.column_stack([H - 1 - c[:, 1], c[:, 0]]),
              lambda c: np.column_stack([c[:, 1], H - 1 - c[:, 0]])),
             (cv2.ROTATE_180, lambda c: np.column_stack([W - 1 - c[:, 0], H - 1 - c[:, 1]]),
              lambda c: np.column_stack([W - 1 - c[:, 0], H - 1 - c[:, 1]])),
             (cv2.ROTATE_90_COUNTERCLOCKWISE, lambda c: np.column_stack([c[:, 1], W - 1 - c[:, 0]]),
              lambda c: np.column_stack([W - 1 - c[:, 1], c[:, 0]])))
    for turn, there, back in turns:
        if on_points:
            turned = there(pts)
            search = lambda pat, fl: _grid_of_points(turned, pat, fl)  # noqa: E731
        else:
            image = grey if turn is None else cv2.rotate(grey, turn)
            search = lambda pat, fl: _grid_of_image(image, pat, fl, det)  # noqa: E731
        for pat in patterns:
            G = search(pat, flags)
            if G is None:
                G = search(pat, flags | cv2.CALIB_CB_CLUSTERING)
            if G is not None:
                yield back(G.reshape(-1, 2)).reshape(pat[1], pat[0], 2)
    uv = _grid_from_blobs(pts, target)
    if uv is not None:
        yield uv.reshape(target.rows, target.cols, 2)


def _grid_of_image(img, pattern, flags, det):
    """OpenCV's grid search on an image with blob detector ``det``: (rows, cols, 2) or None."""
    import cv2

    ok, c = cv2.findCirclesGrid(img, pattern, flags=flags, blobDetector=det)
    if not ok or c is None:
        return None
    return np.asarray(c, float).reshape(pattern[1], pattern[0], 2)


def find_circles(grey, target, method, allow_symmetric, accept=None):
    """Circle-grid points on ``grey``: (ids, uv, "circles", note), or None.

    The blobs come first from a permissive detector (small, tilted, blurred dots), then from
    OpenCV's default one. ``accept(ids, uv)``, when given (the search passes the grid filter),
    judges each grid found: one it refuses, or one that cannot be oriented, does not end the
    search; the next grid (another turn, the assembled grid, the other blob detector) is tried.
    On a real wrist-camera set the permissive detector's blobs of the printed text pulled a point
    of 4 of 15 grids off its dot or doubled it (scripts/results/bench_real_detection.md). When no
    grid is accepted, the first refused one is returned (for its reason), else the first
    orientation error is raised."""
    max_area = 0.25 * grey.size / max(1, target.n_points) + 1e4
    refused, error = None, None
    for det in (blob_detector(max_area), _default_blob_detector(max_area)):
        for G in _grids(grey, target, det):
            try:
                uv, note = orient_grid(G, target, grey, allow_symmetric)
            except DetectionError as e:
                error = error or e
                continue
            found = (np.arange(target.n_points), uv, "circles", note)
            if accept is None or accept(found[0], found[1]):
                return found
            refused = refused or found
    if refused is not None:
        return refused
    if error is not None:
        raise error
    return None
