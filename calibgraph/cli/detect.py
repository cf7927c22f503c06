"""``calibgraph detect DATASET``: detect the target in every image, print per-camera statistics
and every per-file problem (the run never stops on one bad image)."""

from __future__ import annotations

import sys
from pathlib import Path

from calibgraph.cli.solve import add_target_flag


def add_parser(sub):
    p = sub.add_parser("detect", help="detect the target in a dataset's images and report per camera",
                       description="Detect the target in all images of a dataset (results are cached next to the data).")
    p.add_argument("dataset", type=Path, help="dataset folder (calibgraph or a peer layout)")
    add_target_flag(p)
    p.add_argument("--workers", type=int, default=2, help="parallel detection threads (default 2)")
    p.add_argument("--upscale", default="auto", help="'auto' (default), 1 (off), 2 or 3")
    p.add_argument("--method", choices=("classic", "sb", "auto"), default="auto",
                   help="checkerboard detector: auto (default: classic, SB for squares under 8 px), classic or sb")
    p.add_argument("--no-cache", action="store_true", help="do not read or write the detection cache")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def summarise(dataset, results) -> str:
    """Per-camera table: views, detected, points per view, pitch, sharpness, up-scaled, time."""
    import numpy as np

    lines = [f"{'camera':12s} {'views':>5s} {'ok':>5s} {'pts/view':>9s} {'pitch px':>9s} {'blur px':>8s} "
             f"{'upscaled':>8s} {'ms/img':>7s}"]
    for cam in dataset.cameras:
        stored = [v for v in dataset.views if v.camera == cam and v.detected]
        dets = [d for (c, _), d in results.items() if c == cam]
        ok = [d for d in dets if d.ok]
        n_views = len(dets) + len(stored)
        def med(vals):
            vals = [v for v in vals if np.isfinite(v)]
            return f"{np.median(vals):.1f}" if vals else "-"
        lines.append(
            f"{cam:12s} {n_views:5d} {len(ok) + len(stored):5d} {med([d.n_found for d in ok]):>9s} "
            f"{med([d.pitch_px for d in ok]):>9s} {med([d.sharpness_px for d in ok]):>8s} "
            f"{sum(d.upscale > 1 for d in ok):8d} {med([1e3 * d.time_s for d in dets]):>7s}")
        if stored:
            lines.append(f"{'':12s} ({len(stored)} views carry stored detections and were not re-detected)")
    return "\n".join(lines)


def run(args) -> int:
    from calibgraph.detect.corners import dataset_detector
    from calibgraph.io.layouts import load_dataset
    from calibgraph.io.specs import target_option

    from calibgraph.core.errors import InputError

    if args.upscale not in ("auto", "1", "2", "3"):
        raise InputError(f"--upscale {args.upscale}: give auto, 1 (off), 2 or 3.")
    if args.workers < 1:
        raise InputError(f"--workers {args.workers}: give 1 or more threads.")
    ds = load_dataset(args.dataset, target=target_option(args.target))
    up = args.upscale if args.upscale == "auto" else int(args.upscale)
    det = dataset_detector(ds, workers=args.workers, progress=not args.quiet, cache=not args.no_cache, upscale=up,
                           method=args.method, fail_fast=True)
    results = det.run()
    print(f"{ds.root}: target {ds.target.kind} {ds.target.rows}x{ds.target.cols} points, {len(ds.cameras)} camera(s), "
          f"{len(ds.captures)} captures")
    print(summarise(ds, results))
    for note in det.notes:
        print(note)
    problems = list(ds.problems) + list(det.problems)
    if problems:
        print(f"problems ({len(problems)}):", file=sys.stderr)
        for f, msg in problems:
            print(f"  {f}: {msg}", file=sys.stderr)
    n_ok = sum(d.ok for d in results.values()) + sum(v.detected for v in ds.views)
    return 0 if n_ok else 1
