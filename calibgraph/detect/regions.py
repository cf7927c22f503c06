"""Image regions worth a closer look: around detected points, or where the image responds like a
small target (saddle points of a board of squares, dark blobs of a circle grid)."""

from __future__ import annotations

import numpy as np

from calibgraph.core.targets import Target


def roi_from_points(uv: np.ndarray, shape, pad_frac: float = 0.35, pad_px: int = 12):
    h, w = shape
    lo = uv.min(0)
    hi = uv.max(0)
    pad = pad_frac * float(np.max(hi - lo)) + pad_px
    x0 = int(max(0, np.floor(lo[0] - pad)))
    y0 = int(max(0, np.floor(lo[1] - pad)))
    x1 = int(min(w, np.ceil(hi[0] + pad) + 1))
    y1 = int(min(h, np.ceil(hi[1] + pad) + 1))
    return x0, y0, x1, y1


def roi_candidates(grey: np.ndarray, target: Target, max_rois: int = 2, crop: bool = True):
    """Regions likely to hold a small target: clusters of saddle points (boards of squares) or of
    dark blobs (circle grids), found on the original image. ``crop=False`` merges and ranks the
    responses on the whole image instead of the box around them (the same regions, slower: the
    reference the fast path is tested against)."""
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
    # The strong responses are few and clustered: the dilation, the labelling and the sums below
    # are done on the box around them grown by the kernel (every dilated pixel lies inside it),
    # which gives the same components and the same sums as the whole image at a fraction of the
    # cost (tests/test_detect_fast_paths.py checks it against the whole image).
    y0, y1, x0, x1 = _box(mask, k) if crop else (0, mask.shape[0], 0, mask.shape[1])
    mask = cv2.dilate(mask[y0:y1, x0:x1], cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return []
    # Rank by total response inside the component.
    sums = np.bincount(lab.ravel(), weights=resp[y0:y1, x0:x1].ravel(), minlength=n)
    order = [i for i in np.argsort(-sums) if i != 0][:max_rois]
    rois = []
    for i in order:
        x, y, w, h = stats[i, :4]
        x, y = x + x0, y + y0
        if w * h > 0.5 * grey.size:
            continue
        pts = np.array([[x, y], [x + w, y + h]], float)
        # Saddles span the inner corners only: pad by most of that span so the outer squares
        # and the white quiet zone around them are inside the region.
        rois.append(roi_from_points(pts, grey.shape, pad_frac=0.6, pad_px=8))
    return rois


def _box(mask: np.ndarray, pad: int):
    """(y0, y1, x0, x1): the bounding box of the non-zero pixels of ``mask`` grown by ``pad`` on
    every side, clipped to the image (the whole image when it has none)."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    h, w = mask.shape
    if rows.size == 0:
        return 0, h, 0, w
    return (max(0, int(rows[0]) - pad), min(h, int(rows[-1]) + pad + 1), max(0, int(cols[0]) - pad),
            min(w, int(cols[-1]) + pad + 1))
