"""All GTSAM keys of the calibration graph, in one place.

``ref`` is the robot base in eye-to-hand and the flange in eye-in-hand; ``mount`` is the other one,
the frame the board is fixed to.

    C(c)  T_ref_cam of camera c (slot c): T_base_cam (eye-to-hand) or T_flange_cam (eye-in-hand)
    B(0)  T_mount_board, the board mount: T_flange_board (eye-to-hand) or T_base_board (eye-in-hand);
          'single' mode builds one graph per camera, each with its own B(0)
    K(c)  intrinsics [fx, fy, cx, cy, k1, k2] of camera c (unless the intrinsics are fixed)
    S(0)  the board's scale factor s (printed points at s * p_board; unless the scale is fixed)
    F(k)  T_ref_mount of capture k, the robot pose with its forward-kinematics prior: T_base_flange
          (eye-to-hand) or T_flange_base (eye-in-hand)
    O(0)  the robot's free joint zero offsets (rad), only with kinematics='joint-offsets'; then F(k) has a
          kinematic factor to O(0) instead of its fixed prior (:mod:`calibgraph.solver.robot.kinematics`)
"""

from gtsam.symbol_shorthand import B, C, F, K, O, S  # noqa: F401

__all__ = ["B", "C", "F", "K", "O", "S"]
