"""Could the blind look's full-resolution chessboard probe look at the saddle regions only? (issue 36)

The survey's blind look (calibgraph/detect/blind.py) probes a 1080p frame for a chessboard of any
size with OpenCV's SB detector on the half-resolution image, then, when that sees none, on the full
one (~130 ms: on the MC-HEC recording 57 such probes, ~7.5 CPU-s, a fifth of the detection). This
bench measures the cheaper stand-in one would try first: the full-resolution probe on the saddle
regions only (``roi_candidates``, the frame equalised as a whole first so each crop sees the pixels
the whole-frame probe sees), against the whole-frame probe it would replace, on

- the MC-HEC recording's frames (every ``--step``-th) in which the half-resolution probe sees none,
- rendered 1080p frames of a 3 x 4 and a 6 x 9 board with squares of 5-20 px (where the
  full-resolution probe is what finds a far board).

It prints and saves (scripts/results/bench_probe_regions.{md,json}) how often the two agree on
"a chessboard seen or none" and their CPU time per frame. The blind look does not use the stand-in:
a probe that misses what the whole-frame one sees changes which survey frames are searched.

    nice -n 10 python scripts/bench_probe_regions.py
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
OUT = ROOT / "scripts" / "results"
DATA = ROOT.parent / "shared" / "datasets" / "mchec_medium_workcell"


def region_probe(grey, target):
    """(rows, cols) of the largest chessboard OpenCV's SB detector sees in the saddle regions of
    ``grey`` (full resolution, the frame equalised as a whole), or None."""
    import cv2

    from calibgraph.detect.regions import roi_candidates

    eq = cv2.equalizeHist(grey)
    best = None
    for x0, y0, x1, y1 in roi_candidates(grey, target):
        cv2.setRNGSeed(0)
        ok, c, meta = cv2.findChessboardCornersSBWithMeta(eq[y0:y1, x0:x1], (3, 3), cv2.CALIB_CB_LARGER)
        if ok and meta is not None and meta.ndim == 2 and meta.size == len(c) and (best is None or meta.size > best[0]):
            best = (meta.size, tuple(int(v) for v in meta.shape))
    return None if best is None else best[1]


def compare(frames, target) -> dict:
    """Half-resolution probe on every frame; where it sees none, the whole-frame and the region probe."""
    import cv2

    from calibgraph.detect.board_size import chessboard_seen

    rows, t_full, t_reg = [], 0.0, 0.0
    for name, grey in frames:
        half = cv2.resize(grey, (grey.shape[1] // 2, grey.shape[0] // 2), interpolation=cv2.INTER_AREA)
        if chessboard_seen(half, 2) is not None:
            continue
        c0 = time.process_time()
        full = chessboard_seen(grey)
        c1 = time.process_time()
        reg = region_probe(grey, target)
        c2 = time.process_time()
        t_full, t_reg = t_full + c1 - c0, t_reg + c2 - c1
        rows.append({"frame": name, "full": None if full is None else [full.rows, full.cols],
                     "regions": None if reg is None else list(reg)})
    n = len(rows)
    disagree = [r for r in rows if (r["full"] is None) != (r["regions"] is None)]
    return {"frames_probed": n, "agree": n - len(disagree), "disagree": disagree,
            "full_seen": sum(r["full"] is not None for r in rows), "regions_seen": sum(r["regions"] is not None for r in rows),
            "full_ms": 1000 * t_full / max(n, 1), "regions_ms": 1000 * t_reg / max(n, 1)}


def mchec_frames(step):
    import cv2

    for f in sorted(DATA.glob("camera*/image/*.png"))[::step]:
        yield str(f.relative_to(DATA)), cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)


def rendered_frames(target, seed):
    from calibgraph.core.camera import Intrinsics
    from calibgraph.sim.board_image import look_at_board, render_view

    f = 1400.0
    intr = Intrinsics(K=np.array([[f, 0, 959.5], [0, f, 539.5], [0, 0, 1]]), dist=np.zeros(5), width_px=1920,
                      height_px=1080)
    rng = np.random.default_rng(seed)
    for sq in (5, 6, 7, 8, 9, 10, 11, 12, 14, 16, 20):
        for k in range(6):
            tilt, phi = rng.uniform(0, 40), rng.uniform(0, 2 * np.pi)
            off = rng.uniform(-0.5, 0.5, 2) * np.array([960, 540])
            T = look_at_board(target, f * target.pitch_m / sq, tilt * np.cos(phi), tilt * np.sin(phi),
                              rng.uniform(0, 360), tuple(off), intr)
            yield f"{target.rows}x{target.cols} {sq} px #{k}", render_view(
                target, intr, T, blur_sigma_px=rng.uniform(0.4, 1.0), noise_sigma=1.0, seed=k).image


def main() -> int:
    from calibgraph.core.targets import Target

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--step", type=int, default=3, help="every n-th MC-HEC frame")
    args = ap.parse_args()
    t0, load0 = time.time(), os.getloadavg()
    mchec = Target.from_dict({"kind": "checkerboard", "rows": 3, "cols": 4, "pitch_m": 0.05})
    sets = {}
    if DATA.is_dir():
        sets[f"MC-HEC, every {args.step}th frame"] = compare(mchec_frames(args.step), mchec)
    else:
        print(f"bench_probe_regions: {DATA} is absent; rendered frames only", file=sys.stderr)
    for spec in ({"kind": "checkerboard", "rows": 3, "cols": 4, "pitch_m": 0.05},
                 {"kind": "checkerboard", "rows": 6, "cols": 9, "pitch_m": 0.03}):
        t = Target.from_dict(spec)
        sets[f"rendered {t.rows}x{t.cols}, squares 5-20 px"] = compare(rendered_frames(t, 3), t)
    lines = ["# The full-resolution chessboard probe on the saddle regions only, against the whole frame", "",
             f"{platform.node()}, {os.cpu_count()} cores, load average {load0[0]:.1f}/{load0[1]:.1f}/{load0[2]:.1f} at "
             f"the start, {os.getloadavg()[0]:.1f} at the end; {time.time() - t0:.0f} s. Frames in which the "
             "half-resolution probe sees no chessboard (the ones the blind look probes again at full resolution). "
             "CPU ms per frame. Made by scripts/bench_probe_regions.py.", "",
             "| frames | probed | agree (seen / none) | whole frame sees | regions see | whole frame ms | regions ms |",
             "|---|---|---|---|---|---|---|"]
    for name, r in sets.items():
        lines.append(f"| {name} | {r['frames_probed']} | {r['agree']} | {r['full_seen']} | {r['regions_seen']} | "
                     f"{r['full_ms']:.0f} | {r['regions_ms']:.0f} |")
    lines += ["", "Disagreements (whole frame / regions, inner corners seen):", ""]
    for name, r in sets.items():
        lines += [f"- {name}: {d['frame']}: {d['full']} / {d['regions']}" for d in r["disagree"]]
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "bench_probe_regions.md").write_text("\n".join(lines) + "\n")
    (OUT / "bench_probe_regions.json").write_text(json.dumps({"load_start": load0, "sets": sets}, indent=1))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
