"""``calibgraph view RESULT [--dataset DIR] [--rrd out.rrd]``: the calibration in rerun."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path


def add_parser(sub):
    p = sub.add_parser("view", help="show the calibration in the rerun viewer (or save a .rrd)",
                       description="Robot base, flange and board poses, camera frustums with their images, detected "
                                   "vs reprojected corners, residuals per capture, outliers highlighted.")
    p.add_argument("result", type=Path,
                   help="result.json or result.yaml (or the dataset folder `calibgraph solve` wrote result.json into)")
    p.add_argument("--dataset", type=Path, default=None,
                   help="dataset folder: images, detections and recorded flange poses "
                        "(default: the dataset named in RESULT, if it exists)")
    p.add_argument("--rrd", type=Path, default=None,
                   help="save the recording here and do not open a viewer")
    return p


def run(args) -> int:
    from calibgraph.io.output_guard import check_output_file
    from calibgraph.report.rerun_view import rerun_cli, write_rrd
    from calibgraph.solver.output.result import load_result, result_path

    args.result = result_path(args.result)  # a dataset folder: the result.json solve wrote into it
    result = load_result(args.result)
    dataset = args.dataset
    if dataset is None and result.dataset and Path(result.dataset).is_dir():
        dataset = Path(result.dataset)
    path = check_output_file(args.rrd or args.result.with_suffix(".rrd"), "recording", "recording file",
                             "calibgraph.rrd", inputs=[args.result],
                             datasets=[result.dataset, args.dataset, args.result.parent])
    if dataset is not None:  # a layout that names no board (ViSP's) is read with the board it was solved with
        from calibgraph.io.layouts import load_dataset
        from calibgraph.report.rerun_view import plan_log_path
        from calibgraph.solver.output.result import solved_target

        plan_log = plan_log_path(dataset)
        dataset = load_dataset(dataset, fallback_target=solved_target(result))
        write_rrd(result, dataset, path, plan_log=plan_log)
    else:
        write_rrd(result, dataset, path)
    print(f"wrote {path}")
    if args.rrd is None:
        if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
            # the viewer runs on after we exit; the recording file stays for later
            subprocess.Popen(rerun_cli() + [str(path)], start_new_session=True)
            print("opened the rerun viewer")
        else:
            print(f"no display: open it elsewhere with `rerun {path}`")
    return 0
