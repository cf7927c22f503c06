"""Simulated robot and cameras implementing :mod:`calibgraph.acquire.interfaces`.

Both share one :class:`~calibgraph.sim.render.SimWorld`. The robot is kinematic: a motion takes
the time a joint-space move at ``speed_scale`` of the FR3's joint velocity limits would take (on
a simulated clock, not wall time) and ends settled. It reports its flange pose the way a real
controller does, through its forward kinematics, with an optional per-pose error
(``fk_sigma_*``: the robot's kinematic model is never exact); the true pose stays in the world
and goes to the ground truth. With joint zero offsets (the workcell's ``joint_offsets_rad``) the
world turns to the true angles = commanded (encoder) angles + offsets, while the robot reports the
encoder angles and the nominal FK of them, as a real arm with uncalibrated joint zeros does.

The robot starts at :func:`calibgraph.sim.ik.start_configuration` (the simulator's home when the
world is in the model's all-zero pose, which no real arm can take), the configuration
:func:`calibgraph.plan.planner.plan_trajectory` plans from. Like a real arm's collision reflex, it
refuses a motion whose straight joint path (or goal) collides, with
:class:`~calibgraph.acquire.interfaces.UnreachableError`, and stays where it is.
"""

from __future__ import annotations

import numpy as np

from calibgraph.acquire.interfaces import DeviceError, Frame, UnreachableError
from calibgraph.core.camera import Intrinsics
from calibgraph.core.transforms import exp_so3, make_T
from calibgraph.plan.visibility import board_visibility
from calibgraph.sim.ik import in_collision, path_collision, start_configuration

# FR3 maximum joint velocities (rad/s), Franka datasheet.
FR3_MAX_JOINT_VELOCITY_RAD_S = np.array([2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26])


class SimRobot:
    """Kinematic FR3 in a :class:`SimWorld` (implements :class:`calibgraph.acquire.interfaces.Robot`).

    Args:
        world: the shared world.
        fk_sigma_translation_m, fk_sigma_rotation_rad: 1-sigma of the error between the reported
            and the true flange pose, drawn once per motion (Panda class: ~0.1 mm / 0.01 deg).
        seed: seed of that error.
        joint_offsets_rad: (7,) joint zero offsets, physical angle = reported + offset (default: the
            world's workcell's ``joint_offsets_rad``). Joint targets and limits are in reported angles.
    """

    def __init__(self, world, fk_sigma_translation_m: float = 0.0, fk_sigma_rotation_rad: float = 0.0, seed: int = 0,
                 joint_offsets_rad=None):
        self.world = world
        if joint_offsets_rad is None:
            joint_offsets_rad = getattr(getattr(world, "cell", None), "joint_offsets_rad", None)
        self.joint_offsets_rad = np.zeros(7) if joint_offsets_rad is None else np.asarray(joint_offsets_rad, float).reshape(7)
        self.fk_sigma_translation_m = float(fk_sigma_translation_m)
        self.fk_sigma_rotation_rad = float(fk_sigma_rotation_rad)
        self._rng = np.random.default_rng(seed)
        self._T_error = np.eye(4)
        self._closed = False
        self.true_flange_poses = []  # (stamp_s, q_rad, T_base_flange true) after every motion
        world.set_q(start_configuration(world))

    # -- Robot protocol ---------------------------------------------------------------------------
    def joint_positions(self) -> np.ndarray:
        """Reported (encoder) angles: the true ones minus the joint offsets."""
        self._check_open()
        return self.world.q() - self.joint_offsets_rad

    def flange_pose(self) -> np.ndarray:
        """Reported T_base_flange: the nominal FK of the reported angles (the true pose when there are no
        joint offsets) times the current kinematic error."""
        self._check_open()
        if not self.joint_offsets_rad.any():
            return self.world.T_base_flange() @ self._T_error
        return self.forward_kinematics(self.joint_positions()) @ self._T_error

    def true_flange_pose(self) -> np.ndarray:
        """Noise-free T_base_flange (ground truth; a real robot cannot tell you this)."""
        return self.world.T_base_flange()

    def move_to_joints(self, q_rad, speed_scale: float = 0.2) -> None:
        self._check_open()
        q = np.asarray(q_rad, float).reshape(-1)
        if q.shape != (7,) or not np.all(np.isfinite(q)):
            raise UnreachableError(f"simulated FR3: expected 7 finite joint angles, got {np.asarray(q_rad).tolist()}.")
        bad = np.nonzero((q < self.world.q_lo) | (q > self.world.q_hi))[0]
        if bad.size:
            j = int(bad[0])
            raise UnreachableError(f"simulated FR3: joint {j + 1} = {q[j]:.3f} rad is outside "
                                   f"[{self.world.q_lo[j]:.3f}, {self.world.q_hi[j]:.3f}].")
        if not (0 < speed_scale <= 1):
            raise UnreachableError(f"simulated FR3: speed_scale must be in (0, 1], got {speed_scale}.")
        q_now = self.world.q()
        hits = in_collision(self.world, q + self.joint_offsets_rad)  # leaves the model there: put the arm back
        self.world.set_q(q_now)
        if hits:
            raise UnreachableError(f"simulated FR3: the goal configuration collides ({hits[0][0]} with {hits[0][1]}).")
        hits = path_collision(self.world, q_now, q + self.joint_offsets_rad)
        if hits:
            raise UnreachableError(f"simulated FR3: the straight joint motion to the goal collides ({hits[0][0]} with "
                                   f"{hits[0][1]}); the arm stopped before moving. Plan via poses around the obstacle "
                                   "(calibgraph.plan.planner.plan_trajectory does).")
        q_true = q + self.joint_offsets_rad
        dq = np.abs(q_true - self.world.q())
        self.world.clock_s += float(np.max(dq / (FR3_MAX_JOINT_VELOCITY_RAD_S * speed_scale))) + 0.5
        self.world.set_q(q_true)
        self._T_error = make_T(exp_so3(self._rng.normal(scale=self.fk_sigma_rotation_rad, size=3)),
                               self._rng.normal(scale=self.fk_sigma_translation_m, size=3))
        self.true_flange_poses.append((self.world.clock_s, q_true.copy(), self.world.T_base_flange()))

    def is_settled(self) -> bool:
        self._check_open()
        return True

    def close(self) -> None:
        self._closed = True

    # -- extras used by the acquisition's safety checks -----------------------------------------------
    def joint_limits(self):
        """(q_min_rad (7,), q_max_rad (7,)) of the model."""
        return self.world.q_lo.copy(), self.world.q_hi.copy()

    def forward_kinematics(self, q_rad) -> np.ndarray:
        """T_base_flange at ``q_rad`` from the MuJoCo model, the robot's nominal kinematics (the state is
        left unchanged)."""
        q0 = self.world.q()
        self.world.set_q(np.asarray(q_rad, float))
        T = self.world.T_base_flange()
        self.world.set_q(q0)
        return T

    def _check_open(self):
        if self._closed:
            raise DeviceError("simulated robot: used after close().")


def board_plainly_hidden(world, camera: str) -> bool:
    """True when the simulation's ground truth says ``camera`` cannot possibly detect the board at
    the world's current state (board outside the image, seen from behind or edge-on beyond
    80 degrees, or squares under 3 px). Looser than the planner's visibility test, so marginal
    views are still left to the real detector; no occlusion test for the same reason."""

    return not board_visibility(world, camera, world.T_base_board(), margin_px=0.0, max_angle_deg=80.0,
                                min_square_px=3.0, check_occlusion=False)


class SimCamera:
    """A fixed camera of the simulated cell (implements :class:`calibgraph.acquire.interfaces.Camera`).

    ``grab`` renders the world at its current state (with the camera's true intrinsics) and degrades
    the image as the workcell's realism settings say; frames are grey (H, W) uint8. ``intrinsics``
    reports what a real device would: the true ones off by the workcell's
    ``realism.reported_intrinsics`` (:meth:`calibgraph.sim.workcell.Workcell.reported_intrinsics`).

    With ``world.skip_hidden_renders`` set (what :func:`calibgraph.sim.rendered_dataset.simulate_dataset`
    does with its detection gate on), a camera for which :func:`board_plainly_hidden` holds returns
    a blank frame instead of rendering: the gated detector rejects such frames anyway, and the
    acquisition writes no image for rejected views, so the dataset is unchanged and the run is
    several times faster.
    """

    def __init__(self, world, name: str):
        self.world = world
        self.name = name
        self.spec = world.cell.camera(name)
        self._reported = world.cell.reported_intrinsics(name)
        self._closed = False
        self._index = world.cell.camera_names.index(name)

    def intrinsics(self) -> Intrinsics:
        """The intrinsics the camera reports (not the true ones it renders with, unless 'exact')."""
        return self._reported

    def grab(self) -> Frame:
        if self._closed:
            raise DeviceError(f"simulated camera {self.name}: used after close().")
        if getattr(self.world, "skip_hidden_renders", False) and board_plainly_hidden(self.world, self.name):
            img = np.zeros((self.spec.intrinsics.height_px, self.spec.intrinsics.width_px), np.uint8)
        else:
            img = self.world.render(self.name)
        self.world.last_frame_camera[id(img)] = self.name  # lets a simulation-side detector gate know the source
        # a frame period after the last event, offset per camera (unsynchronised sensors)
        self.world.clock_s += 1.0 / 30.0
        return Frame(camera=self.name, image=img, stamp_s=self.world.clock_s + 1e-3 * self._index)

    def close(self) -> None:
        self._closed = True


def make_devices(world, fk_sigma_translation_m: float = 0.0, fk_sigma_rotation_rad: float = 0.0, seed: int = 0,
                 joint_offsets_rad=None):
    """(SimRobot, {name: SimCamera}) of a world (joint offsets default to the workcell's)."""
    robot = SimRobot(world, fk_sigma_translation_m, fk_sigma_rotation_rad, seed, joint_offsets_rad)
    cams = {c: SimCamera(world, c) for c in world.cell.camera_names}
    return robot, cams
