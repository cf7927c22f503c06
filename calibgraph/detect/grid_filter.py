"""The false-detection filter: a detected grid must look like the target seen through a lens.

Two checks, each rejection naming the row/column or point at fault:

1. The thesis's filter (§4.3, Algorithm 3), generalised to partial views: along every row and
   every column of the grid (3 or more points), the points are collinear and evenly spaced.
   Straightness is the perpendicular distance from the total-least-squares line. Perspective
   turns equal spacing into a smooth geometric progression, so "evenly spaced" is tested as the
   ratio of consecutive gaps (close to 1 for moderate tilts; ``max_gap_ratio``) together with the
   thesis's sum test (sum of gaps = end-to-end length, which catches folded or overlapping rows).
2. Homography consistency: a plane maps to the (undistorted) image through a homography. A
   least-squares homography from board points to pixels must reproduce every point within
   ``homography_tol_px`` (plus a fraction of the grid pitch, so lens distortion left in the points
   does not reject good views when no intrinsics are given). A swapped or shifted id moves a point
   by a whole pitch and fails this test.

When intrinsics are given, points are undistorted first (to the pinhole image with the same K),
so lines are straight and the homography is exact up to noise.

Real lenses with nominal intrinsics: intrinsics that come without (or with too little)
distortion leave the rows of a good view bent by the lens, 1-3 px at the image edge. Such a
bend is one smooth radial field about the principal point, unlike a false detection (a point a
pitch away, a fold). So when a view fails with intrinsics given, one radial parameter of the
division model ``x_u = x_d / (1 + lambda r_d^2)`` (normalised coordinates about the principal
point, |lambda| <= 0.6) is fitted to the grid's homography residual, and the checks run again on
the points it straightens. The view passes only if every check passes then; ``lens_lambda``
reports the fitted value (0 when not needed), a hint that the intrinsics lack distortion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibgraph.core.camera import Intrinsics, undistort_normalised


@dataclass(frozen=True)
class FilterResult:
    """Outcome of :func:`check_grid`.

    Attributes:
        ok: True when all checks pass.
        reason: why not (empty when ok).
        line_max_px: largest distance of a point from its row/column line.
        gap_ratio_max: largest ratio between consecutive gaps along a row/column.
        homography_rms_px, homography_max_px: residuals of the board-to-image homography.
    """

    ok: bool
    reason: str = ""
    line_max_px: float = 0.0
    gap_ratio_max: float = 1.0
    homography_rms_px: float = 0.0
    homography_max_px: float = 0.0
    lens_lambda: float = 0.0


def _undistort(uv: np.ndarray, intr: Intrinsics | None) -> np.ndarray:
    """Pixels as an ideal pinhole camera with the same K would see them."""
    if intr is None or not np.any(intr.dist8):
        return uv

    xy = undistort_normalised(intr, uv)
    return xy @ intr.K[:2, :2].T + intr.K[:2, 2]


def grid_pitch_px(uv_px: np.ndarray, ij: np.ndarray) -> float:
    """Median image distance per grid step between neighbours along rows/columns (``ij`` as in
    :func:`check_grid`), pixels; 0 when no two points are neighbours."""
    uv = np.asarray(uv_px, float).reshape(-1, 2)
    ij = np.asarray(ij, int).reshape(-1, 2)
    gaps = []
    for axis in (0, 1):
        other = 1 - axis
        for k in np.unique(ij[:, axis]):
            idx = np.nonzero(ij[:, axis] == k)[0]
            if idx.size < 2:
                continue
            idx = idx[np.argsort(ij[idx, other])]
            steps = np.diff(ij[idx, other]).astype(float)
            d = np.linalg.norm(np.diff(uv[idx], axis=0), axis=1)
            # Only direct neighbours: a gap across missing points says little about the pitch.
            gaps.extend(d[steps == steps.min()] / steps.min() if steps.size else [])
    return float(np.median(gaps)) if gaps else 0.0


def _lines(ij: np.ndarray):
    """Yield (label, indices sorted along the line) for every row and column with >= 3 points."""
    for axis, name in ((0, "row"), (1, "column")):
        other = 1 - axis
        for k in np.unique(ij[:, axis]):
            idx = np.nonzero(ij[:, axis] == k)[0]
            if idx.size >= 3:
                yield f"{name} {int(k)}", idx[np.argsort(ij[idx, other])], ij[idx[np.argsort(ij[idx, other])], other]


def _homography_rms(P: np.ndarray, uv: np.ndarray) -> float:
    """RMS residual (px) of the least-squares homography from board points to pixels (inf if none)."""
    import cv2

    H, _ = cv2.findHomography(P[:, :2], uv, 0)
    if H is None:
        return float("inf")
    ph = np.column_stack([P[:, :2], np.ones(len(P))]) @ H.T
    if np.any(np.abs(ph[:, 2]) < 1e-12):
        return float("inf")
    return float(np.sqrt(np.mean(np.sum((ph[:, :2] / ph[:, 2:3] - uv) ** 2, axis=1))))


LENS_LAMBDA_MAX = 0.6  # division-model bound: ~ -k1 of a wide-angle lens, far beyond what a camera with
                       # sane nominal intrinsics leaves unmodelled


def _division_undistort(uv: np.ndarray, intr: Intrinsics, lam: float) -> np.ndarray:
    """Pixels straightened by the division model with parameter ``lam`` about the principal point."""
    f = np.array([intr.K[0, 0], intr.K[1, 1]])
    c = intr.K[:2, 2]
    x = (uv - c) / f
    return c + f * x / (1.0 + lam * np.sum(x * x, axis=1, keepdims=True))


def fit_lens_lambda(uv_px: np.ndarray, points_board_m: np.ndarray, intrinsics: Intrinsics) -> float:
    """The division-model parameter that best straightens a grid (minimum homography residual)."""
    uv = np.asarray(uv_px, float).reshape(-1, 2)
    P = np.asarray(points_board_m, float).reshape(-1, 3)
    lams = np.linspace(-LENS_LAMBDA_MAX, LENS_LAMBDA_MAX, 61)
    cost = np.array([_homography_rms(P, _division_undistort(uv, intrinsics, lam)) for lam in lams])
    k = int(np.argmin(cost))
    if 0 < k < len(lams) - 1 and np.all(np.isfinite(cost[k - 1:k + 2])):
        # parabola through the best grid value and its neighbours
        c0, c1, c2 = cost[k - 1:k + 2]
        den = c0 - 2 * c1 + c2
        if den > 0:
            return float(lams[k] + 0.5 * (c0 - c2) / den * (lams[1] - lams[0]))
    return float(lams[k])


def check_grid(uv_px: np.ndarray, ij: np.ndarray, points_board_m: np.ndarray, *, intrinsics: Intrinsics | None = None,
               line_tol_px: float = 1.0, line_tol_pitch: float = 0.06, max_gap_ratio: float = 1.6,
               homography_tol_px: float = 2.0, homography_tol_pitch: float = 0.12,
               check_lines: bool = True) -> FilterResult:
    """Check that detected points form the target's grid.

    Args:
        uv_px: (N, 2) detected pixels.
        ij: (N, 2) integer (row, column) index of each point such that points of a straight row
            share ij[:, 0], points of a straight column share ij[:, 1], and the index difference
            counts pitches (``Target.line_ij``).
        points_board_m: (N, 3) board coordinates of the same points (z = 0).
        intrinsics: when given, points are undistorted before the checks, and a view failing them
            gets a second chance with an estimated residual radial distortion (module docstring).
        line_tol_px, line_tol_pitch: a point may sit ``max(line_tol_px, line_tol_pitch * pitch)``
            off its row/column line (pitch = median neighbour spacing in pixels).
        max_gap_ratio: largest allowed ratio of consecutive gaps along a line (perspective of a
            60-degree tilt on a 9-point row stays below ~1.3).
        homography_tol_px, homography_tol_pitch: largest allowed homography residual is
            ``max(homography_tol_px, homography_tol_pitch * pitch)``.
        check_lines: run Algorithm 3 (rows/columns); the homography check always runs.
    Returns:
        :class:`FilterResult`.
    """
    uv = _undistort(np.asarray(uv_px, float).reshape(-1, 2), intrinsics)
    ij = np.asarray(ij, int).reshape(-1, 2)
    P = np.asarray(points_board_m, float).reshape(-1, 3)
    tol = dict(line_tol_px=line_tol_px, line_tol_pitch=line_tol_pitch, max_gap_ratio=max_gap_ratio,
               homography_tol_px=homography_tol_px, homography_tol_pitch=homography_tol_pitch, check_lines=check_lines)
    first = _check(uv, ij, P, **tol)
    if first.ok or intrinsics is None or uv.shape[0] < 6:
        return first
    lam = fit_lens_lambda(uv, P, intrinsics)
    second = _check(_division_undistort(uv, intrinsics, lam), ij, P, **tol)
    if not second.ok:
        return first
    return FilterResult(True, "", second.line_max_px, second.gap_ratio_max, second.homography_rms_px,
                        second.homography_max_px, lens_lambda=lam)


def _check(uv: np.ndarray, ij: np.ndarray, P: np.ndarray, *, line_tol_px, line_tol_pitch, max_gap_ratio,
           homography_tol_px, homography_tol_pitch, check_lines) -> FilterResult:
    """The row/column and homography checks on (already undistorted) points."""
    import cv2

    n = uv.shape[0]
    if n < 4:
        return FilterResult(False, f"only {n} points; at least 4 are needed to check the grid")
    lines = list(_lines(ij))
    # Pitch in pixels: median gap per grid step along rows/columns (partial views may skip points).
    per_step = []
    for _, idx, pos in lines:
        steps = np.diff(pos).astype(float)
        steps[steps == 0] = np.nan
        per_step.append(np.linalg.norm(np.diff(uv[idx], axis=0), axis=1) / steps)
    if per_step:
        pitch_px = float(np.nanmedian(np.concatenate(per_step)))
    else:
        # Sparse partial view (no row/column of 3): only the homography check applies.
        d_ij = np.abs(ij[:, None, :] - ij[None, :, :]).sum(-1)
        nb = np.argwhere(d_ij == 1)
        if nb.size == 0:
            return FilterResult(False, "no two detected points are grid neighbours")
        pitch_px = float(np.median(np.linalg.norm(uv[nb[:, 0]] - uv[nb[:, 1]], axis=1)))
    if not pitch_px > 0.5:
        return FilterResult(False, f"points collapse onto each other (grid pitch {pitch_px:.2f} px)")
    line_max = 0.0
    gap_max = 1.0
    if check_lines:
        tol = max(line_tol_px, line_tol_pitch * pitch_px)
        for label, idx, pos in lines:
            q = uv[idx]
            c = q.mean(0)
            _, _, Vt = np.linalg.svd(q - c)
            normal = Vt[1]
            dist = np.abs((q - c) @ normal)
            k = int(np.argmax(dist))
            line_max = max(line_max, float(dist[k]))
            if dist[k] > tol:
                return FilterResult(False, f"{label} is not straight: point {k} of it is {dist[k]:.2f} px off the line "
                                    f"(tolerance {tol:.2f} px)", line_max_px=line_max)
            # Gaps per grid step (partial views may skip points).
            steps = np.diff(pos).astype(float)
            if np.any(steps <= 0):
                return FilterResult(False, f"{label}: repeated grid index")
            gaps = np.linalg.norm(np.diff(q, axis=0), axis=1) / steps
            if np.any(gaps < 1e-6):
                return FilterResult(False, f"{label}: two points coincide")
            ratios = np.maximum(gaps[1:] / gaps[:-1], gaps[:-1] / gaps[1:])
            if ratios.size:
                gap_max = max(gap_max, float(ratios.max()))
                if ratios.max() > max_gap_ratio:
                    return FilterResult(False, f"{label} is not evenly spaced: consecutive gaps differ by a factor "
                                        f"{ratios.max():.2f} (limit {max_gap_ratio})", line_max_px=line_max,
                                        gap_ratio_max=gap_max)
            # Thesis: sum of the gaps equals the end-to-end distance (no fold-backs).
            total = np.linalg.norm(q[-1] - q[0])
            if np.sum(gaps * steps) > total * 1.02 + tol:
                return FilterResult(False, f"{label} folds back on itself (sum of gaps {np.sum(gaps * steps):.1f} px > "
                                    f"end-to-end {total:.1f} px)", line_max_px=line_max, gap_ratio_max=gap_max)
    H, _ = cv2.findHomography(P[:, :2], uv, 0)
    if H is None:
        return FilterResult(False, "points are degenerate (no homography fits them)", line_max, gap_max)
    ph = np.column_stack([P[:, :2], np.ones(n)]) @ H.T
    if np.any(np.abs(ph[:, 2]) < 1e-12):
        return FilterResult(False, "homography maps a point to infinity", line_max, gap_max)
    res = np.linalg.norm(ph[:, :2] / ph[:, 2:3] - uv, axis=1)
    rms, mx = float(np.sqrt(np.mean(res**2))), float(res.max())
    htol = max(homography_tol_px, homography_tol_pitch * pitch_px)
    if mx > htol:
        k = int(np.argmax(res))
        return FilterResult(False, f"points do not lie on a plane seen through a lens: grid point (row {ij[k, 0]}, "
                            f"column {ij[k, 1]}) is {mx:.2f} px off the best homography (tolerance {htol:.2f} px)",
                            line_max, gap_max, rms, mx)
    return FilterResult(True, "", line_max, gap_max, rms, mx)
