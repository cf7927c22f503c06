#!/usr/bin/env python
"""The guided live intrinsics session (``calibgraph intrinsics --live``, issue 37) on the simulated hand-held board.

Per seed, a :class:`calibgraph.sim.handheld.HandheldBoardCamera` (the board on a random walk at 0.3-1 m,
5 frames per second of simulated clock, motion blur while it moves) feeds
:func:`calibgraph.acquire.live_session.run_live_session` with its default goal (what the error budget's
advice assumes: a 25-view session with the corner noise the session measures, capped at 0.1 px). The
camera reports **factory-class** intrinsics (focal length 0.6 % off, no distortion); the images are
rendered with the true ones (distortion included). Printed and saved per seed: frames read, views taken
and used, the goal, fx 1-sigma reached, the true fx / fy / cx / cy errors and error / 1-sigma, wall time.
The session's intrinsics are estimated (never held), so there is no oracle figure: the truth is only the
yardstick.

    python scripts/bench_live_intrinsics.py [--camera small|l515] [--seeds 3] [--max-frames 800] [--out scripts/results]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from calibgraph.acquire.live_session import run_live_session
from calibgraph.core.camera import Intrinsics, preset
from calibgraph.plan.cell import board_by_name
from calibgraph.sim.handheld import HandheldBoardCamera

REPO = Path(__file__).resolve().parents[1]


def camera(kind: str) -> Intrinsics:
    """The true camera: a D455 at half resolution (640x400) or an L515 (1920x1080), with distortion."""
    p = preset("d455" if kind == "small" else "l515")
    K = p.K.copy()
    if kind == "small":
        K[:2] *= 0.5
    w, h = (640, 400) if kind == "small" else (p.width_px, p.height_px)
    return Intrinsics(K=K, dist=np.array([0.05, -0.08, 0.0004, -0.0003, 0.02]), width_px=w, height_px=h)


def run(kind: str, seed: int, max_frames: int) -> dict:
    true = camera(kind)
    reported = replace(true, K=true.K @ np.diag([1.006, 1.006, 1.0]), dist=np.zeros(5), source="factory")
    board = board_by_name("a4_54")
    cam = HandheldBoardCamera("cam", true, board, reported=reported, fps=5.0, seed=seed)
    t0 = time.time()
    o = run_live_session(cam, board, max_frames=max_frames)
    row = {"seed": seed, "reason": o.reason, "frames": o.frames, "views_taken": len(o.views), "goal_px": o.goal_px,
           "wall_s": round(time.time() - t0, 1)}
    r = o.result
    if r is not None:
        row.update(views_used=len(r.views_used), pixel_sigma_px=r.pixel_sigma_px)
        for name, (i, j) in {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}.items():
            err = float(r.intrinsics.K[i, j] - true.K[i, j])
            row[name] = {"sigma_px": r.sigma[name], "error_px": err, "error_over_sigma": err / r.sigma[name]}
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--camera", choices=("small", "l515"), default="small")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--max-frames", type=int, default=800)
    ap.add_argument("--out", type=Path, default=REPO / "scripts" / "results")
    a = ap.parse_args()
    rows = []
    for seed in range(1, a.seeds + 1):
        row = run(a.camera, seed, a.max_frames)
        rows.append(row)
        fx = row.get("fx", {})
        print(f"seed {seed}: {row['reason']}; {row['frames']} frames, {row['views_taken']} views, goal "
              f"{row['goal_px']:.3f} px, fx 1-sigma {fx.get('sigma_px', float('nan')):.3f} px, error "
              f"{fx.get('error_px', float('nan')):+.3f} px ({fx.get('error_over_sigma', float('nan')):+.2f} sigma), "
              f"{row['wall_s']} s", flush=True)
    z = np.array([[r[n]["error_over_sigma"] for n in ("fx", "fy", "cx", "cy")] for r in rows if "fx" in r])
    summary = {"camera": a.camera, "intrinsics_reported": "factory-class (fx +0.6 %, no distortion)",
               "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()), "load_average": os.getloadavg()[0],
               "rows": rows, "rms_error_over_sigma_fx_fy_cx_cy": np.sqrt(np.mean(z ** 2, axis=0)).tolist() if len(z) else []}
    a.out.mkdir(parents=True, exist_ok=True)
    stem = a.out / f"bench_live_intrinsics_{a.camera}"
    stem.with_suffix(".json").write_text(json.dumps(summary, indent=1))
    lines = [f"# Live intrinsics session on the simulated hand-held board ({a.camera})", "",
             f"{summary['date_utc']} UTC, load {summary['load_average']:.1f} on 2 cores; the camera reports "
             f"{summary['intrinsics_reported']}; default goal (the advice's 25-view session at the measured corner noise).",
             "", "| seed | end | frames | views taken / used | goal px | fx 1σ px | fx err px | err/1σ fx, fy, cx, cy | wall s |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "fx" not in r:
            lines.append(f"| {r['seed']} | {r['reason']} | {r['frames']} | {r['views_taken']} / - | {r['goal_px']:.3f} | - | - | - | {r['wall_s']} |")
            continue
        zs = ", ".join(f"{r[n]['error_over_sigma']:+.2f}" for n in ("fx", "fy", "cx", "cy"))
        lines.append(f"| {r['seed']} | {r['reason']} | {r['frames']} | {r['views_taken']} / {r['views_used']} | "
                     f"{r['goal_px']:.3f} | {r['fx']['sigma_px']:.3f} | {r['fx']['error_px']:+.3f} | {zs} | {r['wall_s']} |")
    if summary["rms_error_over_sigma_fx_fy_cx_cy"]:
        lines += ["", "RMS error / 1σ (fx, fy, cx, cy): " + ", ".join(f"{v:.2f}" for v in summary["rms_error_over_sigma_fx_fy_cx_cy"])]
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {stem}.json and {stem}.md")


if __name__ == "__main__":
    main()
