"""Real data (industrial_calibration's ChArUco set): its published intrinsics carry no distortion,
and the residuals show it. Estimating [fx, fy, cx, cy, k1, k2] must explain them — by default,
with the cause named, as --refine-intrinsics does.

Measured (this detector): --fixed-intrinsics 1.77 px RMS; default 0.52 px with k1 = -0.127 and a
note naming the disagreement (chi-square 254 on 6 dof), pose within 0.1 mm of --refine-intrinsics
(1-sigma 0.12-0.29 mm); the camera moves 4.8 mm from the fixed-intrinsics pose.
"""

import json
import subprocess
import sys

import numpy as np


def _solve(path, out, *flags):
    proc = subprocess.run([sys.executable, "-m", "calibgraph", "solve", str(path), "--out", str(out), *flags],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(out.read_text()), proc.stdout


def test_default_solve_estimates_the_intrinsics_the_data_reject(rct_dir, tmp_path):
    fixed, stdout = _solve(rct_dir, tmp_path / "fixed.json", "--fixed-intrinsics")
    # the cause is said: the views reject the held intrinsics (the residuals' size alone no longer says it: the arm's
    # accuracy is sized before they are judged, and a 2.7 mm robot takes much of the misfit)
    assert "--fixed-intrinsics holds its given intrinsics, but its views reject them" in stdout or \
        "drop --fixed-intrinsics" in stdout
    default, stdout = _solve(rct_dir, tmp_path / "default.json")
    assert "disagree with its given" in stdout  # the cause, in one line
    refined, _ = _solve(rct_dir, tmp_path / "refined.json", "--refine-intrinsics", "--quiet")
    cf, cd, cr = (r["cameras"]["camera"] for r in (fixed, default, refined))
    # Held, the missing distortion shows: in residuals several times the detector's (1.77 px against 0.52 px
    # since ChArUco corners are fitted photometrically; 2.10 px with CharucoDetector's), or, since the arm's
    # accuracy is sized first from what the robot poses alone can explain, in an arm taken for 25x less
    # accurate than stated (0.79 px left)
    fk = fixed["solver"]["settings"] and fixed.get("fk_noise") or {}
    assert (cf["reprojection_rms_px"] > 1.5 and cf["reprojection_rms_px"] > 3.0 * cd["reprojection_rms_px"]) \
        or float(fk.get("applied", 1.0)) > 100.0, (cf["reprojection_rms_px"], fk.get("applied"))
    assert cd["reprojection_rms_px"] < 1.0
    assert cr["reprojection_rms_px"] < 0.5 * cf["reprojection_rms_px"] or float(fk.get("applied", 1.0)) > 100.0
    assert any("disagree" in n for n in default["notes"])
    k1 = cd["intrinsics"]["dist"][0]
    assert -0.2 < k1 < -0.05  # barrel distortion, as expected of this lens
    assert cd["intrinsics"]["estimated"] and set(cd["intrinsics"]["sigma"]) == {"fx", "fy", "cx", "cy", "k1", "k2"}
    # with no flag, the pose agrees with --refine-intrinsics within its 1-sigma, per axis
    d_mm = 1e3 * np.abs(np.array(cd["T_base_cam"])[:3, 3] - np.array(cr["T_base_cam"])[:3, 3])
    assert np.all(d_mm < np.array(cd["sigma_translation_mm"])), (d_mm, cd["sigma_translation_mm"])
    # the camera moves by a few mm from the fixed-intrinsics pose, consistent with the change of model
    move = np.linalg.norm(np.array(cd["T_base_cam"])[:3, 3] - np.array(cf["T_base_cam"])[:3, 3])
    assert move < 0.02


def test_refined_calibration_agrees_with_per_image_pnp_on_all_views(rct_dir, tmp_path):
    """The peer's acceptance (mean difference to per-image PnP < 6 mm / 1.5 deg), on all 16 views
    with no restriction to well-covered ones, once the intrinsics are refined.
    Measured: 1.69 mm / 0.25 deg (fixed intrinsics: 7.26 mm / 1.02 deg)."""
    import cv2

    from calibgraph.core.camera import Intrinsics
    from calibgraph.core.transforms import inv
    from calibgraph.detect.corners import dataset_detector
    from calibgraph.io.layouts import load_dataset

    r, _ = _solve(rct_dir, tmp_path / "refined.json", "--refine-intrinsics", "--quiet")
    cam = r["cameras"]["camera"]
    T_base_cam, T_flange_board = np.array(cam["T_base_cam"]), np.array(r["T_flange_board"])
    ik = cam["intrinsics"]
    intr = Intrinsics(K=np.array(ik["K"]), dist=np.array(ik["dist"]), width_px=ik["width_px"], height_px=ik["height_px"])
    ds = load_dataset(rct_dir)
    det = dataset_detector(ds, progress=False)
    det.run()
    d_mm, d_deg = [], []
    for c in ds.captures:
        d = det.results[("camera", c.index)]
        if not d.ok:
            continue
        T = inv(T_base_cam) @ c.T_base_flange @ T_flange_board
        _, rv, tv = cv2.solvePnP(ds.target.points_board_m[d.ids], d.uv_px, intr.K, intr.dist8,
                                 cv2.Rodrigues(T[:3, :3])[0], T[:3, 3].reshape(3, 1).copy(), useExtrinsicGuess=True)
        R = cv2.Rodrigues(rv)[0]
        d_mm.append(1e3 * np.linalg.norm(tv.ravel() - T[:3, 3]))
        d_deg.append(np.degrees(np.arccos(np.clip((np.trace(R.T @ T[:3, :3]) - 1) / 2, -1, 1))))
    assert len(d_mm) == 16
    assert np.mean(d_mm) < 6.0 and np.mean(d_deg) < 1.5, (np.mean(d_mm), np.mean(d_deg))
