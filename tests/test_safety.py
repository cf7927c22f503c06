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


# -- static cell geometry and the stated pose (issue 16) ---------------------------------------------
def _pose_trajectory(n=20, seed=3):
    """``n`` reachable Franka poses around a presentation posture, each stating its FK flange pose."""
    from calibgraph.acquire.safety import default_cell_limits, geometry_problems
    from calibgraph.plan.trajectory import Trajectory, TrajectoryPose

    lim = default_cell_limits()
    rng = np.random.default_rng(seed)
    base = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785])
    poses = []
    while len(poses) < n:
        q = base + rng.uniform(-0.3, 0.3, 7)
        if not joint_problems(q, lim) and not geometry_problems(franka_fk(q), lim):
            poses.append(TrajectoryPose(q_rad=q, T_base_flange=franka_fk(q)))
    return Trajectory(tuple(poses), speed_scale=0.2)


def _flange_into_pedestal(traj, k):
    """The issue's edit: joint 2 of pose ``k`` changed (1.3 rad), its stated T_base_flange kept."""
    from calibgraph.plan.trajectory import Trajectory, TrajectoryPose

    poses = list(traj.poses)
    q = poses[k].q_rad.copy()
    q[1] = 1.3
    poses[k] = TrajectoryPose(q_rad=q, T_base_flange=poses[k].T_base_flange)
    return Trajectory(tuple(poses), speed_scale=traj.speed_scale), q


def test_stated_pose_against_fk_and_the_pedestal():
    from calibgraph.acquire.safety import default_cell_limits, geometry_problems

    lim = default_cell_limits()
    traj = _pose_trajectory(3)
    bad, q = _flange_into_pedestal(traj, 1)
    p = franka_fk(q)[:3, 3]
    assert lim.pedestal.contains(p[None])[0] and p[2] < 0  # the edit really puts the flange in the pedestal
    # stated pose kept: refused because FK of the joints disagrees with it (by the distance between the two)
    v = check_motion(traj.poses[0].q_rad, q, lim, fk=franka_fk, T_goal_stated=bad.poses[1].T_base_flange)
    dist_mm = 1e3 * np.linalg.norm(p - bad.poses[1].T_base_flange[:3, 3])
    assert not v.ok and "stated T_base_flange" in v.message and f"{dist_mm:.0f} mm" in v.message
    # stated pose updated to the FK: refused because the flange is inside the pedestal
    v = check_motion(traj.poses[0].q_rad, q, lim, fk=franka_fk, T_goal_stated=franka_fk(q))
    assert not v.ok and "inside the pedestal" in v.message
    # no FK at all: the stated pose is checked against the geometry
    v = check_motion(None, q, SafetyLimits(q_min_rad=lim.q_min_rad, q_max_rad=lim.q_max_rad,
                                           pedestal=lim.pedestal, floor_z_m=lim.floor_z_m), T_goal_stated=franka_fk(q))
    assert not v.ok and "pedestal" in v.message
    # floor and declared boxes
    T = np.eye(4)
    T[:3, 3] = [0.6, 0.0, -0.78]
    assert any("floor" in r for r in geometry_problems(T, lim))
    lim2 = SafetyLimits.from_dict({"robot_model": "fr3", "boxes": [{"name": "table", "centre_m": [0.6, 0, 0.1],
                                                                    "size_m": [0.4, 0.4, 0.2]}]})
    T[:3, 3] = [0.6, 0.1, 0.22]  # 2 cm above the table top: inside the 5 cm clearance
    assert geometry_problems(T, lim2) and "table" in geometry_problems(T, lim2)[0]
    T[:3, 3] = [0.6, 0.1, 0.30]
    assert geometry_problems(T, lim2) == []
    with pytest.raises(InputError, match="pedestal"):
        SafetyLimits.from_dict({"pedestal": "big"})


def test_dry_run_refuses_the_pose_inside_the_pedestal(tmp_path, capsys):
    """The issue's case end to end: a workcell without a safety section, a 20-pose trajectory with one
    joint of pose 7 edited; the dry run warns about the default cell model and refuses pose 7 only."""
    import yaml

    from calibgraph.cli.main import main
    from calibgraph.plan.trajectory import save_trajectory

    bad, _ = _flange_into_pedestal(_pose_trajectory(20), 7)
    save_trajectory(bad, tmp_path / "traj.yaml")
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump({"board": "a4_54", "robot": {"driver": "franka",
                                                                                    "ip": "127.0.0.1"}}))
    rc = main(["capture", "--workcell", str(tmp_path / "cell.yaml"), "--trajectory", str(tmp_path / "traj.yaml"),
               "--out", str(tmp_path / "ds"), "--dry-run"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert "declares no safety: section" in cap.err and "pedestal" in cap.err
    assert "19/20 poses pass" in cap.err
    assert "pose 7: would be skipped" in cap.err and "stated T_base_flange" in cap.err
    assert not (tmp_path / "ds").exists()  # a dry run writes nothing


def test_auto_dry_run_warns_of_a_missing_safety_section_as_a_trajectory_run_does(tmp_path, capsys):
    """`capture --auto --dry-run` on the same cell said nothing of the default cell model that
    `capture --trajectory --dry-run` warns about."""
    import yaml

    from calibgraph.cli.main import main

    (tmp_path / "cell.yaml").write_text(yaml.safe_dump({"board": "a4_54", "robot": {"driver": "franka", "ip": "127.0.0.1"},
                                                        "cameras": {"cam0": {"driver": "realsense", "serial": "1"}}}))
    assert main(["capture", "--auto", "--workcell", str(tmp_path / "cell.yaml"), "--out", str(tmp_path / "ds"),
                 "--dry-run"]) == 0
    err = capsys.readouterr().err
    assert "declares no safety: section" in err and "pedestal" in err
    assert not (tmp_path / "ds").exists()
