"""The device registry: how a robot or camera entry of a workcell becomes a device.

=========  ======================================================  ===========================
driver     device                                                  package (an optional extra)
=========  ======================================================  ===========================
sim        the simulated cell (robot and cameras of one world)     ``calibgraph[sim]``
franka     Franka Panda / FR3 arm (robot)                          ``calibgraph_drivers.franka``
realsense  Intel RealSense D455 / L515 colour (camera)             ``calibgraph_drivers.realsense``
ros2       any ROS 2 camera (``sensor_msgs/Image`` + ``CameraInfo``)  ``calibgraph_drivers.ros2``
kinect     Kinect V2 colour (camera)                               ``calibgraph_drivers.kinect``
=========  ======================================================  ===========================

A hardware driver is imported only when a workcell names it; a camera entry's keys are its
driver's constructor arguments (a key it does not take is refused with the ones it does, apart
from the keys only the planner reads: ``hint``, ``preset``, ``intrinsics``). The simulator sits at
the edge of the package (it renders with MuJoCo), so the caller hands it in as ``simulate``: a
function ``simulate(world, where, render_check, skip_hidden) -> Simulation`` of a simulated world
mapping.

Policies: a real robot never moves without the cleared-cell confirmation (a dry run connects if it
can and plans without the robot if it cannot); a hardware camera that cannot open is reported and
left out, no camera at all is an error.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, field
from pathlib import Path

from calibgraph.core.errors import InputError
from calibgraph.io.camera_file import check_camera_names, check_image_size

__all__ = ["ROBOT_DRIVERS", "CAMERA_DRIVERS", "ROBOT_KEYS", "SIM_ROBOT_KEYS", "PLANNING_KEYS", "Simulation", "Devices",
           "open_camera", "open_cameras", "connect_franka", "open_devices"]

ROBOT_DRIVERS = ("sim", "franka")
CAMERA_DRIVERS = ("sim", "realsense", "ros2", "kinect")
ROBOT_KEYS = {"driver", "ip", "model", "realtime", "settle_velocity_rad_s"}
SIM_ROBOT_KEYS = {"fk_sigma_translation_m", "fk_sigma_rotation_deg"}
PLANNING_KEYS = {"hint", "preset", "intrinsics"}  # camera keys the planner reads, not the driver


@dataclass
class Simulation:
    """A simulated cell as devices: what ``simulate`` returns.

    Attributes:
        robot, cameras (name -> camera), detector: the devices and the detector for their frames.
        target: the simulated board; camera_names: the world's cameras.
        write_ground_truth: ``write_ground_truth(out_dir)`` writes ``ground_truth.json`` there.
    """

    robot: object
    cameras: dict
    detector: object
    target: object
    camera_names: list
    write_ground_truth: object


@dataclass
class Devices:
    """The opened devices of a run; :meth:`close` releases them."""

    robot: object = None
    cameras: dict = field(default_factory=dict)
    detector: object = None
    simulation: Simulation | None = None
    closers: list = field(default_factory=list)

    def close(self) -> None:
        for c in self.closers:
            try:
                c.close()
            except Exception:  # closing is best effort; the data is already on disk
                pass

    def write_ground_truth(self, out) -> None:
        """``ground_truth.json`` beside a simulated capture that wrote anything."""
        if self.simulation is not None and (Path(out) / "captures").is_dir():
            self.simulation.write_ground_truth(out)


class FileIntrinsicsCamera:
    """A camera whose intrinsics come from a camera file (``--intrinsics NAME=CAM.yaml``) instead of
    the device; everything else is the device's. A file made for another image size is refused
    when the intrinsics are first asked for."""

    def __init__(self, name: str, camera, intrinsics, where: str):
        self._name, self._camera, self._intrinsics, self._where = name, camera, intrinsics, where

    def intrinsics(self):
        check_image_size(self._name, self._camera.intrinsics(), self._intrinsics, self._where)
        return self._intrinsics

    def __getattr__(self, attr):
        return getattr(self._camera, attr)


def _camera_class(driver: str):
    if driver == "realsense":
        from calibgraph_drivers.realsense import RealSenseCamera

        return RealSenseCamera
    if driver == "ros2":
        from calibgraph_drivers.ros2 import Ros2Camera

        return Ros2Camera
    if driver == "kinect":
        from calibgraph_drivers.kinect import KinectV2Camera

        return KinectV2Camera
    return None


def open_camera(name: str, spec: dict, where: str):
    """A Camera for one workcell camera entry (hardware drivers only)."""
    spec = dict(spec or {})
    drv = spec.pop("driver", "sim")
    cls = _camera_class(drv)
    if cls is None:
        raise InputError(f"{where}: camera {name!r}: driver {drv!r} is not a hardware driver.")
    allowed = set(inspect.signature(cls).parameters) - {"name"}
    unknown = set(spec) - allowed - PLANNING_KEYS
    if unknown:
        raise InputError(f"{where}: camera {name!r} ({drv}): unknown keys {', '.join(sorted(unknown))}; allowed: "
                         f"{', '.join(sorted(allowed | {'driver'}))}.")
    try:
        return cls(name, **{k: v for k, v in spec.items() if k in allowed})
    except TypeError as e:
        raise InputError(f"{where}: camera {name!r} ({drv}): {e}") from None


def open_cameras(specs: dict, where: str, log, devices: Devices) -> None:
    """Open every camera of ``specs`` (name -> driver entry) into ``devices``; one that cannot open
    is reported and left out (it is then 'not seen'); no camera at all is an error."""
    for name, spec in specs.items():
        try:
            cam = open_camera(name, spec, where)
        except InputError:
            raise
        except Exception as e:  # a camera that cannot open is reported; the others go on
            log(f"camera {name}: cannot open ({type(e).__name__}: {e}); continuing without it")
            continue
        devices.cameras[name] = cam
        devices.closers.append(cam)
    if not devices.cameras:
        raise InputError(f"{where}: no camera could be opened.")


def connect_franka(robot: dict, where: str, ip: str | None = None, dry_run: bool = False, log=print,
                   dry_run_instead: str = "planning without the robot"):
    """The Franka arm at ``robot.ip`` (or ``ip``); a dry run goes on without a connection (None),
    saying what it does ``dry_run_instead``."""
    from calibgraph_drivers.franka import FrankaRobot

    ip = ip or robot.get("ip")
    if not ip:
        raise InputError(f"{where}: robot.ip (or --robot-ip) is needed for the franka driver.")
    try:
        return FrankaRobot(ip, model=robot.get("model", "fr3"), realtime=bool(robot.get("realtime", True)),
                           settle_velocity_rad_s=float(robot.get("settle_velocity_rad_s", 0.005)))
    except Exception as e:
        if not dry_run:
            raise
        log(f"robot at {ip}: not connected ({e}); {dry_run_instead}")
        return None


def open_devices(driver: str, workcell=None, *, world=None, names=None, simulate=None, dry_run: bool = False,
                 cleared: bool = False, robot_ip: str | None = None, log=print, dry_run_shows: str = "",
                 plans_without_robot: str = "", render_check: bool = False, skip_hidden: bool = False,
                 check_target: bool = False, camera_files: dict | None = None) -> Devices:
    """The robot, cameras and detector of a run (see the module docstring).

    Args:
        driver: the robot driver ('sim' or 'franka').
        workcell: the :class:`~calibgraph.acquire.workcell.WorkcellSpec` (robot and camera entries).
        world: ``(mapping, where)`` of the simulated world ``simulate`` renders (driver 'sim').
        names: the cameras wanted (the planning cell's); None: every simulated camera plus every
            hardware camera of the workcell.
        dry_run: open no camera; a robot that cannot connect is planned without.
        cleared: the operator confirmed the cell is clear (required before a real robot moves).
        dry_run_shows, plans_without_robot: how the refusal and the dry run without a robot say
            what a dry run does.
        render_check, skip_hidden, check_target: passed to ``simulate`` / checked against it.
        camera_files: name -> Intrinsics of ``--intrinsics NAME=CAM.yaml``: those cameras report
            the file's intrinsics (with its covariance) instead of their own.
    """
    dev = Devices()
    try:
        hw = {}
        where = workcell.where if workcell is not None else "capture"
        if driver == "sim":
            if simulate is None or world is None:
                raise InputError("capture: the simulated robot needs a simulated world.")
            sim = simulate(world[0], world[1], render_check=render_check, skip_hidden=skip_hidden)
            dev.simulation, dev.robot, dev.detector = sim, sim.robot, sim.detector
            if names is None:
                dev.cameras.update(sim.cameras)
                hw = workcell.hardware_cameras() if workcell is not None else {}
            else:
                missing = [c for c in names if c not in sim.camera_names]
                if missing:
                    raise InputError(f"{where}: cameras {', '.join(missing)} are not in the simulated world {world[1]} "
                                     f"(it has {', '.join(sim.camera_names)}).")
                if check_target and workcell is not None and sim.target != workcell.target:
                    raise InputError(f"{where}: board {workcell.target.to_dict()} differs from the simulated world's "
                                     f"{sim.target.to_dict()}.")
                dev.cameras.update({c: sim.cameras[c] for c in names})
        else:
            if not dry_run and not cleared:
                raise InputError("capture: a real robot is configured; it will not move without "
                                 f"--i-have-cleared-the-cell. Run with --dry-run first to {dry_run_shows}.")
            dev.robot = connect_franka(workcell.robot if workcell is not None else {}, where, robot_ip, dry_run, log,
                                       plans_without_robot)
            hw = (workcell.hardware_cameras() if names is None else
                  {n: workcell.cameras.get(n) or {} for n in names}) if workcell is not None else {}
        if dev.robot is not None:
            dev.closers.append(dev.robot)
        if not dry_run and (hw or driver != "sim"):
            open_cameras(hw, where, log, dev)
        if camera_files:
            known = set(dev.cameras) | set(names or ()) | (set(workcell.cameras) if workcell is not None else set())
            check_camera_names(camera_files, sorted(known), where)
            for name, intr in camera_files.items():
                if name in dev.cameras:
                    dev.cameras[name] = FileIntrinsicsCamera(name, dev.cameras[name], intr, where)
        return dev
    except BaseException:
        dev.close()
        raise
