"""OpenCV 4.x cross-check of a converted real set's pose convention (``scripts/real_sets.py crosscheck``).

Runs inside the OpenCV 4 venv of ``scripts/bench_solver.py`` (OpenCV 5 has no calibrateHandEye) and
imports nothing from calibgraph. Input: a JSON file (argv[1]) written by real_sets.py::

    {"mode": "eye_in_hand" | "eye_to_hand", "target": {kind, rows, cols, pitch_m, ...},
     "K": 3x3 | null, "dist": [...], "size": [w, h],
     "views": [{"image": path, "T_base_flange": 4x4}, ...]}

For each view OpenCV's own detector finds the board (checkerboard: findChessboardCornersSB, its
180-degree ambiguity fixed by the colour of the first square, or for a symmetric board by taking
corner 0 nearest the image's top left; ChArUco: CharucoDetector; asymmetric
circles: findCirclesGrid, on the inverted image when the dots are white on black), calibrateCamera
gives the intrinsics where none are given, solvePnP the board pose. Then, for the poses as written
("direct") and inverted ("inverted"), calibrateHandEye TSAI and PARK, and the AX = XB residual of
PARK's X over all pairs of views (rotation deg, translation mm): the direct convention must give a
residual near the robot's and the detector's own error, the inverted one a far larger one.
Output: JSON on stdout.
"""

from __future__ import annotations

import itertools
import json
import sys

import cv2
import numpy as np


def board_points(t: dict) -> np.ndarray:
    rows, cols, p = int(t["rows"]), int(t["cols"]), float(t["pitch_m"])
    i, j = np.mgrid[0:rows, 0:cols]
    i, j = i.ravel(), j.ravel()
    if t["kind"] == "acircles":
        x, y = p * (2 * j + i % 2), p * i
    elif t["kind"] == "charuco":
        x, y = p * (j + 1), p * (i + 1)
    else:
        x, y = p * j, p * i
    return np.stack([x, y, np.zeros_like(x)], axis=1).astype(np.float64)


def detect(gray: np.ndarray, t: dict):
    """(ids, uv) or None."""
    rows, cols = int(t["rows"]), int(t["cols"])
    if t["kind"] == "checkerboard":
        ok, c = cv2.findChessboardCornersSB(gray, (cols, rows), flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
        if not ok:
            return None
        c = c.reshape(-1, 2)
        # the first square's colour: dark in the canonical order (odd x even boards flip colour under 180 deg)
        q = c[[0, 1, cols + 1, cols]].mean(axis=0)
        q2 = c[[1, 2, cols + 2, cols + 1]].mean(axis=0)
        v1 = float(cv2.getRectSubPix(gray, (5, 5), tuple(map(float, q))).mean())
        v2 = float(cv2.getRectSubPix(gray, (5, 5), tuple(map(float, q2))).mean())
        if (rows + cols) % 2 == 0:  # odd x odd (or even x even): the colours do not tell; corner 0 nearest the top left
            if c[-1].sum() < c[0].sum():
                c = c[::-1].copy()
        elif v1 > v2:
            c = c[::-1].copy()
        return np.arange(rows * cols), c
    if t["kind"] == "charuco":
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, t["dictionary"]))
        board = cv2.aruco.CharucoBoard((cols + 1, rows + 1), float(t["pitch_m"]), float(t["marker_m"]), d)
        if t.get("legacy_charuco"):
            board.setLegacyPattern(True)
        cc, ci, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
        if ci is None or len(ci) < 6:
            return None
        return ci.ravel().astype(int), cc.reshape(-1, 2)
    if t["kind"] == "acircles":
        for img in (gray, 255 - gray):
            ok, c = cv2.findCirclesGrid(img, (cols, rows), flags=cv2.CALIB_CB_ASYMMETRIC_GRID)
            if ok:
                return np.arange(rows * cols), c.reshape(-1, 2)
        return None
    raise SystemExit(f"board kind {t['kind']} not handled by the cross-check")


def inv(T):
    R, t = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def rt(R, t):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, np.asarray(t).ravel()
    return T


def axxb_residual(A_list, B_list, X):
    """Over all pairs (i, j): A_ij X vs X B_ij with A_ij = inv(A_i) A_j, B_ij = B_i inv(B_j)."""
    rot, tr = [], []
    for i, j in itertools.combinations(range(len(A_list)), 2):
        A = inv(A_list[i]) @ A_list[j]
        B = B_list[i] @ inv(B_list[j])
        L, Rr = A @ X, X @ B
        D = inv(Rr) @ L
        rot.append(np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1))))
        tr.append(1e3 * np.linalg.norm(L[:3, 3] - Rr[:3, 3]))
    return float(np.sqrt(np.mean(np.square(rot)))), float(np.sqrt(np.mean(np.square(tr))))


def main():
    job = json.load(open(sys.argv[1]))
    t = job["target"]
    P = board_points(t)
    found = []
    for v in job["views"]:
        g = cv2.imread(v["image"], cv2.IMREAD_GRAYSCALE)
        if g is None:
            continue
        d = detect(g, t)
        if d is not None:
            found.append((np.asarray(v["T_base_flange"], float), d))
    out = {"cv2": cv2.__version__, "views": len(job["views"]), "detected": len(found)}
    if len(found) < 3:
        out["error"] = "fewer than 3 views detected"
        print(json.dumps(out))
        return
    w, h = job["size"]
    if job.get("K") is None:
        obj = [P[ids].astype(np.float32) for _, (ids, _) in found]
        img = [uv.astype(np.float32) for _, (_, uv) in found]
        rms, K, dist, _, _ = cv2.calibrateCamera(obj, img, (w, h), None, None)
        out["calibrateCamera_rms_px"] = round(float(rms), 3)
        out["K"] = np.round(K, 2).tolist()
    else:
        K, dist = np.asarray(job["K"], float), np.asarray(job["dist"], float)
    A_list, B_list, pnp = [], [], []
    for T, (ids, uv) in found:
        ok, rv, tv = cv2.solvePnP(P[ids], uv.astype(np.float64), K, dist)
        proj, _ = cv2.projectPoints(P[ids], rv, tv, K, dist)
        pnp.append(float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - uv) ** 2, axis=1)))))
        A_list.append(T)
        B_list.append(rt(cv2.Rodrigues(rv)[0], tv))
    out["pnp_rms_px_median"] = round(float(np.median(pnp)), 3)
    for conv in ("direct", "inverted"):
        As = [a if conv == "direct" else inv(a) for a in A_list]
        if job["mode"] == "eye_to_hand":
            As = [inv(a) for a in As]  # T_flange_base as "gripper2base": returns T_base_cam
        res = {}
        for m in ("TSAI", "PARK"):
            R, tv = cv2.calibrateHandEye([a[:3, :3] for a in As], [a[:3, 3] for a in As],
                                         [b[:3, :3] for b in B_list], [b[:3, 3] for b in B_list],
                                         method=getattr(cv2, f"CALIB_HAND_EYE_{m}"))
            X = rt(R, tv)
            res[m] = {"t_mm": np.round(1e3 * X[:3, 3], 1).tolist()}
            if m == "PARK":
                r_deg, t_mm = axxb_residual(As, B_list, X)
                res["axxb_rms_deg"], res["axxb_rms_mm"] = round(r_deg, 3), round(t_mm, 2)
        out[conv] = res
    print(json.dumps(out))


if __name__ == "__main__":
    main()
