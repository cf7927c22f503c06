"""``calibgraph import rosbag2 BAG --out DATASET``: a ROS 2 recording as a calibgraph dataset.

    calibgraph import rosbag2 BAG --out DATASET [--base-frame F] [--flange-frame F]
                                   [--camera NAME=IMAGE_TOPIC ...] [--target SPEC.yaml]

See :mod:`calibgraph.io.rosbag2` for what is read and how capture moments are chosen. Joint states
give the robot pose through the Franka FR3/Panda model (:func:`calibgraph.acquire.safety.franka_fk`)
when TF has no base -> flange chain (or with ``--robot-pose joint_states``).
"""

from __future__ import annotations

from pathlib import Path


def add_parser(sub):
    top = sub.add_parser("import", help="import a recording (rosbag2: sqlite3 or MCAP) as a dataset",
                         description="Write a calibgraph dataset from a recording; `calibgraph import FORMAT --help` "
                                     "gives the flags of each format.")
    formats = top.add_subparsers(dest="format", metavar="FORMAT", required=True)
    # each format its own usage and flags, so that `import rosbag2 --help` says rosbag2's
    p = formats.add_parser("rosbag2", help="a ROS 2 bag (sqlite3 or MCAP)",
                           description="Write a calibgraph dataset from a rosbag2 recording (sqlite3 or MCAP): camera "
                                       "images + CameraInfo, the robot pose from /tf + /tf_static (base -> flange) or "
                                       "/joint_states (Franka model): a capture at each moment the robot is still, "
                                       "with the cameras that have a frame in it.")
    p.add_argument("bag", type=Path, help="the bag folder (with metadata.yaml) or its .db3 / .mcap file")
    p.add_argument("--out", type=Path, required=True, help="new dataset folder (created; not one holding a dataset)")
    p.add_argument("--base-frame", default=None,
                   help="the bag's TF frame of the robot base, to read the robot pose from (default fr3_link0 / "
                        "panda_link0); not an output frame: the dataset's poses are in the base frame")
    p.add_argument("--flange-frame", default=None, help="TF flange frame (default fr3_link8 / panda_link8)")
    p.add_argument("--camera", action="append", default=[], metavar="NAME=IMAGE_TOPIC",
                   help="a camera and its image topic (repeat; default: every image topic, named by namespace)")
    p.add_argument("--robot-pose", choices=("auto", "joint_states", "tf"), default="auto",
                   help="auto: the TF chain base -> flange when the bag has one, else /joint_states through the Franka model")
    p.add_argument("--target", type=Path, default=None, help="target spec YAML (default: the A4 54-corner board)")
    p.add_argument("--still-mm", type=float, default=0.2, help="the robot is still while it moves less (default 0.2)")
    p.add_argument("--still-deg", type=float, default=0.02, help="... and turns less (default 0.02)")
    p.add_argument("--min-still-s", type=float, default=0.3, help="for at least this long (default 0.3 s)")
    p.add_argument("--quiet", action="store_true", help="no summary (warnings and errors still print)")
    return top


def run(args) -> int:
    import sys

    from calibgraph.acquire.safety import franka_fk
    from calibgraph.core.errors import InputError
    from calibgraph.io.output_guard import check_output_folder
    from calibgraph.io.rosbag2 import import_rosbag2
    from calibgraph.io.specs import load_target

    named = {}
    for item in args.camera:
        name, sep, topic = item.partition("=")
        if not sep or not name or not topic.startswith("/"):
            raise InputError(f"--camera {item!r}: expected NAME=/image/topic.")
        named[name] = topic
    if args.bag.exists():  # a missing bag is said first
        check_output_folder(args.out, "dataset folder (--out)", claimed=True)  # an existing dataset: refused below
    rep = import_rosbag2(args.bag, args.out, base_frame=args.base_frame, flange_frame=args.flange_frame, cameras=named,
                         target=load_target(args.target) if args.target else None,
                         fk=franka_fk, still_mm=args.still_mm, still_deg=args.still_deg, min_still_s=args.min_still_s,
                         robot_pose=args.robot_pose)
    for w in rep.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if not args.quiet:
        print(rep.summary())
        print(f"wrote {rep.out}; next: calibgraph solve {rep.out}")
    return 0
