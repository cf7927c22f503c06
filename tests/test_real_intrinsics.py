"""Real data (industrial_calibration's ChArUco set): its published intrinsics carry no distortion,
and the residuals show it. Refining [fx, fy, cx, cy, k1, k2] must explain them.

Measured: fixed intrinsics 2.32 px RMS; refined 0.65 px with k1 = -0.118, camera moved 6.6 mm.
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


def test_refining_intrinsics_explains_the_real_residuals(rct_dir, tmp_path):
    fixed, stdout = _solve(rct_dir, tmp_path / "fixed.json")
    assert "--refine-intrinsics" in stdout  # the hint appears for large residuals
    refined, _ = _solve(rct_dir, tmp_path / "refined.json", "--refine-intrinsics", "--quiet")
    cf, cr = fixed["cameras"]["camera"], refined["cameras"]["camera"]
    assert cf["reprojection_rms_px"] > 2.0
    assert cr["reprojection_rms_px"] < 0.5 * cf["reprojection_rms_px"]
    k1 = cr["intrinsics"]["dist"][0]
    assert -0.2 < k1 < -0.05  # barrel distortion, as expected of this lens
    # the camera moves by a few mm, consistent with the change of model, not by a gross amount
    move = np.linalg.norm(np.array(cr["T_base_cam"])[:3, 3] - np.array(cf["T_base_cam"])[:3, 3])
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
