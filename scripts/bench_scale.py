"""How the batch solve scales with cameras and poses: wall time, CPU time and peak memory.

Synthetic corners (calibgraph.sim.synthetic_corners.make_scene): D455-class cameras on a 3 m ring, the A4
board, 0.3 px corner noise, FK noise 0.1 mm / 0.01 deg; the true intrinsics are given as a
calibration file's (``source: calibration``, not held), so the solve estimates them under that
file's prior (the default) and the errors stay those of a truthful file. Each configuration
runs in its own process, so its peak resident memory is its own. Prints a table and writes
scripts/results/bench_scale.{md,json}.

    python scripts/bench_scale.py                      # 4/8/16/32 cameras x 120/480 poses
    python scripts/bench_scale.py --cameras 16 --poses 480 --repeat 3
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "scripts" / "results"

ONE = r"""
import json, resource, sys, time
import numpy as np
from calibgraph.core.camera import Intrinsics
from calibgraph.core.transforms import pose_error
from calibgraph.sim.synthetic_corners import make_scene, ring_cameras
from calibgraph.solver.batch import solve
n_cam, n_poses, seed = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
sc = make_scene(cameras=ring_cameras([3.0] * n_cam, presets=("d455",)), n_poses=n_poses, pixel_sigma_px=0.3,
                fk_sigma_translation_m=1e-4, fk_sigma_rotation_rad=np.radians(0.01), seed=seed, reported_intrinsics="exact")
p = sc.problem.with_(cameras={n: Intrinsics(K=c.K, dist=c.dist, width_px=c.width_px, height_px=c.height_px,
                                            source="calibration") for n, c in sc.problem.cameras.items()})
rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
timings = {}
t0, c0 = time.perf_counter(), time.process_time()
r = solve(p, timings=timings)
wall, cpu = time.perf_counter() - t0, time.process_time() - c0
err = [1e3 * pose_error(c.T_ref_cam, sc.truth.T_ref_cam[n])[0] for n, c in r.cameras.items()]
z = [1e3 * pose_error(c.T_ref_cam, sc.truth.T_ref_cam[n])[0] / np.linalg.norm(c.sigma_translation_mm)
     for n, c in r.cameras.items()]
print(json.dumps({"cameras": n_cam, "poses": n_poses, "views": len(p.detections), "wall_s": wall, "cpu_s": cpu,
                  "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20,
                  "rss_before_solve_gb": rss0 / 2 ** 20, "stages_s": timings, "iterations": r.iterations,
                  "converged": r.converged, "err_mm_mean": float(np.mean(err)), "err_mm_max": float(np.max(err)),
                  "err_over_sigma_rms": float(np.sqrt(np.mean(np.square(z))))}))
"""


def run(n_cam: int, n_poses: int, seed: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", ONE, str(n_cam), str(n_poses), str(seed)], capture_output=True,
                         text=True, env=env, check=False)
    if out.returncode != 0:
        return {"cameras": n_cam, "poses": n_poses, "error": out.stderr.strip().splitlines()[-1][:300]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", type=int, nargs="*", default=[4, 8, 16, 32])
    ap.add_argument("--poses", type=int, nargs="*", default=[120, 480])
    ap.add_argument("--repeat", type=int, default=1, help="runs per configuration (seeds 0..repeat-1); the median is shown")
    ap.add_argument("--out", type=Path, default=OUT / "bench_scale")
    args = ap.parse_args()
    rows = []
    t0 = time.time()
    for n_cam in args.cameras:
        for n_poses in args.poses:
            runs = [run(n_cam, n_poses, seed) for seed in range(args.repeat)]
            ok = [r for r in runs if "error" not in r]
            if not ok:
                rows.append(runs[0])
                print(f"{n_cam:3d} cameras x {n_poses:4d} poses: FAILED {runs[0]['error']}", flush=True)
                continue
            best = sorted(ok, key=lambda r: r["wall_s"])[len(ok) // 2]
            best["wall_s_all"] = [r["wall_s"] for r in ok]
            rows.append(best)
            print(f"{n_cam:3d} cameras x {n_poses:4d} poses ({best['views']} views): {best['wall_s']:6.2f} s wall, "
                  f"{best['cpu_s']:6.2f} s CPU, {best['peak_rss_gb']:.2f} GB peak; error {best['err_mm_mean']:.3f} mm "
                  f"mean, error/1σ RMS {best['err_over_sigma_rms']:.2f}", flush=True)
    lines = ["# Solve time and memory against cameras and poses", "",
             f"Synthetic corners, D455-class cameras on a 3 m ring, intrinsics estimated (given as a calibration "
             f"file's). {platform.node()}, {os.cpu_count()} cores, load average at the start "
             f"{os.getloadavg()[0]:.1f}; {time.time() - t0:.0f} s in all. Median of {args.repeat} run(s).", "",
             "| cameras | poses | views | wall s | CPU s | peak GB | LM s | marginals s | error mm mean | error/1σ RMS |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['cameras']} | {r['poses']} | | failed: {r['error']} | | | | | | |")
            continue
        st = r["stages_s"]
        lines.append(f"| {r['cameras']} | {r['poses']} | {r['views']} | {r['wall_s']:.2f} | {r['cpu_s']:.2f} | "
                     f"{r['peak_rss_gb']:.2f} | {st.get('lm', 0):.2f} | {st.get('marginals', 0):.2f} | "
                     f"{r['err_mm_mean']:.3f} | {r['err_over_sigma_rms']:.2f} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    args.out.with_suffix(".json").write_text(json.dumps(rows, indent=2))
    print(f"wrote {args.out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
