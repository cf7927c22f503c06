"""Trajectory planning on the simulated FR3: IK accuracy, joint limits, collisions, visibility,
and the trajectory file."""

import numpy as np
import pytest
from helpers import require_sim, sim_world_fixture

from calibgraph.core.errors import InputError
from calibgraph.core.transforms import pose_error
from calibgraph.plan.trajectory import Trajectory, TrajectoryPose, load_trajectory
from calibgraph.sim.workcell import ring_workcell

pytestmark = pytest.mark.sim


# the thesis's one-side layout
world = sim_world_fixture(lambda: ring_workcell(n_cameras=3, distance_m=2.0, spread_deg=90.0))


def test_ik_reaches_reachable_targets_within_limits(world):
    from calibgraph.sim.ik import LIMIT_MARGIN_RAD, solve_ik
    from calibgraph.sim.scene import HOME_Q_RAD

    rng = np.random.default_rng(0)
    lo, hi = world.q_lo + LIMIT_MARGIN_RAD, world.q_hi - LIMIT_MARGIN_RAD
    solved = 0
    for _ in range(20):
        q_true = rng.uniform(lo + 0.2, hi - 0.2)
        world.set_q(q_true)
        T = world.T_base_flange()
        q = None
        for seed in (HOME_Q_RAD, q_true + rng.normal(scale=0.3, size=7)):
            q = solve_ik(world, T, seed)
            if q is not None:
                break
        if q is None:
            continue
        solved += 1
        assert np.all(q >= lo - 1e-12) and np.all(q <= hi + 1e-12)
        world.set_q(q)
        e_m, e_deg = pose_error(world.T_base_flange(), T)
        assert e_m < 1e-4 and e_deg < 1e-3
    assert solved >= 15  # a local solver from two seeds; measured 20/20


def test_ik_refuses_unreachable_target(world):
    from calibgraph.sim.ik import solve_ik
    from calibgraph.sim.scene import HOME_Q_RAD

    T = np.eye(4)
    T[:3, 3] = [1.5, 0.0, 0.5]  # FR3 reach is ~0.855 m
    assert solve_ik(world, T, HOME_Q_RAD) is None


def test_planned_poses_are_reachable_free_and_visible(world):
    from calibgraph.plan.planner import plan_trajectory
    from calibgraph.plan.visibility import board_visibility
    from calibgraph.sim.ik import (
        LIMIT_MARGIN_RAD,
        in_collision,
        path_collision,
        start_configuration,
    )

    traj = plan_trajectory(world, 18, seed=4)
    assert traj.n_capture == 18 and len(traj) == 18 + traj.n_via
    views = traj.views_per_camera()
    assert set(views) == set(world.cell.camera_names) and min(views.values()) >= 4
    assert sum(len(p.cameras) > 1 for p in traj.poses) >= 1  # some poses serve two cameras
    q_prev = start_configuration(world)
    for p in traj.poses:
        assert np.all(p.q_rad >= world.q_lo + LIMIT_MARGIN_RAD - 1e-9)
        assert np.all(p.q_rad <= world.q_hi - LIMIT_MARGIN_RAD + 1e-9)
        assert in_collision(world, p.q_rad) == []
        assert path_collision(world, q_prev, p.q_rad) == []  # every motion, from the start on
        q_prev = p.q_rad
        world.set_q(p.q_rad)
        assert np.allclose(world.T_base_flange(), p.T_base_flange, atol=1e-9)
        assert p.capture or p.cameras == ()
        for c in p.cameras:
            assert board_visibility(world, c, world.T_base_board())
    # varied tilts: board normals presented to one camera spread over tens of degrees
    cam = world.cell.camera_names[1]
    normals = []
    for p in traj.poses:
        if cam in p.cameras:
            world.set_q(p.q_rad)
            normals.append(world.T_base_board()[:3, 2])
    N = np.array(normals)
    ang = np.degrees(np.arccos(np.clip(N @ N.mean(axis=0) / np.linalg.norm(N.mean(axis=0)), -1, 1)))
    assert ang.max() > 10.0


def test_plan_fails_clearly_when_cameras_cannot_see_the_board():
    require_sim()
    from calibgraph.plan.planner import plan_trajectory
    from calibgraph.sim.render import SimWorld
    from calibgraph.sim.workcell import ring_workcell

    # D455 at 8 m: 25 mm squares are ~2 px wide, below the planner's detectability limit
    w = SimWorld(ring_workcell(n_cameras=1, distance_m=8.0, preset_name="d455"))
    with pytest.raises(InputError, match="planned only 0 of 3 poses"):
        plan_trajectory(w, 3, seed=0, max_attempts=30)
    w.close()


def test_trajectory_file_round_trip(tmp_path):
    rng = np.random.default_rng(2)
    from calibgraph.core.transforms import exp_so3, make_T

    poses = tuple(TrajectoryPose(q_rad=rng.normal(size=7), T_base_flange=make_T(exp_so3(rng.normal(size=3)), rng.normal(size=3)),
                                 cameras=("cam0", "cam2")[: k % 2 + 1] if k != 2 else (), capture=k != 2)
                  for k in range(5))
    traj = Trajectory(poses=poses, workcell="test", seed=7, speed_scale=0.15, notes=("1 via pose",))
    p = traj.save(tmp_path / "traj.yaml")
    back = load_trajectory(p)
    assert len(back) == 5 and back.workcell == "test" and back.seed == 7 and back.speed_scale == 0.15
    assert back.notes == ("1 via pose",) and back.n_capture == 4 and back.n_via == 1
    for a, b in zip(traj.poses, back.poses):
        assert np.allclose(a.q_rad, b.q_rad, atol=1e-12)
        assert np.allclose(a.T_base_flange, b.T_base_flange, atol=1e-9)
        assert a.cameras == b.cameras and a.capture == b.capture
    assert back.views_per_camera() == {"cam0": 4, "cam2": 2}  # the via pose counts for no camera
    assert back.sha256() == traj.sha256()
    # one trajectory type: the capture state machine's loader gives the same object
    from calibgraph.acquire import run as acquire

    assert Trajectory is acquire.Trajectory and load_trajectory is acquire.load_trajectory
    # the capture flag is part of the fingerprint; the expected cameras are bookkeeping
    flip = Trajectory(poses=tuple(TrajectoryPose(q.q_rad, q.T_base_flange, q.cameras, True) for q in traj.poses[:2])
                      + (TrajectoryPose(traj.poses[2].q_rad, traj.poses[2].T_base_flange),) + traj.poses[3:],
                      speed_scale=0.15)
    assert flip.sha256() != traj.sha256()
    mute = Trajectory(poses=tuple(TrajectoryPose(q.q_rad, q.T_base_flange, (), q.capture) for q in traj.poses),
                      speed_scale=0.15)
    assert mute.sha256() == traj.sha256()
    bad = tmp_path / "bad.yaml"
    bad.write_text("poses:\n  - {q_rad: [0, 0, 0, -2, 0, 2, 0]}\n  - {q_rad: [0, 0, 0, -2, 0, 2, 0], capture: maybe}\n")
    with pytest.raises(InputError, match=r"bad.yaml: pose 1: .*capture must be true or false"):
        load_trajectory(bad)
    bad.write_text("poses:\n  - {q_rad: [0, 0, 0, -2, 0, 2, 0], cameras: [cam0, 3]}\n")
    with pytest.raises(InputError, match=r"bad.yaml: pose 0: .*list of camera names"):
        load_trajectory(bad)
    bad.write_text("poses:\n  - {T_base_flange: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}\n")
    with pytest.raises(InputError, match=r"bad.yaml: pose 0: missing 'q_rad'"):
        load_trajectory(bad)
    bad.write_text("format: something-else/2\nposes: []\n")
    with pytest.raises(InputError, match="unsupported format"):
        load_trajectory(bad)
