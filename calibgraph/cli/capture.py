"""``calibgraph capture``: drive the robot along a trajectory and record a dataset.

    calibgraph capture --workcell cell.yaml --trajectory traj.yaml --out DATASET
    calibgraph capture --workcell cell.yaml --out DATASET --resume            # after a crash / Ctrl-C
    calibgraph capture --workcell cell.yaml --trajectory traj.yaml --dry-run  # plan + safety checks only
    calibgraph solve DATASET

Autonomous (``--auto``, camera placements unknown; see :mod:`calibgraph.acquire.auto`)::

    calibgraph capture --auto --robot sim --sim-world WORLD.yaml [--workcell CELL.yaml] --out DIR
    calibgraph capture --auto --workcell CELL.yaml --out DIR --robot franka --i-have-cleared-the-cell
    calibgraph capture --auto --workcell CELL.yaml --out DIR --dry-run      # shows the survey, moves nothing
    calibgraph capture --auto ... --out DIR --resume                          # after a kill

Verify (``--verify``, has a camera moved since RESULT.json? see :mod:`calibgraph.acquire.verify`)::

    calibgraph capture --verify --result RESULT.json --workcell CELL.yaml --out DIR [--verify-poses 5]
    calibgraph capture --verify --result RESULT.json --workcell CELL.yaml --out DIR --robot franka --i-have-cleared-the-cell
    calibgraph capture --verify --result RESULT.json --robot sim --sim-world WORLD.yaml --out DIR

plans ``--verify-poses`` poses most sensitive to every camera's motion from the stored result (no
camera placements needed in CELL.yaml), captures them with the same safety checks and runs
``calibgraph verify`` on the capture (``DIR/verify.json``; exit 0 nothing moved, 3 something moved,
2 bad input or no verdict). With ``--robot sim`` the simulator renders ``--sim-world`` (or the
workcell itself when it is a simulator world with placements).

The simulator renders WORLD.yaml (true placements); the planner reads only CELL.yaml
(:mod:`calibgraph.plan.cell`: cameras without placements, optional hints, obstacles, keep-out
boxes), or WORLD.yaml with every placement stripped when ``--workcell`` is omitted. It writes the
dataset, ``plan_log.json``, ``result.json`` and (simulated) ``ground_truth.json``.

A real robot (``driver: franka``) never moves without ``--i-have-cleared-the-cell``; ``--dry-run``
connects to nothing that moves and opens no camera.

Workcell YAML: the simulator's schema (:mod:`calibgraph.sim.workcell`: ``board``, ``mount``,
``ring``, ``cameras`` with ``preset``/``position_m``, ``realism``, ...) plus the hardware fields
read here::

    board: a4_54                      # or {kind: checkerboard, rows: 6, cols: 9, pitch_m: 0.025}
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

Keys a driver does not know are refused with the list of allowed ones. Heavy imports (SDKs,
MuJoCo) happen only for the drivers a workcell names.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROBOT_DRIVERS = ("sim", "franka")
CAMERA_DRIVERS = ("sim", "realsense", "ros2", "kinect")
_ROBOT_KEYS = {"driver", "ip", "model", "realtime", "settle_velocity_rad_s"}
_SIM_ROBOT_KEYS = {"fk_sigma_translation_m", "fk_sigma_rotation_deg"}


def add_parser(sub):
    p = sub.add_parser("capture", help="drive the robot and record a dataset (real or simulated cell)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--workcell", type=Path, default=None,
                   help="workcell YAML (robot, cameras, safety); with --auto the cell without placements")
    p.add_argument("--trajectory", type=Path, default=None,
                   help="trajectory YAML (calibgraph-trajectory/1); with --resume defaults to DATASET/trajectory.yaml")
    p.add_argument("--out", type=Path, required=True, help="dataset folder to write")
    p.add_argument("--resume", action="store_true", help="continue an interrupted capture in --out")
    p.add_argument("--dry-run", action="store_true", help="plan and check every pose; move nothing, grab nothing")
    p.add_argument("--robot", choices=ROBOT_DRIVERS, default=None, help="override the workcell's robot driver")
    p.add_argument("--robot-ip", default=None, help="override the workcell's robot address")
    p.add_argument("--i-have-cleared-the-cell", dest="cleared", action="store_true",
                   help="confirm that nobody is inside the cell: required before a real robot moves")
    p.add_argument("--speed-scale", type=float, default=None, help="override the trajectory's speed scale")
    p.add_argument("--settle-dwell-s", type=float, default=None,
                   help="extra wait after the robot reports still (default 0.3 s real, 0 s sim)")
    p.add_argument("--incremental", action="store_true", help="show the live 1-sigma per camera (iSAM2)")
    p.add_argument("--quiet", action="store_true")
    a = p.add_argument_group("autonomous calibration (--auto)")
    a.add_argument("--auto", action="store_true",
                   help="discover the cameras, choose each pose by expected information gain, stop at the tolerance")
    a.add_argument("--sim-world", type=Path, default=None,
                   help="with --robot sim: the simulated workcell to render (true placements; the planner never reads them)")
    a.add_argument("--tolerance-mm", type=float, default=0.5, help="1-sigma translation norm to reach (default 0.5 mm)")
    a.add_argument("--tolerance-deg", type=float, default=0.03, help="1-sigma rotation norm to reach (default 0.03 deg)")
    a.add_argument("--max-poses", type=int, default=60, help="capture poses allowed, survey included (default 60)")
    a.add_argument("--seed", type=int, default=0, help="seed of the pose sampling")
    v = p.add_argument_group("verify capture (--verify)")
    v.add_argument("--verify", action="store_true",
                   help="plan a few poses from --result, capture them and test whether any camera moved")
    v.add_argument("--result", type=Path, default=None, help="with --verify: the stored calibration (result.json)")
    v.add_argument("--verify-poses", type=int, default=5, help="poses of a verify capture (default 5)")
    v.add_argument("--alpha", type=float, default=None, help="with --verify: false-alarm probability per camera (default 0.001)")
    return p


def _read_yaml(path: Path, what: str):
    from calibgraph.io.files import read_yaml

    return read_yaml(path, what)


def workcell_hardware(d: dict, where: str):
    """Split a workcell mapping into (robot section, camera sections, safety limits, target, mode)."""
    from calibgraph.acquire.safety import SafetyLimits, default_cell_limits
    from calibgraph.core.errors import InputError
    from calibgraph.plan.cell import boxes_from_list

    robot = dict(d.get("robot") or {})
    unknown = set(robot) - _ROBOT_KEYS - _SIM_ROBOT_KEYS
    if unknown:
        raise InputError(f"{where}: robot: unknown keys {sorted(unknown)}; allowed: {sorted(_ROBOT_KEYS | _SIM_ROBOT_KEYS)}.")
    cams = d.get("cameras") or {}
    if not isinstance(cams, dict):
        raise InputError(f"{where}: cameras must be a mapping name -> settings.")
    for name, c in cams.items():
        drv = (c or {}).get("driver", "sim")
        if drv not in CAMERA_DRIVERS:
            raise InputError(f"{where}: camera {name!r}: unknown driver {drv!r}; choose one of {CAMERA_DRIVERS}.")
    try:
        floor = d.get("floor_z_m")
        floor = None if floor is None else float(floor)
        obstacles = (boxes_from_list(d.get("obstacles"), where, False) + boxes_from_list(d.get("keep_out"), where, True))
        if d.get("safety") is None:  # no safety section: the default cell model, and callers warn
            safety = default_cell_limits(str(robot.get("model", "fr3")), floor_z_m=floor, obstacles=obstacles)
        else:
            safety = SafetyLimits.from_dict(d.get("safety"), floor_z_m=floor, obstacles=obstacles)
    except (TypeError, ValueError) as e:
        raise InputError(f"{where}: floor_z_m / obstacles / safety: {e}") from None
    except InputError as e:
        raise InputError(f"{where}: {e}") from None
    mode = d.get("mode", "eye_to_hand")
    from calibgraph.sim.workcell import board_by_name

    target = board_by_name(d.get("board", "a4_54"))
    return robot, cams, safety, target, mode


def sim_workcell_dict(d: dict) -> dict:
    """The part of a workcell mapping the simulator reads (hardware-only keys removed)."""
    s = {k: v for k, v in d.items() if k not in ("safety", "mode")}
    if "robot" in s:
        s["robot"] = {k: v for k, v in (s["robot"] or {}).items() if k in _SIM_ROBOT_KEYS}
    if "cameras" in s:
        s["cameras"] = {n: {k: v for k, v in (c or {}).items() if k != "driver"} for n, c in (s["cameras"] or {}).items()
                        if (c or {}).get("driver", "sim") == "sim"}
    return s


def open_camera(name: str, spec: dict, where: str):
    """A Camera for one workcell camera entry (real drivers only)."""
    from calibgraph.core.errors import InputError

    spec = dict(spec or {})
    drv = spec.pop("driver", "sim")
    try:
        if drv == "realsense":
            from drivers.realsense import RealSenseCamera

            return RealSenseCamera(name, **spec)
        if drv == "ros2":
            from drivers.ros2 import Ros2Camera

            return Ros2Camera(name, **spec)
        if drv == "kinect":
            from drivers.kinect import KinectV2Camera

            return KinectV2Camera(name, **spec)
    except TypeError as e:
        raise InputError(f"{where}: camera {name!r} ({drv}): {e}") from None
    raise InputError(f"{where}: camera {name!r}: driver {drv!r} is not a hardware driver.")


def run(args) -> int:
    from calibgraph.acquire.run import run_acquisition
    from calibgraph.core.errors import InputError
    from calibgraph.plan.trajectory import Trajectory, load_trajectory

    log = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    if args.auto and args.verify:
        raise InputError("capture: --auto and --verify are different runs; choose one.")
    if args.verify:
        return run_verify_capture_cli(args, log)
    if args.result is not None:
        raise InputError("capture: --result is for --verify runs.")
    if args.auto:
        return run_auto_capture(args, log)
    if args.sim_world is not None:
        raise InputError("capture: --sim-world is for --auto runs; a trajectory replay simulates the --workcell itself.")
    if args.workcell is None:
        raise InputError("capture: give --workcell (the cell: robot, cameras, safety).")
    d = _read_yaml(args.workcell, "workcell")
    robot_cfg, cam_cfg, safety, target, mode = workcell_hardware(d, str(args.workcell))
    if safety.default_model:
        print(f"warning: {args.workcell} declares no safety: section; every pose is checked against a default cell "
              f"model: Franka {robot_cfg.get('model', 'fr3')} joint limits and kinematics, {safety.describe()}. "
              "Declare the cell's safety: section (workspace box, boxes) for a real cell.", file=sys.stderr)
    driver = args.robot or robot_cfg.get("driver", "sim")
    if driver not in ROBOT_DRIVERS:
        raise InputError(f"{args.workcell}: robot driver {driver!r} unknown; choose one of {ROBOT_DRIVERS}.")
    traj_path = args.trajectory
    if traj_path is None:
        if args.resume and (args.out / "trajectory.yaml").is_file():
            traj_path = args.out / "trajectory.yaml"
        else:
            raise InputError("capture: give --trajectory (or --resume a dataset that holds its trajectory.yaml).")
    traj = load_trajectory(traj_path)
    if args.speed_scale is not None:
        traj = Trajectory(poses=traj.poses, speed_scale=args.speed_scale)
    real = driver != "sim"
    if real and not args.dry_run and not args.cleared:
        raise InputError("capture: a real robot is configured; it will not move without --i-have-cleared-the-cell. "
                         "Run with --dry-run first to check every pose against the safety limits.")
    dwell = args.settle_dwell_s if args.settle_dwell_s is not None else (0.3 if real else 0.0)

    robot, cameras, closers, detector, world = None, {}, [], None, None
    try:
        if driver == "sim":
            from calibgraph.sim.devices import make_devices
            from calibgraph.sim.render import SimWorld
            from calibgraph.sim.rendered_dataset import VisibilityGatedDetector
            from calibgraph.sim.workcell import workcell_from_dict

            cell = workcell_from_dict(sim_workcell_dict(d), str(args.workcell))
            target = cell.target
            world = SimWorld(cell)
            import numpy as np

            robot, sim_cams = make_devices(world, cell.fk_sigma_translation_m, np.radians(cell.fk_sigma_rotation_deg),
                                           cell.seed)
            cameras.update(sim_cams)
            detector = VisibilityGatedDetector(world, None)
        else:
            robot = _connect_franka(args, robot_cfg, log, "planning from the first pose instead of the robot's joints")
        if robot is not None:
            closers.append(robot)
        if not args.dry_run:
            hw = {n: spec for n, spec in cam_cfg.items() if (spec or {}).get("driver", "sim") != "sim"}
            _open_cameras(hw, str(args.workcell), cameras, closers, log)
        on_capture = None
        if args.incremental and not args.dry_run:
            from calibgraph.solver.incremental import IncrementalSolver

            inc = IncrementalSolver(target.points_board_m, {n: c.intrinsics() for n, c in cameras.items()}, mode=mode)
            on_capture = inc.add_capture
        try:
            rep = run_acquisition(robot, cameras, traj, args.out, target, detector=detector, resume=args.resume,
                                  safety=safety, on_capture=on_capture, progress=log, dry_run=args.dry_run, mode=mode,
                                  settle_dwell_s=dwell)
        except KeyboardInterrupt:
            print(f"calibgraph capture: interrupted; everything captured so far is in {args.out}. "
                  f"Continue with: calibgraph capture --workcell {args.workcell} --out {args.out} --resume",
                  file=sys.stderr)
            return 130
        finally:
            if not args.dry_run:
                _write_sim_truth(world, args.out)  # the true intrinsics and poses beside a simulated capture
        print(rep.summary())
        if rep.stopped_reason:
            return 3
        if not args.dry_run:
            print(f"next: calibgraph solve {args.out}")
        return 0
    finally:
        _close_all(closers)


def run_auto_capture(args, log) -> int:
    """``capture --auto``: the autonomous loop on the simulated or the real cell."""

    from calibgraph.acquire.auto import AutoOptions, dry_run_survey, run_auto
    from calibgraph.core.errors import InputError
    from calibgraph.plan.cell import cell_from_dict, cell_from_world_dict

    if args.trajectory is not None:
        raise InputError("capture --auto plans its own poses; drop --trajectory.")
    opts = AutoOptions(tolerance_mm=args.tolerance_mm, tolerance_deg=args.tolerance_deg, max_poses=args.max_poses,
                       speed_scale=args.speed_scale if args.speed_scale is not None else 0.2, seed=args.seed,
                       settle_dwell_s=args.settle_dwell_s or 0.0)
    cell_d = _read_yaml(args.workcell, "cell") if args.workcell else None
    world_d = _read_yaml(args.sim_world, "simulated world") if args.sim_world else None
    driver = args.robot or ((cell_d or {}).get("robot") or {}).get("driver", "sim")
    if driver not in ROBOT_DRIVERS:
        raise InputError(f"{args.workcell}: robot driver {driver!r} unknown; choose one of {ROBOT_DRIVERS}.")
    if driver == "sim" and world_d is None:
        raise InputError("capture --auto --robot sim needs --sim-world WORLD.yaml (the cell the simulator renders).")
    if driver != "sim" and cell_d is None:
        raise InputError("capture --auto on a real robot needs --workcell CELL.yaml (cameras, obstacles, safety).")
    cell = cell_from_dict(cell_d, str(args.workcell)) if cell_d is not None else cell_from_world_dict(world_d, str(args.sim_world))
    safety = _cell_safety(args, cell_d)
    from calibgraph.sim.planning_world import planning_world

    pworld = planning_world(cell)
    robot, cameras, closers, detector, sim = None, {}, [], None, None
    try:
        if driver == "sim":
            sim, robot, cameras, detector = _sim_devices(args, cell, world_d, check_target=True)
            sim.skip_hidden_renders = True
        else:
            robot = _franka(args, cell_d, log, "see the survey", "planning the survey")
        if robot is not None:
            closers.append(robot)
        if args.dry_run:
            q0 = robot.joint_positions() if robot is not None else None
            rep = dry_run_survey(cell, pworld, safety, opts, q0, log)
            print(rep.summary())
            return 0
        if driver != "sim":
            cameras = _open_cell_cameras(args, cell, cell_d, closers, log)
        try:
            rep = run_auto(robot, cameras, cell, pworld, args.out, detector=detector, safety=safety, options=opts,
                           resume=args.resume, progress=log)
        except KeyboardInterrupt:
            where = f"--sim-world {args.sim_world}" if sim is not None else f"--workcell {args.workcell}"
            print(f"calibgraph capture: interrupted; everything captured so far is in {args.out}. Continue with: "
                  f"calibgraph capture --auto {where} --out {args.out} --resume", file=sys.stderr)
            return 130
        finally:
            _write_sim_truth(sim, args.out)
        print(rep.summary())
        if rep.result is not None:
            print(f"wrote {args.out / 'result.json'} and {args.out / 'plan_log.json'}")
        return 0 if rep.converged else 3
    finally:
        _close_all(closers)


def _cell_safety(args, cell_d: dict | None):
    """The safety limits of the capture cell ``cell_d`` (``--workcell``); defaults without one."""
    from calibgraph.acquire.safety import SafetyLimits

    if cell_d is None:
        return SafetyLimits()
    return workcell_hardware({k: v for k, v in cell_d.items() if k != "cameras"}, str(args.workcell))[2]


def _write_sim_truth(sim, out: Path) -> None:
    """ground_truth.json beside a simulated capture that wrote anything."""
    if sim is not None and (out / "captures").is_dir():
        from calibgraph.sim.rendered_dataset import write_ground_truth

        write_ground_truth(out, sim.cell, sim)


def _close_all(closers: list) -> None:
    for c in closers:
        try:
            c.close()
        except Exception:  # closing is best effort; the data is already on disk
            pass


def _sim_devices(args, cell, world_d: dict, check_target: bool = False, check_rendering: bool = False):
    """The simulated world ``world_d`` (``--sim-world``) with its robot, the cell's cameras and a
    visibility-gated detector: (sim, robot, cameras, detector)."""
    import numpy as np

    from calibgraph.core.errors import InputError
    from calibgraph.sim.devices import make_devices
    from calibgraph.sim.render import SimWorld
    from calibgraph.sim.rendered_dataset import VisibilityGatedDetector
    from calibgraph.sim.workcell import workcell_from_dict

    wcell = workcell_from_dict(sim_workcell_dict(world_d), str(args.sim_world))
    missing = [c for c in cell.camera_names if c not in wcell.camera_names]
    if missing:
        raise InputError(f"{args.workcell}: cameras {missing} are not in the simulated world {args.sim_world} "
                         f"(it has {wcell.camera_names}).")
    if check_target and wcell.target != cell.target:
        raise InputError(f"{args.workcell}: board {cell.target.to_dict()} differs from the simulated world's "
                         f"{wcell.target.to_dict()}.")
    sim = SimWorld(wcell)
    if check_rendering:
        sim.check_rendering()
    robot, sim_cams = make_devices(sim, wcell.fk_sigma_translation_m, np.radians(wcell.fk_sigma_rotation_deg),
                                   wcell.seed)
    return sim, robot, {c: sim_cams[c] for c in cell.camera_names}, VisibilityGatedDetector(sim, None)


def _franka(args, cell_d: dict | None, log, dry_run_shows: str, plans: str):
    """The Franka arm of the cell; refused without the cleared-cell flag unless dry-running (see
    :func:`_connect_franka`)."""
    from calibgraph.core.errors import InputError

    if not args.dry_run and not args.cleared:
        raise InputError("capture: a real robot is configured; it will not move without "
                         f"--i-have-cleared-the-cell. Run with --dry-run first to {dry_run_shows}.")
    return _connect_franka(args, (cell_d or {}).get("robot") or {}, log, f"{plans} from the home posture")


def _connect_franka(args, robot_cfg: dict, log, dry_run_instead: str):
    """The Franka arm at ``robot.ip`` (or ``--robot-ip``); a dry run goes on without a connection
    (None), saying what it does ``dry_run_instead``."""
    from calibgraph.core.errors import InputError
    from drivers.franka import FrankaRobot

    ip = args.robot_ip or robot_cfg.get("ip")
    if not ip:
        raise InputError(f"{args.workcell}: robot.ip (or --robot-ip) is needed for the franka driver.")
    try:
        return FrankaRobot(ip, model=robot_cfg.get("model", "fr3"), realtime=bool(robot_cfg.get("realtime", True)),
                           settle_velocity_rad_s=float(robot_cfg.get("settle_velocity_rad_s", 0.005)))
    except Exception as e:
        if not args.dry_run:
            raise
        log(f"robot at {ip}: not connected ({e}); {dry_run_instead}")
        return None


def _open_cell_cameras(args, cell, cell_d: dict, closers: list, log) -> dict:
    """The cell's hardware cameras, opened (see :func:`_open_cameras`)."""
    specs = {}
    for name in cell.camera_names:
        spec = (cell_d.get("cameras") or {}).get(name) or {}
        specs[name] = {k: v for k, v in spec.items() if k not in ("hint", "preset", "intrinsics")}
    cameras = {}
    _open_cameras(specs, str(args.workcell), cameras, closers, log)
    return cameras


def _open_cameras(specs: dict, where: str, cameras: dict, closers: list, log) -> None:
    """Open every camera of ``specs`` (name -> driver spec) into ``cameras``; one that cannot open
    is reported and left out (it is then 'not seen'); no camera at all is an error."""
    from calibgraph.core.errors import InputError

    for name, spec in specs.items():
        try:
            cam = open_camera(name, spec, where)
        except InputError:
            raise
        except Exception as e:  # a camera that cannot open is reported; the others go on
            log(f"camera {name}: cannot open ({type(e).__name__}: {e}); continuing without it")
            continue
        cameras[name] = cam
        closers.append(cam)
    if not cameras:
        raise InputError(f"{where}: no camera could be opened.")


def _has_placements(d: dict) -> bool:
    from calibgraph.plan.cell import _PLACEMENT_KEYS

    return bool(d.get("ring")) or any(_PLACEMENT_KEYS & set(c or {}) for c in (d.get("cameras") or {}).values())


def run_verify_capture_cli(args, log) -> int:
    """``capture --verify``: plan from the stored result, capture (sim or real), verify."""
    from calibgraph.acquire.verify import run_verify_capture
    from calibgraph.cli.verify import EXIT_MOVED, format_verdict
    from calibgraph.core.errors import InputError
    from calibgraph.plan.cell import cell_from_dict, cell_from_world_dict
    from calibgraph.solver.result import load_result_dict
    from calibgraph.solver.verify import DEFAULT_ALPHA, stored_model

    if args.result is None:
        raise InputError("capture --verify needs --result RESULT.json (the stored calibration to test against).")
    if args.trajectory is not None:
        raise InputError("capture --verify plans its own poses from --result; drop --trajectory.")
    if args.verify_poses < 1:
        raise InputError(f"capture --verify: --verify-poses must be >= 1, got {args.verify_poses}.")
    stored = load_result_dict(args.result)
    model = stored_model(stored, str(args.result))
    cell_d = _read_yaml(args.workcell, "workcell") if args.workcell else None
    world_d = _read_yaml(args.sim_world, "simulated world") if args.sim_world else None
    driver = args.robot or ((cell_d or {}).get("robot") or {}).get("driver", "sim")
    if driver not in ROBOT_DRIVERS:
        raise InputError(f"{args.workcell}: robot driver {driver!r} unknown; choose one of {ROBOT_DRIVERS}.")
    if cell_d is None and world_d is None:
        raise InputError("capture --verify needs --workcell CELL.yaml (or, with --robot sim, --sim-world WORLD.yaml).")
    if driver == "sim" and world_d is None:
        if not _has_placements(cell_d):
            raise InputError(f"capture --verify --robot sim: {args.workcell} has no camera placements to simulate; "
                             "give the simulated cell as --sim-world WORLD.yaml.")
        world_d, args.sim_world = cell_d, args.workcell
    src_d, src = (cell_d, args.workcell) if cell_d is not None else (world_d, args.sim_world)
    cell = cell_from_world_dict(src_d, str(src)) if _has_placements(src_d) else cell_from_dict(src_d, str(src))
    missing = [n for n in cell.camera_names if n not in model.T_base_cam]
    if len(missing) == len(cell.camera_names):
        raise InputError(f"{args.result}: none of the cell's cameras ({', '.join(cell.camera_names)}) is in the stored "
                         f"result ({', '.join(model.T_base_cam)}).")
    if missing:
        log(f"cameras not in the stored result, not verified: {', '.join(missing)}")
    safety = _cell_safety(args, cell_d)
    from calibgraph.sim.planning_world import planning_world

    pworld = planning_world(cell)
    robot, cameras, closers, detector, sim = None, {}, [], None, None
    try:
        if driver == "sim":
            sim, robot, cameras, detector = _sim_devices(args, cell, world_d, check_rendering=not args.dry_run)
        else:
            robot = _franka(args, cell_d, log, "check the verify poses", "planning")
            if not args.dry_run:
                cameras = _open_cell_cameras(args, cell, cell_d, closers, log)
        if robot is not None:
            closers.append(robot)
        real = driver != "sim"
        dwell = args.settle_dwell_s if args.settle_dwell_s is not None else (0.3 if real else 0.0)
        try:
            rep = run_verify_capture(robot, cameras, stored, cell, pworld, args.out, detector=detector, safety=safety,
                                     n_poses=args.verify_poses, alpha=DEFAULT_ALPHA if args.alpha is None else args.alpha,
                                     resume=args.resume, dry_run=args.dry_run, seed=args.seed, settle_dwell_s=dwell,
                                     progress=log, where=str(args.result))
        except KeyboardInterrupt:
            print(f"calibgraph capture: interrupted; everything captured so far is in {args.out}. Continue with: "
                  f"calibgraph capture --verify --result {args.result} ... --out {args.out} --resume", file=sys.stderr)
            return 130
        finally:
            _write_sim_truth(sim, args.out)
        print(rep.acquisition.summary())
        if args.dry_run:
            return 0
        if rep.verify is None:
            raise InputError(f"the verify capture stopped ({rep.acquisition.stopped_reason}); no verdict. "
                             f"Continue with --resume, or run: calibgraph verify --result {args.result} {args.out}")
        table = format_verdict(rep.verify)
        print(table if not args.quiet else table.splitlines()[-1])
        print(f"wrote {rep.verdict_path}")
        return EXIT_MOVED if rep.verify.anything_moved else 0
    finally:
        _close_all(closers)
