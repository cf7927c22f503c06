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
    summary                                  a text table of the result, then what would improve it
                                             (each camera's advice), each camera's error budget,
                                             advice, intrinsics' provenance, move and notes, and
                                             the notes on the whole cell (report.findings)

and, for an autonomous run (the dataset's ``plan_log.json``, :mod:`calibgraph.acquire.auto`), per
step on the same "capture" timeline (step k is capture k)::

    world/plan/candidates                    the best candidates of the choice: board centres,
                                             coloured by score (viridis, yellow = best), labelled
    world/plan/chosen                        the board centre of the pose moved to (large, red)
    world/plan/chosen_path                   board centres of the steps so far (line)
    plan/log                                 one text line per step: phase, label, why
    plan/sigma_mm/<cam>                      1-sigma translation norm per camera after the step

rerun is imported lazily (it is an optional dependency: ``pip install calibgraph[viz]``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.io.files import atomic_write_via, read_input_bytes
from calibgraph.report.findings import summary_markdown
from calibgraph.report.residuals import observations, report_residuals
from calibgraph.report.svgplot import colormap
from calibgraph.solver.output.result import as_result

GREEN = (40, 200, 60)
MAGENTA = (230, 40, 230)
RED = (230, 30, 30)
ORANGE = (255, 150, 0)
PALETTE = [(31, 119, 180), (44, 160, 44), (148, 103, 189), (140, 86, 75), (23, 190, 207), (188, 189, 34)]
PLAN_LOG_NAME = "plan_log.json"  # as written by calibgraph.acquire.auto
RESIDUAL_GAIN = 20.0  # residual vectors are sub-pixel: magnify to see their pattern


def import_rerun():
    try:
        import rerun as rr
    except ImportError:
        raise InputError("rerun is not installed: pip install 'calibgraph[viz]' (rerun-sdk) to write .rrd files.") from None
    return rr


def axes(rr, length_m: float):
    return rr.Arrows3D(vectors=np.eye(3) * length_m, colors=[(230, 0, 0), (0, 200, 0), (0, 80, 255)])


def pose(rr, T):
    T = np.asarray(T, float)
    return rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3])


def log_result(rec, result, source=None) -> None:
    """Log a :class:`~calibgraph.solver.output.result.Result` and optionally its Problem/Dataset into a
    rerun RecordingStream ``rec``."""
    rr = import_rerun()
    result = as_result(result, "view")
    obs = observations(source) if source is not None else None
    ref = result.ref_frame
    eih = result.mode == "eye_in_hand"
    names = list(result.calibrated)

    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log("world/robot_base", axes(rr, 0.2), static=True)

    # flange poses: refined ones from the result, else the recorded ones
    flange = dict(result.T_base_flange_est)
    if not flange and obs is not None:
        flange = dict(obs["T_base_flange"])
    if flange:
        P = np.array([T[:3, 3] for _, T in sorted(flange.items())])
        rec.log("world/flange_path", rr.Points3D(P, radii=0.004, colors=(150, 150, 150)), static=True)
        rec.log("world/flange", axes(rr, 0.08), static=True)

    pts = obs["points_board_m"] if obs is not None else None
    T_mount = result.T_mount_board
    if T_mount is None:  # 'single' method: every camera has its own; show the first
        T_mount = next((c.T_mount_board for c in result.cameras.values() if c.T_mount_board is not None), None)
    board_path = "world/board" if eih else "world/flange/board"
    if T_mount is not None:
        rec.log(board_path, pose(rr, T_mount), static=True)
        rec.log(board_path + "/axes", axes(rr, 0.05), static=True)
        if pts is not None:
            rec.log(board_path + "/points", rr.Points3D(pts, radii=0.003, colors=(20, 20, 20)), static=True)

    cam_root = "world/flange" if eih else "world/cameras"
    intr = {}
    for n, c in result.calibrated.items():
        T = c.T_ref_cam
        rec.log(f"{cam_root}/{n}", pose(rr, T), static=True)
        rec.log(f"{cam_root}/{n}/axes", axes(rr, 0.1), static=True)
        K = c.solved_intrinsics or (obs["cameras"].get(n) if obs is not None else None)
        intr[n] = K
        if K is not None:
            rec.log(f"{cam_root}/{n}/image", rr.Pinhole(image_from_camera=K.K, resolution=[K.width_px, K.height_px],
                                                         camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.3),
                    static=True)
        rec.log(f"{cam_root}/{n}/label", rr.TextDocument(
            f"{n}: T_{ref}_cam t = {np.round(T[:3, 3], 4).tolist()} m; 1σ {np.round(c.sigma_translation_mm, 3).tolist()} mm, "
            f"{np.round(c.sigma_rotation_deg, 4).tolist()} deg; RMS {c.reprojection_rms_px:.3f} px"),
            static=True)

    residuals, _ = report_residuals(result, source)
    images = {}
    if obs is not None:
        images = {(cam, k): img for cam, k, _ids, _uv, img in obs["views"] if img}

    caps = sorted(set(flange) | {k for r in residuals.values() for k in r})
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
            rec.log("world/flange", pose(rr, flange[k]))
        for n in names:
            _log_view(rec, rr, f"{cam_root}/{n}/image", n, k, (residuals.get(n) or {}).get(k), images.get((n, k)),
                      intr.get(n))

    lines = [f"# calibgraph result ({result.mode}, {result.method})", "",
             "| camera | t (m) | 1σ t (mm) | 1σ r (deg) | RMS px | views |", "|---|---|---|---|---|---|"]
    for n, c in result.calibrated.items():
        lines.append(f"| {n} | {np.round(c.T_ref_cam[:3, 3], 4).tolist()} | "
                     f"{np.round(c.sigma_translation_mm, 3).tolist()} | "
                     f"{np.round(c.sigma_rotation_deg, 4).tolist()} | {c.reprojection_rms_px:.3f} | "
                     f"{c.views_used} used, {len(c.views_rejected)} rejected |")
    lines += [f"| {n} | not calibrated: {why} | | | | |" for n, why in result.not_calibrated.items()]
    lines += ["", *summary_markdown(result)]
    rec.log("summary", rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN), static=True)


def _log_view(rec, rr, base: str, n: str, k: int, v: dict | None, img, intr) -> None:
    """One camera at one capture: its image, detected and reprojected corners, residuals, outliers."""
    if img and Path(img).is_file() and intr is not None:
        rec.log(base, rr.EncodedImage(path=img))
    if v is None:
        # nothing seen at this capture: clear the overlays from the previous one
        for sub in ("detected", "reprojected", "residual_x20", "outliers"):
            rec.log(f"{base}/{sub}", rr.Clear(recursive=False))
        return
    ids = np.asarray(v["ids"], int)
    r = np.asarray(v["residual_px"], float).reshape(-1, 2)
    norm = np.linalg.norm(r, axis=1)
    bad = np.asarray(v["weight"]) == 0
    view_rejected = bool(v["rejected"])
    good = ~bad & (not view_rejected)
    if good.any():
        rec.log(f"residuals/{n}/rms_px", rr.Scalars(float(np.sqrt(np.mean(norm[good] ** 2)))))
        rec.log(f"residuals/{n}/max_px", rr.Scalars(float(norm[good].max())))
    if view_rejected:
        rec.log(f"residuals/{n}/rejected", rr.Scalars(float(np.sqrt(np.mean(norm ** 2)))))
    if intr is None:
        return
    uv = np.asarray(v["uv_detected_px"], float).reshape(-1, 2)
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


def plan_log_path(source):
    """``plan_log.json`` beside a dataset (folder path or Dataset with a ``root``), or None."""
    root = source if isinstance(source, (str, Path)) else getattr(source, "root", None)
    if root is None:
        return None
    p = Path(root) / PLAN_LOG_NAME
    return p if p.is_file() else None


def _load_plan_log(plan_log) -> dict | None:
    if plan_log is None or isinstance(plan_log, dict):
        return plan_log
    import json

    try:
        return json.loads(read_input_bytes(plan_log, "plan log"))
    except (OSError, ValueError) as e:
        raise InputError(f"{plan_log}: cannot read the plan log ({type(e).__name__}: {e}).") from None


def viridis(x) -> np.ndarray:
    """(N, 3) uint8 viridis colours of scores scaled to [0, 1]."""
    return np.array([[int(c[i:i + 2], 16) for i in (1, 3, 5)] for c in map(colormap, x)], np.uint8).reshape(-1, 3)


def plan_points(step: dict):
    """What :func:`log_plan` shows for one plan-log step: (candidate board centres (N, 3), their
    scores (N,), colours (N, 3) uint8, chosen board centre (3,) or None)."""
    cands = step.get("candidates") or []
    P = np.array([c["board_centre_m"] for c in cands], float).reshape(-1, 3)
    score = np.array([c.get("score", 0.0) for c in cands], float)
    if len(score):
        lo, hi = float(score.min()), float(score.max())
        colours = viridis((score - lo) / (hi - lo) if hi > lo else np.ones_like(score))
    else:
        colours = np.zeros((0, 3), np.uint8)
    chosen = step.get("chosen_board_centre_m") or step.get("board_centre_m")
    if not chosen and step.get("T_base_flange") is not None:  # logs without board centres: the flange
        chosen = np.asarray(step["T_base_flange"], float)[:3, 3]
    return P, score, colours, (None if chosen is None or len(chosen) != 3 else np.asarray(chosen, float))


def log_plan(rec, plan_log) -> int:
    """Log an autonomous run's plan (``plan_log.json`` dict or path) into the rerun RecordingStream
    ``rec``: per step the candidates coloured by score and the chosen pose (see the module
    docstring). Returns the number of steps logged."""
    rr = import_rerun()
    log = _load_plan_log(plan_log) or {}
    names = list(log.get("cameras") or [])
    for i, n in enumerate(names):
        rec.log(f"plan/sigma_mm/{n}", rr.SeriesLines(colors=[PALETTE[i % len(PALETTE)]], names=[f"{n} 1σ mm"]),
                static=True)
    path = []
    steps = sorted(log.get("steps") or [], key=lambda s: s.get("step", 0))
    for s in steps:
        rec.set_time("capture", sequence=int(s["step"]))
        P, score, colours, chosen = plan_points(s)
        if len(P):
            rec.log("world/plan/candidates", rr.Points3D(P, colors=colours, radii=0.008,
                                                         labels=[f"{v:.3g}/s" for v in score]))
        else:
            rec.log("world/plan/candidates", rr.Clear(recursive=False))
        if chosen is not None:
            seen = ", ".join(s.get("seen_by") or []) or "no camera"
            rec.log("world/plan/chosen", rr.Points3D([chosen], colors=RED, radii=0.02,
                                                     labels=[f"{s.get('label', '')} ({seen})"]))
            if s.get("status") in ("captured", "no_views", "recovered"):
                path.append(chosen)
        if len(path) > 1:
            rec.log("world/plan/chosen_path", rr.LineStrips3D([np.array(path)], colors=(120, 120, 120), radii=0.002))
        rec.log("plan/log", rr.TextLog(f"step {s['step']} [{s.get('phase', '')}] {s.get('label', '')}: "
                                       f"{s.get('status', '')}; {s.get('why', '')}"))
        for n, v in (s.get("achieved") or {}).items():
            if v:
                rec.log(f"plan/sigma_mm/{n}", rr.Scalars(float(v[0])))
    return len(steps)


def default_blueprint(result, plan: bool = False):
    """Viewer layout: the 3D cell on the left; each camera's image with detected/reprojected corners
    and the residual time series on the right; with ``plan`` the autonomous run's 1-sigma series
    and step log too."""
    import rerun.blueprint as rrb

    cam_root = "world/flange" if result.mode == "eye_in_hand" else "world/cameras"

    images = []
    for n, c in result.calibrated.items():
        intr = c.solved_intrinsics
        # show the whole image, so where the corners fall in the frame is visible even without images
        bounds = (rrb.VisualBounds2D(x_range=[-0.5, intr.width_px - 0.5], y_range=[-0.5, intr.height_px - 0.5])
                  if intr is not None and intr.width_px > 0 else None)
        images.append(rrb.Spatial2DView(origin=f"{cam_root}/{n}/image", visual_bounds=bounds,
                                        name=f"{n}: detected (green) vs reprojected (magenta)"))
    right = rrb.Vertical(rrb.Grid(*images), rrb.TimeSeriesView(origin="residuals", name="residuals per capture (px)"),
                         row_shares=[2, 1])
    if plan:
        right = rrb.Vertical(rrb.Grid(*images), rrb.TimeSeriesView(origin="residuals", name="residuals per capture (px)"),
                             rrb.TimeSeriesView(origin="plan/sigma_mm", name="1σ per camera (mm) after each step"),
                             row_shares=[2, 1, 1])
    left = rrb.Vertical(rrb.Spatial3DView(origin="world", name="workcell (robot base frame)"),
                        rrb.TextDocumentView(origin="summary", name="summary"), row_shares=[3, 1])
    if plan:
        left = rrb.Vertical(rrb.Spatial3DView(origin="world", name="workcell (robot base frame); plan: candidates by "
                                                                    "score, chosen in red"),
                            rrb.TextLogView(origin="plan/log", name="plan steps"),
                            rrb.TextDocumentView(origin="summary", name="summary"), row_shares=[3, 1, 1])
    return rrb.Blueprint(rrb.Horizontal(left, right, column_shares=[1, 1]), collapse_panels=False)


def write_rrd(result, problem_or_dataset=None, path="calibgraph.rrd", plan_log=None) -> Path:
    """Save a rerun recording of ``result`` (a :class:`~calibgraph.solver.output.result.Result`) to ``path``.

    ``problem_or_dataset`` (a Problem, a Dataset or a dataset folder) adds the images, the
    detections (when the result has no ``residuals`` section) and the recorded flange poses.
    ``plan_log`` (dict or path; default: the dataset folder's ``plan_log.json`` when there is one)
    adds the autonomous run's candidates and choices (:func:`log_plan`).
    The file is written without a viewer; open it with ``rerun path``.
    """
    rr = import_rerun()
    R = as_result(result, "view")
    plan = _load_plan_log(plan_log if plan_log is not None else plan_log_path(problem_or_dataset))

    def write(tmp: Path) -> None:
        rec = rr.RecordingStream("calibgraph")
        rec.save(str(tmp), default_blueprint=default_blueprint(R, plan=bool(plan)))
        try:
            log_result(rec, R, problem_or_dataset)
            if plan:
                log_plan(rec, plan)
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
