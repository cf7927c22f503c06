"""Finding a target in one image: :func:`detect_image`, the search ladder around the per-kind finders.

The finder is chosen by the target's kind (:mod:`~calibgraph.detect.chessboard`,
:mod:`~calibgraph.detect.charuco`, :mod:`~calibgraph.detect.circles`). Checkerboard and ChArUco
corners are then refined on the original image by the photometric board fit
(:mod:`calibgraph.detect.board_fit`), which removes the detectors' outward bias on small squares
and most of their noise; ``refine=False`` keeps OpenCV's corners.

Far cameras (thesis §6.3): when the target is not found, or its grid pitch is below
``min_pitch_px``, the region of interest is up-scaled (bicubic, x2 then x3) and searched again;
corners are mapped back to original pixels (``cv2.resize`` maps destination pixel ``X`` to source
``(X + 0.5) / k - 0.5``). The region comes from the first detection or, when there is none, from
a saddle-point (checkerboard) or blob (circles) response map (:mod:`calibgraph.detect.regions`).
Up-scaling finds boards the original image loses, but where the original image already works it
does not improve accuracy, so it is used only when needed (scripts/results/bench_detect.md).

Every detection passes :func:`calibgraph.detect.grid_filter.check_grid` (thesis Algorithm 3 +
homography); a rejection says why.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import DetectionError, InputError
from calibgraph.core.targets import Target
from calibgraph.detect.board_fit import refine_charuco, refine_checkerboard, refine_marker_checkerboard
from calibgraph.detect.board_look import grid_marker_note, marker_side
from calibgraph.detect.charuco import find_charuco
from calibgraph.detect.chessboard import find_checkerboard
from calibgraph.detect.circles import find_circles
from calibgraph.detect.detection import ImageDetection, failed_detection
from calibgraph.detect.grid_filter import check_grid, grid_pitch_px
from calibgraph.detect import progress
from calibgraph.detect.image import read_grey, to_grey8
from calibgraph.detect.orient import BoardSpecError
from calibgraph.detect.overlay import disturbed_corners, outlying_points
from calibgraph.detect.polarity import check_polarity, checkerboard_polarity, inverted, worth_inverting
from calibgraph.detect.quality import edge_sigma_px, hull_area
from calibgraph.detect.regions import roi_candidates, roi_from_points

OPENCV_RNG_SEED = 0  # seeded at each search: detection may not depend on the thread or on what ran before


def detect_image(image, target: Target, intrinsics: Intrinsics | None = None, upscale="auto", method: str = "auto",
                 allow_symmetric: bool = False, filter: bool = True, min_pitch_px: float = 12.0,
                 min_points: int = 4, source: str | None = None, refine: bool = True,
                 region_px: tuple | None = None, bounded: bool = False, polarity: str = "auto") -> ImageDetection:
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
            :mod:`calibgraph.detect.guided`; the spec check's full search,
            :func:`calibgraph.detect.blind.search_in_full`): only that region is searched, like a
            candidate region of the blind search (no quick whole-frame rejection), at full
            resolution and, with ``upscale="auto"``, up-scaled when its squares are small or none
            were found.
        bounded: before a candidate region (or ``region_px``, when nothing was found in it at full
            resolution) is searched up-scaled, a quick probe (OpenCV's fast check at x2 and x3)
            must see a board there: a frame without the board then costs a fraction of a second,
            not seconds (dataset passes and guided detection use it).
        polarity: ``"auto"`` (the board as printed, black on white, then, where that finds nothing, a
            white-on-black print: :mod:`calibgraph.detect.polarity`), ``"normal"`` or ``"inverted"``
            (only that one).
    Returns:
        :class:`ImageDetection`; never raises for a bad image: ``ok=False`` and ``reason`` say why.
    """
    import cv2

    t0 = time.perf_counter()
    cv2.setRNGSeed(OPENCV_RNG_SEED)  # the SB detector draws from the thread's RNG: one image, one result
    src = str(image) if isinstance(image, (str, Path)) else source
    polarity = check_polarity(polarity)
    try:
        grey = read_grey(image) if isinstance(image, (str, Path)) else to_grey8(image, src or "image")
    except DetectionError as e:
        return failed_detection(str(e), target, src, t0, unreadable=True)
    opts = dict(target=target, intrinsics=intrinsics, method=method, upscale=_check_options(method, upscale),
                allow_symmetric=allow_symmetric, filter=filter, min_pitch_px=min_pitch_px, min_points=min_points,
                refine=refine, src=src, t0=t0, bounded=bounded)
    region = None if region_px is None else tuple(int(v) for v in region_px)
    look = grey if region is None else grey[region[1]:region[3], region[0]:region[2]]
    # A white-on-black print (calibgraph.detect.polarity): as printed first, inverted where that
    # finds nothing; a checkerboard's polarity is told first, its classic detector being slow on the
    # wrong one.
    first = "inverted" if polarity == "inverted" or (
        polarity == "auto" and target.kind == "checkerboard" and look.size and
        checkerboard_polarity(look, target) == "inverted") else "normal"
    s = _Search(grey=grey if first == "normal" else inverted(grey), inverted=first == "inverted", **opts)
    best = _ladder(s, region)
    if first == "inverted" and polarity == "auto" and not best.ok:
        best = _told_inverted(best)
    # found, or refused on the spec (the board seen as printed), or nothing to look for inverted
    if best.ok or best.spec_note or polarity != "auto" or first == "inverted" or \
            target.kind == "checkerboard" or not look.size or not worth_inverting(look, target):
        return best
    progress.stage(f"{target.kind} {target.rows}x{target.cols}, the inverted image (white on black?)")
    cv2.setRNGSeed(OPENCV_RNG_SEED)
    inv = _ladder(_Search(grey=inverted(grey), inverted=True, **opts), region)
    if inv.ok:
        return inv
    if inv.spec_note:
        return _told_inverted(inv)
    return replace(best, reason=f"{best.reason}; inverted (a board printed white on black?), {inv.reason}",
                   time_s=time.perf_counter() - t0)


def _told_inverted(det: ImageDetection) -> ImageDetection:
    """A refusal of the search in the inverted image, saying so (a board printed white on black)."""
    said = " (searched in the inverted image: the board looks printed white on black)"
    return replace(det, reason=det.reason + said, spec_note=det.spec_note and det.spec_note + said)


def _ladder(s: _Search, region) -> ImageDetection:
    """The search ladder on ``s.grey`` (the image, or its inverted image): the region ``region``
    (x0, y0, x1, y1) when given, else the whole frame, up-scaled where needed, then the last resorts."""
    target, grey, min_pitch_px = s.target, s.grey, s.min_pitch_px
    if region is not None:
        progress.stage(_stage(s, "the given region"))
        best = _search_region(s, region)
        if s.stop is not None:
            return s.stop
        return best if best is not None else _not_found(s)
    progress.stage(_stage(s, "the whole frame"))
    native = _attempt(s, _raw_detect, s, grey, 1.0) if s.upscale in ("auto", 1) else None
    if s.stop is not None:
        return s.stop
    deferred = native if s.upscale == "auto" and _plainly_small(s, native) else None
    first = _finish(s, native, 1) if native is not None and deferred is None else None
    if s.upscale == 1 or (first is not None and first.ok and first.pitch_px >= min_pitch_px):
        best = first
    else:
        if native is None and s.upscale != "auto":
            native = _attempt(s, _raw_detect, s, grey, 1.0)  # its points give the region to up-scale
        rois, first = _upscale_regions(s, native, first)
        best = _search_upscaled(s, rois, first, deferred) if s.stop is None else None
    if s.stop is not None:
        return s.stop
    if best is None or not best.ok:
        if target.kind == "checkerboard" or s.refit_refused:
            progress.stage(_stage(s, "last resorts (SB detector, the board fit's refusals)" if target.kind == "checkerboard"
                                  else "last resorts (the board fit's refusals)"))
        best = _last_resorts(s, best)
    return best if best is not None else _not_found(s)


def _stage(s: _Search, what: str) -> str:
    """What a search is doing, for the progress lines (:mod:`calibgraph.detect.progress`)."""
    return f"{s.target.kind} {s.target.rows}x{s.target.cols}{', inverted image' if s.inverted else ''}: {what}"


def _last_resorts(s: _Search, best):
    """When the ladder accepted nothing: SB at the image's own resolution (:func:`_native_sb`),
    then the grids the filter refused only after the board fit moved their corners, with the
    detector's corners back where the fit moved them far (:func:`_keep_detector_corners`).
    Returns the first accepted detection, else ``best``."""
    if s.upscale == "auto" and s.method == "auto" and s.target.kind == "checkerboard":
        best = _native_sb(s, best)
    for result, k in ([] if best is not None and best.ok else s.refit_refused):
        det = _finish(s, result, k, keep_detector=True)
        if det.ok:
            return det
    return best


def _native_sb(s: _Search, best):
    """The last resort of the automatic ladder: OpenCV's SB detector at the image's own resolution
    in the saddle-point regions (milliseconds each; the whole frame only when there is none). A
    steeply tilted board of 20 px squares that the classic detector, its fast check and the
    up-scaled searches all miss is found by it (MC-HEC's camera3 frame 0121); what it finds passes
    the same filter. Returns the accepted detection, else ``best``."""
    got = _attempt(s, find_checkerboard, s.grey, s.target, "sb", s.allow_symmetric, 1.0, True, True, s.regions)
    if got is None:
        return best
    det = _finish(s, got, 1)
    return det if det.ok or best is None else best


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
    bounded: bool = False
    inverted: bool = False  # ``grey`` is the inverted image (a white-on-black print)
    attempts: list = field(default_factory=list)
    stop: ImageDetection | None = None  # a refusal no other attempt can change (BoardSpecError)
    _regions: list | None = None
    refit_refused: list = field(default_factory=list)  # (raw result, k) refused after the board fit

    @property
    def regions(self) -> list:
        """The saddle/blob candidate regions of the whole image (computed once)."""
        if self._regions is None:
            self._regions = roi_candidates(self.grey, self.target)
        return self._regions


def _check_options(method: str, upscale):
    """Validate ``method`` and ``upscale``; returns ``upscale`` as ``"auto"`` or an int."""
    if method not in ("classic", "sb", "auto"):
        raise InputError(f"detect: method must be 'classic', 'sb' or 'auto', got {method!r}.")
    if upscale in ("off", None, False):
        upscale = 1
    if upscale != "auto" and int(upscale) not in (1, 2, 3, 4):
        raise InputError(f"detect: upscale must be 'auto', 1, 2, 3 or 4, got {upscale!r}.")
    return upscale


def _raw_detect(s: _Search, img: np.ndarray, scale: float, fast=None, offset=(0, 0)):
    """Raw detection on ``img`` (the original image, or a region at ``offset`` up-scaled by
    ``scale``): (ids, uv, method, note) or None; DetectionError for orientation problems.
    ``fast=True`` is a quick probe: OpenCV's fast check, no SB."""
    target = s.target
    if target.kind == "checkerboard":
        return find_checkerboard(img, target, s.method, s.allow_symmetric, scale=scale,
                                  sb_fallback=(scale > 1 or s.upscale == 1) and not fast, fast=fast)
    if target.kind == "charuco":
        r, _ = find_charuco(img, target, s.intrinsics, scale)
        return r
    return find_circles(img, target, s.method, s.allow_symmetric, accept=_passes_filter(s, scale, offset))


def _passes_filter(s: _Search, scale: float, offset):
    """``(ids, uv) -> bool``: the grid filter :func:`_finish` applies, on points found in a
    region at ``offset`` up-scaled by ``scale`` (None when the search does not filter): a finder
    that has more than one grid to offer keeps looking past a refused one."""
    if not s.filter:
        return None
    t = s.target

    def accept(ids, uv):
        uv = (uv + 0.5) / scale - 0.5 + np.asarray(offset, float)
        return check_grid(uv, t.line_ij[ids], t.points_board_m[ids], intrinsics=_filter_intrinsics(s)).ok
    return accept


def _detect_in_roi(s: _Search, roi, k: int, fast=None):
    """Raw detection in region ``roi`` (x0, y0, x1, y1) up-scaled by ``k``, mapped back to
    original pixels."""
    import cv2

    x0, y0, x1, y1 = roi
    crop = s.grey[y0:y1, x0:x1]
    if crop.shape[0] < 8 or crop.shape[1] < 8:
        return None
    big = crop if k == 1 else cv2.resize(crop, None, fx=k, fy=k, interpolation=cv2.INTER_CUBIC)
    r = _raw_detect(s, big, float(k), fast=(False if k == 1 else None) if fast is None else fast, offset=(x0, y0))
    if r is None:
        return None
    ids, uv, m, note = r
    # cv2.resize: destination pixel X samples source (X + 0.5) / k - 0.5.
    uv = (uv + 0.5) / k - 0.5 + np.array([x0, y0], float)
    return ids, uv, m, note


def _attempt(s: _Search, fn, *a):
    """``fn(*a)``, or None with the reason kept for the final message when it raises. A
    :class:`~calibgraph.detect.orient.BoardSpecError` (the board found, its spec unusable as declared)
    ends the search: ``s.stop`` is the refusal, and later attempts return None at once."""
    if s.stop is not None:
        return None
    try:
        return fn(*a)
    except BoardSpecError as e:
        note = e.note
        if s.target.kind == "checkerboard" and e.grid is not None:
            note = grid_marker_note(s.grey, e.grid) or note
        s.stop = failed_detection(f"{note}; {e}" if note else str(e), s.target, s.src, s.t0, spec_note=note or str(e),
                                  inverted=s.inverted)
        return None
    except DetectionError as e:
        s.attempts.append(str(e))
        return None


def _finish(s: _Search, result, k: int, keep_detector: bool = False) -> ImageDetection:
    """A raw detection (from an image up-scaled by ``k``) refined, filtered and measured.
    ``keep_detector``: when the filter refuses the refined corners, try the detector's where the
    fit moved them far (a last resort, :func:`_last_resorts`)."""
    ids, uv, m, note = result
    target, grey = s.target, s.grey
    n_refined, raw = 0, uv
    if s.refine and target.kind == "checkerboard" and ids.size:
        # On the original pixels whatever the search scale: interpolation adds its own shift.
        # Markers in the white squares (a ChArUco board declared a checkerboard) enter the model.
        side = marker_side(grey, target, ids, uv)
        fit = refine_checkerboard(grey, target, ids, uv) if side is None else refine_marker_checkerboard(
            grey, target, ids, uv, side, blur_px=edge_sigma_px(grey, uv, max(_pitch(ids, uv, target), 4.0)))
        uv, n_refined = fit.uv_px, int(fit.refined.sum())
    elif s.refine and target.kind == "charuco" and ids.size >= 4:
        blur_px = edge_sigma_px(grey, uv, max(_pitch(ids, uv, target), 4.0))
        fit = refine_charuco(grey, target, ids, uv, blur_px=blur_px)
        uv, n_refined = fit.uv_px, int(fit.refined.sum())
    if n_refined:
        # corners the fit could not model (a line drawn over them, calibgraph.detect.overlay) that their
        # neighbours place elsewhere are left out
        bad = outlying_points(uv, target.points_board_m[ids, :2], target.pitch_m, disturbed_corners(fit.rms_grey))
        if bad.any():
            keep = ~bad
            ids, uv, raw = ids[keep], uv[keep], raw[keep]
            n_refined = int(fit.refined[keep].sum())
            out = f"{int(bad.sum())} corners left out: something not of the board over them (a drawing, a glare) moved them"
            note = "; ".join(x for x in (note, out) if x)
    ok, reason = True, note
    if ids.size < s.min_points:
        ok, reason = False, f"only {ids.size} points found (minimum {s.min_points})"
    pitch = _pitch(ids, uv, target) if ids.size >= 2 else 0.0
    h_rms = float("nan")
    if ok and s.filter:
        fr = check_grid(uv, target.line_ij[ids], target.points_board_m[ids], intrinsics=_filter_intrinsics(s))
        if not fr.ok and n_refined and keep_detector:
            uv, fr, n_refined = _keep_detector_corners(s, ids, raw, uv, fr, n_refined)
        elif not fr.ok and n_refined:
            s.refit_refused.append((result, k))
        h_rms = fr.homography_rms_px
        if not fr.ok:
            ok, reason = False, f"rejected by the grid filter{'' if k == 1 else f' (x{k} up-scaled)'}: {fr.reason}"
    area = hull_area(uv)
    return ImageDetection(
        ids=ids, uv_px=uv, ok=ok, reason=reason, n_expected=target.n_points, size_px=float(np.sqrt(area)),
        spread=area / float(grey.size), pitch_px=pitch, sharpness_px=edge_sigma_px(grey, uv, max(pitch, 4.0)),
        upscale=k, method=m, homography_rms_px=h_rms, n_refined=n_refined, time_s=time.perf_counter() - s.t0,
        image=s.src, inverted=s.inverted)


def _keep_detector_corners(s: _Search, ids, raw, uv, fr, n_refined):
    """The board fit must not turn a grid the filter accepts into one it refuses: when nothing else
    is accepted and the refined corners were refused, the corners the fit moved far (over 0.5 px and 3x the median
    move) get the detector's positions back, else all do, whichever the filter accepts first.
    Seen on MC-HEC's rendered frames (paper at 255, ink at 0: the fit ignores clipped pixels and
    has little left), where a corner moved 2.5 px off its row. Returns (uv, filter result, number
    of corners still refined)."""
    t = s.target
    moved = np.linalg.norm(uv - raw, axis=1)
    far = moved > max(0.5, 3.0 * float(np.median(moved)))
    for keep in ([far] if far.any() else []) + [np.ones(len(uv), bool)]:
        cand = np.where(keep[:, None], raw, uv)
        fr2 = check_grid(cand, t.line_ij[ids], t.points_board_m[ids], intrinsics=_filter_intrinsics(s))
        if fr2.ok:
            return cand, fr2, max(0, n_refined - int(keep.sum()))
    return uv, fr, n_refined


def _upscale_regions(s: _Search, native, first):
    """Regions to search up-scaled: around the native detection, else saddle/blob clusters of a
    plausible size. Returns (regions, first detection), the latter possibly found here on a
    board touching the arm (see below)."""
    grey, target = s.grey, s.target
    if native is not None and len(native[1]):
        return [roi_from_points(native[1], grey.shape)], first
    # Up-scaling helps small boards only: skip regions whose size implies squares of more
    # than 2x min_pitch_px (a miss there has another cause, e.g. a wrong target spec, and
    # searching them up-scaled costs seconds). Regions are padded by 60 % + 8 px per side.
    n_steps = max(target.rows, target.cols) + 1
    cands = s.regions
    rois = [r for r in cands if (max(r[2] - r[0], r[3] - r[1]) - 16) / 2.2 / n_steps < 2 * s.min_pitch_px]
    if first is None and target.kind == "checkerboard":
        # A board on the flange touches the arm, whose shading also answers the saddle
        # filter: its region then looks too big for a small board, and OpenCV's fast check
        # on the whole frame rejects boards of ~10-12 px squares. Search such regions
        # up-scaled x2, then x3, with the fast check (a miss costs ~5-100 ms where a search
        # without it costs seconds), then redo the found board at full resolution in a tight
        # region. x3 finds the boards of 4.5-6 px squares that x2's fast check rejects (a far
        # camera's views: on the rendered 5 m D455 cell they were half of those lost).
        for roi in (r for r in cands if r not in rois):
            progress.stage(_stage(s, "a large region's quick look up-scaled x2, x3"))
            for k in (2, 3):
                got = _attempt(s, _detect_in_roi, s, roi, k, True)
                if got is not None:
                    break
            if got is None:
                continue
            tight = roi_from_points(got[1], grey.shape)
            nat = _attempt(s, _detect_in_roi, s, tight, 1)
            first = _finish(s, nat, 1) if nat is not None else _finish(s, got, k)
            rois = [] if first.ok and first.pitch_px >= s.min_pitch_px else [tight]
            break
    return rois, first


def _search_upscaled(s: _Search, rois, first, deferred=None):
    """Search ``rois`` up-scaled (x2 then x3 for ``"auto"``); the first accepted detection wins,
    else the best so far (``first``, or the native detection ``deferred``, or the first rejected
    one for its reason)."""
    factors = (2, 3) if s.upscale == "auto" else (int(s.upscale),)
    if s.bounded and s.target.kind == "checkerboard":
        rois = [roi for roi in rois if _probe_sees_board(s, roi)]
    best = first
    for k in factors:
        for i, roi in enumerate(rois):
            progress.stage(_stage(s, f"region {i + 1} of {len(rois)} up-scaled x{k}"))
            got = _attempt(s, _detect_in_roi, s, roi, k)
            if got is None:
                continue
            det = _finish(s, got, k)
            if det.ok:
                best = det
                break
            if best is None and deferred is None:
                best = det
        if best is not None and best.ok and best.upscale > 1:
            break
    if best is None and deferred is not None:
        best = _finish(s, deferred, 1)
    return best


def _filter_intrinsics(s: _Search) -> Intrinsics:
    """The intrinsics the grid filter judges a grid with: the camera's, or, when none are given, a
    nominal pinhole (principal point at the image centre, focal length half the larger side, no
    distortion), so that a lens's bend still gets the filter's one radial term (grid_filter module
    docstring) instead of failing rows: OpenCV's own left*.jpg samples (k1 -0.27) lost 3 of 13
    views to it."""
    if s.intrinsics is not None:
        return s.intrinsics
    h, w = s.grey.shape[:2]
    f = 0.5 * max(h, w)
    return Intrinsics(K=np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]]), dist=np.zeros(5),
                      width_px=w, height_px=h)


def _plainly_small(s: _Search, raw) -> bool:
    """A raw native detection whose squares are plainly under ``min_pitch_px``: the up-scaled
    search that follows replaces it unless it fails, so its refinement (the board fit, the
    costliest step) waits until then. The margin keeps the decision the refined pitch would make."""
    return raw is not None and len(raw[0]) >= 2 and _pitch(raw[0], raw[1], s.target) < s.min_pitch_px - 1.0


def _search_region(s: _Search, roi) -> ImageDetection | None:
    """Guided search of one region, as the blind search treats a candidate region: full
    resolution, then (``upscale="auto"``) x2 and x3 while the squares are under ``min_pitch_px``;
    the first passing detection, else the best failure. With ``bounded``, before the up-scaled full
    searches a quick probe (OpenCV's fast check at x2 and x3, no SB) must see a board: where the
    estimate expected one but none is (occluded, out of focus), a miss then costs a fraction of a
    full search."""
    if s.upscale != "auto":
        got = _attempt(s, _detect_in_roi, s, roi, int(s.upscale), False)
        return _finish(s, got, int(s.upscale)) if got is not None else None
    got = _attempt(s, _detect_in_roi, s, roi, 1, False)
    deferred = got if _plainly_small(s, got) else None
    best = _finish(s, got, 1) if got is not None and deferred is None else None
    if best is not None and best.ok and best.pitch_px >= s.min_pitch_px:
        return best
    if got is None and s.bounded and not _probe_sees_board(s, roi):
        return None
    for k in (2, 3):
        progress.stage(_stage(s, f"the given region up-scaled x{k}"))
        got = _attempt(s, _detect_in_roi, s, roi, k, False)
        if got is None:
            continue
        det = _finish(s, got, k)
        if det.ok:
            return det
        if best is None and deferred is None:
            best = det
    return best if best is not None or deferred is None else _finish(s, deferred, 1)


def _probe_sees_board(s: _Search, roi) -> bool:
    """OpenCV's fast check sees a board in ``roi`` up-scaled x2 or x3 (a miss costs a fraction
    of a full up-scaled search)."""
    return any(_attempt(s, _detect_in_roi, s, roi, k, True) is not None for k in (2, 3))


def _not_found(s: _Search) -> ImageDetection:
    """The failed detection, with the reasons met on the way (or advice when there were none)."""
    t = s.target
    unit = "inner corners" if t.kind in ("checkerboard", "charuco") else "points"
    # Nothing was found: nothing points at the spec (a board seen from behind, out of view or blurred
    # looks the same), so the spec comes last (issue 47).
    why = "; ".join(dict.fromkeys(s.attempts)) if s.attempts else (
        f"no board found in the image; if the board is in view (printed side towards the camera), check that it "
        f"is whole and in focus, and that it is the {t.kind} of {t.rows}x{t.cols} {unit} the target spec declares")
    return failed_detection(why, t, s.src, s.t0)


def _pitch(ids: np.ndarray, uv: np.ndarray, target: Target) -> float:
    """Median image distance between neighbours one pitch apart along a row/column, pixels."""
    return grid_pitch_px(uv, target.line_ij[ids])
