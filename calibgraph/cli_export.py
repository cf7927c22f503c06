"""``calibgraph export RESULT --format urdf|ros2-launch|opencv-yaml|yaml|json --out DIR``."""

from __future__ import annotations

from pathlib import Path

from .exports import FORMATS


def add_parser(sub):
    p = sub.add_parser("export", help="write the result for a robot stack (URDF, ROS 2 launch, OpenCV YAML, YAML)",
                       description="Export camera poses (and intrinsics when known) in standard formats. "
                                   "Frames and units are stated in every file.")
    p.add_argument("result", type=Path, help="result.json or result.yaml written by `calibgraph solve`")
    p.add_argument("--format", dest="fmt", choices=FORMATS, required=True, action="append",
                   help="output format; repeat for several")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--dataset", type=Path, default=None,
                   help="dataset folder for intrinsics when the result has none (opencv-yaml)")
    p.add_argument("--parent", default=None,
                   help="parent frame/link name (default base_link, or flange for eye-in-hand)")
    return p


def run(args) -> int:
    from .exports import export
    from .result import load_result_dict

    d = load_result_dict(args.result)
    for fmt in args.fmt:
        for p in export(d, fmt, args.out, dataset=args.dataset, parent=args.parent):
            print(f"wrote {p}")
    return 0
