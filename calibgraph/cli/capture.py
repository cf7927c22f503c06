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
2 bad input or no verdict).

With ``--robot sim`` the simulator renders ``--sim-world`` (true placements), or the workcell itself
when it places its cameras; the planner reads only the cell (:mod:`calibgraph.plan.cell`: cameras
without placements, optional hints, obstacles, keep-out boxes): CELL.yaml, or the world with every
placement stripped. A simulated ``--auto`` or ``--verify`` run writes ``ground_truth.json`` too.

``--view`` (a trajectory or ``--auto`` run) streams a live rerun view: each camera's frame with
the board found or not, the robot and the next planned pose, each camera's 1-sigma against the
tolerance (:class:`calibgraph.report.live_view.CaptureView`, an observer of the acquisition loop);
a viewer where there is a display, else ``DIR.rrd`` beside ``--out`` (or ``--rrd FILE``).

A real robot (``driver: franka``) never moves without ``--i-have-cleared-the-cell``; ``--dry-run``
connects to nothing that moves and opens no camera. The workcell file (robot, cameras, safety) is
described in :mod:`calibgraph.acquire.workcell`, its drivers in :mod:`calibgraph.acquire.devices`.
Every run owns its dataset (:mod:`calibgraph.acquire.claim`): ``--resume`` continues only a run of
the same kind with the same inputs, and one process at a time.
"""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

from calibgraph.acquire.devices import ROBOT_DRIVERS  # the registry's robot drivers (a light import)


def add_parser(sub):
    import argparse

    # the help in plain text: the module's examples without its reStructuredText markup
    examples = "\n".join(ln for ln in __doc__.splitlines() if ln.startswith("    calibgraph "))
    p = sub.add_parser("capture", help="drive the robot and record a dataset (real or simulated cell)",
                       description="Drive the robot through the acquisition loop (move, settle, grab, check, write) "
                                   "and record a dataset: a fixed trajectory (default), --auto (discover the cameras, "
                                   "choose each pose by information gain, stop at the tolerance) or --verify (has a "
                                   "camera moved since a stored calibration?). A real robot never moves without "
                                   "--i-have-cleared-the-cell; --dry-run plans and checks every pose, moves nothing.",
                       epilog="examples:\n" + examples, formatter_class=argparse.RawDescriptionHelpFormatter)
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
    p.add_argument("--intrinsics", action="append", default=[], metavar="NAME=CAM.yaml",
                   help="camera NAME's intrinsics from a camera file (calibgraph intrinsics), used instead of what "
                        "the device reports; its covariance becomes the prior (repeatable)")
    p.add_argument("--view", action="store_true",
                   help="stream a live rerun view (each camera's image with the board found or not, the flange, the "
                        "next planned pose, the cameras' estimated poses, each camera's 1-sigma against the "
                        "tolerance): a viewer where there is a display, else a .rrd beside --out (or --rrd)")
    p.add_argument("--rrd", type=Path, default=None, metavar="FILE",
                   help="write the live view into this rerun recording instead of opening a viewer")
    p.add_argument("--quiet", action="store_true", help="no progress lines (the summary, warnings and errors still print)")
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



def run(args) -> int:
    from calibgraph.core.errors import InputError
    from calibgraph.io.camera_file import read_camera_file_args

    args.camera_files = read_camera_file_args(args.intrinsics)  # read (or refused) before anything moves
    log = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    if args.auto and args.verify:
        raise InputError("capture: --auto and --verify are different runs; choose one.")
    args.view_rrd = _check_view(args)  # the recording's path is checked before anything moves
    if args.verify:
        return _verify(args, log)
    if args.result is not None:
        raise InputError("capture: --result is for --verify runs.")
    if args.auto:
        return _auto(args, log)
    if args.sim_world is not None:
        raise InputError("capture: --sim-world is for --auto runs; a trajectory replay simulates the --workcell itself.")
    if args.workcell is None:
        raise InputError("capture: give --workcell (the cell: robot, cameras, safety).")
    return _trajectory(args, log)


def _trajectory(args, log) -> int:
    """``capture --trajectory``: replay a trajectory on the workcell's robot (simulated or real)."""
    from calibgraph.acquire.claim import claim_dataset
    from calibgraph.acquire.run import run_acquisition
    from calibgraph.acquire.workcell import read_workcell
    from calibgraph.core.errors import InputError
    from calibgraph.plan.trajectory import Trajectory, load_trajectory

    wc = read_workcell(args.workcell)
    _warn_default_safety(args.workcell, wc)
    driver = wc.robot_driver(args.robot)
    traj_path = args.trajectory
    if traj_path is None:
        if args.resume and (args.out / "trajectory.yaml").is_file():
            traj_path = args.out / "trajectory.yaml"
        else:
            raise InputError("capture: give --trajectory (or --resume a dataset that holds its trajectory.yaml).")
    traj = load_trajectory(traj_path)
    if args.speed_scale is not None:
        traj = Trajectory(poses=traj.poses, speed_scale=args.speed_scale)
    inputs = {"workcell_sha256": wc.sha256, "trajectory_sha256": traj.sha256()}
    with _claim(args, "trajectory", inputs, log, claim_dataset, workcell=args.workcell):
        dev = _devices(args, driver, wc, wc, log, dry_run_shows="check every pose against the safety limits",
                       plans_without_robot="planning from the first pose instead of the robot's joints")
        with _run_on(dev, args):
            on_capture = None
            if (args.incremental or _viewing(args)) and not args.dry_run:
                from calibgraph.solver.solve.incremental import IncrementalSolver

                inc = IncrementalSolver(wc.target.points_board_m, {n: c.intrinsics() for n, c in dev.cameras.items()},
                                        mode=wc.mode)
                on_capture = inc.add_capture
            target = dev.simulation.target if dev.simulation is not None else wc.target
            with _live_view(args, eye_in_hand=wc.mode == "eye_in_hand") as watch:
                rep = _interruptible(args, "", lambda: run_acquisition(
                    dev.robot, dev.cameras, traj, args.out, target, detector=dev.detector, resume=args.resume,
                    safety=wc.safety, on_capture=on_capture, progress=log, dry_run=args.dry_run, mode=wc.mode,
                    settle_dwell_s=_dwell(args, driver), watch=watch))
    if rep is None:
        return 130
    print(rep.summary())
    if rep.stopped_reason:
        return 3
    if not args.dry_run:
        print(f"next: calibgraph solve {args.out}")
    return 0


def commissioning_check(config=None):
    """``accept`` of :func:`~calibgraph.acquire.auto.run_auto`: camera -> why a batch result fails the
    tolerances ``calibgraph report`` applies (``config``; default ``datasets/tolerances/default.yaml``),
    so that an autonomous run's "within tolerance" is the report's PASS."""
    from calibgraph.report.html import report_verdicts

    def accept(result) -> dict:
        return {n: v["reasons"] for n, v in report_verdicts(result, config).items() if not v["pass"]}
    return accept


def _auto(args, log) -> int:
    """``capture --auto``: the autonomous loop on the simulated or the real cell."""
    from calibgraph.acquire.auto import AutoOptions, dry_run_survey, run_auto
    from calibgraph.acquire.claim import claim_dataset
    from calibgraph.acquire.devices import Devices
    from calibgraph.core.errors import InputError
    from calibgraph.sim.planning_world import planning_world

    if args.trajectory is not None:
        raise InputError("capture --auto plans its own poses; drop --trajectory.")
    opts = AutoOptions(tolerance_mm=args.tolerance_mm, tolerance_deg=args.tolerance_deg, max_poses=args.max_poses,
                       speed_scale=args.speed_scale if args.speed_scale is not None else 0.2, seed=args.seed,
                       settle_dwell_s=args.settle_dwell_s or 0.0)
    wc, world, driver = _cell_and_world(args, "cell")
    if driver == "sim" and world is None and (wc is None or not args.dry_run):
        raise InputError("capture --auto --robot sim needs --sim-world WORLD.yaml (the cell the simulator renders).")
    if driver != "sim" and wc is None:
        raise InputError("capture --auto on a real robot needs --workcell CELL.yaml (cameras, obstacles, safety).")
    cell = (wc.planning_cell(strip_placements=driver == "sim") if wc is not None else world.planning_cell())
    safety = _safety(wc)
    _warn_default_safety(args.workcell, wc)  # as a trajectory run says it, dry run or not

    def devices(**kw):
        return _devices(args, driver, wc, world, log, names=cell.camera_names, dry_run_shows="see the survey",
                        plans_without_robot="planning the survey from the home posture", check_target=True, **kw)

    if args.dry_run:  # a simulated cell without a world to render plans from the home posture
        pworld = planning_world(cell)
        dev = devices() if driver != "sim" or world is not None else Devices()
        try:
            q0 = dev.robot.joint_positions() if dev.robot is not None else None
            rep = dry_run_survey(cell, pworld, safety, opts, q0, log)
        finally:
            dev.close()
        print(rep.summary())
        return 0
    with _claim(args, "auto", _input_hashes(wc, world), log, claim_dataset, workcell=args.workcell or args.sim_world):
        pworld = planning_world(cell)
        dev = devices(skip_hidden=True)
        with _run_on(dev, args), _live_view(args, T_flange_board=cell.T_flange_board) as watch:
            rep = _interruptible(args, "--auto", lambda: run_auto(
                dev.robot, dev.cameras, cell, pworld, args.out, detector=dev.detector, safety=safety, options=opts,
                resume=args.resume, progress=log, accept=commissioning_check(), watch=watch))
    if rep is None:
        return 130
    print(rep.summary())
    if rep.result is not None:
        print(f"wrote {args.out / 'result.json'} and {args.out / 'plan_log.json'}")
    return 0 if rep.converged else 3


def _verify(args, log) -> int:
    """``capture --verify``: plan from the stored result, capture (sim or real), verify."""
    import hashlib

    from calibgraph.acquire.claim import claim_dataset
    from calibgraph.acquire.verify import run_verify_capture
    from calibgraph.cli.verify import EXIT_MOVED, format_verdict
    from calibgraph.core.errors import InputError
    from calibgraph.io.files import read_input_bytes
    from calibgraph.sim.planning_world import planning_world
    from calibgraph.solver.output.result import load_result, result_path
    from calibgraph.solver.changes.verify import DEFAULT_ALPHA, stored_model

    if args.result is None:
        raise InputError("capture --verify needs --result RESULT.json (the stored calibration to test against).")
    if args.trajectory is not None:
        raise InputError("capture --verify plans its own poses from --result; drop --trajectory.")
    if args.verify_poses < 1:
        raise InputError(f"capture --verify: --verify-poses must be >= 1, got {args.verify_poses}.")
    args.result = result_path(args.result)  # the stored calibration's dataset folder: its result.json
    result_sha = hashlib.sha256(read_input_bytes(args.result, "result")).hexdigest()  # a pipe is refused, not read
    stored = load_result(args.result)
    model = stored_model(stored, str(args.result))
    wc, world, driver = _cell_and_world(args, "workcell")
    if wc is None and world is None:
        raise InputError("capture --verify needs --workcell CELL.yaml (or, with --robot sim, --sim-world WORLD.yaml).")
    if driver == "sim" and world is None:
        raise InputError(f"capture --verify --robot sim: {args.workcell} has no camera placements to simulate; "
                         "give the simulated cell as --sim-world WORLD.yaml.")
    cell = (wc or world).planning_cell()
    missing = [n for n in cell.camera_names if n not in model.T_base_cam]
    if len(missing) == len(cell.camera_names):
        raise InputError(f"{args.result}: none of the cell's cameras ({', '.join(cell.camera_names)}) is in the stored "
                         f"result ({', '.join(model.T_base_cam)}).")
    if missing:
        log(f"cameras not in the stored result, not verified: {', '.join(missing)}")
    safety = _safety(wc)
    inputs = {"result_sha256": result_sha, **_input_hashes(wc, world)}
    with _claim(args, "verify", inputs, log, claim_dataset):
        pworld = planning_world(cell)
        dev = _devices(args, driver, wc, world, log, names=cell.camera_names, dry_run_shows="check the verify poses",
                       plans_without_robot="planning from the home posture", render_check=not args.dry_run)
        with _run_on(dev, args):
            rep = _interruptible(args, f"--verify --result {args.result} ...", lambda: run_verify_capture(
                dev.robot, dev.cameras, stored, cell, pworld, args.out, detector=dev.detector, safety=safety,
                n_poses=args.verify_poses, alpha=DEFAULT_ALPHA if args.alpha is None else args.alpha,
                resume=args.resume, dry_run=args.dry_run, seed=args.seed, settle_dwell_s=_dwell(args, driver),
                progress=log, where=str(args.result)))
    if rep is None:
        return 130
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


# -- shared by the three runs -------------------------------------------------------------------------
def _viewing(args) -> bool:
    return bool(args.view or args.rrd is not None)


def _check_view(args):
    """The .rrd the live view writes (``--rrd``, else beside ``--out`` when there is no display), checked
    before anything runs; None for a viewer or no view."""
    from calibgraph.core.errors import InputError

    if not _viewing(args):
        return None
    if args.verify or args.dry_run:
        raise InputError("capture: --view / --rrd show an --auto or a trajectory capture as it runs; "
                         f"{'a dry run grabs nothing' if args.dry_run else '--verify has no live view'} (drop them).")
    from calibgraph.io.output_guard import check_output_file
    from calibgraph.report.live_view import has_display
    from calibgraph.report.rerun_view import import_rerun

    import_rerun()  # not installed: said now, before anything moves
    if args.rrd is None and has_display():
        return None
    inputs = [p for p in (args.workcell, args.trajectory, args.sim_world) if p is not None]
    return check_output_file(args.rrd or args.out.with_suffix(".rrd"), "recording", "recording file", "capture.rrd",
                             inputs=inputs)


@contextlib.contextmanager
def _live_view(args, T_flange_board=None, eye_in_hand: bool = False):
    """The live view of the run (:class:`calibgraph.report.live_view.CaptureView`) or None; closed
    (the recording moved into place) when the run ends, after Ctrl-C or a failure too."""
    if not _viewing(args):
        yield None
        return
    from calibgraph.report.live_view import CaptureView

    view = CaptureView((args.tolerance_mm, args.tolerance_deg), args.view_rrd, T_flange_board=T_flange_board,
                       eye_in_hand=eye_in_hand)
    try:
        yield view
    finally:
        written = view.close()
        if written is not None:
            print(f"wrote {written} (open with: rerun {written})")


def _cell_and_world(args, what: str):
    """(workcell spec or None, simulated world spec or None, robot driver) of an --auto or --verify
    run: the world is --sim-world, or the workcell itself when it places its cameras."""
    from calibgraph.acquire.workcell import read_workcell

    wc = read_workcell(args.workcell, what) if args.workcell else None
    world = read_workcell(args.sim_world, "simulated world", hardware=False) if args.sim_world else None
    driver = wc.robot_driver(args.robot) if wc is not None else (args.robot or "sim")
    if driver == "sim" and world is None and wc is not None and wc.has_placements:
        world = wc  # the workcell is the simulated world; the planner sees it without placements
    return wc, world, driver


def _warn_default_safety(path, wc) -> None:
    """The warning of a workcell that declares no safety: section (every run that checks poses
    against it: a trajectory, --auto, a dry run of either)."""
    if wc is not None and wc.safety.default_model:
        print(f"warning: {path} declares no safety: section; every pose is checked against a default cell "
              f"model: Franka {wc.robot.get('model', 'fr3')} joint limits and kinematics, {wc.safety.describe()}. "
              "Declare the cell's safety: section (workspace box, boxes) for a real cell.", file=sys.stderr)


def _safety(wc):
    """The safety limits of the capture cell (--workcell); none beyond the robot's own without one."""
    from calibgraph.acquire.safety import SafetyLimits

    return wc.safety if wc is not None else SafetyLimits()


def _input_hashes(wc, world) -> dict:
    return {"workcell_sha256": None if wc is None else wc.sha256, "world_sha256": None if world is None else world.sha256}


def _dwell(args, driver: str) -> float:
    return args.settle_dwell_s if args.settle_dwell_s is not None else (0.3 if driver != "sim" else 0.0)


@contextlib.contextmanager
def _run_on(dev, args):
    """The run on its devices ``dev``, closed when it ends. A simulated run's ground truth (the true
    poses and intrinsics) is written beside its captures then, after a crash or Ctrl-C too, but not
    after a refusal (an InputError, e.g. a resume whose cameras report other intrinsics): a refused
    run writes nothing."""
    from calibgraph.core.errors import InputError

    refused = False
    try:
        yield dev
    except InputError:
        refused = True
        raise
    finally:
        try:
            if not (args.dry_run or refused):
                dev.write_ground_truth(args.out)
        finally:
            dev.close()


def _claim(args, mode: str, inputs: dict, log, claim_dataset, workcell=None):
    """The dataset claim of a run (nothing to claim in a dry run, which writes nothing); ``workcell``:
    the file the cameras were read from, recorded for the advice to name."""
    if args.dry_run:
        return contextlib.nullcontext()
    from calibgraph.io.output_guard import check_output_folder

    check_output_folder(args.out, "dataset folder", claimed=True)  # never inside a dataset; --resume decides on one
    from calibgraph.acquire.claim import content_sha256

    files = getattr(args, "camera_files", None)  # a resume must use the same camera files (or none, as its run)
    inputs = {**inputs, "camera_files_sha256": content_sha256(
        {n: i.to_dict() for n, i in sorted(files.items())}) if files else None}
    return claim_dataset(args.out, mode, inputs, args.resume, log, files={"workcell_file": workcell})


def _devices(args, driver, wc, world, log, **kw):
    """The run's devices from the registry, the simulator rendering ``world`` (a workcell spec)."""
    from calibgraph.acquire.devices import open_devices

    return open_devices(driver, wc, world=None if world is None else (world.sim_world(), world.where),
                        simulate=_simulate, dry_run=args.dry_run, cleared=args.cleared, robot_ip=args.robot_ip,
                        log=log, camera_files=getattr(args, "camera_files", None), **kw)


def _simulate(world: dict, where: str, render_check: bool = False, skip_hidden: bool = False):
    """The simulated cell of a world mapping as devices (the registry's 'sim' driver)."""
    import numpy as np

    from calibgraph.acquire.devices import Simulation
    from calibgraph.sim.devices import make_devices
    from calibgraph.sim.render import SimWorld
    from calibgraph.sim.rendered_dataset import VisibilityGatedDetector, write_ground_truth
    from calibgraph.sim.workcell import workcell_from_dict

    cell = workcell_from_dict(world, where)
    sim = SimWorld(cell)
    if render_check:
        sim.check_rendering()
    sim.skip_hidden_renders = bool(skip_hidden)
    robot, cams = make_devices(sim, cell.fk_sigma_translation_m, np.radians(cell.fk_sigma_rotation_deg), cell.seed)
    return Simulation(robot, cams, VisibilityGatedDetector(sim, None), cell.target, list(cell.camera_names),
                      lambda out: write_ground_truth(out, cell, sim))


def _interruptible(args, how: str, call):
    """``call()``; on Ctrl-C the line saying how to continue, and None."""
    try:
        return call()
    except KeyboardInterrupt:
        where = " ".join(f"--{k.replace('_', '-')} {v}" for k, v in (("workcell", args.workcell),
                                                                      ("sim_world", args.sim_world)) if v)
        print(f"calibgraph capture: interrupted; everything captured so far is in {args.out}. Continue with: "
              f"calibgraph capture {how + ' ' if how else ''}{where} --out {args.out} --resume", file=sys.stderr)
        return None


def __getattr__(name):
    """``sim_workcell_dict`` moved to :mod:`calibgraph.acquire.workcell`; still importable from here."""
    if name == "sim_workcell_dict":
        from calibgraph.acquire.workcell import sim_workcell_dict

        return sim_workcell_dict
    raise AttributeError(name)
