"""``calibgraph demo``: a whole calibration of a simulated workcell in one command.

Builds a MuJoCo cell (FR3 arm, A4 board on the flange, cameras around the robot), plans a
trajectory, runs the acquisition state machine on the simulated robot and cameras (images are
rendered, corners detected on the spot), solves the factor graph, prints every camera's pose with
its 1-sigma, reprojection RMS and true error, and writes the dataset, ``result.json``, the HTML
report and a rerun recording into ``--out``.
"""

from __future__ import annotations

import re
import sys
import time
from pathlib import Path


def add_parser(sub):
    p = sub.add_parser("demo", help="calibrate a simulated workcell end to end (needs the 'sim' extra)",
                       description="Simulate a workcell, capture, detect, solve and report in one go.")
    p.add_argument("--out", type=Path, default=Path("calibgraph-demo"), help="output folder (default ./calibgraph-demo)")
    p.add_argument("--cameras", type=int, default=3, help="number of cameras (default 3)")
    p.add_argument("--distance-m", type=float, default=3.0, help="camera distance from the robot base axis (default 3 m)")
    p.add_argument("--preset", default="l515", help="camera preset: l515, d455, kinect_v2 (default l515)")
    p.add_argument("--board", default="a4_7x10_25mm",
                   help="the board on the flange: a shipped board's name (calibgraph target list; default a4_7x10_25mm, "
                        "7 x 10 squares of 25 mm, alias a4_54; thesis_5x4_46mm, alias thesis) or a target spec file")
    p.add_argument("--poses", type=int, default=30, help="robot poses (default 30)")
    p.add_argument("--workcell", type=Path, default=None, help="workcell YAML instead of the options above")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the simulation (image noise, the robot's kinematic error) and of the planner's pose "
                        "sampling (default 0); another seed is another draw of the same cell: its true errors change by "
                        "about their 1-sigma")
    p.add_argument("--plan", choices=("information", "random"), default="information",
                   help="how the planner picks the poses: 'information' (default) chooses them from a sampled pool by "
                        "what they pin (far cameras' focal length against depth, the mount, the board scale); 'random' "
                        "takes the first visible ones, as before")
    p.add_argument("--reported-intrinsics", choices=("factory", "exact"), default=None,
                   help="what the simulated cameras report: factory-class intrinsics (default) or exact, the true "
                        "ones (an oracle's figures, labelled so)")
    p.add_argument("--rrd", dest="rrd", action="store_true", default=True, help="write a rerun recording (default)")
    p.add_argument("--no-rrd", dest="rrd", action="store_false", help="skip the rerun recording")
    p.add_argument("--no-report", dest="report", action="store_false", default=True, help="skip the HTML report")
    p.add_argument("--auto", action="store_true",
                   help="autonomous run: camera placements unknown to the planner; discover, refine by information "
                        "gain, stop at the tolerance (see calibgraph capture --auto)")
    p.add_argument("--max-poses", type=int, default=60, help="with --auto: capture poses allowed (default 60)")
    return p


def _bar(total, desc):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="pose", file=sys.stderr, leave=True, dynamic_ncols=True)


def _check_outputs(args, out: Path, ds_dir: Path) -> None:
    """The output guard on every file and folder the demo writes, before anything is simulated."""
    from calibgraph.io.output_guard import check_output_file, check_output_folder

    check_output_folder(out, "output folder")
    check_output_folder(ds_dir, "dataset folder")
    files = [("trajectory.yaml", "trajectory", "trajectory file")] if not args.auto else []
    files += [("result.json", "result", "result file")]  # demo --auto writes its result and report in --out too
    files += [("report.html", "report", "report file")] if args.report else []
    files += [("calibration.rrd", "recording", "rerun recording")] if args.rrd else []
    for name, kind, what in files:
        check_output_file(out / name, kind, what, name)


def run(args) -> int:
    import numpy as np

    from calibgraph.core.errors import InputError
    from calibgraph.io.files import output_folder
    from calibgraph.plan.planner import plan_trajectory
    from calibgraph.sim.render import SimWorld
    from calibgraph.sim.rendered_dataset import simulate_dataset
    from calibgraph.sim.workcell import load_workcell, ring_workcell

    t_start = time.monotonic()
    out = Path(args.out)
    ds_dir = out / "dataset"
    if args.poses < 6:
        raise InputError(f"--poses {args.poses}: the demo needs at least 6 poses (3 views per camera at the very least).")
    if (ds_dir / "dataset.yaml").exists():
        raise InputError(f"{out}: holds a previous demo; choose another --out or delete it.")
    _check_outputs(args, out, ds_dir)  # a dataset, a user's file, a read-only folder: said now, not after simulating
    if args.workcell:
        cell = load_workcell(args.workcell)
    else:
        if args.cameras > 8:
            raise InputError("--cameras: at most 8 in the demo.")
        cell = ring_workcell(n_cameras=args.cameras, distance_m=args.distance_m, preset_name=args.preset,
                             board=args.board, spread_deg=200.0 if args.cameras <= 3 else 360.0, name="demo",
                             seed=args.seed)
    if args.reported_intrinsics:
        cell = cell.with_reported_intrinsics(args.reported_intrinsics)
    print(f"workcell: {len(cell.cameras)} x {', '.join(sorted({c.preset for c in cell.cameras}))} cameras, "
          f"board {cell.target.rows}x{cell.target.cols} points of {cell.target.pitch_m * 1e3:g} mm, "
          f"camera distances {', '.join(f'{np.hypot(*c.T_base_cam[:2, 3]):.1f}' for c in cell.cameras)} m; cameras report "
          + ("their true intrinsics (oracle)" if cell.oracle_intrinsics else "factory-class intrinsics"))
    if args.auto:
        return _run_auto(args, cell, out, ds_dir, t_start)
    world = SimWorld(cell)
    world.check_rendering()  # no OpenGL: one clear error now, not after planning

    bar = _bar(args.poses, "plan")
    traj = plan_trajectory(world, args.poses, seed=args.seed, select=args.plan, progress=lambda k, n: bar.update(k - bar.n))
    bar.close()
    output_folder(out, "output folder")
    traj.save(out / "trajectory.yaml")

    bar = _bar(len(traj), "capture")
    notes = []

    def progress(line: str):
        m = re.match(r"pose (\d+)/(\d+):", line)
        if m:
            bar.update(int(m.group(1)) - bar.n)
        elif line.startswith(("pose", "camera", "stopped")):
            notes.append(line)

    rep = simulate_dataset(cell, traj, ds_dir, world=world, progress=progress)
    bar.close()
    for n in notes:
        print(n, file=sys.stderr)
    print(f"capture: {rep.captured} poses, views per camera {dict(sorted(rep.accepted_per_camera.items()))}")

    from dataclasses import replace

    from calibgraph.io.layouts import load_dataset
    from calibgraph.solver.solve.batch import solve
    from calibgraph.solver.solve.build import build_problem

    ds = load_dataset(ds_dir)
    problem, _ = build_problem(ds, "joint", None, progress=True)
    t0 = time.monotonic()
    result = replace(solve(problem), dataset=str(ds_dir), target=ds.target.to_dict())
    _, verdict = _write_and_print(args, result, out, ds_dir, problem, f"solve: {time.monotonic() - t0:.1f} s; ")
    print(f"demo finished in {time.monotonic() - t_start:.0f} s; dataset with ground truth in {ds_dir}")
    if not result.converged:
        print("demo: the solver did NOT converge (see above); exit 3", file=sys.stderr)
    print(verdict)
    return 0 if result.converged else 3


def demo_verdict(result, truth: dict, dataset=None) -> str:
    """The demo's last line: PASS when the solve converged and every camera is calibrated, passes the
    report's tolerances (``datasets/tolerances/default.yaml``) and has its true error within its
    covariance (``calibgraph check``'s chi-square test); FAIL naming what failed; with the worst
    error / 1σ either way."""
    from calibgraph.report.html import report_verdicts
    from calibgraph.report.truth import ALPHA, check_against_truth

    rows = check_against_truth(result, truth)
    verdicts = report_verdicts(result, dataset=dataset)
    bad = [] if result.converged else ["the solver did not converge"]
    bad += [f"{r.name} not calibrated" for r in rows if r.status == "not calibrated"]
    bad += [f"{n} fails the report's tolerances ({', '.join(v['reasons'])})" for n, v in verdicts.items()
            if not v["pass"] and result.cameras[n].calibrated]
    bad += [f"{r.name}'s true error is outside its covariance (Mahalanobis² {r.mahalanobis2:.1f}, p {r.p_value:.2g})"
            for r in rows if r.status == "outside"]
    solved = [r for r in rows if r.status in ("inside", "outside")]
    worst = max(solved, key=lambda r: r.error_over_sigma, default=None)
    w = "" if worst is None else (f"worst error/1σ {worst.error_over_sigma:.2f} ({worst.name}: {worst.error_mm:.3f} mm "
                                  f"against a 1σ norm of {worst.sigma_norm_mm:.3f} mm)")
    if not bad:
        return (f"verdict: PASS: {len(solved)} of {len(rows)} cameras calibrated, within the report's tolerances, "
                f"each true error within its covariance (chi-square p >= {ALPHA:g}); {w}")
    return "verdict: FAIL: " + "; ".join(bad) + (f"; {w}" if w else "")


def _write_and_print(args, result, out: Path, ds_dir: Path, source, solve_line: str = "") -> tuple:
    """What both demos end with: ``result.json`` in ``out``, every camera's pose, 1σ and true error
    against the simulator's ground truth, then ``report.html`` and ``calibration.rrd`` in ``out``
    (``source``: the problem or dataset folder the recording draws the views from). Returns the
    result's path and the verdict line (:func:`demo_verdict`) the demo ends with."""
    import numpy as np

    from calibgraph.cli.solve import format_summary
    from calibgraph.core.transforms import log_so3, pose_error
    from calibgraph.io.ground_truth import load_ground_truth
    from calibgraph.io.layouts import load_dataset

    result_path = out / "result.json"
    from calibgraph.io.output_guard import write_keeping_previous

    kept = write_keeping_previous(result_path, lambda: result.save(result_path))  # one left by an interrupted demo
    if kept is not None:
        print(f"kept the previous result as {kept}")
    gt = load_ground_truth(ds_dir)
    print(format_summary(result, truth=gt["T_base_cam"]))
    print("(err mm, err deg: the true error against the simulator's ground truth; err/1σ: the norm of the translation "
          "error over the norm of its per-axis 1σ, around 1 when the 1σ is honest; calibgraph check gives the chi-square "
          "test)")
    print("camera orientations (T_base_cam rotation vector, deg):")
    for n, c in result.calibrated.items():
        print(f"  {n:10s} {np.round(np.degrees(log_so3(c.T_ref_cam[:3, :3])), 3).tolist()}")
    if result.T_mount_board is not None:
        e_m, e_deg = pose_error(result.T_mount_board, gt["T_flange_board"])
        print(f"T_flange_board error vs ground truth: {e_m * 1e3:.3f} mm, {e_deg:.4f} deg")
    print(f"{solve_line}wrote {result_path}")
    if args.report:
        try:
            from calibgraph.report.html import write_report
        except ImportError as e:
            print(f"report skipped: {e}", file=sys.stderr)
        else:
            p = out / "report.html"
            kept = write_keeping_previous(p, lambda: write_report(result, p, dataset=load_dataset(ds_dir),
                                                                  result_path=result_path))
            if kept is not None:
                print(f"kept the previous report as {kept} (edited since calibgraph wrote it, or too old to tell)")
            print(f"wrote {p}")
    if args.rrd:
        try:
            from calibgraph.report.rerun_view import write_rrd
        except ImportError as e:
            print(f"rerun recording skipped: {e}", file=sys.stderr)
        else:
            try:
                p = write_rrd(result, source, out / "calibration.rrd")
                print(f"wrote {p} (open with: rerun {p})")
            except Exception as e:  # the recording is a convenience; the calibration is already saved
                print(f"rerun recording skipped: {type(e).__name__}: {e}", file=sys.stderr)
    return result_path, demo_verdict(result, gt, load_dataset(ds_dir))


def _run_auto(args, cell, out, ds_dir, t_start) -> int:
    """``demo --auto``: the autonomous loop on the demo cell, placements hidden from the planner."""
    import numpy as np

    from calibgraph.acquire.auto import AutoOptions, run_auto
    from calibgraph.cli.capture import commissioning_check
    from calibgraph.plan.cell import cell_from_world_dict
    from calibgraph.sim.devices import make_devices
    from calibgraph.sim.planning_world import planning_world
    from calibgraph.sim.render import SimWorld
    from calibgraph.sim.rendered_dataset import VisibilityGatedDetector, write_ground_truth
    from calibgraph.sim.workcell import workcell_to_dict

    plan_cell = cell_from_world_dict(workcell_to_dict(cell), "demo cell")
    world = SimWorld(cell)
    robot, cams = make_devices(world, cell.fk_sigma_translation_m, np.radians(cell.fk_sigma_rotation_deg), cell.seed)
    world.skip_hidden_renders = True
    rep = run_auto(robot, cams, plan_cell, planning_world(plan_cell), ds_dir, detector=VisibilityGatedDetector(world),
                   options=AutoOptions(max_poses=args.max_poses, seed=args.seed),
                   progress=lambda line: print(line, file=sys.stderr, flush=True), accept=commissioning_check())
    write_ground_truth(ds_dir, cell, world)
    verdict = "verdict: FAIL: no result (see above)"
    if rep.result is not None:
        _, verdict = _write_and_print(args, rep.result, out, ds_dir, ds_dir)
        print(f"captures {rep.captures} (survey included), robot motion {rep.robot_time_s:.0f} s; "
              f"plan log in {ds_dir / 'plan_log.json'}")
    print(rep.summary())
    print(f"demo finished in {time.monotonic() - t_start:.0f} s; dataset with ground truth in {ds_dir}")
    if not rep.converged:
        print("demo --auto did NOT finish within tolerance (see above); exit 3", file=sys.stderr)
    print(verdict)
    return 0 if rep.converged else 3
