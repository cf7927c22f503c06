"""drivers/franka.py against franky-sim (libfranka's network protocol served on loopback by a MuJoCo
FR3), run in its own process: pylibfranka holds the GIL while connecting, so an in-process
server would deadlock."""

import importlib.util
import os
import random
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from helpers import import_sdk, require_realsense, sdk_unavailable

import_sdk("pylibfranka", "pip install 'calibgraph[franka]'")
import_sdk("franky_sim", "pip install 'calibgraph[sim]'")  # its package imports no MuJoCo
if importlib.util.find_spec("mujoco") is None:  # franky-sim's server needs MuJoCo's physics, not its rendering
    sdk_unavailable("franky-sim needs MuJoCo (pip install 'calibgraph[sim]')")

from calibgraph.acquire.interfaces import DeviceError  # noqa: E402
from calibgraph.acquire.run import run_acquisition  # noqa: E402
from calibgraph.acquire.safety import FRANKA_LIMITS, SafetyLimits, franka_fk  # noqa: E402
from calibgraph.core.camera import Intrinsics  # noqa: E402
from calibgraph.core.targets import a4_board_54  # noqa: E402
from calibgraph.core.transforms import exp_so3, inv, look_at, make_T, pose_error  # noqa: E402
from calibgraph.plan.trajectory import Trajectory, TrajectoryPose
from calibgraph.sim.fakes import FakeCamera, FakeCell  # noqa: E402
from calibgraph_drivers.franka import FrankaRobot, quintic_duration_s  # noqa: E402

HOME = np.array([0.0, 0.0, 0.0, -1.57, 0.0, 1.57, 0.785])


def _free_loopback() -> str:
    for _ in range(50):
        ip = f"127.0.{random.randint(100, 250)}.{random.randint(2, 250)}"
        with socket.socket() as s:
            s.settimeout(0.2)
            if s.connect_ex((ip, 1337)) != 0:
                return ip
    pytest.skip("no free loopback address for franky-sim")


def _die_with_parent():
    """Child-side: the kernel kills franky-sim if the test process dies, so none is left behind."""
    import ctypes

    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except OSError:
        pass


@pytest.fixture(scope="module")
def franky_sim():
    import faulthandler

    # pylibfranka blocks in C with the GIL held when a server does not answer; only a C-level
    # watchdog can end such a hang, so the whole module is bounded (it needs ~30 s).
    faulthandler.dump_traceback_later(240, exit=True)
    ip = _free_loopback()
    # MUJOCO_GL=disable: the server only steps the physics, so it needs no OpenGL library (with
    # MUJOCO_GL=egl and no libEGL, `import mujoco` fails)
    p = subprocess.Popen([sys.executable, "-m", "franky_sim.run_server", "-s", "mujoco", "--hostname", ip],
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                         env=dict(os.environ, PYTHONUNBUFFERED="1", MUJOCO_GL="disable"), start_new_session=True,
                         preexec_fn=_die_with_parent)
    t_end = time.monotonic() + 60
    lines = []
    ok = False
    try:
        while time.monotonic() < t_end:
            line = p.stdout.readline()
            if not line:
                break
            lines.append(line)
            if "Connect to the server using" in line:
                ok = True
                break
        if not ok:
            pytest.fail("franky-sim did not start within 60 s:\n" + "".join(lines))
        yield ip
    finally:
        faulthandler.cancel_dump_traceback_later()
        p.send_signal(signal.SIGINT)
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(5)


@pytest.fixture
def robot(franky_sim):
    # one connection at a time: franky-sim serves a single libfranka client (as a real robot does)
    r = FrankaRobot(franky_sim, model="fr3", realtime=False)
    yield r
    r.close()


def test_state_frames_flange_vs_ee(robot):
    q = robot.joint_positions()
    np.testing.assert_allclose(q, HOME, atol=0.02)
    T_flange = robot.flange_pose()
    T_ee = robot.ee_pose()
    # the simulated FR3 has the Franka Hand: EE is 0.1034 m beyond the flange along flange z
    np.testing.assert_allclose(inv(T_flange) @ T_ee[:, 3], [0, 0, 0.1034, 1], atol=1e-4)
    # the flange agrees with calibgraph's nominal FR3 kinematics (used by the safety path check)
    dt_m, dr_deg = pose_error(franka_fk(q), T_flange)
    assert dt_m < 1e-3 and dr_deg < 0.1, (dt_m, dr_deg)


def test_move_respects_velocity_scaling_and_arrives(robot):
    q0 = robot.joint_positions()
    q1 = q0 + np.array([0.2, -0.1, 0.0, 0.15, 0.0, -0.1, 0.25])
    scale = 0.3
    robot.move_to_joints(q1, speed_scale=scale)
    m = robot.last_motion
    assert m["duration_s"] == pytest.approx(quintic_duration_s(q0, q1, scale, "fr3"), rel=0.05), m
    vmax = np.asarray(FRANKA_LIMITS["fr3"]["dq_max_rad_s"])
    # measured joint speed stays under the scaled limit (10% allowance for tracking overshoot)
    assert m["peak_dq_rad_s"] <= 1.1 * scale * vmax.min() + 0.02, m
    t_end = time.monotonic() + 60  # franky-sim runs slower than real time on a loaded machine
    while not robot.is_settled() and time.monotonic() < t_end:
        time.sleep(0.01)
    assert robot.is_settled()
    # the joint impedance controller leaves a steady-state error of ~2 mrad under gravity (measured
    # 0.9-1.7 mrad); the acquisition's arrival tolerance is 10 mrad
    np.testing.assert_allclose(robot.joint_positions(), q1, atol=5e-3)
    dt_m, _ = pose_error(franka_fk(q1), robot.flange_pose())
    assert dt_m < 3e-3, dt_m


def test_out_of_limit_target_is_refused_without_moving(robot):
    from calibgraph.acquire.interfaces import UnreachableError

    q = robot.joint_positions()
    bad = q.copy()
    bad[3] = 0.5  # FR3 joint 4 must stay below -0.15 rad
    with pytest.raises(UnreachableError, match="joint 4"):
        robot.move_to_joints(bad)
    np.testing.assert_allclose(robot.joint_positions(), q, atol=1e-3)


def test_acquisition_on_franky_sim_with_a_board_camera(robot, tmp_path):
    target = a4_board_54()
    T_flange_board = make_T(exp_so3([np.pi, 0.0, 0.0]), [-0.1, 0.0625, 0.02])  # board front faces down (flange +z)
    cell = FakeCell(robot=robot, cameras=[], trajectory=None, target=target, T_flange_board=T_flange_board)
    base = robot.joint_positions()
    qs = [base + d for d in (np.zeros(7), np.array([0.08, 0, 0, 0.05, 0, 0, 0.1]), np.array([-0.05, 0.05, 0, 0, 0, 0.05, -0.1]))]
    bad = base.copy()
    bad[0] = 2.0  # inside the joint limits but outside the workspace box below
    T_board = franka_fk(qs[0]) @ T_flange_board
    centre = T_board[:3, 3] + T_board[:3, :3] @ target.points_board_m.mean(0)
    cam = FakeCamera("floor", look_at(centre - np.array([0, 0, 0.6]), centre, up=(1.0, 0, 0)),
                     Intrinsics.from_hfov(640, 480, 70.0), robot, target, T_flange_board, cell)
    cell.cameras.append(cam)
    traj = Trajectory(poses=tuple(TrajectoryPose(q) for q in (qs[0], bad, qs[1], qs[2])), speed_scale=0.4)
    safety = SafetyLimits.from_dict({"robot_model": "fr3", "workspace_min_m": [0.2, -0.5, 0.2],
                                     "workspace_max_m": [0.9, 0.5, 1.0], "max_speed_scale": 0.5})
    rep = run_acquisition(robot, [cam], traj, tmp_path / "ds", target, detector=cell.detector, safety=safety,
                          progress=False, settle_dwell_s=0.05, settle_timeout_s=60.0)
    assert rep.complete, rep.summary()
    assert [i for i, _, _ in rep.skipped] == [1] and "workspace box" in rep.skipped[0][2]
    assert rep.captured == 3, rep.summary()
    from calibgraph.io.layouts import load_dataset

    ds = load_dataset(tmp_path / "ds")
    for cap in ds.captures:
        # stored flange pose and joints agree through the nominal FR3 model (measured: 0.2 mm,
        # 0.11 deg; the arm is still creeping by < 1 mrad while the pose and joints are read)
        dt_m, dr_deg = pose_error(franka_fk(cap.q_rad), cap.T_base_flange)
        assert dt_m < 2e-3 and dr_deg < 0.3


def test_unreachable_address_fails_fast():
    t0 = time.monotonic()
    with pytest.raises(DeviceError, match="cannot reach"):
        FrankaRobot("127.0.99.254", connect_timeout_s=1.0)
    assert time.monotonic() - t0 < 5


def _record_realsense(path, n):
    """A short colour recording (.db3) from an SDK software device, to stand in for a live camera."""
    rs = require_realsense()
    dev = rs.software_device()
    sensor = dev.add_sensor("RGB Camera")
    intr = rs.intrinsics()
    intr.width, intr.height, intr.fx, intr.fy, intr.ppx, intr.ppy = 64, 48, 60.0, 60.0, 31.5, 23.5
    intr.model, intr.coeffs = rs.distortion.brown_conrady, [0.0] * 5
    vs = rs.video_stream()
    vs.type, vs.index, vs.uid, vs.width, vs.height, vs.fps, vs.bpp = rs.stream.color, 0, 0, 64, 48, 30, 3
    vs.fmt, vs.intrinsics = rs.format.bgr8, intr
    prof = sensor.add_video_stream(vs)
    dev.register_info(rs.camera_info.serial_number, "REC1")
    rec = rs.recorder(str(path), dev)
    rsensor = rec.query_sensors()[0]
    sync = rs.syncer()
    rsensor.open(rsensor.get_stream_profiles()[0])
    rsensor.start(sync)
    for i in range(n):
        f = rs.software_video_frame()
        f.pixels = np.full((48, 64, 3), 128, np.uint8)
        f.stride, f.bpp, f.timestamp, f.frame_number = 64 * 3, 3, 1000.0 + 33.3 * i, i
        f.domain, f.profile = rs.timestamp_domain.hardware_clock, prof.as_video_stream_profile()
        sensor.on_video_frame(f)
        sync.wait_for_frames(2000)
    rsensor.stop()
    rsensor.close()
    del rsensor, rec


def test_cli_capture_drives_franka_with_a_recorded_realsense(franky_sim, tmp_path, capsys):
    import yaml

    from calibgraph.cli.main import main
    from calibgraph.plan.trajectory import save_trajectory

    _record_realsense(tmp_path / "rec.db3", 20)
    r = FrankaRobot(franky_sim)
    q0 = r.joint_positions()
    r.close()
    del r
    traj = Trajectory(poses=(TrajectoryPose(q0), TrajectoryPose(q0 + np.array([0.05, 0, 0, 0.05, 0, 0, 0.05]))),
                      speed_scale=0.3)
    save_trajectory(traj, tmp_path / "t.yaml")
    cell = {"board": "a4_54", "robot": {"driver": "franka", "ip": franky_sim, "model": "fr3", "realtime": False},
            "cameras": {"rs0": {"driver": "realsense", "file": str(tmp_path / "rec.db3"), "settle_frames": 2}},
            "safety": {"robot_model": "fr3", "workspace_min_m": [0.2, -0.5, 0.2], "workspace_max_m": [0.9, 0.5, 1.0],
                       "max_speed_scale": 0.5}}
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    code = main(["capture", "--workcell", str(tmp_path / "cell.yaml"), "--trajectory", str(tmp_path / "t.yaml"),
                 "--out", str(tmp_path / "ds"), "--i-have-cleared-the-cell", "--settle-dwell-s", "0.05"])
    out = capsys.readouterr()
    # the recording shows no board: both poses are visited, every frame is grabbed and rejected
    assert code == 0, out.err
    assert "2 without accepted views" in out.out and "rs0: board seen in 0 frames (views kept), not in 2" in out.out
    r = FrankaRobot(franky_sim)
    np.testing.assert_allclose(r.joint_positions(), traj.poses[1].q_rad, atol=5e-3)
    r.close()
