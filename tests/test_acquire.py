"""The acquisition state machine against the in-process fakes: completeness, crash safety
(SIGKILL mid-run + resume == uninterrupted run), camera faults, unsafe and unreachable poses."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import CAPTURE_SCRIPT, dataset_content

from calibgraph.acquire.run import AcquisitionReport, run_acquisition
from calibgraph.acquire.safety import SafetyLimits, UnsafeTargetError
from calibgraph.core.errors import InputError
from calibgraph.io.layouts import load_dataset
from calibgraph.plan.trajectory import Trajectory, load_trajectory, save_trajectory
from calibgraph.sim.fakes import T_from_q, make_fake_cell

REPO = Path(__file__).resolve().parents[1]


def _run(cell, out, **kw):
    kw.setdefault("detector", cell.detector)
    kw.setdefault("progress", False)
    return run_acquisition(cell.robot, cell.cameras, cell.trajectory, out, cell.target, **kw)


def test_full_run_writes_every_accepted_view(tmp_path):
    cell = make_fake_cell(n_cameras=3, n_poses=12, seed=1)
    rep = _run(cell, tmp_path / "ds")
    assert isinstance(rep, AcquisitionReport) and rep.complete
    assert rep.captured == 12
    ds = load_dataset(tmp_path / "ds")
    assert [c.index for c in ds.captures] == list(range(12))
    assert ds.problems == ()
    # every accepted view is on disk with its image, and counts agree with the report
    for cam in ("cam0", "cam1", "cam2"):
        views = [v for v in ds.views if v.camera == cam]
        assert len(views) == rep.accepted_per_camera[cam]
        for v in views:
            assert (tmp_path / "ds" / v.image).is_file()
    # stored flange poses are the robot's FK at the trajectory targets; joints stored too
    for cap, pose in zip(ds.captures, cell.trajectory.poses):
        np.testing.assert_allclose(cap.T_base_flange, T_from_q(pose.q_rad), atol=1e-12)
        np.testing.assert_allclose(cap.q_rad, pose.q_rad, atol=1e-12)
    # stored detections are the truth plus the fake's 0.2 px noise (5 sigma bound: 1 px)
    cell.robot.move_to_joints(cell.trajectory.poses[3].q_rad)
    truth = cell.cameras[0].true_uv()
    v = next(v for v in ds.views if v.camera == "cam0" and v.capture == 3)
    assert np.abs(v.uv_px - truth[1]).max() < 1.0
    # the problem builds and every capture has at least one view
    prob = ds.to_problem()
    assert {d.capture for d in prob.detections} == set(range(12))
    # states follow START -> (MOVE SETTLE ACQUIRE NEXT)* -> END
    states = [s for s, _ in rep.trace]
    assert states[0] == "START" and states[-1] == "END"
    assert states[1:-1] == ["MOVE", "SETTLE", "ACQUIRE", "NEXT"] * 12
    assert not list((tmp_path / "ds").rglob(".*.tmp*"))


def test_no_image_is_taken_while_the_robot_moves(tmp_path):
    cell = make_fake_cell(n_cameras=2, n_poses=5, seed=2, robot_kwargs=dict(settle_s=0.03))
    grabbed_unsettled = []
    for cam in cell.cameras:
        orig = cam.grab

        def grab(orig=orig):
            if not cell.robot.is_settled():
                grabbed_unsettled.append(True)
            return orig()

        cam.grab = grab
    rep = _run(cell, tmp_path / "ds")
    assert rep.captured == 5 and not grabbed_unsettled


def test_robot_that_never_settles_costs_the_pose_not_the_run(tmp_path):
    cell = make_fake_cell(n_cameras=2, n_poses=3, seed=2, robot_kwargs=dict(settle_s=10.0))
    rep = _run(cell, tmp_path / "ds", settle_timeout_s=0.05)
    assert rep.count("not_settled") == 3 and rep.captured == 0
    assert "still moving" in rep.summary()


def test_sigkill_mid_run_then_resume_loses_and_duplicates_nothing(tmp_path):
    n = 24
    ref = make_fake_cell(n_cameras=2, n_poses=n, seed=5)
    _run(ref, tmp_path / "ref")
    out = tmp_path / "killed"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    kills = 0
    for target_done in (4, 11):  # kill twice, at different points
        p = subprocess.Popen([sys.executable, "-c", CAPTURE_SCRIPT, str(out), str(n), "5", "0.03"], env=env)
        t_end = time.monotonic() + 30
        while time.monotonic() < t_end and p.poll() is None:
            # finished captures only ("0*.json"), never a hidden temporary file being written
            if len(list((out / "captures").glob("0*.json"))) >= target_done:
                break
            time.sleep(0.005)
        assert p.poll() is None, "the capture subprocess ended before it could be killed"
        p.send_signal(signal.SIGKILL)
        p.wait(10)
        kills += 1
        done = len(list((out / "captures").glob("0*.json")))
        assert target_done <= done < n
    cell = make_fake_cell(n_cameras=2, n_poses=n, seed=5)
    rep = _run(cell, out, resume=True)
    assert rep.resumed and rep.complete
    assert rep.count("done_before") + rep.captured == n
    assert len(cell.robot.moves) == rep.captured  # only the missing poses were visited again
    caps_ref, imgs_ref = dataset_content(tmp_path / "ref")
    caps, imgs = dataset_content(out)
    assert caps == caps_ref  # same captures, same poses, same detections
    assert imgs == imgs_ref  # same images, no stray half-written ones
    assert not list(out.rglob(".*.tmp*"))
    ds = load_dataset(out)
    assert len(ds.captures) == n and ds.problems == ()


def test_resume_refuses_another_trajectory_and_fresh_run_refuses_existing(tmp_path):
    cell = make_fake_cell(n_cameras=1, n_poses=3, seed=3)
    _run(cell, tmp_path / "ds")
    with pytest.raises(InputError, match="already exists"):
        _run(make_fake_cell(n_cameras=1, n_poses=3, seed=3), tmp_path / "ds")
    other = make_fake_cell(n_cameras=1, n_poses=4, seed=4)
    with pytest.raises(InputError, match="different trajectory"):
        _run(other, tmp_path / "ds", resume=True)
    # resuming a complete dataset is a no-op
    again = make_fake_cell(n_cameras=1, n_poses=3, seed=3)
    rep = _run(again, tmp_path / "ds", resume=True)
    assert rep.captured == 0 and rep.count("done_before") == 3 and not again.robot.moves


def test_dropped_frames_and_disconnect_are_reported_and_the_run_goes_on(tmp_path):
    cell = make_fake_cell(n_cameras=3, n_poses=10, seed=6,
                          camera_faults={"cam1": dict(fail_grabs={3, 4}), "cam2": dict(disconnect_after=4)})
    lines = []
    rep = _run(cell, tmp_path / "ds", grab_retries=0, max_camera_failures=3, progress=lines.append)
    assert rep.complete and rep.captured == 10
    assert rep.lost_cameras == ("cam2",)
    assert len(rep.camera_errors["cam1"]) == 2 and "dropped" in rep.camera_errors["cam1"][0]
    assert len(rep.camera_errors["cam2"]) == 3 and "disconnected" in rep.camera_errors["cam2"][0]
    assert cell.cameras[2].n_grabs == 7  # stopped asking once declared lost
    ds = load_dataset(tmp_path / "ds")
    assert {v.capture for v in ds.views if v.camera == "cam2"} <= set(range(4))
    assert {v.capture for v in ds.views if v.camera == "cam0"} == set(range(10))
    assert any("LOST" in s for s in lines) and "LOST" in rep.summary()


def test_a_retry_recovers_a_single_dropped_frame(tmp_path):
    cell = make_fake_cell(n_cameras=2, n_poses=4, seed=6, camera_faults={"cam1": dict(fail_grabs={2})})
    rep = _run(cell, tmp_path / "ds", grab_retries=1)
    assert rep.accepted_per_camera["cam1"] + rep.rejected_per_camera["cam1"] == 4
    assert len(rep.camera_errors["cam1"]) == 1 and not rep.lost_cameras


def test_unsafe_poses_are_skipped_before_any_motion(tmp_path):
    cell = make_fake_cell(n_cameras=2, n_poses=8, seed=7)
    xs = np.array([p.q_rad[0] for p in cell.trajectory.poses])
    cut = float(np.median(xs))
    # box that excludes the poses with x above the median (flange origin x = q[0] for the fake arm)
    limits = SafetyLimits(workspace_min_m=[-2, -2, -2], workspace_max_m=[cut, 2, 2], max_speed_scale=0.5)
    rep = _run(cell, tmp_path / "ds", safety=limits)
    bad = {i for i, x in enumerate(xs) if x > cut}
    assert {i for i, s, _ in rep.skipped} == bad and all(s == "skipped_unsafe" for _, s, _ in rep.skipped)
    assert all("workspace box" in m for _, _, m in rep.skipped)
    sent = [q for q, _ in cell.robot.moves]
    assert len(sent) == 8 - len(bad)
    assert all(q[0] <= cut + 1e-12 for q in sent)  # no command ever left the box


def test_path_leaving_the_box_is_refused_even_when_both_ends_are_inside(tmp_path):
    cell = make_fake_cell(n_cameras=1, n_poses=2, seed=7)
    a, b = cell.trajectory.poses[0].q_rad.copy(), cell.trajectory.poses[0].q_rad.copy()
    b[3:] = -b[3:]  # same position, opposite rotation: on the fake arm the straight joint path stays put in xyz,
    # so the robot gets an FK whose path bulges out of the box between two in-box ends
    traj = Trajectory(poses=(a, b), speed_scale=0.2)
    box = SafetyLimits(workspace_min_m=a[:3] - 0.01, workspace_max_m=a[:3] + 0.01, max_speed_scale=0.5)

    def bulging_fk(q):
        T = T_from_q(q)
        T[2, 3] += 0.5 * np.linalg.norm(q[3:] - a[3:]) * np.linalg.norm(q[3:] - b[3:])  # zero at both ends
        return T

    cell.robot.forward_kinematics = bulging_fk
    cell.robot.move_to_joints(a)
    cell.robot.moves.clear()
    rep = run_acquisition(cell.robot, cell.cameras, traj, tmp_path / "ds", cell.target, detector=cell.detector,
                          safety=box, progress=False)
    assert [s for _, s, _ in rep.skipped] == ["skipped_unsafe"]
    assert "% of the path" in rep.skipped[0][2]
    assert len(cell.robot.moves) == 1  # only the pose at the start position was commanded


def test_joint_limits_and_speed_cap(tmp_path):
    cell = make_fake_cell(n_cameras=1, n_poses=4, seed=8)
    qs = np.array([p.q_rad for p in cell.trajectory.poses])
    lim = SafetyLimits(q_min_rad=qs.min(0) - 1, q_max_rad=qs.max(0) + 1, max_speed_scale=0.5)
    cut = float(np.median(qs[:, 0]))
    lim_tight = SafetyLimits(q_min_rad=qs.min(0) - 1, q_max_rad=np.r_[cut, qs.max(0)[1:] + 1], max_speed_scale=0.5)
    rep = _run(cell, tmp_path / "a", safety=lim_tight)
    n_bad = int(np.sum(qs[:, 0] > cut))
    assert n_bad == 2 and len(rep.skipped) == n_bad and "joint 1" in rep.skipped[0][2]
    fast = make_fake_cell(n_cameras=1, n_poses=4, seed=8, speed_scale=0.9)
    with pytest.raises(UnsafeTargetError, match="max_speed_scale"):
        _run(fast, tmp_path / "b", safety=lim)
    assert not fast.robot.moves and not (tmp_path / "b").exists()


def test_unreachable_pose_is_skipped_with_a_message(tmp_path):
    cell = make_fake_cell(n_cameras=2, n_poses=5, seed=9)
    target_q = cell.trajectory.poses[2].q_rad
    cell.robot.unreachable = lambda q: np.allclose(q, target_q)
    rep = _run(cell, tmp_path / "ds")
    assert rep.skipped == [(2, "skipped_unreachable", "fake robot: no joint solution (injected)")]
    assert rep.captured == 4


def test_robot_failure_stops_cleanly_and_resume_finishes(tmp_path):
    cell = make_fake_cell(n_cameras=2, n_poses=6, seed=10, robot_kwargs=dict(fail_moves={4}))
    rep = _run(cell, tmp_path / "ds")
    assert not rep.complete and "robot failed at pose 3" in rep.stopped_reason and rep.captured == 3
    cell2 = make_fake_cell(n_cameras=2, n_poses=6, seed=10)
    rep2 = _run(cell2, tmp_path / "ds", resume=True)
    assert rep2.complete and rep2.captured == 3 and len(load_dataset(tmp_path / "ds").captures) == 6


def test_dry_run_moves_nothing_and_writes_nothing(tmp_path):
    cell = make_fake_cell(n_cameras=2, n_poses=6, seed=11)
    box = SafetyLimits(workspace_min_m=[-2, -2, -2], workspace_max_m=[2, 2, 0.5], max_speed_scale=0.5)
    rep = _run(cell, tmp_path / "ds", dry_run=True, safety=box)
    assert rep.dry_run and not cell.robot.moves and not (tmp_path / "ds").exists()
    z = np.array([p.q_rad[2] for p in cell.trajectory.poses])
    assert rep.count("skipped_unsafe") == int(np.sum(z > 0.5)) and rep.count("planned") == int(np.sum(z <= 0.5))
    assert all(c.n_grabs == 0 for c in cell.cameras)


def test_on_capture_estimates_reach_the_progress_line(tmp_path):
    cell = make_fake_cell(n_cameras=2, n_poses=4, seed=12)
    seen = []

    def on_capture(capture, detections):
        seen.append((capture.index, sorted(d.camera for d in detections)))
        return {"cam0": 0.001 / len(seen), "cam1": 0.002 / len(seen)}

    lines = []
    rep = _run(cell, tmp_path / "ds", on_capture=on_capture, progress=lines.append)
    assert [i for i, _ in seen] == [0, 1, 2, 3]
    assert rep.last_estimate == {"cam0": 0.00025, "cam1": 0.0005}
    assert "cam0 0.25 mm" in lines[-1]


def test_rendered_images_are_detected_and_stored_consistently(tmp_path):
    import cv2

    def detector(img, target, intr):
        ok, c = cv2.findChessboardCorners(img, (target.cols, target.rows))
        if not ok:
            return None
        c = cv2.cornerSubPix(img, c, (5, 5), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01))
        return np.arange(len(c)), c.reshape(-1, 2)

    cell = make_fake_cell(n_cameras=2, n_poses=6, seed=13, render=True, image_size=(480, 360))
    rep = _run(cell, tmp_path / "ds", detector=detector)
    assert sum(rep.accepted_per_camera.values()) >= 6
    ds = load_dataset(tmp_path / "ds")
    for v in ds.views:
        img = cv2.imread(str(tmp_path / "ds" / v.image), cv2.IMREAD_GRAYSCALE)
        assert img.shape == (360, 480)
        ids, uv = detector(img, cell.target, None)
        np.testing.assert_allclose(uv, v.uv_px, atol=1e-3)  # lossless PNG: same pixels, same corners


def test_trajectory_yaml_round_trip(tmp_path):
    cell = make_fake_cell(n_cameras=1, n_poses=3, seed=14)
    p = save_trajectory(cell.trajectory, tmp_path / "t.yaml")
    t = load_trajectory(p)
    assert t.sha256() == cell.trajectory.sha256()
    (tmp_path / "bad.yaml").write_text("poses:\n  - [0, nan, 0]\n")
    with pytest.raises(InputError, match="finite"):
        load_trajectory(tmp_path / "bad.yaml")


def test_sha256_of_a_plain_trajectory_is_unchanged():
    """Journals of datasets captured before trajectories had cameras/capture keys must still match."""
    from calibgraph.core.transforms import exp_so3, make_T
    from calibgraph.plan.trajectory import TrajectoryPose

    T = make_T(exp_so3([0.1, -0.2, 0.3]), [0.4, 0.05, 0.5])
    t = Trajectory(poses=(TrajectoryPose(q_rad=[0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785], T_base_flange=T),
                          TrajectoryPose(q_rad=[0.1, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785])), speed_scale=0.15)
    # computed with the code before the merge of the two trajectory classes (commit 85604fb)
    assert t.sha256() == "112894b5ae432a2924bebf581a7f1ef518d9fa683aea13cb075a332cadab6e0f"
    # bookkeeping keys do not change it; a capture flag does
    named = Trajectory(poses=(TrajectoryPose(t.poses[0].q_rad, T, cameras=("cam0",)), t.poses[1]), speed_scale=0.15,
                       workcell="w", seed=3, notes=("n",))
    assert named.sha256() == t.sha256()
    via = Trajectory(poses=(t.poses[0], TrajectoryPose(t.poses[1].q_rad, capture=False)), speed_scale=0.15)
    assert via.sha256() != t.sha256()


def test_incremental_solver_plugs_in_as_on_capture(tmp_path):
    inc_mod = pytest.importorskip("calibgraph.solver.solve.incremental")
    cell = make_fake_cell(n_cameras=3, n_poses=15, seed=0)
    inc = inc_mod.IncrementalSolver(cell.target.points_board_m, {c.name: c.intrinsics() for c in cell.cameras})
    lines = []
    rep = _run(cell, tmp_path / "ds", on_capture=inc.add_capture, progress=lines.append)
    est = rep.last_estimate
    assert set(est.cameras) == {"cam0", "cam1", "cam2"}
    # the live estimate is close to the fake cell's truth (0.2 px noise: well under 1 cm)
    for cam in cell.cameras:
        err = np.linalg.norm(est.cameras[cam.name].T_ref_cam[:3, 3] - cam.T_base_cam[:3, 3])
        assert err < 0.01, (cam.name, err)
    assert "1σ cam0" in lines[-1] and " mm/" in lines[-1]


# -- CLI ----------------------------------------------------------------------------------------------
def _cli(*argv):
    from calibgraph.cli.main import main

    return main([str(a) for a in argv])


def _write_yaml(path, d):
    import yaml

    path.write_text(yaml.safe_dump(d))
    return path


def test_cli_real_robot_never_moves_without_confirmation(tmp_path, capsys):
    cell = make_fake_cell(n_cameras=1, n_poses=2, seed=1)
    traj = save_trajectory(cell.trajectory, tmp_path / "t.yaml")
    wc = _write_yaml(tmp_path / "cell.yaml", {"board": "a4_54", "robot": {"driver": "franka", "ip": "127.0.99.254"},
                                              "cameras": {"c0": {"driver": "realsense", "serial": "1"}}})
    code = _cli("capture", "--workcell", wc, "--trajectory", traj, "--out", tmp_path / "ds")
    err = capsys.readouterr().err
    assert code == 2 and "--i-have-cleared-the-cell" in err and "Traceback" not in err
    assert not (tmp_path / "ds").exists()


def test_cli_dry_run_plans_without_robot_or_cameras(tmp_path, capsys):
    # FR3 joint vectors: the second breaks joint 4's limit, the third leaves the workspace box
    home = [0.0, 0.0, 0.0, -1.57, 0.0, 1.57, 0.785]
    bad_joint = [0.0, 0.0, 0.0, 0.2, 0.0, 1.57, 0.785]
    far = [2.0, 0.0, 0.0, -1.57, 0.0, 1.57, 0.785]  # flange at x = -0.23 m
    traj = save_trajectory(Trajectory(poses=(home, bad_joint, far), speed_scale=0.2), tmp_path / "t.yaml")
    wc = _write_yaml(tmp_path / "cell.yaml", {
        "board": "a4_54", "robot": {"driver": "franka", "ip": "127.0.99.254"},
        "cameras": {"c0": {"driver": "realsense", "serial": "1"}},
        "safety": {"robot_model": "fr3", "workspace_min_m": [0.2, -0.5, 0.2], "workspace_max_m": [0.8, 0.5, 0.9]}})
    code = _cli("capture", "--workcell", wc, "--trajectory", traj, "--out", tmp_path / "ds", "--dry-run")
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert "1 planned" in cap.out and "pose 1: skipped_unsafe: joint 4" in cap.out
    assert "pose 2: skipped_unsafe" in cap.out and "workspace box" in cap.out
    assert not (tmp_path / "ds").exists()
    # a speed above the cap is refused outright
    code = _cli("capture", "--workcell", wc, "--trajectory", traj, "--out", tmp_path / "ds", "--dry-run",
                "--speed-scale", "0.9")
    assert code == 2 and "max_speed_scale" in capsys.readouterr().err


def test_cli_capture_on_the_mujoco_cell_then_resume_is_a_no_op(tmp_path, capsys):
    from helpers import require_sim

    # MuJoCo must be first imported by calibgraph.sim, which picks the headless GL backend
    require_sim()  # skips (fails with CALIBGRAPH_SIM_REQUIRED=1) without MuJoCo, franky-sim or headless GL
    from calibgraph.plan.planner import plan_trajectory
    from calibgraph.sim.render import SimWorld
    from calibgraph.sim.workcell import workcell_from_dict
    d = {"name": "t", "board": "a4_54", "mode": "eye_to_hand",
         "cameras": {"c0": {"driver": "sim", "preset": "d455", "position_m": [1.2, 0.3, 0.6], "look_at_m": [0.5, 0, 0.45]},
                     "c1": {"preset": "d455", "position_m": [1.2, -0.5, 0.6], "look_at_m": [0.5, 0, 0.45]}},
         "safety": {"robot_model": "fr3", "max_speed_scale": 0.5}}
    from calibgraph.cli.capture import sim_workcell_dict

    world = SimWorld(workcell_from_dict(sim_workcell_dict(d)))
    plan_trajectory(world, n_poses=3, seed=0).save(tmp_path / "t.yaml")
    wc = _write_yaml(tmp_path / "cell.yaml", d)
    code = _cli("capture", "--workcell", wc, "--trajectory", tmp_path / "t.yaml", "--out", tmp_path / "ds")
    out = capsys.readouterr().out
    assert code == 0 and "3 captured" in out
    ds = load_dataset(tmp_path / "ds")
    assert len(ds.captures) == 3 and {v.camera for v in ds.views} == {"c0", "c1"}
    # every stored flange pose is the simulated arm's FK at the stored joints (FK sigmas default 0.05 mm)
    from calibgraph.acquire.safety import franka_fk
    from calibgraph.core.transforms import pose_error

    for cap in ds.captures:
        dt_m, _ = pose_error(franka_fk(cap.q_rad), cap.T_base_flange)
        assert dt_m < 1e-3
    code = _cli("capture", "--workcell", wc, "--out", tmp_path / "ds", "--resume")
    assert code == 0 and "3 done before" in capsys.readouterr().out


GUARD_SCRIPT = r"""
import sys
for m in ("pyrealsense2", "pylibfranka", "rclpy", "pylibfreenect2", "mujoco", "rerun"):
    sys.modules[m] = None  # importing any of these now fails, as on a machine without the SDK
import importlib, pkgutil
import calibgraph
for mod in pkgutil.walk_packages(calibgraph.__path__, "calibgraph."):
    if mod.name != "calibgraph.__main__":
        importlib.import_module(mod.name)  # every engine module imports without any SDK, MuJoCo or rerun
from calibgraph.acquire.interfaces import DeviceError
import calibgraph_drivers.franka, calibgraph_drivers.realsense, calibgraph_drivers.ros2, calibgraph_drivers.kinect
for make in (lambda: calibgraph_drivers.franka.FrankaRobot("127.0.0.1"),
             lambda: calibgraph_drivers.realsense.RealSenseCamera("c"),
             lambda: calibgraph_drivers.ros2.Ros2Camera("c", "/x/image_raw"),
             lambda: calibgraph_drivers.kinect.KinectV2Camera("c")):
    try:
        make()
    except DeviceError as e:
        print("MSG", e)
"""


def test_engine_imports_no_sdk_and_drivers_explain_missing_ones():
    out = subprocess.run([sys.executable, "-c", GUARD_SCRIPT], capture_output=True, text=True, timeout=60,
                         env=dict(os.environ, PYTHONPATH=str(REPO)), cwd=str(REPO))
    assert out.returncode == 0, out.stderr
    msgs = [ln for ln in out.stdout.splitlines() if ln.startswith("MSG")]
    assert len(msgs) == 4
    for m, hint in zip(msgs, ("pylibfranka", "pyrealsense2", "rclpy", "pylibfreenect2")):
        assert hint in m and ("pip install" in m or "not on PyPI" in m), m


def test_stale_frames_are_refused(tmp_path):
    from calibgraph.acquire.interfaces import Frame

    cell = make_fake_cell(n_cameras=2, n_poses=4, seed=15)
    cam = cell.cameras[1]
    orig = cam.grab
    first = {}

    def grab():
        fr = orig()
        first.setdefault("stamp", fr.stamp_s)
        return Frame(camera=fr.camera, image=fr.image, stamp_s=first["stamp"])  # a driver re-delivering one frame

    cam.grab = grab
    rep = _run(cell, tmp_path / "ds", grab_retries=0, max_camera_failures=10)
    assert len(rep.camera_errors["cam1"]) == 3 and "stale frame" in rep.camera_errors["cam1"][0]
    assert rep.accepted_per_camera["cam1"] <= 1 and not rep.camera_errors["cam0"]


def test_ctrl_c_keeps_whole_captures_and_cli_says_how_to_resume(tmp_path, capsys):
    cell = make_fake_cell(n_cameras=2, n_poses=6, seed=16)
    orig = cell.robot.move_to_joints

    def move(q, speed_scale=0.2):
        if len(cell.robot.moves) == 3:
            raise KeyboardInterrupt
        orig(q, speed_scale)

    cell.robot.move_to_joints = move
    with pytest.raises(KeyboardInterrupt):
        _run(cell, tmp_path / "ds")
    assert len(load_dataset(tmp_path / "ds").captures) == 3
    journal = json.loads((tmp_path / "ds" / "acquisition.json").read_text())
    assert journal["runs"][-1]["stopped"] == "interrupted"
    rep = _run(make_fake_cell(n_cameras=2, n_poses=6, seed=16), tmp_path / "ds", resume=True)
    assert rep.captured == 3 and rep.count("done_before") == 3


def test_captured_dataset_solves_to_the_fake_cells_truth(tmp_path):
    """End to end: what the state machine writes (flange poses, detections, intrinsics) is what the
    solver needs, in the right conventions: the solved T_base_cam lands within 4 of its own 1-sigma
    norms (measured: 0.4-1.0 mm for sigma norms 0.7-0.8 mm, 0.05-0.10 deg for 0.06 deg, at 0.2 px
    noise)."""
    import calibgraph
    from calibgraph.core.transforms import pose_error

    cell = make_fake_cell(n_cameras=3, n_poses=20, seed=0)
    _run(cell, tmp_path / "ds")
    res = calibgraph.solve(load_dataset(tmp_path / "ds").to_problem())
    for cam in cell.cameras:
        cr = res.cameras[cam.name]
        err_m, err_deg = pose_error(cr.T_base_cam, cam.T_base_cam)
        sigma_mm = float(np.linalg.norm(cr.sigma_translation_mm))
        assert 1e3 * err_m < 4 * sigma_mm, (cam.name, err_m, sigma_mm)
        assert err_deg < 4 * float(np.linalg.norm(cr.sigma_rotation_deg)), (cam.name, err_deg)


def test_robot_state_failure_and_crashing_helpers_do_not_lose_data(tmp_path):
    cell = make_fake_cell(n_cameras=2, n_poses=6, seed=17)
    calls = {"n": 0}
    orig_pose = cell.robot.flange_pose

    def flange_pose():
        calls["n"] += 1
        if calls["n"] == 7:  # 4th pose, first read: the controller connection drops
            from calibgraph.acquire.interfaces import DeviceError

            raise DeviceError("fake robot: state read failed (injected)")
        return orig_pose()

    cell.robot.flange_pose = flange_pose

    def bad_detector(img, target, intr):
        if bad_detector.n == 1:
            bad_detector.n += 1
            raise RuntimeError("cv2.error (injected)")
        bad_detector.n += 1
        return cell.detector(img, target, intr)

    bad_detector.n = 0

    def bad_on_capture(capture, detections):
        raise RuntimeError("solver blew up (injected)")

    rep = _run(cell, tmp_path / "ds", detector=bad_detector, on_capture=bad_on_capture)
    assert not rep.complete and "robot failed at pose 3" in rep.stopped_reason and rep.captured == 3
    assert rep.rejected_per_camera["cam1"] >= 1
    rep2 = _run(make_fake_cell(n_cameras=2, n_poses=6, seed=17), tmp_path / "ds", resume=True)
    assert rep2.complete and len(load_dataset(tmp_path / "ds").captures) == 6


# -- via (transit) poses --------------------------------------------------------------------------------
def _with_vias(cell, before):
    """``cell.trajectory`` with via poses inserted: ``before`` maps a capture pose's index to the
    number of via poses put in front of it (fake Cartesian joints halfway to it)."""
    from calibgraph.plan.trajectory import TrajectoryPose

    poses, q_prev = [], cell.robot.joint_positions()
    for k, p in enumerate(cell.trajectory.poses):
        for j in range(before.get(k, 0)):
            q = q_prev + (j + 1) / (before[k] + 1) * (p.q_rad - q_prev)
            poses.append(TrajectoryPose(q_rad=q, T_base_flange=T_from_q(q), capture=False))
        poses.append(p)
        q_prev = p.q_rad
    cell.trajectory = Trajectory(poses=tuple(poses), speed_scale=cell.trajectory.speed_scale)
    return cell.trajectory


def test_via_poses_are_moved_through_without_capture(tmp_path):
    cell = make_fake_cell(n_cameras=2, n_poses=6, seed=3)
    traj = _with_vias(cell, {2: 1, 4: 2})  # indices: 0 1 v2 3 4 v5 v6 7 8
    via = [2, 5, 6]
    lines = []
    rep = _run(cell, tmp_path / "ds", progress=lines.append)
    assert rep.complete and rep.captured == 6 and rep.count("via") == 3 and rep.skipped == []
    assert rep.n_poses == 9 and rep.n_via_poses == 3
    assert [o.index for o in rep.outcomes if o.status == "via"] == via
    # the robot went through every pose in order, the via poses included
    assert len(cell.robot.moves) == 9
    for (q, _), p in zip(cell.robot.moves, traj.poses):
        np.testing.assert_allclose(q, p.q_rad)
    # nothing is written for a via pose: no capture file, no image; the journal says "via"
    ds = load_dataset(tmp_path / "ds")
    assert ds.problems == () and [c.index for c in ds.captures] == [0, 1, 3, 4, 7, 8]
    assert not any(v.capture in via for v in ds.views)
    assert not [p for p in (tmp_path / "ds" / "images").rglob("*.png") if int(p.stem) in via]
    journal = json.loads((tmp_path / "ds" / "acquisition.json").read_text())
    assert [journal["poses"][str(i)]["status"] for i in via] == ["via"] * 3
    # a via pose is MOVE -> SETTLE -> NEXT (no ACQUIRE); capture poses keep all four states
    states = {i: [s for s, k in rep.trace if k == i] for i in range(9)}
    assert all(states[i] == ["MOVE", "SETTLE", "NEXT"] for i in via)
    assert all(states[i] == ["MOVE", "SETTLE", "ACQUIRE", "NEXT"] for i in (0, 1, 3, 4, 7, 8))
    s = rep.summary()
    assert "capture of 6 poses (+3 via poses)" in s and "6 captured" in s and "0 skipped" in s and "3 via poses passed" in s
    assert sum("via pose passed" in ln for ln in lines) == 3 and any(ln.startswith("pose 9/9: ") for ln in lines)
    # the dataset's copy of the trajectory keeps the capture flags
    assert load_trajectory(tmp_path / "ds" / "trajectory.yaml").sha256() == traj.sha256()
    assert [p.capture for p in load_trajectory(tmp_path / "ds" / "trajectory.yaml").poses].count(False) == 3


def test_resume_passes_only_the_via_poses_leading_to_pending_poses(tmp_path):
    cell = make_fake_cell(n_cameras=2, n_poses=6, seed=3)
    traj = _with_vias(cell, {2: 1, 4: 2})  # indices: 0 1 v2 3 4 v5 v6 7 8
    cell.robot.fail_moves = {6}  # the 6th move (via pose 5) fails: captures 0 1 3 4 are on disk
    rep = _run(cell, tmp_path / "ds")
    assert not rep.complete and rep.captured == 4 and rep.count("via") == 1
    cell2 = make_fake_cell(n_cameras=2, n_poses=6, seed=3)
    _with_vias(cell2, {2: 1, 4: 2})
    lines = []
    rep2 = _run(cell2, tmp_path / "ds", resume=True, progress=lines.append)
    assert rep2.complete and rep2.captured == 2 and rep2.count("done_before") == 4 and rep2.count("via") == 2
    # via pose 2 led to pose 3, done before: not visited again; via poses 5, 6 lead to pose 7
    assert [o.index for o in rep2.outcomes if o.status == "via"] == [5, 6]
    assert 2 not in {o.index for o in rep2.outcomes}
    for (q, _), i in zip(cell2.robot.moves, (5, 6, 7, 8)):
        np.testing.assert_allclose(q, traj.poses[i].q_rad)
    assert "resume: 4 poses done before, 2 to go (and 2 via poses on the way)" in lines
    assert [c.index for c in load_dataset(tmp_path / "ds").captures] == [0, 1, 3, 4, 7, 8]
    # everything captured: a further resume moves nothing (via poses lead only to done poses)
    cell3 = make_fake_cell(n_cameras=2, n_poses=6, seed=3)
    _with_vias(cell3, {2: 1, 4: 2})
    rep3 = _run(cell3, tmp_path / "ds", resume=True)
    assert rep3.complete and rep3.count("done_before") == 6 and not cell3.robot.moves and rep3.count("via") == 0


def test_unreachable_via_pose_skips_the_pose_it_leads_to(tmp_path):
    cell = make_fake_cell(n_cameras=2, n_poses=6, seed=3)
    traj = _with_vias(cell, {2: 1, 4: 2})  # indices: 0 1 v2 3 4 v5 v6 7 8
    bad_q = traj.poses[5].q_rad
    cell.robot.unreachable = lambda q: np.allclose(q, bad_q)
    rep = _run(cell, tmp_path / "ds")
    assert rep.complete and rep.captured == 5 and rep.count("via") == 1  # via 2 passed
    sk = {i: (st, msg) for i, st, msg in rep.skipped}
    assert set(sk) == {5, 6, 7}
    assert sk[5][0] == "skipped_unreachable"
    assert sk[6] == ("skipped_unsafe", "via pose 5 of the same detour was not reached")
    assert sk[7][0] == "skipped_unsafe" and "via pose 5" in sk[7][1] and "colliding" in sk[7][1]
    # the robot never tried the direct motion to pose 7
    assert not any(np.allclose(q, traj.poses[7].q_rad) for q, _ in cell.robot.moves)
    assert [c.index for c in load_dataset(tmp_path / "ds").captures] == [0, 1, 3, 4, 8]


def test_dry_run_lists_via_poses_apart_from_capture_poses(tmp_path):
    cell = make_fake_cell(n_cameras=2, n_poses=4, seed=3)
    _with_vias(cell, {1: 1, 3: 1})
    rep = _run(cell, tmp_path / "ds", dry_run=True)
    assert rep.count("planned") == 4 and rep.count("via") == 2 and rep.skipped == []
    assert "dry run of 4 poses (+2 via poses)" in rep.summary() and "2 via poses planned" in rep.summary()
    # a via pose outside the box costs the pose it leads to (the direct motion would collide)
    box = SafetyLimits(workspace_min_m=[-5, -5, -5], workspace_max_m=[5, 5, 5])
    cell.trajectory = Trajectory(poses=tuple(p if i != 1 else type(p)(q_rad=p.q_rad + np.r_[0, 0, 20.0, 0, 0, 0],
                                                                      capture=False)
                                             for i, p in enumerate(cell.trajectory.poses)), speed_scale=0.2)
    rep = _run(cell, tmp_path / "ds", dry_run=True, safety=box)
    st = {o.index: (o.status, o.message) for o in rep.outcomes}
    assert st[1][0] == "skipped_unsafe" and st[2] == ("skipped_unsafe", "via pose 1 on the way to it would be skipped")
    assert rep.count("planned") == 3 and rep.count("via") == 1


def test_a_run_records_what_made_it_and_takes_over_the_lock_of_a_killed_run(tmp_path):
    """dataset.yaml says which run made the dataset and with which trajectory; the lock a killed
    process left behind is recognised (the kernel dropped its flock), said, and taken over."""
    import yaml

    out = tmp_path / "ds"
    code = ("import sys, time\nfrom calibgraph.acquire.claim import claim_dataset\n"
            "with claim_dataset(sys.argv[1], 'trajectory', {}, False):\n    print('held', flush=True)\n"
            "    time.sleep(120)\n")
    p = subprocess.Popen([sys.executable, "-c", code, str(out)], stdout=subprocess.PIPE, text=True,
                         env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert p.stdout.readline().strip() == "held"
    p.send_signal(signal.SIGKILL)
    p.wait(10)
    assert json.loads((out / ".calibgraph.lock").read_text())["pid"] == p.pid  # left behind
    cell = make_fake_cell(n_cameras=2, n_poses=4, seed=21)
    lines = []
    rep = _run(cell, out, resume=True, progress=lines.append)
    assert rep.complete and rep.captured == 4
    assert any(f"taking over the lock left by process {p.pid}" in ln and "no longer running" in ln for ln in lines), lines
    assert not (out / ".calibgraph.lock").exists()  # released at the end of the run
    made = yaml.safe_load((out / "dataset.yaml").read_text())["made_by"]
    assert made["mode"] == "trajectory" and made["trajectory_sha256"] == cell.trajectory.sha256()
    # a run of another kind may not continue it, and one with another trajectory neither
    from calibgraph.acquire.claim import claim_dataset

    with pytest.raises(InputError, match="made by a trajectory capture"):
        with claim_dataset(out, "auto", {}, True):
            pass
    with pytest.raises(InputError, match="different trajectory"):
        _run(make_fake_cell(n_cameras=2, n_poses=5, seed=21), out, resume=True)
    assert not (out / ".calibgraph.lock").exists()


def test_a_holder_that_has_not_yet_written_who_it_is_is_still_named(tmp_path):
    """Two runs started together: the first has the lock's flock but has not yet written its details
    when the second is refused. The refusal waits for them and names the holder's run (it said "a
    capture", with no pid, under load: CI's two-solves case)."""
    import fcntl
    import threading

    from calibgraph.io.lock import LOCK_NAME, lock_folder

    fd = os.open(tmp_path / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # held, still empty

    def write_later():
        time.sleep(0.3)
        os.pwrite(fd, json.dumps({"pid": 4242, "host": "cell-pc", "mode": "solve", "started_unix_s": time.time()}).encode(), 0)

    t = threading.Thread(target=write_later)
    t.start()
    try:
        with pytest.raises(InputError, match=r"process 4242 on cell-pc, `calibgraph solve`"):
            lock_folder(tmp_path, "solve")
    finally:
        t.join()
        os.close(fd)
