"""Everyday mistakes in a dataset, named before anything is solved.

A solver fed a wrong input fails far from the cause ("camera not determined … add views" for poses
in millimetres, "never saw the board" for a target with rows and cols swapped) or, worse, succeeds
with a wrong answer (a board pitch 10× off, the same captures twice shrinking the 1σ). The checks
here look at the data the way a person would and say what is wrong, where, and what to do:

* no capture files at all;
* flange poses in millimetres (translations of metres-scale robots are below a few metres);
* the same capture stored twice under two indices (dropped, with a warning: the same data twice
  would count as twice the evidence);
* images whose size disagrees with the intrinsics, and stored corners outside the image;
* a target whose rows and cols are swapped with respect to the stored corners;
* a board pitch far off (board motions seen by the cameras several times those of the robot).

:func:`check_dataset` returns the dataset (duplicates dropped, warnings added to ``problems``) or
raises :class:`~calibgraph.core.errors.InputError` with the cause.
"""

from __future__ import annotations

import hashlib
from dataclasses import replace
from pathlib import Path

import numpy as np

from calibgraph.core.errors import InputError

MAX_ROBOT_REACH_M = 10.0      # a flange farther than this from the base: the poses are not in metres
PITCH_RATIO_LIMIT = 4.0       # board motion / robot motion beyond this (or below its inverse): pitch off
SWAP_RMS_FACTOR = 0.2         # the swapped layout fits this much better: rows and cols are swapped
OUTSIDE_FRACTION = 0.01       # more stored corners than this outside the image: wrong image size


def check_dataset(ds):
    """Run every check on a :class:`~calibgraph.io.dataset.Dataset`; the dataset to use (duplicated
    captures dropped, their warnings appended to ``problems``), or an :class:`InputError` naming the cause."""
    _check_not_empty(ds)
    _check_metres(ds)
    ds = _drop_duplicate_captures(ds)
    _check_image_sizes(ds)
    _check_corners_inside(ds)
    _check_rows_cols(ds)
    _check_pitch(ds)
    return ds


def _check_not_empty(ds) -> None:
    if ds.captures:
        return
    where = Path(ds.root) / "captures"
    if ds.problems:
        f, msg = ds.problems[0]
        raise InputError(f"{where}: none of the {len(ds.problems)} capture files could be read (first: {f}: {msg}).")
    raise InputError(f"{where}: no capture files (captures/NNNNNN.json); capture data first (calibgraph capture) "
                     "or point at the dataset folder that holds them.")


def _check_metres(ds) -> None:
    t = np.array([np.linalg.norm(c.T_base_flange[:3, 3]) for c in ds.captures])
    if np.median(t) > MAX_ROBOT_REACH_M:
        k = int(np.argmax(t))
        raise InputError(
            f"{Path(ds.root)}: the flange poses look like millimetres (T_base_flange translations up to "
            f"{t[k]:.0f}, median {np.median(t):.0f}; capture {ds.captures[k].index}); the dataset format wants "
            "metres: divide the translations by 1000.")


def _view_key(v, root: Path):
    if v.ids is not None:
        return ("det", v.camera, np.asarray(v.ids).tobytes(), np.round(np.asarray(v.uv_px, float), 6).tobytes())
    if v.image:
        p = root / v.image
        try:
            return ("img", v.camera, hashlib.sha256(p.read_bytes()).hexdigest())
        except OSError:
            return ("img?", v.camera, v.image)
    return ("none", v.camera)


def _drop_duplicate_captures(ds):
    """Captures with the same flange pose and the same views as an earlier one are dropped, with a warning."""
    by_pose = {}
    for c in ds.captures:
        by_pose.setdefault(np.round(c.T_base_flange, 9).tobytes(), []).append(c.index)
    groups = [g for g in by_pose.values() if len(g) > 1]
    if not groups:
        return ds
    root = Path(ds.root)
    views_of = {}
    for v in ds.views:
        views_of.setdefault(v.capture, []).append(v)
    pairs = []
    for g in groups:
        kept = {}
        for k in sorted(g):
            key = tuple(sorted(_view_key(v, root) for v in views_of.get(k, [])))
            if key in kept:
                pairs.append((k, kept[key]))
            else:
                kept[key] = k
    if not pairs:
        return ds
    drop = {k for k, _ in pairs}
    said = ", ".join(f"{k} = {j}" for k, j in pairs[:5]) + (f" and {len(pairs) - 5} more" if len(pairs) > 5 else "")
    warnings = [(str(root / "captures"), f"{len(pairs)} duplicated capture(s) dropped ({said}): same flange pose and same "
                 "views as an earlier capture; the same data twice is not twice the evidence")]
    return replace(ds, captures=tuple(c for c in ds.captures if c.index not in drop),
                   views=tuple(v for v in ds.views if v.capture not in drop),
                   problems=tuple(ds.problems) + tuple(warnings))


def image_size(path) -> tuple | None:
    """(width, height) of an image file from its header (PNG, or anything OpenCV reads), or None when
    it cannot be read (the detector then names the file, and the image costs its view only)."""
    try:
        with open(Path(path), "rb") as f:
            head = f.read(24)
    except OSError:
        return None
    if head[:8] == b"\x89PNG\r\n\x1a\n" and len(head) >= 24 and head[12:16] == b"IHDR":
        wh = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
        return wh if min(wh) > 0 else None  # a damaged header: the detector names the file, and it costs one view
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return None if img is None else (img.shape[1], img.shape[0])


def _check_image_sizes(ds) -> None:
    """The first, middle and last image to be detected of every camera must have the intrinsics' size
    (views with stored detections are checked by their corners, :func:`_check_corners_inside`)."""
    root = Path(ds.root)
    for cam, intr in ds.cameras.items():
        if not intr.width_px or not intr.height_px:
            continue
        imgs = [v.image for v in ds.views if v.camera == cam and v.image and v.ids is None]
        for rel in dict.fromkeys(imgs[i] for i in {0, len(imgs) // 2, len(imgs) - 1} if imgs):
            wh = image_size(root / rel)
            if wh is None or wh == (intr.width_px, intr.height_px):
                continue
            w, h = wh
            if (w, h) == (intr.height_px, intr.width_px):
                why = "the image is rotated by 90 degrees, or width and height are swapped in the intrinsics"
            elif abs(w / intr.width_px - h / intr.height_px) < 1e-3:
                why = (f"the image is scaled by {w / intr.width_px:g} against the calibration: use intrinsics of "
                       f"this resolution (K scaled by {w / intr.width_px:g})")
            else:
                why = "these intrinsics belong to another camera mode; use the calibration of this resolution"
            raise InputError(f"{root / rel}: the image is {w}x{h} px but camera {cam!r}'s intrinsics in "
                             f"dataset.yaml are for {intr.width_px}x{intr.height_px} px; {why}.")


def _check_corners_inside(ds) -> None:
    for cam, intr in ds.cameras.items():
        if not intr.width_px or not intr.height_px:
            continue
        uv = [v.uv_px for v in ds.views if v.camera == cam and v.ids is not None and len(v.ids)]
        if not uv:
            continue
        uv = np.concatenate(uv)
        out = ~intr.in_image(uv, margin_px=-2.0)
        if out.mean() > OUTSIDE_FRACTION:
            hi = np.nanmax(uv, axis=0)
            raise InputError(
                f"{Path(ds.root) / 'dataset.yaml'}: camera {cam!r}: {100 * out.mean():.0f} % of its stored corners lie "
                f"outside its {intr.width_px}x{intr.height_px} px image (up to u = {hi[0]:.0f}, v = {hi[1]:.0f} px): "
                "the intrinsics are for another image size; use the calibration of the recorded resolution.")


def _homography_rms(p_xy: np.ndarray, uv: np.ndarray) -> float:
    import cv2

    H, _ = cv2.findHomography(p_xy.astype(np.float64), uv.astype(np.float64), 0)
    if H is None:
        return np.inf
    q = np.c_[p_xy, np.ones(len(p_xy))] @ H.T
    with np.errstate(divide="ignore", invalid="ignore"):
        r = q[:, :2] / q[:, 2:3] - uv
    return float(np.sqrt(np.mean(np.sum(r ** 2, axis=1))))


def _full_views(ds, limit: int = 6) -> list:
    n = ds.target.points_board_m.shape[0]
    out = {}
    for v in ds.views:
        if v.ids is not None and len(v.ids) == n and len(out.setdefault(v.camera, [])) < limit:
            out[v.camera].append(v)
    return [v for vs in out.values() for v in vs]


def _check_rows_cols(ds) -> None:
    t = ds.target
    if t.rows == t.cols or t.kind not in ("checkerboard", "charuco", "circles"):
        return
    views = _full_views(ds)
    if len(views) < 2:
        return
    try:
        swapped = replace(t, rows=t.cols, cols=t.rows)
    except (InputError, TypeError):
        return
    p0, p1 = t.points_board_m[:, :2], swapped.points_board_m[:, :2]
    better = []
    for v in views:
        r0 = _homography_rms(p0[v.ids], v.uv_px)
        r1 = _homography_rms(p1[v.ids], v.uv_px)
        better.append(r1 < SWAP_RMS_FACTOR * r0 and r0 > 2.0)
        if len(better) >= 3 and not any(better):
            return
    if np.mean(better) > 0.5:
        raise InputError(
            f"{Path(ds.root) / 'dataset.yaml'}: target rows and cols look swapped: the stored corners of "
            f"{sum(better)}/{len(better)} full views fit a board of {t.cols} rows x {t.rows} cols, not the declared "
            f"{t.rows} x {t.cols}; swap 'rows' and 'cols' in the target section (or re-detect the images).")


def _check_pitch(ds) -> None:
    """Compare how far the board moves in each camera (PnP with the declared pitch) with how far the flange moves."""
    if ds.mode != "eye_to_hand":
        return
    import cv2

    caps = {c.index: c for c in ds.captures}
    pts = ds.target.points_board_m
    ratios = []
    for cam, intr in ds.cameras.items():
        p_cam, p_fl = [], []
        for v in ds.views:
            if v.camera != cam or v.ids is None or len(v.ids) < 6 or v.capture not in caps:
                continue
            ok, rvec, tvec = cv2.solvePnP(pts[v.ids], np.asarray(v.uv_px, float), intr.K, intr.dist,
                                          flags=cv2.SOLVEPNP_IPPE)
            if ok:
                p_cam.append(pts[v.ids].mean(axis=0) @ cv2.Rodrigues(rvec)[0].T + tvec.ravel())
                p_fl.append(caps[v.capture].T_base_flange[:3, 3])
        if len(p_cam) < 4:
            continue
        s_cam = np.sqrt(np.mean(np.sum((np.array(p_cam) - np.mean(p_cam, axis=0)) ** 2, axis=1)))
        s_fl = np.sqrt(np.mean(np.sum((np.array(p_fl) - np.mean(p_fl, axis=0)) ** 2, axis=1)))
        if s_fl > 0.05:  # too little robot motion says nothing about scale
            ratios.append(s_cam / s_fl)
    if not ratios:
        return
    r = float(np.median(ratios))
    if r > PITCH_RATIO_LIMIT or r < 1.0 / PITCH_RATIO_LIMIT:
        raise InputError(
            f"{Path(ds.root) / 'dataset.yaml'}: the board pitch {ds.target.pitch_m * 1e3:g} mm looks about {r:.2g}x "
            f"too {'large' if r > 1 else 'small'}: with it, the board moves {r:.2g}x as far in the cameras as the "
            "robot moves the flange; check pitch_m in the target section (metres: 0.025 for 25 mm squares) against the "
            "printed board with a ruler.")
