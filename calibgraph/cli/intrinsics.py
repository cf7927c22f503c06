"""``calibgraph intrinsics IMAGES_DIR --target TARGET.yaml --out CAM.yaml``: calibrate one camera
from hand-held images of a board (no robot) and write its intrinsics with their covariance."""

from __future__ import annotations

import sys
from pathlib import Path

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")


def add_parser(sub):
    from calibgraph.solver.camera.intrinsics_model import DEFAULT_MODEL, DISTORTION_MODELS

    p = sub.add_parser("intrinsics", help="calibrate one camera's intrinsics from close-range images of a board",
                       description="Close-range intrinsics calibration: detect the board in every image of "
                                   "IMAGES_DIR, fit the camera (fx, fy, cx, cy, distortion) with every view's pose, "
                                   "reject bad views with the reason, and write CAM.yaml with the full covariance "
                                   "(use it with solve --intrinsics NAME=CAM.yaml). Take 20-30 images at 0.3-0.8 m, "
                                   "the board tilted by 20-45 degrees and moved over the whole image, into its "
                                   "corners.")
    p.add_argument("images", type=Path, metavar="IMAGES_DIR", nargs="?", default=None,
                   help="folder of the camera's images (png, jpg, ...); none with --live")
    p.add_argument("--target", type=Path, default=None,
                   help="target spec YAML (target: {kind, rows, cols, pitch_m}; rows/cols count inner corners); "
                        "default: target.yaml in IMAGES_DIR or its parent, else the board of a calibgraph "
                        "dataset.yaml one or two folders up")
    p.add_argument("--out", type=Path, required=True, help="camera file to write (YAML)")
    p.add_argument("--model", choices=tuple(DISTORTION_MODELS), default=DEFAULT_MODEL,
                   help=f"distortion coefficients to estimate (default {DEFAULT_MODEL})")
    p.add_argument("--quiet", action="store_true", help="print only the result line")
    live = p.add_argument_group("a guided live session at the camera (instead of IMAGES_DIR)")
    live.add_argument("--live", action="store_true",
                      help="take frames from the camera's device while the board is held in front of it: a frame is "
                           "taken when the board is still and adds information; stops when fx's 1-sigma meets the "
                           "goal (Ctrl-C writes what it has)")
    live.add_argument("--camera", default=None, metavar="NAME", help="the camera of --workcell (with --live)")
    live.add_argument("--workcell", type=Path, default=None, metavar="CELL.yaml",
                      help="the workcell naming the camera's device (realsense, kinect, ros2, or a simulated camera: "
                           "a simulated hand-held board); its board unless --target")
    live.add_argument("--goal-fx-percent", type=float, default=None, metavar="PCT",
                      help="fx 1-sigma to reach, in %% of fx (default: what the error budget's advice assumed, a "
                           "25-image session at this camera's corner noise, at most 0.1 px, set by the first "
                           "calibration; else 0.05)")
    live.add_argument("--view", action="store_true",
                      help="stream a live rerun view (the image with the corners, the coverage heat map, fx 1-sigma "
                           "over time): a viewer where there is a display, else a .rrd beside --out (or --rrd)")
    live.add_argument("--rrd", type=Path, default=None, metavar="FILE",
                      help="write the live view into this rerun recording instead of opening a viewer")
    live.add_argument("--save-views", type=Path, default=None, metavar="DIR",
                      help="also write the frames the session took as PNG into this new folder "
                           "(calibgraph intrinsics DIR then calibrates them again)")
    return p


def _images(folder: Path) -> list:
    from calibgraph.core.errors import InputError

    if folder is None:
        raise InputError("intrinsics: give IMAGES_DIR (the folder of the camera's images), or --live --camera NAME "
                         "--workcell CELL.yaml to take them from the camera.")
    if not folder.exists():
        raise InputError(f"{folder}: no such folder; give the folder that holds the camera's images.")
    if not folder.is_dir():
        raise InputError(f"{folder}: is a file; give the folder that holds the camera's images.")
    paths = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
                   and not p.name.startswith("."))
    if not paths:
        raise InputError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)}) in this folder.")
    return paths


def _target_path(args) -> Path:
    from calibgraph.core.errors import InputError

    if args.target is not None:
        return args.target
    for cand in (args.images / "target.yaml", args.images.parent / "target.yaml"):
        if cand.is_file():
            return cand
    # a calibgraph dataset's camera folder (DATASET/images/CAM): the board its header names
    for header in (args.images.parent / "dataset.yaml", args.images.parent.parent / "dataset.yaml"):
        if header.is_file() and _names_a_target(header):
            return header
    raise InputError(f"no --target given and no target.yaml in {args.images} or its parent (nor a calibgraph "
                     "dataset.yaml above it); give the board's spec (target: {kind, rows, cols, pitch_m}, rows/cols "
                     "counting inner corners).")


def _names_a_target(header: Path) -> bool:
    from calibgraph.core.errors import InputError
    from calibgraph.io.files import read_yaml

    try:
        d = read_yaml(header, "dataset header")
    except InputError:
        return False
    return isinstance(d, dict) and isinstance(d.get("target"), dict)


def run(args) -> int:
    if args.live:
        from calibgraph.cli.intrinsics_live import run_live

        return run_live(args)
    from calibgraph.io.camera_file import write_camera_file
    from calibgraph.io.output_guard import check_output_file, write_keeping_previous
    from calibgraph.io.specs import load_target
    from calibgraph.solver.camera.intrinsics_session import calibrate_images

    paths = _images(args.images)
    target_file = _target_path(args)
    out = check_output_file(args.out, "camera file", "camera file", "camera.yaml", inputs=[target_file, *paths])
    target = load_target(target_file)
    say = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    say(f"detecting the {target.kind} ({target.rows}x{target.cols} points of {target.pitch_m * 1e3:g} mm"
        f"{'' if args.target is not None else f', from {target_file}'}) in {len(paths)} images of {args.images}")

    r = calibrate_images(paths, target, model=args.model, progress=not args.quiet, where=str(target_file))
    kept = write_keeping_previous(out, lambda: write_camera_file(out, r.to_dict(target)))
    if kept is not None:
        print(f"kept the previous camera file as {kept}")
    intr, s = r.intrinsics, r.sigma
    if not args.quiet:
        for name, why in r.rejected:
            print(f"  rejected {name}: {why}")
        print(f"  fx {intr.K[0, 0]:.2f} ± {s['fx']:.2f}  fy {intr.K[1, 1]:.2f} ± {s['fy']:.2f}  "
              f"cx {intr.K[0, 2]:.2f} ± {s['cx']:.2f}  cy {intr.K[1, 2]:.2f} ± {s['cy']:.2f} px (1-sigma)")
        dist = ", ".join(f"{n} {r.values[n]:+.5f} ± {s[n]:.5f}" for n in r.parameter_names[4:])
        print(f"  distortion ({r.model}): {dist}")
        for w in r.warnings:
            print(f"  warning: {w}")
    print(f"wrote {out}: {len(r.views_used)} of {len(paths)} images used, RMS {r.rms_px:.3f} px, "
          f"fx 1-sigma {s['fx']:.2f} px ({100 * s['fx'] / intr.K[0, 0]:.3f} %)")
    return 0
