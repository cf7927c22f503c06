"""What fixes a failing check: one step per failed tolerance of a camera, with its numbers.

A camera that FAILs is told what to do about each failing check, not only that it failed: too few
views says how many more poses (at the rate the camera saw the board in this capture) and where in
its image they should put the board (the parts of the image its corners never reached), and with
which command; a 1σ over its limit points at the camera's advice (the step that shrinks it most, with
the 1σ it would bring); a reprojection error over its limit says where to look.
"""

from __future__ import annotations

import math

import numpy as np

from calibgraph.solver.camera.session_plan import shown_path

# the image in thirds, named as a user says where the board should go
_THIRDS_V = ("top", "middle", "bottom")
_THIRDS_U = ("left", "centre", "right")


def unseen_regions(residuals: dict, width_px: float | None, height_px: float | None) -> list:
    """The ninths of the image (``top-left`` ... ``bottom-right``, ``centre``) where the camera's
    used corners (its residual records, camera -> capture -> record) never fell; [] when all were
    reached or nothing is known."""
    uv = [np.asarray(v["uv_detected_px"], float).reshape(-1, 2) for v in (residuals or {}).values()
          if v.get("uv_detected_px") is not None and len(v["uv_detected_px"])]
    if not uv or not width_px or not height_px:
        return []
    uv = np.concatenate(uv)
    iu = np.clip((3 * uv[:, 0] / width_px).astype(int), 0, 2)
    iv = np.clip((3 * uv[:, 1] / height_px).astype(int), 0, 2)
    seen = set(zip(iv.tolist(), iu.tolist()))
    out = []
    for r in range(3):
        for k in range(3):
            if (r, k) not in seen:
                out.append("centre" if (r, k) == (1, 1) else _THIRDS_U[k] if r == 1 else
                           _THIRDS_V[r] if k == 1 else f"{_THIRDS_V[r]}-{_THIRDS_U[k]}")
    return out


def _capture_step(run: dict, n_more: int, n_captures: int | None) -> str:
    """How to take more poses, by what made the dataset (``made_by``)."""
    mode = (run or {}).get("mode")
    cell = (run or {}).get("workcell_file")
    wc = shown_path(cell) if cell else "CELL.yaml"
    if mode == "sim":
        total = (n_captures or 0) + n_more
        return f"calibgraph sim --workcell {wc} --poses {total} --out NEW_DATASET, then solve that"
    if mode == "auto":
        return (f"calibgraph capture --auto --workcell {wc} ... with a larger --max-poses (it plans the poses that "
                "camera needs), then solve that")
    return ("add them to the trajectory and capture it again (calibgraph capture --workcell "
            f"{wc} --trajectory T.yaml --out NEW_DATASET), or let calibgraph capture --auto plan them; then solve")


def fixes(name: str, cam, verdict: dict, residuals: dict | None = None, intr=None, run: dict | None = None,
          n_captures: int | None = None) -> list:
    """One line per failing check of camera ``name`` saying what would fix it (``verdict``:
    :func:`~calibgraph.report.tolerances.camera_verdict`'s; ``residuals``: its residual records;
    ``intr``: its intrinsics, for the image size; ``run``: the dataset's ``made_by``; ``n_captures``:
    the dataset's captures)."""
    out = []
    for key, value, limit in verdict.get("failed", []):
        if key == "min_views_used":
            used, need = int(value), max(int(math.ceil(float(limit) - float(value))), 1)
            seen = used + len(getattr(cam, "views_rejected", ()) or ())
            rate = f"{need} pose{'s that show' if need != 1 else ' that shows'} it the whole board"
            if n_captures and seen:
                more = int(math.ceil(need * n_captures / seen))
                if more > need:
                    rate += (f" (at the rate it saw the board here, {seen} of {n_captures} poses: about {more} more "
                             "poses)")
                need_poses = more
            else:
                need_poses = need
            w, h = (intr.width_px, intr.height_px) if intr is not None else (None, None)
            gaps = unseen_regions(residuals, w, h)
            where = (f", with the board where its image has no corner yet: {', '.join(gaps)}" if gaps else
                     ", the board spread over its image, near and far, tilted")
            out.append(f"{name}: {need} more view{'s' if need != 1 else ''} needed (it has {used}; the tolerance asks "
                       f"for {float(limit):g}): take {rate}{where}: {_capture_step(run, need_poses, n_captures)}.")
        elif key in ("max_sigma_translation_mm", "max_sigma_rotation_deg", "max_workspace_sigma_mm"):
            what = {"max_sigma_translation_mm": f"its 1σ translation {value:.3g} mm",
                    "max_sigma_rotation_deg": f"its 1σ rotation {value:.3g} deg",
                    "max_workspace_sigma_mm": f"its worst 1σ point error in the workspace, {value:.3g} mm,"}[key]
            adv = str((getattr(cam, "error_budget", None) or {}).get("advice") or "")
            out.append(f"{name}: {what} is over the limit of {float(limit):g}: "
                       + ("the step that shrinks it most is its advice under 'What would improve this calibration'."
                          if adv else "more poses, near and far along its line of sight and tilted, shrink it."))
        elif key == "max_reprojection_rms_px":
            out.append(f"{name}: its corners miss their fit by {value:.3g} px RMS (limit {float(limit):g}): a view that "
                       "stands out in its residual plot is a bad capture (take it again); all views high points at "
                       "blur or focus, a board that is not flat, or intrinsics that do not fit (the solver's notes on it).")
        elif key == "max_reprojection_max_px":
            out.append(f"{name}: one corner misses by {value:.3g} px (limit {float(limit):g}): the residual plot per "
                       "capture shows which view; take that pose again, or check its image for a reflection or a "
                       "partly hidden board.")
        elif key == "covariance":
            out.append(f"{name}: the result has no usable covariance ({value}): solve the dataset again with "
                       "calibgraph solve.")
        elif key == "calibrated":
            out.append(f"{name}: not calibrated; its section says why and what it needs.")
    return out
