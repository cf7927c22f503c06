"""``calibgraph solve DATASET --out result.json``: detect (if needed), solve, print, save."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from calibgraph.core.problem import mode_frames, option_flags
from calibgraph.solver.solve.build import build_problem
from calibgraph.solver.uncertainty.budget import share_lines
from calibgraph.solver.output.result import given_intrinsics_source


EXIT_NOT_CALIBRATED = 3  # the result is written, but a camera could not be calibrated from its views


def add_parser(sub):
    p = sub.add_parser("solve", help="calibrate all cameras of a dataset folder",
                       description="Solve a dataset (calibgraph, industrial_calibration, MC-HEC or ViSP layout).")
    p.add_argument("dataset", type=Path, help="dataset folder")
    add_target_flag(p)
    p.add_argument("--out", type=Path, default=None, help="result file (.json or .yaml); default DATASET/result.json")
    p.add_argument("--method", choices=("joint", "single"), default="joint",
                   help="joint: one shared board mount (default); single: each camera alone")
    add_solver_flags(p)
    p.add_argument("--intrinsics", action="append", default=[], metavar="NAME=CAM.yaml",
                   help="camera NAME's intrinsics from a camera file (calibgraph intrinsics): its values and "
                        "covariance become the camera's prior (repeatable)")
    p.add_argument("--rrd", type=Path, default=None, help="also write a rerun recording")
    p.add_argument("--strict", action="store_true",
                   help=f"also judge the result against the report's tolerances, print the verdict and exit "
                        f"{EXIT_NOT_CALIBRATED} on FAIL (the result is still written); default: exit 0 when every camera "
                        "is calibrated, whatever the tolerances")
    p.add_argument("--config", type=Path, default=None,
                   help="with --strict: the tolerances YAML (as report --config; default datasets/tolerances/default.yaml)")
    p.add_argument("--quiet", action="store_true", help="no progress, no table (warnings and errors still go to stderr)")
    return p


def add_target_flag(parser) -> None:
    """``--target SPEC.yaml``: the board of a dataset layout that names none (ViSP's)."""
    parser.add_argument("--target", type=Path, default=None, metavar="SPEC.yaml",
                        help="the board of a ViSP hand-eye folder (target: {kind, rows, cols, pitch_m}, rows/cols "
                             "counting inner corners); wins over its target.yaml and chessboard-data.txt; refused "
                             "for layouts that name their own board")


def add_solver_flags(parser) -> None:
    """Add a flag for every :class:`~calibgraph.core.problem.SolverOptions` field that declares one
    (its ``CliFlag``); :func:`solver_options` turns them back into options."""
    g = parser.add_argument_group("solver options", "dataset.yaml's solver section sets any option by its "
                                                    "SolverOptions name (SI units); these flags win over it")
    for flag in option_flags().values():
        help_text = flag.help.replace("%", "%%")
        if flag.type is None:
            g.add_argument(flag.name, action="store_true", help=help_text)
        else:
            g.add_argument(flag.name, type=flag.type, choices=flag.choices or None, default=None, help=help_text)


def _flag_value(args, flag):
    """The value given for ``flag`` in ``args``, or None when it was not given."""
    v = getattr(args, flag.name.lstrip("-").replace("-", "_"), None)
    return (True if v else None) if flag.type is None else v


def solver_options(args, dataset):
    """SolverOptions from dataset.yaml's solver section overridden by the command-line flags.

    A flag's value reaches the options or the command is refused: a non-positive sigma is not taken
    for "unset", and two settings that contradict each other are named."""
    from calibgraph.core.errors import InputError
    from calibgraph.core.problem import SolverOptions

    d = dict(dataset.solver)
    given = {}
    for name, flag in option_flags().items():
        v = _flag_value(args, flag)
        if v is None:
            continue
        if flag.positive and not (np.isfinite(v) and v > 0):
            raise InputError(f"{flag.name} {v:g}: must be a positive number; leave the flag out to use dataset.yaml's "
                             f"solver section or the default ({name}).")
        d[name] = given[name] = flag.option_value(v)
    try:
        opts = SolverOptions(**d)
    except TypeError as e:
        raise InputError(f"solver settings: {e}") from None
    flags = option_flags()
    for name, want in given.items():
        if getattr(opts, name) != want:
            others = [flags[n].name for n in given if n != name]
            what = " and ".join([flags[name].name, *others]) if others else f"{flags[name].name} and dataset.yaml's solver section"
            raise InputError(f"{what} contradict each other ({name} would be {getattr(opts, name)!r}, not {want!r}); give one.")
    return opts


ORACLE = "true intrinsics held: oracle"


def oracle_label(result) -> str:
    """'' or ' (true intrinsics held: oracle)' (naming the cameras when not all): a result whose
    cameras' intrinsics were a simulation's true ones ('exact') and held, not estimated, is an
    oracle's, and every figure shown from it must say so."""
    held = [n for n, c in result.cameras.items() if not (c.intrinsics or {}).get("estimated")
            and given_intrinsics_source(c, getattr(result, "settings", None)) == "exact"]
    if not held:
        return ""
    return f" ({ORACLE})" if len(held) == len(result.cameras) else f" ({', '.join(held)}: {ORACLE})"


def format_summary(result, truth=None) -> str:
    """A per-camera table: pose, 1-sigma, reprojection, views (and error vs truth when given, with
    error / 1σ: norms of the translation error and of its 1σ)."""
    import numpy as np

    from calibgraph.core.transforms import log_so3, pose_error

    frames = mode_frames(result.mode)
    ref = frames.camera_key
    lines = [f"mode {result.mode}, method {result.method}, pixel sigma {result.pixel_sigma_px:.3f} px, "
             f"solved in {result.solve_time_s:.2f} s{oracle_label(result)}"]
    w = max([10, *(len(n) for n in result.cameras)])  # a long camera name widens the column, not the row
    hdr = f"{'camera':{w}s} {'x [m]':>8s} {'y [m]':>8s} {'z [m]':>8s} {'1σ t [mm]':>16s} {'1σ r [deg]':>20s} {'rms px':>7s} {'views':>9s}"
    if truth is not None:
        hdr += f" {'err mm':>7s} {'err deg':>8s} {'err/1σ':>7s}"
    lines += [f"{ref} per camera:", hdr]
    for n, c in result.cameras.items():
        if not c.calibrated:
            lines.append(f"{n:{w}s} NOT CALIBRATED: {c.why}")
            continue
        t = c.T_ref_cam[:3, 3]
        st = "/".join(f"{v:.2f}" for v in c.sigma_translation_mm)
        sr = "/".join(f"{v:.3f}" for v in c.sigma_rotation_deg)
        row = (f"{n:{w}s} {t[0]:8.4f} {t[1]:8.4f} {t[2]:8.4f} {st:>16s} {sr:>20s} {c.reprojection_rms_px:7.3f} "
               f"{c.views_used:4d}/{c.views_used + len(c.views_rejected):<4d}")
        if truth is not None and n in truth:
            e_m, e_deg = pose_error(c.T_ref_cam, truth[n])
            row += f" {e_m * 1e3:7.3f} {e_deg:8.4f} {e_m * 1e3 / np.linalg.norm(c.sigma_translation_mm):7.2f}"
        lines.append(row)
    if result.T_mount_board is not None:
        key = frames.board_key
        t = result.T_mount_board[:3, 3]
        r = np.degrees(log_so3(result.T_mount_board[:3, :3]))
        lines.append(f"{key}: t = {np.round(t, 4).tolist()} m, rotvec = {np.round(r, 3).tolist()} deg")
    for (a, b), p in result.pairs.items():
        lines.append(f"T_{a}_{b}: |t| = {np.linalg.norm(p.T_a_b[:3, 3]):.4f} m, 1σ "
                     f"{np.round(p.sigma_translation_mm, 2).tolist()} mm / {np.round(p.sigma_rotation_deg, 3).tolist()} deg")
    rej = [rv for c in result.cameras.values() for rv in c.views_rejected]
    if rej:
        lines.append(f"rejected views ({len(rej)}):")
        lines += [f"  {rv.camera} capture {rv.capture}: {rv.reason}" for rv in rej[:20]]
        if len(rej) > 20:
            lines.append(f"  ... and {len(rej) - 20} more (see the result file)")
    if result.rejected_corners:
        lines.append(f"rejected corners: {len(result.rejected_corners)} (listed in the result file)")
    if result.board_scale_sigma is not None:
        lines.append(f"board scale (printed / declared size): {result.board_scale:.5f} ± {result.board_scale_sigma:.5f}")
    budgets = {n: c.error_budget for n, c in result.cameras.items() if c.calibrated and c.error_budget}
    if budgets:
        lines.append("what the 1σ is made of (error_budget in the result file):")
        lines += [f"  {line}" for n, b in budgets.items() for line in share_lines(n, b)]
        lines += [f"  {b['advice']}" for b in budgets.values() if b.get("advice")]
    lines += robot_lines(result.robot)
    lines += [f"note: {n}" for n in result.notes]
    if not result.converged:
        lines.append(f"WARNING: the solver did not converge ({result.iterations} iterations): the estimates may still "
                     "move; the report will say FAIL")
    return "\n".join(lines)


def robot_lines(robot: dict | None) -> list:
    """The estimated joint offsets (mrad, 1-sigma), the joints held fixed and the strongest correlations."""
    if not robot:
        return []
    o, s = robot["joint_offsets_rad"], robot["joint_offsets_sigma_rad"]
    names = robot.get("joint_names") or [f"joint{i + 1}" for i in range(len(o))]
    lines = [f"robot joint zero offsets ({robot.get('model', '?')}; physical angle = reported + offset), mrad:"]
    w = max([10, *(len(str(n)) for n in names)])
    for i, (n, v, sg) in enumerate(zip(names, o, s)):
        if sg is None:
            lines.append(f"  {n:{w}s} held at 0")
        else:
            lines.append(f"  {n:{w}s} {1e3 * v:+8.3f} ± {1e3 * sg:.3f}  ({v / sg:+.1f} σ from zero)")
    for f in robot.get("fixed", []):
        lines.append(f"  joint {f['joint']} fixed: {f['reason']}")
    strong = [c for c in robot.get("strongest_correlations", []) if abs(c["correlation"]) >= 0.5]
    if strong:
        lines.append("  strongest correlations: " + ", ".join(f"joint {c['joint']} ~ {c['with']} {c['correlation']:+.2f}"
                                                           for c in strong))
    return lines


def print_problems(problems, per_kind: int = 3) -> None:
    """Warnings for images the detector could not use, grouped by kind: a recording where most
    frames do not show the board gives one line per kind with a count, not hundreds of lines."""
    import re

    groups = {}
    for f, msg in problems:
        kind = re.sub(r"\(.*?\)|\d+(\.\d+)?", "#", str(msg)).strip()
        groups.setdefault(kind, []).append((f, msg))
    for items in groups.values():
        for f, msg in items[:per_kind]:
            print(f"warning: {f}: {msg}", file=sys.stderr)
        if len(items) > per_kind:
            print(f"warning: ... and {len(items) - per_kind} more images like these", file=sys.stderr)


def name_inputs(result, workcell=None, camera_files: dict | None = None):
    """``result`` naming the user's own files: each advice's ``--workcell CELL.yaml`` the workcell the
    dataset was captured with (when it records one), and each camera's intrinsics the camera file it
    was given with ``--intrinsics NAME=FILE`` (``intrinsics.file``)."""
    from calibgraph.solver.camera.session_plan import name_workcell

    camera_files = camera_files or {}
    cams = {}
    for n, c in result.cameras.items():
        b, intr = c.error_budget, c.intrinsics
        if b and b.get("advice") and workcell is not None:
            b = {**b, "advice": name_workcell(b["advice"], workcell)}
        if intr is not None and n in camera_files:
            intr = {**intr, "file": str(camera_files[n])}
        cams[n] = replace(c, error_budget=b, intrinsics=intr)
    return replace(result, cameras=cams)


def camera_file_paths(items) -> list:
    """The files of ``--intrinsics NAME=CAM.yaml`` arguments (inputs no output may replace)."""
    return [Path(s.partition("=")[2]) for s in items if "=" in s]


def run(args) -> int:
    from calibgraph.io.lock import dataset_lock

    if not args.dataset.is_dir():  # no such folder, or a file: load_dataset says which
        from calibgraph.io.layouts import load_dataset

        load_dataset(args.dataset)
    # a capture, an import or a second solve of the dataset is refused meanwhile, naming this one
    with dataset_lock(args.dataset, "solve", lambda line: print(line, file=sys.stderr)):
        return _run(args)


def _run(args) -> int:
    from calibgraph.io.camera_file import apply_camera_files, read_camera_file_args
    from calibgraph.io.dataset import recorded_workcell
    from calibgraph.io.layouts import load_dataset
    from calibgraph.io.output_guard import check_output_file, write_keeping_previous
    from calibgraph.io.specs import target_option
    from calibgraph.solver.solve.batch import solve

    out = args.out or (args.dataset / "result.json")
    files = read_camera_file_args(args.intrinsics)
    ds = load_dataset(args.dataset, target=target_option(args.target))
    if files:
        ds = replace(ds, cameras=apply_camera_files(ds.cameras, files, f"dataset {args.dataset}"))
    # said now, not after solving; the previous result stays until the new one is whole, and is kept then
    inputs = camera_file_paths(args.intrinsics) + ([args.target] if args.target is not None else []) \
        + ([args.config] if args.config is not None else [])
    check_output_file(out, "result", "result file", "result.json", inputs=inputs, datasets=[args.dataset])
    if args.config is not None:
        if not args.strict:
            from calibgraph.core.errors import InputError

            raise InputError("--config (tolerances) is read only with --strict; add --strict or drop --config.")
        from calibgraph.report.tolerances import load_tolerances

        load_tolerances(args.config)  # a bad tolerance file is said now, not after solving
    if args.rrd:
        check_output_file(args.rrd, "recording", "rerun recording", "calibgraph.rrd", inputs=inputs + [out],
                          datasets=[args.dataset])
    for f, msg in ds.problems:
        print(f"warning: {f}: {msg}", file=sys.stderr)
    opts = solver_options(args, ds)
    if opts.kinematics == "joint-offsets":  # said now, before detection: the angles must give the recorded poses
        from calibgraph.solver.robot.kinematics import check_recorded_angles

        check_recorded_angles(opts.kinematics_model, ds.captures, f"--estimate-kinematics {opts.kinematics}")
    problem, detector = build_problem(ds, args.method, opts, progress=not args.quiet)
    print_problems(getattr(detector, "problems", []) or [])
    if not args.quiet:
        for note in getattr(detector, "notes", []) or []:
            print(note)
    result = solve(problem)
    result = replace(result, dataset=str(args.dataset), target=ds.target.to_dict())
    result = name_inputs(result, recorded_workcell(args.dataset), dict(zip(files, camera_file_paths(args.intrinsics))))
    kept = write_keeping_previous(out, lambda: result.save(out))
    if kept is not None:
        print(f"kept the previous result as {kept}")
    if not args.quiet:
        print(format_summary(result))
        rms_px = max((c.reprojection_rms_px / np.sqrt(2.0) for c in result.calibrated.values()), default=0.0)
        if rms_px > 1.0 and opts.intrinsics == "fixed":
            print(f"hint: residuals of {rms_px:.2f} px per axis are large for a sub-pixel detector; "
                  "if the intrinsics come without (or with wrong) distortion, drop --fixed-intrinsics")
        print(f"wrote {out}")
    if args.rrd:
        try:
            from calibgraph.report.rerun_view import plan_log_path, write_rrd
        except ImportError:
            print("rerun recording skipped: calibgraph.report.rerun_view is not available", file=sys.stderr)
        else:
            write_rrd(result, problem, args.rrd, plan_log=plan_log_path(args.dataset))
            if not args.quiet:
                print(f"wrote {args.rrd}")
    for name, why in result.not_calibrated.items():
        print(f"calibgraph solve: camera {name} is NOT calibrated: {why}", file=sys.stderr)
    if args.strict:
        from calibgraph.cli.report import print_verdict
        from calibgraph.report.html import report_verdicts

        if not print_verdict(result, report_verdicts(result, config=args.config, dataset=ds)):
            return EXIT_NOT_CALIBRATED
    return EXIT_NOT_CALIBRATED if result.not_calibrated else 0
