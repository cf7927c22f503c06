"""``calibgraph export RESULT --format urdf|ros2-launch|opencv-yaml|camera-info|yaml|json|robot --out DIR``, and
``calibgraph export DATASET --format mchec --out DIR`` (a dataset in the Multi-Camera-Hand-Eye-
Calibration layout, for moving data between the two tools).

A result solved with ``--estimate-kinematics joint-offsets`` also gets, with ``--format urdf`` (or
alone with ``--format robot``), the arm's corrected URDF (offsets folded into the joint origins)
and ``joint_offsets.yaml`` for the controller."""

from __future__ import annotations

import sys
from pathlib import Path

from calibgraph.report.exports import FORMATS


def add_parser(sub):
    p = sub.add_parser("export", help="write the result for a robot stack (URDF, ROS 2 launch, OpenCV YAML, ROS "
                                      "camera_info, YAML)",
                       description="Export camera poses (and intrinsics when known) in standard formats. "
                                   "Frames and units are stated in every file.")
    p.add_argument("result", type=Path, help="result.json or result.yaml written by `calibgraph solve` (or the "
                                              "dataset folder it wrote result.json into; a dataset folder for --format "
                                              "mchec)")
    p.add_argument("--format", dest="fmt", choices=tuple(FORMATS) + ("mchec",), required=True, action="append",
                   help="output format; repeat for several (robot: the corrected arm URDF and joint_offsets.yaml of a "
                        "result solved with --estimate-kinematics; urdf writes them too)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--dataset", type=Path, default=None,
                   help="dataset folder for intrinsics when the result has none (opencv-yaml, camera-info)")
    p.add_argument("--parent", default=None,
                   help="parent frame/link name (default base_link, or flange for eye-in-hand)")
    return p


def _planned(result, args) -> list:
    """(file name, kind) of every file the export will write: the export is made first in a
    temporary folder, so the guard judges the very files and headers it will write."""
    import tempfile

    from calibgraph.io.output_guard import output_kind
    from calibgraph.report.exports import export

    with tempfile.TemporaryDirectory(prefix="calibgraph_export_") as tmp:
        for fmt in args.fmt:
            export(result, fmt, tmp, dataset=args.dataset, parent=args.parent)
        return [(p.name, output_kind(p) or "export") for p in sorted(Path(tmp).iterdir()) if not p.name.startswith(".")]


def run(args) -> int:
    from calibgraph.io.output_guard import check_output_file, check_output_folder, keep_previous
    from calibgraph.report.exports import export, renamed
    from calibgraph.solver.output.result import load_result, result_path

    if "mchec" in args.fmt:
        from calibgraph.core.errors import InputError
        from calibgraph.report.mchec_export import export_mchec

        if len(args.fmt) > 1:
            raise InputError("export: --format mchec takes a dataset folder and cannot be combined with result formats.")
        if not args.result.is_dir():
            raise InputError(f"export: --format mchec needs a dataset folder, got {args.result}.")
        check_output_folder(args.out, "export folder")
        export_mchec(args.result, args.out)
        print(f"wrote {args.out} (Multi-Camera-Hand-Eye-Calibration layout)")
        return 0
    args.result = result_path(args.result)  # a dataset folder: the result.json solve wrote into it
    result = load_result(args.result)
    check_output_folder(args.out, "export folder")  # never a dataset or inside one
    planned = _planned(result, args)
    for name, kind in planned:  # none replaces a file calibgraph did not write as that kind, or the input
        check_output_file(args.out / name, kind, "exported file", name, inputs=[args.result])
    for name, _ in planned:
        kept = keep_previous(args.out / name)  # an exported result replaced is kept beside it
        if kept is not None:
            print(f"kept the previous {name} as {kept}")
    for name, why in result.not_calibrated.items():
        print(f"note: camera {name!r} is not exported: it was not calibrated ({why})")
    for name, ident in renamed(result).items():
        print(f"note: camera {name!r} is exported as {ident} (its sanitised name is shared with another camera)")
    if args.dataset is not None and {"opencv-yaml", "camera-info"} & set(args.fmt):
        given = [n for n, c in result.calibrated.items() if c.solved_intrinsics is None]
        if given:
            print(f"warning: the result does not record the intrinsics {', '.join(given)} were solved with; their "
                  f"files carry the dataset's given intrinsics ({args.dataset}), and say so", file=sys.stderr)
    for fmt in args.fmt:
        for p in export(result, fmt, args.out, dataset=args.dataset, parent=args.parent):
            print(f"wrote {p}")
    return 0
