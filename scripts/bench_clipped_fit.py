#!/usr/bin/env python
"""The board fit's clipped pixels: censored (the fit) against dropped (the fit before), on rendered boards
against the renderer's exact truth.

A pixel at 0 or 255 says only that the true level is at most / at least that. The fit before gave such
pixels no weight; on boards rendered or exposed hard (ink at 0, paper at 255, no blur: the MC-HEC
recording's frames) that leaves ~20 quantised edge pixels around a corner. The fit now treats them as
censored: no cost where the model is beyond the clip on the side the pixel allows, a pull where it is
not (``calibgraph.detect.board_fit.CLIPPED_PIXELS``).

Cases: renders made like MC-HEC's (thesis board 5 x 4 squares, 2 x 2 supersampling, no blur, no
noise, exposure 1.3, black 0 / white 255: clipped ink and paper) at 23 and 14 px squares; ordinary
renders (4 x 4 supersampling, blur 0.5-0.7 px, noise 1 DN, levels 20-220, exposure 1.0-1.2) at 8 and 10
px squares. Random views: tilt 0-50 deg, any direction and roll, the board anywhere in the middle 40 %
of the L515-like frame. Per case and mode: corners (all corners of every board, both modes on the same
boards), RMS of the 2-D error against truth, the mean error vector; and the detector before the fit.

Usage: python scripts/bench_clipped_fit.py [--boards 16] [--out scripts/results]
Writes OUT/bench_clipped_fit.{md,json}.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import calibgraph  # noqa: E402,F401  (before numpy: single-threaded BLAS)
import numpy as np  # noqa: E402

import calibgraph.detect.board_fit as bf  # noqa: E402
from calibgraph.core.camera import preset  # noqa: E402
from calibgraph.core.targets import a4_board_54, thesis_board  # noqa: E402
from calibgraph.detect.corners import detect_image  # noqa: E402
from calibgraph.sim.board_image import look_at_board, render_view  # noqa: E402

CASES = [  # name, target, square px, supersample, blur, exposure, black, white, noise
    ("MC-HEC-like, 23 px squares", thesis_board, 23, 2, 0.0, 1.3, 0, 255, 0.0),
    ("MC-HEC-like, 14 px squares", thesis_board, 14, 2, 0.0, 1.3, 0, 255, 0.0),
    ("ordinary, thesis board, 8 px squares", thesis_board, 8, 4, 0.5, 1.2, 20, 220, 1.0),
    ("ordinary, A4 board, 10 px squares", a4_board_54, 10, 4, 0.7, 1.2, 20, 220, 1.0),
    ("ordinary, A4 board, 10 px squares, exposure 1.0", a4_board_54, 10, 4, 0.7, 1.0, 20, 220, 1.0),
]


def boards(target, square_px, ss, blur, exposure, black, white, noise, n, seed):
    """n rendered views whose every corner is seen, with their truth."""
    intr = preset("l515")
    rng = np.random.default_rng(seed)
    z_m = intr.K[0, 0] * target.pitch_m / square_px
    out = []
    while len(out) < n:
        tilt, phi = rng.uniform(0, 50), rng.uniform(0, 2 * np.pi)
        off = rng.uniform(-0.4, 0.4, 2) * np.array([intr.width_px, intr.height_px]) / 2
        T = look_at_board(target, z_m, tilt * np.cos(phi), tilt * np.sin(phi), rng.uniform(0, 360), tuple(off), intr)
        rv = render_view(target, intr, T, blur_sigma_px=blur, noise_sigma=noise, supersample=ss, exposure=exposure,
                         black_level=black, white_level=white, background=0.2, seed=int(rng.integers(1 << 30)))
        if len(rv.ids) == target.n_points:
            out.append(rv)
    return out


def errors(views, target, refine=True):
    """The 2-D errors against truth of the boards every mode finds whole (None where not)."""
    out = []
    for rv in views:
        d = detect_image(rv.image, target, refine=refine)
        if not (d.ok and d.n_found == target.n_points):
            out.append(None)
            continue
        where = {int(i): j for j, i in enumerate(rv.ids)}
        out.append(d.uv_px - rv.uv_px[[where[int(i)] for i in d.ids]])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--boards", type=int, default=16)
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--out", type=Path, default=REPO / "scripts" / "results")
    args = ap.parse_args(argv)
    t0 = time.time()
    rows = []
    for name, make_target, sq, ss, blur, exposure, black, white, noise in CASES:
        target = make_target()
        views = boards(target, sq, ss, blur, exposure, black, white, noise, args.boards, args.seed)
        per = {}
        for mode in ("dropped", "censored"):
            bf.CLIPPED_PIXELS = mode
            per[mode] = errors(views, target)
        bf.CLIPPED_PIXELS = "censored"
        per["detector (no fit)"] = errors(views, target, refine=False)
        both = [i for i in range(len(views)) if all(per[m][i] is not None for m in per)]
        row = {"case": name, "boards": len(views), "boards_all_modes": len(both)}
        for m, E in per.items():
            e = np.concatenate([E[i] for i in both]) if both else np.zeros((0, 2))
            row[m] = {"rms_px": float(np.sqrt(np.mean(np.sum(e ** 2, 1)))) if len(e) else None,
                      "mean_px": e.mean(0).tolist() if len(e) else None, "corners": int(len(e)),
                      "boards_found": int(sum(x is not None for x in E))}
        rows.append(row)
        print(f"{name}: " + ", ".join(f"{m} {row[m]['rms_px']:.4f} px" for m in per), flush=True)
    meta = {"seconds": time.time() - t0, "boards": args.boards, "seed": args.seed}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_clipped_fit.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    L = ["# The board fit's clipped pixels: censored against dropped, on rendered boards vs truth", "",
         f"Made by `python scripts/bench_clipped_fit.py --boards {args.boards}` ({meta['seconds']:.0f} s). "
         "Cases and protocol: the script's docstring. Each cell: RMS of the 2-D corner error against the "
         "renderer's truth, px (mean error vector x, y), over the boards every column finds whole.", "",
         "| case | boards | censored (the fit) | dropped (the fit before) | detector, no fit |", "|---|---|---|---|---|"]
    for r in rows:
        cell = lambda m: (f"{r[m]['rms_px']:.4f} ({r[m]['mean_px'][0]:+.4f}, {r[m]['mean_px'][1]:+.4f})"  # noqa: E731
                          if r[m]["rms_px"] is not None else "-")
        L.append(f"| {r['case']} | {r['boards_all_modes']} of {r['boards']} | {cell('censored')} | {cell('dropped')} | "
                 f"{cell('detector (no fit)')} |")
    (args.out / "bench_clipped_fit.md").write_text("\n".join(L) + "\n")
    print(f"wrote {args.out / 'bench_clipped_fit.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
