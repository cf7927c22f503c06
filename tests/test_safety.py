"""Safety checks: Franka FK, joint limits with margin, the workspace box along the joint path,
the speed cap, and refusal when the workspace cannot be checked."""

import numpy as np
import pytest

from calibgraph.acquire.safety import (
    FRANKA_LIMITS,
    SafetyLimits,
    UnsafeTargetError,
    check_motion,
    check_speed,
    franka_fk,
    joint_problems,
    workspace_problems,
)
from calibgraph.core.errors import InputError


def test_franka_fk_matches_libfranka_flange_at_the_default_pose():
    # franky-sim's FR3 at its start pose reports O_T_EE with the hand (F_T_EE = 0.1034 m along z,
    # -45 deg about z); O_T_EE @ inv(F_T_EE) gives the flange at x 0.5544 m, z 0.6248 m, z axis down.
    T = franka_fk([0.0, 0.0, 0.0, -1.57, 0.0, 1.57, 0.785])
    np.testing.assert_allclose(T[:3, 3], [0.5544, 0.0, 0.6248], atol=2e-4)
    np.testing.assert_allclose(T[:3, 2], [0, 0, -1], atol=1e-3)
    # zero pose: all links stacked, flange z = 0.333 + 0.316 + 0.384 - 0.107 (link 7 points down)
    T0 = franka_fk(np.zeros(7))
    np.testing.assert_allclose(T0[:3, 3], [0.088, 0.0, 0.333 + 0.316 + 0.384 - 0.107], atol=1e-9)
    np.testing.assert_allclose(T0[:3, :3] @ T0[:3, :3].T, np.eye(3), atol=1e-12)


def test_limits_from_dict_with_robot_model_and_margin():
    lim = SafetyLimits.from_dict({"robot_model": "fr3", "joint_margin_rad": 0.1, "max_speed_scale": 0.25,
                                  "workspace_min_m": [0.2, -0.5, 0.1], "workspace_max_m": [0.8, 0.5, 1.0]})
    assert lim.kinematics == "franka"
    np.testing.assert_allclose(lim.q_min_rad, FRANKA_LIMITS["fr3"]["q_min_rad"])
    q = np.array([0, 0, 0, -1.57, 0, 1.57, 0.785])
    assert joint_problems(q, lim) == []
    q_bad = q.copy()
    q_bad[5] = 0.6  # FR3 joint 6 lower limit 0.5445 + 0.1 margin
    probs = joint_problems(q_bad, lim)
    assert len(probs) == 1 and probs[0].startswith("joint 6")
    again = SafetyLimits.from_dict(lim.to_dict())
    np.testing.assert_allclose(again.workspace_max_m, lim.workspace_max_m)
    with pytest.raises(InputError, match="unknown keys"):
        SafetyLimits.from_dict({"max_sped_scale": 0.2})
    with pytest.raises(InputError, match="both"):
        SafetyLimits.from_dict({"workspace_min_m": [0, 0, 0]})
    with pytest.raises(InputError, match="below"):
        SafetyLimits.from_dict({"workspace_min_m": [0, 0, 0], "workspace_max_m": [1, -1, 1]})


def test_speed_cap():
    lim = SafetyLimits(max_speed_scale=0.3)
    check_speed(0.3, lim)
    with pytest.raises(UnsafeTargetError, match="exceeds"):
        check_speed(0.31, lim)
    with pytest.raises(UnsafeTargetError):
        check_speed(float("nan"), lim)


def test_workspace_checked_along_the_franka_joint_path():
    lim = SafetyLimits.from_dict({"robot_model": "fr3", "workspace_min_m": [0.3, -0.4, 0.3],
                                  "workspace_max_m": [0.8, 0.4, 0.9]})
    a = np.array([0.6, 0, 0, -1.57, 0, 1.57, 0.785])
    b = np.array([-0.6, 0, 0, -1.57, 0, 1.57, 0.785])
    from calibgraph.acquire.safety import fk_function

    fk = fk_function(None, lim)
    # joint 1 swings the flange on an arc of radius 0.5544 m: ends at y = +-0.31 m, x = 0.458 m
    assert workspace_problems(fk(a), lim) == [] and workspace_problems(fk(b), lim) == []
    v = check_motion(a, b, lim, fk=fk)
    assert v.ok
    tight = SafetyLimits.from_dict({"robot_model": "fr3", "workspace_min_m": [0.5, -0.4, 0.3],
                                    "workspace_max_m": [0.8, 0.4, 0.9]})
    # the ends are at x = 0.5544 cos(0.6) = 0.4576 < 0.5: refused at the goal
    v = check_motion(a, a, tight, fk=fk)
    assert not v.ok and "goal flange" in v.message
    # both ends inside a box whose x range (< 0.5 m) excludes the middle of the arc (x = 0.5544 m)
    c = np.array([0.0, 0, 0, -1.57, 0, 1.57, 0.785])
    ring = SafetyLimits.from_dict({"robot_model": "fr3", "workspace_min_m": [0.0, -0.4, 0.3],
                                   "workspace_max_m": [0.5, 0.4, 0.9]})
    v = check_motion(a, b, ring, fk=fk)
    assert not v.ok and "% of the path" in v.message
    assert not check_motion(None, c, ring, fk=fk).ok


def test_without_kinematics_the_box_cannot_be_assumed_clear():
    lim = SafetyLimits(workspace_min_m=[0, 0, 0], workspace_max_m=[1, 1, 1])
    v = check_motion(np.zeros(6), np.ones(6) * 0.1, lim, fk=None)
    assert not v.ok and "cannot check the workspace" in v.message
    T = np.eye(4)
    T[:3, 3] = [0.5, 0.5, 0.5]
    v = check_motion(np.zeros(6), np.ones(6) * 0.1, lim, fk=None, T_goal_stated=T)
    assert v.ok and "path not checked" in v.message
    T[0, 3] = 1.5
    assert not check_motion(None, np.ones(6) * 0.1, lim, fk=None, T_goal_stated=T).ok
    # tool radius shrinks the box
    T[0, 3] = 0.95
    assert check_motion(None, np.ones(6), lim, T_goal_stated=T).ok
    lim_r = SafetyLimits(workspace_min_m=[0, 0, 0], workspace_max_m=[1, 1, 1], tool_radius_m=0.1)
    assert not check_motion(None, np.ones(6), lim_r, T_goal_stated=T).ok
    assert joint_problems([0.0, float("nan")], lim_r) == ["joint target contains NaN/inf"]
