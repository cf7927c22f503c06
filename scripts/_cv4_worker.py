"""OpenCV 4.x hand-eye baselines for ``scripts/bench_solver.py``, run inside a separate venv.

OpenCV 5 dropped ``calibrateHandEye`` / ``calibrateRobotWorldHandEye``; calibgraph must not depend
on OpenCV 4 at run time, so the benchmark runs this worker with ``bench_out/.venv-cv4/bin/python``.
It imports nothing from calibgraph (only numpy and cv2 4.x).

Input ``.npz`` (written by the benchmark), for every job ``j`` (one camera of one trial)::

    j{j}_A  (n, 4, 4)  T_base_flange[k]  robot poses reported by forward kinematics
    j{j}_B  (n, 4, 4)  T_cam_board[k]    per-view board pose from PnP

Output ``.npz``: ``j{j}_{METHOD}`` (4, 4) estimated ``T_base_cam`` (NaN when OpenCV raised) and
``cv2_version``; for the robot-world methods (SHAH, LI) also ``j{j}_{METHOD}_mount``, their estimate of
the board's pose in its mount (``T_flange_board``; ``T_base_board`` when the caller passes the
inverted poses of an eye-in-hand set, see ``scripts/bench_heldout.py``).

Eye-to-hand conventions (fixed cameras, board on the flange), from OpenCV's documentation:

* ``calibrateHandEye(R_gripper2base, t_gripper2base, R_target2cam, t_target2cam)`` solves
  ``T_base_target = T_base_gripper[k] @ X @ T_cam_target[k]`` for ``X = T_gripper_cam``
  (eye-in-hand). Eye-to-hand has the same form,
  ``T_flange_board = T_flange_base[k] @ T_base_cam @ T_cam_board[k]``, so passing the *inverted*
  robot poses ``T_flange_base[k]`` as "gripper2base" returns ``T_base_cam`` as "cam2gripper".
* ``calibrateRobotWorldHandEye(R_world2cam, t_world2cam, R_base2gripper, t_base2gripper)`` solves
  ``T_cam_world[k] @ T_world_base = T_cam_gripper @ T_gripper_base[k]``. Eye-to-hand:
  ``T_cam_board[k] @ T_board_flange = T_cam_base @ T_base_flange[k]``, so "world" is the board,
  "base" is the flange and "gripper" is the robot base: pass ``T_cam_board[k]`` as world2cam and
  ``T_base_flange[k]`` (not inverted) as base2gripper; "gripper2cam" is ``T_cam_base``.

The benchmark checks both conventions on noise-free data (errors ~0) before trusting any number.
"""

from __future__ import annotations

import sys

import cv2
import numpy as np

HAND_EYE = {
    "TSAI": cv2.CALIB_HAND_EYE_TSAI,
    "PARK": cv2.CALIB_HAND_EYE_PARK,
    "HORAUD": cv2.CALIB_HAND_EYE_HORAUD,
    "ANDREFF": cv2.CALIB_HAND_EYE_ANDREFF,
    "DANIILIDIS": cv2.CALIB_HAND_EYE_DANIILIDIS,
}
ROBOT_WORLD = {
    "SHAH": cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH,
    "LI": cv2.CALIB_ROBOT_WORLD_HAND_EYE_LI,
}


def _T(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, float).reshape(3, 3)
    T[:3, 3] = np.asarray(t, float).reshape(3)
    return T


def _inv(T: np.ndarray) -> np.ndarray:
    R, t = T[:3, :3], T[:3, 3]
    return _T(R.T, -R.T @ t)


def solve_job(A: np.ndarray, B: np.ndarray) -> dict:
    """All seven OpenCV estimates of T_base_cam for one camera (NaN where OpenCV raised), and the
    robot-world methods' board mount under ``{METHOD}_mount``."""
    out = {}
    A_inv = [_inv(a) for a in A]
    R_fb = [a[:3, :3] for a in A_inv]
    t_fb = [a[:3, 3].reshape(3, 1) for a in A_inv]
    R_cb = [b[:3, :3] for b in B]
    t_cb = [b[:3, 3].reshape(3, 1) for b in B]
    for name, flag in HAND_EYE.items():
        try:
            R, t = cv2.calibrateHandEye(R_fb, t_fb, R_cb, t_cb, method=flag)
            T = _T(R, t)
            out[name] = T if np.all(np.isfinite(T)) else np.full((4, 4), np.nan)
        except cv2.error:
            out[name] = np.full((4, 4), np.nan)
    R_bf = [a[:3, :3] for a in A]
    t_bf = [a[:3, 3].reshape(3, 1) for a in A]
    for name, flag in ROBOT_WORLD.items():
        try:
            R_fl_bd, t_fl_bd, R_cam_base, t_cam_base = cv2.calibrateRobotWorldHandEye(R_cb, t_cb, R_bf, t_bf,
                                                                                     method=flag)
            T = _inv(_T(R_cam_base, t_cam_base))
            M = _inv(_T(R_fl_bd, t_fl_bd))  # "base2world" is T_board_flange here: its inverse is the mount
            ok = np.all(np.isfinite(T)) and np.all(np.isfinite(M))
            out[name] = T if ok else np.full((4, 4), np.nan)
            out[f"{name}_mount"] = M if ok else np.full((4, 4), np.nan)
        except cv2.error:
            out[name] = np.full((4, 4), np.nan)
            out[f"{name}_mount"] = np.full((4, 4), np.nan)
    return out


def main(argv) -> int:
    if len(argv) != 3:
        print("usage: _cv4_worker.py IN.npz OUT.npz", file=sys.stderr)
        return 2
    data = np.load(argv[1])
    jobs = sorted({int(k[1:].split("_")[0]) for k in data.files if k.startswith("j")})
    res = {"cv2_version": np.array(cv2.__version__)}
    for j in jobs:
        for name, T in solve_job(data[f"j{j}_A"], data[f"j{j}_B"]).items():
            res[f"j{j}_{name}"] = T
    np.savez(argv[2], **res)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
