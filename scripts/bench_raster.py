#!/usr/bin/env python
"""MuJoCo's OpenGL renderer vs calibgraph's built-in rasteriser (calibgraph.sim.raster): corner
accuracy on the same scenes, and render time.

For each cell, poses are planned (calibgraph.plan.planner) and at every pose each camera the
planner expects to see the board is rendered by both backends at the same state, degraded by the
same sensor model with the same noise seed (so the two images differ only by the renderer), and
detected with calibgraph's detector. Against the exact truth (the board points projected through
the camera's intrinsics, ``SimWorld.board_truth_px``) each image gives:

* the RMS corner error (px) and the mean error vector;
* the radial scale error: ``s = sum(e . r) / sum(r . r)`` with ``e`` the corner errors and ``r``
  the truth corners about their centroid — a renderer that draws the board too big or too small
  by a factor 1 + s (a half-texel or half-pixel slip, a wrong focal length) shows as s != 0.

Reported per cell and backend: images, square size (px), RMS, mean scale error ± its standard
error (spread of per-image values / sqrt(n)), the paired difference of the scale errors (raster -
MuJoCo) ± its standard error, and the CPU time of one ideal render.

Cells: ``demo`` (the default of ``calibgraph demo``: three L515 at 3 m, A4 board of 25 mm
squares), ``far`` (two L515 at 4 m: squares of ~8 px), ``near`` (two D455 at 1.5 m, lens
distortion on).

Usage: MUJOCO_GL=egl python scripts/bench_raster.py [--poses 20] [--out scripts/results]
Writes OUT/bench_raster.{md,json}. Needs a working MuJoCo renderer (EGL or OSMesa) for the
comparison.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

# The poses of the saved figures came from the planner before it chose poses by information
# (plan_trajectory(select='random')); kept so that this script reproduces them. 'information' (today's
# default) re-measures with the planner `calibgraph sim` uses.
PLAN_SELECT = "random"
sys.path.insert(0, str(REPO))

from calibgraph.detect.corners import detect_image  # noqa: E402
from calibgraph.plan.planner import plan_trajectory  # noqa: E402
from calibgraph.sim.render import SimWorld  # noqa: E402
from calibgraph.sim.workcell import Realism, ring_workcell  # noqa: E402

CELLS = {
    "demo": lambda: ring_workcell(n_cameras=3, distance_m=3.0, preset_name="l515", spread_deg=200.0, name="demo"),
    "far": lambda: ring_workcell(n_cameras=2, distance_m=4.0, preset_name="l515", spread_deg=120.0, name="far"),
    "near": lambda: ring_workcell(n_cameras=2, distance_m=1.5, preset_name="d455", spread_deg=60.0, name="near",
                                  realism=Realism(distortion=True)),
}


def corner_metrics(uv_det: np.ndarray, uv_true: np.ndarray) -> dict:
    """RMS (px), mean error (px, 2) and radial scale error of detected vs true corners."""
    e = uv_det - uv_true
    r = uv_true - uv_true.mean(axis=0)
    return {"rms_px": float(np.sqrt((e**2).sum(axis=1).mean())), "mean_px": e.mean(axis=0).tolist(),
            "scale": float((e * r).sum() / (r * r).sum())}


def square_px(world, camera: str) -> float:
    """Mean distance between neighbouring corners along a row, pixels."""
    uv = world.board_truth_px(camera)
    t = world.cell.target
    g = uv.reshape(t.rows, t.cols, 2)
    return float(np.linalg.norm(np.diff(g, axis=1), axis=2).mean())


def run_cell(name: str, n_poses: int) -> dict:
    cell = CELLS[name]()
    worlds = {b: SimWorld(cell, renderer=b) for b in ("mujoco", "raster")}
    traj = plan_trajectory(worlds["mujoco"], n_poses, seed=1, select=PLAN_SELECT)
    rows = []
    times = {b: [] for b in worlds}
    for k, pose in enumerate(traj.poses):
        for cam in pose.cameras:
            row = {"pose": k, "camera": cam}
            for b, w in worlds.items():
                w.set_q(pose.q_rad)
                t0 = time.process_time()
                w.render_ideal(cam)
                times[b].append(time.process_time() - t0)
                img = w.render(cam, rng=np.random.default_rng(1000 * k + cell.camera_names.index(cam)))
                det = detect_image(img, cell.target, cell.camera(cam).intrinsics)
                if det.ok:
                    row[b] = corner_metrics(det.uv_px, w.board_truth_px(cam)[det.ids])
                    row[b]["n"] = int(det.ids.size)
            row["square_px"] = square_px(worlds["mujoco"], cam)
            rows.append(row)
    for w in worlds.values():
        w.close()
    both = [r for r in rows if "mujoco" in r and "raster" in r]
    summary = {"cell": name, "views": len(rows), "detected_both": len(both),
               "detected": {b: sum(b in r for r in rows) for b in worlds},
               "square_px": [float(np.min([r["square_px"] for r in rows])), float(np.max([r["square_px"] for r in rows]))],
               "render_cpu_s": {b: float(np.mean(v)) for b, v in times.items()}}
    for b in worlds:
        s = np.array([r[b]["scale"] for r in both])
        n = np.array([r[b]["n"] for r in both])
        ms = np.array([r[b]["rms_px"] for r in both]) ** 2
        summary[b] = {"rms_px": float(np.sqrt((n * ms).sum() / n.sum())), "scale": float(s.mean()),
                      "scale_se": float(s.std(ddof=1) / np.sqrt(len(s))),
                      "mean_px": np.mean([r[b]["mean_px"] for r in both], axis=0).tolist()}
    d = np.array([r["raster"]["scale"] - r["mujoco"]["scale"] for r in both])
    summary["scale_diff"] = float(d.mean())
    summary["scale_diff_se"] = float(d.std(ddof=1) / np.sqrt(len(d)))
    return {"summary": summary, "rows": rows}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=20)
    ap.add_argument("--cells", default="demo,far,near")
    ap.add_argument("--out", type=Path, default=REPO / "scripts" / "results")
    args = ap.parse_args()
    t_start = time.time()
    results = [run_cell(c, args.poses) for c in args.cells.split(",")]
    lines = ["# bench_raster: MuJoCo's OpenGL renderer vs calibgraph's rasteriser\n",
             f"Same scenes, same sensor model and noise seed; corners detected by calibgraph's detector vs the exact "
             f"truth (see the script's docstring). {args.poses} planned poses per cell; run time "
             f"{time.time() - t_start:.0f} s.\n",
             "| cell | backend | images detected / rendered | square px | corner RMS px | mean error px | "
             "radial scale error (± s.e.) | render CPU s |",
             "|---|---|---|---|---|---|---|---|"]
    for res in results:
        s = res["summary"]
        for b in ("mujoco", "raster"):
            m = s[b]
            lines.append(f"| {s['cell']} | {b} | {s['detected'][b]} / {s['views']} | {s['square_px'][0]:.1f}-"
                         f"{s['square_px'][1]:.1f} | {m['rms_px']:.3f} | ({m['mean_px'][0]:+.3f}, {m['mean_px'][1]:+.3f}) | "
                         f"{m['scale']:+.1e} ± {m['scale_se']:.1e} | {s['render_cpu_s'][b]:.2f} |")
    lines.append("")
    for res in results:
        s = res["summary"]
        lines.append(f"- {s['cell']}: paired scale difference raster - mujoco {s['scale_diff']:+.1e} ± "
                     f"{s['scale_diff_se']:.1e} over {s['detected_both']} images detected by both.")
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_raster.md").write_text(text)
    (args.out / "bench_raster.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
