"""The capture workcell file: one reader for the robot, the cameras, the safety limits, the board
and the camera placements (when it is also a simulated world).

Workcell YAML: the simulator's schema (:mod:`calibgraph.sim.workcell`: ``board``, ``mount``,
``ring``, ``cameras`` with ``preset``/``position_m``, ``realism``, ...) or the cell's
(:mod:`calibgraph.plan.cell`: cameras without placements, ``hint``, ``obstacles``, ``keep_out``),
plus the hardware fields read here::

    board: a4_7x10_25mm               # a shipped board (alias a4_54), a spec file, or {kind: checkerboard, rows: 6, cols: 9, pitch_m: 0.025}
    mode: eye_to_hand                 # or eye_in_hand
    robot:
      driver: franka                  # franka | sim (default sim)
      ip: 172.16.0.2
      model: fr3                      # fr3 | panda
      realtime: true                  # libfranka real-time checks (needs an RT kernel)
    cameras:
      left:  {driver: realsense, serial: "233522071234", settle_frames: 30}
      right: {driver: ros2, image_topic: /right/color/image_raw, info_topic: /right/color/camera_info}
      top:   {driver: kinect, serial: "003415165047"}
    safety:                           # see calibgraph.acquire.safety
      robot_model: fr3
      workspace_min_m: [0.2, -0.6, 0.05]
      workspace_max_m: [0.9, 0.6, 1.0]
      max_speed_scale: 0.3

The drivers and the keys each takes are those of the device registry
(:mod:`calibgraph.acquire.devices`); a robot key no driver knows is refused with the list of
allowed ones. Degenerate geometry is refused when the file is read, before anything is planned
or moved: a camera whose ``position_m`` equals its ``look_at_m`` (no viewing direction), a
non-finite position, pose, mount, ring or floor.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibgraph.acquire.claim import content_sha256
from calibgraph.acquire.devices import CAMERA_DRIVERS, ROBOT_DRIVERS, ROBOT_KEYS, SIM_ROBOT_KEYS
from calibgraph.acquire.safety import SafetyLimits, default_cell_limits
from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target
from calibgraph.core.transforms import check_pose
from calibgraph.io.files import read_yaml
from calibgraph.io.shipped import resolve_shipped
from calibgraph.plan.cell import (
    CellDescription,
    board_by_name,
    boxes_from_list,
    cell_from_dict,
    cell_from_world_dict,
    has_placements,
)

__all__ = ["WorkcellSpec", "read_workcell", "workcell_spec", "sim_workcell_dict", "check_geometry"]


@dataclass(frozen=True)
class WorkcellSpec:
    """A workcell file as read (see the module docstring).

    Attributes:
        where: the file (for messages).
        data: the mapping as read.
        robot: the robot section.
        cameras: camera name -> its settings (``driver`` defaults to sim).
        safety: the limits every motion is checked against (the default cell model when the file
            has no ``safety:`` section: ``safety.default_model``), or None for a simulated world
            read without its hardware part.
        target: the board.
        mode: 'eye_to_hand' or 'eye_in_hand'.
        sha256: content hash of the mapping (recorded in the dataset it makes).
    """

    where: str
    data: dict
    robot: dict
    cameras: dict
    safety: SafetyLimits | None
    target: Target
    mode: str
    sha256: str

    @property
    def has_placements(self) -> bool:
        """The file places its cameras (it can be rendered as a simulated world)."""
        return has_placements(self.data)

    def robot_driver(self, override: str | None = None) -> str:
        """The robot driver (``--robot`` overrides the file's), checked against the registry."""
        driver = override or self.robot.get("driver", "sim")
        if driver not in ROBOT_DRIVERS:
            raise InputError(f"{self.where}: robot driver {driver!r} unknown; choose one of {ROBOT_DRIVERS}.")
        return driver

    def planning_cell(self, strip_placements: bool = True) -> CellDescription:
        """The cell the planner reads: the cameras without placements (stripped when the file has
        them and ``strip_placements``, refused otherwise), the board, its mount, the obstacles."""
        if self.has_placements and strip_placements:
            return cell_from_world_dict(self.data, self.where)
        return cell_from_dict(self.data, self.where)

    def sim_world(self) -> dict:
        """The part of the mapping the simulator reads (hardware-only keys removed)."""
        return sim_workcell_dict(self.data)

    def hardware_cameras(self) -> dict:
        """name -> entry of every camera with a hardware driver."""
        return {n: dict(c or {}) for n, c in self.cameras.items() if (c or {}).get("driver", "sim") != "sim"}


def sim_workcell_dict(d: dict) -> dict:
    """The part of a workcell mapping the simulator reads (hardware-only keys removed)."""
    s = {k: v for k, v in d.items() if k not in ("safety", "mode")}
    if "robot" in s:
        s["robot"] = {k: v for k, v in (s["robot"] or {}).items() if k in SIM_ROBOT_KEYS}
    if "cameras" in s:
        s["cameras"] = {n: {k: v for k, v in (c or {}).items() if k != "driver"} for n, c in (s["cameras"] or {}).items()
                        if (c or {}).get("driver", "sim") == "sim"}
    return s


def _finite(v, n: int, what: str) -> np.ndarray:
    try:
        a = np.asarray(v, float).reshape(-1)
    except (TypeError, ValueError):
        a = np.full(0, np.nan)
    if a.size != n or not np.all(np.isfinite(a)):
        raise InputError(f"{what} needs {n} finite numbers, got {v!r}.")
    return a


def check_geometry(d: dict, where: str) -> None:
    """Refuse degenerate geometry in a workcell mapping, in one line naming what is wrong."""
    if d.get("floor_z_m") is not None:
        _finite(d["floor_z_m"], 1, f"{where}: floor_z_m")
    mount = d.get("mount")
    if isinstance(mount, dict):
        if "T" in mount:
            check_pose(np.asarray(mount["T"], float), f"{where}: mount")
        for k, n in (("translation_m", 3), ("rotvec_rad", 3), ("rpy_deg", 3)):
            if k in mount:
                _finite(mount[k], n, f"{where}: mount: {k}")
    ring = d.get("ring")
    if isinstance(ring, dict) and ring.get("distances_m") is not None:
        dist = np.asarray(ring["distances_m"], dtype=object).reshape(-1)
        dist = _finite(list(dist), len(dist), f"{where}: ring: distances_m")
        if np.any(dist <= 0):
            raise InputError(f"{where}: ring: distances_m must be positive (metres from the robot base), got "
                             f"{dist.tolist()}.")
        for k in ("height_above_floor_m", "spread_deg", "start_deg"):
            if k in ring:
                _finite(ring[k], 1, f"{where}: ring: {k}")
    cams = d.get("cameras") or {}
    for name, c in (cams.items() if isinstance(cams, dict) else ()):
        if not isinstance(c, dict):
            continue
        what = f"{where}: camera {name!r}"
        if "T_base_cam" in c:
            check_pose(np.asarray(c["T_base_cam"], float) if _numeric(c["T_base_cam"]) else np.full((4, 4), np.nan),
                       f"{what}: T_base_cam")
        if "position_m" in c:
            p = _finite(c["position_m"], 3, f"{what}: position_m")
            if "look_at_m" in c:
                q = _finite(c["look_at_m"], 3, f"{what}: look_at_m")
                if np.linalg.norm(q - p) < 1e-6:
                    raise InputError(f"{what}: position_m equals look_at_m ({p.tolist()}): the camera has no viewing "
                                     "direction; give look_at_m the point it looks at (e.g. where the robot shows the "
                                     "board).")


def _numeric(v) -> bool:
    try:
        np.asarray(v, float)
        return True
    except (TypeError, ValueError):
        return False


def workcell_spec(d, where: str, hardware: bool = True) -> WorkcellSpec:
    """Read a workcell mapping (see the module docstring). With ``hardware=False`` (a simulated
    world given only to render) the robot and safety sections are not read as hardware settings."""
    if not isinstance(d, dict):
        raise InputError(f"{where}: a workcell must be a YAML mapping.")
    check_geometry(d, where)
    robot = d.get("robot") or {}
    if not isinstance(robot, dict):
        raise InputError(f"{where}: robot must be a mapping (driver, ip, model, ...).")
    cams = d.get("cameras") or {}
    if not isinstance(cams, dict):
        raise InputError(f"{where}: cameras must be a mapping name -> settings.")
    safety = None
    if hardware:
        unknown = set(robot) - ROBOT_KEYS - SIM_ROBOT_KEYS
        if unknown:
            raise InputError(f"{where}: robot: unknown keys {', '.join(sorted(unknown))}; allowed: "
                             f"{', '.join(sorted(ROBOT_KEYS | SIM_ROBOT_KEYS))}.")
        for name, c in cams.items():
            drv = (c or {}).get("driver", "sim") if isinstance(c, dict) or c is None else None
            if drv not in CAMERA_DRIVERS:
                raise InputError(f"{where}: camera {name!r}: unknown driver {drv!r}; choose one of {CAMERA_DRIVERS}.")
        safety = _safety(d, robot, where)
    mode = d.get("mode", "eye_to_hand")
    target = board_by_name(d.get("board", "a4_7x10_25mm"))
    return WorkcellSpec(where, d, robot, cams, safety, target, mode, content_sha256(d))


def _safety(d: dict, robot: dict, where: str) -> SafetyLimits:
    """The file's safety limits with its floor and obstacles; the default cell model without a section."""
    try:
        floor = d.get("floor_z_m")
        floor = None if floor is None else float(floor)
        obstacles = (boxes_from_list(d.get("obstacles"), where, False) + boxes_from_list(d.get("keep_out"), where, True))
        if d.get("safety") is None:  # no safety section: the default cell model, and callers warn
            return default_cell_limits(str(robot.get("model", "fr3")), floor_z_m=floor, obstacles=obstacles)
        return SafetyLimits.from_dict(d.get("safety"), floor_z_m=floor, obstacles=obstacles)
    except (TypeError, ValueError) as e:
        raise InputError(f"{where}: floor_z_m / obstacles / safety: {e}") from None
    except InputError as e:
        raise InputError(f"{where}: {e}") from None


def read_workcell(path, what: str = "workcell", hardware: bool = True) -> WorkcellSpec:
    """Read a workcell file (a regular file: a pipe or a device is refused, never waited on)."""
    p = resolve_shipped(path, "workcell")  # a shipped name or datasets/workcells/... from any folder
    return workcell_spec(read_yaml(p, what), str(p), hardware)
