"""Simulated cameras of a world that deliver projected corners instead of rendered images.

For tests and planning benchmarks, where what matters is which poses are chosen, not how the
corners were found: a camera "grabs" a tiny placeholder frame, and :class:`CornerOracle` (the detector)
returns the true corners (through the true chain of the world, at the robot's true joints) plus
seeded Gaussian pixel noise, when the board is fully visible, large enough and unoccluded in the
true camera (:func:`calibgraph.plan.visibility.board_visibility`), else None. With ``partial``
the oracle acts like a ChArUco detector on a board cut by the image border: the corners inside the
image (2 px margin) of a board in front of the camera, facing it within 70 deg, squares >= 4 px and
no geometry on the rays to (up to 12 of) those corners. The robot is the kinematic
:class:`~calibgraph.sim.devices.SimRobot` of the same world. Corners come from the true intrinsics;
a camera reports the workcell's reported ones (``realism.reported_intrinsics``), as
:class:`~calibgraph.sim.devices.SimCamera` does.
"""

from __future__ import annotations

import numpy as np

from calibgraph.acquire.interfaces import DeviceError, Frame
from calibgraph.core.transforms import inv
from calibgraph.plan.visibility import board_visibility, square_px
from calibgraph.sim.devices import SimRobot


class CornerOracle:
    """Detector for :class:`CornerCamera` frames (see the module docstring)."""

    def __init__(self, world, pixel_sigma_px: float = 0.1, seed: int = 0, partial: bool = False):
        self.world = world
        self.partial = bool(partial)
        self.pixel_sigma_px = float(pixel_sigma_px)
        self.rng = np.random.default_rng(seed)
        self.frames = {}

    def __call__(self, image, target, intrinsics=None):
        cam = self.frames.pop(id(image), None)
        if cam is None:
            return None
        if not board_visibility(self.world, cam, self.world.T_base_board(), margin_px=2.0, max_angle_deg=70.0,
                                min_square_px=4.0):
            return self._partial(cam, target) if self.partial else None
        spec = self.world.cell.camera(cam)
        T_cb = inv(spec.T_base_cam) @ self.world.T_base_board()
        p = target.points_board_m @ T_cb[:3, :3].T + T_cb[:3, 3]
        uv = spec.intrinsics.project(p) + self.rng.normal(scale=self.pixel_sigma_px, size=(len(p), 2))
        return np.arange(len(p)), uv

    def _partial(self, cam, target):
        spec = self.world.cell.camera(cam)
        T_bb = self.world.T_base_board()
        T_cb = inv(spec.T_base_cam) @ T_bb
        p = target.points_board_m @ T_cb[:3, :3].T + T_cb[:3, 3]
        if np.any(p[:, 2] < 0.2) or inv(T_cb)[2, 3] >= 0:  # behind the camera, or its back to the camera
            return None
        c = p.mean(axis=0)
        if T_cb[:3, 2] @ c / np.linalg.norm(c) < np.cos(np.radians(70.0)):
            return None
        uv = spec.intrinsics.project(p)
        if square_px(uv, target) < 4.0:
            return None
        ids = np.flatnonzero(spec.intrinsics.in_image(uv, margin_px=2.0))
        if len(ids) == 0:
            return None
        p_base = target.points_board_m[ids] @ T_bb[:3, :3].T + T_bb[:3, 3]
        probe = p_base[np.linspace(0, len(ids) - 1, min(len(ids), 12)).astype(int)]
        if self.world.occluded(spec.T_base_cam[:3, 3], probe):
            return None
        return ids, uv[ids] + self.rng.normal(scale=self.pixel_sigma_px, size=(len(ids), 2))


class CornerCamera:
    """A fixed camera of the world whose frames :class:`CornerOracle` turns into corners."""

    def __init__(self, world, name: str, oracle: CornerOracle):
        self.world, self.name, self.oracle = world, name, oracle
        self.spec = world.cell.camera(name)
        self._reported = world.cell.reported_intrinsics(name)
        self._closed = False

    def intrinsics(self):
        """The intrinsics the camera reports (see the module docstring)."""
        return self._reported

    def grab(self) -> Frame:
        if self._closed:
            raise DeviceError(f"camera {self.name}: used after close().")
        img = np.zeros((2, 2), np.uint8)
        self.oracle.frames[id(img)] = self.name
        self.world.clock_s += 1.0 / 30.0
        return Frame(camera=self.name, image=img, stamp_s=self.world.clock_s)

    def close(self) -> None:
        self._closed = True


def corner_devices(world, pixel_sigma_px: float = 0.1, seed: int = 0, partial: bool = False):
    """(SimRobot, {name: CornerCamera}, CornerOracle) of a world; the robot reports its flange
    with the cell's FK error; ``partial``: boards cut by the image border give their inner corners."""
    cell = world.cell
    robot = SimRobot(world, cell.fk_sigma_translation_m, np.radians(cell.fk_sigma_rotation_deg), seed)
    oracle = CornerOracle(world, pixel_sigma_px, seed, partial)
    return robot, {c: CornerCamera(world, c, oracle) for c in cell.camera_names}, oracle
