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


def _grids(grey, target, det):
    """Candidate grids (rows*cols, 2), OpenCV's order, from one blob detector: OpenCV's grid
    search on the image turned by 0, 90, 180 and 270 degrees, then the grid assembled from the
    blob centres."""
    import cv2

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
                yield back(np.asarray(c, float).reshape(-1, 2)).reshape(pat[1], pat[0], 2)
    pts = np.array([k.pt for k in det.detect(grey)], float).reshape(-1, 2)
    uv = _grid_from_blobs(pts, target)
    if uv is not None:
        yield uv.reshape(target.rows, target.cols, 2)


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
    for det in (_blob_detector(max_area), _default_blob_detector(max_area)):
        for G in _grids(grey, target, det):
            try:
                uv, note = orient_grid(G, target, grey, allow_symmetric)
            except DetectionError as e:
                error = error or e
                continue
            found = (np.arange(target.n_points), uv, "circles", note)
            if accept is None or accept(found[0], uv):
                return found
            refused = refused or found
    if refused is not None:
        return refused
    if error is not None:
        raise error
    return None
