"""Per-corner residuals for the report and the viewer, and whether a dataset is the one a result
was solved from.

A residual record (one camera, one capture) is what :attr:`CameraResult.residuals_px` holds:
``ids`` (N,), ``uv_detected_px`` (N, 2), ``residual_px`` (N, 2) = reprojected - detected (so the
reprojected corner is ``uv_detected + residual``), ``weight`` (N,) of the robust loss (0: the
corner was rejected) and ``rejected`` (the whole view was). A result written without them gets them
recomputed from a dataset's detections and the poses in the result (:func:`compute_residuals`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calibgraph.core.transforms import inv, pose_error
from calibgraph.io.layouts import as_dataset
from calibgraph.solver.output.result import as_result, solved_target, target_differences

# a refined robot pose this far from the recorded one belongs to another capture
FLANGE_MISMATCH_M, FLANGE_MISMATCH_DEG = 0.02, 2.0
# stored corners of one view that differ by more than this are another detection (results written
# before full precision rounded them to 1e-4 px)
CORNER_MISMATCH_PX = 1e-3


def observations(source) -> dict:
    """Normalise a :class:`~calibgraph.core.problem.Problem`, a :class:`~calibgraph.io.dataset.Dataset` or a
    dataset folder into plain data: ``points_board_m`` (M, 3), ``cameras`` (name -> Intrinsics),
    ``T_base_flange`` (capture -> 4x4), ``views`` [(camera, capture, ids, uv_px, image path or None)]."""
    src = as_dataset(source)
    if hasattr(src, "detections"):  # Problem
        views = [(d.camera, d.capture, d.ids, d.uv_px, d.image) for d in src.detections]
        pts = src.points_board_m
    else:  # Dataset: image paths are relative to its root
        views = [(v.camera, v.capture, v.ids, v.uv_px, str(Path(src.root) / v.image) if v.image else None)
                 for v in src.views]
        pts = src.target.points_board_m
    return {"points_board_m": np.asarray(pts, float), "cameras": dict(src.cameras),
            "T_base_flange": {c.index: c.T_base_flange for c in src.captures}, "views": views,
            "mode": getattr(src, "mode", None)}


def compute_residuals(result, source) -> dict:
    """camera -> capture -> residual record, recomputed from the poses in ``result`` (a
    :class:`~calibgraph.solver.output.result.Result`) and the detections of a dataset (folder or
    :class:`~calibgraph.io.dataset.Dataset`) or :class:`~calibgraph.core.problem.Problem`.

    Uses the refined flange poses of the result when present, else the recorded ones, and the
    board as the solver found it printed (its scale factor). Views the solver rejected are flagged
    ``rejected``; corners it rejected get weight 0.
    """
    result = as_result(result, "residuals")
    obs = observations(source)
    pts = obs["points_board_m"] * result.board_scale
    refined = result.T_base_flange_est
    rejected_ids = {}
    for cam, k, i, _r in result.rejected_corners:
        rejected_ids.setdefault((cam, k), set()).add(i)
    out = {}
    for name, cam in result.calibrated.items():
        T_mount_board = result.T_mount_board if result.T_mount_board is not None else cam.T_mount_board
        intr = cam.solved_intrinsics or obs["cameras"].get(name)
        if T_mount_board is None or intr is None:
            continue
        rej = {v.capture for v in cam.views_rejected}
        per = {}
        for cam_name, k, ids, uv, _img in obs["views"]:
            if cam_name != name or ids is None or len(ids) == 0 or k not in obs["T_base_flange"]:
                continue
            T_bf = refined.get(k, obs["T_base_flange"][k])
            if result.mode == "eye_in_hand":
                T_cam_board = inv(T_bf @ cam.T_ref_cam) @ T_mount_board
            else:
                T_cam_board = inv(cam.T_ref_cam) @ T_bf @ T_mount_board
            ids = np.asarray(ids).astype(int)
            uv = np.asarray(uv, float).reshape(-1, 2)
            p = pts[ids] @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
            out_ids = rejected_ids.get((name, k), set())
            per[k] = {"ids": ids, "uv_detected_px": uv, "residual_px": intr.project(p) - uv,
                      "weight": np.array([0.0 if i in out_ids else 1.0 for i in ids]), "rejected": k in rej}
        out[name] = per
    return out


def report_residuals(result, dataset=None) -> tuple[dict, str]:
    """(camera -> capture -> residual record, where they come from): the result's own, else
    recomputed from ``dataset`` when given, else none."""
    if any(c.residuals_px for c in result.cameras.values()):
        return {n: c.residuals_px for n, c in result.cameras.items()}, "the result file"
    if dataset is not None:
        return compute_residuals(result, dataset), "recomputed from the dataset's detections and the poses in the result"
    return {}, ""


def dataset_mismatch(result, dataset) -> list:
    """How ``dataset`` (folder or :class:`~calibgraph.io.dataset.Dataset`) differs from the data
    ``result`` was solved from — cameras, target spec, captures, robot poses, stored corners — one
    phrase each; empty when nothing shows that it is another dataset."""
    result = as_result(result, "report")
    ds = as_dataset(dataset)
    out = []
    rc, dc = set(result.cameras), set(ds.cameras)
    if rc - dc:
        out.append(f"it has no camera {', '.join(sorted(rc - dc))} (the result's cameras: {', '.join(sorted(rc))})")
    if dc - rc:
        out.append(f"its camera(s) {', '.join(sorted(dc - rc))} are not in the result")
    solved = solved_target(result)
    if solved is not None and target_differences(solved, ds.target):
        out.append("its target has " + ", ".join(target_differences(solved, ds.target)))
    used_caps = set(result.T_base_flange_est) | {k for c in result.cameras.values() for k in c.residuals_px} | {
        v.capture for v in result.rejected_views}
    recorded = {c.index: c.T_base_flange for c in ds.captures}
    missing = sorted(used_caps - set(recorded))
    if missing:
        out.append(f"{len(missing)} of the result's {len(used_caps)} captures are not in it (e.g. {missing[0]})")
    far = [k for k, T in result.T_base_flange_est.items() if k in recorded and _far(T, recorded[k])]
    if far:
        out.append(f"the robot poses of {len(far)} captures are more than {FLANGE_MISMATCH_M * 100:g} cm or "
                   f"{FLANGE_MISMATCH_DEG:g}° from the result's (e.g. capture {far[0]})")
    differ, compared = 0, 0
    for v in ds.views:
        rec = result.cameras[v.camera].residuals_px.get(v.capture) if v.camera in result.cameras else None
        if rec is None or v.ids is None:
            continue
        compared += 1
        ids = np.asarray(v.ids).astype(int)
        if not np.array_equal(ids, rec["ids"]) or np.abs(np.asarray(v.uv_px, float) - rec["uv_detected_px"]).max(
                initial=0.0) > CORNER_MISMATCH_PX:
            differ += 1
    if differ:
        out.append(f"the stored corners of {differ} of {compared} views differ from those the result was solved with")
    n_points = len(ds.target.points_board_m)
    top = max((int(r["ids"].max()) for c in result.cameras.values() for r in c.residuals_px.values() if r["ids"].size),
              default=-1)
    if top >= n_points:
        out.append(f"the result has corner id {top}, beyond its target's {n_points} points")
    return out


def _far(T_a, T_b) -> bool:
    e_m, e_deg = pose_error(T_a, T_b)
    return e_m > FLANGE_MISMATCH_M or e_deg > FLANGE_MISMATCH_DEG
