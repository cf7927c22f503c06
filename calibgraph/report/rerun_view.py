"""A rerun recording of a calibration: the workcell in 3D and every residual, per capture.

:func:`write_rrd` saves a ``.rrd`` file (no viewer needed) that ``rerun`` opens. Entity layout
(world = robot base, z up, metres)::

    world/robot_base                         base axes
    world/flange                             flange pose of the current capture (timeline "capture")
    world/flange_path                        all flange positions (static)
    world/flange/board  (eye-to-hand)        T_flange_board and the target points
    world/board         (eye-in-hand)        T_base_board and the target points
    world/cameras/<cam> (eye-to-hand)        T_base_cam, with a Pinhole frustum at .../image
    world/flange/<cam>  (eye-in-hand)        T_flange_cam, with a Pinhole frustum at .../image
    .../image                                the camera image of the capture (when the file exists)
    .../image/detected                       detected corners (green)
    .../image/reprojected                    corners reprojected through the calibrated chain (magenta)
    .../image/residual_x20                   detected -> reprojected, magnified 20x
    .../image/outliers                       rejected corners (red, large) and rejected views (orange)
    residuals/<cam>/rms_px, max_px           per-capture residual time series (timeline "capture")
    residuals/<cam>/rejected                 captures whose view was rejected (red points)
    summary                                  a text table of the result

rerun is imported lazily (it is an optional dependency: ``pip install calibgraph[viz]``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.problem import mode_frames
from calibgraph.io.files import atomic_write_via
from calibgraph.report.exports import camera_intrinsics, camera_pose, ref_frame
from calibgraph.report.html import (
    compute_residuals,
    corner_rejected_mask,
    observations,
    residuals_section,
)

GREEN = (40, 200, 60)
MAGENTA = (230, 40, 230)
RED = (230, 30, 30)
ORANGE = (255, 150, 0)
PALETTE = [(31, 119, 180), (44, 160, 44), (148, 103, 189), (140, 86, 75), (23, 190, 207), (188, 189, 34)]
RESIDUAL_GAIN = 20.0  # residual vectors are sub-pixel: magnify to see their pattern


def _import_rerun():
    try:
        import rerun as rr
    except ImportError:
        raise InputError("rerun is not installed: pip install 'calibgraph[viz]' (rerun-sdk) to write .rrd files.") from None
    return rr


def _result_dict(result) -> dict:
    if isinstance(result, dict):
        return result

    d = result.to_dict()
    if "residuals" not in d:
        d["residuals"] = residuals_section(result)
    return d


def _axes(rr, length_m: float):
    return rr.Arrows3D(vectors=np.eye(3) * length_m, colors=[(230, 0, 0), (0, 200, 0), (0, 80, 255)])


def _pose(rr, T):
    T = np.asarray(T, float)
    return rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3])


def log_result(rec, result, source=None) -> None:
    """Log a result (dict or :class:`Result`) and optionally its Problem/Dataset into a rerun
    RecordingStream ``rec``."""
    rr = _import_rerun()

    R = _result_dict(result)
    obs = observations(source) if source is not None else None
    ref = ref_frame(R)
    eih = R.get("mode") == "eye_in_hand"
    mk = mode_frames(R.get("mode")).board_key
    names = list(R["cameras"])

    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log("world/robot_base", _axes(rr, 0.2), static=True)

    # flange poses: refined ones from the result, else the recorded ones
    flange = {int(k): np.asarray(v, float) for k, v in (R.get("robot_flange_poses_refined") or {}).items()}
    if not flange and obs is not None:
        flange = dict(obs["T_base_flange"])
    if flange:
        P = np.array([T[:3, 3] for _, T in sorted(flange.items())])
        rec.log("world/flange_path", rr.Points3D(P, radii=0.004, colors=(150, 150, 150)), static=True)
        rec.log("world/flange", _axes(rr, 0.08), static=True)

    pts = obs["points_board_m"] if obs is not None else None
    T_mount = R.get(mk)
    if T_mount is None:  # 'single' method: every camera has its own; show the first
        T_mount = next((c[mk] for c in R["cameras"].values() if mk in c), None)
    board_path = "world/board" if eih else "world/flange/board"
    if T_mount is not None:
        rec.log(board_path, _pose(rr, T_mount), static=True)
        rec.log(board_path + "/axes", _axes(rr, 0.05), static=True)
        if pts is not None:
            rec.log(board_path + "/points", rr.Points3D(pts, radii=0.003, colors=(20, 20, 20)), static=True)

    cam_root = "world/flange" if eih else "world/cameras"
    intr = {}
    for n in names:
        T = camera_pose(R, n)
        rec.log(f"{cam_root}/{n}", _pose(rr, T), static=True)
        rec.log(f"{cam_root}/{n}/axes", _axes(rr, 0.1), static=True)
        K = camera_intrinsics(R, n, None) or (obs["cameras"].get(n) if obs is not None else None)
        intr[n] = K
        if K is not None:
            rec.log(f"{cam_root}/{n}/image", rr.Pinhole(image_from_camera=K.K, resolution=[K.width_px, K.height_px],
                                                         camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.3),
                    static=True)
        c = R["cameras"][n]
        rec.log(f"{cam_root}/{n}/label", rr.TextDocument(
            f"{n}: T_{ref}_cam t = {np.round(T[:3, 3], 4).tolist()} m; 1σ {np.round(c.get('sigma_translation_mm', []), 3).tolist()} mm, "
            f"{np.round(c.get('sigma_rotation_deg', []), 4).tolist()} deg; RMS {c.get('reprojection_rms_px', float('nan')):.3f} px"),
            static=True)

    residuals = R.get("residuals") or (compute_residuals(R, source) if source is not None else {})
    rejected_corners = {}
    for rc in R.get("rejected_corners") or []:
        rejected_corners.setdefault((rc["camera"], int(rc["capture"])), set()).add(int(rc["id"]))
    images = {}
    if obs is not None:
        images = {(cam, k): img for cam, k, _ids, _uv, img in obs["views"] if img}

    caps = sorted(set(flange) | {int(k) for r in residuals.values() for k in r})
    for i, n in enumerate(names):
        col = PALETTE[i % len(PALETTE)]
        light = tuple(int(c + 0.55 * (255 - c)) for c in col)  # max: a paler tint of the camera's colour
        rec.log(f"residuals/{n}/rms_px", rr.SeriesLines(colors=[col], names=[f"{n} RMS px"], widths=[2.0]), static=True)
        rec.log(f"residuals/{n}/max_px", rr.SeriesLines(colors=[light], names=[f"{n} max px"]), static=True)
        rec.log(f"residuals/{n}/rejected", rr.SeriesPoints(colors=[RED], markers=["cross"], names=[f"{n} rejected view"],
                                                             marker_sizes=[6.0]), static=True)
    for k in caps:
        rec.set_time("capture", sequence=k)
        if k in flange:
            rec.log("world/flange", _pose(rr, flange[k]))
        for n in names:
            base = f"{cam_root}/{n}/image"
            img = images.get((n, k))
            if img and Path(img).is_file() and intr.get(n) is not None:
                rec.log(base, rr.EncodedImage(path=img))
            v = (residuals.get(n) or {}).get(str(k))
            if v is None:
                # nothing seen at this capture: clear the overlays from the previous one
                for sub in ("detected", "reprojected", "residual_x20", "outliers"):
                    rec.log(f"{base}/{sub}", rr.Clear(recursive=False))
                continue
            ids = np.asarray(v["ids"], int)
            r = np.asarray(v["residual_px"], float).reshape(-1, 2)
            uv = v.get("uv_detected_px")
            norm = np.linalg.norm(r, axis=1)
            bad = np.array([i in rejected_corners.get((n, k), set()) for i in ids], bool)
            bad |= corner_rejected_mask(v, len(ids))
            view_rejected = bool(v.get("rejected"))
            good = ~bad & (not view_rejected)
            if good.any():
                rec.log(f"residuals/{n}/rms_px", rr.Scalars(float(np.sqrt(np.mean(norm[good] ** 2)))))
                rec.log(f"residuals/{n}/max_px", rr.Scalars(float(norm[good].max())))
            if view_rejected:
                rec.log(f"residuals/{n}/rejected", rr.Scalars(float(np.sqrt(np.mean(norm ** 2)))))
            if uv is None or intr.get(n) is None:
                continue
            uv = np.asarray(uv, float).reshape(-1, 2)
            pred = uv + r  # residual = reprojected - detected
            rec.log(f"{base}/detected", rr.Points2D(uv, radii=rr.Radius.ui_points(3.0), colors=GREEN))
            rec.log(f"{base}/reprojected", rr.Points2D(pred, radii=rr.Radius.ui_points(2.0), colors=MAGENTA))
            strips = np.stack([uv, uv + RESIDUAL_GAIN * r], axis=1)
            rec.log(f"{base}/residual_x20", rr.LineStrips2D(strips, colors=MAGENTA, radii=rr.Radius.ui_points(1.0)))
            if view_rejected:
                rec.log(f"{base}/outliers", rr.Points2D(uv, radii=rr.Radius.ui_points(5.0), colors=ORANGE,
                                                        labels=["view rejected"] * len(ids)))
            elif bad.any():
                rec.log(f"{base}/outliers", rr.Points2D(uv[bad], radii=rr.Radius.ui_points(7.0), colors=RED,
                                                        labels=[f"corner {i}: {e:.1f} px" for i, e in zip(ids[bad], norm[bad])]))
            else:
                rec.log(f"{base}/outliers", rr.Clear(recursive=False))

    lines = [f"# calibgraph result ({R.get('mode')}, {R.get('method')})", "",
             "| camera | t (m) | 1σ t (mm) | 1σ r (deg) | RMS px | views |", "|---|---|---|---|---|---|"]
    for n in names:
        c = R["cameras"][n]
        lines.append(f"| {n} | {np.round(camera_pose(R, n)[:3, 3], 4).tolist()} | "
                     f"{np.round(c.get('sigma_translation_mm', []), 3).tolist()} | "
                     f"{np.round(c.get('sigma_rotation_deg', []), 4).tolist()} | {c.get('reprojection_rms_px', float('nan')):.3f} | "
                     f"{c.get('views_used', '?')} used, {len(c.get('views_rejected', []))} rejected |")
    rec.log("summary", rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN), static=True)


def default_blueprint(result: dict):
    """Viewer layout: the 3D cell on the left; each camera's image with detected/reprojected corners
    and the residual time series on the right."""
    import rerun.blueprint as rrb

    cam_root = "world/flange" if result.get("mode") == "eye_in_hand" else "world/cameras"

    images = []
    for n in result["cameras"]:
        intr = camera_intrinsics(result, n, None)
        # show the whole image, so where the corners fall in the frame is visible even without images
        bounds = (rrb.VisualBounds2D(x_range=[-0.5, intr.width_px - 0.5], y_range=[-0.5, intr.height_px - 0.5])
                  if intr is not None and intr.width_px > 0 else None)
        images.append(rrb.Spatial2DView(origin=f"{cam_root}/{n}/image", visual_bounds=bounds,
                                        name=f"{n}: detected (green) vs reprojected (magenta)"))
    right = rrb.Vertical(rrb.Grid(*images), rrb.TimeSeriesView(origin="residuals", name="residuals per capture (px)"),
                         row_shares=[2, 1])
    left = rrb.Vertical(rrb.Spatial3DView(origin="world", name="workcell (robot base frame)"),
                        rrb.TextDocumentView(origin="summary", name="summary"), row_shares=[3, 1])
    return rrb.Blueprint(rrb.Horizontal(left, right, column_shares=[1, 1]), collapse_panels=False)


def write_rrd(result, problem_or_dataset=None, path="calibgraph.rrd") -> Path:
    """Save a rerun recording of ``result`` (a :class:`Result` or result dict) to ``path``.

    ``problem_or_dataset`` (a Problem, a Dataset or a dataset folder) adds the images, the
    detections (when the result has no ``residuals`` section) and the recorded flange poses.
    The file is written without a viewer; open it with ``rerun path``.
    """
    rr = _import_rerun()
    R = _result_dict(result)

    def write(tmp: Path) -> None:
        rec = rr.RecordingStream("calibgraph")
        rec.save(str(tmp), default_blueprint=default_blueprint(R))
        try:
            log_result(rec, R, problem_or_dataset)
            rec.flush()
        finally:
            rec.disconnect()

    atomic_write_via(path, write)
    return Path(path)


def rerun_cli() -> list:
    """Command that runs the ``rerun`` CLI installed with rerun-sdk (e.g. for ``rrd verify``)."""
    import shutil
    import sys

    exe = shutil.which("rerun")
    return [exe] if exe else [sys.executable, "-m", "rerun_cli"]
