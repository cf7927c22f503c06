"""All GTSAM keys of the calibration graph, in one place.

    C(c)  pose of camera c in the reference frame: T_base_cam (eye-to-hand) or T_flange_cam (eye-in-hand)
    B(m)  board mount m: T_flange_board (eye-to-hand) or T_base_board (eye-in-hand); m = 0 in 'joint'
          mode, m = camera index in 'single' mode
    K(c)  intrinsics [fx, fy, cx, cy] of camera c (only with refine_intrinsics)
    F(k)  robot pose of capture k with its forward-kinematics prior: T_base_flange (eye-to-hand) or
          T_flange_base (eye-in-hand)
"""

from gtsam.symbol_shorthand import B, C, F, K  # noqa: F401

__all__ = ["B", "C", "F", "K"]
