"""Ordering a detected grid to the target's own point ids.

OpenCV numbers grid points from whichever corner it meets first. Every grid detection is
therefore re-ordered to the target's ids (``targets`` module docstring): the handedness of the
board (printed side towards the camera) removes mirror orderings, and the remaining 180-degree
ambiguity is settled by the square colours (checkerboards with ``rows + cols`` odd), by the layout
(asymmetric grids with odd row count) or by the big dot (modified circle grid). Boards without such
a cue (``Target.is_symmetric``) are refused, unless ``allow_symmetric=True`` accepts an
image-orientation guess (point 0 nearest the image's top-left), which is then stated as a note.
"""

from __future__ import annotations

import numpy as np

from calibgraph.core.errors import DetectionError
from calibgraph.core.targets import Target
from calibgraph.detect.image import sample_bilinear


class BoardSpecError(DetectionError):
    """The grid was found, but the target spec cannot number its points (a symmetric board): no
    other search of the image can change that, so the search ends (``grid``: the (rows, cols, 2)
    grid found, in the image's pixels; ``note``: the evidence about the spec, in words)."""

    def __init__(self, message: str, grid: np.ndarray | None = None, note: str = ""):
        super().__init__(message)
        self.grid = grid
        self.note = note


def page_xy(target: Target) -> np.ndarray:
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


def _colour_score(grey: np.ndarray, G: np.ndarray) -> float:
    """Mean grey of cells expected black minus cells expected white (negative when the ordering
    matches the board's colours: cell (i, j) between corners (i, j) and (i+1, j+1) is black iff
    i + j is even)."""
    import cv2

    cells = 0.25 * (G[:-1, :-1] + G[1:, 1:] + G[:-1, 1:] + G[1:, :-1])
    sm = cv2.blur(grey, (3, 3))
    val = sample_bilinear(sm, cells.reshape(-1, 2)).reshape(cells.shape[:2])
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


def orient_grid(G: np.ndarray, target: Target, grey: np.ndarray, allow_symmetric: bool):
    """Re-order a detected grid to the target's ids. Returns (uv (N, 2), note) or raises
    DetectionError with the reason."""
    rows, cols = target.rows, target.cols
    page = page_xy(target)
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
        raise BoardSpecError(
            f"the {target.kind} target {target.rows}x{target.cols} looks the same turned by 180 degrees, so its "
            "point ids would flip between views; use a board with rows + cols odd (checkerboard), a ChArUco or a "
            "modified circle grid, or pass allow_symmetric=True to accept an image-orientation guess", grid=cands[0])
    k = int(np.argmin([C[0, 0].sum() for C in cands]))
    return cands[k].reshape(-1, 2), "symmetric target: orientation guessed from the image (point 0 nearest top-left)"
