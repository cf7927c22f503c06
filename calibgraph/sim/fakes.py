"""In-process fake robot and cameras for fast tests of the acquisition state machine.

No simulator, no SDK: the fake robot is a "Cartesian" arm whose six joints are the flange pose
itself (``q_rad = [x, y, z, rx, ry, rz]``: translation in metres and a rotation vector in radians,
``T_base_flange = make_T(exp_so3(r), t)``), so any flange pose is one joint vector away and the
forward kinematics is exact. The board sits on the flange through ``T_flange_board``; fake cameras
are fixed in the base frame (eye-to-hand, the geometry of :func:`calibgraph.sim.synthetic_corners.make_scene`) and
project the board corners through the true chain.

Images: ``render=True`` paints a real checkerboard with a homography (small images, OpenCV can
detect them); ``render=False`` returns a tiny grey image and :meth:`FakeCell.detector` returns
the projected corners plus seeded noise (keyed by the image object, so no image processing runs).
Noise is seeded from the seed, the camera and the joint vector, so a resumed run reproduces the
uninterrupted one bit for bit.

Fault injection: ``FakeCamera(fail_grabs={k,...})`` raises on those grab numbers,
``disconnect_after=n`` raises on every grab after the n-th; ``FakeRobot(unreachable=pred)``
raises :class:`UnreachableError` for targets where ``pred(q)`` is true, ``settle_s`` keeps
``is_settled`` False for a while after each move, ``move_delay_s`` makes moves take time.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass

import numpy as np

from calibgraph.acquire.interfaces import DeviceError, Frame, UnreachableError
from calibgraph.core.camera import Intrinsics
from calibgraph.core.targets import Target, a4_board_54
from calibgraph.core.transforms import exp_so3, inv, log_so3, look_at, make_T
from calibgraph.plan.trajectory import Trajectory, TrajectoryPose
from calibgraph.sim.synthetic_corners import (
    DEFAULT_T_FLANGE_BOARD,
    WORKSPACE_CENTRE_M,
    random_board_facing,
)


def q_from_T(T: np.ndarray) -> np.ndarray:
    """Joint vector of the fake Cartesian arm for flange pose ``T``."""
    return np.concatenate([T[:3, 3], log_so3(T[:3, :3])])


def T_from_q(q_rad) -> np.ndarray:
    q = np.asarray(q_rad, float).reshape(-1)
    return make_T(exp_so3(q[3:6]), q[:3])


class FakeRobot:
    """A six-"joint" Cartesian robot (see the module docstring)."""

    def __init__(self, q0_rad=None, settle_s: float = 0.0, move_delay_s: float = 0.0, unreachable=None,
                 fail_moves=()):
        self._q = np.zeros(6) if q0_rad is None else np.asarray(q0_rad, float).copy()
        self._q[2] = self._q[2] if q0_rad is not None else 0.5
        self.settle_s = settle_s
        self.move_delay_s = move_delay_s
        self.unreachable = unreachable
        self.fail_moves = set(fail_moves)
        self.n_moves = 0
        self._moved_at = -1e9
        self.moves = []

    def joint_positions(self) -> np.ndarray:
        return self._q.copy()

    def forward_kinematics(self, q_rad) -> np.ndarray:
        return T_from_q(q_rad)

    def flange_pose(self) -> np.ndarray:
        return T_from_q(self._q)

    def true_flange_pose(self) -> np.ndarray:
        """The pose the fake cameras render (tests may break :meth:`flange_pose` on purpose)."""
        return T_from_q(self._q)

    def move_to_joints(self, q_rad, speed_scale: float = 0.2) -> None:
        q = np.asarray(q_rad, float).reshape(-1)
        self.n_moves += 1
        if self.n_moves in self.fail_moves:
            raise DeviceError(f"fake robot: move {self.n_moves} failed (injected)")
        if self.unreachable is not None and self.unreachable(q):
            raise UnreachableError("fake robot: no joint solution (injected)")
        if self.move_delay_s:
            time.sleep(self.move_delay_s)
        self._q = q.copy()
        self._moved_at = time.monotonic()
        self.moves.append((q.copy(), float(speed_scale)))

    def is_settled(self) -> bool:
        return time.monotonic() - self._moved_at >= self.settle_s

    def close(self) -> None:
        pass


class FakeCamera:
    """A camera fixed at ``T_base_cam`` looking at the board carried by ``robot``."""

    def __init__(self, name: str, T_base_cam: np.ndarray, intrinsics: Intrinsics, robot: FakeRobot,
                 target: Target, T_flange_board: np.ndarray, cell: "FakeCell", render: bool = False,
                 fail_grabs=(), disconnect_after: int | None = None):
        self.name = name
        self.T_base_cam = np.asarray(T_base_cam, float)
        self._intr = intrinsics
        self.robot = robot
        self.target = target
        self.T_flange_board = T_flange_board
        self.cell = cell
        self.render = render
        self.fail_grabs = set(fail_grabs)
        self.disconnect_after = disconnect_after
        self.n_grabs = 0
        self.max_view_angle_deg = 60.0
        self._t = 0.0

    def intrinsics(self) -> Intrinsics:
        return self._intr

    def _robot_pose(self) -> np.ndarray:
        f = getattr(self.robot, "true_flange_pose", None)
        return f() if callable(f) else self.robot.flange_pose()

    def true_uv(self):
        """(ids, uv_px) of the board points visible in the image (noise-free), or None."""
        T_cb = inv(self.T_base_cam) @ self._robot_pose() @ self.T_flange_board
        p = self.target.points_board_m @ T_cb[:3, :3].T + T_cb[:3, 3]
        if np.any(p[:, 2] <= 0.05):
            return None
        ray = p.mean(axis=0) / np.linalg.norm(p.mean(axis=0))
        if T_cb[:3, 2] @ ray < np.cos(np.radians(self.max_view_angle_deg)):  # seen from the back or edge-on
            return None
        uv = self._intr.project(p)
        if not np.all(self._intr.in_image(uv, margin_px=3)):
            return None
        return np.arange(len(p)), uv

    def grab(self) -> Frame:
        self.n_grabs += 1
        if self.disconnect_after is not None and self.n_grabs > self.disconnect_after:
            raise DeviceError(f"fake camera {self.name}: disconnected (injected)")
        if self.n_grabs in self.fail_grabs:
            raise DeviceError(f"fake camera {self.name}: frame dropped (injected)")
        truth = self.true_uv()
        if self.render:
            img = _render_checkerboard(self.target, self._intr, inv(self.T_base_cam) @ self._robot_pose()
                                       @ self.T_flange_board)
        else:
            img = np.full((4, 4), 128, np.uint8)
        q = self.robot._q if isinstance(self.robot, FakeRobot) else self.robot.joint_positions()
        self.cell._register(self.name, img, truth, q)
        self._t = max(self._t + 1e-3, time.monotonic())
        return Frame(camera=self.name, image=img, stamp_s=self._t)

    def close(self) -> None:
        pass


def _render_checkerboard(target: Target, intr: Intrinsics, T_cam_board: np.ndarray) -> np.ndarray:
    """Grey image of a checkerboard (squares around the inner-corner grid plus a white margin)
    through a pinhole homography; distortion is ignored (fake cameras have none)."""
    import cv2

    s = target.pitch_m
    ppm = 40.0 / s  # 40 texels per square
    nx, ny = target.cols + 1, target.rows + 1
    margin = 1.0
    Wt, Ht = int((nx + 2 * margin) * 40), int((ny + 2 * margin) * 40)
    tex = np.full((Ht, Wt), 255, np.uint8)
    for a in range(ny):
        for b in range(nx):
            if (a + b) % 2 == 0:
                y0, x0 = int((a + margin) * 40), int((b + margin) * 40)
                tex[y0:y0 + 40, x0:x0 + 40] = 0
    # texture pixel (c, r) <-> board (x, y): x = (c + 0.5) / ppm - (margin + 1) * s (inner corner 0 at square 1)
    A_board_tex = np.array([[1 / ppm, 0, 0.5 / ppm - (margin + 1) * s], [0, 1 / ppm, 0.5 / ppm - (margin + 1) * s], [0, 0, 1]])
    Hcb = intr.K @ np.column_stack([T_cam_board[:3, 0], T_cam_board[:3, 1], T_cam_board[:3, 3]])
    Hm = Hcb @ A_board_tex
    img = cv2.warpPerspective(tex, Hm, (intr.width_px, intr.height_px), flags=cv2.INTER_AREA,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=200)
    return img


@dataclass
class FakeCell:
    """A fake eye-to-hand workcell: robot, cameras, a trajectory and a truth detector."""

    robot: FakeRobot
    cameras: list
    trajectory: object
    target: Target
    T_flange_board: np.ndarray
    pixel_sigma_px: float = 0.2
    seed: int = 0

    def __post_init__(self):
        self._frames = {}

    def _register(self, cam, img, truth, q):
        self._frames[id(img)] = (img, cam, truth, np.asarray(q).copy())
        if len(self._frames) > 64:
            self._frames.pop(next(iter(self._frames)))

    def detector(self, image, target, intrinsics):
        """Truth detector: projected corners + seeded noise for a frame a fake camera returned,
        ``None`` when the board is not fully in view."""
        got = self._frames.get(id(image))
        if got is None or got[0] is not image:
            return None
        _, cam, truth, q = got
        if truth is None:
            return None
        ids, uv = truth
        h = hashlib.sha256(f"{self.seed}/{cam}/".encode() + np.round(q, 9).tobytes()).digest()
        rng = np.random.default_rng(int.from_bytes(h[:8], "little"))
        return ids, uv + rng.normal(scale=self.pixel_sigma_px, size=uv.shape)

    def close(self):
        for c in self.cameras:
            c.close()
        self.robot.close()


def make_fake_cell(n_cameras: int = 2, n_poses: int = 10, seed: int = 0, render: bool = False,
                   image_size=(320, 240), hfov_deg: float = 60.0, camera_faults: dict | None = None,
                   robot_kwargs: dict | None = None, target: Target | None = None, speed_scale: float = 0.2) -> FakeCell:
    """A seeded fake cell whose trajectory presents the board to the cameras in turn.

    Args:
        camera_faults: camera name -> kwargs for :class:`FakeCamera` (``fail_grabs``, ``disconnect_after``).
        robot_kwargs: kwargs for :class:`FakeRobot`.
    """

    rng = np.random.default_rng(seed)
    target = target or a4_board_54()
    W, H = image_size
    intr = Intrinsics.from_hfov(W, H, hfov_deg)
    robot = FakeRobot(**(robot_kwargs or {}))
    cell = FakeCell(robot=robot, cameras=[], trajectory=None, target=target, T_flange_board=DEFAULT_T_FLANGE_BOARD,
                    seed=seed)
    faults = camera_faults or {}
    T_cams = {}
    for k in range(n_cameras):
        ang = np.radians(-40 + 80 * k / max(n_cameras - 1, 1)) if n_cameras > 1 else 0.0
        eye = WORKSPACE_CENTRE_M + np.array([0.7 * np.cos(ang), 0.7 * np.sin(ang), 0.3])
        name = f"cam{k}"
        T_cams[name] = look_at(eye, WORKSPACE_CENTRE_M)
        cell.cameras.append(FakeCamera(name, T_cams[name], intr, robot, target, cell.T_flange_board, cell, render=render,
                                       **faults.get(name, {})))
    centre_b = target.points_board_m.mean(axis=0)
    poses = []
    names = list(T_cams)
    for i in range(n_poses):
        centre = WORKSPACE_CENTRE_M + rng.uniform(-0.05, 0.05, 3)
        if len(names) > 1 and i % 3 == 2:  # some poses aimed between two cameras, so both see the board
            T_aim = T_cams[names[0]].copy()
            T_aim[:3, 3] = (T_cams[names[(i // 3) % len(names)]][:3, 3] + T_cams[names[(i // 3 + 1) % len(names)]][:3, 3]) / 2
        else:
            T_aim = T_cams[names[i % len(names)]]
        T_base_board = random_board_facing(T_aim, centre, 15.0, rng) @ make_T(np.eye(3), -centre_b)
        T_bf = T_base_board @ inv(cell.T_flange_board)
        poses.append(TrajectoryPose(q_rad=q_from_T(T_bf), T_base_flange=T_bf))
    cell.trajectory = Trajectory(poses=tuple(poses), speed_scale=speed_scale)
    return cell
