"""The hardware edge as seen by the engine: a Robot and a Camera.

Real drivers (the ``drivers/`` folder, installed as ``calibgraph_drivers``; opened by
:mod:`calibgraph.acquire.devices`) and the simulated workcell (``calibgraph.sim``) implement these, so
the acquisition pipeline that runs in simulation is the one that runs on hardware. Implementations
raise :class:`DeviceError` when the device fails or disconnects, and
:class:`UnreachableError` for a target the robot cannot or may not reach.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import CalibgraphError


class DeviceError(CalibgraphError):
    """A camera or robot failed, timed out or disconnected."""


class UnreachableError(CalibgraphError):
    """A requested robot target is unreachable or violates a safety limit."""


@dataclass(frozen=True)
class Frame:
    """One image from one camera.

    Attributes:
        camera: camera name.
        image: (H, W) uint8 grey or (H, W, 3) uint8 BGR (OpenCV order).
        stamp_s: acquisition time, seconds (device clock or host clock; monotonic per camera).
    """

    camera: str
    image: np.ndarray
    stamp_s: float


@runtime_checkable
class Robot(Protocol):
    """A robot arm that moves the target (eye-to-hand) or the cameras (eye-in-hand)."""

    def joint_positions(self) -> np.ndarray:
        """Current joint angles q_rad (n,)."""

    def flange_pose(self) -> np.ndarray:
        """Current T_base_flange (4, 4) from forward kinematics, metres."""

    def move_to_joints(self, q_rad: np.ndarray, speed_scale: float = 0.2) -> None:
        """Joint-space motion to ``q_rad``; blocks until the motion ends."""

    def is_settled(self) -> bool:
        """True when the arm is still (joint velocities below the settle threshold)."""

    def close(self) -> None:
        """Release the connection."""


@runtime_checkable
class Camera(Protocol):
    """A camera that grabs colour frames."""

    name: str

    def intrinsics(self) -> Intrinsics:
        """Device intrinsics and distortion of the stream :meth:`grab` returns."""

    def grab(self) -> Frame:
        """Grab one fresh frame (not a buffered one from before the robot settled)."""

    def close(self) -> None:
        """Release the device."""
