"""A simulated hand-held board in front of one camera, as a camera device (no hardware needed).

:class:`HandheldBoardCamera` implements :class:`calibgraph.acquire.interfaces.Camera`: every
``grab`` advances a simulated clock by one frame period and renders the board where the hand
holds it, the way :mod:`calibgraph.sim.session` renders a session image (the planar board through
the camera's true model, then the sensor model with a per-frame auto-exposure gain).

The hand's motion is a smooth, human-like random walk: it picks a pose of the board at random
(:func:`calibgraph.solver.camera.session_plan.session_poses` drawn with the device's generator: 0.3-1 m
away, tilted by 20-45 degrees, anywhere in the image), carries the board there on a minimum-jerk
path (position and rotation, 0.8-1.8 s), holds it there for 0.4-1.0 s with a slight tremor, then
picks the next. While it moves, the frame is motion-blurred by the distance the board's image
travels during the exposure (``exposure_fraction`` of the frame period). The true intrinsics
render; :meth:`intrinsics` reports the ones the camera would report (a device's factory values).

With ``follows_hints`` the hand is a user who does what the live session says
(:func:`calibgraph.acquire.live_session.run_live_session` calls :meth:`guide` after every frame
with the hint's pose): each move goes to the hinted pose as a person would reach it (the board's
centre off by ``AIM_LATERAL`` of its distance across and ``AIM_DEPTH`` along the line of sight, its
orientation by ``AIM_DEG`` about each axis, 1-sigma; drawn again while the board would leave the
image), it is held for up to ``GUIDED_HOLD_S`` and left ``REACTION_S`` after the frame is taken.
Without it, the walk ignores the hints (a user who moves the board about at random).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calibgraph.acquire.interfaces import DeviceError, Frame
from calibgraph.core.camera import Intrinsics
from calibgraph.core.targets import Target
from calibgraph.core.transforms import exp_so3, log_so3, make_T
from calibgraph.sim.session import render_session_image
from calibgraph.sim.workcell import Realism
from calibgraph.solver.camera.session_plan import session_poses

DISTANCE_RANGE_M = (0.3, 1.0)
MOVE_S = (0.8, 1.8)  # how long one move from pose to pose takes
HOLD_S = (0.4, 1.0)  # how long the hand holds the board still in a pose
TREMOR_M = 3e-5  # 1-sigma of a steady hand's tremor while holding (30 um)
GOALS_PER_DRAW = 16
AIM_LATERAL = 0.03  # a guided user's aim: 1-sigma of the board centre across the line of sight, share of the distance
AIM_DEPTH = 0.04  # ... along it, share of the distance
AIM_DEG = 4.0  # ... of the orientation about each axis, degrees
GUIDED_HOLD_S = (1.5, 2.5)  # a guided user holds the board still until the frame is taken, or this long
REACTION_S = 0.3  # ... and moves on this long after it is


def camera_seed(seed: int, name: str) -> int:
    """The seed of camera ``name``'s hand-held board in a cell seeded ``seed``: each camera its own
    walk and noise draw (a cell's seed given to every camera made their frames identical, and
    comparing cameras no check of the 1-sigma), the same for a camera from run to run."""
    import zlib

    return int(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, zlib.crc32(name.encode("utf-8"))]).generate_state(1)[0])


def _min_jerk(s: float) -> float:
    """Minimum-jerk profile 0 -> 1 over s in [0, 1] (a reaching hand's speed profile)."""
    s = min(max(s, 0.0), 1.0)
    return s ** 3 * (10.0 - 15.0 * s + 6.0 * s * s)


class HandheldBoardCamera:
    """A camera watching a hand-held board (module docstring).

    Args:
        name: the camera's name.
        true_intrinsics: what the images are rendered with (image size required).
        target: the board.
        reported: the intrinsics :meth:`intrinsics` reports (default: the true ones).
        realism: the sensor model (default ``Realism()``); its motion blur is replaced per frame.
        fps: frames per second of the simulated clock.
        exposure_fraction: the share of a frame period the shutter is open (sets the motion blur).
        distance_range_m: the board's distances from the camera.
        seed: seeds the walk, the exposures and the noise.
        max_frames: after this many frames ``grab`` raises :class:`DeviceError` (a finite stream);
            None: endless.
        follows_hints: the hand goes where :meth:`guide` says (module docstring); else a random walk.
    """

    def __init__(self, name: str, true_intrinsics: Intrinsics, target: Target, reported: Intrinsics | None = None,
                 realism: Realism | None = None, fps: float = 10.0, exposure_fraction: float = 0.3,
                 distance_range_m=DISTANCE_RANGE_M, seed: int = 0, max_frames: int | None = None,
                 follows_hints: bool = False):
        if true_intrinsics.width_px <= 0 or true_intrinsics.height_px <= 0:
            raise DeviceError(f"simulated hand-held board {name}: the camera needs its image size.")
        self.name = name
        self.true_intrinsics = true_intrinsics
        self.target = target
        self._reported = reported if reported is not None else true_intrinsics
        self.realism = realism or Realism()
        self.dt_s = 1.0 / float(fps)
        self.exposure_fraction = float(exposure_fraction)
        self.distance_range_m = tuple(float(d) for d in distance_range_m)
        self.max_frames = max_frames
        self._rng = np.random.default_rng(seed)
        self._goals = []
        self._t_s = 0.0
        self._frames = 0
        self._closed = False
        self.true_poses = []  # (stamp_s, T_cam_board) of every frame: the ground truth
        self.follows_hints = bool(follows_hints)
        self._wanted = None  # the pose the session's hint asks for
        self._seg = self._hold_segment(self._next_goal(), 0.0)
        self._T_prev = self.pose_at(0.0)

    # -- the hand ----------------------------------------------------------------------------------
    def _next_goal(self) -> np.ndarray:
        if not self._goals:
            poses = session_poses(self.true_intrinsics, self.target, GOALS_PER_DRAW, self.distance_range_m,
                                  rng=self._rng)
            self._goals = [poses[i] for i in self._rng.permutation(len(poses))]
        return self._goals.pop()

    def _aim(self, T: np.ndarray) -> np.ndarray:
        """Pose ``T`` as a person reaches it (``AIM_*``), drawn again while the board would leave the image."""
        centre = np.append(np.mean(np.reshape(self.target.extent_m, (2, 2)), axis=0), 0.0)
        x0, y0, x1, y1 = self.target.extent_m
        outline = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]])
        c = T[:3, :3] @ centre + T[:3, 3]
        for _ in range(20):
            R = exp_so3(np.radians(AIM_DEG) * self._rng.normal(size=3)) @ T[:3, :3]
            c2 = c + c[2] * np.array([AIM_LATERAL, AIM_LATERAL, AIM_DEPTH]) * self._rng.normal(size=3)
            t = c2 - R @ centre
            p = outline @ R.T + t
            if np.all(p[:, 2] > 0.05) and np.all(self.true_intrinsics.in_image(self.true_intrinsics.project(p),
                                                                               margin_px=4.0)):
                return make_T(R, t)
        return T.copy()

    def guide(self, T_cam_board, taken: bool = False) -> None:
        """The live session's hint (the pose it asks for, None when it asks for nothing) and whether the
        frame was taken; acted on only when the hand ``follows_hints``."""
        if not self.follows_hints:
            return
        self._wanted = None if T_cam_board is None else np.array(T_cam_board, float)
        if taken and self._seg["kind"] == "hold":
            self._seg["t1"] = min(self._seg["t1"], self._t_s + REACTION_S)

    def _hold_segment(self, T: np.ndarray, t0: float) -> dict:
        hold = GUIDED_HOLD_S if self.follows_hints else HOLD_S
        return {"kind": "hold", "T": T, "t0": t0, "t1": t0 + float(self._rng.uniform(*hold))}

    def _move_segment(self, T0: np.ndarray, t0: float) -> dict:
        T1 = self._aim(self._wanted) if self.follows_hints and self._wanted is not None else self._next_goal()
        return {"kind": "move", "T0": T0, "T1": T1, "w": log_so3(T1[:3, :3] @ T0[:3, :3].T), "t0": t0,
                "t1": t0 + float(self._rng.uniform(*MOVE_S))}

    def pose_at(self, t_s: float) -> np.ndarray:
        """T_cam_board at time ``t_s`` (the walk goes forward only: ``t_s`` never before the last call's)."""
        while t_s >= self._seg["t1"]:
            seg = self._seg
            end = seg["T"] if seg["kind"] == "hold" else seg["T1"]
            self._seg = self._move_segment(end, seg["t1"]) if seg["kind"] == "hold" else self._hold_segment(end, seg["t1"])
        seg = self._seg
        if seg["kind"] == "hold":
            T = seg["T"].copy()
            T[:3, 3] += self._rng.normal(0.0, TREMOR_M, 3)
            return T
        s = _min_jerk((t_s - seg["t0"]) / (seg["t1"] - seg["t0"]))
        T0, T1 = seg["T0"], seg["T1"]
        return make_T(exp_so3(s * seg["w"]) @ T0[:3, :3], (1.0 - s) * T0[:3, 3] + s * T1[:3, 3])

    def _blur_px(self, T_a: np.ndarray, T_b: np.ndarray) -> float:
        """How far the board's image moves during the exposure: its corners' largest travel over one
        frame period, times the shutter's share of it."""
        pts = self.target.points_board_m[[0, self.target.n_points - 1]]
        uv_a = self.true_intrinsics.project((pts @ T_a[:3, :3].T) + T_a[:3, 3])
        uv_b = self.true_intrinsics.project((pts @ T_b[:3, :3].T) + T_b[:3, 3])
        return float(np.max(np.hypot(*(uv_b - uv_a).T))) * self.exposure_fraction

    # -- Camera protocol ---------------------------------------------------------------------------
    def intrinsics(self) -> Intrinsics:
        return self._reported

    def grab(self) -> Frame:
        if self._closed:
            raise DeviceError(f"simulated hand-held board {self.name}: used after close().")
        if self.max_frames is not None and self._frames >= self.max_frames:
            raise DeviceError(f"simulated hand-held board {self.name}: the stream ended after {self._frames} frames.")
        self._t_s += self.dt_s
        T = self.pose_at(self._t_s)
        blur = self._blur_px(self._T_prev, T)
        self._T_prev = T
        realism = replace(self.realism, motion_blur_px=blur if blur > 0.3 else 0.0)
        img = render_session_image(self.target, self.true_intrinsics, T, realism, self._rng)
        self._frames += 1
        self.true_poses.append((self._t_s, T))
        return Frame(camera=self.name, image=img, stamp_s=self._t_s)

    def close(self) -> None:
        self._closed = True
